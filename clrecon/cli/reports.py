"""The measurement reports: ``report``, ``table``, ``trade``, ``converge`` and ``errcheck``.
Each checks its methods and output folder before any work, calls :mod:`clrecon.bench` and
prints the report's markdown."""
from __future__ import annotations

import sys

from clrecon.cli.common import (
    Bar,
    check_knob_names,
    check_methods,
    check_output_dir,
    stage,
    status_printer,
    user_frames,
)


def _with_progress(name: str, fn, **kw):
    """``fn(progress=bar, **kw)`` under a ``name`` progress bar (in steps)."""
    bar = Bar(name, unit="step")
    try:
        return fn(progress=bar, **kw)
    finally:
        bar.close()


def cmd_report(args) -> int:
    from clrecon.bench.report import foundation_report

    check_output_dir("-o", args.output)
    stage(args, "measuring the report into", args.output)
    rep = _with_progress("report", foundation_report, scenes=args.scenes,
                         size=args.size or (512, 512), spps=args.spp, ref_spp=args.ref_spp,
                         device=args.device, out_dir=args.output)
    print(rep["markdown"])
    return 0


def cmd_table(args) -> int:
    from clrecon.bench.table import methods_table

    for label, method, knobs in args.variant or []:
        check_knob_names(method, knobs, f"--variant {label}: ")
    check_output_dir("-o", args.output)
    stage(args, "measuring the table into", args.output)
    rep = _with_progress("table", methods_table, scenes=args.scenes, variants=args.variant,
                         size=args.size or (512, 512), spp=args.spp, device=args.device,
                         out_dir=args.output, repeats=args.repeats, ref_spp=args.ref_spp,
                         inputs=user_frames(args))
    print(rep["markdown"])
    return 0


def _study(args, written: str, run) -> int:
    """A study over ``--methods`` into the folder ``-o``: both checked before any work, then
    ``run()`` (its markdown printed) and the files it ``written`` into the folder."""
    check_methods(args.methods)
    check_output_dir("-o", args.output)
    print(run())
    print(f"written: {args.output}/{written}")
    return 0


def cmd_trade(args) -> int:
    from clrecon.bench.trade import trade

    def run() -> str:
        stage(args, "measuring the trade into", args.output)
        bar = Bar("trade", unit="step")

        def status(line: str) -> None:
            bar.bar.write(f"clrecon trade: {line}", file=sys.stderr)

        try:
            return trade(args.scenes, args.methods, spps=args.spp, size=args.size,
                         repeats=args.repeats, oidn=not args.no_oidn, device=args.device,
                         out_dir=args.output, ref_spp=args.ref_spp, progress=bar,
                         inputs=user_frames(args), status=status,
                         settings=args.settings, sampler=args.sampler)["markdown"]
        finally:
            bar.close()

    return _study(args, "trade.md, trade.json, <scene>_pareto.png, <scene>_crops.png", run)


def cmd_converge(args) -> int:
    from clrecon.bench.convergence import converge

    def run() -> str:
        stage(args, "running the convergence study into", args.output)
        return converge(args.scenes, args.methods, args.settings, spps=args.spp,
                        size=args.size, seeds=args.seeds, out_dir=args.output,
                        ref_spp=args.ref_spp, ablation_spp=args.ablation_spp,
                        device=args.device, status=status_printer("converge"),
                        keep_images=args.keep_images, sampler=args.sampler)["markdown"]

    return _study(args, "convergence.md, convergence.json, <scene>_convergence.png", run)


def cmd_errcheck(args) -> int:
    from clrecon.bench.error_check import check, markdown

    return _study(args, "errcheck.md, errcheck.json", lambda: markdown(check(
        args.scenes, args.methods, size=args.size, spp=args.spp, out_dir=args.output,
        device=args.device, status=status_printer("errcheck"))))
