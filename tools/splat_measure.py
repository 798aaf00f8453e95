"""Measurements of method ``splat`` for docs/measurements/splat-pocl.md (a script, not a test).

    python tools/splat_measure.py --dir /tmp/splat [--repeats 5] [--parts ...]

Renders (once, cached in --dir) the 512x512 references, 4 and 16 spp buffers and pinhole
frames of bokeh, spheres and huge_coc and a 1024x1024 pinhole bokeh, then prints Markdown
tables: quality (SSIM, PSNR, FLIP against the converged reference) and device ms per pass
(median of --repeats warm runs; each variant's runs interleaved with the others').
"""
from __future__ import annotations

import argparse
import functools
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from clrecon.api import run
from clrecon.bench.timing import paired_rounds
from clrecon.io import load_image, load_samples, save_image, save_samples
from clrecon.metrics import evaluate
from clrecon.scenes import get_scene, render_reference, render_samples
from clrecon.scenes.render import render_pinhole


def inputs(d: Path, scene: str, size=(512, 512)):
    w, h = size
    tag = f"{scene}-{w}"
    sc = get_scene(scene)
    paths = {"ref": d / f"{tag}-ref.exr", "pin": d / f"{tag}-pin.npz",
             "4": d / f"{tag}-4.npz", "16": d / f"{tag}-16.npz"}
    if not paths["pin"].exists():
        save_samples(paths["pin"], render_pinhole(sc, w, h))
    if size == (512, 512):
        if not paths["ref"].exists():
            save_image(paths["ref"], render_reference(sc, w, h))
        for spp in ("4", "16"):
            if not paths[spp].exists():
                save_samples(paths[spp], render_samples(sc, w, h, int(spp), seed=0))
    return paths


def measure(buf, variants: dict, repeats: int, ref=None):
    """Interleaved warm runs of every variant (:func:`clrecon.bench.timing.paired_rounds`);
    median device ms per pass and quality."""
    calls = {k: functools.partial(run, buf, method, **knobs)
             for k, (method, knobs) in variants.items()}
    for call in calls.values():  # warm-up (builds, tables)
        call()
    rows = {}
    for k, results in zip(calls, paired_rounds(list(calls.values()), repeats)):
        passes: dict[str, list[float]] = {}
        for res in results:
            for p, v in res.pass_ms.items():
                passes.setdefault(p, []).append(v)
        last = results[-1]
        q = evaluate(last.image, ref) if ref is not None else {}
        rows[k] = {"ms": statistics.median(r.device_ms for r in results),
                   "passes": {p: statistics.median(v) for p, v in passes.items()},
                   "method": last.method, **q}
    return rows


def table(title: str, rows: dict) -> str:
    out = [f"\n### {title}\n",
           "| variant | SSIM | PSNR dB | FLIP | device ms (median) | per pass ms |",
           "|---|---|---|---|---|---|"]
    for k, r in rows.items():
        q = (f"{r['ssim']:.4f} | {r['psnr']:.2f} | {r['flip']:.4f}" if "ssim" in r
             else "- | - | -")
        per = ", ".join(f"{p} {v:.1f}" for p, v in r["passes"].items())
        out.append(f"| {k} | {q} | {r['ms']:.1f} | {per} |")
    return "\n".join(out)


SPLAT = {"splat sparse": ("splat", {}), "splat dense": ("splat", {"dense": True})}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--dir", default="/tmp/splat")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--parts", default="synthesis,reconstruction,huge,big")
    args = ap.parse_args(argv)
    d = Path(args.dir)
    d.mkdir(parents=True, exist_ok=True)
    parts = args.parts.split(",")
    print(f"<!-- {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, repeats "
          f"{args.repeats} -->")
    if "synthesis" in parts:
        for scene in ("bokeh", "spheres"):
            p = inputs(d, scene)
            ref = load_image(p["ref"])
            buf = load_samples(p["pin"])
            rows = measure(buf, {**SPLAT, "splat sparse f5": ("splat", {"pyramid": "f5"}),
                                 "pinhole as is (box)": ("box", {})}, args.repeats, ref)
            print(table(f"synthesis: {scene} 512x512 pinhole", rows), flush=True)
    if "reconstruction" in parts:
        for scene in ("spheres", "bokeh"):
            p = inputs(d, scene)
            ref = load_image(p["ref"])
            b4, b16 = load_samples(p["4"]), load_samples(p["16"])
            rows = measure(b4, {"splat sparse 4 spp": ("splat", {}),
                                "box 4 spp": ("box", {})}, args.repeats, ref)
            rows |= measure(b16, {"box 16 spp": ("box", {})}, args.repeats, ref)
            print(table(f"reconstruction: {scene} 512x512", rows), flush=True)
    if "huge" in parts:
        p = inputs(d, "huge_coc")
        ref = load_image(p["ref"])
        rows = measure(load_samples(p["pin"]), SPLAT, args.repeats, ref)
        print(table("huge_coc 512x512 synthesis (pinhole): sparse vs dense", rows), flush=True)
        rows = measure(load_samples(p["4"]), SPLAT, max(1, args.repeats // 2), ref)
        print(table("huge_coc 512x512 reconstruction (4 spp): sparse vs dense", rows),
              flush=True)
    if "big" in parts:
        p = inputs(d, "bokeh", (1024, 1024))
        buf = load_samples(p["pin"])
        rows = measure(buf, {"splat sparse, 2 layers": ("splat", {"layers": 2}),
                             "splat sparse, 2 layers, f5": ("splat", {"layers": 2,
                                                                     "pyramid": "f5"})},
                       args.repeats)
        print(table("bokeh 1024x1024 synthesis, 2 layers (time target <= 1500 ms)", rows),
              flush=True)
    return 0


if __name__ == "__main__":
    np.seterr(all="ignore")
    sys.exit(main())
