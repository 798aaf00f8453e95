"""Image quality metrics of a linear HDR image against a reference.

Both images are linear radiance of shape ``(H, W, 3)`` (float32 or float64). Every metric
here is computed on the images after one fixed tone mapping, :func:`clrecon.io.tonemap_srgb`:
clip to ``[0, 1]``, then apply the piecewise sRGB OETF. PSNR, SSIM and FLIP are therefore
LDR measures of what a display shows: HDR highlights above 1 are clipped (a reference of 1.0
and a test of 5.0 are indistinguishable), and so are negative values (clipped to 0).

- :func:`psnr`: ``10 log10(1 / MSE)`` over all pixels and all 3 channels, data range 1;
  ``inf`` for identical (tone-mapped) images.
- :func:`ssim`: :func:`skimage.metrics.structural_similarity` with ``channel_axis=2`` and
  ``data_range=1.0``, uniform 7x7 window (shrunk for images smaller than 7 px on a side).
- :func:`flip`: mean LDR-FLIP (``flip_evaluator``, default 67 pixels per degree);
  :func:`flip_map` gives its per-pixel error map.

SSIM and FLIP need the optional dependencies (``pip install clrecon[eval]``); they are
imported on first use.
"""
from __future__ import annotations

import math

import numpy as np

from clrecon.io import tonemap_srgb

__all__ = ["psnr", "ssim", "flip", "flip_map", "evaluate"]

_EVAL_HINT = "pip install clrecon[eval]"


def _check_pair(test, ref) -> tuple[np.ndarray, np.ndarray]:
    """Validate the pair; return both as float64 arrays (not yet tone mapped)."""
    arrays = []
    for name, img in (("test", test), ("ref", ref)):
        arr = np.asarray(img)
        if arr.dtype.kind not in "fiu":
            raise ValueError(f"{name}: expected a real-valued image, got dtype {arr.dtype}")
        if arr.ndim != 3 or arr.shape[2] != 3:
            raise ValueError(f"{name}: expected shape (H, W, 3), got {arr.shape}")
        if arr.shape[0] < 1 or arr.shape[1] < 1:
            raise ValueError(f"{name}: empty image of shape {arr.shape}")
        arrays.append(arr.astype(np.float64, copy=False))
    t, r = arrays
    if t.shape != r.shape:
        raise ValueError(f"test and ref shapes differ: test {t.shape}, ref {r.shape}")
    for name, arr in (("test", t), ("ref", r)):
        bad = int((~np.isfinite(arr).all(axis=2)).sum())
        if bad:
            raise ValueError(
                f"{name} image has {bad} non-finite pixel{'s' if bad != 1 else ''}"
            )
    return t, r


def _tonemapped(test, ref) -> tuple[np.ndarray, np.ndarray]:
    t, r = _check_pair(test, ref)
    return (np.asarray(tonemap_srgb(t), np.float64),
            np.asarray(tonemap_srgb(r), np.float64))


def psnr(test: np.ndarray, ref: np.ndarray) -> float:
    """Peak signal-to-noise ratio in dB of the tone-mapped images (data range 1).

    Parameters
    ----------
    test, ref : numpy.ndarray
        Linear HDR images of shape ``(H, W, 3)``.

    Returns
    -------
    float
        ``10 log10(1 / MSE)`` with the MSE over all pixels and channels; ``inf`` when the
        tone-mapped images are identical.

    Raises
    ------
    ValueError
        If a shape is not ``(H, W, 3)``, the shapes differ, or a value is not finite.
    """
    t, r = _tonemapped(test, ref)
    mse = float(np.mean((t - r) ** 2))
    if mse == 0.0:
        return math.inf
    return 10.0 * math.log10(1.0 / mse)


def ssim(test: np.ndarray, ref: np.ndarray) -> float:
    """Mean structural similarity of the tone-mapped images.

    Uses :func:`skimage.metrics.structural_similarity` with ``channel_axis=2``,
    ``data_range=1.0`` and a uniform window of 7 px, or of the largest odd size that fits
    for images smaller than 7 px on a side.

    Parameters
    ----------
    test, ref : numpy.ndarray
        Linear HDR images of shape ``(H, W, 3)``.

    Returns
    -------
    float
        Mean SSIM; 1 for identical tone-mapped images.

    Raises
    ------
    ValueError
        On bad input (see :func:`psnr`), or an image smaller than 3 px on a side.
    ImportError
        If scikit-image is not installed.
    """
    try:
        from skimage.metrics import structural_similarity
    except ImportError as exc:
        raise ImportError(f"ssim needs scikit-image: {_EVAL_HINT}") from exc
    t, r = _tonemapped(test, ref)
    side = min(t.shape[0], t.shape[1])
    if side < 3:
        raise ValueError(
            f"image of shape {t.shape} is too small for SSIM (needs at least 3x3 pixels)"
        )
    win_size = min(7, side if side % 2 == 1 else side - 1)
    return float(
        structural_similarity(t, r, win_size=win_size, channel_axis=2, data_range=1.0)
    )


def flip_map(test: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """Per-pixel LDR-FLIP error of the tone-mapped images.

    Parameters
    ----------
    test, ref : numpy.ndarray
        Linear HDR images of shape ``(H, W, 3)``.

    Returns
    -------
    numpy.ndarray
        float32 error map of shape ``(H, W)``, values in ``[0, 1]`` (0: no visible error).

    Raises
    ------
    ValueError
        On bad input (see :func:`psnr`).
    ImportError
        If flip-evaluator is not installed.
    """
    return _flip(test, ref)[0]


def flip(test: np.ndarray, ref: np.ndarray) -> float:
    """Mean LDR-FLIP error of the tone-mapped images (0 for identical images).

    Parameters
    ----------
    test, ref : numpy.ndarray
        Linear HDR images of shape ``(H, W, 3)``.

    Returns
    -------
    float
        Mean of :func:`flip_map`.

    Raises
    ------
    ValueError
        On bad input (see :func:`psnr`).
    ImportError
        If flip-evaluator is not installed.
    """
    return _flip(test, ref)[1]


def _flip(test, ref) -> tuple[np.ndarray, float]:
    try:
        import flip_evaluator
    except ImportError as exc:
        raise ImportError(f"flip needs flip-evaluator: {_EVAL_HINT}") from exc
    t, r = _tonemapped(test, ref)
    error_map, mean, _params = flip_evaluator.evaluate(
        np.ascontiguousarray(r, np.float32),
        np.ascontiguousarray(t, np.float32),
        "LDR",
        inputsRGB=True,
        applyMagma=False,
    )
    error_map = np.asarray(error_map, np.float32).reshape(t.shape[:2])
    return error_map, float(mean)


def evaluate(test: np.ndarray, ref: np.ndarray) -> dict[str, float]:
    """All metrics at once.

    Parameters
    ----------
    test, ref : numpy.ndarray
        Linear HDR images of shape ``(H, W, 3)``.

    Returns
    -------
    dict
        ``{"psnr": float, "ssim": float, "flip": float}``.

    Raises
    ------
    ValueError
        On bad input (see :func:`psnr` and :func:`ssim`).
    ImportError
        If an optional metric dependency is missing.
    """
    _check_pair(test, ref)
    return {"psnr": psnr(test, ref), "ssim": ssim(test, ref), "flip": flip(test, ref)}
