"""OpenCL device layer: enumerate and choose devices, profiling queues, cached program builds.

The library never prints; everything here either returns data or raises
:class:`~clrecon.core.errors.DeviceError` / :class:`~clrecon.core.errors.KernelBuildError`.

Choosing a device: ``get_device(spec)`` with ``spec`` an index into :func:`list_devices`, a
case-insensitive substring of ``"platform / device"``, or ``None`` (then the environment
variable ``CLRECON_DEVICE``, then the first GPU, then the first device). Converged
references come from :func:`trusted_device` (PoCL), never from that choice.

Programs are built from ``kernels/<name>.cl`` with ``-I kernels/`` and ``-D NAME=VALUE``
options and cached per context, keyed by the source text, the text of every header in
``kernels/`` and the options; ``cl.Kernel`` objects are cached per program.

Compiled programs are also kept on disk, one file per device binary, so that a second
process does not compile again: in ``$CLRECON_CACHE_DIR`` if set (``off`` or empty turns the
disk cache off), else ``$XDG_CACHE_HOME/clrecon/programs`` or ``~/.cache/clrecon/programs``.
An entry is keyed by the source, the headers, the build options and the device identity
(platform name and version, device name, driver version, device version); a multi-device
context looks up one entry per device and uses them only if every device has one. A
missing, unreadable, corrupt or rejected entry means a build from source; a cache that
cannot be written (read-only home, full disk) never fails a build. See
:func:`program_cache_dir` and :func:`program_cache_stats`.
"""
from __future__ import annotations

import hashlib
import logging
import os
import re
import sys
import tempfile
import threading
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Union

import numpy as np
import pyopencl as cl

from clrecon.core.errors import DeviceError, KernelBuildError
from clrecon.core.fsutil import ENV_CACHE_DIR, cache_dir, write_atomic
from clrecon.core.resources import kernels_dir

ENV_DEVICE = "CLRECON_DEVICE"

logger = logging.getLogger(__name__)

DeviceSpec = Union[int, str, None]
Defines = Mapping[str, Union[int, float, str, bool]]


@dataclass(frozen=True)
class DeviceInfo:
    """What a person (and the tuning database) needs to know about one OpenCL device."""

    index: int
    platform: str
    platform_version: str
    name: str
    vendor: str
    driver: str
    version: str
    device_type: str
    compute_units: int
    global_mem_bytes: int
    local_mem_bytes: int
    max_work_group_size: int
    image_support: bool
    int64_atomics: bool
    native_float_atomics: bool

    @property
    def label(self) -> str:
        return f"{self.platform} / {self.name}"

    @property
    def atomics(self) -> str:
        """Short description of the float accumulation paths this device gets."""
        float_path = "native float add" if self.native_float_atomics else "float CAS loop"
        fixed = "int64 fixed point" if self.int64_atomics else "no int64 atomics"
        return f"{float_path}, {fixed}"

    def fingerprint(self) -> dict:
        """Identity used as a tuning-database key (platform kept apart from hardware vendor)."""
        return {
            "platform": self.platform,
            "platform_version": self.platform_version,
            "vendor": self.vendor,
            "device": self.name,
            "driver": self.driver,
            "device_type": self.device_type,
            "compute_units": self.compute_units,
        }


def _type_name(bits: int) -> str:
    for flag, name in ((cl.device_type.GPU, "GPU"), (cl.device_type.CPU, "CPU"),
                       (cl.device_type.ACCELERATOR, "ACCELERATOR")):
        if bits & flag:
            return name
    return "OTHER"


def _info(index: int, dev: cl.Device) -> DeviceInfo:
    ext = dev.extensions.split()
    return DeviceInfo(
        index=index,
        platform=dev.platform.name.strip(),
        platform_version=dev.platform.version.strip(),
        name=dev.name.strip(),
        vendor=dev.vendor.strip(),
        driver=dev.driver_version.strip(),
        version=dev.version.strip(),
        device_type=_type_name(dev.type),
        compute_units=int(dev.max_compute_units),
        global_mem_bytes=int(dev.global_mem_size),
        local_mem_bytes=int(dev.local_mem_size),
        max_work_group_size=int(dev.max_work_group_size),
        image_support=bool(dev.image_support),
        int64_atomics="cl_khr_int64_base_atomics" in ext,
        native_float_atomics="cl_ext_float_atomics" in ext,
    )


def _all_devices() -> list[cl.Device]:
    try:
        platforms = cl.get_platforms()
    except cl.Error as exc:  # no ICD at all
        raise DeviceError(
            "no OpenCL platform found; install a driver (e.g. `apt-get install "
            "pocl-opencl-icd` for the CPU)"
        ) from exc
    devices = []
    for plat in platforms:
        try:
            devices.extend(plat.get_devices())
        except cl.Error:  # a platform with no devices of any type
            continue
    return devices


def list_devices() -> list[DeviceInfo]:
    """Every OpenCL device on every platform, in a stable order (the index of ``--device``)."""
    return [_info(i, d) for i, d in enumerate(_all_devices())]


def _check_spec(spec, name: str = "device"):
    """``spec`` if it is a device index, a name substring or ``None``; a ``TypeError``
    (``KnobTypeError``) or ``ValueError`` naming the argument otherwise."""
    from clrecon.core.knobs import KnobTypeError

    if spec is None:
        return None
    if isinstance(spec, (bool, np.bool_)) or not isinstance(spec, (int, np.integer, str)):
        raise KnobTypeError(f"{name}: must be a device index (int), a name substring (str), "
                            f"a Device or None, got {spec!r} ({type(spec).__name__})")
    if isinstance(spec, str):
        if not spec.strip():
            raise ValueError(f"{name}: empty device name (give an index, a substring of "
                             f"'platform / device' or None)")
        return spec
    return int(spec)


def _pick(spec: DeviceSpec) -> tuple[int, cl.Device]:
    spec = _check_spec(spec)
    devices = _all_devices()
    if not devices:
        raise DeviceError("no OpenCL device found on any platform")
    if spec is None:
        spec = _check_spec(os.environ.get(ENV_DEVICE, "").strip() or None, ENV_DEVICE)
    if spec is None:
        gpus = [i for i, d in enumerate(devices) if d.type & cl.device_type.GPU]
        i = gpus[0] if gpus else 0
        return i, devices[i]
    if isinstance(spec, str) and spec.strip().isdigit():
        spec = int(spec)
    labels = [f"{d.platform.name.strip()} / {d.name.strip()}" for d in devices]
    if isinstance(spec, int):
        if not 0 <= spec < len(devices):
            raise DeviceError(f"device index {spec} out of range; devices: {labels}")
        return spec, devices[spec]
    matches = [i for i, lab in enumerate(labels) if spec.lower() in lab.lower()]
    if not matches:
        raise DeviceError(f"no OpenCL device matches {spec!r}; devices: {labels}")
    return matches[0], devices[matches[0]]


@dataclass(eq=False)
class Device:
    """One OpenCL device with its context and an in-order profiling queue."""

    info: DeviceInfo
    device: cl.Device
    context: cl.Context
    queue: cl.CommandQueue = field(repr=False)

    def program(self, name: str, defines: Defines | None = None) -> cl.Program:
        return build_program(self.context, name, defines)

    def kernel(self, name: str, kernel_name: str, defines: Defines | None = None) -> cl.Kernel:
        return get_kernel(self.context, name, kernel_name, defines)


_devices: dict[int, Device] = {}


def get_device(spec: DeviceSpec = None) -> Device:
    """The :class:`Device` for ``spec`` (see module docstring); one per device per process."""
    if isinstance(spec, Device):
        return spec
    index, dev = _pick(spec)
    if index not in _devices:
        ctx = cl.Context([dev])
        queue = cl.CommandQueue(ctx, properties=cl.command_queue_properties.PROFILING_ENABLE)
        _devices[index] = Device(_info(index, dev), dev, ctx, queue)
    return _devices[index]


#: the platform converged references come from (:func:`trusted_device`)
TRUSTED_PLATFORM = "Portable Computing Language"


def trusted_device() -> Device:
    """The device converged references are rendered on: PoCL's CPU device (else another PoCL
    device), whatever ``CLRECON_DEVICE`` or ``--device`` choose. A reference made on the
    device under test would carry that device's own faults into the image it is compared
    with (Intel's CPU compiler once returned garbage from ``raytrace_reference``, and the
    comparisons agreed with it); PoCL is the platform CI checks against the NumPy tracer.
    Raises :class:`~clrecon.core.errors.DeviceError` where no PoCL device is registered."""
    devices = _all_devices()
    pocl = [i for i, d in enumerate(devices) if d.platform.name.strip() == TRUSTED_PLATFORM]
    if not pocl:
        labels = [f"{d.platform.name.strip()} / {d.name.strip()}" for d in devices]
        raise DeviceError(
            f"no trusted device for references: they are rendered on PoCL ('{TRUSTED_PLATFORM}'"
            f"), which is not among the devices {labels}; install it (`bash run.sh setup`) and, "
            f"where OCL_ICD_VENDORS is set, put its .icd file in that folder too (or, from "
            f"Python, give render_reference the device= to render on)")
    cpus = [i for i in pocl if devices[i].type & cl.device_type.CPU]
    return get_device((cpus or pocl)[0])


def describe(dev: cl.Device) -> DeviceInfo:
    """:class:`DeviceInfo` of any ``cl.Device`` (index -1 if it is not in the list)."""
    for i, d in enumerate(_all_devices()):
        if d.int_ptr == dev.int_ptr:
            return _info(i, d)
    return _info(-1, dev)


def from_queue(queue: cl.CommandQueue) -> DeviceInfo:
    """Describe the device of a caller's queue (for embedding in a foreign pipeline)."""
    return describe(queue.device)


# -- program building ----------------------------------------------------------------------

def build_options(defines: Defines | None = None,
                  devices: list[cl.Device] | None = None) -> list[str]:
    """``-I kernels/`` plus ``-D NAME=VALUE`` for each define, in sorted order; given the
    ``devices`` a program is built for, then their :func:`language_options`."""
    opts = [f"-I{kernels_dir()}"]
    for key in sorted(defines or {}):
        val = defines[key]
        if isinstance(val, bool):
            val = int(val)
        if isinstance(val, float):
            val = f"{val!r}f"
        opts.append(f"-D{key}={val}")
    if devices:
        opts += language_options(devices)
    return opts


# -- OpenCL C version and native float atomics ---------------------------------------------
#: CL_DEVICE_SINGLE_FP_ATOMIC_CAPABILITIES_EXT (cl_ext_float_atomics; pyopencl has no name
#: for it) and its bit CL_DEVICE_GLOBAL_FP_ATOMIC_ADD_EXT
_FP32_ATOMIC_CAPS, _GLOBAL_FP_ATOMIC_ADD = 0x4231, 1 << 1
_language: dict[int, tuple[str, ...]] = {}


def opencl_c_std(dev: cl.Device) -> str | None:
    """The ``-cl-std`` value builds for ``dev`` pass: ``"CL3.0"`` or ``"CL2.0"`` where its
    compiler accepts it, ``None`` for an OpenCL C 1.x compiler.

    Without ``-cl-std`` a compiler builds the highest OpenCL C 1.x it supports (the OpenCL
    rule; measured: Intel's CPU runtime 1.2, PoCL 3.1 already 3.0), and 1.x has no
    ``atomic_float``. An OpenCL 3.0 device lists its versions
    (``CL_DEVICE_OPENCL_C_ALL_VERSIONS``); an older one has only ``CL_DEVICE_OPENCL_C_VERSION``
    (Oclgrind 21.10, an OpenCL 1.2 device, answers the 3.0 query with a list holding 3.0 and
    then fails to build with ``-cl-std=CL3.0``: the list is read only on 3.0 devices)."""
    m = re.match(r"OpenCL (\d+)\.(\d+)", dev.version)
    versions: set[tuple[int, int]] = set()
    if m and int(m.group(1)) >= 3:
        try:
            for v in dev.get_info(cl.device_info.OPENCL_C_ALL_VERSIONS):
                versions.add((v.version >> 22, (v.version >> 12) & 0x3FF))
        except (cl.Error, AttributeError):  # a driver that does not answer: 1.x below
            pass
    c = re.match(r"OpenCL C (\d+)\.(\d+)", dev.opencl_c_version)
    if c:
        versions.add((int(c.group(1)), int(c.group(2))))
    if (3, 0) in versions:
        return "CL3.0"
    return "CL2.0" if any(v[0] == 2 for v in versions) else None


def native_fp32_atomic_add(dev: cl.Device) -> bool:
    """Whether ``dev`` adds floats atomically in global memory itself (cl_ext_float_atomics
    with the fp32 global add capability) and its builds are OpenCL C 2.0 or later: then
    ``atomic_add_f32`` (``kernels/common.h``) uses ``atomic_fetch_add_explicit``, elsewhere a
    compare-and-swap loop. The capability is queried through the ICD loader (pyopencl has
    no name for it); where that query is not possible the extension alone decides.

    The kernels learn it from ``-DCLRECON_FP32_ATOMIC_ADD=1``: the feature macro the
    extension defines for the compiler (``__opencl_c_ext_fp32_global_atomic_add``) is not
    defined by Intel's CPU compiler (2026.2, OpenCL C 3.0), which does provide the
    function."""
    if "cl_ext_float_atomics" not in dev.extensions.split() or opencl_c_std(dev) is None:
        return False
    caps = _query_ulong(dev, _FP32_ATOMIC_CAPS)
    return True if caps is None else bool(caps & _GLOBAL_FP_ATOMIC_ADD)


def _query_ulong(dev: cl.Device, param: int) -> int | None:
    """A ``cl_ulong`` device info through the ICD loader pyopencl uses (``None``: no loader
    found or the query failed)."""
    import ctypes
    import ctypes.util

    here = Path(cl.__file__).parent
    names = [str(p) for p in sorted((here / ".libs").glob("libOpenCL*"))]
    names += [n for n in (ctypes.util.find_library("OpenCL"), "libOpenCL.so.1") if n]
    for name in names:
        try:
            fn = ctypes.CDLL(name).clGetDeviceInfo
        except (OSError, AttributeError):
            continue
        fn.argtypes = [ctypes.c_void_p, ctypes.c_uint, ctypes.c_size_t, ctypes.c_void_p,
                       ctypes.c_void_p]
        fn.restype = ctypes.c_int
        val = ctypes.c_uint64(0)
        ok = fn(ctypes.c_void_p(dev.int_ptr), param, 8, ctypes.byref(val), None) == 0
        return int(val.value) if ok else None
    return None


def language_options(devices: list[cl.Device]) -> list[str]:
    """``-cl-std`` (:func:`opencl_c_std`) and ``-DCLRECON_FP32_ATOMIC_ADD=1``
    (:func:`native_fp32_atomic_add`) for a program built for ``devices``: one program for
    all of them, so devices that disagree get the compilers' defaults (1.x, CAS loops)."""
    per = []
    for dev in devices:
        if dev.int_ptr not in _language:
            opts = []
            std = opencl_c_std(dev)
            if std:
                opts.append(f"-cl-std={std}")
                if native_fp32_atomic_add(dev):
                    opts.append("-DCLRECON_FP32_ATOMIC_ADD=1")
            _language[dev.int_ptr] = tuple(opts)
        per.append(_language[dev.int_ptr])
    return list(per[0]) if all(p == per[0] for p in per) else []


_file_cache: dict[Path, tuple[int, bytes]] = {}


def _read(path: Path) -> bytes:
    """File bytes, re-read only when the modification time changes (builds look sources up
    on every pass construction; an edited kernel is still seen)."""
    mtime = path.stat().st_mtime_ns
    hit = _file_cache.get(path)
    if hit is None or hit[0] != mtime:
        hit = (mtime, path.read_bytes())
        _file_cache[path] = hit
    return hit[1]


def kernel_source(name: str) -> str:
    """Text of ``kernels/<name>.cl`` (``name`` with or without the extension)."""
    path = kernels_dir() / (name if name.endswith(".cl") else f"{name}.cl")
    if not path.is_file():
        raise FileNotFoundError(f"kernel file {path} not found")
    return _read(path).decode()


_INCLUDE = re.compile(r'^\s*#\s*include\s+"([^"]+)"', re.M)


def _included_headers(source: str) -> set[Path]:
    """Headers of ``kernels/`` that ``source`` includes, transitively."""
    found: set[Path] = set()
    todo = [source]
    while todo:
        for name in _INCLUDE.findall(todo.pop()):
            p = kernels_dir() / name
            if p.is_file() and p not in found:
                found.add(p)
                todo.append(_read(p).decode())
    return found


def _headers_digest(source: str | None = None) -> str:
    """Digest of every header in ``kernels/`` or, given a source, of those it includes."""
    h = hashlib.sha256()
    paths = kernels_dir().glob("*.h") if source is None else _included_headers(source)
    for p in sorted(paths):
        h.update(p.name.encode())
        h.update(_read(p))
    return h.hexdigest()


def source_hash(name: str) -> str:
    """Hash of a kernel file together with the headers it includes (tuning entries key on
    it; a method's own header does not make other methods' entries stale)."""
    src = kernel_source(name)
    return hashlib.sha256((src + _headers_digest(src)).encode()).hexdigest()[:16]


_programs: dict[tuple, tuple[cl.Context, cl.Program]] = {}
_kernels: dict[tuple, cl.Kernel] = {}


#: re-emit what a build writes to file descriptor 2 (compiler chatter) to stderr; the CLI
#: sets it with ``--verbose``. Off, that text goes only to the ``clrecon.core.device`` debug log
#: (and into :class:`~clrecon.core.errors.KernelBuildError` when the build fails).
ECHO_BUILD_OUTPUT = False

_fd2_lock = threading.Lock()


class _CaptureFd2:
    """Redirect file descriptor 2 into a temporary file for the duration of a build: PoCL's
    compiler writes its diagnostics summary ("30 warnings generated.") there itself, past
    Python's ``sys.stderr``. Builds take a lock (fd 2 is the process's, not a thread's);
    fd 2 is restored in any case, and ``text`` holds what was written. A host where fd 2
    cannot be duplicated builds uncaptured."""

    def __init__(self):
        self.text = ""
        self._saved = self._tmp = None

    def __enter__(self):
        _fd2_lock.acquire()
        try:
            _flush_stderr()
            self._tmp = tempfile.TemporaryFile()
            self._saved = os.dup(2)
            os.dup2(self._tmp.fileno(), 2)
        except OSError as exc:
            logger.debug("build output: not captured (%s)", exc)
            if self._saved is not None:
                os.close(self._saved)
                self._saved = None
        except BaseException:
            _fd2_lock.release()
            raise
        return self

    def __exit__(self, *exc_info):
        try:
            if self._saved is not None:
                _flush_stderr()
                try:
                    os.dup2(self._saved, 2)
                finally:
                    os.close(self._saved)
            if self._tmp is not None:
                self._tmp.seek(0)
                self.text = self._tmp.read().decode(errors="replace")
                self._tmp.close()
        finally:
            _fd2_lock.release()
        return False


def _flush_stderr() -> None:
    try:
        sys.stderr.flush()
    except Exception:  # a closed or odd stderr: nothing to flush
        pass


def _report_build_output(label: str, text: str) -> None:
    if not text.strip():
        return
    logger.debug("build output of %s:\n%s", label, text.rstrip())
    if ECHO_BUILD_OUTPUT:
        try:
            sys.stderr.write(text)
            sys.stderr.flush()
        except Exception:
            pass


def build_source(
    context: cl.Context, source: str, defines: Defines | None = None, label: str = "<source>"
) -> cl.Program:
    """Build OpenCL C ``source`` for ``context`` (cached in the process and on disk; includes
    resolve in ``kernels/``). What the compiler writes to file descriptor 2 is captured: it
    is logged at debug level on ``clrecon.core.device``, part of the
    :class:`~clrecon.core.errors.KernelBuildError` of a failed build, and echoed to stderr only
    with :data:`ECHO_BUILD_OUTPUT`."""
    options = build_options(defines, context.devices)
    source_digest = hashlib.sha256(source.encode()).hexdigest()
    headers = _headers_digest()
    key = (context.int_ptr, source_digest, headers, tuple(options))
    hit = _programs.get(key)
    if hit is not None:
        return hit[1]
    entries = _cache_entries(context, source_digest, headers, options)
    prg = None
    if entries:
        with _CaptureFd2() as capture:
            prg = _load_cached(context, entries, options, label)
        _report_build_output(label, capture.text)
    if prg is None:
        prg = cl.Program(context, source)
        capture = _CaptureFd2()
        try:
            with capture:
                # pyopencl's own binary cache would not see edits of included headers reliably
                prg.build(options=options, cache_dir=False)
        except cl.Error as exc:
            log = _build_log(prg, context) or str(exc)
            extra = capture.text.strip()
            if extra and extra not in log:
                log = f"{log.rstrip()}\n{extra}"
            logger.debug("build output of %s:\n%s", label, capture.text.rstrip())
            raise KernelBuildError(label, options, log) from exc
        _report_build_output(label, capture.text)
        if entries:  # asking for the binaries may compile again (PoCL)
            with _CaptureFd2() as capture:
                _store_cached(prg, entries, label)
            _report_build_output(label, capture.text)
    _programs[key] = (context, prg)
    return prg


# -- on-disk binary cache ------------------------------------------------------------------

_CACHE_FORMAT = "clrecon-program-cache/1"
_CACHE_MAGIC = b"CLRPRG1\n"
_CACHE_SUFFIX = ".clbin"
_cache_stats = {"hits": 0, "misses": 0, "writes": 0, "errors": 0}


def program_cache_dir() -> Path | None:
    """Folder of the on-disk program cache, or ``None`` when it is turned off.

    ``$CLRECON_CACHE_DIR`` (``off`` or empty: no disk cache), else
    ``$XDG_CACHE_HOME/clrecon/programs``, else ``~/.cache/clrecon/programs``. Read on every
    build, so a change of the environment takes effect for programs not yet built. Without
    ``$CLRECON_CACHE_DIR`` a PoCL device relies on PoCL's own kernel cache instead
    (:func:`_self_caching`).
    """
    return cache_dir("programs", env_subdir=False)


def program_cache_stats() -> dict[str, int]:
    """Counters of the on-disk program cache in this process (a copy).

    ``hits``: programs built from cached binaries; ``misses``: programs looked up and built
    from source (an entry absent, unreadable, corrupt or rejected by the driver);
    ``writes``: binaries written; ``errors``: entries that were corrupt or rejected, and
    writes that failed. Builds with the cache off and in-process hits count nowhere.
    """
    return dict(_cache_stats)


def _self_caching(dev: cl.Device) -> bool:
    """PoCL keeps its own on-disk kernel cache (``~/.cache/pocl``, ``POCL_CACHE_DIR``), which
    pyopencl's ``cache_dir=False`` does not turn off, so a second process already skips the
    compilation there. Asking PoCL for ``BINARIES`` to fill ours makes it compile each
    program's generic work-group function besides (measured: a cold test run 322 -> 480 s),
    for 0.5 s saved per warm start; so on PoCL clrecon's cache is used only when
    ``CLRECON_CACHE_DIR`` asks for it."""
    return "portable computing language" in dev.platform.name.lower()


def _device_identity(dev: cl.Device) -> str:
    plat = dev.platform
    return "\n".join(x.strip() for x in (plat.name, plat.version, dev.name, dev.driver_version,
                                         dev.version))


def _cache_entries(context: cl.Context, source_digest: str, headers: str,
                   options: list[str]) -> list[tuple[cl.Device, Path]] | None:
    """``(device, entry path)`` for every device of ``context``; ``None`` if the cache is off."""
    try:
        folder = program_cache_dir()
        if folder is None:
            return None
        if ENV_CACHE_DIR not in os.environ and all(_self_caching(d) for d in context.devices):
            return None
        common = [_CACHE_FORMAT, ".".join(map(str, cl.VERSION)),
                  os.environ.get("PYOPENCL_BUILD_OPTIONS", ""), source_digest, headers,
                  *options]
        entries = []
        for dev in context.devices:
            h = hashlib.sha256()
            for part in (*common, _device_identity(dev)):
                data = part.encode()
                h.update(len(data).to_bytes(8, "little"))
                h.update(data)
            entries.append((dev, folder / (h.hexdigest() + _CACHE_SUFFIX)))
        return entries
    except Exception as exc:  # never let the cache break a build
        logger.debug("program cache: disabled for this build (%s)", exc)
        return None


def _read_entry(path: Path) -> bytes | None:
    """The binary stored at ``path``; ``None`` if absent; raises ``ValueError`` if corrupt."""
    try:
        data = path.read_bytes()
    except (FileNotFoundError, NotADirectoryError):
        return None
    n = len(_CACHE_MAGIC)
    if len(data) < n + 32 or data[:n] != _CACHE_MAGIC:
        raise ValueError("not a clrecon program cache entry (truncated?)")
    payload = data[n + 32:]
    if hashlib.sha256(payload).digest() != data[n:n + 32] or not payload:
        raise ValueError("checksum mismatch (truncated or corrupt)")
    return payload


def _drop(entries: list[tuple[cl.Device, Path]]) -> None:
    for _, path in entries:
        try:
            path.unlink()
        except OSError:
            pass


def _load_cached(context: cl.Context, entries: list[tuple[cl.Device, Path]],
                 options: list[str], label: str) -> cl.Program | None:
    """The program built from cached binaries, or ``None`` (then build from source)."""
    try:
        binaries = [_read_entry(path) for _, path in entries]
    except Exception as exc:  # unreadable or corrupt
        logger.debug("program cache: dropping an entry of %s: %s", label, exc)
        _cache_stats["errors"] += 1
        _cache_stats["misses"] += 1
        _drop(entries)
        return None
    if any(b is None for b in binaries):
        _cache_stats["misses"] += 1
        return None
    try:
        prg = cl.Program(context, [dev for dev, _ in entries], binaries)
        prg.build(options=options)
    except Exception as exc:  # the driver rejected the binary (e.g. after an update)
        logger.debug("program cache: binary of %s rejected, building from source: %s",
                     label, exc)
        _cache_stats["errors"] += 1
        _cache_stats["misses"] += 1
        _drop(entries)
        return None
    _cache_stats["hits"] += 1
    logger.debug("program cache: %s loaded from %s", label, entries[0][1].parent)
    return prg


def _store_cached(prg: cl.Program, entries: list[tuple[cl.Device, Path]], label: str) -> None:
    """Write the binary of each device of ``entries`` (atomically; failures are logged)."""
    try:
        devices = prg.get_info(cl.program_info.DEVICES)
        binaries = prg.get_info(cl.program_info.BINARIES)
        by_device = {d.int_ptr: b for d, b in zip(devices, binaries)}
        for dev, path in entries:
            binary = bytes(by_device.get(dev.int_ptr) or b"")
            if not binary:
                logger.debug("program cache: no binary of %s for %s", label, dev.name)
                continue
            data = _CACHE_MAGIC + hashlib.sha256(binary).digest() + binary
            path.parent.mkdir(parents=True, exist_ok=True)
            write_atomic(path, data)
            _cache_stats["writes"] += 1
    except Exception as exc:  # read-only or full disk, odd driver: keep the built program
        logger.debug("program cache: could not store %s: %s", label, exc)
        _cache_stats["errors"] += 1


def _build_log(prg: cl.Program, context: cl.Context) -> str:
    logs = []
    for dev in context.devices:
        try:
            logs.append(prg.get_build_info(dev, cl.program_build_info.LOG))
        except cl.Error:
            pass
    return "\n".join(x for x in logs if x and x.strip())


def build_program(context: cl.Context, name: str, defines: Defines | None = None) -> cl.Program:
    """Build ``kernels/<name>.cl`` for ``context`` with ``defines`` (cached)."""
    return build_source(context, kernel_source(name), defines, label=f"kernels/{name}.cl")


def get_kernel(
    context: cl.Context, name: str, kernel_name: str, defines: Defines | None = None
) -> cl.Kernel:
    """A cached ``cl.Kernel`` for ``kernel_name`` in ``kernels/<name>.cl``."""
    prg = build_program(context, name, defines)
    key = (id(prg), kernel_name)
    k = _kernels.get(key)
    if k is None:
        k = cl.Kernel(prg, kernel_name)
        _kernels[key] = k
    return k


def event_ms(event: cl.Event) -> float:
    """Device time of a completed profiling event, in milliseconds."""
    return (event.profile.end - event.profile.start) * 1e-6


def fixed_to_float(values, shift: int = 20):
    """Convert int64 fixed-point sums written by ``atomic_add_fixed`` to float32."""
    return (np.asarray(values, dtype=np.int64).astype(np.float64) / float(1 << shift)).astype(
        np.float32
    )
