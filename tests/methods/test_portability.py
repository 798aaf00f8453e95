"""Portability: every method and every variant that takes its own code path, end to end on the
device under test, against the same plan on the trusted device (PoCL's CPU device).

The pass-level checks against NumPy live in each pass's test file; this file adds what they
cannot see: that a whole plan (build options, local sizes, tuned or default launch
configurations, image atlases, tile merges, local-memory fallbacks) gives the trusted device's
image. The frames are tiny, so that the file also runs under Oclgrind, which simulates a GPU
and checks every memory access (CI runs it there with data-race checks; see ``.ci/run``).

On the trusted device itself the comparison would be with itself, so it is skipped there.
"""
from __future__ import annotations

import numpy as np
import pytest
from layered_frames import frame

from clrecon.api import make_pipeline, run
from clrecon.core import device as cldev
from clrecon.core.samples import SampleBuffer

#: (id, method, knobs): one entry per code path a device can take; variants a device cannot
#: run (images on a device without image support) are skipped with the reason
VARIANTS = [
    ("box", "box", {}),
    ("sweep-block", "sweep", {"sort": "block", "specialize": False}),
    ("sweep-tile-serial", "sweep", {"sort": "tile", "tile_merge": "serial",
                                    "specialize": False}),
    ("sweep-tile-bitonic", "sweep", {"sort": "tile", "tile_merge": "bitonic",
                                     "specialize": False}),
    ("sweep-pixel", "sweep", {"sort": "pixel", "specialize": False}),
    ("sweep-4-scale", "sweep", {"scales": 4, "specialize": False}),
    ("sweep-dof-layers", "sweep", {"dof_layers": True, "specialize": False}),
    ("layered-sheared", "layered", {"filter": "sheared", "specialize": False}),
    ("layered-mip-buffers", "layered", {"filter": "mip", "mip_images": False,
                                        "specialize": False}),
    ("layered-mip-images", "layered", {"filter": "mip", "mip_images": True,
                                       "specialize": False}),
    ("layered-rotated", "layered", {"filter": "rotated", "specialize": False}),
    ("layered-lrdm", "layered", {"mode": "lrdm", "specialize": False}),
    ("splat", "splat", {}),
    ("splat-dense", "splat", {"dense": True}),
    ("splat-1-layer", "splat", {"layers": 1}),
    ("box-error", "box", {"estimate_error": True}),
    ("sweep-safeguard-error", "sweep", {"sort": "block", "estimate_error": True}),
    ("splat-guided", "splat", {"guided": 2, "safeguard": True}),
    ("splat-guided-nlm", "splat", {"guided": 2, "nlm": 3, "nlm_scales": 3, "safeguard": True}),
    ("box-nlm", "box", {"nlm": 3, "estimate_error": True}),
    ("splat-hybrid", "splat", {"guided": 2, "nlm": 3, "hybrid": True, "estimate_error": True}),
]
# the papers' methods alone, unless the variant is about the safeguard
VARIANTS = [(v, m, k if m == "box" or "estimate_error" in k or "safeguard" in k
             else {**k, "safeguard": False}) for v, m, k in VARIANTS]


def trusted() -> cldev.Device:
    """PoCL's CPU device: the implementation CI runs everything on."""
    for d in cldev.list_devices():
        if "portable computing language" in d.platform.lower():
            return cldev.get_device(d.index)
    pytest.skip("no PoCL device to compare against")


def _frame(h=10, w=12, s=3) -> SampleBuffer:
    return frame(np.random.default_rng(2024), h=h, w=w, s=s)


def _image(buf, method, knobs, dev):
    res = run(buf, method=method, device=dev, **knobs)
    return res.image if res.error is None else np.concatenate([res.image, res.error[..., None]], -1)


@pytest.mark.parametrize("vid,method,knobs", VARIANTS, ids=[v[0] for v in VARIANTS])
def test_plan_matches_trusted_device(device, vid, method, knobs):
    ref_dev = trusted()
    if device.info.index == ref_dev.info.index:
        pytest.skip("the trusted device itself")
    if knobs.get("mip_images") and not device.info.image_support:
        pytest.skip("no image support")
    buf = _frame()
    got = _image(buf, method, knobs, device)
    want = _image(buf, method, knobs, ref_dev)
    assert got.shape == want.shape and got.dtype == np.float32  # image (+ error channel)
    assert np.isfinite(got).all(), f"{vid}: non-finite pixels on {device.info.name}"
    # compilers differ in contraction (FMA), reassociation of sums and the order of atomic
    # adds; none of that moves a pixel by more than a few ulp of the frame's sums
    scale = float(np.abs(want).max())
    err = np.abs(got.astype(np.float64) - want)
    assert err.max() <= 2e-4 * scale + 1e-3 * np.abs(want).max(), (
        f"{vid} on {device.info.name}: max |diff| {err.max():.3g} at "
        f"{np.unravel_index(err.argmax(), err.shape)} (scale {scale:.3g})")


def test_describe_names_the_path(device):
    """The variants above reach the paths they name (so a silent fallback would show)."""
    buf = _frame()
    info = buf.inspect()
    pipe = make_pipeline("sweep", device.context, info, sort="tile", tile_merge="bitonic",
                         specialize=False)
    d = pipe.describe()
    assert d.get("sort") == "tile" and d.get("tile_merge") == "bitonic", d
    if device.info.image_support:
        lay = make_pipeline("layered", device.context, info, filter="mip", mip_images=True,
                            specialize=False)
        assert lay.describe()["mip_images"] is True
