"""Sample buffers: :func:`load_samples` and :func:`save_samples`, by extension.

``.bin`` / ``.txt``: TLFR 1.3 (:mod:`clrecon.io.tlfr`); ``.exr``: one flat multi-channel
OpenEXR image (:mod:`clrecon.io.exr`); ``.npz``: ``numpy.savez`` (:mod:`clrecon.io.npz`).
"""
from __future__ import annotations

import os

from clrecon.core.samples import SampleBuffer
from clrecon.io.exr import load_samples_exr, save_samples_exr
from clrecon.io.files import check_parent, extension
from clrecon.io.npz import load_samples_npz, save_samples_npz
from clrecon.io.tlfr import load_tlfr, save_tlfr

#: sample-buffer extensions understood by :func:`load_samples` / :func:`save_samples`
SAMPLE_EXTENSIONS = (".bin", ".txt", ".exr", ".npz")


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
        Unknown extension, malformed file, a file beyond the format's limits (see the format's
        module), or data that fails :meth:`SampleBuffer.validate` (the message names the
        field and the first offending sample). An EXR file OpenImageIO cannot read raises
        :class:`~clrecon.io.image.ImageReadError`, a ``ValueError`` that is also an ``OSError``.
    FileNotFoundError
        The file (or the TLFR header) does not exist.
    """
    path = os.fspath(path)
    ext = extension(path, SAMPLE_EXTENSIONS, "sample buffer")
    if ext in (".bin", ".txt"):
        buf = load_tlfr(path)
    elif ext == ".exr":
        buf = load_samples_exr(path)
    else:
        buf = load_samples_npz(path)
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
    ext = extension(path, SAMPLE_EXTENSIONS, "sample buffer")
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
    check_parent(path)
    if ext in (".bin", ".txt"):
        save_tlfr(path, buf, encoding)
    elif ext == ".exr":
        save_samples_exr(path, buf)
    else:
        save_samples_npz(path, buf)
