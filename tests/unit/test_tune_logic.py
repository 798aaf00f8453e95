"""Autotuner search and tuning database, without OpenCL: a replayed runner and a fake clock."""
from __future__ import annotations

import json
import statistics
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from clrecon.tune import (
    clear_cache,
    config_key,
    tune,
)

REPLAY = Path(__file__).resolve().parents[1] / "data" / "tune_replay.json"

DEFAULT = {"wg_x": 8, "wg_y": 8}
RUNTIME = None
TOO_BIG_FOR_DEVICE = {"wg_x": 32, "wg_y": 32}   # 1024 work-items
TOO_BIG_FOR_KERNEL = {"wg_x": 16, "wg_y": 16}   # 256 > kernel max 128
BUILD_ERROR = {"wg_x": 64, "wg_y": 1}
RUN_ERROR = {"wg_x": 4, "wg_y": 4}              # fails on the warm-up launch
LATE_RUN_ERROR = {"wg_x": 2, "wg_y": 2}         # fails on the third timed launch
WRONG_FASTEST = {"wg_x": 16, "wg_y": 4}         # 0.5 ms, wrong output
OUTLIER = {"wg_x": 8, "wg_y": 4}                # median 1.0, one 1000 ms run
STEADY = {"wg_x": 32, "wg_y": 2}                # 1.5 ms flat
NEAR_DEFAULT = {"wg_x": 8, "wg_y": 16}          # 1.97 ms, within 2 % of the default's 2.0
WG_SPACE = [RUNTIME, TOO_BIG_FOR_DEVICE, TOO_BIG_FOR_KERNEL, BUILD_ERROR, RUN_ERROR,
            LATE_RUN_ERROR, WRONG_FASTEST, OUTLIER, STEADY, NEAR_DEFAULT]

TILE_DEFAULT = {"tile": 8, "tile_merge": "serial"}   # 3.0
TILE4_SERIAL = {"tile": 4, "tile_merge": "serial"}   # 1.0 (fastest)
TILE4_BITONIC = {"tile": 4, "tile_merge": "bitonic"}  # 1.01 (tie, smaller key)
TILE2_SERIAL = {"tile": 2, "tile_merge": "serial"}   # 1.2


class FakeClock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


class ReplayRunner:
    """Replays tests/data/tune_replay.json; handles are the configurations' keys."""

    def __init__(self, clock: FakeClock | None = None, tick_s: float = 0.0):
        data = json.loads(REPLAY.read_text())
        self.configs = data["configs"]
        rng = np.random.default_rng(data["seed"])
        self.ref = rng.standard_normal(data["shape"]).astype(np.float32)
        self.clock = clock
        self.tick_s = tick_s
        self.builds: list[str] = []
        self.launches: Counter = Counter()

    def _rec(self, key: str) -> dict:
        if key not in self.configs:
            raise ValueError(f"configuration {key} not in the replay")
        return self.configs[key]

    def local_size(self, config):
        return self._rec(config_key(config))["local_size"]

    def build(self, config):
        key = config_key(config)
        rec = self._rec(key)
        self.builds.append(key)
        if "build_error" in rec:
            raise RuntimeError(rec["build_error"])
        return key

    def max_work_group_size(self, handle):
        return self._rec(handle).get("max_wg")

    def _output(self, kind: str) -> np.ndarray:
        out = self.ref.copy()
        if kind == "close":
            out *= np.float32(1 + 1e-7)
        elif kind == "wrong":
            out.flat[0] += np.float32(0.5)
        return out

    def run(self, handle):
        rec = self._rec(handle)
        n = self.launches[handle]
        self.launches[handle] += 1
        if self.clock is not None:
            self.clock.t += self.tick_s
        if "run_error" in rec and n == rec.get("run_error_at", 0):
            raise RuntimeError(rec["run_error"])
        ms = rec["warmup_ms"] if n == 0 else rec["times_ms"][(n - 1) % len(rec["times_ms"])]
        return self._output(rec["output"]), ms


def by_config(result):
    return {config_key(m.config): m for m in result.measurements}



@pytest.fixture(autouse=True)
def clean_tuning(monkeypatch):
    """Every test starts without a ``CLRECON_TUNE_*`` override and with an empty lookup
    cache (the database and budget tests import it too)."""
    import os

    for var in [v for v in os.environ if v.startswith("CLRECON_TUNE_")]:
        monkeypatch.delenv(var)
    clear_cache()
    yield
    clear_cache()


# -- search ----------------------------------------------------------------------------------

def test_runs_below_seven_rejected():
    runner = ReplayRunner()
    with pytest.raises(ValueError, match="runs"):
        tune("p", "s-lo", WG_SPACE, DEFAULT, runner, runs=6)
    assert runner.builds == [] and not runner.launches


def test_full_space_records_failures_as_data_and_goes_on():
    runner = ReplayRunner()
    done = []
    res = tune("p", "s-lo", WG_SPACE, DEFAULT, runner, device_max_wg=512,
               progress=lambda d, t: done.append((d, t)))
    n = len(WG_SPACE) + 1
    assert done == [(i, n) for i in range(1, n + 1)]
    assert [m.config for m in res.measurements] == [DEFAULT, *WG_SPACE]
    m = by_config(res)
    status = {k: v.status for k, v in m.items()}
    assert status == {
        config_key(DEFAULT): "ok", config_key(RUNTIME): "ok",
        config_key(TOO_BIG_FOR_DEVICE): "pruned", config_key(TOO_BIG_FOR_KERNEL): "pruned",
        config_key(BUILD_ERROR): "build_error", config_key(RUN_ERROR): "run_error",
        config_key(LATE_RUN_ERROR): "run_error", config_key(WRONG_FASTEST): "verify_failed",
        config_key(OUTLIER): "ok", config_key(STEADY): "ok", config_key(NEAR_DEFAULT): "ok",
    }
    # pruned by the device limit before building; by the kernel limit after building
    dev = m[config_key(TOO_BIG_FOR_DEVICE)]
    assert "1024" in dev.error and "512" in dev.error and "device" in dev.error
    assert config_key(TOO_BIG_FOR_DEVICE) not in runner.builds
    ker = m[config_key(TOO_BIG_FOR_KERNEL)]
    assert "256" in ker.error and "128" in ker.error and "kernel" in ker.error
    assert config_key(TOO_BIG_FOR_KERNEL) in runner.builds
    assert runner.launches[config_key(TOO_BIG_FOR_KERNEL)] == 0
    assert "WG_TILE" in m[config_key(BUILD_ERROR)].error
    assert "INVALID_WORK_GROUP_SIZE" in m[config_key(RUN_ERROR)].error
    assert "OUT_OF_RESOURCES" in m[config_key(LATE_RUN_ERROR)].error
    for k in (TOO_BIG_FOR_DEVICE, TOO_BIG_FOR_KERNEL, BUILD_ERROR, RUN_ERROR, LATE_RUN_ERROR):
        assert m[config_key(k)].times_ms == [] and m[config_key(k)].median_ms is None
    # the fastest configuration computes a wrong answer: recorded, never chosen
    bad = m[config_key(WRONG_FASTEST)]
    assert bad.max_abs_err == pytest.approx(0.5, abs=1e-6)
    assert bad.times_ms == [] and bad.median_ms is None and "differ" in bad.error
    assert m[config_key(RUNTIME)].max_abs_err < 1e-5  # "close" output passes
    assert res.best == OUTLIER and res.best_median_ms == 1.0
    assert res.default == DEFAULT and res.default_median_ms == 2.0
    assert res.speedup == pytest.approx(2.0)


def test_exactly_runs_timed_launches_after_one_warmup():
    runner = ReplayRunner()
    res = tune("p", "s-lo", WG_SPACE, DEFAULT, runner, runs=9, device_max_wg=512, confirm=0)
    m = by_config(res)
    for cfg in (DEFAULT, RUNTIME, OUTLIER, STEADY, NEAR_DEFAULT):
        k = config_key(cfg)
        assert runner.launches[k] == 1 + 9
        assert len(m[k].times_ms) == 9
        assert 40.0 not in m[k].times_ms and 35.0 not in m[k].times_ms  # warm-up not timed
    rec = runner.configs[config_key(DEFAULT)]["times_ms"]
    assert m[config_key(DEFAULT)].times_ms == [rec[i % 7] for i in range(9)]
    assert runner.launches[config_key(WRONG_FASTEST)] == 1   # warm-up, then verification
    assert runner.launches[config_key(RUN_ERROR)] == 1
    assert runner.launches[config_key(LATE_RUN_ERROR)] == 4  # warm-up + 3 timed, then error
    assert runner.builds.count(config_key(DEFAULT)) == 1


def test_median_decides_not_mean():
    res = tune("p", "s-lo", [OUTLIER, STEADY], DEFAULT, ReplayRunner())
    m = by_config(res)
    outlier, steady = m[config_key(OUTLIER)], m[config_key(STEADY)]
    assert statistics.mean(outlier.times_ms) > statistics.mean(steady.times_ms)
    assert outlier.median_ms == 1.0 and steady.median_ms == 1.5
    assert res.best == OUTLIER


def test_tie_within_two_percent_goes_to_default():
    res = tune("p", "s-lo", [NEAR_DEFAULT, DEFAULT], DEFAULT, ReplayRunner())
    assert by_config(res)[config_key(NEAR_DEFAULT)].median_ms < res.default_median_ms
    assert res.best == DEFAULT and res.best_median_ms == 2.0
    res = tune("p", "s-lo", [NEAR_DEFAULT, DEFAULT], DEFAULT, ReplayRunner(), tie=0.0)
    assert res.best == NEAR_DEFAULT and res.best_median_ms == 1.97


def test_tie_without_default_smallest_key_wins_in_any_order():
    space = [TILE4_SERIAL, TILE4_BITONIC, TILE2_SERIAL]
    bests = {config_key(tune("p", "s-lo", order, TILE_DEFAULT, ReplayRunner()).best)
             for order in (space, space[::-1], [space[1], space[2], space[0]])}
    assert bests == {config_key(TILE4_BITONIC)}  # 1.01 ms ties 1.0 ms; "bitonic" < "serial"


def test_default_measured_first_and_inserted_when_missing():
    runner = ReplayRunner()
    res = tune("p", "s-lo", [STEADY, DEFAULT, STEADY, OUTLIER], DEFAULT, runner)
    assert [m.config for m in res.measurements] == [DEFAULT, STEADY, OUTLIER]
    assert runner.builds[0] == config_key(DEFAULT)
    assert runner.builds.count(config_key(STEADY)) == 1  # duplicates measured once
    res = tune("p", "s-lo", [STEADY], DEFAULT, ReplayRunner())
    assert [m.config for m in res.measurements] == [DEFAULT, STEADY]


@pytest.mark.parametrize("default, kwargs", [
    (BUILD_ERROR, {}),
    (RUN_ERROR, {}),
    (LATE_RUN_ERROR, {}),
    (DEFAULT, {"device_max_wg": 32}),
])
def test_unusable_default_raises(default, kwargs):
    with pytest.raises(RuntimeError, match="default configuration"):
        tune("p", "s-lo", [STEADY], default, ReplayRunner(), **kwargs)



# -- paired confirmation -------------------------------------------------------------------

def paired_runner(later_ms: float) -> ReplayRunner:
    """Default steady at 10 ms; the candidate times 9 ms in its 7 timed runs, then
    ``later_ms`` in every launch after them (the paired confirmation)."""
    runner = ReplayRunner()
    fast = {"wg_x": 2, "wg_y": 2}
    runner.configs[config_key(DEFAULT)] = {"local_size": 64, "warmup_ms": 10.0,
                                           "times_ms": [10.0], "output": "ref"}
    runner.configs[config_key(fast)] = {"local_size": 4, "warmup_ms": 9.0,
                                        "times_ms": [9.0] * 7 + [later_ms] * 14,
                                        "output": "ref"}
    return runner, fast


def test_paired_confirmation_keeps_a_real_gain():
    runner, fast = paired_runner(later_ms=9.0)
    res = tune("p", "s-lo", [fast], DEFAULT, runner)
    assert res.best == fast and res.confirm_ratio == pytest.approx(10.0 / 9.0)


def test_paired_confirmation_rejects_a_gain_that_was_drift():
    """Measured one after another the candidate looked 10% faster; launched alternately
    with the default it is slower: the default stays."""
    runner, fast = paired_runner(later_ms=11.0)
    res = tune("p", "s-lo", [fast], DEFAULT, runner)
    assert res.best == DEFAULT and res.best_median_ms == res.default_median_ms
    assert res.confirm_ratio == pytest.approx(10.0 / 11.0)
    assert tune("p", "s-lo", [fast], DEFAULT, paired_runner(11.0)[0], confirm=0).best == fast
