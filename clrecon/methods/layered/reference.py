"""NumPy reference of the passes of method ``layered``, written for clarity and mirroring the
kernels' data layouts (:mod:`clrecon.methods.layered.layout`) so that every pass can be
compared on its own (tests/passes/test_layered_*.py); :func:`reconstruct` chains them. The
screen-space filters are in :mod:`clrecon.methods.layered.reference_filters`. Unused parts of
the buffers are zero here (unspecified on the device).
"""
from __future__ import annotations

import numpy as np

from clrecon.core.samples import MISS_DEPTH
from clrecon.methods.layered.layout import (
    NCH,
    NPAR,
    NSTAT,
    P_A,
    P_AXIS,
    P_BX,
    P_BY,
    P_DIM,
    P_GUARD,
    P_HI,
    P_LO,
    P_REACH,
    P_SCALE,
    SUBSAMPLE_DEFAULT,
    Layout,
    bucket_params,
    subsample_cap,
)
from clrecon.methods.layered.reference_filters import (
    bilinear_at,
    filter_mip,
    filter_rotated,
    filter_sheared_x,
    filter_sheared_y,
)

# -- buckets ---------------------------------------------------------------------------------

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


def stat_addresses(tile_index: int, layout: Layout, stride: int, seed: int) -> np.ndarray:
    """Addresses a tile's statistics visit: all, or one random address per run of ``stride``."""
    total = layout.tile * layout.tile * layout.spp
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


def tile_stats(depth, motion, c0, c1, bucket_coeffs, layout: Layout, stride: int = 1,
               seed: int = 0):
    """(tiles, NBUCKETS, NSTAT): count, sums of coc, coc^2, mx, my, mx^2, my^2, mx my."""
    h, w, _ = depth.shape
    ntx, nty = layout.tiles(w, h)
    out = np.zeros((ntx * nty, layout.nbuckets, NSTAT))
    for t in range(ntx * nty):
        x0, y0 = (t % ntx) * layout.tile, (t // ntx) * layout.tile
        a = stat_addresses(t, layout, stride, seed)
        m = a // layout.spp
        x, y = x0 + _morton_even(m), y0 + _morton_even(m >> 1)
        ok = (x < w) & (y < h)
        x, y, i = x[ok], y[ok], (a % layout.spp)[ok]
        z = depth[y, x, i]
        b = buckets(z, *bucket_coeffs, layout.nbuckets)
        coc = coc_of(z, c0, c1)
        mv = motion[y, x, i].astype(np.float64) if layout.has_motion else np.zeros((len(z), 2))
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


def _params(s, lo, hi, sigma_x, layout: Layout):
    su, sv, a, xy, b = partition_filter(s, sigma_x, layout.has_motion)
    n = max(s[0], 1e-30)
    big_a = s[1] / n
    bx, by = (s[3] / n, s[4] / n) if layout.has_motion else (0.0, 0.0)
    theta = 0.5 * np.arctan2(2 * xy, a - b)
    sc = 1
    while sc < layout.tile and int(np.ceil(3 * su / sc)) + 1 > layout.gmax:
        sc *= 2
    g = min(layout.gmax, int(np.ceil(3 * su / sc)) + 1)
    axis = int(a > b)  # the Gaussian runs along the axis of larger variance
    along = a if axis else b
    shu = np.sqrt(max((a * b - xy * xy) / along / sc ** 2, 1e-8))
    shift = abs(big_a) + 0.5 * np.hypot(bx, by)
    p = np.zeros(NPAR)
    p[:P_AXIS + 1] = [s[0], lo, hi, big_a, bx, by, su, sv, np.cos(theta), np.sin(theta), shu,
                      np.sqrt(along) / sc, xy / along, np.exp(-np.sqrt(2) / shu), sc, g,
                      min(g * sc + int(np.ceil(shift)) + 1, layout.reach_max),
                      layout.tile // sc + 2 * g, axis]
    return p


def partition_setup(stats, layout: Layout, sigma_x: float = 0.33, threshold: float = 0.1):
    """(tiles, MAXP, NPAR): merged partitions and their filters (see the kernel's header)."""
    out = np.zeros((stats.shape[0], layout.maxp, NPAR))
    for t, st in enumerate(stats):
        parts, his, big = [], [], []
        for b in range(layout.nbuckets):
            s = st[b]
            if not s[0] > 0:
                continue
            f = np.array(partition_filter(s, sigma_x, layout.has_motion)[:2] * 2)
            if parts and threshold >= 0 and \
                    merge_shrink(parts[-1], s, big[-1], f, sigma_x, layout.has_motion) <= threshold:
                parts[-1] = parts[-1] + s
                big[-1] = _extremes(big[-1], f)
                his[-1] = b
                continue
            parts.append(s.copy())
            big.append(f)
            his.append(b)
        while len(parts) > layout.maxp:
            losses = [merge_shrink(parts[i], parts[i + 1], big[i], big[i + 1], sigma_x,
                                   layout.has_motion) for i in range(len(parts) - 1)]
            i = int(np.argmin(losses))
            parts[i] = parts[i] + parts.pop(i + 1)
            big[i] = _extremes(big[i], big.pop(i + 1))
            his[i] = his.pop(i + 1)
        if not parts:
            out[t, 0] = _params(np.zeros(NSTAT), 0, layout.nbuckets - 1, sigma_x, layout)
            continue
        his[-1] = layout.nbuckets - 1
        for i, s in enumerate(parts):
            out[t, i] = _params(s, 0 if i == 0 else his[i - 1] + 1, his[i], sigma_x, layout)
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


def reproject(fields: dict, params, bucket_coeffs, layout: Layout, bilinear: bool = False,
              subsample: int | bool = SUBSAMPLE_DEFAULT):
    """(tiles, MAXP, NCH, DMAX * DMAX): own colour/weight and behind weight per slot."""
    color, pos, depth = fields["color"], fields["position"], fields["depth"]
    lens, time = fields["lens"], fields["time"]
    h, w, _ = depth.shape
    ntx, _ = layout.tiles(w, h)
    bk = buckets(depth, *bucket_coeffs, layout.nbuckets)
    out = np.zeros(params.shape[:2] + (NCH, layout.dmax * layout.dmax))
    for t in range(params.shape[0]):
        x0, y0 = (t % ntx) * layout.tile, (t // ntx) * layout.tile
        for k in range(layout.maxp):
            p = params[t, k]
            dim = int(p[P_DIM])
            if dim == 0:
                continue
            r = int(p[P_REACH])
            sl = (slice(max(0, y0 - r), min(h, y0 + layout.tile + r)),
                  slice(max(0, x0 - r), min(w, x0 + layout.tile + r)))
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
            if layout.has_motion:
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


# -- composite -------------------------------------------------------------------------------

def composite(color, params, filtered, layout: Layout):
    """Front-to-back compositing of each pixel's tile partitions: (H, W, 3)."""
    h, w = color.shape[:2]
    ntx, _ = layout.tiles(w, h)
    stride = layout.filtered_side
    img = np.zeros((h, w, 3))
    for y in range(h):
        for x in range(w):
            t = (y // layout.tile) * ntx + x // layout.tile
            x0, y0 = (x // layout.tile) * layout.tile, (y // layout.tile) * layout.tile
            acc, trans = np.zeros(3), 1.0
            for k in range(layout.maxp):
                p = params[t, k]
                if p[P_DIM] == 0:
                    break
                s = p[P_SCALE]
                cx, cy = (x - x0 + 0.5) / s - 0.5, (y - y0 + 0.5) / s - 0.5
                planes = filtered[t, k].reshape(NCH, stride, stride)
                v = bilinear_at(planes, cx + 1, cy + 1)
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


def used_filtered(filtered, params, layout: Layout):
    """The defined part of each used slot's filtered planes, as (NCH, n, n) arrays."""
    stride = layout.filtered_side
    out = []
    for t, k in zip(*np.nonzero(params[..., P_DIM])):
        n = layout.tile // int(params[t, k, P_SCALE]) + 2
        out.append(filtered[t, k].reshape(NCH, stride, stride)[:, :n, :n])
    return out


def reconstruct(buf, tile: int = 32, stats_stride: int = 1, merge_threshold: float = 0.1,
                sigma_x: float = 0.33, max_partitions: int = 4, guard: int = 16,
                filter: str = "sheared", recursions: int = 3, seed: int = 0,
                bucket_coc: float = 0.5, splat: str = "nearest", nbuckets: int = 32,
                subsample: int | bool = SUBSAMPLE_DEFAULT):
    """The whole method in NumPy (slow: for small frames). Parameters as the pipeline's."""
    info = buf.inspect()
    sig = np.sqrt(info.max_abs_coc ** 2 / 4 + info.max_abs_motion ** 2 / 12 + sigma_x ** 2)
    gmax = max(2, min(guard, int(np.ceil(3 * sig)) + 1))
    layout = Layout(tile=tile, nbuckets=nbuckets, maxp=max_partitions, gmax=gmax,
                    spp=buf.spp, has_motion=info.has_motion)
    c0, c1 = buf.coc_model.c0, buf.coc_model.c1
    bucket_coeffs = bucket_params(c0, c1, info.min_depth, info.max_depth, nbuckets, bucket_coc)
    stats = tile_stats(buf.depth, buf.motion, c0, c1, bucket_coeffs, layout, stats_stride, seed)
    params = partition_setup(stats.astype(np.float32).astype(np.float64), layout, sigma_x,
                             merge_threshold)
    params = params.astype(np.float32).astype(np.float64)
    f = {k: getattr(buf, k) for k in ("color", "position", "depth", "lens", "time")}
    grids = reproject(f, params, bucket_coeffs, layout, splat == "bilinear", subsample)
    if filter == "sheared":
        filtered = filter_sheared_y(params, filter_sheared_x(params, grids, recursions), layout)
    elif filter == "mip":
        filtered = filter_mip(params, grids, layout)
    else:
        filtered = filter_rotated(params, grids, layout)[1]
    return composite(buf.color, params, filtered, layout)
