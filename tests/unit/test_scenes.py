"""Scene generator: the kernel against a NumPy re-tracer, and the pictures it must make
where geometry says what they are."""
from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import assert_close
from raytrace_ref import retrace

from clrecon.metrics import psnr
from clrecon.scenes import (
    SCENES,
    Box,
    Material,
    Plane,
    Quad,
    Scene,
    Sphere,
    get_scene,
    render_reference,
    render_samples,
)
from clrecon.scenes import render as render_module
from clrecon.tune.local import local_size_of

MIXED = Scene("mixed", (
    Sphere((-0.6, 0.1, 3.0), 0.5, Material((0.9, 0.3, 0.2), (0.1, 0.2, 0.9), "checker", 0.3),
           velocity=(0.3, -0.1, 0.0)),
    Box((0.5, -0.2, 4.0), (0.4, 0.3, 0.35), Material((0.2, 0.8, 0.3), (1, 1, 1), "stripe", 0.2),
        rotate=(20.0, 30.0, 10.0), velocity=(-0.2, 0.0, 0.0)),
    Quad((0.0, 0.5, 2.0), (0.3, 0.2), Material((1.0, 0.9, 0.5), emission=5.0),
         rotate=(0.0, 25.0, 0.0)),
    Plane((0.0, 0.0, 7.0), Material((0.8, 0.8, 0.8), (0.2, 0.2, 0.2), "checker", 0.7),
          rotate=(15.0, -20.0, 0.0)),
), focus_depth=3.5, lens_radius=0.1)


@pytest.mark.parametrize("group", [None, (16, 4), (64, 1)])
def test_kernel_matches_numpy_retrace(device, group, monkeypatch):
    """The tuned local size (None) and groups 16 and 64 wide: Intel's CPU compiler on an
    AVX-512 host packed 16 work-items a vector and shuffled their colours (kernels/raytrace.cl;
    the tuner's verification found it); every group the tuner may pick must trace right."""
    if group is not None:
        monkeypatch.setattr(render_module, "_local_size", lambda ctx, w, h, spp: local_size_of(
            {"wg_x": group[0], "wg_y": group[1]}))
    w, h, spp = 40, 32, 4
    buf = render_samples(MIXED, w, h, spp, seed=5, device=device)
    buf.validate()
    color, depth, motion = retrace(MIXED, w, h, buf.position.reshape(-1, 2),
                                   buf.lens.reshape(-1, 2), buf.time.reshape(-1))
    kd = buf.depth.reshape(-1)
    # a handful of rays graze an edge where float32 and float64 disagree on hit or miss
    same = (np.isinf(kd) == np.isinf(depth)) & (
        np.isinf(kd) | (np.abs(kd - depth) < 1e-3 * np.where(np.isinf(depth), 1, depth)))
    assert same.mean() > 0.995, f"{(~same).sum()} of {same.size} samples hit something else"
    hit = same & np.isfinite(kd)
    assert hit.sum() > 0.5 * same.size
    assert_close(kd[hit], depth[hit], rtol=1e-4, what="depth")
    assert_close(buf.motion.reshape(-1, 2)[hit], motion[hit], rtol=1e-3, atol=1e-3, what="motion")
    # texture cells switch at edges too: require agreement on nearly every sample
    col_ok = np.abs(buf.color.reshape(-1, 3)[same] - color[same]).max(1) < 1e-3
    assert col_ok.mean() > 0.99, f"colour differs on {(~col_ok).sum()} samples"


def test_samples_follow_the_convention(device):
    """Every hit's centre(), lifted back to camera space at its depth, lies on the surface
    it hit at mid-shutter: centre() is exact for static and moving objects alike."""
    ball = Sphere((0.2, -0.1, 3.0), 0.6, Material(), velocity=(0.4, 0.2, 0.0))
    still = Sphere((-0.5, 0.3, 6.0), 0.9, Material())
    scene = Scene("t", (ball, still), focus_depth=4.0, lens_radius=0.15)
    w = h = 48
    buf = render_samples(scene, w, h, 8, seed=1, device=device)
    cam = scene.camera(w, h)
    centre = buf.centre().astype(np.float64)
    z = buf.depth.astype(np.float64)
    hit = np.isfinite(z)
    assert hit.mean() > 0.1
    p = np.stack([(centre[..., 0] - cam.centre[0]) * z / cam.focal_px,
                  (centre[..., 1] - cam.centre[1]) * z / cam.focal_px, z], -1)[hit]
    moving = np.abs(buf.motion[hit]).max(-1) > 0
    for sph, sel in ((ball, moving), (still, ~moving)):
        r = np.linalg.norm(p[sel] - np.asarray(sph.centre), axis=-1)
        assert sel.sum() > 100
        assert_close(r, np.full_like(r, sph.radius), rtol=2e-4, what=f"radius {sph.radius}")


def test_defocused_point_becomes_a_disc(device):
    """An emissive ball of projected radius a, out of focus with CoC c, images as its disc
    convolved with the CoC disc: energy conserved, nothing beyond c + a, flat inside c - a.
    Paraxial set-up (narrow field, lens seen from the ball under < 5 degrees), so that the
    ball's projection is the same disc from every lens point to within 0.5%."""
    z, focus, r = 8.0, 16.0, 0.06
    scene = Scene("dot", (Sphere((0.0, 0.0, z), r, Material((1, 1, 1), emission=1.0)),),
                  fov_deg=10.0, focus_depth=focus, lens_radius=0.66, background=(0, 0, 0))
    w = h = 64
    img = render_reference(scene, w, h, 1024, seed=3, device=device)[..., 0].astype(np.float64)
    cam = scene.camera(w, h)
    c = abs(float(cam.coc_model.coc(z)))
    a = cam.focal_px * r / math.sqrt(z * z - r * r)
    assert 10 < c < 25 and a < 0.3 * c
    energy = math.pi * a * a
    assert_close(img.sum(), energy, rtol=0.02, what="energy")
    yy, xx = np.mgrid[0:h, 0:w] + 0.5
    dist = np.hypot(xx - cam.centre[0], yy - cam.centre[1])
    assert img[dist > c + a + 1.0].max() == 0.0
    inside = img[dist < c - a - 1.0]
    assert_close(inside.mean(), energy / (math.pi * c * c), rtol=0.03, what="disc level")


def test_plane_in_focus_reproduces_its_texture(device):
    period, depth = 0.35, 5.0
    mat = Material((0.9, 0.9, 0.9), (0.1, 0.1, 0.1), "checker", period, emission=1.0)
    scene = Scene("plane", (Plane((0.0, 0.0, depth), mat),), focus_depth=depth, lens_radius=0.3)
    w = h = 48
    img = render_reference(scene, w, h, 256, seed=2, device=device)
    cam = scene.camera(w, h)
    n = 16  # analytic pixel-area integral of the checker, n x n supersampled
    sub = (np.arange(n) + 0.5) / n
    xs = (np.arange(w)[:, None] + sub[None, :]).reshape(-1)
    ys = (np.arange(h)[:, None] + sub[None, :]).reshape(-1)
    X = (xs - cam.centre[0]) * depth / cam.focal_px
    Y = (ys - cam.centre[1]) * depth / cam.focal_px
    k = (np.floor(Y / period)[:, None] + np.floor(X / period)[None, :]).astype(int) & 1
    want = np.where(k == 1, 0.1, 0.9).reshape(h, n, w, n).mean(axis=(1, 3))
    assert psnr(img, np.repeat(want[..., None], 3, -1)) > 40.0


def test_moving_edge_becomes_a_linear_ramp(device):
    """A pinhole view of a white half-plane moving right by M pixels: each row is a ramp of
    length M centred on the mid-shutter edge."""
    w, h, depth = 96, 8, 4.0
    scene0 = Scene("edge", (), lens_radius=0.0)
    f = scene0.camera(w, h).focal_px
    m_px = 40.0
    edge_x = 0.0  # mid-shutter edge through the image centre
    half = 10.0
    quad = Quad((edge_x - half, 0.0, depth), (half, half), Material((1, 1, 1), emission=1.0),
                velocity=(m_px * depth / f, 0.0, 0.0))
    scene = Scene("edge", (quad,), lens_radius=0.0, background=(0, 0, 0))
    img = render_reference(scene, w, h, 512, seed=4, device=device)[..., 0]
    x = np.arange(w) + 0.5
    # coverage of the pixel centre x: edge at w/2 + (t - 0.5) M, covered while edge > x
    want = np.clip(0.5 + (w / 2 - x) / m_px, 0.0, 1.0)
    for row in img:
        assert np.abs(row - want).max() < 0.01


def test_seeds_are_deterministic_and_independent(device):
    sc = get_scene("spheres")
    a = render_samples(sc, 16, 16, 4, seed=7, device=device)
    b = render_samples(sc, 16, 16, 4, seed=7, device=device)
    c = render_samples(sc, 16, 16, 4, seed=8, device=device)
    assert np.array_equal(a.position, b.position) and np.array_equal(a.color, b.color)
    assert not np.array_equal(a.position, c.position)


def test_samples_are_stratified(device):
    buf = render_samples(get_scene("empty"), 8, 8, 16, seed=0, device=device)
    t = np.sort(buf.time, axis=-1)
    gaps = np.diff(np.concatenate([t, t[..., :1] + 1.0], -1), axis=-1)
    assert gaps.max() < 2.5 / 16, "times of a pixel must cover the shutter evenly"
    frac = buf.position - np.floor(buf.position)
    for k in range(2):
        counts = np.stack([(np.floor(frac[..., k] * 4) == j).sum(-1) for j in range(4)])
        assert counts.min() >= 3, "each quarter of the pixel gets its share of 16 samples"


def test_random_sampler_draws_independent_samples(device):
    """``sampler="random"``: deterministic per seed, the convention's ranges, and the spread
    of independent samples: the variance of a pixel's mean sub-pixel position, lens
    coordinate and time is that of ``spp`` independent uniform numbers (the lattice's is a
    fraction of it), and the two halves of a pixel's samples are uncorrelated."""
    sc, spp = get_scene("empty"), 16
    a = render_samples(sc, 32, 32, spp, seed=3, device=device, sampler="random")
    b = render_samples(sc, 32, 32, spp, seed=3, device=device, sampler="random")
    c = render_samples(sc, 32, 32, spp, seed=4, device=device, sampler="random")
    lat = render_samples(sc, 32, 32, spp, seed=3, device=device)
    a.validate()
    assert a.shape == lat.shape and np.array_equal(a.position, b.position)
    assert not np.array_equal(a.position, c.position)
    for name, dims, var1 in (("position", 2, 1 / 12), ("time", 1, 1 / 12)):
        for buf, lo, hi in ((a, 0.8, 1.25), (lat, 0.0, 0.3)):
            v = getattr(buf, name).reshape(32, 32, spp, dims)
            v = v - np.floor(v)  # the position's offset inside its pixel
            ratio = v.mean(2).var(axis=(0, 1)) / (var1 / spp)
            assert np.all((ratio > lo) & (ratio < hi)), (name, ratio)
    u = a.lens[..., 0]
    ha, hb = u[..., : spp // 2].mean(-1).ravel(), u[..., spp // 2:].mean(-1).ravel()
    assert abs(np.corrcoef(ha, hb)[0, 1]) < 0.15
    with pytest.raises(ValueError, match="sampler: one of"):
        render_samples(sc, 4, 4, 2, device=device, sampler="sobol")


def test_references_converge(device):
    sc = get_scene("fence")
    a = render_reference(sc, 48, 48, 256, seed=1, device=device)
    b = render_reference(sc, 48, 48, 256, seed=2, device=device)
    box = render_samples(sc, 48, 48, 8, seed=3, device=device).color.mean(axis=2)
    assert psnr(a, b) > 38.0
    assert psnr(a, b) > psnr(box, a) + 8.0


@pytest.mark.parametrize("name", sorted(SCENES))
def test_builtin_scene_renders_valid_buffers(device, name):
    buf = render_samples(get_scene(name), 24, 16, 4, seed=0, device=device)
    buf.validate()
    assert buf.shape == (16, 24, 4)


def test_extreme_scenes_are_extreme(device):
    def info(name):
        sc = get_scene(name)
        return render_samples(sc, *sc.default_size, 1, seed=0, device=device).inspect()

    assert info("huge_coc").max_abs_coc > 50
    assert info("fast_motion").max_abs_motion > 200
    st = info("static_focus")
    assert st.max_abs_coc == 0 and st.max_abs_motion == 0
    assert info("empty").miss_fraction == 1.0
    assert not get_scene("spheres").has_motion and get_scene("fence").has_motion


def test_scene_input_errors(device):
    with pytest.raises(ValueError, match="velocity z must be 0"):
        Scene("bad", (Sphere((0, 0, 3), 1, velocity=(0, 0, 1.0)),))
    with pytest.raises(ValueError, match="unknown 'nope'"):
        get_scene("nope")
    with pytest.raises(ValueError, match="spp"):
        render_samples(get_scene("empty"), 4, 4, 0, device=device)
    with pytest.raises(ValueError, match="texture"):
        Material(texture="plaid")
