"""Where the error against the converged reference sits, per method and region (why OIDN wins).

Usage: ``python tools/oidn_gap.py [--scenes fence,deep,bokeh,fast_motion]
[--size 512x512] [--spp 8] [--methods box,sweep,layered,splat] [--no-oidn]``.

Every pixel falls in one region, decided from its own samples:

* ``sharp``: every sample in focus (|CoC| < 0.75 px) and still (|motion| < 1 px), one depth;
* ``blurred``: one depth (max depth <= 1.1 x min depth) but some defocus or motion;
* ``mixed``: samples at different depths (occlusion edges, partial coverage).

For each method: the whole-frame MSE of the tone-mapped image (what PSNR measures), and per
region its share of the squared error and its mean squared error. OIDN runs on the box image
(``pyoidn``, CPU, hdr, quality high), as in ``clrecon trade``. Prints a Markdown table.
"""
from __future__ import annotations

import argparse

import numpy as np

import clrecon
from clrecon.bench.options import parse_size
from clrecon.core.device import get_device
from clrecon.io import tonemap_srgb
from clrecon.scenes import get_scene, render_reference, render_samples

REGIONS = ("sharp", "blurred", "mixed")


def regions(buf) -> dict[str, np.ndarray]:
    coc = np.abs(buf.coc()).max(-1)
    motion = np.sqrt((buf.motion.astype(np.float64) ** 2).sum(-1)).max(-1)
    mixed = buf.depth.max(-1) > 1.1 * buf.depth.min(-1)
    sharp = (coc < 0.75) & (motion < 1.0) & ~mixed
    return {"sharp": sharp, "blurred": ~sharp & ~mixed, "mixed": mixed}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", default="fence,deep,bokeh,fast_motion")
    ap.add_argument("--size", default="512x512")
    ap.add_argument("--spp", type=int, default=8)
    ap.add_argument("--methods", default="box,sweep,layered,splat")
    ap.add_argument("--no-oidn", action="store_true")
    ap.add_argument("--seed", type=int, default=108)
    args = ap.parse_args()
    w, h = parse_size(args.size)
    dev = get_device(None)
    print(f"{args.size}, {args.spp} spp, samples seed {args.seed}; MSE of the sRGB image; "
          "share = the region's part of the frame's squared error\n")
    print("| scene | method | PSNR dB | " + " | ".join(
        f"{r}: pixels, share, MSE" for r in REGIONS) + " |")
    print("|---|---|---|" + "---|" * len(REGIONS))
    for name in args.scenes.split(","):
        scene = get_scene(name)
        buf = render_samples(scene, w, h, args.spp, seed=args.seed, device=dev)
        ref = tonemap_srgb(render_reference(scene, w, h))  # on the trusted device
        reg = regions(buf)
        images = {m: clrecon.reconstruct(buf, m, device=dev) for m in args.methods.split(",")}
        if not args.no_oidn:
            import pyoidn

            box = images.get("box")
            if box is None:
                box = clrecon.reconstruct(buf, "box", device=dev)
            images["oidn high"] = pyoidn.denoise(np.ascontiguousarray(box), hdr=True,
                                                 quality="high")
        for method, img in images.items():
            err = ((tonemap_srgb(img) - ref) ** 2).mean(-1)
            total = float(err.sum())
            psnr = 10 * np.log10(1.0 / max(float(err.mean()), 1e-30))
            cells = []
            for r in REGIONS:
                m = reg[r]
                if not m.any():
                    cells.append("0% -")
                    continue
                cells.append(f"{m.mean() * 100:.0f}%, {err[m].sum() / total * 100:.0f}%, "
                             f"{err[m].mean():.1e}")
            print(f"| {name} | {method} | {psnr:.2f} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
