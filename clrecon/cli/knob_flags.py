"""``clrecon reconstruct``'s method flags, generated from the methods' constructors.

The rule, decided here and nowhere else: a parameter of a registered method's ``__init__``
(:data:`clrecon.core.pipeline.METHODS`) is a *user knob*, and gets the flag
``--name-with-dashes``, when it has a default and its type hint, ``None`` aside, is made of
``bool``, ``int``, ``float`` and ``str`` only. That leaves out ``context`` and ``info`` (no
default) and launch configurations (``local: LocalSize | None``): the tuner's and the API's,
reachable with ``--knob``/the library. Of the knobs every method takes through
:func:`~clrecon.core.pipeline.make_pipeline` (``PIPELINE_KNOBS``) the same rule applies,
less :data:`SPELLED_OTHERWISE`.

A knob several methods take is one flag; its help names each method with its default, as the
signature has it (``None``: the method chooses, from the frame and the device). A ``bool``
knob is ``--knob/--no-knob``; a knob of several types (``int | bool``) reads its value as
``--knob`` of ``clrecon table`` does. An absent flag passes nothing, so the method's own
default holds.
"""
from __future__ import annotations

import argparse
import inspect
import types
import typing
from dataclasses import dataclass

from clrecon.bench.options import parse_value

SCALARS = (bool, int, float, str)
#: pipeline knobs with a flag of another form: ``estimate_error`` is ``--error PATH``
SPELLED_OTHERWISE = frozenset({"estimate_error"})
#: the value a flag takes, by its type
METAVARS = {int: "N", float: "X", str: "NAME"}
#: who takes a pipeline knob (in the help, in place of a method's name)
EVERY_METHOD = "every method"

#: what a knob does, for its help (its methods and defaults come from the signatures)
DESCRIPTIONS = {
    "scales": "blend 2 or 4 scales",
    "dof_layers": "the sort-free three-layer depth-of-field variant",
    "exponent": "weight exponent (paper: 1.3; at most 126 / log2(K spp), K = 25 for 2 "
                "scales, 49 for 4: 16.5 at 8 spp)",
    "smooth_motion": "add the motion term to the denoising diameter (None: whether the "
                     "frame has motion)",
    "diameter_scale": "scales the denoising diameter max(2|coc|, |motion|)",
    "sort": "how the window is ordered: block, tile or pixel (None: block on CPUs, else "
            "tile)",
    "tile": "sweep: tile size of sort=tile; layered: screen tile (power of two)",
    "tile_merge": "how sort=tile sorts a tile: auto, serial or bitonic",
    "group": "4x4 blocks per work-group of sort=block",
    "specialize": "plan only what the frame needs (--no-specialize: the full plan always)",
    "exact_depth_order": "order the sweep by exact depths (default: to 12 significant bits, "
                         "kernels/sweep_order.h)",
    "mode": "practical (the 2015 method) or lrdm (its 2014 baseline)",
    "filter": "screen-space filter: sheared, mip or rotated (None: sheared; lrdm: rotated)",
    "stats_stride": "every n-th sample in the statistics (1: all; None: 3*spp)",
    "merge_threshold": "merge layers while the filter changes < this (<0: off; None: the "
                       "mode's)",
    "sigma_x": "the spatial filter's sigma (px)",
    "max_partitions": "partitions kept per tile",
    "guard": "guard band (grid px) beyond which a partition is filtered on a coarser grid",
    "bucket_coc": "CoC span of a depth bucket (px)",
    "splat": "how reproject splats a sample: nearest or bilinear",
    "seed": "seed of the sparse statistics' sample choice",
    "has_motion": "plan for motion (None: whether the frame has motion)",
    "recursions": "forward-backward pairs of the recursive sheared filter",
    "reach": "px outside a tile samples are gathered from",
    "subsample": "reproject on coarse grids: one pixel per b x b block (b in [1, 64], or "
                 "false: every pixel)",
    "mip_images": "filter=mip: whether it reads the image atlas (None: the device decides)",
    "deterministic": "bit-identical images run to run",
    "psf": "PSF model: simplelens, combined or stylized (None: combined with motion, else "
           "simplelens)",
    "layers": "global depth layers (at most 64)",
    "pyramid": "integration filter set: f5 or f7",
    "dense": "splat the dense PSF (the paper's Splatting baseline)",
    "fast_ratio": "draw a cell densely when its dense PSF has at most this many times its "
                  "spreadlets",
    "max_error": "draw a cell densely when its spreadlets' L1 error exceeds this",
    "scatter": "atomic or tiles (None: tiles on CPU devices)",
    "mip_radius": "draw each PSF on the pyramid level where its radius is <= X level pixels "
                  "(0: the paper's spreadlets at full resolution; None: the mip plan's "
                  "radius)",
    "safeguard": "blend toward box where the method's estimated bias dominates (None: on for "
                 "every method but box at >= 2 spp); --no-safeguard: the paper's method alone",
    "guided": "refine each half's image by a regression of its box image on it over "
              "(2N+1)^2 windows (0: off; 1..8)",
    "guide_blend": "with --guided: blend each refined half toward the method's own image where "
                   "that is estimated the better",
    "nlm": "average each half's image further with non-local means over (2N+1)^2 pixels, "
           "weighted by the other half (0: off; 1..10)",
    "nlm_scales": "with --nlm: filter each half's low band at N - 1 coarser scales too (1..6)",
    "hybrid": "with --nlm: blend the method's chain per pixel with box's own halves through "
              "the same filter, by their error estimates",
}


@dataclass(frozen=True)
class KnobFlag:
    """One flag: the knob, its value types (every method's together) and, per method that
    takes it, ``(method, default)``."""

    name: str
    kinds: tuple[type, ...]
    defaults: tuple[tuple[str, object], ...]

    @property
    def option(self) -> str:
        return "--" + self.name.replace("_", "-")

    def help(self) -> str:
        takers = ", ".join(f"{m} (default {d!r})" for m, d in self.defaults)
        desc = DESCRIPTIONS.get(self.name)
        return (f"{desc}; {takers}" if desc else takers).replace("%", "%%")


def _scalar_kinds(hint) -> tuple[type, ...]:
    """The types of an annotation other than ``None`` when all are scalars, else ``()``.

    Read from the annotation's text where it is one (``from __future__ import
    annotations``: ``"int | None"``), so that no annotation is evaluated."""
    if isinstance(hint, str):
        parts = [p.strip() for p in hint.split("|")]
    else:
        union = typing.get_origin(hint) in (typing.Union, getattr(types, "UnionType", None))
        parts = [getattr(k, "__name__", k) for k in (typing.get_args(hint) if union else (hint,))]
    by_name = {k.__name__: k for k in SCALARS}
    kinds = tuple(by_name.get(p) for p in parts if p not in ("None", "NoneType"))
    return kinds if kinds and all(kinds) else ()


def signature_knobs(fn) -> list[tuple[str, tuple[type, ...], object]]:
    """``(name, kinds, default)`` of each user knob of ``fn``'s signature (the rule above)."""
    out = []
    for name, param in inspect.signature(fn).parameters.items():
        kinds = () if param.annotation is inspect.Parameter.empty else \
            _scalar_kinds(param.annotation)
        if param.default is not inspect.Parameter.empty and kinds:
            out.append((name, kinds, param.default))
    return out


def method_flags() -> list[KnobFlag]:
    """Every registered method's knobs, then the pipeline's, one :class:`KnobFlag` each."""
    from clrecon.api import METHODS, PIPELINE_KNOBS, make_pipeline

    found: dict[str, tuple[list[type], list[tuple[str, object]]]] = {}
    for method, cls in METHODS.items():
        for name, kinds, default in signature_knobs(cls.__init__):
            have, defaults = found.setdefault(name, ([], []))
            have.extend(k for k in kinds if k not in have)
            defaults.append((method, default))
    for name, kinds, default in signature_knobs(make_pipeline):
        if name in PIPELINE_KNOBS and name not in SPELLED_OTHERWISE:
            found[name] = (list(kinds), [(EVERY_METHOD, default)])
    return [KnobFlag(n, tuple(k), tuple(d)) for n, (k, d) in found.items()]


def _value_of(kinds: tuple[type, ...]):
    """The argparse ``type`` of a knob of several ``kinds``: the value as ``--knob`` reads
    it, refused unless it is one of them."""
    wanted = " or ".join(k.__name__ for k in kinds)

    def parse(text: str):
        value = parse_value(text)
        if isinstance(value, int) and not isinstance(value, bool) and int not in kinds \
                and float in kinds:
            value = float(value)
        if type(value) not in kinds:
            raise argparse.ArgumentTypeError(f"expected {wanted}, got {text!r}")
        return value

    return parse


def add_method_flags(sp: argparse.ArgumentParser) -> list[KnobFlag]:
    """Add every :func:`method_flags` flag to ``sp`` (default ``None``: not given)."""
    flags = method_flags()
    for flag in flags:
        if flag.kinds == (bool,):
            sp.add_argument(flag.option, dest=flag.name, default=None,
                            action=argparse.BooleanOptionalAction, help=flag.help())
        else:
            one = len(flag.kinds) == 1
            sp.add_argument(flag.option, dest=flag.name, default=None, help=flag.help(),
                            type=flag.kinds[0] if one else _value_of(flag.kinds),
                            metavar=METAVARS[flag.kinds[0]] if one else "VALUE")
    sp.set_defaults(method_flags=[f.name for f in flags])
    return flags


def flag_knobs(args, knobs: dict) -> dict:
    """``knobs`` (from ``--knob``) with the method flags given on the command line; a knob
    given both ways is refused."""
    knobs = dict(knobs)
    for name in args.method_flags:
        value = getattr(args, name)
        if value is None:
            continue
        if name in knobs:
            flag = "--" + name.replace("_", "-")
            raise ValueError(f"--knob {name}: also given as {flag}; give it once")
        knobs[name] = value
    return knobs
