"""Seeded fuzzing of the sample-buffer loaders (TLFR binary, TLFR text, EXR, NPZ).

Each format starts from a small valid file (6 x 8 pixels, 2 spp, with motion, misses and
defocus) and gets a fixed number of mutated variants, case ``k`` drawn from its own
``random.Random(f"{SEED}/{fmt}/{k}")`` (so any case can be rebuilt alone with
:func:`build_case`): byte flips, truncations, extensions and insertions; TLFR header line
edits (numbers replaced by 0, -1, huge values, NaN, text ...) and record edits; EXR files
rewritten through OpenImageIO with altered ``clrecon:*`` attributes, channel lists, pixel
types, compressions and sizes; NPZ archives rebuilt with altered members (shapes, dtypes,
compression, missing and extra members, edited ``.npy`` headers).

Every case must either raise ``ValueError`` (or ``ClreconError``), or load and pass
``validate()``; any other exception fails the test with the case id. The cases of a format
run in one child process under an address-space limit, so that a crash (or a runaway
allocation) also fails the test with the id of the case that was running.
"""
from __future__ import annotations

import json
import os
import random
import re
import struct
import subprocess
import sys
import textwrap
import zipfile
from io import BytesIO
from pathlib import Path

import numpy as np
import pytest

SEED = 20240611
#: cases per format (fixed: the seed decides what each case does, not how many there are)
CASES = {"bin": 300, "txt": 300, "exr": 250, "npz": 300}
#: address space a child may add to what its imports took
CHILD_BUDGET = 2 * 2**30
CHILD_TIMEOUT = 150

TESTS = Path(__file__).resolve().parent
ROOT = TESTS.parents[1]

SPECIAL_NUMBERS = ["0", "-1", "1", "2", "2147483647", "2147483648", "4294967297",
                   "99999999999999999999999", "1e30", "1e39", "1e400", "-1e39", "nan", "inf",
                   "-inf", "abc", "", "2.5", "1_0", "0x10", " 3 ", "+4", "--1", "1e", "."]
SPECIAL_FLOATS = [np.nan, np.inf, -np.inf, 0.0, -0.0, -1.0, 1e-45, 1e38, 3.4e38, 1e30, 2.0,
                  0.5, 1e-38, 7.0]


# ==========================================================================================
# the base frame
# ==========================================================================================
def base_buffer():
    from clrecon.core.camera import CocModel
    from clrecon.core.samples import SampleBuffer

    rng = np.random.default_rng(SEED)
    h, w, s = 6, 8, 2
    buf = SampleBuffer.zeros(h, w, s, CocModel(-4.0, 2.0))
    hws = (h, w, s)
    buf.position[:] += rng.uniform(-0.45, 0.45, buf.position.shape)
    r = np.sqrt(rng.uniform(0, 1, hws))
    a = rng.uniform(0, 2 * np.pi, hws)
    buf.lens[:] = np.stack([r * np.cos(a), r * np.sin(a)], -1)
    buf.time[:] = rng.uniform(0, 1, hws)
    buf.depth[:] = rng.uniform(1.0, 30.0, hws)
    miss = rng.uniform(size=hws) < 0.2
    buf.depth[miss] = np.inf
    buf.color[:] = rng.exponential(1.0, buf.color.shape)
    buf.motion[:] = np.where(miss[..., None], 0.0, rng.normal(0, 1.5, buf.motion.shape))
    return buf.validate()


# ==========================================================================================
# byte-level mutations (every format)
# ==========================================================================================
def mutate_bytes(data: bytes, rng: random.Random, region: int | None = None) -> tuple[bytes, str]:
    """One random byte-level edit; ``region`` limits positions to the first bytes."""
    b = bytearray(data)
    top = max(1, min(len(b), region or len(b)))
    kind = rng.choice(["flip", "flip", "set", "truncate", "extend", "insert", "delete", "run"])
    if kind == "flip":
        for _ in range(rng.randint(1, 4)):
            b[rng.randrange(top)] ^= 1 << rng.randrange(8)
    elif kind == "set":
        for _ in range(rng.randint(1, 3)):
            b[rng.randrange(top)] = rng.randrange(256)
    elif kind == "truncate":
        b = b[:rng.randrange(len(b))]
    elif kind == "extend":
        tail = rng.choice([bytes(rng.randint(1, 64)), rng.randbytes(rng.randint(1, 64)),
                           bytes(b[:rng.randint(1, 200)])])
        b += tail
    elif kind == "insert":
        pos = rng.randrange(top)
        b[pos:pos] = rng.randbytes(rng.randint(1, 16))
    elif kind == "delete":
        pos = rng.randrange(top)
        del b[pos:pos + rng.randint(1, 16)]
    else:
        pos = rng.randrange(top)
        n = rng.randint(1, 16)
        b[pos:pos + n] = bytes([rng.choice([0, 0xFF, ord("9"), ord("-")])]) * n
    return bytes(b), kind


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


# ==========================================================================================
# EXR
# ==========================================================================================
EXR_COMPRESSIONS = ["none", "rle", "zips", "zip", "piz", "pxr24", "b44", "dwaa"]


def exr_pixels(buf) -> np.ndarray:
    h, w, s = buf.shape
    data = np.concatenate([buf.color, buf.position, buf.depth[..., None], buf.lens,
                           buf.time[..., None], buf.motion], axis=-1)
    return data.reshape(h, w, 11 * s).astype(np.float32)


def exr_channel_names(spp: int) -> list[str]:
    from clrecon.io import EXR_SAMPLE_CHANNELS

    return [f"s{i}.{c}" for i in range(spp) for c in EXR_SAMPLE_CHANNELS]


def write_exr(path: Path, pixels: np.ndarray, names: list[str], attrs: dict,
              fmt: str = "float", compression: str | None = None, tile: int = 0) -> None:
    import OpenImageIO as oiio

    h, w, c = pixels.shape
    spec = oiio.ImageSpec(w, h, c, fmt)
    spec.channelnames = tuple(names)
    for key, value in attrs.items():
        if isinstance(value, tuple):  # an array attribute
            kind = "float" if any(isinstance(v, float) for v in value) else "int"
            spec.attribute(key, oiio.TypeDesc(f"{kind}[{len(value)}]"), value)
        else:
            spec.attribute(key, value)
    if compression:
        spec.attribute("compression", compression)
    if tile:
        spec.tile_width = spec.tile_height = tile
    out = oiio.ImageOutput.create(str(path))
    if out is None or not out.open(str(path), spec):
        oiio.geterror()
        raise RuntimeError("fuzz: OpenImageIO refused to write the case")
    out.write_image(pixels)
    out.close()


def exr_attrs(buf) -> dict:
    return {"clrecon:format": "samples", "clrecon:spp": buf.spp,
            "clrecon:coc_c0": repr(buf.coc_model.c0), "clrecon:coc_c1": repr(buf.coc_model.c1)}


def build_exr(folder: Path, base: dict, rng: random.Random) -> tuple[Path, str]:
    from clrecon.core.samples import SampleBuffer

    path = folder / "case.exr"
    buf = base["buffer"]
    kind = rng.choice(["bytes", "bytes", "header_bytes", "header_bytes", "spp", "coc",
                       "format", "drop_attr", "channels", "pixels", "values", "size", "spp1"])
    if kind in ("bytes", "header_bytes"):
        data, sub = mutate_bytes(base["exr"], rng, region=800 if kind == "header_bytes" else None)
        path.write_bytes(data)
        return path, f"{kind}/{sub}"
    pixels, names, attrs = exr_pixels(buf), exr_channel_names(buf.spp), exr_attrs(buf)
    fmt, compression, tile = "float", rng.choice([None] + EXR_COMPRESSIONS), 0
    what = kind
    if kind == "spp":
        attrs["clrecon:spp"] = rng.choice([0, -1, 1, 3, 2**31 - 1, -2**31, "2", " 2 ", "2.0",
                                           "abc", 2.0, 2.5, float("inf"), float("nan"),
                                           "99999999999999999999999", "", 1e300, (2, 2),
                                           (2.0,)])
        what += f":{attrs['clrecon:spp']!r}"
    elif kind == "coc":
        key = rng.choice(["clrecon:coc_c0", "clrecon:coc_c1"])
        attrs[key] = rng.choice(["nan", "inf", "-inf", "abc", "", "1e400", 1.5, 3, "0x1p3",
                                 "1" * 5000, "-4.0", "1e-320", float("nan"), (1.0, 2.0)])
        what += f":{key}={str(attrs[key])[:20]!r}"
    elif kind == "format":
        attrs["clrecon:format"] = rng.choice(["Samples", "", "samples ", 5, "image", (1, 2)])
    elif kind == "drop_attr":
        del attrs[rng.choice(list(attrs))]
    elif kind == "channels":
        sub = rng.choice(["drop", "rename", "duplicate", "shuffle", "extra", "prefix"])
        order = list(range(len(names)))
        if sub == "drop":
            del order[rng.randrange(len(order))]
        elif sub == "shuffle":
            rng.shuffle(order)
        elif sub == "extra":
            order.append(0)
        pixels = np.ascontiguousarray(pixels[..., order])
        names = [names[i] for i in order]
        if sub == "extra":
            names[-1] = rng.choice(["A", "s2.R", "s0.R2"])
        elif sub == "rename":
            k = rng.randrange(len(names))
            names[k] = rng.choice([names[k].lower(), names[k] + "x", "s9.R", ""])
        elif sub == "duplicate":
            names[rng.randrange(len(names))] = names[rng.randrange(len(names))]
        elif sub == "prefix":
            names = [n.replace("s", rng.choice(["S", "sample"]), 1) for n in names]
        what += f":{sub}"
    elif kind == "pixels":
        fmt = rng.choice(["half", "uint8", "uint16", "uint32", "int8", "float"])
        tile = rng.choice([0, 4, 16])
        what += f":{fmt}/tile{tile}"
    elif kind == "values":
        for _ in range(rng.randint(1, 3)):
            idx = (rng.randrange(pixels.shape[0]), rng.randrange(pixels.shape[1]),
                   rng.randrange(pixels.shape[2]))
            pixels[idx] = rng.choice(SPECIAL_FLOATS)
    elif kind == "size":
        h, w = rng.choice([(1, 1), (6, 9), (1, 40), (40, 1), (3, 4)])
        sub = SampleBuffer.zeros(h, w, buf.spp, buf.coc_model)
        pixels = exr_pixels(sub) if rng.random() < 0.7 else np.resize(pixels, (h, w, 22))
        what += f":{h}x{w}"
    else:  # a consistent one-sample file
        pixels, names = np.ascontiguousarray(pixels[..., :11]), names[:11]
        attrs["clrecon:spp"] = rng.choice([1, 2])
    try:
        write_exr(path, pixels, names, attrs, fmt, compression, tile)
    except RuntimeError:
        path.write_bytes(base["exr"][:100])  # OpenImageIO would not write it: a stub
        what += ":unwritable"
    return path, f"{what}/{compression}"


# ==========================================================================================
# NPZ
# ==========================================================================================
def npy(arr) -> bytes:
    f = BytesIO()
    np.lib.format.write_array(f, np.asanyarray(arr), allow_pickle=True)
    return f.getvalue()


NPZ_DTYPES = ["<f8", ">f8", "<f2", ">f4", "<i4", "<u1", "<i8", "|b1", "<c8", "<U3", "object",
              "structured", "<M8[s]", "<f16"]


def npz_member_edit(members: dict, rng: random.Random) -> str:
    """One edit of ``members`` (zip member name -> array, or raw bytes)."""
    name = rng.choice(list(members))
    kind = rng.choice(["shape", "dtype", "dtype", "values", "fortran", "missing", "extra",
                       "header", "rename", "scalar"])
    arr = members[name] if not isinstance(members[name], bytes) else None
    if kind == "shape" and arr is not None:
        new = list(arr.shape)
        sub = rng.choice(["drop", "add", "change", "zero"])
        if sub == "drop" and new:
            new.pop(rng.randrange(len(new)))
        elif sub == "add":
            new.insert(rng.randrange(len(new) + 1), rng.choice([1, 2]))
        elif sub == "change" and new:
            k = rng.randrange(len(new))
            new[k] = max(0, new[k] + rng.choice([-1, 1, 5]))
        elif sub == "zero":  # every field empty, consistently
            for key in ("color", "position", "depth", "lens", "time", "motion"):
                key += ".npy"
                if isinstance(members.get(key), np.ndarray):
                    members[key] = np.zeros((0,) + members[key].shape[1:], np.float32)
            return "shape:zero"
        members[name] = np.resize(arr, tuple(new))
        return f"shape:{name}:{tuple(new)}"
    if kind == "dtype" and arr is not None:
        dt = rng.choice(NPZ_DTYPES)
        if dt == "object":
            obj = np.empty(arr.shape, object)
            obj[...] = 1.0
            members[name] = obj
        elif dt == "structured":
            members[name] = np.zeros(arr.shape, [("a", "<f4"), ("b", "<i2")])
        else:
            with np.errstate(all="ignore"):
                members[name] = arr.astype(dt)
        return f"dtype:{name}:{dt}"
    if kind == "values" and arr is not None and arr.size and arr.dtype.kind in "fiu":
        out = arr.astype(rng.choice(["<f8", arr.dtype.str]) if arr.dtype.kind == "f" else "<f8")
        for _ in range(rng.randint(1, 3)):
            out.flat[rng.randrange(out.size)] = rng.choice(SPECIAL_FLOATS + [1e39, -3.5e38, 1e300])
        members[name] = out
        return f"values:{name}"
    if kind == "fortran" and arr is not None:
        members[name] = np.asfortranarray(arr)
        return f"fortran:{name}"
    if kind == "missing":
        del members[name]
        return f"missing:{name}"
    if kind == "extra":
        members[rng.choice(["extra.npy", "color2.npy", "x.txt"])] = rng.choice(
            [np.zeros(3), b"not numpy", np.zeros((2**10,), np.uint8)])
        return "extra"
    if kind == "header" and arr is not None:
        members[name], sub = mutate_bytes(npy(arr), rng, region=128)
        return f"header:{name}:{sub}"
    if kind == "rename":  # a bare name still loads (numpy's own rule); others are missing
        stem = name[:-4] if name.endswith(".npy") else name
        members[stem + rng.choice([".bin", "", ".NPY"])] = members.pop(name)
        return f"rename:{name}"
    members[name] = np.float32(rng.choice(SPECIAL_FLOATS))
    return f"scalar:{name}"


def npz_special(base: dict, rng: random.Random) -> tuple[bytes, str]:
    """Whole files: an .npy, an empty file or archive, other .npy versions, a forged size."""
    kind = rng.choice(["npy", "empty", "no_members", "version", "forged_size", "deflated"])
    buf = base["buffer"]
    if kind == "npy":
        return npy(buf.depth), kind
    if kind == "empty":
        return b"", kind
    out = BytesIO()
    with zipfile.ZipFile(out, "w") as zf:
        if kind != "no_members":
            for name, arr in buf.arrays().items():
                f = BytesIO()
                version = rng.choice([(1, 0), (2, 0), (3, 0)]) if kind == "version" else None
                np.lib.format.write_array(f, arr, version=version)
                zf.writestr(name + ".npy", f.getvalue(), zipfile.ZIP_DEFLATED)
            zf.writestr("coc.npy", npy(np.array([buf.coc_model.c0, buf.coc_model.c1])))
            zf.writestr("format_version.npy", npy(np.int64(1)))
    data = bytearray(out.getvalue())
    if kind == "forged_size":  # a central-directory uncompressed size (offset 24 of 46)
        starts = [m.start() for m in re.finditer(b"PK\x01\x02", bytes(data))]
        entry = rng.choice(starts)
        data[entry + 24:entry + 28] = struct.pack("<I", rng.choice([0, 1, 2**20, 2**32 - 1]))
    return bytes(data), kind


def build_npz(folder: Path, base: dict, rng: random.Random) -> tuple[Path, str]:
    path = folder / "case.npz"
    kind = rng.choice(["bytes", "bytes", "members", "members", "members", "coc", "version",
                       "compression", "special"])
    if kind == "special":
        data, what = npz_special(base, rng)
        path.write_bytes(data)
        return path, f"special:{what}"
    if kind == "bytes":
        source = base["npz"] if rng.random() < 0.5 else base["npz_deflated"]
        data, sub = mutate_bytes(source, rng)
        path.write_bytes(data)
        return path, f"bytes/{sub}"
    buf = base["buffer"]
    members = {f"{k}.npy": v for k, v in buf.arrays().items()}
    members["coc.npy"] = np.array([buf.coc_model.c0, buf.coc_model.c1])
    members["format_version.npy"] = np.int64(1)
    what = kind
    if kind == "members":
        what = "/".join(npz_member_edit(members, rng) for _ in range(rng.choice([1, 1, 1, 2])))
    elif kind == "coc":
        members["coc.npy"] = rng.choice([np.array(["1", "2"]), np.zeros(3), np.array([np.nan, 0]),
                                     np.array([1, 2]), np.zeros((2, 1)), np.float32([1, 2]),
                                     np.array([1e308, 1e308]) * 10, np.array([1 + 1j, 0])])
        what += f":{members['coc.npy'].dtype}{members['coc.npy'].shape}"
    elif kind == "version":
        members["format_version.npy"] = rng.choice([np.int64(2), np.float64(1.0), np.float64(1.5),
                                                np.array("1"), np.array([1]), np.True_,
                                                np.uint8(1), np.float64(np.nan)])
        what += f":{members['format_version.npy']!r}"
    method = rng.choice([zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED, zipfile.ZIP_DEFLATED,
                         zipfile.ZIP_BZIP2, zipfile.ZIP_LZMA] if kind == "compression"
                        else [zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED])
    with zipfile.ZipFile(path, "w", method) as zf:
        for name, value in members.items():
            data = value if isinstance(value, bytes) else npy(value)
            zf.writestr(name, data)
    return path, f"{what}/zip{method}"


# ==========================================================================================
# the cases and the child that runs them
# ==========================================================================================
def base_files(folder: Path) -> dict:
    from clrecon.io import save_samples

    buf = base_buffer()
    base = {"buffer": buf}
    for ext in ("bin", "txt", "exr", "npz"):
        path = folder / f"base.{ext}"
        save_samples(path, buf)
        if ext in ("bin", "txt"):
            base[ext] = {"data": path.read_bytes(),
                         "header": Path(str(path) + ".header").read_text()}
        else:
            base[ext] = path.read_bytes()
    with zipfile.ZipFile(BytesIO(base["npz"])) as zin:
        out = BytesIO()
        with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as zout:
            for info in zin.infolist():
                zout.writestr(info.filename, zin.read(info))
    base["npz_deflated"] = out.getvalue()
    return base


def build_case(fmt: str, k: int, folder: Path, base: dict) -> tuple[Path, str]:
    """Write case ``k`` of ``fmt`` into ``folder``; return the path to load and a label."""
    rng = random.Random(f"{SEED}/{fmt}/{k}")
    if fmt in ("bin", "txt"):
        return build_tlfr(fmt, folder, base[fmt], rng)
    if fmt == "exr":
        return build_exr(folder, base, rng)
    return build_npz(folder, base, rng)


#: what validate() messages start with (they name the field, not the file)
_FIELD_MESSAGE = re.compile(r"^(color|position|depth|lens|time|motion|coc|coc_model)\b")


def names_its_subject(message: str, path: Path) -> bool:
    """A refusal names the file it read (or, from validate(), the field)."""
    return str(path) in message or bool(_FIELD_MESSAGE.match(message))


def _note(f, text: str) -> None:
    """Leave ``text`` (the running case) in the progress file, for a crash report."""
    f.seek(0)
    f.write(text[:300])
    f.truncate()
    f.flush()


def run_cases(fmt: str, folder: str, progress: str) -> dict:
    """Run every case of ``fmt``; return counts and failures (the child's entry point)."""
    import shutil
    import traceback
    import warnings

    from clrecon.core.errors import ClreconError
    from clrecon.io import load_samples

    warnings.simplefilter("ignore")
    work = Path(folder)
    base = base_files(work)
    counts = {"loaded": 0, "refused": 0}
    failures = []
    with open(progress, "w") as prog:
        for k in range(CASES[fmt]):
            case_dir = work / f"case{k}"
            case_dir.mkdir()
            label = "?"
            _note(prog, f"{fmt}#{k} (building)")
            try:
                path, label = build_case(fmt, k, case_dir, base)
            except Exception as exc:  # a bug of this module, not of the loader
                failures.append(f"{fmt}#{k}: building the case failed: {exc!r}")
                continue
            _note(prog, f"{fmt}#{k} ({label})")
            try:
                load_samples(path).validate()
                counts["loaded"] += 1
            except ClreconError:
                counts["refused"] += 1
            except ValueError as exc:
                counts["refused"] += 1
                if not names_its_subject(str(exc), path):
                    failures.append(f"{fmt}#{k} ({label}): ValueError naming neither the file "
                                    f"nor a field: {exc}"[:600])
            except BaseException as exc:  # everything else is a failure of the loader
                failures.append(f"{fmt}#{k} ({label}): {type(exc).__name__}: {exc}"[:600]
                                + "\n" + "".join(traceback.format_tb(exc.__traceback__)[-2:]))
            shutil.rmtree(case_dir, ignore_errors=True)
    return {"counts": counts, "failures": failures, "cases": CASES[fmt]}


CHILD = textwrap.dedent("""
    import json, os, re, resource, signal, sys
    sys.path[:0] = [{tests!r}, {tests!r} + '/../support']
    import numpy, OpenImageIO as oiio, clrecon.io, test_fuzz_io as fuzz
    oiio.attribute("threads", 1)
    oiio.attribute("exr_threads", 1)
    oiio.attribute("limits:imagesize_MB", 1024)
    vm = int(re.search(r"VmSize:\\s+(\\d+)", open("/proc/self/status").read()).group(1))
    limit = vm * 1024 + {budget}
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    if {crash_at}:  # test of the guard itself: the loader dies in that case
        real, calls = clrecon.io.load_samples, []
        def load(path):
            calls.append(path)
            if len(calls) == {crash_at}:
                os.kill(os.getpid(), signal.SIGSEGV)
            return real(path)
        clrecon.io.load_samples = load
    result = fuzz.run_cases({fmt!r}, {folder!r}, {progress!r})
    with open({out!r}, "w") as f:
        json.dump(result, f)
""")


def run_child(tmp_path: Path, fmt: str, crash_at: int = 0) -> dict:
    """Run the cases of ``fmt`` in a child; fail with the running case's id if it dies."""
    work, progress, out = tmp_path / "work", tmp_path / "progress", tmp_path / "result.json"
    work.mkdir()
    code = CHILD.format(tests=str(TESTS), budget=CHILD_BUDGET, fmt=fmt, folder=str(work),
                        progress=str(progress), out=str(out), crash_at=crash_at)
    env = dict(os.environ, MALLOC_ARENA_MAX="2", OMP_NUM_THREADS="1")
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")])
    try:
        proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                              timeout=CHILD_TIMEOUT, env=env)
    except subprocess.TimeoutExpired:
        pytest.fail(f"{fmt}: timed out after {CHILD_TIMEOUT} s in case "
                    f"{progress.read_text().strip() if progress.exists() else '?'}")
    running = progress.read_text().strip() if progress.exists() else "(before the first case)"
    assert proc.returncode == 0 and out.exists(), (
        f"{fmt}: child died with {proc.returncode} in case {running}\n{proc.stderr[-3000:]}")
    return json.loads(out.read_text())


@pytest.mark.parametrize("fmt", list(CASES))
def test_fuzz_loader(tmp_path, fmt):
    result = run_child(tmp_path, fmt)
    assert not result["failures"], "\n".join(result["failures"][:10])
    counts = result["counts"]
    assert counts["loaded"] + counts["refused"] == CASES[fmt]
    # the cases reach both outcomes: the fuzzing is neither all noise nor all harmless
    assert counts["refused"] >= CASES[fmt] // 5 and counts["loaded"] >= CASES[fmt] // 50, counts


def test_fuzz_crash_names_the_case(tmp_path):
    """A loader that crashes the process fails the test with the id of the running case."""
    with pytest.raises(AssertionError, match=r"child died with -11 in case bin#2 \(") as info:
        run_child(tmp_path, "bin", crash_at=3)
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
