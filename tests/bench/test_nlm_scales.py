"""The multi-scale non-local means prototype (tools/nlm_scales.py): its 2x2 means and
tent upsampling against plain loops, one scale is the filter itself, and more scales remove
noise coarser than the filter's window."""
from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np

_PATH = Path(__file__).resolve().parents[2] / "tools" / "nlm_scales.py"
_spec = importlib.util.spec_from_file_location("nlm_scales", _PATH)
ns = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(ns)


def test_down_and_up_against_loops(rng):
    x = rng.random((7, 9, 3))
    d = ns.down2(x)
    assert d.shape == (3, 4, 3)
    assert np.allclose(d[1, 2], x[2:4, 4:6].mean((0, 1)))
    u = ns.up2(d, x.shape)
    assert u.shape == x.shape
    near = np.empty_like(x)  # nearest, edge-replicated past the last full 2x2 block
    for i in range(7):
        for j in range(9):
            near[i, j] = d[min(i, 5) // 2, min(j, 7) // 2]
    t = (0.25, 0.5, 0.25)
    for i, j in ((0, 0), (3, 4), (6, 8), (5, 7)):
        want = sum(t[a + 1] * t[b + 1] * near[min(max(i + a, 0), 6), min(max(j + b, 0), 8)]
                   for a in (-1, 0, 1) for b in (-1, 0, 1))
        assert np.allclose(u[i, j], want)
    # a constant stays constant
    assert np.allclose(ns.up2(np.full((3, 4, 3), 2.0), (7, 9, 3)), 2.0)


def test_one_scale_is_the_filter_and_more_scales_remove_coarse_noise(rng):
    h = w = 32
    truth = np.full((h, w, 3), 1.0)
    # noise with a grain of 8 pixels: coarser than a radius-3 window's averaging
    coarse = rng.normal(0, 0.2, (h // 8, w // 8, 3)).repeat(8, 0).repeat(8, 1)
    a = truth + coarse + rng.normal(0, 0.05, truth.shape)
    b = truth - coarse + rng.normal(0, 0.05, truth.shape)
    one = ns.multiscale(a, b, 8, 3, 1)
    assert np.array_equal(one[0], a) and np.array_equal(one[1], b)
    err = [np.mean(((sum(ns.multiscale(a, b, 8, 3, s)) / 2) - truth) ** 2) for s in (1, 3)]
    assert np.isfinite(err).all()
    # the halves' coarse noise is opposite: each half's coarse band moves toward the other's
    a3, b3 = ns.multiscale(a, b, 8, 3, 3)
    assert np.mean((a3 - truth) ** 2) < 0.8 * np.mean((a - truth) ** 2)
