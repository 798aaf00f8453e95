"""Tests of clrecon.io: sample-buffer formats (TLFR, EXR, npz) and images."""
from __future__ import annotations

import time
import tracemalloc
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest

from clrecon.core.camera import CocModel
from clrecon.core.samples import FIELDS, SampleBuffer
from clrecon.io import (
    load_image,
    load_samples,
    save_image,
    save_samples,
    srgb_to_linear,
    tonemap_srgb,
)

H, W, S = 5, 7, 4
COC = CocModel(c0=-15.242497123456789, c1=19.053122987654321)  # not float32-representable
TLFR_FIELD_LINE = "x,y,z/w,w,u,v,t,r,g,b,a,mv_x,mv_y,mv_w,dwdx,dwdy"


def make_buffer(h=H, w=W, s=S, seed=0, coc=COC) -> SampleBuffer:
    """A random but valid buffer: HDR colour, misses with inf depth, motion in pixels."""
    rng = np.random.default_rng(seed)
    hws = (h, w, s)
    py, px = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    pos = np.stack([px, py], -1)[:, :, None, :] + rng.uniform(0.0, 1.0, hws + (2,))
    r = np.sqrt(rng.uniform(0.0, 1.0, hws))
    phi = rng.uniform(0.0, 2 * np.pi, hws)
    lens = np.stack([r * np.cos(phi), r * np.sin(phi)], -1)
    depth = np.exp(rng.uniform(np.log(0.3), np.log(200.0), hws))
    miss = rng.uniform(size=hws) < 0.2
    depth[miss] = np.inf
    color = rng.uniform(0.0, 1.0, hws + (3,)) * 10.0 ** rng.uniform(-3, 4, hws + (1,))
    motion = rng.normal(0.0, 6.0, hws + (2,))
    motion[miss] = 0.0  # TLFR stores no motion for misses
    buf = SampleBuffer(color=color, position=pos, depth=depth, lens=lens,
                       time=rng.uniform(0.0, 1.0, hws), motion=motion, coc_model=coc)
    assert np.isinf(buf.depth).any() and buf.color.max() > 1e3
    return buf.validate()


def write_tlfr(path: Path, records: np.ndarray, w: int, h: int, s: int, *, c0=-2.0, c1=1.0,
               encoding="binary", header_lines=None) -> None:
    """Write a TLFR 1.3 pair by hand, as another tool would (independent of clrecon.io)."""
    if header_lines is None:
        header_lines = [
            "Version 1.3", f"Width {w}", f"Height {h}", f"Samples per pixel {s}",
            "Motion model: perspective",
            f"CoC coefficients (coc radius = C0/w+C1): {c0:f},{c1:f}",
            f"Encoding = {encoding}", TLFR_FIELD_LINE,
        ]
    Path(str(path) + ".header").write_text("\n".join(header_lines) + "\n")
    records = np.asarray(records, np.float32).reshape(-1, 16)
    if encoding == "binary":
        Path(path).write_bytes(records.astype("<f4").tobytes())
    else:  # the reference writer: "%f," for every value, including the last
        Path(path).write_text("".join(", ".join(f"{v:f}" for v in rec) + ",\n"
                                      for rec in records))


def default_records(w: int, h: int, s: int) -> np.ndarray:
    """Valid static records at pixel centres: (h, w, s, 16)."""
    rec = np.zeros((h, w, s, 16), np.float32)
    py, px = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    rec[..., 0] = (px + 0.5)[:, :, None]
    rec[..., 1] = (py + 0.5)[:, :, None]
    rec[..., 2] = 0.5
    rec[..., 3] = 2.0
    rec[..., 6] = 0.5
    rec[..., 7:11] = 0.25
    return rec


def assert_same(a: SampleBuffer, b: SampleBuffer, *, motion_ulp: int = 0) -> None:
    assert a.coc_model == b.coc_model
    for name in FIELDS:
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype == np.float32 and x.shape == y.shape, name
        if name == "motion" and motion_ulp:
            np.testing.assert_array_max_ulp(x, y, maxulp=motion_ulp)
        else:
            np.testing.assert_array_equal(x, y, err_msg=name)


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
# TLFR written by another tool
# ------------------------------------------------------------------------------------------
def test_tlfr_affine_motion_is_mv_over_w(tmp_path):
    w, h, s = 3, 2, 2
    rng = np.random.default_rng(4)
    rec = default_records(w, h, s)
    rec[..., 3] = rng.uniform(0.5, 50.0, (h, w, s))
    rec[..., 11:13] = rng.normal(0.0, 20.0, (h, w, s, 2))
    rec[..., 6] = rng.uniform(0.0, 1.0, (h, w, s))
    path = tmp_path / "affine.bin"
    write_tlfr(path, rec, w, h, s)
    buf = load_samples(path)
    expected = rec[..., 11:13].astype(np.float64) / rec[..., 3:4].astype(np.float64)
    np.testing.assert_allclose(buf.motion, expected, rtol=1e-6)
    assert buf.coc_model == CocModel(-2.0, 1.0)
    np.testing.assert_array_equal(buf.depth, rec[..., 3])
    np.testing.assert_array_equal(buf.color, rec[..., 7:10])


def test_tlfr_perspective_motion(tmp_path):
    w, h, s = 4, 2, 1
    c0, c1 = -2.0, 1.0
    rec = default_records(w, h, s)
    x, y, depth, u, v, t = 3.25, 1.5, 4.0, 0.5, -0.25, 0.25
    vx, vy, vw = 8.0, -4.0, 2.0
    rec[1, 3, 0, [0, 1, 3, 4, 5, 6]] = [x, y, depth, u, v, t]
    rec[1, 3, 0, 11:14] = [vx, vy, vw]
    path = tmp_path / "persp.bin"
    write_tlfr(path, rec, w, h, s, c0=c0, c1=c1)
    buf = load_samples(path)
    # by hand: lens-centre position, its homogeneous form, pinhole images at t=0 and t=1
    coc = c0 / depth + c1  # 0.5
    cx, cy = x - coc * u, y - coc * v  # (3.0, 1.625)
    hx, hy = cx * depth, cy * depth  # (12.0, 6.5)
    p0 = ((hx - t * vx) / (depth - t * vw), (hy - t * vy) / (depth - t * vw))
    w1 = depth + (1 - t) * vw
    p1 = ((hx + (1 - t) * vx) / w1, (hy + (1 - t) * vy) / w1)
    expected = (p1[0] - p0[0], p1[1] - p0[1])
    np.testing.assert_allclose(expected, (18 / 5.5 - 10 / 3.5, 3.5 / 5.5 - 7.5 / 3.5))
    np.testing.assert_allclose(buf.motion[1, 3, 0], expected, rtol=1e-6)
    # every other (static) record has exactly zero motion
    others = np.ones((h, w, s), bool)
    others[1, 3, 0] = False
    assert not buf.motion[others].any()


def test_tlfr_motion_crossing_camera_plane_raises(tmp_path):
    w, h, s = 4, 2, 1
    rec = default_records(w, h, s)
    rec[1, 3, 0, [3, 6]] = [4.0, 0.25]
    rec[1, 3, 0, 11:14] = [1.0, 1.0, -10.0]  # w(1) = 4 + 0.75 * -10 < 0
    path = tmp_path / "cross.bin"
    write_tlfr(path, rec, w, h, s)
    with pytest.raises(ValueError, match=r"y=1, x=3, i=0.*camera plane"):
        load_samples(path)


def test_tlfr_text_written_by_reference_tool(tmp_path):
    w, h, s = 3, 2, 2
    rng = np.random.default_rng(5)
    rec = default_records(w, h, s)
    rec[..., 0:2] += rng.uniform(-0.4, 0.4, (h, w, s, 2))
    rec[..., 4:6] = rng.uniform(-0.7, 0.7, (h, w, s, 2))
    rec[..., 7:10] = rng.uniform(0.0, 100.0, (h, w, s, 3))
    rec[..., 11:13] = rng.normal(0.0, 5.0, (h, w, s, 2))
    path = tmp_path / "ref.txt"
    write_tlfr(path, rec, w, h, s, encoding="text",
               header_lines=[  # the reference writer omits "Motion model"; loose spacing
                   "Version 1.3", "Width   3", "Height 2 ", "  Samples per pixel 2",
                   "CoC coefficients (coc radius = C0/w+C1): -2.000000,1.000000",
                   "Encoding = text", "", TLFR_FIELD_LINE])
    assert path.read_text().splitlines()[0].endswith(",")
    buf = load_samples(path)
    assert buf.shape == (h, w, s)
    np.testing.assert_allclose(buf.position, rec[..., 0:2], atol=1e-6)
    np.testing.assert_allclose(buf.lens, rec[..., 4:6], atol=1e-6)
    np.testing.assert_allclose(buf.color, rec[..., 7:10], atol=1e-5)
    np.testing.assert_allclose(buf.motion, rec[..., 11:13] / 2.0, atol=1e-6)


def test_tlfr_header_key_order_is_free(tmp_path):
    w, h, s = 2, 2, 1
    path = tmp_path / "order.bin"
    write_tlfr(path, default_records(w, h, s), w, h, s, header_lines=[
        TLFR_FIELD_LINE, "Encoding = binary", "Samples per pixel 1", "Height 2", "Width 2",
        "CoC coefficients (coc radius = C0/w+C1): 0.5,-0.25", "Version 1.3"])
    assert load_samples(path).coc_model == CocModel(0.5, -0.25)


# ------------------------------------------------------------------------------------------
# TLFR errors
# ------------------------------------------------------------------------------------------
def test_truncated_binary(tmp_path):
    path = tmp_path / "f.bin"
    save_samples(path, make_buffer())
    path.write_bytes(path.read_bytes()[:-10])
    with pytest.raises(ValueError, match=rf"{H * W * S * 64 - 10} bytes.*{H * W * S * 64} bytes"):
        load_samples(path)


@pytest.mark.parametrize("size", [(100000, 100000, 16), (20000, 20000, 4)])
def test_huge_header_over_tiny_file_fails_fast(tmp_path, size):
    w, h, s = size
    path = tmp_path / "huge.bin"
    write_tlfr(path, default_records(1, 1, 1), w, h, s)
    assert path.stat().st_size == 64
    tracemalloc.start()
    try:
        start = time.perf_counter()
        with pytest.raises(ValueError, match="bytes"):
            load_samples(path)
        elapsed = time.perf_counter() - start
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 10 * 2**20
    assert elapsed < 1.0


def test_huge_header_over_tiny_text_file(tmp_path):
    path = tmp_path / "huge.txt"
    write_tlfr(path, default_records(1, 1, 1), 100000, 100000, 16, encoding="text")
    with pytest.raises(ValueError, match="too small"):
        load_samples(path)


def _text_file(tmp_path, edit) -> Path:
    w, h, s = 3, 2, 2
    path = tmp_path / "t.txt"
    write_tlfr(path, default_records(w, h, s), w, h, s, encoding="text")
    lines = path.read_text().splitlines()
    path.write_text("\n".join(edit(lines)) + "\n")
    return path


def test_text_missing_line(tmp_path):
    path = _text_file(tmp_path, lambda lines: lines[:-1])
    with pytest.raises(ValueError, match=r"line 12 is missing"):
        load_samples(path)


def test_text_extra_line(tmp_path):
    path = _text_file(tmp_path, lambda lines: lines + lines[:1])
    with pytest.raises(ValueError, match=r"line 13"):
        load_samples(path)


def test_text_line_with_15_fields(tmp_path):
    def edit(lines):
        lines[2] = ",".join(lines[2].rstrip(",").split(",")[:15])
        return lines
    path = _text_file(tmp_path, edit)
    with pytest.raises(ValueError, match=r"line 3: expected 16 .*found 15"):
        load_samples(path)


def test_text_line_with_garbage(tmp_path):
    def edit(lines):
        lines[4] = lines[4].replace("0.500000", "abc", 1)
        return lines
    path = _text_file(tmp_path, edit)
    with pytest.raises(ValueError, match=r"line 5: .*'abc' is not a number"):
        load_samples(path)


HEADER = ["Version 1.3", "Width 2", "Height 2", "Samples per pixel 1",
          "Motion model: perspective", "CoC coefficients (coc radius = C0/w+C1): 0,0",
          "Encoding = binary", TLFR_FIELD_LINE]


@pytest.mark.parametrize("index, line, match", [
    (2, None, "'Height'.*missing"),
    (5, None, "'CoC coefficients'.*missing"),
    (6, None, "'Encoding'.*missing"),
    (0, "Version 1.2", "'Version'.*1.2"),
    (1, "Width 2.5", "'Width'.*integer"),
    (3, "Samples per pixel 0", "'Samples per pixel'.*positive"),
    (6, "Encoding = ascii", "'Encoding'.*ascii"),
    (4, "Motion model: affine", "'Motion model'.*affine"),
    (5, "CoC coefficients (coc radius = C0/w+C1): 1", "'CoC coefficients'"),
    (7, "x,y,w,u,v,t,r,g,b", "field names"),
    (7, "Pixel-to-camera matrix: 1,0", "unrecognised"),
])
def test_bad_header(tmp_path, index, line, match):
    lines = list(HEADER)
    if line is None:
        del lines[index]
    else:
        lines[index] = line
    path = tmp_path / "h.bin"
    write_tlfr(path, default_records(2, 2, 1), 2, 2, 1, header_lines=lines)
    with pytest.raises(ValueError, match=match) as info:
        load_samples(path)
    assert "h.bin.header" in str(info.value)


def test_missing_header(tmp_path):
    path = tmp_path / "nohdr.bin"
    path.write_bytes(b"\0" * 64)
    with pytest.raises(FileNotFoundError, match=r"nohdr\.bin\.header"):
        load_samples(path)


def test_lens_outside_disk_names_lens(tmp_path):
    w, h, s = 2, 2, 2
    rec = default_records(w, h, s)
    rec[1, 0, 1, 4:6] = [0.9, 0.9]
    path = tmp_path / "lens.bin"
    write_tlfr(path, rec, w, h, s)
    with pytest.raises(ValueError, match=r"lens: sample \(y=1, x=0, i=1\)"):
        load_samples(path)


def test_save_validates_first(tmp_path):
    buf = make_buffer()
    buf.time[0, 0, 0] = 2.0
    for ext in (".bin", ".exr", ".npz"):
        with pytest.raises(ValueError, match="time"):
            save_samples(tmp_path / f"bad{ext}", buf)
        assert not (tmp_path / f"bad{ext}").exists()


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
