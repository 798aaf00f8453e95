"""Text forms of the bench's options, shared by the command line, ``clrecon table``'s variants
and the scripts under ``tools/``: sizes (``WxH``) and knob values (``NAME=VALUE``).

Pure Python (no OpenCL, no NumPy), so that a parser can use them without importing the
library's heavy parts.
"""
from __future__ import annotations

import argparse
from collections.abc import Iterable


class SizeError(argparse.ArgumentTypeError, ValueError):
    """A size that is not ``WxH`` of positive integers. A ``ValueError`` for the library and an
    ``argparse.ArgumentTypeError`` for a parser, which then shows this message as it is."""


def parse_size(text: str) -> tuple[int, int]:
    """``"WxH"`` (``x`` in any case) as ``(width, height)``.

    Usable as an argparse ``type``; raises :class:`SizeError` (a ``ValueError``) for text
    that is not two integers or a size that is not positive."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise SizeError(f"expected WxH (e.g. 512x512), got {text!r}") from None
    if w < 1 or h < 1:
        raise SizeError(f"size must be positive, got {text!r}")
    return w, h


def parse_value(text: str) -> int | float | bool | str:
    """A knob value from text: int, then float, then true/false (any case), else the text."""
    for cast in (int, float):
        try:
            return cast(text)
        except ValueError:
            pass
    return {"true": True, "false": False}.get(text.lower(), text)


def parse_knobs(items: Iterable[str], where: str,
                example: str = "") -> dict[str, int | float | bool | str]:
    """``NAME=VALUE`` items as knobs (values by :func:`parse_value`).

    ``where`` and ``example`` shape the messages, so that the command line's ``--knob``
    (``where="--knob"``, ``example=" (e.g. --knob tile=8)"``) and a variant's text
    (``where="variant 'x': knob"``) say where the mistake is in their own terms.

    Raises
    ------
    ValueError
        ``"{where} 'x': expected NAME=VALUE{example}"`` for an item without ``=`` or a name,
        ``"{where} x: given twice"`` for a repeated name.
    """
    knobs: dict[str, int | float | bool | str] = {}
    for item in items:
        name, eq, value = item.partition("=")
        name = name.strip()
        if not eq or not name:
            raise ValueError(f"{where} {item!r}: expected NAME=VALUE{example}")
        if name in knobs:
            raise ValueError(f"{where} {name}: given twice")
        knobs[name] = parse_value(value.strip())
    return knobs
