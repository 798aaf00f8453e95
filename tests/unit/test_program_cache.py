"""The on-disk cache of compiled programs (clrecon.core.device): a second process loads the binary
instead of compiling; a corrupt entry, a disabled or an unwritable cache still builds."""
from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from clrecon.core import device as cldev
from clrecon.core import program_cache as pcache

# Builds one small program (with a define and an include) in a fresh process, runs it and
# reports the cache counters and whether the kernel computed the right thing.
CHILD = r"""
import json, sys
import numpy as np
import pyopencl as cl
from clrecon.core import device

offset = float(sys.argv[1])
dev = device.get_device()
src = '''#include "common.h"
__kernel void scale(__global float *a) { size_t i = get_global_id(0); a[i] = a[i] * 2.0f + OFFSET; }
'''
prg = device.build_source(dev.context, src, {"OFFSET": offset}, label="cache-test")
assert device.build_source(dev.context, src, {"OFFSET": offset}) is prg  # in-process cache
a = np.arange(64, dtype=np.float32)
buf = cl.Buffer(dev.context, cl.mem_flags.READ_WRITE | cl.mem_flags.COPY_HOST_PTR, hostbuf=a)
cl.Kernel(prg, "scale")(dev.queue, (a.size,), None, buf)
cl.enqueue_copy(dev.queue, a, buf)
ok = bool(np.array_equal(a, np.arange(64, dtype=np.float32) * 2 + np.float32(offset)))
folder = device.program_cache_dir()
print(json.dumps({"stats": device.program_cache_stats(), "ok": ok,
                  "dir": None if folder is None else str(folder)}))
"""


def _child(cache_dir, offset: float = 1.0, **env_extra) -> dict:
    env = dict(os.environ)
    env.pop(cldev.ENV_CACHE_DIR, None)
    if cache_dir is not None:
        env[cldev.ENV_CACHE_DIR] = str(cache_dir)
    env.update(env_extra)
    proc = subprocess.run([sys.executable, "-c", CHILD, repr(offset)], env=env,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    # the library never prints: the child's only line of stdout is its report
    lines = proc.stdout.strip().splitlines()
    assert len(lines) == 1, proc.stdout
    return json.loads(lines[0])


def _entries(folder: Path) -> list[Path]:
    return sorted(folder.rglob("*.clbin")) if folder.exists() else []


def _all_files(folder: Path) -> list[Path]:
    return sorted(p for p in folder.rglob("*") if p.is_file())


def _stats(hits=0, misses=0, writes=0, errors=0) -> dict:
    return {"hits": hits, "misses": misses, "writes": writes, "errors": errors}


def test_second_process_loads_the_binary(tmp_path):
    cache = tmp_path / "programs"
    first = _child(cache)
    assert first["ok"] and first["dir"] == str(cache)
    assert first["stats"] == _stats(misses=1, writes=1)
    (entry,) = _entries(cache)
    assert _all_files(cache) == [entry]  # no temporary left behind
    second = _child(cache)
    assert second["ok"]
    assert second["stats"] == _stats(hits=1)
    assert _entries(cache) == [entry]


def test_truncated_entry_falls_back_to_source(tmp_path):
    cache = tmp_path / "programs"
    assert _child(cache)["stats"]["writes"] == 1
    (entry,) = _entries(cache)
    data = entry.read_bytes()
    entry.write_bytes(data[: len(data) // 2])
    again = _child(cache)
    assert again["ok"]
    assert again["stats"] == _stats(misses=1, writes=1, errors=1)
    assert pcache._read_entry(entry)  # rewritten whole
    assert _child(cache)["stats"] == _stats(hits=1)


@pytest.mark.parametrize("how", ["empty", "header-only", "garbage-binary"])
def test_corrupt_entry_falls_back_to_source(tmp_path, how):
    cache = tmp_path / "programs"
    _child(cache)
    (entry,) = _entries(cache)
    magic = pcache._CACHE_MAGIC
    if how == "empty":
        entry.write_bytes(b"")
    elif how == "header-only":
        entry.write_bytes(magic + hashlib.sha256(b"").digest())
    else:  # a well-formed entry whose binary the driver must reject
        junk = b"not a program binary" * 50
        entry.write_bytes(magic + hashlib.sha256(junk).digest() + junk)
    again = _child(cache)
    assert again["ok"]
    assert again["stats"] == _stats(misses=1, writes=1, errors=1)
    assert _child(cache)["stats"] == _stats(hits=1)


@pytest.mark.parametrize("value", ["off", "OFF", "", " "])
def test_disabled_cache_writes_nothing(tmp_path, value):
    home = tmp_path / "home"
    home.mkdir()
    out = _child(value, HOME=str(home), XDG_CACHE_HOME=str(tmp_path / "xdg"))
    assert out["ok"] and out["dir"] is None
    assert out["stats"] == _stats()
    # (the driver and pyopencl may keep caches of their own under XDG_CACHE_HOME)
    assert _entries(tmp_path) == []
    assert not (tmp_path / "xdg" / "clrecon").exists()
    assert not (home / ".cache" / "clrecon").exists()


def test_changed_define_is_another_entry(tmp_path):
    cache = tmp_path / "programs"
    assert _child(cache, 1.0)["stats"] == _stats(misses=1, writes=1)
    assert len(_entries(cache)) == 1
    two = _child(cache, 2.5)
    assert two["ok"] and two["stats"] == _stats(misses=1, writes=1)
    assert len(_entries(cache)) == 2
    assert _child(cache, 1.0)["stats"] == _stats(hits=1)
    assert _child(cache, 2.5)["stats"] == _stats(hits=1)


def test_unwritable_cache_still_builds(tmp_path):
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    out = _child(blocker / "programs")  # mkdir fails (even as root)
    assert out["ok"]
    assert out["stats"] == _stats(misses=1, errors=1)
    assert _all_files(tmp_path) == [blocker]


def test_default_location_follows_xdg_then_home(tmp_path):
    env = {"HOME": str(tmp_path / "home"), "XDG_CACHE_HOME": str(tmp_path / "xdg")}
    out = _child(None, **env)
    assert out["ok"] and out["dir"] == str(tmp_path / "xdg" / "clrecon" / "programs")
    # without CLRECON_CACHE_DIR a PoCL device leaves caching to PoCL's own kernel cache
    own = not pcache._self_caching(cldev.get_device().context.devices[0])
    assert len(_entries(tmp_path / "xdg")) == int(own)


def test_cache_dir_resolution(monkeypatch, tmp_path):
    monkeypatch.setenv(cldev.ENV_CACHE_DIR, str(tmp_path / "c"))
    assert cldev.program_cache_dir() == tmp_path / "c"
    for off in ("off", "Off", "", "  "):
        monkeypatch.setenv(cldev.ENV_CACHE_DIR, off)
        assert cldev.program_cache_dir() is None
    monkeypatch.delenv(cldev.ENV_CACHE_DIR)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert cldev.program_cache_dir() == tmp_path / "xdg" / "clrecon" / "programs"
    monkeypatch.setenv("XDG_CACHE_HOME", "relative/ignored")  # XDG: must be absolute
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert cldev.program_cache_dir() == tmp_path / "home" / ".cache" / "clrecon" / "programs"
    monkeypatch.delenv("XDG_CACHE_HOME")
    assert cldev.program_cache_dir() == tmp_path / "home" / ".cache" / "clrecon" / "programs"


def test_stats_is_a_copy():
    stats = cldev.program_cache_stats()
    assert set(stats) == {"hits", "misses", "writes", "errors"}
    stats["hits"] = -1
    assert cldev.program_cache_stats()["hits"] != -1


def test_multi_device_context_keys_each_device(monkeypatch, tmp_path):
    """A context of several devices looks up one entry per device (a hit needs them all)."""
    from types import SimpleNamespace as NS

    plat = NS(name="Plat", version="1.0")
    devs = [NS(platform=plat, name=n, driver_version="7", version="OpenCL 3.0")
            for n in ("gpu-a", "gpu-b", "gpu-a")]
    monkeypatch.setenv(cldev.ENV_CACHE_DIR, str(tmp_path))
    entries = pcache.cache_entries(NS(devices=devs), "src", "hdr", ["-DA=1"])
    paths = [p for _, p in entries]
    assert [d for d, _ in entries] == devs
    assert paths[0] != paths[1] and paths[0] == paths[2]  # same identity, same binary
    assert all(p.parent == tmp_path and p.suffix == ".clbin" for p in paths)
    other = pcache.cache_entries(NS(devices=devs), "src", "hdr", ["-DA=2"])
    assert not {p for _, p in other} & set(paths)
    newer = [NS(platform=plat, name="gpu-a", driver_version="8", version="OpenCL 3.0")]
    assert pcache.cache_entries(NS(devices=newer), "src", "hdr", ["-DA=1"])[0][1] != paths[0]
    monkeypatch.setenv(cldev.ENV_CACHE_DIR, "off")
    assert pcache.cache_entries(NS(devices=devs), "src", "hdr", ["-DA=1"]) is None
