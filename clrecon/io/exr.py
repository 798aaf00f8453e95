"""Sample buffers as one flat multi-channel OpenEXR image (``.exr``).

``W x H`` pixels with ``11 * S`` float channels ``s{i}.R, s{i}.G, s{i}.B, s{i}.X, s{i}.Y,
s{i}.Z, s{i}.U, s{i}.V, s{i}.T, s{i}.MX, s{i}.MY`` (colour, position, depth, lens, time, motion
of sample ``i``) and the attributes ``clrecon:format = "samples"``, ``clrecon:spp`` (int),
``clrecon:coc_c0`` and ``clrecon:coc_c1``. The CoC coefficients are stored as strings (``repr``
of the Python float): OpenImageIO writes float attributes to EXR in single precision and drops
double ones, and neither would round-trip a ``CocModel`` exactly.

Limits: ``clrecon:spp`` must be a positive integer, compared with the channel count
(``11 * spp``) before anything is built from it; ``W*H*S`` at most :data:`EXR_MAX_SAMPLES`
(``2**31``), checked before the pixels are read. OpenImageIO's own limits apply when the file
is opened (``limits:resolution``, ``limits:imagesize_MB`` and ``limits:channels``, by default
1024 channels, so ``S <= 93`` unless raised). A file OpenImageIO cannot read raises
:class:`~clrecon.io.image.ImageReadError` (a ``ValueError`` and an ``OSError``).
"""
from __future__ import annotations

import contextlib
import math

import numpy as np

from clrecon.core.camera import CocModel
from clrecon.core.samples import SampleBuffer
from clrecon.io.files import atomic_write, columns_buffer, fill_columns
from clrecon.io.image import oiio_read, oiio_write

EXR_SAMPLE_CHANNELS = ("R", "G", "B", "X", "Y", "Z", "U", "V", "T", "MX", "MY")
EXR_FORMAT_NAME = "samples"
#: samples (W*H*S) refused beyond this count in a sample EXR
EXR_MAX_SAMPLES = 2**31
#: where each field sits among a sample's :data:`EXR_SAMPLE_CHANNELS`
_COLUMNS = {"color": slice(0, 3), "position": slice(3, 5), "depth": 5, "lens": slice(6, 8),
            "time": 8, "motion": slice(9, 11)}


def save_samples_exr(path: str, buf: SampleBuffer) -> None:
    """Write ``buf`` (already validated) as a sample EXR, atomically."""
    import OpenImageIO as oiio

    h, w, s = buf.shape
    nc = len(EXR_SAMPLE_CHANNELS)
    data = np.empty((h, w, s, nc), np.float32)
    fill_columns(data, _COLUMNS, buf)
    spec = oiio.ImageSpec(w, h, nc * s, "float")
    spec.channelnames = tuple(f"s{i}.{c}" for i in range(s) for c in EXR_SAMPLE_CHANNELS)
    spec.attribute("clrecon:format", EXR_FORMAT_NAME)
    spec.attribute("clrecon:spp", int(s))
    # strings: OIIO stores float attributes in EXR as float32 and drops doubles
    spec.attribute("clrecon:coc_c0", repr(float(buf.coc_model.c0)))
    spec.attribute("clrecon:coc_c1", repr(float(buf.coc_model.c1)))
    with atomic_write(path) as (tmp,):
        oiio_write(tmp, spec, data.reshape(h, w, nc * s), path)


def _exr_attribute(path: str, key: str, raw, integer: bool):
    """``clrecon:spp`` (an int, or a string or float holding one) or a CoC coefficient (a
    finite float, or a string holding one)."""
    value = None
    if isinstance(raw, str):
        with contextlib.suppress(ValueError):
            value = int(raw.strip()) if integer else float(raw)
    elif isinstance(raw, (int, float)) and not isinstance(raw, bool):
        value = raw
        if integer and isinstance(raw, float):
            value = int(raw) if raw.is_integer() else None
    if value is None or (not integer and not math.isfinite(value)):
        what = "an integer" if integer else "a finite number"
        raise ValueError(f"{path}: malformed clrecon attribute: {key} must be {what}, "
                         f"got {raw!r:.80}")
    return value


def _exr_layout(path: str, info: dict) -> tuple[int, CocModel, list[int]]:
    """Check a sample EXR's attributes and channels (before its pixels are read): ``spp``,
    the CoC model and the channel index of each ``s{i}.{c}`` in sample-major order."""
    attrs = info["attrs"]
    fmt = attrs["clrecon:format"]
    if not (isinstance(fmt, str) and fmt == EXR_FORMAT_NAME):  # (an array would compare)
        raise ValueError(
            f"{path}: not a clrecon sample EXR (attribute clrecon:format is "
            f"{attrs['clrecon:format']!r}, expected {EXR_FORMAT_NAME!r})"
        )
    for key in ("clrecon:spp", "clrecon:coc_c0", "clrecon:coc_c1"):
        if attrs[key] is None:
            raise ValueError(f"{path}: missing attribute {key}")
    spp = _exr_attribute(path, "clrecon:spp", attrs["clrecon:spp"], True)
    model = CocModel(*(_exr_attribute(path, k, attrs[k], False)
                       for k in ("clrecon:coc_c0", "clrecon:coc_c1")))
    names = info["channelnames"]
    if spp < 1:
        raise ValueError(f"{path}: clrecon:spp must be positive, got {spp} (the file has "
                         f"{len(names)} channels)")
    nc = len(EXR_SAMPLE_CHANNELS)
    position = {n: k for k, n in enumerate(names)}
    # first few missing names, in order; bounded by len(names) + 5 look-ups whatever spp is
    missing: list[str] = []
    for i in range(spp):
        missing += [f"s{i}.{c}" for c in EXR_SAMPLE_CHANNELS if f"s{i}.{c}" not in position]
        if len(missing) > 5 or (i + 1) * nc > len(names) + 5:
            break
    if missing or len(names) != nc * spp:
        detail = (f"; missing {', '.join(missing[:5])}" + (", ..." if len(missing) > 5 else "")
                  if missing else "")
        raise ValueError(
            f"{path}: found {len(names)} channels, but clrecon:spp = {spp} needs "
            f"{nc} * {spp} = {nc * spp} (s{{i}}.{{{','.join(EXR_SAMPLE_CHANNELS)}}})"
            f"{detail}")
    n = info["width"] * info["height"] * spp
    if n > EXR_MAX_SAMPLES:
        raise ValueError(f"{path}: {info['width']} x {info['height']} pixels x {spp} spp = "
                         f"{n} samples exceed the limit of {EXR_MAX_SAMPLES}")
    order = [position[f"s{i}.{c}"] for i in range(spp) for c in EXR_SAMPLE_CHANNELS]
    return spp, model, order


def load_samples_exr(path: str) -> SampleBuffer:
    """Read a sample EXR, its layout checked before the pixels are read."""
    layout = []
    info, pixels = oiio_read(path, lambda info: layout.append(_exr_layout(path, info)))
    spp, model, order = layout[0]
    h, w = info["height"], info["width"]
    if order != list(range(len(order))):
        pixels = pixels[..., order]
    data = pixels.reshape(h, w, spp, len(EXR_SAMPLE_CHANNELS))
    return columns_buffer(data, _COLUMNS, model)

