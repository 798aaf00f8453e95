"""SampleBuffer: validation, the centre convention, inspect() and the constructors."""
from __future__ import annotations

import re

import numpy as np
import pytest
from conftest import assert_close
from sample_frames import random_frame

from clrecon.core.camera import CocModel
from clrecon.core.samples import FIELDS, MISS_DEPTH, SampleBuffer, pixel_centres

H, W, S = 4, 5, 3
MODEL = CocModel.from_focus(aperture_px=6.0, focus_depth=2.0)


def _valid_buffer(rng, h=H, w=W, s=S, coc_model=MODEL) -> SampleBuffer:
    """A random buffer that satisfies every documented constraint."""
    def hdr(rng, hws):  # a tenth of the samples far above 1
        return (rng.exponential(3.0, hws + (3,)) * (rng.uniform(size=hws + (1,)) < 0.1) * 100
                + rng.uniform(0.0, 1.0, hws + (3,)))

    buf = random_frame(rng, h, w, s, 0.2, coc_model, (0.5, 20.0), hdr)
    buf.depth.flat[0] = np.inf  # at least one miss
    return buf


def _first(name: str, y: int, x: int, i: int) -> str:
    return re.escape(f"{name}: sample (y={y}, x={x}, i={i})")


# -- validate: accepted --------------------------------------------------------------------------
def test_valid_buffer_is_accepted(rng):
    buf = _valid_buffer(rng)
    assert buf.validate() is buf
    assert np.isinf(buf.depth).any() and buf.color.max() > 1.0
    for name in FIELDS:
        arr = getattr(buf, name)
        assert arr.dtype == np.float32 and arr.flags.c_contiguous, name


def test_zeros_and_single_sample_are_valid():
    SampleBuffer.zeros(1, 1, 1).validate()
    SampleBuffer.zeros(3, 7, 16, MODEL).validate()


def test_miss_depth_beyond_threshold_is_valid(rng):
    buf = _valid_buffer(rng)
    buf.depth[0, 1, 0] = 2 * MISS_DEPTH
    buf.validate()


@pytest.mark.parametrize("lens", [(1.0, 0.0), (0.0, -1.0), (0.6, 0.8), (-0.6, -0.8),
                                  (np.cos(1.0), np.sin(1.0)), (1.0 + 0.5e-4, 0.0)],
                         ids=["+u", "-v", "0.6,0.8", "-0.6,-0.8", "angle1", "within-tol"])
def test_lens_on_circle_is_accepted(rng, lens):
    buf = _valid_buffer(rng)
    buf.lens[2, 3, 1] = lens
    buf.validate()


@pytest.mark.parametrize("t", [0.0, 1.0])
def test_time_at_shutter_ends_is_accepted(rng, t):
    buf = _valid_buffer(rng)
    buf.time[:] = t
    buf.validate()


def test_position_on_pixel_edges_is_accepted(rng):
    buf = _valid_buffer(rng)
    buf.position[1, 2, 0] = (2.0, 1.0)  # top-left corner of its pixel
    buf.position[1, 2, 1] = (3.0, 2.0)  # bottom-right corner
    buf.validate()


# -- validate: rejected --------------------------------------------------------------------------
def _set(buf, name, y, x, i, value):
    getattr(buf, name)[y, x, i] = value


BAD_VALUES = {
    "depth-nan": ("depth", np.nan),
    "depth-negative": ("depth", -1.0),
    "depth-zero": ("depth", 0.0),
    "depth-neg-inf": ("depth", -np.inf),
    "color-nan": ("color", (0.5, np.nan, 0.5)),
    "color-inf": ("color", (np.inf, 0.5, 0.5)),
    "motion-nan": ("motion", (np.nan, 0.0)),
    "motion-inf": ("motion", (0.0, -np.inf)),
    "time-negative": ("time", -0.01),
    "time-above-one": ("time", 1.01),
    "time-nan": ("time", np.nan),
    "lens-outside": ("lens", (1.001, 0.0)),
    "lens-outside-diag": ("lens", (0.71, 0.71)),
    "lens-nan": ("lens", (np.nan, 0.0)),
}


@pytest.mark.parametrize("case", list(BAD_VALUES))
def test_bad_value_names_field_and_first_sample(rng, case):
    name, value = BAD_VALUES[case]
    buf = _valid_buffer(rng)
    _set(buf, name, 3, 4, 2, value)  # a later bad sample: must not be the one reported
    _set(buf, name, 1, 2, 1, value)
    with pytest.raises(ValueError, match=_first(name, 1, 2, 1)) as info:
        buf.validate()
    assert "(2 bad samples)" in str(info.value)


def test_position_x_too_large(rng):
    buf = _valid_buffer(rng)
    buf.position[2, 3, 0, 0] = 4.01  # pixel x = 3 covers [3, 4]
    with pytest.raises(ValueError, match=_first("position", 2, 3, 0) + ".*inside its pixel"):
        buf.validate()


def test_position_y_too_small(rng):
    buf = _valid_buffer(rng)
    buf.position[1, 0, 2, 1] = 0.99  # pixel y = 1 covers [1, 2]
    with pytest.raises(ValueError, match=_first("position", 1, 0, 2)):
        buf.validate()


def test_position_in_neighbouring_pixel(rng):
    buf = _valid_buffer(rng)
    buf.position[0, 0, 0] = buf.position[0, 1, 0]
    with pytest.raises(ValueError, match=_first("position", 0, 0, 0)):
        buf.validate()


def test_position_nan(rng):
    buf = _valid_buffer(rng)
    buf.position[3, 1, 1, 0] = np.nan
    with pytest.raises(ValueError, match=_first("position", 3, 1, 1)):
        buf.validate()


@pytest.mark.parametrize("name", [n for n in FIELDS if n != "depth"])
@pytest.mark.parametrize("how", ["spp", "trailing"])
def test_mismatched_shape_names_field(rng, name, how):
    buf = _valid_buffer(rng)
    arr = getattr(buf, name)
    if how == "spp":
        bad = np.zeros(arr.shape[:2] + (S + 1,) + arr.shape[3:], np.float32)
    else:
        tail = (FIELDS[name][0] + 1,) if FIELDS[name] else (1,)  # (H, W, S, 1) for time
        bad = np.zeros(arr.shape[:3] + tail, np.float32)
    setattr(buf, name, bad)
    expected = re.escape(f"{name}: expected shape {(H, W, S) + FIELDS[name]}, got {bad.shape}")
    with pytest.raises(ValueError, match=expected):
        buf.validate()


def test_depth_of_wrong_rank(rng):
    buf = _valid_buffer(rng)
    buf.depth = buf.depth[..., 0]
    with pytest.raises(ValueError, match=re.escape("depth: expected shape (H, W, S)")):
        buf.validate()


def test_depth_with_other_spp_is_rejected(rng):
    buf = _valid_buffer(rng)
    buf.depth = np.ones((H, W, S + 1), np.float32)
    with pytest.raises(ValueError, match="expected shape"):
        buf.validate()


@pytest.mark.parametrize("shape", [(0, 4, 2), (3, 0, 2), (3, 4, 0)])
def test_empty_frame_is_rejected(shape):
    with pytest.raises(ValueError, match="depth: empty frame"):
        SampleBuffer.zeros(*shape).validate()


def test_non_finite_coc_model_is_rejected(rng):
    buf = _valid_buffer(rng, coc_model=CocModel(c0=np.nan, c1=1.0))
    with pytest.raises(ValueError, match="coc_model"):
        buf.validate()


def test_coc_model_type_is_checked(rng):
    with pytest.raises(TypeError, match="coc_model"):
        SampleBuffer.zeros(1, 1, 1, coc_model=(1.0, 2.0))


# -- centre ---------------------------------------------------------------------------------
def test_centre_matches_formula(rng):
    buf = _valid_buffer(rng)
    depth = buf.depth.astype(np.float64)
    coc = MODEL.c0 / depth + MODEL.c1  # inf depth -> c1
    expected = (buf.position.astype(np.float64) - coc[..., None] * buf.lens
                - (buf.time.astype(np.float64)[..., None] - 0.5) * buf.motion)
    got = buf.centre()
    assert got.shape == (H, W, S, 2) and got.dtype == np.float32
    assert_close(got, expected, rtol=1e-5, atol=1e-5, what="centre")
    assert_close(buf.coc(), coc, rtol=1e-6, atol=1e-6, what="coc")


def test_centre_of_static_in_focus_sample_is_its_position(rng):
    buf = _valid_buffer(rng)
    buf.depth[:] = MODEL.focus_depth
    buf.motion[:] = 0.0
    assert_close(buf.centre(), buf.position, rtol=0, atol=1e-6, what="centre")


def test_centre_recovers_pinhole_point(rng):
    hws = (3, 4, 8)
    p = rng.uniform(-5.0, 50.0, hws + (2,))
    depth = rng.uniform(0.3, 30.0, hws)
    depth[0, 0, :3] = np.inf
    r = np.sqrt(rng.uniform(0.0, 1.0, hws))
    phi = rng.uniform(0.0, 2 * np.pi, hws)
    lens = np.stack([r * np.cos(phi), r * np.sin(phi)], -1)
    time = rng.uniform(0.0, 1.0, hws)
    motion = rng.normal(0.0, 10.0, hws + (2,))
    coc = MODEL.c0 / depth + MODEL.c1
    position = p + coc[..., None] * lens + (time[..., None] - 0.5) * motion
    buf = SampleBuffer(color=np.ones(hws + (3,)), position=position, depth=depth, lens=lens,
                       time=time, motion=motion, coc_model=MODEL)
    assert_close(buf.centre(), p, rtol=1e-5, atol=2e-5, what="recovered pinhole point")


# -- inspect --------------------------------------------------------------------------------
def test_inspect_reports_constructed_facts():
    model = CocModel.from_focus(aperture_px=4.0, focus_depth=2.0)  # coc = 4 - 8 / w
    buf = SampleBuffer.zeros(2, 3, 2, model)
    buf.depth[:] = 2.0
    buf.depth[0, 0, 0] = 1.0  # coc -4
    buf.depth[1, 2, 1] = 8.0  # coc 3
    buf.depth[0, 1, :] = np.inf  # 2 misses of 12
    buf.motion[1, 1, 0] = (0.0, -7.0)
    buf.motion[0, 2, 1] = (2.0, 1.0)
    info = buf.validate().inspect()
    assert (info.height, info.width, info.spp) == (2, 3, 2)
    assert info.max_abs_coc == pytest.approx(4.0, rel=1e-6)
    assert info.max_abs_motion == pytest.approx(7.0)
    assert info.min_depth == pytest.approx(1.0) and info.max_depth == pytest.approx(8.0)
    assert info.miss_fraction == pytest.approx(2 / 12)
    assert info.has_motion and info.has_defocus


def test_inspect_static_in_focus_frame():
    info = SampleBuffer.zeros(4, 4, 4).inspect()
    assert info.max_abs_coc == 0.0 and info.max_abs_motion == 0.0
    assert not info.has_motion and not info.has_defocus
    assert info.miss_fraction == 0.0 and info.min_depth == info.max_depth == 1.0


def test_inspect_all_misses():
    buf = SampleBuffer.zeros(2, 2, 2)
    buf.depth[:] = np.inf
    info = buf.inspect()
    assert info.miss_fraction == 1.0
    assert np.isinf(info.min_depth) and np.isinf(info.max_depth)


def test_inspect_counts_defocus_of_misses():
    """A miss has coc = C1: with every hit in focus the background still needs the lens."""
    buf = SampleBuffer.zeros(2, 2, 2, CocModel.from_focus(aperture_px=5.0, focus_depth=1.0))
    buf.depth[0, 0, :] = np.inf
    buf.lens[0, 0, 0] = (0.5, 0.0)
    assert not np.allclose(buf.centre(), buf.position)  # the lens term matters for the miss
    info = buf.inspect()
    assert info.has_defocus and info.max_abs_coc == pytest.approx(5.0)


# -- constructors ---------------------------------------------------------------------------
def test_pinhole(rng):
    color = rng.exponential(2.0, (3, 5, 3))
    depth = rng.uniform(1.0, 9.0, (3, 5))
    motion = rng.normal(0.0, 3.0, (3, 5, 2))
    buf = SampleBuffer.pinhole(color, depth, motion, coc_model=MODEL).validate()
    assert buf.shape == (3, 5, 1) and buf.spp == 1
    assert np.all(buf.lens == 0.0) and np.all(buf.time == 0.5)
    assert_close(buf.position, pixel_centres(3, 5, 1), rtol=0, atol=0, what="position")
    assert_close(buf.position[2, 4, 0], [4.5, 2.5], rtol=0, atol=0, what="last pixel")
    assert_close(buf.color[:, :, 0], color, rtol=1e-6, what="color")
    assert_close(buf.depth[:, :, 0], depth, rtol=1e-6, what="depth")
    assert_close(buf.motion[:, :, 0], motion, rtol=1e-6, what="motion")
    assert buf.coc_model == MODEL
    # lens 0, time 0.5: a pinhole sample's centre is its position
    assert_close(buf.centre(), buf.position, rtol=0, atol=0, what="centre")


def test_pinhole_without_motion(rng):
    buf = SampleBuffer.pinhole(np.ones((2, 2, 3)), np.full((2, 2), 3.0))
    assert np.all(buf.motion == 0.0) and buf.coc_model == CocModel()
    assert not buf.inspect().has_motion


@pytest.mark.parametrize("shape", [(4, 4), (4, 4, 4), (4, 4, 1, 3), (12,)])
def test_pinhole_bad_color_shape(shape):
    expected = re.escape(f"color: expected shape (H, W, 3), got {shape}")
    with pytest.raises(ValueError, match=expected):
        SampleBuffer.pinhole(np.zeros(shape), np.ones((4, 4)))


def test_zeros_layout():
    buf = SampleBuffer.zeros(2, 3, 4)
    assert buf.shape == (2, 3, 4) and (buf.height, buf.width, buf.spp) == (2, 3, 4)
    assert buf.nbytes == 2 * 3 * 4 * (3 + 2 + 1 + 2 + 1 + 2) * 4
    assert_close(buf.position[1, 2, 3], [2.5, 1.5], rtol=0, atol=0, what="pixel centre")
    assert set(buf.arrays()) == set(FIELDS)


def test_zeros_fields_are_writable_for_every_shape():
    for shape in ((1, 1, 1), (1, 3, 1), (2, 2, 4)):
        buf = SampleBuffer.zeros(*shape)
        buf.position[..., 0] += 0.25  # a broadcast view would raise here
        assert buf.position.flags.writeable and buf.position.flags.owndata
