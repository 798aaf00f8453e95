"""Per-pass device times of method ``layered`` (practical sheared / mip vs lrdm) on one
scene, interleaved runs (one run of each variant per round), and the device memory each plan
allocates at 1920x1080. Run: ``python tools/layered_speed.py [--scene deep]
[--size 1280x720] [--spp 8] [--repeats 5]``; prints one JSON object per variant, then
``{"memory_1920x1080": {...}}``. Used for docs/measurements/layered-pocl.md."""
from __future__ import annotations

import argparse
import json
import statistics

import pyopencl as cl

from clrecon.core.device import get_device
from clrecon.core.pipeline import DeviceSamples, make_pipeline
from clrecon.scenes import get_scene, render_samples

VARIANTS = [("practical sheared", {}), ("practical mip", {"filter": "mip"}),
            ("lrdm", {"mode": "lrdm"})]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", default="deep")
    ap.add_argument("--size", default="1280x720")
    ap.add_argument("--spp", type=int, default=8)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--device", default=None)
    ap.add_argument("--variant", action="append", default=None, metavar="NAME=JSON",
                    help='e.g. \'forced-5d={"has_motion": true}\' (default: the three modes)')
    args = ap.parse_args()
    variants = VARIANTS
    if args.variant:
        variants = [(v.split("=", 1)[0], json.loads(v.split("=", 1)[1])) for v in args.variant]
    w, h = (int(v) for v in args.size.split("x"))
    dev = get_device(args.device)
    scene = get_scene(args.scene)
    buf = render_samples(scene, w, h, args.spp, seed=100 + args.spp, device=dev)
    info = buf.inspect()
    runs = []
    for name, knobs in variants:
        pipe = make_pipeline("layered", dev.context, info, **knobs)
        s = DeviceSamples.upload(dev.queue, buf, pipe.fields)
        out = cl.Buffer(dev.context, cl.mem_flags.READ_WRITE, w * h * 12)
        pipe(dev.queue, s, out).wait()  # warm-up: builds, PoCL's per-shape specialisation
        runs.append((name, pipe, s, out, []))
    for _ in range(args.repeats):
        for _name, pipe, s, out, times in runs:
            pipe(dev.queue, s, out).wait()
            times.append(pipe.pass_times_ms())
    for name, pipe, _s, _out, times in runs:
        totals = [sum(t.values()) for t in times]
        print(json.dumps({
            "variant": name, "scene": args.scene, "size": [w, h], "spp": args.spp,
            "device": dev.info.label, "repeats": args.repeats,
            "total_ms_median": round(statistics.median(totals), 1),
            "total_ms_min": round(min(totals), 1), "total_ms_max": round(max(totals), 1),
            "pass_ms_median": {k: round(statistics.median(t[k] for t in times), 1)
                               for k in times[0]},
            "describe": {k: v for k, v in pipe.describe().items() if k != "tuning"}}))
    big = render_samples(scene, 1920, 1080, 2, seed=1, device=dev).inspect()
    mem = {}
    for name, knobs in variants:
        pipe = make_pipeline("layered", dev.context, big, **knobs)
        sizes = pipe.buffer_sizes(1920, 1080)
        mem[name] = {"total_MB": round(sum(sizes.values()) / 2 ** 20, 1),
                     **{k: round(v / 2 ** 20, 1) for k, v in sizes.items()}}
    print(json.dumps({"memory_1920x1080": mem, "scene": args.scene}))


if __name__ == "__main__":
    main()
