"""Per-pass device times of method ``layered`` (practical sheared / mip vs lrdm) on one scene,
interleaved runs (one run of each variant per round), and the device memory each plan
allocates at 1920x1080 (the method's own plan: a safeguarded one's full-frame pipeline).
Run: ``python tools/layered_speed.py [--scene deep] [--size 1280x720] [--spp 8] [--repeats
5]``; prints one JSON object per variant, then ``{"memory_1920x1080": {...}}``. Used for
docs/measurements/layered-pocl.md."""
from __future__ import annotations

import argparse
import json
import statistics

from clrecon.api import make_pipeline
from clrecon.bench.scripts import add_frame_options, frame_of
from clrecon.bench.timing import PipelineRun, paired_rounds
from clrecon.scenes import get_scene, render_samples

VARIANTS = [("practical sheared", {}), ("practical mip", {"filter": "mip"}),
            ("lrdm", {"mode": "lrdm"})]


def main() -> None:
    ap = argparse.ArgumentParser()
    add_frame_options(ap)
    ap.add_argument("--variant", action="append", default=None, metavar="NAME=JSON",
                    help='e.g. \'forced-5d={"has_motion": true}\' (default: the three modes)')
    args = ap.parse_args()
    variants = VARIANTS
    if args.variant:
        variants = [(v.split("=", 1)[0], json.loads(v.split("=", 1)[1])) for v in args.variant]
    dev, buf = frame_of(args)
    runs = [(name, PipelineRun(dev, buf, "layered", knobs)) for name, knobs in variants]
    for _name, r in runs:  # warm-up: builds, PoCL's per-shape specialisation
        r.run()
        r.pass_ms.clear()
    totals = paired_rounds([r.run for _, r in runs], args.repeats)
    for (name, r), times in zip(runs, totals):
        print(json.dumps({
            "variant": name, "scene": args.scene, "size": [buf.width, buf.height],
            "spp": args.spp, "device": dev.info.label, "repeats": args.repeats,
            "total_ms_median": round(statistics.median(times), 1),
            "total_ms_min": round(min(times), 1), "total_ms_max": round(max(times), 1),
            "pass_ms_median": {k: round(v, 1) for k, v in r.median_pass_ms().items()},
            "describe": {k: v for k, v in r.describe().items() if k != "tuning"}}))
    big = render_samples(get_scene(args.scene), 1920, 1080, 2, seed=1, device=dev).inspect()
    mem = {}
    for name, knobs in variants:
        pipe = make_pipeline("layered", dev.context, big, **knobs)
        sizes = getattr(pipe, "full", pipe).buffer_sizes(1920, 1080)  # safeguarded: its plan
        mem[name] = {"total_MB": round(sum(sizes.values()) / 2 ** 20, 1),
                     **{k: round(v / 2 ** 20, 1) for k, v in sizes.items()}}
    print(json.dumps({"memory_1920x1080": mem, "scene": args.scene}))


if __name__ == "__main__":
    main()
