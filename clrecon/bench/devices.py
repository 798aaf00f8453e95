"""Cross-device benchmark: per-pass and whole-frame device times of reconstruction variants on
every OpenCL device, with the tuned configuration and the default one side by side
(``clrecon bench``).

Per device and variant the pipeline is built once with the configuration the normal tuning
lookup gives (:func:`clrecon.tune.runtime.tuned`) and once more with every pass forced to
its spec's declared default (``SPECS[pass].default``, through
:func:`clrecon.tune.runtime.override_tuning` while the second pipeline is built; the
environment is not touched). The samples are uploaded once; after one warm-up launch of each
pipeline, ``repeats`` *paired* runs follow (:func:`clrecon.bench.timing.paired_rounds`): in
each run the tuned and the default pipeline are launched back to back (the order alternating
from run to run), so both see the same machine noise. The devices take turns variant by
variant (every device runs the first variant, then every device the second...), so that a
shared machine's load, which drifts over minutes, is not all on the device benched last; all
devices reconstruct the same samples. Reported per pass and for the whole frame (the sum of
the passes): min, median and max device ms from the profiling events, samples per second at
the median frame time, and the median of the per-run ratio default / tuned.

Passes whose configuration already is the default (tuning source ``"default"`` or
``"runtime"``) or was fixed by the caller's knobs (``"api"``) are not forced; when no pass
is left to force, the default runs are skipped, the ratio is reported as 1.0 and the run's
``forced_default`` is ``False``.

Times come from :class:`clrecon.bench.timing.LeafRun`. Each pass is also reported as a
bandwidth: the bytes it must at least move, divided by its device time. A pass here is a
leaf plan step, one that launches kernels itself: a step that runs a sub-pipeline (a
safeguarded method's ``sweep`` and ``sweep (halves)`` steps) is looked into, down to the
steps of the method's own plan. The byte count of a pass is that of the buffers its
:class:`clrecon.core.plan.Step` names as ``inputs`` and ``outputs``, at the size bound for
the call (sample fields as uploaded or split into halves, the frame's for a half read in
place, temporaries as planned, ``out``
``H * W * 12``), each input read once and each output written once (a buffer a step both
reads and writes counts twice; a step run twice, for both halves, counts twice). Caches can
serve re-reads of a neighbourhood, so this is a floor of the traffic, and the GB/s a floor
of what the pass achieved. A pass is named after its kernels: most launch one, whose row it
shares; one that launches several (layered's ``filter_sheared``: ``filter_sheared_recursive``
then ``_gauss``) gets its own row, ``"filter_sheared_recursive + filter_sheared_gauss"``,
timed as the sum of its
kernels. The frame's bytes are the sum of its passes', over the frame's time (the sum of the
kernels'). Each GB/s is also given as a fraction of the device's streaming peak, measured
per device before the variants with :func:`clrecon.bench.bandwidth.measure_peak` on the
bench's queue; optionally clpeak's global-memory bandwidth is reported beside it
(:func:`clrecon.bench.bandwidth.clpeak_bandwidth`).

Results are long rows in the manner of clpeak (one measured value per row, see
:data:`ROW_KEYS`), written as JSON and CSV by :func:`write_outputs`; :func:`compare` gives
the change against an earlier JSON (both in :mod:`clrecon.bench.devices_report`, with the
markdown). :func:`plot_bandwidth` (:mod:`clrecon.bench.devices_plot`) draws each pass's GB/s
against each device's peak. This module measures; those names are importable from it too."""
from __future__ import annotations

import numbers
from collections.abc import Sequence
from typing import Callable, Optional

import pyopencl as cl

from clrecon.api import make_pipeline
from clrecon.bench.bandwidth import clpeak_bandwidth, measure_peak
from clrecon.bench.devices_plot import plot_bandwidth
from clrecon.bench.devices_report import (
    COMPARED,
    MATCH_KEYS,
    PEAK_CONFIG,
    ROW_KEYS,
    compare,
    markdown,
    rows_of,
    write_outputs,
)
from clrecon.bench.table import Variant, _check_variants
from clrecon.bench.timing import LeafRun, paired_rounds
from clrecon.core.device import Device, DeviceSpec, get_device, list_devices
from clrecon.core.errors import DeviceError
from clrecon.core.pipeline import DeviceSamples
from clrecon.core.samples import SampleBuffer
from clrecon.scenes import get_scene, render_samples
from clrecon.tune.runners import SPECS, synthetic_frame
from clrecon.tune.runtime import override_tuning

__all__ = ["COMPARED", "DEFAULT_VARIANTS", "MATCH_KEYS", "NOT_FORCED", "PEAK_CONFIG",
           "ROW_KEYS", "bench", "compare", "plot_bandwidth", "variant_list", "write_outputs"]

Progress = Optional[Callable[[int, int], None]]

#: the variants benchmarked when none are given
DEFAULT_VARIANTS: tuple[Variant, ...] = (
    ("box", "box", {}),
    ("sweep 2-scale", "sweep", {"scales": 2}),
    ("sweep dof-layers", "sweep", {"dof_layers": True}),
)

#: tuning sources whose pass is not forced to its default ("api": fixed by the caller's knobs)
NOT_FORCED = ("default", "runtime", "api")


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


def _time_variant(dev: Device, buf: SampleBuffer, method: str, knobs: dict,
                  repeats: int) -> dict:
    """Build, upload, warm up and time the tuned (and, paired, the default) pipeline."""
    info = buf.inspect()
    tuned_pipe = make_pipeline(method, dev.context, info, **knobs)
    desc = tuned_pipe.describe()
    sources = dict(desc.get("tuning", {}))
    forced = [p for p, src in sources.items() if src not in NOT_FORCED and p in SPECS]
    default_pipe = None
    if forced:
        with override_tuning({p: SPECS[p].default for p in forced}):
            default_pipe = make_pipeline(method, dev.context, info, **knobs)
    samples = DeviceSamples.upload(dev.queue, buf, tuned_pipe.fields)
    out = cl.Buffer(dev.context, cl.mem_flags.READ_WRITE, size=buf.height * buf.width * 12)
    pipes = {"tuned": tuned_pipe, "default": default_pipe}
    leaf = {k: LeafRun(p, dev.queue, samples, out) for k, p in pipes.items() if p is not None}
    runs = dict(zip(leaf, paired_rounds([r.run for r in leaf.values()], repeats)))
    runs.setdefault("default", [])
    return {"describe": desc, "tuning": sources, "forced": forced,
            "default_describe": None if default_pipe is None else default_pipe.describe(),
            "tuned": [t for t, _ in runs["tuned"]], "default": [t for t, _ in runs["default"]],
            "steps": {k: [st for _, st in v] for k, v in runs.items()},
            "step_bytes": {k: r.passes.bytes for k, r in leaf.items()},
            "step_kernels": {k: r.passes.kernels for k, r in leaf.items()}}


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
            rows += rows_of(dev, label, size_s, spp, w * h * spp, timed,
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
    result["markdown"] = markdown(result)
    return result
