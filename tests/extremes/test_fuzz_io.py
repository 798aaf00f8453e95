"""Seeded fuzzing of the sample-buffer loaders (TLFR binary, TLFR text, EXR, NPZ).

Each format starts from a small valid file (6 x 8 pixels, 2 spp, with motion, misses and
defocus) and gets a fixed number of mutated variants, case ``k`` drawn from its own
``random.Random(f"{SEED}/{fmt}/{k}")`` (so any case can be rebuilt alone with the
``build_case`` of its format's test file): byte flips, truncations, extensions and
insertions; TLFR header line edits (numbers replaced by 0, -1, huge values, NaN, text ...)
and record edits; EXR files rewritten through OpenImageIO with altered ``clrecon:*``
attributes, channel lists, pixel types, compressions and sizes; NPZ archives rebuilt with
altered members (shapes, dtypes, compression, missing and extra members, edited ``.npy``
headers).

Every case must either raise ``ValueError`` (or ``ClreconError``), or load and pass
``validate()``; any other exception fails the test with the case id. The cases of a format
run in one child process under an address-space limit, so that a crash (or a runaway
allocation) also fails the test with the id of the case that was running.

TLFR cases and the harness's own tests are here; EXR in ``test_fuzz_io_exr.py``, NPZ in
``test_fuzz_io_npz.py``; the harness (base frame, byte mutations, child) in ``io_cases``.
"""
from __future__ import annotations

import random
from pathlib import Path

import numpy as np
import pytest
from io_cases import (
    SPECIAL_FLOATS,
    SPECIAL_NUMBERS,
    assert_fuzz_outcomes,
    base_files,
    case_rng,
    mutate_bytes,
    run_child,
)


# ==========================================================================================
# TLFR (binary and text)
# ==========================================================================================
def tlfr_header_edit(lines: list[str], rng: random.Random) -> tuple[list[str], str]:
    lines = list(lines)
    kind = rng.choice(["number", "number", "number", "delete", "duplicate", "swap", "garbage",
                       "encoding", "motion", "fields", "case", "version"])
    k = rng.randrange(len(lines))
    if kind == "number":
        k = rng.choice([i for i, line in enumerate(lines) if any(c.isdigit() for c in line)])
        tokens = lines[k].replace(",", " , ").split(" ")
        digits = [i for i, t in enumerate(tokens) if any(c.isdigit() for c in t)]
        tokens[rng.choice(digits)] = rng.choice(SPECIAL_NUMBERS)
        lines[k] = " ".join(tokens).replace(" , ", ",")
    elif kind == "delete":
        del lines[k]
    elif kind == "duplicate":
        lines.insert(k, lines[k])
    elif kind == "swap":
        j = rng.randrange(len(lines))
        lines[k], lines[j] = lines[j], lines[k]
    elif kind == "garbage":
        lines.insert(k, rng.choice(["Pixel-to-camera matrix: 1,0,0", "\x00\x01", "width",
                                    "Width = ", "Samples per pixel: 2 3", "#comment", "=" * 300]))
    elif kind == "encoding":
        lines = [f"Encoding = {rng.choice(['binary', 'text', 'ascii', '', 'BINARY'])}"
                 if line.startswith("Encoding") else line for line in lines]
    elif kind == "motion":
        lines = [f"Motion model: {rng.choice(['affine', '', 'perspective x'])}"
                 if line.startswith("Motion") else line for line in lines]
    elif kind == "fields":
        names = lines[-1].split(",")
        del names[rng.randrange(len(names))]
        lines[-1] = ",".join(names)
    elif kind == "case":
        lines[k] = lines[k].upper() if rng.random() < 0.5 else "  " + lines[k] + "  "
    else:
        lines[0] = f"Version {rng.choice(['1.2', '1.30', '2', 'x', '1.3.0', '01.3'])}"
    return lines, f"header:{kind}"


def tlfr_binary_edit(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    rec = np.frombuffer(data, "<f4").reshape(-1, 16).copy()
    for _ in range(rng.randint(1, 3)):
        rec[rng.randrange(len(rec)), rng.randrange(16)] = rng.choice(SPECIAL_FLOATS)
    return rec.astype("<f4").tobytes(), "records"


def tlfr_text_edit(text: str, rng: random.Random) -> tuple[str, str]:
    lines = text.splitlines()
    kind = rng.choice(["value", "value", "value", "delete", "duplicate", "blank", "add_field",
                       "drop_field", "comma", "crlf", "cr", "nul", "tab", "unicode", "long",
                       "tail_blanks", "swap"])
    k = rng.randrange(len(lines))
    sep = "\n"
    if kind == "value":
        values = lines[k].split(",")
        values[rng.randrange(16)] = rng.choice(SPECIAL_NUMBERS + ["1e39", "-3.5e38", "\u0661"])
        lines[k] = ",".join(values)
    elif kind == "delete":
        del lines[k]
    elif kind == "duplicate":
        lines.insert(k, lines[k])
    elif kind == "blank":
        lines.insert(k, rng.choice(["", "   ", "\t"]))
    elif kind == "add_field":
        lines[k] += ",0"
    elif kind == "drop_field":
        lines[k] = lines[k].rsplit(",", 1)[0]
    elif kind == "comma":
        lines = [line + rng.choice([",", ", ", ",,"]) for line in lines]
    elif kind == "crlf":
        sep = "\r\n"
    elif kind == "cr":
        sep = "\r"
    elif kind == "nul":
        lines[k] = lines[k][:5] + "\x00" + lines[k][5:]
    elif kind == "tab":
        lines[k] = lines[k].replace(",", "\t,", 3)
    elif kind == "unicode":
        lines[k] = lines[k].replace("0", "\u00e9", 1)
    elif kind == "long":
        lines[k] += " " * rng.choice([1000, (1 << 20) + 10])
    elif kind == "tail_blanks":
        lines += [""] * rng.randint(1, 50)
    else:
        j = rng.randrange(len(lines))
        lines[k], lines[j] = lines[j], lines[k]
    return sep.join(lines) + sep, f"text:{kind}"


def build_tlfr(fmt: str, folder: Path, base: dict, rng: random.Random) -> tuple[Path, str]:
    path = folder / f"case.{fmt}"
    header = base["header"].splitlines()
    data = base["data"]
    kind = rng.choice(["header", "header", "data", "data", "both", "reshape", "header_bytes"])
    what = kind
    if kind in ("header", "both"):
        header, what = tlfr_header_edit(header, rng)
    if kind in ("data", "both"):
        if fmt == "bin" and rng.random() < 0.5:
            data, sub = tlfr_binary_edit(data, rng)
        elif fmt == "txt" and rng.random() < 0.7:
            text, sub = tlfr_text_edit(data.decode("ascii"), rng)
            data = text.encode("utf-8")
        else:
            data, sub = mutate_bytes(data, rng)
        what += "/" + sub
    header_bytes = ("\n".join(header) + "\n").encode("utf-8")
    if kind == "reshape":  # another (W, H, S) with the same product: sizes still agree
        dims = rng.choice([(6, 8, 2), (8, 2, 6), (2, 6, 8), (12, 8, 1), (96, 1, 1), (1, 1, 96),
                           (4, 6, 4), (8, 6, 2)])
        new = [f"Width {dims[0]}", f"Height {dims[1]}", f"Samples per pixel {dims[2]}"]
        keys = ("Width", "Height", "Samples")
        header = [new[keys.index(line.split()[0])] if line.split()[0] in keys else line
                  for line in header]
        header_bytes = ("\n".join(header) + "\n").encode()
        what = f"reshape:{dims}"
    elif kind == "header_bytes":
        header_bytes, sub = mutate_bytes(header_bytes, rng)
        what += "/" + sub
    if rng.random() < 0.05:
        header_bytes = b"\xef\xbb\xbf" + header_bytes
    if rng.random() < 0.03:
        header_bytes += b"Width 8\n" * 10000  # beyond 64 KiB
    path.write_bytes(data)
    Path(str(path) + ".header").write_bytes(header_bytes)
    return path, what


def build_case(fmt: str, k: int, folder: Path, base: dict) -> tuple[Path, str]:
    """Write case ``k`` of ``fmt`` ("bin" or "txt") into ``folder``; return the path to load
    and a label."""
    return build_tlfr(fmt, folder, base[fmt], case_rng(fmt, k))


@pytest.mark.parametrize("fmt", ["bin", "txt"])
def test_fuzz_loader(tmp_path, fmt):
    assert_fuzz_outcomes(run_child(tmp_path, __file__, fmt), fmt)


def test_fuzz_crash_names_the_case(tmp_path):
    """A loader that crashes the process fails the test with the id of the running case."""
    with pytest.raises(AssertionError, match=r"child died with -11 in case bin#2 \(") as info:
        run_child(tmp_path, __file__, "bin", crash_at=3)
    assert "bin#3" not in str(info.value)


def test_fuzz_base_files_load(tmp_path):
    """The unmutated files of every format load back to the base frame."""
    from clrecon.io import load_samples

    base = base_files(tmp_path)
    buf = base["buffer"]
    for ext in ("bin", "txt", "exr", "npz"):
        back = load_samples(tmp_path / f"base.{ext}")
        np.testing.assert_array_equal(back.depth, buf.depth)
        np.testing.assert_array_equal(back.color, buf.color)
