"""The on-disk cache of program binaries, so that a second process does not compile again.

One file per device binary: in ``$CLRECON_CACHE_DIR`` if set (``off`` or empty turns the
disk cache off), else ``$XDG_CACHE_HOME/clrecon/programs`` or ``~/.cache/clrecon/programs``.
An entry is keyed by the source, the headers, the build options and the device identity
(platform name and version, device name, driver version, device version); a multi-device
context looks up one entry per device and uses them only if every device has one. A
missing, unreadable, corrupt or rejected entry means a build from source; a cache that
cannot be written (read-only home, full disk) never fails a build. Used by
:func:`clrecon.core.build.build_source`; :func:`program_cache_dir` and
:func:`program_cache_stats` are re-exported by :mod:`clrecon.core.device`.
"""
from __future__ import annotations

import hashlib
import logging
import os
from pathlib import Path

import pyopencl as cl

from clrecon.core.fsutil import ENV_CACHE_DIR, cache_dir, write_atomic

#: the device layer's logger (one name for selection, builds and the program cache)
logger = logging.getLogger("clrecon.core.device")

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


def cache_entries(context: cl.Context, source_digest: str, headers: str,
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


def load_cached(context: cl.Context, entries: list[tuple[cl.Device, Path]],
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


def store_cached(prg: cl.Program, entries: list[tuple[cl.Device, Path]], label: str) -> None:
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
