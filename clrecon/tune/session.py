"""Tune every pass (or a selection) on one device and store the results in the database."""
from __future__ import annotations

import time

import pyopencl as cl

from clrecon.core.device import Device, DeviceSpec, get_device, source_hash
from clrecon.tune.db import bucket_for, db_path, entry_key, load, save_result
from clrecon.tune.runners import SPECS
from clrecon.tune.runtime import clear_cache
from clrecon.tune.tuner import BudgetExceeded, tune

#: the frame size tuned by default: large enough to be representative, small enough that
#: every pass tunes within minutes on a 2-core CPU
DEFAULT_SIZE = (640, 360)
DEFAULT_SPP = 16


class SessionResults(list):
    """The ``(result, file written)`` pairs of :func:`tune_device`, one per tuned pass, with
    what did not fit: ``skipped`` lists ``(pass, why)`` for each pass left out for the
    budget, ``elapsed_s`` and ``budget_s`` the whole session's seconds."""

    def __init__(self, budget_s: float):
        super().__init__()
        self.skipped: list[tuple[str, str]] = []
        self.budget_s = float(budget_s)
        self.elapsed_s = 0.0


def _options(handle, device: cl.Device) -> list[str]:
    prg = handle.kernel.get_info(cl.kernel_info.PROGRAM)
    return prg.get_build_info(device, cl.program_build_info.OPTIONS).split()


def _known_default_s(info, name: str, bucket: str, runs: int, root) -> float | None:
    """Device seconds the default's warm-up and ``runs`` timed launches took the last time
    this pass and bucket were tuned on this device (its database entry, stale or not: a
    prediction, not a configuration), or ``None`` without one. Device time only: a floor of
    the wall time the measurement will take."""
    try:
        entry = load(db_path(info, root))["entries"].get(entry_key(name, bucket))
        ms = float(entry["default_median_ms"])
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return (1 + runs) * ms * 1e-3 if ms > 0 else None


def tune_device(device: DeviceSpec | Device = None, passes=None, size=DEFAULT_SIZE,
                spp: int = DEFAULT_SPP, budget_s: float = 600.0, runs: int = 7, root=None,
                progress=None, clock=time.perf_counter) -> SessionResults:
    """Tune ``passes`` (default: all) at ``size``/``spp``; returns (result, file written) pairs.

    ``budget_s`` caps the whole session, everything counted: making each pass's inputs,
    measuring its default, its candidates and their confirmation, and saving. Each pass gets
    an equal part of what the earlier ones left for its candidates (:func:`tune`'s
    ``budget_s``, less what its inputs took), and may use the rest of the session for its
    default (``limit_s``). A pass that starts with nothing left, whose default took more
    than what is left when it was last tuned on this device (its database entry), or whose
    default does not fit in what is left, is not tuned and is listed in the result's
    ``skipped``. Nothing is
    interrupted, so the budget can be passed by what one step that cannot be predicted
    takes: making a pass's inputs, a build, the default's warm-up launch (the first time a
    pass runs says how long it runs), one launch slower than its prediction.
    """
    if not budget_s >= 0:
        raise ValueError(f"budget_s must be >= 0 (got {budget_s!r})")
    dev = get_device(device)
    names = list(passes or SPECS)
    unknown = sorted(set(names) - set(SPECS))
    if unknown:
        raise ValueError(f"passes: unknown {unknown}; tunable passes: {sorted(SPECS)}")
    w, h = size
    bucket = bucket_for(w, h, spp)
    out = SessionResults(budget_s)
    start = clock()
    deadline = start + budget_s
    for k, name in enumerate(names):
        spec = SPECS[name]
        left = deadline - clock()
        if left <= 0:
            out.skipped.append((name, f"the {budget_s:g} s budget was spent before it "
                                      "started"))
            continue
        known = _known_default_s(dev.info, name, bucket, runs, root)
        if known is not None and known > left:
            out.skipped.append((name, f"its default alone took {known:.3g} s of device time "
                                      f"when last tuned here, more than the {left:.3g} s left"))
            continue
        share = left / (len(names) - k)
        t = clock()
        runner = spec.runner(dev, w, h, spp)
        setup = clock() - t  # a pass's inputs can take seconds (a full frame, a prepass)
        try:
            result = tune(name, bucket, spec.candidates(), spec.default, runner, runs=runs,
                          budget_s=max(share - setup, 0.0), limit_s=max(left - setup, 0.0),
                          rtol=spec.rtol, atol=spec.atol,
                          device_max_wg=dev.info.max_work_group_size, clock=clock,
                          progress=(lambda d, total, n=name: progress(n, d, total))
                          if progress else None)
        except BudgetExceeded as exc:
            out.skipped.append((name, str(exc)))
            continue
        options = _options(runner.build(spec.default), dev.device)
        path = save_result(dev.info, result, source_hash(spec.kernel_file), options, root)
        out.append((result, str(path)))
    clear_cache()
    out.elapsed_s = float(clock() - start)
    return out
