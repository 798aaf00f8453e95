"""What the measurement scripts under ``tools/`` share: the options of the frame they measure
on, that frame, and the page they print and write. (The timing itself is
:mod:`clrecon.bench.timing`'s, as for every report.)"""
from __future__ import annotations

import argparse
import os
from collections.abc import Sequence

from clrecon.bench.options import parse_size
from clrecon.core.device import Device, get_device
from clrecon.core.fsutil import write_atomic
from clrecon.core.samples import SampleBuffer
from clrecon.scenes import get_scene, render_samples


def add_frame_options(ap: argparse.ArgumentParser, scene: str = "deep",
                      size: str = "1280x720", spp: int = 8, repeats: int = 5,
                      device: bool = True) -> None:
    """``--scene``, ``--size`` (``WxH``), ``--spp``, ``--repeats`` and (with ``device``)
    ``--device``, with these defaults; :func:`frame_of` renders what they name."""
    ap.add_argument("--scene", default=scene)
    ap.add_argument("--size", default=size)
    ap.add_argument("--spp", type=int, default=spp)
    ap.add_argument("--repeats", type=int, default=repeats)
    if device:
        ap.add_argument("--device", default=None)


def frame_of(args: argparse.Namespace) -> tuple[Device, SampleBuffer]:
    """The device (``args.device``, the default one without it) and the frame the options of
    :func:`add_frame_options` name, rendered with the seed ``100 + spp`` (``clrecon table``'s
    and ``trade``'s)."""
    w, h = parse_size(args.size)
    dev = get_device(getattr(args, "device", None))
    return dev, render_samples(get_scene(args.scene), w, h, args.spp, seed=100 + args.spp,
                               device=dev)


def emit_page(lines: Sequence[str], path: str | os.PathLike | None = None) -> str:
    """Print a page (its ``lines`` joined, ending in a newline) and, with ``path``, write it
    there too; the text."""
    text = "\n".join(lines) + "\n"
    print(text)
    if path:
        write_atomic(path, text.encode(), 0o644)
    return text
