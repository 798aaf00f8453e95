"""Random valid frames, the whole-array validation formulas the block scans replaced, and
small helpers shared by the SampleBuffer tests (tests/unit/test_samples*.py) and the
numeric-range tests."""
from __future__ import annotations

import dataclasses

import numpy as np

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


def disc_points(rng, shape) -> np.ndarray:
    """Points uniform in the unit disc, ``shape + (2,)`` (radii drawn first, then angles)."""
    r = np.sqrt(rng.uniform(0.0, 1.0, shape))
    phi = rng.uniform(0.0, 2 * np.pi, shape)
    return np.stack([r * np.cos(phi), r * np.sin(phi)], -1)


def position_and_lens(rng, hws):
    """Positions jittered inside their pixels and lens points uniform in the unit disc, of
    frame shape ``hws`` (drawn in this order: positions, radii, angles)."""
    h, w, _ = hws
    py, px = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    position = np.stack([px, py], -1)[:, :, None, :] + rng.uniform(0.0, 1.0, hws + (2,))
    return position, disc_points(rng, hws)


def random_frame(rng, h=6, w=7, s=5, miss=0.2, model=MODEL, depths=(0.3, 40.0),
                 color=None) -> SampleBuffer:
    """A valid random frame: hit depths uniform in ``depths`` with a ``miss`` fraction of
    misses; colours ``color(rng, (h, w, s))`` (default: exponential, mean 3)."""
    hws = (h, w, s)
    position, lens = position_and_lens(rng, hws)
    depth = rng.uniform(*depths, hws)
    depth[rng.uniform(size=hws) < miss] = np.inf
    return SampleBuffer(
        color=rng.exponential(3.0, hws + (3,)) if color is None else color(rng, hws),
        position=position,
        depth=depth,
        lens=lens,
        time=rng.uniform(0.0, 1.0, hws),
        motion=rng.normal(0.0, 4.0, hws + (2,)),
        coc_model=model,
    )


def method_frame(rng, h=11, w=13, s=4, aperture=8.0, misses=True, focus_ties=False,
                 motion=True, moving=0.3, motion_sigma=4.0) -> SampleBuffer:
    """Random valid frame for a method's tests: depths 2.2..40 around a focus at 4 (CoC up to
    ~|aperture| px), ``misses`` (a tenth at inf), ``focus_ties`` (a tenth at exactly the
    focus depth: equal depths), and ``moving`` of the samples with N(0, motion_sigma) motion."""
    model = CocModel.from_focus(aperture_px=aperture, focus_depth=4.0)
    buf = SampleBuffer.zeros(h, w, s, model)
    buf.position[:] = buf.position - 0.5 + rng.uniform(0.0, 0.999, buf.position.shape)
    buf.depth[:] = rng.uniform(2.2, 40.0, buf.depth.shape)
    if misses:
        buf.depth[rng.uniform(size=buf.depth.shape) < 0.1] = np.inf
    if focus_ties:
        buf.depth[rng.uniform(size=buf.depth.shape) < 0.1] = 4.0
    buf.lens[:] = disc_points(rng, (h, w, s))
    buf.time[:] = rng.uniform(0, 1, buf.time.shape)
    buf.color[:] = rng.exponential(1.0, buf.color.shape)
    if motion:
        share = rng.uniform(size=buf.depth.shape) < moving
        buf.motion[:] = np.where(share[..., None], rng.normal(0, motion_sigma, buf.motion.shape),
                                 0.0)
    return buf.validate()


def message_of(fn, buf) -> str | None:
    """The ``ValueError`` text ``fn(buf)`` raises, ``None`` if it raises none."""
    try:
        fn(buf)
    except ValueError as exc:
        return str(exc)
    return None


def same_info(a: FrameInfo, b: FrameInfo) -> None:
    # repr: exact floats, NaN equal to NaN
    assert repr(dataclasses.astuple(a)) == repr(dataclasses.astuple(b)), (a, b)


# -- the whole-array formulas of validate() before the block scans ---------------------------
def _first_bad(name, bad, values, what):
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
    _first_bad("depth", ~(self.depth >= F32(1e-20)), self.depth,
                   "must be at least 1e-20 (inf for a miss), got")
    c = self.color
    if allow_negative:
        _first_bad("color", ~(np.abs(c) <= F32(1e30)).all(-1), c,
                       "must be finite and in [-1e+30, 1e+30], got")
    else:
        _first_bad("color", ~((c >= 0) & (c <= F32(1e30))).all(-1), c,
                       "must be finite and in [0, 1e+30] (negative radiance needs "
                       "allow_negative=True), got")
    _first_bad("motion", ~(np.abs(self.motion) <= 65536).all(-1), self.motion,
                   "must be finite with components in [-65536, 65536] px, got")
    _first_bad("time", ~((self.time >= 0) & (self.time <= 1)), self.time,
                   "must lie in [0, 1], got")
    r2 = (self.lens.astype(np.float64) ** 2).sum(-1)
    _first_bad("lens", ~(r2 <= (1 + LENS_TOLERANCE) ** 2), self.lens,
                   "must lie in the unit disk, got")
    h, w, _ = hws
    px = np.arange(w, dtype=np.float32)[None, :, None]
    py = np.arange(h, dtype=np.float32)[:, None, None]
    x, y = self.position[..., 0], self.position[..., 1]
    tol = POSITION_TOLERANCE
    outside = ~((x >= px - tol) & (x <= px + 1 + tol) & (y >= py - tol) & (y <= py + 1 + tol))
    _first_bad("position", outside, self.position, "must lie inside its pixel, got")
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
