"""What every format shares: path checks, the float32 range, column layouts and safe writes.

Safe writes: every file is written to a new temporary file in the same folder (created with
mode ``0o666`` less the umask, flushed to disk) and then renamed over the target with
:func:`os.replace`, so a reader sees the old file or the new one, never part of one; on any
failure the temporary file is removed and the target is left as it was. A group of files (a
TLFR pair) is renamed only once all are written and no target is a directory; if a later
rename still fails, the targets renamed before it are restored (from a hard link to the old
file).
"""
from __future__ import annotations

import contextlib
import errno
import os
from collections.abc import Iterator, Mapping
from typing import Union

import numpy as np

from clrecon.core.camera import CocModel
from clrecon.core.samples import SampleBuffer

#: the largest finite float32: a finite wider value beyond it would silently become ``inf``
F32_MAX = float(np.finfo(np.float32).max)

#: where a field sits on the last axis of a record array: a slice, or one column
Columns = Mapping[str, Union[slice, int]]


def extension(path: str, allowed: tuple[str, ...], what: str) -> str:
    """The lower-cased extension of ``path``, refused unless it is one of ``allowed``."""
    ext = os.path.splitext(path)[1].lower()
    if ext not in allowed:
        raise ValueError(
            f"unsupported {what} file extension {ext or '(none)'!r} in {path!r}; "
            f"supported: {', '.join(allowed)}"
        )
    return ext


def check_exists(path: str, what: str = "file") -> None:
    """A missing input is a ``FileNotFoundError`` naming it (and what it was for)."""
    if not os.path.isfile(path):
        raise FileNotFoundError(errno.ENOENT, f"{what} not found", path)


def check_parent(path: str) -> None:
    """Refuse to write where the parent directory does not exist (before any work)."""
    parent = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(parent):
        raise FileNotFoundError(
            errno.ENOENT, f"cannot write {path!r}: directory does not exist", parent
        )


def columns_buffer(records: np.ndarray, columns: Columns, coc_model: CocModel,
                   **given: np.ndarray) -> SampleBuffer:
    """A :class:`SampleBuffer` of the ``columns`` of ``records`` (fields on the last axis),
    plus the fields ``given`` ready-made; the inverse of :func:`fill_columns`."""
    fields = {name: records[..., where] for name, where in columns.items()}
    return SampleBuffer(**fields, **given, coc_model=coc_model)


def fill_columns(records: np.ndarray, columns: Columns, buf: SampleBuffer) -> None:
    """Write the fields of ``buf`` named by ``columns`` into ``records`` (in place)."""
    for name, where in columns.items():
        records[..., where] = getattr(buf, name)


# ==========================================================================================
# safe writes
# ==========================================================================================
def _sibling(path: str, tag: str) -> str:
    """A fresh hidden name next to ``path`` that keeps its extension (OpenImageIO picks the
    format by extension): ``dir/.NAME.<random>.<tag>EXT``."""
    head, tail = os.path.split(os.path.abspath(path))
    return os.path.join(head, f".{tail}.{os.urandom(6).hex()}.{tag}{os.path.splitext(tail)[1]}")


def _new_temp(path: str) -> str:
    """Create an empty temporary file next to ``path`` (mode 0o666 less the umask)."""
    while True:
        tmp = _sibling(path, "tmp")
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        except FileExistsError:  # pragma: no cover - 48 random bits
            continue
        os.close(fd)
        return tmp


def _remove_quietly(path: str) -> None:
    with contextlib.suppress(OSError):
        os.remove(path)


def _fsync(path: str) -> None:
    fd = os.open(path, os.O_RDWR)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


@contextlib.contextmanager
def atomic_write(*paths: str) -> Iterator[tuple[str, ...]]:
    """Yield one new temporary path per target; when the block succeeds, flush them and
    rename each over its target (:func:`_replace_all`). On any failure every temporary file
    is removed and no target is touched."""
    temps: list[str] = []
    try:
        for path in paths:
            temps.append(_new_temp(path))
        yield tuple(temps)
        for tmp in temps:
            _fsync(tmp)
        _replace_all(temps, paths)
    finally:
        for tmp in temps:  # gone already after a successful rename
            _remove_quietly(tmp)


def _backup(path: str) -> str | None:
    """Keep the current ``path`` (if any) under a hidden name: a hard link, or where links
    fail, the file itself moved aside."""
    if not os.path.isfile(path):
        return None
    keep = _sibling(path, "old")
    try:
        os.link(path, keep)
    except OSError:
        os.replace(path, keep)
    return keep


def _replace_all(temps: list[str], paths: tuple[str, ...]) -> None:
    """Rename ``temps`` over ``paths`` in order, after checking that no target is a
    directory; if a rename fails, the targets renamed before it are restored."""
    for path in paths:
        if os.path.isdir(path):
            raise IsADirectoryError(errno.EISDIR, "cannot replace a directory", path)
    done: list[tuple[str, str | None]] = []  # (target, its old file) renamed so far
    try:
        for k, (tmp, path) in enumerate(zip(temps, paths)):
            keep = _backup(path) if k < len(paths) - 1 else None
            done.append((path, keep))
            os.replace(tmp, path)
    except BaseException:
        for path, keep in reversed(done):
            if keep is not None:
                os.replace(keep, path)  # the old file back (undoes a move aside too)
            elif path != done[-1][0]:
                _remove_quietly(path)  # a new file where there was none
        raise
    for _, keep in done:
        if keep is not None:
            _remove_quietly(keep)
