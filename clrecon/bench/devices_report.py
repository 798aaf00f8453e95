"""The results of ``clrecon bench`` (:func:`clrecon.bench.devices.bench`): its long rows in
the manner of clpeak (one measured value per row, see :data:`ROW_KEYS`), the markdown
report made of them, the JSON and CSV files (:func:`write_outputs`) and the change against
an earlier run (:func:`compare`). :mod:`clrecon.bench.devices` measures;
:mod:`clrecon.bench.devices_plot` draws."""
from __future__ import annotations

import csv
import json
import math
import os
import statistics
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Callable, Union

from clrecon.core.device import Device

PathLike = Union[str, "os.PathLike[str]"]

#: the keys of every long-format row, in CSV column order
ROW_KEYS = ("device", "driver", "platform", "method", "pass", "size", "spp", "config",
            "metric", "unit", "value")

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


# -- rows ----------------------------------------------------------------------------------

def _ratio(a: float, b: float) -> float:
    return a / b if b > 0 and math.isfinite(a) and math.isfinite(b) else math.nan


def _median_finite(values: Sequence[float]) -> float:
    finite = [v for v in values if math.isfinite(v)]
    return statistics.median(finite) if finite else math.nan

def rows_of(dev: Device, label: str, size: str, spp: int, npix_spp: int,
             timed: dict, peak: dict) -> list[dict]:
    """The long rows of one device and variant: ``timed`` is what the bench measured (see
    :func:`clrecon.bench.devices.bench`), ``peak`` the device's entry of the result's
    ``peaks``."""
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


# -- markdown ------------------------------------------------------------------------------

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


def markdown(res: dict) -> str:
    """The report of a bench result (its ``markdown``): per device, variant and pass the
    tuned and default times, GB/s and tuning; the peaks; the devices side by side."""
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


# -- files and comparison ----------------------------------------------------------------

def jsonable(obj: Any) -> Any:
    """Non-finite floats as None (strict JSON), recursively."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    return obj


def write_outputs(result: dict, json_path: PathLike | None = None,
                  csv_path: PathLike | None = None) -> list[Path]:
    """Write a :func:`~clrecon.bench.devices.bench` result as JSON (everything but
    ``markdown``) and/or CSV.

    Parameters
    ----------
    result : dict
        What :func:`~clrecon.bench.devices.bench` returned.
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
        data = jsonable({k: v for k, v in result.items() if k != "markdown"})
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
    """Markdown table of the change of :func:`~clrecon.bench.devices.bench` results against an
    earlier run.

    Rows are matched on :data:`MATCH_KEYS`; only the metrics of :data:`COMPARED`
    (``median_ms``, ``samples_per_s``) are reported, with old value, new value and the change
    in percent of the old one. Rows present on one side only are listed as added or removed.

    Parameters
    ----------
    result : dict
        The new :func:`~clrecon.bench.devices.bench` result.
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
