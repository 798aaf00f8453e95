"""The scaling study's measurement (``tools/scaling_study.py`` is its command line): which
frames it renders, and each method's device time on each, per leaf pass with the bytes the
pass moves (:class:`clrecon.bench.timing.LeafRun`, what ``clrecon bench`` uses), within a
time budget. The script's docstring describes the study; :mod:`clrecon.bench.scaling_report`
and :mod:`clrecon.bench.scaling_plots` write it up."""
from __future__ import annotations

import datetime
import math
import shlex
import statistics
import sys
import time
import traceback

import pyopencl as cl

from clrecon.api import make_pipeline
from clrecon.bench.bandwidth import measure_peak
from clrecon.bench.scaling import render_blur_frame
from clrecon.bench.timing import LeafRun, host_cpu
from clrecon.core.device import get_device
from clrecon.core.pipeline import DeviceSamples
from clrecon.scenes import get_scene, render_samples

#: each buffer of the bandwidth peak in ``--quick`` (the full study uses the default size)
QUICK_PEAK_BYTES = 32 * 2**20

SERIES = ("resolution", "spp", "coc", "motion")
SKIPPED = "skipped (over budget)"


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
    leaf = LeafRun(pipe, q, samples, out)  # the warm-up launch
    passes = leaf.passes
    warm_ms = float(sum(pipe.pass_times_ms().values()))
    res = {"plan": pipe.describe()["plan"], "warmup_ms": warm_ms, "predicted_s": predicted}
    if warm_ms * 1e-3 > budget_s:
        return {"status": SKIPPED, **res}
    runs = [leaf.run() for _ in range(repeats)]
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


def study(a, argv: list[str]) -> dict:
    """Render every frame of the plan and time every method on it; the results.

    ``a``: the script's parsed options (``tools/scaling_study.py``'s ``parse_args``:
    ``device``, ``scene``, ``seed``, ``variants``, ``repeats``, ``max_seconds_per_frame``,
    ``quick`` and what :func:`plan_frames` reads); ``argv``: its command line, recorded."""
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
            "host_cpu": host_cpu(), "scene": a.scene, "seed": a.seed, "repeats": a.repeats,
            "max_seconds_per_frame": a.max_seconds_per_frame, "quick": a.quick,
            "peak": peak.to_dict(), "peaks_gb_per_s": [p.gb_per_s for p in peaks],
            "methods": [{"label": lab, "method": m, "knobs": k} for lab, m, k in a.variants],
            "frames": out_frames,
            "series": {s: [{"x": x, "frame": k} for x, k in pts] for s, pts in series.items()},
            "shares_frame": a.shares_key}


def log(text: str) -> None:
    """A progress line on stderr (stdout stays free)."""
    print(text, file=sys.stderr, flush=True)
