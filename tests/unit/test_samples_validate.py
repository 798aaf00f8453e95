"""SampleBuffer.validate(): layout checks, and the block scan against the whole-array
formulas it replaced (same messages on every kind of frame); inspect()'s block scan:
tests/unit/test_samples_inspect.py."""
from __future__ import annotations

import re

import numpy as np
import pytest
from sample_frames import F32, MODEL, message_of, random_frame, ref_validate

from clrecon.core import frame_info
from clrecon.core import samples as smp
from clrecon.core import validate as cval
from clrecon.core.camera import CocModel
from clrecon.core.samples import (
    FIELDS,
    LENS_TOLERANCE,
    MISS_DEPTH,
    POSITION_TOLERANCE,
    SampleBuffer,
)


@pytest.fixture(params=[frame_info.BLOCK_SAMPLES, 1, 12, 40, 1000], ids=lambda b: f"block{b}")
def block(request, monkeypatch):
    """Run with the real block size and with small ones (many blocks, partial rows)."""
    monkeypatch.setattr(frame_info, "BLOCK_SAMPLES", request.param)
    return request.param


# -- layout ---------------------------------------------------------------------------------
@pytest.mark.parametrize("name", list(FIELDS))
def test_float64_field_is_rejected(rng, name):
    buf = random_frame(rng)
    setattr(buf, name, getattr(buf, name).astype(np.float64))
    with pytest.raises(ValueError, match=re.escape(f"{name}: expected float32, got float64")):
        buf.validate()


@pytest.mark.parametrize("name", list(FIELDS))
@pytest.mark.parametrize("dtype", [np.float16, np.int32, np.dtype(">f4")], ids=str)
def test_other_dtypes_are_rejected(rng, name, dtype):
    buf = random_frame(rng)
    with np.errstate(invalid="ignore"):  # inf depths as int32
        arr = getattr(buf, name).astype(dtype)
    setattr(buf, name, arr)
    with pytest.raises(ValueError, match=re.escape(f"{name}: expected float32, got {arr.dtype}")):
        buf.validate()


@pytest.mark.parametrize("name", list(FIELDS))
def test_non_contiguous_field_is_rejected(rng, name):
    buf = random_frame(rng)
    arr = getattr(buf, name)
    wide = np.zeros(arr.shape[:3] + (2 * max(1, arr[0, 0, 0].size),), np.float32)
    view = wide[..., ::2] if arr.ndim == 4 else wide[..., 0]
    view[...] = arr
    assert view.shape == arr.shape and not view.flags.c_contiguous
    setattr(buf, name, view)
    with pytest.raises(ValueError, match=re.escape(f"{name}: expected a C-contiguous array")):
        buf.validate()


@pytest.mark.parametrize("name", ["color", "position", "lens", "motion"])
def test_fortran_order_field_is_rejected(rng, name):
    buf = random_frame(rng)
    setattr(buf, name, np.asfortranarray(getattr(buf, name)))
    with pytest.raises(ValueError, match=re.escape(f"{name}: expected a C-contiguous array")):
        buf.validate()


def test_non_array_field_is_rejected(rng):
    buf = random_frame(rng)
    buf.time = buf.time.tolist()
    with pytest.raises(ValueError, match=re.escape("time: expected a numpy array, got list")):
        buf.validate()


def test_layout_is_checked_before_values(rng):
    buf = random_frame(rng)
    buf.depth[0, 0, 0] = -1.0
    buf.motion = buf.motion.astype(np.float64)
    with pytest.raises(ValueError, match="motion: expected float32"):
        buf.validate()


def test_wrong_shape_message_is_unchanged(rng):
    buf = random_frame(rng)
    buf.lens = np.zeros((6, 7, 5, 3), np.float32)
    with pytest.raises(ValueError, match=re.escape("lens: expected shape (6, 7, 5, 2), got "
                                                   "(6, 7, 5, 3)")):
        buf.validate()


# -- validate: the block scan against the whole-array formulas ------------------------------
def _boundary_values(name: str, y: int, x: int, rng):
    """Values at, just inside and just outside each bound of ``name`` at pixel (y, x)."""
    nxt = np.nextafter
    if name == "depth":
        lo = F32(1e-20)
        coc_lo = smp.coc_min_depth(MODEL.c0, MODEL.c1)  # |coc| = 2**20 px of MODEL
        return [F32(0.0), F32(-0.0), nxt(F32(0), F32(1)), F32(-1e-30), F32(np.nan), F32(-np.inf),
                F32(np.inf), F32(3e38), F32(1e-40), lo, nxt(lo, F32(0)), nxt(lo, F32(1)),
                coc_lo, nxt(coc_lo, F32(0)), nxt(coc_lo, F32(1)), F32(1e-6)]
    if name in ("color", "motion"):
        k = FIELDS[name][0]
        top = F32(1e30) if name == "color" else F32(65536)
        vals = [np.inf, -np.inf, np.nan, 3.4e38, -3.4e38, 1e-45, -1e-45, -0.0, top, -top,
                nxt(top, F32(np.inf)), nxt(top, F32(0)), -nxt(top, F32(np.inf)), -1.0]
        return [np.array([rng.choice(vals) if j == rng.integers(k) else 0.5 for j in range(k)],
                         F32) for _ in range(12)]
    if name == "time":
        return [F32(0.0), F32(-0.0), F32(1.0), nxt(F32(0), F32(-1)), nxt(F32(1), F32(2)),
                F32(np.nan), F32(np.inf), F32(-1e-45)]
    if name == "lens":
        out = []
        for r in (1.0, 1 + LENS_TOLERANCE, 1 + 0.999e-4, 1 + 1.001e-4, 1 + LENS_TOLERANCE + 1e-7,
                  1 + LENS_TOLERANCE - 1e-7, 2.0, 1e20):
            phi = rng.uniform(0, 2 * np.pi)
            out.append(np.array([r * np.cos(phi), r * np.sin(phi)], F32))
        out += [np.array(v, F32) for v in ([1 + 1e-4, 0], [0, -(1 + 1e-4)], [np.nan, 0],
                                           [0, np.inf], [0.7072, 0.7072], [0.70717, 0.70717])]
        return out
    tol = POSITION_TOLERANCE
    lx, hx = F32(x) - tol, F32(x) + 1 + tol
    ly, hy = F32(y) - tol, F32(y) + 1 + tol
    cy = F32(y + 0.5)
    cx = F32(x + 0.5)
    out = []
    for v in (lx, hx, nxt(lx, F32(-np.inf)), nxt(hx, F32(np.inf)), F32(x), F32(x + 1)):
        out.append(np.array([v, cy], F32))
    for v in (ly, hy, nxt(ly, F32(-np.inf)), nxt(hy, F32(np.inf)), F32(y), F32(y + 1)):
        out.append(np.array([cx, v], F32))
    out += [np.array(v, F32) for v in ([np.nan, cy], [cx, np.inf], [-np.inf, cy])]
    return out


@pytest.mark.parametrize("seed", range(40))
def test_validate_messages_match_whole_array_formulas(block, seed):
    rng = np.random.default_rng(seed)
    h, w, s = (int(v) for v in rng.integers(1, 9, 3))
    buf = random_frame(rng, h, w, s)
    for _ in range(int(rng.integers(1, 6))):
        name = str(rng.choice(list(FIELDS)))
        y, x, i = int(rng.integers(h)), int(rng.integers(w)), int(rng.integers(s))
        vals = _boundary_values(name, y, x, rng)
        getattr(buf, name)[y, x, i] = vals[int(rng.integers(len(vals)))]
    expected = message_of(ref_validate, buf)
    assert message_of(SampleBuffer.validate, buf) == expected
    allowed = message_of(lambda b: ref_validate(b, allow_negative=True), buf)
    assert message_of(lambda b: b.validate(allow_negative=True), buf) == allowed


@pytest.mark.parametrize("seed", range(12))
def test_coc_rule_matches_whole_array_formula(block, seed):
    """Random models (both signs of c0, |c1| up to the bound) and depths on both sides of
    each model's threshold: the block scan's one-comparison filter decides as the
    per-sample formula."""
    rng = np.random.default_rng(500 + seed)
    c1 = float(rng.choice([0.0, 1.0, -7.5, 2.0**20, -(2.0**20), 1e5]))
    c0 = float(rng.choice([-1.0, 1.0]) * 10.0 ** rng.uniform(-12, 36))
    model = CocModel(c0=c0, c1=c1)
    buf = random_frame(rng, 5, 6, 4, model=model)
    lo = max(smp.coc_min_depth(c0, c1), F32(1e-20))
    hit = buf.depth < MISS_DEPTH
    # hits above the threshold (those it leaves: all of them when no hit is valid)
    buf.depth[hit] = np.minimum(lo * rng.uniform(1, 4, int(hit.sum())),
                                np.nextafter(F32(MISS_DEPTH), F32(0)))
    near = [lo, np.nextafter(lo, F32(0)), np.nextafter(lo, F32(np.inf)), lo * F32(0.5),
            lo * F32(2)]
    for _ in range(int(rng.integers(0, 5))):
        y, x, i = (int(rng.integers(n)) for n in buf.shape)
        buf.depth[y, x, i] = max(F32(near[int(rng.integers(len(near)))]), F32(1e-20))
    assert message_of(SampleBuffer.validate, buf) == message_of(ref_validate, buf)


def test_coc_rule_of_a_subclassed_model():
    class Odd(CocModel):  # not monotonic in depth: checked sample by sample
        def coc(self, depth):
            d = np.asarray(depth, np.float64)
            return np.where(np.abs(d - 3.0) < 0.5, 2.0**21, 1.0).astype(np.float32)

    buf = random_frame(np.random.default_rng(3), 4, 5, 3, model=Odd())
    buf.depth[:] = 10.0
    buf.validate()
    buf.depth[2, 1, 1] = 3.2
    buf.depth[3, 0, 2] = 2.9
    msg = message_of(SampleBuffer.validate, buf)
    assert msg == message_of(ref_validate, buf)
    assert msg.startswith("coc: sample (y=2, x=1, i=1)") and msg.endswith("(2 bad samples)")


@pytest.mark.parametrize("name", list(FIELDS))
def test_every_boundary_value_decides_as_before(block, name):
    rng = np.random.default_rng(7)
    for y, x in [(0, 0), (1, 2), (3, 6)]:
        for v in _boundary_values(name, y, x, rng):
            buf = random_frame(rng, 4, 7, 3)
            getattr(buf, name)[y, x, 1] = v
            assert message_of(SampleBuffer.validate, buf) == message_of(ref_validate, buf), \
                (v, y, x)


@pytest.mark.parametrize("shape", [(1, 3000, 1), (3000, 1, 1), (2, 2100, 2)],
                         ids=["wide", "tall", "wide-2spp"])
@pytest.mark.parametrize("block_samples", [frame_info.BLOCK_SAMPLES, 500])
def test_position_bounds_of_large_coordinates(monkeypatch, shape, block_samples):
    """Beyond 2048 the float32 bound ``p - tol`` rounds to ``p``: bounds at every scale."""
    monkeypatch.setattr(frame_info, "BLOCK_SAMPLES", block_samples)
    rng = np.random.default_rng(3)
    h, w, s = shape
    buf = random_frame(rng, h, w, s)
    picks = [(int(rng.integers(h)), int(rng.integers(w))) for _ in range(8)]
    picks += [(h - 1, w - 1), (0, 0), (h // 2, min(w - 1, 2048)), (h // 2, min(w - 1, 1023))]
    for y, x in picks:
        for v in _boundary_values("position", y, x, rng):
            old = buf.position[y, x, 0].copy()
            buf.position[y, x, 0] = v
            assert message_of(SampleBuffer.validate, buf) == message_of(ref_validate, buf), \
                (v, y, x)
            buf.position[y, x, 0] = old


def test_lens_near_the_tolerance_circle(block):
    """Samples in a thin shell around the float64 limit: the float32 filter must send every
    one of them to the exact rule."""
    rng = np.random.default_rng(11)
    buf = random_frame(rng, 3, 4, 6)
    n = buf.lens[..., 0].size
    r = (1 + LENS_TOLERANCE) + rng.uniform(-3e-7, 3e-7, n)
    phi = rng.uniform(0, 2 * np.pi, n)
    shell = np.stack([r * np.cos(phi), r * np.sin(phi)], -1).astype(F32)
    for j in range(n):
        buf2 = random_frame(np.random.default_rng(j), 3, 4, 6)
        buf2.lens.reshape(-1, 2)[j] = shell[j]
        assert message_of(SampleBuffer.validate, buf2) == message_of(ref_validate, buf2)


def test_counts_span_blocks(monkeypatch):
    monkeypatch.setattr(frame_info, "BLOCK_SAMPLES", 8)
    buf = random_frame(np.random.default_rng(5), 5, 6, 4)
    buf.time[4, 5, 3] = 2.0
    buf.time[0, 1, 2] = -1.0
    buf.time[2, 0, 0] = np.nan
    msg = message_of(SampleBuffer.validate, buf)
    assert msg == message_of(ref_validate, buf)
    assert msg.startswith("time: sample (y=0, x=1, i=2)") and msg.endswith("(3 bad samples)")


def test_valid_frames_never_take_the_exact_path(block, monkeypatch):
    def fail(*a, **k):
        raise AssertionError("exact path on a valid frame")

    monkeypatch.setattr(cval, "_exact_bad", fail)
    monkeypatch.setattr(smp, "inspect_arrays", fail)
    for seed in range(5):
        buf = random_frame(np.random.default_rng(seed), 5, 9, 4)
        # every pixel's corners, the unit circle, the shutter ends
        buf.position[0, 0, 0] = (0.0, 0.0)
        buf.position[4, 8, 3] = (9.0, 5.0)
        buf.lens[1, 1, 1] = (1.0, 0.0)
        buf.time[2, 2, 2] = 1.0
        buf.time[2, 2, 1] = 0.0
        buf.validate()
        buf.inspect()
    SampleBuffer.zeros(1, 1, 1).validate().inspect()


def test_coc_model_check_comes_after_values(rng):
    buf = random_frame(rng, model=CocModel(c0=np.nan, c1=1.0))
    assert message_of(SampleBuffer.validate, buf) == message_of(ref_validate, buf)
    buf.color[1, 1, 1, 0] = np.inf
    assert message_of(SampleBuffer.validate, buf).startswith("color:")
