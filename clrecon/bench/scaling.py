"""Frames of one built-in scene at a chosen amount of blur: the blur family the scaling study
(``tools/scaling_study.py``) times every method on.

A scene's blur comes from its camera and its objects: a surface at depth ``Z`` has the CoC
``f R (1/F - 1/Z)`` pixels (:class:`clrecon.core.camera.ThinLensCamera`), linear in the lens
radius ``R``, and an object moving at ``v`` (parallel to the image plane) moves ``f v / Z``
pixels over the shutter, linear in ``v``. A frame whose largest |CoC| is ``c`` pixels and
whose longest motion is ``m`` pixels is therefore the scene with its lens radius and every
velocity scaled, *rendered*: the renderer traces each sample from its own position, lens
point and time, so the buffer follows the sample convention exactly (rescaling a rendered
buffer's CoC model would move every sample's centre and break that). Geometry, focus depth
and the samples' random numbers (same seed) stay, so every frame of the family has the
scene's depth structure with each CoC and each motion scaled by one factor.

Which surface a ray hits shifts a little with the lens radius and the velocities, so the
frame's measured maxima (:meth:`clrecon.core.samples.SampleBuffer.inspect`) can miss a scale
computed from the scene's first render; :func:`render_blur_frame` refines both scales from
each render's measured maxima until they are within ``rel_tol`` (on ``deep`` the first
refinement already lands within float32 rounding).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

from clrecon.core.device import Device, DeviceSpec
from clrecon.core.samples import FrameInfo, SampleBuffer
from clrecon.scenes import Scene, render_samples

#: relative tolerance of a frame's measured max |CoC| and |motion| against the targets
REL_TOL = 0.02

#: renders :func:`render_blur_frame` tries before it returns its closest frame
MAX_RENDERS = 4


def scaled_scene(scene: Scene, lens_scale: float, motion_scale: float) -> Scene:
    """``scene`` with its lens radius times ``lens_scale`` and every object's velocity times
    ``motion_scale`` (both finite and >= 0; 0 gives a pinhole or a static scene)."""
    for name, k in (("lens_scale", lens_scale), ("motion_scale", motion_scale)):
        if not (isinstance(k, (int, float)) and math.isfinite(k) and k >= 0):
            raise ValueError(f"{name}: must be finite and >= 0, got {k!r}")
    objects = tuple(replace(ob, velocity=tuple(float(v) * motion_scale for v in ob.velocity))
                    for ob in scene.objects)
    return replace(scene, lens_radius=scene.lens_radius * lens_scale, objects=objects)


@dataclass(frozen=True)
class BlurFrame:
    """One frame of the family and how it was made.

    Attributes
    ----------
    buf : SampleBuffer
    info : FrameInfo
        ``buf.inspect()``: the measured ``max_abs_coc`` and ``max_abs_motion``.
    target_coc, target_motion : float
        The maxima asked for, pixels.
    lens_scale, motion_scale : float
        The factors applied to the scene's lens radius and velocities.
    renders : int
        Renders it took in all (``buf`` is the closest to the targets of them).
    """

    buf: SampleBuffer
    info: FrameInfo
    target_coc: float
    target_motion: float
    lens_scale: float
    motion_scale: float
    renders: int

    @property
    def coc_error(self) -> float:
        """``|measured / target - 1|`` of the max |CoC| (0 when both are 0)."""
        return _rel_error(self.info.max_abs_coc, self.target_coc)

    @property
    def motion_error(self) -> float:
        """``|measured / target - 1|`` of the max |motion| (0 when both are 0)."""
        return _rel_error(self.info.max_abs_motion, self.target_motion)


def _rel_error(measured: float, target: float) -> float:
    if target == 0:
        return 0.0 if measured == 0 else math.inf
    return abs(measured / target - 1.0)


def render_blur_frame(scene: Scene, width: int, height: int, spp: int, max_coc: float,
                      max_motion: float, seed: int = 1, device: DeviceSpec | Device = None,
                      rel_tol: float = REL_TOL, max_renders: int = MAX_RENDERS) -> BlurFrame:
    """Render ``scene`` with its lens radius and velocities scaled so that the frame's
    max |CoC| is ``max_coc`` pixels and its max |motion| ``max_motion`` pixels.

    The first render uses the scene's own camera and motion (scale 1, or 0 for a target of
    0); each next one scales by ``target / measured`` of the last, until both maxima are
    within ``rel_tol`` of their targets or ``max_renders`` renders are spent. Then the
    frame closest to the targets is returned: the caller reports its measured maxima
    (:attr:`BlurFrame.info`), which are what the methods are specialised on.

    Raises
    ------
    ValueError
        A negative or non-finite target, a bad ``rel_tol`` or ``max_renders``, or a target
        above 0 for a scene without defocus (lens radius 0) or without moving objects, or
        for a frame in which no sample sees the blur to scale.
    """
    for name, v in (("max_coc", max_coc), ("max_motion", max_motion)):
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
            raise ValueError(f"{name}: must be finite and >= 0 pixels, got {v!r}")
    if not (isinstance(rel_tol, (int, float)) and rel_tol > 0):
        raise ValueError(f"rel_tol: must be > 0, got {rel_tol!r}")
    if isinstance(max_renders, bool) or not isinstance(max_renders, int) or max_renders < 1:
        raise ValueError(f"max_renders: must be a positive integer, got {max_renders!r}")
    if max_coc > 0 and scene.lens_radius == 0:
        raise ValueError(f"max_coc={max_coc:g}: scene {scene.name!r} is a pinhole (lens "
                         "radius 0), there is no defocus to scale")
    if max_motion > 0 and not scene.has_motion:
        raise ValueError(f"max_motion={max_motion:g}: nothing moves in scene {scene.name!r}, "
                         "there is no motion to scale")
    lens_k = 1.0 if max_coc > 0 else 0.0
    motion_k = 1.0 if max_motion > 0 else 0.0
    best: BlurFrame | None = None
    for k in range(1, max_renders + 1):
        buf = render_samples(scaled_scene(scene, lens_k, motion_k), width, height, spp,
                             seed=seed, device=device)
        frame = BlurFrame(buf, buf.inspect(), float(max_coc), float(max_motion), lens_k,
                          motion_k, k)
        if best is None or (max(frame.coc_error, frame.motion_error)
                            < max(best.coc_error, best.motion_error)):
            best = frame
        if frame.coc_error <= rel_tol and frame.motion_error <= rel_tol:
            break
        for what, measured in (("CoC", frame.info.max_abs_coc),
                               ("motion", frame.info.max_abs_motion)):
            target = max_coc if what == "CoC" else max_motion
            if target > 0 and not measured > 0:
                raise ValueError(f"scene {scene.name!r} at {width}x{height}: no sample has "
                                 f"any {what} to scale to {target:g} px")
        if max_coc > 0:
            lens_k *= max_coc / frame.info.max_abs_coc
        if max_motion > 0:
            motion_k *= max_motion / frame.info.max_abs_motion
    return replace(best, renders=k)
