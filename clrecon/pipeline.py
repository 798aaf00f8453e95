"""What every method shares: device-side sample buffers, the pass/pipeline protocol, the
method registry and the one entry point :func:`reconstruct`.

A *pass* builds its program once in its constructor and its ``__call__(queue, ...,
wait_for=None)`` only sets arguments and enqueues, returning a ``cl.Event``. A *pipeline* (a
method) is an ordered list of passes with temporaries allocated once per frame shape; it
takes device buffers on the caller's queue and returns the last event, so it embeds in a
foreign OpenCL pipeline. :func:`reconstruct` is the convenience path from a host
:class:`~clrecon.samples.SampleBuffer` to an image.
"""
from __future__ import annotations

import inspect
import time
from dataclasses import dataclass, field
from typing import Callable, ClassVar

import numpy as np
import pyopencl as cl

from .device import Device, DeviceSpec, event_ms, get_device
from .samples import FIELDS, FrameInfo, SampleBuffer


@dataclass(frozen=True)
class LocalSize:
    """A pass's launch configuration: local size, or ``None`` for "runtime chooses"."""

    x: int | None = 16
    y: int = 4

    def for_range(self, width: int, height: int) -> tuple[tuple[int, int], tuple | None]:
        """(global, local) for a 2D range covering ``width x height``."""
        if self.x is None:
            return (width, height), None
        gx = -(-width // self.x) * self.x
        gy = -(-height // self.y) * self.y
        return (gx, gy), (self.x, self.y)


@dataclass(eq=False)
class DeviceSamples:
    """A sample buffer's fields as OpenCL buffers (only the fields a method asked for)."""

    height: int
    width: int
    spp: int
    buffers: dict[str, cl.Buffer]
    coc: tuple[float, float] = (0.0, 0.0)

    @classmethod
    def upload(cls, queue: cl.CommandQueue, buf: SampleBuffer, fields=None) -> DeviceSamples:
        fields = tuple(fields or FIELDS)
        mf = cl.mem_flags
        bufs = {}
        for name in fields:
            host = getattr(buf, name)
            d = cl.Buffer(queue.context, mf.READ_ONLY, size=max(host.nbytes, 4))
            cl.enqueue_copy(queue, d, host, is_blocking=False)
            bufs[name] = d
        queue.finish()  # host arrays may be freed by the caller after this returns
        return cls(buf.height, buf.width, buf.spp, bufs,
                   (buf.coc_model.c0, buf.coc_model.c1))

    def __getitem__(self, name: str) -> cl.Buffer:
        try:
            return self.buffers[name]
        except KeyError:
            have = sorted(self.buffers)
            raise KeyError(f"field {name!r} was not uploaded (have {have})") from None


class Pipeline:
    """Base class of a method: an ordered plan of passes.

    Subclasses set ``name`` and ``fields`` (the sample fields they read), build their passes
    in ``__init__(context, info, <knob>=<default>, ...)`` and implement ``enqueue``.
    """

    name: ClassVar[str] = ""
    fields: ClassVar[tuple[str, ...]] = tuple(FIELDS)

    def __init__(self, context: cl.Context, info: FrameInfo):
        self.context = context
        self.info = info
        self.events: list[tuple[str, cl.Event]] = []

    def describe(self) -> dict:
        """Mode and knobs that ran (reported by ``--json``)."""
        return {"method": self.name}

    def enqueue(self, queue: cl.CommandQueue, samples: DeviceSamples, out: cl.Buffer,
                wait_for=None) -> cl.Event:
        """Reconstruct into ``out`` (float32 (H, W, 3)); return the last event."""
        raise NotImplementedError

    def __call__(self, queue, samples, out, wait_for=None) -> cl.Event:
        if (samples.height, samples.width) != (self.info.height, self.info.width):
            raise ValueError(
                f"samples: frame {samples.width}x{samples.height} does not match the pipeline's "
                f"{self.info.width}x{self.info.height}"
            )
        if out.size < samples.height * samples.width * 3 * 4:
            raise ValueError(f"out: buffer of {out.size} bytes is too small for the image")
        self.events = []
        return self.enqueue(queue, samples, out, wait_for)

    def pass_times_ms(self) -> dict[str, float]:
        """Per-pass device times of the last run (events must have completed)."""
        times: dict[str, float] = {}
        for name, ev in self.events:
            times[name] = times.get(name, 0.0) + event_ms(ev)
        return times


METHODS: dict[str, Callable[..., Pipeline]] = {}


def register(cls):
    """Class decorator adding a pipeline to :data:`METHODS` under ``cls.name``."""
    METHODS[cls.name] = cls
    return cls


def make_pipeline(method: str, context: cl.Context, info: FrameInfo, **knobs) -> Pipeline:
    _load_methods()
    try:
        cls = METHODS[method]
    except KeyError:
        raise ValueError(f"method: unknown {method!r}; available: {sorted(METHODS)}") from None
    accepted = set(inspect.signature(cls.__init__).parameters) - {"self", "context", "info"}
    unknown = sorted(set(knobs) - accepted)
    if unknown:
        raise TypeError(
            f"method {method!r} got unknown knobs: {unknown}; it takes {sorted(accepted)}"
        )
    return cls(context, info, **knobs)


def _load_methods() -> None:
    from . import box, layered, splat, sweep  # noqa: F401  (they register themselves)


@dataclass
class Reconstruction:
    """An image with what produced it and how long each part took."""

    image: np.ndarray
    method: dict
    device: str
    pass_ms: dict[str, float] = field(default_factory=dict)
    upload_ms: float = 0.0
    total_ms: float = 0.0

    @property
    def device_ms(self) -> float:
        return float(sum(self.pass_ms.values()))


def run(buf: SampleBuffer, method: str = "box", device: DeviceSpec | Device = None,
        **knobs) -> Reconstruction:
    """Validate, upload, reconstruct and read back; report per-pass device times."""
    if not isinstance(buf, SampleBuffer):
        raise TypeError(f"buf must be a SampleBuffer, got {type(buf).__name__}")
    buf.validate()
    dev = get_device(device)
    t0 = time.perf_counter()
    pipe = make_pipeline(method, dev.context, buf.inspect(), **knobs)
    t1 = time.perf_counter()
    samples = DeviceSamples.upload(dev.queue, buf, pipe.fields)
    t2 = time.perf_counter()
    out = cl.Buffer(dev.context, cl.mem_flags.READ_WRITE, size=buf.height * buf.width * 12)
    ev = pipe(dev.queue, samples, out)
    image = np.empty((buf.height, buf.width, 3), np.float32)
    cl.enqueue_copy(dev.queue, image, out, wait_for=[ev])
    t3 = time.perf_counter()
    return Reconstruction(
        image=image,
        method=pipe.describe(),
        device=dev.info.label,
        pass_ms=pipe.pass_times_ms(),
        upload_ms=(t2 - t1) * 1e3,
        total_ms=(t3 - t0) * 1e3,
    )


def reconstruct(buf: SampleBuffer, method: str = "box", device: DeviceSpec | Device = None,
                **knobs) -> np.ndarray:
    """Reconstruct a frame: the (H, W, 3) float32 linear image.

    Parameters
    ----------
    buf : SampleBuffer
        The frame's samples (validated here).
    method : str
        ``"box"`` (more as methods land: see ``clrecon.pipeline.METHODS``).
    device : int, str, Device or None
        See :func:`clrecon.device.get_device`.
    **knobs
        Method-specific settings; unknown names raise ``TypeError``.
    """
    return run(buf, method, device, **knobs).image
