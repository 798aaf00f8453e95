"""The ``clrecon`` argument parser: one function per subcommand (in the order ``clrecon
--help`` lists them), each naming the function that runs it. ``reconstruct``'s method
flags are generated from the methods' signatures (:mod:`clrecon.cli.knob_flags`)."""
from __future__ import annotations

import argparse

from clrecon.cli.common import (
    HelpFormatter,
    IntsAction,
    device_arg,
    device_list,
    int_list,
    names,
    parse_size,
    side_or_size,
    variant,
)
from clrecon.cli.demo import cmd_demo
from clrecon.cli.devices import cmd_bench, cmd_devices, cmd_tune
from clrecon.cli.knob_flags import add_method_flags
from clrecon.cli.reports import cmd_converge, cmd_errcheck, cmd_report, cmd_table, cmd_trade
from clrecon.cli.run import cmd_compare, cmd_psf, cmd_reconstruct, cmd_reference, cmd_scene
from clrecon.cli.sequences import SAMPLE_FORMATS, add_batch_parser
from clrecon.scenes.render import SAMPLERS

DESCRIPTION = ("The ``clrecon`` command line: a thin layer that parses, calls the library and "
               "prints.")


def _output_folder(sp, default: str, help: str = "output folder") -> None:
    sp.add_argument("-o", "--output", default=default, help=help)


def _user_frame_args(sp) -> None:
    sp.add_argument("--input", action="append", default=None, metavar="F",
                    help="a frame of your own (sample file; repeatable, with --reference)")
    sp.add_argument("--reference", action="append", default=None, metavar="R",
                    help="the converged reference image of the matching --input")


def _devices(sub) -> None:
    sp = sub.add_parser("devices", help="list OpenCL devices")
    sp.add_argument("--json", action="store_true")
    sp.set_defaults(fn=cmd_devices)


def _scene(sub) -> None:
    sp = sub.add_parser("scene", help="render a built-in scene's sample buffer")
    sp.add_argument("name")
    sp.add_argument("--size", type=parse_size, default=None,
                    help="WxH (default: the scene's, 512x512)")
    sp.add_argument("--spp", type=int, default=8)
    sp.add_argument("--seed", type=int, default=0)
    sp.add_argument("-o", "--output", required=True, help=".bin/.txt (TLFR), .exr or .npz")
    sp.add_argument("--pinhole", action="store_true",
                    help="a pinhole frame (S = 1, lens 0, time 0.5): synthesis input of splat")
    sp.add_argument("--frames", type=int, default=None, metavar="N",
                    help="an animated sequence of N frames into the folder -o "
                    "(<name>_0000.<format>, ...; objects and camera move continuously)")
    sp.add_argument("--format", choices=SAMPLE_FORMATS, default="npz",
                    help="file format of --frames (default: %(default)s)")
    device_arg(sp)
    sp.set_defaults(fn=cmd_scene)


def _reference(sub) -> None:
    sp = sub.add_parser("reference", help="render a converged reference image")
    sp.add_argument("name")
    sp.add_argument("--size", type=parse_size, default=None)
    sp.add_argument("--spp", type=int, default=None, help="default: the scene's (1024; bokeh 4096)")
    sp.add_argument("--seed", type=int, default=1)
    sp.add_argument("-o", "--output", required=True, help=".exr (or .png)")
    sp.add_argument("--frames", type=int, default=None, metavar="N",
                    help="the references of `scene --frames N` into the folder -o")
    device_arg(sp)
    sp.set_defaults(fn=cmd_reference)


def _reconstruct(sub) -> None:
    sp = sub.add_parser("reconstruct", help="reconstruct an image from a sample buffer",
                        epilog="A default of None: the method chooses, from the frame and "
                        "the device.")
    sp.add_argument("input")
    sp.add_argument("-o", "--output", required=True, help=".exr or .png")
    sp.add_argument("--method", default="box")
    sp.add_argument("--reference", help="converged reference .exr: print PSNR/SSIM/FLIP")
    sp.add_argument("--knob", action="append", metavar="NAME=VALUE",
                    help="method knob (repeatable); the flags below are shorthands")
    add_method_flags(sp)
    sp.add_argument("--error", metavar="PATH",
                    help="also write the per-pixel squared-error estimate (.exr, one channel "
                         "repeated in RGB; linear radiance, mean over RGB)")
    sp.add_argument("--json", action="store_true", help="print one JSON object")
    device_arg(sp)
    sp.add_argument("--allow-negative", action="store_true",
                    help="accept negative radiance (every method then stays linear in it)")
    sp.set_defaults(fn=cmd_reconstruct)


def _compare(sub) -> None:
    sp = sub.add_parser("compare", help="quality of image A against reference B; of two "
                        "sequences (folders or globs, frames paired by name) with flicker")
    sp.add_argument("a")
    sp.add_argument("b")
    sp.add_argument("--json", action="store_true")
    sp.set_defaults(fn=cmd_compare)


def _demo(sub) -> None:
    sp = sub.add_parser("demo", help="render a scene, reconstruct it, print time and quality",
                        description="Render a built-in scene, reconstruct it with each method "
                        "and print time and quality against a converged reference (cached "
                        "in $CLRECON_CACHE_DIR/references or ~/.cache/clrecon/references: "
                        "a second run skips its render).")
    sp.add_argument("--scene", default="fence", help="built-in scene")
    sp.add_argument("--size", type=parse_size, default=None, help="WxH (default: the scene's)")
    sp.add_argument("--spp", type=int, default=8, help="samples per pixel of the input")
    sp.add_argument("--ref-spp", type=int, default=None, help="default: the scene's")
    sp.add_argument("--seed", type=int, default=0, help="of the input (reference: seed + 1)")
    sp.add_argument("--methods", default="box,oidn,sweep,layered,splat,splat+guided,"
                    "splat+guided+nlm",
                    help="comma-separated methods to run (oidn: box + Open Image Denoise; "
                    "METHOD+guided: the method with the guided refinement, guided=2; "
                    "METHOD+guided+nlm, METHOD+nlm: with non-local means on the halves, "
                    "nlm=3 at nlm_scales=4; box+nlm: on box's own halves)")
    _output_folder(sp, "out", "folder of the images")
    device_arg(sp)
    sp.set_defaults(fn=cmd_demo)


def _tune(sub) -> None:
    sp = sub.add_parser("tune", help="autotune every pass's launch configuration on a device")
    sp.add_argument("--passes", nargs="*", default=None, help="default: every tunable pass")
    sp.add_argument("--budget", type=float, default=600.0,
                    help="seconds for all passes, a cap: a configuration or pass predicted "
                    "not to fit is skipped and listed")
    sp.add_argument("--size", type=parse_size, default=(640, 360), help="tuned frame size WxH")
    sp.add_argument("--spp", type=int, default=16, help="samples per pixel of the tuned frame")
    sp.add_argument("--runs", type=int, default=7, help="timed runs per configuration, at least 7")
    sp.add_argument("--root", default=None, help="database folder (default: the package's)")
    device_arg(sp)
    sp.set_defaults(fn=cmd_tune)


def _report(sub) -> None:
    sp = sub.add_parser("report", help="generator throughput, reference convergence, box quality")
    sp.add_argument("--scenes", nargs="*", default=None, help="default: every built-in scene")
    sp.add_argument("--size", type=parse_size, default=None, help="WxH (default 512x512)")
    sp.add_argument("--spp", type=int_list, default=[4, 8, 16], metavar="N,...",
                    help="samples per pixel of the box-quality rows")
    sp.add_argument("--ref-spp", type=int, default=None, help="default: each scene's")
    _output_folder(sp, "out/report")
    device_arg(sp)
    sp.set_defaults(fn=cmd_report)


def _table(sub) -> None:
    sp = sub.add_parser("table", help="device time and quality of reconstruction variants")
    sp.add_argument("--scenes", nargs="*", default=None, help="default: every built-in scene")
    sp.add_argument("--variant", action="append", type=variant, default=None,
                    metavar="SPEC",
                    help="a column, [LABEL=]METHOD[:K=V,...], e.g. sweep4=sweep:scales=4 "
                         "(repeatable; default: box and four sweep variants)")
    sp.add_argument("--size", type=parse_size, default=None, help="WxH (default 512x512)")
    sp.add_argument("--spp", type=int, default=16, help="samples per pixel")
    sp.add_argument("--ref-spp", type=int, default=None, help="default: each scene's")
    sp.add_argument("--repeats", type=int, default=5, help="timed runs after a warm-up")
    _user_frame_args(sp)
    _output_folder(sp, "out/methods")
    device_arg(sp)
    sp.set_defaults(fn=cmd_table)


def _scenes_and_methods(sp, scenes_help: str) -> None:
    """``--scenes S,...`` and ``--methods M,...`` of the studies (default: all)."""
    sp.add_argument("--scenes", type=names, default=None, metavar="S,...", help=scenes_help)
    sp.add_argument("--methods", type=names, default=None,
                    metavar="M,...", help="methods (default: all registered; box always runs)")


def _trade(sub) -> None:
    sp = sub.add_parser("trade", help="speed/accuracy trade of every method's knobs, with box "
                        "and Open Image Denoise, Pareto plots and crops")
    _scenes_and_methods(sp, "built-in scenes (default: all)")
    sp.add_argument("--spp", type=int_list, nargs="+", action=IntsAction, default=[4, 8, 16],
                    metavar="N", help="samples per pixel of the measured buffers (N N ... or "
                    "N,N,...)")
    sp.add_argument("--size", type=parse_size, default=(512, 512), help="WxH")
    sp.add_argument("--repeats", type=int, default=5, help="paired rounds after a warm-up")
    sp.add_argument("--ref-spp", type=int, default=None, help="default: each scene's")
    sp.add_argument("--no-oidn", action="store_true",
                    help="leave out Open Image Denoise (default: included)")
    sp.add_argument("--settings", type=lambda t: [s.strip() for s in t.split(",") if s.strip()],
                    default=None, metavar="LABEL,...",
                    help="only these settings of the methods (labels as in the report, e.g. "
                    "\"layered guided,splat guided\"; box always runs)")
    _sampler_arg(sp)
    _user_frame_args(sp)
    _output_folder(sp, "out/trade", "output folder (references cached in its references/)")
    device_arg(sp)
    sp.set_defaults(fn=cmd_trade)


def _sampler_arg(sp) -> None:
    sp.add_argument("--sampler", choices=SAMPLERS, default="lattice",
                    help="how the built-in scenes' samples are drawn: the tracer's stratified "
                    "lattice (default) or independent uniform samples (random), a renderer "
                    "without stratification")


def _errcheck(sub) -> None:
    sp = sub.add_parser("errcheck", help="how well the per-pixel error estimate ranks the "
                        "true error: Spearman over 8x8 tiles, per scene and method")
    sp.add_argument("--scenes", type=names,
                    default=["fence", "deep", "fast_motion"], metavar="S,...")
    sp.add_argument("--methods", type=names,
                    default=["box", "sweep", "layered", "splat"], metavar="M,...")
    sp.add_argument("--size", type=parse_size, default=(512, 512), help="WxH")
    sp.add_argument("--spp", type=int, default=8)
    sp.add_argument("-o", "--output", default="out/errcheck")
    device_arg(sp)
    sp.set_defaults(fn=cmd_errcheck)


def _converge(sub) -> None:
    sp = sub.add_parser("converge", help="convergence study: MSE split into bias² and variance "
                        "against spp for every method's settings, log-log plots, an ablation")
    _scenes_and_methods(sp, "built-in scenes (default: every one with blur)")
    sp.add_argument("--settings", type=lambda t: [m.strip() for m in t.split(",") if m.strip()],
                    default=None, metavar="LABEL,...",
                    help="only these settings (labels of the study; a method's name: its "
                    "defaults; box always runs; default: every default and trade setting)")
    sp.add_argument("--size", type=side_or_size, default=(256, 256),
                    help="N or WxH (default: 256x256)")
    sp.add_argument("--spp", type=int_list, nargs="+", action=IntsAction,
                    default=[4, 8, 16, 32, 64, 128], metavar="N",
                    help="samples per pixel (N N ... or N,N,...)")
    sp.add_argument("--seeds", type=int, default=4,
                    help="independent sample seeds per cell (at least 2)")
    sp.add_argument("--ref-spp", type=int, default=None, help="default: each scene's")
    sp.add_argument("--ablation-spp", type=int, default=64,
                    help="spp of the ablation of bias sources (0: none)")
    _sampler_arg(sp)
    sp.add_argument("--keep-images", action="store_true",
                    help="keep every cell's image in the cache (default: removed once its "
                    "seeds are summarised)")
    _output_folder(sp, "out/converge",
                   "output folder (references and the resume cache inside it)")
    device_arg(sp)
    sp.set_defaults(fn=cmd_converge)


def _bench(sub) -> None:
    sp = sub.add_parser("bench", help="per-pass device times on every device, tuned vs default")
    sp.add_argument("--devices", type=device_list, default="all", metavar="all|D,...",
                    help="comma-separated device indices or name substrings, as --device "
                    "of the other commands, which bench takes too (default: all)")
    sp.add_argument("--device", dest="devices", type=device_list,
                    default=argparse.SUPPRESS, help=argparse.SUPPRESS)
    sp.add_argument("--variant", action="append", type=variant, default=None,
                    metavar="SPEC",
                    help="[LABEL=]METHOD[:K=V,...], run after the default variants (box, "
                         "sweep 2-scale, sweep dof-layers) (repeatable; default: none)")
    sp.add_argument("--methods", type=names, default=None,
                    metavar="M,...", help="methods with their default knobs, run after the "
                    "default variants and --variant (default: none)")
    sp.add_argument("--only", action="store_true",
                    help="run only the --variant and --methods given, not the default variants")
    sp.add_argument("--no-peak", action="store_true",
                    help="skip measuring each device's streaming peak (copy kernel, ~1 s a "
                    "device); fractions of peak are then n/a")
    sp.add_argument("--clpeak", action="store_true",
                    help="also run clpeak's global-memory bandwidth test on each device, when "
                    "clpeak is installed (~30 s a device)")
    sp.add_argument("--scene", default=None,
                    help="built-in scene to render as input (default: a synthetic frame)")
    sp.add_argument("--size", type=parse_size, default=(1280, 720), help="WxH")
    sp.add_argument("--spp", type=int, default=16, help="samples per pixel")
    sp.add_argument("--repeats", type=int, default=7, help="paired timed runs after a warm-up")
    sp.add_argument("--json", default=None, metavar="F",
                    help="write the result as JSON (default: not written)")
    sp.add_argument("--csv", default=None, metavar="F",
                    help="write the long rows as CSV (default: not written)")
    sp.add_argument("--compare", default=None, metavar="OLD.json",
                    help="print the change against an earlier --json result (default: none)")
    sp.add_argument("--plot", default=None, metavar="F.png",
                    help="plot each pass's GB/s against each device's peak (default: none)")
    sp.set_defaults(fn=cmd_bench)


def _psf(sub) -> None:
    sp = sub.add_parser("psf", help="splat: pre-compute a PSF model's spreadlet table")
    sp.add_argument("action", choices=("build",))
    sp.add_argument("model", choices=("simplelens", "combined", "stylized"))
    sp.add_argument("-o", "--output", default=None,
                    help="default: the package's table (clrecon/methods/splat/data/MODEL.npz)")
    sp.add_argument("--failures", type=int, default=10_000,
                    help="dart-throwing stop (consecutive failures)")
    sp.add_argument("--lloyd", type=int, default=50, help="weighted Lloyd steps")
    sp.add_argument("--anneal", type=int, default=400, help="simulated-annealing steps")
    sp.add_argument("--spacing", type=float, default=0.5, help="dart radius scale")
    sp.set_defaults(fn=cmd_psf)


#: the subcommands in the order ``clrecon --help`` lists them
SUBCOMMANDS = (_devices, _scene, _reference, _reconstruct, add_batch_parser,
               _compare, _demo, _tune, _report, _table, _trade, _errcheck, _converge, _bench,
               _psf)


def build_parser() -> argparse.ArgumentParser:
    """The ``clrecon`` parser; every option's help ends with its default."""
    p = argparse.ArgumentParser(prog="clrecon", description=DESCRIPTION,
                                formatter_class=HelpFormatter)
    p.add_argument("-v", "--verbose", action="store_true", help="log what the library decides")
    p.add_argument("--debug", action="store_true",
                   help="on an error, show the traceback instead of the one-line message")
    sub = p.add_subparsers(dest="command", required=True)
    for add in SUBCOMMANDS:
        add(sub)
    for sp in sub.choices.values():
        sp.formatter_class = HelpFormatter
    return p
