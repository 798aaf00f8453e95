"""What every method shares: device-side sample buffers, the pass/pipeline protocol, the
method registry and the one entry point :func:`reconstruct`.

A *pass* builds its program once in its constructor and its ``__call__(queue, ...,
wait_for=None)`` only sets arguments and enqueues, returning a ``cl.Event``. A *pipeline* (a
method) is an ordered list of passes with temporaries allocated once per frame shape; it
takes device buffers on the caller's queue and returns the last event, so it embeds in a
foreign OpenCL pipeline. :func:`reconstruct` is the convenience path from a host
:class:`~clrecon.core.samples.SampleBuffer` to an image.
"""
from __future__ import annotations

import inspect
import os
import threading
import time
from dataclasses import dataclass, field
from typing import Callable, ClassVar

import numpy as np
import pyopencl as cl

from clrecon.core.device import Device, DeviceSpec, event_ms, get_device
from clrecon.core.errors import DeviceMemoryError
from clrecon.core.plan import BOX_PLAN, Plan, covering
from clrecon.core.samples import FIELDS, FrameInfo, SampleBuffer


@dataclass(frozen=True)
class LocalSize:
    """A pass's launch configuration: local size, or ``None`` for "runtime chooses".

    ``x`` and ``y`` are positive integers (``bool`` and ``float`` refused; NumPy integers
    are stored as ``int``), ``x`` may be ``None`` (then ``y`` is unused). Values beyond a
    device's limits are refused by :meth:`check` when a pass is built for that device.
    """

    x: int | None = 16
    y: int = 4

    def __post_init__(self):
        from clrecon.core.knobs import INT32_MAX, check_int

        if self.x is not None:
            object.__setattr__(self, "x", check_int("LocalSize.x", self.x, 1, INT32_MAX))
        object.__setattr__(self, "y", check_int("LocalSize.y", self.y, 1, INT32_MAX))

    def check(self, device: cl.Device, pass_name: str, kernel: cl.Kernel | None = None
              ) -> None:
        """Refuse, with a ``ValueError`` naming the pass, the size and the limit, a local size
        the device cannot launch: beyond its max work-item sizes, its max work-group size
        or (given the built ``kernel``) the kernel's own work-group limit."""
        if self.x is None:
            return
        x, y = self.x, self.y
        dev = device.name.strip()
        items = tuple(device.max_work_item_sizes)
        for axis, v, lim in (("x", x, items[0]), ("y", y, items[1] if len(items) > 1 else 1)):
            if v > lim:
                raise ValueError(f"{pass_name}: local size {x}x{y}: {axis} = {v} exceeds the "
                                 f"device's max work-item size {lim} in {axis} ({dev}; "
                                 f"max work-item sizes {list(items)})")
        limit, what = device.max_work_group_size, "the device's max work-group size"
        if kernel is not None:
            limit = min(limit, kernel.get_work_group_info(
                cl.kernel_work_group_info.WORK_GROUP_SIZE, device))
            what = "the max work-group size of the built kernel"
        if x * y > limit:
            raise ValueError(f"{pass_name}: local size {x}x{y} = {x * y} work-items exceeds "
                             f"{what}, {limit} ({dev})")

    def for_range(self, width: int, height: int) -> tuple[tuple[int, int], tuple | None]:
        """(global, local) for a 2D range covering ``width x height``."""
        if self.x is None:
            return (width, height), None
        gx = -(-width // self.x) * self.x
        gy = -(-height // self.y) * self.y
        return (gx, gy), (self.x, self.y)


@dataclass(eq=False)
class DeviceSamples:
    """A frame's sample fields as OpenCL buffers (the structure-of-arrays layout of
    :mod:`clrecon.core.samples`: float32, row-major, sample ``(y, x, i)``).

    ``buffers`` holds the fields a plan reads (any subset of :data:`~clrecon.core.samples.FIELDS`);
    each is checked to be large enough for ``height * width * spp`` samples. ``coc`` is the
    thin-lens model ``(C0, C1)`` and must be given: a frame without defocus says ``(0, 0)``.
    ``info`` is the frame's description; when it is ``None`` the executor computes it (and
    validates the samples) with one reduction pass on the device, :mod:`clrecon.core.inspect`, the
    first time a pipeline needs it. A caller who sets ``info`` vouches for it: every bound a
    plan checks is read from it.
    """

    height: int
    width: int
    spp: int
    buffers: dict[str, cl.Buffer]
    coc: tuple[float, float]
    info: FrameInfo | None = None

    def __post_init__(self):
        for name in ("height", "width", "spp"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise ValueError(f"samples: {name} must be a positive integer, got {v!r}")
        try:
            c0, c1 = (float(c) for c in self.coc)
        except (TypeError, ValueError):
            raise ValueError(f"samples: coc must be (C0, C1), got {self.coc!r}") from None
        if not (np.isfinite(c0) and np.isfinite(c1)):
            raise ValueError(f"samples: coc coefficients must be finite, got {self.coc!r}")
        self.coc = (c0, c1)
        n = self.height * self.width * self.spp
        for name, b in self.buffers.items():
            if name not in FIELDS:
                raise ValueError(f"samples: unknown field {name!r}; fields are {list(FIELDS)}")
            need = n * int(np.prod(FIELDS[name], dtype=np.int64)) * 4
            if not isinstance(b, cl.MemoryObjectHolder) or b.size < need:
                size = getattr(b, "size", type(b).__name__)
                raise ValueError(f"samples: field {name!r} needs a buffer of at least {need} "
                                 f"bytes (float32, {self.width}x{self.height}x{self.spp}), "
                                 f"got {size}")
        if self.info is not None and (self.info.width, self.info.height, self.info.spp) != (
                self.width, self.height, self.spp):
            raise ValueError(f"samples: info describes a {self.info.width}x{self.info.height}"
                             f"x{self.info.spp} frame, the buffers a {self.width}x{self.height}"
                             f"x{self.spp} one")

    @classmethod
    def upload(cls, queue: cl.CommandQueue, buf: SampleBuffer, fields=None,
               info: FrameInfo | None = None, into: DeviceSamples | None = None
               ) -> DeviceSamples:
        """Copy ``fields`` (default: all) of a host buffer to the device.

        ``info`` (e.g. ``buf.inspect()``) is attached as given; without it the executor
        inspects on the device. ``into`` reuses the buffers of an earlier upload of the same
        shape and fields (a sequence of frames allocates once).
        """
        fields = tuple(fields or FIELDS)
        buf.check_layout(fields)
        reuse = into is not None and into.shape == buf.shape and set(fields) <= set(
            into.buffers)
        bufs = {}
        for name in fields:
            host = getattr(buf, name)
            d = into.buffers[name] if reuse else cl.Buffer(
                queue.context, cl.mem_flags.READ_ONLY, size=max(host.nbytes, 4))
            cl.enqueue_copy(queue, d, host, is_blocking=False)
            bufs[name] = d
        queue.finish()  # host arrays may be freed by the caller after this returns
        return cls(buf.height, buf.width, buf.spp, bufs,
                   (buf.coc_model.c0, buf.coc_model.c1), info)

    @property
    def shape(self) -> tuple[int, int, int]:
        return (self.height, self.width, self.spp)

    def __getitem__(self, name: str) -> cl.Buffer:
        try:
            return self.buffers[name]
        except KeyError:
            have = sorted(self.buffers)
            raise KeyError(f"field {name!r} was not uploaded (have {have})") from None

    def inspect(self, queue: cl.CommandQueue, validate: bool = True, wait_for=None,
                allow_negative: bool = False) -> FrameInfo:
        """Validate and describe the samples with one pass on the device; sets ``info``.

        ``allow_negative`` accepts negative colours (as ``SampleBuffer.validate``); a
        pipeline called without ``info`` validates with the default, so a frame with
        negative radiance is inspected here first."""
        from clrecon.core.inspect import inspect_device

        self.info = inspect_device(queue, self.buffers, self.height, self.width, self.spp,
                                   self.coc, validate=validate, wait_for=wait_for,
                                   allow_negative=allow_negative)
        return self.info


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


class Pipeline:
    """The one executor: runs the :class:`~clrecon.core.plan.Plan` a method builds.

    A method subclasses it, sets ``name``, builds its passes in ``__init__(context, info,
    <knob>=<default>, ...)`` and ends with :meth:`set_plan`. ``__call__`` checks the frame
    against the plan's bounds, binds temporaries and enqueues the steps on the caller's
    queue; it never blocks, except to inspect a frame that comes without ``info``.
    """

    name: ClassVar[str] = ""
    fields: tuple[str, ...] = tuple(FIELDS)

    def __init__(self, context: cl.Context, info: FrameInfo):
        self.context = context
        self.info = info
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

    def _own_buffer(self, name: str) -> cl.Buffer:
        if name not in self._own:
            self._own[name] = cl.Buffer(self.context, cl.mem_flags.READ_WRITE,
                                        max(int(self.plan.temporaries[name]), 4))
        return self._own[name]

    def describe(self) -> dict:
        """Mode and knobs that ran (reported by ``--json``)."""
        return {"method": self.name}

    # -- running ---------------------------------------------------------------------------
    def check(self, info: FrameInfo) -> list[str]:
        """Why the plan does not hold for a frame described by ``info`` (empty: it holds)."""
        return self.plan.violations(info)

    def __call__(self, queue, samples: DeviceSamples, out, wait_for=None,
                 temporaries: dict[str, cl.Buffer] | None = None) -> cl.Event:
        """Reconstruct ``samples`` into ``out`` (float32 (H, W, 3)); return the last event.

        A frame outside the plan's bounds raises ``ValueError`` naming the bound and both
        values; a pipeline made with ``grow=True`` re-plans instead (covering both frames).
        ``temporaries`` replaces the pipeline's own buffers by name (checked for size).
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
        info = self._frame_info(queue, samples, wait_for)
        bad = self.check(info)
        if bad:
            if not getattr(self, "grow", False):
                raise ValueError(f"{self.name} pipeline: " + "; ".join(bad) +
                                 ". Build a pipeline for this frame, or make it with "
                                 "grow=True to re-plan.")
            self.regrow(covering(self.info, info))
            self._check_fields(samples)  # the new plan may read more (motion, say)
        bufs = dict(samples.buffers)
        bufs["out"] = out
        bufs.update(self._bind(temporaries or {}))
        frame = _Frame(samples, info, bufs)
        self.events = []
        wait = wait_for
        for step in self.plan.steps:
            evs = step.run(queue, frame, wait)
            self.events.extend(evs)
            wait = [ev for _, ev in evs]
        return self.events[-1][1]

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

    def _bind(self, given: dict[str, cl.Buffer]) -> dict[str, cl.Buffer]:
        temps = self.plan.temporaries
        unknown = sorted(set(given) - set(temps))
        if unknown:
            raise ValueError(f"temporaries: the {self.name} plan has no {unknown}; it takes "
                             f"{sorted(temps)}")
        for name, b in given.items():
            if not isinstance(b, cl.MemoryObjectHolder) or b.size < temps[name]:
                raise ValueError(f"temporaries: {name!r} needs {temps[name]} bytes, got "
                                 f"{getattr(b, 'size', type(b).__name__)}")
        return {name: self._own_buffer(name) for name in temps if name not in given} | given

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


def make_pipeline(method: str, context: cl.Context, info: FrameInfo, grow: bool = False,
                  safeguard: bool | None = None, estimate_error: bool = False,
                  **knobs) -> Pipeline:
    """Plan ``method`` for frames like ``info`` on ``context``.

    ``info`` may describe a family rather than one frame: a renderer that knows its largest
    CoC and motion plans once for them (``dataclasses.replace(info, max_abs_coc=...)``).
    ``grow=True`` re-plans (kernels come from the build cache) when a frame falls outside the
    bounds instead of refusing it. Unknown knobs raise ``TypeError``.

    ``safeguard`` (default: on for every method but ``box`` at 2 spp or more) blends the
    method's image toward box wherever its estimated bias dominates
    (:mod:`clrecon.methods.safeguard`);
    ``safeguard=False`` is the papers' method alone. ``estimate_error=True`` also computes the
    per-pixel squared-error estimate, the temporary ``"error"`` (needs 2 spp or more).
    """
    from clrecon.core.knobs import check_bool

    safeguard = check_bool("safeguard", safeguard, none_ok=True)
    estimate_error = check_bool("estimate_error", estimate_error)
    inner = _make_one(method, context, info, **knobs)
    if safeguard is None:
        safeguard = method != "box" and info.spp >= 2
    if safeguard and method == "box":
        raise ValueError("safeguard: box is the unbiased estimate the safeguard blends "
                         "toward; it has nothing to safeguard")
    if safeguard and info.spp < 2:
        raise ValueError(f"safeguard: needs >= 2 samples per pixel (two independent halves), "
                         f"the frame has {info.spp}; pass safeguard=False")
    if estimate_error and info.spp < 2:
        raise ValueError(f"estimate_error: needs >= 2 samples per pixel (two independent "
                         f"halves), the frame has {info.spp}")
    # a frame without blur is planned as box, with nothing to blend: the method's own
    # pipeline, unless it may grow into a blurred frame (the wrapper re-plans both)
    if estimate_error or (safeguard and (grow or inner.plan.name != BOX_PLAN)):
        from clrecon.methods.safeguard import Safeguarded

        pipe = Safeguarded(context, info, method, knobs, blend=bool(safeguard), full=inner)
    else:
        pipe = inner
    pipe.grow, pipe.knobs = bool(grow), dict(knobs)
    return pipe


#: knobs every method takes through :func:`make_pipeline` (beside its class's own)
PIPELINE_KNOBS = ("safeguard", "estimate_error")


def method_knobs(method: str) -> set[str]:
    """The knob names ``method`` takes (its class's and :data:`PIPELINE_KNOBS`)."""
    _load_methods()
    cls = METHODS[method]
    return (set(inspect.signature(cls.__init__).parameters) - {"self", "context", "info"}
            | set(PIPELINE_KNOBS))


def _make_one(method: str, context: cl.Context, info: FrameInfo, **knobs) -> Pipeline:
    """One method's own pipeline (no safeguard)."""
    _load_methods()
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


def _load_methods() -> None:
    from clrecon.methods import box, layered, splat, sweep  # noqa: F401  (they register themselves)


@dataclass
class Reconstruction:
    """An image with what produced it and how long each part took.

    ``pass_ms`` are device times of the plan's passes; ``upload_ms`` the host-to-device copy
    (wall); ``inspect_ms`` the device validation and inspection (wall: it reads a few bytes
    back); ``plan_ms`` planning (wall, 0 when the cached plan held; a first call of a process
    also compiles here); ``total_ms`` the wall time of the whole call.
    """

    image: np.ndarray
    method: dict
    device: str
    pass_ms: dict[str, float] = field(default_factory=dict)
    upload_ms: float = 0.0
    total_ms: float = 0.0
    inspect_ms: float = 0.0
    plan_ms: float = 0.0
    #: with ``estimate_error=True``: (H, W) float32 estimated squared error of ``image``
    error: np.ndarray | None = None

    @property
    def device_ms(self) -> float:
        return float(sum(self.pass_ms.values()))


@dataclass(eq=False)
class _Session:
    """What :func:`run` keeps between frames of one method on one device."""

    pipe: Pipeline
    samples: DeviceSamples
    out: cl.Buffer


#: (context, method, knobs) -> session, most recent last; at most _MAX_SESSIONS
_sessions: dict[tuple, _Session] = {}
_MAX_SESSIONS = 4
_sessions_lock = threading.Lock()


def clear_sessions() -> None:
    """Release the device buffers :func:`run` keeps for the next frame."""
    _sessions.clear()


def _knob_key(knobs: dict) -> tuple:
    try:
        key = tuple(sorted(knobs.items()))
        hash(key)
        return key
    except TypeError:  # an unhashable knob value: no reuse, still correct
        return (object(),)


def run(buf: SampleBuffer, method: str = "box", device: DeviceSpec | Device = None,
        allow_negative: bool = False, estimate_error: bool = False,
        **knobs) -> Reconstruction:
    """Upload, validate and inspect on the device, plan, reconstruct and read back.

    Frame after frame of one method and device, the device buffers are reused and the plan
    too while the frame's description is unchanged; any other frame is planned afresh
    (kernels come from the build cache), so the image is always that of a plan made for this
    frame. Invalid samples raise the ``ValueError`` of
    :meth:`SampleBuffer.validate(allow_negative) <SampleBuffer.validate>`.

    With ``allow_negative`` negative radiance is accepted and every method gives the linear
    combination ``f(c+) - f(c-)`` of its images of the positive and negative parts: box,
    sweep and layered are linear in the colour (one run); a pipeline whose class sets
    ``color_linear = False`` (splat: its composite clamps each layer's colour at 0 against
    the integration's ringing) runs twice on a frame with negative colours, once per part,
    and the image is the difference (``pass_ms`` sums both runs).

    ``estimate_error=True`` also returns ``error``: the (H, W) float32 estimate of the
    squared error of ``image`` (linear radiance, mean over RGB) from independent halves of
    the samples (:mod:`clrecon.methods.safeguard`), for every method, box included.
    """
    from clrecon.core.knobs import check_bool

    estimate_error = check_bool("estimate_error", estimate_error)
    if not isinstance(buf, SampleBuffer):
        raise TypeError(f"buf must be a SampleBuffer, got {type(buf).__name__}")
    buf.check_layout()
    dev = get_device(device)
    t0 = time.perf_counter()
    # tuning overrides from the environment decide launch configurations too
    tune_env = tuple(sorted((k, v) for k, v in os.environ.items()
                            if k.startswith("CLRECON_TUNE_")))
    key = (dev.context.int_ptr, method, _knob_key(knobs), estimate_error, tune_env)
    with _sessions_lock:  # batch runs one thread per device
        sess = _sessions.pop(key, None)
    samples = DeviceSamples.upload(dev.queue, buf, FIELDS,
                                   into=None if sess is None else sess.samples)
    t1 = time.perf_counter()
    info = samples.inspect(dev.queue, allow_negative=allow_negative)
    t2 = time.perf_counter()
    if sess is not None and sess.pipe.info == info:
        pipe, plan_ms = sess.pipe, 0.0
    else:
        pipe = make_pipeline(method, dev.context, info, estimate_error=estimate_error, **knobs)
        plan_ms = (time.perf_counter() - t2) * 1e3
    nbytes = buf.height * buf.width * 12
    out = sess.out if sess is not None and sess.out.size == nbytes else cl.Buffer(
        dev.context, cl.mem_flags.READ_WRITE, size=nbytes)
    split = (allow_negative and not getattr(pipe, "color_linear", True)
             and bool(buf.color.min() < 0))
    if split:  # the positive part first, then the negative one into the same buffer
        cl.enqueue_copy(dev.queue, samples["color"], np.maximum(buf.color, 0),
                        is_blocking=True)
    ev = pipe(dev.queue, samples, out)
    image = np.empty((buf.height, buf.width, 3), np.float32)
    cl.enqueue_copy(dev.queue, image, out, wait_for=[ev])
    error = _read_error(dev.queue, pipe, image.shape[:2]) if estimate_error else None
    pass_ms = pipe.pass_times_ms()
    if split:
        cl.enqueue_copy(dev.queue, samples["color"], np.maximum(-buf.color, 0),
                        is_blocking=True)
        ev = pipe(dev.queue, samples, out)
        negative = np.empty_like(image)
        cl.enqueue_copy(dev.queue, negative, out, wait_for=[ev])
        image -= negative
        if error is not None:  # the parts' errors add (independent estimates)
            error += _read_error(dev.queue, pipe, image.shape[:2])
        for name, ms in pipe.pass_times_ms().items():
            pass_ms[name] = pass_ms.get(name, 0.0) + ms
    t3 = time.perf_counter()
    with _sessions_lock:
        _sessions[key] = _Session(pipe, samples, out)
        while len(_sessions) > _MAX_SESSIONS:
            _sessions.pop(next(iter(_sessions)))
    return Reconstruction(
        image=image,
        method=pipe.describe(),
        device=dev.info.label,
        pass_ms=pass_ms,
        upload_ms=(t1 - t0) * 1e3,
        total_ms=(t3 - t0) * 1e3,
        inspect_ms=(t2 - t1) * 1e3,
        plan_ms=plan_ms,
        error=error,
    )


def _read_error(queue, pipe: Pipeline, shape) -> np.ndarray:
    err = np.empty(shape, np.float32)
    cl.enqueue_copy(queue, err, pipe.buffers["error"])
    return err


def reconstruct(buf: SampleBuffer, method: str = "box", device: DeviceSpec | Device = None,
                allow_negative: bool = False, **knobs) -> np.ndarray:
    """Reconstruct a frame: the (H, W, 3) float32 linear image.

    Parameters
    ----------
    buf : SampleBuffer
        The frame's samples (validated here).
    method : str
        ``"box"`` (more as methods land: see ``clrecon.core.pipeline.METHODS``).
    device : int, str, Device or None
        See :func:`clrecon.core.device.get_device`.
    allow_negative : bool
        Accept negative colours (validation refuses them by default); every method then
        gives ``f(c+) - f(c-)``, linear in the colour (see :func:`run`).
    **knobs
        Method-specific settings; unknown names raise ``TypeError``.
    """
    return run(buf, method, device, allow_negative, **knobs).image
