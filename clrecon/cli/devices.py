"""The device commands: ``devices`` (what OpenCL offers), ``bench`` (per-pass device times on
every device, tuned against default) and ``tune`` (autotune the launch configurations)."""
from __future__ import annotations

import json
from pathlib import Path

from clrecon.cli.common import (
    Bar,
    check_files,
    check_knob_names,
    check_methods,
    check_output,
    stage,
)


def cmd_devices(args) -> int:
    from clrecon.core.device import list_devices

    devs = list_devices()
    if args.json:
        print(json.dumps([d.__dict__ | {"atomics": d.atomics} for d in devs], indent=2))
        return 0
    for d in devs:
        print(f"[{d.index}] {d.platform} / {d.name}")
        print(f"    driver {d.driver}, {d.version}, type {d.device_type}")
        print(f"    {d.compute_units} compute units, {d.global_mem_bytes / 2**30:.1f} GiB global, "
              f"{d.local_mem_bytes / 1024:.0f} KiB local, max work-group {d.max_work_group_size}")
        print(f"    images: {'yes' if d.image_support else 'no'}; atomics: {d.atomics}")
    return 0


def _bench_baseline(args):
    """Check ``bench``'s outputs and read its ``--compare`` baseline (``None`` without one)
    before any measurement."""
    writes = {k: [str(v)] for k, v in (("--json", args.json), ("--csv", args.csv),
                                       ("--plot", args.plot)) if v}
    check_files({"--compare baseline": [str(args.compare)]} if args.compare else {}, writes)
    for opt, (path,) in writes.items():
        check_output(opt, path, (".png",) if opt == "--plot" else None)
    if not args.compare:
        return None
    stage(args, "reading the baseline", args.compare)
    try:
        return json.loads(Path(args.compare).read_text())
    except json.JSONDecodeError as exc:  # a ValueError that would not name the file
        raise ValueError(f"--compare {args.compare}: not JSON ({exc})") from None


def cmd_bench(args) -> int:
    from clrecon.bench.devices import bench, compare, plot_bandwidth, variant_list, write_outputs

    for label, method, knobs in args.variant or []:
        check_knob_names(method, knobs, f"--variant {label}: ")
    check_methods(args.methods)
    variants = variant_list((args.variant or []) + [(m, m, {}) for m in args.methods or []],
                            only=args.only)
    old = _bench_baseline(args)
    stage(args, "measuring")
    bar = Bar("bench", unit="step")
    try:
        res = bench(args.devices, variants=variants, size=args.size, spp=args.spp,
                    repeats=args.repeats, progress=bar, scene=args.scene,
                    peak=not args.no_peak, clpeak=args.clpeak)
    finally:
        bar.close()
    stage(args, "writing the results")
    write_outputs(res, json_path=args.json, csv_path=args.csv)
    if args.plot:
        plot_bandwidth(res, args.plot)
    print(res["markdown"])
    if old is not None:
        print(f"Change against {args.compare}:")
        print()
        print(compare(res, old))
    return 0


def cmd_tune(args) -> int:
    from clrecon.tune.session import tune_device
    from clrecon.tune.summary import results_markdown

    bars = {}

    def progress(name, done, total):
        if name not in bars:
            for b in bars.values():
                b.close()
            bars[name] = Bar(f"tune {name}", unit="config")
        bars[name](done, total)

    try:
        results = tune_device(args.device, args.passes, args.size, args.spp, args.budget,
                              args.runs, args.root, progress)
    finally:
        for b in bars.values():
            b.close()
    print(results_markdown(results))
    written = sorted({p for _, p in results})
    print(f"written: {', '.join(written) if written else 'nothing'}")
    return 0
