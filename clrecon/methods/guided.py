"""The guided refinement (``guided=R``): every method's image of each half of the samples used
as the guide of a local linear regression of that half's box image (``kernels/guided.cl``),
then blended back toward the method's image where that is estimated the better
(``guide_blend``).

Why. A method's image is smooth but biased: its filters stand in for the true disc and
segment shapes, place layer boundaries, and widen or soften edges. The box image is unbiased
but noisy. Where the method's image is *structurally* right (its edges where the true edges
are, its gradients proportional to the true ones), the truth is, window by window, close to
an affine function of it, and the box image fixes that function's coefficients with the
noise of a window's worth of samples instead of one pixel's. This is He, Sun and Tang's guided
filter (2010; 2013 TPAMI) with the method's image as the guide and the box image as the
input, written on the residual so that its ridge pulls toward "the method is right up to a
local offset" rather than toward a flat image. Where the method's image is nearly
noise-free and unbiased (a wide blur of one surface: the regression's 12 coefficients from
``(2R+1)^2`` noisy pixels add noise there), the method's own image is the better estimate.

How. For each half h (samples ``0..ha-1``, ``ha..S-1``) with box image ``y`` and the method's
image ``g`` of the same half, per window ``k`` of ``(2R + 1)^2`` pixels (clipped to the image,
``n`` pixels), with ``u = g - g_k`` and the residual ``e = y - g``:

* ``A_k = (cov(u) + eps I)^-1 cov(u, e)`` (3x3: guide channel by output channel), ``beta_k =
  mean(e) - A_k^T mean(u)``, solved by Cholesky (float32: the cofactors of a guide whose
  channels move together, a grey texture, cancel);
* ``eps = var(y) / n``, ``var(y)`` the window's mean of the half's variance from the halves'
  difference (``var(yA) = hb/S |yA - yB|^2``, mean over RGB): the ridge of a prior whose
  coefficients are of the order of 1 (the method's error is of the order of its image),
  with ``n`` pixels of data. Floors of ``1e-5`` of the guide's variance and ``1e-12`` of
  the window's largest squared value keep a flat guide's system regular;
* ``q_p = g_p + mean over the windows k holding p of (A_k^T (g_p - g_k) + beta_k)``.
* ``guide_blend``: the safeguard's estimator (:mod:`clrecon.methods.safeguard`) run with the
  refined halves ``qA``, ``qB`` in box's place and the method's halves as the method gives
  a weight ``w`` per pixel; each half becomes ``q + w (g - q)`` (one weight for both, so the
  halves' difference still measures the variance).

The halves' images then replace the method's halves' images in the safeguard: its image is
their mean, its variance and bias estimates are theirs, and with ``safeguard`` on its blend
toward box keeps the result consistent. Each half's regression reads only that half's
samples and its own guide. No constant is fitted to scenes: ``R`` is the one knob (2 in
every setting shipped).

Range: each window is computed in units of its largest absolute value (guide, box and the
halves' difference), so squares of any valid colour stay finite.

Measured: ``docs/measurements/guided-pocl-512-8spp.md``.
"""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from clrecon.core import knobs
from clrecon.core.device import cpu_context, get_kernel
from clrecon.core.plan import Step
from clrecon.methods.safeguard_passes import halves
from clrecon.methods.safeguard_reference import MODE_BLEND, reference_of_halves

#: floats a window's coefficients take: A (3x3, row = guide channel), then beta (3)
COEF = 12
#: planes of the fit's input (``GP_PLANES`` in the kernel)
PLANES = 15
#: the radii the kernels are built for
RADII = range(1, 9)
#: the ridge's floors: relative to the guide's variance in the window, and to the square of
#: the window's largest absolute value (the kernel's unit)
RIDGE_FLOOR, ABS_FLOOR = 1e-5, 1e-12


def plane_pitch(width: int, height: int) -> int:
    """Floats from one of the fit's input planes to the next: the pixel count rounded up to
    4 KiB, plus 80 floats, so that the 15 planes start in 15 different L1 sets (planes a
    multiple of 4 KiB apart put a tap's seven loads in one set: the fit at 512x512 took 67 ms
    against 40 at 500x500)."""
    return -(-int(width) * int(height) // 1024) * 1024 + 80


def check_radius(r) -> int:
    """``r`` as a radius the refinement takes (0: off); ``ValueError`` otherwise."""
    return knobs.check_radius("guided", r, RADII, "window radius")


# -- NumPy reference -------------------------------------------------------------------------
def _windows(h: int, w: int, r: int):
    """Per pixel, the clipped window's row and column ranges."""
    ys = [(max(j - r, 0), min(j + r, h - 1) + 1) for j in range(h)]
    xs = [(max(i - r, 0), min(i + r, w - 1) + 1) for i in range(w)]
    return ys, xs


def refine(y: np.ndarray, g: np.ndarray, diff2: np.ndarray, f: float, r: int) -> np.ndarray:
    """The refined image of one half (float64): box image ``y`` and guide ``g`` (H, W, 3),
    ``diff2`` (H, W) the halves' squared difference (mean over RGB), ``f`` its share that is
    this half's variance, radius ``r``."""
    y, g, diff2 = (np.asarray(a, np.float64) for a in (y, g, diff2))
    var = f * diff2
    h, w, _ = y.shape
    ys, xs = _windows(h, w, r)
    coef = np.zeros((h, w, 4, 3))
    for j in range(h):
        for i in range(w):
            (a, b), (c, d) = ys[j], xs[i]
            u = (g[a:b, c:d] - g[j, i]).reshape(-1, 3)
            e = (y[a:b, c:d] - g[a:b, c:d]).reshape(-1, 3)
            n = len(u)
            mu, me = u.mean(0), e.mean(0)
            cu = u.T @ u / n - np.outer(mu, mu)
            ce = u.T @ e / n - np.outer(mu, me)
            # the kernel works in units of the window's largest absolute value s
            s = max(np.abs(g[a:b, c:d]).max(), np.abs(y[a:b, c:d]).max(),
                    np.sqrt(diff2[a:b, c:d].max()))
            if s == 0:
                continue
            eps = var[a:b, c:d].mean() / n + RIDGE_FLOOR * max(np.trace(cu), 0.0) + \
                ABS_FLOOR * s * s
            m = cu + eps * np.eye(3)
            A = np.linalg.solve(m, ce) if np.linalg.det(m) > 0 else np.zeros((3, 3))
            coef[j, i, :3] = A
            coef[j, i, 3] = me - A.T @ mu
    out = np.empty_like(g)
    for j in range(h):
        for i in range(w):
            (a, b), (c, d) = ys[j], xs[i]
            u = g[j, i] - g[a:b, c:d]  # (wy, wx, 3)
            A, beta = coef[a:b, c:d, :3], coef[a:b, c:d, 3]
            out[j, i] = g[j, i] + (np.einsum("yxk,yxkc->yxc", u, A) + beta).mean((0, 1))
    return out


def reference(color: np.ndarray, ga: np.ndarray, gb: np.ndarray, r: int):
    """(qA, qB): both halves' refined images from the samples' colours (H, W, S, 3) and the
    method's images of the halves (samples ``0..S//2-1`` and the rest); float64."""
    c = np.asarray(color, np.float64)
    ha, hb = halves(c.shape[2])
    ya, yb = c[:, :, :ha].mean(2), c[:, :, ha:].mean(2)
    d2 = ((ya - yb) ** 2).mean(-1)
    return (refine(ya, ga, d2, hb / (ha + hb), r), refine(yb, gb, d2, ha / (ha + hb), r))


# -- the passes ------------------------------------------------------------------------------
class GuidedPasses:
    """The three kernels of ``kernels/guided.cl`` for window radius ``r``."""

    def __init__(self, context: cl.Context, r: int, vw: int | None = None):
        """``vw``: windows a work-item of the fit (1, 8 or 16; default 8 on a CPU, where the
        sums run as the lanes of a float8, 1 elsewhere)."""
        self.r = check_radius(r)
        if self.r == 0:
            raise ValueError("guided: radius 0 is the refinement off; nothing to build")
        self.vw = (8 if cpu_context(context) else 1) if vw is None else int(vw)
        if self.vw not in (1, 8, 16):
            raise ValueError(f"guided: vector width {vw} is not 1, 8 or 16")
        defines = {"GR": self.r, "GF_VW": self.vw}
        self.means = get_kernel(context, "guided", "guided_means", defines)
        self.fit = get_kernel(context, "guided", "guided_fit", defines)
        self.apply = get_kernel(context, "guided", "guided_apply", defines)

    @staticmethod
    def temporaries(width: int, height: int) -> dict[str, int]:
        """Bytes of the refinement's buffers: the fit's input planes (both halves' guides and
        box images, their difference, the windows' scale), the windows' coefficients and the
        two refined images."""
        npx = int(width) * int(height)
        return {"guided_planes": PLANES * plane_pitch(width, height) * 4,
                "guided_coef": 2 * COEF * plane_pitch(width, height) * 4, "qa": npx * 12,
                "qb": npx * 12}

    def __call__(self, queue, color, ga, gb, planes, coef, qa, qb, w, h, spp, wait_for=None):
        """[("guided_means", ev), ("guided_fit", ev), ("guided_apply", ev)]."""
        ha, hb = halves(spp)
        ps = np.int32(plane_pitch(w, h))
        self.means.set_args(color, ga, gb, planes, np.int32(w), np.int32(h), np.int32(spp),
                            np.int32(ha), ps)
        ev0 = cl.enqueue_nd_range_kernel(queue, self.means, (w, h), None, wait_for=wait_for)
        self.fit.set_args(planes, coef, np.int32(w), np.int32(h), np.float32(hb / spp),
                          np.float32(ha / spp), ps)
        ev1 = cl.enqueue_nd_range_kernel(queue, self.fit, (-(-w // self.vw), h, 2), None,
                                         wait_for=[ev0])
        self.apply.set_args(planes, coef, qa, qb, np.int32(w), np.int32(h), ps)
        ev2 = cl.enqueue_nd_range_kernel(queue, self.apply, (-(-w // self.vw), h, 2), None,
                                         wait_for=[ev1])
        return [("guided_means", ev0), ("guided_fit", ev1), ("guided_apply", ev2)]

    def step(self) -> Step:
        """The plan's step: the halves' images ``ma``, ``mb`` refined into ``qa``, ``qb``
        with the frame's colours (its buffers: :meth:`temporaries`)."""
        def run(queue, f, wait_for):
            b = f.buffers
            return self(queue, b["color"], b["ma"], b["mb"], b["guided_planes"],
                        b["guided_coef"], b["qa"], b["qb"], f.width, f.height, f.spp, wait_for)
        return Step("guided", ("color", "ma", "mb"), ("qa", "qb"), run)


def chain_reference(color: np.ndarray, ga: np.ndarray, gb: np.ndarray, r: int,
                    guide_blend: bool = True):
    """(A, B): the halves' images the safeguard reads with ``guided=r``: the refinements of
    :func:`reference`, each blended toward its guide with the weight the safeguard's
    estimator gives the guide against the refinement (``guide_blend``); float64."""
    qa, qb = reference(color, ga, gb, r)
    if not guide_blend:
        return qa, qb
    _, _, w = reference_of_halves(qa, qb, *halves(color.shape[2]), None, ga, gb, MODE_BLEND)
    w = w[..., None]
    return qa + w * (ga - qa), qb + w * (gb - qb)
