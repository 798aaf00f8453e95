"""The autotuner's budget, without OpenCL: a search and a session that stop within the time
they are given (fake clock, replayed runner)."""
from __future__ import annotations

import pytest
from test_tune_db import make_info
from test_tune_logic import (
    DEFAULT,
    NEAR_DEFAULT,
    OUTLIER,
    RUNTIME,
    STEADY,
    FakeClock,
    ReplayRunner,
    clean_tuning,  # noqa: F401  (autouse: no tuning override leaks in)
    paired_runner,
)

from clrecon.tune import (
    config_key,
    db_path,
    load,
    tune,
)


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
    runner, fast = paired_runner(later_ms=9.0)
    runner.clock, runner.tick_s = clock, 1.0
    # default 8 s + candidate 8 s + 7 pairs (14 s) = 30 s
    res = tune("p", "s-lo", [fast], DEFAULT, runner, budget_s=30.0, clock=clock)
    assert res.best == fast and res.confirm_ratio is not None and not res.confirm_skipped
    assert res.elapsed_s == 30.0
    # 29 s: the candidate fits only by eating the confirmation's reserve, so it is skipped
    clock = FakeClock()
    runner, fast = paired_runner(later_ms=9.0)
    runner.clock, runner.tick_s = clock, 1.0
    res = tune("p", "s-lo", [fast], DEFAULT, runner, budget_s=29.0, clock=clock)
    assert [m.status for m in res.measurements] == ["ok", "skipped_budget"]
    assert "kept for the paired confirmation" in res.measurements[1].error
    assert res.best == DEFAULT and res.elapsed_s == 8.0


def test_budget_skips_an_unaffordable_confirmation_and_keeps_the_default():
    """The winner is faster on the device but its launches take twice the default's wall
    time (reading back, say): its confirmation needs more than was kept back."""
    clock = FakeClock()
    replay, fast = paired_runner(later_ms=9.0)
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
