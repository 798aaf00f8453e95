"""The ``clrecon`` command line: a thin layer that parses, calls the library and prints.

Subcommands: ``devices``, ``scene``, ``reference``, ``reconstruct``, ``compare``, ``demo``
(the quick start's main job) and ``report`` (generator throughput, reference convergence
and box-filter quality of the built-in scenes); ``table`` compares the device time and
quality of reconstruction variants side by side; ``trade`` measures every method's
speed/accuracy knobs against ``box`` and Open Image Denoise.

Here: :func:`main` and its error handling (the families a user can cause as one line and
exit code 2; anything else, a bug, keeps its traceback). The parser is
:mod:`clrecon.cli.parser`, the commands :mod:`~clrecon.cli.run`, :mod:`~clrecon.cli.demo`,
:mod:`~clrecon.cli.reports`, :mod:`~clrecon.cli.devices` and :mod:`~clrecon.cli.sequences`.
"""
from __future__ import annotations

import logging
import sys
import warnings

from clrecon.cli.parser import build_parser

__all__ = ["build_parser", "main"]


def _expected_errors() -> tuple[type[BaseException], ...]:
    """The error families a user can cause (bad input, files, the device, memory): one line
    on stderr and exit code 2. Anything else (``TypeError``, ``AttributeError``...) is a bug
    and keeps its traceback. ``ValueError`` includes :class:`~clrecon.core.knobs.KnobTypeError`,
    the ``TypeError`` of a knob of the wrong type."""
    import zipfile

    import pyopencl as cl

    from clrecon.core.errors import ClreconError

    return (ValueError, ClreconError, OSError, MemoryError, OverflowError,
            zipfile.BadZipFile, cl.Error)


def _kind(exc: BaseException) -> str | None:
    """The family of ``exc`` where its message alone would not say it."""
    import zipfile

    import pyopencl as cl

    if isinstance(exc, cl.Error):
        return f"OpenCL {type(exc).__name__}"
    if isinstance(exc, MemoryError):
        return "out of host memory"
    if isinstance(exc, OverflowError):
        return "value out of range"
    if isinstance(exc, zipfile.BadZipFile):
        return "corrupt archive"
    return None


def _message(exc: BaseException, stage) -> str:
    """One line for ``exc``: its message (first line; OSError as ``file: reason``), the
    family where the message alone would not say it, and what the command was doing when
    the message names no file."""
    if isinstance(exc, OSError) and exc.filename is not None and exc.strerror:
        text = f"{exc.filename}: {exc.strerror}"
        if exc.filename2 is not None:
            text += f" (and {exc.filename2})"
    else:
        text = str(exc)
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    text = lines[0] if lines else ""
    if len(lines) > 1:
        text += f" [{len(lines) - 1} more lines: run with --debug to see them]"
    kind = _kind(exc)
    if kind:
        text = f"{kind}: {text}" if text else kind
    elif not text:
        text = type(exc).__name__
    if stage is not None and not isinstance(exc, ValueError):
        what, path = stage
        if path is None or path not in text:
            text += f" (while {what}{'' if path is None else ' ' + path})"
    return text


def main(argv=None) -> int:
    """Run ``clrecon ARGV``: the command's exit code; an expected error is one line on
    stderr and 2 (``--debug``: raised, with its traceback)."""
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="clrecon: %(message)s")
    args.stage = None
    from clrecon.core import build as clbuild

    echo = clbuild.ECHO_BUILD_OUTPUT
    # what compilers write to fd 2 (PoCL's "N warnings generated.") only with -v/--debug
    clbuild.ECHO_BUILD_OUTPUT = bool(args.verbose or args.debug)
    try:
        with warnings.catch_warnings():
            if not (args.verbose or args.debug):  # "Non-empty compiler output": noise
                import pyopencl as cl

                warnings.filterwarnings("ignore", category=cl.CompilerWarning)
            return args.fn(args)
    except _expected_errors() as exc:
        if args.debug:
            raise
        print(f"clrecon {args.command}: error: {_message(exc, args.stage)}", file=sys.stderr)
        return 2
    finally:
        clbuild.ECHO_BUILD_OUTPUT = echo
