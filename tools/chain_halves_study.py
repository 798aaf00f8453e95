"""The final safeguard after the guided/nlm chain: what its halves tell it, and what it costs
at low spp (issue 13; measured, nothing here is shipped).

Two studies of ``clrecon.run(buf, "splat", guided=2, nlm=3, nlm_scales=4)`` (the quality end
of the trade), each run on the device, the rest in float64 on the host:

* ``--variances``: over ``--seeds`` independent frames, the true variance of the image the
  safeguard blends (the halves' mean ``m``, per pixel across the seeds, mean over the frame)
  against its estimate from the halves (``k |mA - mB|^2``, the same frames), per chain
  setting; and box's likewise. A ratio ``true / estimate`` of 1 is exact; independent
  halves of stratified samples give a little below 1 (box's own row).
* ``--blend``: on one frame per scene and spp (``seed = 100 + spp``, as ``clrecon trade``),
  PSNR of box, of ``m`` alone (no safeguard), of the final blend with and without its 3x3
  test (``3x3 test``, ``no 3x3``: the chain's 7x7 test alone, at the frame's z for the
  false discovery rate ``FDR_Q``; the library runs the first from 32 spp and the second
  below, ``bias_tests``; the host's blend is checked against the device's image; before
  2026-12-07 night the 7x7 test was at 2 standard errors), of one estimator change and of
  one bound:
  ``w other seed``: the ``3x3 test`` weights from an independent frame applied to this one
  (what the dependence between a frame's weights and its own box noise costs);
  ``oracle``: weights from the true squared errors of ``m`` and box, each averaged over the
  3x3 window (not a setting: the best this blend's form can do).
* ``--calibration``: ``clrecon.run(..., estimate_error=True)`` per chain setting on the same
  frames as ``--blend``: the frame's mean estimate over its true MSE (1: exact in the mean)
  and Spearman's rank correlation over 8x8 tiles (as ``clrecon errcheck``).

No constant here is fitted to the scenes. Run:
``python tools/chain_halves_study.py --variances --size 256 --spp 4 --seeds 8``;
``python tools/chain_halves_study.py --blend --size 512 --spp 4,8,16``;
``python tools/chain_halves_study.py --calibration --size 512 --spp 8``.
"""
from __future__ import annotations

import argparse
import json
from datetime import datetime, timezone

import numpy as np
import pyopencl as cl

import clrecon
from clrecon.bench.error_check import spearman, tile_means
from clrecon.bench.scripts import emit_page
from clrecon.core.device import get_device
from clrecon.core.pipeline import DeviceSamples
from clrecon.methods import safeguard as sg
from clrecon.methods.safeguard_passes import bias_tests, models_covariance
from clrecon.methods.safeguard_reference import (
    _lum2,
    _window_mean,
    halves,
    reference_of_halves,
    variance_scale,
)
from clrecon.metrics import psnr
from clrecon.scenes.builtin import get_scene
from clrecon.scenes.render import SAMPLERS, render_reference, render_samples

CHAIN = {"guided": 2, "nlm": 3, "nlm_scales": 4}
#: the chain settings of --variances (label, Safeguarded's flags)
SETTINGS = (("splat", {}), ("splat guided", {"guided": 2}), ("splat nlm3", {"nlm": 3}),
            ("splat guided nlm3x4", CHAIN))
SCENES = "fence,deep,bokeh,fast_motion,huge_coc,spheres"


def run_halves(dev, buf, flags: dict):
    """(device image, mA, mB, box halves a, b, ha, hb) of splat with ``flags`` (float64)."""
    pipe = sg.Safeguarded(dev.context, buf.inspect(), "splat", {}, **flags)
    s = DeviceSamples.upload(dev.queue, buf, pipe.fields)
    out = cl.Buffer(dev.context, cl.mem_flags.READ_WRITE, buf.width * buf.height * 12)
    pipe(dev.queue, s, out).wait()
    imgs = [np.empty((buf.height, buf.width, 3), np.float32) for _ in range(3)]
    for img, name in zip(imgs, (None,) + tuple(pipe.half_images)):
        cl.enqueue_copy(dev.queue, img, out if name is None else pipe.buffers[name])
    dev.queue.finish()
    c = buf.color.astype(np.float64)
    ha, hb = halves(c.shape[2])
    return ([i.astype(np.float64) for i in imgs]
            + [c[:, :, :ha].mean(2), c[:, :, ha:].mean(2), ha, hb])


def _var_across(xs: np.ndarray) -> np.ndarray:
    """Per pixel, the unbiased variance across the first axis (mean over RGB)."""
    return ((xs - xs.mean(0)) ** 2).mean(-1).sum(0) / (len(xs) - 1)


def variances(dev, scenes, size: int, spp: int, seeds: int,
              sampler: str = "lattice") -> list[str]:
    lines = ["| scene | setting | var(m) true | estimate | true / estimate | "
             "var(box) true / estimate |", "|---|---|---|---|---|---|"]
    for name in scenes:
        bufs = [render_samples(get_scene(name), size, size, spp, seed=5000 + 17 * i,
                               device=dev, sampler=sampler) for i in range(seeds)]
        for label, flags in SETTINGS:
            ms, boxes, vms, vbs = [], [], [], []
            for buf in bufs:
                _, ma, mb, a, b, ha, hb = run_halves(dev, buf, flags)
                k, s = ha * hb / (ha + hb) ** 2, ha + hb
                ms.append((ha * ma + hb * mb) / s)
                boxes.append((ha * a + hb * b) / s)
                vms.append(k * _lum2(ma - mb).mean())
                vbs.append(k * _lum2(a - b).mean())
            vm_true = _var_across(np.array(ms)).mean()
            vb_ratio = _var_across(np.array(boxes)).mean() / np.mean(vbs)
            lines.append(f"| {name} | {label} | {vm_true:.3e} | {np.mean(vms):.3e} | "
                         f"{vm_true / np.mean(vms):.2f} | {vb_ratio:.2f} |")
            print(lines[-1], flush=True)
    return lines


def _blend(a, b, ha, hb, ma, mb, vscale: float, with_3x3: bool):
    """The chain's blend (its 7x7 test at the frame's z for false discovery rate
    ``safeguard.FDR_Q``) with or without its 3x3 test (the safeguard's reference,
    ``test3``): its image and its weights."""
    img, _, w = reference_of_halves(a, b, ha, hb, None, ma, mb, sg.MODE_BLEND, sg.GUIDED_Z7,
                                    vscale, with_3x3, models_covariance(ha + hb), sg.FDR_Q)
    return img, w


def blend(dev, scenes, size: int, spps, sampler: str = "lattice") -> list[str]:
    cols = ("box", "m alone", "3x3 test", "no 3x3", "w other seed", "oracle")
    lines = ["| scene | spp | " + " | ".join(cols) + " | mean w |",
             "|---|---|" + "---|" * (len(cols) + 1)]
    for name in scenes:
        ref = render_reference(get_scene(name), size, size)
        for spp in spps:
            frames = []
            for seed in (100 + spp, 7777 + spp):
                buf = render_samples(get_scene(name), size, size, spp, seed=seed, device=dev,
                                     sampler=sampler)
                got, ma, mb, a, b, ha, hb = run_halves(dev, buf, CHAIN)
                vs = variance_scale(buf.color)
                frames.append((got, ma, mb, a, b, ha, hb, vs))
            got, ma, mb, a, b, ha, hb, vs = frames[0]
            s = ha + hb
            box, m = (ha * a + hb * b) / s, (ha * ma + hb * mb) / s
            img, w = _blend(a, b, ha, hb, ma, mb, vs, True)
            no3 = _blend(a, b, ha, hb, ma, mb, vs, False)[0]
            lib = img if bias_tests(True, spp)[1] else no3  # what the library runs
            if abs(psnr(lib.astype(np.float32), ref) - psnr(got.astype(np.float32), ref)) > .02:
                raise AssertionError(f"{name} {spp}: the host's blend is not the device's")
            w_other = _blend(*frames[1][3:5], ha, hb, *frames[1][1:3], frames[1][7], True)[1]
            tm, tb = _window_mean(_lum2(m - ref), 1), _window_mean(_lum2(box - ref), 1)
            w_oracle = tb / np.maximum(tb + tm, 1e-30)
            imgs = (box, m, img, no3,
                    box + w_other[..., None] * (m - box), box + w_oracle[..., None] * (m - box))
            cells = [f"{psnr(x.astype(np.float32), ref):.2f}" for x in imgs]
            lines.append(f"| {name} | {spp} | " + " | ".join(cells) + f" | {w.mean():.2f} |")
            print(lines[-1], flush=True)
    return lines


def calibration(dev, scenes, size: int, spps, sampler: str = "lattice") -> list[str]:
    lines = ["| scene | spp | setting | mean estimate / true MSE | Spearman (8x8 tiles) |",
             "|---|---|---|---|---|"]
    for name in scenes:
        ref = render_reference(get_scene(name), size, size).astype(np.float64)
        for spp in spps:
            buf = render_samples(get_scene(name), size, size, spp, seed=100 + spp, device=dev,
                                 sampler=sampler)
            for label, flags in SETTINGS:
                r = clrecon.run(buf, "splat", device=dev, estimate_error=True, **flags)
                true = _lum2(r.image.astype(np.float64) - ref)
                lines.append(f"| {name} | {spp} | {label} | {r.error.mean() / true.mean():.2f} "
                             f"| {spearman(tile_means(r.error), tile_means(true)):.3f} |")
                print(lines[-1], flush=True)
    return lines


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--variances", action="store_true")
    ap.add_argument("--blend", action="store_true")
    ap.add_argument("--calibration", action="store_true")
    ap.add_argument("--scenes", default=SCENES)
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--spp", default="4", help="comma-separated; --variances takes the first")
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--sampler", choices=SAMPLERS, default="lattice",
                    help="how the samples are drawn (render_samples): the tracer's lattice or "
                         "independent samples")
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    if not (args.variances or args.blend or args.calibration):
        ap.error("choose --variances, --blend and/or --calibration")
    if args.seeds < 2:
        ap.error("--seeds: at least 2 (a variance across seeds)")
    dev = get_device(None)
    scenes = args.scenes.split(",")
    spps = [int(x) for x in args.spp.split(",")]
    stamp = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    lines = [f"`python tools/chain_halves_study.py {' '.join(argv or [])}`".replace("  ", " "),
             f"on {dev.info.label}, {stamp}; chain {json.dumps(CHAIN)}; {args.sampler} samples.",
             ""]
    if args.variances:
        lines += [f"### Variances ({args.size}x{args.size}, {spps[0]} spp, {args.seeds} "
                  "seeds)", ""] + variances(dev, scenes, args.size, spps[0], args.seeds,
                                               args.sampler) + [""]
    if args.blend:
        lines += [f"### The final blend ({args.size}x{args.size}, PSNR dB)", ""] + blend(
            dev, scenes, args.size, spps, args.sampler) + [""]
    if args.calibration:
        lines += [f"### The error estimate ({args.size}x{args.size})", ""] + calibration(
            dev, scenes, args.size, spps, args.sampler) + [""]
    emit_page(lines, args.out)


if __name__ == "__main__":
    import sys
    main(sys.argv[1:])
