"""Quality metrics on tone-mapped HDR images: PSNR, SSIM, FLIP."""
from __future__ import annotations

import math
import re
import sys

import numpy as np
import pytest
from conftest import assert_close

from clrecon import metrics
from clrecon.io import tonemap_srgb


def _srgb(x):
    """Independent clip + piecewise sRGB OETF, float64."""
    x = np.clip(np.asarray(x, np.float64), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)


def _scene(h=32, w=40):
    """A smooth HDR-ish reference with edges (values mostly in (0, 1), a few above)."""
    y, x = np.mgrid[0:h, 0:w] / np.array([h, w])[:, None, None]
    check = ((np.floor(x * 8) + np.floor(y * 8)) % 2)[..., None]
    img = 0.15 + 0.5 * check * np.array([0.9, 0.6, 0.3]) + 0.2 * x[..., None]
    img[h // 4, w // 4] = 8.0  # a highlight
    return img


def test_tonemap_is_clip_then_srgb():
    x = np.linspace(-0.5, 3.0, 97).reshape(1, -1, 1) * np.ones((2, 1, 3))
    assert_close(tonemap_srgb(x), _srgb(x), rtol=1e-6, atol=1e-7, what="tonemap_srgb")


# -- identical images -----------------------------------------------------------------------
def test_identical_images():
    ref = _scene()
    assert metrics.psnr(ref, ref.copy()) == math.inf
    assert metrics.ssim(ref, ref.copy()) == pytest.approx(1.0, abs=1e-12)
    assert metrics.flip(ref, ref.copy()) == 0.0
    assert np.all(metrics.flip_map(ref, ref) == 0.0)


def test_hdr_values_above_one_are_clipped():
    ref = np.ones((8, 9, 3))
    test = np.full((8, 9, 3), 5.0)
    assert metrics.psnr(test, ref) == math.inf
    assert metrics.ssim(test, ref) == pytest.approx(1.0, abs=1e-12)
    assert metrics.flip(test, ref) == 0.0
    # and negative values clip to black
    assert metrics.psnr(np.full((8, 9, 3), -2.0), np.zeros((8, 9, 3))) == math.inf


# -- PSNR -----------------------------------------------------------------------------------
def test_psnr_of_known_mse():
    # linear 0 encodes to 0 and linear 1 to white (1 up to float32 rounding): 4 of 300 values
    # differ by `white` -> MSE = 4 white^2 / 300
    white = float(tonemap_srgb(np.ones(1))[0])
    assert white == pytest.approx(1.0, abs=1e-6)
    ref = np.zeros((10, 10, 3))
    test = ref.copy()
    test[2, 3, 1] = 1.0
    test[7, 0, :] = 1.0
    expected = 10 * math.log10(300 / (4 * white**2))
    assert metrics.psnr(test, ref) == pytest.approx(expected, abs=1e-9)
    assert metrics.psnr(test, ref) == pytest.approx(10 * math.log10(75), abs=1e-5)


def test_psnr_matches_hand_computation(rng):
    ref = rng.uniform(0.0, 1.5, (12, 17, 3))
    test = ref + rng.normal(0.0, 0.1, ref.shape)
    tm = np.asarray(tonemap_srgb(test), np.float64)
    rm = np.asarray(tonemap_srgb(ref), np.float64)
    mse = np.mean((tm - rm) ** 2)
    assert metrics.psnr(test, ref) == pytest.approx(10 * math.log10(1 / mse), abs=1e-9)
    # and against the independent sRGB formula (io may tone map in float32)
    mse = np.mean((_srgb(test) - _srgb(ref)) ** 2)
    assert metrics.psnr(test, ref) == pytest.approx(10 * math.log10(1 / mse), abs=1e-4)
    assert metrics.psnr(ref, test) == pytest.approx(metrics.psnr(test, ref), abs=1e-12)


def test_float32_and_float64_agree(rng):
    ref = _scene()
    test = ref + rng.normal(0.0, 0.05, ref.shape)
    r64 = metrics.evaluate(test, ref)
    r32 = metrics.evaluate(test.astype(np.float32), ref.astype(np.float32))
    assert r32["psnr"] == pytest.approx(r64["psnr"], abs=1e-3)
    assert r32["ssim"] == pytest.approx(r64["ssim"], abs=1e-4)
    assert r32["flip"] == pytest.approx(r64["flip"], abs=1e-4)


# -- monotonic in the error -----------------------------------------------------------------
def test_more_noise_is_worse(rng):
    ref = _scene()
    noise = rng.normal(0.0, 1.0, ref.shape)
    results = [metrics.evaluate(ref + sigma * noise, ref) for sigma in (0.01, 0.05, 0.2)]
    psnrs = [r["psnr"] for r in results]
    ssims = [r["ssim"] for r in results]
    flips = [r["flip"] for r in results]
    assert psnrs[0] > psnrs[1] > psnrs[2] > 0, psnrs
    assert 1.0 > ssims[0] > ssims[1] > ssims[2], ssims
    assert 0.0 < flips[0] < flips[1] < flips[2] <= 1.0, flips


# -- SSIM -----------------------------------------------------------------------------------
def test_ssim_is_skimage_on_tonemapped(rng):
    from skimage.metrics import structural_similarity

    ref = _scene()
    test = ref + rng.normal(0.0, 0.05, ref.shape)
    tm = np.asarray(tonemap_srgb(test), np.float64)
    rm = np.asarray(tonemap_srgb(ref), np.float64)
    expected = structural_similarity(tm, rm, channel_axis=2, data_range=1.0)
    assert metrics.ssim(test, ref) == pytest.approx(expected, abs=1e-9)


@pytest.mark.parametrize("shape", [(5, 5, 3), (3, 8, 3), (6, 4, 3), (3, 3, 3)])
def test_tiny_images_work(rng, shape):
    ref = rng.uniform(0.0, 1.0, shape)
    test = ref + rng.normal(0.0, 0.1, shape)
    r = metrics.evaluate(test, ref)
    assert set(r) == {"psnr", "ssim", "flip"}
    assert all(isinstance(v, float) and math.isfinite(v) for v in r.values()), r
    assert -1.0 <= r["ssim"] < 1.0 and 0.0 < r["flip"] <= 1.0
    assert metrics.ssim(ref, ref) == pytest.approx(1.0)


def test_ssim_window_shrinks_on_small_images(rng):
    from skimage.metrics import structural_similarity

    ref = rng.uniform(0.0, 1.0, (5, 6, 3))
    test = ref + rng.normal(0.0, 0.1, ref.shape)
    tm = np.asarray(tonemap_srgb(test), np.float64)
    rm = np.asarray(tonemap_srgb(ref), np.float64)
    expected = structural_similarity(tm, rm, win_size=5, channel_axis=2, data_range=1.0)
    assert metrics.ssim(test, ref) == pytest.approx(expected, abs=1e-9)


@pytest.mark.parametrize("shape", [(2, 2, 3), (1, 9, 3), (9, 2, 3)])
def test_ssim_rejects_images_below_3px(shape):
    img = np.full(shape, 0.5)
    with pytest.raises(ValueError, match="too small for SSIM"):
        metrics.ssim(img, img)
    with pytest.raises(ValueError, match="too small for SSIM"):
        metrics.evaluate(img, img)
    # the other metrics do not need a window
    assert metrics.psnr(img, img) == math.inf
    assert metrics.flip(img, img) == 0.0


# -- FLIP -----------------------------------------------------------------------------------
def test_flip_map(rng):
    ref = _scene()
    test = ref.copy()
    test[10:14, 20:26] += 0.4  # a localised error
    fmap = metrics.flip_map(test, ref)
    assert fmap.shape == ref.shape[:2] and fmap.dtype == np.float32
    assert fmap.min() >= 0.0 and fmap.max() <= 1.0
    assert fmap[10:14, 20:26].mean() > 10 * fmap[:5, :5].mean()
    assert float(fmap.mean()) == pytest.approx(metrics.flip(test, ref), abs=1e-6)


def test_flip_matches_flip_evaluator(rng):
    import flip_evaluator

    ref = _scene()
    test = ref + rng.normal(0.0, 0.05, ref.shape)
    _, mean, _ = flip_evaluator.evaluate(_srgb(ref).astype(np.float32),
                                         _srgb(test).astype(np.float32), "LDR",
                                         inputsRGB=True, applyMagma=False)
    assert metrics.flip(test, ref) == pytest.approx(mean, abs=1e-6)


# -- input checks ---------------------------------------------------------------------------
def test_evaluate_keys(rng):
    ref = _scene()
    test = ref + rng.normal(0.0, 0.05, ref.shape)
    r = metrics.evaluate(test, ref)
    assert list(r) == ["psnr", "ssim", "flip"]
    assert all(type(v) is float for v in r.values())
    assert r["psnr"] == metrics.psnr(test, ref)
    assert r["ssim"] == metrics.ssim(test, ref)
    assert r["flip"] == metrics.flip(test, ref)


FUNCS = [metrics.psnr, metrics.ssim, metrics.flip, metrics.flip_map, metrics.evaluate]
IDS = [f.__name__ for f in FUNCS]


@pytest.mark.parametrize("func", FUNCS, ids=IDS)
def test_shape_mismatch(func):
    with pytest.raises(ValueError, match=re.escape("test (8, 9, 3), ref (8, 10, 3)")):
        func(np.zeros((8, 9, 3)), np.zeros((8, 10, 3)))


@pytest.mark.parametrize("func", FUNCS, ids=IDS)
@pytest.mark.parametrize("which", ["test", "ref"])
@pytest.mark.parametrize("shape", [(8, 8), (8, 8, 4), (8, 8, 3, 1), (0, 8, 3)])
def test_bad_shape_names_argument(func, which, shape):
    good, bad = np.zeros((8, 8, 3)), np.zeros(shape)
    args = (bad, good) if which == "test" else (good, bad)
    with pytest.raises(ValueError, match=rf"^{which}: .*{re.escape(str(shape))}"):
        func(*args)


@pytest.mark.parametrize("func", FUNCS, ids=IDS)
def test_non_finite_test_image(func):
    test = np.full((8, 8, 3), 0.5)
    test[1, 2, 0] = np.nan
    with pytest.raises(ValueError, match="test image has 1 non-finite pixel$"):
        func(test, np.full((8, 8, 3), 0.5))


@pytest.mark.parametrize("func", FUNCS, ids=IDS)
def test_non_finite_ref_image(func):
    ref = np.full((8, 8, 3), 0.5, np.float32)
    ref[0, 0, :] = np.inf  # one pixel, three channels
    ref[3, 4, 1] = -np.inf
    ref[7, 7, 2] = np.nan
    with pytest.raises(ValueError, match="ref image has 3 non-finite pixels"):
        func(np.full((8, 8, 3), 0.5, np.float32), ref)


def test_missing_optional_dependencies(monkeypatch):
    img = np.zeros((8, 8, 3))
    monkeypatch.setitem(sys.modules, "flip_evaluator", None)
    with pytest.raises(ImportError, match=re.escape("pip install clrecon[eval]")):
        metrics.flip(img, img)
    monkeypatch.setitem(sys.modules, "skimage.metrics", None)
    with pytest.raises(ImportError, match=re.escape("pip install clrecon[eval]")):
        metrics.ssim(img, img)
    assert metrics.psnr(img, img) == math.inf  # PSNR needs neither
