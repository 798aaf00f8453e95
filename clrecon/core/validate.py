"""Value validation of a host frame (:meth:`SampleBuffer.validate
<clrecon.core.samples.SampleBuffer.validate>`): the rules, their messages (shared with the
device pass, :mod:`clrecon.core.inspect`) and the block scan that finds the first bad
sample. Re-exported by :mod:`clrecon.core.samples`."""
from __future__ import annotations

import functools

import numpy as np

from clrecon.core.camera import CocModel
from clrecon.core.frame_info import scan_blocks
from clrecon.core.limits import (
    C0_MAX,
    COC_MAX,
    COLOR_MAX,
    LENS_TOLERANCE,
    MIN_DEPTH,
    MISS_DEPTH,
    MOTION_MAX,
    POSITION_TOLERANCE,
)

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


def _f32_below(x: float) -> np.float32:
    """The largest float32 that is <= ``x`` (x finite and positive)."""
    f = np.float32(x)
    return f if float(f) <= x else np.nextafter(f, np.float32(0))


def _pixel_bounds(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper position bounds of pixels ``0..n-1`` exactly as the rule computes
    them (float32 arithmetic with the tolerance as a float32 scalar)."""
    p = np.arange(n, dtype=np.float32)
    return p - POSITION_TOLERANCE, p + 1 + POSITION_TOLERANCE


def _exact_bad(buf, name: str, blk: tuple[int, int, int, int],
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


def check_values(buf, allow_negative: bool = False) -> None:
    """The value rules of :meth:`SampleBuffer.validate` on ``buf`` (a SampleBuffer whose layout
    is checked), then the model's coefficients, then the CoC rule.

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
    blocks = scan_blocks(h, w, s)
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


