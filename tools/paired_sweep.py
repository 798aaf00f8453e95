"""Paired timing of sweep plans on one frame, in one process, runs interleaved.

Usage: ``python tools/paired_sweep.py [--scene deep] [--size 1280x720] [--spp 16]
[--repeats 7] [--plan LABEL=knob=value,...]...``. Each plan is built and warmed up once;
then every round launches each plan once, the order rotated from round to round
(:func:`clrecon.bench.timing.paired_rounds`), so that the machine's load drifts over all of
them alike. Prints device ms (profiling events, all passes) per plan: the median, the
runs, and the largest difference of each plan's image from the first plan's.
"""
from __future__ import annotations

import argparse
import json
import statistics

import numpy as np

from clrecon.bench.options import parse_knobs
from clrecon.bench.scripts import add_frame_options, frame_of
from clrecon.bench.timing import PipelineRun, paired_rounds

MAIN = "main tile=scales=2,sort=tile,tile=2,tile_merge=serial"  # main's tuned m-hi default


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    add_frame_options(ap, size="1280x720", spp=16, repeats=7, device=False)
    ap.add_argument("--plan", action="append", default=None,
                    help=f"LABEL=knob=value,... (default: '{MAIN}' and 'block=scales=2')")
    args = ap.parse_args()
    plans = {}
    for text in args.plan or [MAIN, "block=scales=2"]:
        label, _, knobs = text.partition("=")
        plans[label] = parse_knobs([kv for kv in knobs.split(",") if kv], f"--plan {text!r}: knob")
    dev, buf = frame_of(args)
    runs = {k: PipelineRun(dev, buf, "sweep", v) for k, v in plans.items()}
    images = {}
    for k, r in runs.items():  # warm-up, keeps the images
        r.run()
        images[k] = r.image()
    times = dict(zip(runs, paired_rounds([r.run for r in runs.values()], args.repeats)))
    first = images[next(iter(images))]
    rows = [{"plan": k, "knobs": plans[k], "describe": runs[k].describe(),
             "median_ms": statistics.median(t), "runs_ms": [round(x, 1) for x in t],
             "max_rel_diff": float(np.abs(images[k] - first).max() / np.abs(first).max())}
            for k, t in times.items()]
    print(json.dumps({"device": dev.info.label, "scene": args.scene,
                      "size": [buf.width, buf.height], "spp": args.spp,
                      "repeats": args.repeats, "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
