"""Pass ``splat_integrate``: convolution-pyramid integration of every layer's Laplacian
image and its ring anchor (``kernels/splat_integrate.cl``)."""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from clrecon.core.device import get_kernel
from clrecon.core.local_size import LocalSize
from clrecon.methods.splat.reference import PYRAMIDS, pyramid_shapes
from clrecon.tune.runtime import check_kernel_fits
from clrecon.tune.tunable import DEFAULT_LOCAL, GPU_LOCAL, Tunable, local_candidates

#: integrate_ring's work-group size where the device takes it (:func:`ring_group`)
RING_WG = 256


def ring_group(device: cl.Device) -> int:
    """integrate_ring's work-group size on ``device``: :data:`RING_WG`, or the largest power
    of two below it (its reduction halves) within the device's max work-group size, its max
    work-item size in x and its local memory (a float4 per work-item)."""
    limit = min(RING_WG, int(device.max_work_group_size), int(device.max_work_item_sizes[0]),
                int(device.local_mem_size) // 16)
    if limit < 1:
        raise ValueError(f"splat_integrate: integrate_ring needs 16 bytes of local memory; the "
                         f"device has {device.local_mem_size} ({device.name.strip()})")
    return 1 << (limit.bit_length() - 1)


class SplatIntegrate:
    """``kernels/splat_integrate.cl``: ``integrate_down``, ``integrate_up``, ``integrate_ring``.

    Allocates the pyramid levels for one padded image shape; layers reuse them in turn.
    """

    name = "splat_integrate"
    TUNABLE = Tunable(name, "splat_integrate", DEFAULT_LOCAL, local_candidates, rtol=1e-4,
                      atol=1e-6, gpu=GPU_LOCAL)

    def __init__(self, context: cl.Context, height: int, width: int, pyramid: str = "f5",
                 local: LocalSize | None = None):
        if pyramid not in PYRAMIDS:
            raise ValueError(f"pyramid: expected one of {sorted(PYRAMIDS)}, got {pyramid!r}")
        self.pyramid = pyramid
        self.local = local or LocalSize(16, 4)
        dev = context.devices[0]
        self.ring_wg = ring_group(dev)
        # the 2D kernels' local size is a launch parameter only: one program for every one
        defines = {"PYR": 5 if pyramid == "f5" else 7, "WG_RING": self.ring_wg}
        self.down = get_kernel(context, "splat_integrate", "integrate_down", defines)
        self.up = get_kernel(context, "splat_integrate", "integrate_up", defines)
        self.ring = get_kernel(context, "splat_integrate", "integrate_ring", defines)
        check_kernel_fits(self.ring, dev, self.name, self.ring_wg,
                          f"integrate_ring with {self.ring_wg} work-items")
        self.kernel = self.up  # the 2D kernels share the local size; the tuner queries one
        pad = len(PYRAMIDS[pyramid][0])
        self.shapes = pyramid_shapes(height, width, pad)
        rw = cl.mem_flags.READ_WRITE
        self.a = [None] + [cl.Buffer(context, rw, h * w * 16) for h, w in self.shapes[1:]]
        self.b = [None] + [cl.Buffer(context, rw, h * w * 16) for h, w in self.shapes[1:]]

    def _launch(self, queue, kernel, w, h, wait_for):
        g, loc = self.local.for_range(w, h)
        return cl.enqueue_nd_range_kernel(queue, kernel, g, loc, wait_for=wait_for)

    def __call__(self, queue, lap: cl.Buffer, layer: int, out: cl.Buffer, ring: cl.Buffer,
                 wait_for=None) -> cl.Event:
        """Integrate layer ``layer`` of ``lap`` into the same layer of ``out`` (the pyramid's
        output ``b0``; the image is ``ring[layer] - b0``) and write ``ring[layer]``.
        ``self.events`` then holds every kernel's event (for per-pass timing)."""
        self.events = []
        h0, w0 = self.shapes[0]
        off = np.int32(layer * h0 * w0)
        src, soff, ev = lap, off, wait_for
        for i in range(1, len(self.shapes)):
            (sh, sw), (dh, dw) = self.shapes[i - 1], self.shapes[i]
            self.down.set_args(src, soff, np.int32(sw), np.int32(sh), self.a[i], np.int32(dw),
                               np.int32(dh))
            ev = [self._launch(queue, self.down, dw, dh, ev)]
            self.events += ev
            src, soff = self.a[i], np.int32(0)
        top = len(self.shapes) - 1
        for i in range(top, -1, -1):
            fh, fw = self.shapes[i]
            coarse, cw, ch = (self.b[i + 1], *self.shapes[i + 1][::-1]) if i < top else \
                (self.a[top], 0, 0)
            fine, foff = (lap, off) if i == 0 else (self.a[i], np.int32(0))
            dst, ooff = (out, off) if i == 0 else (self.b[i], np.int32(0))
            self.up.set_args(coarse, np.int32(cw), np.int32(ch), fine, foff, np.int32(fw),
                             np.int32(fh), dst, ooff)
            ev = [self._launch(queue, self.up, fw, fh, ev)]
            self.events += ev
        self.ring.set_args(out, off, np.int32(w0), np.int32(h0), ring, np.int32(layer))
        last = cl.enqueue_nd_range_kernel(queue, self.ring, (self.ring_wg,), (self.ring_wg,),
                                          wait_for=ev)
        self.events.append(last)
        return last
