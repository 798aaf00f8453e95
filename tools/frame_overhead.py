"""Host overhead of a frame: ``clrecon.run()`` wall time against the frame's device work.

Usage: ``.venv/bin/python tools/frame_overhead.py [--size 1280x720] [--spp 8]
[--rounds 5] [-o docs/measurements/frame-overhead-pocl.md]``

For every method's default (and sweep's ``dof_layers``), on ``deep``, in paired rounds
(each setting once per round, rotated order, medians over rounds):

* ``run()`` on the frame it has just seen (the plan and the buffers are reused) and on a new
  frame of the same shape (another seed: planned afresh, buffers reused);
* the frame's device work: upload (a blocking copy, wall), device inspection (wall: it
  reads back a few bytes) and the plan's passes (profiling events);
* the path before the frame contract, side by side: host ``validate()`` + ``inspect()`` +
  ``make_pipeline`` + upload of the plan's fields + passes + read back, every frame.

Also the host ``validate()`` + ``inspect()`` against one NumPy reduction over all fields
(``sum`` of each), and the device inspection alone.
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time

import numpy as np
import pyopencl as cl

import clrecon
from clrecon.api import make_pipeline
from clrecon.bench.options import parse_size
from clrecon.bench.scripts import emit_page
from clrecon.bench.timing import host_cpu
from clrecon.core.device import get_device
from clrecon.core.pipeline import DeviceSamples
from clrecon.core.samples import FIELDS
from clrecon.scenes import get_scene, render_samples

SETTINGS = [("box", {}), ("sweep", {}), ("sweep", {"dof_layers": True}), ("layered", {}),
            ("splat", {})]


def label(method, knobs):
    return method + "".join(f" {k}={v}" for k, v in knobs.items())


def old_path(dev, buf, method, knobs):
    """What run() did before: host validation and inspection, a new plan, every frame."""
    t0 = time.perf_counter()
    buf.validate()
    pipe = make_pipeline(method, dev.context, buf.inspect(), **knobs)
    s = DeviceSamples.upload(dev.queue, buf, pipe.fields, info=buf.inspect())
    out = cl.Buffer(dev.context, cl.mem_flags.READ_WRITE, buf.height * buf.width * 12)
    img = np.empty((buf.height, buf.width, 3), np.float32)
    cl.enqueue_copy(dev.queue, img, out, wait_for=[pipe(dev.queue, s, out)])
    return (time.perf_counter() - t0) * 1e3


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="1280x720")
    ap.add_argument("--spp", type=int, default=8)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("-o", "--output", default=None)
    a = ap.parse_args(argv)
    w, h = parse_size(a.size)
    dev = get_device()
    print(f"rendering deep {w}x{h} {a.spp} spp (two seeds) ...", file=sys.stderr)
    frames = [render_samples(get_scene("deep"), w, h, spp=a.spp, seed=s, device=dev)
              for s in (1, 2)]
    rows = {label(m, k): {"same": [], "new": [], "upload": [], "inspect": [], "passes": [],
                          "old": []} for m, k in SETTINGS}
    for m, k in SETTINGS:  # warm: kernels built, buffers allocated
        clrecon.run(frames[0], m, dev, **k)
        old_path(dev, frames[0], m, k)
    for r in range(a.rounds):
        order = SETTINGS[r % len(SETTINGS):] + SETTINGS[:r % len(SETTINGS)]
        for m, k in order:
            row = rows[label(m, k)]
            new = clrecon.run(frames[(r + 1) % 2], m, dev, **k)  # another frame: re-plan
            same = clrecon.run(frames[(r + 1) % 2], m, dev, **k)  # the same frame again
            row["new"].append(new.wall_ms)
            row["same"].append(same.wall_ms)
            row["upload"].append(same.upload_ms)
            row["inspect"].append(same.inspect_ms)
            row["passes"].append(same.device_ms)
            row["old"].append(old_path(dev, frames[r % 2], m, k))
        print(f"round {r + 1}/{a.rounds}", file=sys.stderr)
    buf = frames[0]
    host_v, host_i, red = [], [], []
    for _ in range(a.rounds):
        t = time.perf_counter()
        buf.validate()
        host_v.append((time.perf_counter() - t) * 1e3)
        t = time.perf_counter()
        buf.inspect()
        host_i.append((time.perf_counter() - t) * 1e3)
        t = time.perf_counter()
        sum(float(getattr(buf, f).sum()) for f in FIELDS)
        red.append((time.perf_counter() - t) * 1e3)
    med = statistics.median
    lines = [f"# Host overhead per frame: deep {w}x{h}, {a.spp} spp", "",
             f"Device: {dev.info.label}. Host CPU: {host_cpu()}. {a.rounds} paired rounds, "
             "medians. Command: `.venv/bin/python tools/frame_overhead.py "
             f"--size {a.size} --spp {a.spp} --rounds {a.rounds}`.", "",
             "`device work` = upload (wall, blocking copy of all six fields) + device "
             "inspection (wall) + the plan's passes (profiling events). `same frame`: `run()` "
             "on the frame it has just reconstructed (plan reused); `new frame`: another "
             "frame of the same shape (planned afresh, buffers reused); `before`: host "
             "validate + inspect + new pipeline + upload + passes, as run() did before.", "",
             "| setting | upload ms | inspect ms | passes ms | device work ms | run() same "
             "frame ms | x device work | run() new frame ms | x device work | before ms |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for name, row in rows.items():
        work = med(row["upload"]) + med(row["inspect"]) + med(row["passes"])
        lines.append(
            f"| {name} | {med(row['upload']):.0f} | {med(row['inspect']):.0f} | "
            f"{med(row['passes']):.0f} | {work:.0f} | {med(row['same']):.0f} | "
            f"{med(row['same']) / work:.2f} | {med(row['new']):.0f} | "
            f"{med(row['new']) / work:.2f} | {med(row['old']):.0f} |")
    lines += ["", f"Host `validate()` {med(host_v):.0f} ms + `inspect()` {med(host_i):.0f} ms "
              f"= {med(host_v) + med(host_i):.0f} ms, against one NumPy reduction over all "
              f"fields {med(red):.0f} ms: {(med(host_v) + med(host_i)) / med(red):.2f}x.", ""]
    emit_page(lines, a.output)


if __name__ == "__main__":
    main()
