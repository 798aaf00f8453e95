"""What every method shares: the pass/pipeline protocol and the method registry (the
device-side sample buffers, :class:`DeviceSamples`, are in :mod:`clrecon.core.device_samples`;
the entry points :func:`~clrecon.api.make_pipeline`, :func:`~clrecon.api.run` and
:func:`~clrecon.api.reconstruct` are in :mod:`clrecon.api`).

A *pass* builds its program once in its constructor and its ``__call__(queue, ...,
wait_for=None)`` only sets arguments and enqueues, returning a ``cl.Event``. A *pipeline* (a
method) is an ordered list of passes with temporaries allocated once per frame shape; it
takes device buffers on the caller's queue and returns the last event, so it embeds in a
foreign OpenCL pipeline. :func:`reconstruct` is the convenience path from a host
:class:`~clrecon.core.samples.SampleBuffer` to an image.
"""
from __future__ import annotations

import contextlib
import inspect
import os
import threading
from dataclasses import dataclass
from typing import Callable, ClassVar

import numpy as np
import pyopencl as cl

from clrecon.core.device import event_ms
from clrecon.core.device_samples import DeviceSamples as DeviceSamples
from clrecon.core.errors import DeviceMemoryError
from clrecon.core.plan import Plan, covering
from clrecon.core.samples import FIELDS, FrameInfo


@dataclass
class _Frame:
    """What a step sees of the frame it runs on."""

    samples: DeviceSamples
    info: FrameInfo
    buffers: dict[str, cl.Buffer]

    @property
    def width(self) -> int:
        return self.samples.width

    @property
    def height(self) -> int:
        return self.samples.height

    @property
    def spp(self) -> int:
        return self.samples.spp


_reuse = threading.local()


@contextlib.contextmanager
def reusing(buffers):
    """Within the block, a pipeline allocating one of its own temporaries takes a buffer of
    the same context and size from ``buffers`` (released by a pipeline done with them:
    :meth:`Pipeline.release_buffers`) before it allocates a new one. A re-planned frame then
    skips the first touch of hundreds of MB of fresh device memory (on a CPU device, page
    faults). A temporary's content is undefined either way: a pass that needs zeros clears
    its buffer (as OpenCL's fresh buffers hold no defined value either). Per thread."""
    free: dict[tuple[int, int], list[cl.Buffer]] = {}
    for b in buffers:
        free.setdefault((b.context.int_ptr, b.size), []).append(b)
    prev = getattr(_reuse, "free", None)
    _reuse.free = free
    try:
        yield
    finally:
        _reuse.free = prev


class Pipeline:
    """The one executor: runs the :class:`~clrecon.core.plan.Plan` a method builds.

    A method subclasses it, sets ``name``, builds its passes in ``__init__(context, info,
    <knob>=<default>, ...)`` and ends with :meth:`set_plan`. ``__call__`` checks the frame
    against the plan's bounds, binds temporaries and enqueues the steps on the caller's
    queue; it never blocks, except to inspect a frame that comes without ``info``.
    """

    name: ClassVar[str] = ""
    fields: tuple[str, ...] = tuple(FIELDS)
    #: the method's weights do not depend on the sample count (given the outputs of its
    #: ``shared_steps``), so the mean of its images of a frame's two halves has its image's
    #: bias and variance: the safeguard blends that mean and skips the rest of the method's
    #: run on the frame (:mod:`clrecon.methods.safeguard`)
    halves_mean: ClassVar[bool] = False
    #: steps the safeguard runs on the frame alone, whose outputs the halves' runs take
    #: (layered's depth statistics and partitions: both halves then filter the same layers)
    shared_steps: ClassVar[tuple[str, ...]] = ()
    #: every pass of the plan reads its samples through ``DeviceSamples.strided``, so a view
    #: of a frame (``DeviceSamples.view``: one half, in place) runs as a frame of its own; the
    #: safeguard then reads the halves without copying them (set by the method per plan)
    sample_views: bool = False

    def __init__(self, context: cl.Context, info: FrameInfo):
        self.context = context
        self.info = info
        self.sample_views = False  # each plan (regrow re-runs __init__) says so anew
        self.events: list[tuple[str, cl.Event]] = []
        self.plan: Plan | None = None
        self._own: dict[str, cl.Buffer] = {}

    # -- building --------------------------------------------------------------------------
    def set_plan(self, plan: Plan) -> None:
        check_memory(self.context.devices[0], plan, self.info)
        self.plan = plan
        # what a caller uploads: what the passes read, and what checking the bounds on the
        # device needs (the inspection pass always reads depth)
        need = set(plan.fields) | set(plan.inspect_fields)
        if plan.inspect_fields:
            need.add("depth")
        self.fields = tuple(f for f in FIELDS if f in need)
        self._own = {}

    @property
    def buffers(self) -> dict[str, cl.Buffer]:
        """The pipeline's own temporaries (allocated on first use)."""
        return {name: self._own_buffer(name) for name in self.plan.temporaries}

    def buffer(self, name: str) -> cl.Buffer:
        """One of the pipeline's own temporaries (allocated on first use)."""
        if name not in self.plan.temporaries:
            raise KeyError(f"the {self.name} plan has no temporary {name!r}; it has "
                           f"{sorted(self.plan.temporaries)}")
        return self._own_buffer(name)

    def _own_buffer(self, name: str) -> cl.Buffer:
        if name not in self._own:
            size = max(int(self.plan.temporaries[name]), 4)
            free = getattr(_reuse, "free", None) or {}
            spare = free.get((self.context.int_ptr, size))
            self._own[name] = spare.pop() if spare else cl.Buffer(
                self.context, cl.mem_flags.READ_WRITE, size)
        return self._own[name]

    def pipelines(self) -> list[Pipeline]:
        """This pipeline and every pipeline it holds (the safeguard's frame and halves), each
        once."""
        out, seen, todo = [], set(), [self]
        while todo:
            p = todo.pop()
            if id(p) not in seen:
                seen.add(id(p))
                out.append(p)
                todo.extend(v for v in vars(p).values() if isinstance(v, Pipeline))
        return out

    def release_buffers(self) -> list[cl.Buffer]:
        """Give up this pipeline's own temporaries and those of the pipelines it holds (a
        later call allocates afresh): what :func:`reusing` hands to a successor."""
        out = []
        for p in self.pipelines():
            out.extend(p._own.values())
            p._own = {}
        return out

    def describe(self) -> dict:
        """Mode and knobs that ran (reported by ``--json``)."""
        return {"method": self.name}

    # -- running ---------------------------------------------------------------------------
    def check(self, info: FrameInfo) -> list[str]:
        """Why the plan does not hold for a frame described by ``info`` (empty: it holds)."""
        return self.plan.violations(info)

    def __call__(self, queue, samples: DeviceSamples, out, wait_for=None,
                 temporaries: dict[str, cl.Buffer] | None = None,
                 steps: tuple[str, ...] | None = None) -> cl.Event:
        """Reconstruct ``samples`` into ``out`` (float32 (H, W, 3)); return the last event.

        A frame outside the plan's bounds raises ``ValueError`` naming the bound and both
        values; a pipeline made with ``grow=True`` re-plans instead (covering both frames).
        ``temporaries`` replaces the pipeline's own buffers by name (checked for size).
        ``steps`` runs only the plan's steps of those names, in plan order: what a skipped
        step would have written must already be in its buffers (``temporaries``).
        """
        if not isinstance(samples, DeviceSamples):
            raise TypeError(f"samples must be DeviceSamples, got {type(samples).__name__}")
        if not isinstance(out, cl.MemoryObjectHolder):
            raise TypeError(f"out must be a cl.Buffer, got {type(out).__name__}")
        if out.size < samples.height * samples.width * 3 * 4:
            raise ValueError(f"out: buffer of {out.size} bytes is too small for the "
                             f"{samples.width}x{samples.height} image "
                             f"({samples.height * samples.width * 12} bytes)")
        self._check_fields(samples)
        if samples.is_view and not self.sample_views:
            raise ValueError(f"samples: the {self.name} pipeline ({self.plan.name}) reads whole "
                             f"frames, not a view (samples {samples.offset}.."
                             f"{samples.offset + samples.spp - 1} of {samples.stride} per "
                             f"pixel)")
        info = self._frame_info(queue, samples, wait_for)
        bad = self.check(info)
        if bad:
            if not getattr(self, "grow", False):
                raise ValueError(f"{self.name} pipeline: " + "; ".join(bad) +
                                 ". Build a pipeline for this frame, or make it with "
                                 "grow=True to re-plan.")
            self.regrow(covering(self.info, info))
            self._check_fields(samples)  # the new plan may read more (motion, say)
        run = self._steps(steps)
        bufs = dict(samples.buffers)
        bufs["out"] = out
        # a selection of steps allocates only the temporaries those steps name
        used = None if steps is None else {n for st in run for n in st.inputs + st.outputs}
        bufs.update(self._bind(temporaries or {}, used))
        frame = _Frame(samples, info, bufs)
        self.events = []
        wait = wait_for
        for step in run:
            evs = step.run(queue, frame, wait)
            self.events.extend(evs)
            wait = [ev for _, ev in evs]
        return self.events[-1][1]

    def _steps(self, names: tuple[str, ...] | None) -> tuple:
        if names is None:
            return self.plan.steps
        have = [s.name for s in self.plan.steps]
        unknown = sorted(set(names) - set(have))
        if unknown or not names:
            raise ValueError(f"steps: the {self.name} plan has no {unknown or 'empty'} "
                             f"selection; its steps are {have}")
        return tuple(s for s in self.plan.steps if s.name in set(names))

    def _check_fields(self, samples: DeviceSamples) -> None:
        missing = [f for f in self.plan.fields if f not in samples.buffers]
        if missing:
            raise ValueError(f"samples: the {self.name} plan reads {list(self.plan.fields)}; "
                             f"missing {missing}")

    def _frame_info(self, queue, samples: DeviceSamples, wait_for) -> FrameInfo:
        if samples.info is not None:
            return samples.info
        need = set(self.plan.inspect_fields) | {"depth"}
        if not need <= set(samples.buffers):
            if not self.plan.bounds or all(not b.needs for b in self.plan.bounds):
                return _shape_info(samples)
            raise ValueError(f"samples: checking the {self.name} plan's bounds needs the "
                             f"fields {sorted(need)} on the device (have "
                             f"{sorted(samples.buffers)}), or samples.info")
        return samples.inspect(queue, wait_for=wait_for)

    def _bind(self, given: dict[str, cl.Buffer], used: set[str] | None = None
              ) -> dict[str, cl.Buffer]:
        temps = self.plan.temporaries
        unknown = sorted(set(given) - set(temps))
        if unknown:
            raise ValueError(f"temporaries: the {self.name} plan has no {unknown}; it takes "
                             f"{sorted(temps)}")
        for name, b in given.items():
            if not isinstance(b, cl.MemoryObjectHolder) or b.size < temps[name]:
                raise ValueError(f"temporaries: {name!r} needs {temps[name]} bytes, got "
                                 f"{getattr(b, 'size', type(b).__name__)}")
        return {name: self._own_buffer(name) for name in temps
                if name not in given and (used is None or name in used)} | given

    def regrow(self, info: FrameInfo) -> None:
        """Re-plan for ``info`` with the same knobs (kernels come from the build cache);
        ``grow`` and ``knobs`` (set by :func:`make_pipeline`) are instance attributes that
        ``__init__`` leaves alone."""
        self.__init__(self.context, info, **getattr(self, "knobs", {}))

    def pass_times_ms(self) -> dict[str, float]:
        """Per-pass device times of the last run (events must have completed; the queue
        must have been created with ``cl.command_queue_properties.PROFILING_ENABLE``)."""
        times: dict[str, float] = {}
        for name, ev in self.events:
            times[name] = times.get(name, 0.0) + event_ms(ev)
        return times


def _gib(n: float) -> str:
    return f"{n / 2**30:.2f} GiB"


def _address_space_left() -> float:
    """Bytes this process may still map under its address-space limit (inf: no limit)."""
    try:
        import resource

        soft = resource.getrlimit(resource.RLIMIT_AS)[0]
        if soft == resource.RLIM_INFINITY:
            return float("inf")
        with open("/proc/self/statm") as f:
            used = int(f.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
        return float(max(soft - used, 0))
    except (ImportError, OSError, ValueError):
        return float("inf")


def check_memory(dev: cl.Device, plan: Plan, info: FrameInfo) -> None:
    """Refuse a plan whose buffers cannot fit the device, before anything is allocated:
    each temporary against the largest allocation, the temporaries with the samples the plan
    reads and the image against the device's memory and, on a CPU device (whose buffers live
    in this process), against the address space the process may still map."""
    n = info.width * info.height * info.spp
    samples = sum(n * int(np.prod(FIELDS[f], dtype=np.int64)) * 4 for f in plan.fields)
    temps = sum(plan.temporaries.values())
    total = temps + samples + info.width * info.height * 12
    what = f"the {plan.method} plan for {info.width}x{info.height} at {info.spp} spp"
    for name, size in plan.temporaries.items():
        if size > dev.max_mem_alloc_size:
            raise DeviceMemoryError(
                f"{what}: temporary {name!r} needs {_gib(size)}, more than the device's "
                f"largest allocation ({_gib(dev.max_mem_alloc_size)}, {dev.name})")
    budget, where = float(dev.global_mem_size), f"the device's memory ({dev.name})"
    if dev.type & cl.device_type.CPU:
        left = _address_space_left()
        if left < budget:
            budget, where = left, "the address space this process may still map (ulimit -v)"
    if total > budget:
        raise DeviceMemoryError(
            f"{what} needs {_gib(total)} (temporaries {_gib(temps)}, samples {_gib(samples)}), "
            f"more than {where}: {_gib(budget)}")


def _shape_info(samples: DeviceSamples) -> FrameInfo:
    """A description with the frame's shape alone, for plans whose bounds need no more."""
    return FrameInfo(samples.width, samples.height, samples.spp, 0.0, 0.0, np.inf, np.inf, 0.0)


METHODS: dict[str, Callable[..., Pipeline]] = {}


def register(cls):
    """Class decorator adding a pipeline to :data:`METHODS` under ``cls.name``."""
    METHODS[cls.name] = cls
    return cls


def make_method(method: str, context: cl.Context, info: FrameInfo, **knobs) -> Pipeline:
    """One method's own pipeline (no safeguard), from the registry :data:`METHODS`
    (filled by importing :mod:`clrecon.methods`: ``import clrecon`` does)."""
    try:
        cls = METHODS[method]
    except KeyError:
        raise ValueError(f"method: unknown {method!r}; available: {sorted(METHODS)}") from None
    if not isinstance(info, FrameInfo):
        raise TypeError(f"info must be a FrameInfo (SampleBuffer.inspect() or "
                        f"DeviceSamples.inspect()), got {type(info).__name__}")
    accepted = set(inspect.signature(cls.__init__).parameters) - {"self", "context", "info"}
    unknown = sorted(set(knobs) - accepted)
    if unknown:
        raise TypeError(
            f"method {method!r} got unknown knobs: {unknown}; it takes {sorted(accepted)}"
        )
    pipe = cls(context, info, **knobs)
    pipe.grow, pipe.knobs = False, dict(knobs)
    return pipe
