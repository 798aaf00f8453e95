"""A method's plan as data: ordered steps, named temporaries, and the bounds it is valid for.

A method decides once, from one description of the frame (:class:`~clrecon.core.samples.FrameInfo`)
and its knobs, what will run: which passes in which order (:class:`Step`), which temporaries
they need and how large (``Plan.temporaries``, bytes by name), and which facts about the frame
those decisions rest on (:class:`Bound`). The one executor, :class:`clrecon.core.pipeline.Pipeline`,
runs every method's plan, checks every frame against the bounds before it enqueues anything,
and binds temporaries (the pipeline's own, or the caller's, checked for size).

A bound says what a plan was *specialised* on, so that a frame outside it would make a kernel
trust something false: the spp a kernel was compiled for, the guard band or splat reach sized
from the largest blur, a motion term compiled out of a static frame, the box plan chosen
because every blur stays inside the pixel. Facts that only set a kernel argument (the depth
range of layered's buckets, splat's layer placement) are not bounds: the steps read them from
each frame's own description.
"""
from __future__ import annotations

import math
import operator
from dataclasses import dataclass, field, replace
from typing import Callable

from clrecon.core.samples import FrameInfo

_OPS = {"==": operator.eq, "<=": operator.le, "<": operator.lt}

#: tolerance of the inequality bounds (relative, and absolute in pixels)
REL_TOL, ABS_TOL = 1e-5, 1e-6

#: the one name of the plan that is the per-pixel average, whatever the method
BOX_PLAN = "box"


@dataclass(frozen=True)
class Bound:
    """``quantity(frame) <op> limit``, with what the plan specialised on it for.

    ``quantity`` defaults to the :class:`FrameInfo` attribute ``name``; a derived quantity
    (layered's blur sigma) passes a function and the frame fields it needs.
    """

    name: str
    op: str
    limit: float
    why: str
    quantity: Callable[[FrameInfo], float] | None = field(default=None, compare=False)
    #: sample fields the quantity is computed from (what a device inspection must see)
    needs: tuple[str, ...] = ()

    def __post_init__(self):
        if self.op not in _OPS:
            raise ValueError(f"bound {self.name}: op must be one of {sorted(_OPS)}")

    def value(self, info: FrameInfo) -> float:
        return self.quantity(info) if self.quantity is not None else getattr(info, self.name)

    def holds(self, info: FrameInfo) -> bool:
        v, limit = self.value(info), self.limit
        if self.op != "==" and math.isfinite(limit):
            # the device computes |coc| and |motion| in float32, the host in float64: a few
            # ulps apart. Every size derived from a bound has at least a pixel of slack.
            limit += REL_TOL * abs(limit) + ABS_TOL
        return bool(_OPS[self.op](v, limit))

    def message(self, info: FrameInfo) -> str:
        return (f"frame {self.name} = {_fmt(self.value(info))} is outside the plan's bound "
                f"{self.name} {self.op} {_fmt(self.limit)} ({self.why})")

    def describe(self) -> str:
        return f"{self.name} {self.op} {_fmt(self.limit)}"


def _fmt(v) -> str:
    return f"{v:.6g}" if isinstance(v, float) else str(v)


@dataclass(frozen=True)
class Step:
    """One pass of a plan. ``run(queue, frame, wait_for)`` enqueues it and returns its
    ``(pass name, event)`` pairs (a multi-kernel pass returns several); the next step waits on
    all of them. ``inputs`` and ``outputs`` name sample fields, temporaries or ``"out"``."""

    name: str
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    run: Callable = field(compare=False, repr=False)


@dataclass(frozen=True)
class Plan:
    """What a method will do for frames within ``bounds``."""

    method: str
    name: str  # BOX_PLAN, or the method's own name for its variant
    fields: tuple[str, ...]  # sample fields the steps read
    steps: tuple[Step, ...]
    temporaries: dict[str, int] = field(default_factory=dict)  # bytes by name
    bounds: tuple[Bound, ...] = ()

    def __post_init__(self):
        known = set(self.fields) | set(self.temporaries) | {"out"}
        for s in self.steps:
            for name in s.inputs + s.outputs:
                if name not in known:
                    raise ValueError(f"plan {self.method}/{self.name}: step {s.name} names "
                                     f"{name!r}, which is neither a field nor a temporary")

    @property
    def inspect_fields(self) -> tuple[str, ...]:
        """Sample fields a device inspection needs to check this plan's bounds."""
        return tuple(sorted({f for b in self.bounds for f in b.needs}))

    def violations(self, info: FrameInfo) -> list[str]:
        return [b.message(info) for b in self.bounds if not b.holds(info)]

    def describe(self) -> dict:
        return {"plan": self.name, "steps": [s.name for s in self.steps],
                "temporaries": dict(self.temporaries),
                "bounds": [b.describe() for b in self.bounds]}


# -- the bounds every method shares --------------------------------------------------------
def shape_bounds(info: FrameInfo, spp_why: str | None = None) -> tuple[Bound, ...]:
    """Width and height (temporaries are sized from them), and spp when a kernel is compiled
    for it (``spp_why`` says which)."""
    out = (Bound("width", "==", info.width, "temporaries and launch sizes"),
           Bound("height", "==", info.height, "temporaries and launch sizes"))
    if spp_why:
        out += (Bound("spp", "==", info.spp, spp_why),)
    return out


def unique_bounds(bounds) -> tuple[Bound, ...]:
    """``bounds`` in order, each (name, op, limit) once."""
    seen, out = set(), []
    for b in bounds:
        key = (b.name, b.op, b.limit)
        if key not in seen:
            seen.add(key)
            out.append(b)
    return tuple(out)


def coc_bound(limit: float, why: str, op: str = "<=") -> Bound:
    return Bound("max_abs_coc", op, float(limit), why, needs=("depth",))


def motion_bound(limit: float, why: str, op: str = "<=") -> Bound:
    return Bound("max_abs_motion", op, float(limit), why, needs=("motion",))


def covering(plan_info: FrameInfo, frame: FrameInfo) -> FrameInfo:
    """A description covering both ``plan_info`` and ``frame`` (``grow=True``): the frame's
    shape and spp, the larger blur, the wider depth range. Planning from it keeps a pipeline
    that is fed frames of varying blur from rebuilding on every frame."""
    if (plan_info.width, plan_info.height, plan_info.spp) != (frame.width, frame.height,
                                                               frame.spp):
        return frame
    lo = min(plan_info.min_depth, frame.min_depth)
    hi = frame.max_depth if not math.isfinite(plan_info.max_depth) else (
        plan_info.max_depth if not math.isfinite(frame.max_depth)
        else max(plan_info.max_depth, frame.max_depth))
    return replace(frame, max_abs_coc=max(plan_info.max_abs_coc, frame.max_abs_coc),
                   max_abs_motion=max(plan_info.max_abs_motion, frame.max_abs_motion),
                   min_depth=lo, max_depth=hi)
