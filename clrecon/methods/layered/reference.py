"""NumPy reference of the passes of method ``layered``, written for clarity and mirroring the
kernels' data layouts so that every pass can be compared on its own (tests/test_layered_*.py).

Layouts (see ``kernels/layered.h``): ``stats`` (tiles, NBUCKETS, NSTAT); ``params`` (tiles,
MAXP, NPAR); ``grids`` (tiles, MAXP, NCH, DMAX * DMAX) with row stride ``D`` of the slot;
``filtered`` (tiles, MAXP, NCH, FT * FT), FT = TILE + 2. Only the used part of a grid (the
first ``D * D`` values of each plane) and of a filtered plane (``(T/s + 2)^2`` values with row
stride FT) is defined; the rest is zero here and unspecified on the device.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

NSTAT = 8
NPAR = 20
NCH = 5
MISS_DEPTH = 1e30
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
        return self.tile + 2 * self.gmax

    @property
    def ft(self) -> int:
        return self.tile + 2

    def tiles(self, width: int, height: int) -> tuple[int, int]:
        return -(-width // self.tile), -(-height // self.tile)

    def defines(self) -> dict:
        return {"TILE": self.tile, "NBUCKETS": self.nbuckets, "MAXP": self.maxp,
                "GMAX": self.gmax, "SPP": self.spp, "HAS_MOTION": self.has_motion,
                "REACH_MAX": self.reach_max}


# -- buckets ---------------------------------------------------------------------------------

def bucket_params(c0: float, c1: float, zmin: float, zmax: float, nbuckets: int,
                  bucket_coc: float = 0.5, uniform: int = 8) -> tuple:
    """``(ka, kb, kc)`` of the bucket function of ``layered.h`` (float32).

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


def buckets(depth: np.ndarray, ka, kb, kc, nbuckets: int) -> np.ndarray:
    """Bucket of each depth, in float32 as the kernel computes it."""
    w = np.asarray(depth, np.float32)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        ell = (np.float32(ka) / w + np.float32(kb) * w) - np.float32(kc)
        b = np.clip(np.floor(ell), 0, nbuckets - 2)
    b = np.where(np.isnan(b), 0, b).astype(np.int64)
    return np.where(w < MISS_DEPTH, b, nbuckets - 1)


def coc_of(depth, c0, c1):
    d = np.asarray(depth, np.float64)
    with np.errstate(divide="ignore"):
        return np.where(d < MISS_DEPTH, c0 / d + c1, c1)


# -- tile_stats ------------------------------------------------------------------------------

def _morton_even(m):
    m = m & 0x55555555
    m = (m | (m >> 1)) & 0x33333333
    m = (m | (m >> 2)) & 0x0F0F0F0F
    m = (m | (m >> 4)) & 0x00FF00FF
    return (m | (m >> 8)) & 0x0000FFFF


def _xorshift(x):
    x ^= (x << 13) & 0xFFFFFFFF
    x ^= x >> 17
    x ^= (x << 5) & 0xFFFFFFFF
    return x


def stat_addresses(tile_index: int, lay: Layout, stride: int, seed: int) -> np.ndarray:
    """Addresses a tile's statistics visit: all, or one random address per run of ``stride``."""
    total = lay.tile * lay.tile * lay.spp
    if stride <= 1:
        return np.arange(total)
    state = ((seed * 0x9E3779B9) ^ ((tile_index * 0x85EBCA6B + 0x632BE5AB) & 0xFFFFFFFF))
    state &= 0xFFFFFFFF
    state = state or 1
    out = []
    for j in range(0, total, stride):
        state = _xorshift(state)
        out.append(j + state % min(stride, total - j))
    return np.array(out)


def tile_stats(depth, motion, c0, c1, kabc, lay: Layout, stride: int = 1, seed: int = 0):
    """(tiles, NBUCKETS, NSTAT): count, sums of coc, coc^2, mx, my, mx^2, my^2, mx my."""
    h, w, _ = depth.shape
    ntx, nty = lay.tiles(w, h)
    out = np.zeros((ntx * nty, lay.nbuckets, NSTAT))
    for t in range(ntx * nty):
        x0, y0 = (t % ntx) * lay.tile, (t // ntx) * lay.tile
        a = stat_addresses(t, lay, stride, seed)
        m = a // lay.spp
        x, y = x0 + _morton_even(m), y0 + _morton_even(m >> 1)
        ok = (x < w) & (y < h)
        x, y, i = x[ok], y[ok], (a % lay.spp)[ok]
        z = depth[y, x, i]
        b = buckets(z, *kabc, lay.nbuckets)
        coc = coc_of(z, c0, c1)
        mv = motion[y, x, i].astype(np.float64) if lay.has_motion else np.zeros((len(z), 2))
        vals = np.stack([np.ones_like(coc), coc, coc * coc, mv[:, 0], mv[:, 1], mv[:, 0] ** 2,
                         mv[:, 1] ** 2, mv[:, 0] * mv[:, 1]], -1)
        np.add.at(out[t], b, vals)
    return out


# -- partition_setup -------------------------------------------------------------------------

def partition_filter(s, sigma_x: float, has_motion: bool = True):
    """(sigma_u, sigma_v, cov_xx, cov_xy, cov_yy) of a partition with summed stats ``s``.

    Covariance ``(c^2 / 4 + sigma_x^2) I + m m^T / 12`` (c mean CoC, m mean motion).
    Merging judges the merged filter against the constituent buckets' (no drift).
    """
    n = max(s[0], 1e-30)
    c = s[1] / n
    mx, my = (s[3] / n, s[4] / n) if has_motion else (0.0, 0.0)
    iso = c * c / 4 + sigma_x ** 2
    a = max(iso + mx * mx / 12, 1e-4)
    b = max(iso + my * my / 12, 1e-4)
    xy = mx * my / 12
    h = (a + b) / 2
    d = np.sqrt((a - b) ** 2 / 4 + xy * xy)
    return np.sqrt(h + d), np.sqrt(max(h - d, 1e-4)), a, xy, b


def merge_shrink(a, b, ext_a, ext_b, sigma_x, has_motion=True) -> float:
    """How far the merged filter strays from its constituent buckets' filters.

    ``ext``: per-axis extremes (max sigma_u, max sigma_v, min sigma_u, min sigma_v) of the
    buckets in a partition. The larger of the relative shrink below the largest (the paper's
    test) and the relative growth above the smallest.
    """
    fm = partition_filter(a + b, sigma_x, has_motion)
    shrink = max(1 - fm[0] / max(ext_a[0], ext_b[0]), 1 - fm[1] / max(ext_a[1], ext_b[1]))
    grow = max(1 - min(ext_a[2], ext_b[2]) / fm[0], 1 - min(ext_a[3], ext_b[3]) / fm[1])
    return max(shrink, grow)


def _extremes(e, f):
    return np.array([max(e[0], f[0]), max(e[1], f[1]), min(e[2], f[2]), min(e[3], f[3])])


def _params(s, lo, hi, sigma_x, lay: Layout):
    su, sv, a, xy, b = partition_filter(s, sigma_x, lay.has_motion)
    n = max(s[0], 1e-30)
    big_a = s[1] / n
    bx, by = (s[3] / n, s[4] / n) if lay.has_motion else (0.0, 0.0)
    theta = 0.5 * np.arctan2(2 * xy, a - b)
    sc = 1
    while sc < lay.tile and int(np.ceil(3 * su / sc)) + 1 > lay.gmax:
        sc *= 2
    g = min(lay.gmax, int(np.ceil(3 * su / sc)) + 1)
    axis = int(a > b)  # the Gaussian runs along the axis of larger variance
    along = a if axis else b
    shu = np.sqrt(max((a * b - xy * xy) / along / sc ** 2, 1e-8))
    shift = abs(big_a) + 0.5 * np.hypot(bx, by)
    p = np.zeros(NPAR)
    p[:P_AXIS + 1] = [s[0], lo, hi, big_a, bx, by, su, sv, np.cos(theta), np.sin(theta), shu,
                      np.sqrt(along) / sc, xy / along, np.exp(-np.sqrt(2) / shu), sc, g,
                      min(g * sc + int(np.ceil(shift)) + 1, lay.reach_max),
                      lay.tile // sc + 2 * g, axis]
    return p


def partition_setup(stats, lay: Layout, sigma_x: float = 0.33, threshold: float = 0.1):
    """(tiles, MAXP, NPAR): merged partitions and their filters (see the kernel's header)."""
    out = np.zeros((stats.shape[0], lay.maxp, NPAR))
    for t, st in enumerate(stats):
        parts, his, big = [], [], []
        for b in range(lay.nbuckets):
            s = st[b]
            if not s[0] > 0:
                continue
            f = np.array(partition_filter(s, sigma_x, lay.has_motion)[:2] * 2)
            if parts and threshold >= 0 and \
                    merge_shrink(parts[-1], s, big[-1], f, sigma_x, lay.has_motion) <= threshold:
                parts[-1] = parts[-1] + s
                big[-1] = _extremes(big[-1], f)
                his[-1] = b
                continue
            parts.append(s.copy())
            big.append(f)
            his.append(b)
        while len(parts) > lay.maxp:
            losses = [merge_shrink(parts[i], parts[i + 1], big[i], big[i + 1], sigma_x,
                                   lay.has_motion) for i in range(len(parts) - 1)]
            i = int(np.argmin(losses))
            parts[i] = parts[i] + parts.pop(i + 1)
            big[i] = _extremes(big[i], big.pop(i + 1))
            his[i] = his.pop(i + 1)
        if not parts:
            out[t, 0] = _params(np.zeros(NSTAT), 0, lay.nbuckets - 1, sigma_x, lay)
            continue
        his[-1] = lay.nbuckets - 1
        for i, s in enumerate(parts):
            out[t, i] = _params(s, 0 if i == 0 else his[i - 1] + 1, his[i], sigma_x, lay)
    return out


# -- reproject -------------------------------------------------------------------------------

def row_hash(cy, sub):
    """The kernel's uint32 hash of block row ``cy`` for blocks of side ``sub`` (vectorised)."""
    m = np.uint64(0xFFFFFFFF)
    cy = np.asarray(cy, np.uint64)
    h = ((cy * np.uint64(0xD8163841)) & m) ^ np.uint64((sub * 0xCB1AB31F) & 0xFFFFFFFF)
    h ^= h >> np.uint64(13)
    h = (h * np.uint64(0x85EBCA6B)) & m
    h ^= h >> np.uint64(16)
    return h


#: ``subsample=True``: a slot on a grid of spacing s reads one pixel per min(s, 8)^2 block
SUBSAMPLE_DEFAULT = 8


def subsample_cap(subsample: int | bool) -> int:
    """The largest block side read as one pixel: ``True`` -> 8, ``False`` -> 1 (every pixel),
    an int >= 1 as given."""
    if isinstance(subsample, (bool, np.bool_)):
        return SUBSAMPLE_DEFAULT if subsample else 1
    if not isinstance(subsample, (int, np.integer)) or not 1 <= subsample <= 64:
        raise ValueError(f"subsample: must be true, false or an int in [1, 64], "
                         f"got {subsample!r}")
    return int(subsample)


def reproject(fields: dict, params, kabc, lay: Layout, bilinear: bool = False,
              subsample: int | bool = True):
    """(tiles, MAXP, NCH, DMAX * DMAX): own colour/weight and behind weight per slot."""
    color, pos, depth = fields["color"], fields["position"], fields["depth"]
    lens, time = fields["lens"], fields["time"]
    h, w, _ = depth.shape
    ntx, _ = lay.tiles(w, h)
    bk = buckets(depth, *kabc, lay.nbuckets)
    out = np.zeros(params.shape[:2] + (NCH, lay.dmax * lay.dmax))
    for t in range(params.shape[0]):
        x0, y0 = (t % ntx) * lay.tile, (t // ntx) * lay.tile
        for k in range(lay.maxp):
            p = params[t, k]
            dim = int(p[P_DIM])
            if dim == 0:
                continue
            r = int(p[P_REACH])
            sl = (slice(max(0, y0 - r), min(h, y0 + lay.tile + r)),
                  slice(max(0, x0 - r), min(w, x0 + lay.tile + r)))
            b = bk[sl].ravel()
            keep = b >= p[P_LO]
            sub = min(int(p[P_SCALE]), subsample_cap(subsample))
            if sub > 1:  # one pixel per sub x sub block (kernels/reproject.cl)
                ys, xs = np.mgrid[sl]
                hh = row_hash(ys // sub, sub)  # per block row: the reads stream
                pick = (xs % sub == hh % sub) & (ys % sub == (hh >> 16) % sub)
                keep &= np.repeat(pick.ravel(), depth.shape[2])
            own = (b <= p[P_HI])[keep]
            # float32 in the kernel's order: the nearest grid pixel must agree
            f32 = np.float32
            pk = p.astype(f32)
            q = (pos[sl].reshape(-1, 2)[keep].astype(f32)
                 - pk[P_A] * lens[sl].reshape(-1, 2)[keep].astype(f32))
            if lay.has_motion:
                q = q - (time[sl].ravel()[keep, None].astype(f32) - f32(0.5)) * pk[[P_BX, P_BY]]
            g = ((q - np.array([x0, y0], f32)) * (f32(1) / pk[P_SCALE]) + pk[P_GUARD])
            g = g.astype(np.float64)
            col = color[sl].reshape(-1, 3)[keep]
            if bilinear:
                f = g - 0.5
                i0 = np.floor(f).astype(np.int64)
                fr = f - i0
                ax, ay = fr[:, 0], fr[:, 1]
                taps = [((0, 0), (1 - ax) * (1 - ay)), ((1, 0), ax * (1 - ay)),
                        ((0, 1), (1 - ax) * ay), ((1, 1), ax * ay)]
            else:
                i0 = np.floor(g).astype(np.int64)
                taps = [((0, 0), np.ones(len(g)))]
            grid = out[t, k]
            for (dx, dy), wt in taps:
                ix, iy = i0[:, 0] + dx, i0[:, 1] + dy
                ok = (ix >= 0) & (iy >= 0) & (ix < dim) & (iy < dim)
                if not bilinear:
                    ok &= (g[:, 0] >= 0) & (g[:, 1] >= 0)
                at = iy * dim + ix
                o, bh = ok & own, ok & ~own
                for c in range(3):
                    np.add.at(grid[c], at[o], wt[o] * col[o, c])
                np.add.at(grid[3], at[o], wt[o])
                np.add.at(grid[4], at[bh], wt[bh])
    return out


# -- screen-space filters --------------------------------------------------------------------

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


def filter_sheared_y(params, grids, lay: Layout):
    """Gaussian along the sheared axis, linear along the recursive one: (tiles, MAXP, NCH,
    FT * FT). Axis 1 is axis 0 on the transposed grid with i and j swapped."""
    ft = lay.ft
    out = np.zeros(params.shape[:2] + (NCH, ft * ft))
    for t, k in zip(*np.nonzero(params[..., P_DIM])):
        p = params[t, k]
        dim, g, sv, beta = int(p[P_DIM]), int(p[P_GUARD]), p[P_SHV], p[P_BETA]
        axis = int(p[P_AXIS])
        side = lay.tile // int(p[P_SCALE])
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
                out[t, k, :, (j + 1) * ft + i + 1] = acc
    return out


def _bilinear(planes, x, y):
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


def filter_rotated(params, grids, lay: Layout):
    """LRDM: 1D Gaussians along u then v with bilinear taps: (tmp, filtered)."""
    ft = lay.ft
    tmp = np.zeros_like(grids)
    out = np.zeros(params.shape[:2] + (NCH, ft * ft))
    for t, k in zip(*np.nonzero(params[..., P_DIM])):
        p = params[t, k]
        dim, s, g = int(p[P_DIM]), p[P_SCALE], p[P_GUARD]
        side = lay.tile // int(s)
        planes = grids[t, k, :, :dim * dim].reshape(NCH, dim, dim)
        su, sv, c, sn = p[P_SU] / s, p[P_SV] / s, p[P_COS], p[P_SIN]
        ku, kv = min(int(np.ceil(3 * su)), dim), min(int(np.ceil(3 * sv)), dim)
        u = np.zeros((NCH, dim, dim))
        for y in range(dim):
            for x in range(dim):
                for kk in range(-ku, ku + 1):
                    u[:, y, x] += np.exp(-kk * kk / (2 * su * su)) * _bilinear(
                        planes, x + kk * c, y + kk * sn)
        tmp[t, k, :, :dim * dim] = u.reshape(NCH, -1)
        for j in range(-1, side + 1):
            for i in range(-1, side + 1):
                acc = np.zeros(NCH)
                for kk in range(-kv, kv + 1):
                    acc += np.exp(-kk * kk / (2 * sv * sv)) * _bilinear(
                        u, i + g - kk * sn, j + g + kk * c)
                out[t, k, :, (j + 1) * ft + i + 1] = acc
    return tmp, out


MIP_ALPHA, MIP_D, MAX_ANISO = 2.24, 0.33, 16


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
        v += wt * _bilinear(levels[l], (x - 0.5 * (sc - 1)) / sc, (y - 0.5 * (sc - 1)) / sc)
    return v


def filter_mip(params, grids, lay: Layout):
    """Four taps of trilinear probes along the major axis (see kernels/filter_mip.cl)."""
    ft = lay.ft
    nlev, _ = mip_levels(lay.dmax)
    out = np.zeros(params.shape[:2] + (NCH, ft * ft))
    for t, k in zip(*np.nonzero(params[..., P_DIM])):
        p = params[t, k]
        dim, s, g = int(p[P_DIM]), p[P_SCALE], p[P_GUARD]
        side = lay.tile // int(s)
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
                out[t, k, :, (j + 1) * ft + i + 1] = acc / n
    return out


# -- composite -------------------------------------------------------------------------------

def composite(color, params, filtered, lay: Layout):
    """Front-to-back compositing of each pixel's tile partitions: (H, W, 3)."""
    h, w = color.shape[:2]
    ntx, _ = lay.tiles(w, h)
    ft = lay.ft
    img = np.zeros((h, w, 3))
    for y in range(h):
        for x in range(w):
            t = (y // lay.tile) * ntx + x // lay.tile
            x0, y0 = (x // lay.tile) * lay.tile, (y // lay.tile) * lay.tile
            acc, trans = np.zeros(3), 1.0
            for k in range(lay.maxp):
                p = params[t, k]
                if p[P_DIM] == 0:
                    break
                s = p[P_SCALE]
                cx, cy = (x - x0 + 0.5) / s - 0.5, (y - y0 + 0.5) / s - 0.5
                planes = filtered[t, k].reshape(NCH, ft, ft)
                v = _bilinear(planes, cx + 1, cy + 1)
                cw = v[3] + v[4]
                if not cw > 1e-6:
                    continue
                acc += trans * v[:3] / cw
                trans *= v[4] / cw
            if trans < 1 - 1e-6:
                img[y, x] = acc / (1 - trans)
            else:
                img[y, x] = color[y, x].astype(np.float64).mean(0)
    return img


def used_grid(grids, params):
    """The defined part of each used slot's grid, as a list of (NCH, D, D) arrays."""
    return [grids[t, k, :, :int(params[t, k, P_DIM]) ** 2]
            for t, k in zip(*np.nonzero(params[..., P_DIM]))]


def used_filtered(filtered, params, lay: Layout):
    """The defined part of each used slot's filtered planes, as (NCH, n, n) arrays."""
    ft = lay.ft
    out = []
    for t, k in zip(*np.nonzero(params[..., P_DIM])):
        n = lay.tile // int(params[t, k, P_SCALE]) + 2
        out.append(filtered[t, k].reshape(NCH, ft, ft)[:, :n, :n])
    return out


def reconstruct(buf, tile: int = 32, stats_stride: int = 1, merge_threshold: float = 0.1,
                sigma_x: float = 0.33, max_partitions: int = 4, guard: int = 16,
                filter: str = "sheared", recursions: int = 3, seed: int = 0,
                bucket_coc: float = 0.5, splat: str = "nearest", nbuckets: int = 32,
                subsample: int | bool = True):
    """The whole method in NumPy (slow: for small frames). Parameters as the pipeline's."""
    info = buf.inspect()
    sig = np.sqrt(info.max_abs_coc ** 2 / 4 + info.max_abs_motion ** 2 / 12 + sigma_x ** 2)
    gmax = max(2, min(guard, int(np.ceil(3 * sig)) + 1))
    lay = Layout(tile=tile, nbuckets=nbuckets, maxp=max_partitions, gmax=gmax, spp=buf.spp,
                 has_motion=info.has_motion)
    c0, c1 = buf.coc_model.c0, buf.coc_model.c1
    kabc = bucket_params(c0, c1, info.min_depth, info.max_depth, nbuckets, bucket_coc)
    stats = tile_stats(buf.depth, buf.motion, c0, c1, kabc, lay, stats_stride, seed)
    params = partition_setup(stats.astype(np.float32).astype(np.float64), lay, sigma_x,
                             merge_threshold)
    params = params.astype(np.float32).astype(np.float64)
    f = {k: getattr(buf, k) for k in ("color", "position", "depth", "lens", "time")}
    grids = reproject(f, params, kabc, lay, splat == "bilinear", subsample)
    if filter == "sheared":
        filtered = filter_sheared_y(params, filter_sheared_x(params, grids, recursions), lay)
    elif filter == "mip":
        filtered = filter_mip(params, grids, lay)
    else:
        filtered = filter_rotated(params, grids, lay)[1]
    return composite(buf.color, params, filtered, lay)
