"""Animated built-in scenes: frame ``k`` of a sequence in which objects and camera move
continuously.

The shutter of frame ``k`` spans the frame interval ``[k, k + 1)``: an object with velocity
``v`` (world units per shutter, as in a still scene) starts frame ``k`` at ``centre + k v``,
so the end of one frame's shutter is the start of the next and the motion blur of every
frame matches the motion between frames. The camera pans laterally by ``pan`` world units
per frame (x, y; ``z`` must be 0: lateral motion keeps screen motion linear, the renderer's
convention): equivalently every object moves by ``-pan``, which is added to its velocity and
to its per-frame displacement. A static object therefore shows the pan's motion blur, as it
would in a real panning shot.

The default pan is ``0.004 * focus_depth`` per frame along x: about 2 px of screen motion
per frame at the focus plane for a 512 px wide frame (fov 50°), enough that every pixel's
content changes from frame to frame without dominating the scene's own motion.
"""
from __future__ import annotations

from dataclasses import replace

from clrecon.scenes.primitives import Scene

DEFAULT_PAN_PER_FOCUS = 0.004


def default_pan(scene: Scene) -> tuple[float, float, float]:
    return (DEFAULT_PAN_PER_FOCUS * scene.focus_depth, 0.0, 0.0)


def frame_of(scene: Scene, k: int, pan: tuple[float, float, float] | None = None) -> Scene:
    """Frame ``k`` (>= 0) of the animation of ``scene`` (see the module docstring)."""
    if isinstance(k, bool) or not isinstance(k, int) or k < 0:
        raise ValueError(f"frame: must be an integer >= 0, got {k!r}")
    pan = default_pan(scene) if pan is None else tuple(float(p) for p in pan)
    if len(pan) != 3 or pan[2] != 0.0:
        raise ValueError(f"pan: must be (x, y, 0) world units per frame, got {pan}")
    objects = []
    for ob in scene.objects:
        v = tuple(a - b for a, b in zip(ob.velocity, pan))
        centre = tuple(c + k * d for c, d in zip(ob.centre, v))
        objects.append(replace(ob, centre=centre, velocity=v))
    return replace(scene, objects=tuple(objects), name=f"{scene.name}@{k}")


def frame_seed(seed: int, k: int) -> int:
    """Each frame's samples get their own seed (deterministic in ``seed`` and ``k``)."""
    return int(seed) * 100_003 + int(k)
