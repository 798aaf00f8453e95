"""Tests of clrecon.io's TLFR loader on files written by hand, as another tool writes them:
motion conversion, the reference tool's text, header parsing and every kind of bad file."""
from __future__ import annotations

import time
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from io_cases import TLFR_FIELD_LINE, H, S, W, default_records, make_buffer, write_tlfr

from clrecon.core.camera import CocModel
from clrecon.io import load_samples, save_samples


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

