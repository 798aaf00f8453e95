"""NumPy references of the ``splat`` passes (written for clarity; the kernels are tested
against them) and of the whole method.

Conventions shared with the kernels:

* padded images: the frame plus ``pad`` pixels on every side, ``(nl, H + 2 pad, W + 2 pad, 4)``
  (RGB + coverage), layer 0 the farthest;
* a sample's centre (section 6.2 re-centring) is
  ``position - coc * lens - (time - 0.5) * motion``; its PSF is drawn around the pixel
  ``floor(centre)``; offsets of Combined are rotated from +x to the motion direction and
  rounded to the nearest pixel;
* layers are uniform in ``1 / depth`` (constant parallax) between the frame's extremes,
  misses (depth >= 1e30) at ``1 / depth = 0``;
* ``integrate`` solves ``laplacian5(u) = lap`` with a convolution pyramid (Farbman et al.
  2011, REFERENCES.md) and anchors ``u`` so that the outermost ring of the padded image is 0
  on average (the padding is wider than any PSF, so the true image is 0 there);
* ``composite``: back to front, per layer ``rgb, cov`` (integrated Laplacian plus the
  direct image) clamped at 0; a layer with ``cov > eps`` contributes its normalised colour
  ``rgb / cov`` with weight ``a = min(cov, 1)``, except the farthest layer with
  ``cov >= FILL_COV`` (0.1), which takes ``a = 1`` (it fills the holes nearer surfaces left in
  its coverage): ``out = a colour + (1 - a) out``, divided at the end by the accumulated
  alpha (1 once a layer filled the pixel).
"""
from __future__ import annotations

import math

import numpy as np

from clrecon.core.samples import MISS_DEPTH

COV_EPS = 1e-7
FILL_COV = 0.1

F5 = (np.array([0.15, 0.5, 0.7, 0.5, 0.15]), None, np.array([0.175, 0.547, 0.175]))
F7_H1 = np.array([0.06110, 0.26177, 0.53034, 0.65934, 0.53034, 0.26177, 0.06110])
# REFERENCES.md's "h2 = 0.51106 * h1" scales the 2D filter h1 (x) h1 once, so the separable
# 1D factor is sqrt(0.51106): read literally (0.51106 per axis) the result keeps ~2% of the
# image's energy, read this way it agrees with the FFT solve as well as F_5 does.
F7 = (F7_H1, np.sqrt(0.51106) * F7_H1, np.array([0.05407, 0.24453, 0.57410, 0.24453, 0.05407]))
PYRAMIDS = {"f5": (F5[0], F5[0], F5[2]), "f7": F7}


def _sep(img: np.ndarray, k: np.ndarray) -> np.ndarray:
    from scipy.ndimage import correlate1d  # the references need scipy (test/eval extras)

    out = correlate1d(img, k, axis=0, mode="constant")
    return correlate1d(out, k, axis=1, mode="constant")


def pyramid_levels(h: int, w: int) -> int:
    return max(1, math.ceil(math.log2(max(h, w, 2))))


def pyramid_shapes(h: int, w: int, pad: int) -> list[tuple[int, int]]:
    """Shapes of the analysis levels: level ``i + 1`` is level ``i`` padded by ``pad`` on every
    side and decimated by 2."""
    shapes = [(h, w)]
    for _ in range(pyramid_levels(h, w)):
        ph, pw = shapes[-1]
        shapes.append(((ph + 2 * pad + 1) // 2, (pw + 2 * pad + 1) // 2))
    return shapes


def integrate(lap: np.ndarray, pyramid: str = "f5") -> np.ndarray:
    """Convolution-pyramid integration of one channel (H, W) and the ring anchor."""
    h1, h2, g = PYRAMIDS[pyramid]
    pad = len(h1)
    a = [-np.asarray(lap, np.float64)]  # the pyramid takes the negated Laplacian
    for _ in range(pyramid_levels(*lap.shape)):
        p = np.pad(a[-1], pad)
        a.append(_sep(p, h1)[::2, ::2])
    b = _sep(a[-1], g)
    for i in range(len(a) - 2, -1, -1):
        hh, ww = a[i].shape
        up = np.zeros((hh + 2 * pad, ww + 2 * pad))
        up[::2, ::2] = b
        b = _sep(up, h2)[pad:pad + hh, pad:pad + ww] + _sep(a[i], g)
    return b - ring_mean(b)


def ring_mean(u: np.ndarray) -> float:
    """Mean of the outermost ring of pixels."""
    if min(u.shape) <= 2:
        return float(u.mean())
    ring = np.concatenate([u[0], u[-1], u[1:-1, 0], u[1:-1, -1]])
    return float(ring.mean())


def layer_of(depth: np.ndarray, inv_far: float, inv_near: float, nlayers: int) -> np.ndarray:
    """Global depth layer (0 = farthest) of each depth, uniform in ``1 / depth``."""
    inv = np.where(depth >= MISS_DEPTH, 0.0, 1.0 / np.maximum(depth, 1e-30))
    span = inv_near - inv_far
    scale = nlayers / span if span > 0 else 0.0
    return np.clip(np.floor((inv - inv_far) * scale), 0, nlayers - 1).astype(np.int64)


def splat(buf, table, grid, nlayers: int, inv_range: tuple[float, float], pad: int,
          reach: int, fast: np.ndarray, rotate: bool, smax: tuple[float, ...]):
    """The ``splat`` pass: per-layer Laplacian and direct images, each
    ``(nl, H + 2 pad, W + 2 pad, 4)``.

    ``table``: (points (x, y), values, offsets, dense points, dense values, dense offsets);
    ``grid``: a callable mapping PSF parameters (k, ndim) to cell indices; ``fast``: per cell,
    whether it is drawn densely (fast track) into the direct image; ``rotate``: a 2D (CoC,
    motion) model; ``smax``: the model's parameter ranges. Samples whose centre pixel lies
    closer than ``reach`` to the padded image's border are skipped.
    """
    pts, vals, offs, dpts, dvals, doffs = table
    h, w, s = buf.shape
    ph, pw = h + 2 * pad, w + 2 * pad
    lap = np.zeros((nlayers, ph, pw, 4))
    direct = np.zeros((nlayers, ph, pw, 4))
    depth = buf.depth.reshape(-1).astype(np.float64)
    coc = np.where(depth >= MISS_DEPTH, buf.coc_model.c1,
                   buf.coc_model.c0 / np.where(depth >= MISS_DEPTH, 1.0, depth)
                   + buf.coc_model.c1)
    mot = buf.motion.reshape(-1, 2).astype(np.float64)
    # float32 like the kernel (floor of the centre must agree); a CoC beyond the table's
    # range re-centres by its clamped value
    smax = np.asarray(smax, np.float32)
    coc32, pos = coc.astype(np.float32), buf.position.reshape(-1, 2)
    a32 = np.abs(coc32)
    cs = np.where(a32 > smax[0], smax[0] / np.where(a32 > 0, a32, 1), np.float32(1))
    centre = pos - (coc32 * cs)[:, None] * buf.lens.reshape(-1, 2)
    nsub = np.ones(len(depth), np.int64)
    m32 = buf.motion.reshape(-1, 2)
    if rotate:
        l32 = np.hypot(m32[:, 0], m32[:, 1]).astype(np.float32)
        # a segment beyond the table's range: nsub sub-segments, each within it
        nsub = np.where(l32 > smax[-1], np.ceil(l32 / smax[-1]), 1).astype(np.int64)
        centre = centre - (buf.time.reshape(-1) - np.float32(0.5))[:, None] * m32
    layer = layer_of(depth, *inv_range, nlayers)
    mlen = np.hypot(mot[:, 0], mot[:, 1])
    params = np.stack([np.abs(coc), mlen / nsub], -1) if rotate else np.abs(coc)[:, None]
    cells = grid(params)
    col = np.concatenate([buf.color.reshape(-1, 3), np.ones((len(depth), 1))], 1) / s
    for k in range(len(depth)):
        c = cells[k]
        if fast[c]:
            p, v, img = dpts[doffs[c]:doffs[c + 1]], dvals[doffs[c]:doffs[c + 1]], direct
        else:
            p, v, img = pts[offs[c]:offs[c + 1]], vals[offs[c]:offs[c + 1]], lap
        dx, dy = p[:, 0].astype(np.float32), p[:, 1].astype(np.float32)
        if rotate and mlen[k] > 0:
            # float32 like the kernel: rounding of rotated offsets must agree exactly
            mk = mot[k].astype(np.float32)
            cs, sn = mk / np.float32(np.hypot(*mk))
            dx, dy = np.rint(dx * cs - dy * sn), np.rint(dx * sn + dy * cs)
        n = int(nsub[k])
        for j in range(n):
            f = np.float32((np.float32(j) + np.float32(0.5)) / np.float32(n) - np.float32(0.5))
            cj = centre[k] + f * m32[k] if rotate else centre[k]
            cx, cy = np.floor(cj[0]) + pad, np.floor(cj[1]) + pad
            if not (reach <= cx < pw - reach and reach <= cy < ph - reach):
                continue
            x, y = (cx + dx).astype(np.int64), (cy + dy).astype(np.int64)
            np.add.at(img[layer[k]], (y, x), v[:, None] * (col[k] / n)[None, :])
    return lap, direct


def composite(prim: np.ndarray, direct: np.ndarray, pad: int, h: int, w: int,
              fill_cov: float = FILL_COV, color: np.ndarray | None = None) -> np.ndarray:
    """The ``composite`` pass: (H, W, 3) from the per-layer anchored integrals ``prim`` (the
    image, not the Laplacian) and direct images, back to front (layer 0 the farthest). A
    pixel no layer covers, or whose layers give black, takes the mean of its samples'
    ``color`` (H, W, S, 3) when given."""
    out = np.zeros((h, w, 3))
    alpha = np.zeros((h, w))
    filled = np.zeros((h, w), bool)
    for layer in range(prim.shape[0]):
        v = (prim[layer] + direct[layer])[pad:pad + h, pad:pad + w]
        rgb, cov = np.maximum(v[..., :3], 0.0), np.maximum(v[..., 3], 0.0)
        present = cov > COV_EPS
        colour = rgb / np.where(present, cov, 1.0)[..., None]
        fill = ~filled & (cov >= fill_cov)
        a = np.where(fill, 1.0, np.minimum(cov, 1.0))
        a = np.where(present, a, 0.0)
        out = a[..., None] * colour + (1.0 - a[..., None]) * out
        alpha = a + (1.0 - a) * alpha
        filled |= fill
    res = np.where(alpha[..., None] > 0, out / np.where(alpha > 0, alpha, 1.0)[..., None], 0.0)
    if color is None:
        return res
    # no layer covers the pixel, or what covers it is black: its own samples' mean
    hole = res.max(-1) <= 0
    return np.where(hole[..., None], np.maximum(color.astype(np.float64).mean(2), 0.0), res)
