"""The hybrid bound script (tools/hybrid_bound.py): its window mean and per-pixel pick
against plain loops, and one tiny scene end to end, whose oracles must bound every default
(a selection by the true error cannot lose to any one of its candidates)."""
from __future__ import annotations

import math

import numpy as np
from tool_module import load_tool

from clrecon.scenes import render

hb = load_tool("hybrid_bound")


def test_window_mean_is_the_edge_padded_window_average(rng):
    a = rng.random((2, 9, 7))
    for r in (0, 1, 2):
        got = hb.window_mean(a, r)
        want = np.empty_like(a)
        for y in range(9):
            for x in range(7):
                ys = np.clip(np.arange(y - r, y + r + 1), 0, 8)
                xs = np.clip(np.arange(x - r, x + r + 1), 0, 6)
                want[:, y, x] = a[:, ys][:, :, xs].mean((1, 2))
        np.testing.assert_allclose(got, want, rtol=1e-12)


def test_pick_takes_each_pixels_indexed_image(rng):
    images = rng.random((3, 4, 5, 3))
    index = rng.integers(0, 3, (4, 5))
    got = hb.pick(images, index)
    for y in range(4):
        for x in range(5):
            np.testing.assert_array_equal(got[y, x], images[index[y, x], y, x])


def test_tiny_scene_oracles_bound_every_default(monkeypatch, device):
    # a 64-spp reference on the trusted device keeps the test short (the bound holds for
    # any reference)
    monkeypatch.setattr(hb, "render_reference",
                        lambda scene, w, h: render.render_reference(scene, w, h, spp=64))
    out = hb.measure("fence", 32, 32, 4, oidn=False, dev=device)
    assert set(out) == {*hb.METHODS, "oracle 8x8", "oracle px",
                        *(f"{k} {r}" for k in ("min", "inv") for r in hb.RADII)}
    assert all(math.isfinite(v) for v in out.values()), out
    best = max(out[m] for m in hb.METHODS)
    assert out["oracle px"] >= out["oracle 8x8"] - 1e-9 >= best - 2e-9, out
