"""Cross-device benchmark: per-pass and whole-frame device times of reconstruction variants on
every OpenCL device, with the tuned configuration and the default one side by side
(``clrecon bench``).

Per device and variant the pipeline is built once with the configuration the normal tuning
lookup gives (:func:`clrecon.tune.runtime.tuned`) and once more with every pass forced to
its spec's default (``CLRECON_TUNE_<PASS>`` set to ``SPECS[pass].default`` while the second
pipeline is built; the environment is restored afterwards). The samples are uploaded once;
after one warm-up launch of each pipeline, ``repeats`` *paired* runs follow: in each run the
tuned and the default pipeline are launched back to back (the order alternating from run to
run), so both see the same machine noise. The devices take turns variant by variant (every
device runs the first variant, then every device the second...), so that a shared machine's
load, which drifts over minutes, is not all on the device benched last; all devices
reconstruct the same samples. Reported per pass and for the whole frame (the sum of the
passes): min, median and max device ms from the profiling events, samples per second at
the median frame time, and the median of the per-run ratio default / tuned.

Passes whose configuration already is the default (tuning source ``"default"`` or
``"runtime"``) or was fixed by the caller's knobs (``"api"``) are not forced; when no pass is
left to force, the default runs are skipped, the ratio is reported as 1.0 and the run's
``forced_default`` is ``False``.

Each pass is also reported as a bandwidth: the bytes it must at least move, divided by its
device time. A pass here is a leaf plan step, one that launches kernels itself: a step that
runs a sub-pipeline (a safeguarded method's ``sweep`` and ``sweep (halves)`` steps) is
looked into, down to the steps of the method's own plan. The byte count of a pass is that
of the buffers its :class:`clrecon.core.plan.Step` names as ``inputs`` and ``outputs``, at the
size bound for the call (sample fields as uploaded or split into halves, temporaries as
planned, ``out`` ``H * W * 12``), each input read once and each output written once (a
buffer a step both reads and writes counts twice; a step run twice, for both halves, counts
twice). Caches can serve re-reads of a neighbourhood, so this is a floor of the traffic, and
the GB/s a floor of what the pass achieved. A pass is named after its kernels: most launch
one, whose row it shares; one that launches several (layered's ``filter_sheared``:
``filter_sheared_x`` then ``_y``) gets its own row, ``"filter_sheared_x + filter_sheared_y"``,
timed as the sum of its kernels. The frame's bytes are the sum of its passes', over the
frame's time (the sum of the kernels'). Each GB/s is also given as a fraction of the
device's streaming peak, measured per device before the variants with
:func:`clrecon.bench.bandwidth.measure_peak` on the bench's queue; optionally clpeak's
global-memory bandwidth is reported beside it (:func:`clrecon.bench.bandwidth.clpeak_bandwidth`).

Results are long rows in the manner of clpeak (one measured value per row, see
:data:`ROW_KEYS`), written as JSON and CSV by :func:`write_outputs`; :func:`compare` gives
the change against an earlier JSON. :func:`plot_bandwidth` draws each pass's GB/s against
each device's peak.
"""
from __future__ import annotations

import csv
import io
import json
import math
import numbers
import os
import statistics
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Callable, Optional, Union

import pyopencl as cl

from clrecon.bench.bandwidth import clpeak_bandwidth, measure_peak
from clrecon.bench.table import Variant, _check_variants
from clrecon.core.device import Device, DeviceSpec, event_ms, get_device, list_devices
from clrecon.core.errors import DeviceError
from clrecon.core.fsutil import write_atomic
from clrecon.core.pipeline import DeviceSamples, Pipeline, make_pipeline
from clrecon.core.samples import SampleBuffer
from clrecon.tune.db import env_var
from clrecon.tune.runtime import clear_cache
from clrecon.tune.specs import SPECS, synthetic_frame

Progress = Optional[Callable[[int, int], None]]
PathLike = Union[str, "os.PathLike[str]"]

#: the variants benchmarked when none are given
DEFAULT_VARIANTS: tuple[Variant, ...] = (
    ("box", "box", {}),
    ("sweep 2-scale", "sweep", {"scales": 2}),
    ("sweep dof-layers", "sweep", {"dof_layers": True}),
)

#: the keys of every long-format row, in CSV column order
ROW_KEYS = ("device", "driver", "platform", "method", "pass", "size", "spp", "config",
            "metric", "unit", "value")

#: tuning sources whose pass is not forced to its default ("api": fixed by the caller's knobs)
NOT_FORCED = ("default", "runtime", "api")

#: the key a row is matched on by :func:`compare`
MATCH_KEYS = ("device", "method", "pass", "size", "spp", "config", "metric")

#: the metrics :func:`compare` reports, and whether a larger value is better
COMPARED = {"median_ms": False, "samples_per_s": True, "gb_per_s": True}

#: the ``config`` of the rows that hold a device's peak (metrics ``peak_gb_per_s`` and,
#: with clpeak, ``clpeak_gb_per_s``), one set per variant on its ``frame`` row
PEAK_CONFIG = "peak"

_UNITS = {"min_ms": "ms", "median_ms": "ms", "max_ms": "ms", "samples_per_s": "1/s",
          "ratio_default_over_tuned": "x", "bytes": "B", "gb_per_s": "GB/s",
          "fraction_of_peak": "x", "peak_gb_per_s": "GB/s", "clpeak_gb_per_s": "GB/s"}


def variant_list(extra: Sequence[Variant] = (), only: bool = False) -> list[Variant]:
    """The variants a bench runs: :data:`DEFAULT_VARIANTS`, then ``extra``.

    An ``extra`` variant equal to a default one (label, method and knobs) is not repeated;
    one that reuses a default's label for something else is refused by :func:`bench`. With
    ``only``, ``extra`` alone (``clrecon bench --only``).

    Raises
    ------
    ValueError
        ``only`` without any ``extra`` variant.
    """
    extra = [(label, method, dict(knobs or {})) for label, method, knobs in extra]
    if only:
        if not extra:
            raise ValueError("--only: give the variants to run (--variant or --methods)")
        return extra
    out = [(label, method, dict(knobs)) for label, method, knobs in DEFAULT_VARIANTS]
    return out + [v for v in extra if v not in out]


# -- measuring -----------------------------------------------------------------------------

def _select_devices(devices: str | DeviceSpec | Sequence[DeviceSpec]) -> list[Device]:
    """The :class:`Device` objects for ``"all"`` or a list of specs (no repeats, in order)."""
    if isinstance(devices, str) and devices.strip().lower() == "all":
        specs: list[DeviceSpec] = [d.index for d in list_devices()]
        if not specs:
            raise DeviceError("no OpenCL device found on any platform")
    elif isinstance(devices, (int, str)):
        specs = [devices]
    else:
        specs = list(devices)
        if not specs:
            raise ValueError("devices: need at least one (or 'all')")
    out: dict[int, Device] = {}
    for spec in specs:
        if spec is None or isinstance(spec, bool):
            raise ValueError(f"devices: expected an index or a name substring, got {spec!r}")
        dev = get_device(spec)
        out.setdefault(dev.info.index, dev)
    return list(out.values())


def _forced_default(method: str, context: cl.Context, info, knobs: dict,
                    passes: Sequence[str]) -> Pipeline:
    """Build the pipeline with ``passes`` forced to their spec's default configuration."""
    saved: dict[str, str | None] = {}
    try:
        for p in passes:
            var = env_var(p)
            saved.setdefault(var, os.environ.get(var))
            os.environ[var] = json.dumps(SPECS[p].default)
        clear_cache()
        return make_pipeline(method, context, info, **knobs)
    finally:
        for var, value in saved.items():
            if value is None:
                os.environ.pop(var, None)
            else:
                os.environ[var] = value
        clear_cache()


@dataclass
class _Passes:
    """What the bench reports a bandwidth for: each *leaf* plan step (one that runs kernels
    itself, not through a sub-pipeline), named after the kernels it launched.

    ``owners[i]`` is the pass of the top pipeline's ``events[i]``; ``bytes`` the bytes of each
    pass's bound buffers (inputs + outputs, summed over its invocations); ``kernels`` the
    kernel (event) names of each pass in launch order."""

    owners: list[str]
    bytes: dict[str, int]
    kernels: dict[str, list[str]]


def _sub_pipelines(pipe: Pipeline) -> list[Pipeline]:
    """``pipe`` and every pipeline it holds as an attribute (a safeguarded method's full-frame
    and half-frame pipelines), recursively, each once."""
    out, todo = [], [pipe]
    while todo:
        p = todo.pop()
        if any(p is q for q in out):
            continue
        out.append(p)
        todo += [v for v in vars(p).values() if isinstance(v, Pipeline)]
    return out


def _warm_up(pipe: Pipeline, queue: cl.CommandQueue, samples: DeviceSamples,
             out: cl.Buffer) -> _Passes:
    """One launch, waited for (PoCL specialises on the first), that also finds the passes.

    For this launch only, every step of ``pipe`` and of its sub-pipelines is wrapped (the
    plan is data: the same steps, each noting the buffers it was given and the events it
    returned; every plan is restored afterwards). A step during which no other step ran is a
    leaf; its bytes are the sizes of the buffers its ``inputs`` and ``outputs`` name as
    bound for that call, and it owns the events it returned. A leaf is named after its
    kernels as the top pipeline names them (``"filter_sheared_x + filter_sheared_y"`` for
    a two-kernel step; a safeguarded method's half-frame runs keep their ``" (halves)"``)."""
    calls: list[tuple[int, list[int]]] = []  # leaf calls: (bytes, event handles)
    nested = [False]  # did a step run since the current one started?

    def counted(step):
        def run(q, frame, wait_for):
            nested[0] = False
            evs = step.run(q, frame, wait_for)
            if not nested[0]:
                sizes = {n: int(frame.buffers[n].size) for n in step.inputs + step.outputs}
                calls.append((sum(sizes[n] for n in step.inputs)
                              + sum(sizes[n] for n in step.outputs),
                              [ev.int_ptr for _, ev in evs]))
            nested[0] = True  # the enclosing step, if any, is not a leaf
            return evs
        return replace(step, run=run)

    pipes = _sub_pipelines(pipe)
    plans = [p.plan for p in pipes]
    for p in pipes:
        p.plan = replace(p.plan, steps=tuple(counted(st) for st in p.plan.steps))
    try:
        pipe(queue, samples, out).wait()
    finally:
        for p, plan in zip(pipes, plans):
            p.plan = plan
    call_of = {h: i for i, (_, handles) in enumerate(calls) for h in handles}
    names_of: dict[int, list[str]] = {}
    for name, ev in pipe.events:
        i = call_of.get(ev.int_ptr, -1)
        if name not in names_of.setdefault(i, []):
            names_of[i].append(name)
    label = {i: " + ".join(names) for i, names in names_of.items() if i >= 0}
    passes = _Passes([], {}, {})
    for name, ev in pipe.events:
        i = call_of.get(ev.int_ptr, -1)
        passes.owners.append(label.get(i, name))  # an event no leaf returned: by its name
    for i, (nbytes, _) in enumerate(calls):
        if i in label:
            passes.bytes[label[i]] = passes.bytes.get(label[i], 0) + nbytes
            passes.kernels.setdefault(label[i], names_of[i])
    return passes


def _launch(pipe: Pipeline, queue: cl.CommandQueue, samples: DeviceSamples,
            out: cl.Buffer, passes: _Passes) -> tuple[dict[str, float], dict[str, float]]:
    """One launch, waited for: per-kernel device ms plus ``"frame"`` (their sum), and per
    pass (see :func:`_warm_up`) the sum of its kernels (NaN should the launch enqueue other
    events than the warm-up's)."""
    pipe(queue, samples, out).wait()
    times = dict(pipe.pass_times_ms())
    times["frame"] = float(sum(times.values()))
    steps: dict[str, float] = {}
    if len(pipe.events) == len(passes.owners):
        for owner, (_, ev) in zip(passes.owners, pipe.events):
            steps[owner] = steps.get(owner, 0.0) + event_ms(ev)
    else:
        steps = {name: math.nan for name in passes.bytes}
    return times, steps


def _ratio(a: float, b: float) -> float:
    return a / b if b > 0 and math.isfinite(a) and math.isfinite(b) else math.nan


def _median_finite(values: Sequence[float]) -> float:
    finite = [v for v in values if math.isfinite(v)]
    return statistics.median(finite) if finite else math.nan


def _time_variant(dev: Device, buf: SampleBuffer, method: str, knobs: dict,
                  repeats: int) -> dict:
    """Build, upload, warm up and time the tuned (and, paired, the default) pipeline."""
    info = buf.inspect()
    tuned_pipe = make_pipeline(method, dev.context, info, **knobs)
    desc = tuned_pipe.describe()
    sources = dict(desc.get("tuning", {}))
    forced = [p for p, src in sources.items() if src not in NOT_FORCED and p in SPECS]
    default_pipe = (_forced_default(method, dev.context, info, knobs, forced)
                    if forced else None)
    q = dev.queue
    samples = DeviceSamples.upload(q, buf, tuned_pipe.fields)
    out = cl.Buffer(dev.context, cl.mem_flags.READ_WRITE, size=buf.height * buf.width * 12)
    pipes = {"tuned": tuned_pipe, "default": default_pipe}
    passes = {k: _warm_up(p, q, samples, out) for k, p in pipes.items() if p is not None}
    runs: dict[str, list] = {"tuned": [], "default": []}
    for i in range(repeats):
        order = ["tuned"] if default_pipe is None else (
            ["tuned", "default"] if i % 2 == 0 else ["default", "tuned"])
        for k in order:
            runs[k].append(_launch(pipes[k], q, samples, out, passes[k]))
    return {"describe": desc, "tuning": sources, "forced": forced,
            "default_describe": None if default_pipe is None else default_pipe.describe(),
            "tuned": [t for t, _ in runs["tuned"]], "default": [t for t, _ in runs["default"]],
            "steps": {k: [st for _, st in v] for k, v in runs.items()},
            "step_bytes": {k: v.bytes for k, v in passes.items()},
            "step_kernels": {k: v.kernels for k, v in passes.items()}}


def _rows_of(dev: Device, label: str, size: str, spp: int, npix_spp: int,
             timed: dict, peak: dict) -> list[dict]:
    """The long rows of one device and variant (``peak``: the device's entry of the
    result's ``peaks``)."""
    base = {"device": dev.info.label, "driver": dev.info.driver,
            "platform": dev.info.platform, "method": label, "size": size, "spp": spp}
    rows = []

    def row(pass_name: str, config: str, metric: str, value: float) -> None:
        r = base | {"pass": pass_name, "config": config, "metric": metric,
                    "unit": _UNITS[metric], "value": float(value)}
        rows.append({k: r[k] for k in ROW_KEYS})

    names = list(timed["tuned"][0])  # pass order of the pipeline, then "frame"
    for config in ("tuned", "default"):
        runs = timed[config]
        if not runs:
            continue
        for name in names:
            vals = [r[name] for r in runs]
            row(name, config, "min_ms", min(vals))
            row(name, config, "median_ms", statistics.median(vals))
            row(name, config, "max_ms", max(vals))
            if name == "frame":
                med_s = statistics.median(vals) * 1e-3
                row(name, config, "samples_per_s", npix_spp / med_s if med_s > 0 else math.nan)
    for name in names:
        if timed["default"]:
            ratio = _median_finite([_ratio(d[name], t[name])
                                    for t, d in zip(timed["tuned"], timed["default"])])
        else:
            ratio = 1.0  # every pass already runs its default configuration
        row(name, "default", "ratio_default_over_tuned", ratio)
    peak_gbs = (peak.get("copy") or {}).get("gb_per_s", math.nan)
    for config in ("tuned", "default"):
        runs = timed["steps"][config]
        if not runs:
            continue
        moved = timed["step_bytes"][config]
        for step, nbytes in moved.items():
            vals = [r.get(step, math.nan) for r in runs]
            if step not in names:  # a multi-kernel pass: its own time beside its kernels'
                row(step, config, "min_ms", min(vals))
                row(step, config, "median_ms", _median_finite(vals))
                row(step, config, "max_ms", max(vals))
                if config == "default":
                    row(step, config, "ratio_default_over_tuned", _median_finite(
                        [_ratio(d.get(step, math.nan), t.get(step, math.nan))
                         for t, d in zip(timed["steps"]["tuned"], runs)]))
                elif not timed["default"]:
                    row(step, "default", "ratio_default_over_tuned", 1.0)
            _bandwidth_rows(row, step, config, nbytes, _median_finite(vals), peak_gbs)
        frame_ms = statistics.median(r["frame"] for r in timed[config])
        _bandwidth_rows(row, "frame", config, sum(moved.values()), frame_ms, peak_gbs)
    row("frame", PEAK_CONFIG, "peak_gb_per_s", peak_gbs)
    if (peak.get("clpeak") or {}).get("best_gb_per_s") is not None:
        row("frame", PEAK_CONFIG, "clpeak_gb_per_s", peak["clpeak"]["best_gb_per_s"])
    return rows


def _bandwidth_rows(row: Callable, name: str, config: str, nbytes: int, ms: float,
                    peak_gbs: float) -> None:
    gbs = nbytes / (ms * 1e6) if ms > 0 and math.isfinite(ms) else math.nan
    row(name, config, "bytes", nbytes)
    row(name, config, "gb_per_s", gbs)
    row(name, config, "fraction_of_peak", _ratio(gbs, peak_gbs))


def _peak_of(dev: Device, peak: bool, peak_bytes: int | None, clpeak: bool) -> dict:
    """The device's entry of a result's ``peaks``: ``copy`` (our copy kernel's
    :class:`~clrecon.bench.bandwidth.Peak` as a dict, ``None`` without ``peak``) and
    ``clpeak`` (``None`` when not asked for or not installed, else what
    :func:`~clrecon.bench.bandwidth.clpeak_bandwidth` gave)."""
    return {"copy": measure_peak(dev.queue, peak_bytes).to_dict() if peak else None,
            "clpeak": clpeak_bandwidth(dev.device) if clpeak else None,
            "clpeak_asked": bool(clpeak)}


def bench(devices: str | DeviceSpec | Sequence[DeviceSpec] = "all",
          variants: Sequence[Variant] | None = None, size: tuple[int, int] = (1280, 720),
          spp: int = 16, repeats: int = 7, progress: Progress = None,
          scene: str | None = None, peak: bool = True, peak_bytes: int | None = None,
          clpeak: bool = False) -> dict:
    """Time each variant's passes on each device, tuned and with default configurations.

    Parameters
    ----------
    devices : "all", int, str or sequence of int/str
        ``"all"``: every OpenCL device present (:func:`clrecon.core.device.list_devices`);
        otherwise device indices or case-insensitive substrings of ``"platform / device"``
        (see :func:`clrecon.core.device.get_device`). A device named twice is benched once.
    variants : sequence of (label, method, knobs), optional
        Default :data:`DEFAULT_VARIANTS` (box, sweep 2-scale, sweep dof-layers); see
        :func:`clrecon.bench.table.parse_variant` for a text form. Labels must be unique.
    size : tuple of int
        ``(width, height)`` of the frame.
    spp : int
        Samples per pixel.
    repeats : int
        Timed (paired) runs per device and variant, after one warm-up launch.
    progress : callable, optional
        ``progress(done, total)`` after the input frame, each device's peak and each
        variant.
    scene : str, optional
        ``None``: :func:`clrecon.tune.specs.synthetic_frame` (no renderer involved);
        otherwise a built-in scene rendered with :func:`clrecon.scenes.render_samples`
        (seed 0) once, on the first benched device: every device reconstructs the same
        samples.
    peak : bool
        Measure each device's streaming peak (:func:`clrecon.bench.bandwidth.measure_peak`)
        before its variants; without it the fractions of peak are NaN.
    peak_bytes : int, optional
        Size of each of the peak's two buffers (default: far beyond the last-level cache,
        see :func:`clrecon.bench.bandwidth.default_buffer_bytes`).
    clpeak : bool
        Also run clpeak's global-memory bandwidth test on each device when the ``clpeak``
        binary is installed (about half a minute a device; skipped when it is absent).

    Returns
    -------
    dict
        ``devices`` (labels), ``size`` (``[w, h]``), ``spp``, ``repeats``, ``scene``,
        ``variants`` (``label``, ``method``, ``knobs``), ``peaks`` (device label ->
        ``copy``, ``clpeak``, ``clpeak_asked``; see :func:`clrecon.bench.bandwidth`),
        ``runs`` (per device and variant: ``device``, ``method``, ``tuning`` (pass ->
        tuning source), ``forced_default``, ``forced_passes``, ``describe``,
        ``default_describe``, ``pass_bytes`` (pass -> bytes) and ``step_kernels`` (pass -> its
        kernels' names)), ``rows`` (long rows with the keys
        :data:`ROW_KEYS`; ``config`` ``"tuned"`` or ``"default"``, metrics ``min_ms``,
        ``median_ms``, ``max_ms``, ``samples_per_s`` (frame only),
        ``ratio_default_over_tuned`` (config ``"default"``), per pass and the frame
        ``bytes``, ``gb_per_s`` and ``fraction_of_peak``; config :data:`PEAK_CONFIG` on the
        frame: ``peak_gb_per_s`` and, with clpeak, ``clpeak_gb_per_s``) and ``markdown``.

    Raises
    ------
    ValueError
        Bad size, spp, repeats, device list, scene or variant.
    TypeError
        A variant's knob that its method does not take.
    clrecon.core.errors.DeviceError
        No OpenCL device, or a spec that matches none.
    """
    variants = _check_variants(DEFAULT_VARIANTS if variants is None else variants)
    try:
        w, h = (int(v) for v in size)
    except (TypeError, ValueError):
        raise ValueError(f"size: expected (width, height), got {size!r}") from None
    for name, v in (("width", w), ("height", h), ("spp", spp), ("repeats", repeats)):
        if isinstance(v, bool) or not isinstance(v, numbers.Integral) or v < 1:
            raise ValueError(f"{name}: must be a positive integer, got {v!r}")
    spp, repeats = int(spp), int(repeats)
    scene_obj = None
    if scene is not None:
        from clrecon.scenes import get_scene

        scene_obj = get_scene(scene)  # unknown names fail before any device work
    if peak_bytes is not None and not peak:
        raise ValueError("peak_bytes: given with peak=False")
    devs = _select_devices(devices)
    steps, done = 1 + len(devs) * (1 + len(variants)), 0

    def step() -> None:
        nonlocal done
        done += 1
        if progress:
            progress(done, steps)

    size_s = f"{w}x{h}"
    if scene_obj is None:
        buf = synthetic_frame(w, h, spp)
    else:
        from clrecon.scenes import render_samples

        buf = render_samples(scene_obj, w, h, spp, seed=0, device=devs[0])
        buf.validate()
    step()
    rows: list[dict] = []
    runs: list[dict] = []
    peaks: dict[str, dict] = {}
    for dev in devs:
        peaks[dev.info.label] = _peak_of(dev, peak, peak_bytes, clpeak)
        step()
    # variant by variant, every device in turn: a shared machine's load, which drifts over
    # minutes, then weighs on all devices alike instead of on whichever ran last
    for label, method, knobs in variants:
        for dev in devs:
            timed = _time_variant(dev, buf, method, knobs, repeats)
            rows += _rows_of(dev, label, size_s, spp, w * h * spp, timed,
                             peaks[dev.info.label])
            runs.append({"device": dev.info.label, "method": label, "tuning": timed["tuning"],
                         "forced_default": bool(timed["forced"]),
                         "forced_passes": timed["forced"], "describe": timed["describe"],
                         "default_describe": timed["default_describe"],
                         "pass_bytes": timed["step_bytes"]["tuned"],
                         "step_kernels": timed["step_kernels"]["tuned"]})
            step()
    result = {"devices": [d.info.label for d in devs], "size": [w, h], "spp": spp,
              "repeats": repeats, "scene": scene,
              "variants": [{"label": lab, "method": m, "knobs": k} for lab, m, k in variants],
              "peaks": peaks, "runs": runs, "rows": rows}
    result["markdown"] = _markdown(result)
    return result


# -- reporting -----------------------------------------------------------------------------

def _fmt(v: Any, spec: str = ".3f") -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "n/a"
    return format(v, spec)


def _index(rows: Sequence[dict]) -> dict[tuple, float]:
    return {(r["device"], r["method"], r["pass"], r["config"], r["metric"]): r["value"]
            for r in rows}


def _pass_order(res: dict, run: dict) -> list[str]:
    """The pass names of a run's rows in launch order: each kernel, a multi-kernel step after
    its last kernel, then ``frame``."""
    d, m = run["device"], run["method"]
    names = list(dict.fromkeys(r["pass"] for r in res["rows"]
                               if r["device"] == d and r["method"] == m))
    after = {kernels[-1]: step for step, kernels in run.get("step_kernels", {}).items()
             if kernels and step not in kernels}
    out = []
    for name in names:
        if name == "frame" or name in after.values():
            continue
        out.append(name)
        if name in after and after[name] in names:
            out.append(after[name])
    return out + (["frame"] if "frame" in names else [])


def _gbs_cells(vals: dict, d: str, m: str, name: str, config: str = "tuned") -> tuple[str, str]:
    """GB/s and percent of peak of a pass (``-`` for a kernel that is part of a step)."""
    gbs = vals.get((d, m, name, config, "gb_per_s"))
    if gbs is None:
        return "-", "-"
    frac = vals.get((d, m, name, config, "fraction_of_peak"))
    return _fmt(gbs, ".2f"), _fmt(None if frac is None else 100 * frac, ".0f") + (
        "%" if frac is not None and math.isfinite(frac) else "")


def _peak_lines(res: dict) -> list[str]:
    lines = ["Streaming peak per device: `copy_float4` (kernels/bandwidth.cl) on the bench's "
             "queue, bytes read + written over device time, median of the timed launches; "
             "clpeak: its global-memory (read) bandwidth, fastest vector width.", "",
             "| device | copy GB/s (median) | copy runs min-max GB/s | buffer MiB | clpeak GB/s |",
             "|---|---|---|---|---|"]
    for d in res["devices"]:
        pk = res.get("peaks", {}).get(d, {})
        copy, clp = pk.get("copy"), pk.get("clpeak")
        if clp is None:
            clp_s = "not installed" if pk.get("clpeak_asked") else "not run (--clpeak)"
        elif "error" in clp:
            clp_s = f"failed: {clp['error']}"
        else:
            clp_s = f"{clp['best_gb_per_s']:.2f} ({clp['best_width']})"
        if copy is None:
            lines.append(f"| {d} | not measured | | | {clp_s} |")
            continue
        rr = copy["runs_gb_per_s"]
        lines.append(f"| {d} | {copy['gb_per_s']:.2f} | {min(rr):.2f}-{max(rr):.2f} | "
                     f"{copy['buffer_bytes'] / 2**20:.0f} | {clp_s} |")
    return lines


def _markdown(res: dict) -> str:
    w, h = res["size"]
    vals = _index(res["rows"])
    source = "synthetic frame" if res.get("scene") is None else f"scene {res['scene']!r}"
    lines = [f"{w}x{h}, {res['spp']} spp ({source}); device ms of {res['repeats']} runs after "
             "a warm-up; default runs paired with the tuned ones (alternating launches); "
             "default/tuned: median of the per-run ratios (> 1: tuning helps); GB/s: the "
             "bytes of the pass's buffers (inputs read once, outputs written once) over its "
             "median device time, and that as a percentage of the device's peak.", "",
             "| device | variant | pass | tuned min ms | tuned median ms | tuned max ms | "
             "GB/s | of peak | default median ms | default/tuned | tuning |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for run in res["runs"]:
        d, m = run["device"], run["method"]
        for name in _pass_order(res, run):
            t = [vals.get((d, m, name, "tuned", k)) for k in ("min_ms", "median_ms", "max_ms")]
            dflt = vals.get((d, m, name, "default", "median_ms"))
            ratio = vals.get((d, m, name, "default", "ratio_default_over_tuned"))
            if name == "frame":
                tuning = ("default forced: " + ", ".join(run["forced_passes"])
                          if run["forced_default"] else "all at default: not forced")
                label = "**frame**"
            else:
                tuning, label = run["tuning"].get(name, ""), name
            dflt_s = _fmt(dflt) if run["forced_default"] else "= tuned"
            gbs, frac = _gbs_cells(vals, d, m, name)
            lines.append(f"| {d} | {m} | {label} | {_fmt(t[0])} | {_fmt(t[1])} | {_fmt(t[2])} | "
                         f"{gbs} | {frac} | {dflt_s} | {_fmt(ratio, '.2f')} | {tuning} |")
    lines += ["", *_peak_lines(res)]
    labels = list(dict.fromkeys(r["method"] for r in res["rows"]))
    lines += ["", "Frame median device ms (tuned) and M samples/s, devices side by side:", "",
              "| variant | " + " | ".join(res["devices"]) + " |",
              "|---|" + "---|" * len(res["devices"])]
    for m in labels:
        cells = []
        for d in res["devices"]:
            ms = vals.get((d, m, "frame", "tuned", "median_ms"))
            sps = vals.get((d, m, "frame", "tuned", "samples_per_s"))
            cells.append("n/a" if ms is None else
                         f"{_fmt(ms)} ms ({_fmt(None if sps is None else sps / 1e6, '.1f')} M/s)")
        lines.append(f"| {m} | " + " | ".join(cells) + " |")
    lines += ["", *_side_by_side(res, vals)]
    return "\n".join(lines) + "\n"


def _side_by_side(res: dict, vals: dict) -> list[str]:
    """Per pass (tuned): device ms, GB/s and percent of peak on every device, and each
    device's time over the first device's."""
    devs = res["devices"]
    head = "| variant | pass | " + " | ".join(f"{d} ms | GB/s | of peak" for d in devs)
    rule = "|---|---|" + "---|---|---|" * len(devs)
    if len(devs) > 1:
        head += " | " + " | ".join(f"ms {d} / {devs[0]}" for d in devs[1:])
        rule += "---|" * (len(devs) - 1)
    lines = ["Per pass, devices side by side (tuned configurations):", "", head + " |", rule]
    seen = set()
    for run in res["runs"]:
        m = run["method"]
        if m in seen:
            continue
        seen.add(m)
        order = list(dict.fromkeys(n for r in res["runs"] if r["method"] == m
                                   for n in _pass_order(res, r)))
        for name in order:
            ms = [vals.get((d, m, name, "tuned", "median_ms")) for d in devs]
            cells = []
            for d, t in zip(devs, ms):
                gbs, frac = _gbs_cells(vals, d, m, name)
                cells += [_fmt(t), gbs, frac]
            for t in ms[1:]:
                r = math.nan if t is None or ms[0] is None else _ratio(t, ms[0])
                cells.append(f"{r:.2f}x" if math.isfinite(r) else "n/a")
            label = "**frame**" if name == "frame" else name
            lines.append(f"| {m} | {label} | " + " | ".join(cells) + " |")
    return lines


def plot_bandwidth(result: dict, path: PathLike) -> Path:
    """Plot each pass's achieved GB/s (tuned) against each device's peak, as a PNG.

    x: the plan steps of every variant in launch order (a multi-kernel step as one), and the
    frame; y: GB/s on a log scale; one colour per device, its ``copy_float4`` peak a solid
    line and clpeak's (when measured) a dashed one. A roofline without the compute roof: the
    passes' arithmetic intensities are not counted, so distance below the line is all the
    plot says.

    Parameters
    ----------
    result : dict
        What :func:`bench` returned.
    path : str or Path
        The PNG to write (parent folders are created).

    Returns
    -------
    pathlib.Path
    """
    from clrecon.bench.trade import _plt

    plt = _plt()
    vals = _index(result["rows"])
    devs = result["devices"]
    xs: list[tuple[str, str]] = []  # (variant, pass)
    for run in result["runs"]:
        for name in _pass_order(result, run):
            key = (run["method"], name)
            if key not in xs and (run["device"], *key, "tuned", "gb_per_s") in vals:
                xs.append(key)
    fig, ax = plt.subplots(figsize=(max(8.0, 0.26 * len(xs) + 1.5), 6.5), dpi=110)
    width = 0.8 / max(len(devs), 1)
    shown: list[float] = []  # every value drawn, to leave the legend a decade below them
    platforms = [d.split(" / ")[0] for d in devs]
    short = platforms if len(set(platforms)) == len(devs) else devs
    for k, (d, name) in enumerate(zip(devs, short)):
        colour = f"C{k}"
        pk = result.get("peaks", {}).get(d, {})
        pts = [(i, vals.get((d, m, n, "tuned", "gb_per_s"))) for i, (m, n) in enumerate(xs)]
        pts = [(i, v) for i, v in pts if v is not None and math.isfinite(v) and v > 0]
        if pts:
            ix, ys = zip(*pts)
            shown += ys
            ax.scatter([i + (k - (len(devs) - 1) / 2) * width for i in ix], ys, color=colour,
                       marker="os^vD"[k % 5], s=26, zorder=3, label=name)
        copy = (pk.get("copy") or {}).get("gb_per_s")
        if copy:
            shown.append(copy)
            ax.axhline(copy, color=colour, lw=1.2, label=f"{name}: copy peak {copy:.1f} GB/s")
        clp = (pk.get("clpeak") or {}).get("best_gb_per_s")
        if clp:
            shown.append(clp)
            ax.axhline(clp, color=colour, lw=1.0, ls="--",
                       label=f"{name}: clpeak {clp:.1f} GB/s")
    ax.set_yscale("log")
    if shown:
        ax.set_ylim(min(shown) / 15, max(shown) * 1.6)
    ax.set_xlim(-0.6, len(xs) - 0.4)
    first = 0
    for i, (m, _) in enumerate(xs):  # a band per variant, its name on top
        if i + 1 == len(xs) or xs[i + 1][0] != m:
            if i + 1 < len(xs):
                ax.axvline(i + 0.5, color="grey", lw=0.6, alpha=0.6)
            ax.text((first + i) / 2, 1.01, m, transform=ax.get_xaxis_transform(),
                    ha="center", va="bottom", fontsize=7)
            first = i + 1
    ax.set_xticks(range(len(xs)))
    ax.set_xticklabels([n.replace(" (halves)", " (h)") for _, n in xs], rotation=60,
                       ha="right", fontsize=7)
    ax.set_ylabel("achieved GB/s (log): bytes of the pass's buffers / device time", fontsize=8)
    w, h = result["size"]
    src = "synthetic frame" if result.get("scene") is None else result["scene"]
    fig.suptitle(f"{src} {w}x{h} {result['spp']} spp: achieved bandwidth per pass (tuned) vs "
                 "each device's streaming peak; (h): the safeguard's half-frame runs",
                 fontsize=9)
    ax.grid(True, which="both", axis="y", alpha=0.3)
    ax.legend(fontsize=7, loc="lower left", ncol=2, framealpha=0.85)
    fig.tight_layout()
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    png = io.BytesIO()
    fig.savefig(png, format="png")
    plt.close(fig)
    write_atomic(out, png.getvalue())
    return out


def _jsonable(obj: Any) -> Any:
    """Non-finite floats as None (strict JSON), recursively."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    return obj


def write_outputs(result: dict, json_path: PathLike | None = None,
                  csv_path: PathLike | None = None) -> list[Path]:
    """Write a :func:`bench` result as JSON (everything but ``markdown``) and/or CSV.

    Parameters
    ----------
    result : dict
        What :func:`bench` returned.
    json_path : str or Path, optional
        JSON file (non-finite values become ``null``); parent folders are created.
    csv_path : str or Path, optional
        CSV of the long rows, header :data:`ROW_KEYS`; parent folders are created.

    Returns
    -------
    list of pathlib.Path
        The files written.
    """
    written = []
    if json_path is not None:
        path = Path(json_path)
        path.parent.mkdir(parents=True, exist_ok=True)
        data = _jsonable({k: v for k, v in result.items() if k != "markdown"})
        path.write_text(json.dumps(data, indent=2, allow_nan=False, default=str) + "\n")
        written.append(path)
    if csv_path is not None:
        path = Path(csv_path)
        path.parent.mkdir(parents=True, exist_ok=True)
        with path.open("w", newline="", encoding="utf-8") as fh:
            writer = csv.DictWriter(fh, fieldnames=ROW_KEYS, extrasaction="ignore")
            writer.writeheader()
            for r in result["rows"]:
                writer.writerow(r)
        written.append(path)
    return written


def _key(row: dict) -> tuple:
    return tuple(str(row.get(k)) for k in MATCH_KEYS)


def compare(result: dict, old: dict) -> str:
    """Markdown table of the change of :func:`bench` results against an earlier run.

    Rows are matched on :data:`MATCH_KEYS`; only the metrics of :data:`COMPARED`
    (``median_ms``, ``samples_per_s``) are reported, with old value, new value and the change
    in percent of the old one. Rows present on one side only are listed as added or removed.

    Parameters
    ----------
    result : dict
        The new :func:`bench` result.
    old : dict
        An earlier result, e.g. ``json.load`` of a file written by :func:`write_outputs`.

    Returns
    -------
    str
        The table (markdown).

    Raises
    ------
    ValueError
        ``old`` has no ``rows`` list.
    """
    if not isinstance(old, dict) or not isinstance(old.get("rows"), list):
        raise ValueError("old: expected a bench result (a JSON object with a 'rows' list)")
    new_rows = {_key(r): r for r in result["rows"] if r.get("metric") in COMPARED}
    old_rows = {_key(r): r for r in old["rows"]
                if isinstance(r, dict) and r.get("metric") in COMPARED}
    lines = ["| device | variant | pass | size | spp | config | metric | old | new | change % "
             "| |", "|---|---|---|---|---|---|---|---|---|---|---|"]

    def line(r: dict, old_v: Any, new_v: Any, change: str, note: str) -> None:
        unit = r.get("unit", "")
        lines.append(f"| {r.get('device')} | {r.get('method')} | {r.get('pass')} | "
                     f"{r.get('size')} | {r.get('spp')} | {r.get('config')} | "
                     f"{r.get('metric')} ({unit}) | {old_v} | "
                     f"{new_v} | {change} | {note} |")

    def num(v: Any) -> str:
        return _fmt(v, ".4g") if isinstance(v, (int, float)) or v is None else str(v)

    for key, r in new_rows.items():
        if key not in old_rows:
            line(r, "", num(r["value"]), "", "added")
            continue
        a, b = old_rows[key].get("value"), r["value"]
        if not (isinstance(a, (int, float)) and isinstance(b, (int, float))
                and math.isfinite(a) and math.isfinite(b) and a != 0):
            line(r, num(a), num(b), "n/a", "")
            continue
        pct = (b - a) / abs(a) * 100.0
        better = (pct > 0) == COMPARED[r["metric"]]
        note = "" if pct == 0 else ("better" if better else "worse")
        line(r, num(a), num(b), f"{pct:+.1f}", note)
    for key, r in old_rows.items():
        if key not in new_rows:
            line(r, num(r.get("value")), "", "", "removed")
    return "\n".join(lines) + "\n"
