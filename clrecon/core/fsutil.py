"""Two file-system helpers every writer of the library shares: where a cache lives, and how
a single file is written so that a reader never sees part of it."""
from __future__ import annotations

import os
import tempfile
from pathlib import Path

ENV_CACHE_DIR = "CLRECON_CACHE_DIR"


def cache_dir(kind: str, env_subdir: bool = True) -> Path | None:
    """Folder of the ``kind`` cache, or ``None`` when caching is turned off.

    ``$CLRECON_CACHE_DIR`` (``off``, empty or blank: off; ``env_subdir``: ``<it>/<kind>``,
    else the folder itself), else ``$XDG_CACHE_HOME/clrecon/<kind>`` (an absolute path
    only), else ``~/.cache/clrecon/<kind>``; ``None`` without a home directory. Read on
    every call, so a change of the environment takes effect at once.
    """
    env = os.environ.get(ENV_CACHE_DIR)
    if env is not None:
        env = env.strip()
        if not env or env.lower() == "off":
            return None
        base = Path(env).expanduser()
        return base / kind if env_subdir else base
    xdg = os.environ.get("XDG_CACHE_HOME", "")
    if xdg and os.path.isabs(xdg):
        return Path(xdg) / "clrecon" / kind
    try:
        return Path.home() / ".cache" / "clrecon" / kind
    except (RuntimeError, KeyError):  # no home directory to be found
        return None


def write_atomic(path: str | os.PathLike, data: bytes, mode: int | None = None) -> None:
    """Write ``data`` to a temporary file beside ``path``, flush it to disk, then rename it
    over ``path`` (``mode``: its permission bits). On any failure the temporary file is
    removed and ``path`` is left as it was."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem[:24]}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        if mode is not None:
            os.chmod(tmp, mode)
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise
