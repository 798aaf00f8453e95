"""Device layer: enumeration, selection, program cache, build errors, atomic helpers."""
from __future__ import annotations

import numpy as np
import pyopencl as cl
import pytest

from clrecon.core import device as cldev
from clrecon.core.errors import DeviceError, KernelBuildError

ATOMIC_SRC = """
#include "common.h"
/* Every work-item adds its value into one of NBINS bins: heavy contention when NBINS is small. */
__kernel void add_float(__global const float *vals, __global const int *bins,
                        volatile __global float *out)
{
    int i = get_global_id(0);
    atomic_add_f32(&out[bins[i]], vals[i]);
}
#if CLRECON_HAS_FIXED
__kernel void add_fixed(__global const float *vals, __global const int *bins,
                        volatile __global long *out)
{
    int i = get_global_id(0);
    atomic_add_fixed(&out[bins[i]], vals[i]);
}
#endif
"""


def test_list_devices_describes_each_device():
    devs = cldev.list_devices()
    assert devs, "the test machine must have an OpenCL device (PoCL in CI)"
    for i, d in enumerate(devs):
        assert d.index == i
        assert d.compute_units >= 1 and d.global_mem_bytes > 0
        assert d.device_type in {"GPU", "CPU", "ACCELERATOR", "OTHER"}
        assert "float" in d.atomics


def test_select_by_index_substring_and_env(monkeypatch):
    first = cldev.list_devices()[0]
    assert cldev.get_device(0).info.name == first.name
    assert cldev.get_device("0").info.index == 0
    assert cldev.get_device(first.name[:6].upper()).info.name == first.name
    monkeypatch.setenv(cldev.ENV_DEVICE, first.name[:6])
    assert cldev.get_device().info.name == first.name
    with pytest.raises(DeviceError, match="no OpenCL device matches"):
        cldev.get_device("no-such-device-xyz")
    with pytest.raises(DeviceError, match="out of range"):
        cldev.get_device(999)


def test_queue_profiles(device):
    assert device.queue.properties & cl.command_queue_properties.PROFILING_ENABLE


def test_program_and_kernel_cache(device):
    a = cldev.build_source(device.context, ATOMIC_SRC, {"FIXED_SHIFT": 20})
    b = cldev.build_source(device.context, ATOMIC_SRC, {"FIXED_SHIFT": 20})
    c = cldev.build_source(device.context, ATOMIC_SRC, {"FIXED_SHIFT": 16})
    assert a is b and a is not c
    k1 = device.kernel("box", "box_average")
    k2 = device.kernel("box", "box_average")
    assert k1 is k2


def test_build_error_carries_options_and_log(device):
    src = "__kernel void broken(__global float *x) { x[0] = undeclared_thing; }"
    with pytest.raises(KernelBuildError) as info:
        cldev.build_source(device.context, src, {"MY_OPT": 3}, label="broken.cl")
    err = info.value
    assert "-DMY_OPT=3" in err.options
    assert any(o.startswith("-I") for o in err.options)
    assert "undeclared_thing" in err.log


def test_build_options_format():
    opts = cldev.build_options({"WG_X": 8, "SIGMA": 0.5, "HAS_MOTION": False})
    assert opts[0].startswith("-I") and opts[0].endswith("kernels")
    assert opts[1:] == ["-DHAS_MOTION=0", "-DSIGMA=0.5f", "-DWG_X=8"]


def _contended_inputs(n=1 << 18, nbins=7, seed=0):
    rng = np.random.default_rng(seed)
    vals = rng.uniform(-1.0, 4.0, n).astype(np.float32)
    bins = rng.integers(0, nbins, n).astype(np.int32)
    return vals, bins, nbins


def _run(device, kernel_name, vals, bins, nbins, dtype):
    prg = cldev.build_source(device.context, ATOMIC_SRC)
    mf = cl.mem_flags
    ctx, q = device.context, device.queue
    dv = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=vals)
    db = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=bins)
    out = np.zeros(nbins, dtype)
    dout = cl.Buffer(ctx, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=out)
    cl.Kernel(prg, kernel_name)(q, (vals.size,), None, dv, db, dout)
    cl.enqueue_copy(q, out, dout)
    return out


def test_float_atomic_add_under_contention(device):
    vals, bins, nbins = _contended_inputs()
    got = _run(device, "add_float", vals, bins, nbins, np.float32)
    want = np.bincount(bins, weights=vals.astype(np.float64), minlength=nbins)
    # float32 accumulation of ~37k terms of magnitude <= 4: order-dependent rounding only
    np.testing.assert_allclose(got, want, rtol=2e-4)


def test_fixed_point_sum_is_exact_and_bit_identical(device):
    if not device.info.int64_atomics:
        pytest.skip("device lacks cl_khr_int64_base_atomics")
    vals, bins, nbins = _contended_inputs(seed=1)
    runs = [_run(device, "add_fixed", vals, bins, nbins, np.int64) for _ in range(4)]
    for r in runs[1:]:
        assert np.array_equal(r, runs[0]), "fixed-point accumulation must not depend on order"
    # each term is rounded to 2^-20 independently: the integer sum equals NumPy's exactly
    want = np.zeros(nbins, np.int64)
    np.add.at(want, bins, np.rint(vals.astype(np.float64) * (1 << 20)).astype(np.int64))
    assert np.array_equal(runs[0], want)
    np.testing.assert_allclose(cldev.fixed_to_float(runs[0]),
                               np.bincount(bins, weights=vals, minlength=nbins), rtol=1e-6)


def test_event_ms(device):
    vals, bins, nbins = _contended_inputs(n=1024)
    prg = cldev.build_source(device.context, ATOMIC_SRC)
    mf = cl.mem_flags
    dv = cl.Buffer(device.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=vals)
    db = cl.Buffer(device.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=bins)
    dout = cl.Buffer(device.context, mf.READ_WRITE, size=4 * nbins)
    cl.enqueue_fill_buffer(device.queue, dout, np.float32(0), 0, 4 * nbins)
    ev = cl.Kernel(prg, "add_float")(device.queue, (1024,), None, dv, db, dout)
    ev.wait()
    assert cldev.event_ms(ev) >= 0.0
