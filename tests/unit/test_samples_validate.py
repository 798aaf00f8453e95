"""SampleBuffer.validate() and inspect(): layout checks, and the block scans against the
whole-array formulas they replace (same messages, same FrameInfo, on every kind of frame)."""
from __future__ import annotations

import dataclasses
import re

import numpy as np
import pytest

from clrecon.core import samples as smp
from clrecon.core.camera import CocModel
from clrecon.core.samples import (
    FIELDS,
    LENS_TOLERANCE,
    MISS_DEPTH,
    POSITION_TOLERANCE,
    FrameInfo,
    SampleBuffer,
)

MODEL = CocModel.from_focus(aperture_px=6.0, focus_depth=2.0)
F32 = np.float32


# -- the whole-array formulas of validate() and inspect() before the block scans -----------
def _ref_first_bad(name, bad, values, what):
    if bad.any():
        idx = tuple(int(i) for i in np.argwhere(bad)[0])
        py, px, s = idx
        count = int(bad.sum())
        raise ValueError(
            f"{name}: sample (y={py}, x={px}, i={s}) {what} {values[idx].tolist()} "
            f"({count} bad sample{'s' if count != 1 else ''})"
        )


def ref_validate(self, allow_negative=False):
    if self.depth.ndim != 3:
        raise ValueError(f"depth: expected shape (H, W, S), got {self.depth.shape}")
    hws = self.depth.shape
    if min(hws) < 1:
        raise ValueError(f"depth: empty frame of shape {hws}")
    for name, tail in FIELDS.items():
        arr = getattr(self, name)
        if arr.shape != hws + tail:
            raise ValueError(f"{name}: expected shape {hws + tail}, got {arr.shape}")
    _ref_first_bad("depth", ~(self.depth >= F32(1e-20)), self.depth,
                   "must be at least 1e-20 (inf for a miss), got")
    c = self.color
    if allow_negative:
        _ref_first_bad("color", ~(np.abs(c) <= F32(1e30)).all(-1), c,
                       "must be finite and in [-1e+30, 1e+30], got")
    else:
        _ref_first_bad("color", ~((c >= 0) & (c <= F32(1e30))).all(-1), c,
                       "must be finite and in [0, 1e+30] (negative radiance needs "
                       "allow_negative=True), got")
    _ref_first_bad("motion", ~(np.abs(self.motion) <= 65536).all(-1), self.motion,
                   "must be finite with components in [-65536, 65536] px, got")
    _ref_first_bad("time", ~((self.time >= 0) & (self.time <= 1)), self.time,
                   "must lie in [0, 1], got")
    r2 = (self.lens.astype(np.float64) ** 2).sum(-1)
    _ref_first_bad("lens", ~(r2 <= (1 + LENS_TOLERANCE) ** 2), self.lens,
                   "must lie in the unit disk, got")
    h, w, _ = hws
    px = np.arange(w, dtype=np.float32)[None, :, None]
    py = np.arange(h, dtype=np.float32)[:, None, None]
    x, y = self.position[..., 0], self.position[..., 1]
    tol = POSITION_TOLERANCE
    outside = ~((x >= px - tol) & (x <= px + 1 + tol) & (y >= py - tol) & (y <= py + 1 + tol))
    _ref_first_bad("position", outside, self.position, "must lie inside its pixel, got")
    m = self.coc_model
    if not (abs(m.c0) <= 2.0**20 * 1e30 and abs(m.c1) <= 2.0**20):
        raise ValueError(f"coc_model: coefficients must be finite with |c1| <= 1048576 px and "
                         f"|c0| <= 1048576 * 1e+30, got {m}")
    coc = m.coc(self.depth)
    bad = (self.depth < MISS_DEPTH) & ~(np.abs(coc) <= 2.0**20)
    if bad.any():
        idx = tuple(int(i) for i in np.argwhere(bad)[0])
        count = int(bad.sum())
        raise ValueError(
            f"coc: sample (y={idx[0]}, x={idx[1]}, i={idx[2]}) must have |coc(depth)| <= "
            f"1048576 px, got coc {coc[idx].tolist()} px at depth {self.depth[idx].tolist()} "
            f"with {m} ({count} bad sample{'s' if count != 1 else ''})")
    return self


def ref_inspect(self):
    hit = self.depth < MISS_DEPTH
    coc = np.abs(self.coc())
    hit_depth = self.depth[hit] if hit.any() else np.array([np.inf], np.float32)
    motion = np.sqrt((self.motion.astype(np.float64) ** 2).sum(-1))
    return FrameInfo(
        width=self.width,
        height=self.height,
        spp=self.spp,
        max_abs_coc=float(coc.max(initial=0.0)),
        max_abs_motion=float(motion.max(initial=0.0)),
        min_depth=float(hit_depth.min()),
        max_depth=float(hit_depth.max()),
        miss_fraction=float(1.0 - hit.mean()),
    )


# -- helpers --------------------------------------------------------------------------------
def _frame(rng, h=6, w=7, s=5, miss=0.2, model=MODEL) -> SampleBuffer:
    """A valid random frame."""
    hws = (h, w, s)
    py, px = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    position = np.stack([px, py], -1)[:, :, None, :] + rng.uniform(0.0, 1.0, hws + (2,))
    r = np.sqrt(rng.uniform(0.0, 1.0, hws))
    phi = rng.uniform(0.0, 2 * np.pi, hws)
    depth = rng.uniform(0.3, 40.0, hws)
    depth[rng.uniform(size=hws) < miss] = np.inf
    return SampleBuffer(
        color=rng.exponential(3.0, hws + (3,)),
        position=position,
        depth=depth,
        lens=np.stack([r * np.cos(phi), r * np.sin(phi)], -1),
        time=rng.uniform(0.0, 1.0, hws),
        motion=rng.normal(0.0, 4.0, hws + (2,)),
        coc_model=model,
    )


def _message(fn, buf) -> str | None:
    try:
        fn(buf)
    except ValueError as exc:
        return str(exc)
    return None


def _same_info(a: FrameInfo, b: FrameInfo) -> None:
    # repr: exact floats, NaN equal to NaN
    assert repr(dataclasses.astuple(a)) == repr(dataclasses.astuple(b)), (a, b)


@pytest.fixture(params=[smp._BLOCK_SAMPLES, 1, 12, 40, 1000], ids=lambda b: f"block{b}")
def block(request, monkeypatch):
    """Run with the real block size and with small ones (many blocks, partial rows)."""
    monkeypatch.setattr(smp, "_BLOCK_SAMPLES", request.param)
    return request.param


# -- layout ---------------------------------------------------------------------------------
@pytest.mark.parametrize("name", list(FIELDS))
def test_float64_field_is_rejected(rng, name):
    buf = _frame(rng)
    setattr(buf, name, getattr(buf, name).astype(np.float64))
    with pytest.raises(ValueError, match=re.escape(f"{name}: expected float32, got float64")):
        buf.validate()


@pytest.mark.parametrize("name", list(FIELDS))
@pytest.mark.parametrize("dtype", [np.float16, np.int32, np.dtype(">f4")], ids=str)
def test_other_dtypes_are_rejected(rng, name, dtype):
    buf = _frame(rng)
    with np.errstate(invalid="ignore"):  # inf depths as int32
        arr = getattr(buf, name).astype(dtype)
    setattr(buf, name, arr)
    with pytest.raises(ValueError, match=re.escape(f"{name}: expected float32, got {arr.dtype}")):
        buf.validate()


@pytest.mark.parametrize("name", list(FIELDS))
def test_non_contiguous_field_is_rejected(rng, name):
    buf = _frame(rng)
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
    buf = _frame(rng)
    setattr(buf, name, np.asfortranarray(getattr(buf, name)))
    with pytest.raises(ValueError, match=re.escape(f"{name}: expected a C-contiguous array")):
        buf.validate()


def test_non_array_field_is_rejected(rng):
    buf = _frame(rng)
    buf.time = buf.time.tolist()
    with pytest.raises(ValueError, match=re.escape("time: expected a numpy array, got list")):
        buf.validate()


def test_layout_is_checked_before_values(rng):
    buf = _frame(rng)
    buf.depth[0, 0, 0] = -1.0
    buf.motion = buf.motion.astype(np.float64)
    with pytest.raises(ValueError, match="motion: expected float32"):
        buf.validate()


def test_wrong_shape_message_is_unchanged(rng):
    buf = _frame(rng)
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
    buf = _frame(rng, h, w, s)
    for _ in range(int(rng.integers(1, 6))):
        name = str(rng.choice(list(FIELDS)))
        y, x, i = int(rng.integers(h)), int(rng.integers(w)), int(rng.integers(s))
        vals = _boundary_values(name, y, x, rng)
        getattr(buf, name)[y, x, i] = vals[int(rng.integers(len(vals)))]
    expected = _message(ref_validate, buf)
    assert _message(SampleBuffer.validate, buf) == expected
    allowed = _message(lambda b: ref_validate(b, allow_negative=True), buf)
    assert _message(lambda b: b.validate(allow_negative=True), buf) == allowed


@pytest.mark.parametrize("seed", range(12))
def test_coc_rule_matches_whole_array_formula(block, seed):
    """Random models (both signs of c0, |c1| up to the bound) and depths on both sides of
    each model's threshold: the block scan's one-comparison filter decides as the
    per-sample formula."""
    rng = np.random.default_rng(500 + seed)
    c1 = float(rng.choice([0.0, 1.0, -7.5, 2.0**20, -(2.0**20), 1e5]))
    c0 = float(rng.choice([-1.0, 1.0]) * 10.0 ** rng.uniform(-12, 36))
    model = CocModel(c0=c0, c1=c1)
    buf = _frame(rng, 5, 6, 4, model=model)
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
    assert _message(SampleBuffer.validate, buf) == _message(ref_validate, buf)


def test_coc_rule_of_a_subclassed_model():
    class Odd(CocModel):  # not monotonic in depth: checked sample by sample
        def coc(self, depth):
            d = np.asarray(depth, np.float64)
            return np.where(np.abs(d - 3.0) < 0.5, 2.0**21, 1.0).astype(np.float32)

    buf = _frame(np.random.default_rng(3), 4, 5, 3, model=Odd())
    buf.depth[:] = 10.0
    buf.validate()
    buf.depth[2, 1, 1] = 3.2
    buf.depth[3, 0, 2] = 2.9
    msg = _message(SampleBuffer.validate, buf)
    assert msg == _message(ref_validate, buf)
    assert msg.startswith("coc: sample (y=2, x=1, i=1)") and msg.endswith("(2 bad samples)")


@pytest.mark.parametrize("name", list(FIELDS))
def test_every_boundary_value_decides_as_before(block, name):
    rng = np.random.default_rng(7)
    for y, x in [(0, 0), (1, 2), (3, 6)]:
        for v in _boundary_values(name, y, x, rng):
            buf = _frame(rng, 4, 7, 3)
            getattr(buf, name)[y, x, 1] = v
            assert _message(SampleBuffer.validate, buf) == _message(ref_validate, buf), (v, y, x)


@pytest.mark.parametrize("shape", [(1, 3000, 1), (3000, 1, 1), (2, 2100, 2)],
                         ids=["wide", "tall", "wide-2spp"])
@pytest.mark.parametrize("block_samples", [smp._BLOCK_SAMPLES, 500])
def test_position_bounds_of_large_coordinates(monkeypatch, shape, block_samples):
    """Beyond 2048 the float32 bound ``p - tol`` rounds to ``p``: bounds at every scale."""
    monkeypatch.setattr(smp, "_BLOCK_SAMPLES", block_samples)
    rng = np.random.default_rng(3)
    h, w, s = shape
    buf = _frame(rng, h, w, s)
    picks = [(int(rng.integers(h)), int(rng.integers(w))) for _ in range(8)]
    picks += [(h - 1, w - 1), (0, 0), (h // 2, min(w - 1, 2048)), (h // 2, min(w - 1, 1023))]
    for y, x in picks:
        for v in _boundary_values("position", y, x, rng):
            old = buf.position[y, x, 0].copy()
            buf.position[y, x, 0] = v
            assert _message(SampleBuffer.validate, buf) == _message(ref_validate, buf), (v, y, x)
            buf.position[y, x, 0] = old


def test_lens_near_the_tolerance_circle(block):
    """Samples in a thin shell around the float64 limit: the float32 filter must send every
    one of them to the exact rule."""
    rng = np.random.default_rng(11)
    buf = _frame(rng, 3, 4, 6)
    n = buf.lens[..., 0].size
    r = (1 + LENS_TOLERANCE) + rng.uniform(-3e-7, 3e-7, n)
    phi = rng.uniform(0, 2 * np.pi, n)
    shell = np.stack([r * np.cos(phi), r * np.sin(phi)], -1).astype(F32)
    for j in range(n):
        buf2 = _frame(np.random.default_rng(j), 3, 4, 6)
        buf2.lens.reshape(-1, 2)[j] = shell[j]
        assert _message(SampleBuffer.validate, buf2) == _message(ref_validate, buf2)


def test_counts_span_blocks(monkeypatch):
    monkeypatch.setattr(smp, "_BLOCK_SAMPLES", 8)
    buf = _frame(np.random.default_rng(5), 5, 6, 4)
    buf.time[4, 5, 3] = 2.0
    buf.time[0, 1, 2] = -1.0
    buf.time[2, 0, 0] = np.nan
    msg = _message(SampleBuffer.validate, buf)
    assert msg == _message(ref_validate, buf)
    assert msg.startswith("time: sample (y=0, x=1, i=2)") and msg.endswith("(3 bad samples)")


def test_valid_frames_never_take_the_exact_path(block, monkeypatch):
    def fail(*a, **k):
        raise AssertionError("exact path on a valid frame")

    monkeypatch.setattr(smp, "_exact_bad", fail)
    monkeypatch.setattr(smp, "_inspect_arrays", fail)
    for seed in range(5):
        buf = _frame(np.random.default_rng(seed), 5, 9, 4)
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
    buf = _frame(rng, model=CocModel(c0=np.nan, c1=1.0))
    assert _message(SampleBuffer.validate, buf) == _message(ref_validate, buf)
    buf.color[1, 1, 1, 0] = np.inf
    assert _message(SampleBuffer.validate, buf).startswith("color:")


# -- inspect: the block scan against the whole-array formulas -------------------------------
def _variants(rng):
    """Frames of every kind inspect() meets (valid or not)."""
    yield "random", _frame(rng)
    yield "1x1x1", _frame(rng, 1, 1, 1)
    yield "1x1x1-miss", _frame(rng, 1, 1, 1, miss=1.0)
    yield "no-misses", _frame(rng, miss=0.0)
    yield "all-misses", _frame(rng, miss=1.0)
    b = _frame(rng)
    b.motion[:] = 0.0
    yield "zero-motion", b
    b = _frame(rng)
    b.motion[:] = -0.0
    yield "negative-zero-motion", b
    b = _frame(rng)
    b.motion[:] = 0.0
    b.motion[2, 3, 1] = (1e-30, -3e-31)  # float32 squares underflow
    yield "tiny-motion", b
    b = _frame(rng)
    b.motion *= F32(1e-20)
    yield "small-motion", b
    b = _frame(rng)
    b.motion[1, 1, 1] = (2e19, -3e19)  # float32 squares overflow
    yield "huge-motion", b
    b = _frame(rng)
    b.motion[1, 1, 1] = (3e38, 3e38)
    yield "max-motion", b
    b = _frame(rng)
    b.motion[0, 2, 0, 1] = np.nan
    yield "nan-motion", b
    b = _frame(rng)
    b.motion[0, 2, 0, 1] = np.inf
    yield "inf-motion", b
    b = _frame(rng)
    b.motion[3, 3, 3] = (3.0, 4.0)
    b.motion[3, 3, 2] = (4.0, 3.0)
    b.motion[3, 3, 1] = (np.nextafter(F32(3), F32(4)), 4.0)
    yield "motion-ties", b
    b = _frame(rng)
    b.depth[0, 0, 0] = MISS_DEPTH
    b.depth[0, 0, 1] = np.nextafter(F32(MISS_DEPTH), F32(0))
    b.depth[0, 0, 2] = np.nextafter(F32(MISS_DEPTH), F32(np.inf))
    b.depth[0, 0, 3] = 3e38
    yield "miss-threshold", b
    b = _frame(rng)
    b.depth[:] = np.nextafter(F32(MISS_DEPTH), F32(0))
    yield "all-just-hits", b
    b = _frame(rng)
    b.depth[1, 1, 1] = 1e-40  # subnormal
    yield "subnormal-depth", b
    b = _frame(rng)
    b.depth[1, 1, 1] = -2.0
    yield "negative-depth", b
    b = _frame(rng)
    b.depth[1, 1, 1] = 0.0
    yield "zero-depth", b
    b = _frame(rng)
    b.depth[1, 1, 1] = np.nan
    yield "nan-depth", b
    yield "pinhole", _frame(rng, model=CocModel())
    yield "c0-only", _frame(rng, model=CocModel(c0=-5.0, c1=0.0))
    yield "huge-c0", _frame(rng, model=CocModel(c0=3e35, c1=-1.0))
    yield "positive-c0", _frame(rng, model=CocModel(c0=12.0, c1=-3.0))
    yield "nan-model", _frame(rng, model=CocModel(c0=np.nan, c1=1.0))
    yield "inf-model", _frame(rng, model=CocModel(c0=1.0, c1=np.inf))

    class Odd(CocModel):
        def coc(self, depth):
            return np.full(np.shape(depth), 7.0, np.float32)

    yield "subclassed-model", _frame(rng, model=Odd())
    b = _frame(rng)
    b.depth = b.depth.astype(np.float64)
    yield "float64-depth", b
    b = _frame(rng)
    b.motion = np.asfortranarray(b.motion)
    yield "fortran-motion", b
    yield "wide", _frame(rng, 2, 300, 3)
    yield "many-spp", _frame(rng, 2, 3, 200)


@pytest.mark.parametrize("seed", range(6))
def test_inspect_matches_whole_array_formulas(block, seed):
    with np.errstate(all="ignore"):
        for label, buf in _variants(np.random.default_rng(seed)):
            _same_info(buf.inspect(), ref_inspect(buf))
            assert label


@pytest.mark.parametrize("seed", range(20))
def test_inspect_random_shapes(block, seed):
    rng = np.random.default_rng(100 + seed)
    h, w, s = (int(v) for v in rng.integers(1, 12, 3))
    buf = _frame(rng, h, w, s, miss=float(rng.choice([0.0, 0.01, 0.5, 1.0])))
    buf.motion *= F32(10.0 ** rng.integers(-3, 4))
    if rng.random() < 0.3:
        buf.motion[rng.random(buf.depth.shape) < 0.7] = 0.0
    _same_info(buf.inspect(), ref_inspect(buf))


def test_inspect_of_the_unit_tests_frame():
    info = SampleBuffer.zeros(3, 7, 16, MODEL).inspect()
    _same_info(info, ref_inspect(SampleBuffer.zeros(3, 7, 16, MODEL)))


@pytest.mark.parametrize("block_samples", [1, 4, smp._BLOCK_SAMPLES])
def test_longest_motion_where_float32_orders_otherwise(monkeypatch, block_samples):
    """Two vectors whose float32 squared lengths order the other way round than in float64:
    the longest one (float64) must be found even when it is not the float32 maximum."""
    monkeypatch.setattr(smp, "_BLOCK_SAMPLES", block_samples)
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
    buf = _frame(rng, 2, 3, 2)
    buf.motion[:] = 0.0
    buf.motion[0, 0, 0] = m[a]
    buf.motion[1, 2, 1] = m[b]
    _same_info(buf.inspect(), ref_inspect(buf))
    buf.motion[0, 0, 0], buf.motion[1, 2, 1] = m[b], m[a]
    _same_info(buf.inspect(), ref_inspect(buf))
