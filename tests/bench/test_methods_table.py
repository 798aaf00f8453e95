"""The methods table (``clrecon.bench.table``, ``clrecon table``) on tiny frames."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from clrecon.bench.table import crop_montage, hardest_region, methods_table, parse_variant
from clrecon.cli import main
from clrecon.io import load_image

VARIANTS = [("box", "box", {}), ("sweep dof-layers", "sweep", {"dof_layers": True})]


def test_methods_table_writes_json_markdown_and_crops(tmp_path, device):
    calls = []
    rep = methods_table(["spheres"], VARIANTS, size=(48, 32), spp=4, device=device,
                        out_dir=tmp_path, repeats=2, ref_spp=64,
                        progress=lambda d, t: calls.append((d, t)))
    for name in ("methods.json", "methods.md", "spheres_crops.png"):
        assert (tmp_path / name).is_file()
    assert calls[-1] == (4, 4)  # reference, samples, two variants

    data = json.loads((tmp_path / "methods.json").read_text())
    rows = data["rows"]
    assert [r["variant"] for r in rows] == ["box", "sweep dof-layers"]
    for r in rows:
        assert r["scene"] == "spheres" and r["size"] == [48, 32] and r["spp"] == 4
        assert math.isfinite(r["psnr"]) and math.isfinite(r["ssim"])
        assert r["ms"] >= 0 and all(v >= 0 for v in r["pass_ms"].values())
        assert "method" in r["describe"]
    assert rows[1]["describe"]["mode"] == "dof_layers"
    assert rows[1]["knobs"] == {"dof_layers": True}

    md = (tmp_path / "methods.md").read_text()
    assert md == rep["markdown"]
    assert "| spheres |" in md and "sweep dof-layers" in md and "**" in md

    strip = load_image(tmp_path / "spheres_crops.png")
    assert strip.shape == (32, 3 * 48 + 2 * 2, 3)
    assert (strip[:, 48:50] == 0).all() and (strip[:, 98:100] == 0).all()


def test_hardest_region_and_montage():
    err = np.zeros((200, 300))
    err[150:160, 40:50] = 1.0
    y, x = hardest_region(err, window=32)
    assert abs(y - 155) <= 16 and abs(x - 45) <= 16
    imgs = [np.full((200, 300, 3), v, np.float32) for v in (0.25, 0.5)]
    strip = crop_montage(imgs, (y, x))
    assert strip.shape == (128, 2 * 128 + 2, 3)
    assert (strip[:, :128] == 0.25).all() and (strip[:, 130:] == 0.5).all()
    assert (strip[:, 128:130] == 0).all()
    # smaller than the crop on one side: that side is used whole
    assert crop_montage(imgs[:1] * 3, (0, 0), crop=150).shape == (150, 3 * 150 + 4, 3)
    assert crop_montage([np.zeros((20, 10, 3))] * 2, (5, 5)).shape == (20, 22, 3)


@pytest.mark.parametrize("text, expected", [
    ("box", ("box", "box", {})),
    ("sweep:scales=4,sort=pixel", ("sweep:scales=4,sort=pixel", "sweep",
                                   {"scales": 4, "sort": "pixel"})),
    ("sweep:exponent=1.3,diameter_scale=2e-1", ("sweep:exponent=1.3,diameter_scale=2e-1",
                                                "sweep", {"exponent": 1.3,
                                                          "diameter_scale": 0.2})),
    ("sweep:dof_layers=true,smooth_motion=False", ("sweep:dof_layers=true,smooth_motion=False",
                                                   "sweep", {"dof_layers": True,
                                                             "smooth_motion": False})),
    ("sweep4=sweep:scales=4", ("sweep4", "sweep", {"scales": 4})),
    ("b=box", ("b", "box", {})),
    ("sweep:", ("sweep:", "sweep", {})),
])
def test_parse_variant(text, expected):
    label, method, knobs = parse_variant(text)
    assert (label, method, knobs) == expected
    for k, v in expected[2].items():
        assert type(knobs[k]) is type(v)


@pytest.mark.parametrize("text", ["", ":scales=4", "=box", "sweep:scales", "sweep:=4",
                                  "sweep:scales=2,scales=4"])
def test_parse_variant_rejects(text):
    with pytest.raises(ValueError):
        parse_variant(text)


def test_bad_variants_fail_before_rendering(tmp_path):
    with pytest.raises(ValueError, match="unknown method"):
        methods_table(["spheres"], [("x", "nope", {})], out_dir=tmp_path)
    with pytest.raises(TypeError, match="unknown knobs"):
        methods_table(["spheres"], [("x", "sweep", {"bogus": 1})], out_dir=tmp_path)
    with pytest.raises(ValueError, match="used twice"):
        methods_table(["spheres"], [("x", "box", {}), ("x", "box", {})], out_dir=tmp_path)
    assert not any(tmp_path.iterdir())


def test_cli_table(tmp_path, capsys):
    assert main(["table", "--scenes", "spheres", "--variant", "box", "--variant",
                 "layers=sweep:dof_layers=true", "--size", "32x32", "--spp", "2",
                 "--repeats", "1", "--ref-spp", "16", "-o", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "| spheres |" in out and "layers" in out
    rows = json.loads((tmp_path / "methods.json").read_text())["rows"]
    assert [r["variant"] for r in rows] == ["box", "layers"]
    assert load_image(tmp_path / "spheres_crops.png").shape == (32, 3 * 32 + 4, 3)
    assert main(["table", "--variant", "sweep:bogus=1", "--scenes", "spheres", "-o",
                 str(tmp_path / "x")]) == 2
    assert "unknown knobs" in capsys.readouterr().err
