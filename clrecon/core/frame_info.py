"""What a frame needs, from one look at it on the host: :class:`FrameInfo` and the scans
behind :meth:`SampleBuffer.inspect <clrecon.core.samples.SampleBuffer.inspect>`, plus the
block walk that :mod:`clrecon.core.validate` shares (re-exported by
:mod:`clrecon.core.samples`)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clrecon.core.camera import CocModel
from clrecon.core.limits import MISS_DEPTH


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


# Block scans of validate() and inspect().
#
# Both methods walk the frame in blocks of about BLOCK_SAMPLES samples (whole rows, or a run
# of pixels of one row, so that every block of every field is contiguous) and reduce each
# block to a few scalars with float32 temporaries that stay in cache. validate() uses the
# scalars as a filter that never passes a bad block: a block that fails it is checked again
# with the exact whole-array formulas, which give the messages (and float64 where the rule
# is float64). inspect() derives every FrameInfo value exactly from the block scalars.

#: samples per block (a few hundred kB per field; the temporaries fit in L2 / L3)
BLOCK_SAMPLES = 1 << 16


def scan_blocks(h: int, w: int, s: int) -> list[tuple[int, int, int, int]]:
    """``(y0, y1, x0, x1)`` blocks in C order, each contiguous in every field."""
    row = w * s
    if row <= BLOCK_SAMPLES:
        k = BLOCK_SAMPLES // row
        return [(y, min(h, y + k), 0, w) for y in range(0, h, k)]
    k = max(1, BLOCK_SAMPLES // s)
    return [(y, y + 1, x, min(w, x + k)) for y in range(h) for x in range(0, w, k)]


def inspect_arrays(buf) -> FrameInfo:
    """:meth:`SampleBuffer.inspect` of ``buf`` (a SampleBuffer) by whole-array formulas (any
    frame, any layout)."""
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
    """Squared motion length of each sample in float64, as :func:`inspect_arrays`."""
    return (motion.astype(np.float64) ** 2).sum(-1)


def inspect_blocks(buf) -> FrameInfo | None:
    """:meth:`SampleBuffer.inspect` of ``buf`` (a SampleBuffer) from per-block scalars;
    ``None`` where it does not apply (then :func:`inspect_arrays`). Every value equals the
    whole-array formula's:

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
    blocks = scan_blocks(h, w, s)
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
