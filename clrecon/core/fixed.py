"""The host side of ``kernels/common.h``'s fixed-point accumulation (``deterministic=True``):
the per-frame colour bound its scale comes from, shared by every scatter pass."""
from __future__ import annotations

import numpy as np
import pyopencl as cl

#: the colour bound: max |r|, |g|, |b| as uint bits (and one word of padding)
BOUND_BYTES = 16
#: work-items of the colour-bound reduction (a multiple of 3: one channel per item); few
#: enough that its 3072 atomic maxima cost nothing, enough to spread the reads
BOUND_ITEMS = 3 * 1024


def enqueue_color_bound(queue, kernel: cl.Kernel, color: cl.Buffer, n: int, bound: cl.Buffer,
                        wait_for=None) -> tuple[cl.Event, cl.Event]:
    """Clear ``bound`` and reduce the ``n`` samples' colours into it with ``kernel`` (a pass's
    build of ``fixed_color_bound``); returns (clear, reduction) events."""
    clear = cl.enqueue_fill_buffer(queue, bound, np.uint32(0), 0, BOUND_BYTES,
                                   wait_for=wait_for)
    kernel.set_args(color, np.int32(n), bound)
    ev = cl.enqueue_nd_range_kernel(queue, kernel, (BOUND_ITEMS,), None, wait_for=[clear])
    return clear, ev
