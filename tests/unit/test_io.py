"""Tests of clrecon.io: round trips of every sample-buffer format, EXR and npz errors,
dispatch by extension, and images (TLFR files from other tools: ``test_io_tlfr.py``)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest
from io_cases import TLFR_FIELD_LINE, H, S, W, assert_same, make_buffer

from clrecon.io import (
    load_image,
    load_samples,
    save_image,
    save_samples,
    srgb_to_linear,
    tonemap_srgb,
)


# ------------------------------------------------------------------------------------------
# round trips
# ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("ext", [".npz", ".exr", ".bin", ".txt"])
def test_round_trip(tmp_path, ext):
    buf = make_buffer()
    path = tmp_path / f"frame{ext}"
    save_samples(path, buf)
    back = load_samples(str(path))
    # TLFR stores motion * w in float32: the division on load may land one ulp away
    assert_same(buf, back, motion_ulp=1 if ext in (".bin", ".txt") else 0)
    if ext in (".bin", ".txt"):
        header = Path(str(path) + ".header").read_text()
        assert f"Encoding = {'text' if ext == '.txt' else 'binary'}" in header
        assert "Version 1.3\n" in header and TLFR_FIELD_LINE in header
        size = path.stat().st_size
        if ext == ".bin":
            assert size == H * W * S * 64
        else:
            assert len(path.read_text().splitlines()) == H * W * S


def test_tlfr_explicit_encoding_overrides_extension(tmp_path):
    buf = make_buffer(seed=1)
    path = tmp_path / "frame.bin"
    save_samples(path, buf, encoding="text")
    assert "Encoding = text" in Path(str(path) + ".header").read_text()
    assert_same(buf, load_samples(path), motion_ulp=1)
    with pytest.raises(ValueError, match="encoding"):
        save_samples(tmp_path / "f.bin", buf, encoding="ascii")
    with pytest.raises(ValueError, match="encoding"):
        save_samples(tmp_path / "f.npz", buf, encoding="text")


def test_tlfr_static_frame_stays_static_and_miss_motion_dropped(tmp_path):
    buf = make_buffer(seed=2)
    buf.motion[:] = 0.0
    path = tmp_path / "static.bin"
    save_samples(path, buf)
    back = load_samples(path)
    assert not back.motion.any()
    assert not back.inspect().has_motion
    # motion of a miss is not representable in TLFR: it loads as zero
    miss = np.isinf(buf.depth)
    buf.motion[miss] = 3.0
    save_samples(path, buf)
    back = load_samples(path)
    assert not back.motion.any()


def test_tlfr_file_columns(tmp_path):
    buf = make_buffer(seed=3)
    path = tmp_path / "frame.bin"
    save_samples(path, buf)
    rec = np.fromfile(path, "<f4").reshape(H, W, S, 16)
    hit = np.isfinite(buf.depth)
    np.testing.assert_array_equal(rec[..., 0:2], buf.position)
    np.testing.assert_array_equal(rec[..., 3], buf.depth)
    np.testing.assert_array_equal(rec[..., 10], 1.0)
    np.testing.assert_array_equal(rec[..., 13:16], 0.0)
    np.testing.assert_array_equal(rec[~hit][:, 2], 1.0)
    zw = rec[hit][:, 2]
    assert np.all((zw > 0) & (zw < 1))
    np.testing.assert_allclose(rec[hit][:, 11:13], buf.motion[hit] * buf.depth[hit][:, None],
                               rtol=1e-6)
    np.testing.assert_array_equal(rec[~hit][:, 11:14], 0.0)



# ------------------------------------------------------------------------------------------
# EXR / npz / dispatch errors
# ------------------------------------------------------------------------------------------
def test_exr_layout(tmp_path):
    buf = make_buffer(s=2)
    path = tmp_path / "s.exr"
    save_samples(path, buf)
    inp = oiio.ImageInput.open(str(path))
    spec = inp.spec()
    inp.close()
    assert spec.format == oiio.TypeDesc("float")
    assert spec.nchannels == 22 and "s1.MY" in spec.channelnames
    assert spec.getattribute("clrecon:format") == "samples"
    assert spec.getattribute("clrecon:spp") == 2


def test_exr_without_clrecon_attributes(tmp_path):
    path = tmp_path / "plain.exr"
    save_image(path, np.ones((3, 4, 3), np.float32))
    with pytest.raises(ValueError, match="clrecon:format"):
        load_samples(path)


def test_exr_missing_channel(tmp_path):
    path = tmp_path / "short.exr"
    spec = oiio.ImageSpec(2, 2, 10, "float")
    spec.channelnames = tuple(f"s0.{c}" for c in ("R", "G", "B", "X", "Y", "Z", "U", "V", "T",
                                                   "MX"))
    spec.attribute("clrecon:format", "samples")
    spec.attribute("clrecon:spp", 1)
    spec.attribute("clrecon:coc_c0", "0.0")
    spec.attribute("clrecon:coc_c1", "0.0")
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec)
    assert out.write_image(np.zeros((2, 2, 10), np.float32))
    out.close()
    with pytest.raises(ValueError, match="s0.MY"):
        load_samples(path)


def test_corrupt_exr_raises_oserror(tmp_path):
    path = tmp_path / "junk.exr"
    path.write_bytes(b"not an exr file at all")
    with pytest.raises(OSError, match="junk.exr"):
        load_samples(path)


def test_npz_missing_key(tmp_path):
    buf = make_buffer()
    path = tmp_path / "m.npz"
    arrays = buf.arrays()
    del arrays["lens"]
    np.savez(path, **arrays, coc=np.zeros(2), format_version=1)
    with pytest.raises(ValueError, match="lens"):
        load_samples(path)


def test_npz_upper_case_extension(tmp_path):
    buf = make_buffer()
    path = tmp_path / "m.NPZ"
    save_samples(path, buf)
    assert path.exists()
    assert_same(buf, load_samples(path))


def test_unknown_extension(tmp_path):
    with pytest.raises(ValueError, match=r"\.bin, \.txt, \.exr, \.npz"):
        load_samples(tmp_path / "f.dat")
    with pytest.raises(ValueError, match=r"\.foo"):
        save_samples(tmp_path / "f.foo", make_buffer())
    with pytest.raises(ValueError, match=r"\.exr, \.png"):
        save_image(tmp_path / "f.jpg", np.zeros((2, 2, 3)))


def test_missing_files_and_directories(tmp_path):
    with pytest.raises(FileNotFoundError, match="nothere.exr"):
        load_samples(tmp_path / "nothere.exr")
    with pytest.raises(FileNotFoundError, match="nothere.npz"):
        load_samples(tmp_path / "nothere.npz")
    with pytest.raises(FileNotFoundError, match="nodir"):
        save_samples(tmp_path / "nodir" / "f.exr", make_buffer())
    with pytest.raises(FileNotFoundError, match="nodir"):
        save_image(tmp_path / "nodir" / "f.png", np.zeros((2, 2, 3)))


# ------------------------------------------------------------------------------------------
# images
# ------------------------------------------------------------------------------------------
def test_exr_image_round_trip_exact(tmp_path):
    rng = np.random.default_rng(6)
    img = (rng.uniform(0.0, 1.0, (6, 9, 3)) * 10.0 ** rng.uniform(-4, 4, (6, 9, 1)))
    img = img.astype(np.float32)
    img[0, 0] = 0.0
    img[1, 1] = [1e4, 3.5, 1.0]
    path = tmp_path / "img.exr"
    save_image(path, img)
    inp = oiio.ImageInput.open(str(path))
    assert inp.spec().format == oiio.TypeDesc("float")
    inp.close()
    back = load_image(path)
    assert back.dtype == np.float32 and back.shape == img.shape
    np.testing.assert_array_equal(back, img)


def test_png_round_trip(tmp_path):
    rng = np.random.default_rng(7)
    img = rng.uniform(0.0, 1.3, (6, 9, 3)).astype(np.float32)
    img[0, 0] = [0.0, 0.5, 1.0]
    path = tmp_path / "img.png"
    save_image(path, img)
    back = load_image(path)
    assert back.dtype == np.float32 and back.shape == img.shape
    assert np.abs(tonemap_srgb(back) - tonemap_srgb(img)).max() <= 0.5 / 255 + 1e-6
    np.testing.assert_allclose(back[0, 0], [0.0, 0.5, 1.0], atol=3e-3)


def test_image_shapes(tmp_path):
    grey = np.linspace(0.0, 2.0, 12, dtype=np.float32).reshape(3, 4)
    save_image(tmp_path / "g.exr", grey)
    back = load_image(tmp_path / "g.exr")
    np.testing.assert_array_equal(back, np.repeat(grey[:, :, None], 3, axis=2))
    rgba = np.random.default_rng(8).uniform(size=(3, 4, 4)).astype(np.float32)
    save_image(tmp_path / "a.exr", rgba)
    np.testing.assert_array_equal(load_image(tmp_path / "a.exr"), rgba[:, :, :3])
    for bad in (np.zeros((3, 4, 2)), np.zeros(5), np.zeros((2, 3, 4, 3))):
        with pytest.raises(ValueError, match="img"):
            save_image(tmp_path / "bad.exr", bad)


def test_tonemap_srgb():
    assert tonemap_srgb(0.0) == 0.0
    assert tonemap_srgb(1.0) == 1.0
    assert tonemap_srgb(0.5) == pytest.approx(0.7354, abs=1e-4)
    assert tonemap_srgb(0.002) == pytest.approx(0.002 * 12.92, rel=1e-6)
    x = np.linspace(-1.0, 3.0, 4001, dtype=np.float32)
    y = tonemap_srgb(x)
    assert y.dtype == np.float32 and y.shape == x.shape
    assert np.all(np.diff(y) >= 0)
    assert y.min() == 0.0 and y.max() == 1.0
    assert np.all(y[x >= 1.0] == 1.0) and np.all(y[x <= 0.0] == 0.0)
    inner = np.linspace(0.0, 1.0, 1001, dtype=np.float32)
    np.testing.assert_allclose(srgb_to_linear(tonemap_srgb(inner)), inner, atol=2e-6)
