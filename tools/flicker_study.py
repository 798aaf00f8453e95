"""Temporal stability of every method on animated built-in scenes (per-frame quality and
flicker, :mod:`clrecon.temporal`), with box and Open Image Denoise high as baselines.

Usage: ``.venv/bin/python tools/flicker_study.py [--scenes fence fast_motion]
[--frames 8] [--size 256x256] [--spp 8] [--ref-spp 1024] [-o docs/measurements/flicker.md]``

Each frame ``k`` is ``clrecon.scenes.animate.frame_of(scene, k)`` (objects and a camera pan
moving continuously, the shutter spanning the frame) rendered with its own seed; references
are rendered at ``--ref-spp`` with one seed per frame as well, so their own noise (about
``sqrt(spp / ref_spp)`` of box's) is part of every figure.
"""
from __future__ import annotations

import argparse
import sys

import numpy as np

import clrecon
from clrecon.bench.options import parse_size
from clrecon.bench.scripts import emit_page
from clrecon.core.device import get_device
from clrecon.scenes import get_scene, render_reference, render_samples
from clrecon.scenes.animate import frame_of, frame_seed
from clrecon.temporal import compare_sequences

SETTINGS = [("box", "box", {}), ("sweep", "sweep", {}),
            ("sweep dof_layers", "sweep", {"dof_layers": True}), ("layered", "layered", {}),
            ("splat", "splat", {})]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=["fence", "fast_motion"])
    ap.add_argument("--frames", type=int, default=8)
    ap.add_argument("--size", default="256x256")
    ap.add_argument("--spp", type=int, default=8)
    ap.add_argument("--ref-spp", type=int, default=1024)
    ap.add_argument("-o", "--output", default=None)
    a = ap.parse_args(argv)
    w, h = parse_size(a.size)
    dev = get_device()
    try:
        import pyoidn
    except ImportError:
        pyoidn = None
    lines = [f"# Flicker: animated scenes, {w}x{h}, {a.spp} spp, {a.frames} frames", "",
             f"Command: `.venv/bin/python tools/flicker_study.py --scenes "
             f"{' '.join(a.scenes)} --frames {a.frames} --size {a.size} --spp {a.spp} "
             f"--ref-spp {a.ref_spp}`. Device: {dev.info.label}.", "",
             "`flicker` is the RMSE (display units, sRGB-encoded [0, 1]) of frame-to-frame "
             "differences against the reference's own; `tPSNR` the same as dB. Lower "
             "flicker, higher tPSNR: steadier. References carry their own noise at "
             f"{a.ref_spp} spp.", "",
             "| scene | setting | mean PSNR | mean SSIM | mean FLIP | flicker | tPSNR |",
             "|---|---|---|---|---|---|---|"]
    for name in a.scenes:
        scene = get_scene(name)
        bufs, refs = [], []
        for k in range(a.frames):
            sk = frame_of(scene, k)
            print(f"{name}: frame {k + 1}/{a.frames}", file=sys.stderr)
            bufs.append(render_samples(sk, w, h, a.spp, seed=frame_seed(0, k), device=dev))
            refs.append(render_reference(sk, w, h, a.ref_spp, seed=frame_seed(1, k)))
        rows = [(label, [clrecon.reconstruct(b, m, dev, **kn) for b in bufs])
                for label, m, kn in SETTINGS]
        if pyoidn is not None:
            rows.append(("OIDN high", [pyoidn.denoise(clrecon.reconstruct(b, "box", dev),
                                                      hdr=True, quality="high")
                                       for b in bufs]))
        for label, imgs in rows:
            q = compare_sequences([np.asarray(i, np.float32) for i in imgs], refs)
            lines.append(f"| {name} | {label} | {q['mean_psnr']:.2f} | {q['mean_ssim']:.4f} | "
                         f"{q['mean_flip']:.4f} | {q['flicker_rmse']:.4f} | "
                         f"{q['temporal_psnr']:.2f} |")
            print(lines[-1], file=sys.stderr)
    emit_page(lines, a.output)


if __name__ == "__main__":
    main()
