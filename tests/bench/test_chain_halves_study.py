"""The chain's halves study (tools/chain_halves_study.py): its blend without the 3x3 test only
ever trusts the method more than the shipped blend, its variance across frames is the
unbiased one, and each study end to end on a tiny frame (where the blend study checks its
host blend against the device's own image)."""
from __future__ import annotations

import math

import numpy as np
import pytest
from tool_module import load_tool

from clrecon.scenes import render

ch = load_tool("chain_halves_study")


def _frame(rng, h=15, w=17, s=4):
    color = rng.exponential(1.0, (h, w, s, 3))
    ha, hb = s // 2, s - s // 2
    a, b = color[:, :, :ha].mean(2), color[:, :, ha:].mean(2)
    # smoothed halves with a bias on one pixel (the 3x3 test's case) and in one corner
    ma, mb = (0.6 * x + 0.4 * x.mean((0, 1)) for x in (a, b))
    for m in (ma, mb):
        m[7, 8] += 6.0
        m[:5, :5] += 0.8
    return a, b, ha, hb, ma, mb


def test_without_the_3x3_test_the_blend_only_trusts_the_method_more(rng):
    a, b, ha, hb, ma, mb = _frame(rng)
    img_s, w_s = ch._blend(a, b, ha, hb, ma, mb, 1.0, True)
    img_n, w_n = ch._blend(a, b, ha, hb, ma, mb, 1.0, False)
    assert np.all(w_n >= w_s - 1e-12)
    assert np.any(w_n > w_s + 1e-3)  # the one-pixel bias is the 3x3 test's alone
    box = (ha * a + hb * b) / (ha + hb)
    m = (ha * ma + hb * mb) / (ha + hb)
    np.testing.assert_allclose(img_n, box + w_n[..., None] * (m - box), rtol=1e-12)


def test_variance_across_frames_is_the_unbiased_one(rng):
    xs = rng.normal(size=(5, 4, 6, 3))
    want = xs.var(0, ddof=1).mean(-1)
    np.testing.assert_allclose(ch._var_across(xs), want, rtol=1e-12)


@pytest.fixture
def cheap_reference(monkeypatch):
    monkeypatch.setattr(ch, "render_reference",
                        lambda scene, w, h: render.render_reference(scene, w, h, spp=64))


def _cells(lines):
    return [c.strip() for row in lines[2:] for c in row.strip("|").split("|")]


@pytest.mark.parametrize("spp, sampler", [(4, "lattice"), (8, "random")])
def test_blend_end_to_end(device, cheap_reference, spp, sampler):
    """(The study raises where its host blend of the library's tests is not the device's.)"""
    lines = ch.blend(device, ["fence"], 24, [spp], sampler)
    assert len(lines) == 3
    nums = [float(c) for c in _cells(lines)[2:]]
    assert all(math.isfinite(v) for v in nums) and 0.0 <= nums[-1] <= 1.0


def test_variances_and_calibration_end_to_end(device, cheap_reference, monkeypatch):
    monkeypatch.setattr(ch, "SETTINGS", ch.SETTINGS[:1] + ch.SETTINGS[-1:])
    lines = ch.variances(device, ["fence"], 24, 4, 2)
    assert len(lines) == 4
    for row in lines[2:]:
        cells = [c.strip() for c in row.strip("|").split("|")]
        assert all(float(c) > 0 for c in cells[2:]), row
    lines = ch.calibration(device, ["fence"], 24, [4])
    assert len(lines) == 4
    for row in lines[2:]:
        cells = [c.strip() for c in row.strip("|").split("|")]
        assert float(cells[3]) > 0 and -1.0 <= float(cells[4]) <= 1.0, row
