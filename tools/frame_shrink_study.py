"""The 7x7 bias mean scaled by the frame's q-value, against the other forms a method's own
blend can take, on the methods' device halves (issue 13).

Each scene is rendered at each spp (``render_samples(seed=SEED + spp)``, ``--seed``
default 100, the lattice or
independent samples); every method's default runs on the device and its halves' images
``mA``, ``mB`` are read back; the blend is then recomputed on the host in float64 by the
safeguard's NumPy reference (``clrecon.methods.safeguard_reference``) with the 7x7 mean:

* ``untested``: as it comes (the lattice's form from 16 spp until 2026-12-08);
* ``2 se``: tested at 2 standard errors (every form below 8 spp, declared independent
  samples' below 16);
* ``shrink``: shrunk by its significance, ``mu7 max(0, 1 - se7^2 / mu7^2)`` (independent
  samples declared, from 16 spp);
* ``q normal``: scaled by ``1 - q``, ``q`` the frame's false discovery rate at the mean's
  significance with a normal null matched to the frame's histogram of z (its central peak:
  Efron's empirical null), the undeclared samples' form from 8 spp
  (``safeguard_passes.shrinks_by_frame``, since 2026-12-08);
* ``local``: scaled by ``1 - fdr``, ``fdr`` the frame's local false discovery rate in the
  mean's bin of z (the null's expected count in the bin over the frame's smoothed count,
  least of any bin at or below), the same null (measured, not in the kernels);
* ``q about 0``: the same with the frame's negative means as the null, mirrored about 0;
* ``q about mode``: the same mirrored about the frame's mode of ``z`` (the lattice's form at
  8-15 spp on 2026-12-07).
* ``q no3``: ``q normal`` without the 3x3 test (the guided chain's form below 32 spp).

The halves' variances are scaled as the pipeline scales them: the lattice's by its measured
convergence from 16 spp, independent samples' not at all. PSNR dB against the converged
reference; each form's change against the first in brackets, and the mean, least and most
change per spp at the end. Nothing here is fitted to the scenes.
Run: ``python tools/frame_shrink_study.py [--size 512] [--spp 8,16,64] [--sampler random]
[--figures DIR --figure-method splat]`` (the figures: each form's image and squared error).
"""
from __future__ import annotations

import argparse
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
from safeguard_variants import METHODS, halves_images

import clrecon.api  # noqa: F401  (registers the methods)
from clrecon.bench.figures import pyplot, save_png
from clrecon.bench.scripts import emit_page
from clrecon.core.device import get_device
from clrecon.methods import safeguard as sg
from clrecon.methods import safeguard_reference as sr
from clrecon.methods.safeguard_passes import (
    FDR_BINS,
    FDR_SCALE,
    bias_tests,
    models_covariance,
    shrinks_by_frame,
)
from clrecon.methods.safeguard_reference import halves, reference_of_halves, variance_scale
from clrecon.metrics import psnr
from clrecon.scenes.builtin import get_scene
from clrecon.scenes.render import render_reference, render_samples

SCENES = "fence,spheres,bokeh,deep,huge_coc,fast_motion"
FORMS = {"untested": {}, "2 se": {"z7": sg.GUIDED_Z7}, "shrink": {"z7": sg.SHRINK_Z7},
         "q normal": {"frame_shrink": True},
         "local": {"frame_shrink": True, "rate": "local"},
         "q about 0": {"frame_shrink": True, "null": "zero"},
         "q about mode": {"frame_shrink": True, "null": "mode"},
         "q no3": {"frame_shrink": True, "test3": False}}


def pipeline_form(spp: int) -> str:
    """The form a method's own blend takes on stratified samples (``bias_tests``,
    ``shrinks_by_frame``)."""
    return "2 se" if bias_tests(False, spp)[0] else (
        "q normal" if shrinks_by_frame(False, spp) else "untested")


def measure(name: str, size: int, spp: int, sampler: str, forms, dev, ref, seed: int,
            images: dict | None = None):
    """{method: {form: PSNR}} and box's PSNR for one frame. On the lattice the form the
    pipeline takes is checked against the device's own image (to 0.02 dB). ``images``: a
    dict that receives each (method, form)'s image, each (method, "z")'s histogram of the
    frame's 7x7 bias means' z (``safeguard_reference.z_histogram``), and ``"box"``."""
    buf = render_samples(get_scene(name), size, size, spp, seed=seed + spp, device=dev,
                         sampler=sampler)
    c = buf.color.astype(np.float64)
    ha, hb = halves(spp)
    a, b = c[:, :, :ha].mean(2), c[:, :, ha:].mean(2)
    vscale = 1.0 if sampler == "random" else variance_scale(c)
    out = {}
    for method in METHODS:
        imgs = halves_images(dev, buf, method)
        if imgs is None:
            continue
        got, ma, mb = imgs
        row = {}
        for f in forms:
            img = reference_of_halves(a, b, ha, hb, None, ma, mb, sg.MODE_BLEND, vscale=vscale,
                                      cov=models_covariance(spp), **FORMS[f])[0]
            row[f] = psnr(img.astype(np.float32), ref)
            if images is not None:
                images[method, f] = img
        if images is not None:
            _, vb, _, e, _ = sr.bias_terms(a, b, ha, hb, None, ma, mb, vscale,
                                           models_covariance(spp))
            images[method, "z"] = sr.z_histogram(*sr.window7(e), sr.noisy7(vb))
        out[method] = row
        own = pipeline_form(spp)
        if sampler == "lattice" and own in row and abs(row[own] - psnr(got, ref)) > 0.02:
            raise AssertionError(f"{name} {spp} {method}: the host's {own!r} gives "
                                 f"{row[own]:.3f} dB, the device {psnr(got, ref):.3f}")
    if images is not None:
        images["box"] = buf.color.mean(2)
    return out, psnr(buf.color.mean(2).astype(np.float32), ref)


def figure(path, ref, images: dict, method: str, forms, title: str) -> None:
    """A PNG: the reference, box and each form's image (tone-mapped), and below each its
    squared error (mean over RGB) on one scale, the first form's 99.5th percentile."""
    plt = pyplot()
    shown = [("box", images["box"])] + [(f, images[method, f]) for f in forms]

    def err(x):
        return ((np.asarray(x, np.float64) - ref) ** 2).mean(-1)

    vmax = max(float(np.percentile(err(shown[1][1]), 99.5)), 1e-12)
    fig, ax = plt.subplots(2, len(shown) + 1, figsize=(2.4 * (len(shown) + 1), 5.0))
    for i, (name, img) in enumerate([("reference", ref)] + shown):
        ax[0][i].imshow(np.clip(img / (1 + img), 0, 1) ** (1 / 2.2))
        label = name if i == 0 else f"{name} {psnr(img.astype(np.float32), ref):.2f} dB"
        ax[0][i].set_title(label, fontsize=9)
        if i:
            ax[1][i].imshow(err(img), vmin=0, vmax=vmax, cmap="magma")
            ax[1][i].set_title(f"{name}: squared error", fontsize=9)
    for a in ax.flat:
        a.axis("off")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    save_png(fig, path)


def z_figure(path, hist, title: str) -> None:
    """A PNG of the frame's histogram of its 7x7 bias means' z (signed, log counts) with the
    nulls the q-value can take: the normal matched to its peak (the kernels'), and the
    negative means mirrored about the frame's mode (never above 0), whose positive side
    is what that null counts as noise."""
    plt = pyplot()
    b = FDR_BINS
    sc = sr.signed_counts(hist)
    z = (np.arange(2 * b) - b + 0.5) / FDR_SCALE
    smoothed = sr.smoothed_counts(sc)
    mu, sigma, n0 = sr.normal_null(smoothed, int(sc.sum()))
    normal = n0 / (sigma * np.sqrt(2 * np.pi)) * np.exp(-0.5 * ((z - mu) / sigma) ** 2) \
        / FDR_SCALE
    m = sr.mode_mirror(smoothed)  # bin k mirrors to m - k
    mirror = np.where(z > 0, sc[np.clip(m - np.arange(2 * b), 0, 2 * b - 1)], np.nan)
    fig, ax = plt.subplots(figsize=(7.0, 3.6))
    ax.step(z[1:-1], np.maximum(sc[1:-1], 0.5), where="mid", color="k", lw=0.8,
            label="the frame's 7x7 means")
    ax.plot(z, np.maximum(normal, 0.5), color="tab:blue",
            label=f"normal null (shipped): mode {mu:.2f}, sigma {sigma:.2f}")
    ax.plot(z, np.maximum(mirror, 0.5), color="tab:red", ls="--",
            label="negative means mirrored about the mode")
    ax.axvline(0.0, color="grey", lw=0.5)
    ax.set_yscale("log")
    ax.set_xlabel("z = mu7 / se7 (the last bins, |z| >= 8, left out)")
    ax.set_ylabel("pixels per bin (1/32)")
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=7)
    fig.tight_layout()
    save_png(fig, path)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", default=SCENES)
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--spp", default="8,16,64")
    ap.add_argument("--sampler", choices=("lattice", "random"), default="lattice")
    ap.add_argument("--seed", type=int, default=100, help="samples: seed + spp")
    ap.add_argument("--forms", default="untested,q normal,q about mode,2 se")
    ap.add_argument("--out", default=None)
    ap.add_argument("--figures", default=None, metavar="DIR",
                    help="write DIR/<scene>_<spp>spp_<method>.png per frame (error maps) "
                         "and <...>_z.png (the frame's z histogram and its nulls)")
    ap.add_argument("--figure-method", default="splat", choices=METHODS)
    args = ap.parse_args(argv)
    forms = args.forms.split(",")
    dev = get_device(None)
    stamp = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    lines = [f"# The 7x7 bias mean's forms ({args.size}x{args.size}, {args.sampler})", "",
             f"`python tools/frame_shrink_study.py --size {args.size} --spp {args.spp} "
             f"--sampler {args.sampler} --seed {args.seed} --forms '{args.forms}'` on "
             f"{dev.info.label}, {stamp}; PSNR dB; each form's change against `{forms[0]}` "
             "in brackets.", "",
             "| scene | spp | box | method | " + " | ".join(forms) + " |",
             "|---|---|---|---|" + "---|" * len(forms)]
    change = {}
    for name in args.scenes.split(","):
        ref = render_reference(get_scene(name), args.size, args.size)  # the trusted device's
        for spp in (int(s) for s in args.spp.split(",")):
            images = {} if args.figures else None
            res, box = measure(name, args.size, spp, args.sampler, forms, dev, ref, args.seed,
                               images)
            if images and (args.figure_method, forms[0]) in images:
                what = (f"{name}, {spp} spp, {args.size}x{args.size}, {args.sampler}: "
                        f"{args.figure_method}")
                stem = Path(args.figures) / f"{name}_{spp}spp_{args.figure_method}"
                figure(f"{stem}.png", ref, images, args.figure_method, forms, what)
                z_figure(f"{stem}_z.png", images[args.figure_method, "z"], what)
            for method, row in res.items():
                first = row[forms[0]]
                for f in forms[1:]:
                    change.setdefault((spp, f), []).append(row[f] - first)
                lines.append(f"| {name} | {spp} | {box:.2f} | {method} | {first:.2f} | "
                             + " | ".join(f"{row[f]:.2f} ({row[f] - first:+.2f})"
                                          for f in forms[1:]) + " |")
            print(f"{name} {spp}: done", flush=True)
    lines += ["", "| spp | form | mean change | least | most |", "|---|---|---|---|---|"]
    lines += [f"| {spp} | {f} | {np.mean(d):+.3f} | {min(d):+.2f} | {max(d):+.2f} |"
              for (spp, f), d in sorted(change.items())]
    emit_page(lines, args.out)


if __name__ == "__main__":
    main()
