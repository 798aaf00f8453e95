"""The speed/accuracy trade (``clrecon trade``): every method at every knob setting that trades
time for quality, beside ``box`` and Intel Open Image Denoise, on the built-in scenes.

Per scene one converged reference (seed 1; cached as EXR under ``references/`` of the output
directory) and per spp one sample buffer (seed ``100 + spp``) are rendered. Every variant's
pipeline is built and its samples uploaded once, and it is warmed up. Then the variants run
**paired**: ``repeats`` rounds, each round running every variant once in a rotated order, so
that the host's noise hits all of them alike. A variant's time is the median over rounds of
its summed per-pass device times (OpenCL profiling events; on a CPU device these are wall
times of the kernels), and ``x_box`` is the median over rounds of its time divided by the
box filter's time in the same round.

The OIDN baseline is what a user would otherwise run: the box-filtered image denoised by
``pyoidn.denoise(box, hdr=True, quality=...)`` on the CPU. Its time is the box pass plus the
denoiser's wall time (host arrays in and out, as a user would call it).

Quality is PSNR, SSIM and FLIP of the last round's image against the reference
(:mod:`clrecon.metrics`). Per scene and spp the Pareto front in (time, PSNR) is marked.

Outputs: ``trade.md``, ``trade.json``, ``{scene}_pareto.png`` (time vs PSNR, the fronts
drawn) and ``{scene}_crops.png`` (the same crop of the reference, box, OIDN and the best
setting of each method, at the middle spp, centred where the box filter errs most).
"""
from __future__ import annotations

import statistics
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from clrecon.api import METHODS
from clrecon.bench.table import Progress, _check_variants, frame_sources
from clrecon.bench.timing import OidnRun, PipelineRun, duration_text, paired_rounds
from clrecon.bench.trade_report import markdown, save_crops, verdicts, write_outputs
from clrecon.bench.trade_settings import TRADES as TRADES  # re-exported: the settings
from clrecon.core.device import Device, DeviceSpec, get_device
from clrecon.io import load_image, load_samples, save_image
from clrecon.metrics import evaluate
from clrecon.scenes import get_scene, render_reference, render_samples
from clrecon.scenes.render import check_sampler

#: the external baseline: pyoidn quality modes
OIDN_QUALITIES = ("fast", "high")


def trade_variants(methods: Sequence[str] | None = None,
                   settings: Sequence[str] | None = None) -> list[tuple[str, str, dict]]:
    """The (label, method, knobs) settings of :data:`TRADES` for ``methods`` (default: every
    registered method), only those labelled in ``settings`` when it is given. The plain box
    filter is always included: every ratio is taken against it (box's other settings, its
    halves filtered, only where ``methods`` names box)."""
    methods = [m for m in TRADES if m in METHODS] if methods is None else list(methods)
    for m in methods:
        if m not in METHODS:
            raise ValueError(f"methods: unknown {m!r}; available: {sorted(METHODS)}")
        if m not in TRADES:
            raise ValueError(f"methods: {m!r} has no trade settings in "
                             f"clrecon.bench.trade_settings")
    every = [(lab, m, k) for m in methods for lab, k in TRADES[m]]
    if "box" not in methods:
        every = [("box", "box", {}), *every]
    if settings is not None:
        known = {lab for lab, _, _ in every}
        unknown = [s for s in settings if s not in known]
        if unknown:
            raise ValueError(f"settings: unknown {unknown}; known: {sorted(known)}")
        wanted = set(settings)
        every = [v for v in every if v[0] == "box" or v[0] in wanted]
    return _check_variants(every)


def pareto_front(points: Sequence[tuple[float, float]]) -> list[bool]:
    """Which ``(time, quality)`` points no other point dominates (no slower, no worse, and
    better in one); NaN quality is never on the front."""
    flags = []
    for i, (t, q) in enumerate(points):
        if not np.isfinite(q):
            flags.append(False)
            continue
        dominated = any(
            j != i and np.isfinite(q2) and t2 <= t and q2 >= q and (t2 < t or q2 > q)
            for j, (t2, q2) in enumerate(points))
        flags.append(not dominated)
    return flags


def _reference_path(scene, w, h, spp, cache: Path) -> Path:
    return cache / f"{scene.name}_{w}x{h}_{spp}spp_seed1.exr"


def _reference(scene, w, h, spp, dev, cache: Path) -> np.ndarray:
    path = _reference_path(scene, w, h, spp, cache)
    if path.exists():
        return load_image(path)
    ref = render_reference(scene, w, h, spp, seed=1)  # on the trusted device
    cache.mkdir(parents=True, exist_ok=True)
    save_image(path, ref)
    return ref


def trade(scenes: Sequence[str] | None = None, methods: Sequence[str] | None = None,
          spps: Sequence[int] = (4, 8, 16), size: tuple[int, int] = (512, 512),
          repeats: int = 5, oidn: bool = True, device: DeviceSpec | Device = None,
          out_dir: str | Path = "out/trade", ref_spp: int | None = None,
          progress: Progress = None,
          inputs: Sequence[tuple[str, str]] | None = None,
          status: Callable[[str], None] | None = None,
          settings: Sequence[str] | None = None, sampler: str = "lattice") -> dict:
    """Measure the speed/accuracy trade; write ``trade.md``, ``trade.json`` and the pictures.

    Parameters
    ----------
    scenes : sequence of str, optional
        Built-in scene names (default: all).
    methods : sequence of str, optional
        Methods whose :data:`TRADES` settings run (default: every registered one; ``box``
        always runs).
    spps : sequence of int
        Samples per pixel of the reconstructed buffers.
    size : tuple of int
        ``(width, height)``.
    repeats : int
        Paired rounds after one warm-up run of every variant.
    oidn : bool
        Include the Open Image Denoise baselines (needs ``pyoidn``).
    device : int, str, Device or None
        See :func:`clrecon.core.device.get_device`.
    out_dir : str or Path
        Created; receives the outputs and the reference cache ``references/``.
    ref_spp : int, optional
        Reference samples per pixel (default: each scene's).
    progress : callable, optional
        ``progress(done, total)`` after each reference, buffer and measured (scene, spp).
    inputs : sequence of (samples path, reference path), optional
        The user's own frames (any format of :func:`clrecon.io.load_samples`, references as
        images), measured like a scene named after the file's stem at the file's spp. With
        ``inputs`` and no ``scenes``, only the user's frames run.
    settings : sequence of str, optional
        Only the :data:`TRADES` settings of these labels (and box).
    status : callable, optional
        ``status(line)``: before measuring, one line saying what will run (scenes x spp x
        settings = measurements, the rounds, the references to render); then one after
        each reference rendered and each frame measured, with the time so far and an
        estimate of the time left.
    sampler : str
        How the built-in scenes' samples are drawn (:data:`clrecon.scenes.render.SAMPLERS`):
        the tracer's stratified ``"lattice"`` or independent ``"random"`` samples.

    Returns
    -------
    dict
        ``device``, ``size``, ``spps``, ``repeats``, ``rows`` (one per scene, spp and variant:
        ``scene``, ``spp``, ``variant``, ``method``, ``knobs``, ``describe``, ``ms``,
        ``x_box``, ``pass_ms``, ``psnr``, ``ssim``, ``flip``, ``pareto``), ``verdicts`` (per
        scene and spp: the clrecon settings that beat each OIDN mode in both time and PSNR)
        and ``markdown``.
    """
    scenes, inputs, stems = frame_sources(scenes, inputs)
    scene_objs = {n: get_scene(n) for n in scenes}
    spps, variants = _check_options(spps, repeats, methods, oidn, settings)
    check_sampler(sampler)  # before any device work
    w, h = (int(v) for v in size)
    dev = get_device(device)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    total, done = len(scenes) * (1 + 2 * len(spps)) + 2 * len(inputs), 0
    if progress:
        progress(0, total)  # the total from the start: a bar shows its ETA
    ref_spps = {n: ref_spp or s.reference_spp for n, s in scene_objs.items()}
    cached = {n for n, s in scene_objs.items()
              if _reference_path(s, w, h, ref_spps[n], out / "references").exists()}
    eta = _Eta([w * h * ref_spps[n] for n in scene_objs],
               [w * h * spp for _ in scenes for spp in spps] + [None] * len(inputs))
    if status:
        status(_plan_line(scenes, spps, inputs, len(variants) +
                          (len(OIDN_QUALITIES) if oidn else 0), (w, h), repeats,
                          {n: ref_spps[n] for n in scene_objs if n not in cached},
                          len(cached), out / "references"))

    def step():
        nonlocal done
        done += 1
        if progress:
            progress(done, total)

    rows, crops = [], {}

    def measure(name, spp, buf, ref):
        group = _group(dev, buf, variants, oidn, repeats, name, spp, ref)
        rows.extend(r for r, _ in group)
        return group

    for name, scene in scene_objs.items():
        t = time.perf_counter()
        ref = _reference(scene, w, h, ref_spps[name], dev, out / "references")
        dt = time.perf_counter() - t
        eta.reference(w * h * ref_spps[name], None if name in cached else dt)
        if status and name not in cached:
            status(eta.line(f"reference of {name} ({ref_spps[name]} spp) rendered", dt))
        step()
        for spp in spps:
            t = time.perf_counter()
            buf = render_samples(scene, w, h, spp, seed=100 + spp, device=dev,
                                 sampler=sampler).validate()
            step()
            group = measure(name, spp, buf, ref)
            if spp == spps[len(spps) // 2]:
                crops[name] = (ref, group)
            dt = time.perf_counter() - t
            eta.frame(w * h * spp, w * h * spp, dt)
            if status:
                status(eta.line(f"{name} at {spp} spp measured", dt))
            step()
        save_crops(out / f"{name}_crops.png", name, *crops[name])
    for (path, ref_path), name in zip(inputs, stems):
        t = time.perf_counter()
        buf, ref = _user_frame(path, ref_path)
        step()
        group = measure(name, buf.spp, buf, ref)
        save_crops(out / f"{name}_crops.png", name, ref, group)
        dt = time.perf_counter() - t
        eta.frame(None, buf.width * buf.height * buf.spp, dt)
        if status:
            status(eta.line(f"{name} ({buf.spp} spp) measured", dt))
        step()
    report = {"device": dev.info.label, "size": [w, h], "spps": spps, "repeats": repeats,
              "sampler": sampler, "rows": rows}
    report["verdicts"] = verdicts(rows)
    report["markdown"] = markdown(report)
    write_outputs(out, report, [*scene_objs, *stems])
    return report


def _check_options(spps, repeats, methods, oidn: bool, settings=None
                   ) -> tuple[list[int], list]:
    """The spp list and the variants, checked before any measurement."""
    spps = [int(s) for s in spps]
    if not spps or min(spps) < 1:
        raise ValueError(f"spps: need positive integers, got {spps}")
    if not (isinstance(repeats, int) and repeats >= 1):
        raise ValueError(f"repeats: must be a positive integer, got {repeats!r}")
    variants = trade_variants(methods, settings)
    if oidn:
        import pyoidn  # noqa: F401  (fail before any measurement when it is missing)
    return spps, variants


def _user_frame(path, ref_path):
    """A frame of the user's and its reference, which must have the frame's size."""
    buf, ref = load_samples(path), load_image(ref_path)
    if ref.shape != (buf.height, buf.width, 3):
        raise ValueError(f"--reference {ref_path}: {ref.shape[1]}x{ref.shape[0]} image for "
                         f"a {buf.width}x{buf.height} frame ({path})")
    return buf, ref


class _Eta:
    """The time a trade has left, from what it measured so far. A reference costs its
    pixels x spp at the rate of those rendered; a measured frame (its buffer, every
    setting's build, warm-up and rounds) ``a + b * pixels * spp``, fitted to the frames
    done (proportional until two sizes are known); a frame of the user's, whose size is
    known only once it is read, the mean of the frames done."""

    def __init__(self, refs: list[int], frames: list[int | None]):
        self.refs, self.frames = list(refs), list(frames)  # work left: pixels x spp
        self.ref_done: list[tuple[int, float]] = []
        self.frame_done: list[tuple[int, float]] = []
        self.t0 = time.perf_counter()

    def reference(self, units: int, seconds: float | None) -> None:
        """A reference done (``seconds`` ``None``: it was cached)."""
        self.refs.remove(units)
        if seconds is not None:
            self.ref_done.append((units, seconds))

    def frame(self, planned: int | None, units: int, seconds: float) -> None:
        self.frames.remove(planned)
        self.frame_done.append((units, seconds))

    def left(self) -> float | None:
        """Seconds left, ``None`` while a kind of work left has no measurement yet."""
        total = 0.0
        if self.refs:
            if not self.ref_done:
                return None
            rate = sum(t for _, t in self.ref_done) / max(sum(u for u, _ in self.ref_done), 1)
            total += rate * sum(self.refs)
        if self.frames:
            if not self.frame_done:
                return None
            xs = np.array([u for u, _ in self.frame_done], np.float64)
            ts = np.array([t for _, t in self.frame_done], np.float64)
            a, b = 0.0, float(ts.sum() / max(xs.sum(), 1.0))
            if len(set(xs.tolist())) > 1:
                b_fit, a_fit = np.polyfit(xs, ts, 1)
                if a_fit >= 0 and b_fit >= 0:
                    a, b = float(a_fit), float(b_fit)
            total += sum(float(ts.mean()) if u is None else a + b * u for u in self.frames)
        return total

    def line(self, what: str, seconds: float) -> str:
        left = self.left()
        eta = "the time left is estimated once a reference and a frame are done" \
            if left is None else f"about {duration_text(left)} left"
        return (f"{what} in {duration_text(seconds)}; "
                f"{duration_text(time.perf_counter() - self.t0)} so far, {eta}")


def _measure(dev, buf, variants, oidn: bool, repeats: int):
    """Build, warm up and run every variant in paired rounds: (label, method, knobs, runner,
    median ms, median ratio to box)."""
    entries = [(lab, m, k, PipelineRun(dev, buf, m, k)) for lab, m, k in variants]
    box = next(r for lab, m, k, r in entries if m == "box" and not k)
    if oidn:
        entries += [(f"oidn {q}", "oidn", {"quality": q}, OidnRun(dev, buf, q))
                    for q in OIDN_QUALITIES]
    for entry in entries:
        entry[3].run()  # warm-up: PoCL compiles work-group functions on the first launch
        entry[3].pass_ms.clear()
    times = paired_rounds([e[3].run for e in entries], repeats)
    box_i = next(i for i, e in enumerate(entries) if e[3] is box)
    box_times = times[box_i]
    res = []
    for (lab, m, k, runner), ts in zip(entries, times):
        ratio = statistics.median(t / max(b, 1e-6) for t, b in zip(ts, box_times))
        res.append((lab, m, k, runner, statistics.median(ts), ratio))
    return res


def _group(dev, buf, variants, oidn: bool, repeats: int, name: str, spp: int,
           ref: np.ndarray) -> list[tuple[dict, np.ndarray]]:
    """One frame measured (:func:`_measure`): per setting its row (time, quality against
    ``ref``, whether it is on the frame's Pareto front) and its image."""
    group = []
    for label, method, knobs, runner, ms, ratio in _measure(dev, buf, variants, oidn, repeats):
        image = runner.image()
        row = {"scene": name, "spp": spp, "variant": label, "method": method,
               "knobs": knobs, "describe": runner.describe(), "ms": ms, "x_box": ratio,
               "pass_ms": {k: statistics.median(v) for k, v in runner.pass_ms.items()},
               **evaluate(image, ref)}
        group.append((row, image))
    for (row, _), front in zip(group, pareto_front([(r["ms"], r["psnr"]) for r, _ in group])):
        row["pareto"] = front
    return group


def _plan_line(scenes, spps, inputs, settings: int, size, repeats: int,
               to_render: dict[str, int], cached: int, cache: Path) -> str:
    """What a trade will run, in one line."""
    frames = len(scenes) * len(spps) + len(inputs)
    what = f"{len(scenes)} scenes x {len(spps)} spp ({','.join(map(str, spps))})" \
        if scenes else ""
    if inputs:
        what += f"{' + ' if what else ''}{len(inputs)} frames of yours"
        what = f"({what} = {frames} frames)" if scenes else what
    refs = ""
    if to_render:
        refs = (f"; {len(to_render)} references to render at "
                f"{'/'.join(map(str, sorted(set(to_render.values()))))} spp")
    if cached:
        refs += f"; {cached} references cached in {cache}"
    rounds = f"{repeats} paired round{'s' * (repeats != 1)}"
    return (f"{what} x {settings} settings = {frames * settings} measurements at "
            f"{size[0]}x{size[1]}, each {rounds} after a warm-up{refs}; "
            f"the time left is estimated once a reference and a frame are done")
