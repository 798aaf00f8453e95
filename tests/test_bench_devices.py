"""The cross-device benchmark (``clrecon bench``) on a tiny frame: rows, outputs, compare, CLI
and the forced-default runs."""
from __future__ import annotations

import copy
import csv
import json
import os

import pytest

from clrecon.bench.devices import ROW_KEYS, bench, compare, write_outputs
from clrecon.cli import main
from clrecon.device import get_device

SIZE, SPP, REPEATS = (32, 24), 2, 3
VARIANTS = [("box", "box", {}), ("sweep dof-layers", "sweep", {"dof_layers": True})]


@pytest.fixture(scope="module")
def result():
    return bench(devices=[0], variants=VARIANTS, size=SIZE, spp=SPP, repeats=REPEATS)


def _value(rows, **match):
    found = [r["value"] for r in rows if all(r[k] == v for k, v in match.items())]
    assert len(found) == 1, f"{match}: {len(found)} rows"
    return found[0]


def test_rows_and_statistics(result):
    label = get_device(0).info.label
    assert result["devices"] == [label]
    assert result["size"] == [32, 24] and result["spp"] == SPP and result["repeats"] == REPEATS
    rows = result["rows"]
    assert rows and all(tuple(r) == ROW_KEYS for r in rows)
    assert {r["method"] for r in rows} == {"box", "sweep dof-layers"}
    assert {r["size"] for r in rows} == {"32x24"} and {r["spp"] for r in rows} == {SPP}
    passes = {"box": {"box", "frame"},
              "sweep dof-layers": {"sweep_layer_sums", "sweep_layer_resolve", "frame"}}
    for method, names in passes.items():
        assert {r["pass"] for r in rows if r["method"] == method} == names
        for name in names:
            lo, med, hi = (_value(rows, method=method, config="tuned", metric=m, **{"pass": name})
                           for m in ("min_ms", "median_ms", "max_ms"))
            assert 0 <= lo <= med <= hi
            ratio = _value(rows, method=method, config="default",
                           metric="ratio_default_over_tuned", **{"pass": name})
            assert ratio > 0
        sps = _value(rows, method=method, config="tuned", metric="samples_per_s",
                     **{"pass": "frame"})
        assert sps > 0
    units = {r["metric"]: r["unit"] for r in rows}
    assert units["median_ms"] == "ms" and units["samples_per_s"] == "1/s"
    assert units["ratio_default_over_tuned"] == "x"
    for run in result["runs"]:
        if not run["forced_default"]:  # all passes at default: no default runs, ratio 1.0
            assert not any(r["config"] == "default" and r["metric"] == "median_ms"
                           and r["method"] == run["method"] for r in rows)
            assert _value(rows, method=run["method"], config="default",
                          metric="ratio_default_over_tuned", **{"pass": "frame"}) == 1.0
    assert label in result["markdown"]
    assert "sweep_layer_sums" in result["markdown"]


def test_write_outputs(result, tmp_path):
    jp, cp = tmp_path / "b.json", tmp_path / "sub" / "b.csv"
    write_outputs(result, json_path=jp, csv_path=cp)
    data = json.loads(jp.read_text())
    assert "markdown" not in data and len(data["rows"]) == len(result["rows"])
    with cp.open(newline="") as fh:
        lines = list(csv.reader(fh))
    assert tuple(lines[0]) == ROW_KEYS
    assert len(lines) == 1 + len(result["rows"])


def test_compare(result):
    old = copy.deepcopy({k: v for k, v in result.items() if k != "markdown"})
    for r in old["rows"]:
        if r["metric"] == "median_ms":
            r["value"] *= 2
    gone = next(r for r in old["rows"] if r["metric"] == "median_ms" and r["method"] == "box"
                and r["config"] == "tuned")
    old["rows"].remove(gone)
    old["rows"].append(dict(gone, method="old variant"))
    text = compare(result, old)
    lines = text.splitlines()
    frame = next(ln for ln in lines if "| sweep dof-layers | frame |" in ln
                 and "| tuned | median_ms" in ln)
    assert "-50.0" in frame and "better" in frame
    assert any("old variant" in ln and "removed" in ln for ln in lines)
    assert any("| box |" in ln and "added" in ln for ln in lines)
    with pytest.raises(ValueError):
        compare(result, {"nope": 1})


def test_cli(tmp_path, capsys):
    p, c = tmp_path / "bench.json", tmp_path / "bench.csv"
    argv = ["bench", "--devices", "0", "--size", "32x24", "--spp", "2", "--repeats", "3",
            "--variant", "box"]
    assert main(argv + ["--json", str(p)]) == 0
    data = json.loads(p.read_text())
    assert data["devices"] == [get_device(0).info.label] and data["rows"]
    assert "| box |" in capsys.readouterr().out
    assert main(argv + ["--csv", str(c), "--compare", str(p)]) == 0
    out = capsys.readouterr().out
    assert "change %" in out and c.read_text().startswith(",".join(ROW_KEYS))
    assert main(["bench", "--devices", "0", "--compare", str(tmp_path / "missing.json")]) == 2


def test_forced_default_restores_env(monkeypatch):
    monkeypatch.setenv("CLRECON_TUNE_BOX", '{"wg_x": 1, "wg_y": 1}')
    before = {k: v for k, v in os.environ.items() if k.startswith("CLRECON_TUNE_")}
    res = bench(devices=[0], variants=[("box", "box", {})], size=SIZE, spp=SPP,
                repeats=REPEATS)
    assert os.environ["CLRECON_TUNE_BOX"] == '{"wg_x": 1, "wg_y": 1}'
    assert {k: v for k, v in os.environ.items() if k.startswith("CLRECON_TUNE_")} == before
    (run,) = res["runs"]
    assert run["tuning"] == {"box": "env"}
    assert run["forced_default"] and run["forced_passes"] == ["box"]
    assert run["describe"]["local_size"] == [1, 1]
    assert run["default_describe"]["local_size"] == [16, 4]
    rows = res["rows"]
    for name in ("box", "frame"):
        assert _value(rows, config="default", metric="median_ms", **{"pass": name}) > 0
        assert _value(rows, config="default", metric="ratio_default_over_tuned",
                      **{"pass": name}) > 0
    assert "| env |" in res["markdown"]


def test_cli_methods_option(tmp_path, capsys):
    from clrecon.cli import main

    out = tmp_path / "m.json"
    assert main(["bench", "--devices", "0", "--size", "16x16", "--spp", "2", "--repeats", "3",
                 "--methods", "box,sweep", "--json", str(out)]) == 0
    rows = json.loads(out.read_text())["rows"]
    assert {r["method"] for r in rows} == {"box", "sweep"}
