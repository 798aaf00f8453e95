"""Pass ``reproject``: samples of a tile and its guard band splatted into each partition."""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from clrecon.core.fixed import enqueue_color_bound
from clrecon.core.local_size import LocalSize
from clrecon.core.pipeline import DeviceSamples
from clrecon.methods.layered.layout import SUBSAMPLE_DEFAULT, Layout, subsample_cap
from clrecon.methods.layered.passes import layered_kernel
from clrecon.tune.tunable import GPU_1D, Tunable, layered_1d_candidates


class Reproject:
    """``kernels/reproject.cl``: ``reproject_buckets`` (every sample's depth bucket, a byte,
    computed once instead of by each of the 4-5 slots that gather it), then one work-group of
    ``local.x`` items per (tile, slot); with one item the slot's grid is owned (plain adds),
    otherwise items scatter with atomics: float atomics (the order of the adds varies run to
    run), or with ``fixed`` int64 fixed-point atomics into a second buffer of the grids'
    layout, converted to the float grids by the same group (bit-identical run to run;
    ``deterministic=True`` of the method)."""

    name = "reproject"
    # one item per (tile, slot) owns its grid on a CPU; a GPU's 64 scatter with atomics
    TUNABLE = Tunable(name, "reproject", {"wg_x": 1, "wg_y": 1}, layered_1d_candidates,
                      rtol=1e-4, atol=1e-4, gpu=GPU_1D)

    def __init__(self, context: cl.Context, layout: Layout, bilinear: bool = False,
                 local: LocalSize | None = None, subsample: int | bool = SUBSAMPLE_DEFAULT,
                 fixed: bool = False, local_acc: bool | None = None):
        self.layout = layout
        wg = local.x if local and local.x else 1
        self.local = LocalSize(wg, 1)
        self.fixed = bool(fixed)
        # the owner (one item) of a slot keeps its channels in local memory, a float4 and a
        # float per grid cell and per lane's spare cell (kernels/reproject.cl: OWN_LOCAL),
        # where the device has room for them (local_acc None; False: in the grids, as the
        # items of a group do)
        need = 20 * (layout.dmax ** 2 + 8)
        have = min(d.local_mem_size for d in context.devices)
        room = need <= have
        if local_acc and not room:
            raise ValueError(f"local_acc: needs {need} bytes of local memory; the device has "
                             f"{have}")
        self.local_acc = wg == 1 and room and local_acc is not False
        defines = dict(SPLAT_BILINEAR=bool(bilinear), SUBSAMPLE=subsample_cap(subsample),
                       FIXED=self.fixed, LOCAL_ACC=self.local_acc)
        self.kernel = layered_kernel(context, "reproject", "reproject", layout, self.local,
                                     **defines)
        self._defines, self._room = defines, 2 * need <= have
        self._joint: dict[int, cl.Kernel] = {}
        self.bucket_kernel = layered_kernel(context, "reproject", "reproject_buckets", layout,
                                            self.local, **defines)
        self._own_buckets: cl.Buffer | None = None
        if self.fixed:
            self.bound_kernel = layered_kernel(context, "reproject", "reproject_color_bound",
                                               layout, self.local, **defines)
        self.events: list[tuple[str, cl.Event]] = []

    @staticmethod
    def buckets_bytes(width: int, height: int, spp: int) -> int:
        """Bytes of the ``buckets`` temporary: one per sample."""
        return width * height * spp

    def __call__(self, queue, samples: DeviceSamples, bucket_coeffs, params: cl.Buffer,
                 grids: cl.Buffer, wait_for=None, fixed: cl.Buffer | None = None,
                 bound: cl.Buffer | None = None, buckets: cl.Buffer | None = None
                 ) -> cl.Event:
        """Enqueue the pass (with ``fixed``: first the colour bound into ``bound``, 16 bytes,
        and ``fixed``, twice the size of ``grids``, as the accumulator); ``buckets``
        (:meth:`buckets_bytes`; without it the pass's own, kept between calls) receives the
        samples' buckets. ``self.events`` then holds every command's ``(name, event)``."""
        if self.fixed and (fixed is None or bound is None):
            raise ValueError("fixed: the pass needs the fixed-point grids and the colour bound "
                             "buffer")
        ntx, nty = self.layout.tiles(samples.width, samples.height)
        need = self.buckets_bytes(samples.width, samples.height, self.layout.spp)
        if buckets is None:
            if self._own_buckets is None or self._own_buckets.size < need:
                self._own_buckets = cl.Buffer(queue.context, cl.mem_flags.READ_WRITE, need)
            buckets = self._own_buckets
        elif buckets.size < need:
            raise ValueError(f"buckets: needs {need} bytes, got {buckets.size}")
        ev, args = self._buckets(queue, samples, bucket_coeffs, buckets, wait_for)
        args += [np.int32(ntx), params, grids]
        deps = [ev]
        if self.fixed:
            n = samples.width * samples.height * samples.spp
            clear, ev = enqueue_color_bound(queue, self.bound_kernel, samples["color"], n,
                                            bound, wait_for)
            self.events += [("clear", clear), ("reproject_color_bound", ev)]
            deps.append(ev)
            args += [fixed, bound]
        self.kernel.set_args(*args)
        n = ntx * nty * self.layout.maxp * self.local.x
        ev = cl.enqueue_nd_range_kernel(queue, self.kernel, (n,), (self.local.x,),
                                        wait_for=deps)
        self.events.append(("reproject", ev))
        return ev

    def _buckets(self, queue, samples: DeviceSamples, bucket_coeffs, buckets: cl.Buffer,
                 wait_for) -> tuple[cl.Event, list]:
        """Enqueue ``reproject_buckets`` (``self.events`` starts with it, named as the pass:
        its time and bytes are the pass's); the event and reproject's leading arguments (the
        fields, strides and frame size)."""
        npix = samples.width * samples.height
        depth, sstride, soffset = samples.strided("depth")
        self.bucket_kernel.set_args(depth, np.int32(sstride), np.int32(soffset), np.int32(npix),
                                    *(np.float32(v) for v in bucket_coeffs), buckets)
        ev = cl.enqueue_nd_range_kernel(queue, self.bucket_kernel, (npix,), None,
                                        wait_for=wait_for)
        self.events = [("reproject", ev)]
        time = samples.strided("time")[0] if "time" in samples.buffers else depth
        return ev, [samples.strided("color")[0], samples.strided("position")[0], buckets,
                    samples.strided("lens")[0], time, np.int32(sstride), np.int32(soffset),
                    np.int32(samples.width), np.int32(samples.height)]

    def joint_halves(self, queue, samples: DeviceSamples, ha: int, bucket_coeffs,
                     params: cl.Buffer, grids_a: cl.Buffer, grids_b: cl.Buffer,
                     buckets: cl.Buffer, wait_for=None) -> cl.Event:
        """Both of the safeguard's halves of a whole frame in one pass: samples ``0..ha-1`` of
        every pixel into ``grids_a``, the rest into ``grids_b`` (each the grids of the same
        layout), sums equal bit for bit to the pass run on each half's view. The frame's
        samples are read once instead of twice (a half's view loads its pixels' cache lines
        of both halves). Not for ``fixed`` (one fixed-point accumulator)."""
        if self.fixed:
            raise ValueError("joint_halves: the fixed-point accumulation is for one grid")
        if not 1 <= ha < self.layout.spp or samples.spp != self.layout.spp:
            raise ValueError(f"joint_halves: {ha} samples for half A of a frame of "
                             f"{samples.spp} (the pass is built for {self.layout.spp})")
        kernel = self._joint.get(ha)
        if kernel is None:
            defines = dict(self._defines, JOINT_HA=ha,
                           LOCAL_ACC=self.local_acc and self._room)
            kernel = self._joint[ha] = layered_kernel(queue.context, "reproject", "reproject",
                                                      self.layout, self.local, **defines)
        ntx, nty = self.layout.tiles(samples.width, samples.height)
        ev, args = self._buckets(queue, samples, bucket_coeffs, buckets, wait_for)
        kernel.set_args(*args, np.int32(ntx), params, grids_a, grids_b)
        n = ntx * nty * self.layout.maxp * self.local.x
        ev = cl.enqueue_nd_range_kernel(queue, kernel, (n,), (self.local.x,), wait_for=[ev])
        self.events.append(("reproject", ev))
        return ev
