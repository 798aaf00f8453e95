"""How far a hybrid of today's methods gets against Open Image Denoise (issue 13, item 4).

Every default (box and the three methods with the safeguard) returns its image and its own
per-pixel squared-error estimate (``estimate_error=True``). This measures, per scene:

* each default's PSNR, and OIDN high's on the box image;
* ``min r``: per pixel, the image of the default whose error estimate, averaged over the
  (2r+1)^2 window, is smallest;
* ``inv r``: per pixel, the defaults' images weighted by 1 / (that averaged estimate): the
  inverse-variance blend, exact for independent unbiased errors (these are neither: every
  default reads the same samples, so this is a heuristic, measured);
* ``oracle 8x8`` / ``oracle px``: the best default per 8x8 tile / per pixel by the *true*
  error (tone-mapped, PSNR's own), an upper bound of any selector of tiles / pixels among
  these images (not a setting).

The blends use no constant but the window radius, and none is fitted to the scenes. A hybrid
costs the sum of its members' times (each member also runs its halves), so it is only worth
building where it wins in quality; the page says where.

Run: ``python tools/hybrid_bound.py [--scenes fence,...] [--size 512x512] [--spp 8]
[--out docs/measurements/hybrid-bound-pocl-512-8spp.md]``. Samples ``seed = 100 + spp``;
references from the trusted device (PoCL).
"""
from __future__ import annotations

import argparse
from datetime import datetime, timezone

import numpy as np

import clrecon
from clrecon.bench.options import parse_size
from clrecon.bench.scripts import emit_page
from clrecon.core.device import get_device
from clrecon.io.image import tonemap_srgb
from clrecon.metrics import psnr
from clrecon.scenes.builtin import get_scene
from clrecon.scenes.render import render_reference, render_samples

METHODS = ("box", "sweep", "layered", "splat")
RADII = (0, 1, 3)


def window_mean(a: np.ndarray, r: int) -> np.ndarray:
    """Mean over the (2r+1)^2 window (edge pixels repeated) of each (H, W) plane of ``a``."""
    if r == 0:
        return a
    h, w = a.shape[-2:]
    p = np.pad(a, [(0, 0)] * (a.ndim - 2) + [(r, r), (r, r)], mode="edge")
    s = sum(p[..., dy:dy + h, dx:dx + w] for dy in range(2 * r + 1) for dx in range(2 * r + 1))
    return s / (2 * r + 1) ** 2


def pick(images: np.ndarray, index: np.ndarray) -> np.ndarray:
    """Per pixel, ``images[index]`` of a (K, H, W, 3) stack."""
    return np.take_along_axis(images, index[None, :, :, None].repeat(3, -1), 0)[0]


def measure(name: str, w: int, h: int, spp: int, oidn: bool, dev) -> dict[str, float]:
    """Every column of the page for one scene (PSNR in dB)."""
    scene = get_scene(name)
    ref = render_reference(scene, w, h)  # the trusted device's, never the one under test
    buf = render_samples(scene, w, h, spp, seed=100 + spp, device=dev)
    runs = [clrecon.run(buf, method=m, device=dev, estimate_error=True) for m in METHODS]
    images = np.stack([r.image.astype(np.float64) for r in runs])
    errors = np.stack([r.error.astype(np.float64) for r in runs])
    out = {m: psnr(images[k].astype(np.float32), ref) for k, m in enumerate(METHODS)}
    if oidn:
        import pyoidn

        box = np.ascontiguousarray(runs[0].image)
        out["oidn high"] = psnr(pyoidn.denoise(box, hdr=True, quality="high"), ref)
    for r in RADII:
        est = window_mean(errors, r)
        out[f"min {r}"] = psnr(pick(images, np.argmin(est, 0)).astype(np.float32), ref)
        wt = 1.0 / np.maximum(est, np.finfo(np.float32).tiny)
        wt /= wt.sum(0)
        out[f"inv {r}"] = psnr((wt[..., None] * images).sum(0).astype(np.float32), ref)
    # the oracles select by PSNR's own error (tone-mapped), so they bound every selector
    tm = np.asarray(tonemap_srgb(images.astype(np.float32)), np.float64)
    true = ((tm - np.asarray(tonemap_srgb(ref), np.float64)[None]) ** 2).mean(-1)
    tiles = true[:, :h // 8 * 8, :w // 8 * 8].reshape(len(METHODS), h // 8, 8, w // 8, 8)
    best = np.kron(np.argmin(tiles.mean((2, 4)), 0), np.ones((8, 8), int))
    px = np.argmin(true, 0)
    sel = px.copy()  # tiles, and the pixels past the last whole tile by pixel
    sel[:h // 8 * 8, :w // 8 * 8] = best
    out["oracle 8x8"] = psnr(pick(images, sel).astype(np.float32), ref)
    out["oracle px"] = psnr(pick(images, px).astype(np.float32), ref)
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", default="fence,spheres,bokeh,deep,huge_coc,fast_motion")
    ap.add_argument("--size", default="512x512")
    ap.add_argument("--spp", type=int, default=8)
    ap.add_argument("--no-oidn", action="store_true")
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    w, h = parse_size(args.size)
    dev = get_device(None)
    rows = []
    for name in args.scenes.split(","):
        rows.append((name, measure(name, w, h, args.spp, not args.no_oidn, dev)))
        print(f"{name}: done", flush=True)
    cols = list(rows[0][1])
    stamp = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    lines = [f"# A hybrid of the defaults against OIDN ({args.size}, {args.spp} spp)", "",
             f"`python tools/hybrid_bound.py --size {args.size} --spp {args.spp}` on "
             f"{dev.info.label}, {stamp}; samples seed {100 + args.spp}; PSNR in dB against "
             "the converged reference. `min r` / `inv r`: per pixel the default with the "
             "smallest / the defaults weighted by 1 / their own error estimate averaged over "
             "(2r+1)^2; the oracles select by the true error (bounds, not settings).", "",
             "| scene | " + " | ".join(cols) + " | best blend - best default | "
             "best blend - OIDN |",
             "|---|" + "---|" * (len(cols) + 2)]
    for name, out in rows:
        blend = max(v for k, v in out.items() if k.startswith(("min", "inv")))
        default = max(out[m] for m in METHODS)
        vs_oidn = f"{blend - out['oidn high']:+.2f}" if "oidn high" in out else "-"
        lines.append(f"| {name} | " + " | ".join(f"{out[c]:.2f}" for c in cols)
                     + f" | {blend - default:+.2f} | {vs_oidn} |")
    emit_page(lines, args.out)


if __name__ == "__main__":
    main()
