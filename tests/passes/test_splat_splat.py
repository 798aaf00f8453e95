"""Pass ``splat`` against its NumPy reference: re-centring, nested-grid lookup, rotation,
layers, fast track, on frames with defocus and motion."""
from __future__ import annotations

import numpy as np
import pytest
from conftest import assert_close
from splat_frames import frame, reference_splat, splat_layers

from clrecon.api import make_pipeline


def run_splat(device, buf, **knobs):
    pipe = make_pipeline("splat", device.context, buf.inspect(), **knobs, safeguard=False,
                         mip_radius=0)
    return (pipe, *splat_layers(device, pipe, buf))


def assert_layers_match(pipe, buf, lap, direct, laplacian: bool = True):
    """Both layer images (``laplacian=False``: the direct one only) equal the reference's,
    within 1e-6 of the largest |value|; returns the reference's."""
    want_lap, want_direct = reference_splat(pipe, buf)
    scale = float(np.abs(want_direct).max() + np.abs(want_lap).max())
    if laplacian:
        assert_close(lap, want_lap, rtol=1e-4, atol=1e-6 * scale, what="laplacian")
    assert_close(direct, want_direct, rtol=1e-4, atol=1e-6 * scale, what="direct")
    return want_lap, want_direct


@pytest.mark.parametrize("scatter", ["atomic", "tiles"])
@pytest.mark.parametrize("knobs,motion", [
    (dict(psf="simplelens", layers=1), False),
    (dict(psf="simplelens", layers=3), True),
    (dict(psf="combined", layers=2), True),
    # every small hexagon cell this frame reaches errs > 0.05: max_error=inf keeps them sparse
    (dict(psf="stylized", layers=2, fast_ratio=2.0, max_error=float("inf")), False),
    (dict(psf="combined", layers=2, dense=True), True),
], ids=["simple1", "simple3-moving", "combined2", "stylized-fast2", "combined-dense"])
def test_splat_matches_reference(device, rng, knobs, motion, scatter):
    knobs = dict(knobs, scatter=scatter)
    buf = frame(rng, h=40, w=37, s=2, motion=motion)  # several owner tiles per phase
    pipe, lap, direct = run_splat(device, buf, **knobs)
    dense = bool(knobs.get("dense"))
    want_lap, want_direct = assert_layers_match(pipe, buf, lap, direct, laplacian=not dense)
    assert np.abs(want_direct).max() > 0, "the fast track must be exercised"
    if not dense:
        assert np.abs(want_lap).max() > 0, "spreadlets must be exercised"


def test_lookup_matches_nested_grid(device, rng):
    """Samples spread over the whole Combined parameter space land in the cells psf.py's
    forward map picks. Motion along the axes only: rotations by multiples of 90 degrees are
    exact in float32, so long rotated offsets cannot round differently (with arbitrary
    directions a handful of the ~10^6 points of this frame land one pixel apart: OpenCL's
    length() and division are not correctly rounded)."""
    buf = frame(rng, h=9, w=9, s=8, aperture=60.0)
    axes = np.array([[1, 0], [0, 1], [-1, 0], [0, -1]], np.float32)
    pick = rng.integers(0, 4, buf.depth.shape)
    buf.motion[:] = axes[pick] * rng.uniform(0, 200.0, buf.depth.shape)[..., None]
    pipe, lap, direct = run_splat(device, buf, psf="combined", layers=1, scatter="atomic")
    want_lap, want_direct = reference_splat(pipe, buf)
    scale = float(np.abs(want_direct).max() + np.abs(want_lap).max())
    assert_close(lap[..., 3], want_lap[..., 3], rtol=1e-4, atol=1e-6 * scale, what="coverage")


def test_motion_beyond_the_table_is_clamped(device, rng):
    """Motion of ~1000 px (the Combined table ends at 192 px): re-centring uses the clamped
    motion, so the pad stays bounded by the PSF reach and kernel and reference agree."""
    buf = frame(rng, h=8, w=9, s=4, motion=False)
    buf.motion[:] = rng.normal(0, 700.0, buf.motion.shape)
    pipe, lap, direct = run_splat(device, buf, psf="combined", layers=1)
    assert pipe.pad <= 2 * pipe.reach + 2 < buf.inspect().max_abs_motion / 2
    assert_layers_match(pipe, buf, lap, direct)


@pytest.mark.parametrize("phases", [2, 3, 5])
def test_owner_tiles_cover_every_sample_once(device, rng, phases):
    """Many owner tiles per phase (small PSFs on a 160x48 frame): every sample drawn once."""
    buf = frame(rng, h=48, w=160, s=1, motion=False, aperture=2.0)
    # max_error=inf: keep the small discs' spreadlets (errors > 0.05) off the fast track
    pipe = make_pipeline("splat", device.context, buf.inspect(), mip_radius=0, psf="simplelens",
                         layers=2, scatter="tiles", max_error=float("inf"), safeguard=False)
    assert pipe.use_lap, "spreadlets must be exercised"
    pipe.splat.phases = phases
    tile = pipe.splat.tile_size(pipe.reach, pipe.shift, phases)
    assert -(-160 // tile) >= 2 * phases, "several tiles per phase and row"
    lap, direct = splat_layers(device, pipe, buf)
    assert_layers_match(pipe, buf, lap, direct)


@pytest.mark.parametrize("scatter", ["atomic", "tiles"])
def test_long_motion_sub_segments_match_reference(device, rng, scatter):
    """Motion beyond Combined's 192 px: each sample is drawn as ceil(L / 192) sub-PSFs, in the
    kernel exactly as in the reference (centres, cells, weights)."""
    buf = frame(rng, h=12, w=30, s=2, motion=True)
    long = rng.uniform(size=buf.depth.shape) < 0.3
    ang = rng.uniform(0, 2 * np.pi, buf.depth.shape)
    length = rng.uniform(200.0, 450.0, buf.depth.shape)
    buf.motion[long] = np.stack([length * np.cos(ang), length * np.sin(ang)], -1)[long]
    pipe, lap, direct = run_splat(device, buf, psf="combined", layers=2, scatter=scatter)
    assert pipe.describe()["motion_split"] == 3
    want_lap, want_direct = assert_layers_match(pipe, buf, lap, direct)
    assert np.abs(want_direct).max() > 0 and np.abs(want_lap).max() > 0
