"""Where ``sweep_block``'s time goes, and a kernel change against a revision, side by side.

Usage: ``.venv/bin/python tools/sweep_block_phases.py [--scene deep] [--size 1280x720]
[--spp 8] [--repeats 12] [--against REV] [-o PAGE]``

The pass of sweep's default (2 scales) for the frame, as its pipeline builds it (tuned group,
the blocks per work-item that fit), launched alone in paired rounds (rotated order, median
wall ms of the launch and its wait; the first two rounds are warm-up), for:

* ``current``: ``kernels/sweep_block.cl`` as it is;
* with ``--against REV``: the file at that git revision (``git show``), and whether the two
  images are bit-identical;
* ``no one-box shortcut``: the current source with ``UNIFORM_BOX=0``: every window is
  sorted and swept, also those whose every sample weighs in one box (whose image the
  kernel otherwise takes as that box's mean); the same image to float rounding;
* phase variants of that, each one cut less: ``no sweep math`` (each list entry's record
  is still read), ``no list walk`` (the blocks' lists are built but not read), ``no
  sort`` (the window's samples stay in window order). The difference between two
  neighbours is that phase's share of the full sweep. A variant's image is meaningless;
  only its time.

The variants edit the source by exact text; if the kernel changed so that a cut no longer
applies, that variant is left out with a note instead of timing the wrong thing.
"""
from __future__ import annotations

import argparse
import copy
import statistics
import subprocess
import time
from pathlib import Path

import numpy as np
import pyopencl as cl

from clrecon.api import make_pipeline
from clrecon.bench.scripts import add_frame_options, emit_page, frame_of
from clrecon.bench.timing import host_cpu, paired_rounds
from clrecon.core.build import build_source, kernel_source
from clrecon.core.pipeline import DeviceSamples

ROOT = Path(__file__).resolve().parents[1]
STEP = "sweep_block_step(&st, &mk,"
WALK = "const int m = count[q];"
SORT = "__local const ulong *sorted = sweep_block_sort("


def _cut_step(src: str) -> str | None:
    """The sweep's per-sample update replaced by one add of the record (still read)."""
    i = src.find(STEP)
    if i < 0:
        return None
    j = src.index(";", i)
    return src[:i] + "st.r += k.y;" + src[j + 1:]


def _cut_walk(src: str) -> str | None:
    return src.replace(WALK, "const int m = 0;") if WALK in src else None


def _cut_sort(src: str) -> str | None:
    i = src.find(SORT)
    if i < 0:
        return None
    j = src.index(";", i)
    return src[:i] + "__local const ulong *sorted = lsort[lid][0];" + src[j + 1:]


def variants(src: str) -> list[tuple[str, str | None]]:
    """(name, source or None where the cut does not apply), each cut on top of the last."""
    out = []
    cur: str | None = src
    for name, cut in (("no sweep math", _cut_step), ("no list walk", _cut_walk),
                      ("no sort", _cut_sort)):
        cur = cut(cur) if cur is not None else None
        out.append((name, cur))
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_frame_options(ap, repeats=12)
    ap.add_argument("--against", default=None, help="git revision of the kernel to compare")
    ap.add_argument("-o", "--output", default=None)
    args = ap.parse_args(argv)
    if args.repeats < 3:
        ap.error("--repeats: at least 3 (two rounds are warm-up)")
    dev, buf = frame_of(args)
    pipe = make_pipeline("sweep", dev.context, buf.inspect(), safeguard=False)
    block = getattr(pipe, "block", None)
    if block is None:
        raise SystemExit("sweep's default did not plan the block sweep for this frame")
    samples = DeviceSamples.upload(dev.queue, buf, pipe.fields, info=buf.inspect())
    out = cl.Buffer(dev.context, cl.mem_flags.READ_WRITE, buf.height * buf.width * 12)

    current = kernel_source("sweep_block")
    full = {**block.defines, "UNIFORM_BOX": False}  # every window sorted and swept
    sources = [("current", current, block.defines)]
    if args.against:
        old = subprocess.run(["git", "show", f"{args.against}:kernels/sweep_block.cl"],
                             cwd=ROOT, check=True, capture_output=True, text=True).stdout
        sources.append((args.against, old, block.defines))
    sources.append(("no one-box shortcut", current, full))
    skipped = [name for name, s in variants(current) if s is None]
    sources += [(name, s, full) for name, s in variants(current) if s is not None]

    runs, images = [], {}
    for name, src, defines in sources:
        b = copy.copy(block)
        b.kernel = build_source(dev.context, src, defines, f"sweep_block ({name})"
                                ).sweep_block

        def call(b=b, name=name):
            t = time.perf_counter()
            b(dev.queue, samples, pipe.diameter_scale, out).wait()
            ms = (time.perf_counter() - t) * 1e3
            img = np.empty((buf.height, buf.width, 3), np.float32)
            cl.enqueue_copy(dev.queue, img, out)
            images[name] = img
            return ms
        runs.append(call)
    times = paired_rounds(runs, args.repeats)
    med = [statistics.median(t[2:]) for t in times]

    lines = [f"# sweep_block by phase: {args.scene} {args.size}, {args.spp} spp", "",
             f"Device: {dev.device.name}; host CPU: {host_cpu()}; {args.repeats} paired "
             f"rounds, median of the last {args.repeats - 2} (ms, launch + wait).", "",
             "| kernel | ms | x current |", "|---|---|---|"]
    for (name, *_), m in zip(sources, med):
        lines.append(f"| {name} | {m:.1f} | {m / med[0]:.3f} |")
    if args.against:
        same = np.array_equal(images["current"], images[args.against], equal_nan=True)
        ratio = statistics.median(np.array(times[0][2:]) / np.array(times[1][2:]))
        lines += ["", f"current / {args.against}: median of the per-round ratios "
                  f"{ratio:.3f}; images bit-identical: {same}"]
    if skipped:
        lines += ["", "Left out (the cut's text is not in the kernel): " + ", ".join(skipped)]
    emit_page(lines, args.output)


if __name__ == "__main__":
    main()
