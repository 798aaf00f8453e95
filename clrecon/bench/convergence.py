"""The convergence study (``clrecon converge``): does a method's error keep falling as the
samples grow, and where it stops, is what remains bias or variance?

Per scene one converged reference (seed 1, the scene's ``reference_spp``) and a second one
(seed 2) are rendered on the trusted device and cached under ``references/`` of the output
folder; half the mean squared difference of the two is the reference's own noise variance.
Per spp and seed index ``i`` one sample buffer (seed :func:`sample_seed`: ``1000 (i + 1) +
spp``, never a reference's seed) is rendered, and every setting reconstructs it
(:func:`clrecon.core.pipeline.run`).

Error measure. MSE is taken on **linear radiance**, the mean over pixels and the three
channels, against the seed-1 reference. (:func:`clrecon.metrics.psnr` is not defined on
linear values: it tone maps both images, clipping to [0, 1], first. Clipping is not linear,
so bias and variance only add up on linear values; the study reports the PSNR of each
seed's image as that function computes it, the median over seeds, beside the linear MSE.)
With ``n`` seeds' images ``x_i`` of one (scene, setting, spp), their mean ``m`` and the
per-pixel sample variance ``s^2`` (``ddof=1``), :func:`bias_variance` gives

* ``variance = mean_pixels(s^2)``: the per-pixel spread across seeds;
* ``bias2 = mean_pixels((m - ref)^2) - variance / n``: the squared error of the mean image
  less the variance that mean still has, so that it is unbiased;
* ``mse = mean_i mean_pixels((x_i - ref)^2) = bias2 + variance`` (exactly).

The reference's noise (independent of the samples) is inside ``bias2``: no setting can get
below it, and box, the unbiased per-pixel average, measures it (``bias2`` of box is the
reference's variance, up to the estimate's own noise).

Settings (:func:`study_settings`): box, every method's default and its trade settings of
:data:`clrecon.bench.trade.TRADES` (less those that are the default spelled out). Where a
method takes a knob of :data:`DEFAULT_AXES` (``safeguard``: found by trying) its default
runs at each of the knob's values. The ablation (:func:`ablation_settings`, at one spp)
switches, one at a time, the knobs of :data:`ABLATIONS` that turn a bias source off or down,
each against the method alone (the axes' ``paper`` value); :data:`UNSWITCHED` lists the
bias sources no knob reaches.

Resume: each (scene, setting, spp, seed) image is cached under ``cells/`` until its
(scene, setting, spp) has every seed; then the group's numbers are written there
(``spp<N>_ref<R>.json``, with the seeds they came from) and its images removed (unless
``keep_images``). A re-run skips every finished group and every cached image. The cache
trusts its files: after a change to the code, use a new output folder (or remove ``cells/``).

Outputs: ``convergence.json`` (every number), ``convergence.md`` (per scene: MSE with bias
share, median PSNR; the ablation; the bias sources without a knob) and per scene
``<scene>_convergence.png`` (log-log MSE against spp; bias² and variance in a second panel).
"""
from __future__ import annotations

import io
import json
import statistics
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from clrecon.api import clear_sessions, run
from clrecon.bench.convergence_report import save_plot, write_report
from clrecon.bench.convergence_settings import (
    ABLATIONS,
    DEFAULT_AXES,
    UNSWITCHED,
    Probe,
    Setting,
    ablation_settings,
    blur_scenes,
    study_settings,
)
from clrecon.bench.convergence_stats import (
    FLAT_GAIN,
    bias_variance,
    reference_noise,
    sample_seed,
    summarize,
)
from clrecon.bench.timing import duration_text
from clrecon.core.device import Device, DeviceSpec, get_device
from clrecon.core.errors import ClreconError
from clrecon.core.fsutil import write_atomic
from clrecon.core.resources import code_digest
from clrecon.io import load_image, save_image
from clrecon.metrics import psnr
from clrecon.scenes import get_scene, render_reference, render_samples
from clrecon.scenes.render import check_sampler

__all__ = ["ABLATIONS", "ABLATION_SPP", "DEFAULT_AXES", "DEFAULT_SEEDS", "DEFAULT_SIZE",
           "DEFAULT_SPPS", "FLAT_GAIN", "REFERENCE_SEEDS", "UNSWITCHED", "Probe", "Setting",
           "ablation_settings", "bias_variance", "blur_scenes", "converge", "reference_noise",
           "sample_seed", "study_settings", "summarize"]

DEFAULT_SPPS = (4, 8, 16, 32, 64, 128)
DEFAULT_SIZE = (256, 256)
DEFAULT_SEEDS = 4
#: spp of the ablation (0: no ablation)
ABLATION_SPP = 64
#: seeds of the reference (what the study measures against) and of its noise estimate
REFERENCE_SEEDS = (1, 2)

Status = Callable[[str], None]


# -- the study --------------------------------------------------------------------------------

def _check_options(scenes, spps, size, seeds, ablation_spp, ref_spp):
    scenes = blur_scenes() if scenes is None else list(dict.fromkeys(scenes))
    if not scenes:
        raise ValueError("scenes: need at least one")
    for s in scenes:
        get_scene(s)  # unknown names: the list of built-in scenes
    try:
        spps = sorted({int(v) for v in spps})
    except (TypeError, ValueError):
        raise ValueError(f"spp: expected positive integers, got {spps!r}") from None
    if not spps or spps[0] < 1 or spps[-1] >= 1000:
        raise ValueError(f"spp: need positive integers below 1000 (the sample seeds are "
                         f"1000 (seed + 1) + spp), got {spps}")
    try:
        w, h = (int(v) for v in size)
    except (TypeError, ValueError):
        raise ValueError(f"size: expected (width, height), got {size!r}") from None
    if w < 1 or h < 1:
        raise ValueError(f"size: must be positive, got {w}x{h}")
    if isinstance(seeds, bool) or not isinstance(seeds, (int, np.integer)) or seeds < 2:
        raise ValueError(f"seeds: need an integer >= 2 (the variance is the spread across "
                         f"seeds), got {seeds!r}")
    if isinstance(ablation_spp, bool) or not isinstance(ablation_spp, (int, np.integer)) \
            or not 0 <= ablation_spp < 1000:
        raise ValueError(f"ablation_spp: need an integer in [1, 999], or 0 for no ablation, "
                         f"got {ablation_spp!r}")
    if ref_spp is not None and (isinstance(ref_spp, bool) or
                                not isinstance(ref_spp, (int, np.integer)) or ref_spp < 1):
        raise ValueError(f"ref_spp: must be a positive integer or None, got {ref_spp!r}")
    return scenes, spps, (w, h), int(seeds), int(ablation_spp)


def _reference(scene, w, h, spp, seed, cache: Path) -> tuple[np.ndarray, bool]:
    path = cache / f"{scene.name}_{w}x{h}_{spp}spp_seed{seed}.exr"
    if path.exists():
        return load_image(path), True
    ref = render_reference(scene, w, h, spp, seed=seed)  # on the trusted device
    cache.mkdir(parents=True, exist_ok=True)
    save_image(path, ref)
    return ref, False


def _save_npy(path: Path, img: np.ndarray) -> None:
    buf = io.BytesIO()
    np.save(buf, np.ascontiguousarray(img, np.float32))
    write_atomic(path, buf.getvalue())


class _Eta:
    """Time left from the work done: a step of (scene, spp, seed) costs about ``spp x
    (settings to run + 1)`` units (the render and the reconstructions grow with the
    samples), at the rate measured so far."""

    def __init__(self, units: float):
        self.left, self.done, self.spent, self.t0 = float(units), 0.0, 0.0, time.perf_counter()

    def step(self, units: float, seconds: float) -> None:
        self.left -= units
        if seconds > 0:  # a step served from the cache says nothing about the rate
            self.done += units
            self.spent += seconds

    def line(self) -> str:
        so_far = duration_text(time.perf_counter() - self.t0)
        if not self.done:
            return f"{so_far} so far"
        return f"{so_far} so far, about {duration_text(self.left * self.spent / self.done)} left"


def converge(scenes: Sequence[str] | None = None, methods: Sequence[str] | None = None,
             settings: Sequence[str] | None = None, spps: Sequence[int] = DEFAULT_SPPS,
             size: tuple[int, int] = DEFAULT_SIZE, seeds: int = DEFAULT_SEEDS,
             out_dir: str | Path = "out/converge", ref_spp: int | None = None,
             ablation_spp: int = ABLATION_SPP, device: DeviceSpec | Device = None,
             status: Status | None = None, keep_images: bool = False,
             sampler: str = "lattice") -> dict:
    """Run the convergence study; write ``convergence.json``, ``convergence.md`` and the
    plots into ``out_dir`` (see the module docstring).

    Parameters
    ----------
    scenes : sequence of str, optional
        Built-in scenes (default: every one with blur, :func:`blur_scenes`).
    methods, settings : sequence of str, optional
        Restrict the settings (:func:`study_settings`); ``methods`` the ablation too.
    spps : sequence of int
        Samples per pixel (each below 1000).
    size : tuple of int
        ``(width, height)``.
    seeds : int
        Independent sample seeds per (scene, setting, spp), at least 2.
    out_dir : str or Path
        Created; holds the outputs, ``references/`` and the resume cache ``cells/``.
    ref_spp : int, optional
        Reference samples per pixel (default: each scene's ``reference_spp``).
    ablation_spp : int
        spp of the ablation; 0: none.
    device : int, str, Device or None
        Where the methods run (references: on the trusted device).
    status : callable, optional
        ``status(line)``: what will run, then a line per reference and per (scene, spp,
        seed) step with the time so far and an estimate of the time left.
    keep_images : bool
        Keep each cell's image in the cache once its group is summarised.
    sampler : str
        How the sample buffers are drawn (:data:`clrecon.scenes.render.SAMPLERS`): the
        tracer's stratified ``"lattice"`` or independent ``"random"`` samples (its cells are
        cached apart).

    Returns
    -------
    dict
        ``config``, ``settings``, ``references`` (per scene: ``ref_spp``, ``noise_var``),
        ``rows`` (per scene, setting and spp: ``mse``, ``bias2``, ``variance``,
        ``bias_share``, ``psnr_median``, ``psnr_seed``, ``mse_seed``, ``seeds``, ``run_s``,
        or ``error``), ``ablation`` (per scene and ablation setting: its and its base's
        ``bias2`` and ``variance``) and ``markdown``.
    """
    scenes, spps, (w, h), seeds, ablation_spp = _check_options(
        scenes, spps, size, seeds, ablation_spp, ref_spp)
    check_sampler(sampler)  # before any device work
    dev = get_device(device)
    probe = Probe(dev)
    main = study_settings(methods, settings, probe)
    abl = ablation_settings(methods, probe) if ablation_spp else []
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    cells = out / "cells" / code_digest() / (f"{w}x{h}" if sampler == "lattice"
                                             else f"{w}x{h}-{sampler}")
    scene_objs = {n: get_scene(n) for n in scenes}
    ref_spps = {n: int(ref_spp or s.reference_spp) for n, s in scene_objs.items()}
    # per spp, the settings measured at it (an ablation's cells share a main setting's key)
    plan: dict[int, list[Setting]] = {spp: list(main) for spp in spps}
    if abl:
        at = plan.setdefault(ablation_spp, [])
        at.extend(s for s in abl if all(s.key != o.key for o in at))
    plan = dict(sorted(plan.items()))
    n_groups = sum(len(v) for v in plan.values()) * len(scenes)
    eta = _Eta(sum(spp * (len(v) + 1) for spp, v in plan.items()) * seeds * len(scenes))
    if status:
        status(f"{len(scenes)} scenes ({', '.join(scenes)}) x {len(main)} settings x "
               f"{len(spps)} spp ({','.join(map(str, spps))})"
               + (f" + {sum(s.kind == 'ablation' for s in abl)} ablation settings at "
                  f"{ablation_spp} spp" if abl else "")
               + f" = {n_groups} groups of {seeds} seeds at {w}x{h} on {dev.info.label}; "
               f"cache in {cells}")
    report: dict[str, Any] = {
        "config": {"size": [w, h], "spps": spps, "seeds": seeds,
                   "sample_seed": "1000 * (seed + 1) + spp", "sampler": sampler,
                   "ablation_spp": ablation_spp,
                   "device": dev.info.label, "reference_seeds": list(REFERENCE_SEEDS),
                   "mse": "linear radiance, mean over pixels and RGB, against the seed-1 "
                          "reference", "psnr": "clrecon.metrics.psnr (tone mapped)"},
        "settings": [_setting_json(s) for s in _unique_settings(main + abl)],
        "references": {}, "rows": [], "ablation": []}
    for name, scene in scene_objs.items():
        refs = _references(scene, w, h, ref_spps[name], out / "references", status)
        report["references"][name] = {"ref_spp": ref_spps[name],
                                      "noise_var": reference_noise(*refs)}
        ref = refs[0]
        results: dict[tuple[str, int], dict] = {}
        for spp, group in plan.items():
            results.update(_measure_spp(dev, scene, w, h, spp, seeds, group, ref,
                                        ref_spps[name], cells / name, keep_images, status,
                                        eta, sampler))
            clear_sessions()  # the next spp's buffers are larger
        for s in main:
            for spp in spps:
                report["rows"].append({"scene": name, "setting": s.label, "method": s.method,
                                       "kind": s.kind, "spp": spp, **results[(s.key, spp)]})
        report["ablation"] += _ablation_rows(name, abl, results, ablation_spp)
        write_report(out, report)
        save_plot(out / f"{name}_convergence.png", name,
                   [r for r in report["rows"] if r["scene"] == name],
                   report["references"][name]["noise_var"])
    return report


def _references(scene, w: int, h: int, spp: int, cache: Path,
                status: Status | None) -> list[np.ndarray]:
    """The scene's references of :data:`REFERENCE_SEEDS`, cached or rendered."""
    refs = []
    for seed in REFERENCE_SEEDS:
        t = time.perf_counter()
        ref, cached = _reference(scene, w, h, spp, seed, cache)
        refs.append(ref)
        if status and not cached:
            status(f"reference of {scene.name} ({spp} spp, seed {seed}) rendered in "
                   f"{duration_text(time.perf_counter() - t)}")
    return refs


def _ablation_rows(name: str, abl: list[Setting], results: dict[tuple[str, int], dict],
                   spp: int) -> list[dict]:
    """Each ablation setting's numbers at ``spp`` beside its base's (``base_*``)."""
    rows = []
    for s in (a for a in abl if a.kind == "ablation"):
        base = next(b for b in abl if b.label == s.base)
        mine, theirs = results[(s.key, spp)], results[(base.key, spp)]
        rows.append({
            "scene": name, "method": s.method, "setting": s.label, "base": base.label,
            "source": s.source, "spp": spp, "knobs": s.knobs,
            **{k: mine.get(k) for k in ("bias2", "bias2_se", "variance", "mse", "error")},
            **{f"base_{k}": theirs.get(k) for k in ("bias2", "bias2_se", "variance", "mse")}})
    return rows


def _unique_settings(settings: list[Setting]) -> list[Setting]:
    seen, out = set(), []
    for s in settings:
        if s.label not in seen:
            seen.add(s.label)
            out.append(s)
    return out


def _setting_json(s: Setting) -> dict:
    return {"label": s.label, "method": s.method, "knobs": s.knobs, "kind": s.kind,
            "key": s.key, "canonical_knobs": s.canonical, "source": s.source, "base": s.base}


def _measure_spp(dev, scene, w, h, spp, seeds, group, ref, ref_spp, cache: Path,
                 keep_images, status, eta, sampler="lattice") -> dict[tuple[str, int], dict]:
    """Every setting of ``group`` at ``spp``: from the cache where done, else measured."""
    done: dict[tuple[str, int], dict] = {}
    todo: list[Setting] = []
    sample_seeds = [sample_seed(i, spp) for i in range(seeds)]
    for s in group:
        path = cache / s.key / f"spp{spp}_ref{ref_spp}.json"
        if path.exists():
            saved = json.loads(path.read_text())
            if saved.get("seeds") == sample_seeds:
                done[(s.key, spp)] = saved
                continue
        todo.append(s)
    if not todo:
        eta.step(spp * (len(group) + 1) * seeds, 0.0)
        return done
    run_s: dict[str, list[float]] = {s.key: [] for s in todo}
    errors: dict[str, str] = {}
    for i, sseed in enumerate(sample_seeds):
        t = time.perf_counter()
        missing = [s for s in todo if s.key not in errors
                   and not (cache / s.key / f"spp{spp}_seed{sseed}.npy").exists()]
        buf = render_samples(scene, w, h, spp, seed=sseed, device=dev,
                             sampler=sampler) if missing else None
        for s in missing:
            t1 = time.perf_counter()
            try:
                img = run(buf, s.method, dev, **s.knobs).image
                bad = int((~np.isfinite(img)).any(axis=2).sum())
                if bad:  # a result of the device, not an error of the study: recorded
                    raise ValueError(f"{bad} non-finite pixels (sample seed {sseed})")
            except (ValueError, ClreconError) as exc:
                errors[s.key] = f"{type(exc).__name__}: {exc}"
                if status:
                    status(f"{scene.name} {spp} spp: {s.label} failed: {errors[s.key]}")
                continue
            run_s[s.key].append(time.perf_counter() - t1)
            (cache / s.key).mkdir(parents=True, exist_ok=True)
            _save_npy(cache / s.key / f"spp{spp}_seed{sseed}.npy", img)
        dt = time.perf_counter() - t if missing else 0.0
        eta.step(spp * (len(group) + 1), dt)
        if status:
            status(f"{scene.name} {spp} spp seed {i + 1}/{seeds}: {len(missing)} of "
                   f"{len(group)} settings run in {duration_text(dt)}; {eta.line()}")
    for s in todo:
        if s.key in errors:
            done[(s.key, spp)] = {"error": errors[s.key], "seeds": sample_seeds}
            continue
        paths = [cache / s.key / f"spp{spp}_seed{v}.npy" for v in sample_seeds]
        images = np.stack([np.load(p) for p in paths])
        res = bias_variance(images, ref)
        ps = [psnr(img, ref) for img in images]
        res.update(psnr_seed=ps, psnr_median=float(statistics.median(ps)), seeds=sample_seeds,
                   run_s=float(statistics.median(run_s[s.key])) if run_s[s.key] else None)
        write_atomic(cache / s.key / f"spp{spp}_ref{ref_spp}.json",
                     json.dumps(res, indent=1).encode())
        if not keep_images:
            for p in paths:
                p.unlink()
        done[(s.key, spp)] = res
    return done
