"""The error-estimate check (clrecon errcheck): its statistics, and a tiny end-to-end run."""
from __future__ import annotations

import json

import numpy as np
import pytest

from clrecon.bench import error_check as ec


def test_spearman_matches_its_definition():
    rng = np.random.default_rng(0)
    a = rng.normal(size=200)
    b = a + rng.normal(size=200)
    # Pearson on ranks (no ties here)
    ra, rb = np.argsort(np.argsort(a)), np.argsort(np.argsort(b))
    want = np.corrcoef(ra, rb)[0, 1]
    assert ec.spearman(a, b) == pytest.approx(want, abs=1e-12)
    assert ec.spearman(a, np.exp(a)) == pytest.approx(1.0)  # monotone: 1
    assert ec.spearman(a, -a) == pytest.approx(-1.0)


def test_spearman_averages_tied_ranks():
    a = np.array([1.0, 2.0, 2.0, 3.0])
    b = np.array([1.0, 2.0, 3.0, 4.0])
    ra = np.array([0.0, 1.5, 1.5, 3.0])
    want = np.corrcoef(ra, np.arange(4.0))[0, 1]
    assert ec.spearman(a, b) == pytest.approx(want)
    assert np.isnan(ec.spearman(np.ones(5), np.arange(5.0)))
    with pytest.raises(ValueError, match="one length"):
        ec.spearman(np.ones(3), np.ones(4))


def test_tile_means_drop_partial_tiles():
    a = np.arange(17 * 10, dtype=np.float64).reshape(10, 17)
    t = ec.tile_means(a, 8)
    assert t.shape == (2,)
    assert t[0] == pytest.approx(a[:8, :8].mean()) and t[1] == pytest.approx(a[:8, 8:16].mean())
    with pytest.raises(ValueError, match="smaller than a tile"):
        ec.tile_means(np.ones((4, 40)), 8)


def test_check_end_to_end(device, tmp_path):
    rep = ec.check(["fence"], ["box", "sweep"], size=(32, 24), spp=4, out_dir=tmp_path,
                   device=device)
    assert [(r["scene"], r["method"]) for r in rep["rows"]] == [("fence", "box"),
                                                                ("fence", "sweep")]
    for r in rep["rows"]:
        assert -1.0 <= r["spearman"] <= 1.0 and r["calibration"] > 0
    assert json.loads((tmp_path / "errcheck.json").read_text())["rows"] == rep["rows"]
    assert "| fence | sweep |" in (tmp_path / "errcheck.md").read_text()
