"""A measurement script under ``tools/`` loaded as a module (``tools/`` is not a package)."""
from __future__ import annotations

import importlib.util
from pathlib import Path
from types import ModuleType

#: the repository's root
ROOT = Path(__file__).resolve().parents[2]


def load_tool(name: str) -> ModuleType:
    """``tools/<name>.py`` as a module named ``name``."""
    spec = importlib.util.spec_from_file_location(name, ROOT / "tools" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module
