"""The declaration of a tunable pass and the candidate spaces the passes share.

Each pass declares what can be tuned about it beside its class (``Box.TUNABLE``): its
kernel file (whose source hash keys the tuning database), its CPU and GPU defaults, its
candidate configurations and the tolerance its outputs are verified with. A configuration
is a dict of the pass's tunables, or ``None`` for "runtime chooses" (local size left to the
OpenCL runtime).

This module imports nothing of clrecon, so that looking up a tuned configuration
(:mod:`clrecon.tune.runtime`) imports no pass and no tuner; the runners that build and
launch the passes for the tuner live in :mod:`clrecon.tune.runners`.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

#: Every pass that declares a :class:`Tunable`. A fixed list rather than a registry filled
#: as the passes are imported: :func:`clrecon.tune.runtime.override_tuning` checks the
#: names it is given before any method need have been imported, and importing every
#: method from the lookup would put the passes and the lookup in one import cycle. A new
#: pass adds its name here (its declaration refuses to exist otherwise).
PASS_NAMES = frozenset({
    "raytrace", "box",
    "sweep_prepare", "sweep_resolve", "sweep_block", "sweep_layer_sums", "sweep_layer_resolve",
    "tile_stats", "partition_setup", "reproject", "filter_sheared", "filter_rotated",
    "filter_mip", "layered_composite",
    "splat", "splat_integrate", "splat_composite",
})

LOCAL_SIZES = [(1, 1), (4, 4), (8, 8), (16, 4), (16, 8), (32, 4), (32, 8), (64, 1), (16, 16)]

DEFAULT_LOCAL = {"wg_x": 16, "wg_y": 4}
#: the layered passes that run one work-item (or group) per tile
LAYERED_1D = {"wg_x": 8, "wg_y": 1}

# GPU defaults (no tuning entry on a GPU): whole warps/wavefronts (multiples of 32 items,
# 64-256 per group) where the CPU defaults run one to eight items a group; rows of 32
# pixels for the per-pixel passes (coalesced loads), 64 items for one group (or item) per
# tile. The layered filters keep 8x8: their ranges are grids of 34-64 pixels a side, which
# 32-wide rows would pad to 64.
GPU_LOCAL = {"wg_x": 32, "wg_y": 4}
GPU_1D = {"wg_x": 64, "wg_y": 1}


def local_candidates() -> list[dict | None]:
    """The 2D local sizes of :data:`LOCAL_SIZES`, then "runtime chooses"."""
    return [{"wg_x": x, "wg_y": y} for x, y in LOCAL_SIZES] + [None]


def layered_1d_candidates() -> list[dict | None]:
    """Work-group sizes of the layered passes that run one work-item (or group) per tile."""
    return [{"wg_x": x, "wg_y": 1} for x in (1, 2, 4, 8, 16, 32, 64)] + [None]


def splat_candidates() -> list[dict | None]:
    """Work-group sizes of the splat scatter."""
    return [{"wg": g} for g in (32, 64, 128, 256)] + [None]


@dataclass(frozen=True)
class Tunable:
    """What can be tuned about one pass.

    ``default`` is what the tuner measures first and what a CPU (or any device but a GPU)
    gets without a tuning entry; ``gpu`` is what a GPU gets instead (``None``: ``default``
    suits GPUs too). :func:`clrecon.tune.runtime.default_config` fits either to the device.
    ``rtol``/``atol`` bound how far a candidate's output may differ from the default's
    (passes that sum floats in another order per configuration need a relative tolerance).
    """

    name: str
    kernel_file: str
    default: dict | None
    candidates: Callable[[], list]
    rtol: float = 1e-5
    atol: float = 1e-6
    gpu: dict | None = None

    def __post_init__(self):
        if self.name not in PASS_NAMES:
            raise ValueError(f"Tunable {self.name!r}: add the pass to "
                             "clrecon.tune.tunable.PASS_NAMES")

    def default_for(self, device_type: str) -> dict | None:
        """The unfitted default of a device of ``device_type`` (``"GPU"``, ``"CPU"``...)."""
        return self.gpu if device_type == "GPU" and self.gpu is not None else self.default
