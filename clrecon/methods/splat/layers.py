"""splat's global depth layers: uniform in 1/depth over each frame's own hit range (kernel
arguments, so a frame is placed on its own depths whatever the plan was made for)."""
from __future__ import annotations


def inv_range(info) -> tuple[float, float]:
    """(1 / nearest hit, 1 / farthest hit or 0 when the frame has misses)."""
    hits = info.miss_fraction < 1.0
    inv_near = 1.0 / info.min_depth if hits else 0.0
    inv_far = 0.0 if info.miss_fraction > 0 or not hits else 1.0 / info.max_depth
    return inv_near, inv_far


def inv_span(info) -> float:
    inv_near, inv_far = inv_range(info)
    return inv_near - inv_far


def layer_params(info, layers: int) -> tuple[float, float]:
    """``(inv_far, layer_scale)`` of a frame: layers uniform in 1/depth over its own range
    (kernel arguments, so each frame gets its own placement)."""
    inv_near, inv_far = inv_range(info)
    return inv_far, (layers / (inv_near - inv_far) if inv_near > inv_far else 0.0)
