"""The safeguard's NumPy reference (:mod:`clrecon.methods.safeguard` has the derivation):
the image and error estimate from the unbiased estimate's halves and the method's images,
in float64, as ``kernels/safeguard.cl`` computes them."""
from __future__ import annotations

from math import erfc, sqrt

import numpy as np

from clrecon.methods.safeguard_passes import (
    FDR_BINS,
    FDR_MODE_RADIUS,
    FDR_SCALE,
    halves,
    measures_convergence,
    models_covariance,
)

_FLT_MAX = float(np.finfo(np.float32).max)  # the error image saturates there

#: the blend kernel's modes
MODE_BOX, MODE_METHOD, MODE_BLEND = 0, 1, 2


# -- NumPy reference -------------------------------------------------------------------------
def _lum2(d: np.ndarray) -> np.ndarray:
    return (d.astype(np.float64) ** 2).mean(-1)


def _window_mean(a: np.ndarray, r: int) -> np.ndarray:
    """Mean over the (2r+1)^2 window, counting only pixels inside the image."""
    h, w = a.shape
    p = np.pad(a, r)
    ones = np.pad(np.ones_like(a), r)
    s = sum(p[dy:dy + h, dx:dx + w] for dy in range(2 * r + 1) for dx in range(2 * r + 1))
    n = sum(ones[dy:dy + h, dx:dx + w] for dy in range(2 * r + 1) for dx in range(2 * r + 1))
    return s / n


def _window_count(shape, r: int) -> np.ndarray:
    """How many pixels of the (2r+1)^2 window lie inside the image."""
    h, w = shape
    ones = np.pad(np.ones(shape), r)
    return sum(ones[dy:dy + h, dx:dx + w] for dy in range(2 * r + 1) for dx in range(2 * r + 1))


def variance_scale(color: np.ndarray) -> float:
    """The factor of the halves' variances, from the samples' colours (H, W, S, 3): 1 below
    16 spp (:func:`~clrecon.methods.safeguard_passes.measures_convergence`); else the
    frame's sum of the halves' squared differences over its quarters', each per unit of its
    independent-sample variance (``1/n0 + 1/n1``), clamped to [0, 1], or 1 where the
    quarters show no spread (``safeguard_ratio``)."""
    s = color.shape[2]
    if not measures_convergence(s):
        return 1.0
    c = np.asarray(color, np.float64)
    ha, hb = halves(s)
    dh = _lum2(c[:, :, :ha].mean(2) - c[:, :, ha:].mean(2)) / (1 / ha + 1 / hb)
    dq = 0.0
    for lo, n in ((0, ha), (ha, hb)):
        n0 = n // 2
        d = c[:, :, lo:lo + n0].mean(2) - c[:, :, lo + n0:lo + n].mean(2)
        dq = dq + 0.5 * _lum2(d) / (1 / n0 + 1 / (n - n0))
    sq = float(np.sum(dq))
    r = float(np.sum(dh)) / sq if sq > 0 else np.inf
    return float(np.clip(r, 0.0, 1.0)) if np.isfinite(r) else 1.0


def fdr_threshold(mu7: np.ndarray, var7: np.ndarray, q: float) -> float:
    """The 7x7 test's z at false discovery rate ``q`` (``kernels/safeguard_fdr.cl``): the
    lowest bin edge ``t = j / FDR_SCALE`` with ``N Q(t) <= q R(t)``, ``R(t)`` the pixels
    whose ``mu7 / se7`` (``se7^2 = var7``) is at least ``t`` (Benjamini-Hochberg, to the
    bins' resolution; ``Q`` the normal's upper tail), ``FDR_BINS / FDR_SCALE`` if none."""
    bins = _z_bins(mu7, var7)[mu7 > 0]
    r = np.cumsum(np.bincount(bins, minlength=FDR_BINS)[::-1])[::-1]
    for j in range(FDR_BINS):
        if mu7.size * 0.5 * erfc(j / FDR_SCALE / sqrt(2)) <= q * r[j]:
            return j / FDR_SCALE
    return FDR_BINS / FDR_SCALE


def _z_bins(mu7: np.ndarray, var7: np.ndarray) -> np.ndarray:
    """Each pixel's bin of ``|z| = |mu7| / se7`` (``fdr_bin`` of kernels/safeguard_vec.h;
    ``se7 = 0``: the last)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(var7 > 0, np.abs(mu7) / np.sqrt(np.where(var7 > 0, var7, 1.0)), np.inf)
    return np.where(z < FDR_BINS / FDR_SCALE, np.floor(z * FDR_SCALE),
                    FDR_BINS - 1).astype(np.int64)


#: the nulls :func:`shrink_table_of` takes: the shipped ``"normal"`` (the kernels'), and the
#: frame's negative means mirrored about its mode of z (``"mode"``) or about 0 (``"zero"``),
#: measured in ``tools/frame_shrink_study.py``
NULLS = ("normal", "mode", "zero")
#: the rates :func:`shrink_table_of` takes: Efron's local false discovery rate (measured, not
#: in the kernels: ``docs/measurements/frame-shrink-pocl.md``) and the tail area's q-value
#: (the kernels')
RATES = ("local", "tail")


def fdr_shrink_table(mu7: np.ndarray, var7: np.ndarray, noisy=None,
                     null: str = "normal", rate: str | None = None) -> np.ndarray:
    """The factors ``1 - fdr`` by bin of ``|z|`` (``kernels/safeguard_fdr.cl``:
    ``safeguard_fdr_shrink``; :func:`shrink_table_of`). ``rate="tail"`` (None; the
    kernels'): the q-value ``fdr_j = min over i <= j of min(1, N(t_i) / R(t_i))``, ``R(t)``
    the pixels with ``mu7 > 0`` and ``|z| >= t``, ``N(t)`` the count the frame's null
    expects there (1 where ``R(t) = 0``). ``rate="local"`` (measured in
    ``tools/frame_shrink_study.py``, not in the kernels): ``fdr_j = min over i <= j of
    min(1, f0(t_i) / f(t_i))``, the null's expected count in bin ``i`` over the frame's
    (Efron's local false discovery rate: the chance that a mean there is noise).
    ``noisy``: the pixels that count (None: all; the blend's, those whose 7x7 window of box
    shows noise: ``safeguard_fdr_rows``' ``noisy_only``)."""
    return shrink_table_of(z_histogram(mu7, var7, noisy), null, rate)


def z_histogram(mu7: np.ndarray, var7: np.ndarray, noisy=None) -> np.ndarray:
    """The frame's counts of ``|z|`` by sign as ``safeguard_fdr_rows`` and
    ``safeguard_fdr_sum`` lay them out (2 FDR_BINS: the positive means' bins, then the
    negative ones'); ``noisy`` as for :func:`fdr_shrink_table`."""
    j = _z_bins(mu7, var7)
    if noisy is not None:
        mu7 = np.where(noisy, mu7, 0.0)
    return np.concatenate([np.bincount(j[mu7 > 0], minlength=FDR_BINS),
                           np.bincount(j[mu7 < 0], minlength=FDR_BINS)])


def normal_null(smoothed: np.ndarray, total: int) -> tuple[float, float, float]:
    """``(mu, sigma, n0)`` of the frame's null of z, a normal matched to its histogram's
    central peak (Efron's empirical null): ``smoothed`` the signed bins' counts weighted by
    a triangle of +-:data:`FDR_MODE_RADIUS` bins. Its mode: the first peak bin ``k`` moved
    by the vertex of the parabola through it and its neighbours. ``sigma``: the half width
    at half maximum over ``sqrt(2 ln 2)``, the narrower side's, each side's the distance
    from ``k`` to where the counts fall below half the peak's, interpolated between the two
    bins about it (an end of the bins: the distance to one past it). A peak above 0 is the
    biased pixels', not the noise's, and so is its width: the null is then the theoretical
    one, centred at 0 with z's own unit spread, its height the counts' just below 0.
    ``n0``: the normal's count with the peak's height, at most the frame's ``total``. The
    interpolations keep the fit continuous in the counts: a count moved across a bin's
    edge (float32 sums against float64) moves it by a fraction of a bin."""
    w = np.asarray(smoothed, np.int64)
    n, k = w.size, int(np.argmax(w))
    if k >= FDR_BINS:
        mu, sigma, peak = 0.0, 1.0, int(w[FDR_BINS - 1])
    else:
        peak, off = int(w[k]), 0.0
        if 0 < k and w[k - 1] - 2 * peak + w[k + 1] < 0:
            off = 0.5 * float(w[k - 1] - w[k + 1]) / float(w[k - 1] - 2 * peak + w[k + 1])
        hw = float(n)
        for side in (-1, 1):
            idx = k + side * np.arange(1, n)
            idx = idx[(idx >= 0) & (idx < n)]
            below = np.nonzero(2 * w[idx] < peak)[0]
            if not below.size:
                hw = min(hw, float(idx.size + 1))
                continue
            d = int(below[0]) + 1  # bins from k to the first below half the peak
            hi, lo = float(w[k + side * (d - 1)]), float(w[k + side * d])
            hw = min(hw, d - 1 + (hi - 0.5 * peak) / (hi - lo))
        sigma = hw / (FDR_SCALE * sqrt(2.0 * np.log(2.0)))
        mu = min((k + off - FDR_BINS + 0.5) / FDR_SCALE, 0.0)
    n0 = min(peak / (FDR_MODE_RADIUS + 1) ** 2 * sigma * sqrt(2.0 * np.pi) * FDR_SCALE,
             float(total))
    return mu, sigma, n0


def signed_counts(hist: np.ndarray) -> np.ndarray:
    """The frame's counts by signed bin of z (2 FDR_BINS, z from ``-FDR_BINS / FDR_SCALE``
    up) from the kernels' layout (``|z|``'s bins of the positive means, then the negative
    ones')."""
    hist = np.asarray(hist, np.int64)
    return np.concatenate([hist[FDR_BINS:][::-1], hist[:FDR_BINS]])


def smoothed_counts(sc: np.ndarray) -> np.ndarray:
    """Signed counts weighted by the kernels' triangle of +-:data:`FDR_MODE_RADIUS` bins
    (``smoothed_count`` of ``kernels/safeguard_fdr.cl``), integers."""
    r = FDR_MODE_RADIUS
    return np.convolve(sc, r + 1 - np.abs(np.arange(-r, r + 1)))[r:r + 2 * FDR_BINS]


def mode_mirror(smoothed: np.ndarray) -> int:
    """The mirror of the ``"mode"`` null: signed bin ``k`` mirrors to ``m - k``, ``m`` twice
    the first peak bin of ``smoothed``, never past 0."""
    return min(2 * int(np.argmax(smoothed)), 2 * FDR_BINS - 1)


def shrink_table_of(hist: np.ndarray, null: str = "normal",
                    rate: str | None = None) -> np.ndarray:
    """:func:`fdr_shrink_table` from the frame's histogram as ``safeguard_fdr_rows`` lays it
    out, summed over rows (2 FDR_BINS counts: ``|z|``'s bins of the positive means, then of
    the negative ones). ``null``: ``"normal"`` (:func:`normal_null`, what the kernels
    compute), or the frame's negative means mirrored about its mode (``"mode"``, never
    above 0) or about 0 (``"zero"``): ``N(t)`` the means with ``z <= 2 mode - t`` (these
    two with ``rate="tail"`` only). ``rate``: ``"tail"`` (None; the kernels'), or
    ``"local"`` with the normal null (measured, not in the kernels): ``f(t_j)`` the frame's
    smoothed count in bin ``j`` (:func:`smoothed_counts` over the triangle's weight),
    ``f0(t_j)`` the normal's density at the bin's middle times the bin's width."""
    if null not in NULLS:
        raise ValueError(f"null: one of {NULLS}, got {null!r}")
    rate = "tail" if rate is None else rate
    if rate not in RATES or (rate == "local" and null != "normal"):
        raise ValueError(f"rate: one of {RATES} ({RATES[0]!r} with the normal null), got "
                         f"{rate!r} with {null!r}")
    b = FDR_BINS
    sc = signed_counts(hist)
    smoothed = smoothed_counts(sc)
    below = np.concatenate([[0], np.cumsum(sc)])  # below[i]: the bins < i
    top = np.arange(b)
    if null == "normal":
        mu, sigma, n0 = normal_null(smoothed, int(below[-1]))
    if rate == "local":  # the null's count in each bin against the frame's (smoothed) there
        u = ((top + 0.5) / FDR_SCALE - mu) / sigma
        neg = n0 * np.exp(-0.5 * u * u) / (sigma * sqrt(2.0 * np.pi) * FDR_SCALE)
        pos = smoothed[b:].astype(np.float64) / (FDR_MODE_RADIUS + 1) ** 2
    else:  # the null's count above each bin's edge against the frame's positive means there
        pos = below[2 * b] - below[b + top]
        if null == "normal":
            neg = n0 * 0.5 * np.array([erfc((t / FDR_SCALE - mu) / (sigma * sqrt(2.0)))
                                       for t in top])
        else:
            m = 2 * b - 1 if null == "zero" else mode_mirror(smoothed)
            neg = below[np.clip(m - b - top + 1, 0, 2 * b)]
    with np.errstate(divide="ignore", invalid="ignore"):
        fdr = np.where(pos > 0, np.minimum(1.0, neg / np.where(pos > 0, pos, 1)), 1.0)
    return 1.0 - np.minimum.accumulate(fdr)


def fdr_shrink(mu7: np.ndarray, var7: np.ndarray, noisy=None, null: str = "normal",
               rate: str | None = None):
    """``mu7`` scaled by its bin's factor (:func:`fdr_shrink_table`) where positive, else 0."""
    t = fdr_shrink_table(mu7, var7, noisy, null, rate)
    return np.where(mu7 > 0, mu7 * t[_z_bins(mu7, var7)], 0.0)


def reference(color: np.ndarray, m=None, ma=None, mb=None, mode: int = MODE_BLEND,
              z7: float = 0.0, test3: bool = True, cov: bool | None = None,
              vscale: float | None = None, fdr_q: float | None = None,
              frame_shrink: bool = False, null: str = "normal", rate: str | None = None):
    """(image, error) of the safeguard from the samples' colours (H, W, S, 3) and the
    method's images on the frame and on its halves (H, W, 3); float64. ``m=None`` (with
    the halves given): the method's image is the halves' mean ``(ha mA + hb mB) / S``.
    The halves' variances are scaled by ``vscale`` (None: :func:`variance_scale`, the
    frame's measured factor; 1: declared independent samples); ``cov`` (None: from 16 spp,
    as the pipeline: ``safeguard_passes.models_covariance``) and ``fdr_q`` as for
    :func:`reference_of_halves`, and ``frame_shrink``, ``null`` and ``rate``."""
    s = color.shape[2]
    ha, hb = halves(s)
    if m is None and ma is not None:
        m = (ha * ma.astype(np.float64) + hb * mb.astype(np.float64)) / s
    c = color.astype(np.float64)
    cov = models_covariance(s) if cov is None else bool(cov)
    return reference_of_halves(c[:, :, :ha].mean(2), c[:, :, ha:].mean(2), ha, hb, m, ma, mb,
                               mode, z7, variance_scale(c) if vscale is None else vscale,
                               test3, cov, fdr_q, frame_shrink, null, rate)[:2]


def window7(e: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(mu7, se7^2)``: each pixel's 7x7 mean of ``e`` and its squared standard error (the
    windows clipped to the image), as the blend and ``safeguard_fdr_rows`` take them."""
    mu7 = _window_mean(e, 3)
    return mu7, np.maximum(_window_mean(e * e, 3) - mu7 * mu7, 0.0) / _window_count(e.shape, 3)


def noisy7(vb: np.ndarray) -> np.ndarray:
    """The pixels whose 7x7 window of box shows noise (``vb`` not 0 throughout): those the
    frame's histogram of z counts (``safeguard_fdr_rows``' ``noisy_only``)."""
    return _window_mean(vb, 3) > 0


def bias_terms(a, b, ha: int, hb: int, m=None, ma=None, mb=None, vscale: float = 1.0,
               cov: bool = False):
    """``(box, vb, vm, e, m)`` of :func:`reference_of_halves` (float64): box and its
    variance ``vb`` from the halves ``a``, ``b``; with the method's halves, the method's
    variance ``vm``, each pixel's bias term ``e`` (``d2 - vm - vb``, with ``cov`` ``d2 + vm
    - vb``) and the method's image ``m`` (None: the halves' mean); else those three None."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    s = ha + hb
    box = (ha * a + hb * b) / s
    k = ha * hb / (s * s)
    vb = vscale * k * _lum2(a - b)
    if ma is None:
        return box, vb, None, None, None
    if m is None:
        m = (ha * ma.astype(np.float64) + hb * mb.astype(np.float64)) / s
    m = m.astype(np.float64)
    vm = vscale * k * _lum2(ma.astype(np.float64) - mb)
    d2 = _lum2(m - box)
    return box, vb, vm, (d2 + vm - vb if cov else d2 - vm - vb), m


def reference_of_halves(a, b, ha: int, hb: int, m=None, ma=None, mb=None,
                        mode: int = MODE_BLEND, z7: float = 0.0, vscale: float = 1.0,
                        test3: bool = True, cov: bool = False, fdr_q: float | None = None,
                        frame_shrink: bool = False, null: str = "normal",
                        rate: str | None = None):
    """(image, error, w) of the safeguard from the unbiased estimate's halves ``a``, ``b``
    ((H, W, 3): the samples' means of ``ha`` and ``hb`` samples, or any two independent
    half estimates, as the guided refinement's blend toward its guide takes) and the
    method's images; float64. ``w``: the blend's weight of the method (None unless
    ``mode`` is the blend). ``z7 > 0``: the 7x7 bias mean must stand ``z7`` standard errors
    above zero (the guided refinement's chain), as the 3x3 mean must stand 2; ``z7 < 0``: it
    is shrunk by its significance, ``mu7 max(0, 1 - se7^2 / mu7^2)`` (independent samples
    declared). ``vscale``:
    the factor of the halves' variances (:func:`variance_scale`; 1: independent samples).
    ``test3=False``: the bias term leaves the 3x3 test out (``safeguard_passes.bias_tests``).
    ``cov``: the covariance of the method's image and box added back, modelled as ``vm``:
    ``e = d2 + vm - vb`` (``safeguard_passes.models_covariance``). ``fdr_q``: the 7x7 test's
    z is :func:`fdr_threshold`'s at that rate (the guided chain), not ``z7``.
    ``frame_shrink``: the 7x7 mean scaled by the frame's q-value (:func:`fdr_shrink`; a
    method's own blend from 8 spp on undeclared samples), ``z7`` unused; ``null`` and
    ``rate``: its null and rate (:func:`shrink_table_of`; the kernels': ``"normal"``,
    ``"tail"``)."""
    if mode == MODE_BOX:
        box, vb = bias_terms(a, b, ha, hb, vscale=vscale)[:2]
        return box, np.minimum(_window_mean(vb, 1), _FLT_MAX), None
    box, vb, vm, e, m = bias_terms(a, b, ha, hb, m, ma, mb, vscale, cov)
    vb3 = _window_mean(vb, 1)
    mu3 = _window_mean(e, 1)
    n3 = _window_count(e.shape, 1)
    se3 = np.sqrt(np.maximum(_window_mean(e * e, 1) - mu3 * mu3, 0.0) / n3)
    mu7, var7 = window7(e)
    if frame_shrink:
        mu7 = fdr_shrink(mu7, var7, noisy7(vb), null, rate)
    elif z7 != 0 or fdr_q is not None:
        z7 = z7 if fdr_q is None else fdr_threshold(mu7, var7, fdr_q)
        with np.errstate(divide="ignore", invalid="ignore"):
            mu7 = mu7 - z7 * np.sqrt(var7) if z7 > 0 else \
                np.where(mu7 > 0, mu7 - var7 / np.where(mu7 > 0, mu7, 1.0), 0.0)
    b2 = np.maximum(0.0, np.maximum(mu7, mu3 - 2.0 * se3) if test3 else mu7)
    err_m = b2 + _window_mean(vm, 1)
    if mode == MODE_METHOD:
        return m, np.minimum(err_m, _FLT_MAX), None
    vbw = np.maximum(vb3, _window_mean(vb, 3))
    den = vbw + err_m
    w = np.where(den > 0, vbw / np.where(den > 0, den, 1), 0.0)
    img = box + w[..., None] * (m - box)
    return img, np.minimum(w * w * err_m + (1 - w) ** 2 * vbw, _FLT_MAX), w
