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

Before anything sized by the header is allocated, the data file's size is checked against it
(binary: exactly ``W*H*S*64`` bytes; text: at least ``W*H*S*32``), and more than
``2**31`` records are refused. Every loader calls :meth:`SampleBuffer.validate` on its result,
so bad data raises a ``ValueError`` naming the field and the sample.

Images (:func:`load_image`, :func:`save_image`): ``.exr`` is linear float32 (never half);
``.png`` is 8-bit sRGB, tone mapped by :func:`tonemap_srgb` on save and decoded back to
linear with :func:`srgb_to_linear` on load.
"""
from __future__ import annotations

import errno
import math
import os
import re

import numpy as np
from numpy.typing import ArrayLike

from .camera import CocModel
from .samples import FIELDS, MISS_DEPTH, SampleBuffer

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
_TLFR_TEXT_CHUNK = 1 << 16

# sRGB OETF 1.055 x**(1/2.4) - 0.055 in float32, with the offset taken as exactly
# float32(1.055) - 1 (within 5e-8 of 0.055) so that 1 maps to exactly 1
_SRGB_A = np.float32(1.055)
_SRGB_B = _SRGB_A - np.float32(1.0)

EXR_SAMPLE_CHANNELS = ("R", "G", "B", "X", "Y", "Z", "U", "V", "T", "MX", "MY")
EXR_FORMAT_NAME = "samples"
NPZ_FORMAT_VERSION = 1


# ==========================================================================================
# public API
# ==========================================================================================
def load_samples(path: str | os.PathLike) -> SampleBuffer:
    """Load a sample buffer; the format follows the extension.

    Parameters
    ----------
    path : str or os.PathLike
        ``.bin`` / ``.txt`` (TLFR 1.3, header in ``path + ".header"``), ``.exr`` or ``.npz``.

    Returns
    -------
    SampleBuffer
        The buffer, already validated.

    Raises
    ------
    ValueError
        Unknown extension, malformed file, or data that fails :meth:`SampleBuffer.validate`
        (the message names the field and the first offending sample).
    FileNotFoundError
        The file (or the TLFR header) does not exist.
    OSError
        OpenImageIO could not read an EXR file (its message is included).
    """
    path = os.fspath(path)
    ext = _extension(path, SAMPLE_EXTENSIONS, "sample buffer")
    if ext in (".bin", ".txt"):
        buf = _load_tlfr(path)
    elif ext == ".exr":
        buf = _load_samples_exr(path)
    else:
        buf = _load_samples_npz(path)
    return buf.validate()


def save_samples(
    path: str | os.PathLike, buf: SampleBuffer, *, encoding: str | None = None
) -> None:
    """Save a sample buffer; the format follows the extension.

    Parameters
    ----------
    path : str or os.PathLike
        ``.bin`` / ``.txt`` (TLFR 1.3; the header goes to ``path + ".header"``), ``.exr`` or
        ``.npz``. The parent directory must exist.
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
        Writing failed (OpenImageIO's message is included for EXR).
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
        Output file; its parent directory must exist.
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
        OpenImageIO failed to write (its message is included).
    """
    import OpenImageIO as oiio

    path = os.fspath(path)
    ext = _extension(path, IMAGE_EXTENSIONS, "image")
    rgb = _as_rgb(img)
    h, w = rgb.shape[:2]
    _check_parent(path)
    if ext == ".exr":
        _oiio_write(path, oiio.ImageSpec(w, h, 3, "float"), rgb)
    else:
        if np.isnan(rgb).any():
            idx = tuple(int(i) for i in np.argwhere(np.isnan(rgb))[0])
            raise ValueError(f"img: NaN at (y={idx[0]}, x={idx[1]}, c={idx[2]}); cannot tone map")
        ldr = np.round(tonemap_srgb(rgb) * np.float32(255.0)).astype(np.uint8)
        _oiio_write(path, oiio.ImageSpec(w, h, 3, "uint8"), ldr)


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
        Unknown extension or an unsupported channel layout.
    FileNotFoundError
        The file does not exist.
    OSError
        OpenImageIO failed to read (its message is included).
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
# OpenImageIO
# ==========================================================================================
def _oiio_write(path: str, spec: object, pixels: np.ndarray) -> None:
    import OpenImageIO as oiio

    out = oiio.ImageOutput.create(path)
    if out is None:
        raise OSError(f"cannot write {path!r}: {oiio.geterror()}")
    if not out.open(path, spec):
        raise OSError(f"cannot open {path!r} for writing: {out.geterror()}")
    try:
        if not out.write_image(pixels):
            raise OSError(f"cannot write {path!r}: {out.geterror()}")
    except BaseException:
        out.close()
        raise
    if not out.close():
        raise OSError(f"cannot finish writing {path!r}: {out.geterror()}")


def _oiio_read(path: str) -> tuple[dict, np.ndarray]:
    """Pixels of subimage 0 as float32 (H, W, C) and the facts of its spec that we use."""
    import OpenImageIO as oiio

    _check_exists(path)
    inp = oiio.ImageInput.open(path)
    if inp is None:
        raise OSError(f"cannot open {path!r}: {oiio.geterror()}")
    try:
        spec = inp.spec()
        if spec.deep:
            raise ValueError(f"{path}: deep images are not supported")
        info = {
            "width": int(spec.width),
            "height": int(spec.height),
            "channelnames": tuple(spec.channelnames),
            "attrs": {
                key: spec.getattribute(key)
                for key in ("clrecon:format", "clrecon:spp", "clrecon:coc_c0", "clrecon:coc_c1")
            },
        }
        nch = int(spec.nchannels)
        pixels = inp.read_image(0, 0, 0, nch, "float")
        if pixels is None:
            raise OSError(f"cannot read {path!r}: {inp.geterror()}")
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
    _oiio_write(path, spec, data.reshape(h, w, nc * s))


def _load_samples_exr(path: str) -> SampleBuffer:
    info, pixels = _oiio_read(path)
    attrs = info["attrs"]
    if attrs["clrecon:format"] != EXR_FORMAT_NAME:
        raise ValueError(
            f"{path}: not a clrecon sample EXR (attribute clrecon:format is "
            f"{attrs['clrecon:format']!r}, expected {EXR_FORMAT_NAME!r})"
        )
    for key in ("clrecon:spp", "clrecon:coc_c0", "clrecon:coc_c1"):
        if attrs[key] is None:
            raise ValueError(f"{path}: missing attribute {key}")
    try:
        spp = int(attrs["clrecon:spp"])
        c0 = float(attrs["clrecon:coc_c0"])
        c1 = float(attrs["clrecon:coc_c1"])
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{path}: malformed clrecon attribute: {exc}") from None
    if spp < 1:
        raise ValueError(f"{path}: clrecon:spp must be positive, got {spp}")
    names = info["channelnames"]
    expected = [f"s{i}.{c}" for i in range(spp) for c in EXR_SAMPLE_CHANNELS]
    position = {n: k for k, n in enumerate(names)}
    missing = [n for n in expected if n not in position]
    if missing or len(names) != len(expected):
        detail = f"; missing {', '.join(missing[:5])}" + (", ..." if len(missing) > 5 else "")
        raise ValueError(
            f"{path}: expected {len(expected)} channels s{{i}}.{{"
            f"{','.join(EXR_SAMPLE_CHANNELS)}}} for clrecon:spp = {spp}, found "
            f"{len(names)}{detail if missing else ''}"
        )
    h, w = info["height"], info["width"]
    data = pixels[..., [position[n] for n in expected]].reshape(h, w, spp, len(EXR_SAMPLE_CHANNELS))
    return SampleBuffer(
        color=data[..., 0:3],
        position=data[..., 3:5],
        depth=data[..., 5],
        lens=data[..., 6:8],
        time=data[..., 8],
        motion=data[..., 9:11],
        coc_model=CocModel(c0, c1),
    )


# ==========================================================================================
# npz
# ==========================================================================================
def _save_samples_npz(path: str, buf: SampleBuffer) -> None:
    arrays = buf.arrays()
    with open(path, "wb") as f:  # a file object: numpy would append ".npz" to ".NPZ"
        np.savez(
            f,
            **arrays,
            coc=np.array([buf.coc_model.c0, buf.coc_model.c1], dtype=np.float64),
            format_version=np.int64(NPZ_FORMAT_VERSION),
        )


def _load_samples_npz(path: str) -> SampleBuffer:
    _check_exists(path)
    try:
        npz = np.load(path, allow_pickle=False)
    except (ValueError, OSError) as exc:
        raise ValueError(f"{path}: not a readable .npz file: {exc}") from None
    with npz:
        if not hasattr(npz, "files"):
            raise ValueError(f"{path}: expected an .npz archive, found a single array")
        required = [*FIELDS, "coc", "format_version"]
        missing = [k for k in required if k not in npz.files]
        if missing:
            raise ValueError(f"{path}: missing key(s) {', '.join(missing)} (required: "
                             f"{', '.join(required)})")
        version = npz["format_version"]
        if version.shape != () or int(version) != NPZ_FORMAT_VERSION:
            raise ValueError(f"{path}: format_version must be {NPZ_FORMAT_VERSION}, got {version}")
        coc = npz["coc"]
        if coc.shape != (2,):
            raise ValueError(f"{path}: coc must hold [c0, c1], got shape {coc.shape}")
        arrays = {}
        for name in FIELDS:
            arr = npz[name]
            if arr.dtype.kind not in "fiu":
                raise ValueError(f"{path}: {name} has non-numeric dtype {arr.dtype}")
            arrays[name] = arr
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


def _parse_tlfr_header(header_path: str) -> dict:
    """Parse a TLFR 1.3 header: order and whitespace free, every required key present.

    ``Motion model`` (must be ``perspective``) and the field-name line (must list the 16
    standard fields) are optional: the reference writer omits the former.
    """
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


_TRAILING_COMMA = re.compile(r",[ \t]*(?=\r?$)", re.MULTILINE)


def _read_tlfr_text(path: str, n: int) -> np.ndarray:
    """Parse ``n`` text records into an (n, 16) float32 array (one trailing comma allowed)."""
    with open(path, "rb") as f:
        raw = f.read()
    try:
        text = raw.decode("ascii")
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path}: text TLFR data is not ASCII ({exc})") from None
    del raw
    # the reference writer ends every line with a comma
    lines = _TRAILING_COMMA.sub("", text).splitlines()
    del text
    while lines and not lines[-1].strip():
        lines.pop()
    if len(lines) < n:
        raise ValueError(f"{path}: truncated: the file ends after line {len(lines)}, "
                         f"expected {n} lines (one per record); line {len(lines) + 1} is missing")
    if len(lines) > n:
        raise ValueError(f"{path}: line {n + 1}: unexpected data after the {n} expected records")
    try:
        data = np.loadtxt(lines, delimiter=",", dtype=np.float32, ndmin=2, comments=None)
    except ValueError as exc:
        _locate_text_error(path, lines)
        raise ValueError(f"{path}: cannot parse text TLFR data: {exc}") from None
    if data.shape != (n, 16):
        _locate_text_error(path, lines)
        raise ValueError(f"{path}: expected {n} records of 16 values, parsed {data.shape}")
    return data


def _locate_text_error(path: str, lines: list[str]) -> None:
    """Raise a ValueError naming the first malformed line (slow; only on failure)."""
    for lineno, line in enumerate(lines, start=1):
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
    """Screen motion P(1) - P(0) of (H, W, S, 16) records; see the module docstring."""
    height, width, spp = records.shape[:3]
    motion = np.zeros((height, width, spp, 2), np.float32)
    depth = records[..., 3]
    hit = (depth > 0) & (depth < MISS_DEPTH)  # NaN/negative depth: left to validate()
    if not hit.any():
        return motion
    r = records[hit].astype(np.float64)
    w, t = r[:, 3], r[:, 6]
    v_xy, v_w = r[:, 11:13], r[:, 13]
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        w0 = w - t * v_w
        w1 = w + (1.0 - t) * v_w
        crossing = (w0 <= 0) | (w1 <= 0)
        if crossing.any():
            k = int(np.flatnonzero(crossing)[0])
            flat = int(np.flatnonzero(hit.ravel())[k])
            raise ValueError(
                f"{path}: {_sample_index(flat, width, spp)}: motion crosses the camera plane "
                f"(homogeneous w is {w0[k]:g} at t=0 and {w1[k]:g} at t=1 for w={w[k]:g}, "
                f"t={t[k]:g}, mv_w={v_w[k]:g}); perspective motion cannot be linearised"
            )
        coc = model.c0 / w + model.c1
        centre = r[:, 0:2] - coc[:, None] * r[:, 4:6]
        general = w[:, None] * (v_xy - v_w[:, None] * centre) / (w0 * w1)[:, None]
        m = np.where((v_w == 0)[:, None], v_xy / w[:, None], general)
    motion[hit] = m
    return motion


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


def _save_tlfr(path: str, buf: SampleBuffer, encoding: str) -> None:
    h, w, s = buf.shape
    c0, c1 = float(buf.coc_model.c0), float(buf.coc_model.c1)
    header = (
        f"Version {TLFR_VERSION}\n"
        f"Width {w}\n"
        f"Height {h}\n"
        f"Samples per pixel {s}\n"
        "Motion model: perspective\n"
        f"CoC coefficients (coc radius = C0/w+C1): {c0!r},{c1!r}\n"
        f"Encoding = {encoding}\n"
        f"{','.join(TLFR_FIELDS)}\n"
    )
    records = _tlfr_records(buf)
    if encoding == "binary":
        with open(path, "wb") as f:
            records.astype("<f4", copy=False).tofile(f)
    else:
        line = ",".join(["%.9g"] * 16) + "\n"
        with open(path, "w", encoding="ascii", newline="\n") as f:
            for start in range(0, len(records), _TLFR_TEXT_CHUNK):
                chunk = records[start:start + _TLFR_TEXT_CHUNK]
                f.write((line * len(chunk)) % tuple(chunk.ravel().tolist()))
    with open(path + ".header", "w", encoding="ascii", newline="\n") as f:
        f.write(header)
