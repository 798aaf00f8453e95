"""Seeded fuzzing of the EXR sample-file loader (see ``test_fuzz_io.py``): files rewritten
through OpenImageIO with altered ``clrecon:*`` attributes, channel lists, pixel types,
compressions and sizes, and byte-level edits of the whole file or its header."""
from __future__ import annotations

import random
from pathlib import Path

import numpy as np
import pytest
from io_cases import (
    SPECIAL_FLOATS,
    assert_fuzz_outcomes,
    case_rng,
    exr_channels,
    mutate_bytes,
    run_child,
)

from clrecon.core.samples import SampleBuffer

# ==========================================================================================
# EXR
# ==========================================================================================
EXR_COMPRESSIONS = ["none", "rle", "zips", "zip", "piz", "pxr24", "b44", "dwaa"]


def exr_pixels(buf) -> np.ndarray:
    h, w, s = buf.shape
    data = np.concatenate([buf.color, buf.position, buf.depth[..., None], buf.lens,
                           buf.time[..., None], buf.motion], axis=-1)
    return data.reshape(h, w, 11 * s).astype(np.float32)


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
    path = folder / "case.exr"
    buf = base["buffer"]
    kind = rng.choice(["bytes", "bytes", "header_bytes", "header_bytes", "spp", "coc",
                       "format", "drop_attr", "channels", "pixels", "values", "size", "spp1"])
    if kind in ("bytes", "header_bytes"):
        data, sub = mutate_bytes(base["exr"], rng, region=800 if kind == "header_bytes" else None)
        path.write_bytes(data)
        return path, f"{kind}/{sub}"
    pixels, names, attrs = exr_pixels(buf), exr_channels(buf.spp), exr_attrs(buf)
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


def build_case(fmt: str, k: int, folder: Path, base: dict) -> tuple[Path, str]:
    """Write EXR case ``k`` into ``folder``; return the path to load and a label."""
    return build_exr(folder, base, case_rng(fmt, k))


@pytest.mark.parametrize("fmt", ["exr"])
def test_fuzz_loader(tmp_path, fmt):
    assert_fuzz_outcomes(run_child(tmp_path, __file__, fmt), fmt)
