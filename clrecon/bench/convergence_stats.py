"""The convergence study's numbers: the bias/variance split of a setting's error across
seeds (:func:`bias_variance`), the reference's own noise (:func:`reference_noise`), the sample
seeds (:func:`sample_seed`) and, per setting of a scene, how its error falls with the samples
(:func:`summarize`). Pure NumPy: no device."""
from __future__ import annotations

import math
from typing import Any

import numpy as np


def sample_seed(index: int, spp: int) -> int:
    """The sample seed of seed index ``index`` at ``spp``: ``1000 (index + 1) + spp``,
    independent across spp and seeds and never a reference's seed (1 or 2; spp < 1000)."""
    return 1000 * (int(index) + 1) + int(spp)


def bias_variance(images, ref) -> dict[str, Any]:
    """MSE of ``n >= 2`` images of one estimator against ``ref``, split into bias² and
    variance (linear values; mean over pixels and channels).

    Parameters
    ----------
    images : array_like, shape (n, H, W, 3)
        Independent estimates (different sample seeds).
    ref : array_like, shape (H, W, 3)

    Returns
    -------
    dict
        ``mse`` (mean over images of their MSE), ``bias2`` (``mean((m - ref)^2) - variance
        / n``, ``m`` the mean image: unbiased, may be slightly negative), ``variance`` (mean
        of the per-pixel sample variance, ``ddof=1``), ``mse_seed`` (each image's MSE),
        ``bias_share`` (``bias2 / mse``, clipped to [0, 1]), ``bias2_se`` (the standard
        error of ``bias2`` were the pixels independent: the spread of the per-pixel terms
        over the root of their count, which also counts the bias's own spread across
        pixels, so it errs large); ``mse == bias2 + variance``.
    """
    x = np.asarray(images, np.float64)
    r = np.asarray(ref, np.float64)
    if x.ndim != 4 or x.shape[1:] != r.shape or r.ndim != 3:
        raise ValueError(f"images: expected (n, H, W, 3) with ref (H, W, 3), got {x.shape} "
                         f"and {r.shape}")
    n = x.shape[0]
    if n < 2:
        raise ValueError(f"images: need at least 2 (seeds) to split bias from variance, got {n}")
    mse_seed = ((x - r) ** 2).mean(axis=(1, 2, 3))
    var_px = x.var(axis=0, ddof=1)
    d = (((x.mean(axis=0) - r) ** 2) - var_px / n).mean(axis=2)  # per pixel: mean is bias2
    variance = float(var_px.mean())
    bias2 = float(d.mean())
    mse = float(mse_seed.mean())
    return {"mse": mse, "bias2": bias2, "variance": variance,
            "bias2_se": float(d.std(ddof=1) / math.sqrt(d.size)) if d.size > 1 else math.inf,
            "mse_seed": [float(v) for v in mse_seed],
            "bias_share": float(min(max(bias2 / mse, 0.0), 1.0)) if mse > 0 else 0.0}


def reference_noise(a, b) -> float:
    """Variance of one reference from two of independent seeds: ``mean((a - b)^2) / 2``."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    if a.shape != b.shape:
        raise ValueError(f"references differ in shape: {a.shape} and {b.shape}")
    return float(((a - b) ** 2).mean() / 2)


def by_setting(rows: list[dict]) -> dict[str, dict[int, dict]]:
    """The rows of one scene as ``{setting: {spp: row}}``."""
    table: dict[str, dict[int, dict]] = {}
    for r in rows:
        table.setdefault(r["setting"], {})[r["spp"]] = r
    return table


#: a setting is flat from the spp where doubling the samples gains less than this share
FLAT_GAIN = 0.2


def summarize(rows: list[dict]) -> list[dict]:
    """Per setting of one scene: the MSE ratio per doubling of spp over the last two spp
    (0.5: falling like 1/spp; 1: not improving), ``flat_from`` (the smallest spp from which
    every further doubling lowers the MSE by less than :data:`FLAT_GAIN`; ``None``: not in
    range), the bias share at the largest spp, and the smallest spp from which box's MSE is
    below the setting's (``None``: never in range)."""
    table = by_setting(rows)
    box = table.get("box", {})
    out = []
    for label, cells in table.items():
        spps = sorted(k for k, r in cells.items() if "mse" in r)
        item = {"setting": label, "per_doubling": None, "flat_from": None,
                "bias_share_top": None, "box_better_from": None}
        ratios = []
        for lo, hi in zip(spps, spps[1:]):
            a, b = cells[lo]["mse"], cells[hi]["mse"]
            ratios.append((b / a) ** (1.0 / math.log2(hi / lo)) if a > 0 else math.nan)
        if ratios:
            item["per_doubling"] = ratios[-1]
            for i in range(len(ratios)):
                if all(r > 1 - FLAT_GAIN for r in ratios[i:]):
                    item["flat_from"] = spps[i]
                    break
        if spps:
            item["bias_share_top"] = cells[spps[-1]]["bias_share"]
        if label != "box":
            for spp in spps:
                if spp in box and "mse" in box[spp] and box[spp]["mse"] < cells[spp]["mse"]:
                    item["box_better_from"] = spp
                    break
        out.append(item)
    return out
