"""Pass ``inspect``: validate and inspect a frame whose samples are already on the device.

One kernel (``kernels/inspect.cl`` / ``inspect_samples``) reads every present field once
and yields both what :meth:`clrecon.core.samples.SampleBuffer.inspect` computes and the value
rules of :meth:`clrecon.core.samples.SampleBuffer.validate`, so that a frame uploaded (or
produced) on the device need not come back to the host to be checked.

* :class:`Inspect` is the pass: built once per field set, ``__call__`` only sets arguments
  and enqueues (clear + reduction), :meth:`Inspect.read` fetches the small result.
* :func:`inspect_device` runs it and returns a :class:`~clrecon.core.samples.FrameInfo`; with
  ``validate=True`` it raises the same ``ValueError`` (same text) that
  ``validate(allow_negative=...)`` would raise for the host copy of the frame (the bounds of
  :mod:`clrecon.core.samples`: colour, depth, CoC, motion).

Agreement with the host: validation verdicts, first bad samples, counts, ``min_depth``,
``max_depth`` and ``miss_fraction`` are exact (the per-sample CoC bound is one depth
comparison against the host's exact threshold, :func:`clrecon.core.samples.coc_min_depth`).
``max_abs_coc`` is computed in float on the device (the host rounds a float64 coc to
float32) and ``max_abs_motion`` is a float length (the host: a float64 sqrt): both agree
within a few ulp. Without fp64 on the device, the lens rule is evaluated in float and may
differ from the host for samples within an ulp of the unit circle's tolerance.

Limits: ``N = H * W * S < 2**31`` (uint indices and counts; larger frames are refused).
The result buffer of a pass is shared by its calls: one call in flight per pass object
(:func:`inspect_device` serialises its cached passes with a lock).
"""
from __future__ import annotations

import math
import threading

import numpy as np
import pyopencl as cl

from clrecon.core.camera import CocModel
from clrecon.core.device import get_kernel
from clrecon.core.samples import (
    COLOR_MAX,
    FIELDS,
    LENS_TOLERANCE,
    MIN_DEPTH,
    MISS_DEPTH,
    MOTION_MAX,
    POSITION_TOLERANCE,
    RULE_NAMES,
    FrameInfo,
    bad_sample_message,
    coc_min_depth,
    coc_model_error,
)

#: validation rules in SampleBuffer.validate() order (``coc`` after the coefficients); the
#: index is the rule number of kernels/inspect.cl (R_DEPTH ... R_COC)
RULES: tuple[str, ...] = RULE_NAMES

#: the field each rule reads (``coc``: the depth)
RULE_FIELD = {name: ("depth" if name == "coc" else name) for name in RULES}

# result slots of kernels/inspect.cl
_NRULE = len(RULES)
_S_FIRST, _S_COUNT = 0, _NRULE
_S_COC = 2 * _NRULE
_S_MOTION, _S_DMIN, _S_DMAX, _S_HITS = _S_COC + 1, _S_COC + 2, _S_COC + 3, _S_COC + 4
NSLOT = _S_COC + 5
_NONE = 0xFFFFFFFF

#: the largest N (exclusive) the kernel's uint indices allow
MAX_SAMPLES = 2**31

#: default tunables per device type (PoCL on a 2-core EPYC: contiguous 64 x 256 is ~3x
#: faster than interleaved; GPUs want interleaved, coalesced work-items)
DEFAULTS = {
    "CPU": {"local_size": 64, "items": 256, "contiguous": True},
    "GPU": {"local_size": 256, "items": 16, "contiguous": False},
}

_FLAGS = {"color": "HAS_COLOR", "position": "HAS_POSITION", "lens": "HAS_LENS",
          "time": "HAS_TIME", "motion": "HAS_MOTION"}


def _hex_f32(value: float) -> str:
    """An exact OpenCL C float literal of ``float32(value)`` (as NumPy rounds it)."""
    return float.hex(float(np.float32(value))) + "f"


def _order_key_to_float(key: int) -> float:
    """Inverse of ``order_key()`` in kernels/inspect.cl."""
    bits = key & 0x7FFFFFFF if key & 0x80000000 else ~key & 0xFFFFFFFF
    return float(np.uint32(bits).view(np.float32))


def _bits_to_float(bits: int) -> float:
    return float(np.uint32(bits).view(np.float32))


def udiv_magic(d: int) -> tuple[int, int]:
    """``(m, sh)`` with ``(a * m) >> sh == a // d`` for every ``0 <= a < 2**31``
    (``udiv31`` in kernels/inspect.cl; Granlund-Montgomery with ``m < 2**32``)."""
    if not 1 <= d < 2**31:
        raise ValueError(f"divisor must lie in [1, 2**31), got {d}")
    sh = 31 + (d - 1).bit_length()
    return -(-(1 << sh) // d), sh


def normalise_fields(fields) -> tuple[str, ...]:
    """``fields`` as a tuple in :data:`clrecon.core.samples.FIELDS` order (``depth`` required)."""
    names = set(fields)
    unknown = sorted(names - set(FIELDS))
    if unknown:
        raise ValueError(f"unknown sample fields {unknown}; known: {list(FIELDS)}")
    if "depth" not in names:
        raise ValueError("inspect needs the depth field")
    return tuple(n for n in FIELDS if n in names)


class Inspect:
    """Pass ``inspect``: ``kernels/inspect.cl`` / ``inspect_clear`` + ``inspect_samples``.

    ``fields`` names the fields present (``depth`` required); the kernel is built once with
    ``HAS_<FIELD>`` flags, rules of absent fields are not checked. Tunables (``None``: the
    default of the context's device type, :data:`DEFAULTS`): ``local_size`` (power of two
    >= 32; local memory ``NSLOT * local_size * 4`` bytes), ``items`` (samples per
    work-item) and ``contiguous`` (each work-item reads ``items`` consecutive samples: what
    CPUs vectorise; else work-items interleave: coalesced loads on GPUs).
    """

    name = "inspect"

    def __init__(self, context: cl.Context, fields, local_size: int | None = None,
                 items: int | None = None, contiguous: bool | None = None):
        self.fields = normalise_fields(fields)
        kind = "CPU" if context.devices[0].type & cl.device_type.CPU else "GPU"
        dflt = DEFAULTS[kind]
        local_size = int(dflt["local_size"] if local_size is None else local_size)
        items = int(dflt["items"] if items is None else items)
        contiguous = bool(dflt["contiguous"] if contiguous is None else contiguous)
        if local_size < 32 or local_size & (local_size - 1):
            raise ValueError(f"local_size must be a power of two >= 32, got {local_size}")
        if not 1 <= items <= 2**20 // local_size:
            raise ValueError(f"items must lie in [1, 2**20 / local_size], got {items}")
        self.local_size, self.items, self.contiguous = local_size, items, contiguous
        defines = {flag: name in self.fields for name, flag in _FLAGS.items()}
        defines.update(
            WG_SIZE=local_size,
            ITEMS=items,
            CONTIGUOUS=contiguous,
            MISS_DEPTH=_hex_f32(MISS_DEPTH),
            POS_TOL=_hex_f32(POSITION_TOLERANCE),
            LENS_R2_MAX=float.hex((1 + LENS_TOLERANCE) ** 2),  # double, as validate()
            MIN_DEPTH=_hex_f32(MIN_DEPTH),
            COLOR_MAX=_hex_f32(COLOR_MAX),
            MOTION_MAX=_hex_f32(MOTION_MAX),
        )
        self.kernel = get_kernel(context, "inspect", "inspect_samples", defines)
        self.clear = get_kernel(context, "inspect", "inspect_clear", defines)
        self.result = cl.Buffer(context, cl.mem_flags.READ_WRITE, size=NSLOT * 4)

    def check(self, buffers, height: int, width: int, spp: int) -> int:
        """Host-side preconditions of a call; returns ``N``."""
        height, width, spp = int(height), int(width), int(spp)
        if min(height, width, spp) < 1:
            raise ValueError(f"depth: empty frame of shape {(height, width, spp)}")
        n = height * width * spp
        if n >= MAX_SAMPLES:
            raise ValueError(
                f"inspect: {height}x{width}x{spp} = {n} samples; the device pass handles "
                f"fewer than 2**31 (uint sample indices and counts)")
        for name in self.fields:
            if name not in buffers:
                raise ValueError(f"{name}: no buffer given (the pass was built for "
                                 f"{list(self.fields)})")
            need = n * max(1, math.prod(FIELDS[name])) * 4
            have = buffers[name].size
            if have < need:
                raise ValueError(f"{name}: buffer of {have} bytes, shape "
                                 f"{(height, width, spp) + FIELDS[name]} needs {need}")
        return n

    def __call__(self, queue: cl.CommandQueue, buffers, height: int, width: int, spp: int,
                 coc: tuple[float, float], wait_for=None,
                 allow_negative: bool = False) -> cl.Event:
        """Enqueue the clear and the reduction; returns the reduction's event (no waits).
        ``allow_negative``: the colour rule accepts ``[-COLOR_MAX, COLOR_MAX]``."""
        n = self.check(buffers, height, width, spp)
        with np.errstate(over="ignore", invalid="ignore"):
            c0, c1 = np.float32(coc[0]), np.float32(coc[1])
        model = CocModel(c0=coc[0], c1=coc[1])
        coc_lo = (coc_min_depth(float(coc[0]), float(coc[1]))
                  if coc_model_error(model) is None else np.float32(0))
        color_lo = np.float32(-COLOR_MAX if allow_negative else 0.0)
        args = [buffers[name] if name in self.fields else None
                for name in ("depth", "color", "position", "lens", "time", "motion")]
        self.clear.set_args(self.result)
        ev = cl.enqueue_nd_range_kernel(queue, self.clear, (NSLOT,), None, wait_for=wait_for)
        wm, wsh = udiv_magic(int(width))
        sm, ssh = udiv_magic(int(spp))
        self.kernel.set_args(*args, np.uint32(n), np.uint32(width), np.uint32(wm),
                             np.uint32(wsh), np.uint32(sm), np.uint32(ssh), c0, c1, color_lo,
                             np.float32(coc_lo), self.result)
        chunk = self.local_size * self.items
        groups = -(-n // chunk)
        return cl.enqueue_nd_range_kernel(queue, self.kernel, (groups * self.local_size,),
                                          (self.local_size,), wait_for=[ev])

    def read(self, queue: cl.CommandQueue, wait_for=None) -> dict:
        """The last call's result (blocking read of ``NSLOT`` uints).

        ``first_bad`` / ``bad_count``: per present rule (``coc`` always: it reads the
        depth), the smallest bad linear sample index (``None`` if none) and the number of
        bad samples; ``max_abs_coc``,
        ``max_abs_motion`` (0 without motion), ``min_depth`` / ``max_depth`` over hits (both
        ``inf`` without hits) and ``hits`` (samples with ``depth < MISS_DEPTH``).
        """
        raw = np.empty(NSLOT, np.uint32)
        cl.enqueue_copy(queue, raw, self.result, wait_for=wait_for, is_blocking=True)
        raw = [int(v) for v in raw]
        rules = [r for r, name in enumerate(RULES) if RULE_FIELD[name] in self.fields]
        hits = raw[_S_HITS]
        return {
            "first_bad": {RULES[r]: (None if raw[_S_FIRST + r] == _NONE
                                     else raw[_S_FIRST + r]) for r in rules},
            "bad_count": {RULES[r]: raw[_S_COUNT + r] for r in rules},
            "max_abs_coc": _bits_to_float(raw[_S_COC]),
            "max_abs_motion": _bits_to_float(raw[_S_MOTION]),
            "min_depth": _order_key_to_float(raw[_S_DMIN]) if hits else math.inf,
            "max_depth": _order_key_to_float(raw[_S_DMAX]) if hits else math.inf,
            "hits": hits,
        }


_passes: dict[tuple[int, tuple[str, ...]], Inspect] = {}
_lock = threading.Lock()


def _get_pass(context: cl.Context, fields: tuple[str, ...]) -> Inspect:
    key = (context.int_ptr, fields)  # the pass holds the context: its address stays unique
    p = _passes.get(key)
    if p is None:
        p = _passes[key] = Inspect(context, fields)
    return p


def _read_sample(queue, buf: cl.Buffer, name: str, index: int):
    """One sample's value of a field, as ``values[idx].tolist()`` gives it on the host."""
    k = max(1, math.prod(FIELDS[name]))
    out = np.empty(k, np.float32)
    cl.enqueue_copy(queue, out, buf, src_offset=index * k * 4, is_blocking=True)
    return out.tolist() if FIELDS[name] else out[0].tolist()


def _raise_first_bad(queue, buffers, result: dict, width: int, spp: int,
                     coc: tuple[float, float], allow_negative: bool) -> None:
    """The error validate() raises: the value rules in order, the coefficients, the CoC."""
    model = CocModel(c0=coc[0], c1=coc[1])
    for name in RULES:
        if name == "coc":
            error = coc_model_error(model)
            if error is not None:
                raise ValueError(error)
        count = result["bad_count"].get(name, 0)
        if not count:
            continue
        index = result["first_bad"][name]
        field = RULE_FIELD[name]
        value = _read_sample(queue, buffers[field], field, index)
        pixel, s = divmod(index, spp)
        py, px = divmod(pixel, width)
        raise ValueError(bad_sample_message(name, (py, px, s), count, value, allow_negative,
                                            model))


def inspect_device(queue: cl.CommandQueue, buffers, height: int, width: int, spp: int,
                   coc: tuple[float, float], validate: bool = True,
                   wait_for=None, allow_negative: bool = False) -> FrameInfo:
    """:class:`FrameInfo` of a frame on the device (``buffers``: field name -> cl.Buffer).

    The fields present are the keys of ``buffers`` (``depth`` required). With ``validate``,
    raises the ``ValueError`` that ``SampleBuffer.validate(allow_negative)`` raises for the
    same frame (rules of absent fields skipped; the coc coefficients are always checked).
    Blocks until the small result is read back; the pass is cached per (context, fields).
    """
    fields = normalise_fields(buffers)
    height, width, spp = int(height), int(width), int(spp)
    with _lock:
        pass_ = _get_pass(queue.context, fields)
        ev = pass_(queue, buffers, height, width, spp, coc, wait_for=wait_for,
                   allow_negative=allow_negative)
        result = pass_.read(queue, wait_for=[ev])
    if validate:
        _raise_first_bad(queue, buffers, result, width, spp, coc, bool(allow_negative))
    n = height * width * spp
    return FrameInfo(
        width=width,
        height=height,
        spp=spp,
        max_abs_coc=result["max_abs_coc"],
        max_abs_motion=result["max_abs_motion"],
        min_depth=result["min_depth"],
        max_depth=result["max_depth"],
        miss_fraction=float(1.0 - result["hits"] / n),
    )
