"""``deterministic=True`` of the scatter passes (splat's ``splat``, layered's ``reproject``):
int64 fixed-point accumulation, bit-identical run to run, close to the float-atomic path and
to the NumPy references; and the native float atomics the build options switch on where a
device offers them (``kernels/common.h``, ``clrecon.core.device.language_options``).

Tolerances. The fixed-point sums round each term once, to 2^-40 or finer of the brightest
colour on these frames (``describe()["fixed_resolution"]``): against the references they get
the pass tests' own tolerance (rtol 1e-4, atol 1e-6 of the image's scale: the float32 terms'
rounding, and the reference's rotated offsets). Against the float-atomic path the difference
is that path's own rounding (up to n 2^-24 of the sum of |terms| for n terms into a pixel;
the fixed-point splat images are 30x closer to a float64 sum, see
docs/measurements/deterministic-pocl-intel.md), which the integration then sums over the
PSF: it grows with the blur and the frame (3.5e-4 of the image's maximum at fence 512x512
8 spp); on these frames it stays below 1e-6 of the maximum, tested at 1e-5. On CPU devices
the float atomics of one reproject work-group happen to run in a fixed order (PoCL and
Intel step a group's items in turn), so there the layered test cannot tell the two paths
apart by bit-identity; on a GPU it can, and the grids are still checked against the
reference.
"""
from __future__ import annotations

import numpy as np
import pyopencl as cl
import pytest
from conftest import assert_close
from layered_frames import LAYOUT, bucket_coeffs, empty, fields, read, to_device, upload
from layered_frames import frame as layered_frame
from splat_frames import frame as splat_frame
from splat_frames import reference_splat

from clrecon.core import device as cldev
from clrecon.core.knobs import KnobTypeError
from clrecon.core.local_size import LocalSize
from clrecon.core.pipeline import DeviceSamples
from clrecon.methods.layered import LayeredPipeline
from clrecon.methods.layered import layout as geom
from clrecon.methods.layered import reference as lref
from clrecon.methods.layered.reproject import Reproject
from clrecon.methods.splat import SplatPipeline

RUNS = 3
PROBE = """
#include "common.h"
__kernel void probe(__global int *out)
{
    out[0] = CLRECON_NATIVE_F32_ADD;
    out[1] = __OPENCL_C_VERSION__;
    out[2] = CLRECON_HAS_FIXED;
}
"""


def _int64(device) -> bool:
    return device.info.int64_atomics


def crowded(rng, h=20, w=22, s=16, aperture=14.0):
    """Many samples on the same pixels: CoC up to ~12 px at 16 spp, so that every pixel
    receives thousands of atomic adds whose order the device picks. Motion along the axes
    only: rotations by multiples of 90 degrees are exact in float32, so kernel and reference
    round every rotated offset alike (see test_splat_splat.test_lookup_matches_nested_grid)."""
    buf = splat_frame(rng, h=h, w=w, s=s, aperture=aperture, motion=False)
    axes = np.array([[1, 0], [0, 1], [-1, 0], [0, -1]], np.float32)
    moving = rng.uniform(size=buf.depth.shape) < 0.5
    length = np.where(moving, rng.uniform(0.0, 16.0, buf.depth.shape), 0.0)
    buf.motion[:] = axes[rng.integers(0, 4, buf.depth.shape)] * length[..., None]
    return buf.validate()


# -- native float atomics and the OpenCL C version -----------------------------------------
def test_native_float_add_where_the_device_offers_it(device):
    """The kernels see the native fp32 atomic add exactly where the device has it (and the
    `clrecon devices` atomics line says so), and OpenCL C 2.0+ wherever the device's
    compiler accepts -cl-std for it."""
    prg = cldev.build_source(device.context, PROBE)
    buf = cl.Buffer(device.context, cl.mem_flags.WRITE_ONLY, 12)
    out = np.zeros(3, np.int32)
    cl.Kernel(prg, "probe")(device.queue, (1,), None, buf)
    cl.enqueue_copy(device.queue, out, buf)
    native, version, fixed = (int(v) for v in out)
    std = cldev.opencl_c_std(device.device)
    if std is not None:  # else the compiler's default (OpenCL C 1.x on Oclgrind)
        assert version == {"CL3.0": 300, "CL2.0": 200}[std]
    assert native == int(cldev.native_fp32_atomic_add(device.device))
    assert ("native float add" in device.info.atomics) == bool(native), device.info.atomics
    assert fixed == int(_int64(device))


def test_language_options_of_a_device(device):
    opts = cldev.build_options({"A": 1}, device.context.devices)
    std = cldev.opencl_c_std(device.device)
    assert (f"-cl-std={std}" in opts) == (std is not None)
    assert ("-DCLRECON_FP32_ATOMIC_ADD=1" in opts) == cldev.native_fp32_atomic_add(
        device.device)
    # without devices: the defines alone (what a cache key or a log shows for any device)
    assert cldev.build_options({"A": 1}) == opts[:2]


# -- splat -----------------------------------------------------------------------------------
def _splat(device, buf, runs=RUNS, **knobs):
    """Images of ``runs`` runs of one pipeline: (final images, lap, direct) per run."""
    pipe = SplatPipeline(device.context, buf.inspect(), **{"mip_radius": 0, **knobs})
    q = device.queue
    samples = DeviceSamples.upload(q, buf, pipe.fields)
    shape = (pipe.layers, *pipe.shape, 4)
    got = []
    for _ in range(runs):
        out = cl.Buffer(device.context, cl.mem_flags.READ_WRITE, buf.height * buf.width * 12)
        pipe(q, samples, out).wait()
        img = np.empty((buf.height, buf.width, 3), np.float32)
        lap, direct = np.empty(shape, np.float32), np.empty(shape, np.float32)
        cl.enqueue_copy(q, img, out)
        cl.enqueue_copy(q, lap, pipe.lap)
        cl.enqueue_copy(q, direct, pipe.direct)
        got.append((img, lap, direct))
    q.finish()
    return pipe, got


@pytest.mark.parametrize("knobs", [
    dict(psf="combined", layers=2),
    # every cell sparse: the Laplacian images (values of both signs) carry everything
    dict(psf="simplelens", layers=3, max_error=float("inf")),
], ids=["combined", "simplelens-sparse"])
def test_splat_is_bit_identical_and_matches_reference(device, rng, knobs):
    if not _int64(device):
        pytest.skip("device lacks cl_khr_int64_base_atomics")
    buf = crowded(rng)
    pipe, runs = _splat(device, buf, scatter="atomic", deterministic=True, **knobs)
    d = pipe.describe()
    assert d["deterministic"] and d["accumulation"] == "fixed point"
    assert d["fixed_resolution"] <= 2.0**-40
    for img, lap, direct in runs[1:]:
        for a, b, what in ((img, runs[0][0], "image"), (lap, runs[0][1], "laplacian"),
                           (direct, runs[0][2], "direct")):
            assert np.array_equal(a.view(np.uint32), b.view(np.uint32)), f"{what} differs"
    want_lap, want_direct = reference_splat(pipe, buf)
    scale = float(np.abs(want_direct).max() + np.abs(want_lap).max())
    _, lap, direct = runs[0]
    assert np.abs(want_direct).max() > 0
    if pipe.use_lap:
        assert np.abs(want_lap).max() > 0
        assert_close(lap, want_lap, rtol=1e-4, atol=1e-6 * scale, what="laplacian")
    assert_close(direct, want_direct, rtol=1e-4, atol=1e-6 * scale, what="direct")
    # the float-atomic path: the same sums, rounded in the order the device chose
    _, (flt,) = _splat(device, buf, runs=1, scatter="atomic", **knobs)
    top = float(np.abs(flt[0]).max())
    assert_close(runs[0][0], flt[0], rtol=0.0, atol=1e-5 * top, what="image vs float atomics")
    for a, b, what in ((lap, flt[1], "laplacian"), (direct, flt[2], "direct")):
        assert_close(a, b, rtol=1e-4, atol=1e-6 * scale, what=f"{what} vs float atomics")


def test_splat_plan_lists_the_fixed_point_buffers(device, rng):
    if not _int64(device):
        pytest.skip("device lacks cl_khr_int64_base_atomics")
    buf = crowded(rng, h=8, w=9, s=4)
    info = buf.inspect()
    plain = SplatPipeline(device.context, info, scatter="atomic", max_error=float("inf"),
                          mip_radius=0)
    pipe = SplatPipeline(device.context, info, scatter="atomic", max_error=float("inf"),
                         mip_radius=0,
                         deterministic=True)
    t0, t = plain.plan.temporaries, pipe.plan.temporaries
    assert t["direct_fixed"] == 2 * t0["direct"] and t["lap_fixed"] == 2 * t0["lap"]
    assert t["color_bound"] == 16
    assert set(t) - set(t0) == {"direct_fixed", "lap_fixed", "color_bound"}
    steps = [s.name for s in pipe.plan.steps]
    assert steps[:4] == ["clear", "color_bound", "splat", "fixed_to_float"]
    assert plain.describe()["accumulation"] == "float atomics"
    assert plain.describe()["deterministic"] is False


def test_splat_tiles_are_deterministic_without_fixed_point(device, rng):
    """The owner tiles add in a fixed order: deterministic=True keeps them as they are."""
    buf = crowded(rng, h=12, w=14, s=8)
    pipe, runs = _splat(device, buf, scatter="tiles", deterministic=True)
    assert pipe.describe()["accumulation"] == "owner tiles"
    assert "direct_fixed" not in pipe.plan.temporaries
    for img, _, _ in runs[1:]:
        assert np.array_equal(img, runs[0][0])


def test_splat_brightest_colours_cannot_overflow(device, rng):
    """Colours up to 1e30 (the validation limit) piled on the same pixels: pixel sums of
    ~1e28, beyond int64 even in units of 1 (2^63 = 9.2e18; atomic_add_fixed's 2^-20 units end
    at 8.8e12), let alone in the units ordinary colours need. The scale follows
    the frame's brightest colour, so the result is finite, bit-identical, and matches the
    reference wherever it holds more than the resolution; colours far below the brightest are
    quantised to 2^-e, e = fixed_exponent(klog2, max |colour|) (kernels/common.h)."""
    if not _int64(device):
        pytest.skip("device lacks cl_khr_int64_base_atomics")
    buf = crowded(rng, h=12, w=12, s=8)
    buf.color[:6] *= np.float32(0.99e30) / buf.color[:6].max()  # upper half: up to 1e30
    buf.validate()
    pipe, runs = _splat(device, buf, scatter="atomic", deterministic=True, psf="simplelens",
                        layers=1, max_error=float("inf"))
    assert pipe.use_lap
    for img, lap, direct in runs:
        assert np.isfinite(img).all() and np.isfinite(direct).all() and np.isfinite(lap).all()
        assert np.array_equal(img, runs[0][0])
    want_lap, want_direct = reference_splat(pipe, buf)
    scale = float(np.abs(want_direct).max() + np.abs(want_lap).max())
    assert scale > 1e27
    _, lap, direct = runs[0]
    for c in range(4):
        m = float(np.abs(buf.color[..., c]).max()) if c < 3 else 1.0
        unit = 2.0 ** -_fixed_exponent(pipe.klog2, m)  # the channel's resolution
        for got, want, what in ((direct, want_direct, "direct"), (lap, want_lap, "laplacian")):
            # the documented quantisation: every value a whole number of units ...
            q = got[..., c].astype(np.float64) / unit
            assert np.array_equal(q, np.round(q)), f"{what} channel {c}: not in units"
            # ... and equal to the reference up to the float32 terms' own rounding
            top = scale if c < 3 else 1.0
            assert_close(got[..., c], want[..., c], rtol=1e-4, atol=1e-6 * top,
                         what=f"{what} channel {c}")
        if c < 3:
            assert unit > 1e15, "colours of the dim half lie below the resolution"


def _fixed_exponent(klog2: int, m: float) -> int:
    """kernels/common.h fixed_exponent."""
    ilogb = int(np.frexp(np.float32(max(m, 2.0**-60)))[1]) - 1
    return min(61 - klog2 - (ilogb + 1), 120)


# -- layered ---------------------------------------------------------------------------------
def _params(buf, layout):
    st = lref.tile_stats(buf.depth, buf.motion, buf.coc_model.c0, buf.coc_model.c1,
                         bucket_coeffs(buf, layout), layout, 1)
    return lref.partition_setup(st, layout, 0.33, 0.1).astype(np.float32)


@pytest.mark.parametrize("bilinear", [False, True], ids=["nearest", "bilinear"])
def test_reproject_fixed_is_bit_identical_and_matches_reference(device, rng, bilinear):
    if not _int64(device):
        pytest.skip("device lacks cl_khr_int64_base_atomics")
    buf = layered_frame(rng, s=16)
    layout = geom.Layout(**{**LAYOUT.__dict__, "spp": 16})
    params = _params(buf, layout)
    q = device.queue
    shape = params.shape[:2] + (geom.NCH, layout.dmax * layout.dmax)
    k = bucket_coeffs(buf, layout)
    samples, dparams = upload(q, buf), to_device(q, params)
    rp = Reproject(device.context, layout, bilinear, LocalSize(16, 1), fixed=True)
    fixed = cl.Buffer(device.context, cl.mem_flags.READ_WRITE, int(np.prod(shape)) * 8)
    bound = cl.Buffer(device.context, cl.mem_flags.READ_WRITE, 16)
    runs = []
    for _ in range(RUNS):
        grids = empty(q, shape)
        ev = rp(q, samples, k, dparams, grids, None, fixed, bound)
        runs.append(lref.used_grid(read(q, grids, shape, [ev]), params))
    # the first "reproject" event is the per-sample depth buckets (reproject_buckets)
    assert [n for n, _ in rp.events] == ["reproject", "clear", "reproject_color_bound",
                                         "reproject"]
    flat = [np.concatenate([x.ravel() for x in r]) for r in runs]
    for f in flat[1:]:
        assert np.array_equal(f, flat[0]), "fixed-point grids differ run to run"
    want = lref.used_grid(lref.reproject(fields(buf), params.astype(np.float64), k, layout,
                                         bilinear), params)
    assert sum(x[3].sum() for x in want) > 0 and sum(x[4].sum() for x in want) > 0
    assert_close(flat[0], np.concatenate([x.ravel() for x in want]), rtol=1e-4, atol=2e-4,
                 what="grids")
    if not bilinear:  # the weights are counts: exact in fixed point
        for g, w in zip(runs[0], want):
            assert np.array_equal(g[3:], w[3:].astype(np.float32))


def test_layered_frame_is_bit_identical_with_atomic_reproject(device, rng, monkeypatch):
    """A tuned wg_x > 1 makes reproject's items share a grid with atomics: deterministic=True
    makes that fixed point; the images are bit-identical and close to the float atomics'."""
    if not _int64(device):
        pytest.skip("device lacks cl_khr_int64_base_atomics")
    monkeypatch.setenv("CLRECON_TUNE_REPROJECT", '{"wg_x": 16, "wg_y": 1}')
    buf = layered_frame(rng, h=40, w=44, s=16)
    info = buf.inspect()
    imgs = {}
    for det in (False, True):
        pipe = LayeredPipeline(device.context, info, deterministic=det)
        assert pipe.reproject.local.x == 16
        q = device.queue
        samples = DeviceSamples.upload(q, buf, pipe.fields)
        out = cl.Buffer(device.context, cl.mem_flags.READ_WRITE, buf.height * buf.width * 12)
        imgs[det] = []
        for _ in range(RUNS if det else 1):
            pipe(q, samples, out).wait()
            img = np.empty((buf.height, buf.width, 3), np.float32)
            cl.enqueue_copy(q, img, out)
            imgs[det].append(img)
        d = pipe.describe()
        assert d["deterministic"] is det
        assert d["accumulation"] == ("fixed point" if det else "float atomics")
        temps = pipe.plan.temporaries
        if det:
            assert temps["grids_fixed"] == 2 * temps["grids"] and temps["color_bound"] == 16
            assert d["device_bytes"] == sum(temps.values())
        else:
            assert "grids_fixed" not in temps
    for img in imgs[True][1:]:
        assert np.array_equal(img, imgs[True][0])
    top = float(np.abs(imgs[False][0]).max())
    assert_close(imgs[True][0], imgs[False][0], rtol=0.0, atol=1e-5 * top,
                 what="image vs float atomics")


def test_layered_owner_reproject_needs_no_fixed_point(device, rng, monkeypatch):
    monkeypatch.setenv("CLRECON_TUNE_REPROJECT", '{"wg_x": 1, "wg_y": 1}')
    info = layered_frame(rng, h=8, w=9).inspect()
    pipe = LayeredPipeline(device.context, info, deterministic=True)
    assert pipe.describe()["accumulation"] == "owner"
    assert "grids_fixed" not in pipe.plan.temporaries


# -- the knob --------------------------------------------------------------------------------
@pytest.mark.parametrize("cls", [SplatPipeline, LayeredPipeline], ids=["splat", "layered"])
@pytest.mark.parametrize("bad", [1, "yes", None])
def test_knob_is_a_flag(device, rng, cls, bad):
    info = layered_frame(rng, h=6, w=7).inspect()
    with pytest.raises(KnobTypeError, match="deterministic"):
        cls(device.context, info, deterministic=bad)
