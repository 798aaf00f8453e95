"""SampleBuffer.inspect(): the block scan against the whole-array formulas it replaced
(:func:`clrecon.core.frame_info.inspect_arrays`, the fallback path): the same FrameInfo on
every kind of frame."""
from __future__ import annotations

import numpy as np
import pytest
from sample_frames import F32, MODEL, random_frame, same_info

from clrecon.core import frame_info
from clrecon.core.camera import CocModel
from clrecon.core.frame_info import inspect_arrays
from clrecon.core.samples import MISS_DEPTH, SampleBuffer


@pytest.fixture(params=[frame_info.BLOCK_SAMPLES, 1, 12, 40, 1000], ids=lambda b: f"block{b}")
def block(request, monkeypatch):
    """Run with the real block size and with small ones (many blocks, partial rows)."""
    monkeypatch.setattr(frame_info, "BLOCK_SAMPLES", request.param)
    return request.param


# -- inspect: the block scan against the whole-array formulas -------------------------------
def _variants(rng):
    """Frames of every kind inspect() meets (valid or not)."""
    yield "random", random_frame(rng)
    yield "1x1x1", random_frame(rng, 1, 1, 1)
    yield "1x1x1-miss", random_frame(rng, 1, 1, 1, miss=1.0)
    yield "no-misses", random_frame(rng, miss=0.0)
    yield "all-misses", random_frame(rng, miss=1.0)
    b = random_frame(rng)
    b.motion[:] = 0.0
    yield "zero-motion", b
    b = random_frame(rng)
    b.motion[:] = -0.0
    yield "negative-zero-motion", b
    b = random_frame(rng)
    b.motion[:] = 0.0
    b.motion[2, 3, 1] = (1e-30, -3e-31)  # float32 squares underflow
    yield "tiny-motion", b
    b = random_frame(rng)
    b.motion *= F32(1e-20)
    yield "small-motion", b
    b = random_frame(rng)
    b.motion[1, 1, 1] = (2e19, -3e19)  # float32 squares overflow
    yield "huge-motion", b
    b = random_frame(rng)
    b.motion[1, 1, 1] = (3e38, 3e38)
    yield "max-motion", b
    b = random_frame(rng)
    b.motion[0, 2, 0, 1] = np.nan
    yield "nan-motion", b
    b = random_frame(rng)
    b.motion[0, 2, 0, 1] = np.inf
    yield "inf-motion", b
    b = random_frame(rng)
    b.motion[3, 3, 3] = (3.0, 4.0)
    b.motion[3, 3, 2] = (4.0, 3.0)
    b.motion[3, 3, 1] = (np.nextafter(F32(3), F32(4)), 4.0)
    yield "motion-ties", b
    b = random_frame(rng)
    b.depth[0, 0, 0] = MISS_DEPTH
    b.depth[0, 0, 1] = np.nextafter(F32(MISS_DEPTH), F32(0))
    b.depth[0, 0, 2] = np.nextafter(F32(MISS_DEPTH), F32(np.inf))
    b.depth[0, 0, 3] = 3e38
    yield "miss-threshold", b
    b = random_frame(rng)
    b.depth[:] = np.nextafter(F32(MISS_DEPTH), F32(0))
    yield "all-just-hits", b
    b = random_frame(rng)
    b.depth[1, 1, 1] = 1e-40  # subnormal
    yield "subnormal-depth", b
    b = random_frame(rng)
    b.depth[1, 1, 1] = -2.0
    yield "negative-depth", b
    b = random_frame(rng)
    b.depth[1, 1, 1] = 0.0
    yield "zero-depth", b
    b = random_frame(rng)
    b.depth[1, 1, 1] = np.nan
    yield "nan-depth", b
    yield "pinhole", random_frame(rng, model=CocModel())
    yield "c0-only", random_frame(rng, model=CocModel(c0=-5.0, c1=0.0))
    yield "huge-c0", random_frame(rng, model=CocModel(c0=3e35, c1=-1.0))
    yield "positive-c0", random_frame(rng, model=CocModel(c0=12.0, c1=-3.0))
    yield "nan-model", random_frame(rng, model=CocModel(c0=np.nan, c1=1.0))
    yield "inf-model", random_frame(rng, model=CocModel(c0=1.0, c1=np.inf))

    class Odd(CocModel):
        def coc(self, depth):
            return np.full(np.shape(depth), 7.0, np.float32)

    yield "subclassed-model", random_frame(rng, model=Odd())
    b = random_frame(rng)
    b.depth = b.depth.astype(np.float64)
    yield "float64-depth", b
    b = random_frame(rng)
    b.motion = np.asfortranarray(b.motion)
    yield "fortran-motion", b
    yield "wide", random_frame(rng, 2, 300, 3)
    yield "many-spp", random_frame(rng, 2, 3, 200)


@pytest.mark.parametrize("seed", range(6))
def test_inspect_matches_whole_array_formulas(block, seed):
    with np.errstate(all="ignore"):
        for label, buf in _variants(np.random.default_rng(seed)):
            same_info(buf.inspect(), inspect_arrays(buf))
            assert label


@pytest.mark.parametrize("seed", range(20))
def test_inspect_random_shapes(block, seed):
    rng = np.random.default_rng(100 + seed)
    h, w, s = (int(v) for v in rng.integers(1, 12, 3))
    buf = random_frame(rng, h, w, s, miss=float(rng.choice([0.0, 0.01, 0.5, 1.0])))
    buf.motion *= F32(10.0 ** rng.integers(-3, 4))
    if rng.random() < 0.3:
        buf.motion[rng.random(buf.depth.shape) < 0.7] = 0.0
    same_info(buf.inspect(), inspect_arrays(buf))


def test_inspect_of_the_unit_tests_frame():
    info = SampleBuffer.zeros(3, 7, 16, MODEL).inspect()
    same_info(info, inspect_arrays(SampleBuffer.zeros(3, 7, 16, MODEL)))


@pytest.mark.parametrize("block_samples", [1, 4, frame_info.BLOCK_SAMPLES])
def test_longest_motion_where_float32_orders_otherwise(monkeypatch, block_samples):
    """Two vectors whose float32 squared lengths order the other way round than in float64:
    the longest one (float64) must be found even when it is not the float32 maximum."""
    monkeypatch.setattr(frame_info, "BLOCK_SAMPLES", block_samples)
    rng = np.random.default_rng(0)
    m = rng.uniform(3.0, 4.0, (200000, 2)).astype(F32)
    target = 25.0 + rng.uniform(-2e-5, 2e-5, len(m))  # |m| ~ 5, a few float32 ulps apart
    m[:, 1] = np.sqrt(target - m[:, 0].astype(np.float64) ** 2).astype(F32)
    r64 = (m.astype(np.float64) ** 2).sum(-1)
    q = m * m
    r32 = q[:, 0] + q[:, 1]
    order64, order32 = np.argsort(r64, kind="stable"), np.argsort(r32, kind="stable")
    a = order32[-1]  # the float32 maximum
    better = np.flatnonzero(r64 > r64[a])
    assert better.size, "no inverted pair found"
    b = better[np.argmin(r32[better])]  # longer in float64, shorter in float32
    assert r32[b] < r32[a] and r64[b] > r64[a] and order64[-1] != a
    buf = random_frame(rng, 2, 3, 2)
    buf.motion[:] = 0.0
    buf.motion[0, 0, 0] = m[a]
    buf.motion[1, 2, 1] = m[b]
    same_info(buf.inspect(), inspect_arrays(buf))
    buf.motion[0, 0, 0], buf.motion[1, 2, 1] = m[b], m[a]
    same_info(buf.inspect(), inspect_arrays(buf))
