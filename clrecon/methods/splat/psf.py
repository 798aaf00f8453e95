"""PSF models of method ``splat`` (Leimkühler et al. 2018, section 5.1) and their sample
spaces (power remapping + nested grid, section 5.2). Pure NumPy, no OpenCL.

A PSF is a dense float64 image of odd size ``(2 * ry + 1, 2 * rx + 1)`` whose centre pixel is
the pixel containing the point's (re-centred) sensor position; it sums to 1 (unit energy).
Pixel values are the pixel-area integral of the continuous PSF (supersampled).

Models (parameters in pixels):

* :class:`SimpleLens`: ``(r,)``, a disc of CoC radius ``r`` (thin lens, section 5.1).
* :class:`Combined`: ``(r, l)``, the disc swept uniformly along a segment of length ``l``
  centred on the point in the reference direction +x (linear motion over the shutter);
  rotated at run time to the motion direction.
* :class:`Stylized`: ``(r,)``, an aperture shape (a regular hexagon of circumradius ``r``).
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import numpy as np


def _tri(level: int) -> int:
    return level * (level + 1) // 2


@dataclass(frozen=True)
class NestedGrid:
    """Cells of a 1D regular grid or a 2D nested grid over integer grid coordinates
    ``[0, n0) x [0, n1)`` (section 5.2, Fig. 5).

    In 2D, level ``l`` holds the points whose smaller coordinate lies in
    ``[T(l), T(l + 1))`` (``T`` the triangular numbers) and tiles that L-shaped strip with
    cells of edge ``l + 1``: first the arm along axis 1 (``g0`` in the level's band), then
    the arm along axis 0. Cells at the far end are cut by the grid's extent (not cubic).
    The forward map :meth:`index` is O(1): level from the triangular root of ``min(g)``.
    """

    n: tuple[int, ...]

    def __post_init__(self):
        if len(self.n) not in (1, 2) or min(self.n) < 1:
            raise ValueError(f"n: one or two positive extents, got {self.n}")

    def levels(self) -> list[tuple[int, int, int, int]]:
        """Per 2D level: ``(first cell index, cells in the axis-1 arm, cells in the axis-0
        arm, edge)``."""
        n0, n1 = self.n
        out, first, lev = [], 0, 0
        while _tri(lev) < min(n0, n1):
            t, e = _tri(lev), lev + 1
            cv = -(-(n1 - t) // e)
            ch = -(-max(0, n0 - t - e) // e)
            out.append((first, cv, ch, e))
            first += cv + ch
            lev += 1
        return out

    def boxes(self) -> np.ndarray:
        """Every cell's box in grid coordinates, ``(cells, ndim, 2)`` (lo, hi); computed once
        per grid (every new frame's plan asks for it: ~18 ms a call at 1280x720), read-only."""
        return _grid_boxes(self)

    def _boxes(self) -> np.ndarray:
        if len(self.n) == 1:
            k = np.arange(self.n[0], dtype=np.float64)
            return np.stack([k, k + 1], -1)[:, None, :]
        n0, n1 = self.n
        out = []
        for lev, (_, cv, ch, e) in enumerate(self.levels()):
            t = _tri(lev)
            for k in range(cv):
                out.append([[t, min(t + e, n0)], [t + k * e, min(t + (k + 1) * e, n1)]])
            for k in range(ch):
                out.append([[t + e + k * e, min(t + e + (k + 1) * e, n0)], [t, min(t + e, n1)]])
        return np.asarray(out, np.float64)

    def index(self, g) -> np.ndarray:
        """Cell index of grid coordinates ``g`` (..., ndim), clamped into the grid."""
        g = np.asarray(g, np.float64)
        if len(self.n) == 1:
            return np.clip(np.floor(g[..., 0]), 0, self.n[0] - 1).astype(np.int64)
        n0, n1 = self.n
        g0 = np.clip(g[..., 0], 0, n0 - 1e-9)
        g1 = np.clip(g[..., 1], 0, n1 - 1e-9)
        m = np.minimum(g0, g1)
        lev = np.floor((np.sqrt(8 * m + 1) - 1) / 2).astype(np.int64)
        table = np.asarray(self.levels(), np.int64)
        lev = np.clip(lev, 0, len(table) - 1)
        t = lev * (lev + 1) // 2
        first, cv, _, e = (table[lev, j] for j in range(4))
        in_v = g0 < t + e
        iv = np.floor((g1 - t) / e).astype(np.int64)
        ih = cv + np.floor((g0 - t - e) / e).astype(np.int64)
        return first + np.where(in_v, iv, ih)

    @property
    def cells(self) -> int:
        if len(self.n) == 1:
            return self.n[0]
        lv = self.levels()
        return lv[-1][0] + lv[-1][1] + lv[-1][2]


@cache
def _grid_boxes(grid: NestedGrid) -> np.ndarray:
    b = grid._boxes()
    b.flags.writeable = False
    return b


@dataclass(frozen=True)
class PsfModel:
    """Base of the PSF models: parameter ranges, power remapping and the nested grid.

    Grid coordinate of parameter ``s`` (pixels) along axis ``d``:
    ``g = n[d] * (min(s / smax[d], 1)) ** (1 / beta[d])``; ``beta > 1`` gives small
    parameters (near focus, slow motion) more cells.
    """

    name = ""
    smax: tuple[float, ...] = ()
    beta: tuple[float, ...] = ()
    n: tuple[int, ...] = ()

    @property
    def grid(self) -> NestedGrid:
        return NestedGrid(tuple(self.n))

    def to_grid(self, s) -> np.ndarray:
        s = np.asarray(s, np.float64)
        x = np.clip(s / np.asarray(self.smax), 0.0, 1.0)
        return np.asarray(self.n) * x ** (1.0 / np.asarray(self.beta))

    def from_grid(self, g) -> np.ndarray:
        g = np.asarray(g, np.float64)
        return np.asarray(self.smax) * (g / np.asarray(self.n)) ** np.asarray(self.beta)

    def from_grid_axis(self, g, d: int) -> np.ndarray:
        """:meth:`from_grid` along axis ``d`` only."""
        return self.smax[d] * (np.asarray(g, np.float64) / self.n[d]) ** self.beta[d]

    def cell_of(self, s) -> np.ndarray:
        """Index of the cell (pre-computed PSF) for parameters ``s`` (..., ndim)."""
        return self.grid.index(self.to_grid(s))

    def extent(self, s) -> tuple[int, int]:
        """Half sizes ``(ry, rx)`` of the image holding the PSF of ``s``."""
        raise NotImplementedError

    def coverage(self, s, x, y) -> np.ndarray:
        """The continuous PSF (unnormalised, >= 0) at offsets ``x, y`` from the point."""
        raise NotImplementedError

    def dense(self, samples, ss: int = 4) -> np.ndarray:
        """Unit-energy PSF image averaged over parameter samples ``(k, ndim)``: with one row,
        the PSF of those parameters; with many, the pre-filtered PSF of a cell (section 5.4).
        ``ss``: supersamples per pixel and axis."""
        samples = np.atleast_2d(np.asarray(samples, np.float64))
        ry, rx = np.max([self.extent(s) for s in samples], axis=0)
        off = (np.arange(ss) + 0.5) / ss - 0.5
        ys = (np.arange(-ry, ry + 1)[:, None] + off[None, :]).ravel()
        xs = (np.arange(-rx, rx + 1)[:, None] + off[None, :]).ravel()
        acc = np.zeros((2 * ry + 1, 2 * rx + 1))
        for s in samples:
            c = self.coverage(s, xs[None, :], ys[:, None])
            c = c.reshape(2 * ry + 1, ss, 2 * rx + 1, ss).sum(axis=(1, 3))
            tot = c.sum()
            if tot <= 0:  # below the supersampling: all energy in the centre pixel
                c = np.zeros_like(c)
                c[ry, rx] = 1.0
                tot = 1.0
            acc += c / tot
        return acc / len(samples)


def _disc(r, x, y):
    # a disc never thinner than half a pixel, so r = 0 is the centre pixel's delta
    r = max(float(r), 0.5)
    return (x * x + y * y <= r * r).astype(np.float64)


@dataclass(frozen=True)
class SimpleLens(PsfModel):
    """Thin-lens defocus: a uniform disc of CoC radius ``r``."""

    name = "simplelens"
    smax: tuple[float, ...] = (128.0,)
    beta: tuple[float, ...] = (2.0,)
    n: tuple[int, ...] = (64,)

    def extent(self, s):
        r = int(np.ceil(max(float(s[0]), 0.5))) + 1
        return r, r

    def coverage(self, s, x, y):
        return _disc(s[0], x, y)


@dataclass(frozen=True)
class Combined(PsfModel):
    """Defocus and linear motion: the disc of radius ``r`` swept uniformly along
    ``[-l/2, l/2] x {0}`` (reference direction +x)."""

    name = "combined"
    smax: tuple[float, ...] = (96.0, 192.0)
    # beta 2 on motion too (paper: 1.0): static and slow pixels then get cells < 0.5 px wide
    # instead of being pre-filtered over 8 px of motion
    beta: tuple[float, ...] = (2.0, 2.0)
    n: tuple[int, ...] = (32, 40)

    def extent(self, s):
        r = max(float(s[0]), 0.5)
        return int(np.ceil(r)) + 1, int(np.ceil(r + 0.5 * float(s[1]))) + 1

    def coverage(self, s, x, y):
        r, length = max(float(s[0]), 0.5), float(s[1])
        if length < 1e-6:
            return _disc(r, x, y)
        half = np.sqrt(np.maximum(r * r - y * y, 0.0))
        # time the swept disc covers (x, y): overlap of [x - half, x + half] and the segment
        lo = np.maximum(x - half, -0.5 * length)
        hi = np.minimum(x + half, 0.5 * length)
        return np.where(r * r >= y * y, np.maximum(hi - lo, 0.0), 0.0) / length


@dataclass(frozen=True)
class Stylized(PsfModel):
    """A stylized aperture: a regular hexagon of circumradius ``r`` (flat sides up/down)."""

    name = "stylized"
    smax: tuple[float, ...] = (128.0,)
    beta: tuple[float, ...] = (1.5,)
    n: tuple[int, ...] = (64,)

    def extent(self, s):
        r = int(np.ceil(max(float(s[0]), 0.5))) + 1
        return r, r

    def coverage(self, s, x, y):
        r = max(float(s[0]), 0.5)
        ax, ay = np.abs(x), np.abs(y)
        h = r * np.sqrt(3.0) / 2.0
        return ((ay <= h) & (np.sqrt(3.0) * ax + ay <= np.sqrt(3.0) * r)).astype(np.float64)


MODELS = {m.name: m for m in (SimpleLens, Combined, Stylized)}


def get_model(name: str) -> PsfModel:
    try:
        return MODELS[name]()
    except KeyError:
        raise ValueError(f"psf: unknown model {name!r}; available: {sorted(MODELS)}") from None
