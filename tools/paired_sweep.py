"""Paired timing of sweep plans on one frame, in one process, runs interleaved.

Usage: ``python tools/paired_sweep.py [--scene deep] [--size 1280x720] [--spp 16]
[--repeats 7] [--plan LABEL=knob=value,...]...``. Each plan is built and warmed up once;
then every round launches each plan once, in turn, so that the machine's load drifts over
all of them alike. Prints device ms (profiling events, all passes) per plan: the median, the
runs, and the largest difference of each plan's image from the first plan's.
"""
from __future__ import annotations

import argparse
import json
import statistics

import numpy as np
import pyopencl as cl

from clrecon.bench.table import parse_value
from clrecon.core.device import get_device
from clrecon.core.pipeline import DeviceSamples, make_pipeline
from clrecon.scenes import get_scene, render_samples

MAIN = "main tile=scales=2,sort=tile,tile=2,tile_merge=serial"  # main's tuned m-hi default


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scene", default="deep")
    ap.add_argument("--size", default="1280x720")
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--plan", action="append", default=None,
                    help=f"LABEL=knob=value,... (default: '{MAIN}' and 'block=scales=2')")
    args = ap.parse_args()
    w, h = (int(v) for v in args.size.split("x"))
    plans = {}
    for text in args.plan or [MAIN, "block=scales=2"]:
        label, _, knobs = text.partition("=")
        plans[label] = {k: parse_value(v) for k, v in
                        (kv.split("=", 1) for kv in knobs.split(",") if kv)}
    dev = get_device(None)
    buf = render_samples(get_scene(args.scene), w, h, args.spp, seed=100 + args.spp, device=dev)
    info = buf.inspect()
    pipes = {k: make_pipeline("sweep", dev.context, info, **v) for k, v in plans.items()}
    samples = DeviceSamples.upload(dev.queue, buf)
    out = cl.Buffer(dev.context, cl.mem_flags.READ_WRITE, size=w * h * 12)
    images, times = {}, {k: [] for k in pipes}
    for rnd in range(args.repeats + 1):  # round 0: warm-up, keeps the images
        for k, pipe in pipes.items():
            pipe(dev.queue, samples, out).wait()
            if rnd == 0:
                images[k] = np.empty((h, w, 3), np.float32)
                cl.enqueue_copy(dev.queue, images[k], out)
            else:
                times[k].append(sum(pipe.pass_times_ms().values()))
    first = images[next(iter(images))]
    rows = [{"plan": k, "knobs": plans[k], "describe": pipes[k].describe(),
             "median_ms": statistics.median(t), "runs_ms": [round(x, 1) for x in t],
             "max_rel_diff": float(np.abs(images[k] - first).max() / np.abs(first).max())}
            for k, t in times.items()]
    print(json.dumps({"device": dev.info.label, "scene": args.scene, "size": [w, h],
                      "spp": args.spp, "repeats": args.repeats, "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
