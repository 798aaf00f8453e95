"""How well the safeguard's factor of the halves' variances matches the truth (issue 13).

The halves estimate box's variance as if the samples were independent; for stratified
samples that overstates it, and the safeguard scales it by a factor measured on the frame
(:func:`clrecon.methods.safeguard_reference.variance_scale`). This renders ``--seeds``
frames per (scene, spp) and prints, as factors of the halves' mean ``vb``:

* ``exact``: box's true variance (across the seeds, per pixel, mean over the frame) over the
  seeds' mean ``vb``: what a perfect factor would be;
* ``quarters``: the quarters' convergence alone (the factor until 2026-12-07);
* ``blurred``: over the pixels whose 3x3 neighbourhood is blurred by ``BLUR_MIN`` px or more,
  the 5-point Laplacian of ``box - m`` squared over 20 against ``vb`` (``m``: the method's
  image with ``safeguard=False``), and the share of such pixels;
* ``mixed``: the factor that was built and measured on 2026-12-07 (commit 56b914f, reverted:
  ``docs/measurements/convergence-pocl-128-spatial.md``): the blurred pixels' variance
  measured so, the others' ``vb`` scaled by the quarters' factor, over ``sum vb``.

Run: ``python tools/variance_factor_study.py [--size 128] [--spp 16,32,64] [--seeds 8]
[--method splat] [--scenes ...]``. Samples ``seed = 500 + 37 i + spp``. No reference
image is needed: the truth is the spread across seeds.
"""
from __future__ import annotations

import argparse

import numpy as np

import clrecon
from clrecon.bench.scripts import emit_page
from clrecon.core.device import get_device
from clrecon.methods.safeguard_reference import _lum2, halves, variance_scale
from clrecon.scenes.builtin import get_scene
from clrecon.scenes.render import render_samples

SCENES = ("fence", "spheres", "bokeh", "deep", "huge_coc", "fast_motion")
#: px: a pixel whose samples, and its 8 neighbours', are all blurred at least this much
BLUR_MIN = 2.0


def pixel_blur(depth: np.ndarray, motion, coc) -> np.ndarray:
    """Each pixel's smallest sample blur (H, W): the least ``max(|c0 / z + c1|, |motion|)``
    of its samples (CoC radius and motion length, px; a non-finite value counts as 0)."""
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        r = np.abs(coc[0] / np.asarray(depth, np.float64) + coc[1])
        if motion is not None:
            r = np.maximum(r, np.hypot(motion[..., 0], motion[..., 1]))
    return np.where(np.isfinite(r), r, 0.0).min(2)


def _blurred(color: np.ndarray, m: np.ndarray, blur: np.ndarray):
    """vb, |lap(box - m)|^2 / 20 and the blurred pixels (H, W; the border is never blurred:
    its Laplacian would leave the image)."""
    c = np.asarray(color, np.float64)
    ha, hb = halves(c.shape[2])
    vb = ha * hb / (ha + hb) ** 2 * _lum2(c[:, :, :ha].mean(2) - c[:, :, ha:].mean(2))
    r = c.mean(2) - m
    lap = 4 * r[1:-1, 1:-1] - r[:-2, 1:-1] - r[2:, 1:-1] - r[1:-1, :-2] - r[1:-1, 2:]
    h, w = blur.shape
    lv, mask = np.zeros((h, w)), np.zeros((h, w), bool)
    lv[1:-1, 1:-1] = _lum2(lap) / 20
    mask[1:-1, 1:-1] = np.min([blur[1 + dy:h - 1 + dy, 1 + dx:w - 1 + dx] for dy in (-1, 0, 1)
                               for dx in (-1, 0, 1)], axis=0) >= BLUR_MIN
    return vb, lv, mask


def blurred_ratio(color: np.ndarray, m: np.ndarray, blur: np.ndarray) -> tuple[float, float]:
    """(sum L / sum vb over the blurred pixels, their share of the frame); NaN without any."""
    vb, lv, mask = _blurred(color, m, blur)
    den = vb[mask].sum()
    share = float(mask.sum()) / blur.size
    return (float(lv[mask].sum() / den) if den > 0 else float("nan")), share


def mixed_factor(color: np.ndarray, m: np.ndarray, blur: np.ndarray) -> float:
    """``(sum_blurred L + s (sum vb - sum_blurred vb)) / sum vb`` clamped to [0, 1], ``s``
    the quarters' factor (:func:`variance_scale`); ``s`` where no pixel is blurred."""
    s = variance_scale(color)
    vb, lv, mask = _blurred(color, m, blur)
    tot, sbv = float(vb.sum()), float(vb[mask].sum())
    if not (sbv > 0 and tot > 0):
        return s
    return float(np.clip((float(lv[mask].sum()) + s * (tot - sbv)) / tot, 0.0, 1.0))


def study(dev, scene: str, size: int, spp: int, seeds: int, method: str) -> str:
    boxes, vbs, rows = [], [], []
    for i in range(seeds):
        buf = render_samples(get_scene(scene), size, size, spp, seed=500 + 37 * i + spp,
                             device=dev)
        c = buf.color.astype(np.float64)
        ha, hb = halves(spp)
        boxes.append(c.mean(2))
        vbs.append((ha * hb / spp ** 2 * _lum2(c[:, :, :ha].mean(2) - c[:, :, ha:].mean(2)))
                   .mean())
        m = clrecon.run(buf, method, dev, safeguard=False).image.astype(np.float64)
        cm = buf.coc_model
        blur = pixel_blur(buf.depth, buf.motion, (cm.c0, cm.c1))
        rows.append((variance_scale(buf.color), *blurred_ratio(buf.color, m, blur),
                     mixed_factor(buf.color, m, blur)))
    exact = np.var(np.array(boxes), axis=0, ddof=1).mean(-1).mean() / np.mean(vbs)
    q, br, share, mixed = np.nanmean(np.array(rows), axis=0)
    return (f"| {scene} | {spp} | {exact:.2f} | {q:.2f} | "
            f"{'-' if np.isnan(br) else f'{br:.2f}'} ({share:.0%}) | {mixed:.2f} |")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--spp", default="16,32,64")
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--method", default="splat", help="the method whose image is m")
    ap.add_argument("--scenes", default=",".join(SCENES))
    ap.add_argument("-o", "--output", default=None)
    args = ap.parse_args(argv)
    if args.seeds < 2:
        ap.error("--seeds: at least 2 (the truth is the spread across them)")
    dev = get_device(None)
    lines = [f"# The variances' factor against the truth ({args.size}x{args.size}, "
             f"{args.seeds} seeds, m: {args.method})", "",
             "| scene | spp | exact | quarters (shipped) | blurred (pixels) | mixed |",
             "|---|---|---|---|---|---|"]
    for scene in args.scenes.split(","):
        for spp in (int(s) for s in args.spp.split(",")):
            lines.append(study(dev, scene, args.size, spp, args.seeds, args.method))
            print(lines[-1], flush=True)
    emit_page(lines, args.output)


if __name__ == "__main__":
    main()
