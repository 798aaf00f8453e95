"""Images through OpenImageIO, and the OpenImageIO plumbing the sample EXR shares.

Images (:func:`load_image`, :func:`save_image`): ``.exr`` is linear float32 (never half);
``.png`` is 8-bit sRGB, tone mapped by :func:`tonemap_srgb` on save and decoded back to
linear with :func:`srgb_to_linear` on load. Both are written atomically
(:func:`clrecon.io.files.atomic_write`). A file OpenImageIO cannot read raises
:class:`ImageReadError` (a ``ValueError`` and an ``OSError``).
"""
from __future__ import annotations

import os

import numpy as np
from numpy.typing import ArrayLike

from clrecon.io.files import atomic_write, check_exists, check_parent, extension

#: image extensions understood by :func:`load_image` / :func:`save_image`
IMAGE_EXTENSIONS = (".exr", ".png")

# sRGB OETF 1.055 x**(1/2.4) - 0.055 in float32, with the offset taken as exactly
# float32(1.055) - 1 (within 5e-8 of 0.055) so that 1 maps to exactly 1
_SRGB_A = np.float32(1.055)
_SRGB_B = _SRGB_A - np.float32(1.0)


class ImageReadError(ValueError, OSError):
    """OpenImageIO could not open or read a file: bad input (a ``ValueError``, naming the
    file) that is also an ``OSError``, as these errors were before."""


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
    ext = extension(path, IMAGE_EXTENSIONS, "image")
    rgb = _as_rgb(img)
    h, w = rgb.shape[:2]
    check_parent(path)
    if ext == ".exr":
        spec, pixels = oiio.ImageSpec(w, h, 3, "float"), rgb
    else:
        if np.isnan(rgb).any():
            idx = tuple(int(i) for i in np.argwhere(np.isnan(rgb))[0])
            raise ValueError(f"img: NaN at (y={idx[0]}, x={idx[1]}, c={idx[2]}); cannot tone map")
        spec = oiio.ImageSpec(w, h, 3, "uint8")
        pixels = np.round(tonemap_srgb(rgb) * np.float32(255.0)).astype(np.uint8)
    with atomic_write(path) as (tmp,):
        oiio_write(tmp, spec, pixels, path)


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
    ext = extension(path, IMAGE_EXTENSIONS, "image")
    info, pixels = oiio_read(path)
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


# ==========================================================================================
# OpenImageIO
# ==========================================================================================
def oiio_error(source) -> str:
    """``source.geterror()``; a message OpenImageIO cannot decode (it may quote the bytes of
    a damaged file) is reported as such."""
    try:
        return source.geterror()
    except UnicodeDecodeError as exc:
        return f"(undecodable error message: {exc})"


def oiio_write(path: str, spec: object, pixels: np.ndarray, shown: str | None = None) -> None:
    """Write ``pixels`` to ``path``; messages name ``shown`` (the target of a temp file)."""
    import OpenImageIO as oiio

    shown = shown or path
    out = oiio.ImageOutput.create(path)
    if out is None:
        raise OSError(f"cannot write {shown!r}: {oiio_error(oiio)}")
    if not out.open(path, spec):
        raise OSError(f"cannot open {shown!r} for writing: {oiio_error(out)}")
    try:
        if not out.write_image(pixels):
            raise OSError(f"cannot write {shown!r}: {oiio_error(out)}")
    except BaseException:
        out.close()
        raise
    if not out.close():
        raise OSError(f"cannot finish writing {shown!r}: {oiio_error(out)}")


def oiio_read(path: str, check=None) -> tuple[dict, np.ndarray]:
    """Pixels of subimage 0 as float32 (H, W, C) and the facts of its spec that we use;
    ``check(info)``, if given, runs before the pixels are read (and may refuse them)."""
    import OpenImageIO as oiio

    check_exists(path)
    inp = oiio.ImageInput.open(path)
    if inp is None:
        raise ImageReadError(f"cannot open {path!r}: {oiio_error(oiio)}")
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
            raise ImageReadError(f"cannot read {path!r}: {oiio_error(inp)}")
    finally:
        inp.close()
    pixels = np.asarray(pixels, dtype=np.float32).reshape(info["height"], info["width"], nch)
    return info, pixels

