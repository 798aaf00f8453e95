"""A pass's launch configuration (:class:`LocalSize`): what the tuner searches and every pass
launches with."""
from __future__ import annotations

from dataclasses import dataclass

import pyopencl as cl

from clrecon.core.knobs import INT32_MAX, check_int


@dataclass(frozen=True)
class LocalSize:
    """A pass's launch configuration: local size, or ``None`` for "runtime chooses".

    ``x`` and ``y`` are positive integers (``bool`` and ``float`` refused; NumPy integers
    are stored as ``int``), ``x`` may be ``None`` (then ``y`` is unused). Values beyond a
    device's limits are refused by :meth:`check` when a pass is built for that device.
    """

    x: int | None = 16
    y: int = 4

    def __post_init__(self):
        if self.x is not None:
            object.__setattr__(self, "x", check_int("LocalSize.x", self.x, 1, INT32_MAX))
        object.__setattr__(self, "y", check_int("LocalSize.y", self.y, 1, INT32_MAX))

    def check(self, device: cl.Device, pass_name: str, kernel: cl.Kernel | None = None
              ) -> None:
        """Refuse, with a ``ValueError`` naming the pass, the size and the limit, a local size
        the device cannot launch: beyond its max work-item sizes, its max work-group size
        or (given the built ``kernel``) the kernel's own work-group limit."""
        if self.x is None:
            return
        x, y = self.x, self.y
        dev = device.name.strip()
        items = tuple(device.max_work_item_sizes)
        for axis, v, lim in (("x", x, items[0]), ("y", y, items[1] if len(items) > 1 else 1)):
            if v > lim:
                raise ValueError(f"{pass_name}: local size {x}x{y}: {axis} = {v} exceeds the "
                                 f"device's max work-item size {lim} in {axis} ({dev}; "
                                 f"max work-item sizes {list(items)})")
        limit, what = device.max_work_group_size, "the device's max work-group size"
        if kernel is not None:
            limit = min(limit, kernel.get_work_group_info(
                cl.kernel_work_group_info.WORK_GROUP_SIZE, device))
            what = "the max work-group size of the built kernel"
        if x * y > limit:
            raise ValueError(f"{pass_name}: local size {x}x{y} = {x * y} work-items exceeds "
                             f"{what}, {limit} ({dev})")

    def for_range(self, width: int, height: int) -> tuple[tuple[int, int], tuple | None]:
        """(global, local) for a 2D range covering ``width x height``."""
        if self.x is None:
            return (width, height), None
        gx = -(-width // self.x) * self.x
        gy = -(-height // self.y) * self.y
        return (gx, gy), (self.x, self.y)
