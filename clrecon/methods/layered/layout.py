"""Run-time layout of method ``layered``: what its passes are built and launched with.

The compile-time shape every layered kernel shares (:class:`Layout`, its ``-D`` defines), the
buffer layouts of ``kernels/layered.h``, the bucket function's coefficients, the MIP pyramid
and image atlas sizes and the reproject block cap. The NumPy reference
(:mod:`clrecon.methods.layered.reference`) imports this module; the passes never import the
reference.

Buffer layouts: ``stats`` (tiles, NBUCKETS, NSTAT); ``params`` (tiles, MAXP, NPAR);
``grids`` (tiles, MAXP, NCH, DMAX * DMAX) with row stride ``D`` of the slot; ``filtered``
(tiles, MAXP, NCH, FT * FT), FT = TILE + 2 (:attr:`Layout.filtered_side`). Only the used part
of a grid (the first ``D * D`` values of each plane) and of a filtered plane
(``(T/s + 2)^2`` values with row stride FT) is defined; the rest is unspecified on the
device (zero in the reference).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: statistics per (tile, bucket): count, sums of coc, coc^2, mx, my, mx^2, my^2, mx my
NSTAT = 8
#: parameters per (tile, slot), indexed by the ``P_*`` constants
NPAR = 20
#: channels of a grid or filtered plane: r, g, b, own weight, behind weight
NCH = 5
(P_COUNT, P_LO, P_HI, P_A, P_BX, P_BY, P_SU, P_SV, P_COS, P_SIN, P_SHU, P_SHV, P_BETA,
 P_GAMMA, P_SCALE, P_GUARD, P_REACH, P_DIM, P_AXIS) = range(19)


@dataclass(frozen=True)
class Layout:
    """Compile-time shape of the method: the ``-D`` defines every layered kernel shares."""

    tile: int = 32
    nbuckets: int = 32
    maxp: int = 4
    gmax: int = 16
    spp: int = 8
    has_motion: bool = True
    reach_max: int = 96

    @property
    def dmax(self) -> int:
        """Side of a slot's grid: the tile and its guard band on both sides."""
        return self.tile + 2 * self.gmax

    @property
    def filtered_side(self) -> int:
        """Side (and row stride) of a filtered plane: the tile and a one-texel ring (FT)."""
        return self.tile + 2

    def tiles(self, width: int, height: int) -> tuple[int, int]:
        return -(-width // self.tile), -(-height // self.tile)

    def defines(self) -> dict:
        return {"TILE": self.tile, "NBUCKETS": self.nbuckets, "MAXP": self.maxp,
                "GMAX": self.gmax, "SPP": self.spp, "HAS_MOTION": self.has_motion,
                "REACH_MAX": self.reach_max}


def bucket_params(c0: float, c1: float, zmin: float, zmax: float, nbuckets: int,
                  bucket_coc: float = 0.5, uniform: int = 8) -> tuple:
    """``(ka, kb, kc)`` of the bucket function of ``layered.h`` (float32): the bucket of depth
    ``w`` is ``floor(ka / w + kb w - kc)``, clamped to the hit buckets.

    ``L(w) = -|c0| / (bucket_coc w) + w / dz`` (dz = depth range / ``uniform``) grows with
    depth; buckets are unit steps of ``(L - L(zmin)) / f``, the stretch ``f >= 1`` chosen so
    the frame's hit depths fit the ``nbuckets - 1`` hit buckets.
    """
    ka0 = -abs(c0) / bucket_coc
    finite = np.isfinite(zmin) and np.isfinite(zmax) and zmax > zmin > 0
    kb0 = uniform / (zmax - zmin) if finite else 0.0
    if not (np.isfinite(zmin) and zmin > 0):
        zmin = zmax = 1.0

    def ell(w):
        return ka0 / w + kb0 * w

    span = ell(zmax) - ell(zmin)
    f = max(1.0, span / ((nbuckets - 1) * 0.999))
    return np.float32(ka0 / f), np.float32(kb0 / f), np.float32(ell(zmin) / f)


#: the default cap: a slot on a grid of spacing s reads one pixel per min(s, 8)^2 block
SUBSAMPLE_DEFAULT = 8
SUBSAMPLE_MAX = 64


def subsample_cap(subsample: int | bool) -> int:
    """The largest block side reproject reads as one pixel: an int in [1, 64] as given
    (default :data:`SUBSAMPLE_DEFAULT`), or ``False``: 1, every pixel (the documented
    ``--knob subsample=false``)."""
    if isinstance(subsample, (bool, np.bool_)):
        if not subsample:
            return 1
    elif isinstance(subsample, (int, np.integer)) and 1 <= subsample <= SUBSAMPLE_MAX:
        return int(subsample)
    raise ValueError(f"subsample: must be false or an int in [1, {SUBSAMPLE_MAX}] (default "
                     f"{SUBSAMPLE_DEFAULT}), got {subsample!r}")


def mip_levels(dmax: int) -> tuple[int, int]:
    """(levels including level 0, floats per channel plane of levels 1..) for a DMAX grid."""
    nlev, side, plane = 1, dmax, 0
    while side > 1:
        side = -(-side // 2)
        plane += side * side
        nlev += 1
    return nlev, max(plane, 1)


def mip_atlas(dmax: int, nlev: int, nslots: int, max_width: int) -> dict:
    """Layout of the image variant's atlas (kernels/filter_mip_image.cl): every slot a
    ``rw x rh`` region, ``per_row`` regions side by side; level boxes of side
    ``level side + 2`` (a zero ring): level 0 at (0, 0), level 1 right of it, level 2 right
    of level 1, levels 3.. below level 2. ``width x height`` is the whole atlas."""
    boxes = [-(-dmax // (1 << lv)) + 2 for lv in range(nlev)]
    rw = sum(boxes[:3])
    rh = max([boxes[0]] + ([boxes[1]] if nlev > 1 else []) + [sum(boxes[2:])])
    per_row = max(1, min(nslots, max_width // rw))
    rows = -(-nslots // per_row)
    return {"rw": rw, "rh": rh, "per_row": per_row, "width": per_row * rw,
            "height": rows * rh}
