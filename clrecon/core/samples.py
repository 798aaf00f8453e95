"""The sample buffer: one frame of stochastic samples as a structure of float32 arrays.

Field layout (``S`` samples per pixel, sample ``(py, px, i)``):

========== ============== ==============================================================
field      shape          meaning
========== ============== ==============================================================
color      (H, W, S, 3)   linear radiance (HDR values far above 1 are normal), <= 1e30
position   (H, W, S, 2)   sensor position in pixels (x right, y down), inside its pixel
depth      (H, W, S)      camera-space depth ``w >= 1e-20``; ``inf`` (or >= 1e30): a miss
lens       (H, W, S, 2)   lens coordinates ``(u, v)`` in the unit disk
time       (H, W, S)      shutter time in [0, 1]
motion     (H, W, S, 2)   pinhole screen displacement (pixels) from t=0 to t=1
========== ============== ==============================================================

The thin-lens model is :class:`clrecon.core.camera.CocModel`; the centre of a sample (its
reprojection to ``(u, v, t) = (0, 0, 0.5)``) is
``position - coc(depth) * lens - (time - 0.5) * motion``.

Value bounds (:meth:`SampleBuffer.validate` on the host, :mod:`clrecon.core.inspect` on the
device, same rules and messages), chosen so that no kernel overflows float32 on a valid
frame:

* colour: every channel finite and in ``[0, COLOR_MAX]``, ``COLOR_MAX = 1e30`` (compared
  as float32), so that float32 holds a sum of 3.4e8 colours at the bound. The kernels only
  add colours times weights (none squares a colour), and their largest sums are far below
  that: box's S per pixel, sweep's 49 S per window, splat's layer images and pyramid (~5x
  the largest colour), layered's filtered grids (~1.6e3x at 512x512 16 spp, proportional to
  spp): safe beyond 1e5 spp. ``allow_negative=True`` accepts ``[-COLOR_MAX, COLOR_MAX]``;
  every method then gives ``f(c+) - f(c-)`` (see :func:`clrecon.core.pipeline.run`).
* depth: ``>= MIN_DEPTH = 1e-20`` (float32) or a miss; ``1 / depth <= 1e20`` then fits
  float32 for the methods that place samples in 1/depth (layered buckets, splat layers).
* CoC: the coefficients ``|c1| <= COC_MAX = 2**20`` px (the CoC of a miss) and
  ``|c0| <= COC_MAX * 1e30``, and every hit's ``|coc(depth)| <= COC_MAX`` (about a million
  pixels, wider than any frame: a larger CoC would only spread a sample evenly over it; a
  sample at the near plane of a defocused camera, ~5e5 px, is valid). A CoC square
  (layered's statistics) is then at most 2**40 per sample.
* motion: each component in ``[-MOTION_MAX, MOTION_MAX]``, ``MOTION_MAX = 2**16`` px (a
  length of at most 2**16.5 px, wider than any frame); it bounds splat's motion
  sub-segments (``ceil(|motion| / 192)`` <= 483 per sample).
"""
from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np

from clrecon.core.camera import CocModel

#: field name -> trailing shape after (H, W, S)
FIELDS: dict[str, tuple[int, ...]] = {
    "color": (3,),
    "position": (2,),
    "depth": (),
    "lens": (2,),
    "time": (),
    "motion": (2,),
}

#: depths at or beyond this are misses (background)
MISS_DEPTH = 1e30

LENS_TOLERANCE = 1e-4
POSITION_TOLERANCE = 1e-4

#: largest colour magnitude (float32(1e30)); negative colours need ``allow_negative``
COLOR_MAX = 1e30
#: smallest depth of a hit (float32(1e-20))
MIN_DEPTH = 1e-20
#: largest |coc| of a sample and |c1| of the model, pixels
COC_MAX = 2.0**20
#: largest |c0| of the model (pixels times depth units): COC_MAX at the miss depth
C0_MAX = COC_MAX * MISS_DEPTH
#: largest |component| of a motion vector, pixels
MOTION_MAX = 2.0**16


@dataclass(frozen=True)
class FrameInfo:
    """What one look at a frame says it needs (used to specialise kernels)."""

    width: int
    height: int
    spp: int
    max_abs_coc: float  # pixels, over every sample (misses: |C1|)
    max_abs_motion: float  # pixels, longest motion vector
    min_depth: float
    max_depth: float
    miss_fraction: float

    @property
    def has_motion(self) -> bool:
        return self.max_abs_motion > 0.0

    @property
    def has_defocus(self) -> bool:
        return self.max_abs_coc > 0.0


@dataclass(eq=False)
class SampleBuffer:
    """One frame of samples; see the module docstring for the fields.

    Arrays are converted to C-contiguous float32 on construction; shapes are checked by
    :meth:`validate` (called by every consumer at its boundary), not here, so that a
    loader can build a buffer and report every problem through one path.
    """

    color: np.ndarray
    position: np.ndarray
    depth: np.ndarray
    lens: np.ndarray
    time: np.ndarray
    motion: np.ndarray
    coc_model: CocModel = field(default_factory=CocModel)

    def __post_init__(self):
        for name in FIELDS:
            setattr(self, name, np.ascontiguousarray(getattr(self, name), dtype=np.float32))
        if not isinstance(self.coc_model, CocModel):
            raise TypeError(f"coc_model must be a CocModel, got {type(self.coc_model).__name__}")

    # -- shape -----------------------------------------------------------------------------
    @property
    def height(self) -> int:
        return self.depth.shape[0]

    @property
    def width(self) -> int:
        return self.depth.shape[1]

    @property
    def spp(self) -> int:
        return self.depth.shape[2]

    @property
    def shape(self) -> tuple[int, int, int]:
        """``(H, W, S)``."""
        return tuple(self.depth.shape)

    @property
    def nbytes(self) -> int:
        return sum(getattr(self, n).nbytes for n in FIELDS)

    def arrays(self) -> dict[str, np.ndarray]:
        return {n: getattr(self, n) for n in FIELDS}

    # -- constructors ----------------------------------------------------------------------
    @classmethod
    def zeros(cls, height: int, width: int, spp: int, coc_model: CocModel | None = None):
        """A buffer of the given shape, samples at pixel centres, lens 0, time 0.5, depth 1."""
        hws = (height, width, spp)
        buf = cls(
            color=np.zeros(hws + (3,), np.float32),
            position=pixel_centres(height, width, spp),
            depth=np.ones(hws, np.float32),
            lens=np.zeros(hws + (2,), np.float32),
            time=np.full(hws, 0.5, np.float32),
            motion=np.zeros(hws + (2,), np.float32),
            coc_model=coc_model or CocModel(),
        )
        return buf

    @classmethod
    def pinhole(cls, color, depth, motion=None, coc_model: CocModel | None = None):
        """Synthesis input from a pinhole frame: S = 1, lens 0, time 0.5, pixel centres.

        ``color`` is (H, W, 3), ``depth`` (H, W), ``motion`` (H, W, 2) or None.
        """
        color = np.asarray(color, np.float32)
        if color.ndim != 3 or color.shape[2] != 3:
            raise ValueError(f"color: expected shape (H, W, 3), got {color.shape}")
        h, w = color.shape[:2]
        buf = cls.zeros(h, w, 1, coc_model)
        buf.color[:] = color[:, :, None, :]
        buf.depth[:] = np.asarray(depth, np.float32).reshape(h, w, 1)
        if motion is not None:
            buf.motion[:] = np.asarray(motion, np.float32).reshape(h, w, 1, 2)
        return buf

    # -- convention ------------------------------------------------------------------------
    def coc(self) -> np.ndarray:
        """Signed CoC radius of every sample, pixels, (H, W, S)."""
        return self.coc_model.coc(self.depth)

    def centre(self) -> np.ndarray:
        """Each sample reprojected to ``(u, v, t) = (0, 0, 0.5)``: (H, W, S, 2) pixels.

        Misses (depth >= MISS_DEPTH) have ``coc = C1``; their centre is still defined.
        """
        coc = self.coc()[..., None]
        shutter = (self.time[..., None] - 0.5) * self.motion
        return (self.position - coc * self.lens - shutter).astype(np.float32)

    def inspect(self) -> FrameInfo:
        """One pass over the frame: the facts that decide which terms a kernel needs.

        Scans the frame in blocks that stay in cache; a frame the block scan does not cover
        (not validated: non-positive or NaN depths, another layout, a subclassed or
        non-finite CoC model) is described by the plain whole-array formulas instead, with
        the same results.
        """
        with np.errstate(over="ignore", invalid="ignore"):  # float32 squares may overflow
            info = _inspect_blocks(self)
        return info if info is not None else _inspect_arrays(self)

    # -- validation ------------------------------------------------------------------------
    def check_layout(self, fields=None) -> SampleBuffer:
        """Check what the kernels read of memory, without looking at values: each field of
        ``fields`` (default: all) is a C-contiguous float32 array of the frame's shape.
        Raises ``ValueError`` naming the field. Cheap: the values are checked by
        :meth:`validate` on the host or by the device inspection pass."""
        if not isinstance(self.depth, np.ndarray) or self.depth.ndim != 3:
            raise ValueError(f"depth: expected shape (H, W, S), got "
                             f"{getattr(self.depth, 'shape', type(self.depth).__name__)}")
        hws = self.depth.shape
        if min(hws) < 1:
            raise ValueError(f"depth: empty frame of shape {hws}")
        for name in fields or FIELDS:
            arr = getattr(self, name)
            if not isinstance(arr, np.ndarray):
                raise ValueError(f"{name}: expected a numpy array, got {type(arr).__name__}")
            if arr.dtype != np.float32:
                raise ValueError(f"{name}: expected float32, got {arr.dtype}")
            if arr.shape != hws + FIELDS[name]:
                raise ValueError(f"{name}: expected shape {hws + FIELDS[name]}, got {arr.shape}")
            if not arr.flags.c_contiguous:
                raise ValueError(f"{name}: expected a C-contiguous array")
        return self

    def validate(self, allow_negative: bool = False) -> SampleBuffer:
        """Check layout (:meth:`check_layout`) and value ranges (module docstring); raise
        ``ValueError`` naming the field and, for a value, the first bad sample in C order
        and the number of bad samples.

        Order: the rules of depth, color, motion, time, lens and position, then the
        ``coc_model`` coefficients, then each hit's CoC (rule ``coc``). Negative colours
        are refused unless ``allow_negative``. Returns ``self`` so that
        ``buf.validate()`` can be used inline.
        """
        self.check_layout()
        with np.errstate(over="ignore", invalid="ignore"):  # float32 squares may overflow
            _check_values(self, bool(allow_negative))
        return self


def rule_text(name: str, allow_negative: bool = False) -> str:
    """What a bad sample of rule ``name`` violates (the middle of its message)."""
    if name == "color":
        if allow_negative:
            return f"must be finite and in [{-COLOR_MAX:g}, {COLOR_MAX:g}], got"
        return (f"must be finite and in [0, {COLOR_MAX:g}] (negative radiance needs "
                f"allow_negative=True), got")
    return _RULE_TEXT[name]


def bad_sample_message(name: str, first: tuple[int, int, int], count: int, value,
                       allow_negative: bool = False, model=None) -> str:
    """The ``ValueError`` text of rule ``name`` (host and device alike): ``value`` is the
    first bad sample's value of the field (for ``coc``: its depth; ``model`` gives the
    CoC)."""
    py, px, i = first
    if name == "coc":
        coc = model.coc(np.array([value], np.float32))[0].tolist()
        value = f"coc {coc} px at depth {value} with {model}"
    return (f"{name}: sample (y={py}, x={px}, i={i}) {rule_text(name, allow_negative)} "
            f"{value} ({count} bad sample{'s' if count != 1 else ''})")


def coc_model_error(model) -> str | None:
    """Why the coefficients of ``model`` are refused (``None``: they are valid)."""
    if abs(model.c0) <= C0_MAX and abs(model.c1) <= COC_MAX:  # NaN fails
        return None
    return (f"coc_model: coefficients must be finite with |c1| <= {COC_MAX:.0f} px and "
            f"|c0| <= {COC_MAX:.0f} * {MISS_DEPTH:g}, got {model}")


@functools.lru_cache(maxsize=256)
def coc_min_depth(c0: float, c1: float) -> np.float32:
    """The smallest float32 hit depth whose CoC (``CocModel(c0, c1).coc``, the host
    formula) satisfies ``|coc| <= COC_MAX``; ``float32(MISS_DEPTH)`` when no hit does.

    For coefficients that :func:`coc_model_error` accepts, a hit ``d`` (``d < MISS_DEPTH``)
    breaks the CoC bound exactly when ``d < coc_min_depth(c0, c1)``: ``coc`` is monotonic
    in ``d`` (each rounding step is) and tends to ``c1``, within the bound, on the side of
    large depths (``c0 / d`` has the sign of ``c0``: ``coc <= c1`` when ``c0 <= 0``,
    ``coc >= c1`` when ``c0 >= 0``), so only small depths can break it. Found by bisection
    over the float32 bit patterns (positive floats order like their bits); the device pass
    compares depths with this one threshold.
    """
    model = CocModel(c0, c1)
    miss = np.float32(MISS_DEPTH)

    def ok(bits: int) -> bool:
        d = np.array([bits], np.uint32).view(np.float32)
        with np.errstate(over="ignore", invalid="ignore"):  # subnormal depths: inf
            return bool(np.abs(model.coc(d))[0] <= COC_MAX)

    lo, hi = 0, int(miss.view(np.uint32))  # ok(hi) taken as true: a miss; ok(0) false
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if ok(mid):
            hi = mid
        else:
            lo = mid
    return np.array([hi], np.uint32).view(np.float32)[0] if hi > 1 else np.float32(0)


def pixel_centres(height: int, width: int, spp: int) -> np.ndarray:
    """Positions at pixel centres, (H, W, S, 2)."""
    ys, xs = np.meshgrid(np.arange(height, dtype=np.float32) + 0.5,
                         np.arange(width, dtype=np.float32) + 0.5, indexing="ij")
    pos = np.stack([xs, ys], -1)[:, :, None, :]
    # a real copy: a broadcast view would be read-only (and shared by every sample)
    return np.array(np.broadcast_to(pos, (height, width, spp, 2)), dtype=np.float32)


# -- block scans of validate() and inspect() ------------------------------------------------
#
# Both methods walk the frame in blocks of about _BLOCK_SAMPLES samples (whole rows, or a run
# of pixels of one row, so that every block of every field is contiguous) and reduce each
# block to a few scalars with float32 temporaries that stay in cache. validate() uses the
# scalars as a filter that never passes a bad block: a block that fails it is checked again
# with the exact whole-array formulas, which give the messages (and float64 where the rule
# is float64). inspect() derives every FrameInfo value exactly from the block scalars.

#: samples per block (a few hundred kB per field; the temporaries fit in L2 / L3)
_BLOCK_SAMPLES = 1 << 16

#: value rules of validate(), in the order they are reported (``coc`` after the
#: coefficients of the model); the colour text depends on ``allow_negative``
#: (:func:`rule_text`)
RULE_NAMES: tuple[str, ...] = ("depth", "color", "motion", "time", "lens", "position", "coc")

_RULE_TEXT = {
    "depth": f"must be at least {MIN_DEPTH:g} (inf for a miss), got",
    "motion": f"must be finite with components in [{-MOTION_MAX:.0f}, {MOTION_MAX:.0f}] px, "
              "got",
    "time": "must lie in [0, 1], got",
    "lens": "must lie in the unit disk, got",
    "position": "must lie inside its pixel, got",
    "coc": f"must have |coc(depth)| <= {COC_MAX:.0f} px, got",
}

#: the bounds as the rules compare them (float32)
_MIN_DEPTH32 = np.float32(MIN_DEPTH)
_COLOR_MAX32 = np.float32(COLOR_MAX)
_MOTION_MAX32 = np.float32(MOTION_MAX)
_MISS32 = np.float32(MISS_DEPTH)

_LENS_LIMIT = (1 + LENS_TOLERANCE) ** 2  # float64, as the rule compares


def _blocks(h: int, w: int, s: int) -> list[tuple[int, int, int, int]]:
    """``(y0, y1, x0, x1)`` blocks in C order, each contiguous in every field."""
    row = w * s
    if row <= _BLOCK_SAMPLES:
        k = _BLOCK_SAMPLES // row
        return [(y, min(h, y + k), 0, w) for y in range(0, h, k)]
    k = max(1, _BLOCK_SAMPLES // s)
    return [(y, y + 1, x, min(w, x + k)) for y in range(h) for x in range(0, w, k)]


def _f32_below(x: float) -> np.float32:
    """The largest float32 that is <= ``x`` (x finite and positive)."""
    f = np.float32(x)
    return f if float(f) <= x else np.nextafter(f, np.float32(0))


def _pixel_bounds(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper position bounds of pixels ``0..n-1`` exactly as the rule computes
    them (float32 arithmetic with the tolerance as a float32 scalar)."""
    p = np.arange(n, dtype=np.float32)
    return p - POSITION_TOLERANCE, p + 1 + POSITION_TOLERANCE


def _exact_bad(buf: SampleBuffer, name: str, blk: tuple[int, int, int, int],
               allow_negative: bool = False) -> np.ndarray:
    """The rule ``name`` on one block: a bool mask (y, x, i), the whole-array formula."""
    y0, y1, x0, x1 = blk
    sl = (slice(y0, y1), slice(x0, x1))
    if name == "depth":
        return ~(buf.depth[sl] >= _MIN_DEPTH32)
    if name == "coc":
        d = buf.depth[sl]
        return (d < _MISS32) & ~(np.abs(buf.coc_model.coc(d)) <= COC_MAX)
    if name == "color":
        c = buf.color[sl]
        ok = (np.abs(c) <= _COLOR_MAX32) if allow_negative else (c >= 0) & (c <= _COLOR_MAX32)
        return ~ok.all(-1)
    if name == "motion":
        return ~(np.abs(buf.motion[sl]) <= _MOTION_MAX32).all(-1)
    if name == "time":
        t = buf.time[sl]
        return ~((t >= 0) & (t <= 1))
    if name == "lens":
        r2 = (buf.lens[sl].astype(np.float64) ** 2).sum(-1)
        return ~(r2 <= _LENS_LIMIT)
    h, w, _ = buf.depth.shape
    px = np.arange(w, dtype=np.float32)[x0:x1][None, :, None]
    py = np.arange(h, dtype=np.float32)[y0:y1][:, None, None]
    pos = buf.position[sl]
    x, y = pos[..., 0], pos[..., 1]
    tol = POSITION_TOLERANCE
    return ~((x >= px - tol) & (x <= px + 1 + tol) & (y >= py - tol) & (y <= py + 1 + tol))


def _check_values(buf: SampleBuffer, allow_negative: bool = False) -> None:
    """The value rules of :meth:`SampleBuffer.validate` (layout already checked), then the
    model's coefficients, then the CoC rule.

    Filters, per block, each exact or conservative (a block that holds a bad sample always
    fails; a good block fails only within a rounding margin of a bound):

    * depth ``min >= MIN_DEPTH``; coc ``min >= coc_min_depth(c0, c1)`` (exact for the base
      model; any other model's CoC is checked sample by sample); time ``min >= 0 and
      max <= 1``; color ``min >= 0 (or -COLOR_MAX) and max <= COLOR_MAX``; motion
      ``min >= -MOTION_MAX and max <= MOTION_MAX``: exact (NaN propagates through min and
      max and fails every comparison).
    * lens: float32 ``u*u + v*v`` (two roundings, relative error < 2**-22) against a float32
      limit 2**-22 below the float64 one; NaN and overflow fail.
    * position: ``d = position - lower`` in float32 has the sign of the exact difference
      (gradual underflow), so ``min(d) >= 0`` is the lower bound exactly; ``max(d) <= W``,
      with ``W`` 2**-22 below the narrowest pixel's ``upper - lower``, implies the upper.
    """
    h, w, s = buf.depth.shape
    model = buf.coc_model
    model_error = coc_model_error(model)
    if model_error is not None:
        coc_lo = np.float32(0)  # not checked: the coefficients are reported first
    elif type(model) is CocModel:
        coc_lo = coc_min_depth(float(model.c0), float(model.c1))
    else:  # another model's CoC need not be monotonic: every block is checked exactly
        coc_lo = np.float32(np.inf)
    color_lo = -_COLOR_MAX32 if allow_negative else np.float32(0)
    blocks = _blocks(h, w, s)
    lo_x, hi_x = _pixel_bounds(w)
    lo_y, hi_y = _pixel_bounds(h)
    width = min(float(np.min(hi_x.astype(np.float64) - lo_x)),
                float(np.min(hi_y.astype(np.float64) - lo_y)))
    w_safe = _f32_below(width * (1 - 2.0**-22))
    lens_safe = _f32_below(_LENS_LIMIT * (1 - 2.0**-22))
    y0, y1, x0, x1 = blocks[0]
    cols = x1 - x0
    n = (y1 - y0) * cols * s
    sq = np.empty(2 * n, np.float32)
    r2 = np.empty(n, np.float32)
    # lower x bound of every position value of a row of the block (0 under y); the y bound
    # is subtracted row by row after
    lower = np.zeros((cols, s, 2), np.float32)
    lower[..., 0] = lo_x[:cols, None]
    partial = cols < w  # blocks are runs of pixels of one row: lower is refilled per block
    suspect: dict[str, list] = {name: [] for name in RULE_NAMES}
    for blk in blocks:
        y0, y1, x0, x1 = blk
        m = (y1 - y0) * (x1 - x0) * s
        dmin = buf.depth[y0:y1, x0:x1].min()
        if not dmin >= _MIN_DEPTH32:
            suspect["depth"].append(blk)
        if not dmin >= coc_lo:
            suspect["coc"].append(blk)
        c = buf.color[y0:y1, x0:x1]
        if not (c.min() >= color_lo and c.max() <= _COLOR_MAX32):
            suspect["color"].append(blk)
        mo = buf.motion[y0:y1, x0:x1]
        if not (mo.min() >= -_MOTION_MAX32 and mo.max() <= _MOTION_MAX32):
            suspect["motion"].append(blk)
        t = buf.time[y0:y1, x0:x1]
        if not (t.min() >= 0 and t.max() <= 1):
            suspect["time"].append(blk)
        lens = buf.lens[y0:y1, x0:x1].reshape(-1)
        q = np.multiply(lens, lens, out=sq[:2 * m]).reshape(m, 2)
        if not np.add(q[:, 0], q[:, 1], out=r2[:m]).max() <= lens_safe:
            suspect["lens"].append(blk)
        rows, k = y1 - y0, x1 - x0
        if partial:
            lower[:k, :, 0] = lo_x[x0:x1, None]
        pos = buf.position[y0:y1, x0:x1].reshape(rows, k * s * 2)
        diff = np.subtract(pos, lower[:k].reshape(-1), out=sq[:2 * m].reshape(rows, -1))
        ydiff = diff.reshape(rows, k * s, 2)[:, :, 1]
        np.subtract(ydiff, lo_y[y0:y1, None], out=ydiff)
        if not (diff.min() >= 0 and diff.max() <= w_safe):
            suspect["position"].append(blk)
    for name in RULE_NAMES:
        if name == "coc" and model_error is not None:
            raise ValueError(model_error)
        count, first = 0, None
        for blk in suspect[name]:
            bad = _exact_bad(buf, name, blk, allow_negative)
            c = int(np.count_nonzero(bad))
            if c and first is None:
                dy, dx, i = (int(v) for v in np.argwhere(bad)[0])
                first = (blk[0] + dy, blk[2] + dx, i)
            count += c
        if count:
            field_name = "depth" if name == "coc" else name
            value = getattr(buf, field_name)[first].tolist()
            raise ValueError(bad_sample_message(name, first, count, value, allow_negative,
                                                model))


def _inspect_arrays(buf: SampleBuffer) -> FrameInfo:
    """:meth:`SampleBuffer.inspect` by whole-array formulas (any frame, any layout)."""
    hit = buf.depth < MISS_DEPTH
    # misses keep their lens term: coc(inf) = C1 (the background is defocused too)
    coc = np.abs(buf.coc())
    hit_depth = buf.depth[hit] if hit.any() else np.array([np.inf], np.float32)
    motion = np.sqrt((buf.motion.astype(np.float64) ** 2).sum(-1))
    return FrameInfo(
        width=buf.width,
        height=buf.height,
        spp=buf.spp,
        max_abs_coc=float(coc.max(initial=0.0)),
        max_abs_motion=float(motion.max(initial=0.0)),
        min_depth=float(hit_depth.min()),
        max_depth=float(hit_depth.max()),
        miss_fraction=float(1.0 - hit.mean()),
    )


def _motion_r2(motion: np.ndarray) -> np.ndarray:
    """Squared motion length of each sample in float64, as :func:`_inspect_arrays`."""
    return (motion.astype(np.float64) ** 2).sum(-1)


def _inspect_blocks(buf: SampleBuffer) -> FrameInfo | None:
    """:meth:`SampleBuffer.inspect` from per-block scalars; ``None`` where it does not
    apply (then :func:`_inspect_arrays`). Every value equals the whole-array formula's:

    * depth (all > 0, none NaN): hits are ``d < float32(MISS_DEPTH)``, counted; the hit
      minimum is the overall minimum when there is a hit; the hit maximum is the maximum of
      the bit patterns less ``bits(MISS_DEPTH)`` modulo 2**32 (hits wrap to the top).
    * coc: ``coc(d)`` is monotonic in ``d`` (every rounding step is), so ``max |coc|`` is
      reached at the smallest or the largest depth: two evaluations of the same formula.
    * motion: float32 ``mx*mx + my*my`` per sample is within a factor (1 +- 2**-23) of the
      float64 value, so the longest vector lies in a block whose float32 maximum is within
      1e-6 of the overall one; only those blocks are evaluated in float64 (sqrt is
      monotonic: max of sqrt = sqrt of max).
    """
    depth, motion, model = buf.depth, buf.motion, buf.coc_model
    for arr in (depth, motion):
        if not (isinstance(arr, np.ndarray) and arr.dtype == np.float32
                and arr.flags.c_contiguous):
            return None
    if depth.ndim != 3 or min(depth.shape) < 1 or motion.shape != depth.shape + (2,):
        return None
    if type(model) is not CocModel or not (np.isfinite(model.c0) and np.isfinite(model.c1)):
        return None
    h, w, s = depth.shape
    blocks = _blocks(h, w, s)
    y0, y1, x0, x1 = blocks[0]
    n = (y1 - y0) * (x1 - x0) * s
    miss = np.float32(MISS_DEPTH)
    miss_bits = np.uint32(miss.view(np.uint32))
    sq = np.empty(2 * n, np.float32)
    r2 = np.empty(n, np.float32)
    wrapped = np.empty(n, np.uint32)
    flags = np.empty(n, np.bool_)
    lo = np.float32(np.inf)
    hi = np.float32(-np.inf)
    hit_top = None  # largest wrapped hit bit pattern
    hits = 0
    block_r2 = []
    for y0, y1, x0, x1 in blocks:
        m = (y1 - y0) * (x1 - x0) * s
        d = depth[y0:y1, x0:x1].reshape(-1)
        dmin = d.min()
        if not dmin > 0:  # not validated: zero, negative or NaN depths
            return None
        dmax = d.max()
        lo, hi = min(lo, dmin), max(hi, dmax)
        if dmax < miss:
            h_top = (int(dmax.view(np.uint32)) - int(miss_bits)) % 2**32
            hits += m
        else:
            nmiss = int(np.count_nonzero(np.greater_equal(d, miss, out=flags[:m])))
            hits += m - nmiss
            h_top = (int(np.subtract(d.view(np.uint32), miss_bits, out=wrapped[:m]).max())
                     if nmiss < m else None)
        if h_top is not None and (hit_top is None or h_top > hit_top):
            hit_top = h_top
        mo = motion[y0:y1, x0:x1].reshape(-1)
        q = np.multiply(mo, mo, out=sq[:2 * m]).reshape(m, 2)
        block_r2.append(float(np.add(q[:, 0], q[:, 1], out=r2[:m]).max()))
    top = float(np.max(block_r2))  # NaN propagates
    if not np.isfinite(top):  # NaN or float32 overflow: evaluate every sample
        r2max = float(_motion_r2(motion).max(initial=0.0))
    elif top >= 1e-30:
        r2max = max(float(_motion_r2(motion[b[0]:b[1], b[2]:b[3]]).max())
                    for b, v in zip(blocks, block_r2) if v >= top * (1 - 1e-6))
    elif motion.min() == 0 and motion.max() == 0:  # no motion at all
        r2max = 0.0
    else:  # float32 squares underflow: evaluate every sample
        r2max = float(_motion_r2(motion).max(initial=0.0))
    coc = np.abs(model.coc(np.array([lo, hi], np.float32)))
    if hits:
        hit_max = np.array((hit_top + int(miss_bits)) % 2**32, np.uint32).view(np.float32)
        min_depth, max_depth = float(lo), float(hit_max)
    else:
        min_depth = max_depth = float(np.inf)
    return FrameInfo(
        width=w,
        height=h,
        spp=s,
        max_abs_coc=float(coc.max(initial=0.0)),
        max_abs_motion=float(np.sqrt(np.float64(r2max))),
        min_depth=min_depth,
        max_depth=max_depth,
        miss_fraction=float(1.0 - np.float64(hits) / (h * w * s)),
    )
