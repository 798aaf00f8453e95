"""Autotuner search and tuning database, without OpenCL: a replayed runner and a fake clock."""
from __future__ import annotations

import json
import logging
import statistics
from collections import Counter
from datetime import datetime
from pathlib import Path

import numpy as np
import pytest

from clrecon.core.device import DeviceInfo
from clrecon.tune import (
    SCHEMA_VERSION,
    Lookup,
    bucket_for,
    clear_cache,
    config_key,
    db_path,
    load,
    lookup,
    save_result,
    slug,
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


def test_budget_skips_the_rest_but_always_measures_the_default():
    clock = FakeClock()
    runner = ReplayRunner(clock, tick_s=1.0)  # every launch takes 1 s of wall time
    res = tune("p", "s-lo", [STEADY, OUTLIER, NEAR_DEFAULT], DEFAULT, runner,
               budget_s=16.0, clock=clock, confirm=0)
    # default: 8 launches -> t = 8; STEADY predicted 8 s, fits the 8 s left -> t = 16: the
    # rest (predicted 8 s each, 0 s left) skipped
    assert [m.status for m in res.measurements] == ["ok", "ok", "skipped_budget",
                                                    "skipped_budget"]
    assert config_key(OUTLIER) not in runner.builds
    assert res.measurements[2].times_ms == [] and "budget" in res.measurements[2].error
    assert res.best == STEADY and res.elapsed_s == 16.0

    clock = FakeClock()
    res = tune("p", "s-lo", [STEADY, OUTLIER], DEFAULT, ReplayRunner(clock, tick_s=1.0),
               budget_s=0.0, clock=clock)
    assert [m.status for m in res.measurements] == ["ok", "skipped_budget", "skipped_budget"]
    assert res.best == DEFAULT and res.best_median_ms == res.default_median_ms == 2.0


class TickingRunner(ReplayRunner):
    """A replayed runner whose builds, launches and launches of chosen configurations cost
    fake seconds: ``build_s`` per build, ``tick_s`` per launch, ``slow`` maps configuration
    keys to their own launch seconds."""

    def __init__(self, clock, tick_s=1.0, build_s=0.0, slow=None):
        super().__init__(clock, tick_s)
        self.build_s, self.slow = build_s, dict(slow or {})

    def build(self, config):
        self.clock.t += self.build_s
        return super().build(config)

    def run(self, handle):
        self.clock.t += self.slow.get(handle, self.tick_s) - self.tick_s
        return super().run(handle)


def test_budget_is_a_cap_no_candidate_started_that_cannot_finish():
    """The old check ran a candidate whenever the budget was not yet spent: with 10 s,
    STEADY started at t = 8 and ended at 16. Its cost (build + warm-up + 7 runs) is now
    predicted from the default's and it is skipped, with the figures in its error."""
    clock = FakeClock()
    runner = TickingRunner(clock, tick_s=1.0, build_s=0.5)
    res = tune("p", "s-lo", [STEADY, OUTLIER], DEFAULT, runner, budget_s=10.0, clock=clock,
               confirm=0)
    assert [m.status for m in res.measurements] == ["ok", "skipped_budget", "skipped_budget"]
    assert res.elapsed_s == 8.5 <= 10.0
    assert config_key(STEADY) not in runner.builds and not runner.launches[config_key(STEADY)]
    err = res.measurements[1].error
    assert "predicted 8.5 s" in err and "build 0.5 s" in err and "7 runs x 1 s" in err
    assert "1.5 s of the 10 s budget left" in err
    assert [m.config for m in res.skipped] == [STEADY, OUTLIER]


def test_budget_counts_builds_and_warmups_of_the_candidates():
    """Candidates' builds are slower than the default's (cached) one: the prediction learns
    from the first candidate and the total stays within the budget."""
    clock = FakeClock()

    class SlowBuilds(TickingRunner):
        def build(self, config):
            self.clock.t += 0.0 if config == DEFAULT else 5.0
            return ReplayRunner.build(self, config)

    runner = SlowBuilds(clock, tick_s=1.0)
    space = [STEADY, OUTLIER, NEAR_DEFAULT, RUNTIME]
    res = tune("p", "s-lo", space, DEFAULT, runner, budget_s=30.0, clock=clock, confirm=0)
    st = [m.status for m in res.measurements]
    # default 8 s; STEADY predicted 8 s, took 13 s (t = 21); OUTLIER predicted 13 s > 9 s left
    assert st == ["ok", "ok", "skipped_budget", "skipped_budget", "skipped_budget"]
    assert res.elapsed_s == 21.0 <= 30.0
    assert "build 5 s" in res.measurements[2].error


def test_budget_stops_a_slower_candidate_between_runs():
    """A candidate five times slower than predicted stops as soon as its remaining runs would
    pass the budget (the most it can pass it by is the one launch that revealed it)."""
    clock = FakeClock()
    runner = TickingRunner(clock, tick_s=1.0, slow={config_key(STEADY): 5.0})
    res = tune("p", "s-lo", [STEADY, OUTLIER], DEFAULT, runner, budget_s=20.0, clock=clock,
               confirm=0)
    steady = res.measurements[1]
    # t = 8; predicted 8 s, started; the warm-up (5 s, t = 13) stands for the first run at
    # the others' 1 s: 7 s fit in 7; after one 5 s run (t = 18) six more need 30 s: stopped
    assert steady.status == "skipped_budget" and steady.times_ms == []
    assert "stopped after 1 of 7 timed runs" in steady.error
    assert runner.launches[config_key(STEADY)] == 2
    assert res.measurements[2].status == "skipped_budget"
    assert res.elapsed_s == 18.0 and res.best == DEFAULT


def test_budget_keeps_time_for_the_paired_confirmation():
    clock = FakeClock()
    runner, fast = _paired_runner(later_ms=9.0)
    runner.clock, runner.tick_s = clock, 1.0
    # default 8 s + candidate 8 s + 7 pairs (14 s) = 30 s
    res = tune("p", "s-lo", [fast], DEFAULT, runner, budget_s=30.0, clock=clock)
    assert res.best == fast and res.confirm_ratio is not None and not res.confirm_skipped
    assert res.elapsed_s == 30.0
    # 29 s: the candidate fits only by eating the confirmation's reserve, so it is skipped
    clock = FakeClock()
    runner, fast = _paired_runner(later_ms=9.0)
    runner.clock, runner.tick_s = clock, 1.0
    res = tune("p", "s-lo", [fast], DEFAULT, runner, budget_s=29.0, clock=clock)
    assert [m.status for m in res.measurements] == ["ok", "skipped_budget"]
    assert "kept for the paired confirmation" in res.measurements[1].error
    assert res.best == DEFAULT and res.elapsed_s == 8.0


def test_budget_skips_an_unaffordable_confirmation_and_keeps_the_default():
    """The winner is faster on the device but its launches take twice the default's wall
    time (reading back, say): its confirmation needs more than was kept back."""
    clock = FakeClock()
    replay, fast = _paired_runner(later_ms=9.0)
    runner = TickingRunner(clock, tick_s=1.0, slow={config_key(fast): 2.0})
    runner.configs = replay.configs
    res = tune("p", "s-lo", [fast], DEFAULT, runner, budget_s=40.0, clock=clock)
    # default t = 8, 14 s kept back; the winner runs 2 s launches to t = 24; its 7 pairs
    # need 21 s > 16 s left: not confirmed, the default kept
    assert res.measurements[1].status == "ok" and res.measurements[1].median_ms == 9.0
    assert res.confirm_skipped and res.confirm_ratio is None and res.best == DEFAULT
    assert res.elapsed_s == 24.0
    assert runner.launches[config_key(fast)] == 8  # no paired launches


def test_limit_raises_when_the_default_cannot_be_measured():
    from clrecon.tune.tuner import BudgetExceeded

    clock = FakeClock()
    runner = TickingRunner(clock, tick_s=1.0)
    with pytest.raises(BudgetExceeded, match="does not fit in the 5 s left"):
        tune("p", "s-lo", [STEADY], DEFAULT, runner, budget_s=5.0, limit_s=5.0, clock=clock)
    assert clock.t == 1.0  # after the warm-up: 7 runs of 1 s cannot fit in 4 s
    with pytest.raises(ValueError, match="limit_s"):
        tune("p", "s-lo", [STEADY], DEFAULT, runner, limit_s=-1.0)
    runner = TickingRunner(clock, tick_s=1.0)
    with pytest.raises(BudgetExceeded, match="no time left"):
        tune("p", "s-lo", [STEADY], DEFAULT, runner, budget_s=0.0, limit_s=0.0, clock=clock)
    assert runner.builds == [] and not runner.launches  # not even a warm-up


@pytest.mark.parametrize("default, kwargs", [
    (BUILD_ERROR, {}),
    (RUN_ERROR, {}),
    (LATE_RUN_ERROR, {}),
    (DEFAULT, {"device_max_wg": 32}),
])
def test_unusable_default_raises(default, kwargs):
    with pytest.raises(RuntimeError, match="default configuration"):
        tune("p", "s-lo", [STEADY], default, ReplayRunner(), **kwargs)


# -- database --------------------------------------------------------------------------------

POCL = "Portable Computing Language"


def make_info(**kw) -> DeviceInfo:
    fields = dict(
        index=0, platform=POCL, platform_version="OpenCL 3.0 PoCL 3.1+debian",
        name="cpu-haswell-Intel(R) Xeon(R) CPU @ 2.20GHz", vendor="GenuineIntel",
        driver="3.1+debian", version="OpenCL 3.0 PoCL HSTR: cpu-x86_64-pc-linux-gnu-haswell",
        device_type="CPU", compute_units=2, global_mem_bytes=8 << 30, local_mem_bytes=4 << 20,
        max_work_group_size=4096, image_support=True, int64_atomics=True,
        native_float_atomics=False,
    )
    fields.update(kw)
    return DeviceInfo(**fields)


def make_result(pass_name="sweep_resolve", bucket="s-lo", candidates=(RUNTIME, OUTLIER)):
    return tune(pass_name, bucket, list(candidates), DEFAULT, ReplayRunner())


@pytest.fixture(autouse=True)
def _clean(monkeypatch):
    import os

    for var in [v for v in os.environ if v.startswith("CLRECON_TUNE_")]:
        monkeypatch.delenv(var)
    clear_cache()
    yield
    clear_cache()


def warnings_of(caplog):
    return [r.getMessage() for r in caplog.records
            if r.name == "clrecon" and r.levelno == logging.WARNING]


def test_slugs_and_path_keep_runtime_apart_from_vendor(tmp_path):
    assert slug(POCL) == "portable-computing-language"
    assert slug("  NVIDIA GeForce RTX 4090 ") == "nvidia-geforce-rtx-4090"
    assert slug("cpu-haswell-Intel(R) Xeon(R) CPU @ 2.20GHz") == \
        "cpu-haswell-intel-r-xeon-r-cpu-2-20ghz"
    assert slug("--__--") == "unknown"
    p = db_path(make_info(), tmp_path)
    assert p == tmp_path / "portable-computing-language" / \
        "cpu-haswell-intel-r-xeon-r-cpu-2-20ghz.json"


def test_save_layout_and_exact_lookup(tmp_path):
    info, res = make_info(), make_result()
    path = save_result(info, res, "hash1", ["-I/k", "-DTILE=4"], root=tmp_path)
    assert path == db_path(info, tmp_path)
    assert list(path.parent.iterdir()) == [path]  # no temporary file left behind
    text = path.read_text()
    data = json.loads(text)
    assert text == json.dumps(data, sort_keys=True, indent=1) + "\n"
    assert data["schema"] == SCHEMA_VERSION == 1
    assert data["device"] == info.fingerprint()
    e = data["entries"]["sweep_resolve|s-lo"]
    assert e["pass"] == "sweep_resolve" and e["bucket"] == "s-lo"
    assert e["source_hash"] == "hash1" and e["build_options"] == ["-I/k", "-DTILE=4"]
    assert e["default"] == DEFAULT and e["best"] == OUTLIER
    assert e["best_median_ms"] == 1.0 and e["default_median_ms"] == 2.0
    assert datetime.fromisoformat(e["tuned_at"]).tzinfo is not None
    assert [m["config"] for m in e["measurements"]] == [DEFAULT, RUNTIME, OUTLIER]
    assert set(e["measurements"][0]) == {"config", "status", "times_ms", "median_ms", "error",
                                         "max_abs_err"}
    assert load(path) == data
    got = lookup(info, "sweep_resolve", "s-lo", "hash1", root=tmp_path)
    assert got == Lookup(OUTLIER, "exact", str(path))
    assert lookup(info, "sweep_resolve", "m-lo", "hash1", root=tmp_path).source == "runtime"


def test_save_merges_entries(tmp_path):
    info = make_info()
    save_result(info, make_result("a", "s-lo"), "ha", [], root=tmp_path)
    save_result(info, make_result("b", "m-hi", [STEADY]), "hb", [], root=tmp_path)
    path = save_result(info, make_result("a", "s-lo", [STEADY]), "ha2", [], root=tmp_path)
    entries = load(path)["entries"]
    assert sorted(entries) == ["a|s-lo", "b|m-hi"]
    assert entries["a|s-lo"]["best"] == STEADY and entries["a|s-lo"]["source_hash"] == "ha2"
    assert entries["b|m-hi"]["best"] == STEADY
    assert lookup(info, "b", "m-hi", "hb", root=tmp_path).source == "exact"


def test_stale_hash_warns_and_falls_through(tmp_path, caplog):
    info = make_info()
    path = save_result(info, make_result(), "old", [], root=tmp_path)
    with caplog.at_level(logging.WARNING, logger="clrecon"):
        got = lookup(info, "sweep_resolve", "s-lo", "new", defaults={"sweep_resolve": STEADY},
                     root=tmp_path)
    assert got == Lookup(STEADY, "default", None)
    msgs = warnings_of(caplog)
    assert len(msgs) == 1 and "sweep_resolve" in msgs[0] and str(path) in msgs[0]
    assert "stale" in msgs[0]
    # with a current entry from a sibling device, the stale exact entry yields to it
    sibling = make_info(index=1, name="cpu-skylake-Intel(R) Core(TM) i7-8700")
    spath = save_result(sibling, make_result(candidates=[STEADY]), "new", [], root=tmp_path)
    got = lookup(info, "sweep_resolve", "s-lo", "new", root=tmp_path)
    assert got == Lookup(STEADY, "vendor", str(spath))
    assert lookup(info, "sweep_resolve", "s-lo", "old", root=tmp_path).source == "exact"


def test_vendor_fallback_same_vendor_and_type_only(tmp_path):
    info = make_info()
    other_vendor = make_info(name="cpu-zen3-AMD Ryzen 9 5950X", vendor="AuthenticAMD")
    other_type = make_info(platform="Intel(R) OpenCL Graphics", name="Intel(R) UHD Graphics",
                           device_type="GPU")
    for dev in (other_vendor, other_type):
        save_result(dev, make_result(candidates=[STEADY]), "h", [], root=tmp_path)
    assert lookup(info, "sweep_resolve", "s-lo", "h", root=tmp_path).source == "runtime"

    # two matching files: the same runtime first, then sorted path order
    foreign = make_info(platform="Intel(R) CPU Runtime for OpenCL(TM) Applications",
                        name="Intel(R) Xeon(R) CPU @ 2.20GHz")
    b = make_info(name="cpu-skylake-b")
    a = make_info(name="cpu-skylake-a")
    fpath = save_result(foreign, make_result(candidates=[RUNTIME]), "h", [], root=tmp_path)
    bpath = save_result(b, make_result(candidates=[STEADY]), "h", [], root=tmp_path)
    apath = save_result(a, make_result(candidates=[OUTLIER]), "h", [], root=tmp_path)
    got = lookup(info, "sweep_resolve", "s-lo", "h", root=tmp_path)
    assert got == Lookup(OUTLIER, "vendor", str(apath))
    apath.unlink()
    clear_cache()
    got = lookup(info, "sweep_resolve", "s-lo", "h", root=tmp_path)
    assert got == Lookup(STEADY, "vendor", str(bpath))
    bpath.unlink()
    got = lookup(info, "sweep_resolve", "s-lo", "h", root=tmp_path)
    assert got == Lookup(DEFAULT, "vendor", str(fpath))  # another runtime: tried last


def test_defaults_then_runtime(tmp_path):
    info = make_info()
    got = lookup(info, "p", "s-lo", "h", defaults={"p": {"tile": 4}}, root=tmp_path)
    assert got == Lookup({"tile": 4}, "default", None)
    got = lookup(info, "p", "s-lo", "h", defaults={"p": None}, root=tmp_path)
    assert got == Lookup(None, "default", None)
    got = lookup(info, "p", "s-lo", "h", defaults={"q": {"tile": 4}}, root=tmp_path / "none")
    assert got == Lookup(None, "runtime", None)


def test_env_override(tmp_path, monkeypatch):
    info = make_info()
    save_result(info, make_result(), "h", [], root=tmp_path)
    monkeypatch.setenv("CLRECON_TUNE_SWEEP_RESOLVE", '{"tile": 2, "tile_merge": "serial"}')
    got = lookup(info, "sweep_resolve", "s-lo", "h", root=tmp_path)
    assert got == Lookup(TILE2_SERIAL, "env", None)
    monkeypatch.setenv("CLRECON_TUNE_SWEEP_RESOLVE", "null")
    assert lookup(info, "sweep_resolve", "s-lo", "h", root=tmp_path) == Lookup(None, "env", None)
    monkeypatch.setenv("CLRECON_TUNE_SWEEP_RESOLVE", "")
    assert lookup(info, "sweep_resolve", "s-lo", "h", root=tmp_path).source == "exact"
    for bad in ("{tile: 2}", "[1, 2]", "4"):
        monkeypatch.setenv("CLRECON_TUNE_SWEEP_RESOLVE", bad)
        with pytest.raises(ValueError, match="CLRECON_TUNE_SWEEP_RESOLVE"):
            lookup(info, "sweep_resolve", "s-lo", "h", root=tmp_path)


def test_corrupt_files_skipped_with_warning(tmp_path, caplog):
    info = make_info()
    own = db_path(info, tmp_path)
    own.parent.mkdir(parents=True)
    own.write_text('{"schema": 1, "device": {"vendor": ')
    broken = own.parent / "cpu-broken.json"
    broken.write_text("[]")
    other_schema = own.parent / "cpu-future.json"
    other_schema.write_text(json.dumps({"schema": 2, "device": {}, "entries": {}}))
    good = save_result(make_info(name="cpu-zz"), make_result(candidates=[STEADY]), "h", [],
                       root=tmp_path)
    with caplog.at_level(logging.WARNING, logger="clrecon"):
        got = lookup(info, "sweep_resolve", "s-lo", "h", root=tmp_path)
    assert got == Lookup(STEADY, "vendor", str(good))
    msgs = warnings_of(caplog)
    for p in (own, broken, other_schema):
        assert any(str(p) in m for m in msgs), p
    # saving over a corrupt file refuses instead of losing it
    with pytest.raises(ValueError, match="invalid JSON"):
        save_result(info, make_result(), "h", [], root=tmp_path)
    assert own.read_text() == '{"schema": 1, "device": {"vendor": '


def test_load_schema_mismatch_raises(tmp_path):
    p = tmp_path / "dev.json"
    p.write_text(json.dumps({"schema": 99, "device": {}, "entries": {}}))
    with pytest.raises(ValueError, match=r"dev\.json.*schema 99"):
        load(p)
    p.write_text("{oops")
    with pytest.raises(ValueError, match=r"dev\.json"):
        load(p)


def test_bucket_for():
    assert bucket_for(1, 1, 1) == "s-lo"
    assert bucket_for(500, 600, 8) == "s-lo"        # 300 000 px, 8 spp
    assert bucket_for(640, 480, 4) == "m-lo"        # 307 200 px
    assert bucket_for(1000, 1200, 9) == "m-hi"      # 1.2M px
    assert bucket_for(1200001, 1, 16) == "l-hi"
    assert bucket_for(np.int64(1920), np.int32(1080), np.int64(32)) == "l-hi"
    for args in ((0, 10, 4), (10, -1, 4), (10, 10, 0), (2.5, 10, 4), (True, 10, 4)):
        with pytest.raises(ValueError):
            bucket_for(*args)


def _paired_runner(later_ms: float) -> ReplayRunner:
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
    runner, fast = _paired_runner(later_ms=9.0)
    res = tune("p", "s-lo", [fast], DEFAULT, runner)
    assert res.best == fast and res.confirm_ratio == pytest.approx(10.0 / 9.0)


def test_paired_confirmation_rejects_a_gain_that_was_drift():
    """Measured one after another the candidate looked 10% faster; launched alternately
    with the default it is slower: the default stays."""
    runner, fast = _paired_runner(later_ms=11.0)
    res = tune("p", "s-lo", [fast], DEFAULT, runner)
    assert res.best == DEFAULT and res.best_median_ms == res.default_median_ms
    assert res.confirm_ratio == pytest.approx(10.0 / 11.0)
    assert tune("p", "s-lo", [fast], DEFAULT, _paired_runner(11.0)[0], confirm=0).best == fast


def test_session_budget_caps_the_whole_run(monkeypatch, tmp_path):
    """tune_device with fake passes, a fake clock and fake device: making inputs counts, a
    pass whose default cannot fit is skipped by name, and the session ends within budget
    (the old session ran every pass's default whatever was left)."""
    from types import SimpleNamespace

    from clrecon.tune import session

    clock = FakeClock()

    def spec(setup_s, tick_s):
        def runner(dev, w, h, spp):
            clock.t += setup_s
            return TickingRunner(clock, tick_s=tick_s)
        return SimpleNamespace(default=DEFAULT, candidates=lambda: [STEADY, OUTLIER],
                               runner=runner, rtol=1e-5, atol=1e-6, kernel_file="box")

    specs = {"quick": spec(1.0, 0.25), "slow": spec(1.0, 10.0), "late": spec(1.0, 0.25),
             "heavy": spec(13.0, 0.25)}
    dev = SimpleNamespace(info=make_info(max_work_group_size=512), device=None)
    monkeypatch.setattr(session, "SPECS", specs)
    monkeypatch.setattr(session, "get_device", lambda d: dev)
    monkeypatch.setattr(session, "_options", lambda handle, device: [])
    res = session.tune_device("fake", None, (8, 8), 2, budget_s=40.0, root=tmp_path,
                              clock=clock)
    saved = sorted(e["pass"] for e in load(db_path(dev.info, tmp_path))["entries"].values())
    # quick: 1 s inputs, default 2 s, STEADY 2 s, OUTLIER does not fit its 9 s share with
    # the 3.5 s kept back for confirming STEADY, which follows -> t = 8.5; slow: 1 s inputs,
    # a 10 s warm-up, then its 7 runs need 70 s of the 20.5 s left: skipped at t = 19.5;
    # late: as quick, t = 28; heavy: making its inputs takes 13 s of the 12 s left (t = 41:
    # the one overrun a session cannot predict), then it is skipped before any build
    assert [r.pass_name for r, _ in res] == ["quick", "late"] and saved == ["late", "quick"]
    assert [name for name, _ in res.skipped] == ["slow", "heavy"]
    assert "does not fit" in res.skipped[0][1] and "no time left" in res.skipped[1][1]
    assert res.elapsed_s == clock.t == 41.0
    assert all(r.confirm_ratio is not None for r, _ in res)
    # tuned again with 10 ms: quick's entry says its default took 8 x 2 ms of device time,
    # so it is skipped before its inputs are made; slow, without an entry, after them
    clock.t = 0.0
    res = session.tune_device("fake", ["quick", "slow"], (8, 8), 2, budget_s=0.01,
                              root=tmp_path, clock=clock)
    assert not res and [name for name, _ in res.skipped] == ["quick", "slow"]
    assert "0.016 s of device time when last tuned here" in res.skipped[0][1]
    assert "no time left" in res.skipped[1][1] and clock.t == 1.0
