"""The cross-device benchmark (``clrecon bench``) on a tiny frame: rows, outputs, compare, CLI
and the forced-default runs."""
from __future__ import annotations

import copy
import csv
import json
import math
import os

import numpy as np
import pytest

from clrecon.bench.devices import (
    DEFAULT_VARIANTS,
    PEAK_CONFIG,
    ROW_KEYS,
    bench,
    compare,
    plot_bandwidth,
    variant_list,
    write_outputs,
)
from clrecon.cli import main
from clrecon.core.device import get_device
from clrecon.core.samples import FIELDS

SIZE, SPP, REPEATS = (32, 24), 2, 3
# the papers' method alone (the safeguard, on by default, runs it on halves too: see
# test_safeguarded_method_is_looked_into)
VARIANTS = [("box", "box", {}),
            ("sweep dof-layers", "sweep", {"dof_layers": True, "safeguard": False})]


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
                 "--methods", "box,sweep", "--only", "--json", str(out)]) == 0
    rows = json.loads(out.read_text())["rows"]
    assert {r["method"] for r in rows} == {"box", "sweep"}


# -- variants: --methods adds, --only restricts ----------------------------------------------

def test_variant_list_adds_to_the_defaults():
    defaults = [(lab, m, dict(k)) for lab, m, k in DEFAULT_VARIANTS]
    assert variant_list() == defaults
    extra = [("box", "box", {}), ("sweep", "sweep", {}), ("s4", "sweep", {"scales": 4})]
    assert variant_list(extra) == defaults + extra[1:]  # the default box is not repeated
    assert variant_list(extra, only=True) == extra
    with pytest.raises(ValueError, match="--only"):
        variant_list([], only=True)


def test_cli_methods_add_to_the_default_variants(tmp_path):
    out = tmp_path / "m.json"
    assert main(["bench", "--devices", "0", "--size", "16x16", "--spp", "2", "--repeats", "3",
                 "--no-peak", "--methods", "box,splat", "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    labels = [v["label"] for v in data["variants"]]
    assert labels == [lab for lab, _, _ in DEFAULT_VARIANTS] + ["splat"]
    assert {r["method"] for r in data["rows"]} == set(labels)
    # a variant that takes a default's label for something else is refused by name
    assert main(["bench", "--devices", "0", "--variant", "box=sweep"]) == 2
    assert main(["bench", "--devices", "0", "--only"]) == 2


# -- bandwidth -------------------------------------------------------------------------------

def _bytes_of_plan(pipe, samples_bytes: dict, out_bytes: int) -> dict:
    """Per step: inputs + outputs at the plan's sizes (computed from the plan, not from the
    buffers the bench saw bound)."""
    sizes = dict(samples_bytes) | dict(pipe.plan.temporaries) | {"out": out_bytes}
    return {s.name: sum(sizes[n] for n in s.inputs + s.outputs) for s in pipe.plan.steps}


def test_bandwidth_rows(result):
    from clrecon.api import make_pipeline
    from clrecon.tune.runners import synthetic_frame

    dev = get_device(0)
    label = dev.info.label
    rows = result["rows"]
    peak = result["peaks"][label]["copy"]
    assert peak["gb_per_s"] > 0 and math.isfinite(peak["gb_per_s"])
    w, h = SIZE
    npx = w * h
    buf = synthetic_frame(w, h, SPP)
    fields = {"color": npx * SPP * 12, "depth": npx * SPP * 4}
    expect = {"box": {"box": fields["color"] + npx * 12}}
    pipe = make_pipeline("sweep", dev.context, buf.inspect(), dof_layers=True, safeguard=False)
    expect["sweep dof-layers"] = _bytes_of_plan(pipe, fields, npx * 12)
    assert set(expect["sweep dof-layers"]) == {"sweep_layer_sums", "sweep_layer_resolve"}
    for method, passes in expect.items():
        (run,) = [r for r in result["runs"] if r["method"] == method]
        assert run["pass_bytes"] == passes
        for name, nbytes in [*passes.items(), ("frame", sum(passes.values()))]:
            def val(metric, name=name, method=method):
                return _value(rows, method=method, config="tuned", metric=metric,
                              **{"pass": name})
            assert val("bytes") == nbytes
            ms = val("median_ms")
            assert val("gb_per_s") == pytest.approx(nbytes / (ms * 1e6))
            assert val("fraction_of_peak") == pytest.approx(val("gb_per_s") / peak["gb_per_s"])
        assert _value(rows, method=method, config=PEAK_CONFIG, metric="peak_gb_per_s",
                      **{"pass": "frame"}) == peak["gb_per_s"]
    assert "GB/s" in result["markdown"] and "copy_float4" in result["markdown"]
    assert "Per pass, devices side by side" in result["markdown"]


def test_safeguarded_method_is_looked_into():
    """A safeguarded method runs as two steps of sub-pipelines (the frame, both halves): the
    bench reports the method's own passes, each half-frame pass counting both halves, and a
    two-kernel pass (layered's filter_sheared) as one row beside its kernels. (The error
    estimate alone runs the method on the frame and on its halves; the default blend runs
    only layered's statistics and partitions on the frame.)"""
    from clrecon.api import make_pipeline
    from clrecon.tune.runners import synthetic_frame

    w, h = SIZE
    npx = w * h
    knobs = {"safeguard": False, "estimate_error": True}
    res = bench(devices=[0], variants=[("layered", "layered", knobs)], size=SIZE, spp=SPP,
                repeats=REPEATS, peak=False)
    (run,) = res["runs"]
    pb = run["pass_bytes"]
    sheared = "filter_sheared_recursive + filter_sheared_gauss"
    assert "safeguard_split" not in pb  # layered reads its halves in place
    assert {"reproject", "reproject (halves)", sheared,
            "filter_sheared_recursive (halves) + filter_sheared_gauss (halves)",
            "safeguard_stats", "safeguard_rows + safeguard_blend"} <= set(pb)
    assert run["step_kernels"][sheared] == ["filter_sheared_recursive", "filter_sheared_gauss"]
    dev = get_device(0)
    paper = make_pipeline("layered", dev.context, synthetic_frame(w, h, SPP).inspect(),
                          safeguard=False)
    full = {f: npx * SPP * 4 * int(np.prod(FIELDS[f])) for f in FIELDS}
    own = _bytes_of_plan(paper, full, npx * 12)
    # the halves run a plan made for half the spp (reproject's buckets: a byte per sample)
    # on views of the frame's fields: each half is bound to (and loads the lines of) them all
    half_plan = make_pipeline("layered", dev.context,
                              synthetic_frame(w, h, SPP // 2).inspect(), safeguard=False)
    halves = _bytes_of_plan(half_plan, full, npx * 12)
    assert pb["reproject"] == own["reproject"]
    assert pb["reproject (halves)"] == 2 * halves["reproject"]
    assert pb[sheared] == own["filter_sheared"]
    rows = res["rows"]
    ms = _value(rows, config="tuned", metric="median_ms", **{"pass": sheared})
    parts = [_value(rows, config="tuned", metric="min_ms", **{"pass": k})
             for k in run["step_kernels"][sheared]]
    assert ms >= sum(parts) * 0.999
    frac = _value(rows, config="tuned", metric="fraction_of_peak", **{"pass": sheared})
    assert math.isnan(frac)  # peak=False: no peak to compare with
    peak_rows = [r for r in rows if r["config"] == PEAK_CONFIG]
    assert peak_rows and all(math.isnan(r["value"]) for r in peak_rows)
    md = res["markdown"]
    assert f"| {sheared} |" in md and "not measured" in md
    assert md.index("| filter_sheared_gauss |") < md.index(f"| {sheared} |")


def test_plot_bandwidth(result, tmp_path):
    png = plot_bandwidth(result, tmp_path / "sub" / "bw.png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_cli_plot_and_clpeak_flag(tmp_path, monkeypatch, capsys):
    from clrecon.bench import bandwidth

    monkeypatch.setattr(bandwidth.shutil, "which", lambda name: None)  # clpeak absent
    png = tmp_path / "bw.png"
    assert main(["bench", "--devices", "0", "--size", "16x16", "--spp", "2", "--repeats", "3",
                 "--only", "--variant", "box", "--clpeak", "--plot", str(png)]) == 0
    assert png.stat().st_size > 0
    assert "| not installed |" in capsys.readouterr().out
    assert main(["bench", "--devices", "0", "--only", "--variant", "box",
                 "--plot", str(tmp_path / "bw.jpg")]) == 2


def test_devices_take_turns_variant_by_variant(monkeypatch):
    """Every device runs a variant before any runs the next (the machine's drifting load is
    shared out), all on the same samples; here the second device is the first under another
    name."""
    import dataclasses

    from clrecon.bench import devices as bd

    dev = get_device(0)
    twin = dataclasses.replace(dev, info=dataclasses.replace(dev.info, name="twin"))
    monkeypatch.setattr(bd, "_select_devices", lambda spec: [dev, twin])
    res = bench(devices="all", variants=VARIANTS, size=SIZE, spp=SPP, repeats=REPEATS,
                peak=False)
    assert [(r["method"], r["device"]) for r in res["runs"]] == [
        (v, d) for v, _, _ in VARIANTS for d in (dev.info.label, twin.info.label)]
    assert res["devices"] == [dev.info.label, twin.info.label]
    assert f"ms {twin.info.label} / {dev.info.label}" in res["markdown"]
