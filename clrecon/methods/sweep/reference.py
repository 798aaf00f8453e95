"""NumPy reference of the sweep reconstruction (Shirley et al. 2011), written to follow the
paper's Algorithm 2 and Appendices A and B literally; the kernels are tested against it.

Conventions shared with the kernels (and not fixed by the paper):

* ``x_i - x_c``: the sample's sensor ``position``, moved strictly inside its own pixel
  (clamped to ``[p + e, p + 1 - e]`` with ``e = max(2^-12, one float32 ulp)``), minus the pixel
  centre. So every sample lies in exactly the blocks its pixel belongs to, whether a kernel
  tests ``|x| < r`` or ``-r <= x < r``, and no pixel's 1x1 block is empty (a sample on a pixel
  corner, which validation accepts, would otherwise count for no pixel: 0/0 at 1 spp).
* The window of a pixel holds every sample of the ``(2R+1)^2`` pixels around it that lie in
  the image (R = 2 for two scales, 3 for four); pixels outside contribute nothing.
* Front-to-back order sorts on depth; ties (e.g. misses at ``inf``) keep window order: window
  pixels row-major from the top-left, then sample index. The depth's precision in the order
  is ``kernels/sweep_order.h``'s: :func:`depth_order_key`, its float32 bits without the
  ``shift`` lowest (default :data:`DEPTH_KEY_SHIFT`; 0: the exact order), so depths that
  agree in their top ``24 - shift`` significant bits are ties.
* Denoising diameter (the paper's default, a knob): ``D = scale * max(2 |coc(w)|, |motion|)``
  with the motion term only when motion is smoothed.
* ``exponent`` (the paper's 1.3 variant): each sample's weight ``w`` is raised to it before
  it enters ``cov`` and ``sum``; the coverage terms themselves are not. A weight that is not
  positive then weighs zero (Appendix B's can be negative where coverages sum past 1), as in
  the kernels.
* The three-layer depth-of-field variant: a sample's blend ``b = clamp((D - 1) / 5, 0, 1)``
  (Appendix A) splits it between a wide layer, with weight ``b``, and the narrow (in-focus)
  layer, with weight ``1 - b``; the wide layer is the near one when the sample is in front of
  the focus plane (``coc < 0``), the far one otherwise. Layers are combined front to back,
  near wide, narrow, far wide, each with Appendix A's update, in which the coverage terms
  stay constant within a layer. With no partial blends and depth-separated layers this is
  exactly Algorithm 2.
"""
from __future__ import annotations

import numpy as np

from clrecon.core.samples import SampleBuffer

#: low mantissa bits of a depth's float32 that the front-to-back order ignores
#: (``kernels/sweep_order.h``'s DEPTH_KEY_SHIFT default)
DEPTH_KEY_SHIFT = 12


def depth_order_key(z: np.ndarray, shift: int = DEPTH_KEY_SHIFT) -> np.ndarray:
    """The order's key of depths ``z`` (> 0 or inf; float32 values): their float32 bits
    shifted right by ``shift``, as ``sweep_depth_key`` in ``kernels/sweep_order.h``."""
    if not 0 <= shift <= 20:
        raise ValueError(f"shift: 0 (exact) to 20, got {shift}")
    return np.asarray(z, np.float32).view(np.uint32) >> np.uint32(shift)


def denoising_diameter(buf: SampleBuffer, smooth_motion: bool = True,
                       scale: float = 1.0) -> np.ndarray:
    """Per-sample denoising diameter in pixels, (H, W, S)."""
    d = 2.0 * np.abs(buf.coc().astype(np.float64))
    if smooth_motion:
        d = np.maximum(d, np.sqrt((buf.motion.astype(np.float64) ** 2).sum(-1)))
    return scale * d


def _box(x, radius):
    return np.where((x >= -radius) & (x < radius), 0.5 / radius, 0.0)


def _gather(buf: SampleBuffer, radius: int, diameter: np.ndarray,
            shift: int = DEPTH_KEY_SHIFT):
    """Window samples of every pixel in front-to-back order (:func:`depth_order_key` with
    ``shift``): dict of (H, W, N) arrays."""
    h, w, s = buf.shape
    k = 2 * radius + 1
    pad = [(radius, radius), (radius, radius), (0, 0)]
    ys, xs = np.mgrid[0:h, 0:w]
    def own(pos, p):  # strictly inside pixel p, in float32, as the kernels clamp
        p = p.astype(np.float32)
        e = np.float32(2.0 ** -12)
        lo = np.maximum(p + e, np.nextafter(p, np.float32(np.inf)))
        hi = np.minimum((p + 1) - e, np.nextafter(p + 1, np.float32(0)))
        return np.clip(pos, lo, hi)

    px = own(buf.position[..., 0], xs[..., None])
    py = own(buf.position[..., 1], ys[..., None])
    fields = {
        "x": np.pad(px.astype(np.float64), pad),
        "y": np.pad(py.astype(np.float64), pad),
        "z": np.pad(buf.depth.astype(np.float64), pad, constant_values=np.inf),
        "d": np.pad(diameter, pad),
        "valid": np.pad(np.ones((h, w, s), bool), pad),
        "r": np.pad(buf.color[..., 0].astype(np.float64), pad),
        "g": np.pad(buf.color[..., 1].astype(np.float64), pad),
        "b": np.pad(buf.color[..., 2].astype(np.float64), pad),
    }
    out = {}
    for name, arr in fields.items():
        parts = [arr[dy:dy + h, dx:dx + w] for dy in range(k) for dx in range(k)]
        out[name] = np.concatenate(parts, axis=-1)  # window row-major, then sample
    order = np.argsort(depth_order_key(out["z"], shift), axis=-1, kind="stable")
    out = {n: np.take_along_axis(a, order, -1) for n, a in out.items()}
    out["dx"] = out["x"] - (xs[..., None] + 0.5)
    out["dy"] = out["y"] - (ys[..., None] + 0.5)
    return out


def _raised(wgt, exponent: float):
    """A weight raised to ``exponent``: with ``exponent != 1`` a weight that is not positive
    (Appendix B's coverage can exceed 1 and make one negative) weighs zero, as the kernels'
    ``exp2(exponent * log2(w))`` for ``w > 0`` (a negative power would be NaN)."""
    if exponent == 1.0:
        return wgt
    return np.where(wgt > 0, np.abs(wgt) ** exponent, 0.0)


def sweep_two_scale(buf: SampleBuffer, diameter: np.ndarray, exponent: float = 1.0,
                    shift: int = DEPTH_KEY_SHIFT):
    """Appendix A: 1x1 and 5x5 blocks, blended. Returns (H, W, 3) float64."""
    g = _gather(buf, 2, diameter, shift)
    ns = buf.spp
    h, w = buf.height, buf.width
    cov_1, cov_5, cov = (np.zeros((h, w)) for _ in range(3))
    total = np.zeros((h, w, 3))
    for i in range(g["z"].shape[-1]):
        valid = g["valid"][..., i]
        x, y, big_d = g["dx"][..., i], g["dy"][..., i], g["d"][..., i]
        w_1 = np.where(valid, (1 / ns) * _box(x, 0.5) * _box(y, 0.5), 0.0)
        w_5 = np.where(valid, (1 / ns) * _box(x, 2.5) * _box(y, 2.5), 0.0)
        blend = np.clip((big_d - 1) / 5, 0, 1)
        wgt = blend * (w_5 * (1 - cov_1) + w_1 * cov_1)
        cov_5 = cov_5 + blend * (w_5 * (1 - cov_1))
        wgt = wgt + (1 - blend) * (w_1 * (1 - cov_5) + w_5 * cov_5)
        cov_1 = cov_1 + (1 - blend) * (w_1 * (1 - cov_5))
        wgt = _raised(wgt, exponent)
        cov = cov + wgt
        total += wgt[..., None] * np.stack([g["r"][..., i], g["g"][..., i], g["b"][..., i]], -1)
    return total / cov[..., None]


def sweep_four_scale(buf: SampleBuffer, diameter: np.ndarray, exponent: float = 1.0,
                     shift: int = DEPTH_KEY_SHIFT):
    """Appendix B: 1x1, 3x3, 5x5 and 7x7 blocks. Returns (H, W, 3) float64."""
    g = _gather(buf, 3, diameter, shift)
    ns = buf.spp
    h, w = buf.height, buf.width
    c1, c3, c5, c7, cov = (np.zeros((h, w)) for _ in range(5))
    total = np.zeros((h, w, 3))
    for i in range(g["z"].shape[-1]):
        valid = g["valid"][..., i]
        x, y, big_d = g["dx"][..., i], g["dy"][..., i], g["d"][..., i]
        w1, w3, w5, w7 = (np.where(valid, (1 / ns) * _box(x, r) * _box(y, r), 0.0)
                          for r in (0.5, 1.5, 2.5, 3.5))
        s7, s5, s3 = big_d > 7, (big_d > 5) & ~(big_d > 7), (big_d > 3) & ~(big_d > 5)
        s1 = ~(big_d > 3)
        wgt = (s7 * (w7 * (1 - c1 - c3 - c5) + w1 * c1 + w3 * c3 + w5 * c5)
               + s5 * (w5 * (1 - c1 - c3 - c7) + w1 * c1 + w3 * c3 + w7 * c7)
               + s3 * (w3 * (1 - c1 - c5 - c7) + w1 * c1 + w5 * c5 + w7 * c7)
               + s1 * (w1 * (1 - c3 - c5 - c7) + w3 * c3 + w5 * c5 + w7 * c7))
        n7 = c7 + s7 * w7 * (1 - c1 - c3 - c5)
        n5 = c5 + s5 * w5 * (1 - c1 - c3 - c7)
        n3 = c3 + s3 * w3 * (1 - c1 - c5 - c7)
        n1 = c1 + s1 * w1 * (1 - c3 - c5 - c7)
        c1, c3, c5, c7 = n1, n3, n5, n7
        wgt = _raised(wgt, exponent)
        cov = cov + wgt
        total += wgt[..., None] * np.stack([g["r"][..., i], g["g"][..., i], g["b"][..., i]], -1)
    return total / cov[..., None]


def sweep_dof_layers(buf: SampleBuffer, diameter: np.ndarray):
    """Sort-free three-layer variant (section 3.1) with Appendix A's 1x1/5x5 blend.

    Per layer L the sums ``S1 = sum b_L w_1``, ``S5 = sum b_L w_5`` and the same times
    colour; combined front to back (near wide, narrow, far wide)."""
    h, w, s = buf.shape
    ns = s
    coc = buf.coc().astype(np.float64)
    blend = np.clip((diameter - 1) / 5, 0, 1)
    member = {"near": np.where(coc < 0, blend, 0.0), "narrow": 1 - blend,
              "far": np.where(coc < 0, 0.0, blend)}
    col = buf.color.astype(np.float64)
    sums = {}
    for name, m in member.items():
        cnt = m.sum(-1)  # per-pixel membership; w_1 = 1/ns inside the pixel
        rgb = (m[..., None] * col).sum(-2)
        s1, c1 = cnt / ns, rgb / ns
        s5, c5 = _box_sum(cnt) / (25 * ns), _box_sum(rgb) / (25 * ns)
        sums[name] = (s1, s5, c1, c5)
    cov_1, cov_5, cov = (np.zeros((h, w)) for _ in range(3))
    total = np.zeros((h, w, 3))
    for name in ("near", "narrow", "far"):
        s1, s5, c1, c5 = sums[name]
        if name == "narrow":
            cov += (1 - cov_5) * s1 + cov_5 * s5
            total += (1 - cov_5)[..., None] * c1 + cov_5[..., None] * c5
            cov_1 = cov_1 + (1 - cov_5) * s1
        else:
            cov += (1 - cov_1) * s5 + cov_1 * s1
            total += (1 - cov_1)[..., None] * c5 + cov_1[..., None] * c1
            cov_5 = cov_5 + (1 - cov_1) * s5
    return total / cov[..., None]


def _box_sum(a, r: int = 2):
    """Sum over the (2r+1)^2 window (zero outside the image) of an (H, W[, C]) array."""
    pad = [(r, r), (r, r)] + [(0, 0)] * (a.ndim - 2)
    p = np.pad(a, pad)
    h, w = a.shape[:2]
    return sum(p[dy:dy + h, dx:dx + w] for dy in range(2 * r + 1) for dx in range(2 * r + 1))


def reconstruct(buf: SampleBuffer, scales: int = 2, dof_layers: bool = False,
                exponent: float = 1.0, smooth_motion: bool = True,
                diameter_scale: float = 1.0, exact_depth_order: bool = False) -> np.ndarray:
    """The whole method in NumPy (small inputs only: it loops over window samples)."""
    shift = 0 if exact_depth_order else DEPTH_KEY_SHIFT
    if dof_layers:
        d = denoising_diameter(buf, smooth_motion=False, scale=diameter_scale)
        return sweep_dof_layers(buf, d)
    d = denoising_diameter(buf, smooth_motion, diameter_scale)
    if scales == 2:
        return sweep_two_scale(buf, d, exponent, shift)
    if scales == 4:
        return sweep_four_scale(buf, d, exponent, shift)
    raise ValueError(f"scales: must be 2 or 4, got {scales}")
