"""The tuner on real OpenCL devices: specs build and verify, failures are data, and the
run-time lookup feeds the pipelines (the search logic itself: tests/unit/test_tune_logic.py)."""
from __future__ import annotations

import json

import pytest

import clrecon
from clrecon.core.device import source_hash
from clrecon.tune import db
from clrecon.tune.runners import DEFAULTS, SPECS, synthetic_frame
from clrecon.tune.runtime import tuned
from clrecon.tune.session import tune_device
from clrecon.tune.tuner import tune


def test_tune_device_writes_a_database_entry_per_pass(device, tmp_path):
    results = tune_device(device, ["box", "sweep_layer_sums"], size=(24, 16), spp=2,
                          budget_s=60, runs=7, root=tmp_path)
    path = db.db_path(device.info, tmp_path)
    data = db.load(path)
    assert data["device"] == device.info.fingerprint()
    for res, written in results:
        assert written == str(path)
        entry = data["entries"][f"{res.pass_name}|{res.bucket}"]
        assert entry["source_hash"] == source_hash(SPECS[res.pass_name].kernel_file)
        assert any(o.startswith("-I") for o in entry["build_options"])
        ok = [m for m in entry["measurements"] if m["status"] == "ok"]
        assert ok and all(len(m["times_ms"]) == 7 for m in ok)
        found = db.lookup(device.info, res.pass_name, res.bucket, entry["source_hash"], DEFAULTS,
                          root=tmp_path)
        assert found.source == "exact" and found.config == res.best
        # a changed kernel makes the entry stale: never used
        stale = db.lookup(device.info, res.pass_name, res.bucket, "0" * 16, DEFAULTS,
                          root=tmp_path)
        assert stale.source == "default"


def test_failures_are_recorded_not_fatal(device):
    spec = SPECS["sweep_resolve"]
    runner = spec.runner(device, 20, 12, 2)
    candidates = [spec.default,
                  {"sort": "tile", "tile": 0, "tile_merge": "serial"},  # refused by the pass
                  {"sort": "pixel", "wg_x": 256, "wg_y": 256},  # beyond any device limit
                  {"sort": "pixel", "wg_x": 8, "wg_y": 2}]
    res = tune("sweep_resolve", "t", candidates, spec.default, runner,
               device_max_wg=device.info.max_work_group_size, rtol=spec.rtol, atol=spec.atol)
    status = {json.dumps(m.config, sort_keys=True): m.status for m in res.measurements}
    assert list(status.values()) == ["ok", "build_error", "pruned", "ok"]
    assert res.best in (candidates[0], candidates[3])


def test_every_spec_verifies_its_candidates(device):
    """Each spec's runner builds its default and a second candidate that must agree."""
    for name, spec in SPECS.items():
        runner = spec.runner(device, 20, 12, 2)
        others = [c for c in spec.candidates() if c != spec.default][:1]
        res = tune(name, "t", [spec.default, *others], spec.default, runner,
                   rtol=spec.rtol, atol=spec.atol)
        assert [m.status for m in res.measurements] == ["ok", "ok"], name


def test_pipelines_report_where_their_configuration_came_from(device, monkeypatch):
    buf = synthetic_frame(16, 12, 2)
    res = clrecon.run(buf, "box", device)
    assert res.method["tuning"]["box"] in {"exact", "vendor", "default", "runtime"}
    monkeypatch.setenv(db.env_var("box"), '{"wg_x": 1, "wg_y": 1}')
    res = clrecon.run(buf, "box", device)
    assert res.method["tuning"] == {"box": "env"} and res.method["local_size"] == [1, 1]
    monkeypatch.setenv(db.env_var("sweep_resolve"), '{"sort": "pixel", "wg_x": 4, "wg_y": 4}')
    monkeypatch.setenv(db.env_var("sweep_block"), '{"group": 2}')
    res = clrecon.run(buf, "sweep", device)
    if res.method["sort"] == "block":  # the default plan on CPUs
        assert res.method["tuning"]["sweep_block"] == "env" and res.method["group"] == 2
        res = clrecon.run(buf, "sweep", device, sort="block", group=1)
        assert res.method["tuning"]["sweep_block"] == "api" and res.method["group"] == 1
    else:
        assert res.method["tuning"]["sweep_resolve"] == "env" and res.method["sort"] == "pixel"
    res = clrecon.run(buf, "sweep", device, sort="tile")  # the caller's knob wins
    assert res.method["tuning"]["sweep_resolve"] == "api" and res.method["sort"] == "tile"


def test_lookup_levels_for_this_device(device):
    info = synthetic_frame(8, 8, 2).inspect()
    found = tuned(device.context, SPECS["sweep_prepare"].tunable, info)
    assert found.source in {"exact", "vendor", "default", "runtime"}
    assert found.config is None or set(found.config) == {"wg_x", "wg_y"}


def test_unknown_pass_is_an_error(device):
    with pytest.raises(ValueError, match="unknown"):
        tune_device(device, ["nope"], size=(8, 8), spp=1)


def test_multi_kernel_passes_are_timed_whole(device):
    """splat_integrate enqueues one kernel per pyramid level: the runner's time is their sum, not
    the last kernel's (which alone took ~0.02 ms and would decide the tuning)."""
    runner = SPECS["splat_integrate"].runner(device, 96, 64, 4)
    handle = runner.build(None)
    _, ms = runner.run(handle)
    events = handle.events
    assert len(events) > 2
    parts = [(e.profile.end - e.profile.start) * 1e-6 for e in events]
    assert ms == pytest.approx(sum(parts), rel=1e-6)
    assert ms > parts[-1]
