"""The built-in scenes, each a few lines of data (figures at the default 512x512, fov 50°,
focal length 549 px; CoC and motion in pixels scale with the width).

========== ===================================================================================
fence      defocused fence (CoC ~ -9 px) before a diagonally moving checkerboard (~40 px) in
           focus and a static slanted checkerboard (Hasselgren et al. 2015, Fig. 8)
spheres    three flat-shaded spheres with strong defocus (CoC -14 .. +9 px; Shirley Fig. 2)
bokeh      small HDR highlights (radiance 4-24) out of focus, some moving, over a dim wall
deep       ~40 objects from depth 1.5 to 60 with varied motion (the stress scene)
huge_coc   a near object with CoC radius ~ -75 px, far wall +9 px
fast_motion  a checkered bar moving ~280 px over the shutter before a static wall
static_focus  pinhole camera, nothing moves: box filtering is already right
empty      background only
========== ===================================================================================
"""
from __future__ import annotations

import numpy as np

from clrecon.scenes.primitives import Box, Material, Plane, Quad, Scene, Sphere

CHECK_W = Material((0.85, 0.85, 0.8), (0.08, 0.08, 0.1), "checker", 0.25)
CHECK_R = Material((0.9, 0.3, 0.2), (0.95, 0.9, 0.8), "checker", 0.2)
STRIPE = Material((0.2, 0.5, 0.85), (0.9, 0.9, 0.9), "stripe", 0.3)
WOOD = Material((0.55, 0.35, 0.18))


def fence() -> Scene:
    slats = [Box((x, 0.0, 2.5), (0.04, 1.6, 0.03), WOOD) for x in np.arange(-1.4, 1.45, 0.35)]
    rails = [Box((0.0, y, 2.45), (1.6, 0.03, 0.02), WOOD) for y in (-0.55, 0.6)]
    mover = Quad((0.2, 0.0, 6.0), (1.3, 1.3), Material((0.9, 0.3, 0.2), (0.95, 0.9, 0.8), "checker",
                 0.45), velocity=(0.35, 0.25, 0.0))
    wall = Plane((0.0, 0.0, 11.0), Material((0.8, 0.8, 0.75), (0.15, 0.2, 0.3), "checker", 0.9),
                 rotate=(10.0, 35.0, 0.0))
    return Scene("fence", tuple(slats + rails + [mover, wall]), focus_depth=6.0,
                 lens_radius=0.07, description="defocused fence, moving and slanted checkers")


def spheres() -> Scene:
    flat = [Material(c, emission=1.0) for c in ((0.9, 0.25, 0.2), (0.25, 0.8, 0.3),
                                                 (0.25, 0.35, 0.95))]
    objs = (Sphere((-0.9, 0.2, 3.0), 0.45, flat[0]), Sphere((0.1, -0.1, 5.0), 0.8, flat[1]),
            Sphere((1.9, -0.6, 9.0), 1.3, flat[2]))
    return Scene("spheres", objs, focus_depth=5.0, lens_radius=0.18,
                 background=(0.75, 0.75, 0.7), description="three flat spheres, strong defocus")


def bokeh() -> Scene:
    rng = np.random.default_rng(7)
    lights = []
    for k in range(14):
        z = rng.uniform(2.0, 3.2) if k % 2 else rng.uniform(12.0, 18.0)
        x, y = rng.uniform(-0.45, 0.45, 2) * z
        colour = tuple(rng.uniform(0.4, 1.0, 3))
        vel = (rng.uniform(-0.08, 0.08) * z, 0.0, 0.0) if k % 3 == 0 else (0.0, 0.0, 0.0)
        lights.append(Sphere((x, y, z), 0.012 * z, Material(colour, emission=rng.uniform(4, 24)),
                             velocity=vel))
    wall = Plane((0.0, 0.0, 20.0), Material((0.12, 0.1, 0.09), (0.05, 0.05, 0.06), "checker", 1.5))
    subject = Box((0.0, 0.4, 5.0), (0.5, 0.5, 0.5), CHECK_W, rotate=(20.0, 30.0, 0.0))
    # HDR discs converge slowly at their rims (one sample hit moves a pixel by E / spp)
    return Scene("bokeh", tuple(lights + [wall, subject]), focus_depth=5.0, lens_radius=0.12,
                 background=(0.01, 0.01, 0.015), description="out-of-focus HDR highlights",
                 reference_spp=4096)


def deep() -> Scene:
    rng = np.random.default_rng(11)
    mats = [CHECK_W, CHECK_R, STRIPE, WOOD, Material((0.3, 0.7, 0.4)), Material((0.8, 0.7, 0.2))]
    objs = []
    for k in range(40):
        z = float(np.exp(rng.uniform(np.log(1.5), np.log(60.0))))
        x, y = rng.uniform(-0.5, 0.5, 2) * z
        size = 0.06 * z * rng.uniform(0.5, 1.5)
        vel = tuple(rng.normal(0.0, 0.04 * z, 2)) + (0.0,) if k % 2 else (0.0, 0.0, 0.0)
        mat = mats[k % len(mats)]
        if k % 3 == 0:
            objs.append(Sphere((x, y, z), size, mat, velocity=vel))
        elif k % 3 == 1:
            objs.append(Box((x, y, z), (size, 0.7 * size, 0.8 * size), mat, velocity=vel,
                            rotate=tuple(rng.uniform(0, 90, 3))))
        else:
            objs.append(Quad((x, y, z), (size, 1.3 * size), mat, velocity=vel,
                             rotate=(0.0, rng.uniform(-40, 40), rng.uniform(0, 90))))
    objs.append(Plane((0.0, 2.5, 0.0), Material((0.6, 0.6, 0.6), (0.3, 0.3, 0.35), "checker", 2.0),
                      rotate=(90.0, 0.0, 0.0)))
    return Scene("deep", tuple(objs), focus_depth=6.0, lens_radius=0.06,
                 description="many objects over a large depth range, varied motion")


def huge_coc() -> Scene:
    objs = (Box((-0.3, 0.0, 1.2), (0.12, 0.4, 0.05), CHECK_R, rotate=(0.0, 0.0, 20.0)),
            Sphere((0.0, 0.0, 8.0), 1.2, STRIPE),
            Plane((0.0, 0.0, 30.0), CHECK_W))
    return Scene("huge_coc", objs, focus_depth=8.0, lens_radius=0.19,
                 description="near CoC ~ -75 px")


def fast_motion() -> Scene:
    objs = (Box((0.0, 0.0, 4.0), (0.3, 0.8, 0.1), CHECK_R, velocity=(2.0, 0.3, 0.0)),
            Sphere((-1.0, 0.8, 6.0), 0.4, STRIPE, velocity=(-0.8, 0.0, 0.0)),
            Plane((0.0, 0.0, 9.0), CHECK_W))
    return Scene("fast_motion", objs, focus_depth=4.0, lens_radius=0.01,
                 description="motion ~280 px over the shutter")


def static_focus() -> Scene:
    objs = (Sphere((-0.7, 0.1, 4.0), 0.6, STRIPE), Box((0.8, 0.2, 5.0), (0.5, 0.5, 0.5), CHECK_R,
                                                         rotate=(25.0, 35.0, 0.0)),
            Plane((0.0, 0.0, 8.0), CHECK_W))
    return Scene("static_focus", objs, focus_depth=5.0, lens_radius=0.0,
                 description="pinhole, static: no defocus, no motion")


def empty() -> Scene:
    return Scene("empty", (), focus_depth=5.0, lens_radius=0.05, background=(0.2, 0.3, 0.5),
                 description="background only")


SCENES = {f.__name__: f for f in (fence, spheres, bokeh, deep, huge_coc, fast_motion,
                                  static_focus, empty)}


def get_scene(name: str) -> Scene:
    """A built-in scene by name (see :data:`SCENES`)."""
    try:
        return SCENES[name]()
    except KeyError:
        raise ValueError(f"scene: unknown {name!r}; built-in scenes: {sorted(SCENES)}") from None
