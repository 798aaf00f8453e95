"""Text TLFR data (``Encoding = text``): one comma-separated line of 16 values per record.

Parsed in chunks of :data:`_TLFR_TEXT_READ` bytes (1 MiB) straight into the preallocated
records; a line may not be longer than a chunk, one trailing comma per line is allowed (the
reference writer ends every line with one), blank lines only at the end, and a finite value
beyond float32's range is refused (it would silently become ``inf``, a miss). Peak memory: the
records and one chunk.
"""
from __future__ import annotations

import re

import numpy as np

from clrecon.io.files import F32_MAX
from clrecon.io.tlfr_header import TLFR_FIELDS

#: bytes per read when parsing text (also the longest line accepted)
_TLFR_TEXT_READ = 1 << 20

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


def read_tlfr_text(path: str, n: int) -> np.ndarray:
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
                         f"(largest finite {F32_MAX:.8g})")
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
