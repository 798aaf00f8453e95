"""Pre-computation of method ``splat`` (Leimkühler et al. 2018, section 5): for every cell of
a PSF model's nested grid, the pre-filtered PSF, its 3x3 (5-point) Laplacian and a sparse set
of "spreadlets" (integer offsets and values) whose integral approximates the PSF.

Sparsification (section 5.5), per cell:

1. dart throwing with importance ``|Laplacian|``: candidates drawn with probability
   proportional to ``|L|``; a candidate is rejected when an accepted point lies closer than
   its radius ``spacing * sqrt(max|L| / |L(x)|)`` (clamped to [1, 16] px; spacing 0.5 by
   default: at 1.0 the two signs of an edge fall into one Voronoi cell and cancel); stop after
   ``failures`` consecutive rejections (paper: 10,000);
2. ``lloyd`` steps of ``|L|``-weighted Lloyd relaxation (paper: 50);
3. Voronoi sums: each point takes the sum of ``L`` over its Voronoi cell (so the values sum to
   ``sum(L) = 0`` like the Laplacian itself);
4. ``anneal`` steps of simulated annealing (paper: 400): move 1% of the points by at most one
   pixel, re-assign the Voronoi sums, keep the move when the L1 error of the integrated
   approximation against the PSF drops (or, early on, with a Boltzmann probability);
5. merge points that share a pixel;
6. (not in the paper) the values of steps 3-5 are corrected so that the moments of order 0-2
   equal the Laplacian's: every PSF keeps its energy exactly (:func:`match_moments`);
   annealing judges the corrected values.

The integration inside the optimisation is the exact inverse of the 5-point Laplacian by FFT
(:func:`poisson_fft`). Tables (:class:`PsfTable`) are saved as ``.npz``.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Optional

import numpy as np

from clrecon.methods.splat.psf import PsfModel, get_model

Progress = Optional[Callable[[int, int], None]]


def laplacian5(f: np.ndarray) -> np.ndarray:
    """The 5-point Laplacian of ``f`` with zero outside (same shape)."""
    p = np.pad(f, 1)
    return p[:-2, 1:-1] + p[2:, 1:-1] + p[1:-1, :-2] + p[1:-1, 2:] - 4.0 * f


def poisson_fft(lap: np.ndarray, pad: int = 8) -> np.ndarray:
    """Solve ``laplacian5(u) = lap`` on a periodic domain padded by ``pad`` zeros, anchored so
    that the outermost ring of the padded domain is 0 on average; returns ``u`` cropped to
    ``lap``'s shape. Exact (to rounding) when ``lap`` is the Laplacian of an image that is zero
    on its border."""
    p = np.pad(np.asarray(lap, np.float64), pad)
    h, w = p.shape
    ky = 2.0 * np.cos(2.0 * np.pi * np.arange(h) / h)[:, None]
    kx = 2.0 * np.cos(2.0 * np.pi * np.arange(w // 2 + 1) / w)[None, :]
    lam = kx + ky - 4.0
    lam[0, 0] = 1.0
    spec = np.fft.rfft2(p) / lam
    spec[0, 0] = 0.0
    u = np.fft.irfft2(spec, s=p.shape)
    ring = np.concatenate([u[0], u[-1], u[1:-1, 0], u[1:-1, -1]])
    u -= ring.mean()
    return u[pad:h - pad, pad:w - pad] if pad else u


def splat_points(shape, pts: np.ndarray, vals: np.ndarray) -> np.ndarray:
    """Add ``vals`` at integer ``pts`` (k, 2) as (y, x) into a zero image of ``shape``."""
    img = np.zeros(shape)
    np.add.at(img, (pts[:, 0], pts[:, 1]), vals)
    return img


@dataclass(frozen=True)
class SparsifyOptions:
    """Knobs of the sparsification (paper defaults; see the module docstring)."""

    failures: int = 10_000
    lloyd: int = 50
    anneal: int = 400
    spacing: float = 0.5
    move_fraction: float = 0.01
    seed: int = 0


def _voronoi(points: np.ndarray, pix: np.ndarray, lap_vals: np.ndarray):
    from scipy.spatial import cKDTree  # build-time only (scipy ships with the eval extra)

    _, lab = cKDTree(points).query(pix)
    return lab, np.bincount(lab, weights=lap_vals, minlength=len(points))


def dart_throw(w: np.ndarray, rng, failures: int, spacing: float) -> np.ndarray:
    """Importance-driven dart throwing on ``w = |L|``: integer (y, x) points."""
    ys, xs = np.nonzero(w)
    if len(ys) == 0:
        return np.zeros((0, 2), np.int64)
    wv = w[ys, xs]
    prob = wv / wv.sum()
    rad = np.clip(spacing * np.sqrt(wv.max() / wv), 1.0, 16.0)
    occ = np.zeros((w.shape[0] + 34, w.shape[1] + 34), bool)  # 17-px guard on each side
    acc, fails = [], 0
    while fails < failures:
        for k in rng.choice(len(ys), size=4096, p=prob):
            y, x, r = ys[k] + 17, xs[k] + 17, rad[k]
            ri = int(r)
            win = occ[y - ri:y + ri + 1, x - ri:x + ri + 1]
            if win.any():
                oy, ox = np.nonzero(win)
                if np.any((oy - ri) ** 2 + (ox - ri) ** 2 < r * r):
                    fails += 1
                    if fails >= failures:
                        break
                    continue
            occ[y, x] = True
            acc.append((ys[k], xs[k]))
            fails = 0
    return np.asarray(acc, np.int64)


def sparsify(f: np.ndarray, opts: SparsifyOptions = SparsifyOptions()):
    """Spreadlets of the dense PSF ``f`` (zero border of >= 1 px assumed).

    Returns ``(points (k, 2) int (y, x) in f's frame, values (k,), l1_error)``; the error is
    the L1 distance of the integrated spreadlets to ``f`` (``f`` sums to 1).
    """
    rng = np.random.default_rng(opts.seed)
    lap = laplacian5(f)
    w = np.abs(lap)
    w[w < 1e-9 * max(w.max(), 1e-300)] = 0.0
    pix = np.argwhere(w > 0)
    if len(pix) == 0:
        return np.zeros((0, 2), np.int64), np.zeros(0), 0.0
    lv, wv = lap[pix[:, 0], pix[:, 1]], w[pix[:, 0], pix[:, 1]]
    pts = dart_throw(w, rng, opts.failures, opts.spacing).astype(np.float64)
    for _ in range(opts.lloyd):
        lab, _ = _voronoi(pts, pix, lv)
        mass = np.bincount(lab, weights=wv, minlength=len(pts))
        cy = np.bincount(lab, weights=wv * pix[:, 0], minlength=len(pts))
        cx = np.bincount(lab, weights=wv * pix[:, 1], minlength=len(pts))
        ok = mass > 0
        pts[ok] = np.stack([cy[ok], cx[ok]], -1) / mass[ok, None]
    pts = np.unique(np.rint(pts).astype(np.int64), axis=0)

    def values(p):  # Voronoi sums, moment-matched: what the table will hold
        return match_moments(p, _voronoi(p, pix, lv)[1], pix, lv)

    vals = values(pts)

    def cost(p, v):
        return float(np.abs(poisson_fft(splat_points(f.shape, p, v)) - f).sum())

    best = cost(pts, vals)
    t0 = 0.02 * best
    lo, hi = np.zeros(2, np.int64), np.asarray(f.shape, np.int64) - 1
    for step in range(opts.anneal):
        k = max(1, int(round(opts.move_fraction * len(pts))))
        idx = rng.choice(len(pts), size=min(k, len(pts)), replace=False)
        cand = pts.copy()
        cand[idx] = np.clip(cand[idx] + rng.integers(-1, 2, (len(idx), 2)), lo, hi)
        cvals = values(cand)
        c = cost(cand, cvals)
        temp = t0 * (1.0 - step / opts.anneal)
        if c < best or (temp > 0 and rng.random() < np.exp(-(c - best) / temp)):
            pts, vals, best = cand, cvals, c
    # merge coincident points
    uniq, inv = np.unique(pts, axis=0, return_inverse=True)
    vals = np.bincount(inv.ravel(), weights=vals, minlength=len(uniq))
    keep = vals != 0
    pts, vals = uniq[keep], vals[keep]
    vals = match_moments(pts, vals, pix, lv)
    return pts, vals, cost(pts, vals)


def _moments(pts: np.ndarray) -> np.ndarray:
    y, x = pts[:, 0].astype(np.float64), pts[:, 1].astype(np.float64)
    return np.stack([np.ones_like(x), x, y, x * x, y * y, x * y])


def match_moments(pts: np.ndarray, vals: np.ndarray, lap_pts: np.ndarray,
                  lap_vals: np.ndarray) -> np.ndarray:
    """Correct spreadlet values (least change, relative to |value|) so that their moments
    of order 0-2 equal the Laplacian's. The second moments carry the PSF's energy
    (``sum |x|^2 lap = 4 sum f`` for the 5-point Laplacian) and its far field: without this,
    every PSF of a cell gains or loses the same few percent of energy and the errors add up
    over large regions to low-frequency colour shifts."""
    if len(pts) < 6:
        return vals
    centre = lap_pts.mean(0)  # moments about a nearby point keep the system well scaled
    a = _moments(pts - centre)
    b = _moments(lap_pts - centre) @ lap_vals
    w = np.abs(vals) + 1e-3 * np.abs(vals).max()
    aw = a * w
    try:
        lam = np.linalg.solve(aw @ a.T, a @ vals - b)
    except np.linalg.LinAlgError:
        return vals
    return vals - aw.T @ lam


def cell_params(model: PsfModel, box: np.ndarray, max_per_dim: int = 4) -> np.ndarray:
    """Parameter samples (k, ndim) spread over a cell's box (grid coordinates) for
    pre-filtering: midpoints of a regular subdivision, about one per pixel of parameter
    range, at most ``max_per_dim`` per axis."""
    axes = []
    for d in range(box.shape[0]):
        lo, hi = box[d]
        span_px = float(model.from_grid_axis(hi, d) - model.from_grid_axis(lo, d))
        q = int(np.clip(np.ceil(span_px), 1, max_per_dim))
        g = lo + (np.arange(q) + 0.5) / q * (hi - lo)
        axes.append(model.from_grid_axis(g, d))
    mesh = np.meshgrid(*axes, indexing="ij")
    return np.stack([m.ravel() for m in mesh], -1)


@dataclass
class PsfTable:
    """Spreadlets of every cell of a model, concatenated (section 6.1).

    Points are (x, y) offsets from the PSF centre (int16), the PSF's reference direction
    +x. Cell ``i`` owns ``points[offsets[i]:offsets[i + 1]]``. ``dense_*`` hold the dense
    pre-filtered PSF of the cells whose dense form is small (the fast track; ``dense_offsets``
    has ``dense_offsets[i] == dense_offsets[i + 1]`` for the others: ``has_dense``).
    """

    model: str
    points: np.ndarray
    values: np.ndarray
    offsets: np.ndarray
    dense_points: np.ndarray
    dense_values: np.ndarray
    dense_offsets: np.ndarray
    has_dense: np.ndarray
    dense_sizes: np.ndarray  # nonzero pixels of every cell's dense PSF
    errors: np.ndarray  # L1 error of each cell's spreadlets
    meta: dict

    @property
    def cells(self) -> int:
        return len(self.offsets) - 1

    def counts(self) -> np.ndarray:
        return np.diff(self.offsets)

    def sparsity(self) -> np.ndarray:
        """Spreadlets per cell over the dense PSF's nonzero pixels."""
        return self.counts() / np.maximum(self.dense_sizes, 1)

    def max_radius(self) -> int:
        """Largest |offset| of any point, sparse or dense (the boundary padding)."""
        r = 0
        for p in (self.points, self.dense_points):
            if len(p):
                r = max(r, int(np.abs(p.astype(np.int64)).max()))
        return r

    def save(self, path) -> None:
        np.savez_compressed(
            path, model=self.model, points=self.points, values=self.values,
            offsets=self.offsets, dense_points=self.dense_points,
            dense_values=self.dense_values, dense_offsets=self.dense_offsets,
            has_dense=self.has_dense, dense_sizes=self.dense_sizes, errors=self.errors,
            meta_keys=np.asarray(list(self.meta.keys())),
            meta_vals=np.asarray([float(v) for v in self.meta.values()]))

    @classmethod
    def load(cls, path) -> PsfTable:
        with np.load(path) as z:
            meta = dict(zip(z["meta_keys"].tolist(), z["meta_vals"].tolist()))
            return cls(str(z["model"]), z["points"], z["values"], z["offsets"],
                       z["dense_points"], z["dense_values"], z["dense_offsets"],
                       z["has_dense"], z["dense_sizes"], z["errors"], meta)


def _to_xy(pts: np.ndarray, centre) -> np.ndarray:
    cy, cx = centre
    return np.stack([pts[:, 1] - cx, pts[:, 0] - cy], -1).astype(np.int16)


def build_table(model: PsfModel | str, opts: SparsifyOptions = SparsifyOptions(),
                dense_ratio: float = 4.0, progress: Progress = None) -> PsfTable:
    """Pre-compute every cell of ``model``; keep the dense PSF of cells whose dense form has
    at most ``dense_ratio`` times as many pixels as their spreadlets (fast-track candidates).
    """
    if isinstance(model, str):
        model = get_model(model)
    boxes = model.grid.boxes()
    pts_l, val_l, dp_l, dv_l, has, sizes, errs = [], [], [], [], [], [], []
    for i, box in enumerate(boxes):
        f = np.pad(model.dense(cell_params(model, box)), 2)
        centre = (f.shape[0] // 2, f.shape[1] // 2)
        p, v, err = sparsify(f, SparsifyOptions(**{**opts.__dict__, "seed": opts.seed + i}))
        pts_l.append(_to_xy(p, centre))
        val_l.append(v.astype(np.float32))
        nz = np.argwhere(f > 1e-7 * f.max())
        sizes.append(len(nz))
        keep = len(nz) <= dense_ratio * max(len(p), 1)
        has.append(keep)
        dp_l.append(_to_xy(nz, centre) if keep else np.zeros((0, 2), np.int16))
        dv_l.append(f[nz[:, 0], nz[:, 1]].astype(np.float32) if keep else np.zeros(0, np.float32))
        errs.append(err)
        if progress is not None:
            progress(i + 1, len(boxes))

    def cat(parts, shape, dtype):
        return np.concatenate(parts).astype(dtype) if parts else np.zeros(shape, dtype)

    def offs(parts):
        return np.concatenate([[0], np.cumsum([len(q) for q in parts])]).astype(np.int32)

    meta = {"failures": opts.failures, "lloyd": opts.lloyd, "anneal": opts.anneal,
            "spacing": opts.spacing, "dense_ratio": dense_ratio}
    return PsfTable(model.name, cat(pts_l, (0, 2), np.int16), cat(val_l, (0,), np.float32),
                    offs(pts_l), cat(dp_l, (0, 2), np.int16), cat(dv_l, (0,), np.float32),
                    offs(dp_l), np.asarray(has, bool), np.asarray(sizes, np.int64),
                    np.asarray(errs), meta)


def dense_table(model: PsfModel | str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The dense pre-filtered PSF of every cell as (points (x, y) int16, values, offsets):
    the input of the ``dense=True`` baseline (computed on demand, not shipped)."""
    if isinstance(model, str):
        model = get_model(model)
    pts, vals = [], []
    for box in model.grid.boxes():
        f = model.dense(cell_params(model, box))
        nz = np.argwhere(f > 1e-7 * f.max())
        pts.append(_to_xy(nz, (f.shape[0] // 2, f.shape[1] // 2)))
        vals.append(f[nz[:, 0], nz[:, 1]].astype(np.float32))
    offsets = np.concatenate([[0], np.cumsum([len(p) for p in pts])]).astype(np.int32)
    return np.concatenate(pts), np.concatenate(vals), offsets


DATA_DIR = Path(__file__).resolve().parent / "data"


def table_path(name: str) -> Path:
    return DATA_DIR / f"{name}.npz"
