"""Sample buffers as ``.npz`` archives.

``numpy.savez`` (uncompressed) with the six fields, ``coc = [c0, c1]`` (float64) and
``format_version = 1``.

Limits: only stored and deflated members are read. Every member's ``.npy`` header (version 1
or 2, numeric dtype, no objects: nothing is unpickled) and its ``ZipInfo.file_size`` are
checked before any data is decompressed: the stored size must be what the header's shape and
dtype imply, a deflated member may not claim more than 1032 times its compressed size
(deflate's ceiling), the six fields must agree in ``(H, W, S)``, and ``H*W*S`` is at most
:data:`NPZ_MAX_SAMPLES` (``2**31``). Decompression is streamed into the preallocated array; a
finite value beyond float32's range is refused.
"""
from __future__ import annotations

import contextlib
import math
import os
import struct
import tokenize
import zipfile
import zlib

import numpy as np

from clrecon.core.camera import CocModel
from clrecon.core.samples import FIELDS, SampleBuffer
from clrecon.io.files import F32_MAX, atomic_write, check_exists

NPZ_FORMAT_VERSION = 1
#: samples (H*W*S) refused beyond this count in an .npz
NPZ_MAX_SAMPLES = 2**31
#: the most a deflate stream can expand (zlib's documented ceiling, 1032:1)
_DEFLATE_MAX_RATIO = 1032
#: bytes per read when streaming an .npz member into its array
_NPZ_READ = 1 << 20
_NPZ_MEMBERS = (*FIELDS, "coc", "format_version")


def save_samples_npz(path: str, buf: SampleBuffer) -> None:
    """Write ``buf`` (already validated) as an uncompressed ``.npz``, atomically."""
    arrays = buf.arrays()
    with atomic_write(path) as (tmp,), open(tmp, "wb") as f:
        # a file object: numpy would append ".npz" to a name like ".NPZ"
        np.savez(
            f,
            **arrays,
            coc=np.array([buf.coc_model.c0, buf.coc_model.c1], dtype=np.float64),
            format_version=np.int64(NPZ_FORMAT_VERSION),
        )


#: what a damaged zip archive or member stream raises (zipfile, zlib; numpy's header parser
#: runs ast.literal_eval and, for headers it takes for Python 2 ones, tokenize)
_ZIP_ERRORS = (zipfile.BadZipFile, zlib.error, EOFError, OSError, NotImplementedError,
               RuntimeError, struct.error, ValueError, OverflowError, SyntaxError,
               tokenize.TokenError, TypeError, KeyError)


@contextlib.contextmanager
def _zip_step(path: str, what: str):
    """Report a damaged archive as ``ValueError: PATH: WHAT: ...`` (no own raises inside)."""
    try:
        yield
    except _ZIP_ERRORS as exc:
        raise ValueError(f"{path}: {what}: {str(exc) or type(exc).__name__}") from None


class _Npy:
    """A member's zip entry and the facts of its ``.npy`` header."""

    def __init__(self, name: str, info: zipfile.ZipInfo, shape, fortran: bool, dtype, offset):
        self.name, self.info, self.shape, self.fortran = name, info, shape, fortran
        self.dtype, self.offset = dtype, offset

    @property
    def count(self) -> int:
        return math.prod(self.shape)


def _npz_entries(path: str, zf: zipfile.ZipFile, size: int) -> dict[str, zipfile.ZipInfo]:
    """The zip entry of each required member, checked against the archive's size."""
    entries = {}
    for info in zf.infolist():
        key = info.filename[:-4] if info.filename.endswith(".npy") else info.filename
        if key in _NPZ_MEMBERS and (key not in entries or info.filename.endswith(".npy")):
            entries[key] = info
    missing = [k for k in _NPZ_MEMBERS if k not in entries]
    if missing:
        raise ValueError(f"{path}: missing key(s) {', '.join(missing)} (required: "
                         f"{', '.join(_NPZ_MEMBERS)})")
    for info in entries.values():
        where = f"{path}: member {info.filename}"
        if info.compress_type not in (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED):
            raise ValueError(f"{where}: unsupported compression method {info.compress_type} "
                             "(only stored and deflate are read)")
        if info.flag_bits & 0x1:
            raise ValueError(f"{where}: encrypted")
        if info.header_offset + info.compress_size > size:
            raise ValueError(f"{where}: its {info.compress_size} compressed bytes extend past "
                             f"the end of the {size}-byte file")
        ceiling = info.compress_size * (
            1 if info.compress_type == zipfile.ZIP_STORED else _DEFLATE_MAX_RATIO)
        if info.file_size > ceiling:
            raise ValueError(f"{where}: claims {info.file_size} bytes from {info.compress_size} "
                             f"compressed bytes (at most {ceiling})")
    return entries


def _npy_header(path: str, zf: zipfile.ZipFile, key: str, info: zipfile.ZipInfo) -> _Npy:
    """Read only the ``.npy`` header of a member (version 1 or 2; a numeric dtype, no
    negative dimension)."""
    fmt = np.lib.format
    with _zip_step(path, f"member {info.filename}"), zf.open(info) as f:
        version = fmt.read_magic(f)
        if version not in ((1, 0), (2, 0)):
            raise ValueError(f"unsupported .npy format version {version}")
        read = fmt.read_array_header_1_0 if version == (1, 0) else fmt.read_array_header_2_0
        shape, fortran, dtype = read(f)
        offset = f.tell()
    npy = _Npy(key, info, shape, fortran, dtype, offset)
    if dtype.hasobject or dtype.kind not in "fiu" or dtype.itemsize == 0:
        raise ValueError(f"{path}: {key} has non-numeric dtype {dtype}")
    if any(d < 0 for d in shape):
        raise ValueError(f"{path}: member {info.filename}: negative dimension in shape {shape}")
    return npy


def _check_npy_size(path: str, npy: _Npy) -> None:
    """The member's stored size is what its header's shape and dtype imply."""
    expected = npy.offset + npy.count * npy.dtype.itemsize
    if npy.info.file_size != expected:
        raise ValueError(
            f"{path}: member {npy.info.filename} stores {npy.info.file_size} bytes, but its "
            f".npy header (shape {npy.shape}, dtype {npy.dtype}) implies {expected} bytes")


def _npz_frame_shape(path: str, npys: dict[str, _Npy]) -> tuple[int, int, int]:
    """All six fields agree in (H, W, S); H*W*S within :data:`NPZ_MAX_SAMPLES`."""
    if npys["format_version"].shape != ():
        raise ValueError(f"{path}: format_version must be a scalar, got shape "
                         f"{npys['format_version'].shape}")
    if npys["coc"].shape != (2,):
        raise ValueError(f"{path}: coc must hold [c0, c1], got shape {npys['coc'].shape}")
    hws = npys["depth"].shape
    if len(hws) != 3:
        raise ValueError(f"{path}: depth: expected shape (H, W, S), got {hws}")
    for name, trail in FIELDS.items():
        if npys[name].shape != hws + trail:
            raise ValueError(
                f"{path}: {name} has shape {npys[name].shape}, expected {hws + trail}: all six "
                f"fields must agree in (H, W, S) = {hws} (that of depth)")
    n = math.prod(hws)
    if n > NPZ_MAX_SAMPLES:
        raise ValueError(f"{path}: {' x '.join(map(str, hws))} = {n} samples exceed the limit "
                         f"of {NPZ_MAX_SAMPLES}")
    return hws


def _read_npy_data(path: str, zf: zipfile.ZipFile, npy: _Npy) -> np.ndarray:
    """Stream a member's data (header already checked) into a new array of its shape."""
    flat = np.empty(npy.count, npy.dtype)
    raw = memoryview(flat.view(np.uint8))
    with _zip_step(path, f"member {npy.info.filename}"), zf.open(npy.info) as f:
        f.read(npy.offset)
        pos = 0
        while pos < len(raw):
            got = f.readinto(raw[pos:pos + _NPZ_READ])
            if not got:
                raise EOFError(f"data ends after {pos} of {len(raw)} bytes")
            pos += got
        f.read(1)  # the end of the member: zipfile checks its CRC
    return flat.reshape(npy.shape[::-1]).T if npy.fortran else flat.reshape(npy.shape)


def _as_float32(path: str, name: str, arr: np.ndarray) -> np.ndarray:
    """C-contiguous float32, refusing finite values that float32 cannot hold (they would
    become ``inf``: for depth, a miss)."""
    with np.errstate(over="ignore"):
        out = np.ascontiguousarray(arr, dtype=np.float32)
    if arr.dtype.kind == "f" and arr.dtype.itemsize > 4:
        bad = np.isinf(out) & np.isfinite(arr)
        if bad.any():
            if bad.ndim > 3:
                bad = bad.any(axis=tuple(range(3, bad.ndim)))
            y, x, i = (int(v) for v in np.argwhere(bad)[0])
            count = int(np.count_nonzero(bad))
            raise ValueError(
                f"{path}: {name}: sample (y={y}, x={x}, i={i}) {arr[y, x, i].tolist()} is "
                f"beyond float32's range (largest finite {F32_MAX:.8g}; "
                f"{count} bad sample{'s' if count != 1 else ''})")
    return out


def load_samples_npz(path: str) -> SampleBuffer:
    """Read an ``.npz``: every header and size checked before any member's data is read."""
    check_exists(path)
    with open(path, "rb") as f:
        if f.read(6) == b"\x93NUMPY":
            raise ValueError(f"{path}: expected an .npz archive, found a single array "
                             "(.npy data)")
        f.seek(0)
        with _zip_step(path, "not a readable .npz file"):
            zf = zipfile.ZipFile(f)
        with zf:
            entries = _npz_entries(path, zf, os.fstat(f.fileno()).st_size)
            npys = {k: _npy_header(path, zf, k, info) for k, info in entries.items()}
            _npz_frame_shape(path, npys)
            for npy in npys.values():
                _check_npy_size(path, npy)
            version = _read_npy_data(path, zf, npys["format_version"]).item()
            if version != NPZ_FORMAT_VERSION:
                raise ValueError(f"{path}: format_version must be {NPZ_FORMAT_VERSION}, got "
                                 f"{version!r}")
            with np.errstate(over="ignore"):
                coc = _read_npy_data(path, zf, npys["coc"]).astype(np.float64)
            if not np.isfinite(coc).all():
                raise ValueError(f"{path}: coc must be finite, got {coc.tolist()}")
            arrays = {name: _as_float32(path, name, _read_npy_data(path, zf, npys[name]))
                      for name in FIELDS}
    return SampleBuffer(**arrays, coc_model=CocModel(float(coc[0]), float(coc[1])))
