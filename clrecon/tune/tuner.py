"""Brute-force search of a small configuration space for one pass, device and size bucket.

Pure logic: everything that touches OpenCL sits behind the :class:`Runner` protocol, so the
search, the verification, the pruning and the choice can be tested with a replayed runner.

Practice followed (see ``REFERENCES.md``, "Autotuning practice"):

* the default configuration is measured first and its output is the verification reference;
* every other configuration is pruned by the device's and the compiled kernel's work-group
  limits, built, launched once as a warm-up (PoCL compiles a work-group function per local
  size on the first launch), verified against the reference and then timed ``runs >= 7``
  times; the median decides, never the mean;
* compile errors, launch errors and verification failures are recorded as data, and tuning
  goes on with the next configuration;
* medians within ``tie`` (2 %) of the fastest are ties, broken deterministically: the default
  wins if it is among them, else the smallest configuration by :func:`config_sort_key`;
* the budget is a cap on everything the search does, not a check between candidates: a
  candidate whose predicted cost (build + warm-up and verification + timed runs, from what
  the configurations before it cost) exceeds what is left is skipped, time for the paired
  confirmation is kept back, and a measurement whose remaining runs would pass the budget
  stops (``"skipped_budget"``, with the prediction in its ``error``).
"""
from __future__ import annotations

import json
import math
import statistics
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Callable, Optional, Protocol

import numpy as np

Config = Optional[dict]

MIN_RUNS = 7

#: Status values of :class:`Measurement`.
STATUSES = ("ok", "build_error", "pruned", "run_error", "verify_failed", "skipped_budget")


class BudgetExceeded(RuntimeError):
    """The default configuration could not be measured within ``limit_s`` (see :func:`tune`):
    without it there is nothing to verify against, so the pass is not tuned."""


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
            "config": _copy_config(self.config),
            "status": self.status,
            "times_ms": [float(t) for t in self.times_ms],
            "median_ms": self.median_ms,
            "error": self.error,
            "max_abs_err": self.max_abs_err,
        }


@dataclass
class TuneResult:
    """Outcome of :func:`tune` for one pass and problem-size bucket on one device."""

    pass_name: str
    bucket: str
    default: Config
    best: Config
    best_median_ms: float | None
    default_median_ms: float | None
    measurements: list[Measurement]
    elapsed_s: float
    #: median over paired runs of default ms / winner ms (None: no confirmation was run)
    confirm_ratio: float | None = None
    #: a winner other than the default was not confirmed because the paired runs would have
    #: passed the budget (the default was kept)
    confirm_skipped: bool = False

    @property
    def skipped(self) -> list[Measurement]:
        """The configurations left out or stopped for the budget."""
        return [m for m in self.measurements if m.status == "skipped_budget"]

    @property
    def speedup(self) -> float | None:
        """``default_median_ms / best_median_ms`` (``None`` if either is missing)."""
        if not self.best_median_ms or self.default_median_ms is None:
            return None
        return self.default_median_ms / self.best_median_ms


def config_key(config: Config) -> str:
    """Canonical text of a configuration: ``json.dumps(config, sort_keys=True)``."""
    return json.dumps(config, sort_keys=True)


def config_sort_key(config: Config) -> tuple[int, str]:
    """Stable sort key of a configuration; ``None`` (runtime chooses) sorts first."""
    return (0, "") if config is None else (1, config_key(config))


def _copy_config(config: Config) -> Config:
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
class _Cost:
    """Wall seconds one measurement spent: build, warm-up launch with verification, and
    each timed launch (output read back included); ``None`` where it did not get that far."""

    build_s: float | None = None
    warmup_s: float | None = None
    launch_s: list[float] = field(default_factory=list)


def _median_or(values: list[float], fallback: float) -> float:
    return float(statistics.median(values)) if values else fallback


class _Budget:
    """Predicts what a measurement will cost from what the earlier ones cost.

    Builds and warm-ups are predicted from the candidates' (the default's build may have come
    from a cache, and its warm-up made the reference instead of verifying), falling back on
    the default's; a launch from the median launch of every configuration so far."""

    def __init__(self, clock: Callable[[], float], deadline: float | None):
        self.clock, self.deadline = clock, deadline
        self.default: _Cost | None = None
        self.others: list[_Cost] = []
        self.launch_of: dict[str, float] = {}  # median launch seconds by configuration key

    def add(self, key: str, cost: _Cost) -> None:
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
        d = self.default or _Cost()
        build = _median_or([c.build_s for c in self.others if c.build_s is not None],
                           d.build_s or 0.0)
        warm = _median_or([c.warmup_s for c in self.others if c.warmup_s is not None],
                          d.warmup_s or 0.0)
        launch = self.launch_s()
        total = build + warm + runs * launch
        return total, (f"predicted {total:.3g} s: build {build:.3g} s + warm-up and "
                       f"verification {warm:.3g} s + {runs} runs x {launch:.3g} s")


def _measure(config: Config, runner: Runner, runs: int, device_max_wg: int | None,
             ref: np.ndarray | None, rtol: float, atol: float,
             clock: Callable[[], float] = time.perf_counter, deadline: float | None = None,
             cost: _Cost | None = None, expect_launch_s: float | None = None
             ) -> tuple[Measurement, np.ndarray | None]:
    """Measure one configuration; ``ref is None`` makes its warm-up output the reference.

    With a ``deadline`` (a ``clock()`` value) the timed runs stop, as ``"skipped_budget"``,
    as soon as the ones left would end after it: predicted, before the first, from the
    warm-up launch or ``expect_launch_s`` (the other configurations' launches) whichever is
    shorter (a warm-up may include a one-time work-group compile), then from this
    configuration's own timed launches. What each phase took goes into ``cost``."""
    cfg = _copy_config(config)
    cost = _Cost() if cost is None else cost

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


def _choose(measurements: list[Measurement], default: Config, tie: float) -> Measurement | None:
    ok = [m for m in measurements if m.status == "ok"]
    if not ok:
        return None
    fastest = min(m.median_ms for m in ok)
    ties = [m for m in ok if m.median_ms <= fastest * (1.0 + tie)]
    default_key = config_key(default)
    for m in ties:
        if config_key(m.config) == default_key:
            return m
    return min(ties, key=lambda m: config_sort_key(m.config))


def tune(
    pass_name: str,
    bucket: str,
    candidates: Sequence[Config],
    default: Config,
    runner: Runner,
    *,
    runs: int = MIN_RUNS,
    budget_s: float | None = None,
    limit_s: float | None = None,
    rtol: float = 1e-5,
    atol: float = 1e-6,
    tie: float = 0.02,
    confirm: int = 7,
    device_max_wg: int | None = None,
    clock: Callable[[], float] = time.perf_counter,
    progress: Callable[[int, int], None] | None = None,
) -> TuneResult:
    """Measure every candidate configuration of one pass and choose the fastest correct one.

    Parameters
    ----------
    pass_name, bucket : str
        What is tuned (recorded in the result).
    candidates : sequence of dict or None
        The search space; ``None`` means "the runtime chooses the local size". Duplicates are
        measured once. ``default`` is added in front if it is missing.
    default : dict or None
        The configuration used without tuning; measured first, its output is the reference.
    runner : Runner
        Builds and launches the pass.
    runs : int, optional
        Timed runs per configuration after one untimed warm-up (at least 7).
    budget_s : float, optional
        Seconds of ``clock()`` from the start that the whole search must fit in, the
        default's measurement included (the default is always measured, within ``limit_s``,
        even when it alone takes more). Before each
        candidate its cost is predicted from the configurations measured so far (build,
        warm-up with verification, ``runs`` launches); a candidate predicted not to fit in
        what is left, less the time the paired confirmation will need, is not started, and
        one whose remaining timed runs would pass the budget stops: both are
        ``"skipped_budget"`` with the figures in ``error``. A winner whose confirmation would
        pass the budget is not confirmed and the default is kept (``confirm_skipped``).
        Nothing is interrupted: a budget can be passed by at most one launch whose time
        exceeds the prediction, or one build.
    limit_s : float, optional
        Hard limit for the default's measurement itself: when it is 0, or when the default's
        remaining timed runs would end more than ``limit_s`` after the start,
        :class:`BudgetExceeded` is raised (a caller sharing one budget between passes gives
        each pass its share as ``budget_s`` and what is left of the whole as ``limit_s``).
        ``None``: no limit.
    rtol, atol : float, optional
        Verification tolerance (:func:`numpy.allclose`, NaNs never equal).
    tie : float, optional
        Medians within this fraction of the fastest are ties; the default wins a tie, else the
        smallest configuration by :func:`config_sort_key`.
    confirm : int, optional
        Paired runs confirming a winner other than the default: default and winner are
        launched alternately this many times, and the winner is kept only if the median of
        the per-pair ratios default/winner exceeds ``1 + tie`` (``0``: no confirmation).
    device_max_wg : int, optional
        The device's maximum work-group size; larger local sizes are pruned before building.
    clock : callable, optional
        Seconds, for the budget and ``elapsed_s``.
    progress : callable, optional
        Called as ``progress(done, total)`` after each configuration.

    Returns
    -------
    TuneResult
        One :class:`Measurement` per configuration, the default first.

    Raises
    ------
    ValueError
        ``runs < 7``, a negative ``tie``/``budget_s``/``limit_s``/tolerance.
    BudgetExceeded
        ``limit_s`` is 0, or the default's timed runs would end after it.
    RuntimeError
        The default configuration cannot be built, launched or timed (nothing to verify
        against).
    """
    if isinstance(runs, bool) or not isinstance(runs, int) or runs < MIN_RUNS:
        raise ValueError(f"runs must be an integer >= {MIN_RUNS} (got {runs!r})")
    if not tie >= 0:
        raise ValueError(f"tie must be >= 0 (got {tie!r})")
    for name, value in (("budget_s", budget_s), ("limit_s", limit_s)):
        if value is not None and not value >= 0:
            raise ValueError(f"{name} must be >= 0 (got {value!r})")
    if not (rtol >= 0 and atol >= 0):
        raise ValueError(f"rtol and atol must be >= 0 (got {rtol!r}, {atol!r})")
    for c in candidates:
        if c is not None and not isinstance(c, dict):
            raise ValueError(f"a configuration must be a dict or None (got {c!r})")
    if default is not None and not isinstance(default, dict):
        raise ValueError(f"the default configuration must be a dict or None (got {default!r})")

    default_key = config_key(default)
    order: list[Config] = [default]
    seen = {default_key}
    for c in candidates:
        k = config_key(c)
        if k not in seen:
            seen.add(k)
            order.append(c)
    total = len(order)

    if limit_s is not None and limit_s <= 0:
        raise BudgetExceeded(f"{pass_name} [{bucket}]: no time left to measure the default "
                             f"configuration {default_key}")
    start = clock()
    budget = _Budget(clock, None if budget_s is None else start + budget_s)
    cost = _Cost()
    first, ref = _measure(default, runner, runs, device_max_wg, None, rtol, atol, clock,
                          None if limit_s is None else start + limit_s, cost)
    budget.add(default_key, cost)
    if first.status == "skipped_budget":
        raise BudgetExceeded(f"{pass_name} [{bucket}]: the default configuration {default_key} "
                             f"does not fit in the {limit_s:.3g} s left ({first.error})")
    if first.status != "ok":
        raise RuntimeError(
            f"{pass_name} [{bucket}]: the default configuration {default_key} is not usable "
            f"({first.status}: {first.error}); nothing to verify the others against"
        )
    measurements = [first]
    if progress is not None:
        progress(1, total)

    # kept back for the paired confirmation: both configurations launched `confirm` times
    # (a winner is faster than the default, so twice the default's launch bounds it)
    reserve = budget.confirm_s(confirm, default_key, default_key) if total > 1 else 0.0
    for done, config in enumerate(order[1:], start=2):
        if budget.deadline is None:
            m, _ = _measure(config, runner, runs, device_max_wg, ref, rtol, atol, clock)
        else:
            need, how = budget.candidate_s(runs)
            left = budget.left() - reserve
            if need > left:
                m = Measurement(_copy_config(config), "skipped_budget",
                                error=f"{how}; {max(left, 0.0):.3g} s of the {budget_s:.3g} s "
                                      f"budget left (after {reserve:.3g} s kept for the "
                                      "paired confirmation)")
            else:
                cost = _Cost()
                m, _ = _measure(config, runner, runs, device_max_wg, ref, rtol, atol, clock,
                                budget.deadline - reserve, cost, budget.launch_s())
                budget.add(config_key(config), cost)
        measurements.append(m)
        if progress is not None:
            progress(done, total)

    best = _choose(measurements, default, tie)
    assert best is not None  # the default is always "ok" here
    ratio, confirm_skipped = None, False
    if confirm > 0 and config_key(best.config) != default_key:
        if budget.confirm_s(confirm, default_key, config_key(best.config)) > budget.left():
            confirm_skipped, best = True, first  # unconfirmed: keep the default
        else:
            ratio = _paired_ratio(runner, default, best.config, confirm)
            if ratio is None or ratio < 1.0 + tie:
                best = first  # the gain did not survive paired runs: keep the default
    return TuneResult(
        pass_name=pass_name,
        bucket=bucket,
        default=_copy_config(default),
        best=_copy_config(best.config),
        best_median_ms=best.median_ms,
        default_median_ms=first.median_ms,
        measurements=measurements,
        elapsed_s=float(clock() - start),
        confirm_ratio=ratio,
        confirm_skipped=confirm_skipped,
    )


def _paired_ratio(runner: Runner, default: Config, winner: Config, pairs: int) -> float | None:
    """Median of default/winner device-time ratios over ``pairs`` alternating launches.

    Candidates are measured one after another, so slow drift of a shared machine can favour
    whichever ran in a quiet moment; paired launches see the same conditions. ``None`` if a
    launch fails."""
    try:
        hd, hw = runner.build(default), runner.build(winner)
        ratios = []
        for i in range(pairs):
            if i % 2:
                _, tw = runner.run(hw)
                _, td = runner.run(hd)
            else:
                _, td = runner.run(hd)
                _, tw = runner.run(hw)
            if not (tw > 0 and math.isfinite(tw) and math.isfinite(td)):
                return None
            ratios.append(float(td) / float(tw))
    except Exception:
        return None
    return float(statistics.median(ratios))
