"""A method's passes with some kernel files as they are against the same files at a git
revision, side by side: per-pass device ms, the per-round ratios, and bit-identity.

Run: ``python tools/kernel_against.py --files reproject tile_stats [--rev HEAD]
[--method layered] [--knobs '{"safeguard": false}'] [--scene deep] [--size 1280x720]
[--spp 8] [--repeats 9] [-o PAGE]``

Two pipelines of the method on one frame: ``REV`` builds ``kernels/<file>.cl`` from
``git show REV:kernels/<file>.cl`` for each file named (headers and the other kernels as
they are), ``current`` from the working tree. Rounds are paired (one call of each per
round, the order alternating); the ratio column is the median of the per-round ratios of
``current`` to ``REV``, the meaningful number on a shared machine.
"""
from __future__ import annotations

import argparse
import json
import statistics
import subprocess
from pathlib import Path

import numpy as np

import clrecon.core.build as build
from clrecon.bench.scripts import add_frame_options, emit_page, frame_of
from clrecon.bench.timing import PipelineRun, host_cpu, paired_rounds

ROOT = Path(__file__).resolve().parents[1]


def sources_at(rev: str, files: list[str]) -> dict[str, str]:
    """``{file: text}`` of ``kernels/<file>.cl`` at git revision ``rev``."""
    out = {}
    for f in files:
        name = f.removesuffix(".cl")
        out[name] = subprocess.run(["git", "show", f"{rev}:kernels/{name}.cl"], cwd=ROOT,
                                   check=True, capture_output=True, text=True).stdout
    return out


def pipeline_with(dev, buf, method: str, knobs: dict, sources: dict[str, str]) -> PipelineRun:
    """The method's pipeline with ``kernels/<name>.cl`` replaced by ``sources[name]``."""
    orig = build.kernel_source

    def patched(name: str) -> str:
        return sources.get(name.removesuffix(".cl")) or orig(name)
    build.kernel_source = patched
    try:
        return PipelineRun(dev, buf, method, knobs)
    finally:
        build.kernel_source = orig


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_frame_options(ap, repeats=9)
    ap.add_argument("--files", nargs="+", required=True, help="kernel files (no extension)")
    ap.add_argument("--rev", default="HEAD")
    ap.add_argument("--method", default="layered")
    ap.add_argument("--knobs", default='{"safeguard": false}', help="JSON")
    ap.add_argument("-o", "--output", default=None)
    args = ap.parse_args(argv)
    knobs = json.loads(args.knobs)
    dev, buf = frame_of(args)
    old = pipeline_with(dev, buf, args.method, knobs, sources_at(args.rev, args.files))
    new = PipelineRun(dev, buf, args.method, knobs)
    for r in (old, new):  # warm-up: PoCL specialises per launch shape
        r.run()
        r.pass_ms.clear()
    same = np.array_equal(old.image(), new.image(), equal_nan=True)
    totals = paired_rounds([old.run, new.run], args.repeats)
    lines = [f"# {args.method} {json.dumps(knobs)}: current against {args.rev} "
             f"(kernels {', '.join(args.files)})", "",
             f"{args.scene} {buf.width}x{buf.height}, {args.spp} spp; device "
             f"{dev.device.name}; host CPU {host_cpu()}; {args.repeats} paired rounds, "
             "medians (device ms, the passes' profiling events).", "",
             f"| pass | {args.rev} ms | current ms | current / {args.rev} |", "|---|---|---|---|"]
    for name, a in old.pass_ms.items():
        b = new.pass_ms.get(name, [])
        ratio = statistics.median([y / x for x, y in zip(a, b) if x > 0]) if b else float("nan")
        lines.append(f"| {name} | {statistics.median(a):.1f} | "
                     f"{statistics.median(b) if b else float('nan'):.1f} | {ratio:.3f} |")
    ratio = statistics.median([y / x for x, y in zip(*totals)])
    lines += [f"| **total** | {statistics.median(totals[0]):.1f} | "
              f"{statistics.median(totals[1]):.1f} | **{ratio:.3f}** |", "",
              f"Images bit-identical: {same}."]
    emit_page(lines, args.output)


if __name__ == "__main__":
    main()
