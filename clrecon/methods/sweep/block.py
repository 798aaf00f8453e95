"""Pass ``sweep_block``: the whole sorted sweep for 4x4 pixel blocks in one kernel."""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from clrecon.core.device import get_kernel
from clrecon.core.pipeline import DeviceSamples
from clrecon.methods.sweep.reference import DEPTH_KEY_SHIFT
from clrecon.tune.runtime import check_kernel_fits
from clrecon.tune.tunable import Tunable

BLOCK = 4  # block side: the 16 pixels of a lane set (float16 lanes)
SUPERS = (2, 1)  # blocks per side of a work-item, the first that fits local memory wins


def block_local_bytes(scales: int, spp: int, group: int = 1, supers: int = 1) -> int:
    """Local memory of a work-group (``kernels/sweep_block.cl``): per work-item, for each
    sample of its window (``supers`` x ``supers`` blocks and their margin), two 8-byte sort
    slots and a 16-byte record; with ``supers > 1`` the sort slots also hold each block's
    list of window samples (``(4 + 2R)^2 spp + 1`` 4-byte entries per block)."""
    r = 2 if scales == 2 else 3
    window = (BLOCK * supers + 2 * r) ** 2 * spp
    slots = window
    if supers > 1:
        slots = max(slots, -(-supers * supers * ((BLOCK + 2 * r) ** 2 * spp + 1) // 2))
    return group * (2 * 8 * slots + 16 * window)


def fit_supers(dev: cl.Device, scales: int, spp: int, group: int) -> int:
    """The most blocks per side (2 or 1) a work-item of a ``group`` takes within the
    device's local memory; 1 when even that does not fit (the caller names the limit)."""
    return next((s for s in SUPERS
                 if block_local_bytes(scales, spp, group, s) <= dev.local_mem_size), 1)


class SweepBlock:
    """``kernels/sweep_block.cl``: each work-item radix-sorts the samples of the window of
    2x2 blocks of 4x4 pixels (one block where local memory allows no more) once, and sweeps
    them for each block's 16 pixels in float16 lanes (same image as ``sweep_prepare`` +
    ``sweep_resolve``, from the sample buffer directly).

    Parameters
    ----------
    context : cl.Context
    spp : int
        Samples per pixel (at most 255).
    scales : int
        2 (Appendix A) or 4 (Appendix B).
    exponent : float
        Weights are raised to it (the paper's 1.3 variant; 1 = off).
    smooth_motion : bool
        Whether the denoising diameter includes the motion length.
    group : int
        Work-items (independent) per work-group: a tunable.
    supers : int or None
        Blocks per side of a work-item, 1 or 2 (None: the most that fit local memory).
    """

    name = "sweep_block"
    # the whole sorted sweep per 4x4 block (sort="block"): work-items per group; the sweep
    # fits the group to the device's local memory
    TUNABLE = Tunable(name, "sweep_block", {"group": 1},
                      lambda: [{"group": g} for g in (1, 2, 4, 8, 16)],
                      rtol=1e-4, atol=1e-5, gpu={"group": 64})

    def __init__(self, context: cl.Context, spp: int, scales: int = 2, exponent: float = 1.0,
                 smooth_motion: bool = True, group: int = 1, supers: int | None = None,
                 depth_key_shift: int = DEPTH_KEY_SHIFT, uniform_box: bool = True):
        """``depth_key_shift``: low mantissa bits of a depth the front-to-back order
        ignores (``kernels/sweep_order.h``; 0: the exact order). ``uniform_box=False``
        sorts and sweeps every window, also those whose every sample weighs in one box
        alone (whose image is that box's mean, computed without the sort by default: the
        tests compare the two)."""
        if scales not in (2, 4):
            raise ValueError(f"scales: must be 2 or 4, got {scales}")
        if not exponent > 0:
            raise ValueError(f"exponent: must be positive, got {exponent}")
        if not 1 <= spp <= 255:
            raise ValueError(f"spp: the block sort takes 1 to 255 samples per pixel, got {spp}")
        self.group = int(group)
        dev = context.devices[0]
        need = block_local_bytes(scales, spp, self.group)
        if self.group < 1 or need > dev.local_mem_size:
            raise ValueError(
                f"group: {self.group} blocks need {need} bytes of local memory for {spp} spp "
                f"(device has {dev.local_mem_size}); use a smaller group or sort='pixel'")
        if supers is None:
            supers = fit_supers(dev, scales, spp, self.group)
        elif supers not in SUPERS:
            raise ValueError(f"supers: must be one of {SUPERS} or None, got {supers!r}")
        elif block_local_bytes(scales, spp, self.group, supers) > dev.local_mem_size:
            raise ValueError(
                f"supers: {supers} needs {block_local_bytes(scales, spp, self.group, supers)} "
                f"bytes of local memory for group {self.group} at {spp} spp (device has "
                f"{dev.local_mem_size})")
        self.supers = int(supers)
        #: the kernel's compile-time defines (``tools/sweep_block_phases.py`` builds variants
        #: of its source with them)
        self.defines = {
            "SPP": spp, "SCALES": scales, "SMOOTH_MOTION": smooth_motion,
            "EXPONENT": float(exponent), "EXPONENT_ON": exponent != 1.0, "GROUP": self.group,
            "SUPER": self.supers, "DEPTH_KEY_SHIFT": int(depth_key_shift),
            "UNIFORM_BOX": bool(uniform_box)}
        self.kernel = get_kernel(context, "sweep_block", "sweep_block", self.defines)
        check_kernel_fits(self.kernel, dev, self.name, self.group,
                          f"group {self.group} at {spp} spp")

    def __call__(self, queue, samples: DeviceSamples, diameter_scale: float, out: cl.Buffer,
                 wait_for=None) -> cl.Event:
        w, h = samples.width, samples.height
        c0, c1 = samples.coc
        color, stride, offset = samples.strided("color")
        self.kernel.set_args(color, samples.strided("depth")[0], samples.strided("motion")[0],
                             np.int32(stride), np.int32(offset), np.int32(w), np.int32(h),
                             np.float32(c0), np.float32(c1), np.float32(diameter_scale), out)
        side = BLOCK * self.supers
        items = -(-w // side) * -(-h // side)
        size = -(-items // self.group) * self.group
        return cl.enqueue_nd_range_kernel(queue, self.kernel, (size,), (self.group,),
                                          wait_for=wait_for)
