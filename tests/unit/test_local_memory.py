"""Every pass that sizes local memory chooses a configuration the device holds, or refuses
with the need and the limit before anything is enqueued: the sweep's block and tile sorts
(falling back to a smaller group or tile, then to the pixel sort, which needs none) and
integrate's ring reduction. Fake devices give the limits of other hardware (Intel's CPU
runtime: 256 KiB; Oclgrind: 32 KiB); the device tests run where a device's own limit
forces the fallback."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pyopencl as cl
import pytest
from conftest import assert_close
from sweep_frames import frame

from clrecon.core import device as cldev
from clrecon.core.pipeline import DeviceSamples
from clrecon.methods.splat.integrate import RING_WG, ring_group
from clrecon.methods.sweep import SweepPipeline, default_sort, fit_group, fit_tile
from clrecon.methods.sweep import reference as ref
from clrecon.methods.sweep.block import block_local_bytes
from clrecon.methods.sweep.resolve import (
    MAX_TILE_SAMPLES,
    SweepResolve,
    tile_local_bytes,
    tile_samples_fit,
    tile_sort_size,
)
from clrecon.tune.runtime import check_kernel_fits

INTEL_CPU = 262_144  # Intel's OpenCL CPU runtime
OCLGRIND = 32_768


def fake(local: int, max_wg: int = 8192, kind=cl.device_type.CPU) -> SimpleNamespace:
    return SimpleNamespace(local_mem_size=local, max_work_group_size=max_wg,
                           max_work_item_sizes=[max_wg] * 3, type=kind, name="fake")


def test_the_issue_case_falls_back_to_a_tile_that_fits():
    """256 spp: the block sort takes at most 255; tile 4 needs 360,456 bytes, more than
    Intel's 262,144: the sweep takes tile 2 (245,768 bytes) rather than failing."""
    dev = fake(INTEL_CPU)
    assert tile_local_bytes(4, 2, 256) == 360_456
    assert fit_group(dev, 2, 256, 1) == 0
    assert fit_tile(dev, 2, 256, 4) == 2
    assert tile_local_bytes(2, 2, 256) <= INTEL_CPU < tile_local_bytes(3, 2, 256)
    assert default_sort(SimpleNamespace(devices=[dev]), 2, 256) == "tile"


@pytest.mark.parametrize("local", [OCLGRIND, 48 * 1024, INTEL_CPU, 512 * 1024])
@pytest.mark.parametrize("scales", [2, 4])
def test_fitted_tile_and_group_hold_their_samples(local, scales):
    """What the fits choose fits, and one more would not: at every spp up to 256."""
    dev = fake(local, max_wg=1024)
    for spp in (1, 4, 16, 32, 64, 128, 256):
        t = fit_tile(dev, scales, spp, 8)
        if t:
            assert tile_local_bytes(t, scales, spp) <= local and t * t <= 1024
            assert tile_sort_size(t, scales, spp) <= MAX_TILE_SAMPLES
        if t < 8:
            assert tile_local_bytes(t + 1, scales, spp) > local
        g = fit_group(dev, scales, spp, 16)
        if g:
            assert block_local_bytes(scales, spp, g) <= local
        if g < 16 and spp <= 255:
            assert block_local_bytes(scales, spp, g + 1) > local


def test_default_sort_never_picks_what_does_not_fit():
    for local in (OCLGRIND, INTEL_CPU):
        for kind in (cl.device_type.CPU, cl.device_type.GPU):
            ctx = SimpleNamespace(devices=[fake(local, 1024, kind)])
            for spp in (1, 8, 16, 64, 128, 256, 1024):
                sort = default_sort(ctx, 2, spp)
                dev = ctx.devices[0]
                if sort == "block":
                    assert kind == cl.device_type.CPU and fit_group(dev, 2, spp, 1)
                elif sort == "tile":
                    assert fit_tile(dev, 2, spp, 1024)
                else:
                    assert sort == "pixel" and not fit_tile(dev, 2, spp, 1024)
    # Oclgrind's 32 KiB: one tile of 1 x 1 pixels at 64 spp needs 25 * 64 * 16 + 2048 * 6
    assert default_sort(SimpleNamespace(devices=[fake(OCLGRIND, 1024, cl.device_type.GPU)]),
                        2, 64) == "pixel"


def test_ring_group_fits_the_device():
    assert ring_group(fake(1 << 20, 8192)) == RING_WG
    assert ring_group(fake(1 << 20, 64)) == 64
    assert ring_group(fake(1000, 8192)) == 32  # 62 float4s: the power of two below
    with pytest.raises(ValueError, match="16 bytes of local memory"):
        ring_group(fake(8, 8192))


def sweep_image(device, buf, **knobs):
    """The sweep's own plan (SweepPipeline, nothing around it) on ``buf``: (describe(),
    image)."""
    pipe = SweepPipeline(device.context, buf.inspect(), **knobs)
    s = DeviceSamples.upload(device.queue, buf, pipe.fields)
    out = cl.Buffer(device.context, cl.mem_flags.READ_WRITE, buf.width * buf.height * 12)
    pipe(device.queue, s, out).wait()
    img = np.empty((buf.height, buf.width, 3), np.float32)
    cl.enqueue_copy(device.queue, img, out)
    return pipe.describe(), img


def _spp_where(device, want):
    """The smallest spp <= 256 at which ``want(spp)`` holds for this device, else None."""
    return next((s for s in (2, 4, 8, 16, 32, 64, 128, 256) if want(s)), None)


def test_sweep_falls_back_to_a_smaller_tile(device, rng):
    """At an spp where the block sort and the default tile do not fit this device's local
    memory but a smaller tile does, the default plan takes that tile and its image is the
    reference's."""
    dev = device.device
    spp = _spp_where(device, lambda s: default_sort(device.context, 2, s) == "tile"
                     and 0 < fit_tile(dev, 2, s, 4) < 4)
    if spp is None:
        pytest.skip(f"{dev.local_mem_size} bytes of local memory hold tile 4 (or the block "
                    f"sort) at every spp up to 256")
    buf = frame(rng, h=5, w=6, s=spp)
    how, img = sweep_image(device, buf, scales=2, specialize=False)
    assert how["sort"] == "tile" and how["tile"] == fit_tile(dev, 2, spp, 4)
    assert_close(img, ref.reconstruct(buf, scales=2), rtol=2e-4, atol=2e-5,
                 what=f"tile {how['tile']} at {spp} spp")


def test_sweep_falls_back_to_the_pixel_sort(device, rng):
    """Where no tile fits at all, the default plan is the pixel sort (no local memory)."""
    dev = device.device
    spp = _spp_where(device, lambda s: default_sort(device.context, 2, s) != "block"
                     and fit_tile(dev, 2, s, dev.max_work_group_size) == 0)
    if spp is None:
        pytest.skip(f"{dev.local_mem_size} bytes of local memory hold a tile at every spp "
                    f"up to 256")
    buf = frame(rng, h=3, w=4, s=spp)
    how, img = sweep_image(device, buf, scales=2, specialize=False)
    assert how["sort"] == "pixel"
    assert_close(img, ref.reconstruct(buf, scales=2), rtol=2e-4, atol=2e-5,
                 what=f"pixel at {spp} spp")


def test_explicit_tile_that_does_not_fit_names_need_and_limit(device, rng):
    dev = device.device
    tile = next((t for t in range(1, 256) if tile_local_bytes(t, 2, 16) > dev.local_mem_size
                 and tile_samples_fit(t, 2, 16)), None)
    if tile is None:  # PoCL on skylake-avx512: 2 MiB
        pytest.skip(f"{dev.local_mem_size} bytes of local memory hold every tile whose "
                    "samples fit the kernel's 16-bit indices at 16 spp")
    with pytest.raises(ValueError, match=f"{dev.local_mem_size}"):
        SweepResolve(device.context, 16, 2, sort="tile", tile=tile)
    with pytest.raises(ValueError, match="local memory"):
        SweepPipeline(device.context, frame(rng, h=3, w=3, s=16).inspect(), tile=tile)


def test_serial_merge_limit_is_refused(device):
    """The serial merge's winner tree has 1024 leaves: a tile whose window has more pixels
    is refused before it is built (it would write past the tree)."""
    with pytest.raises(ValueError, match="serial merge takes at most 1024"):
        SweepResolve(device.context, 1, 2, sort="tile", tile=29, tile_merge="serial")


def test_built_kernel_over_local_memory_is_refused(device):
    """The compiler's own count: a sweep_block group whose windows exceed the device's local
    memory builds, and check_kernel_fits refuses it with both numbers; one that fits
    passes."""
    have, one = device.device.local_mem_size, block_local_bytes(2, 16)
    group = have // one + 1
    if group > device.device.max_work_group_size:
        pytest.skip("the device takes fewer work-items than that")
    k = cldev.get_kernel(device.context, "sweep_block", "sweep_block",
                         {"SPP": 16, "GROUP": group})
    need = block_local_bytes(2, 16, group)
    with pytest.raises(ValueError, match=f"needs {need} bytes of local memory; the device "
                                         f"has {have}"):
        check_kernel_fits(k, device.device, "sweep_block", group, f"group {group}")
    if group > 1:
        k = cldev.get_kernel(device.context, "sweep_block", "sweep_block",
                             {"SPP": 16, "GROUP": group - 1})
        check_kernel_fits(k, device.device, "sweep_block", group - 1, f"group {group - 1}")


def test_integrate_ring_launches_with_the_fitted_group(device):
    from clrecon.methods.splat.integrate import SplatIntegrate

    integ = SplatIntegrate(device.context, 12, 10)
    wg = integ.ring_wg
    assert wg == ring_group(device.device) and wg & (wg - 1) == 0
    info = cl.kernel_work_group_info
    assert integ.ring.get_work_group_info(info.LOCAL_MEM_SIZE, device.device) == 16 * wg


def test_block_sort_that_fits_no_group_names_one_block(device, rng):
    """sort="block" asked for where even one 4x4 block's window exceeds local memory: the
    error names what one block needs and the device's limit (not the tuned group's)."""
    have = device.device.local_mem_size
    spp = next((s for s in (2, 4, 8, 16, 32, 64, 128, 255) if block_local_bytes(4, s) > have),
               None)
    if spp is None:
        pytest.skip(f"{have} bytes of local memory hold a block at every spp up to 255")
    with pytest.raises(ValueError, match=f"group: 1 blocks need {block_local_bytes(4, spp)} "
                                         f"bytes of local memory for {spp} spp \\(device has "
                                         f"{have}\\)"):
        SweepPipeline(device.context, frame(rng, h=2, w=3, s=spp).inspect(), scales=4,
                      sort="block")
