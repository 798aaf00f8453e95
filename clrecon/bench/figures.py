"""Matplotlib for the reports' pictures: headless (the Agg backend, chosen on first use, so
that importing a report needs no display and no matplotlib until it draws), and PNGs written
atomically so that an interrupted run leaves no half-written picture."""
from __future__ import annotations

import io
from pathlib import Path

from clrecon.core.fsutil import write_atomic


def pyplot():
    """``matplotlib.pyplot`` on the Agg backend."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_png(fig, path: Path) -> Path:
    """Write ``fig`` as a PNG at ``path`` (parent folders created) and close it."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    png = io.BytesIO()
    fig.savefig(png, format="png")
    pyplot().close(fig)
    write_atomic(path, png.getvalue())
    return path
