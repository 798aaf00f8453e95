"""Dual-buffer non-local means on the safeguard's halves (``nlm=R``; ``kernels/nlm.cl``).

Why. A method's filters are tied to the physical blur: where the blur is a few pixels wide
and the surface behind it has texture finer than the blur (a far checkered wall behind a
defocused object), the method averages a few hundred samples per pixel and its image keeps
a fine grain that the true image does not have. A denoiser that knows nothing of the blur
averages further wherever the image looks flat; the method cannot, because its support is
the blur's. The halves know how noisy each pixel of the method's image is, so the image
can be averaged further exactly where its differences are noise.

How (Rousselle, Knaus and Zwicker 2012, "Adaptive rendering with non-local means
filtering", with its dual buffers). The two halves' images ``A`` and ``B`` (the method's,
or the guided refinement's) are independent. ``v`` is the 3x3 mean (clipped) of
``|A - B|^2`` (mean over RGB); ``var(A) = fa v`` and ``var(B) = fb v`` with ``fa = hb / S``,
``fb = ha / S`` (for equal halves ``|A - B|^2 / 2`` each). Each half is averaged over the
``(2R + 1)^2`` pixels ``q`` around ``p`` with weights from the *other* half ``g``:

* ``t(s, s') = (|g_s - g_s'|^2 - (v_s + min(v_s, v_s'))) / (k^2 (v_s + v_s'))`` (mean over
  RGB, ``v`` the guide's variance): the squared difference less its expected noise, in
  units of that noise; where both variances are 0, ``t`` is 0 for equal colours and
  ``+inf`` otherwise (no noise estimate, no averaging across a difference);
* ``D2(p, q)``: the mean of ``t(s, s + q - p)`` over the 3x3 patch of ``s`` around ``p``
  (clipped to the image); the weight ``exp(-max(0, D2))``, 0 where ``D2`` is NaN, 1 for
  ``q = p``; coordinates off the image clamp to its edge.

Because each half's weights come from the other half, the filtered halves stay independent
and their difference still measures the variance: the safeguard after it (its bias test
against box, its blend) sees the filtered halves as it sees any method's, so the result
stays consistent as samples grow (where the filter's averaging is a bias, the blend moves
toward box).

Constants: ``k = 0.45`` and the 3x3 patch are Rousselle et al.'s; ``R`` is the knob (the
trade lists 3 and 5: 5 the cheapest of the radii measured, 3, 4, 5 and 7, that kept the
gains on every scene, 3 at less than half its cost; ``docs/measurements/nlm-pocl.md``).
Range: the kernel squares colour differences in float32, so its weights are those of the
float64 reference for colours between about 1e-15 and 1e15 (tested); a difference whose
square underflows counts as none (equal pixels), one whose square overflows as infinitely
far (weight 0: the pixel keeps its own value), and the image stays finite at any valid
colour.
"""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from clrecon.core import knobs
from clrecon.core.device import get_kernel
from clrecon.core.plan import Step
from clrecon.methods.safeguard_passes import halves

#: Rousselle et al. 2012's damping of the noise in the distance
K = 0.45
#: the search radii the kernels are built for
RADII = range(1, 11)
#: the kernel's planes: A's RGB, B's RGB, v
PLANES = 7
#: rows a work-item of the filter walks (its 8 columns are the lanes of a float8)
ROWS = 64


def check_radius(r) -> int:
    """``r`` as a search radius the filter takes (0: off); ``ValueError`` otherwise."""
    return knobs.check_radius("nlm", r, RADII, "search radius")


def padded(width: int, height: int, r: int) -> tuple[int, int, int]:
    """(row pitch, rows, plane pitch) of the kernel's planes: the image with ``r + 1``
    pixels of replicated edge around it, the rows rounded up to the filter's 8 lanes; planes
    a multiple of 1024 floats plus 80 apart (not a multiple of 4 KiB: seven loads of one
    pixel would share an L1 set)."""
    pad = r + 1
    pw = -(-int(width) // 8) * 8 + 2 * pad
    ph = int(height) + 2 * pad
    return pw, ph, -(-pw * ph // 1024) * 1024 + 80


# -- NumPy reference -------------------------------------------------------------------------
def _clamped(a: np.ndarray, dy: int, dx: int) -> np.ndarray:
    """``a[clamp(y + dy), clamp(x + dx)]`` over the image."""
    h, w = a.shape[:2]
    return a[np.clip(np.arange(h) + dy, 0, h - 1)][:, np.clip(np.arange(w) + dx, 0, w - 1)]


def _patch_mean(t: np.ndarray) -> np.ndarray:
    """3x3 mean over the window clipped to the image."""
    h, w = t.shape
    acc, n = np.zeros_like(t), np.zeros_like(t)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            ys = np.arange(h) + dy
            xs = np.arange(w) + dx
            ok = ((ys >= 0) & (ys < h))[:, None] & ((xs >= 0) & (xs < w))[None, :]
            acc += np.where(ok, _clamped(t, dy, dx), 0.0)
            n += ok
    return acc / n


def _filter(u: np.ndarray, g: np.ndarray, vg: np.ndarray, r: int) -> np.ndarray:
    acc, wsum = np.zeros_like(u), np.zeros(u.shape[:2])
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        for dy in range(-r, r + 1):
            for dx in range(-r, r + 1):
                gq, vq = _clamped(g, dy, dx), _clamped(vg, dy, dx)
                dd = ((g - gq) ** 2).mean(-1)
                den = K * K * (vg + vq)
                t = np.where(den == 0, np.where(dd > 0, np.inf, 0.0),
                             (dd - (vg + np.minimum(vg, vq))) / np.where(den == 0, 1, den))
                d2 = _patch_mean(t)
                w = np.where(np.isnan(d2), 0.0, np.exp(-np.maximum(d2, 0.0)))
                if dy == 0 and dx == 0:
                    w = np.ones_like(w)
                acc += w[..., None] * _clamped(u, dy, dx)
                wsum += w
    return acc / wsum[..., None]


def reference(a: np.ndarray, b: np.ndarray, spp: int, r: int):
    """(A', B'): both halves' images filtered, each with the other's weights (float64);
    ``a``, ``b`` (H, W, 3) the halves' images of a frame of ``spp`` samples."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    ha, hb = halves(spp)
    v = _patch_mean(((a - b) ** 2).mean(-1))
    return (_filter(a, b, (ha / spp) * v, r), _filter(b, a, (hb / spp) * v, r))


# -- the passes ------------------------------------------------------------------------------
class NlmPasses:
    """The two kernels of ``kernels/nlm.cl`` for search radius ``r``."""

    def __init__(self, context: cl.Context, r: int):
        self.r = check_radius(r)
        if self.r == 0:
            raise ValueError("nlm: radius 0 is the filter off; nothing to build")
        defines = {"NR": self.r, "NLM_ROWS": ROWS}
        self.planes = get_kernel(context, "nlm", "nlm_planes", defines)
        self.filter = get_kernel(context, "nlm", "nlm_filter", defines)

    def temporaries(self, width: int, height: int) -> dict[str, int]:
        """Bytes of the filter's buffers: its padded planes and the two filtered halves."""
        npx = int(width) * int(height)
        return {"nlm_planes": PLANES * padded(width, height, self.r)[2] * 4,
                "na": npx * 12, "nb": npx * 12}

    def __call__(self, queue, ua, ub, planes, na, nb, w, h, spp, wait_for=None):
        """[("nlm", ev), ("nlm", ev)]: ``na``, ``nb`` from the halves' images ``ua``,
        ``ub`` (H, W, 3) of a frame of ``spp`` samples."""
        ha, hb = halves(spp)
        pw, ph, ps = padded(w, h, self.r)
        self.planes.set_args(ua, ub, planes, np.int32(w), np.int32(h), np.int32(pw),
                             np.int32(ph), np.int32(ps))
        ev0 = cl.enqueue_nd_range_kernel(queue, self.planes, (pw, ph), None,
                                         wait_for=wait_for)
        self.filter.set_args(planes, na, nb, np.int32(w), np.int32(h), np.int32(pw),
                             np.int32(ps), np.float32(hb / spp), np.float32(ha / spp),
                             np.float32(K * K))
        # independent work-items, one a group (PoCL's own group shape: the same time, 119
        # against 122 ms at 512x512)
        ev1 = cl.enqueue_nd_range_kernel(queue, self.filter, (-(-w // 8), -(-h // ROWS), 2),
                                         (1, 1, 1), wait_for=[ev0])
        return [("nlm", ev0), ("nlm", ev1)]

    def step(self, inputs: tuple[str, str]) -> Step:
        """The plan's step: the halves' images named ``inputs`` filtered into ``na``, ``nb``
        (its buffers: :meth:`temporaries`)."""
        def run(queue, f, wait_for):
            b = f.buffers
            return self(queue, b[inputs[0]], b[inputs[1]], b["nlm_planes"], b["na"], b["nb"],
                        f.width, f.height, f.spp, wait_for)
        return Step("nlm", tuple(inputs), ("na", "nb"), run)
