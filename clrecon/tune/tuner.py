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

import math
import statistics
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Callable

from clrecon.tune.measure import (
    STATUSES,
    Budget,
    Config,
    Cost,
    Measurement,
    Runner,
    config_key,
    config_sort_key,
    copy_config,
    measure,
)

MIN_RUNS = 7


class BudgetExceeded(RuntimeError):
    """The default configuration could not be measured within ``limit_s`` (see :func:`tune`):
    without it there is nothing to verify against, so the pass is not tuned."""


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
    budget = Budget(clock, None if budget_s is None else start + budget_s)
    cost = Cost()
    first, ref = measure(default, runner, runs, device_max_wg, None, rtol, atol, clock,
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
            m, _ = measure(config, runner, runs, device_max_wg, ref, rtol, atol, clock)
        else:
            need, how = budget.candidate_s(runs)
            left = budget.left() - reserve
            if need > left:
                m = Measurement(copy_config(config), "skipped_budget",
                                error=f"{how}; {max(left, 0.0):.3g} s of the {budget_s:.3g} s "
                                      f"budget left (after {reserve:.3g} s kept for the "
                                      "paired confirmation)")
            else:
                cost = Cost()
                m, _ = measure(config, runner, runs, device_max_wg, ref, rtol, atol, clock,
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
        default=copy_config(default),
        best=copy_config(best.config),
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


__all__ = ["MIN_RUNS", "STATUSES", "BudgetExceeded", "Config", "Measurement", "Runner",
           "TuneResult", "config_key", "config_sort_key", "tune"]
