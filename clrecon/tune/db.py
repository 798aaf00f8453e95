"""The tuning database: one JSON file per OpenCL runtime and device, and the lookup chain.

Layout: ``ROOT/<runtime>/<device>.json`` with ``ROOT`` the package data directory
``tuning/`` (:func:`clrecon.core.resources.tuning_dir`), ``<runtime>`` the slug of the OpenCL
platform name (``portable-computing-language``) and ``<device>`` the slug of the device name.
The runtime is kept apart from the hardware vendor: the same CPU tunes differently under PoCL
and under a vendor runtime. A file holds::

    {"schema": 1,
     "device": DeviceInfo.fingerprint(),
     "entries": {"<pass>|<bucket>": {"pass": ..., "bucket": ..., "source_hash": ...,
                                     "build_options": [...], "default": config,
                                     "best": config, "best_median_ms": ...,
                                     "default_median_ms": ..., "tuned_at": ISO time,
                                     "measurements": [{"config", "status", "times_ms",
                                                       "median_ms", "error",
                                                       "max_abs_err"}, ...]}}}

:func:`lookup` resolves a configuration through the chain environment override ->
exact device -> same vendor and device type -> caller's defaults -> runtime chooses. Entries
whose ``source_hash`` differs from the kernel's current hash are stale and never used; bad
files are skipped with a warning (a tuning file never breaks a reconstruction).
"""
from __future__ import annotations

import json
import logging
import math
import operator
import os
import re
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import TYPE_CHECKING, Union

from clrecon.core.fsutil import write_atomic
from clrecon.core.resources import tuning_dir
from clrecon.tune.tuner import Config, TuneResult

if TYPE_CHECKING:  # no OpenCL import at run time: this module is pure logic
    from clrecon.core.device import DeviceInfo

log = logging.getLogger("clrecon")

SCHEMA_VERSION = 1
ENV_PREFIX = "CLRECON_TUNE_"

#: Pixel-count limits of the size buckets "s" and "m" (larger is "l").
BUCKET_PIXELS = (300_000, 1_200_000)
#: Samples per pixel up to which the bucket is "lo" (more is "hi").
BUCKET_SPP = 8

PathLike = Union[str, "os.PathLike[str]"]


@dataclass(frozen=True)
class Lookup:
    """A resolved configuration and where it came from.

    Attributes
    ----------
    config : dict or None
        The configuration (``None``: the runtime chooses the local size).
    source : str
        ``"env"``, ``"exact"``, ``"vendor"``, ``"default"`` or ``"runtime"``; ``"override"``
        from :func:`clrecon.tune.runtime.override_tuning`.
    path : str or None
        The tuning file it came from (``"exact"`` and ``"vendor"`` only).
    """

    config: Config
    source: str
    path: str | None


def slug(text: str) -> str:
    """Lowercase, runs of non-alphanumerics replaced by ``-``, stripped of ``-``.

    ``"Portable Computing Language"`` -> ``"portable-computing-language"``; an empty result
    becomes ``"unknown"``.
    """
    s = re.sub(r"[^a-z0-9]+", "-", str(text).lower()).strip("-")
    return s or "unknown"


def entry_key(pass_name: str, bucket: str) -> str:
    """Key of an entry in a tuning file: ``"<pass>|<bucket>"``."""
    return f"{pass_name}|{bucket}"


def env_var(pass_name: str) -> str:
    """Name of the environment override of a pass: ``CLRECON_TUNE_<PASS>``."""
    return ENV_PREFIX + re.sub(r"[^A-Z0-9]", "_", pass_name.upper())


def _root(root: PathLike | None) -> Path:
    if root is None:
        return tuning_dir()
    return Path(root)


def db_path(info: DeviceInfo, root: PathLike | None = None) -> Path:
    """The tuning file of a device: ``ROOT/<slug(platform)>/<slug(name)>.json``."""
    return _root(root) / slug(info.platform) / f"{slug(info.name)}.json"


def bucket_for(width: int, height: int, spp: int) -> str:
    """Problem-size bucket of a frame: ``"<size>-<spp>"``.

    Size is ``"s"`` up to 300k pixels, ``"m"`` up to 1.2M, else ``"l"``; samples per pixel
    are ``"lo"`` up to 8, else ``"hi"``. E.g. 640x480 at 4 spp -> ``"m-lo"``.

    Raises
    ------
    ValueError
        A non-positive or non-integer argument.
    """
    vals = []
    for name, v in (("width", width), ("height", height), ("spp", spp)):
        try:
            if isinstance(v, bool):
                raise TypeError
            n = operator.index(v)
        except TypeError:
            raise ValueError(f"{name} must be an integer (got {v!r})") from None
        if n < 1:
            raise ValueError(f"{name} must be >= 1 (got {v!r})")
        vals.append(n)
    w, h, s = vals
    px = w * h
    size = "s" if px <= BUCKET_PIXELS[0] else "m" if px <= BUCKET_PIXELS[1] else "l"
    return f"{size}-{'lo' if s <= BUCKET_SPP else 'hi'}"


# -- reading ---------------------------------------------------------------------------------

def _validate(data: object, path: Path) -> dict:
    if not isinstance(data, dict):
        raise ValueError(f"tuning file {path}: not a JSON object")
    if data.get("schema") != SCHEMA_VERSION:
        raise ValueError(
            f"tuning file {path}: schema {data.get('schema')!r}, this clrecon reads "
            f"schema {SCHEMA_VERSION} (retune or delete the file)"
        )
    if not isinstance(data.get("device"), dict) or not isinstance(data.get("entries"), dict):
        raise ValueError(f"tuning file {path}: missing 'device' or 'entries' object")
    return data


def load(path: PathLike) -> dict:
    """Read and validate one tuning file.

    Raises
    ------
    ValueError
        The file is not valid JSON, not a tuning file, or of another schema version.
    OSError
        The file cannot be read.
    """
    path = Path(path)
    text = path.read_text(encoding="utf-8")
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(f"tuning file {path}: invalid JSON ({exc})") from None
    return _validate(data, path)


_cache: dict[str, tuple[tuple[int, int], dict]] = {}
_warned: set[tuple] = set()


def clear_cache() -> None:
    """Forget the cached files and which warnings were already logged (for tests, tools)."""
    _cache.clear()
    _warned.clear()


def _warn_once(key: tuple, msg: str, *args: object) -> None:
    if key not in _warned:
        _warned.add(key)
        log.warning(msg, *args)


def _read(path: Path) -> dict | None:
    """Load a file for :func:`lookup` (cached by mtime and size); warn and give None if bad."""
    stamp = None
    try:
        st = path.stat()
        stamp = (st.st_mtime_ns, st.st_size)
        hit = _cache.get(str(path))
        if hit is not None and hit[0] == stamp:
            return hit[1]
        data = load(path)
    except (OSError, ValueError) as exc:
        _warn_once((str(path), stamp, "bad"), "ignoring tuning file %s: %s", path, exc)
        return None
    _cache[str(path)] = (stamp, data)
    return data


def _usable(data: dict, path: Path, pass_name: str, bucket: str, source_hash: str
            ) -> tuple[bool, Config]:
    """(found, config) of the entry for pass/bucket in a loaded file; warn if stale/bad."""
    key = entry_key(pass_name, bucket)
    entry = data["entries"].get(key)
    if entry is None:
        return False, None
    if not (isinstance(entry, dict) and "best" in entry
            and (entry["best"] is None or isinstance(entry["best"], dict))):
        _warn_once((str(path), key, "malformed"),
                   "ignoring malformed tuning entry %r in %s (no 'best' object)", key, path)
        return False, None
    stored = entry.get("source_hash")
    if stored != source_hash:
        _warn_once((str(path), key, stored, source_hash),
                   "stale tuning entry for pass %r (bucket %r) in %s: tuned for kernel source "
                   "%s, current source is %s; ignoring it (retune the pass)",
                   pass_name, bucket, path, stored, source_hash)
        return False, None
    best = entry["best"]
    return True, (None if best is None else dict(best))


def _same(a: object, b: object) -> bool:
    return isinstance(a, str) and isinstance(b, str) and a.strip().lower() == b.strip().lower()


def lookup(
    info: DeviceInfo,
    pass_name: str,
    bucket: str,
    source_hash: str,
    defaults: dict[str, Config] | None = None,
    root: PathLike | None = None,
) -> Lookup:
    """The configuration to use for a pass on a device, through the fallback chain.

    1. ``CLRECON_TUNE_<PASS>`` (pass name upper-cased): JSON text of a configuration, or
       ``null`` for "runtime chooses" -> source ``"env"``;
    2. this device's file, entry ``"<pass>|<bucket>"`` with the same ``source_hash`` ->
       ``"exact"``;
    3. any other file under ``root`` whose device has the same vendor and device type, same
       entry and hash -> ``"vendor"``; files of the same runtime (OpenCL platform) first, then
       in sorted path order;
    4. ``defaults[pass_name]`` -> ``"default"``;
    5. ``None`` -> ``"runtime"``.

    Entries with another ``source_hash`` are stale: a warning is logged and they are skipped.
    Unreadable, corrupt or other-schema files are skipped with a warning. Each warning is
    logged once per process (per file state); loaded files are cached by mtime and size.

    Parameters
    ----------
    info : DeviceInfo
        The device.
    pass_name, bucket : str
        The pass and the problem-size bucket (:func:`bucket_for`).
    source_hash : str
        Current :func:`clrecon.core.device.source_hash` of the pass's kernel.
    defaults : dict, optional
        Per-pass configurations used when the database has nothing.
    root : path, optional
        Database root (default: the package's ``tuning/`` directory).

    Returns
    -------
    Lookup

    Raises
    ------
    ValueError
        The environment override is not JSON of an object or ``null``.
    """
    var = env_var(pass_name)
    text = os.environ.get(var)
    if text is not None and text.strip():
        try:
            cfg = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ValueError(f"{var}={text!r} is not valid JSON ({exc})") from None
        if cfg is not None and not isinstance(cfg, dict):
            raise ValueError(f"{var}={text!r} must be a JSON object or null")
        return Lookup(cfg, "env", None)

    base = _root(root)
    own = db_path(info, base)
    if own.is_file():
        data = _read(own)
        if data is not None:
            found, cfg = _usable(data, own, pass_name, bucket, source_hash)
            if found:
                return Lookup(cfg, "exact", str(own))

    if base.is_dir():
        runtime = slug(info.platform)
        others = sorted((p for p in base.glob("*/*.json") if p != own),
                        key=lambda p: (p.parent.name != runtime, str(p)))
        for path in others:
            if not path.is_file():
                continue
            data = _read(path)
            if data is None:
                continue
            dev = data["device"]
            if not (_same(dev.get("vendor"), info.vendor)
                    and _same(dev.get("device_type"), info.device_type)):
                continue
            found, cfg = _usable(data, path, pass_name, bucket, source_hash)
            if found:
                return Lookup(cfg, "vendor", str(path))

    if defaults is not None and pass_name in defaults:
        cfg = defaults[pass_name]
        return Lookup(None if cfg is None else dict(cfg), "default", None)
    return Lookup(None, "runtime", None)


# -- writing ---------------------------------------------------------------------------------

def _finite(x: object) -> object:
    """Non-finite floats as None (strict JSON)."""
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def _entry(result: TuneResult, source_hash: str, build_options: list[str]) -> dict:
    measurements = []
    for m in result.measurements:
        d = m.to_dict()
        d["times_ms"] = [_finite(t) for t in d["times_ms"]]
        d["median_ms"] = _finite(d["median_ms"])
        d["max_abs_err"] = _finite(d["max_abs_err"])
        measurements.append(d)
    return {
        "pass": result.pass_name,
        "bucket": result.bucket,
        "source_hash": source_hash,
        "build_options": [str(o) for o in build_options],
        "default": None if result.default is None else dict(result.default),
        "best": None if result.best is None else dict(result.best),
        "best_median_ms": _finite(result.best_median_ms),
        "confirm_ratio": _finite(result.confirm_ratio),
        "default_median_ms": _finite(result.default_median_ms),
        "tuned_at": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "measurements": measurements,
    }


def save_result(
    info: DeviceInfo,
    result: TuneResult,
    source_hash: str,
    build_options: list[str],
    root: PathLike | None = None,
) -> Path:
    """Store a tuning result in the device's file, keeping its other entries.

    The file is written atomically (temporary file in the same directory, then
    :func:`os.replace`) with sorted keys and ``indent=1``; its ``device`` becomes the current
    :meth:`DeviceInfo.fingerprint`.

    Returns
    -------
    pathlib.Path
        The file written.

    Raises
    ------
    ValueError
        An existing file is corrupt or of another schema (it is not overwritten), or the
        result holds values JSON cannot represent.
    """
    path = db_path(info, root)
    if path.exists():
        data = load(path)
    else:
        data = {"schema": SCHEMA_VERSION, "device": {}, "entries": {}}
    data["schema"] = SCHEMA_VERSION
    data["device"] = info.fingerprint()
    data["entries"][entry_key(result.pass_name, result.bucket)] = _entry(
        result, source_hash, build_options)
    try:
        text = json.dumps(data, sort_keys=True, indent=1, allow_nan=False) + "\n"
    except (TypeError, ValueError) as exc:
        raise ValueError(f"tuning result for {result.pass_name!r} is not JSON: {exc}") from None

    mode = (path.stat().st_mode & 0o777) if path.exists() else 0o644
    path.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(path, text.encode("utf-8"), mode)
    _cache.pop(str(path), None)
    return path
