"""The tuning database without OpenCL: layout, merging, the lookup chain and its fallbacks,
bad files, size buckets."""
from __future__ import annotations

import json
import logging
from datetime import datetime

import numpy as np
import pytest
from test_tune_logic import (
    DEFAULT,
    OUTLIER,
    RUNTIME,
    STEADY,
    TILE2_SERIAL,
    ReplayRunner,
    clean_tuning,  # noqa: F401  (autouse: no tuning override leaks in)
)

from clrecon.core.device import DeviceInfo
from clrecon.tune import (
    SCHEMA_VERSION,
    Lookup,
    bucket_for,
    clear_cache,
    db_path,
    load,
    lookup,
    save_result,
    slug,
    tune,
)

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
