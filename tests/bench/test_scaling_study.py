"""The scaling study script (tools/scaling_study.py) on tiny frames: it writes its
page, plots and JSON, its numbers are sane, the blur family hits the asked maxima, and the
budget rule skips instead of timing. No timing is asserted: only that times are positive."""
from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
from tool_module import load_tool

from clrecon.bench.scaling import render_blur_frame, scaled_scene
from clrecon.scenes import get_scene

study = load_tool("scaling_study")

PLOTS = ("resolution", "blur", "spp", "shares", "bandwidth")


def _run(tmp_path: Path, device, *extra: str, plots=PLOTS) -> tuple[int, dict, str]:
    out = tmp_path / "study"
    rc = study.main(["--quick", "--out", str(out), "--device", str(device.info.index),
                     "--sizes", "64x64", "--spp", "2", "--shares-size", "64x64", *extra])
    assert sorted(p.stem for p in out.glob("*.png")) == sorted(plots)
    for name in plots:
        assert (out / f"{name}.png").stat().st_size > 1000, name
    res = json.loads((out / "results.json").read_text())
    return rc, res, (tmp_path / "study.md").read_text()


def test_quick_study_numbers(tmp_path, device):
    rc, res, md = _run(tmp_path, device, "--methods", "box", "sweep", "--coc", "2,6",
                       "--motion", "0,12", "--repeats", "2")
    assert rc == 0
    assert res["peak"]["gb_per_s"] == max(res["peaks_gb_per_s"]) > 0
    assert len(res["peaks_gb_per_s"]) == 2  # before the first frame and after the last
    assert [m["label"] for m in res["methods"]] == ["box", "sweep"]
    # the shared frames are measured once: 64x64 2 spp (resolution, spp, shares), coc 2 /
    # motion 0 (both blur series), coc 6, motion 12
    assert len(res["frames"]) == 4
    for key, fr in res["frames"].items():
        for label, r in fr["results"].items():
            assert r["status"] == "ok", (key, label, r["status"])
            t = r["total_ms"]
            assert 0 < t["min"] <= t["median"] <= t["max"] and len(t["runs"]) == 2
            assert math.isclose(sum(p["share"] for p in r["passes"]), 1.0, rel_tol=1e-9)
            for p in r["passes"]:
                assert p["median_ms"] > 0 and p["bytes"] > 0, (key, label, p)
                assert p["gb_per_s"] > 0 and p["fraction_of_peak"] > 0, (key, label, p)
            assert math.isclose(sum(p["median_ms"] for p in r["passes"]), t["median"],
                                rel_tol=1e-6)  # two runs: the sum of medians is the median
        assert fr["results"]["box"]["passes"][0]["name"] == "box"
    sweep = res["frames"]["64x64 2spp"]["results"]["sweep"]
    names = {p["name"] for p in sweep["passes"]}  # the halves read in place: no split
    assert {"sweep_block (halves)", "safeguard_rows + safeguard_blend"} <= names
    assert "safeguard_split" not in names
    for series, want in (("coc", [2, 6]), ("motion", [0, 12])):
        pts = res["series"][series]
        assert [p["x"] for p in pts] == want
        for p in pts:
            fr = res["frames"][p["frame"]]
            coc, motion = (p["x"], 0.0) if series == "coc" else (2.0, p["x"])
            assert fr["max_abs_coc"] == pytest.approx(coc, rel=0.02)
            assert fr["max_abs_motion"] == pytest.approx(motion, rel=0.02, abs=0.0)
    assert "python tools/scaling_study.py --quick" in res["command"]
    for text in ("## Frames", "against resolution", "against blur size", "against spp",
                 "Byte model", "| sweep | sweep_block (halves) |", "(study/shares.png)"):
        assert text in md, text


def test_budget_skips(tmp_path, device):
    rc, res, md = _run(tmp_path, device, "--methods", "box", "--coc", "none", "--motion",
                       "none", "--max-seconds-per-frame", "1e-9",
                       plots=("resolution", "spp", "shares", "bandwidth"))
    assert rc == 0
    (fr,) = res["frames"].values()
    r = fr["results"]["box"]
    assert r["status"] == study.SKIPPED and r["warmup_ms"] > 0 and "total_ms" not in r
    assert "skipped (warm-up" in md and "against blur size" not in md


def test_bad_methods_fail_before_rendering(tmp_path):
    with pytest.raises(SystemExit, match="unknown method"):
        study.parse_args(["--out", str(tmp_path / "x"), "--methods", "nope"])
    with pytest.raises(SystemExit, match="not JSON"):
        study.parse_args(["--out", str(tmp_path / "x"), "--methods", "layered={filter}"])
    with pytest.raises(SystemExit, match="unknown knobs"):
        study.parse_args(["--out", str(tmp_path / "x"), "--methods", 'box={"nope": 1}'])
    a = study.parse_args(["--out", str(tmp_path / "x"), "--methods", "box",
                          'layered={"filter": "mip"}'])
    assert a.variants == [("box", "box", {}), ("layered filter=mip", "layered",
                                                {"filter": "mip"})]
    assert a.sizes[-1] == (1920, 1080) and a.coc == [2, 4, 8, 16, 32, 64]


def test_predict():
    assert study.predict_s([], 10) is None
    assert study.predict_s([(10, 1.0)], 40) == pytest.approx(4.0)
    # the blur family: same samples, time doubling per step -> the next step doubles again
    assert study.predict_s([(10, 1.0), (10, 2.0)], 10) == pytest.approx(4.0)
    # growth below what the samples explain does not shrink the prediction
    assert study.predict_s([(10, 1.0), (40, 2.0)], 80) == pytest.approx(4.0)
    # a frame measured earlier for another series is placed by its samples
    assert study.predict_s([(40, 6.0), (10, 1.0)], 80) == pytest.approx(18.0)


def test_blur_frame_refuses_what_it_cannot_scale():
    with pytest.raises(ValueError, match="pinhole"):
        render_blur_frame(get_scene("static_focus"), 16, 16, 1, 4.0, 0.0)
    with pytest.raises(ValueError, match="nothing moves"):
        render_blur_frame(get_scene("static_focus"), 16, 16, 1, 0.0, 4.0)
    with pytest.raises(ValueError, match="max_coc"):
        render_blur_frame(get_scene("deep"), 16, 16, 1, -1.0, 0.0)
    sc = scaled_scene(get_scene("deep"), 2.0, 0.0)
    assert sc.lens_radius == pytest.approx(2 * get_scene("deep").lens_radius)
    assert not sc.has_motion
