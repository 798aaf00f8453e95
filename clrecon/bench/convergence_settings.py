"""What the convergence study (:mod:`clrecon.bench.convergence`) runs: the settings of
each method (its default at every value of the :data:`DEFAULT_AXES` it takes, its trade
settings), the ablation's knobs that switch one bias source each, and the bias sources no
knob reaches. A :class:`Probe` finds, on two small frames, which knobs a method takes and
which values are its default, so that two spellings of one reconstruction share a cache
key."""
from __future__ import annotations

import hashlib
import itertools
import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from clrecon.api import METHODS, make_pipeline
from clrecon.bench.trade import TRADES
from clrecon.core.device import Device, DeviceSpec, get_device
from clrecon.scenes import SCENES, get_scene, render_samples

#: knobs every method's default runs at each value of, where the method takes the knob
#: (found by trying on a small frame): ``(name, values, paper)``, ``paper`` the value that is
#: the method alone, which the ablation runs with (its bias sources are the method's own)
DEFAULT_AXES: tuple[tuple[str, tuple, Any], ...] = (("safeguard", (True, False), False),)

#: per method, the knobs that switch off or shrink one of its bias sources: (label, knobs,
#: the bias source). Measured as the change of bias² at the ablation's spp (``ABLATION_SPP``
#: of :mod:`clrecon.bench.convergence`) against the
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
