"""Run-time PSF tables of method ``splat``: the shipped spreadlet tables (loaded once per
process), the dense tables of the ``dense=True`` baseline (computed on demand), the fast-track
choice and the device copies."""
from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import numpy as np
import pyopencl as cl

from clrecon.methods.splat.precompute import PsfTable, dense_table, table_path
from clrecon.methods.splat.psf import PsfModel, get_model


@cache
def load_table(name: str) -> PsfTable:
    """The shipped table of PSF model ``name`` (``clrecon psf build NAME`` writes it)."""
    path = table_path(name)
    if not path.exists():
        raise ValueError(f"psf: no table for {name!r} at {path}; run `clrecon psf build {name}`")
    return PsfTable.load(path)


@cache
def load_dense(name: str):
    """Dense pre-filtered PSFs of every cell of ``name`` (the ``dense=True`` baseline)."""
    return dense_table(get_model(name))


@dataclass
class HostTable:
    """What the ``splat`` kernel reads: two point lists and the per-cell fast-track flag."""

    model: PsfModel
    pts: np.ndarray
    vals: np.ndarray
    offs: np.ndarray
    dpts: np.ndarray
    dvals: np.ndarray
    doffs: np.ndarray
    fast: np.ndarray
    radius: np.ndarray  # per cell, the largest |offset| of the list it draws

    def as_tuple(self):
        return self.pts, self.vals, self.offs, self.dpts, self.dvals, self.doffs

    def reachable(self, info) -> np.ndarray:
        """Cells a frame can use: their box's lower corner lies within the frame's largest
        |CoC| (and |motion| for 2D models)."""
        smax = [info.max_abs_coc, info.max_abs_motion][:len(self.model.n)]
        lo = self.model.grid.boxes()[:, :, 0]
        return np.all(lo <= self.model.to_grid(smax)[None, :] + 1e-9, axis=1)


def _radius(pts: np.ndarray, offs: np.ndarray) -> np.ndarray:
    r = np.hypot(pts[:, 0].astype(np.float64), pts[:, 1].astype(np.float64))
    return np.array([r[a:b].max(initial=0.0) for a, b in zip(offs[:-1], offs[1:])])


@cache
def host_table(name: str, dense: bool, fast_ratio: float,
               max_error: float = float("inf")) -> HostTable:
    """Sparse spreadlets with the fast track, or everything dense.

    A cell goes on the fast track (drawn densely) when its dense PSF has at most
    ``fast_ratio`` times as many pixels as spreadlets, or when its spreadlets' L1 error
    (``PsfTable.errors``, measured at build time against the unit-energy PSF) exceeds
    ``max_error``: every sample of a frame that lands in such a cell repeats the same error
    pattern, so over a large uniform region (a defocused background) the errors add up to
    visible low-frequency blotches instead of averaging out.

    Computed once per set of arguments (each new frame's plan asks; the arrays are shared,
    read-only)."""
    model = get_model(name)
    if dense:
        dp, dv, do = load_dense(name)
        cells = len(do) - 1
        return HostTable(model, np.zeros((1, 2), np.int16), np.zeros(1, np.float32),
                         np.zeros(cells + 1, np.int32), dp, dv, do, np.ones(cells, np.uint8),
                         _radius(dp, do))
    t = load_table(name)
    nd, ns = np.diff(t.dense_offsets), np.diff(t.offsets)
    fast = t.has_dense & ((nd <= fast_ratio * ns) | (ns == 0) | (t.errors > max_error))
    rad = np.where(fast, _radius(t.dense_points, t.dense_offsets), _radius(t.points, t.offsets))
    fast = fast.astype(np.uint8)
    fast.flags.writeable = rad.flags.writeable = False
    return HostTable(model, t.points, t.values, t.offsets, t.dense_points, t.dense_values,
                     t.dense_offsets, fast, rad)


class DeviceTable:
    """Device copies of a :class:`HostTable` and its grid description."""

    def __init__(self, context: cl.Context, table: HostTable):
        ro = cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR

        def buf(a, dtype):
            a = np.ascontiguousarray(a, dtype)
            if a.size == 0:
                a = np.zeros(max(1, a.itemsize), dtype)
            return cl.Buffer(context, ro, hostbuf=a)

        m = table.model
        self.pts, self.vals = buf(table.pts, np.int16), buf(table.vals, np.float32)
        self.offs = buf(table.offs, np.int32)
        self.dpts, self.dvals = buf(table.dpts, np.int16), buf(table.dvals, np.float32)
        self.doffs, self.fast = buf(table.doffs, np.int32), buf(table.fast, np.uint8)
        levels = m.grid.levels() if len(m.n) == 2 else [(0, 0, 0, 1)]
        self.levels = buf(np.asarray(levels, np.int32).reshape(-1, 4), np.int32)
        self.nlev = len(levels)
        # 1D models repeat their one axis (the kernel ignores the second with NDIM == 1)
        self.gn = np.array((m.n[0], m.n[-1]), np.int32)
        self.gsmax = np.array((m.smax[0], m.smax[-1]), np.float32)
        self.ginvb = np.array((1.0 / m.beta[0], 1.0 / m.beta[-1]), np.float32)
