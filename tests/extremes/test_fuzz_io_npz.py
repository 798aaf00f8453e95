"""Seeded fuzzing of the NPZ loader (see ``test_fuzz_io.py``): archives rebuilt with
altered members (shapes, dtypes, compression, missing and extra members, edited ``.npy``
headers), whole special files, and byte-level edits."""
from __future__ import annotations

import random
import re
import struct
import zipfile
from io import BytesIO
from pathlib import Path

import numpy as np
import pytest
from io_cases import (
    SPECIAL_FLOATS,
    assert_fuzz_outcomes,
    case_rng,
    mutate_bytes,
    npy_bytes,
    run_child,
)

# ==========================================================================================
# NPZ
# ==========================================================================================
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
        members[name], sub = mutate_bytes(npy_bytes(arr), rng, region=128)
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
        return npy_bytes(buf.depth), kind
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
            zf.writestr("coc.npy", npy_bytes(np.array([buf.coc_model.c0, buf.coc_model.c1])))
            zf.writestr("format_version.npy", npy_bytes(np.int64(1)))
    data = bytearray(out.getvalue())
    if kind == "forged_size":  # a central-directory uncompressed size (offset 24 of 46)
        starts = [m.start() for m in re.finditer(b"PK\x01\x02", bytes(data))]
        entry = rng.choice(starts)
        data[entry + 24:entry + 28] = struct.pack("<I", rng.choice([0, 1, 2**20, 2**32 - 1]))
    return bytes(data), kind


def build_case(fmt: str, k: int, folder: Path, base: dict) -> tuple[Path, str]:
    """Write NPZ case ``k`` into ``folder``; return the path to load and a label."""
    rng = case_rng(fmt, k)
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
    members = {f"{key}.npy": v for key, v in buf.arrays().items()}
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
            data = value if isinstance(value, bytes) else npy_bytes(value)
            zf.writestr(name, data)
    return path, f"{what}/zip{method}"


@pytest.mark.parametrize("fmt", ["npz"])
def test_fuzz_loader(tmp_path, fmt):
    assert_fuzz_outcomes(run_child(tmp_path, __file__, fmt), fmt)
