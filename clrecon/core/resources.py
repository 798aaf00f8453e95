"""Where the shipped kernels and tuning files are, for editable and wheel installs alike.

``kernels/`` and ``tuning/`` sit at the top of the repository (embedders look there for the
``.cl`` files) and are mapped onto the sub-packages ``clrecon.kernels`` and ``clrecon.tuning`` by
``setup.cfg``, so one lookup through importlib finds them however the package was installed.
"""
from __future__ import annotations

import hashlib
from functools import lru_cache
from importlib import resources
from pathlib import Path


def kernels_dir() -> Path:
    """Directory holding ``common.h`` and the ``<pass>.cl`` files."""
    return Path(str(resources.files("clrecon.kernels")))


def tuning_dir() -> Path:
    """Directory holding ``<runtime>/<device>.json`` tuning databases."""
    return Path(str(resources.files("clrecon.tuning")))


@lru_cache(maxsize=1)
def code_digest() -> str:
    """16 hex digits of a SHA-256 over the library's code as this process loaded it: every
    ``.py`` file of the ``clrecon`` package and every ``.cl`` and ``.h`` file of
    :func:`kernels_dir`, by relative path and content. Caches of measured results key on
    it, so a change to any pass or method never reuses a number the old code made."""
    h = hashlib.sha256()
    pkg = Path(__file__).resolve().parents[1]
    files = [(f"clrecon/{p.relative_to(pkg).as_posix()}", p) for p in pkg.rglob("*.py")]
    kdir = kernels_dir()
    files += [(f"kernels/{p.relative_to(kdir).as_posix()}", p) for p in kdir.rglob("*")
              if p.suffix in (".cl", ".h")]
    for name, path in sorted(files):
        h.update(name.encode() + b"\0" + path.read_bytes() + b"\0")
    return h.hexdigest()[:16]
