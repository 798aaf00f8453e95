"""Measuring one configuration of a pass: build, prune, warm up, verify, time, within a budget.

Pure logic, like :mod:`clrecon.tune.tuner` (the search built on it): everything that touches
OpenCL sits behind the :class:`Runner` protocol. :func:`measure` records failures as data
(a :class:`Measurement` with its status) rather than raising; :class:`Budget` predicts what
the next measurement will cost from what the earlier ones cost.
"""
from __future__ import annotations

import json
import math
import statistics
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Optional, Protocol

import numpy as np

Config = Optional[dict]

#: Status values of :class:`Measurement`.
STATUSES = ("ok", "build_error", "pruned", "run_error", "verify_failed", "skipped_budget")


class Runner(Protocol):
    """Builds and launches one pass for a given configuration (real OpenCL lives elsewhere)."""

    def build(self, config: Config) -> object:
        """Compile the pass for ``config``; may raise any exception (recorded as data)."""

    def max_work_group_size(self, handle: Any) -> int | None:
        """The compiled kernel's ``CL_KERNEL_WORK_GROUP_SIZE`` (``None``: unknown)."""

    def local_size(self, config: Config) -> int | None:
        """Work-items per group that ``config`` launches (``None``: the runtime chooses)."""

    def run(self, handle: Any) -> tuple[np.ndarray, float]:
        """One launch: the output array and the device time in ms; may raise."""


@dataclass
class Measurement:
    """What happened to one configuration.

    Attributes
    ----------
    config : dict or None
        The configuration (``None``: the runtime chooses the local size).
    status : str
        One of ``"ok"``, ``"build_error"``, ``"pruned"``, ``"run_error"``, ``"verify_failed"``,
        ``"skipped_budget"``.
    times_ms : list of float
        Device times of the timed runs (warm-up excluded); empty unless ``status == "ok"``.
    median_ms : float or None
        Median of ``times_ms``.
    error : str or None
        Why the configuration was not usable (exception text, pruning reason...).
    max_abs_err : float or None
        Largest absolute difference from the default's output (finite elements only).
    """

    config: Config
    status: str
    times_ms: list[float] = field(default_factory=list)
    median_ms: float | None = None
    error: str | None = None
    max_abs_err: float | None = None

    def to_dict(self) -> dict:
        """Plain JSON-ready dictionary (the layout of the tuning database)."""
        return {
            "config": copy_config(self.config),
            "status": self.status,
            "times_ms": [float(t) for t in self.times_ms],
            "median_ms": self.median_ms,
            "error": self.error,
            "max_abs_err": self.max_abs_err,
        }


def config_key(config: Config) -> str:
    """Canonical text of a configuration: ``json.dumps(config, sort_keys=True)``."""
    return json.dumps(config, sort_keys=True)


def config_sort_key(config: Config) -> tuple[int, str]:
    """Stable sort key of a configuration; ``None`` (runtime chooses) sorts first."""
    return (0, "") if config is None else (1, config_key(config))


def copy_config(config: Config) -> Config:
    return None if config is None else dict(config)


def _exc_text(exc: BaseException) -> str:
    text = str(exc).strip()
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def _compare(out: np.ndarray, ref: np.ndarray, rtol: float, atol: float
             ) -> tuple[bool, float | None, str | None]:
    """(passes, max_abs_err, error text) of ``out`` against the reference ``ref``."""
    if out.shape != ref.shape:
        return False, None, f"output shape {out.shape} != reference shape {ref.shape}"
    a = np.asarray(out, np.float64)
    b = np.asarray(ref, np.float64)
    with np.errstate(invalid="ignore", over="ignore"):
        diff = np.abs(a - b)
    finite = np.isfinite(diff)
    max_err = float(diff[finite].max()) if finite.any() else (0.0 if diff.size == 0 else None)
    if np.allclose(a, b, rtol=rtol, atol=atol, equal_nan=False):
        return True, max_err, None
    with np.errstate(invalid="ignore", over="ignore"):
        bad = ~(diff <= atol + rtol * np.abs(b))
    n_bad = int(bad.sum())
    n_nonfinite = int((bad & ~finite).sum())
    msg = f"{n_bad} of {diff.size} values differ from the default's output"
    if n_nonfinite:
        msg += f" ({n_nonfinite} non-finite)"
    if max_err is not None:
        msg += f"; max abs err {max_err:.3g}"
    return False, max_err, msg


class _Failed(Exception):
    """Internal: a candidate's measurement ended early (carries the measurement)."""

    def __init__(self, measurement: Measurement):
        super().__init__(measurement.error)
        self.measurement = measurement


@dataclass
class Cost:
    """Wall seconds one measurement spent: build, warm-up launch with verification, and
    each timed launch (output read back included); ``None`` where it did not get that far."""

    build_s: float | None = None
    warmup_s: float | None = None
    launch_s: list[float] = field(default_factory=list)


def _median_or(values: list[float], fallback: float) -> float:
    return float(statistics.median(values)) if values else fallback


class Budget:
    """Predicts what a measurement will cost from what the earlier ones cost.

    Builds and warm-ups are predicted from the candidates' (the default's build may have come
    from a cache, and its warm-up made the reference instead of verifying), falling back on
    the default's; a launch from the median launch of every configuration so far."""

    def __init__(self, clock: Callable[[], float], deadline: float | None):
        self.clock, self.deadline = clock, deadline
        self.default: Cost | None = None
        self.others: list[Cost] = []
        self.launch_of: dict[str, float] = {}  # median launch seconds by configuration key

    def add(self, key: str, cost: Cost) -> None:
        if self.default is None:
            self.default = cost
        else:
            self.others.append(cost)
        if cost.launch_s:
            self.launch_of[key] = float(statistics.median(cost.launch_s))

    def left(self) -> float:
        return math.inf if self.deadline is None else self.deadline - self.clock()

    def launch_s(self) -> float:
        return _median_or(list(self.launch_of.values()), 0.0)

    def confirm_s(self, pairs: int, default_key: str, winner_key: str) -> float:
        """Predicted seconds of ``pairs`` paired launches of the default and the winner."""
        return pairs * (self.launch_of.get(default_key, 0.0)
                        + self.launch_of.get(winner_key, self.launch_s()))

    def candidate_s(self, runs: int) -> tuple[float, str]:
        """Predicted seconds of one more candidate, and how the figure was made."""
        d = self.default or Cost()
        build = _median_or([c.build_s for c in self.others if c.build_s is not None],
                           d.build_s or 0.0)
        warm = _median_or([c.warmup_s for c in self.others if c.warmup_s is not None],
                          d.warmup_s or 0.0)
        launch = self.launch_s()
        total = build + warm + runs * launch
        return total, (f"predicted {total:.3g} s: build {build:.3g} s + warm-up and "
                       f"verification {warm:.3g} s + {runs} runs x {launch:.3g} s")


def measure(config: Config, runner: Runner, runs: int, device_max_wg: int | None,
             ref: np.ndarray | None, rtol: float, atol: float,
             clock: Callable[[], float] = time.perf_counter, deadline: float | None = None,
             cost: Cost | None = None, expect_launch_s: float | None = None
             ) -> tuple[Measurement, np.ndarray | None]:
    """Measure one configuration; ``ref is None`` makes its warm-up output the reference.

    With a ``deadline`` (a ``clock()`` value) the timed runs stop, as ``"skipped_budget"``,
    as soon as the ones left would end after it: predicted, before the first, from the
    warm-up launch or ``expect_launch_s`` (the other configurations' launches) whichever is
    shorter (a warm-up may include a one-time work-group compile), then from this
    configuration's own timed launches. What each phase took goes into ``cost``."""
    cfg = copy_config(config)
    cost = Cost() if cost is None else cost

    def fail(status: str, error: str, max_abs_err: float | None = None) -> _Failed:
        return _Failed(Measurement(cfg, status, error=error, max_abs_err=max_abs_err))

    def check_time(done: int, launch_s: float) -> None:
        if deadline is None:
            return
        need, left = (runs - done) * launch_s, deadline - clock()
        if need > left:
            raise fail("skipped_budget", f"stopped after {done} of {runs} timed runs: the "
                                         f"{runs - done} left need ~{need:.3g} s, "
                                         f"{max(left, 0.0):.3g} s of the budget left")

    try:
        try:
            local = runner.local_size(config)
        except Exception as exc:
            raise fail("build_error", f"invalid configuration: {_exc_text(exc)}") from None
        if local is not None and device_max_wg is not None and local > device_max_wg:
            raise fail("pruned", f"local size {local} exceeds the device's maximum work-group "
                                 f"size {device_max_wg}")
        t = clock()
        try:
            handle = runner.build(config)
        except Exception as exc:
            raise fail("build_error", _exc_text(exc)) from None
        finally:
            cost.build_s = clock() - t
        try:
            kernel_max = runner.max_work_group_size(handle)
        except Exception as exc:
            raise fail("build_error", f"kernel work-group size query failed: "
                                      f"{_exc_text(exc)}") from None
        if local is not None and kernel_max is not None and local > kernel_max:
            raise fail("pruned", f"local size {local} exceeds the compiled kernel's "
                                 f"work-group size {kernel_max}")
        t = clock()
        try:
            out, _ = runner.run(handle)  # warm-up: not timed
        except Exception as exc:
            raise fail("run_error", _exc_text(exc)) from None
        warm_launch = clock() - t
        out = np.array(out, copy=True)
        if ref is None:
            ref, max_err = out, 0.0
        else:
            ok, max_err, msg = _compare(out, ref, rtol, atol)
            if not ok:
                raise fail("verify_failed", msg, max_err)
        cost.warmup_s = clock() - t
        first = warm_launch if expect_launch_s is None else min(warm_launch, expect_launch_s)
        times: list[float] = []
        for done in range(runs):
            check_time(done, _median_or(cost.launch_s, first))
            t = clock()
            try:
                _, ms = runner.run(handle)
            except Exception as exc:
                raise fail("run_error", _exc_text(exc)) from None
            finally:
                cost.launch_s.append(clock() - t)
            ms = float(ms)
            if not math.isfinite(ms) or ms < 0:
                raise fail("run_error", f"invalid device time {ms!r} ms")
            times.append(ms)
    except _Failed as failed:
        return failed.measurement, None
    return Measurement(cfg, "ok", times, float(statistics.median(times)), None, max_err), ref
