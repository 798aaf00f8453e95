"""A float64 NumPy re-implementation of kernels/raytrace.cl's intersection and shading, used
to check the kernel sample by sample: it re-traces the ray each sample's own (position,
lens, time) define and must find the same depth, colour and motion."""
from __future__ import annotations

import numpy as np

from clrecon.scenes.primitives import Box, Plane, Quad, Scene, Sphere, rotation


def _hit(ob, o, d, t):
    """Ray parameter (inf for a miss), normal and texture coords for rays o + s d, (N, 3)."""
    n = o.shape[0]
    c = np.asarray(ob.centre, float) + (t[:, None] - 0.5) * np.asarray(ob.velocity, float)
    axes = rotation(*getattr(ob, "rotate", (0, 0, 0)))
    oc = o - c
    s = np.full(n, np.inf)
    nrm = np.zeros((n, 3))
    uvw = np.zeros((n, 3))
    if isinstance(ob, Sphere):
        b = (oc * d).sum(1)
        disc = b * b - ((oc * oc).sum(1) - ob.radius**2)
        ok = disc >= 0
        q = np.sqrt(np.where(ok, disc, 0))
        s1, s2 = -b - q, -b + q
        s = np.where(ok & (s1 > 1e-6), s1, np.where(ok & (s2 > 1e-6), s2, np.inf))
        p = oc + np.where(np.isfinite(s), s, 0)[:, None] * d
        nrm = p / ob.radius
        uvw = p @ axes.T
    elif isinstance(ob, (Quad, Plane)):
        e2 = axes[2]
        den = d @ e2
        with np.errstate(divide="ignore", invalid="ignore"):
            s = -(oc @ e2) / den
        s = np.where(s > 1e-6, s, np.inf)
        p = oc + np.where(np.isfinite(s), s, 0)[:, None] * d
        a, b = p @ axes[0], p @ axes[1]
        if isinstance(ob, Quad):
            s = np.where((np.abs(a) <= ob.half[0]) & (np.abs(b) <= ob.half[1]), s, np.inf)
        nrm = np.broadcast_to(e2, (n, 3))
        uvw = np.stack([a, b, np.zeros(n)], 1)
    elif isinstance(ob, Box):
        h = np.asarray(ob.half, float)
        lo, ld = oc @ axes.T, d @ axes.T
        with np.errstate(divide="ignore", invalid="ignore"):
            ta, tb = (-h - lo) / ld, (h - lo) / ld
        tn, tf = np.fmin(ta, tb).max(1), np.fmax(ta, tb).min(1)
        ok = (tn <= tf) & (tf > 1e-6)
        s = np.where(ok, np.where(tn > 1e-6, tn, tf), np.inf)
        p = lo + np.where(np.isfinite(s), s, 0)[:, None] * ld
        k = np.argmax(np.abs(p) / h, axis=1)
        nrm = axes[k]
        others = np.array([[1, 2], [0, 2], [0, 1]])[k]
        uvw = np.stack([np.take_along_axis(p, others, 1)[:, 0],
                        np.take_along_axis(p, others, 1)[:, 1], np.zeros(n)], 1)
    return s, nrm, uvw


def _shade(ob, nrm, uvw, d, light, ambient):
    m = ob.material
    a, b = np.asarray(m.color, float), np.asarray(m.color2, float)
    if m.texture == "flat":
        albedo = np.broadcast_to(a, nrm.shape)
    else:
        cell = np.floor(uvw / m.period)
        k = cell.sum(1) if m.texture == "checker" else cell[:, 0]
        albedo = np.where((k.astype(np.int64) & 1)[:, None] == 1, b, a)
    if m.emission > 0:
        return albedo * m.emission
    nrm = np.where(((nrm * d).sum(1) > 0)[:, None], -nrm, nrm)
    return albedo * (ambient + (1 - ambient) * np.maximum(0, nrm @ light))[:, None]


def retrace(scene: Scene, width: int, height: int, position, lens, time):
    """Colour, depth and motion of the rays given by flat (N, 2)/(N,) sample arrays."""
    cam = scene.camera(width, height)
    cx, cy = cam.centre
    f, F, R = cam.focal_px, cam.focus_depth, cam.lens_radius
    position, lens, time = (np.asarray(a, float) for a in (position, lens, time))
    o = np.concatenate([R * lens, np.zeros((len(time), 1))], 1)
    q = np.stack([(position[:, 0] - cx) * F / f, (position[:, 1] - cy) * F / f,
                  np.full(len(time), F)], 1)
    d = q - o
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    best = np.full(len(time), np.inf)
    color = np.broadcast_to(np.asarray(scene.background, float), (len(time), 3)).copy()
    motion = np.zeros((len(time), 2))
    light = np.asarray(scene.light()[:3], float)
    for ob in scene.objects:
        s, nrm, uvw = _hit(ob, o, d, time)
        closer = s < best
        if closer.any():
            best = np.where(closer, s, best)
            col = _shade(ob, nrm[closer], uvw[closer], d[closer], light, scene.ambient)
            color[closer] = col
            depth = s[closer] * d[closer, 2]
            motion[closer] = f * np.asarray(ob.velocity[:2], float) / depth[:, None]
    depth = best * d[:, 2]
    return color, depth, motion
