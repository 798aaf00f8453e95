"""``clrecon trade``: the Pareto front, the variant list, and a tiny end-to-end run."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
from conftest import trusted_reference

from clrecon.api import METHODS
from clrecon.bench.trade import TRADES, pareto_front, trade, trade_variants
from clrecon.cli import main


def test_pareto_front():
    pts = [(1.0, 30.0), (2.0, 29.0), (2.0, 31.0), (3.0, 31.0), (0.5, math.nan), (5.0, 40.0),
           (1.0, 30.0)]
    # (2, 29) is dominated by (1, 30); (3, 31) by (2, 31); NaN never on the front; equal
    # points do not dominate each other
    assert pareto_front(pts) == [True, False, True, False, False, True, True]
    assert pareto_front([]) == []


def test_trade_variants():
    got = trade_variants(["sweep"])
    assert got[0] == ("box", "box", {}), "box always runs: the ratios are taken against it"
    assert [v[0] for v in got[1:]] == [lab for lab, _ in TRADES["sweep"]]
    every = trade_variants()
    assert {m for _, m, _ in every} == {m for m in TRADES if m in METHODS}
    # box's own settings (its halves filtered) where box is named
    assert [v[0] for v in every if v[1] == "box"] == [lab for lab, _ in TRADES["box"]]
    assert "box nlm3 +safeguard" in [v[0] for v in every]
    with pytest.raises(ValueError, match="unknown 'nope'"):
        trade_variants(["nope"])
    picked = trade_variants(["layered", "splat"], settings=["splat guided", "layered guided"])
    assert [v[0] for v in picked] == ["box", "layered guided", "splat guided"]
    assert picked[1][2]["guided"] == 2 and picked[1][2]["safeguard"] is False
    with pytest.raises(ValueError, match="settings: unknown"):
        trade_variants(["sweep"], settings=["layered guided"])


def test_trade_end_to_end(device, tmp_path):
    rep = trade(["fence"], methods=["sweep"], spps=(2, 4), size=(40, 24), repeats=2,
                device=device, out_dir=tmp_path, ref_spp=16)
    labels = [lab for lab, _, _ in trade_variants(["sweep"])] + ["oidn fast", "oidn high"]
    assert [r["variant"] for r in rep["rows"]] == labels * 2
    for r in rep["rows"]:
        assert r["ms"] > 0 and math.isfinite(r["psnr"]) and 0 < r["ssim"] <= 1
        assert "mode" in r["describe"] or r["method"] == "box"
    for spp in (2, 4):
        group = [r for r in rep["rows"] if r["spp"] == spp]
        assert any(r["pareto"] for r in group)
        fastest = min(group, key=lambda r: r["ms"])
        assert fastest["pareto"], "the fastest setting is always on the front"
    assert {(v["spp"], v["oidn"]) for v in rep["verdicts"]} == \
        {(s, f"oidn {q}") for s in (2, 4) for q in ("fast", "high")}
    saved = json.loads((tmp_path / "trade.json").read_text())
    assert len(saved["rows"]) == len(rep["rows"])
    assert "### Against Open Image Denoise" in (tmp_path / "trade.md").read_text()
    for name in ("fence_pareto.png", "fence_crops.png"):
        assert (tmp_path / name).stat().st_size > 1000
    assert list((tmp_path / "references").glob("fence_40x24_16spp_seed1.exr"))


def test_trade_with_the_random_sampler(device, tmp_path):
    rep = trade(["fence"], methods=["sweep"], spps=(2,), size=(24, 16), repeats=1,
                oidn=False, device=device, out_dir=tmp_path, ref_spp=8, sampler="random",
                settings=["sweep 2-scale"])
    assert rep["sampler"] == "random"
    assert json.loads((tmp_path / "trade.json").read_text())["sampler"] == "random"
    assert "samples: random" in (tmp_path / "trade.md").read_text()
    with pytest.raises(ValueError, match="sampler: one of"):
        trade(["fence"], methods=["sweep"], spps=(2,), device=device, out_dir=tmp_path,
              sampler="sobol")


def test_trade_cli_rejects_bad_input(tmp_path, capsys):
    assert main(["trade", "--scenes", "nope", "-o", str(tmp_path)]) == 2
    assert "nope" in capsys.readouterr().err


def test_trade_on_the_users_own_frames(device, tmp_path):
    """A user's sample file and reference image run like a scene named after the file."""
    from clrecon.io import save_image, save_samples
    from clrecon.scenes import get_scene, render_samples

    scene = get_scene("spheres")
    save_samples(str(tmp_path / "shot_0042.bin"),
                 render_samples(scene, 32, 24, 3, seed=5, device=device))
    save_image(str(tmp_path / "shot_0042_ref.exr"), trusted_reference(scene, 32, 24, 64, seed=1))
    rep = trade(methods=["sweep"], repeats=1, oidn=False, device=device,
                out_dir=tmp_path / "out",
                inputs=[(tmp_path / "shot_0042.bin", tmp_path / "shot_0042_ref.exr")])
    assert {r["scene"] for r in rep["rows"]} == {"shot_0042"}
    assert {r["spp"] for r in rep["rows"]} == {3}
    box = next(r for r in rep["rows"] if r["variant"] == "box")
    assert 10 < box["psnr"] < 60
    assert (tmp_path / "out" / "shot_0042_pareto.png").exists()
    with pytest.raises(ValueError, match="image for a 32x24 frame"):
        save_image(str(tmp_path / "small.exr"), np.zeros((4, 4, 3), np.float32))
        trade(methods=["sweep"], repeats=1, oidn=False, device=device, out_dir=tmp_path,
              inputs=[(tmp_path / "shot_0042.bin", tmp_path / "small.exr")])


def test_trade_spp_takes_spaces_and_commas():
    from clrecon.cli import build_parser

    p = build_parser()
    assert p.parse_args(["trade", "--spp", "32", "64"]).spp == [32, 64]
    assert p.parse_args(["trade", "--spp", "4,8", "64"]).spp == [4, 8, 64]
    assert p.parse_args(["trade"]).spp == [4, 8, 16]


def test_trade_cli_at_32_and_64_spp(tmp_path, capsys):
    """``clrecon trade --spp 32 64`` runs (the space-separated list was refused before)."""
    assert main(["trade", "--scenes", "fence", "--methods", "box", "--spp", "32", "64",
                 "--size", "16x12", "--repeats", "1", "--no-oidn", "--ref-spp", "32",
                 "-o", str(tmp_path)]) == 0
    rep = json.loads((tmp_path / "trade.json").read_text())
    assert rep["spps"] == [32, 64]
    assert sorted({r["spp"] for r in rep["rows"]}) == [32, 64]
