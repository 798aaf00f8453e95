"""What a device without a tuning entry gets: GPU-shaped defaults on GPUs (whole warps, 64-256
work-items a group, within the device's limits), the specs' CPU defaults elsewhere; tuning
candidates that differ only in their local size share one program; stale committed entries
fall back cleanly."""
from __future__ import annotations

import dataclasses
import json
import logging

import numpy as np
import pyopencl as cl
import pytest
from conftest import assert_close
from sweep_frames import frame
from test_local_memory import sweep_image

import clrecon
from clrecon.core import device as cldev
from clrecon.core.device import source_hash
from clrecon.core.resources import tuning_dir
from clrecon.methods.sweep import reference as ref
from clrecon.tune import db
from clrecon.tune.runners import DEFAULTS, GPU_DEFAULTS, SPECS, synthetic_frame
from clrecon.tune.runtime import default_config, fit_config, resolve, tuned

_TEMPLATE = cldev.list_devices()[0]


def fake(device_type: str, max_wg: int = 1024, **kw) -> cldev.DeviceInfo:
    """A device description (no OpenCL device behind it): a made-up vendor, so that no
    committed tuning file matches it."""
    return dataclasses.replace(_TEMPLATE, platform="Fake Platform", name=f"fake {device_type}",
                               vendor="Fake Vendor", device_type=device_type,
                               max_work_group_size=max_wg, **kw)


def items(config: dict) -> int:
    """Work-items a group of a configuration."""
    if "wg_x" in config:
        return config["wg_x"] * config["wg_y"]
    if "tile" in config:
        return config["tile"] ** 2
    return config.get("wg") or config["group"]


@pytest.fixture(autouse=True)
def _clean(monkeypatch):
    import os

    for var in [v for v in os.environ if v.startswith("CLRECON_TUNE_")]:
        monkeypatch.delenv(var)
    db.clear_cache()
    yield
    db.clear_cache()


@pytest.mark.parametrize("name", sorted(SPECS))
def test_gpu_defaults_are_gpu_shaped(name):
    cfg = default_config(SPECS[name].tunable, fake("GPU"))
    assert cfg == GPU_DEFAULTS[name]
    n = items(cfg)
    assert 64 <= n <= 256 and n % 32 == 0, f"{name}: {cfg} is {n} work-items a group"


def test_gpu_defaults_differ_where_the_cpu_defaults_are_not_gpu_shaped():
    """The CPU defaults that run one to sixteen items a group are replaced on GPUs."""
    narrow = [n for n, c in DEFAULTS.items() if items(c) < 32]
    assert {"reproject", "tile_stats", "partition_setup", "sweep_block",
            "sweep_resolve"} <= set(narrow)
    for name in narrow:
        assert GPU_DEFAULTS[name] != DEFAULTS[name], name


@pytest.mark.parametrize("name", sorted(SPECS))
def test_other_devices_get_the_spec_default(name):
    for kind in ("CPU", "ACCELERATOR", "OTHER"):
        assert default_config(SPECS[name].tunable, fake(kind, max_wg=8192)) == \
            SPECS[name].default


@pytest.mark.parametrize("max_wg", [1, 16, 32, 48, 64, 100])
def test_defaults_fit_the_device_max_work_group_size(max_wg):
    for name in SPECS:
        for kind in ("GPU", "CPU"):
            cfg = default_config(SPECS[name].tunable, fake(kind, max_wg))
            assert 1 <= items(cfg) <= max_wg, (name, kind, cfg)


def test_fit_config_keeps_rows_and_shape():
    assert fit_config({"wg_x": 32, "wg_y": 4}, 64) == {"wg_x": 32, "wg_y": 2}
    assert fit_config({"wg_x": 32, "wg_y": 4}, 16) == {"wg_x": 16, "wg_y": 1}
    assert fit_config({"wg_x": 8, "wg_y": 8}, 1024) == {"wg_x": 8, "wg_y": 8}
    assert fit_config({"sort": "tile", "tile": 8, "tile_merge": "auto"}, 32) == \
        {"sort": "tile", "tile": 4, "tile_merge": "auto"}
    assert fit_config({"group": 64}, 20) == {"group": 16}
    assert fit_config({"wg": 256}, 100) == {"wg": 64}
    assert fit_config(None, 1) is None


def test_chain_on_a_fake_gpu(tmp_path, monkeypatch):
    """No entry: the GPU default; an entry of a sibling GPU (same vendor and type) with a
    larger group than this one takes: fitted; an environment override: as given."""
    gpu = fake("GPU", max_wg=256)
    reproject, box = SPECS["reproject"].tunable, SPECS["box"].tunable
    digest = source_hash("reproject")
    found = resolve(gpu, reproject, "s-hi", digest, root=tmp_path)
    assert found == db.Lookup({"wg_x": 64, "wg_y": 1}, "default", None)
    cpu = fake("CPU")
    assert resolve(cpu, reproject, "s-hi", digest, root=tmp_path).config == \
        {"wg_x": 1, "wg_y": 1}

    sibling = dataclasses.replace(gpu, name="fake GPU, larger", max_work_group_size=1024)
    path = db.db_path(sibling, tmp_path)
    path.parent.mkdir(parents=True)
    entry = {"pass": "box", "bucket": "s-hi", "source_hash": source_hash("box"),
             "best": {"wg_x": 32, "wg_y": 32}}
    path.write_text(json.dumps({"schema": db.SCHEMA_VERSION, "device": sibling.fingerprint(),
                                "entries": {"box|s-hi": entry}}))
    found = resolve(gpu, box, "s-hi", source_hash("box"), root=tmp_path)
    assert found.source == "vendor" and found.config == {"wg_x": 32, "wg_y": 8}

    monkeypatch.setenv(db.env_var("box"), '{"wg_x": 64, "wg_y": 16}')
    assert resolve(gpu, box, "s-hi", source_hash("box"), root=tmp_path) == \
        db.Lookup({"wg_x": 64, "wg_y": 16}, "env", None)


def test_committed_entries_resolve_without_error(caplog):
    """Every entry of the committed tuning files, looked up for its own device with the
    kernel's current hash: a current entry is used, a stale one (its kernel changed since)
    is skipped with a warning and the chain goes on; nothing raises."""
    paths = sorted(tuning_dir().glob("*/*.json"))
    assert paths
    for path in paths:
        data = db.load(path)
        d = data["device"]
        info = dataclasses.replace(
            _TEMPLATE, platform=d["platform"], name=d["device"], vendor=d["vendor"],
            device_type=d["device_type"], max_work_group_size=4096)
        assert db.db_path(info) == path
        for key, entry in data["entries"].items():
            digest = source_hash(SPECS[entry["pass"]].kernel_file)
            with caplog.at_level(logging.WARNING, logger="clrecon"):
                found = resolve(info, SPECS[entry["pass"]].tunable, entry["bucket"], digest)
            if entry["source_hash"] == digest:
                assert found.source == "exact", key
            else:
                assert found.source in ("vendor", "default"), key
                assert any("stale" in r.getMessage() and key.split("|")[0] in r.getMessage()
                           for r in caplog.records), key


def test_this_device_gets_the_default_of_its_type(device, tmp_path):
    """On every device (Oclgrind reports itself as a GPU): with no tuning entry, each pass's
    configuration is the default for the device's type, fitted to it."""
    info = device.info
    for name in SPECS:
        found = resolve(info, SPECS[name].tunable, "s-hi", source_hash(SPECS[name].kernel_file),
                        root=tmp_path)
        assert found.source == "default"
        want = (GPU_DEFAULTS if info.device_type == "GPU" else DEFAULTS)[name]
        assert found.config == fit_config(want, info.max_work_group_size)
    frame = synthetic_frame(8, 6, 2).inspect()
    got = tuned(device.context, SPECS["reproject"].tunable, frame)
    if got.source == "default":
        assert got.config == default_config(SPECS["reproject"].tunable, info)


def test_gpu_defaults_run_and_match_the_reference(device, rng):
    """The defaults this device gets launch and give the reference's image: box (its local
    size), and the sweep's tile sort (an 8x8 tile on GPUs where it fits local memory)."""
    buf = frame(rng, h=9, w=10, s=2)
    res = clrecon.run(buf, "box", device)
    if res.method["tuning"]["box"] == "default":
        cfg = default_config(SPECS["box"].tunable, device.info)
        assert res.method["local_size"] == [cfg["wg_x"], cfg["wg_y"]]
    assert_close(res.image, buf.color.astype(np.float64).mean(axis=2), rtol=1e-5, what="box")
    how, img = sweep_image(device, buf, specialize=False)
    if how["sort"] == "tile" and how["tuning"].get("sweep_resolve") == "default":
        assert how["tile"] == default_config(SPECS["sweep_resolve"].tunable, device.info)["tile"]
    assert_close(img, ref.reconstruct(buf), rtol=2e-4, atol=2e-5, what="sweep")


def test_local_size_candidates_share_one_program(device):
    """The local size of these passes is a launch parameter only: the pass built for two
    local sizes (two tuning candidates) uses one program, built once, not one per size."""
    from clrecon.core.local_size import LocalSize
    from clrecon.methods.layered.composite import LayeredComposite
    from clrecon.methods.layered.filter_mip import FilterMip
    from clrecon.methods.layered.filter_rotated import FilterRotated
    from clrecon.methods.layered.filter_sheared import FilterSheared
    from clrecon.methods.layered.layout import Layout
    from clrecon.methods.layered.partition_setup import PartitionSetup
    from clrecon.methods.layered.tile_stats import TileStats
    from clrecon.methods.splat.composite import SplatComposite
    from clrecon.methods.splat.integrate import SplatIntegrate
    from clrecon.methods.sweep.layers import SweepLayerResolve, SweepLayerSums
    from clrecon.methods.sweep.prepare import SweepPrepare
    from clrecon.methods.sweep.resolve import SweepResolve

    ctx, lay = device.context, Layout()
    passes = {
        "sweep_prepare": lambda loc: SweepPrepare(ctx, 4, True, loc),
        "sweep_resolve (pixel)": lambda loc: SweepResolve(ctx, 4, sort="pixel", local=loc),
        "sweep_layer_sums": lambda loc: SweepLayerSums(ctx, 4, loc),
        "sweep_layer_resolve": lambda loc: SweepLayerResolve(ctx, 4, loc),
        "tile_stats": lambda loc: TileStats(ctx, lay, loc),
        "partition_setup": lambda loc: PartitionSetup(ctx, lay, loc),
        "filter_sheared": lambda loc: FilterSheared(ctx, lay, 3, loc),
        "filter_rotated": lambda loc: FilterRotated(ctx, lay, loc),
        "filter_mip": lambda loc: FilterMip(ctx, lay, loc),
        "layered_composite": lambda loc: LayeredComposite(ctx, lay, loc),
        "splat_integrate": lambda loc: SplatIntegrate(ctx, 12, 10, "f5", loc),
        "splat_composite": lambda loc: SplatComposite(ctx, 2, True, loc),
    }
    for name, make in passes.items():
        progs = {make(loc).kernel.get_info(cl.kernel_info.PROGRAM).int_ptr
                 for loc in (LocalSize(8, 1), LocalSize(16, 4), LocalSize(4, 4))}
        assert len(progs) == 1, f"{name}: {len(progs)} programs for 3 local sizes"
