"""Run-time side of tuning: which configuration a pass uses on this device for this frame.

``tuned(context, pass_name, info)`` walks the fallback chain of :func:`clrecon.tune.db.lookup`
(env override, exact device with the same kernel hash, same vendor and type, the global
default of the pass's spec, runtime chooses) once per device, pass, bucket and kernel hash
per process.
"""
from __future__ import annotations

import os

import pyopencl as cl

from ..device import describe, source_hash
from ..samples import FrameInfo
from .db import Lookup, bucket_for, lookup
from .specs import DEFAULTS, SPECS

_cache: dict[tuple, Lookup] = {}


def tuned(context: cl.Context, pass_name: str, info: FrameInfo) -> Lookup:
    """The configuration ``pass_name`` should use for frames like ``info`` on ``context``."""
    spec = SPECS[pass_name]
    dev = context.devices[0]
    bucket = bucket_for(info.width, info.height, info.spp)
    digest = source_hash(spec.kernel_file)
    env = os.environ.get(f"CLRECON_TUNE_{pass_name.upper()}")
    key = (dev.int_ptr, pass_name, bucket, digest, env)
    if key not in _cache:
        _cache[key] = lookup(describe(dev), pass_name, bucket, digest, DEFAULTS)
    return _cache[key]


def clear_cache() -> None:
    """Forget looked-up configurations (after a tuning run wrote new entries)."""
    _cache.clear()
