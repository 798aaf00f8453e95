"""Cross-device benchmark: per-pass and whole-frame device times of reconstruction variants on
every OpenCL device, with the tuned configuration and the default one side by side
(``clrecon bench``).

Per device and variant the pipeline is built once with the configuration the normal tuning
lookup gives (:func:`clrecon.tune.runtime.tuned`) and once more with every pass forced to
its spec's default (``CLRECON_TUNE_<PASS>`` set to ``SPECS[pass].default`` while the second
pipeline is built; the environment is restored afterwards). The samples are uploaded once;
after one warm-up launch of each pipeline, ``repeats`` *paired* runs follow: in each run the
tuned and the default pipeline are launched back to back (the order alternating from run to
run), so both see the same machine noise. Reported per pass and for the whole frame (the sum
of the passes): min, median and max device ms from the profiling events, samples per second
at the median frame time, and the median of the per-run ratio default / tuned.

Passes whose configuration already is the default (tuning source ``"default"`` or
``"runtime"``) or was fixed by the caller's knobs (``"api"``) are not forced; when no pass is
left to force, the default runs are skipped, the ratio is reported as 1.0 and the run's
``forced_default`` is ``False``.

Results are long rows in the manner of clpeak (one measured value per row, see
:data:`ROW_KEYS`), written as JSON and CSV by :func:`write_outputs`; :func:`compare` gives
the change against an earlier JSON.
"""
from __future__ import annotations

import csv
import json
import math
import numbers
import os
import statistics
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Callable, Optional, Union

import pyopencl as cl

from ..device import Device, DeviceSpec, get_device, list_devices
from ..errors import DeviceError
from ..pipeline import DeviceSamples, Pipeline, make_pipeline
from ..samples import SampleBuffer
from ..tune.db import env_var
from ..tune.runtime import clear_cache
from ..tune.specs import SPECS, synthetic_frame
from .methods import Variant, _check_variants

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
COMPARED = {"median_ms": False, "samples_per_s": True}

_UNITS = {"min_ms": "ms", "median_ms": "ms", "max_ms": "ms", "samples_per_s": "1/s",
          "ratio_default_over_tuned": "x"}


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


def _launch(pipe: Pipeline, queue: cl.CommandQueue, samples: DeviceSamples,
            out: cl.Buffer) -> dict[str, float]:
    """One launch, waited for: per-pass device ms plus ``"frame"`` (their sum)."""
    pipe(queue, samples, out).wait()
    times = dict(pipe.pass_times_ms())
    times["frame"] = float(sum(times.values()))
    return times


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
    _launch(tuned_pipe, q, samples, out)  # warm-up (PoCL specialises on the first launch)
    if default_pipe is not None:
        _launch(default_pipe, q, samples, out)
    tuned_runs: list[dict[str, float]] = []
    default_runs: list[dict[str, float]] = []
    for i in range(repeats):
        if default_pipe is None:
            tuned_runs.append(_launch(tuned_pipe, q, samples, out))
        elif i % 2 == 0:
            tuned_runs.append(_launch(tuned_pipe, q, samples, out))
            default_runs.append(_launch(default_pipe, q, samples, out))
        else:
            default_runs.append(_launch(default_pipe, q, samples, out))
            tuned_runs.append(_launch(tuned_pipe, q, samples, out))
    return {"describe": desc, "tuning": sources, "forced": forced,
            "default_describe": None if default_pipe is None else default_pipe.describe(),
            "tuned": tuned_runs, "default": default_runs}


def _rows_of(dev: Device, label: str, size: str, spp: int, npix_spp: int,
             timed: dict) -> list[dict]:
    """The long rows of one device and variant."""
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
    return rows


def bench(devices: str | DeviceSpec | Sequence[DeviceSpec] = "all",
          variants: Sequence[Variant] | None = None, size: tuple[int, int] = (1280, 720),
          spp: int = 16, repeats: int = 7, progress: Progress = None,
          scene: str | None = None) -> dict:
    """Time each variant's passes on each device, tuned and with default configurations.

    Parameters
    ----------
    devices : "all", int, str or sequence of int/str
        ``"all"``: every OpenCL device present (:func:`clrecon.device.list_devices`);
        otherwise device indices or case-insensitive substrings of ``"platform / device"``
        (see :func:`clrecon.device.get_device`). A device named twice is benched once.
    variants : sequence of (label, method, knobs), optional
        Default :data:`DEFAULT_VARIANTS` (box, sweep 2-scale, sweep dof-layers); see
        :func:`clrecon.bench.methods.parse_variant` for a text form. Labels must be unique.
    size : tuple of int
        ``(width, height)`` of the frame.
    spp : int
        Samples per pixel.
    repeats : int
        Timed (paired) runs per device and variant, after one warm-up launch.
    progress : callable, optional
        ``progress(done, total)`` after each device's input frame and each variant.
    scene : str, optional
        ``None``: :func:`clrecon.tune.specs.synthetic_frame` (no renderer involved);
        otherwise a built-in scene rendered with :func:`clrecon.scenes.render_samples`
        (seed 0) on each benched device.

    Returns
    -------
    dict
        ``devices`` (labels), ``size`` (``[w, h]``), ``spp``, ``repeats``, ``scene``,
        ``variants`` (``label``, ``method``, ``knobs``), ``runs`` (per device and variant:
        ``device``, ``method``, ``tuning`` (pass -> tuning source), ``forced_default``,
        ``forced_passes``, ``describe``, ``default_describe``), ``rows`` (long rows with
        the keys :data:`ROW_KEYS`; ``config`` ``"tuned"`` or ``"default"``, metrics
        ``min_ms``, ``median_ms``, ``max_ms``, ``samples_per_s`` (frame only) and
        ``ratio_default_over_tuned`` (config ``"default"``)) and ``markdown``.

    Raises
    ------
    ValueError
        Bad size, spp, repeats, device list, scene or variant.
    TypeError
        A variant's knob that its method does not take.
    clrecon.errors.DeviceError
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
        from ..scenes import get_scene

        scene_obj = get_scene(scene)  # unknown names fail before any device work
    devs = _select_devices(devices)
    steps, done = len(devs) * (1 + len(variants)), 0

    def step() -> None:
        nonlocal done
        done += 1
        if progress:
            progress(done, steps)

    size_s = f"{w}x{h}"
    synthetic = synthetic_frame(w, h, spp) if scene_obj is None else None
    rows: list[dict] = []
    runs: list[dict] = []
    for dev in devs:
        if scene_obj is None:
            buf = synthetic
        else:
            from ..scenes import render_samples

            buf = render_samples(scene_obj, w, h, spp, seed=0, device=dev)
            buf.validate()
        step()
        for label, method, knobs in variants:
            timed = _time_variant(dev, buf, method, knobs, repeats)
            rows += _rows_of(dev, label, size_s, spp, w * h * spp, timed)
            runs.append({"device": dev.info.label, "method": label, "tuning": timed["tuning"],
                         "forced_default": bool(timed["forced"]),
                         "forced_passes": timed["forced"], "describe": timed["describe"],
                         "default_describe": timed["default_describe"]})
            step()
    result = {"devices": [d.info.label for d in devs], "size": [w, h], "spp": spp,
              "repeats": repeats, "scene": scene,
              "variants": [{"label": lab, "method": m, "knobs": k} for lab, m, k in variants],
              "runs": runs, "rows": rows}
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


def _markdown(res: dict) -> str:
    w, h = res["size"]
    vals = _index(res["rows"])
    source = "synthetic frame" if res.get("scene") is None else f"scene {res['scene']!r}"
    lines = [f"{w}x{h}, {res['spp']} spp ({source}); device ms of {res['repeats']} runs after "
             "a warm-up; default runs paired with the tuned ones (alternating launches); "
             "default/tuned: median of the per-run ratios (> 1: tuning helps).", "",
             "| device | variant | pass | tuned min ms | tuned median ms | tuned max ms | "
             "default median ms | default/tuned | tuning |",
             "|---|---|---|---|---|---|---|---|---|"]
    for run in res["runs"]:
        d, m = run["device"], run["method"]
        names = list(dict.fromkeys(r["pass"] for r in res["rows"]
                                   if r["device"] == d and r["method"] == m))
        for name in names:
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
            lines.append(f"| {d} | {m} | {label} | {_fmt(t[0])} | {_fmt(t[1])} | {_fmt(t[2])} | "
                         f"{dflt_s} | {_fmt(ratio, '.2f')} | {tuning} |")
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
    return "\n".join(lines) + "\n"


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
