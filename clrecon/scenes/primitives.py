"""Scene description: analytic primitives, materials and the thin-lens camera (pure NumPy).

Camera space is the world: the camera sits at the origin looking down +z, x right, y down
(so "up" is -y). Objects move linearly over the shutter, parallel to the image plane
(velocity z must be 0): that keeps screen motion exactly linear and depth constant, as the
sample-buffer convention assumes. Positions are given at mid-shutter (t = 0.5).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Union

import numpy as np

from clrecon.core.camera import ThinLensCamera

OBJ_STRIDE = 32
TEXTURES = {"flat": 0, "checker": 1, "stripe": 2}
Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class Material:
    """Flat colour, or a checker/stripe of ``color`` and ``color2`` with period ``period``.

    ``emission > 0`` makes the surface unlit with radiance ``color * emission`` (HDR
    highlights, flat-shaded objects).
    """

    color: Vec3 = (0.7, 0.7, 0.7)
    color2: Vec3 = (0.1, 0.1, 0.1)
    texture: str = "flat"
    period: float = 1.0
    emission: float = 0.0

    def __post_init__(self):
        if self.texture not in TEXTURES:
            raise ValueError(f"texture: {self.texture!r} not in {sorted(TEXTURES)}")
        if not self.period > 0:
            raise ValueError(f"period: must be positive, got {self.period}")


def rotation(rx: float = 0.0, ry: float = 0.0, rz: float = 0.0) -> np.ndarray:
    """Rows are the local axes e0, e1, e2 after rotating by rz, ry, rx degrees about x, y, z."""
    ax, ay, az = (math.radians(a) for a in (rx, ry, rz))
    mx = np.array([[1, 0, 0], [0, math.cos(ax), -math.sin(ax)], [0, math.sin(ax), math.cos(ax)]])
    my = np.array([[math.cos(ay), 0, math.sin(ay)], [0, 1, 0], [-math.sin(ay), 0, math.cos(ay)]])
    mz = np.array([[math.cos(az), -math.sin(az), 0], [math.sin(az), math.cos(az), 0], [0, 0, 1]])
    return (mz @ my @ mx).T


@dataclass(frozen=True)
class Sphere:
    centre: Vec3
    radius: float
    material: Material = field(default_factory=Material)
    velocity: Vec3 = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class _Extended:
    """The fields a quad and a box share: ``half`` holds their half extents (two for a quad,
    three for a box), ``rotate`` their orientation."""

    centre: Vec3
    half: tuple[float, ...]
    material: Material = field(default_factory=Material)
    velocity: Vec3 = (0.0, 0.0, 0.0)
    rotate: Vec3 = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class Quad(_Extended):
    """A rectangle of half extents ``half = (h0, h1)`` in its local (e0, e1) plane, normal e2.

    With no rotation it faces the camera (normal along z)."""


@dataclass(frozen=True)
class Box(_Extended):
    """An oriented box (axis aligned when ``rotate`` is zero) of half extents ``half``
    (three values)."""


@dataclass(frozen=True)
class Plane:
    """An infinite plane through ``centre``; with no rotation it faces the camera."""

    centre: Vec3
    material: Material = field(default_factory=Material)
    velocity: Vec3 = (0.0, 0.0, 0.0)
    rotate: Vec3 = (0.0, 0.0, 0.0)


Primitive = Union[Sphere, Quad, Box, Plane]
_TYPE = {Sphere: 0, Quad: 1, Box: 2, Plane: 3}


@dataclass(frozen=True)
class Scene:
    """Primitives, light and a thin-lens camera given independently of the image size.

    ``fov_deg`` is the horizontal field of view; CoC and motion in pixels scale with the
    image width. ``default_size`` is the size the scene's description (e.g. "CoC > 50 px")
    refers to.
    """

    name: str
    objects: tuple
    fov_deg: float = 50.0
    focus_depth: float = 5.0
    lens_radius: float = 0.0
    light_dir: Vec3 = (-0.4, -0.7, -0.6)
    ambient: float = 0.35
    background: Vec3 = (0.05, 0.06, 0.08)
    default_size: tuple[int, int] = (512, 512)
    description: str = ""
    #: samples per pixel a converged reference needs (two seeds agree to >= 45 dB PSNR)
    reference_spp: int = 1024

    def __post_init__(self):
        for k, ob in enumerate(self.objects):
            if type(ob) not in _TYPE:
                raise TypeError(f"objects[{k}]: not a primitive: {type(ob).__name__}")
            if ob.velocity[2] != 0.0:
                raise ValueError(
                    f"objects[{k}]: velocity z must be 0 (motion parallel to the image plane "
                    f"keeps screen motion linear), got {ob.velocity}"
                )
        if self.lens_radius < 0 or not self.focus_depth > 0:
            raise ValueError("lens_radius must be >= 0 and focus_depth > 0")

    def camera(self, width: int, height: int) -> ThinLensCamera:
        return ThinLensCamera.from_fov(width, height, self.fov_deg, focus_depth=self.focus_depth,
                                       lens_radius=self.lens_radius)

    @property
    def has_motion(self) -> bool:
        return any(any(v != 0 for v in ob.velocity) for ob in self.objects)

    def pack(self) -> np.ndarray:
        """Object records for ``kernels/raytrace.cl`` (float32, (n, OBJ_STRIDE)), nearest
        first: slot 27 holds the least depth the object reaches over the shutter (0 for
        planes and objects reaching the lens plane), which lets the kernel stop early."""
        if not self.objects:
            return np.zeros((1, OBJ_STRIDE), np.float32)
        records = np.stack([_record(ob) for ob in self.objects])
        return records[np.argsort(records[:, 27], kind="stable")]

    def screen_bounds(self, width: int, height: int) -> np.ndarray:
        """Per object (xmin, ymin, xmax, ymax) in pixels: a superset of where any sample of
        the frame can see it. A sample at sensor s sees P only if |s - pinhole(P)| <=
        |coc(P.z)| per axis; the pinhole image of a convex set in front of the lens lies in
        the hull of its corners' images, so the corners of the object's bounding box at both
        ends of its travel, projected and grown by the largest |CoC| over their depth range
        (CoC is monotonic in depth), bound it. Planes and objects reaching the lens plane get
        infinite bounds.
        """
        cam = self.camera(width, height)
        coc = cam.coc_model
        cx, cy = cam.centre
        f = cam.focal_px
        records = self.pack().astype(np.float64)
        out = np.tile(np.array([-np.inf, -np.inf, np.inf, np.inf], np.float32),
                      (max(len(self.objects), 1), 1))
        for k, rec in enumerate(records[: len(self.objects)]):
            pts = _hull_points(rec)
            if pts is None:
                continue
            z0, z1 = pts[:, 2].min(), pts[:, 2].max()
            if z0 <= 1e-3:
                continue
            grow = max(abs(float(coc.coc(z0))), abs(float(coc.coc(z1)))) + 1.0
            xs = cx + f * pts[:, 0] / pts[:, 2]
            ys = cy + f * pts[:, 1] / pts[:, 2]
            out[k] = (xs.min() - grow, ys.min() - grow, xs.max() + grow, ys.max() + grow)
        return out

    def light(self) -> np.ndarray:
        """float4 (direction to the light, normalised; ambient) for the kernel."""
        d = np.asarray(self.light_dir, np.float64)
        d = d / np.linalg.norm(d)
        return np.array([*d, self.ambient], np.float32)


def _record(ob) -> np.ndarray:
    """One object's record (see kernels/raytrace.cl for the layout)."""
    r = np.zeros(OBJ_STRIDE, np.float32)
    m = ob.material
    r[0] = _TYPE[type(ob)]
    r[1] = TEXTURES[m.texture]
    r[2] = m.emission
    r[3] = m.period
    r[4:7] = ob.centre
    r[8:11] = ob.velocity
    axes = rotation(*getattr(ob, "rotate", (0.0, 0.0, 0.0)))
    if isinstance(ob, Sphere):
        half = (0.0, 0.0, 0.0)
        r[7] = ob.radius
        reach = ob.radius
    elif isinstance(ob, Plane):
        half = (0.0, 0.0, 0.0)
        reach = math.inf
    else:
        half = tuple(ob.half) + (0.0,) * (3 - len(ob.half))
        reach = math.hypot(*half)
    # bounding sphere over the whole shutter (slot 11): the kernel's cheap reject
    r[11] = reach + 0.5 * math.hypot(*ob.velocity)
    for j in range(3):
        r[12 + 4 * j: 15 + 4 * j] = axes[j]
        r[15 + 4 * j] = half[j]
    r[24:27] = m.color
    r[28:31] = m.color2
    pts = _hull_points(r.astype(np.float64))
    r[27] = 0.0 if pts is None else max(0.0, float(pts[:, 2].min()))
    return r


def _hull_points(rec: np.ndarray) -> np.ndarray | None:
    """Camera-space corners of a box containing a packed object over the whole shutter
    (None for a plane)."""
    kind = int(rec[0])
    if kind == 3:
        return None
    c, v = rec[4:7], rec[8:11]
    if kind == 0:
        axes, half = np.eye(3), np.full(3, rec[7])
    else:
        axes = np.stack([rec[12:15], rec[16:19], rec[20:23]])
        half = np.array([rec[15], rec[19], rec[23]])
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
    corners = c + (signs * half) @ axes
    return np.concatenate([corners - 0.5 * v, corners + 0.5 * v])
