"""Scaling study (issue 19): each method's device time against resolution, blur size and spp,
and each pass's share of the frame's time and its achieved bandwidth.

Usage: ``.venv/bin/python tools/scaling_study.py --out docs/measurements/scaling-pocl``
(options below; ``--quick`` for a smoke run on tiny frames). Writes ``OUT.md`` (the docs
page), ``OUT/results.json`` (everything measured) and ``OUT/{resolution,blur,spp,shares,
bandwidth}.png``.

Frames, all of one built-in scene (``--scene``, default ``deep``), seed ``--seed``:

* resolution series: the scene as it is at each ``--sizes``, ``--base-spp`` spp (its CoC and
  motion in pixels grow with the width: the same picture at a finer resolution);
* spp series: at ``--base-size``, each ``--spp``;
* blur family, at ``--base-size`` and ``--base-spp``: the scene rendered with its lens radius
  and every velocity scaled (:mod:`clrecon.bench.scaling`) so that the frame's measured max
  |CoC| is each ``--coc`` (nothing moving), and its max |motion| each ``--motion`` with the
  max |CoC| ``--motion-coc``;
* the pass-share frame: ``--shares-size`` at ``--base-spp`` (1280x720 8 spp by default).

A frame that belongs to several series is rendered and measured once.

Per frame and method (``--methods``: each ``METHOD`` with its defaults, or ``METHOD=JSON``
with knobs, e.g. ``'layered={"filter": "mip"}'``): the pipeline is planned on the frame's
own description, all six fields are uploaded once, then one warm-up launch and ``--repeats``
timed launches, each waited for. A launch's device time is the sum of its kernels'
profiling events; a pass is a leaf step of the plan (a safeguarded method's half-frame
steps are their own passes, ``"(halves)"``), its time the sum of its kernels
(:class:`clrecon.bench.timing.LeafRun`, what ``clrecon bench`` uses). Reported:
the median, min and max of the frame's device ms; per pass its median ms, its share (median
over the sum of the passes' medians, so the shares sum to 1), the bytes it must at least move
(every buffer its step names as input read once, every output written once: compulsory
traffic, a lower bound) and that over its median time in GB/s, also as a fraction of the
device's streaming peak (:func:`clrecon.bench.bandwidth.measure_peak`, measured before the
first frame and after the last; the higher of the two, since a busy machine only lowers it).

Budget: a frame a method is predicted to need more than ``--max-seconds-per-frame`` for
(one launch, extrapolated from the method's last frames of the same series: by samples, and
by the growth between its last two frames beyond that; the first frame of a series from the
method's frame nearest in samples), or whose warm-up took longer, is recorded as ``skipped
(over budget)`` instead of timed. Series run in increasing cost, so the first skipped frame
of a series usually skips the rest. A method that fails on a frame is recorded as
``failed: ...`` and the study goes on (exit status 1 at the end).

The library part: :mod:`clrecon.bench.scaling_study` (frames, measuring),
:mod:`clrecon.bench.scaling_report` (the page) and :mod:`clrecon.bench.scaling_plots`.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from clrecon.bench.devices_report import jsonable
from clrecon.bench.options import parse_size
from clrecon.bench.scaling_plots import plots
from clrecon.bench.scaling_report import markdown
from clrecon.bench.scaling_study import SKIPPED, log, predict_s, study
from clrecon.bench.table import _check_variants
from clrecon.core.fsutil import write_atomic
from clrecon.scenes import get_scene

__all__ = ["SKIPPED", "main", "parse_args", "parse_methods", "predict_s", "write"]

#: option defaults of the full study, and of ``--quick`` (explicit options win over both)
DEFAULTS = {"methods": ["box", "sweep", "layered", "splat"],
            "sizes": "256x256,640x360,1280x720,1920x1080", "base_size": "640x360",
            "base_spp": 8, "spp": "4,8,16,32", "coc": "2,4,8,16,32,64",
            "motion": "0,16,64,128,256", "motion_coc": 2.0, "shares_size": "1280x720",
            "repeats": 3, "max_seconds_per_frame": 10.0}
QUICK = {"sizes": "64x64,128x72", "base_size": "64x64", "base_spp": 2, "spp": "2,4",
         "coc": "2,4", "motion": "0,8", "shares_size": "128x72", "repeats": 1}


# -- arguments -------------------------------------------------------------------------------

def _list(text: str, parse, what: str) -> list:
    """A comma-separated list (``none`` or empty: that series is left out), sorted."""
    if text.strip().lower() in ("", "none"):
        return []
    out = []
    for item in text.split(","):
        try:
            out.append(parse(item.strip()))
        except ValueError as exc:
            raise SystemExit(f"--{what}: {exc}") from None
    return sorted(set(out), key=lambda v: (v[0] * v[1], v) if isinstance(v, tuple) else v)


def _positive_int(text: str) -> int:
    v = int(text)
    if v < 1:
        raise ValueError(f"{text!r} is not a positive integer")
    return v


def _pixels(text: str) -> float:
    v = float(text)
    if not (math.isfinite(v) and v >= 0):
        raise ValueError(f"{text!r} is not a finite number of pixels >= 0")
    return v


def parse_methods(specs: list[str]) -> list[tuple[str, str, dict]]:
    """``(label, method, knobs)`` of each ``METHOD`` or ``METHOD=JSON`` (a knob object)."""
    out = []
    for spec in specs:
        method, sep, text = spec.partition("=")
        method = method.strip()
        knobs = {}
        if sep:
            try:
                knobs = json.loads(text)
            except json.JSONDecodeError as exc:
                raise SystemExit(f"--methods {spec!r}: knobs are not JSON ({exc})") from None
            if not isinstance(knobs, dict):
                raise SystemExit(f"--methods {spec!r}: knobs must be a JSON object")
        label = method + "".join(f" {k}={json.dumps(v) if not isinstance(v, str) else v}"
                                 for k, v in knobs.items())
        out.append((label, method, knobs))
    try:
        return _check_variants(out)
    except (ValueError, TypeError) as exc:
        raise SystemExit(f"--methods: {exc}") from None


def parse_args(argv: list[str]) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True, metavar="DIR",
                    help="writes DIR.md, DIR/results.json and DIR/*.png")
    ap.add_argument("--methods", nargs="+", default=None, metavar="METHOD[=JSON]",
                    help="default: box sweep layered splat, each with its defaults")
    ap.add_argument("--scene", default="deep")
    ap.add_argument("--sizes", default=None, help="resolution series, e.g. 256x256,640x360")
    ap.add_argument("--base-size", default=None,
                    help="size of the spp series and the blur family (default 640x360)")
    ap.add_argument("--base-spp", type=int, default=None,
                    help="spp of the resolution series and the blur family (default 8)")
    ap.add_argument("--spp", default=None, help="spp series, e.g. 4,8,16,32")
    ap.add_argument("--coc", default=None, help="max |CoC| px of the CoC series (no motion)")
    ap.add_argument("--motion", default=None, help="max |motion| px of the motion series")
    ap.add_argument("--motion-coc", type=float, default=None,
                    help="max |CoC| px of the motion series (default 2)")
    ap.add_argument("--shares-size", default=None,
                    help="frame of the pass-share chart, at --base-spp (default 1280x720)")
    ap.add_argument("--repeats", type=int, default=None,
                    help="timed launches after one warm-up; the median is reported (default 3)")
    ap.add_argument("--max-seconds-per-frame", type=float, default=None,
                    help="skip a method's frame predicted or warmed up above this (default 10)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--quick", action="store_true", help="tiny frames, one repeat: smoke run")
    ap.add_argument("--device", default=None, help="index or name substring (clrecon devices)")
    a = ap.parse_args(argv)
    for key, default in DEFAULTS.items():
        if getattr(a, key) is None:
            setattr(a, key, QUICK.get(key, default) if a.quick else default)
    a.variants = parse_methods(a.methods)
    try:
        a.base_size, a.shares_size = parse_size(a.base_size), parse_size(a.shares_size)
    except ValueError as exc:
        ap.error(str(exc))
    a.sizes = _list(a.sizes, parse_size, "sizes")
    a.spp = _list(a.spp, _positive_int, "spp")
    a.coc = _list(a.coc, _pixels, "coc")
    a.motion = _list(a.motion, _pixels, "motion")
    if a.base_spp < 1 or a.repeats < 1:
        ap.error("--base-spp and --repeats must be positive")
    if not (a.motion_coc >= 0 and math.isfinite(a.motion_coc)):
        ap.error("--motion-coc must be a finite number of pixels >= 0")
    if not a.max_seconds_per_frame > 0:
        ap.error("--max-seconds-per-frame must be positive")
    try:
        get_scene(a.scene)
    except ValueError as exc:
        ap.error(str(exc))
    return a


def write(res: dict, out: Path) -> list[Path]:
    """``OUT.md``, ``OUT/results.json`` and the plots; returns the files written."""
    out.mkdir(parents=True, exist_ok=True)
    js = out / "results.json"
    write_atomic(js, (json.dumps(jsonable(res), indent=1, allow_nan=False) + "\n").encode())
    written = [js, *plots(res, out)]
    md = out.with_name(out.name + ".md")
    write_atomic(md, markdown(res, out).encode())
    return [md, *written]


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    a = parse_args(argv)
    res = study(a, argv)
    for path in write(res, Path(a.out)):
        log(f"wrote {path}")
    failed = any(r["status"].startswith("failed") for fr in res["frames"].values()
                 for r in fr["results"].values())
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
