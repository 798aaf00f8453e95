"""Pass ``reproject``: samples of a tile and its guard band splatted into each partition."""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from ..fixed import enqueue_color_bound
from ..pipeline import DeviceSamples, LocalSize
from .passes import layered_kernel
from .reference import Layout, subsample_cap


class Reproject:
    """``kernels/reproject.cl``: one work-group of ``local.x`` items per (tile, slot); with one
    item the slot's grid is owned (plain adds), otherwise items scatter with atomics: float
    atomics (the order of the adds varies run to run), or with ``fixed`` int64 fixed-point
    atomics into a second buffer of the grids' layout, converted to the float grids by the
    same group (bit-identical run to run; ``deterministic=True`` of the method)."""

    name = "reproject"

    def __init__(self, context: cl.Context, lay: Layout, bilinear: bool = False,
                 local: LocalSize | None = None, subsample: int | bool = True,
                 fixed: bool = False):
        self.lay = lay
        wg = local.x if local and local.x else 1
        self.local = LocalSize(wg, 1)
        self.fixed = bool(fixed)
        defines = dict(SPLAT_BILINEAR=bool(bilinear), SUBSAMPLE=subsample_cap(subsample),
                       FIXED=self.fixed)
        self.kernel = layered_kernel(context, "reproject", "reproject", lay, self.local,
                                     **defines)
        if self.fixed:
            self.bound_kernel = layered_kernel(context, "reproject", "reproject_color_bound",
                                               lay, self.local, **defines)
        self.events: list[tuple[str, cl.Event]] = []

    def __call__(self, queue, samples: DeviceSamples, kabc, params: cl.Buffer,
                 grids: cl.Buffer, wait_for=None, fixed: cl.Buffer | None = None,
                 bound: cl.Buffer | None = None) -> cl.Event:
        """Enqueue the pass (with ``fixed``: first the colour bound into ``bound``, 16 bytes,
        and ``fixed``, twice the size of ``grids``, as the accumulator); ``self.events`` then
        holds every command's ``(name, event)``."""
        ntx, nty = self.lay.tiles(samples.width, samples.height)
        time = samples.buffers.get("time", samples["depth"])
        args = [samples["color"], samples["position"], samples["depth"], samples["lens"], time,
                np.int32(samples.width), np.int32(samples.height), np.int32(ntx),
                *(np.float32(v) for v in kabc), params, grids]
        self.events = []
        if self.fixed:
            if fixed is None or bound is None:
                raise ValueError("fixed: the pass needs the fixed-point grids and the colour "
                                 "bound buffer")
            n = samples.width * samples.height * samples.spp
            clear, ev = enqueue_color_bound(queue, self.bound_kernel, samples["color"], n,
                                            bound, wait_for)
            self.events += [("clear", clear), ("reproject_color_bound", ev)]
            wait_for = [ev]
            args += [fixed, bound]
        self.kernel.set_args(*args)
        n = ntx * nty * self.lay.maxp * self.local.x
        ev = cl.enqueue_nd_range_kernel(queue, self.kernel, (n,), (self.local.x,),
                                        wait_for=wait_for)
        self.events.append(("reproject", ev))
        return ev
