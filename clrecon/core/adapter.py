"""Input adapter: a renderer's interleaved sample records, already in an OpenCL buffer,
unpacked on the device into the structure of arrays clrecon's passes read.

clrecon's passes read float32 row-major fields of ``N = H * W * S`` samples in the order
``(y, x, i)``: ``color`` (N, 3), ``position`` (N, 2), ``depth`` (N), ``lens`` (N, 2), ``time``
(N), ``motion`` (N, 2) (:mod:`clrecon.core.samples`). A renderer usually holds an array of structs
instead: :class:`RecordLayout` describes one record (its stride and where each field's float32
components start), :class:`Unpack` is the pass (``kernels/adapt.cl`` / ``unpack_records``)
that writes the fields a plan needs into the caller's buffers, on the caller's queue, with no
host round trip::

    layout = RecordLayout.tlfr()                      # or RecordLayout.from_dtype(my_dtype)
    unpack = Unpack(ctx, layout, ("color", "depth", "motion"))
    out = unpack.allocate(ctx, height, width, spp)    # or the caller's own buffers
    ev = unpack(queue, records, height, width, spp, (c0, c1), out, wait_for=[rendered])

Motion, ``motion="screen"``: the record holds clrecon's linear screen motion (2 floats),
copied. ``motion="tlfr"``: the record holds TLFR's perspective motion ``mv = (mv_x, mv_y,
mv_w)`` (3 floats) and the kernel converts it to screen motion exactly as
:func:`clrecon.io._tlfr_motion` does (see the :mod:`clrecon.io` docstring), but in float32:
``w (V_xy - V_w c) / ((w + (1 - t) V_w) (w - t V_w))`` with ``c = position - coc(w) * lens``,
``V_w == 0`` giving ``V_xy / w``, misses (depth >= 1e30 or inf, or depth <= 0 or NaN) giving
zero motion. A motion that crosses the camera plane (homogeneous ``w <= 0`` at ``t = 0`` or
``t = 1``) makes :func:`clrecon.io.load_samples` raise; a kernel cannot raise, so the adapter
writes NaN motion for that sample and device validation (which flags non-finite motion)
refuses the frame. Run validation after the adapter whenever records may hold such motion.

Every other field (and screen motion) is copied as a bit pattern: bit-exact. The TLFR motion
is float32 arithmetic: within a few float32 ulps of the float64 loader for ``mv_w == 0``
(one correctly rounded division on devices that round division correctly), and within a few
ulps of the terms ``|V_xy| + |V_w c|`` (scaled by ``w / (w0 w1)``) in general, since those
terms may cancel.
"""
from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

import numpy as np
import pyopencl as cl

from clrecon.core.device import get_kernel
from clrecon.core.samples import FIELDS
from clrecon.io import _TLFR_RECORD_BYTES, TLFR_FIELDS

#: float32 components of each field in a record (``motion="tlfr"``: 3, see :data:`TLFR_MOTION`)
COMPONENTS: dict[str, int] = {name: max(1, math.prod(tail)) for name, tail in FIELDS.items()}
#: components of TLFR perspective motion ``(mv_x, mv_y, mv_w)``
TLFR_MOTION = 3
MOTION_MODES = ("screen", "tlfr")
#: fields the TLFR motion conversion reads besides the motion itself
TLFR_MOTION_NEEDS = ("position", "depth", "lens", "time")


@dataclass(frozen=True)
class RecordLayout:
    """One interleaved sample record: ``stride`` bytes, field ``f``'s float32 components
    contiguous from byte ``offset(f)``.

    Parameters
    ----------
    stride : int
        Bytes per record, a positive multiple of 4.
    offsets : mapping or iterable of (field, byte offset)
        Where each present field starts; stored as a tuple of pairs in :data:`FIELDS` order
        (hashable, so a layout can key a kernel cache). Fields not listed are absent.
    motion : {"screen", "tlfr"}
        ``"screen"``: ``motion`` is clrecon's linear screen motion (2 floats). ``"tlfr"``: it is
        TLFR's ``(mv_x, mv_y, mv_w)`` (3 floats), converted on the device; the layout must
        then also hold position, depth, lens and time.

    Raises
    ------
    ValueError
        Unknown or duplicate field, offset not a non-negative multiple of 4, a field reaching
        past the stride, two fields overlapping, a bad stride or motion mode (the message
        names the field).
    """

    stride: int
    offsets: tuple[tuple[str, int], ...]
    motion: str = "screen"

    def __post_init__(self):
        stride = _as_int(self.stride, "stride")
        if stride < 4 or stride % 4:
            raise ValueError(f"stride: must be a positive multiple of 4 bytes, got {self.stride}")
        if self.motion not in MOTION_MODES:
            raise ValueError(f"motion: expected one of {MOTION_MODES}, got {self.motion!r}")
        items = self.offsets.items() if isinstance(self.offsets, Mapping) else self.offsets
        found: dict[str, int] = {}
        for item in items:
            try:
                name, offset = item
            except (TypeError, ValueError):
                raise ValueError(f"offsets: expected (field, byte offset) pairs, got {item!r}"
                                 ) from None
            if name not in FIELDS:
                raise ValueError(f"offsets: unknown field {name!r}; fields: {', '.join(FIELDS)}")
            if name in found:
                raise ValueError(f"{name}: listed twice in offsets")
            offset = _as_int(offset, f"{name}: offset")
            if offset < 0 or offset % 4:
                raise ValueError(f"{name}: byte offset must be a non-negative multiple of 4, "
                                 f"got {offset}")
            found[name] = offset
        if not found:
            raise ValueError("offsets: a layout needs at least one field")
        ordered = tuple((name, found[name]) for name in FIELDS if name in found)
        object.__setattr__(self, "stride", stride)
        object.__setattr__(self, "offsets", ordered)
        spans = []
        for name, offset in ordered:
            end = offset + 4 * self.components(name)
            if end > stride:
                raise ValueError(
                    f"{name}: {self.components(name)} float32 at byte {offset} end at byte "
                    f"{end}, past the record stride of {stride} bytes"
                )
            spans.append((offset, end, name))
        spans.sort()
        for (_, end_a, a), (start_b, _, b) in zip(spans, spans[1:]):
            if start_b < end_a:
                raise ValueError(f"{b}: bytes [{start_b}, ...) overlap field {a} "
                                 f"(which ends at byte {end_a})")
        if self.motion == "tlfr" and "motion" in found:
            lacking = [f for f in TLFR_MOTION_NEEDS if f not in found]
            if lacking:
                raise ValueError(f"motion: motion='tlfr' converts perspective motion with "
                                 f"position, depth, lens and time; the layout lacks "
                                 f"{', '.join(lacking)}")

    # -- queries ---------------------------------------------------------------------------
    @property
    def fields(self) -> tuple[str, ...]:
        """Fields present, in :data:`FIELDS` order."""
        return tuple(name for name, _ in self.offsets)

    def offset(self, name: str) -> int:
        """Byte offset of a present field (``KeyError`` otherwise)."""
        for f, off in self.offsets:
            if f == name:
                return off
        raise KeyError(f"field {name!r} is not in this layout (has {', '.join(self.fields)})")

    def components(self, name: str) -> int:
        """float32 components of ``name`` in the record (TLFR motion: 3)."""
        if name == "motion" and self.motion == "tlfr":
            return TLFR_MOTION
        return COMPONENTS[name]

    # -- constructors ----------------------------------------------------------------------
    @classmethod
    def tlfr(cls) -> RecordLayout:
        """TLFR 1.3's 64-byte record ``x,y,z/w,w,u,v,t,r,g,b,a,mv_x,mv_y,mv_w,dwdx,dwdy``:
        position 0, depth (``w``) 12, lens 16, time 24, color 28, motion (``mv``) 44,
        ``motion="tlfr"``; ``z/w``, ``a``, ``dwdx``, ``dwdy`` are ignored."""
        first = {"position": "x", "depth": "w", "lens": "u", "time": "t", "color": "r",
                 "motion": "mv_x"}
        return cls(_TLFR_RECORD_BYTES,
                   {name: 4 * TLFR_FIELDS.index(col) for name, col in first.items()},
                   motion="tlfr")

    @classmethod
    def from_dtype(cls, dtype, names: Mapping[str, str] | None = None,
                   motion: str = "screen") -> RecordLayout:
        """The layout of a record described by a NumPy structured dtype.

        Parameters
        ----------
        dtype : numpy.dtype (or anything ``numpy.dtype`` accepts)
            A structured dtype; its ``itemsize`` is the stride (padding and other members are
            allowed and skipped). Each used member must be little-endian (or native) float32,
            a scalar or a (k,) subarray with k the field's component count (depth, time: a
            scalar or shape (1,)).
        names : mapping clrecon field -> dtype member name, optional
            Default: every member whose name is a clrecon field (``color``, ``position``,
            ``depth``, ``lens``, ``time``, ``motion``).
        motion : {"screen", "tlfr"}
            See :class:`RecordLayout`; ``"tlfr"`` expects a (3,) motion member.

        Raises
        ------
        ValueError
            Not a structured dtype, a named member missing, or a member of the wrong type or
            length (the message names the field and the member).
        """
        dt = np.dtype(dtype)
        if dt.names is None:
            raise ValueError(f"dtype: expected a structured dtype, got {dt}")
        if names is None:
            names = {n: n for n in dt.names if n in FIELDS}
        else:
            names = dict(names)
        if not names:
            raise ValueError(f"dtype: no member is named after a clrecon field "
                             f"({', '.join(FIELDS)}); pass names={{field: member}}")
        offsets = {}
        for name, member in names.items():
            if name not in FIELDS:
                raise ValueError(f"names: unknown field {name!r}; fields: {', '.join(FIELDS)}")
            if member not in dt.fields:
                raise ValueError(f"{name}: dtype has no member {member!r} "
                                 f"(members: {', '.join(dt.names)})")
            sub, offset = dt.fields[member][:2]
            base, shape = (sub.subdtype if sub.subdtype is not None else (sub, ()))
            want = TLFR_MOTION if (name == "motion" and motion == "tlfr") else COMPONENTS[name]
            count = math.prod(shape)
            if base != np.dtype("<f4"):
                raise ValueError(f"{name}: member {member!r} must be little-endian float32, "
                                 f"got {sub}")
            if len(shape) > 1 or count != want:
                raise ValueError(f"{name}: member {member!r} must hold {want} float32 "
                                 f"(shape ({want},){' or ()' if want == 1 else ''}), got {sub}")
            offsets[name] = offset
        return cls(dt.itemsize, offsets, motion=motion)

    def defines(self) -> dict[str, int]:
        """``-D`` defines of ``kernels/adapt.cl`` describing this layout (units: floats)."""
        d = {"STRIDE": self.stride // 4, "MOTION_TLFR": int(self.motion == "tlfr")}
        for name, off in self.offsets:
            d[f"OFF_{name.upper()}"] = off // 4
        return d


def field_nbytes(name: str, n: int) -> int:
    """Bytes of the SoA output ``name`` for ``n`` samples (float32)."""
    return 4 * COMPONENTS[name] * n


def allocate(context: cl.Context, height: int, width: int, spp: int,
             fields: Iterable[str] = tuple(FIELDS)) -> dict[str, cl.Buffer]:
    """Device buffers for the SoA fields of an ``height x width x spp`` frame (uninitialised)."""
    n = _frame_samples(height, width, spp)
    out = {}
    for name in _check_fields(fields):
        out[name] = cl.Buffer(context, cl.mem_flags.READ_WRITE, size=field_nbytes(name, n))
    return out


class Unpack:
    """Pass ``unpack``: ``kernels/adapt.cl`` / ``unpack_records``, records -> SoA fields.

    Parameters
    ----------
    context : pyopencl.Context
    layout : RecordLayout
        The records' layout; the kernel is specialised for it (``-D`` defines).
    fields : iterable of str
        The fields to write (those the plan needs), each present in ``layout``.
    wg, items, stage : tunables
        Local size (default 128), samples per work-item (default 1), and whether a group
        first copies its ``wg * items`` records into local memory with coalesced loads
        (default off; a candidate for GPUs, where one record per work-item makes strided
        loads). See ``kernels/adapt.cl``.

    Raises
    ------
    ValueError
        Unknown fields, fields the layout lacks (named), or bad tunables.
    """

    name = "unpack"

    def __init__(self, context: cl.Context, layout: RecordLayout,
                 fields: Iterable[str] = tuple(FIELDS), *, wg: int = 128, items: int = 1,
                 stage: bool = False):
        if not isinstance(layout, RecordLayout):
            raise TypeError(f"layout must be a RecordLayout, got {type(layout).__name__}")
        fields = _check_fields(fields)
        lacking = [f for f in fields if f not in layout.fields]
        if lacking:
            raise ValueError(f"fields: the plan needs {', '.join(lacking)}, which the record "
                             f"layout lacks (layout has {', '.join(layout.fields)})")
        wg, items = _as_int(wg, "wg"), _as_int(items, "items")
        if wg < 1 or items < 1:
            raise ValueError(f"wg, items: must be positive, got wg={wg}, items={items}")
        max_wg = min(int(d.max_work_group_size) for d in context.devices)
        if wg > max_wg:
            raise ValueError(f"wg: {wg} exceeds the device's maximum work-group size {max_wg}")
        stage_bytes = wg * items * layout.stride
        local_bytes = min(int(d.local_mem_size) for d in context.devices)
        if stage and stage_bytes > local_bytes:
            raise ValueError(f"stage: {wg} x {items} records of {layout.stride} bytes need "
                             f"{stage_bytes} bytes of local memory; the device has "
                             f"{local_bytes}")
        self.context = context
        self.layout = layout
        self.fields = fields
        self.wg, self.items, self.stage = wg, items, bool(stage)
        defines = layout.defines()
        defines.update({f"WRITE_{f.upper()}": 1 for f in fields})
        defines.update({"WG": wg, "ITEMS": items, "STAGE": int(self.stage)})
        self.kernel = get_kernel(context, "adapt", "unpack_records", defines)

    def allocate(self, context: cl.Context, height: int, width: int,
                 spp: int) -> dict[str, cl.Buffer]:
        """Output buffers for this pass's fields (see :func:`allocate`)."""
        return allocate(context, height, width, spp, self.fields)

    def check(self, records: cl.Buffer, height: int, width: int, spp: int,
              out: Mapping[str, cl.Buffer]) -> int:
        """Check the buffers for an ``height x width x spp`` frame; return ``N``."""
        n = _frame_samples(height, width, spp)
        need = n * self.layout.stride
        if not isinstance(records, cl.Buffer):
            raise TypeError(f"records must be a pyopencl.Buffer, got {type(records).__name__}")
        if records.size < need:
            raise ValueError(f"records: buffer holds {records.size} bytes, needs {need} "
                             f"({n} records of {self.layout.stride} bytes)")
        missing = [f for f in self.fields if f not in out]
        if missing:
            raise ValueError(f"out: no buffer for {', '.join(missing)} (this pass writes "
                             f"{', '.join(self.fields)})")
        extra = [f for f in out if f not in self.fields]
        if extra:
            raise ValueError(f"out: this pass does not write {', '.join(map(str, extra))} "
                             f"(it writes {', '.join(self.fields)}); build it with those fields")
        for f in self.fields:
            size, want = out[f].size, field_nbytes(f, n)
            if size < want:
                raise ValueError(f"{f}: output buffer holds {size} bytes, needs {want} "
                                 f"({n} samples x {COMPONENTS[f]} float32)")
        return n

    def __call__(self, queue: cl.CommandQueue, records: cl.Buffer, height: int, width: int,
                 spp: int, coc: tuple[float, float], out: Mapping[str, cl.Buffer],
                 wait_for=None) -> cl.Event:
        """Enqueue the unpack of ``H * W * S`` records into ``out``; returns its event.

        ``coc = (c0, c1)`` (only used by TLFR motion). Does not block.
        """
        if queue.context != self.context:
            raise ValueError("queue: belongs to another context than this pass")
        n = self.check(records, height, width, spp, out)
        c0, c1 = (float(c) for c in coc)
        if not (math.isfinite(c0) and math.isfinite(c1)):
            raise ValueError(f"coc: coefficients must be finite, got {coc}")
        groups = -(-n // (self.wg * self.items))
        self.kernel.set_args(records, np.uint64(n), np.float32(c0), np.float32(c1),
                             *(out.get(f) for f in FIELDS))
        return cl.enqueue_nd_range_kernel(queue, self.kernel, (groups * self.wg,),
                                          (self.wg,), wait_for=wait_for)


# -- helpers ---------------------------------------------------------------------------------
def _as_int(value, what: str) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{what}: expected an integer, got {value!r}")
    return int(value)


def _frame_samples(height: int, width: int, spp: int) -> int:
    dims = [_as_int(v, k) for k, v in (("height", height), ("width", width), ("spp", spp))]
    if min(dims) < 1:
        raise ValueError(f"height, width, spp: must be positive, got {height}x{width}x{spp}")
    return dims[0] * dims[1] * dims[2]


def _check_fields(fields: Iterable[str]) -> tuple[str, ...]:
    if isinstance(fields, str):
        fields = (fields,)
    fields = tuple(fields)
    unknown = [f for f in fields if f not in FIELDS]
    if unknown:
        raise ValueError(f"fields: unknown {', '.join(map(repr, unknown))}; fields: "
                         f"{', '.join(FIELDS)}")
    if not fields:
        raise ValueError("fields: at least one field to write")
    return tuple(f for f in FIELDS if f in fields)
