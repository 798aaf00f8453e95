"""Pass ``splat``: every sample adds its PSF's spreadlets (or, on the fast track, its dense
PSF) into the images of its depth layer (``kernels/splat.cl``).

Two scatter strategies (``scatter``): ``"atomic"``, one work-item per sample with float atomic
adds (any device); ``"tiles"``, one work-item per screen tile in ``phases x phases`` launches
so that no two work-items of a launch write the same pixel, with plain adds (CPUs: a CAS float
atomic costs ~10 plain adds there; the result is also bit-reproducible).

``fixed=True`` (``deterministic=True`` of the method, atomic scatter only): the atomic adds go
into int64 images in scaled fixed point (``kernels/common.h``), so that the sums are
bit-identical run to run: :meth:`Splat.color_bound` first reduces the frame's largest
|colour| per channel (the scale), the pass accumulates, and :meth:`Splat.to_float` writes
the float images the integration reads.
"""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from clrecon.core.device import get_kernel
from clrecon.core.fixed import enqueue_color_bound
from clrecon.core.pipeline import DeviceSamples
from clrecon.methods.splat.tables import DeviceTable
from clrecon.tune.tunable import Tunable, splat_candidates

SCATTERS = ("atomic", "tiles")
MIN_TILE = 16


def owner_phases(nx: int, ny: int, k: int):
    """The ``k x k`` phases of an ``nx x ny`` grid of owner tiles: ``(px, py, gx, gy)``, the
    phase and how many of its tiles lie along x and y (tiles ``k i + px``, ``k j + py``);
    phases without a tile are left out."""
    for py in range(k):
        for px in range(k):
            gx, gy = -(-(nx - px) // k), -(-(ny - py) // k)
            if gx > 0 and gy > 0:
                yield px, py, gx, gy


class Splat:
    """``kernels/splat.cl``: ``splat_samples`` (atomic) or ``splat_tiles`` (owner tiles)."""

    name = "splat"
    # float atomics add in a different order per configuration: relative tolerance
    TUNABLE = Tunable(name, "splat", {"wg": 64}, splat_candidates, rtol=1e-3, atol=1e-6)

    def __init__(self, context: cl.Context, spp: int, ndim: int, has_motion: bool, nlayers: int,
                 wg: int | None = 64, scatter: str = "atomic", phases: int = 4,
                 fixed: bool = False):
        if scatter not in SCATTERS:
            raise ValueError(f"scatter: expected one of {SCATTERS}, got {scatter!r}")
        if int(phases) < 2:
            raise ValueError(f"phases: must be >= 2, got {phases}")
        if fixed and scatter != "atomic":
            raise ValueError("fixed: the fixed-point images are for scatter='atomic' (the "
                             f"owner tiles add in a fixed order already), got {scatter!r}")
        self.wg, self.scatter, self.phases = wg, scatter, int(phases)
        self.fixed = bool(fixed)
        name = "splat_samples" if scatter == "atomic" else "splat_tiles"
        defines = {"SPP": spp, "NDIM": ndim, "HAS_MOTION": int(has_motion),
                   "NLAYERS": nlayers, "FIXED": int(self.fixed)}
        self.kernel = get_kernel(context, "splat", name, defines)
        if self.fixed:
            self.bound_kernel = get_kernel(context, "splat", "splat_color_bound", defines)
            self.to_float_kernel = get_kernel(context, "splat", "splat_fixed_to_float",
                                              defines)
        self.events: list[cl.Event] = []

    @staticmethod
    def tile_size(reach: int, shift: float, k: int) -> int:
        """Smallest owner tile for ``k x k`` phases: a sample writes within
        ``R = reach + shift + 1`` px of its pixel, and tiles of one phase, ``k - 1`` tiles
        apart, must not both reach a pixel: ``(k - 1) * tile > 2 R - 1``."""
        # a shift beyond 2**30 px (validated frames stay below 2**17) only asks for one
        # tile over the frame: clamped before int() so that no count overflows int32
        r = int(reach) + int(np.ceil(min(float(shift), 2.0**30))) + 1
        # any larger tile is as safe; below 16 px the launch overhead per tile dominates
        return max((2 * r - 1) // (k - 1) + 1, MIN_TILE)

    def __call__(self, queue, samples: DeviceSamples, table: DeviceTable, inv_far: float,
                 layer_scale: float, pad: int, reach: int, lap: cl.Buffer, direct: cl.Buffer,
                 wait_for=None, shift: float = 0.0, bound: cl.Buffer | None = None,
                 klog2: int = 0) -> cl.Event:
        """Enqueue the pass; ``shift`` bounds how far a re-centred centre lies from its
        sample's pixel (``"tiles"`` only). ``self.events`` then holds every launch's event.
        With ``fixed``, ``lap`` and ``direct`` are the int64 images, ``bound`` what
        :meth:`color_bound` wrote and ``2**klog2`` the bound on the sum of
        ``|weight * value|`` a pixel receives per unit of colour."""
        w, h = samples.width, samples.height
        n = h * w * samples.spp
        c0, c1 = samples.coc
        pw, ph = w + 2 * pad, h + 2 * pad
        args = [samples["color"], samples["position"], samples["depth"], samples["lens"],
                samples["time"], samples["motion"], np.int32(n), np.float32(c0),
                np.float32(c1), np.float32(inv_far), np.float32(layer_scale), np.int32(pad),
                np.int32(pw), np.int32(ph), np.int32(reach), table.pts, table.vals,
                table.offs, table.dpts, table.dvals, table.doffs, table.fast, table.gn,
                table.gsmax, table.ginvb, table.levels, np.int32(table.nlev), lap, direct]
        if self.fixed:
            if bound is None:
                raise ValueError("fixed: the pass needs the colour bound buffer")
            args += [bound, np.int32(klog2)]
        if self.scatter == "atomic":
            self.kernel.set_args(*args)
            loc = None if self.wg is None else (self.wg,)
            g = n if self.wg is None else -(-n // self.wg) * self.wg
            ev = cl.enqueue_nd_range_kernel(queue, self.kernel, (g,), loc, wait_for=wait_for)
            self.events = [ev]
            return ev
        k = self.phases
        # a tile as large as the frame is one tile (one phase runs): as safe as any larger
        tile = min(self.tile_size(reach, shift, k), max(w, h))
        nx, ny = -(-w // tile), -(-h // tile)
        self.events = []
        evs = wait_for
        for px, py, gx, gy in owner_phases(nx, ny, k):
            self.kernel.set_args(*args, np.int32(w), np.int32(h), np.int32(tile),
                                 np.int32(k), np.int32(px), np.int32(py))
            # tiles of one phase never write the same pixel: any local size is safe
            ev = cl.enqueue_nd_range_kernel(queue, self.kernel, (gx, gy), None, wait_for=evs)
            self.events.append(ev)
            evs = [ev]
        return self.events[-1]

    def color_bound(self, queue, samples: DeviceSamples, bound: cl.Buffer,
                    wait_for=None) -> cl.Event:
        """``fixed``: the largest |colour| of each channel into ``bound`` (16 bytes), the
        scale of the fixed-point images. ``self.events`` then holds the clear and the
        reduction."""
        n = samples.width * samples.height * samples.spp
        clear, ev = enqueue_color_bound(queue, self.bound_kernel, samples["color"], n, bound,
                                        wait_for)
        self.events = [clear, ev]
        return ev

    def to_float(self, queue, src: cl.Buffer, dst: cl.Buffer, npix: int, bound: cl.Buffer,
                 klog2: int, wait_for=None) -> cl.Event:
        """``fixed``: ``npix`` float4 pixels of the int64 image ``src`` as floats into
        ``dst``."""
        self.to_float_kernel.set_args(src, dst, np.int32(npix), bound, np.int32(klog2))
        return cl.enqueue_nd_range_kernel(queue, self.to_float_kernel, (npix,), None,
                                          wait_for=wait_for)
