"""Where the shipped kernels and tuning files are, for editable and wheel installs alike.

``kernels/`` and ``tuning/`` sit at the top of the repository (embedders look there for the
``.cl`` files) and are mapped onto the sub-packages ``clrecon.kernels`` and ``clrecon.tuning`` by
``setup.cfg``, so one lookup through importlib finds them however the package was installed.
"""
from __future__ import annotations

from importlib import resources
from pathlib import Path


def kernels_dir() -> Path:
    """Directory holding ``common.h`` and the ``<pass>.cl`` files."""
    return Path(str(resources.files("clrecon.kernels")))


def tuning_dir() -> Path:
    """Directory holding ``<runtime>/<device>.json`` tuning databases."""
    return Path(str(resources.files("clrecon.tuning")))
