"""The TLFR 1.3 header file (``PATH + ".header"``): parsed on load, written on save.

The header is text of at most 64 KiB: ``Version 1.3``, ``Width``, ``Height``, ``Samples per
pixel``, ``CoC coefficients (coc radius = C0/w+C1): C0,C1``, ``Encoding = binary|text``,
optionally ``Motion model: perspective`` and the line of the 16 field names; in any order,
with free whitespace, every line one known key and none twice. The CoC coefficients are
written with ``repr`` (exact).
"""
from __future__ import annotations

import math
import re

from clrecon.core.camera import CocModel
from clrecon.core.samples import SampleBuffer
from clrecon.io.files import check_exists

TLFR_VERSION = "1.3"
TLFR_FIELDS = (
    "x", "y", "z/w", "w", "u", "v", "t", "r", "g", "b", "a",
    "mv_x", "mv_y", "mv_w", "dwdx", "dwdy",
)
_TLFR_MAX_HEADER_BYTES = 1 << 16

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
    check_exists(header_path, "TLFR header file")
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


def parse_tlfr_header(header_path: str) -> dict:
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

    return {**sizes, "coc_model": CocModel(c0, c1), "encoding": encoding}


def tlfr_header_text(buf: SampleBuffer, encoding: str) -> str:
    """The header of ``buf`` saved with ``encoding``, every key the reference writer uses."""
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
