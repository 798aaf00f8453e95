"""A device's streaming bandwidth, the peak that ``clrecon bench`` compares each pass with.

:func:`measure_peak` times ``kernels/bandwidth.cl`` (``copy_float4``: one float4 read and one
written per work-item, the local size left to the runtime) on the caller's queue, over two
buffers far larger than the last-level cache: one untimed launch first (on a CPU device it
faults the pages in), then ``runs`` launches timed from their profiling events. The peak is
the median of ``bytes read + bytes written`` over the device time of each launch; the median
because a shared machine's noise only ever makes a launch slower, and one lucky launch
should not set the bar either.

The buffers default to :func:`default_buffer_bytes`: at least :data:`MIN_BUFFER_BYTES`, and
8 times the global-memory cache the device reports (a CPU device reports a per-core level,
a GPU its L2), within the device's largest allocation and a quarter of its memory.

:func:`clpeak_bandwidth` runs the ``clpeak`` binary's global-memory test on the same device
for comparison, when it is installed (it is optional: ``None`` when absent). clpeak's kernels
read and sum (they write one float per work-item), so its figure is a read bandwidth, while
ours counts a copy's reads and writes; on a CPU a copy's writes also cost a read of each
line (write-allocate), which neither figure counts.
"""
from __future__ import annotations

import math
import os
import shutil
import statistics
import subprocess
import tempfile
import xml.etree.ElementTree as ET
from dataclasses import dataclass

import numpy as np
import pyopencl as cl

from clrecon.core.device import event_ms, get_kernel

#: the smallest buffer :func:`default_buffer_bytes` picks (each of source and destination)
MIN_BUFFER_BYTES = 256 * 2**20

#: timed launches of :func:`measure_peak` after its untimed one
RUNS = 7

#: clpeak's vector widths, in the order it reports them
CLPEAK_WIDTHS = ("float", "float2", "float4", "float8", "float16")

_ITEM = 16  # bytes of one float4


@dataclass(frozen=True)
class Peak:
    """The copy kernel's bandwidth on one device.

    Attributes
    ----------
    gb_per_s : float
        Median over the timed launches of ``bytes_per_launch / device time`` (1 GB = 1e9 B).
    runs_gb_per_s : tuple of float
        Each timed launch's bandwidth, in launch order.
    buffer_bytes : int
        Size of the source (and of the destination) buffer.
    bytes_per_launch : int
        Bytes one launch reads and writes: ``2 * buffer_bytes``.
    """

    gb_per_s: float
    runs_gb_per_s: tuple[float, ...]
    buffer_bytes: int
    bytes_per_launch: int

    def to_dict(self) -> dict:
        return {"kernel": "copy_float4", "gb_per_s": self.gb_per_s,
                "runs_gb_per_s": list(self.runs_gb_per_s), "buffer_bytes": self.buffer_bytes,
                "bytes_per_launch": self.bytes_per_launch}


def default_buffer_bytes(device: cl.Device) -> int:
    """The size of each buffer :func:`measure_peak` copies by default on ``device``.

    ``max(MIN_BUFFER_BYTES, 8 * GLOBAL_MEM_CACHE_SIZE)``, at most the device's
    ``MAX_MEM_ALLOC_SIZE`` and a quarter of its global memory (source and destination both
    fit with room to spare), in whole float4s."""
    cache = int(device.get_info(cl.device_info.GLOBAL_MEM_CACHE_SIZE) or 0)
    want = max(MIN_BUFFER_BYTES, 8 * cache)
    cap = min(int(device.max_mem_alloc_size), int(device.global_mem_size) // 4)
    return max(_ITEM, min(want, cap) // _ITEM * _ITEM)


def _check_bytes(nbytes) -> int:
    if isinstance(nbytes, bool) or not isinstance(nbytes, (int, np.integer)):
        raise ValueError(f"buffer_bytes: expected an integer, got {nbytes!r}")
    if nbytes < _ITEM or nbytes % _ITEM:
        raise ValueError(f"buffer_bytes: must be a positive multiple of {_ITEM} (whole "
                         f"float4s), got {nbytes}")
    return int(nbytes)


def _copy(queue: cl.CommandQueue, src: cl.Buffer, dst: cl.Buffer, n4: int) -> cl.Event:
    kernel = get_kernel(queue.context, "bandwidth", "copy_float4")
    kernel.set_args(src, dst, np.uint64(n4))
    return cl.enqueue_nd_range_kernel(queue, kernel, (n4,), None)


def copy_array(queue: cl.CommandQueue, host: np.ndarray) -> np.ndarray:
    """``host`` copied on the device by ``copy_float4`` and read back (what the tests check
    the kernel with).

    Parameters
    ----------
    queue : pyopencl.CommandQueue
    host : numpy.ndarray
        float32, C-contiguous, a whole number of float4s (``size % 4 == 0``, not empty).

    Returns
    -------
    numpy.ndarray
        The device's copy, of ``host``'s shape.
    """
    a = np.asarray(host)
    if a.dtype != np.float32 or not a.flags.c_contiguous:
        raise ValueError(f"host: expected a C-contiguous float32 array, got {a.dtype}")
    nbytes = _check_bytes(a.nbytes)
    mf = cl.mem_flags
    src = cl.Buffer(queue.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=a)
    dst = cl.Buffer(queue.context, mf.WRITE_ONLY, nbytes)
    _copy(queue, src, dst, nbytes // _ITEM).wait()
    out = np.empty_like(a)
    cl.enqueue_copy(queue, out, dst)
    return out


def measure_peak(queue: cl.CommandQueue, buffer_bytes: int | None = None,
                 runs: int = RUNS) -> Peak:
    """Median streaming bandwidth of ``queue``'s device (see the module docstring).

    Parameters
    ----------
    queue : pyopencl.CommandQueue
        Created with profiling enabled (the bench's queue:
        :attr:`clrecon.core.device.Device.queue`).
    buffer_bytes : int, optional
        Size of each of the two buffers, a multiple of 16; default
        :func:`default_buffer_bytes`.
    runs : int
        Timed launches (at least 1), after one untimed one.

    Returns
    -------
    Peak

    Raises
    ------
    ValueError
        A bad ``buffer_bytes`` or ``runs``, a queue without profiling, or a launch whose
        device time is not positive.
    """
    if isinstance(runs, bool) or not isinstance(runs, (int, np.integer)) or runs < 1:
        raise ValueError(f"runs: must be a positive integer, got {runs!r}")
    if not queue.properties & cl.command_queue_properties.PROFILING_ENABLE:
        raise ValueError("queue: profiling must be enabled (device times come from events)")
    nbytes = _check_bytes(default_buffer_bytes(queue.device) if buffer_bytes is None
                          else buffer_bytes)
    mf = cl.mem_flags
    src = cl.Buffer(queue.context, mf.READ_ONLY, nbytes)
    dst = cl.Buffer(queue.context, mf.WRITE_ONLY, nbytes)
    try:
        cl.enqueue_fill_buffer(queue, src, np.float32(1.0), 0, nbytes).wait()
        n4 = nbytes // _ITEM
        _copy(queue, src, dst, n4).wait()  # untimed: first touch of every page
        moved = 2 * nbytes
        rates = []
        for _ in range(int(runs)):
            ev = _copy(queue, src, dst, n4)
            ev.wait()
            ms = event_ms(ev)
            if not (ms > 0 and math.isfinite(ms)):
                raise ValueError(f"copy_float4: device time {ms!r} ms is not positive")
            rates.append(moved / (ms * 1e6))
    finally:
        src.release()
        dst.release()
    return Peak(float(statistics.median(rates)), tuple(rates), nbytes, moved)


# -- clpeak ----------------------------------------------------------------------------------

def clpeak_indices(device: cl.Device) -> tuple[int, int]:
    """``(platform, device)`` indices of ``device`` as clpeak's ``-p``/``-d`` count them:
    the ICD loader's platform order and each platform's devices of every type (clpeak and
    this process see the same ``OCL_ICD_VENDORS``)."""
    platforms = cl.get_platforms()
    for p, plat in enumerate(platforms):
        for d, dev in enumerate(plat.get_devices()):
            if dev.int_ptr == device.int_ptr:
                return p, d
    raise ValueError(f"device {device.name!r} is on no platform of this process")


def parse_clpeak_xml(text: str) -> dict[str, dict]:
    """``{"platform / device": {width: GB/s}}`` of a clpeak XML dump's global-memory
    bandwidth (widths as clpeak names them, e.g. ``"float4"``; empty for a device without
    that test). Raises ``ValueError`` on text that is not clpeak XML."""
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise ValueError(f"clpeak XML: {exc}") from None
    if root.tag != "clpeak":
        raise ValueError(f"clpeak XML: root element {root.tag!r}, expected 'clpeak'")
    out = {}
    for plat in root.iter("platform"):
        for dev in plat.iter("device"):
            bw = dev.find("global_memory_bandwidth")
            widths = {}
            for child in (() if bw is None else bw):
                try:
                    widths[child.tag] = float(child.text)
                except (TypeError, ValueError):
                    raise ValueError(f"clpeak XML: {child.tag} = {child.text!r} is not a "
                                     "number") from None
            out[f"{plat.get('name')} / {dev.get('name')}"] = widths
    return out


def clpeak_bandwidth(device: cl.Device, timeout_s: float = 300.0,
                     executable: str | None = None) -> dict | None:
    """clpeak's global-memory bandwidth of ``device``, or ``None`` when clpeak is not
    installed (``executable`` or ``clpeak`` on ``$PATH``).

    Returns
    -------
    dict or None
        ``gb_per_s`` (``{width: GB/s}``), ``best_gb_per_s`` and ``best_width`` (the fastest
        width), ``command``; or, when clpeak ran but gave no figure (non-zero exit, timeout,
        a dump without this device), ``error`` with the reason and no figures: the bench
        goes on without them.
    """
    exe = executable or shutil.which("clpeak")
    if exe is None or not os.access(exe, os.X_OK):
        return None
    p, d = clpeak_indices(device)
    with tempfile.TemporaryDirectory(prefix="clrecon-clpeak-") as tmp:
        xml = os.path.join(tmp, "clpeak.xml")
        cmd = [exe, "--global-bandwidth", "-p", str(p), "-d", str(d), "--enable-xml-dump",
               "-f", xml]
        shown = " ".join(cmd[:-2])
        try:
            proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s)
        except subprocess.TimeoutExpired:
            return {"command": shown, "error": f"timed out after {timeout_s:g} s"}
        except OSError as exc:
            return {"command": shown, "error": f"could not run: {exc}"}
        if proc.returncode != 0:
            tail = (proc.stderr or proc.stdout).strip().splitlines()[-1:] or [""]
            return {"command": shown, "error": f"exit status {proc.returncode}: {tail[0]}"}
        try:
            with open(xml, encoding="utf-8") as fh:
                found = parse_clpeak_xml(fh.read())
        except (OSError, ValueError) as exc:
            return {"command": shown, "error": str(exc)}
    names = list(found)
    if len(found) != 1 or not names[0].endswith(f" / {device.name.strip()}"):
        return {"command": shown, "error": f"expected the figures of {device.name.strip()!r} "
                                           f"alone, got {names}"}
    (widths,) = found.values()
    if not widths:
        return {"command": shown, "error": "no global-memory bandwidth in clpeak's dump"}
    best = max(widths, key=widths.get)
    return {"command": shown, "gb_per_s": widths, "best_width": best,
            "best_gb_per_s": widths[best]}
