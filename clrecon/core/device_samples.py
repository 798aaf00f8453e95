"""Device-side sample buffers: a frame's fields as OpenCL buffers, with the frame's shape,
its CoC model and (once inspected) its description. Made by :meth:`DeviceSamples.upload`
(a copy), :meth:`DeviceSamples.wrap` (the host arrays in place) or by an embedder from
buffers of its own."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyopencl as cl

from clrecon.core.inspect import inspect_device
from clrecon.core.samples import FIELDS, FrameInfo, SampleBuffer


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
    #: samples per pixel in the buffers (``None``: ``spp``) and the first of them this frame
    #: reads: sample ``i`` of pixel ``p`` is element ``p * stride + offset + i``. A frame with
    #: ``(stride, offset) != (spp, 0)`` is a *view* (:meth:`view`: one half of a frame's
    #: samples, read in place); only a pipeline whose passes say so takes one
    #: (``Pipeline.sample_views``), and ``[name]`` refuses to hand out a view's field.
    stride: int | None = None
    offset: int = 0

    def __post_init__(self):
        if self.stride is None:
            self.stride = self.spp
        for name in ("height", "width", "spp", "stride"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise ValueError(f"samples: {name} must be a positive integer, got {v!r}")
        o = self.offset
        if isinstance(o, bool) or not isinstance(o, (int, np.integer)) or not (
                0 <= o and o + self.spp <= self.stride):
            raise ValueError(f"samples: offset must be an integer with 0 <= offset and offset "
                             f"+ spp <= stride ({self.spp} + offset <= {self.stride}), got {o!r}")
        try:
            c0, c1 = (float(c) for c in self.coc)
        except (TypeError, ValueError):
            raise ValueError(f"samples: coc must be (C0, C1), got {self.coc!r}") from None
        if not (np.isfinite(c0) and np.isfinite(c1)):
            raise ValueError(f"samples: coc coefficients must be finite, got {self.coc!r}")
        self.coc = (c0, c1)
        n = self.height * self.width * self.stride
        for name, b in self.buffers.items():
            if name not in FIELDS:
                raise ValueError(f"samples: unknown field {name!r}; fields are {list(FIELDS)}")
            need = n * int(np.prod(FIELDS[name], dtype=np.int64)) * 4
            if not isinstance(b, cl.MemoryObjectHolder) or b.size < need:
                size = getattr(b, "size", type(b).__name__)
                raise ValueError(f"samples: field {name!r} needs a buffer of at least {need} "
                                 f"bytes (float32, {self.width}x{self.height}x{self.stride}), "
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

    @classmethod
    def wrap(cls, context: cl.Context, buf: SampleBuffer, fields=None,
             info: FrameInfo | None = None) -> DeviceSamples:
        """Device buffers over the host arrays themselves (``USE_HOST_PTR``, read-only): no
        copy on a device that shares the host's memory (a CPU). The buffers alias ``buf``'s
        arrays: they are valid while the arrays live, and what the arrays hold when a pass
        runs is what it reads; the passes never write them."""
        fields = tuple(fields or FIELDS)
        buf.check_layout(fields)
        flags = cl.mem_flags.READ_ONLY | cl.mem_flags.USE_HOST_PTR
        bufs = {name: cl.Buffer(context, flags, hostbuf=getattr(buf, name))
                for name in fields}
        return cls(buf.height, buf.width, buf.spp, bufs,
                   (buf.coc_model.c0, buf.coc_model.c1), info)

    @property
    def shape(self) -> tuple[int, int, int]:
        return (self.height, self.width, self.spp)

    @property
    def is_view(self) -> bool:
        return (self.stride, self.offset) != (self.spp, 0)

    def view(self, spp: int, offset: int, info: FrameInfo | None = None) -> DeviceSamples:
        """Samples ``offset .. offset + spp - 1`` of every pixel of this frame, in place (no
        copy): a frame of ``spp`` samples per pixel described by ``info``."""
        if self.is_view:
            raise ValueError("samples: a view of a view is not supported")
        return DeviceSamples(self.height, self.width, spp, dict(self.buffers), self.coc, info,
                             self.spp, offset)

    def strided(self, name: str) -> tuple[cl.Buffer, int, int]:
        """``(buffer, stride, offset)`` of field ``name``: for a pass that reads views."""
        return self._field(name), int(self.stride), int(self.offset)

    def __getitem__(self, name: str) -> cl.Buffer:
        if self.is_view:
            raise ValueError(f"samples: field {name!r} of a view (samples {self.offset}.."
                             f"{self.offset + self.spp - 1} of {self.stride} per pixel) read "
                             f"as a whole frame; a pass that reads views uses strided()")
        return self._field(name)

    def _field(self, name: str) -> cl.Buffer:
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
        if self.is_view:
            raise ValueError("samples: a view is not inspected on the device; give its info")
        self.info = inspect_device(queue, self.buffers, self.height, self.width, self.spp,
                                   self.coc, validate=validate, wait_for=wait_for,
                                   allow_negative=allow_negative)
        return self.info
