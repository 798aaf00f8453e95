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

Because each half's weights come from the other half, the safeguard after it (its bias test
against box, its blend) can treat the filtered halves as it treats any method's, so the
result stays consistent as samples grow (where the filter's averaging is a bias, the blend
moves toward box). They are not fully independent: half B's noise steers half A's weights
and moves B's own filtered value as well, so the halves' difference understates the
variance of their mean (0.9-1.6x at one scale, 1.6-2.1x at four; most of that variance is
the weights' own noise, so a fixed-weight propagation understates it more;
``docs/measurements/chain-safeguard-pocl.md``).

More scales (``nlm_scales=S``). The filter averages over (2R+1)^2 pixels, so noise whose
grain is coarser than that stays (low-frequency blotches on a far wall behind a defocused
object). With ``S > 1`` each filtered half ``n`` gets its low band from the same filter one
scale down: ``n + up2(m - d)``, ``d = down2(n)`` (2x2 means) and ``m`` the dual-buffer
filter of both halves' ``d`` (itself with its ``S - 2`` coarser scales); ``up2`` is nearest
then a [1/4, 1/2, 1/4] tent (:func:`multiscale`). Each coarser scale costs a quarter of the
one above.

Box too. With ``method="box"`` (or a method whose frame is planned as box: no blur beyond
the pixel) the halves are box's own, each half's samples' mean (``safeguard_box_halves``),
and the filter is Rousselle et al.'s on the renderer's samples, blended toward box by the
safeguard like any method's image. It knows nothing of depth or motion; where a method's
bias holds it near box at high spp (fast_motion at 64 spp, 512x512: box 43.55, the best
method 42.7, box with ``nlm=3`` 47.0 dB) it still averages what the halves show to be noise.

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
from clrecon.methods.guided import plane_pitch
from clrecon.methods.safeguard_passes import halves

#: Rousselle et al. 2012's damping of the noise in the distance
K = 0.45
#: the search radii the kernels are built for
RADII = range(1, 11)
#: the kernel's planes: A's RGB, B's RGB, v
PLANES = 7
#: the scales the filter runs at (``nlm_scales``): 1 the image's alone; each more one at
#: half the resolution of the last
SCALES = range(1, 7)
#: rows a work-item of the filter walks (its 8 columns are the lanes of a float8)
ROWS = 64


def check_radius(r) -> int:
    """``r`` as a search radius the filter takes (0: off); ``ValueError`` otherwise."""
    return knobs.check_radius("nlm", r, RADII, "search radius")


def check_scales(n) -> int:
    """``n`` as a number of scales (1..6); ``ValueError`` (``KnobTypeError`` for a
    non-integer) otherwise."""
    return knobs.check_int("nlm_scales", n, SCALES.start, SCALES.stop - 1)


def levels(width: int, height: int, scales: int) -> list[tuple[int, int]]:
    """The (width, height) of each coarser scale the filter runs at: halved (rounded down)
    from the last while it is at least 2 pixels in both directions."""
    out, w, h = [], int(width), int(height)
    while len(out) < scales - 1 and min(w, h) >= 2:
        w, h = w // 2, h // 2
        out.append((w, h))
    return out


def padded(width: int, height: int, r: int) -> tuple[int, int, int]:
    """(row pitch, rows, plane pitch) of the kernel's planes: the image with ``r + 1``
    pixels of replicated edge around it, the rows rounded up to the filter's 8 lanes; planes
    apart by the guided refinement's pitch (:func:`~clrecon.methods.guided.plane_pitch`: not
    a multiple of 4 KiB, so that seven loads of one pixel do not share an L1 set)."""
    pad = r + 1
    pw = -(-int(width) // 8) * 8 + 2 * pad
    ph = int(height) + 2 * pad
    return pw, ph, plane_pitch(pw, ph)


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


def down2(x: np.ndarray) -> np.ndarray:
    """2x2 means (an odd last row or column is left out)."""
    h, w = x.shape[0] // 2 * 2, x.shape[1] // 2 * 2
    x = x[:h, :w]
    return 0.25 * (x[0::2, 0::2] + x[1::2, 0::2] + x[0::2, 1::2] + x[1::2, 1::2])


def up2(x: np.ndarray, shape) -> np.ndarray:
    """``x`` at twice the resolution into ``shape`` (edge-replicated where ``shape`` is odd):
    nearest, then a [1/4, 1/2, 1/4] tent along each axis (edges replicated)."""
    y = np.repeat(np.repeat(x, 2, 0), 2, 1)
    h, w = shape[:2]
    y = np.pad(y, ((0, h - y.shape[0]), (0, w - y.shape[1])) + ((0, 0),) * (y.ndim - 2),
               mode="edge")
    for axis in (0, 1):
        p = np.pad(y, [(1, 1) if a == axis else (0, 0) for a in range(y.ndim)], mode="edge")
        lo = [slice(None)] * y.ndim
        mid, hi = list(lo), list(lo)
        lo[axis], mid[axis], hi[axis] = slice(0, -2), slice(1, -1), slice(2, None)
        y = 0.25 * p[tuple(lo)] + 0.5 * p[tuple(mid)] + 0.25 * p[tuple(hi)]
    return y


def multiscale(na: np.ndarray, nb: np.ndarray, spp: int, r: int, scales: int):
    """(A, B): the filtered halves ``na``, ``nb`` with their low bands from ``scales - 1``
    coarser filters: ``n - up2(down2(n)) + up2(m)``, ``m`` the filter (:func:`reference`)
    of ``down2`` of both halves, itself with its coarser scales (float64)."""
    na, nb = np.asarray(na, np.float64), np.asarray(nb, np.float64)
    if scales <= 1 or min(na.shape[:2]) < 2:
        return na, nb
    ca, cb = multiscale(*reference(down2(na), down2(nb), spp, r), spp, r, scales - 1)
    return (na - up2(down2(na), na.shape) + up2(ca, na.shape),
            nb - up2(down2(nb), nb.shape) + up2(cb, nb.shape))


# -- the passes ------------------------------------------------------------------------------
class NlmPasses:
    """The kernels of ``kernels/nlm.cl`` for search radius ``r`` at ``scales`` scales."""

    def __init__(self, context: cl.Context, r: int, scales: int = 1):
        self.r, self.scales = check_radius(r), check_scales(scales)
        if self.r == 0:
            raise ValueError("nlm: radius 0 is the filter off; nothing to build")
        defines = {"NR": self.r, "NLM_ROWS": ROWS}
        self.planes = get_kernel(context, "nlm", "nlm_planes", defines)
        self.filter = get_kernel(context, "nlm", "nlm_filter", defines)
        self.down = get_kernel(context, "nlm", "nlm_down", defines)
        self.merge = get_kernel(context, "nlm", "nlm_merge", defines)

    def temporaries(self, width: int, height: int) -> dict[str, int]:
        """Bytes of the filter's buffers: its padded planes (the image's: every coarser
        scale fits them), the two filtered halves, and per coarser scale its halves' 2x2
        means (``nl<k>a``, ``nl<k>b``) and their filtered images (``nm<k>a``, ``nm<k>b``)."""
        npx = int(width) * int(height)
        out = {"nlm_planes": PLANES * padded(width, height, self.r)[2] * 4,
               "na": npx * 12, "nb": npx * 12}
        for k, (w, h) in enumerate(levels(width, height, self.scales), 1):
            out |= {f"{n}{k}{x}": w * h * 12 for n in ("nl", "nm") for x in "ab"}
        return out

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

    def run_scales(self, queue, planes, na, nb, bufs, w, h, spp, wait_for=None):
        """The coarser scales on the filtered halves ``na``, ``nb`` (in place): down to the
        coarsest (2x2 means, the filter), then each scale merged into the one above it.
        ``bufs``: the temporaries of :meth:`temporaries` by name."""
        sizes = [(w, h)] + levels(w, h, self.scales)
        imgs = [(na, nb)] + [(bufs[f"nm{k}a"], bufs[f"nm{k}b"]) for k in range(1, len(sizes))]
        evs, wait = [], wait_for
        for k in range(1, len(sizes)):
            (fw, fh), (cw, ch) = sizes[k - 1], sizes[k]
            la, lb = bufs[f"nl{k}a"], bufs[f"nl{k}b"]
            self.down.set_args(*imgs[k - 1], la, lb, np.int32(fw), np.int32(fh))
            evs.append(("nlm", cl.enqueue_nd_range_kernel(queue, self.down, (cw, ch, 2), None,
                                                          wait_for=wait)))
            evs += self(queue, la, lb, planes, *imgs[k], cw, ch, spp, [evs[-1][1]])
            wait = [evs[-1][1]]
        for k in range(len(sizes) - 1, 0, -1):
            (fw, fh) = sizes[k - 1]
            self.merge.set_args(*imgs[k - 1], bufs[f"nl{k}a"], bufs[f"nl{k}b"], *imgs[k],
                                np.int32(fw), np.int32(fh))
            evs.append(("nlm", cl.enqueue_nd_range_kernel(queue, self.merge, (fw, fh, 2), None,
                                                          wait_for=wait)))
            wait = [evs[-1][1]]
        return evs

    def step(self, inputs: tuple[str, str]) -> Step:
        """The plan's step: the halves' images named ``inputs`` filtered into ``na``, ``nb``
        (its buffers: :meth:`temporaries`)."""
        def run(queue, f, wait_for):
            b = f.buffers
            evs = self(queue, b[inputs[0]], b[inputs[1]], b["nlm_planes"], b["na"], b["nb"],
                       f.width, f.height, f.spp, wait_for)
            return evs + self.run_scales(queue, b["nlm_planes"], b["na"], b["nb"], b,
                                         f.width, f.height, f.spp, [evs[-1][1]])
        return Step("nlm", tuple(inputs), ("na", "nb"), run)
