"""Quality of an image sequence against its reference sequence: per-frame PSNR, SSIM and FLIP,
and a flicker figure.

Flicker is what a viewer sees of frame-to-frame noise: the error of the frame-to-frame
differences against the reference's own differences, on the same tone mapping as every
other metric (:func:`clrecon.io.tonemap_srgb`). With ``T`` the tone mapping, test frames
``x_t`` and reference frames ``r_t``::

    d_t     = (T(x_t) - T(x_{t-1})) - (T(r_t) - T(r_{t-1}))      t = 1 .. N-1
    flicker = sqrt(mean over t, pixels, channels of d_t^2)        (RMSE, display units)
    temporal_psnr = 10 log10(1 / mean(d_t^2))                     (dB, higher is steadier)

A method whose displayed error is the same in every frame has no flicker (its differences
match the reference's; a linear bias is only approximately that after the tone mapping's
curve); per-frame noise that does not repeat shows up at about sqrt(2) times its
per-frame RMSE. Motion that the reference shows is not counted as flicker.
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from clrecon.io import tonemap_srgb
from clrecon.metrics import evaluate


def flicker(test: Sequence[np.ndarray], ref: Sequence[np.ndarray]) -> dict[str, float]:
    """``{"flicker_rmse", "temporal_psnr"}`` of two equally long sequences (>= 2 frames)."""
    if len(test) != len(ref):
        raise ValueError(f"sequences differ in length: {len(test)} test, {len(ref)} reference "
                         "frames")
    if len(test) < 2:
        raise ValueError(f"flicker needs at least 2 frames, got {len(test)}")
    total, count = 0.0, 0
    prev = None
    for k, (x, r) in enumerate(zip(test, ref)):
        x, r = np.asarray(x, np.float64), np.asarray(r, np.float64)
        if x.shape != r.shape or x.ndim != 3 or x.shape[2] != 3:
            raise ValueError(f"frame {k}: test {x.shape} and reference {r.shape} must both be "
                             "(H, W, 3)")
        cur = (np.asarray(tonemap_srgb(x), np.float64), np.asarray(tonemap_srgb(r), np.float64))
        if prev is not None:
            if prev[0].shape != cur[0].shape:
                raise ValueError(f"frame {k}: shape {cur[0].shape} differs from frame {k - 1}'s "
                                 f"{prev[0].shape}")
            d = (cur[0] - prev[0]) - (cur[1] - prev[1])
            total += float(np.square(d).sum())
            count += d.size
        prev = cur
    mse = total / count
    return {"flicker_rmse": math.sqrt(mse),
            "temporal_psnr": math.inf if mse == 0 else 10.0 * math.log10(1.0 / mse)}


def compare_sequences(test: Sequence[np.ndarray], ref: Sequence[np.ndarray],
                      names: Sequence[str] | None = None) -> dict:
    """Per-frame metrics (``evaluate``) and the flicker of the whole sequence."""
    names = list(names) if names is not None else [str(k) for k in range(len(test))]
    if len(names) != len(test):
        raise ValueError(f"names: {len(names)} for {len(test)} frames")
    frames = [{"frame": n} | evaluate(x, r) for n, x, r in zip(names, test, ref)]
    out = {"frames": frames,
           "mean_psnr": float(np.mean([f["psnr"] for f in frames])),
           "mean_ssim": float(np.mean([f["ssim"] for f in frames])),
           "mean_flip": float(np.mean([f["flip"] for f in frames]))}
    if len(test) >= 2:
        out |= flicker(test, ref)
    return out
