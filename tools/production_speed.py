"""Issue 19's targets at production resolution, in one paired run: each setting's device time
(its passes' profiling events, a warm pipeline) and the wall time of ``clrecon.run()`` on the
same frame, against Open Image Denoise high (box + denoise, wall) and layered's device time.

Run: ``python tools/production_speed.py [--scene deep] [--size 1280x720]
[--spp 8] [--repeats 3] [--out docs/measurements/production-speed-pocl.md]``; prints the
markdown table (and writes it with ``--out``). Rounds are paired: one run of every setting
per round, medians over the rounds; ratios are the meaningful numbers on a shared machine.
"""
from __future__ import annotations

import argparse
import statistics
import time
from datetime import datetime, timezone

import clrecon
from clrecon.bench.scripts import add_frame_options, emit_page, frame_of
from clrecon.bench.timing import OidnRun, PipelineRun, host_cpu

SETTINGS = [
    ("box", "box", {}),
    ("sweep (2 scales)", "sweep", {"safeguard": False}),
    ("sweep dof_layers", "sweep", {"dof_layers": True, "safeguard": False}),
    ("layered", "layered", {"safeguard": False}),
    ("splat (mip 8)", "splat", {"safeguard": False}),
    ("splat mip 4", "splat", {"mip_radius": 4.0, "safeguard": False}),
    ("splat mip 12", "splat", {"mip_radius": 12.0, "safeguard": False}),
    # the defaults as shipped: every method but box with the safeguard (the method on the
    # frame and on its two halves, then the blend)
    ("sweep default (+safeguard)", "sweep", {}),
    ("layered default (+safeguard)", "layered", {}),
    ("splat default (+safeguard)", "splat", {}),
    # the quality end of the trade: the guided refinement, and non-local means on its halves
    ("splat guided (+safeguard)", "splat", {"guided": 2}),
    ("splat guided nlm3 (+safeguard)", "splat", {"guided": 2, "nlm": 3}),
    # box's own halves through the filter, and the hybrid of the chain with it
    ("box nlm3x4 (+safeguard)", "box", {"nlm": 3, "nlm_scales": 4}),
    ("splat guided nlm3x4 +hybrid", "splat", {"guided": 2, "nlm": 3, "nlm_scales": 4,
                                              "hybrid": True}),
]
#: run once (a round of it takes ~20 s at 720p): the paper's plan, for the before/after
SLOW = [("splat paper (mip_radius=0)", "splat", {"mip_radius": 0, "safeguard": False})]


def main() -> None:
    ap = argparse.ArgumentParser()
    add_frame_options(ap, repeats=3)
    ap.add_argument("--no-slow", action="store_true", help="leave out the paper's splat plan")
    ap.add_argument("--out", default=None)
    args = ap.parse_args()
    dev, buf = frame_of(args)
    w, h, info = buf.width, buf.height, buf.inspect()
    settings = SETTINGS + ([] if args.no_slow else SLOW)
    runners = [(name, method, knobs, PipelineRun(dev, buf, method, knobs))
               for name, method, knobs in settings]
    oidn = OidnRun(dev, buf, "high")
    for *_, r in runners:  # warm-up: builds, PoCL's per-shape specialisation
        r.run()
    oidn.run()
    for _name, method, knobs, _ in runners:  # warm run() (its own cached pipeline)
        clrecon.run(buf, method, dev, **knobs)
    dev_ms = {name: [] for name, *_ in settings}
    wall_ms = {name: [] for name, *_ in settings}
    oidn_ms = []
    for rnd in range(args.repeats):
        for name, method, knobs, r in runners:
            if (name, method, knobs) in SLOW and rnd > 0:
                continue
            dev_ms[name].append(r.run())
            # run() keeps a few sessions (plan and buffers) per method and knobs: the first
            # call after the other settings' may re-plan, the second is the warm frame
            clrecon.run(buf, method, dev, **knobs)
            t0 = time.perf_counter()
            clrecon.run(buf, method, dev, **knobs)
            wall_ms[name].append((time.perf_counter() - t0) * 1e3)
        oidn_ms.append(oidn.run())
        print(f"round {rnd + 1}/{args.repeats} done", flush=True)
    med = {k: statistics.median(v) for k, v in dev_ms.items()}
    wmed = {k: statistics.median(v) for k, v in wall_ms.items()}
    o = statistics.median(oidn_ms)
    lay = med["layered"]
    lines = [
        f"# Speed at production resolution: {args.scene} {w}x{h}, {args.spp} spp",
        "",
        f"Device: {dev.info.label}. Host CPU: {host_cpu()}. {args.repeats} paired rounds "
        f"(the paper's splat plan: one), medians; "
        f"{datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC. Frame: max |CoC| "
        f"{info.max_abs_coc:.1f} px, max |motion| {info.max_abs_motion:.1f} px. Command: "
        f"`python tools/production_speed.py --scene {args.scene} --size {w}x{h} "
        f"--spp {args.spp} --repeats {args.repeats}`.",
        "",
        "`device ms`: the setting's passes (profiling events, a warm pipeline); `run() ms`: "
        "wall of `clrecon.run(buf, method, device, **knobs)` on the same frame, its second "
        "call in a row (plan and buffers reused; upload, inspection, passes, read-back). "
        "OIDN high: box + `pyoidn.denoise(quality='high')`, "
        f"wall: **{o:.0f} ms**.",
        "",
        "| setting | device ms | x layered | OIDN / device | run() ms | OIDN / run() |",
        "|---|---|---|---|---|---|",
    ]
    for name, *_ in settings:
        lines.append(f"| {name} | {med[name]:.1f} | {med[name] / lay:.2f} | "
                     f"{o / med[name]:.1f} | {wmed[name]:.0f} | {o / wmed[name]:.2f} |")
    emit_page(lines, args.out)


if __name__ == "__main__":
    main()
