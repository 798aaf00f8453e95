"""Tune every pass (or a selection) on one device and store the results in the database."""
from __future__ import annotations

import time

import pyopencl as cl

from ..device import Device, DeviceSpec, get_device, source_hash
from .db import bucket_for, save_result
from .runtime import clear_cache
from .specs import SPECS
from .tuner import TuneResult, tune

#: the frame size tuned by default: large enough to be representative, small enough that
#: every pass tunes within minutes on a 2-core CPU
DEFAULT_SIZE = (640, 360)
DEFAULT_SPP = 16


def _options(handle, device: cl.Device) -> list[str]:
    prg = handle.kernel.get_info(cl.kernel_info.PROGRAM)
    return prg.get_build_info(device, cl.program_build_info.OPTIONS).split()


def tune_device(device: DeviceSpec | Device = None, passes=None, size=DEFAULT_SIZE,
                spp: int = DEFAULT_SPP, budget_s: float = 600.0, runs: int = 7, root=None,
                progress=None) -> list[tuple[TuneResult, str]]:
    """Tune ``passes`` (default: all) at ``size``/``spp``; returns (result, file written).

    The budget is shared: each pass gets what the earlier ones left, in equal parts."""
    dev = get_device(device)
    names = list(passes or SPECS)
    unknown = sorted(set(names) - set(SPECS))
    if unknown:
        raise ValueError(f"passes: unknown {unknown}; tunable passes: {sorted(SPECS)}")
    w, h = size
    bucket = bucket_for(w, h, spp)
    out = []
    start = time.perf_counter()
    for k, name in enumerate(names):
        spec = SPECS[name]
        left = budget_s - (time.perf_counter() - start)
        share = max(left / (len(names) - k), 0.0)
        runner = spec.runner(dev, w, h, spp)
        result = tune(name, bucket, spec.candidates(), spec.default, runner, runs=runs,
                      budget_s=share, rtol=spec.rtol, atol=spec.atol,
                      device_max_wg=dev.info.max_work_group_size,
                      progress=(lambda d, t, n=name: progress(n, d, t)) if progress else None)
        options = _options(runner.build(spec.default), dev.device)
        path = save_result(dev.info, result, source_hash(spec.kernel_file), options, root)
        out.append((result, str(path)))
    clear_cache()
    return out
