"""What the CLI's commands share: argument types, the help formatter, the checks of the files
a command reads and writes (made before any work), stage logging, progress bars, timing and
the method/knob checks."""
from __future__ import annotations

import argparse
import errno
import os
import sys

from clrecon.bench import options
from clrecon.bench.options import parse_size

# -- argument types --------------------------------------------------------------------------


def side_or_size(text: str) -> tuple[int, int]:
    """``N`` (N x N) or ``WxH``."""
    return parse_size(f"{text}x{text}" if text.strip().isdigit() else text)


def names(text: str) -> list[str]:
    """A comma-separated list of names (``--scenes``, ``--methods``); empty items dropped."""
    return [t for t in text.split(",") if t]


def int_list(text: str) -> list[int]:
    """A comma-separated list of ints; empty items dropped."""
    try:
        return [int(v) for v in text.split(",") if v]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a comma-separated list, got {text!r}") from None


def device_list(text: str):
    """``all`` or comma-separated device indices / name substrings."""
    if text.strip().lower() == "all":
        return "all"
    specs = [int(v) if v.isdigit() else v for v in (t.strip() for t in text.split(",")) if v]
    if not specs:
        raise argparse.ArgumentTypeError(f"expected 'all' or D[,D...], got {text!r}")
    return specs


def variant(text: str):
    """A ``--variant`` spec (``[LABEL=]METHOD[:K=V,...]``) as ``(label, method, knobs)``."""
    from clrecon.bench.table import parse_variant

    try:
        return parse_variant(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def device_arg(sp) -> None:
    """``--device`` of the commands that run on one device."""
    sp.add_argument("--device", default=None,
                    help="OpenCL device index or name substring (default: "
                    "$CLRECON_DEVICE, else the first GPU, else the first device; a simulator "
                    "(Oclgrind) only by name or index)")


class IntsAction(argparse.Action):
    """A list of ints given as ``4 8 16``, ``4,8,16`` or both mixed (``nargs="+"`` of
    :func:`int_list`): one flat list."""

    def __call__(self, parser, namespace, values, option_string=None):
        setattr(namespace, self.dest, [v for group in values for v in group])


class HelpFormatter(argparse.HelpFormatter):
    """Every option's help ends with its default, unless it already names one or there is
    none to show (``None``, a flag's ``False``); sizes as WxH, lists comma-separated."""

    def _get_help_string(self, action):
        text = action.help or ""
        default = action.default
        if (not action.option_strings or action.nargs == 0 or default is None
                or default is argparse.SUPPRESS or default is False
                or "default" in text.lower()):
            return text
        if isinstance(default, tuple) and len(default) == 2 and action.type is parse_size:
            shown = f"{default[0]}x{default[1]}"
        elif isinstance(default, (list, tuple)):
            shown = ",".join(map(str, default))
        else:
            shown = str(default)
        shown = shown.replace("%", "%%")
        return f"{text} (default: {shown})" if text else f"default: {shown}"


# -- what a command reads and writes -------------------------------------------------------

def stage(args, what: str, path=None) -> None:
    """Record what the command is doing: an error that names nothing is reported with it."""
    args.stage = (what, None if path is None else str(path))


def sample_files(path) -> list[str]:
    """The files a sample buffer path stands for (TLFR: the data file and its header)."""
    path = str(path)
    if os.path.splitext(path)[1].lower() in (".bin", ".txt"):
        return [path, path + ".header"]
    return [path]


def _same_file(a: str, b: str) -> bool:
    """Whether ``a`` and ``b`` are one file: the same path after resolving links, or (both
    existing) the same inode."""
    if os.path.realpath(a) == os.path.realpath(b):
        return True
    try:
        return os.path.samefile(a, b)
    except OSError:  # one of them does not exist (yet)
        return False


def check_files(reads: dict[str, list[str]], writes: dict[str, list[str]]) -> None:
    """Refuse, before anything is read or written, an output that is one of the inputs or
    another output (``reads``/``writes``: the option naming them -> their files)."""
    outs = [(opt, f) for opt, files in writes.items() for f in files]
    for i, (opt, out) in enumerate(outs):
        for what, files in reads.items():
            for f in files:
                if _same_file(out, f):
                    raise ValueError(f"{opt} {out}: is the same file as the {what} {f}; "
                                     f"refusing to overwrite it (write elsewhere)")
        for opt2, out2 in outs[:i]:
            if _same_file(out, out2) and opt2 != opt:
                raise ValueError(f"{opt} {out}: is the same file as {opt2} {out2}")


def check_output(opt: str, path, allowed: tuple[str, ...] | None = None) -> None:
    """What saving ``path`` would refuse, checked before the work that produces it: the
    extension, a missing parent folder, a folder in the file's place."""
    path = str(path)
    if allowed is not None:
        ext = os.path.splitext(path)[1].lower()
        if ext not in allowed:
            raise ValueError(f"{opt} {path}: unsupported extension {ext or '(none)'!r}; "
                             f"supported: {', '.join(allowed)}")
    parent = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(parent):
        raise FileNotFoundError(errno.ENOENT, f"no folder {parent} to write into ({opt})",
                                path)
    if os.path.isdir(path):
        raise IsADirectoryError(errno.EISDIR, f"is a directory, not a file ({opt})", path)


def check_output_dir(opt: str, path) -> None:
    """An output folder: refuse an existing file in its place before any work."""
    if os.path.exists(path) and not os.path.isdir(path):
        raise NotADirectoryError(errno.ENOTDIR, f"exists and is not a folder ({opt})",
                                 str(path))


def user_frames(args) -> list[tuple[str, str]]:
    """``--input F --reference R`` pairs (repeatable, paired in order)."""
    ins, refs = args.input or [], args.reference or []
    if len(ins) != len(refs):
        raise ValueError(f"--input/--reference: {len(ins)} inputs but {len(refs)} references "
                         "(give one --reference per --input)")
    for f in [*ins, *refs]:
        if not os.path.isfile(f):
            raise ValueError(f"--input/--reference: {f}: no such file")
    return list(zip(ins, refs))


# -- methods and knobs -----------------------------------------------------------------------

def parse_knobs(items) -> dict:
    """``--knob NAME=VALUE`` options as a dict (values as in ``clrecon table``'s variants),
    the messages naming the option as the user spelled it."""
    return options.parse_knobs(items or [], "--knob", " (e.g. --knob tile=8)")


def check_knob_names(method: str, knobs: dict, what: str = "") -> None:
    """Unknown methods and knobs as a ``ValueError`` before any work (the library's
    ``make_pipeline`` says ``TypeError``, an API misuse there, a typo here)."""
    from clrecon.api import METHODS, method_knobs

    if method not in METHODS:
        raise ValueError(f"{what}method: unknown {method!r}; available: {sorted(METHODS)}")
    accepted = method_knobs(method)
    unknown = sorted(set(knobs) - accepted)
    if unknown:
        raise ValueError(f"{what}method {method!r} got unknown knobs: {unknown}; it takes "
                         f"{sorted(accepted)}")


def check_methods(methods) -> None:
    """``--methods`` names that are no registered method, before any work."""
    for method in methods or []:
        check_knob_names(method, {}, "--methods: ")


# -- what a command shows while it works -----------------------------------------------------

def _stderr_is_terminal() -> bool:
    try:
        return sys.stderr.isatty()
    except (AttributeError, ValueError):
        return False


def stage_logger(command: str):
    """``log(line)`` for a command's long stages: a line on stderr where there is no terminal
    for a progress bar to show on (a log, a pipe, CI); nothing on a terminal."""
    quiet = _stderr_is_terminal()

    def log(line: str) -> None:
        if not quiet:
            print(f"clrecon {command}: {line}", file=sys.stderr, flush=True)

    return log


def status_printer(command: str):
    """``status(line)`` for a library's status lines: ``clrecon COMMAND: line`` on stderr."""
    def status(line: str) -> None:
        print(f"clrecon {command}: {line}", file=sys.stderr, flush=True)

    return status


class Bar:
    """A tqdm progress bar usable as a ``progress(done, total)`` callback."""

    def __init__(self, desc: str, unit: str = "it", scale: float = 1.0):
        from tqdm import tqdm

        self.bar = tqdm(desc=desc, unit=unit, unit_scale=True, leave=False, disable=None,
                        file=sys.stderr)
        self.scale = scale

    def __call__(self, done: int, total: int) -> None:
        self.bar.total = total * self.scale
        self.bar.n = done * self.scale
        self.bar.refresh()

    def close(self):
        self.bar.close()


def with_bar(desc: str, fn, *args, unit: str = "samples", **kw):
    """``fn(*args, progress=bar, **kw)`` with a progress bar that is closed whatever happens."""
    bar = Bar(desc, unit=unit)
    try:
        return fn(*args, progress=bar, **kw)
    finally:
        bar.close()


def timed(fn, warmup: bool = False):
    """``(fn(), wall seconds)``, measured as every report measures
    (:func:`clrecon.bench.timing.median_wall_s`; after one warm-up call when ``warmup``)."""
    from clrecon.bench.timing import median_wall_s

    results = []
    seconds = median_wall_s(lambda: results.append(fn()), 1, warmup=warmup)
    return results[-1], seconds
