"""Limits and hostile files of clrecon.io: EXR sample files and text TLFR.

Every loader states and enforces its limits before it allocates anything sized by the file
(EXR: ``clrecon:spp`` against the channel count, samples against a limit; text TLFR: parsed
in bounded chunks), and a malformed file raises ``ValueError`` naming the file. A case that
could blow memory runs in a child process under ``RLIMIT_AS``. NPZ archives:
``test_io_limits_npz.py``; safe writes: ``test_io_limits_writes.py``.
"""
from __future__ import annotations

import tracemalloc
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest
from io_cases import exr_channels, run_limited, small_buffer

import clrecon.io.exr
import clrecon.io.tlfr
import clrecon.io.tlfr_text
from clrecon.core.camera import CocModel
from clrecon.core.samples import FIELDS
from clrecon.io import load_image, load_samples, save_samples


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


def exr_attrs(spp) -> dict:
    return {"clrecon:format": "samples", "clrecon:spp": spp, "clrecon:coc_c0": "0.0",
            "clrecon:coc_c1": "0.0"}


# ------------------------------------------------------------------------------------------
# EXR: clrecon:spp against the channel count, before anything is built from it
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
    monkeypatch.setattr(clrecon.io.exr, "EXR_MAX_SAMPLES", 23)  # 4 x 3 x 2 = 24 samples
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
# text TLFR: parsed in bounded chunks
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
            monkeypatch.setattr(clrecon.io.tlfr_text, "_TLFR_TEXT_READ", size)
            back = load_samples(path)
            np.testing.assert_array_equal(back.depth, buf.depth)
            np.testing.assert_array_max_ulp(back.motion, buf.motion, maxulp=1)
    monkeypatch.setattr(clrecon.io.tlfr_text, "_TLFR_TEXT_READ", longest)
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


def edited_text_tlfr(path: Path, edit) -> Path:
    """:func:`small_buffer` saved as text TLFR at ``path``, its lines then changed in place
    by ``edit(lines)``."""
    save_samples(path, small_buffer())
    lines = path.read_text().splitlines()
    edit(lines)
    path.write_text("\n".join(lines) + "\n")
    return path


def test_text_tlfr_line_too_long(tmp_path, monkeypatch):
    def edit(lines):
        lines[3] = lines[3] + " " * 5000
    path = edited_text_tlfr(tmp_path / "long.txt", edit)
    monkeypatch.setattr(clrecon.io.tlfr_text, "_TLFR_TEXT_READ", 1024)
    with pytest.raises(ValueError, match=r"long.txt: line 4: longer than"):
        load_samples(path)


def test_text_tlfr_value_beyond_float32(tmp_path):
    def edit(lines):
        values = lines[5].split(",")
        values[3] = "1e39"
        lines[5] = ",".join(values)
    path = edited_text_tlfr(tmp_path / "o.txt", edit)
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
    whole = clrecon.io.tlfr._tlfr_motion(rec, model, "<r>")
    monkeypatch.setattr(clrecon.io.tlfr, "_TLFR_MOTION_BLOCK", 4)
    np.testing.assert_array_equal(clrecon.io.tlfr._tlfr_motion(rec, model, "<r>"), whole)
    rec[5, 2, 1, 13] = -100.0  # the first crossing in C order is reported
    rec[6, 4, 0, 13] = -100.0
    with pytest.raises(ValueError, match=r"y=5, x=2, i=1.*camera plane"):
        clrecon.io.tlfr._tlfr_motion(rec, model, "<r>")

