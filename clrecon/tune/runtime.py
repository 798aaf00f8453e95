"""Run-time side of tuning: which configuration a pass uses on this device for this frame.

``tuned(context, tunable, info)`` walks the fallback chain of :func:`clrecon.tune.db.lookup`
(env override, exact device with the same kernel hash, same vendor and type, the default of
the pass's declaration (:class:`~clrecon.tune.tunable.Tunable`) for the device's type,
runtime chooses) once per device, pass, bucket and kernel hash per process. The declared
defaults are shaped for CPUs (one to eight work-items a group in places); a GPU gets the
declared GPU default instead (:func:`default_config`). Whatever the chain finds, except an
environment or API override (the caller's explicit choice, refused by the pass if the
device cannot launch it), is fitted to the device's maximum
work-group size (:func:`fit_config`): an entry of another device of the same vendor may
have tuned a larger group than this one takes. Local memory depends on knobs the lookup
does not see (spp, scales): the passes that use it fit their configuration themselves and
check the built kernel with :func:`check_kernel_fits`.

The lookup imports the declarations' module and the database only: no pass, no runner.
"""
from __future__ import annotations

import contextlib
import contextvars
import os
from collections.abc import Iterator, Mapping
from typing import TYPE_CHECKING, Union

import pyopencl as cl

from clrecon.core.device import describe, source_hash
from clrecon.core.samples import FrameInfo
from clrecon.tune.db import Lookup, bucket_for, lookup
from clrecon.tune.tunable import PASS_NAMES, Tunable

if TYPE_CHECKING:
    from clrecon.core.device import DeviceInfo

_cache: dict[tuple, Lookup] = {}

#: what :func:`override_tuning` set for this thread (or task): None, "default" or a mapping
_override: contextvars.ContextVar = contextvars.ContextVar("clrecon_tuning", default=None)

Override = Union[str, Mapping[str, Union[dict, None]]]


def override_key() -> object:
    """A hashable form of the override in force (``None`` outside :func:`override_tuning`):
    what a cache of pipelines built under it must key on (:func:`clrecon.api.run` does)."""
    value = _override.get()
    if isinstance(value, dict):
        return tuple(sorted((k, None if v is None else tuple(sorted(v.items())))
                            for k, v in value.items()))
    return value


@contextlib.contextmanager
def override_tuning(override: Override) -> Iterator[None]:
    """Within the block, pipelines built in this thread take their launch configurations
    from ``override`` instead of the tuning database.

    ``"default"``: every pass its default for the device's type, fitted to the device
    (lookup level ``"default"``), as if no tuning entry existed; what the device bench
    compares tuned runs against. A mapping ``{pass: config}``: those passes get exactly
    that configuration (``None``: the runtime chooses), source ``"override"``, and the
    pass refuses one the device cannot launch, as it does an environment override; passes
    not named take the usual chain. The environment override ``CLRECON_TUNE_<PASS>`` is
    the same thing for a whole process; this one wins over it inside the block. Pass names
    are checked against :data:`~clrecon.tune.tunable.PASS_NAMES` (known before any method
    is imported); an unknown one raises ``ValueError``."""
    if isinstance(override, str):
        if override != "default":
            raise ValueError(f"override_tuning: expected 'default' or a mapping of pass "
                             f"names to configurations, got {override!r}")
        value: object = "default"
    elif isinstance(override, Mapping):
        value = {}
        for name, cfg in override.items():
            if name not in PASS_NAMES:
                raise ValueError(f"override_tuning: unknown pass {name!r} (passes: "
                                 f"{', '.join(sorted(PASS_NAMES))})")
            if cfg is not None and not isinstance(cfg, dict):
                raise ValueError(f"override_tuning: {name}: expected a dict or None, "
                                 f"got {cfg!r}")
            value[name] = None if cfg is None else dict(cfg)
    else:
        raise ValueError(f"override_tuning: expected 'default' or a mapping, got "
                         f"{type(override).__name__}")
    token = _override.set(value)
    try:
        yield
    finally:
        _override.reset(token)


def _halve_to(n: int, limit: int) -> int:
    while n > limit and n > 1:
        n //= 2
    return n


def fit_config(config: dict | None, max_work_group_size: int) -> dict | None:
    """``config`` with its work-group size brought within ``max_work_group_size``.

    ``wg_x * wg_y`` (``wg_y`` halved first, keeping rows of ``wg_x`` items), ``wg``,
    ``group`` (halved) and ``tile`` (``tile ** 2`` items; halved) shrink until they fit; the
    other keys are kept. ``None`` (runtime chooses) stays ``None``."""
    if config is None:
        return None
    cfg = dict(config)
    limit = max(int(max_work_group_size), 1)
    if "wg_x" in cfg and "wg_y" in cfg:
        x, y = int(cfg["wg_x"]), int(cfg["wg_y"])
        while x * y > limit and y > 1:
            y //= 2
        while x * y > limit and x > 1:
            x //= 2
        cfg["wg_x"], cfg["wg_y"] = x, y
    for key in ("wg", "group"):
        if key in cfg:
            cfg[key] = _halve_to(int(cfg[key]), limit)
    if "tile" in cfg:
        t = int(cfg["tile"])
        while t * t > limit and t > 1:
            t //= 2
        cfg["tile"] = t
    return cfg


def default_config(tunable: Tunable, info: DeviceInfo) -> dict | None:
    """The configuration the pass ``tunable`` declares gets on the device ``info`` describes
    when no tuning entry applies: its GPU default on a GPU, its default elsewhere, fitted
    to the device's maximum work-group size (:func:`fit_config`)."""
    return fit_config(tunable.default_for(info.device_type), info.max_work_group_size)


def resolve(info: DeviceInfo, tunable: Tunable, bucket: str, digest: str,
            root=None) -> Lookup:
    """The fallback chain for a described device (no OpenCL: :func:`tuned` is this plus the
    device query and a cache). The default level is :func:`default_config`; every level
    but the environment override is fitted to the device (:func:`fit_config`)."""
    name = tunable.name
    found = lookup(info, name, bucket, digest, {name: default_config(tunable, info)}, root)
    if found.source == "env":
        return found
    return Lookup(fit_config(found.config, info.max_work_group_size), found.source, found.path)


def tuned(context: cl.Context, tunable: Tunable, info: FrameInfo) -> Lookup:
    """The configuration the pass ``tunable`` declares should use for frames like ``info``
    on ``context``."""
    name = tunable.name
    dev = context.devices[0]
    forced = _override.get()
    if forced == "default":
        return Lookup(default_config(tunable, describe(dev)), "default", None)
    if isinstance(forced, dict) and name in forced:
        cfg = forced[name]
        return Lookup(None if cfg is None else dict(cfg), "override", None)
    bucket = bucket_for(info.width, info.height, info.spp)
    digest = source_hash(tunable.kernel_file)
    env = os.environ.get(f"CLRECON_TUNE_{name.upper()}")
    key = (dev.int_ptr, name, bucket, digest, env)
    if key not in _cache:
        _cache[key] = resolve(describe(dev), tunable, bucket, digest)
    return _cache[key]


def check_kernel_fits(kernel: cl.Kernel, device: cl.Device, pass_name: str, items: int,
                      config: str) -> None:
    """Refuse, with a ``ValueError`` naming the need and the limit, a built kernel the device
    cannot launch with ``items`` work-items a group: the local memory the compiler allotted
    it (``CL_KERNEL_LOCAL_MEM_SIZE``, its own arrays) beyond the device's, or more items than
    the kernel's own work-group limit (which private memory lowers below the device's on
    Intel's CPU runtime). ``config`` says what was asked for. The passes size their local
    arrays on the host first; this is the compiler's word on the same question."""
    info = cl.kernel_work_group_info
    dev = device.name.strip()
    need = int(kernel.get_work_group_info(info.LOCAL_MEM_SIZE, device))
    have = int(device.local_mem_size)
    if need > have:
        raise ValueError(f"{pass_name}: {config} needs {need} bytes of local memory; the "
                         f"device has {have} ({dev})")
    limit = int(kernel.get_work_group_info(info.WORK_GROUP_SIZE, device))
    if items > limit:
        raise ValueError(f"{pass_name}: {config} launches {items} work-items a group; the "
                         f"built kernel takes at most {limit} ({dev})")


def clear_cache() -> None:
    """Forget looked-up configurations (after a tuning run wrote new entries)."""
    _cache.clear()
