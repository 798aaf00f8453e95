"""``clrecon trade``: the Pareto front, the variant list, and a tiny end-to-end run."""
from __future__ import annotations

import json
import math

import pytest

from clrecon.bench.trade import TRADES, pareto_front, trade, trade_variants
from clrecon.cli import main
from clrecon.pipeline import METHODS


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
    with pytest.raises(ValueError, match="unknown 'nope'"):
        trade_variants(["nope"])


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


def test_trade_cli_rejects_bad_input(tmp_path, capsys):
    assert main(["trade", "--scenes", "nope", "-o", str(tmp_path)]) == 2
    assert "nope" in capsys.readouterr().err
