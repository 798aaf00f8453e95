"""Limits, hostile files and safe writes of clrecon.io.

Every loader states and enforces its limits before it allocates anything sized by the file
(EXR: ``clrecon:spp`` against the channel count, samples against a limit; NPZ: every
member's ``.npy`` header and stored size before anything is decompressed; text TLFR: parsed
in bounded chunks), a malformed file raises ``ValueError`` naming the file, and every file
the library writes appears atomically (temp file in the same folder, then ``os.replace``).
A case that could blow memory runs in a child process under ``RLIMIT_AS``.
"""
from __future__ import annotations

import io as _io
import math
import os
import subprocess
import sys
import textwrap
import tracemalloc
import zipfile
import zlib
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest

import clrecon.io as cio
from clrecon.core.camera import CocModel
from clrecon.core.samples import FIELDS, SampleBuffer
from clrecon.io import EXR_SAMPLE_CHANNELS, load_image, load_samples, save_image, save_samples

ROOT = Path(__file__).resolve().parents[2]


def small_buffer(h=3, w=4, s=2, seed=0) -> SampleBuffer:
    rng = np.random.default_rng(seed)
    buf = SampleBuffer.zeros(h, w, s, CocModel(-2.0, 1.0))
    buf.color[:] = rng.uniform(0, 4, buf.color.shape)
    buf.depth[:] = rng.uniform(0.5, 50, buf.depth.shape)
    buf.depth[0, 0, 0] = np.inf
    buf.motion[:] = rng.normal(0, 2, buf.motion.shape)
    buf.motion[0, 0, 0] = 0.0
    buf.time[:] = rng.uniform(0, 1, buf.time.shape)
    return buf.validate()


def run_limited(body: str, budget_mb: int = 200, timeout: float = 120) -> str:
    """Run ``body`` in a child whose address space may grow ``budget_mb`` beyond what its
    imports took; return its stdout (the body prints one result line)."""
    prelude = textwrap.dedent(f"""
        import re, resource, sys
        import numpy as np
        import OpenImageIO as oiio
        import clrecon.io as cio
        oiio.attribute("threads", 1)
        oiio.attribute("exr_threads", 1)
        status = open("/proc/self/status").read()
        vm = int(re.search(r"VmSize:\\s+(\\d+)", status).group(1)) * 1024
        limit = vm + {budget_mb} * 2**20
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
        def report(fn):
            try:
                fn()
            except BaseException as exc:  # the parent judges the type
                print(f"{{type(exc).__name__}}|{{exc}}")
            else:
                print("loaded|")
        """)
    env = dict(os.environ, MALLOC_ARENA_MAX="2", OMP_NUM_THREADS="1")
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")])
    proc = subprocess.run([sys.executable, "-c", prelude + textwrap.dedent(body)],
                          capture_output=True, text=True, timeout=timeout, env=env)
    assert proc.returncode == 0, f"child died ({proc.returncode}): {proc.stderr[-2000:]}"
    return proc.stdout.strip().splitlines()[-1]


def write_exr(path: Path, channels, attrs: dict, w=4, h=3, data=None) -> None:
    spec = oiio.ImageSpec(w, h, len(channels), "float")
    spec.channelnames = tuple(channels)
    for key, value in attrs.items():
        if isinstance(value, tuple):
            spec.attribute(key, oiio.TypeDesc(f"int[{len(value)}]"), value)
        else:
            spec.attribute(key, value)
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec), out.geterror()
    pixels = np.zeros((h, w, len(channels)), np.float32) if data is None else data
    assert out.write_image(pixels), out.geterror()
    out.close()


def exr_channels(spp: int) -> list[str]:
    return [f"s{i}.{c}" for i in range(spp) for c in EXR_SAMPLE_CHANNELS]


def exr_attrs(spp) -> dict:
    return {"clrecon:format": "samples", "clrecon:spp": spp, "clrecon:coc_c0": "0.0",
            "clrecon:coc_c1": "0.0"}


# ------------------------------------------------------------------------------------------
# 1. EXR: clrecon:spp against the channel count, before anything is built from it
# ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("spp", [2147483647, "1099511627776"])
def test_exr_absurd_spp_refused_before_allocating(tmp_path, spp):
    """The old loader built the 11 * spp expected channel names first (5.6 GB for
    2**31 - 1): MemoryError under a 300 MiB budget."""
    path = tmp_path / "absurd.exr"
    write_exr(path, exr_channels(2), exr_attrs(spp))
    line = run_limited(f"report(lambda: cio.load_samples({str(path)!r}))", budget_mb=300)
    kind, msg = line.split("|", 1)
    assert kind == "ValueError", line
    assert "absurd.exr" in msg and str(spp) in msg and "22" in msg, msg
    assert str(11 * int(spp)) in msg, msg


@pytest.mark.parametrize("spp, match", [
    (0, "positive"), (-1, "positive"), (3, r"22 channels.*3.*33"), (1, r"22 channels.*1.*11"),
    ("abc", "clrecon:spp"), (2.5, "clrecon:spp"), ("2.0", "clrecon:spp"),
    (float("inf"), "clrecon:spp"), (float("nan"), "clrecon:spp"), ((1, 2), "clrecon:spp"),
])
def test_exr_bad_spp(tmp_path, spp, match):
    path = tmp_path / "bad.exr"
    attrs = exr_attrs(2)
    attrs["clrecon:spp"] = spp
    write_exr(path, exr_channels(2), attrs)
    with pytest.raises(ValueError, match=match) as info:
        load_samples(path)
    assert "bad.exr" in str(info.value)


def test_exr_string_spp_and_reordered_channels_load(tmp_path):
    """A string spp that is an integer is accepted; channels are found by name."""
    buf = small_buffer()
    path = tmp_path / "ok.exr"
    save_samples(path, buf)
    inp = oiio.ImageInput.open(str(path))
    pixels = inp.read_image(0, 0, 0, 22, "float")
    names = list(inp.spec().channelnames)
    inp.close()
    order = list(range(22))[::-1]
    write_exr(path, [names[k] for k in order], {**exr_attrs("2"),
              "clrecon:coc_c0": "-2.0", "clrecon:coc_c1": "1.0"}, data=pixels[..., order].copy())
    back = load_samples(path)
    for name in FIELDS:
        np.testing.assert_array_equal(getattr(back, name), getattr(buf, name))


def test_exr_duplicate_channel_names_refused(tmp_path):
    path = tmp_path / "dup.exr"
    names = exr_channels(1)
    names[-1] = names[0]
    write_exr(path, names, exr_attrs(1))
    with pytest.raises(ValueError, match="dup.exr"):
        load_samples(path)


def test_exr_sample_limit_checked_before_reading(tmp_path, monkeypatch):
    path = tmp_path / "big.exr"
    write_exr(path, exr_channels(2), exr_attrs(2))
    monkeypatch.setattr(cio, "EXR_MAX_SAMPLES", 23)  # 4 x 3 x 2 = 24 samples
    with pytest.raises(ValueError, match=r"big.exr.*24 samples.*limit of 23"):
        load_samples(path)


def test_unreadable_exr_is_value_error_naming_the_file(tmp_path):
    path = tmp_path / "junk.exr"
    path.write_bytes(b"not an exr file at all")
    with pytest.raises(ValueError, match="junk.exr") as info:
        load_samples(path)
    assert isinstance(info.value, OSError)  # still an OSError, as documented before
    with pytest.raises(ValueError, match="junk.exr"):
        load_image(path)


def test_truncated_exr_is_value_error(tmp_path):
    path = tmp_path / "cut.exr"
    save_samples(path, small_buffer())
    data = path.read_bytes()
    path.write_bytes(data[: len(data) - 40])
    with pytest.raises(ValueError, match="cut.exr"):
        load_samples(path)


# ------------------------------------------------------------------------------------------
# 2. NPZ: headers and stored sizes first; corrupt files, wrong dtypes, float32 overflow
# ------------------------------------------------------------------------------------------
def npy_bytes(arr: np.ndarray) -> bytes:
    f = _io.BytesIO()
    np.lib.format.write_array(f, np.asanyarray(arr), allow_pickle=True)
    return f.getvalue()


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
    real = cio._read_npy_data
    monkeypatch.setattr(cio, "_read_npy_data", lambda *a, **k: read.append(a) or real(*a, **k))
    with pytest.raises(ValueError, match="motion"):
        load_samples(path)
    assert read == []


# ------------------------------------------------------------------------------------------
# 3. text TLFR: parsed in bounded chunks
# ------------------------------------------------------------------------------------------
def test_text_tlfr_peak_memory_is_output_plus_a_chunk(tmp_path):
    buf = small_buffer(h=100, w=150, s=8, seed=3)  # 120000 records
    path = tmp_path / "big.txt"
    save_samples(path, buf)
    size = path.stat().st_size
    n = buf.depth.size
    tracemalloc.start()
    try:
        back = load_samples(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    np.testing.assert_array_max_ulp(back.motion, buf.motion, maxulp=1)
    records, fields = 64 * n, 44 * n
    # the (n, 16) float32 records, the buffer's fields, one chunk of text and its parse
    # (1 MiB of text: ~1 MiB of str, ~1 MiB of float64 values); the whole-file parse
    # took ~22 MiB beyond records + fields here (2.6x the file), and grew with the file
    assert peak < records + fields + 6 * 2**20, (peak, records + fields, size)


def test_text_tlfr_chunk_boundaries(tmp_path, monkeypatch):
    """Small chunks of many sizes, so that chunk ends fall everywhere (between CR and LF
    too): CRLF and CR line ends, trailing commas and trailing blank lines all still parse."""
    buf = small_buffer()
    path = tmp_path / "t.txt"
    save_samples(path, buf)
    text = path.read_text()
    longest = max(len(line) for line in text.splitlines()) + 4
    for variant in (text, text.replace("\n", "\r\n"), text.replace("\n", "\r"),
                    text.replace("\n", ",\n"), text + "\n\n  \n", text.replace("\n", ", \r\n")):
        path.write_bytes(variant.encode())
        for size in range(longest, longest + 40, 3):
            monkeypatch.setattr(cio, "_TLFR_TEXT_READ", size)
            back = load_samples(path)
            np.testing.assert_array_equal(back.depth, buf.depth)
            np.testing.assert_array_max_ulp(back.motion, buf.motion, maxulp=1)
    monkeypatch.setattr(cio, "_TLFR_TEXT_READ", longest)
    lines = text.splitlines()
    path.write_text("\n".join(lines[:5] + [""] + lines[5:]) + "\n")
    with pytest.raises(ValueError, match="line 6 is empty"):
        load_samples(path)
    path.write_text("\n".join(lines[:-1]) + "\n\n\n")
    with pytest.raises(ValueError, match=f"line {len(lines)} is missing"):
        load_samples(path)
    path.write_text("\n".join(lines + ["", lines[0]]) + "\n")
    with pytest.raises(ValueError, match=f"line {len(lines) + 1}: unexpected data"):
        load_samples(path)


def test_text_tlfr_line_too_long(tmp_path, monkeypatch):
    buf = small_buffer()
    path = tmp_path / "long.txt"
    save_samples(path, buf)
    lines = path.read_text().splitlines()
    lines[3] = lines[3] + " " * 5000
    path.write_text("\n".join(lines) + "\n")
    monkeypatch.setattr(cio, "_TLFR_TEXT_READ", 1024)
    with pytest.raises(ValueError, match=r"long.txt: line 4: longer than"):
        load_samples(path)


def test_text_tlfr_value_beyond_float32(tmp_path):
    buf = small_buffer()
    path = tmp_path / "o.txt"
    save_samples(path, buf)
    lines = path.read_text().splitlines()
    values = lines[5].split(",")
    values[3] = "1e39"
    lines[5] = ",".join(values)
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(ValueError, match=r"o.txt: line 6: value 4 \(w\) '1e39'.*float32"):
        load_samples(path)


def test_text_tlfr_non_ascii(tmp_path):
    buf = small_buffer()
    path = tmp_path / "u.txt"
    save_samples(path, buf)
    path.write_bytes(path.read_bytes().replace(b"0", "\u00e9".encode(), 1))
    with pytest.raises(ValueError, match="not ASCII"):
        load_samples(path)


def test_tlfr_motion_in_blocks_matches_whole(monkeypatch):
    rng = np.random.default_rng(9)
    h, w, s = 7, 5, 3
    rec = np.zeros((h, w, s, 16), np.float32)
    rec[..., 3] = rng.uniform(1, 10, (h, w, s))
    rec[..., 6] = rng.uniform(0, 1, (h, w, s))
    rec[..., 11:14] = rng.normal(0, 0.3, (h, w, s, 3))
    rec[0, 1, 2, 3] = np.inf
    model = CocModel(-2.0, 1.0)
    whole = cio._tlfr_motion(rec, model, "<r>")
    monkeypatch.setattr(cio, "_TLFR_MOTION_BLOCK", 4)
    np.testing.assert_array_equal(cio._tlfr_motion(rec, model, "<r>"), whole)
    rec[5, 2, 1, 13] = -100.0  # the first crossing in C order is reported
    rec[6, 4, 0, 13] = -100.0
    with pytest.raises(ValueError, match=r"y=5, x=2, i=1.*camera plane"):
        cio._tlfr_motion(rec, model, "<r>")


# ------------------------------------------------------------------------------------------
# 4. safe writes: temp file in the same folder, then os.replace
# ------------------------------------------------------------------------------------------
def listing(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()}


SAMPLE_FILES = {".bin": ["f.bin", "f.bin.header"], ".txt": ["f.txt", "f.txt.header"],
                ".exr": ["f.exr"], ".npz": ["f.npz"]}


@pytest.mark.parametrize("ext", list(SAMPLE_FILES))
def test_save_samples_leaves_only_its_files(tmp_path, ext):
    save_samples(tmp_path / f"f{ext}", small_buffer())
    assert sorted(listing(tmp_path)) == SAMPLE_FILES[ext]
    umask = os.umask(0)
    os.umask(umask)
    for name in SAMPLE_FILES[ext]:
        assert (tmp_path / name).stat().st_mode & 0o777 == 0o666 & ~umask


def fail_last_rename(monkeypatch, renames: int) -> None:
    """Make the ``renames``-th os.replace from now on (the last of a save) fail."""
    real = os.replace
    calls = []

    def replace(src, dst):
        calls.append(dst)
        if len(calls) == renames:
            raise OSError(28, "injected: no space left")
        return real(src, dst)
    monkeypatch.setattr(os, "replace", replace)


@pytest.mark.parametrize("ext", list(SAMPLE_FILES))
def test_failed_rename_keeps_the_old_files(tmp_path, ext, monkeypatch):
    """For a TLFR pair the header's rename fails after the data's: the data is restored
    (or, where there was none, removed)."""
    fail_last_rename(monkeypatch, len(SAMPLE_FILES[ext]))
    with pytest.raises(OSError, match="injected"):
        save_samples(tmp_path / f"f{ext}", small_buffer(seed=1))
    assert listing(tmp_path) == {}
    monkeypatch.undo()
    save_samples(tmp_path / f"f{ext}", small_buffer(seed=1))
    before = listing(tmp_path)
    fail_last_rename(monkeypatch, len(SAMPLE_FILES[ext]))
    with pytest.raises(OSError, match="injected"):
        save_samples(tmp_path / f"f{ext}", small_buffer(seed=2))
    monkeypatch.undo()
    assert listing(tmp_path) == before
    assert load_samples(tmp_path / f"f{ext}").shape == small_buffer().shape


def test_tlfr_pair_restored_without_hard_links(tmp_path, monkeypatch):
    """Where hard links fail, the old data file is moved aside and moved back."""
    path = tmp_path / "f.bin"
    save_samples(path, small_buffer(seed=1))
    before = listing(tmp_path)

    def no_link(src, dst):
        raise OSError(1, "links not supported")
    monkeypatch.setattr(os, "link", no_link)
    fail_last_rename(monkeypatch, 3)  # the move aside, the data, then the header
    with pytest.raises(OSError, match="injected"):
        save_samples(path, small_buffer(seed=2))
    monkeypatch.undo()
    assert listing(tmp_path) == before


def inject_write_failure(monkeypatch, ext: str) -> None:
    """Make the next save of ``ext`` fail half-way through writing its data."""
    def boom():
        raise OSError(5, "injected: write failed")

    if ext == ".exr":
        real = cio._oiio_write

        def partial(path, *args):
            real(path, *args)
            Path(path).write_bytes(Path(path).read_bytes()[:100])
            boom()
        monkeypatch.setattr(cio, "_oiio_write", partial)
    elif ext == ".npz":
        real_savez = np.savez

        def savez(f, **arrays):
            real_savez(f, **arrays)
            boom()
        monkeypatch.setattr(np, "savez", savez)
    else:
        real_data = cio._write_tlfr_data

        def data(f, records, encoding):
            real_data(f, records[: len(records) // 2], encoding)
            boom()
        monkeypatch.setattr(cio, "_write_tlfr_data", data)


@pytest.mark.parametrize("ext", list(SAMPLE_FILES))
def test_failed_write_leaves_nothing_new(tmp_path, ext, monkeypatch):
    """A failure in the middle of writing the data: no temp left, no file created, an
    existing file (pair) untouched."""
    inject_write_failure(monkeypatch, ext)
    with pytest.raises(OSError, match="injected"):
        save_samples(tmp_path / f"f{ext}", small_buffer())
    assert listing(tmp_path) == {}
    monkeypatch.undo()
    save_samples(tmp_path / f"f{ext}", small_buffer(seed=1))
    before = listing(tmp_path)
    inject_write_failure(monkeypatch, ext)
    with pytest.raises(OSError, match="injected"):
        save_samples(tmp_path / f"f{ext}", small_buffer(seed=2))
    assert listing(tmp_path) == before


@pytest.mark.parametrize("ext", [".bin", ".txt"])
def test_tlfr_header_path_is_a_directory(tmp_path, ext):
    (tmp_path / f"f{ext}.header").mkdir()
    with pytest.raises(OSError, match=rf"f\{ext}\.header"):
        save_samples(tmp_path / f"f{ext}", small_buffer())
    assert sorted(p.name for p in tmp_path.iterdir()) == [f"f{ext}.header"]


@pytest.mark.parametrize("ext", [".bin", ".txt"])
def test_tlfr_header_write_fails_pair_intact(tmp_path, ext, monkeypatch):
    path = tmp_path / f"f{ext}"
    save_samples(path, small_buffer(seed=1))
    before = listing(tmp_path)

    def header(*args, **kwargs):
        raise OSError(13, "injected: header not writable")
    monkeypatch.setattr(cio, "_tlfr_header_text", header)
    with pytest.raises(OSError, match="injected"):
        save_samples(path, small_buffer(seed=2))
    assert listing(tmp_path) == before
    (tmp_path / f"f{ext}").unlink()
    (tmp_path / f"f{ext}.header").unlink()
    with pytest.raises(OSError, match="injected"):
        save_samples(path, small_buffer(seed=2))
    assert listing(tmp_path) == {}


@pytest.mark.parametrize("ext", [".bin", ".txt"])
def test_tlfr_data_path_is_a_directory(tmp_path, ext):
    """The data rename is refused before the header is replaced: the old header stays."""
    save_samples(tmp_path / "g.bin", small_buffer())
    os.replace(tmp_path / "g.bin.header", tmp_path / f"f{ext}.header")
    (tmp_path / "g.bin").unlink()
    (tmp_path / f"f{ext}").mkdir()
    before = listing(tmp_path)
    with pytest.raises(OSError):
        save_samples(tmp_path / f"f{ext}", small_buffer(seed=3))
    assert listing(tmp_path) == before


@pytest.mark.parametrize("ext", [".exr", ".png"])
def test_save_image_atomic(tmp_path, ext, monkeypatch):
    path = tmp_path / f"img{ext}"
    save_image(path, np.full((3, 4, 3), 0.25, np.float32))
    assert sorted(listing(tmp_path)) == [f"img{ext}"]
    before = listing(tmp_path)

    def replace(src, dst):
        raise OSError(28, "injected: no space left")
    monkeypatch.setattr(os, "replace", replace)
    with pytest.raises(OSError, match="injected"):
        save_image(path, np.full((3, 4, 3), 0.75, np.float32))
    assert listing(tmp_path) == before
    monkeypatch.undo()
    real = cio._oiio_write

    def partial(p, *args):
        real(p, *args)
        raise OSError(5, "injected: write failed")
    monkeypatch.setattr(cio, "_oiio_write", partial)
    with pytest.raises(OSError, match="injected"):
        save_image(tmp_path / f"new{ext}", np.zeros((3, 4, 3), np.float32))
    assert listing(tmp_path) == before


def test_save_over_a_read_only_file_replaces_it(tmp_path):
    """Replacing, not rewriting in place: a read-only old file is no obstacle, and a reader
    holding the old file keeps reading the old bytes."""
    path = tmp_path / "f.npz"
    save_samples(path, small_buffer(seed=1))
    old = path.read_bytes()
    path.chmod(0o444)
    with open(path, "rb") as reader:
        save_samples(path, small_buffer(seed=2))
        assert reader.read() == old
    assert path.read_bytes() != old


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
