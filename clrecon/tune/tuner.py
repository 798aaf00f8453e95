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
  wins if it is among them, else the smallest configuration by :func:`config_sort_key`.
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


def _measure(config: Config, runner: Runner, runs: int, device_max_wg: int | None,
             ref: np.ndarray | None, rtol: float, atol: float
             ) -> tuple[Measurement, np.ndarray | None]:
    """Measure one configuration; ``ref is None`` makes its warm-up output the reference."""
    cfg = _copy_config(config)

    def fail(status: str, error: str, max_abs_err: float | None = None) -> _Failed:
        return _Failed(Measurement(cfg, status, error=error, max_abs_err=max_abs_err))

    try:
        try:
            local = runner.local_size(config)
        except Exception as exc:
            raise fail("build_error", f"invalid configuration: {_exc_text(exc)}") from None
        if local is not None and device_max_wg is not None and local > device_max_wg:
            raise fail("pruned", f"local size {local} exceeds the device's maximum work-group "
                                 f"size {device_max_wg}")
        try:
            handle = runner.build(config)
        except Exception as exc:
            raise fail("build_error", _exc_text(exc)) from None
        try:
            kernel_max = runner.max_work_group_size(handle)
        except Exception as exc:
            raise fail("build_error", f"kernel work-group size query failed: "
                                      f"{_exc_text(exc)}") from None
        if local is not None and kernel_max is not None and local > kernel_max:
            raise fail("pruned", f"local size {local} exceeds the compiled kernel's "
                                 f"work-group size {kernel_max}")
        try:
            out, _ = runner.run(handle)  # warm-up: not timed
        except Exception as exc:
            raise fail("run_error", _exc_text(exc)) from None
        out = np.array(out, copy=True)
        if ref is None:
            ref, max_err = out, 0.0
        else:
            ok, max_err, msg = _compare(out, ref, rtol, atol)
            if not ok:
                raise fail("verify_failed", msg, max_err)
        times: list[float] = []
        for _ in range(runs):
            try:
                _, ms = runner.run(handle)
            except Exception as exc:
                raise fail("run_error", _exc_text(exc)) from None
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
        Once ``clock()`` has advanced more than this since the start, the configurations not
        yet started are marked ``"skipped_budget"`` (the default is always measured).
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
        ``runs < 7``, a negative ``tie``/``budget_s``/tolerance.
    RuntimeError
        The default configuration cannot be built, launched or timed (nothing to verify
        against).
    """
    if isinstance(runs, bool) or not isinstance(runs, int) or runs < MIN_RUNS:
        raise ValueError(f"runs must be an integer >= {MIN_RUNS} (got {runs!r})")
    if not tie >= 0:
        raise ValueError(f"tie must be >= 0 (got {tie!r})")
    if budget_s is not None and not budget_s >= 0:
        raise ValueError(f"budget_s must be >= 0 (got {budget_s!r})")
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

    start = clock()
    first, ref = _measure(default, runner, runs, device_max_wg, None, rtol, atol)
    if first.status != "ok":
        raise RuntimeError(
            f"{pass_name} [{bucket}]: the default configuration {default_key} is not usable "
            f"({first.status}: {first.error}); nothing to verify the others against"
        )
    measurements = [first]
    if progress is not None:
        progress(1, total)

    over_budget = False
    for done, config in enumerate(order[1:], start=2):
        if not over_budget and budget_s is not None and clock() - start > budget_s:
            over_budget = True
        if over_budget:
            m = Measurement(_copy_config(config), "skipped_budget",
                            error=f"tuning budget of {budget_s:g} s spent")
        else:
            m, _ = _measure(config, runner, runs, device_max_wg, ref, rtol, atol)
        measurements.append(m)
        if progress is not None:
            progress(done, total)

    best = _choose(measurements, default, tie)
    assert best is not None  # the default is always "ok" here
    ratio = None
    if confirm > 0 and config_key(best.config) != default_key:
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
