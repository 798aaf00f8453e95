"""The scene generator at the extremes: 1x1, 1xN, Nx1 and odd image sizes, 1 and 64 spp, the
extreme built-in scenes (huge CoC, fast motion, HDR bokeh, an empty frame; that they
are extreme at full size is tested in test_scenes.py). Every
buffer validates (positions inside their pixels, lens in the disk, time in [0, 1]) and every
value is finite; references are finite and non-negative."""
from __future__ import annotations

import numpy as np
import pytest

from clrecon.core.samples import MISS_DEPTH
from clrecon.scenes import get_scene, render_reference, render_samples

SIZES = [(1, 1), (37, 1), (1, 37), (17, 33)]  # (width, height)


@pytest.mark.parametrize("spp", [1, 64])
@pytest.mark.parametrize("size", SIZES, ids=lambda s: f"{s[0]}x{s[1]}")
@pytest.mark.parametrize("scene", ["huge_coc", "fast_motion", "bokeh", "empty"])
def test_samples_at_extremes(device, scene, size, spp):
    w, h = size
    buf = render_samples(get_scene(scene), w, h, spp, seed=3, device=device).validate()
    assert buf.shape == (h, w, spp)
    for name, arr in buf.arrays().items():
        if name != "depth":
            assert np.isfinite(arr).all(), f"{scene}: non-finite {name}"
    hit = buf.depth < MISS_DEPTH
    assert (buf.depth[hit] > 0).all() and (buf.color >= 0).all()


@pytest.mark.parametrize("size", SIZES, ids=lambda s: f"{s[0]}x{s[1]}")
def test_reference_at_odd_sizes(device, size):
    w, h = size
    ref = render_reference(get_scene("bokeh"), w, h, 16, device=device)
    assert ref.shape == (h, w, 3) and np.isfinite(ref).all() and (ref >= 0).all()

