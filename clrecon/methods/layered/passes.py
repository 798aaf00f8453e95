"""What the host classes of the layered passes share: building a kernel with the method's
compile-time layout plus a pass's own defines and local size."""
from __future__ import annotations

import pyopencl as cl

from clrecon.core.device import get_kernel
from clrecon.core.local_size import LocalSize
from clrecon.methods.layered.layout import Layout


def layered_kernel(context: cl.Context, file: str, kernel: str, layout: Layout,
                   local: LocalSize | None, **extra) -> cl.Kernel:
    defines = layout.defines() | extra
    if local is not None and local.x is not None:
        defines |= {"WG_X": local.x, "WG_Y": local.y}
    return get_kernel(context, file, kernel, defines)


def local_for(local: LocalSize | None, size: tuple) -> tuple:
    """(global, local) for a 1D/2D/3D range, rounded up to the local size (x, y, 1)."""
    if local is None or local.x is None:
        return tuple(size), None
    loc = (local.x, local.y, 1)[:len(size)]
    if len(size) == 1:
        loc = (local.x,)
    g = tuple(-(-n // m) * m for n, m in zip(size, loc))
    return g, loc
