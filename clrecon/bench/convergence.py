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

import hashlib
import io
import itertools
import json
import math
import statistics
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from clrecon.bench.timing import duration_text
from clrecon.bench.trade import TRADES
from clrecon.core.device import Device, DeviceSpec, get_device
from clrecon.core.errors import ClreconError
from clrecon.core.fsutil import write_atomic
from clrecon.core.pipeline import METHODS, _load_methods, clear_sessions, make_pipeline, run
from clrecon.io import load_image, save_image
from clrecon.metrics import psnr
from clrecon.scenes import SCENES, get_scene, render_reference, render_samples

DEFAULT_SPPS = (4, 8, 16, 32, 64, 128)
DEFAULT_SIZE = (256, 256)
DEFAULT_SEEDS = 4
#: spp of the ablation (0: no ablation)
ABLATION_SPP = 64
#: seeds of the reference (what the study measures against) and of its noise estimate
REFERENCE_SEEDS = (1, 2)

#: knobs every method's default runs at each value of, where the method takes the knob
#: (found by trying on a small frame): ``(name, values, paper)``, ``paper`` the value that is
#: the method alone, which the ablation runs with (its bias sources are the method's own)
DEFAULT_AXES: tuple[tuple[str, tuple, Any], ...] = (("safeguard", (True, False), False),)

#: per method, the knobs that switch off or shrink one of its bias sources: (label, knobs,
#: the bias source). Measured as the change of bias² at :data:`ABLATION_SPP` against the
#: method's default, both run as the method alone
ABLATIONS: dict[str, tuple[tuple[str, dict[str, Any], str], ...]] = {
    "sweep": (
        ("4 scales", {"scales": 4}, "box-scale weights: 2 scales (1x1, 5x5 px) vs 4 (3x3, 7x7)"),
        ("exponent 1.3", {"exponent": 1.3}, "weight falloff: the paper's sharper variant"),
        ("diameter x0.5", {"diameter_scale": 0.5}, "denoising diameter: narrower than the blur"),
        ("diameter x2", {"diameter_scale": 2.0}, "denoising diameter: wider than the blur"),
    ),
    "layered": (
        ("sigma_x 0.29", {"sigma_x": 0.29}, "spatial filter matched to the box pixel "
                                           "(variance 1/12) instead of 0.33"),
        ("sigma_x 0.15", {"sigma_x": 0.15}, "narrower spatial filter"),
        ("no merging", {"merge_threshold": -1.0}, "layer merging (10%)"),
        ("full stats", {"stats_stride": 1}, "sparse tile statistics (every 3 spp-th sample)"),
        ("tile 16", {"tile": 16}, "tile size: one filter per partition and tile"),
        ("filter mip", {"filter": "mip"}, "filter: MIP taps instead of the sheared Gaussian"),
        ("filter rotated", {"filter": "rotated"}, "filter: rotated separable Gaussian"),
    ),
    "splat": (
        ("2 layers", {"layers": 2}, "depth layers of the composite: fewer"),
        ("8 layers", {"layers": 8}, "depth layers of the composite: more"),
        ("mip radius 16", {"mip_radius": 16.0}, "mip levels: PSFs resolved to 16 level "
                                                "pixels of radius instead of 8"),
        ("paper plan", {"mip_radius": 0}, "the mip levels and bins instead of the paper's "
                                          "full-resolution spreadlets"),
        ("dense", {"dense": True}, "(the paper's plan) the dense PSF at full resolution"),
    ),
}

#: per method, bias sources that no knob switches off
UNSWITCHED: dict[str, tuple[str, ...]] = {
    "sweep": ("the scale weights are boxes (5x5 or 7x7 windows), not the blur's disc or "
              "segment: the denoising diameter only chooses between them",),
    "layered": ("the filter is a Gaussian matched in variance to the disc and the motion "
                "segment, not their shape (a disc has a sharp rim)",
                "one CoC and one motion per partition: samples of different blur within "
                "it are filtered alike (the reprojection residual is only matched in "
                "expectation)",
                "partition and tile boundaries: a surface's blur changes where the "
                "partitioning of the depth axis or the tile changes",
                "the gather reach (96 px) truncates wider blurs"),
    "splat": ("the composite at depth edges: coverage-normalised layers, the farthest "
              "well-covered layer fills, so occluded surfaces behind an edge are lost or "
              "doubled",
              "the mip plan: the samples of one layer and level pixel share one PSF (their "
              "mean radius and motion), and a PSF is resolved to its level's pixels",
              "holes: pixels no sample's PSF covers in a layer"),
}

Status = Callable[[str], None]


# -- the measure ----------------------------------------------------------------------------

def sample_seed(index: int, spp: int) -> int:
    """The sample seed of seed index ``index`` at ``spp``: ``1000 (index + 1) + spp``,
    independent across spp and seeds and never one of :data:`REFERENCE_SEEDS` (spp < 1000)."""
    return 1000 * (int(index) + 1) + int(spp)


def bias_variance(images, ref) -> dict[str, Any]:
    """MSE of ``n >= 2`` images of one estimator against ``ref``, split into bias² and
    variance (linear values; mean over pixels and channels).

    Parameters
    ----------
    images : array_like, shape (n, H, W, 3)
        Independent estimates (different sample seeds).
    ref : array_like, shape (H, W, 3)

    Returns
    -------
    dict
        ``mse`` (mean over images of their MSE), ``bias2`` (``mean((m - ref)^2) - variance
        / n``, ``m`` the mean image: unbiased, may be slightly negative), ``variance`` (mean
        of the per-pixel sample variance, ``ddof=1``), ``mse_seed`` (each image's MSE),
        ``bias_share`` (``bias2 / mse``, clipped to [0, 1]), ``bias2_se`` (the standard
        error of ``bias2`` were the pixels independent: the spread of the per-pixel terms
        over the root of their count, which also counts the bias's own spread across
        pixels, so it errs large); ``mse == bias2 + variance``.
    """
    x = np.asarray(images, np.float64)
    r = np.asarray(ref, np.float64)
    if x.ndim != 4 or x.shape[1:] != r.shape or r.ndim != 3:
        raise ValueError(f"images: expected (n, H, W, 3) with ref (H, W, 3), got {x.shape} "
                         f"and {r.shape}")
    n = x.shape[0]
    if n < 2:
        raise ValueError(f"images: need at least 2 (seeds) to split bias from variance, got {n}")
    mse_seed = ((x - r) ** 2).mean(axis=(1, 2, 3))
    var_px = x.var(axis=0, ddof=1)
    d = (((x.mean(axis=0) - r) ** 2) - var_px / n).mean(axis=2)  # per pixel: mean is bias2
    variance = float(var_px.mean())
    bias2 = float(d.mean())
    mse = float(mse_seed.mean())
    return {"mse": mse, "bias2": bias2, "variance": variance,
            "bias2_se": float(d.std(ddof=1) / math.sqrt(d.size)) if d.size > 1 else math.inf,
            "mse_seed": [float(v) for v in mse_seed],
            "bias_share": float(min(max(bias2 / mse, 0.0), 1.0)) if mse > 0 else 0.0}


def reference_noise(a, b) -> float:
    """Variance of one reference from two of independent seeds: ``mean((a - b)^2) / 2``."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    if a.shape != b.shape:
        raise ValueError(f"references differ in shape: {a.shape} and {b.shape}")
    return float(((a - b) ** 2).mean() / 2)


# -- settings -------------------------------------------------------------------------------

@dataclass
class Setting:
    """One reconstruction the study runs: ``kind`` is ``box``, ``default`` (a method's
    default, at one value of each axis it takes), ``trade`` (a :data:`TRADES` setting) or
    ``ablation``; ``key`` names its cache folder (method and knobs less the defaults: two
    spellings of one reconstruction share it)."""

    label: str
    method: str
    knobs: dict[str, Any]
    kind: str
    key: str = ""
    source: str = ""  # the bias source an ablation switches
    base: str = ""  # an ablation: the label of the default it is measured against
    canonical: dict[str, Any] = field(default_factory=dict)


class Probe:
    """What a method takes and defaults to, found on two small blurred frames (fence 48x48
    at 4 and 8 spp): whether it takes a knob (:func:`make_pipeline` raises ``TypeError``
    otherwise) and which values of knobs are its default (equal to the signature's default,
    or to what ``describe()`` of the default pipeline reports, on both frames)."""

    def __init__(self, device: DeviceSpec | Device = None):
        self.dev = get_device(device)
        scene = get_scene("fence")
        self.infos = [render_samples(scene, 48, 48, spp, seed=7, device=self.dev).inspect()
                      for spp in (4, 8)]
        self._desc: dict[str, list[dict]] = {}

    def takes(self, method: str, knob: str, value: Any) -> bool:
        try:
            make_pipeline(method, self.dev.context, self.infos[0], **{knob: value})
        except TypeError as exc:
            if knob in str(exc):
                return False
            raise
        return True

    def is_default(self, method: str, knob: str, value: Any) -> bool:
        import inspect

        param = inspect.signature(METHODS[method].__init__).parameters.get(knob)
        if param is not None and param.default is not inspect.Parameter.empty \
                and param.default is not None and _same(param.default, value):
            return True
        if method not in self._desc:
            self._desc[method] = [make_pipeline(method, self.dev.context, info).describe()
                                  for info in self.infos]
        return all(knob in d and _same(d[knob], value) for d in self._desc[method])


def _same(a, b) -> bool:
    return type(a) is type(b) and a == b or (
        isinstance(a, (int, float)) and isinstance(b, (int, float))
        and not isinstance(a, bool) and not isinstance(b, bool) and float(a) == float(b))


def _key(method: str, canonical: dict) -> str:
    text = json.dumps([method, canonical], sort_keys=True, default=str)
    return f"{method}-{hashlib.sha1(text.encode()).hexdigest()[:10]}"


def _default_label(method: str, axes: dict) -> str:
    """``sweep``; with axes ``sweep +safeguard``, ``sweep -safeguard`` (bools), ``name=value``."""
    parts = [(f"+{k}" if v else f"-{k}") if isinstance(v, bool) else f"{k}={v}"
             for k, v in axes.items()]
    return " ".join([method, *parts])


def _check_methods(methods: Sequence[str] | None) -> list[str]:
    _load_methods()
    if methods is None:
        return [m for m in TRADES if m in METHODS]
    methods = list(methods)
    for m in methods:
        if m not in METHODS:
            raise ValueError(f"methods: unknown {m!r}; available: {sorted(METHODS)}")
    return ["box", *[m for m in dict.fromkeys(methods) if m != "box"]]


def _setting(label, method, knobs, kind, probe, **extra) -> Setting:
    canonical = {k: v for k, v in sorted(knobs.items()) if not probe.is_default(method, k, v)}
    return Setting(label, method, dict(knobs), kind, _key(method, canonical),
                   canonical=canonical, **extra)


def _axes(method: str, probe) -> list[tuple[str, tuple, Any]]:
    """The :data:`DEFAULT_AXES` ``method`` takes (box: none, it is what they compare with)."""
    if method == "box":
        return []
    return [ax for ax in DEFAULT_AXES if probe.takes(method, ax[0], ax[2])]


def study_settings(methods: Sequence[str] | None = None,
                   settings: Sequence[str] | None = None, probe=None) -> list[Setting]:
    """Box, each method's default (at every value of each :data:`DEFAULT_AXES` knob it
    takes) and its :data:`TRADES` settings that are not one of those spelled out.

    ``methods`` restricts the methods (box always runs); ``settings`` the settings by label,
    where a method's name selects every default of it. ``probe``: a :class:`Probe` (made on
    the default device when ``None``).
    """
    methods = _check_methods(methods)
    probe = probe or Probe()
    out: list[Setting] = []
    for m in methods:
        axes = _axes(m, probe)
        defaults = [dict(zip([a[0] for a in axes], vals))
                    for vals in itertools.product(*[a[1] for a in axes])]
        for knobs in defaults:
            out.append(_setting(_default_label(m, knobs), m, knobs,
                                "box" if m == "box" else "default", probe))
        for label, knobs in TRADES.get(m, ()):
            s = _setting(label, m, knobs, "trade", probe)
            if all(s.key != o.key for o in out):
                out.append(s)
    if settings is not None:
        wanted = list(dict.fromkeys(settings))
        labels = {s.label for s in out}
        unknown = [w for w in wanted if w not in labels and w not in methods]
        if unknown:
            raise ValueError(f"settings: unknown {unknown}; available: "
                             f"{[s.label for s in out]} (or a method's name: its defaults)")
        out = [s for s in out if s.kind == "box" or s.label in wanted
               or (s.kind == "default" and s.method in wanted)]
    return out


def ablation_settings(methods: Sequence[str] | None = None, probe=None) -> list[Setting]:
    """For each method of :data:`ABLATIONS` in ``methods``: its default as the method alone
    (``base``) and each ablation knob on top of it."""
    methods = [m for m in _check_methods(methods) if m in ABLATIONS]
    probe = probe or Probe()
    out = []
    for m in methods:
        paper = {a[0]: a[2] for a in _axes(m, probe)}
        base = _setting(_default_label(m, paper), m, paper, "default", probe)
        out.append(base)
        for label, knobs, source in ABLATIONS[m]:
            out.append(_setting(f"{m} {label}", m, {**paper, **knobs}, "ablation", probe,
                                source=source, base=base.label))
    return out


def blur_scenes() -> list[str]:
    """The built-in scenes with blur: objects, and a lens or motion."""
    names = []
    for name in SCENES:
        s = get_scene(name)
        if s.objects and (s.lens_radius > 0 or s.has_motion):
            names.append(name)
    return names


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
             status: Status | None = None, keep_images: bool = False) -> dict:
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
    dev = get_device(device)
    probe = Probe(dev)
    main = study_settings(methods, settings, probe)
    abl = ablation_settings(methods, probe) if ablation_spp else []
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    cells = out / "cells" / f"{w}x{h}"
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
                   "sample_seed": "1000 * (seed + 1) + spp", "ablation_spp": ablation_spp,
                   "device": dev.info.label, "reference_seeds": list(REFERENCE_SEEDS),
                   "mse": "linear radiance, mean over pixels and RGB, against the seed-1 "
                          "reference", "psnr": "clrecon.metrics.psnr (tone mapped)"},
        "settings": [_setting_json(s) for s in _unique_settings(main + abl)],
        "references": {}, "rows": [], "ablation": []}
    for name, scene in scene_objs.items():
        refs = []
        for seed in REFERENCE_SEEDS:
            t = time.perf_counter()
            ref, cached = _reference(scene, w, h, ref_spps[name], seed, out / "references")
            refs.append(ref)
            if status and not cached:
                status(f"reference of {name} ({ref_spps[name]} spp, seed {seed}) rendered in "
                       f"{duration_text(time.perf_counter() - t)}")
        report["references"][name] = {"ref_spp": ref_spps[name],
                                      "noise_var": reference_noise(*refs)}
        ref = refs[0]
        results: dict[tuple[str, int], dict] = {}
        for spp, group in plan.items():
            results.update(_measure_spp(dev, scene, w, h, spp, seeds, group, ref,
                                        ref_spps[name], cells / name, keep_images, status,
                                        eta))
            clear_sessions()  # the next spp's buffers are larger
        for s in main:
            for spp in spps:
                report["rows"].append({"scene": name, "setting": s.label, "method": s.method,
                                       "kind": s.kind, "spp": spp, **results[(s.key, spp)]})
        for s in (a for a in abl if a.kind == "ablation"):
            base = next(b for b in abl if b.label == s.base)
            mine, theirs = results[(s.key, ablation_spp)], results[(base.key, ablation_spp)]
            report["ablation"].append({
                "scene": name, "method": s.method, "setting": s.label, "base": base.label,
                "source": s.source, "spp": ablation_spp, "knobs": s.knobs,
                **{k: mine.get(k) for k in ("bias2", "bias2_se", "variance", "mse", "error")},
                **{f"base_{k}": theirs.get(k) for k in ("bias2", "bias2_se", "variance",
                                                        "mse")}})
        _write(out, report)
        _save_plot(out / f"{name}_convergence.png", name,
                   [r for r in report["rows"] if r["scene"] == name],
                   report["references"][name]["noise_var"])
    return report


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
                 keep_images, status, eta) -> dict[tuple[str, int], dict]:
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
        buf = render_samples(scene, w, h, spp, seed=sseed, device=dev) if missing else None
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


# -- outputs ----------------------------------------------------------------------------------

def _write(out: Path, report: dict) -> None:
    """``convergence.json`` and ``.md`` of the scenes done so far (rewritten after each)."""
    report["markdown"] = _markdown(report)
    write_atomic(out / "convergence.json", json.dumps(
        {k: v for k, v in report.items() if k != "markdown"}, indent=1, default=str).encode(),
        0o644)
    write_atomic(out / "convergence.md", report["markdown"].encode(), 0o644)


def _sci(v) -> str:
    if v is None or not math.isfinite(v):
        return "-"
    return f"{v:.2e}".replace("e-0", "e-").replace("e+0", "e")


def _by_setting(rows: list[dict]) -> dict[str, dict[int, dict]]:
    table: dict[str, dict[int, dict]] = {}
    for r in rows:
        table.setdefault(r["setting"], {})[r["spp"]] = r
    return table


#: a setting is flat from the spp where doubling the samples gains less than this share
FLAT_GAIN = 0.2


def summarize(rows: list[dict]) -> list[dict]:
    """Per setting of one scene: the MSE ratio per doubling of spp over the last two spp
    (0.5: falling like 1/spp; 1: not improving), ``flat_from`` (the smallest spp from which
    every further doubling lowers the MSE by less than :data:`FLAT_GAIN`; ``None``: not in
    range), the bias share at the largest spp, and the smallest spp from which box's MSE is
    below the setting's (``None``: never in range)."""
    table = _by_setting(rows)
    box = table.get("box", {})
    out = []
    for label, cells in table.items():
        spps = sorted(k for k, r in cells.items() if "mse" in r)
        item = {"setting": label, "per_doubling": None, "flat_from": None,
                "bias_share_top": None, "box_better_from": None}
        ratios = []
        for lo, hi in zip(spps, spps[1:]):
            a, b = cells[lo]["mse"], cells[hi]["mse"]
            ratios.append((b / a) ** (1.0 / math.log2(hi / lo)) if a > 0 else math.nan)
        if ratios:
            item["per_doubling"] = ratios[-1]
            for i in range(len(ratios)):
                if all(r > 1 - FLAT_GAIN for r in ratios[i:]):
                    item["flat_from"] = spps[i]
                    break
        if spps:
            item["bias_share_top"] = cells[spps[-1]]["bias_share"]
        if label != "box":
            for spp in spps:
                if spp in box and "mse" in box[spp] and box[spp]["mse"] < cells[spp]["mse"]:
                    item["box_better_from"] = spp
                    break
        out.append(item)
    return out


def _markdown(rep: dict) -> str:
    cfg = rep["config"]
    w, h = cfg["size"]
    lines = [
        f"Device: {cfg['device']}; {w}x{h}; {cfg['seeds']} sample seeds per cell "
        f"({cfg['sample_seed']}); references on the trusted device (seeds 1 and 2).", "",
        "MSE: linear radiance, mean over pixels and RGB, against the seed-1 reference, mean "
        "over seeds; in brackets the bias share, bias² / MSE, with bias² = mean((mean image "
        "- ref)²) - variance / seeds and variance the per-pixel spread across seeds (MSE = "
        "bias² + variance). bias² includes the reference's own noise (the floor no setting "
        "gets below; box measures it). PSNR: clrecon.metrics.psnr (tone mapped, clipped), "
        "median over seeds. Per doubling: MSE ratio per doubling of spp over the last two "
        f"spp (0.50: like 1/spp; 1.00: not improving); flat from: the spp from which every "
        f"doubling gains less than {100 * FLAT_GAIN:.0f}% MSE.", ""]
    lines += _overview(rep)
    for scene in dict.fromkeys(r["scene"] for r in rep["rows"]):
        rows = [r for r in rep["rows"] if r["scene"] == scene]
        spps = sorted({r["spp"] for r in rows})
        ref = rep["references"][scene]
        table = _by_setting(rows)
        box = table.get("box", {}).get(spps[-1], {})
        box_line = "" if "bias2" not in box else (
            f" Box's bias² at {spps[-1]} spp: {_sci(box['bias2'])} ± {_sci(box['bias2_se'])} "
            "(box is unbiased, so this is the reference's noise seen from the other side).")
        lines += [f"### {scene}", "",
                  f"Reference {ref['ref_spp']} spp; its noise variance (half the mean squared "
                  f"difference of seeds 1 and 2): {_sci(ref['noise_var'])}.{box_line}", "",
                  "| setting | " + " | ".join(f"{s} spp" for s in spps)
                  + " | per doubling | flat from | box better from |",
                  "|---|" + "---|" * (len(spps) + 3)]
        summ = {s["setting"]: s for s in summarize(rows)}
        for label, cells in table.items():
            vals = []
            for spp in spps:
                r = cells.get(spp, {})
                vals.append("error" if "error" in r else
                            f"{_sci(r['mse'])} ({100 * r['bias_share']:.0f}%)" if r else "-")
            sm = summ[label]
            per = "-" if sm["per_doubling"] is None else f"{sm['per_doubling']:.2f}"
            better = "-" if label == "box" else (
                f"{sm['box_better_from']} spp" if sm["box_better_from"] else "never")
            flat = f"{sm['flat_from']} spp" if sm["flat_from"] else "-"
            lines.append(f"| {label} | " + " | ".join(vals) + f" | {per} | {flat} | {better} |")
        lines += ["", "Median PSNR dB:", "",
                  "| setting | " + " | ".join(f"{s} spp" for s in spps) + " |",
                  "|---|" + "---|" * len(spps)]
        for label, cells in table.items():
            lines.append(f"| {label} | " + " | ".join(
                f"{cells[s]['psnr_median']:.2f}" if "psnr_median" in cells.get(s, {}) else "-"
                for s in spps) + " |")
        errs = [(label, s, c["error"]) for label, cs in table.items() for s, c in cs.items()
                if "error" in c]
        lines += [""] + [f"- {label} at {s} spp: {e}" for label, s, e in errs]
        lines += [""] * bool(errs) + [f"![{scene}]({scene}_convergence.png)", ""]
    if rep["ablation"]:
        scenes = list(dict.fromkeys(a["scene"] for a in rep["ablation"]))
        lines += [f"### Ablation at {cfg['ablation_spp']} spp", "",
                  "bias² of each method alone (the base row) and, per knob that switches a "
                  "bias source, its bias² with the change against the base in brackets "
                  "(variance change after the slash); `*`: the change exceeds twice the "
                  "combined standard error of the two bias² estimates (pixels taken as "
                  "independent).", ""]
        for method in dict.fromkeys(a["method"] for a in rep["ablation"]):
            rows = [a for a in rep["ablation"] if a["method"] == method]
            lines += [f"#### {method}", "", "| setting | bias source | "
                      + " | ".join(scenes) + " |", "|---|---|" + "---|" * len(scenes)]
            base = {a["scene"]: a for a in rows}
            lines.append(f"| {rows[0]['base']} | (base) | " + " | ".join(
                _sci(base[s]["base_bias2"]) if s in base else "-" for s in scenes) + " |")
            for label in dict.fromkeys(a["setting"] for a in rows):
                cells = {a["scene"]: a for a in rows if a["setting"] == label}
                src = next(iter(cells.values()))["source"]
                lines.append(f"| {label} | {src} | " + " | ".join(
                    _ablation_cell(cells.get(s)) for s in scenes) + " |")
            lines.append("")
    lines += ["### Bias sources without a knob", ""]
    for method, items in UNSWITCHED.items():
        lines += [f"- {method}: " + "; ".join(items)]
    lines.append("")
    return "\n".join(lines)


def _overview(rep: dict) -> list[str]:
    """One table over the scenes: per setting, where it is flat and its bias share there."""
    scenes = list(dict.fromkeys(r["scene"] for r in rep["rows"]))
    if not scenes:
        return []
    per = {s: {x["setting"]: x for x in summarize([r for r in rep["rows"]
                                                    if r["scene"] == s])} for s in scenes}
    top = max(r["spp"] for r in rep["rows"])
    lines = ["### Overview", "", f"Per scene: the spp from which the MSE is flat, the bias "
             f"share at {top} spp, and MSE at {top} spp relative to box's.", "",
             "| setting | " + " | ".join(scenes) + " |", "|---|" + "---|" * len(scenes)]
    for label in dict.fromkeys(r["setting"] for r in rep["rows"]):
        cells = []
        for s in scenes:
            sm = per[s].get(label)
            mine = next((r for r in rep["rows"] if r["scene"] == s and r["setting"] == label
                         and r["spp"] == top), {})
            box = next((r for r in rep["rows"] if r["scene"] == s and r["setting"] == "box"
                        and r["spp"] == top), {})
            if sm is None or "mse" not in mine:
                cells.append("-")
                continue
            flat = f"{sm['flat_from']}" if sm["flat_from"] else "-"
            rel = f", x{mine['mse'] / box['mse']:.2f}" if box.get("mse") else ""
            cells.append(f"{flat} / {100 * mine['bias_share']:.0f}%{rel}")
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return lines + [""]


def _ablation_cell(a: dict | None) -> str:
    if a is None:
        return "-"
    if a.get("error") or a.get("bias2") is None:
        return "error"
    b, b0, v, v0 = a["bias2"], a["base_bias2"], a["variance"], a["base_variance"]
    if b0 is None:
        return f"{_sci(b)} (base: error)"
    db = "" if b0 == 0 else f" ({100 * (b - b0) / abs(b0):+.0f}%"
    dv = "" if not db or not v0 else f" / {100 * (v - v0) / v0:+.0f}%"
    sig = "*" if abs(b - b0) > 2 * math.hypot(a["bias2_se"], a["base_bias2_se"]) else ""
    return f"{_sci(b)}{sig}{db}{dv}{')' if db else ''}"


def _save_plot(path: Path, scene: str, rows: list[dict], noise_var: float) -> None:
    from clrecon.bench.trade import _plt

    plt = _plt()
    table = _by_setting(rows)
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(12, 5.2), dpi=100, sharey=True)
    cmap = plt.get_cmap("tab10" if len(table) <= 10 else "tab20")
    k = 0
    for label, cells in table.items():
        spps = sorted(s for s, r in cells.items() if "mse" in r)
        if not spps:
            continue
        xs = np.array(spps, float)
        got = {key: np.array([cells[s][key] for s in spps], float)
               for key in ("mse", "bias2", "variance")}
        if label == "box":
            colour, style, lw = "black", "--", 2.0
        else:
            colour, style, lw = cmap(k % cmap.N), "-", 1.6
            k += 1
        ax.plot(xs, got["mse"], style, color=colour, lw=lw, marker="o", ms=3, label=label)
        bias = got["bias2"]
        ax2.plot(xs, np.where(bias > 0, bias, np.nan), style, color=colour, lw=0.9)
        ax2.plot(xs, got["variance"], ":", color=colour, lw=0.9)
    for a in (ax, ax2):
        if noise_var > 0:
            a.axhline(noise_var, color="grey", lw=0.8, ls="-.")
        a.set_xscale("log", base=2)
        a.set_yscale("log")
        a.set_xlabel("samples per pixel")
        a.grid(True, which="both", alpha=0.3)
        xs = sorted({r["spp"] for r in rows})
        a.set_xticks(xs, [str(x) for x in xs])
    ax.set_ylabel("MSE (linear radiance, mean over RGB)")
    ax.set_title(f"{scene}: MSE against the reference (box dashed; dash-dot: the "
                 "reference's noise)", fontsize=9)
    ax2.set_title("bias² (solid; box dashed) and variance (dotted), same colours", fontsize=9)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
