"""Pass ``filter_sheared``: recursive filter along one grid axis and Gaussian along the sheared
axis (eq. 9-10)."""
from __future__ import annotations

import pyopencl as cl

from clrecon.core.device import cpu_context
from clrecon.core.local_size import LocalSize
from clrecon.methods.layered.layout import NCH, Layout
from clrecon.methods.layered.passes import layered_kernel, local_for
from clrecon.tune.tunable import Tunable, local_candidates


def recursive_lines(context: cl.Context) -> int:
    """Grid lines a work-item of ``filter_sheared_recursive``: 8 on a CPU, 1 elsewhere.

    Each line's recursion is a serial chain, and PoCL 3.1 does not vectorise across
    work-items a kernel that holds vector values, so on a CPU a work-item runs 8 lines as the
    lanes of a ``float8`` (deep 1280x720 8 spp: 37 -> 20 ms for the halves' filter on PoCL,
    86 -> 33 ms on Intel's runtime). The vector kernel runs with a local size of 1 x 1: with
    a NULL local size PoCL 3.1 picked 8 x 128 at 256x256 and crashed in the pipeline (a
    10 KB private array a work-item; the same launch alone in a test ran), and 1 x 1 is as
    fast. 16 lines are no faster and are not offered."""
    return 8 if cpu_context(context) else 1


def gauss_width(context: cl.Context) -> int:
    """Outputs a work-item of ``filter_sheared_gauss``: 8 on a CPU, 4 elsewhere.

    A tap's per-lane work is two loads and two multiply-adds a channel; its weight, shear and
    bounds are shared by the work-item's lanes, so wider work-items spread them thinner (deep
    1280x720 8 spp, the halves' Gaussian 45-49 -> 30-34 ms on PoCL with 8; 16 lanes: 74-80 ms,
    more of the taps at a grid's edge go lane by lane)."""
    return 8 if cpu_context(context) else 4


#: bytes of the private array a work-item of the vector kernel holds (FR_CH channels of
#: DMAX x lines floats) at most: the size measured to run on PoCL 3.1 (the default layout,
#: 8 lines, all channels); wider guard bands filter fewer channels at a time
PRIVATE_BYTES = 10240


def recursive_channels(dmax: int, lines: int) -> int:
    """Channels the vector kernel filters at a time: the largest divisor of NCH whose lines
    fit :data:`PRIVATE_BYTES` (one where none does)."""
    fit = PRIVATE_BYTES // (4 * dmax * lines)
    return max([c for c in range(1, NCH + 1) if NCH % c == 0 and c <= fit], default=1)


class FilterSheared:
    """``kernels/filter_sheared.cl``: ``filter_sheared_recursive`` (in place on the grids) then
    ``filter_sheared_gauss`` (into ``filtered``). Returns the last event; ``events`` has both."""

    name = "filter_sheared"
    TUNABLE = Tunable(name, "filter_sheared", {"wg_x": 8, "wg_y": 8}, local_candidates,
                      rtol=1e-4, atol=1e-5)

    def __init__(self, context: cl.Context, layout: Layout, recursions: int = 3,
                 local: LocalSize | None = None, lines: int | None = None,
                 width: int | None = None):
        """``lines``: grid lines a work-item of the recursive filter (1, 4 or 8; default 8 on
        a CPU, 1 elsewhere); ``width``: outputs a work-item of the Gaussian (4, 8 or 16;
        default :func:`gauss_width`)."""
        self.layout = layout
        self.local = local or LocalSize(8, 8)
        self.lines = recursive_lines(context) if lines is None else int(lines)
        if self.lines not in (1, 4, 8):
            raise ValueError(f"filter_sheared: {lines} lines a work-item is not 1, 4 or 8")
        self.width = gauss_width(context) if width is None else int(width)
        if self.width not in (4, 8, 16):
            raise ValueError(f"filter_sheared: {width} outputs a work-item is not 4, 8 or 16")
        r = {"RECURSIONS": int(recursions)}
        # the local size is a launch parameter only: every configuration shares one program
        self.recursive = layered_kernel(context, "filter_sheared", "filter_sheared_recursive",
                                        layout, None, FR_VW=self.lines,
                                        FR_CH=recursive_channels(layout.dmax, self.lines), **r)
        self.gauss = layered_kernel(context, "filter_sheared", "filter_sheared_gauss", layout, None,
                                    GS_VW=self.width, **r)
        self.kernel = self.gauss  # the one the local size tunes
        self.events: list = []

    def __call__(self, queue, params: cl.Buffer, grids: cl.Buffer, filtered: cl.Buffer,
                 nslots: int, wait_for=None) -> cl.Event:
        self.recursive.set_args(params, grids)
        er = cl.enqueue_nd_range_kernel(queue, self.recursive,
                                        (-(-self.layout.dmax // self.lines), nslots),
                                        None if self.lines == 1 else (1, 1),
                                        wait_for=wait_for)
        self.gauss.set_args(params, grids, filtered)
        side = self.layout.filtered_side
        g, loc = local_for(self.local, (-(-side // self.width), side, nslots))
        eg = cl.enqueue_nd_range_kernel(queue, self.gauss, g, loc, wait_for=[er])
        self.events = [("filter_sheared_recursive", er), ("filter_sheared_gauss", eg)]
        return eg
