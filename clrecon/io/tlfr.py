"""Sample buffers in TLFR 1.3 (``.bin`` / ``.txt``), the format of Lehtinen et al. 2011's
public code.

A text header file ``PATH + ".header"`` (:mod:`clrecon.io.tlfr_header`) and a data file of
``W*H*S`` records ordered y, then x, then sample, each
``x,y,z/w,w,u,v,t,r,g,b,a,mv_x,mv_y,mv_w,dwdx,dwdy``; ``Encoding = binary``: 16 little-endian
float32 per record, ``Encoding = text``: one comma-separated line per record
(:mod:`clrecon.io.tlfr_text`). On load the header's ``Encoding`` decides, whatever the
extension; on save ``.txt`` is written as text and ``.bin`` as binary unless ``encoding`` says
otherwise.

Motion conversion
-----------------
TLFR stores motion as ``V = (mv_x, mv_y, mv_w)``, the homogeneous camera-space position
``(x*w, y*w, w)`` at ``t = 1`` minus that at ``t = 0``, where positions are pixel coordinates
(no clip-space scale). For a sample at time ``t``, depth ``w``, lens ``(u, v)``, its
lens-centre position is ``c = (x, y) - coc(w) * (u, v)`` with homogeneous position
``h = (c * w, w)``; its pinhole image at time ``s`` is

    ``P(s) = (h_xy + (s - t) V_xy) / (w + (s - t) V_w)``

and the loaded screen motion is ``P(1) - P(0)``, evaluated in float64 as the algebraically
equal ``w (V_xy - V_w c) / ((w + (1 - t) V_w) (w - t V_w))`` (so ``V = 0`` gives exactly zero
motion, and ``V_w = 0`` gives ``V_xy / w``). A sample whose homogeneous ``w`` is not positive
at ``t = 0`` or ``t = 1`` (the point crosses the camera plane) raises ``ValueError``. This
linearises perspective motion: clrecon's convention is linear screen motion. On save (linear
screen motion at constant depth) ``mv_xy = motion * w`` and ``mv_w = 0``, so a round trip
returns the motion to within one float32 rounding (one ulp; ``motion * w`` is rounded to
float32 in the file). Misses (``w >= 1e30`` or ``inf``) are written with ``mv = 0`` and load
with zero motion, whatever their file ``mv``.

Other columns: ``z/w`` is written as ``w / (w + 1)`` for hits and ``1.0`` for misses (finite,
increasing with depth, in (0, 1]; the reference code does not use it) and is ignored on load;
``a = 1``, ``dwdx = dwdy = 0`` on save, all three ignored on load. Miss depth is written as
is (``inf`` in binary, ``"inf"`` in text). Text values are written with ``%.9g``, which
round-trips float32 exactly.

Limits: the header at most 64 KiB; ``W*H*S`` at most :data:`TLFR_MAX_RECORDS` (``2**31``)
records. The data file's size is checked against the header first: binary exactly
``W*H*S*64`` bytes, text at least ``W*H*S*32`` (the shortest record line), so the
``(W*H*S, 16)`` float32 records never exceed twice the file's size. Peak memory: the
records, the buffer's fields and (text) one chunk.

A pair is written atomically (:func:`clrecon.io.files.atomic_write`): renamed only once both
files are written and neither target is a directory; if the second rename still fails, the
first target is restored.
"""
from __future__ import annotations

import os

import numpy as np

from clrecon.core.camera import CocModel
from clrecon.core.samples import MISS_DEPTH, SampleBuffer
from clrecon.io.files import atomic_write, check_exists, columns_buffer, fill_columns
from clrecon.io.tlfr_header import parse_tlfr_header, tlfr_header_text
from clrecon.io.tlfr_text import read_tlfr_text

#: records refused beyond this count (a header that large is corrupt or hostile)
TLFR_MAX_RECORDS = 2**31
_TLFR_RECORD_BYTES = 16 * 4
#: shortest possible text record: 16 one-character numbers, 15 commas, a newline
_TLFR_MIN_TEXT_RECORD = 32
#: records per formatting call when writing text
_TLFR_TEXT_CHUNK = 1 << 16
#: records per block of the motion conversion (bounds its float64 temporaries)
_TLFR_MOTION_BLOCK = 1 << 14
#: where each field of a buffer sits in a record (motion is converted)
_COLUMNS = {"position": slice(0, 2), "depth": 3, "lens": slice(4, 6), "time": 6,
            "color": slice(7, 10)}


def load_tlfr(path: str) -> SampleBuffer:
    """Read a TLFR pair, every size checked against the header before anything is read."""
    header_path = path + ".header"
    hdr = parse_tlfr_header(header_path)
    width, height, spp = hdr["width"], hdr["height"], hdr["spp"]
    n = width * height * spp
    check_exists(path, "TLFR data file")
    size = os.path.getsize(path)
    shape_text = f"W={width}, H={height}, S={spp} in {header_path}"
    if hdr["encoding"] == "binary":
        expected = n * _TLFR_RECORD_BYTES
        if size != expected:
            raise ValueError(
                f"{path}: binary TLFR data file size is {size} bytes, expected exactly "
                f"{expected} bytes ({n} records of {_TLFR_RECORD_BYTES} bytes; {shape_text})"
            )
    elif size < n * _TLFR_MIN_TEXT_RECORD:
        raise ValueError(
            f"{path}: text TLFR data file size is {size} bytes, too small for {n} records "
            f"(at least {n * _TLFR_MIN_TEXT_RECORD} bytes; {shape_text})"
        )
    if n > TLFR_MAX_RECORDS:
        raise ValueError(f"{path}: {n} records ({shape_text}) exceed the limit of "
                         f"{TLFR_MAX_RECORDS}")
    if hdr["encoding"] == "binary":
        records = np.fromfile(path, dtype="<f4").reshape(n, 16)
    else:
        records = read_tlfr_text(path, n)
    records = records.astype(np.float32, copy=False).reshape(height, width, spp, 16)
    motion = _tlfr_motion(records, hdr["coc_model"], path)
    return columns_buffer(records, _COLUMNS, hdr["coc_model"], motion=motion)


def _sample_index(flat: int, width: int, spp: int) -> str:
    i = flat % spp
    x = (flat // spp) % width
    y = flat // (spp * width)
    return f"sample (y={y}, x={x}, i={i}) (record {flat})"


def _tlfr_motion(records: np.ndarray, model: CocModel, path: str) -> np.ndarray:
    """Screen motion P(1) - P(0) of (H, W, S, 16) records; see the module docstring.
    Converted in blocks of :data:`_TLFR_MOTION_BLOCK` records (bounded temporaries)."""
    height, width, spp = records.shape[:3]
    flat = records.reshape(-1, 16)
    motion = np.zeros((len(flat), 2), np.float32)
    for start in range(0, len(flat), _TLFR_MOTION_BLOCK):
        depth = flat[start:start + _TLFR_MOTION_BLOCK, 3]
        hit = np.flatnonzero((depth > 0) & (depth < MISS_DEPTH))  # NaN/negative: validate()
        if len(hit):
            index = start + hit
            motion[index] = _tlfr_motion_block(flat[index], model, path, index, width, spp)
    return motion.reshape(height, width, spp, 2)


def _tlfr_motion_block(rec: np.ndarray, model: CocModel, path: str, index: np.ndarray,
                       width: int, spp: int) -> np.ndarray:
    """Motion of hit records ``rec`` (N, 16) at flat ``index``, in float64."""
    r = rec.astype(np.float64)
    w, t = r[:, 3], r[:, 6]
    v_xy, v_w = r[:, 11:13], r[:, 13]
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        w0 = w - t * v_w
        w1 = w + (1.0 - t) * v_w
        crossing = (w0 <= 0) | (w1 <= 0)
        if crossing.any():
            k = int(np.flatnonzero(crossing)[0])
            raise ValueError(
                f"{path}: {_sample_index(int(index[k]), width, spp)}: motion crosses the "
                f"camera plane (homogeneous w is {w0[k]:g} at t=0 and {w1[k]:g} at t=1 for "
                f"w={w[k]:g}, t={t[k]:g}, mv_w={v_w[k]:g}); perspective motion cannot be "
                "linearised"
            )
        coc = model.c0 / w + model.c1
        centre = r[:, 0:2] - coc[:, None] * r[:, 4:6]
        general = w[:, None] * (v_xy - v_w[:, None] * centre) / (w0 * w1)[:, None]
        return np.where((v_w == 0)[:, None], v_xy / w[:, None], general)


def _tlfr_records(buf: SampleBuffer) -> np.ndarray:
    """(N, 16) float32 records of a buffer (order y, x, sample)."""
    h, w, s = buf.shape
    depth = buf.depth
    hit = depth < MISS_DEPTH
    d64 = depth.astype(np.float64)
    rec = np.zeros((h, w, s, 16), np.float32)
    with np.errstate(invalid="ignore", over="ignore"):
        rec[..., 2] = np.where(hit, d64 / (d64 + 1.0), 1.0)
        mv = np.where(hit[..., None], buf.motion * d64[..., None], 0.0).astype(np.float32)
    bad = ~np.isfinite(mv).all(-1)
    if bad.any():
        flat = int(np.flatnonzero(bad.ravel())[0])
        raise ValueError(f"motion: {_sample_index(flat, w, s)}: motion * depth overflows "
                         "float32; cannot encode it in TLFR")
    fill_columns(rec, _COLUMNS, buf)
    rec[..., 10] = 1.0
    rec[..., 11:13] = mv
    return rec.reshape(h * w * s, 16)


def _write_tlfr_data(f, records: np.ndarray, encoding: str) -> None:
    """Write (N, 16) float32 records to the binary file object ``f``."""
    if encoding == "binary":
        f.write(records.astype("<f4", copy=False).tobytes())
        return
    line = ",".join(["%.9g"] * 16) + "\n"
    for start in range(0, len(records), _TLFR_TEXT_CHUNK):
        chunk = records[start:start + _TLFR_TEXT_CHUNK]
        f.write(((line * len(chunk)) % tuple(chunk.ravel().tolist())).encode("ascii"))


def save_tlfr(path: str, buf: SampleBuffer, encoding: str) -> None:
    """Both files to temporaries, then the data and the header renamed into place (see
    :func:`~clrecon.io.files.atomic_write`): a failure leaves the old pair, or nothing."""
    records = _tlfr_records(buf)
    with atomic_write(path, path + ".header") as (data_tmp, header_tmp):
        with open(data_tmp, "wb") as f:
            _write_tlfr_data(f, records, encoding)
        with open(header_tmp, "wb") as f:
            f.write(tlfr_header_text(buf, encoding).encode("ascii"))
