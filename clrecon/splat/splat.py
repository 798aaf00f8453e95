"""Pass ``splat``: every sample adds its PSF's spreadlets (or, on the fast track, its dense
PSF) into the images of its depth layer (``kernels/splat.cl``).

Two scatter strategies (``scatter``): ``"atomic"``, one work-item per sample with float atomic
adds (any device); ``"tiles"``, one work-item per screen tile in ``phases x phases`` launches
so that no two work-items of a launch write the same pixel, with plain adds (CPUs: a CAS float
atomic costs ~10 plain adds there; the result is also bit-reproducible).
"""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from ..device import get_kernel
from ..pipeline import DeviceSamples
from .tables import DeviceTable

SCATTERS = ("atomic", "tiles")
MIN_TILE = 16


class Splat:
    """``kernels/splat.cl``: ``splat_samples`` (atomic) or ``splat_tiles`` (owner tiles)."""

    name = "splat"

    def __init__(self, context: cl.Context, spp: int, ndim: int, has_motion: bool, nlayers: int,
                 wg: int | None = 64, scatter: str = "atomic", phases: int = 4):
        if scatter not in SCATTERS:
            raise ValueError(f"scatter: expected one of {SCATTERS}, got {scatter!r}")
        if int(phases) < 2:
            raise ValueError(f"phases: must be >= 2, got {phases}")
        self.wg, self.scatter, self.phases = wg, scatter, int(phases)
        name = "splat_samples" if scatter == "atomic" else "splat_tiles"
        self.kernel = get_kernel(context, "splat", name,
                                 {"SPP": spp, "NDIM": ndim, "HAS_MOTION": int(has_motion),
                                  "NLAYERS": nlayers})
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
                 wait_for=None, shift: float = 0.0) -> cl.Event:
        """Enqueue the pass; ``shift`` bounds how far a re-centred centre lies from its
        sample's pixel (``"tiles"`` only). ``self.events`` then holds every launch's event."""
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
        for py in range(k):
            for px in range(k):
                gx, gy = -(-(nx - px) // k), -(-(ny - py) // k)
                if gx <= 0 or gy <= 0:
                    continue
                self.kernel.set_args(*args, np.int32(w), np.int32(h), np.int32(tile),
                                     np.int32(k), np.int32(px), np.int32(py))
                # tiles of one phase never write the same pixel: any local size is safe
                ev = cl.enqueue_nd_range_kernel(queue, self.kernel, (gx, gy), None,
                                                wait_for=evs)
                self.events.append(ev)
                evs = [ev]
        return self.events[-1]
