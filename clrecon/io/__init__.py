"""Reading and writing sample buffers and images.

Sample buffers (:func:`load_samples`, :func:`save_samples`); the format follows the extension:

``.bin`` / ``.txt``
    TLFR, version 1.3 (the format of Lehtinen et al. 2011's public code): a text header file
    ``PATH + ".header"`` and a data file of ``W*H*S`` records ordered y, then x, then sample,
    each ``x,y,z/w,w,u,v,t,r,g,b,a,mv_x,mv_y,mv_w,dwdx,dwdy``; ``Encoding = binary``: 16
    little-endian float32 per record, ``Encoding = text``: one comma-separated line per record.
    On load the header's ``Encoding`` decides, whatever the extension; on save ``.txt`` is
    written as text and ``.bin`` as binary unless ``encoding`` says otherwise.
``.exr``
    One flat multi-channel OpenEXR image of ``W x H`` pixels with ``11 * S`` float channels
    ``s{i}.R, s{i}.G, s{i}.B, s{i}.X, s{i}.Y, s{i}.Z, s{i}.U, s{i}.V, s{i}.T, s{i}.MX,
    s{i}.MY`` (colour, position, depth, lens, time, motion of sample ``i``) and the
    attributes ``clrecon:format = "samples"``, ``clrecon:spp`` (int), ``clrecon:coc_c0`` and
    ``clrecon:coc_c1``. The CoC coefficients are stored as strings (``repr`` of the Python
    float): OpenImageIO writes float attributes to EXR in single precision and drops double
    ones, and neither would round-trip a ``CocModel`` exactly.
``.npz``
    ``numpy.savez`` (uncompressed) with the six fields, ``coc = [c0, c1]`` (float64) and
    ``format_version = 1``.

TLFR motion conversion
----------------------
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

Other TLFR columns: ``z/w`` is written as ``w / (w + 1)`` for hits and ``1.0`` for misses
(finite, increasing with depth, in (0, 1]; the reference code does not use it) and is ignored
on load; ``a = 1``, ``dwdx = dwdy = 0`` on save, all three ignored on load. Miss depth is
written as is (``inf`` in binary, ``"inf"`` in text). Text values are written with ``%.9g``,
which round-trips float32 exactly. The CoC coefficients are written with ``repr`` (exact).

Images (:func:`load_image`, :func:`save_image`): ``.exr`` is linear float32 (never half);
``.png`` is 8-bit sRGB, tone mapped by :func:`tonemap_srgb` on save and decoded back to
linear with :func:`srgb_to_linear` on load.

Limits
------
Every loader checks what a file declares before it allocates anything sized by it, and
refuses a malformed file with a ``ValueError`` naming the file (and the field, member, line
or sample); every result then passes :meth:`SampleBuffer.validate`, so bad values raise a
``ValueError`` naming the field and the first bad sample.

TLFR (``.bin`` / ``.txt``)
    Header at most 64 KiB; ``W*H*S`` at most :data:`TLFR_MAX_RECORDS` (``2**31``) records.
    The data file's size is checked against the header first: binary exactly ``W*H*S*64``
    bytes, text at least ``W*H*S*32`` (the shortest record line), so the ``(W*H*S, 16)``
    float32 records never exceed twice the file's size. Text is parsed in chunks of
    :data:`_TLFR_TEXT_READ` bytes (1 MiB) straight into the preallocated records; a line
    may not be longer than a chunk, and a finite value beyond float32's range is refused
    (it would silently become ``inf``, a miss). Peak memory: the records, the buffer's
    fields and one chunk.
``.exr``
    ``clrecon:spp`` must be a positive integer, compared with the channel count
    (``11 * spp``) before anything is built from it; ``W*H*S`` at most
    :data:`EXR_MAX_SAMPLES` (``2**31``), checked before the pixels are read. OpenImageIO's
    own limits apply when the file is opened (``limits:resolution``, ``limits:imagesize_MB``
    and ``limits:channels``, by default 1024 channels, so ``S <= 93`` unless raised). A file
    OpenImageIO cannot read raises :class:`ImageReadError` (a ``ValueError`` and an
    ``OSError``).
``.npz``
    Only stored and deflated members are read. Every member's ``.npy`` header (version 1 or
    2, numeric dtype, no objects: nothing is unpickled) and its ``ZipInfo.file_size`` are
    checked before any data is decompressed: the stored size must be what the header's
    shape and dtype imply, a deflated member may not claim more than 1032 times its
    compressed size (deflate's ceiling), the six fields must agree in ``(H, W, S)``, and
    ``H*W*S`` is at most :data:`NPZ_MAX_SAMPLES` (``2**31``). Decompression is streamed into
    the preallocated array; a finite value beyond float32's range is refused.

Safe writes: every file is written to a new temporary file in the same folder (created with
mode ``0o666`` less the umask, flushed to disk) and then renamed over the target with
:func:`os.replace`, so a reader sees the old file or the new one, never part of one; on any
failure the temporary file is removed and the target is left as it was. A TLFR pair is
renamed only once both files are written and neither target is a directory; if the second
rename still fails, the first target is restored (from a hard link to the old file).
"""
from __future__ import annotations

import contextlib
import errno
import math
import os
import re
import struct
import tokenize
import zipfile
import zlib

import numpy as np
from numpy.typing import ArrayLike

from clrecon.core.camera import CocModel
from clrecon.core.samples import FIELDS, MISS_DEPTH, SampleBuffer

#: sample-buffer extensions understood by :func:`load_samples` / :func:`save_samples`
SAMPLE_EXTENSIONS = (".bin", ".txt", ".exr", ".npz")
#: image extensions understood by :func:`load_image` / :func:`save_image`
IMAGE_EXTENSIONS = (".exr", ".png")

TLFR_VERSION = "1.3"
TLFR_FIELDS = (
    "x", "y", "z/w", "w", "u", "v", "t", "r", "g", "b", "a",
    "mv_x", "mv_y", "mv_w", "dwdx", "dwdy",
)
#: records refused beyond this count (a header that large is corrupt or hostile)
TLFR_MAX_RECORDS = 2**31
_TLFR_RECORD_BYTES = 16 * 4
#: shortest possible text record: 16 one-character numbers, 15 commas, a newline
_TLFR_MIN_TEXT_RECORD = 32
_TLFR_MAX_HEADER_BYTES = 1 << 16
#: records per formatting call when writing text
_TLFR_TEXT_CHUNK = 1 << 16
#: bytes per read when parsing text (also the longest line accepted)
_TLFR_TEXT_READ = 1 << 20
#: records per block of the motion conversion (bounds its float64 temporaries)
_TLFR_MOTION_BLOCK = 1 << 14

# sRGB OETF 1.055 x**(1/2.4) - 0.055 in float32, with the offset taken as exactly
# float32(1.055) - 1 (within 5e-8 of 0.055) so that 1 maps to exactly 1
_SRGB_A = np.float32(1.055)
_SRGB_B = _SRGB_A - np.float32(1.0)

EXR_SAMPLE_CHANNELS = ("R", "G", "B", "X", "Y", "Z", "U", "V", "T", "MX", "MY")
EXR_FORMAT_NAME = "samples"
#: samples (W*H*S) refused beyond this count in a sample EXR
EXR_MAX_SAMPLES = 2**31
NPZ_FORMAT_VERSION = 1
#: samples (H*W*S) refused beyond this count in an .npz
NPZ_MAX_SAMPLES = 2**31
#: the most a deflate stream can expand (zlib's documented ceiling, 1032:1)
_DEFLATE_MAX_RATIO = 1032
#: bytes per read when streaming an .npz member into its array
_NPZ_READ = 1 << 20
_NPZ_MEMBERS = (*FIELDS, "coc", "format_version")

_F32_MAX = float(np.finfo(np.float32).max)


class ImageReadError(ValueError, OSError):
    """OpenImageIO could not open or read a file: bad input (a ``ValueError``, naming the
    file) that is also an ``OSError``, as these errors were before."""


# ==========================================================================================
# public API
# ==========================================================================================
def load_samples(path: str | os.PathLike, allow_negative: bool = False) -> SampleBuffer:
    """Load a sample buffer; the format follows the extension.

    Parameters
    ----------
    path : str or os.PathLike
        ``.bin`` / ``.txt`` (TLFR 1.3, header in ``path + ".header"``), ``.exr`` or ``.npz``.
    allow_negative : bool
        Accept negative radiance (see :meth:`SampleBuffer.validate`).

    Returns
    -------
    SampleBuffer
        The buffer, already validated.

    Raises
    ------
    ValueError
        Unknown extension, malformed file, a file beyond the format's limits (see the module
        docstring), or data that fails :meth:`SampleBuffer.validate` (the message names the
        field and the first offending sample). An EXR file OpenImageIO cannot read raises
        :class:`ImageReadError`, a ``ValueError`` that is also an ``OSError``.
    FileNotFoundError
        The file (or the TLFR header) does not exist.
    """
    path = os.fspath(path)
    ext = _extension(path, SAMPLE_EXTENSIONS, "sample buffer")
    if ext in (".bin", ".txt"):
        buf = _load_tlfr(path)
    elif ext == ".exr":
        buf = _load_samples_exr(path)
    else:
        buf = _load_samples_npz(path)
    return buf.validate(allow_negative=allow_negative)


def save_samples(
    path: str | os.PathLike, buf: SampleBuffer, *, encoding: str | None = None
) -> None:
    """Save a sample buffer; the format follows the extension.

    Parameters
    ----------
    path : str or os.PathLike
        ``.bin`` / ``.txt`` (TLFR 1.3; the header goes to ``path + ".header"``), ``.exr`` or
        ``.npz``. The parent directory must exist. Written atomically (a temporary file in
        the same folder, then :func:`os.replace`): on failure the old file, or TLFR pair,
        is left as it was.
    buf : SampleBuffer
        The buffer; it is validated first.
    encoding : {None, "binary", "text"}, optional
        TLFR data encoding. ``None`` (default) picks ``"text"`` for ``.txt`` and ``"binary"``
        for ``.bin``. Must be ``None`` for ``.exr`` and ``.npz``.

    Raises
    ------
    ValueError
        Unknown extension or encoding, or ``buf`` fails validation.
    FileNotFoundError
        The parent directory does not exist.
    OSError
        Writing failed (OpenImageIO's message is included for EXR); nothing was replaced.
    """
    path = os.fspath(path)
    ext = _extension(path, SAMPLE_EXTENSIONS, "sample buffer")
    if not isinstance(buf, SampleBuffer):
        raise TypeError(f"buf must be a SampleBuffer, got {type(buf).__name__}")
    if ext in (".bin", ".txt"):
        if encoding is None:
            encoding = "text" if ext == ".txt" else "binary"
        if encoding not in ("binary", "text"):
            raise ValueError(f"encoding must be 'binary' or 'text', got {encoding!r}")
    elif encoding is not None:
        raise ValueError(f"encoding applies to TLFR (.bin/.txt) only, not to {ext} ({path})")
    buf.validate()
    _check_parent(path)
    if ext in (".bin", ".txt"):
        _save_tlfr(path, buf, encoding)
    elif ext == ".exr":
        _save_samples_exr(path, buf)
    else:
        _save_samples_npz(path, buf)


def tonemap_srgb(img: ArrayLike) -> np.ndarray:
    """Clip linear radiance to [0, 1] and apply the sRGB transfer function (OETF).

    Pure, element-wise NumPy: ``12.92 x`` for ``x <= 0.0031308``, else
    ``1.055 x**(1/2.4) - 0.055``. NaN stays NaN.

    Parameters
    ----------
    img : array_like
        Linear values, any shape.

    Returns
    -------
    numpy.ndarray
        float32 array of the same shape, values in [0, 1] (``tonemap_srgb(0.5) ~ 0.7354``).
    """
    x = np.clip(np.asarray(img, dtype=np.float32), np.float32(0.0), np.float32(1.0))
    with np.errstate(invalid="ignore"):
        out = np.where(
            x <= np.float32(0.0031308),
            x * np.float32(12.92),
            _SRGB_A * np.power(x, np.float32(1.0 / 2.4)) - _SRGB_B,
        )
    return np.clip(out, np.float32(0.0), np.float32(1.0)).astype(np.float32, copy=False)


def srgb_to_linear(img: ArrayLike) -> np.ndarray:
    """Inverse of the sRGB transfer function (EOTF), for decoding 8-bit images.

    Parameters
    ----------
    img : array_like
        sRGB-encoded values in [0, 1], any shape.

    Returns
    -------
    numpy.ndarray
        float32 linear values of the same shape: ``v / 12.92`` for ``v <= 0.04045``, else
        ``((v + 0.055) / 1.055) ** 2.4``.
    """
    v = np.asarray(img, dtype=np.float32)
    with np.errstate(invalid="ignore"):
        out = np.where(
            v <= np.float32(0.04045),
            v / np.float32(12.92),
            np.power((v + np.float32(0.055)) / np.float32(1.055), np.float32(2.4)),
        )
    return out.astype(np.float32, copy=False)


def save_image(path: str | os.PathLike, img: ArrayLike) -> None:
    """Write an image: ``.exr`` as linear float32, ``.png`` tone mapped to 8-bit sRGB.

    Parameters
    ----------
    path : str or os.PathLike
        Output file; its parent directory must exist. Written atomically, as
        :func:`save_samples` writes.
    img : array_like
        (H, W, 3) linear RGB; (H, W) or (H, W, 1) greyscale is replicated to RGB and
        (H, W, 4) has its alpha dropped.

    Raises
    ------
    ValueError
        Unknown extension, bad shape, or NaN in an image bound for PNG.
    FileNotFoundError
        The parent directory does not exist.
    OSError
        OpenImageIO failed to write (its message is included); nothing was replaced.
    """
    import OpenImageIO as oiio

    path = os.fspath(path)
    ext = _extension(path, IMAGE_EXTENSIONS, "image")
    rgb = _as_rgb(img)
    h, w = rgb.shape[:2]
    _check_parent(path)
    if ext == ".exr":
        spec, pixels = oiio.ImageSpec(w, h, 3, "float"), rgb
    else:
        if np.isnan(rgb).any():
            idx = tuple(int(i) for i in np.argwhere(np.isnan(rgb))[0])
            raise ValueError(f"img: NaN at (y={idx[0]}, x={idx[1]}, c={idx[2]}); cannot tone map")
        spec = oiio.ImageSpec(w, h, 3, "uint8")
        pixels = np.round(tonemap_srgb(rgb) * np.float32(255.0)).astype(np.uint8)
    with _atomic_write(path) as (tmp,):
        _oiio_write(tmp, spec, pixels, path)


def load_image(path: str | os.PathLike) -> np.ndarray:
    """Read an image as linear float32 RGB.

    Parameters
    ----------
    path : str or os.PathLike
        ``.exr`` (read as stored, linear) or ``.png`` (decoded with :func:`srgb_to_linear`).

    Returns
    -------
    numpy.ndarray
        (H, W, 3) float32. Greyscale images are replicated to RGB; alpha is dropped.

    Raises
    ------
    ValueError
        Unknown extension or an unsupported channel layout; :class:`ImageReadError` (also
        an ``OSError``) when OpenImageIO cannot read the file (its message is included).
    FileNotFoundError
        The file does not exist.
    """
    path = os.fspath(path)
    ext = _extension(path, IMAGE_EXTENSIONS, "image")
    info, pixels = _oiio_read(path)
    names = info["channelnames"]
    if all(c in names for c in ("R", "G", "B")):
        rgb = pixels[..., [names.index(c) for c in ("R", "G", "B")]]
    elif len(names) in (1, 2):  # grey, grey + alpha
        rgb = np.repeat(pixels[..., :1], 3, axis=-1)
    elif len(names) in (3, 4):
        rgb = pixels[..., :3]
    else:
        raise ValueError(f"{path}: cannot find RGB among channels {list(names)}")
    rgb = np.ascontiguousarray(rgb, dtype=np.float32)
    if ext == ".png":
        rgb = srgb_to_linear(rgb)
    return rgb


# ==========================================================================================
# helpers
# ==========================================================================================
def _extension(path: str, allowed: tuple[str, ...], what: str) -> str:
    ext = os.path.splitext(path)[1].lower()
    if ext not in allowed:
        raise ValueError(
            f"unsupported {what} file extension {ext or '(none)'!r} in {path!r}; "
            f"supported: {', '.join(allowed)}"
        )
    return ext


def _check_exists(path: str, what: str = "file") -> None:
    if not os.path.isfile(path):
        raise FileNotFoundError(errno.ENOENT, f"{what} not found", path)


def _check_parent(path: str) -> None:
    parent = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(parent):
        raise FileNotFoundError(
            errno.ENOENT, f"cannot write {path!r}: directory does not exist", parent
        )


def _as_rgb(img: ArrayLike) -> np.ndarray:
    a = np.asarray(img)
    if a.dtype.kind not in "fiub":
        raise ValueError(f"img: expected a numeric array, got dtype {a.dtype}")
    a = a.astype(np.float32, copy=False)
    if a.ndim == 2:
        a = a[:, :, None]
    if a.ndim != 3 or a.shape[2] not in (1, 3, 4) or a.shape[0] < 1 or a.shape[1] < 1:
        raise ValueError(
            f"img: expected shape (H, W, 3), (H, W), (H, W, 1) or (H, W, 4), got {a.shape}"
        )
    if a.shape[2] == 1:
        a = np.repeat(a, 3, axis=2)
    return np.ascontiguousarray(a[:, :, :3])


def _sample_index(flat: int, width: int, spp: int) -> str:
    i = flat % spp
    x = (flat // spp) % width
    y = flat // (spp * width)
    return f"sample (y={y}, x={x}, i={i}) (record {flat})"


# ==========================================================================================
# safe writes
# ==========================================================================================
def _sibling(path: str, tag: str) -> str:
    """A fresh hidden name next to ``path`` that keeps its extension (OpenImageIO picks the
    format by extension): ``dir/.NAME.<random>.<tag>EXT``."""
    head, tail = os.path.split(os.path.abspath(path))
    return os.path.join(head, f".{tail}.{os.urandom(6).hex()}.{tag}{os.path.splitext(tail)[1]}")


def _new_temp(path: str) -> str:
    """Create an empty temporary file next to ``path`` (mode 0o666 less the umask)."""
    while True:
        tmp = _sibling(path, "tmp")
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        except FileExistsError:  # pragma: no cover - 48 random bits
            continue
        os.close(fd)
        return tmp


def _remove_quietly(path: str) -> None:
    with contextlib.suppress(OSError):
        os.remove(path)


def _fsync(path: str) -> None:
    fd = os.open(path, os.O_RDWR)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


@contextlib.contextmanager
def _atomic_write(*paths: str):
    """Yield one new temporary path per target; when the block succeeds, flush them and
    rename each over its target (:func:`_replace_all`). On any failure every temporary file
    is removed and no target is touched."""
    temps: list[str] = []
    try:
        for path in paths:
            temps.append(_new_temp(path))
        yield tuple(temps)
        for tmp in temps:
            _fsync(tmp)
        _replace_all(temps, paths)
    finally:
        for tmp in temps:  # gone already after a successful rename
            _remove_quietly(tmp)


def _backup(path: str) -> str | None:
    """Keep the current ``path`` (if any) under a hidden name: a hard link, or where links
    fail, the file itself moved aside."""
    if not os.path.isfile(path):
        return None
    keep = _sibling(path, "old")
    try:
        os.link(path, keep)
    except OSError:
        os.replace(path, keep)
    return keep


def _replace_all(temps: list[str], paths: tuple[str, ...]) -> None:
    """Rename ``temps`` over ``paths`` in order, after checking that no target is a
    directory; if a rename fails, the targets renamed before it are restored."""
    for path in paths:
        if os.path.isdir(path):
            raise IsADirectoryError(errno.EISDIR, "cannot replace a directory", path)
    done: list[tuple[str, str | None]] = []  # (target, its old file) renamed so far
    try:
        for k, (tmp, path) in enumerate(zip(temps, paths)):
            keep = _backup(path) if k < len(paths) - 1 else None
            done.append((path, keep))
            os.replace(tmp, path)
    except BaseException:
        for path, keep in reversed(done):
            if keep is not None:
                os.replace(keep, path)  # the old file back (undoes a move aside too)
            elif path != done[-1][0]:
                _remove_quietly(path)  # a new file where there was none
        raise
    for _, keep in done:
        if keep is not None:
            _remove_quietly(keep)


# ==========================================================================================
# OpenImageIO
# ==========================================================================================
def _oiio_error(source) -> str:
    """``source.geterror()``; a message OpenImageIO cannot decode (it may quote the bytes of
    a damaged file) is reported as such."""
    try:
        return source.geterror()
    except UnicodeDecodeError as exc:
        return f"(undecodable error message: {exc})"


def _oiio_write(path: str, spec: object, pixels: np.ndarray, shown: str | None = None) -> None:
    """Write ``pixels`` to ``path``; messages name ``shown`` (the target of a temp file)."""
    import OpenImageIO as oiio

    shown = shown or path
    out = oiio.ImageOutput.create(path)
    if out is None:
        raise OSError(f"cannot write {shown!r}: {_oiio_error(oiio)}")
    if not out.open(path, spec):
        raise OSError(f"cannot open {shown!r} for writing: {_oiio_error(out)}")
    try:
        if not out.write_image(pixels):
            raise OSError(f"cannot write {shown!r}: {_oiio_error(out)}")
    except BaseException:
        out.close()
        raise
    if not out.close():
        raise OSError(f"cannot finish writing {shown!r}: {_oiio_error(out)}")


def _oiio_read(path: str, check=None) -> tuple[dict, np.ndarray]:
    """Pixels of subimage 0 as float32 (H, W, C) and the facts of its spec that we use;
    ``check(info)``, if given, runs before the pixels are read (and may refuse them)."""
    import OpenImageIO as oiio

    _check_exists(path)
    inp = oiio.ImageInput.open(path)
    if inp is None:
        raise ImageReadError(f"cannot open {path!r}: {_oiio_error(oiio)}")
    try:
        spec = inp.spec()
        if spec.deep:
            raise ValueError(f"{path}: deep images are not supported")
        try:
            info = {
                "width": int(spec.width),
                "height": int(spec.height),
                "channelnames": tuple(spec.channelnames),
                "attrs": {key: spec.getattribute(key) for key in
                          ("clrecon:format", "clrecon:spp", "clrecon:coc_c0", "clrecon:coc_c1")},
            }
        except UnicodeDecodeError as exc:
            raise ImageReadError(f"{path}: undecodable text in the header ({exc})") from None
        if check is not None:
            check(info)
        nch = int(spec.nchannels)
        pixels = inp.read_image(0, 0, 0, nch, "float")
        if pixels is None:
            raise ImageReadError(f"cannot read {path!r}: {_oiio_error(inp)}")
    finally:
        inp.close()
    pixels = np.asarray(pixels, dtype=np.float32).reshape(info["height"], info["width"], nch)
    return info, pixels


# ==========================================================================================
# EXR sample buffers
# ==========================================================================================
def _save_samples_exr(path: str, buf: SampleBuffer) -> None:
    import OpenImageIO as oiio

    h, w, s = buf.shape
    nc = len(EXR_SAMPLE_CHANNELS)
    data = np.empty((h, w, s, nc), np.float32)
    data[..., 0:3] = buf.color
    data[..., 3:5] = buf.position
    data[..., 5] = buf.depth
    data[..., 6:8] = buf.lens
    data[..., 8] = buf.time
    data[..., 9:11] = buf.motion
    spec = oiio.ImageSpec(w, h, nc * s, "float")
    spec.channelnames = tuple(f"s{i}.{c}" for i in range(s) for c in EXR_SAMPLE_CHANNELS)
    spec.attribute("clrecon:format", EXR_FORMAT_NAME)
    spec.attribute("clrecon:spp", int(s))
    # strings: OIIO stores float attributes in EXR as float32 and drops doubles
    spec.attribute("clrecon:coc_c0", repr(float(buf.coc_model.c0)))
    spec.attribute("clrecon:coc_c1", repr(float(buf.coc_model.c1)))
    with _atomic_write(path) as (tmp,):
        _oiio_write(tmp, spec, data.reshape(h, w, nc * s), path)


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


def _load_samples_exr(path: str) -> SampleBuffer:
    layout = []
    info, pixels = _oiio_read(path, lambda info: layout.append(_exr_layout(path, info)))
    spp, model, order = layout[0]
    h, w = info["height"], info["width"]
    if order != list(range(len(order))):
        pixels = pixels[..., order]
    data = pixels.reshape(h, w, spp, len(EXR_SAMPLE_CHANNELS))
    return SampleBuffer(
        color=data[..., 0:3],
        position=data[..., 3:5],
        depth=data[..., 5],
        lens=data[..., 6:8],
        time=data[..., 8],
        motion=data[..., 9:11],
        coc_model=model,
    )


# ==========================================================================================
# npz
# ==========================================================================================
def _save_samples_npz(path: str, buf: SampleBuffer) -> None:
    arrays = buf.arrays()
    with _atomic_write(path) as (tmp,), open(tmp, "wb") as f:
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
                f"beyond float32's range (largest finite {_F32_MAX:.8g}; "
                f"{count} bad sample{'s' if count != 1 else ''})")
    return out


def _load_samples_npz(path: str) -> SampleBuffer:
    _check_exists(path)
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


# ==========================================================================================
# TLFR
# ==========================================================================================
_HEADER_KEYS = {
    # key -> (pattern on the whitespace-normalised, lower-cased line, display name)
    "version": (re.compile(r"^version\s*[:=]?\s*(.*)$"), "Version"),
    "width": (re.compile(r"^width\s*[:=]?\s*(.*)$"), "Width"),
    "height": (re.compile(r"^height\s*[:=]?\s*(.*)$"), "Height"),
    "spp": (re.compile(r"^samples\s+per\s+pixel\s*[:=]?\s*(.*)$"), "Samples per pixel"),
    "motion": (re.compile(r"^motion\s+model\s*[:=]?\s*(.*)$"), "Motion model"),
    "coc": (
        re.compile(r"^coc\s+coefficients\s*(?:\([^)]*\))?\s*[:=]?\s*(.*)$"),
        "CoC coefficients",
    ),
    "encoding": (re.compile(r"^encoding\s*[:=]?\s*(.*)$"), "Encoding"),
    "fields": (re.compile(r"^(x\s*,.*)$"), "field names"),
}
_HEADER_REQUIRED = ("version", "width", "height", "spp", "coc", "encoding")


def _tlfr_header_values(header_path: str) -> dict[str, str]:
    """The raw value of each key of a TLFR header (at most 64 KiB of UTF-8 text; every line
    one known key, none twice)."""
    _check_exists(header_path, "TLFR header file")
    with open(header_path, "rb") as f:
        raw = f.read(_TLFR_MAX_HEADER_BYTES + 1)
    if len(raw) > _TLFR_MAX_HEADER_BYTES:
        raise ValueError(f"{header_path}: TLFR header larger than {_TLFR_MAX_HEADER_BYTES} bytes")
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ValueError(f"{header_path}: TLFR header is not text ({exc})") from None

    values: dict[str, str] = {}
    for lineno, line in enumerate(text.splitlines(), start=1):
        norm = " ".join(line.split())
        if not norm:
            continue
        low = norm.lower()
        for key, (pattern, display) in _HEADER_KEYS.items():
            m = pattern.match(low)
            if m:
                if key in values:
                    raise ValueError(f"{header_path}: line {lineno}: duplicate key {display!r}")
                values[key] = m.group(1).strip()
                break
        else:
            raise ValueError(f"{header_path}: line {lineno}: unrecognised header line {line!r}")
    return values


def _parse_tlfr_header(header_path: str) -> dict:
    """Parse a TLFR 1.3 header: order and whitespace free, every required key present.

    ``Motion model`` (must be ``perspective``) and the field-name line (must list the 16
    standard fields) are optional: the reference writer omits the former.
    """
    values = _tlfr_header_values(header_path)

    def fail(key: str, what: str) -> ValueError:
        return ValueError(f"{header_path}: {_HEADER_KEYS[key][1]!r}: {what}")

    for key in _HEADER_REQUIRED:
        if key not in values:
            raise fail(key, "missing key")

    try:
        version_ok = float(values["version"]) == float(TLFR_VERSION)
    except ValueError:
        version_ok = False
    if not version_ok:
        raise fail("version", f"unsupported version {values['version']!r} (only "
                              f"{TLFR_VERSION} is supported)")

    sizes = {}
    for key in ("width", "height", "spp"):
        try:
            n = int(values[key])
        except ValueError:
            raise fail(key, f"expected a positive integer, got {values[key]!r}") from None
        if n < 1:
            raise fail(key, f"expected a positive integer, got {n}")
        sizes[key] = n

    parts = values["coc"].split(",")
    try:
        if len(parts) != 2:
            raise ValueError
        c0, c1 = (float(p) for p in parts)
    except ValueError:
        raise fail("coc", f"expected 'C0,C1', got {values['coc']!r}") from None
    if not (math.isfinite(c0) and math.isfinite(c1)):
        raise fail("coc", f"coefficients must be finite, got {values['coc']!r}")

    encoding = values["encoding"]
    if encoding not in ("binary", "text"):
        raise fail("encoding", f"expected 'binary' or 'text', got {encoding!r}")

    if "motion" in values and values["motion"] != "perspective":
        raise fail("motion", f"only 'perspective' is supported, got {values['motion']!r}")
    if "fields" in values:
        found = tuple(f.strip() for f in values["fields"].split(","))
        if found != TLFR_FIELDS:
            raise fail("fields", f"expected {','.join(TLFR_FIELDS)}, got {values['fields']!r}")

    return {
        "width": sizes["width"],
        "height": sizes["height"],
        "spp": sizes["spp"],
        "coc_model": CocModel(c0, c1),
        "encoding": encoding,
    }


def _load_tlfr(path: str) -> SampleBuffer:
    header_path = path + ".header"
    hdr = _parse_tlfr_header(header_path)
    width, height, spp = hdr["width"], hdr["height"], hdr["spp"]
    n = width * height * spp
    _check_exists(path, "TLFR data file")
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
        records = _read_tlfr_text(path, n)
    records = records.astype(np.float32, copy=False).reshape(height, width, spp, 16)
    motion = _tlfr_motion(records, hdr["coc_model"], path)
    return SampleBuffer(
        color=records[..., 7:10],
        position=records[..., 0:2],
        depth=records[..., 3],
        lens=records[..., 4:6],
        time=records[..., 6],
        motion=motion,
        coc_model=hdr["coc_model"],
    )


# the reference writer ends every line with a comma
_TRAILING_COMMA = re.compile(r",[ \t]*(?=\r\n|\r|\n|\Z)")


def _text_chunks(path: str):
    """Yield ``(first line number, lines)`` of a text data file, :data:`_TLFR_TEXT_READ`
    bytes at a time, cut at line ends (never inside ``\r\n``); the lines are those of
    ``str.splitlines()`` on the whole text, each without its trailing comma."""
    with open(path, "rb") as f:
        carry, lineno = b"", 1
        while True:
            block = f.read(_TLFR_TEXT_READ)
            data = carry + block
            if not data:
                return
            if block:
                cut = max(data.rfind(b"\n"), data.rfind(b"\r", 0, len(data) - 1)) + 1
                if not cut:
                    if len(data) > _TLFR_TEXT_READ:
                        raise ValueError(f"{path}: line {lineno}: longer than "
                                         f"{_TLFR_TEXT_READ} bytes")
                    carry = data
                    continue
                data, carry = data[:cut], data[cut:]
            else:
                carry = b""
            try:
                text = data.decode("ascii")
            except UnicodeDecodeError as exc:
                line = lineno + len((data[:exc.start] + b"x").splitlines()) - 1
                raise ValueError(f"{path}: text TLFR data is not ASCII (line {line}: "
                                 f"{exc})") from None
            lines = _TRAILING_COMMA.sub("", text).splitlines()
            yield lineno, lines
            lineno += len(lines)


def _read_tlfr_text(path: str, n: int) -> np.ndarray:
    """Parse ``n`` text records into an (n, 16) float32 array, chunk by chunk (one trailing
    comma per line allowed; blank lines only at the end)."""
    out = np.empty((n, 16), np.float32)
    row = 0
    blank = None  # first line of a run of blank lines not (yet) followed by data
    for lineno, lines in _text_chunks(path):
        k = len(lines)
        while k and not lines[k - 1].strip():
            k -= 1
        if k and blank is not None:
            if blank > n:
                break
            raise ValueError(f"{path}: line {blank} is empty")
        if row + k > n:
            break
        if k:
            out[row:row + k] = _parse_text_lines(path, lines[:k], lineno)
            row += k
        if k < len(lines) and blank is None:
            blank = lineno + k
    else:
        if row < n:
            raise ValueError(f"{path}: truncated: the file ends after line {row}, expected {n} "
                             f"lines (one per record); line {row + 1} is missing")
        return out
    raise ValueError(f"{path}: line {n + 1}: unexpected data after the {n} expected records")


def _parse_text_lines(path: str, lines: list[str], first: int) -> np.ndarray:
    """(len(lines), 16) float32 records of lines ``first...``; refuses finite values beyond
    float32's range (they would become inf)."""
    try:
        data = np.loadtxt(lines, delimiter=",", dtype=np.float64, ndmin=2, comments=None)
    except ValueError as exc:
        _locate_text_error(path, lines, first)
        raise ValueError(f"{path}: cannot parse text TLFR data: {exc}") from None
    if data.shape != (len(lines), 16):
        _locate_text_error(path, lines, first)
        raise ValueError(f"{path}: expected {len(lines)} records of 16 values from line "
                         f"{first}, parsed {data.shape}")
    with np.errstate(over="ignore"):
        records = data.astype(np.float32)
    bad = np.isinf(records) & np.isfinite(data)
    if bad.any():
        r, c = (int(v) for v in np.argwhere(bad)[0])
        raise ValueError(f"{path}: line {first + r}: value {c + 1} ({TLFR_FIELDS[c]}) "
                         f"{lines[r].split(',')[c].strip()!r} is beyond float32's range "
                         f"(largest finite {_F32_MAX:.8g})")
    return records


def _locate_text_error(path: str, lines: list[str], first: int = 1) -> None:
    """Raise a ValueError naming the first malformed line (slow; only on failure)."""
    for lineno, line in enumerate(lines, start=first):
        if not line.strip():
            raise ValueError(f"{path}: line {lineno} is empty")
        fields = line.split(",")
        if len(fields) != 16:
            raise ValueError(f"{path}: line {lineno}: expected 16 comma-separated values "
                             f"({','.join(TLFR_FIELDS)}), found {len(fields)}")
        for k, field_ in enumerate(fields):
            try:
                float(field_)
            except ValueError:
                raise ValueError(f"{path}: line {lineno}: value {k + 1} ({TLFR_FIELDS[k]}) "
                                 f"{field_.strip()!r} is not a number") from None


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
    rec[..., 0:2] = buf.position
    with np.errstate(invalid="ignore", over="ignore"):
        rec[..., 2] = np.where(hit, d64 / (d64 + 1.0), 1.0)
        mv = np.where(hit[..., None], buf.motion * d64[..., None], 0.0).astype(np.float32)
    bad = ~np.isfinite(mv).all(-1)
    if bad.any():
        flat = int(np.flatnonzero(bad.ravel())[0])
        raise ValueError(f"motion: {_sample_index(flat, w, s)}: motion * depth overflows "
                         "float32; cannot encode it in TLFR")
    rec[..., 3] = depth
    rec[..., 4:6] = buf.lens
    rec[..., 6] = buf.time
    rec[..., 7:10] = buf.color
    rec[..., 10] = 1.0
    rec[..., 11:13] = mv
    return rec.reshape(h * w * s, 16)


def _tlfr_header_text(buf: SampleBuffer, encoding: str) -> str:
    h, w, s = buf.shape
    c0, c1 = float(buf.coc_model.c0), float(buf.coc_model.c1)
    return (
        f"Version {TLFR_VERSION}\n"
        f"Width {w}\n"
        f"Height {h}\n"
        f"Samples per pixel {s}\n"
        "Motion model: perspective\n"
        f"CoC coefficients (coc radius = C0/w+C1): {c0!r},{c1!r}\n"
        f"Encoding = {encoding}\n"
        f"{','.join(TLFR_FIELDS)}\n"
    )


def _write_tlfr_data(f, records: np.ndarray, encoding: str) -> None:
    """Write (N, 16) float32 records to the binary file object ``f``."""
    if encoding == "binary":
        f.write(records.astype("<f4", copy=False).tobytes())
        return
    line = ",".join(["%.9g"] * 16) + "\n"
    for start in range(0, len(records), _TLFR_TEXT_CHUNK):
        chunk = records[start:start + _TLFR_TEXT_CHUNK]
        f.write(((line * len(chunk)) % tuple(chunk.ravel().tolist())).encode("ascii"))


def _save_tlfr(path: str, buf: SampleBuffer, encoding: str) -> None:
    """Both files to temporaries, then the data and the header renamed into place (see
    :func:`_replace_all`): a failure leaves the old pair, or nothing."""
    records = _tlfr_records(buf)
    with _atomic_write(path, path + ".header") as (data_tmp, header_tmp):
        with open(data_tmp, "wb") as f:
            _write_tlfr_data(f, records, encoding)
        with open(header_tmp, "wb") as f:
            f.write(_tlfr_header_text(buf, encoding).encode("ascii"))
