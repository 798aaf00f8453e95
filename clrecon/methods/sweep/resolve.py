"""Pass ``sweep_resolve``: the front-to-back sweep over each pixel's window."""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from clrecon.core.device import get_kernel
from clrecon.core.local_size import LocalSize
from clrecon.tune.runtime import check_kernel_fits
from clrecon.tune.tunable import Tunable

SORTS = ("tile", "pixel")
TILE_MERGES = ("auto", "serial", "bitonic")
#: the tile kernel indexes its samples with 16 bits (``ushort lidx``)
MAX_TILE_SAMPLES = 1 << 16
#: the serial merge's winner tree has at most this many leaves (``LEAVES``): one per pixel
#: of the tile's window
MAX_MERGE_RUNS = 1024


def tile_sort_size(tile: int, scales: int, spp: int) -> int:
    """Entries the tile kernel sorts: the next power of two of (tile + 2R)^2 * spp."""
    r = 2 if scales == 2 else 3
    n = (tile + 2 * r) ** 2 * spp
    return 1 << (n - 1).bit_length()


def tile_local_bytes(tile: int, scales: int, spp: int) -> int:
    """Local memory of the tile kernel: a float4 key per window sample, a float depth and
    a ushort index per sort entry, and two ints (the window's smallest and largest box
    radius, for the one-box shortcut)."""
    r = 2 if scales == 2 else 3
    return (tile + 2 * r) ** 2 * spp * 16 + tile_sort_size(tile, scales, spp) * 6 + 8


def tile_samples_fit(tile: int, scales: int, spp: int) -> bool:
    """Whether the tile's sort entries fit the kernel's 16-bit sample indices."""
    return tile_sort_size(tile, scales, spp) <= MAX_TILE_SAMPLES


def resolve_candidates() -> list[dict]:
    """sweep_resolve's tuning space: the tile sort's tile sides and merges, and the pixel
    sort's local sizes."""
    tiles = [{"sort": "tile", "tile": t, "tile_merge": m} for t in (2, 4, 8)
             for m in ("serial", "bitonic")]
    pixels = [{"sort": "pixel", "wg_x": x, "wg_y": y} for x, y in ((8, 8), (16, 4), (32, 2))]
    return tiles + pixels


class SweepResolve:
    """``kernels/sweep_resolve.cl``: ``sort="tile"`` (one local-memory sort per tile, by a
    serial winner-tree merge or a bitonic network: ``tile_merge``, default by device type) or
    ``"pixel"`` (each pixel merges its window's sorted lists); all give the same image."""

    name = "sweep_resolve"
    # float sums in a different order per configuration: relative tolerance
    # "auto": the serial merge on CPUs, the bitonic network on GPUs; the sweep fits the
    # tile to the device's local memory (an 8x8 tile holds 12x12 pixels' samples)
    TUNABLE = Tunable(name, "sweep_resolve", {"sort": "tile", "tile": 4, "tile_merge": "auto"},
                      resolve_candidates, rtol=1e-4, atol=1e-5,
                      gpu={"sort": "tile", "tile": 8, "tile_merge": "auto"})

    def __init__(self, context: cl.Context, spp: int, scales: int = 2, exponent: float = 1.0,
                 sort: str = "tile", tile: int = 4, tile_merge: str = "auto",
                 local: LocalSize | None = None, uniform_box: bool = True):
        """``uniform_box=False`` sweeps every window, also those whose every sample weighs
        in one box alone (whose image is that box's mean, unsorted by default)."""
        if scales not in (2, 4):
            raise ValueError(f"scales: must be 2 or 4, got {scales}")
        if sort not in SORTS:
            raise ValueError(f"sort: must be one of {SORTS}, got {sort!r}")
        if not exponent > 0:
            raise ValueError(f"exponent: must be positive, got {exponent}")
        self.sort, self.tile, self.tile_merge = sort, int(tile), None
        defines = {"SPP": spp, "SCALES": scales, "EXPONENT": float(exponent),
                   "EXPONENT_ON": exponent != 1.0, "UNIFORM_BOX": bool(uniform_box)}
        if sort == "tile":
            dev = context.devices[0]
            need = tile_local_bytes(self.tile, scales, spp)
            too_big = self.tile ** 2 > dev.max_work_group_size
            if self.tile < 1 or need > dev.local_mem_size or too_big:
                raise ValueError(
                    f"tile: {self.tile} needs {need} bytes of local memory for {spp} spp "
                    f"(device has {dev.local_mem_size}); use a smaller tile or sort='pixel'")
            if not tile_samples_fit(self.tile, scales, spp):
                raise ValueError(
                    f"tile: {self.tile} sorts {tile_sort_size(self.tile, scales, spp)} entries "
                    f"at {spp} spp; the tile kernel indexes at most {MAX_TILE_SAMPLES}: use a "
                    f"smaller tile or sort='pixel'")
            if tile_merge not in TILE_MERGES:
                raise ValueError(f"tile_merge: must be one of {TILE_MERGES}, got {tile_merge!r}")
            if tile_merge == "auto":  # serial merge where a group runs on one core anyway
                tile_merge = "serial" if dev.type & cl.device_type.CPU else "bitonic"
            runs = (self.tile + 2 * (2 if scales == 2 else 3)) ** 2
            if tile_merge == "serial" and runs > MAX_MERGE_RUNS:
                raise ValueError(
                    f"tile: {self.tile} has a window of {runs} pixels; the serial merge takes "
                    f"at most {MAX_MERGE_RUNS}: use a smaller tile or tile_merge='bitonic'")
            self.tile_merge = tile_merge
            defines.update(TILE=self.tile, SORT_N=tile_sort_size(self.tile, scales, spp),
                           TILE_MERGE=tile_merge == "serial")
            self.local = LocalSize(self.tile, self.tile)
            self.kernel = get_kernel(context, "sweep_resolve", "sweep_resolve_tile", defines)
            check_kernel_fits(self.kernel, dev, self.name, self.tile ** 2,
                              f"tile {self.tile} ({tile_merge} merge) at {spp} spp")
        else:
            self.local = local or LocalSize(16, 4)
            self.kernel = get_kernel(context, "sweep_resolve", "sweep_resolve_pixel", defines)

    def __call__(self, queue, keys: cl.Buffer, colors: cl.Buffer, width: int, height: int,
                 out: cl.Buffer, wait_for=None) -> cl.Event:
        self.kernel.set_args(keys, colors, np.int32(width), np.int32(height), out)
        g, loc = self.local.for_range(width, height)
        return cl.enqueue_nd_range_kernel(queue, self.kernel, g, loc, wait_for=wait_for)


def make_resolve(context: cl.Context, spp: int, scales: int, exponent: float,
                 config: dict) -> SweepResolve:
    """A :class:`SweepResolve` for a tuning configuration (``{"sort": "tile", "tile",
    "tile_merge"}`` or ``{"sort": "pixel", "wg_x", "wg_y"}``)."""
    sort = config.get("sort")
    if sort not in SORTS:
        raise ValueError(f"sort: must be one of {SORTS}, got {sort!r}")
    if sort == "tile":
        return SweepResolve(context, spp, scales, exponent, "tile", config["tile"],
                            config["tile_merge"])
    return SweepResolve(context, spp, scales, exponent, "pixel",
                        local=LocalSize(int(config["wg_x"]), int(config["wg_y"])))
