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
(:func:`clrecon.bench.devices._warm_up` / ``_launch``, what ``clrecon bench`` uses). Reported:
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
"""
from __future__ import annotations

import argparse
import datetime
import io
import json
import math
import platform
import shlex
import statistics
import subprocess
import sys
import time
import traceback
from pathlib import Path

import pyopencl as cl

from clrecon.bench.bandwidth import measure_peak
from clrecon.bench.devices import _jsonable, _launch, _warm_up
from clrecon.bench.scaling import render_blur_frame
from clrecon.bench.table import _check_variants
from clrecon.core.device import get_device
from clrecon.core.fsutil import write_atomic
from clrecon.core.pipeline import DeviceSamples, make_pipeline
from clrecon.scenes import get_scene, render_samples

#: option defaults of the full study, and of ``--quick`` (explicit options win over both)
DEFAULTS = {"methods": ["box", "sweep", "layered", "splat"],
            "sizes": "256x256,640x360,1280x720,1920x1080", "base_size": "640x360",
            "base_spp": 8, "spp": "4,8,16,32", "coc": "2,4,8,16,32,64",
            "motion": "0,16,64,128,256", "motion_coc": 2.0, "shares_size": "1280x720",
            "repeats": 3, "max_seconds_per_frame": 10.0}
QUICK = {"sizes": "64x64,128x72", "base_size": "64x64", "base_spp": 2, "spp": "2,4",
         "coc": "2,4", "motion": "0,8", "shares_size": "128x72", "repeats": 1}
#: each buffer of the bandwidth peak in ``--quick`` (the full study uses the default size)
QUICK_PEAK_BYTES = 32 * 2**20

SERIES = ("resolution", "spp", "coc", "motion")
SKIPPED = "skipped (over budget)"


# -- arguments -------------------------------------------------------------------------------

def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"size {text!r}: expected WxH, e.g. 640x360") from None
    if w < 1 or h < 1:
        raise argparse.ArgumentTypeError(f"size {text!r}: width and height must be positive")
    return w, h


def _list(text: str, parse, what: str) -> list:
    """A comma-separated list (``none`` or empty: that series is left out), sorted."""
    if text.strip().lower() in ("", "none"):
        return []
    out = []
    for item in text.split(","):
        try:
            out.append(parse(item.strip()))
        except (ValueError, argparse.ArgumentTypeError) as exc:
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
        a.base_size, a.shares_size = _size(a.base_size), _size(a.shares_size)
    except argparse.ArgumentTypeError as exc:
        ap.error(str(exc))
    a.sizes = _list(a.sizes, _size, "sizes")
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


# -- frames ----------------------------------------------------------------------------------

def frame_key(w: int, h: int, spp: int, coc: float | None, motion: float | None) -> str:
    """A frame's name: size, spp and, for the blur family, the asked max |CoC| and |motion|."""
    blur = "" if coc is None else f" coc={coc:g} motion={motion:g}"
    return f"{w}x{h} {spp}spp{blur}"


def plan_frames(a) -> tuple[dict[str, tuple], dict[str, list[tuple[float, str]]]]:
    """Frames to measure (key -> (w, h, spp, coc, motion), in measuring order) and each
    series' points (x, frame key)."""
    frames: dict[str, tuple] = {}
    series: dict[str, list[tuple[float, str]]] = {s: [] for s in SERIES}
    bw, bh = a.base_size

    def add(name, x, spec):
        key = frame_key(*spec)
        frames.setdefault(key, spec)
        if name:
            series[name].append((x, key))
        return key

    for w, h in a.sizes:
        add("resolution", w * h, (w, h, a.base_spp, None, None))
    for s in a.spp:
        add("spp", s, (bw, bh, s, None, None))
    for c in a.coc:
        add("coc", c, (bw, bh, a.base_spp, c, 0.0))
    for m in a.motion:
        add("motion", m, (bw, bh, a.base_spp, a.motion_coc, m))
    a.shares_key = add(None, 0, (*a.shares_size, a.base_spp, None, None))
    return frames, series


def render_frame(scene, spec, seed, dev):
    """The frame's samples and how they were made (a dict for the results)."""
    w, h, spp, coc, motion = spec
    t0 = time.perf_counter()
    if coc is None:
        buf = render_samples(scene, w, h, spp, seed=seed, device=dev)
        info, made = buf.inspect(), {"lens_scale": 1.0, "motion_scale": 1.0, "renders": 1}
    else:
        fr = render_blur_frame(scene, w, h, spp, coc, motion, seed=seed, device=dev)
        buf, info = fr.buf, fr.info
        made = {"lens_scale": fr.lens_scale, "motion_scale": fr.motion_scale,
                "renders": fr.renders}
    return buf, info, {"width": w, "height": h, "spp": spp, "target_coc": coc,
                       "target_motion": motion, "max_abs_coc": info.max_abs_coc,
                       "max_abs_motion": info.max_abs_motion, "min_depth": info.min_depth,
                       "miss_fraction": info.miss_fraction, **made,
                       "render_s": time.perf_counter() - t0, "results": {}}


# -- measuring -------------------------------------------------------------------------------

def predict_s(history: list[tuple[int, float]], samples: int) -> float | None:
    """Seconds a launch on ``samples`` samples is predicted to take from a method's earlier
    frames of the series (``(samples, seconds)``, oldest first; ordered by samples, so that
    a frame measured earlier for another series falls into place): the last scaled by
    samples, times the growth from the one before beyond what its samples explain (at
    least 1)."""
    if not history:
        return None
    history = sorted(history, key=lambda e: e[0])  # stable: equal samples keep their order
    n1, s1 = history[-1]
    growth = 1.0
    if len(history) > 1:
        n0, s0 = history[-2]
        if s0 > 0:
            growth = max(1.0, (s1 / s0) / (n1 / n0))
    return s1 * samples / n1 * growth


def measure(dev, samples: DeviceSamples, info, method: str, knobs: dict, repeats: int,
            budget_s: float, predicted: float | None) -> dict:
    """Warm up and time one method on one uploaded frame (see the module docstring)."""
    if predicted is not None and predicted > budget_s:
        return {"status": SKIPPED, "predicted_s": predicted}
    q = dev.queue
    pipe = make_pipeline(method, dev.context, info, **knobs)
    out = cl.Buffer(dev.context, cl.mem_flags.READ_WRITE, size=info.width * info.height * 12)
    passes = _warm_up(pipe, q, samples, out)
    warm_ms = float(sum(pipe.pass_times_ms().values()))
    res = {"plan": pipe.describe()["plan"], "warmup_ms": warm_ms, "predicted_s": predicted}
    if warm_ms * 1e-3 > budget_s:
        return {"status": SKIPPED, **res}
    runs = [_launch(pipe, q, samples, out, passes) for _ in range(repeats)]
    totals = [t["frame"] for t, _ in runs]
    med = {name: statistics.median(st[name] for _, st in runs) for name in passes.bytes}
    whole = sum(med.values())
    rows = []
    for name, nbytes in passes.bytes.items():
        ms = med[name]
        gbs = nbytes / (ms * 1e6) if ms > 0 else math.nan
        rows.append({"name": name, "kernels": passes.kernels[name], "median_ms": ms,
                     "share": ms / whole if whole > 0 else math.nan, "bytes": nbytes,
                     "gb_per_s": gbs})
    nbytes = sum(passes.bytes.values())
    frame_ms = statistics.median(totals)
    return {"status": "ok", **res, "total_ms": {"median": frame_ms, "min": min(totals),
                                                "max": max(totals), "runs": totals},
            "bytes": nbytes, "gb_per_s": nbytes / (frame_ms * 1e6) if frame_ms > 0 else math.nan,
            "passes": rows}


def cpu_name() -> str:
    """``lscpu``'s model name (``/proc/cpuinfo``'s, or the platform's, where it is absent)."""
    try:
        text = subprocess.run(["lscpu"], capture_output=True, text=True, timeout=10).stdout
        for line in text.splitlines():
            if line.startswith("Model name:"):
                return line.split(":", 1)[1].strip()
    except (OSError, subprocess.SubprocessError):
        pass
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def study(a, argv: list[str]) -> dict:
    dev = get_device(a.device)
    scene = get_scene(a.scene)
    frames, series = plan_frames(a)
    started = datetime.datetime.now(datetime.timezone.utc)
    t_start = time.perf_counter()
    log(f"device {dev.info.label}; {len(frames)} frames x {len(a.variants)} methods")
    peak_bytes = QUICK_PEAK_BYTES if a.quick else None
    peaks = [measure_peak(dev.queue, peak_bytes)]
    log(f"streaming peak {peaks[0].gb_per_s:.2f} GB/s")
    series_of = {key: [s for s, pts in series.items() if any(k == key for _, k in pts)]
                 for key in frames}
    history: dict[tuple[str, str], list[tuple[int, float]]] = {}
    overall: dict[str, list[tuple[int, float]]] = {}  # every frame of a method, any series
    out_frames = {}
    for key, spec in frames.items():
        buf, info, rec = render_frame(scene, spec, a.seed, dev)
        log(f"{key}: max |CoC| {info.max_abs_coc:.2f} px, max |motion| "
            f"{info.max_abs_motion:.2f} px ({rec['renders']} render(s), {rec['render_s']:.1f} s)")
        samples = DeviceSamples.upload(dev.queue, buf, info=info)
        n = info.width * info.height * info.spp
        for label, method, knobs in a.variants:
            # the series whose history predicts the most: a frame in several takes the worst
            preds = [predict_s(history.get((s, label), []), n) for s in series_of[key]]
            preds = [p for p in preds if p is not None]
            if not preds and overall.get(label):
                # first of its series: scaled from the method's frame nearest in samples
                near = min(overall[label], key=lambda e: abs(math.log(e[0] / n)))
                preds = [predict_s([near], n)]
            t0 = time.perf_counter()
            try:
                r = measure(dev, samples, info, method, knobs, a.repeats,
                            a.max_seconds_per_frame, max(preds) if preds else None)
            except Exception as exc:  # recorded and reported; exit status 1 at the end
                last = traceback.extract_tb(exc.__traceback__)[-1]
                r = {"status": f"failed: {type(exc).__name__}: {exc}",
                     "where": f"{last.filename}:{last.lineno}"}
            r["wall_s"] = time.perf_counter() - t0
            rec["results"][label] = r
            seconds = (r["total_ms"]["median"] if r["status"] == "ok"
                       else r.get("warmup_ms", math.nan)) * 1e-3
            if math.isfinite(seconds):
                overall.setdefault(label, []).append((n, seconds))
                for s in series_of[key]:
                    history.setdefault((s, label), []).append((n, seconds))
            shown = (f"{r['total_ms']['median']:.1f} ms" if r["status"] == "ok"
                     else r["status"])
            log(f"  {label}: {shown} ({r['wall_s']:.1f} s)"
                + (f" at {r['where']}" if "where" in r else ""))
        del samples, buf
        out_frames[key] = rec
    peaks.append(measure_peak(dev.queue, peak_bytes))
    log(f"streaming peak after the frames {peaks[1].gb_per_s:.2f} GB/s")
    peak = max(peaks, key=lambda p: p.gb_per_s)
    for rec in out_frames.values():
        for r in rec["results"].values():
            for p in r.get("passes", []):
                p["fraction_of_peak"] = p["gb_per_s"] / peak.gb_per_s
    return {"command": "python tools/scaling_study.py " + shlex.join(argv),
            "date": started.strftime("%Y-%m-%d %H:%M UTC"),
            "elapsed_s": time.perf_counter() - t_start, "device": dev.info.label,
            "host_cpu": cpu_name(), "scene": a.scene, "seed": a.seed, "repeats": a.repeats,
            "max_seconds_per_frame": a.max_seconds_per_frame, "quick": a.quick,
            "peak": peak.to_dict(), "peaks_gb_per_s": [p.gb_per_s for p in peaks],
            "methods": [{"label": lab, "method": m, "knobs": k} for lab, m, k in a.variants],
            "frames": out_frames,
            "series": {s: [{"x": x, "frame": k} for x, k in pts] for s, pts in series.items()},
            "shares_frame": a.shares_key}


def log(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


# -- report ----------------------------------------------------------------------------------

def _ms(r: dict | None) -> float | None:
    return r["total_ms"]["median"] if r and r.get("status") == "ok" else None


def _f(ms: float) -> str:
    """Milliseconds with three or four significant digits (0.012 to 12345)."""
    return f"{ms:.0f}" if ms >= 100 else f"{ms:.1f}" if ms >= 10 else f"{ms:.3g}"


def _cell(r: dict | None) -> str:
    if r is None:
        return "-"
    if r["status"] == "ok":
        t = r["total_ms"]
        return f"{_f(t['median'])} ({_f(t['min'])}-{_f(t['max'])})"
    if r["status"] == SKIPPED:
        why = (f"warm-up {r['warmup_ms'] / 1e3:.1f} s" if "warmup_ms" in r
               else f"predicted {r['predicted_s']:.1f} s")
        return f"skipped ({why})"
    return r["status"].split(":", 1)[0] + " (see below)"


def _series_table(res: dict, name: str, head: str, x_of) -> list[str]:
    labels = [m["label"] for m in res["methods"]]
    lines = [f"| {head} | frame max abs CoC px | max abs motion px | "
             + " | ".join(f"{lab} ms" for lab in labels) + " |",
             "|---|---|---|" + "---|" * len(labels)]
    for p in res["series"][name]:
        fr = res["frames"][p["frame"]]
        cells = [_cell(fr["results"].get(lab)) for lab in labels]
        lines.append(f"| {x_of(p, fr)} | {fr['max_abs_coc']:.2f} | {fr['max_abs_motion']:.2f} "
                     "| " + " | ".join(cells) + " |")
    return lines


def markdown(res: dict, out: Path) -> str:
    peak = res["peak"]
    sub = out.name
    sw, sh = res["frames"][res["shares_frame"]]["width"], res["frames"][res["shares_frame"]][
        "height"]
    spp = res["frames"][res["shares_frame"]]["spp"]
    lines = [f"# Scaling study: {res['scene']}, {res['device']}", "",
             f"Command ({res['date']}, {res['elapsed_s'] / 60:.1f} min; device "
             f"{res['device']}; host CPU (`lscpu`): {res['host_cpu']}):", "",
             "```", res["command"], "```", "",
             f"Device ms: the sum of a launch's kernel profiling events; each cell is the "
             f"median (min-max) of {res['repeats']} launch(es) after one warm-up. Each method "
             "runs with its defaults (the safeguard included: its split, half-frame runs, "
             "statistics and blend are passes of the method) unless the label gives knobs. "
             f"A method's frame predicted (from its earlier frames of the series) or warmed "
             f"up above {res['max_seconds_per_frame']:g} s is skipped.", "",
             "## Frames", "",
             f"All frames are the built-in scene `{res['scene']}` (seed {res['seed']}). The "
             "resolution and spp series render it as it is: its CoC and motion in pixels "
             "grow with the width. The blur family renders it with its lens radius and every "
             "object's velocity scaled (`clrecon/bench/scaling.py`): CoC is linear in the "
             "lens radius, screen motion in the velocity, so each scale is refined from the "
             "measured maxima of a render until the frame's max |CoC| and |motion| "
             "(`SampleBuffer.inspect()`) are within 2% of the asked values; geometry, focus "
             "and the samples' random numbers stay, so every sample's CoC (and motion) is "
             "scaled by one factor. The renderer traces each sample from its position, lens "
             "point and time, so positions, lens, time and motion stay consistent.", "",
             "| frame | measured max abs CoC px | measured max abs motion px | lens radius x "
             "| velocity x | renders | miss fraction |", "|---|---|---|---|---|---|---|"]
    for key, fr in res["frames"].items():
        lines.append(f"| {key} | {fr['max_abs_coc']:.3f} | {fr['max_abs_motion']:.3f} | "
                     f"{fr['lens_scale']:.4g} | {fr['motion_scale']:.4g} | {fr['renders']} | "
                     f"{fr['miss_fraction']:.3f} |")
    if res["series"]["resolution"]:
        lines += ["", "## Device time against resolution", "",
                  f"![time vs pixels]({sub}/resolution.png)", "",
                  *_series_table(res, "resolution", "size",
                                 lambda p, fr: f"{fr['width']}x{fr['height']} {fr['spp']} spp")]
    if res["series"]["coc"] or res["series"]["motion"]:
        lines += ["", "## Device time against blur size", "",
                  f"![time vs blur]({sub}/blur.png)", "",
                  "Box's and the safeguard's split, which do not depend on blur, show the "
                  f"machine's noise across these frames (`{sub}/results.json` has every "
                  "pass).", ""]
        if res["series"]["coc"]:
            lines += ["Max |CoC| series (nothing moves):", "",
                      *_series_table(res, "coc", "asked max abs CoC px",
                                     lambda p, fr: f"{p['x']:g}"), ""]
        if res["series"]["motion"]:
            lines += ["Max |motion| series:", "",
                      *_series_table(res, "motion", "asked max abs motion px",
                                     lambda p, fr: f"{p['x']:g}")]
    if res["series"]["spp"]:
        lines += ["", "## Device time against spp", "", f"![time vs spp]({sub}/spp.png)", "",
                  *_series_table(res, "spp", "spp", lambda p, fr: f"{fr['spp']}")]
    lines += ["", f"## Passes at {sw}x{sh} {spp} spp: share of the time, achieved bandwidth",
              "", f"![pass shares]({sub}/shares.png)", "",
              f"![bandwidth]({sub}/bandwidth.png)", "",
              "Byte model (a lower bound: compulsory traffic): a pass is a leaf step of the "
              "plan (`clrecon/core/plan.py`); its bytes are the sizes of the buffers its step "
              "names "
              "as inputs (each read once) and outputs (each written once), as bound for the "
              "call: sample fields as uploaded (or split into halves), temporaries as planned, "
              "`out` H x W x 12. Re-reads of a neighbourhood, gathers and scattered atomics "
              "are not counted, nor a CPU's write-allocate reads, so GB/s is a floor of what "
              "the pass moved. Share: the pass's median ms over the sum of the passes' medians. "
              f"Peak: `copy_float4` (`clrecon/bench/bandwidth.py`), {peak['gb_per_s']:.2f} GB/s "
              f"(runs {min(peak['runs_gb_per_s']):.2f}-{max(peak['runs_gb_per_s']):.2f}, "
              f"{peak['buffer_bytes'] / 2**20:.0f} MiB buffers), the higher of its medians "
              "before the first frame and after the last ("
              + " and ".join(f"{g:.2f}" for g in res["peaks_gb_per_s"]) + " GB/s); a pass "
              "above 100% ran while the machine was less busy than at both, or its buffers "
              "fit in a cache.", "",
              "| method | pass | median ms | share | MB moved (floor) | GB/s | of peak |",
              "|---|---|---|---|---|---|---|"]
    shares = res["frames"][res["shares_frame"]]["results"]
    for m in res["methods"]:
        r = shares.get(m["label"])
        if r is None or r["status"] != "ok":
            lines.append(f"| {m['label']} | {_cell(r)} | | | | | |")
            continue
        for p in r["passes"]:
            lines.append(f"| {m['label']} | {p['name']} | {_f(p['median_ms'])} | "
                         f"{100 * p['share']:.1f}% | {p['bytes'] / 1e6:.1f} | "
                         f"{p['gb_per_s']:.2f} | {100 * p['fraction_of_peak']:.1f}% |")
        lines.append(f"| {m['label']} | **frame** ({r['plan']} plan) | "
                     f"{_f(r['total_ms']['median'])} | 100% | {r['bytes'] / 1e6:.1f} | "
                     f"{r['gb_per_s']:.2f} | {100 * r['gb_per_s'] / peak['gb_per_s']:.1f}% |")
    failed = [(k, lab, r) for k, fr in res["frames"].items()
              for lab, r in fr["results"].items() if r["status"].startswith("failed")]
    if failed:
        lines += ["", "## Failures", ""] + [f"- {k}, {lab}: {r['status']} (at `{r['where']}`)"
                                            for k, lab, r in failed]
    lines += ["", f"Everything measured (every frame's passes): `{sub}/results.json`.", ""]
    return "\n".join(lines)


def _plt():
    from clrecon.bench.trade import _plt

    return _plt()


def _save(fig, path: Path) -> None:
    png = io.BytesIO()
    fig.savefig(png, format="png")
    _plt().close(fig)
    write_atomic(path, png.getvalue())


def _series_lines(ax, res: dict, name: str, x_of, logx: bool = True) -> bool:
    """One line per method: median device ms against the series' x; skipped points named.
    Returns whether any point was drawn."""
    drawn = False
    for k, m in enumerate(res["methods"]):
        pts, missing = [], []
        for p in res["series"][name]:
            fr = res["frames"][p["frame"]]
            ms = _ms(fr["results"].get(m["label"]))
            if ms is None:
                missing.append(p["frame"])
            else:
                pts.append((x_of(p, fr), ms))
        label = m["label"] + (f" ({len(missing)} not timed)" if missing else "")
        xs, ys = zip(*pts) if pts else ((), ())
        ax.plot(xs, ys, marker="os^vDP"[k % 6], color=f"C{k}", label=label)
        drawn = drawn or bool(pts)
    if drawn:
        ax.set_yscale("log")
        if logx:
            from matplotlib.ticker import ScalarFormatter

            ax.set_xscale("log", base=2)
            ax.xaxis.set_major_formatter(ScalarFormatter())
    else:  # every frame skipped or failed: no axis to scale logarithmically
        ax.text(0.5, 0.5, "nothing timed", ha="center", transform=ax.transAxes)
    ax.set_ylabel("device ms (median)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    return drawn


def plots(res: dict, out: Path) -> list[Path]:
    plt = _plt()
    written = []
    title = f"{res['scene']}, {res['device']}"
    if res["series"]["resolution"]:
        fig, ax = plt.subplots(figsize=(7, 5), dpi=110)
        if _series_lines(ax, res, "resolution", lambda p, fr: fr["width"] * fr["height"],
                         logx=False):
            ax.set_xscale("log")
        pts = res["series"]["resolution"]
        ax.set_xticks([p["x"] for p in pts])
        ax.set_xticklabels([p["frame"].split()[0] for p in pts], fontsize=7)
        ax.minorticks_off()
        ax.set_xlabel(f"pixels ({res['frames'][pts[0]['frame']]['spp']} spp)")
        ax.set_title(f"Device time vs resolution: {title}", fontsize=9)
        fig.tight_layout()
        _save(fig, out / "resolution.png")
        written.append(out / "resolution.png")
    if res["series"]["coc"] or res["series"]["motion"]:
        fig, axes = plt.subplots(1, 2, figsize=(11, 4.8), dpi=110)
        if res["series"]["coc"]:
            _series_lines(axes[0], res, "coc", lambda p, fr: fr["max_abs_coc"])
        axes[0].set_xlabel("frame max |CoC| px (measured; nothing moves)")
        if res["series"]["motion"]:
            _series_lines(axes[1], res, "motion", lambda p, fr: fr["max_abs_motion"],
                          logx=False)
            coc = res["frames"][res["series"]["motion"][0]["frame"]]["target_coc"]
            axes[1].set_xlabel(f"frame max |motion| px (measured; max |CoC| {coc:g} px)")
        fig.suptitle(f"Device time vs blur: {title}", fontsize=9)
        fig.tight_layout()
        _save(fig, out / "blur.png")
        written.append(out / "blur.png")
    if res["series"]["spp"]:
        fig, ax = plt.subplots(figsize=(7, 5), dpi=110)
        _series_lines(ax, res, "spp", lambda p, fr: fr["spp"])
        pts = res["series"]["spp"]
        ax.set_xticks([p["x"] for p in pts])
        ax.set_xticklabels([f"{p['x']:g}" for p in pts])
        ax.set_xlabel("samples per pixel")
        ax.set_title(f"Device time vs spp: {title}", fontsize=9)
        fig.tight_layout()
        _save(fig, out / "spp.png")
        written.append(out / "spp.png")
    written += _pass_plots(res, out, plt)
    return written


def _base(name: str) -> str:
    return name.replace(" (halves)", "")


def _pass_plots(res: dict, out: Path, plt) -> list[Path]:
    """The pass-share stacked bars and the per-pass bandwidth at the shares frame."""
    fr = res["frames"][res["shares_frame"]]
    where = f"{fr['width']}x{fr['height']} {fr['spp']} spp"
    ok = [(m["label"], fr["results"][m["label"]]) for m in res["methods"]
          if fr["results"].get(m["label"], {}).get("status") == "ok"]
    names = list(dict.fromkeys(_base(p["name"]) for _, r in ok for p in r["passes"]))
    cmap = plt.get_cmap("tab20")
    colour = {n: cmap(i % 20) for i, n in enumerate(names)}
    fig, ax = plt.subplots(figsize=(max(6.0, 1.6 * len(res["methods"]) + 4), 5.5), dpi=110)
    shown = set()
    for i, m in enumerate(res["methods"]):
        r = fr["results"].get(m["label"])
        if r is None or r["status"] != "ok":
            ax.text(i, 0.5, "not timed", ha="center", rotation=90, fontsize=8)
            continue
        bottom = 0.0
        for p in r["passes"]:
            b = _base(p["name"])
            ax.bar(i, p["share"], bottom=bottom, color=colour[b], edgecolor="white",
                   hatch="//" if b != p["name"] else None,
                   label=b if b not in shown else None)
            shown.add(b)
            if p["share"] > 0.06:
                ax.text(i, bottom + p["share"] / 2, f"{100 * p['share']:.0f}%", ha="center",
                        va="center", fontsize=7)
            bottom += p["share"]
        ax.text(i, 1.01, f"{_f(r['total_ms']['median'])} ms", ha="center", va="bottom",
                fontsize=7)
    ax.set_xticks(range(len(res["methods"])))
    ax.set_xticklabels([m["label"] for m in res["methods"]], fontsize=8)
    ax.set_ylim(0, 1.08)
    ax.set_ylabel("share of the frame's device time")
    ax.set_title(f"Pass shares at {where} ({res['scene']}); hatched: the safeguard's "
                 "half-frame runs", fontsize=9)
    if shown:
        ax.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.0, 0.5))
    fig.tight_layout()
    _save(fig, out / "shares.png")

    peak = res["peak"]["gb_per_s"]
    xs = [(lab, p) for lab, r in ok for p in r["passes"]]
    fig, ax = plt.subplots(figsize=(max(7.0, 0.28 * len(xs) + 2), 6), dpi=110)
    for i, (_lab, p) in enumerate(xs):
        if p["gb_per_s"] > 0 and math.isfinite(p["gb_per_s"]):
            ax.scatter(i, p["gb_per_s"], color=colour[_base(p["name"])], zorder=3, s=24)
    ax.axhline(peak, color="k", lw=1.2, label=f"copy_float4 peak {peak:.1f} GB/s")
    ax.set_yscale("log")
    ax.set_xticks(range(len(xs)))
    ax.set_xticklabels([f"{lab}: {p['name'].replace(' (halves)', ' (h)')}" for lab, p in xs],
                       rotation=70, ha="right", fontsize=6)
    ax.set_ylabel("achieved GB/s (floor: compulsory bytes / device time)")
    ax.set_title(f"Achieved bandwidth per pass at {where} ({res['scene']}); (h): half-frame "
                 "runs", fontsize=9)
    ax.grid(True, which="both", axis="y", alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    _save(fig, out / "bandwidth.png")
    return [out / "shares.png", out / "bandwidth.png"]


def write(res: dict, out: Path) -> list[Path]:
    """``OUT.md``, ``OUT/results.json`` and the plots; returns the files written."""
    out.mkdir(parents=True, exist_ok=True)
    js = out / "results.json"
    write_atomic(js, (json.dumps(_jsonable(res), indent=1, allow_nan=False) + "\n").encode())
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
