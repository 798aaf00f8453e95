"""The streaming-peak kernel (kernels/bandwidth.cl) against NumPy, the peak's numbers, and
clpeak's figures read from its XML (a stand-in binary: no clpeak run, no timing asserted)."""
from __future__ import annotations

import math
import os
import stat
import sys

import numpy as np
import pyopencl as cl
import pytest

from clrecon.bench import bandwidth as bw


def test_copy_is_bit_exact(device, rng):
    a = rng.standard_normal(4 * 4099).astype(np.float32)  # not a multiple of a work-group
    a[:6] = [np.inf, -np.inf, np.nan, -0.0, np.finfo(np.float32).tiny / 4, -1e38]
    out = bw.copy_array(device.queue, a)
    assert out.shape == a.shape
    np.testing.assert_array_equal(out.view(np.uint32), a.view(np.uint32))


def test_copy_catches_a_wrong_copy(device, rng):
    """The comparison above can fail: a copy of other data is not equal."""
    a = rng.standard_normal(64).astype(np.float32)
    out = bw.copy_array(device.queue, a)
    assert not np.array_equal(out.view(np.uint32), (a + 1).view(np.uint32))


@pytest.mark.parametrize("bad, match", [
    (np.zeros(6, np.float32), "multiple of 16"),
    (np.zeros(0, np.float32), "multiple of 16"),
    (np.zeros(8, np.float64), "float32"),
    (np.zeros((4, 8), np.float32)[:, ::2], "C-contiguous"),
])
def test_copy_refuses_bad_arrays(device, bad, match):
    with pytest.raises(ValueError, match=match):
        bw.copy_array(device.queue, bad)


def test_peak_numbers_are_sane(device):
    nbytes = 4 * 2**20
    pk = bw.measure_peak(device.queue, nbytes, runs=3)
    assert pk.buffer_bytes == nbytes and pk.bytes_per_launch == 2 * nbytes
    assert len(pk.runs_gb_per_s) == 3
    assert all(math.isfinite(r) and r > 0 for r in pk.runs_gb_per_s)
    assert pk.gb_per_s == sorted(pk.runs_gb_per_s)[1]  # the median
    d = pk.to_dict()
    assert d["kernel"] == "copy_float4" and d["gb_per_s"] == pk.gb_per_s


def test_peak_refuses_bad_arguments(device):
    with pytest.raises(ValueError, match="multiple of 16"):
        bw.measure_peak(device.queue, 1000)
    with pytest.raises(ValueError, match="runs"):
        bw.measure_peak(device.queue, 1024, runs=0)
    plain = cl.CommandQueue(device.context)
    with pytest.raises(ValueError, match="profiling"):
        bw.measure_peak(plain, 1024)


def test_default_buffer_is_beyond_the_cache_and_fits(device):
    dev = device.device
    n = bw.default_buffer_bytes(dev)
    assert n % 16 == 0 and n <= dev.max_mem_alloc_size and n <= dev.global_mem_size // 4
    cache = dev.get_info(cl.device_info.GLOBAL_MEM_CACHE_SIZE)
    cap = min(dev.max_mem_alloc_size, dev.global_mem_size // 4) // 16 * 16
    assert n == min(max(bw.MIN_BUFFER_BYTES, 8 * cache), cap) // 16 * 16


class _FakeDevice:
    """What default_buffer_bytes reads of a device: its cache and memory sizes."""

    def __init__(self, cache, alloc, total):
        self.cache, self.max_mem_alloc_size, self.global_mem_size = cache, alloc, total

    def get_info(self, what):
        assert what == cl.device_info.GLOBAL_MEM_CACHE_SIZE
        return self.cache


@pytest.mark.parametrize("cache, alloc, total, want", [
    (2**20, 2**32, 2**34, bw.MIN_BUFFER_BYTES),      # a small cache: the floor
    (64 * 2**20, 2**32, 2**34, 512 * 2**20),        # 8x the cache fits
    (260 * 2**20, 2**32, 4500 * 2**20, 1125 * 2**20),  # a 260 MiB L3: a quarter of memory
    (0, 2**30 + 8, 2**34, bw.MIN_BUFFER_BYTES),     # no cache reported
    (2**30, 2**28 + 8, 2**34, 2**28),               # the allocation limit, in whole float4s
])
def test_default_buffer_sizes(cache, alloc, total, want):
    assert bw.default_buffer_bytes(_FakeDevice(cache, alloc, total)) == want


# -- clpeak --------------------------------------------------------------------------------

XML = """<?xml version="1.0" encoding="utf-8"?>
<clpeak os="Linux x64">
  <platform name="Plat A">
    <device name="{name}" driver_version="1" compute_units="2">
      <global_memory_bandwidth unit="gbps">
        <float>4.5</float><float2>7.5</float2><float4>9.0</float4><float8>11.25</float8>
        <float16>9.5</float16>
      </global_memory_bandwidth>
    </device>
  </platform>
</clpeak>
"""


def test_parse_clpeak_xml():
    found = bw.parse_clpeak_xml(XML.format(name="Dev"))
    assert found == {"Plat A / Dev": {"float": 4.5, "float2": 7.5, "float4": 9.0,
                                      "float8": 11.25, "float16": 9.5}}
    with pytest.raises(ValueError, match="clpeak XML"):
        bw.parse_clpeak_xml("<other/>")
    with pytest.raises(ValueError, match="clpeak XML"):
        bw.parse_clpeak_xml("not xml")
    with pytest.raises(ValueError, match="not a number"):
        bw.parse_clpeak_xml(XML.format(name="Dev").replace("9.0", "fast"))


def _fake_clpeak(tmp_path, body: str) -> str:
    """An executable standing in for clpeak: ``body`` is Python run with clpeak's argv."""
    path = tmp_path / "clpeak"
    path.write_text(f"#!{sys.executable}\nimport sys\nargs = sys.argv[1:]\n{body}\n")
    path.chmod(path.stat().st_mode | stat.S_IEXEC)
    return str(path)


def test_clpeak_figures_of_this_device(device, tmp_path):
    log = tmp_path / "argv.txt"
    xml = XML.format(name=device.device.name.strip())
    exe = _fake_clpeak(tmp_path, f"open({str(log)!r}, 'w').write(' '.join(args))\n"
                                 f"open(args[args.index('-f') + 1], 'w').write({xml!r})")
    res = bw.clpeak_bandwidth(device.device, executable=exe)
    p, d = bw.clpeak_indices(device.device)
    argv = log.read_text().split()
    assert argv[:5] == ["--global-bandwidth", "-p", str(p), "-d", str(d)]
    assert res["best_width"] == "float8" and res["best_gb_per_s"] == 11.25
    assert res["gb_per_s"]["float4"] == 9.0 and "error" not in res
    plat = cl.get_platforms()[p]
    assert plat.get_devices()[d].int_ptr == device.device.int_ptr


def test_clpeak_failures_are_reported_not_raised(device, tmp_path):
    exe = _fake_clpeak(tmp_path, "sys.stderr.write('no platform\\n'); sys.exit(3)")
    res = bw.clpeak_bandwidth(device.device, executable=exe)
    assert "exit status 3" in res["error"] and "no platform" in res["error"]
    assert "best_gb_per_s" not in res
    other = XML.format(name="some other device")
    exe = _fake_clpeak(tmp_path, f"open(args[args.index('-f') + 1], 'w').write({other!r})")
    assert "some other device" in bw.clpeak_bandwidth(device.device, executable=exe)["error"]
    exe = _fake_clpeak(tmp_path, "import time; time.sleep(30)")
    assert "timed out" in bw.clpeak_bandwidth(device.device, timeout_s=0.5,
                                              executable=exe)["error"]


def test_clpeak_absent_is_none(device, monkeypatch, tmp_path):
    monkeypatch.setattr(bw.shutil, "which", lambda name: None)
    assert bw.clpeak_bandwidth(device.device) is None
    assert bw.clpeak_bandwidth(device.device, executable=str(tmp_path / "nope")) is None
    assert not os.path.exists(tmp_path / "nope")
