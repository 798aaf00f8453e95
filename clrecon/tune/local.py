"""The :class:`~clrecon.core.pipeline.LocalSize` a tuned local-size configuration stands for.

Apart from :mod:`clrecon.tune.tunable` because :mod:`clrecon.core.pipeline` (where
``LocalSize`` lives) also builds pipelines, which imports the methods: the declarations
and the lookup stay free of that import.
"""
from __future__ import annotations

from clrecon.core.local_size import LocalSize


def local_size_of(config: dict | None) -> LocalSize:
    """The :class:`LocalSize` of a ``{"wg_x", "wg_y"}`` configuration (``None``: the
    runtime chooses)."""
    if config is None:
        return LocalSize(None)
    return LocalSize(int(config["wg_x"]), int(config["wg_y"]))
