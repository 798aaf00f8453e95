"""Program building: ``kernels/<name>.cl`` with ``-I kernels/`` and ``-D NAME=VALUE``
options, the OpenCL C version and float-atomics options each device gets, the kernel
sources and their hashes (tuning entries key on them), the compiler output captured from
file descriptor 2, and the in-process caches of programs and kernels (re-exported by
:mod:`clrecon.core.device`).

Programs are cached per context, keyed by the source text, the text of every header in
``kernels/`` and the options; ``cl.Kernel`` objects are cached per program. Compiled
binaries are also kept on disk (:mod:`clrecon.core.program_cache`). Builds log on the
device layer's logger, ``clrecon.core.device``.
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
from pathlib import Path
from typing import Union

import pyopencl as cl

from clrecon.core.errors import KernelBuildError
from clrecon.core.program_cache import cache_entries, load_cached, store_cached
from clrecon.core.resources import kernels_dir

#: the device layer's logger (one name for selection, builds and the program cache)
logger = logging.getLogger("clrecon.core.device")

Defines = Mapping[str, Union[int, float, str, bool]]


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
#: sets it (on this module) with ``--verbose``. Off, that text goes only to the
#: ``clrecon.core.device`` debug log (and into :class:`~clrecon.core.errors.KernelBuildError`
#: when the build fails).
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
    entries = cache_entries(context, source_digest, headers, options)
    prg = None
    if entries:
        with _CaptureFd2() as capture:
            prg = load_cached(context, entries, options, label)
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
                store_cached(prg, entries, label)
            _report_build_output(label, capture.text)
    _programs[key] = (context, prg)
    return prg


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


