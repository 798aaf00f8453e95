"""NumPy reference of ``splat``'s mip plan (``kernels/splat_mip_*.cl``, :mod:`.mip`): the bins,
the drawn levels and their upsampling into level 0, for the kernels' tests.

The discrete choices (level, layer, bin) follow the kernel's float32 arithmetic; what is
drawn is evaluated in float64. Slow (a Python loop over the non-empty bins): small frames.
"""
from __future__ import annotations

import numpy as np

from clrecon.core.samples import MISS_DEPTH
from clrecon.methods.splat.mip import MipGeometry

F = np.float32


def bins(buf, geo: MipGeometry, inv_far: float, layer_scale: float,
         has_motion: bool) -> np.ndarray:
    """The bin images ``(pixels, 12)`` (every level and layer, the kernels' layout)."""
    c0, c1 = F(buf.coc_model.c0), F(buf.coc_model.c1)
    z = buf.depth.reshape(-1).astype(np.float32)
    miss = z >= F(MISS_DEPTH)
    with np.errstate(divide="ignore"):
        coc = np.where(miss, c1, c0 / z + c1).astype(np.float32)
    r = np.abs(coc)
    mot = buf.motion.reshape(-1, 2).astype(np.float32) if has_motion else \
        np.zeros((len(z), 2), np.float32)
    ln = np.sqrt(mot[:, 0] * mot[:, 0] + mot[:, 1] * mot[:, 1]).astype(np.float32)
    lev = np.zeros(len(z), np.int64)
    for j in range(geo.nlev - 1):  # the lowest level whose thresholds hold the PSF
        lev += (r > geo.tr[j]) | (ln > geo.tm[j])
    rl, ml = geo.rl[lev], geo.ml[lev]
    s = (2.0 ** lev).astype(np.float32)
    inv_s = (F(1) / s).astype(np.float32)
    with np.errstate(divide="ignore", invalid="ignore"):
        cs = np.where(r * inv_s > rl, rl * s / r, F(1)).astype(np.float32)
        ms = np.where(ln * inv_s > ml, ml * s / ln, F(1)).astype(np.float32)
    cc = coc * cs
    pos = buf.position.reshape(-1, 2).astype(np.float32)
    lens = buf.lens.reshape(-1, 2).astype(np.float32)
    cen = pos - cc[:, None] * lens
    if has_motion:
        dt = (buf.time.reshape(-1).astype(np.float32) - F(0.5)) * ms
        cen = cen - dt[:, None] * mot
    with np.errstate(divide="ignore"):
        inv = np.where(miss, F(0), F(1) / z).astype(np.float32)
    layer = np.clip(np.floor((inv - F(inv_far)) * F(layer_scale)), 0, geo.layers - 1)
    layer = layer.astype(np.int64)
    c = (cen * inv_s[:, None]).astype(np.float32)
    fq = np.floor(c)
    qx, qy = fq[:, 0].astype(np.int64), fq[:, 1].astype(np.int64)
    lv = geo.levels.astype(np.int64)
    nw, nh, first, p = lv[lev, 1], lv[lev, 2], lv[lev, 0], lv[lev, 3]
    reach = p // 2
    keep = (qx >= reach - p) & (qy >= reach - p) & (qx < nw - p - reach) & (qy < nh - p - reach)
    idx = first + (layer * nh + qy + p) * nw + qx + p
    w = 1.0 / buf.spp
    col = buf.color.reshape(-1, 3).astype(np.float64)
    rec = np.zeros((len(z), 12))
    rec[:, :3] = col * w
    rec[:, 3] = w
    rec[:, 4] = (r * cs * inv_s).astype(np.float64) * w
    rec[:, 5:7] = mot.astype(np.float64) * (ms * inv_s)[:, None] * w
    rec[:, 8:10] = (c - fq).astype(np.float64) * w
    out = np.zeros((geo.pixels, 12))
    np.add.at(out, idx[keep], rec[keep])
    return out


def psf(dx: np.ndarray, dy: np.ndarray, rho: float, length: float, u) -> np.ndarray:
    """``mip_psf``: the antialiased disc (a small one: the square of its area), or the disc
    swept along ``length * u``."""
    if length < 0.5:
        if rho >= 1.5:
            return np.clip(rho + 0.5 - np.hypot(dx, dy), 0.0, 1.0)
        a = 0.5 * np.sqrt(np.pi) * rho  # a small disc: the square of its area
        ox = np.maximum(np.minimum(dx + 0.5, a) - np.maximum(dx - 0.5, -a), 0.0)
        oy = np.maximum(np.minimum(dy + 0.5, a) - np.maximum(dy - 0.5, -a), 0.0)
        return ox * oy
    x, y = dx * u[0] + dy * u[1], dy * u[0] - dx * u[1]
    v = 0.0
    for rr in (rho - 0.25, rho + 0.25):
        h = np.sqrt(np.maximum(rr * rr - y * y, 0.0))
        v = v + np.maximum(np.minimum(x + h, 0.5 * length) - np.maximum(x - h, -0.5 * length),
                           0.0)
    return v


def draw(b: np.ndarray, geo: MipGeometry) -> np.ndarray:
    """The level images ``(pixels, 4)`` drawn from the bins ``b``."""
    img = np.zeros((geo.pixels, 4))
    for first, nw, nh, p in geo.levels.astype(np.int64):
        reach = p // 2
        for layer in range(geo.layers):
            base = first + layer * nh * nw
            blk = b[base:base + nh * nw].reshape(nh, nw, 12)
            for py, px in zip(*np.nonzero(blk[..., 3] > 0)):
                rec = blk[py, px]
                wgt = rec[3]
                rad, mx, my = rec[4] / wgt, rec[5] / wgt, rec[6] / wgt
                ln = float(np.hypot(mx, my))
                b0 = rec[:4]
                if rad < 0.5 and ln < 0.5:
                    img[base + py * nw + px] += b0
                    continue
                rho = max(rad, 0.5)
                u = (mx / ln, my / ln) if ln > 0 else (1.0, 0.0)
                qx, qy = px - p, py - p
                cx, cy = qx + rec[8] / wgt, qy + rec[9] / wgt
                ex = abs(u[0]) * 0.5 * ln + rho + 1.0
                ey = abs(u[1]) * 0.5 * ln + rho + 1.0
                xs = np.arange(max(int(np.floor(cx - ex)), qx - reach),
                               min(int(np.floor(cx + ex)), qx + reach) + 1)
                ys = np.arange(max(int(np.floor(cy - ey)), qy - reach),
                               min(int(np.floor(cy + ey)), qy + reach) + 1)
                gx, gy = np.meshgrid(xs, ys)
                v = psf(gx + 0.5 - cx, gy + 0.5 - cy, rho, ln, u)
                if ln < 0.5:
                    tot = np.pi * (rho * rho + 1 / 12) if rho >= 3 else v.sum()
                else:
                    tot = 2 * ln * np.pi * (rho * rho + 0.0625) if rho >= 4 else v.sum()
                if not tot > 0:
                    img[base + py * nw + px] += b0
                    continue
                at = base + (gy + p) * nw + gx + p
                np.add.at(img, at.ravel(), (v.ravel() / tot)[:, None] * b0[None, :])
    return img


def upsample(img: np.ndarray, geo: MipGeometry) -> np.ndarray:
    """Each level into the one below it, bilinearly (1/4 per child pixel), top down."""
    img = img.copy()
    lv = geo.levels.astype(np.int64)
    for level in range(geo.nlev - 1, 0, -1):
        fp, wp, hp, pp = lv[level]
        fc, wc, hc, pc = lv[level - 1]
        for layer in range(geo.layers):
            par = img[fp + layer * hp * wp:fp + (layer + 1) * hp * wp].reshape(hp, wp, 4)
            par = np.pad(par, ((1, 1), (1, 1), (0, 0)))  # zero outside
            u = 0.5 * (np.arange(wc) - pc) - 0.25 + pp
            t = 0.5 * (np.arange(hc) - pc) - 0.25 + pp
            ix, iy = np.floor(u).astype(np.int64), np.floor(t).astype(np.int64)
            fx, fy = (u - ix)[None, :, None], (t - iy)[:, None, None]
            ix = np.clip(ix, -1, wp) + 1
            iy = np.clip(iy, -1, hp) + 1
            ix1, iy1 = np.minimum(ix + 1, wp + 1), np.minimum(iy + 1, hp + 1)
            acc = ((1 - fy) * ((1 - fx) * par[iy][:, ix] + fx * par[iy][:, ix1])
                   + fy * ((1 - fx) * par[iy1][:, ix] + fx * par[iy1][:, ix1]))
            child = img[fc + layer * hc * wc:fc + (layer + 1) * hc * wc]
            child += 0.25 * acc.reshape(-1, 4)
    return img


def level0(buf, geo: MipGeometry, inv_far: float, layer_scale: float,
           has_motion: bool) -> np.ndarray:
    """What ``splat_composite`` reads: level 0 after the upsampling, ``(layers, H + 2 P,
    W + 2 P, 4)``."""
    img = upsample(draw(bins(buf, geo, inv_far, layer_scale, has_motion), geo), geo)
    _, nw, nh, _ = geo.levels[0]
    return img[:geo.layers * nh * nw].reshape(geo.layers, nh, nw, 4)
