"""Checks of the knobs a method's constructor takes (and of other user-given arguments).

Every check names the knob and states its valid range. The rules, the same for every knob
of every method:

* an integer knob takes an ``int`` (or a NumPy integer); ``bool`` is refused (``True`` is
  not a count), and so is every ``float``, even one with an integer value such as ``8.0``
  (``int(8.5)`` would silently become 8, and ``8.0`` usually means a value was computed
  where a count was meant): :class:`KnobTypeError`;
* a float knob takes an ``int`` or ``float`` (NumPy scalars too, ``bool`` refused); it
  must be finite unless its documentation gives ``inf`` a meaning (``splat``'s
  ``max_error``), and NaN is always refused;
* a flag takes ``True`` or ``False`` (NumPy's ``bool_`` too), not ``0``/``1``;
* a choice takes one of its strings.

A value of the wrong type raises :class:`KnobTypeError`, which is both a ``TypeError`` and
a ``ValueError``: an API caller may catch either, and the command line reports it in one
line like every other bad input (a ``TypeError`` that is not a :class:`KnobTypeError` is a
programming error and keeps its traceback). A value of the right type outside its range
raises ``ValueError``.
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

INT32_MAX = 2**31 - 1
UINT32_END = 2**32


class KnobTypeError(TypeError, ValueError):
    """A knob or argument of the wrong type (user input, not a programming error)."""


def _show(value) -> str:
    return f"{value!r} ({type(value).__name__})"


def check_int(name: str, value, lo: int | None = None, hi: int | None = None,
              hi_open: bool = False, what: str = "") -> int:
    """``value`` as an ``int`` in ``[lo, hi]`` (``[lo, hi)`` with ``hi_open``); ``lo`` or
    ``hi`` ``None``: unbounded on that side. ``what`` is appended to the message (a reason
    for the range)."""
    lo_s = "-inf" if lo is None else str(lo)
    hi_s = "inf" if hi is None else str(hi)
    rng = f"[{lo_s}, {hi_s}{')' if hi_open or hi is None else ']'}"
    extra = f" {what}" if what else ""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise KnobTypeError(f"{name}: must be an integer in {rng}{extra}, got {_show(value)}")
    v = int(value)
    if (lo is not None and v < lo) or (hi is not None and (v >= hi if hi_open else v > hi)):
        raise ValueError(f"{name}: must be an integer in {rng}{extra}, got {v}")
    return v


def check_radius(name: str, value, radii: range, what: str = "radius") -> int:
    """``value`` as a radius in ``radii`` or 0 (off): the guided refinement's and the
    non-local means' knobs; ``ValueError`` otherwise (a bool or a non-integer included)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or not (
            value == 0 or value in radii):
        raise ValueError(f"{name}: the {what} must be an integer 0 (off) or "
                         f"{radii.start}..{radii.stop - 1}, got {value!r}")
    return int(value)


def check_float(name: str, value, lo: float | None = None, hi: float | None = None,
                lo_open: bool = False, hi_open: bool = False, allow_inf: bool = False,
                what: str = "") -> float:
    """``value`` as a finite ``float`` in the interval from ``lo`` to ``hi`` (open ends as
    asked; ``None``: unbounded). ``allow_inf``: ``+inf`` is accepted too (where the knob
    documents what it means)."""
    left = "(" if lo is None or lo_open else "["
    lo_s = "-inf" if lo is None else f"{lo:g}"
    if hi is None:
        hi_s, right = "inf", "]" if allow_inf else ")"
    else:
        hi_s, right = f"{hi:g}", ")" if hi_open else "]"
    rng = f"{left}{lo_s}, {hi_s}{right}"
    kind = "a number (inf allowed)" if allow_inf else "a finite number"
    extra = f" {what}" if what else ""
    if isinstance(value, (bool, np.bool_)) or not isinstance(
            value, (int, float, np.integer, np.floating)):
        raise KnobTypeError(f"{name}: must be {kind} in {rng}{extra}, got {_show(value)}")
    try:
        v = float(value)
    except OverflowError:  # an int beyond the float range
        raise ValueError(f"{name}: must be {kind} in {rng}{extra}, got {value}") from None
    bad = math.isnan(v) or (math.isinf(v) and not (allow_inf and v > 0))
    if not bad and lo is not None:
        bad = v <= lo if lo_open else v < lo
    if not bad and hi is not None:
        bad = v >= hi if hi_open else v > hi
    if bad:
        raise ValueError(f"{name}: must be {kind} in {rng}{extra}, got {v!r}")
    return v


def check_bool(name: str, value, none_ok: bool = False) -> bool | None:
    """``value`` as a ``bool`` (``None`` passed through when ``none_ok``)."""
    if value is None and none_ok:
        return None
    if not isinstance(value, (bool, np.bool_)):
        alt = ", false or None" if none_ok else " or false"
        raise KnobTypeError(f"{name}: must be true{alt}, got {_show(value)}")
    return bool(value)


def check_choice(name: str, value, choices: Sequence[str], none_ok: bool = False):
    """``value`` if it is one of ``choices`` (or ``None`` when ``none_ok``)."""
    if value is None and none_ok:
        return None
    opts = tuple(choices) + ((None,) if none_ok else ())
    if not isinstance(value, str):
        raise KnobTypeError(f"{name}: must be one of {opts}, got {_show(value)}")
    if value not in choices:
        raise ValueError(f"{name}: must be one of {opts}, got {value!r}")
    return value
