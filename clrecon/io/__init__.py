"""Reading and writing sample buffers and images: the public API of the io package.

Sample buffers (:func:`load_samples`, :func:`save_samples`, in :mod:`clrecon.io.buffers`);
the format follows the extension:

``.bin`` / ``.txt``
    TLFR 1.3, the format of Lehtinen et al. 2011's public code (:mod:`clrecon.io.tlfr`, which
    also states how its perspective motion becomes clrecon's linear screen motion; header in
    :mod:`clrecon.io.tlfr_header`, text data in :mod:`clrecon.io.tlfr_text`).
``.exr``
    One flat multi-channel OpenEXR image of ``11 * S`` float channels (:mod:`clrecon.io.exr`).
``.npz``
    ``numpy.savez`` with the six fields, ``coc`` and ``format_version`` (:mod:`clrecon.io.npz`).

Images (:func:`load_image`, :func:`save_image`, :func:`tonemap_srgb`, :func:`srgb_to_linear`,
in :mod:`clrecon.io.image`): ``.exr`` linear float32, ``.png`` 8-bit sRGB.

Limits: every loader checks what a file declares before it allocates anything sized by it
(each format's module states its limits), and refuses a malformed file with a ``ValueError``
naming the file (and the field, member, line or sample); every result then passes
:meth:`SampleBuffer.validate`, so bad values raise a ``ValueError`` naming the field and the
first bad sample. A file OpenImageIO cannot read raises :class:`ImageReadError` (a
``ValueError`` and an ``OSError``).

Safe writes: every file is written to a temporary file in the same folder and renamed over
its target, so a reader sees the old file or the new one, never part of one
(:mod:`clrecon.io.files`).
"""
from __future__ import annotations

from clrecon.io.buffers import SAMPLE_EXTENSIONS, load_samples, save_samples
from clrecon.io.exr import EXR_FORMAT_NAME, EXR_MAX_SAMPLES, EXR_SAMPLE_CHANNELS
from clrecon.io.image import (
    IMAGE_EXTENSIONS,
    ImageReadError,
    load_image,
    save_image,
    srgb_to_linear,
    tonemap_srgb,
)
from clrecon.io.npz import NPZ_FORMAT_VERSION, NPZ_MAX_SAMPLES
from clrecon.io.tlfr import _TLFR_RECORD_BYTES as _TLFR_RECORD_BYTES
from clrecon.io.tlfr import TLFR_MAX_RECORDS
from clrecon.io.tlfr import _tlfr_motion as _tlfr_motion
from clrecon.io.tlfr_header import TLFR_FIELDS, TLFR_VERSION

# also here, outside __all__: _TLFR_RECORD_BYTES and _tlfr_motion, the record layout and
# the motion conversion that the input adapter (clrecon.core.adapter) mirrors on the device
__all__ = [
    "EXR_FORMAT_NAME", "EXR_MAX_SAMPLES", "EXR_SAMPLE_CHANNELS", "IMAGE_EXTENSIONS",
    "NPZ_FORMAT_VERSION", "NPZ_MAX_SAMPLES", "SAMPLE_EXTENSIONS", "TLFR_FIELDS",
    "TLFR_MAX_RECORDS", "TLFR_VERSION", "ImageReadError", "load_image", "load_samples",
    "save_image", "save_samples", "srgb_to_linear", "tonemap_srgb",
]
