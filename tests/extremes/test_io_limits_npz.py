"""Limits and hostile files of clrecon.io: NPZ archives.

Every member's ``.npy`` header and stored size are checked before anything is decompressed;
corrupt files, wrong dtypes and float32 overflow raise ``ValueError`` naming the file. A case
that could blow memory runs in a child process under ``RLIMIT_AS``.
"""
from __future__ import annotations

import io as _io
import math
import os
import zipfile
import zlib
from pathlib import Path

import numpy as np
import pytest
from io_cases import npy_bytes, run_limited, small_buffer

import clrecon.io.npz
from clrecon.core.samples import FIELDS, SampleBuffer
from clrecon.io import load_samples


# ------------------------------------------------------------------------------------------
# NPZ: headers and stored sizes first; corrupt files, wrong dtypes, float32 overflow
# ------------------------------------------------------------------------------------------
def npy_header(shape, descr="<f4") -> bytes:
    f = _io.BytesIO()
    np.lib.format.write_array_header_1_0(
        f, {"descr": descr, "fortran_order": False, "shape": tuple(shape)})
    return f.getvalue()


def write_npz(path: Path, members: dict, compression=zipfile.ZIP_STORED) -> None:
    """``members``: name -> array (saved as .npy) or raw bytes."""
    with zipfile.ZipFile(path, "w", compression) as zf:
        for name, value in members.items():
            data = value if isinstance(value, bytes) else npy_bytes(value)
            zf.writestr(name if "." in name else name + ".npy", data)


def npz_members(buf: SampleBuffer) -> dict:
    return {**buf.arrays(), "coc": np.array([buf.coc_model.c0, buf.coc_model.c1]),
            "format_version": np.int64(1)}


def test_npz_deflate_bomb_refused_before_decompressing(tmp_path):
    """color declares (4096, 8192, 1, 3) float32 (384 MiB) in a ~2 MB deflate stream while
    the other fields are (2, 2, 1): refused from the headers, nothing decompressed (the old
    loader decompressed it whole: MemoryError under a 200 MiB budget)."""
    path = tmp_path / "bomb.npz"
    members = npz_members(SampleBuffer.zeros(2, 2, 1))
    shape = (4096, 8192, 1, 3)
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED, compresslevel=1) as zf:
        for name, value in members.items():
            if name != "color":
                zf.writestr(name + ".npy", npy_bytes(value))
        with zf.open("color.npy", "w", force_zip64=True) as f:
            f.write(npy_header(shape))
            zero = bytes(2**24)
            for _ in range(math.prod(shape) * 4 // len(zero)):
                f.write(zero)
    assert path.stat().st_size < 8 * 2**20
    line = run_limited(f"report(lambda: cio.load_samples({str(path)!r}))", budget_mb=200)
    kind, msg = line.split("|", 1)
    assert kind == "ValueError", line
    assert "bomb.npz" in msg and "color" in msg and "(4096, 8192, 1, 3)" in msg, msg


def test_npz_consistent_shapes_beyond_the_limit(tmp_path):
    """Six headers that agree on 2**31 + 2**16 samples, no data: refused by the limit (the
    old loader allocated 25 GB for color first: MemoryError under a 200 MiB budget)."""
    shape = (2**16, 2**15 + 1, 1)
    members = {name: npy_header(shape + trail) for name, trail in FIELDS.items()}
    members.update(coc=np.zeros(2), format_version=np.int64(1))
    path = tmp_path / "huge.npz"
    write_npz(path, members)
    line = run_limited(f"report(lambda: cio.load_samples({str(path)!r}))", budget_mb=200)
    kind, msg = line.split("|", 1)
    assert kind == "ValueError", line
    assert "huge.npz" in msg and "2147549184 samples" in msg, msg
    assert "limit of 2147483648" in msg, msg


def test_npz_stored_size_must_match_header(tmp_path):
    members = npz_members(small_buffer())
    members["depth"] = npy_bytes(members["depth"]) + bytes(1000)  # trailing data
    path = tmp_path / "trail.npz"
    write_npz(path, members)
    with pytest.raises(ValueError, match=r"trail.npz.*depth.*1\d{3} bytes.*implies"):
        load_samples(path)
    members["depth"] = npy_bytes(small_buffer().depth)[:-8]  # short data
    write_npz(path, members)
    with pytest.raises(ValueError, match=r"trail.npz.*depth"):
        load_samples(path)


@pytest.mark.parametrize("name, shape", [
    ("color", (3, 4, 2)), ("lens", (3, 4, 3, 2)), ("time", (3, 5, 2)), ("depth", (3, 4)),
    ("motion", (3, 4, 2, 2, 1)), ("position", (3, 4, 2, 3)),
])
def test_npz_field_shapes_must_agree(tmp_path, name, shape):
    members = npz_members(small_buffer())
    members[name] = np.zeros(shape, np.float32)
    path = tmp_path / "shape.npz"
    write_npz(path, members)
    with pytest.raises(ValueError, match=rf"shape.npz.*{name}|shape.npz.*depth"):
        load_samples(path)


def test_npz_negative_dimension_in_header(tmp_path):
    members = npz_members(small_buffer())
    members["depth"] = npy_header((3, -4, 2))
    path = tmp_path / "neg.npz"
    write_npz(path, members)
    with pytest.raises(ValueError, match=r"neg.npz.*depth"):
        load_samples(path)


@pytest.mark.parametrize("how", ["truncated", "garbage", "empty", "crc", "deflate"])
def test_npz_corrupt_file_is_value_error(tmp_path, how):
    path = tmp_path / "bad.npz"
    members = npz_members(small_buffer())
    write_npz(path, members, zipfile.ZIP_DEFLATED if how == "deflate" else zipfile.ZIP_STORED)
    data = bytearray(path.read_bytes())
    if how == "truncated":
        data = data[: len(data) // 2]
    elif how == "garbage":
        data = bytearray(b"PK\x03\x04" + bytes(range(256)) * 4)
    elif how == "empty":
        data = bytearray()
    else:  # a byte inside the first member's data (stored: CRC; deflated: the stream)
        with zipfile.ZipFile(path) as zf:
            info = zf.infolist()[0]
        start = info.header_offset + 30 + len(info.filename.encode())
        data[start + info.compress_size // 2] ^= 0x5A
    path.write_bytes(bytes(data))
    with pytest.raises(ValueError, match="bad.npz"):
        load_samples(path)


def test_npy_renamed_npz(tmp_path):
    path = tmp_path / "single.npz"
    np.save(tmp_path / "single.npy", np.zeros((2, 2)))
    os.replace(tmp_path / "single.npy", path)
    with pytest.raises(ValueError, match=r"single.npz.*\.npy"):
        load_samples(path)


@pytest.mark.parametrize("value, match", [
    (np.array(["1", "2"]), "coc"),
    (np.array([1.0, 2.0, 3.0]), "coc"),
    (np.array([1 + 2j, 0]), "coc"),
])
def test_npz_bad_coc_names_the_field(tmp_path, value, match):
    members = npz_members(small_buffer())
    members["coc"] = value
    path = tmp_path / "coc.npz"
    write_npz(path, members)
    with pytest.raises(ValueError, match=rf"coc.npz.*{match}"):
        load_samples(path)


@pytest.mark.parametrize("value", [np.float64(1.5), np.int64(2), np.array([1]), np.array("1")])
def test_npz_bad_format_version(tmp_path, value):
    members = npz_members(small_buffer())
    members["format_version"] = value
    path = tmp_path / "ver.npz"
    write_npz(path, members)
    with pytest.raises(ValueError, match="format_version"):
        load_samples(path)


@pytest.mark.parametrize("name", ["depth", "color", "motion", "position", "lens", "time"])
def test_npz_float64_beyond_float32_is_refused(tmp_path, name):
    buf = small_buffer()
    members = npz_members(buf)
    arr = getattr(buf, name).astype(np.float64)
    arr[1, 2, 1] = 3.5e38  # finite in float64, inf in float32
    members[name] = arr
    path = tmp_path / "big.npz"
    write_npz(path, members)
    with pytest.raises(ValueError, match=rf"big.npz.*{name}.*y=1, x=2, i=1.*float32"):
        load_samples(path)


def test_npz_float64_inf_and_rounding_to_max_are_kept(tmp_path):
    buf = small_buffer()
    members = npz_members(buf)
    depth = buf.depth.astype(np.float64)
    depth[1, 1, 0] = np.inf  # a miss stays a miss
    depth[2, 3, 1] = 3.4028235e38  # rounds to float32's max: finite
    members["depth"] = depth
    members["color"] = buf.color.astype(">f8")  # big-endian float64
    members["lens"] = np.asfortranarray(buf.lens.astype(np.float16))
    path = tmp_path / "ok.npz"
    write_npz(path, members, zipfile.ZIP_DEFLATED)
    back = load_samples(path)
    assert np.isinf(back.depth[1, 1, 0]) and back.depth[2, 3, 1] == np.finfo(np.float32).max
    np.testing.assert_array_equal(back.color, buf.color)
    np.testing.assert_array_equal(back.lens, buf.lens.astype(np.float16).astype(np.float32))


@pytest.mark.parametrize("kind", ["object", "structured", "bool", "string"])
def test_npz_non_numeric_members_refused(tmp_path, kind):
    buf = small_buffer()
    members = npz_members(buf)
    if kind == "object":
        arr = np.empty(buf.depth.shape, object)
        arr[...] = 1.0
    elif kind == "structured":
        arr = np.zeros(buf.depth.shape, [("a", "<f4")])
    elif kind == "bool":
        arr = np.ones(buf.depth.shape, bool)
    else:
        arr = np.full(buf.depth.shape, "1.0")
    members["depth"] = arr
    path = tmp_path / "obj.npz"
    write_npz(path, members)
    with pytest.raises(ValueError, match=r"obj.npz.*depth"):
        load_samples(path)


def test_npz_unsupported_compression_refused(tmp_path):
    path = tmp_path / "bz.npz"
    write_npz(path, npz_members(small_buffer()), zipfile.ZIP_BZIP2)
    with pytest.raises(ValueError, match=r"bz.npz.*compression"):
        load_samples(path)


def test_npz_written_by_numpy_still_loads(tmp_path):
    buf = small_buffer()
    for saver in (np.savez, np.savez_compressed):
        path = tmp_path / "np.npz"
        saver(path, **npz_members(buf))
        back = load_samples(path)
        for name in FIELDS:
            np.testing.assert_array_equal(getattr(back, name), getattr(buf, name))
        assert back.coc_model == buf.coc_model


def test_npz_reads_no_member_data_before_all_headers_pass(tmp_path, monkeypatch):
    """A bad header of the last member is found before any member's data is read."""
    members = npz_members(small_buffer())
    members["motion"] = np.zeros((3, 4, 2, 3), np.float32)
    path = tmp_path / "order.npz"
    write_npz(path, members)
    read = []
    real = clrecon.io.npz._read_npy_data
    monkeypatch.setattr(clrecon.io.npz, "_read_npy_data",
                        lambda *a, **k: read.append(a) or real(*a, **k))
    with pytest.raises(ValueError, match="motion"):
        load_samples(path)
    assert read == []


def test_compressed_npz_bomb_bound(tmp_path):
    """A deflated member may not claim more than 1032x its compressed size (deflate's
    ceiling): a forged file_size is refused before anything is decompressed."""
    buf = small_buffer()
    path = tmp_path / "forged.npz"
    write_npz(path, npz_members(buf), zipfile.ZIP_DEFLATED)
    data = bytearray(path.read_bytes())
    with zipfile.ZipFile(path) as zf:
        info = zf.getinfo("depth.npy")
    # central directory entry of depth.npy (46 bytes, then the name): uncompressed size at 24
    entry = data.find(b"depth.npy", data.find(b"PK\x01\x02")) - 46
    assert data[entry:entry + 4] == b"PK\x01\x02"
    data[entry + 24:entry + 28] = (info.compress_size * 2000).to_bytes(4, "little")
    path.write_bytes(bytes(data))
    with pytest.raises(ValueError, match=r"forged.npz.*depth"):
        load_samples(path)


def test_zlib_ceiling_holds():
    """The 1032:1 ceiling the NPZ check relies on (zlib's documented maximum)."""
    data = bytes(2**22)
    assert len(data) / len(zlib.compress(data, 9)) < 1032
