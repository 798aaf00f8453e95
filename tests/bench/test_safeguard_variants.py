"""The safeguard-variants script (tools/safeguard_variants.py): its ``shipped`` estimator is
the safeguard's NumPy reference, each variant moves only what it names, and one tiny scene
end to end (where the script checks ``shipped`` against the device's own image)."""
from __future__ import annotations

import math

import numpy as np
import pytest
from tool_module import load_tool

from clrecon.methods import safeguard as sg
from clrecon.scenes import render

sv = load_tool("safeguard_variants")


def _halves(rng, h=11, w=13, s=8):
    color = rng.exponential(1.0, (h, w, s, 3))
    box = color.mean(2)
    # a method's halves: the box images smoothed, with a bias in one corner
    ha = s // 2
    ma, mb = (color[:, :, sl].mean(2) * 0.7 + 0.3 * box.mean((0, 1)) for sl in
              (slice(0, ha), slice(ha, None)))
    ma[:4, :4] += 0.5  # a coherent bias
    mb[:4, :4] += 0.5
    ma[7, 8] += 20.0  # and one pixel's
    mb[7, 8] += 20.0
    ma[8:, 6:] += 1.0  # and a band 3 pixels wide (the 3x3 test finds it, the 7x7 mean dilutes)
    mb[8:, 6:] += 1.0
    return color, ma, mb


@pytest.mark.parametrize("s", [3, 8, 16])
def test_shipped_is_the_safeguards_reference(rng, s):
    color, ma, mb = _halves(rng, s=s)
    # the library's tests at this sample count (below 8 spp the 7x7 mean is tested, from
    # 8 spp scaled by the frame's q-value)
    want, _ = sg.reference(color, ma=ma, mb=mb, z7=sg.GUIDED_Z7 if s < 8 else 0.0,
                           frame_shrink=s >= 8)
    np.testing.assert_allclose(sv.blend(color, ma, mb, "shipped"), want, rtol=1e-12, atol=0)


def test_variants_move_only_what_they_name(rng):
    color, ma, mb = _halves(rng, s=3)
    shipped = sv.blend(color, ma, mb, "shipped")
    # below 4 spp there are no quarters: strat is the shipped estimator
    np.testing.assert_array_equal(sv.blend(color, ma, mb, "strat"), shipped)
    # below 8 spp the library tests the 7x7 mean: the untested one is a variant there
    np.testing.assert_array_equal(sv.blend(color, ma, mb, "se7 2"), shipped)
    assert not np.array_equal(sv.blend(color, ma, mb, "untested 7x7"), shipped)
    color, ma, mb = _halves(rng, s=8)
    shipped = sv.blend(color, ma, mb, "shipped")
    box = color.mean(2)
    for v in sv.VARIANTS[1:]:
        if v.startswith("strat"):  # iid samples: a half's variance is half a quarter's
            continue
        got = sv.blend(color, ma, mb, v)
        assert got.shape == shipped.shape and np.isfinite(got).all(), v
        assert not np.array_equal(got, shipped), v
    # a larger bias estimate (pixel 3sd only adds a bound) never moves a pixel away from box
    m = (ma + mb) / 2
    w_ship = (shipped - box)[..., 0] / (m - box)[..., 0]
    w_pix = (sv.blend(color, ma, mb, "pixel 3sd") - box)[..., 0] / (m - box)[..., 0]
    assert np.all(w_pix <= w_ship + 1e-12)


def test_tiny_scene_end_to_end(monkeypatch, device):
    monkeypatch.setattr(sv, "render_reference",
                        lambda scene, w, h: render.render_reference(scene, w, h, spp=64))
    out = sv.measure("fence", 24, 8, device)
    assert set(out) == {"box", *sv.METHODS}, out
    for method in sv.METHODS:
        assert set(out[method]) == set(sv.VARIANTS)
        assert all(math.isfinite(v) for v in out[method].values()), out


@pytest.mark.parametrize("variant", ["strat", "strat frame"])
def test_strat_trusts_box_more_where_halves_agree_better_than_quarters(rng, variant):
    """Each half's second quarter mirrors its first about a value of its own: the halves'
    means differ a little while the quarters' differ a lot, so the measured convergence is
    faster than independent samples' (r < 1/2), box's variance estimate shrinks and every
    pixel moves toward box."""
    color, ma, mb = _halves(rng, s=8)
    mu = color.mean(2, keepdims=True)
    color[:, :, 2:4] = 2 * mu - color[:, :, 0:2]
    color[:, :, 6:8] = 2 * (mu + rng.normal(0, 0.05, mu.shape)) - color[:, :, 4:6]
    box = color.mean(2)
    d_strat = np.abs(sv.blend(color, ma, mb, variant) - box)
    d_ship = np.abs(sv.blend(color, ma, mb, "shipped") - box)
    assert np.all(d_strat <= d_ship + 1e-12) and np.any(d_strat < 0.5 * d_ship)


def test_cov_adds_back_the_covariance_of_the_halves(rng):
    """``cov``: with the method's halves equal (no covariance with box's) it is the shipped
    estimator; for a method whose halves differ exactly as box's (box plus a bias) its
    e = d2 - vm - vb + 2 cov is the squared bias itself, where the shipped e is 2 vb lower:
    the blend keeps the biased method less."""
    color, ma, mb = _halves(rng, s=8)
    same = (ma + mb) / 2
    np.testing.assert_array_equal(sv.blend(color, same, same, "cov"),
                                  sv.blend(color, same, same, "shipped"))
    ha = 4
    a, b = color[:, :, :ha].mean(2), color[:, :, ha:].mean(2)
    box = (a + b) / 2
    bias = np.zeros_like(box)
    bias[:5, :5] = 0.3  # a coherent bias in one corner
    got = sv.blend(color, a + bias, b + bias, "cov")
    ship = sv.blend(color, a + bias, b + bias, "shipped")
    # the halves differ exactly as box's: vm = vb, cov = vb, so e = |bias|^2 exactly under
    # cov and |bias|^2 - 2 vb shipped: cov's weight of the biased method is never larger
    w_cov = (got - box)[:5, :5, 0] / bias[:5, :5, 0]
    w_ship = (ship - box)[:5, :5, 0] / bias[:5, :5, 0]
    assert np.all(w_cov <= w_ship + 1e-12) and np.any(w_cov < w_ship - 1e-3)
