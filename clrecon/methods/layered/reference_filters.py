"""NumPy reference of the screen-space filters of method ``layered`` (passes
``filter_sheared``, ``filter_rotated``, ``filter_mip``): each slot's grid planes in, its
filtered planes out, in the layouts of :mod:`clrecon.methods.layered.layout`."""
from __future__ import annotations

import numpy as np

from clrecon.methods.layered.layout import (
    NCH,
    P_AXIS,
    P_BETA,
    P_COS,
    P_DIM,
    P_GUARD,
    P_SCALE,
    P_SHU,
    P_SHV,
    P_SIN,
    P_SU,
    P_SV,
    Layout,
    mip_levels,
)


def sampled_gauss_var(s: float) -> float:
    """Variance of exp(-k^2 / (2 s^2)) sampled at the integers (s^2 for s >= 2)."""
    if s >= 2:
        return s * s
    k = np.arange(1, 7)
    w = np.exp(-k * k / (2 * s * s))
    return float(2 * (k * k * w).sum() / (1 + 2 * w.sum()))


def recursive_gamma(v: float) -> float:
    """gamma with forward-backward variance 2 gamma / (1 - gamma)^2 = v (eq. 10 for v >> 1)."""
    return ((v + 1) - np.sqrt(2 * v + 1)) / v if v > 1e-6 else 0.0


def _planes(grids, t, k, dim, axis):
    """The used (NCH, dim, dim) planes of a slot, transposed for axis 1 (recursive along y)."""
    pl = grids[t, k, :, :dim * dim].reshape(NCH, dim, dim)
    return pl.transpose(0, 2, 1) if axis else pl


def filter_sheared_x(params, grids, recursions: int = 3):
    """Recursive filter along the slot's recursive axis, forward then backward."""
    out = grids.copy()
    for t, k in zip(*np.nonzero(params[..., P_DIM])):
        p = params[t, k]
        dim, axis = int(p[P_DIM]), int(p[P_AXIS])
        gm = recursive_gamma(sampled_gauss_var(p[P_SHU]) / recursions)
        rows = _planes(out, t, k, dim, axis).copy()  # (NCH, line, position along the line)
        for order in (range(dim), range(dim - 1, -1, -1)) * recursions:
            y = np.zeros((NCH, dim))
            for i in order:
                y = (1 - gm) * rows[:, :, i] + gm * y
                rows[:, :, i] = y
        if axis:
            rows = rows.transpose(0, 2, 1)
        out[t, k, :, :dim * dim] = rows.reshape(NCH, -1)
    return out


def _interp_row(row, xf):
    """Linear interpolation of (NCH, dim) rows at xf, zero outside."""
    dim = row.shape[-1]
    x = int(np.floor(xf))
    f = xf - x
    v = np.zeros(row.shape[0])
    if 0 <= x < dim:
        v += (1 - f) * row[:, x]
    if 0 <= x + 1 < dim:
        v += f * row[:, x + 1]
    return v


def filter_sheared_y(params, grids, layout: Layout):
    """Gaussian along the sheared axis, linear along the recursive one: (tiles, MAXP, NCH,
    FT * FT). Axis 1 is axis 0 on the transposed grid with i and j swapped."""
    stride = layout.filtered_side
    out = np.zeros(params.shape[:2] + (NCH, stride * stride))
    for t, k in zip(*np.nonzero(params[..., P_DIM])):
        p = params[t, k]
        dim, g, sv, beta = int(p[P_DIM]), int(p[P_GUARD]), p[P_SHV], p[P_BETA]
        axis = int(p[P_AXIS])
        side = layout.tile // int(p[P_SCALE])
        rows = _planes(grids, t, k, dim, axis)
        kmax = min(int(np.ceil(3 * sv)), dim)
        for j in range(-1, side + 1):
            for i in range(-1, side + 1):
                u, w = (j, i) if axis else (i, j)
                acc = np.zeros(NCH)
                for kk in range(-kmax, kmax + 1):
                    y = w + g + kk
                    if 0 <= y < dim:
                        wk = np.exp(-kk * kk / (2 * sv * sv))
                        acc += wk * _interp_row(rows[:, y, :], u + g + beta * kk)
                out[t, k, :, (j + 1) * stride + i + 1] = acc
    return out


def bilinear_at(planes, x, y):
    """Bilinear lookup of (NCH, dim, dim) planes at (x, y), zero outside."""
    dim = planes.shape[-1]
    ix, iy = int(np.floor(x)), int(np.floor(y))
    ax, ay = x - ix, y - iy
    v = np.zeros(planes.shape[0])
    for dx, dy, wt in ((0, 0, (1 - ax) * (1 - ay)), (1, 0, ax * (1 - ay)),
                       (0, 1, (1 - ax) * ay), (1, 1, ax * ay)):
        if 0 <= ix + dx < dim and 0 <= iy + dy < dim:
            v += wt * planes[:, iy + dy, ix + dx]
    return v


def filter_rotated(params, grids, layout: Layout):
    """LRDM: 1D Gaussians along u then v with bilinear taps: (tmp, filtered)."""
    stride = layout.filtered_side
    tmp = np.zeros_like(grids)
    out = np.zeros(params.shape[:2] + (NCH, stride * stride))
    for t, k in zip(*np.nonzero(params[..., P_DIM])):
        p = params[t, k]
        dim, s, g = int(p[P_DIM]), p[P_SCALE], p[P_GUARD]
        side = layout.tile // int(s)
        planes = grids[t, k, :, :dim * dim].reshape(NCH, dim, dim)
        su, sv, c, sn = p[P_SU] / s, p[P_SV] / s, p[P_COS], p[P_SIN]
        ku, kv = min(int(np.ceil(3 * su)), dim), min(int(np.ceil(3 * sv)), dim)
        u = np.zeros((NCH, dim, dim))
        for y in range(dim):
            for x in range(dim):
                for kk in range(-ku, ku + 1):
                    u[:, y, x] += np.exp(-kk * kk / (2 * su * su)) * bilinear_at(
                        planes, x + kk * c, y + kk * sn)
        tmp[t, k, :, :dim * dim] = u.reshape(NCH, -1)
        for j in range(-1, side + 1):
            for i in range(-1, side + 1):
                acc = np.zeros(NCH)
                for kk in range(-kv, kv + 1):
                    acc += np.exp(-kk * kk / (2 * sv * sv)) * bilinear_at(
                        u, i + g - kk * sn, j + g + kk * c)
                out[t, k, :, (j + 1) * stride + i + 1] = acc
    return tmp, out


MIP_ALPHA, MIP_D, MAX_ANISO = 2.24, 0.33, 16


def mip_pyramid(planes):
    """Levels 0.. of (NCH, d, d) planes: 2x2 means, missing texels count as 0."""
    levels = [planes]
    while levels[-1].shape[-1] > 1:
        a = levels[-1]
        d = a.shape[-1]
        e = -(-d // 2)
        pad = np.zeros(a.shape[:1] + (2 * e, 2 * e))
        pad[:, :d, :d] = a
        levels.append(0.25 * pad.reshape(a.shape[0], e, 2, e, 2).sum((2, 4)))
    return levels


def _mip_lookup(levels, lod, x, y):
    nlev = len(levels)
    lod = min(max(lod, 0.0), nlev - 1)
    lv = min(int(lod), max(nlev - 2, 0))
    f = lod - lv if nlev > 1 else 0.0
    v = np.zeros(levels[0].shape[0])
    for l, wt in ((lv, 1 - f), (lv + 1, f)):
        if wt == 0 or l >= nlev:
            continue
        sc = 2.0 ** l
        v += wt * bilinear_at(levels[l], (x - 0.5 * (sc - 1)) / sc, (y - 0.5 * (sc - 1)) / sc)
    return v


def filter_mip(params, grids, layout: Layout):
    """Four taps of trilinear probes along the major axis (see kernels/filter_mip.cl)."""
    stride = layout.filtered_side
    nlev, _ = mip_levels(layout.dmax)
    out = np.zeros(params.shape[:2] + (NCH, stride * stride))
    for t, k in zip(*np.nonzero(params[..., P_DIM])):
        p = params[t, k]
        dim, s, g = int(p[P_DIM]), p[P_SCALE], p[P_GUARD]
        side = layout.tile // int(s)
        levels = mip_pyramid(grids[t, k, :, :dim * dim].reshape(NCH, dim, dim))[:nlev]
        su, sv = p[P_SU] / s, p[P_SV] / s
        eu, ev = np.array([p[P_COS], p[P_SIN]]), np.array([-p[P_SIN], p[P_COS]])
        tsu, tsv = (MIP_ALPHA - MIP_D) / MIP_ALPHA * su, (MIP_ALPHA - MIP_D) / MIP_ALPHA * sv
        n = int(np.clip(np.ceil(tsu / max(tsv, 1e-3)), 1, MAX_ANISO))
        minor = max(tsv, tsu / MAX_ANISO)
        lod = np.log2(max(MIP_ALPHA * minor, 1.0))
        half = np.sqrt(max(3 * (tsu * tsu - minor * minor), 0.0))
        offs = [MIP_D * su * eu, -MIP_D * su * eu, MIP_D * sv * ev, -MIP_D * sv * ev]
        for j in range(-1, side + 1):
            for i in range(-1, side + 1):
                acc = np.zeros(NCH)
                for o in offs:
                    for m in range(n):
                        along = half * (2 * (m + 0.5) / n - 1) if n > 1 else 0.0
                        q = np.array([i + g, j + g]) + o + along * eu
                        acc += _mip_lookup(levels, lod, q[0], q[1])
                out[t, k, :, (j + 1) * stride + i + 1] = acc / n
    return out
