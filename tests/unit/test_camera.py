"""CocModel and ThinLensCamera: the signed CoC convention and its thin-lens derivation."""
from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import assert_close

from clrecon.core.camera import CocModel, ThinLensCamera


# -- CocModel -------------------------------------------------------------------------------
@pytest.mark.parametrize("aperture, focus", [(5.0, 2.0), (0.5, 100.0), (40.0, 0.1)])
def test_from_focus(aperture, focus):
    m = CocModel.from_focus(aperture, focus)
    assert m.c1 == aperture and m.c0 == pytest.approx(-aperture * focus)
    assert m.has_defocus
    assert m.focus_depth == pytest.approx(focus, rel=1e-12)
    assert float(m.coc(focus)) == pytest.approx(0.0, abs=1e-5 * aperture)
    assert float(m.coc(np.inf)) == pytest.approx(aperture, rel=1e-6)
    assert float(m.coc(0.5 * focus)) < 0.0 < float(m.coc(2.0 * focus))
    # coc(w) = c0 / w + c1, evaluated on an array, as float32
    w = np.array([0.25, 0.5, 1.0, 2.0, 4.0, np.inf]) * focus
    got = m.coc(w)
    assert got.shape == w.shape and got.dtype == np.float32
    assert_close(got, aperture * (1.0 - focus / w), rtol=1e-6, atol=1e-6 * aperture, what="coc")


def test_coc_is_monotonic_in_depth():
    m = CocModel.from_focus(8.0, 3.0)
    w = np.geomspace(0.01, 1e6, 200)
    assert np.all(np.diff(m.coc(w).astype(np.float64)) >= 0.0)


@pytest.mark.parametrize("coc", [-20.0, -3.0, -0.5, 0.0, 0.5, 3.0, 4.5])
def test_depth_at_coc_inverts_coc(coc):
    m = CocModel.from_focus(5.0, 2.0)
    w = m.depth_at_coc(coc)
    assert w > 0
    assert float(m.coc(w)) == pytest.approx(coc, abs=1e-5)
    assert m.depth_at_coc(float(m.coc(7.0))) == pytest.approx(7.0, rel=1e-5)


def test_depth_at_coc_of_c1_is_infinity():
    m = CocModel.from_focus(5.0, 2.0)
    assert m.depth_at_coc(5.0) == math.inf


def test_pinhole_model():
    m = CocModel()
    assert not m.has_defocus and m.focus_depth == math.inf
    assert np.all(m.coc([0.1, 1.0, np.inf]) == 0.0)
    assert not CocModel.from_focus(0.0, 3.0).has_defocus


@pytest.mark.parametrize("focus", [0.0, -1.0, math.inf, math.nan])
def test_from_focus_rejects_bad_focus(focus):
    with pytest.raises(ValueError, match="focus_depth"):
        CocModel.from_focus(5.0, focus)


@pytest.mark.parametrize("aperture", [math.inf, -math.inf, math.nan])
def test_from_focus_rejects_bad_aperture(aperture):
    with pytest.raises(ValueError, match="aperture_px"):
        CocModel.from_focus(aperture, 2.0)


# -- ThinLensCamera -------------------------------------------------------------------------
def _ray_traced_image(cam: ThinLensCamera, p: np.ndarray, u: float, v: float) -> np.ndarray:
    """Sensor position of point ``p`` seen through lens point ``(u, v)``, by ray geometry.

    The line from the lens point ``L = (u R, v R, 0)`` through ``P`` meets the focus plane
    ``z = F`` at ``Q``; every ray through ``Q`` lands where its pinhole ray does,
    ``c + f Q_xy / F``.
    """
    f, r, focus = cam.focal_px, cam.lens_radius, cam.focus_depth
    lens = np.array([u * r, v * r, 0.0])
    q = lens + (p - lens) * (focus / p[2])
    return np.array(cam.centre) + f * q[:2] / focus


@pytest.mark.parametrize("cam", [
    ThinLensCamera(64, 48, focal_px=80.0, focus_depth=3.0, lens_radius=0.05),
    ThinLensCamera(640, 360, focal_px=500.0, focus_depth=12.5, lens_radius=0.4),
    ThinLensCamera.from_fov(256, 256, 60.0, focus_depth=0.7, lens_radius=0.01),
], ids=["small", "wide", "fov"])
def test_coc_model_matches_ray_geometry(rng, cam):
    model = cam.coc_model
    focus = cam.focus_depth
    depths = np.concatenate([rng.uniform(0.2, 0.95, 6), rng.uniform(1.05, 20.0, 6)]) * focus
    for z in depths:
        xy = rng.uniform(-0.5, 0.5, 2) * z * np.array([cam.width, cam.height]) / cam.focal_px
        p = np.array([xy[0], xy[1], z])
        for _ in range(4):
            r, phi = math.sqrt(rng.uniform()), rng.uniform(0.0, 2 * math.pi)
            u, v = r * math.cos(phi), r * math.sin(phi)
            expected = _ray_traced_image(cam, p, u, v)
            got = cam.project(p) + float(model.coc(z)) * np.array([u, v])
            assert_close(got, expected, rtol=1e-6, atol=1e-6 * cam.width,
                         what=f"image of {p} through ({u:.3f}, {v:.3f})")
    # the sign convention: in front of focus negative, behind positive, 0 at focus
    assert float(model.coc(0.5 * focus)) < 0.0 < float(model.coc(2.0 * focus))
    assert model.focus_depth == pytest.approx(focus, rel=1e-12)
    assert model.c1 == pytest.approx(cam.focal_px * cam.lens_radius / focus)


def test_pinhole_camera_has_no_defocus():
    cam = ThinLensCamera(32, 32, focal_px=40.0, focus_depth=5.0)
    assert not cam.coc_model.has_defocus


def test_project():
    cam = ThinLensCamera(100, 50, focal_px=200.0)
    assert cam.centre == (50.0, 25.0)
    pts = np.array([[0.0, 0.0, 3.0], [1.0, -2.0, 4.0]])
    got = cam.project(pts)
    assert got.shape == (2, 2)
    assert_close(got, [[50.0, 25.0], [50.0 + 200.0 / 4, 25.0 - 400.0 / 4]], rtol=1e-12,
                 what="project")


@pytest.mark.parametrize("width, fov", [(640, 90.0), (256, 60.0), (100, 30.0)])
def test_from_fov(width, fov):
    cam = ThinLensCamera.from_fov(width, 200, fov, focus_depth=2.0, lens_radius=0.1)
    assert cam.focal_px == pytest.approx(0.5 * width / math.tan(math.radians(fov) / 2), rel=1e-12)
    assert (cam.width, cam.height, cam.focus_depth, cam.lens_radius) == (width, 200, 2.0, 0.1)
    # a point on the edge of the horizontal field of view projects to the image border
    edge = np.array([math.tan(math.radians(fov) / 2), 0.0, 1.0])
    assert cam.project(edge)[0] == pytest.approx(width, rel=1e-12)
