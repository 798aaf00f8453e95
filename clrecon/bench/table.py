"""The methods table: device time and quality of several reconstruction variants side by side
on the built-in scenes (``clrecon table``).

Per scene one converged reference (seed 1, the scene's default spp unless ``ref_spp`` is
given) and one sample buffer (seed ``100 + spp``) are rendered. Each variant's pipeline is
built and its samples uploaded once; after one warm-up call it runs ``repeats`` times and
the table reports the median of the summed per-pass device times (and the median of each
pass). Quality (PSNR, SSIM, FLIP; see :mod:`clrecon.metrics`) is that of the last run's
image against the reference.

Per scene, ``{scene}_crops.png`` shows the same crop of the reference and of every variant,
left to right: the crop is centred on the region where the box filter's error is largest.
"""
from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Callable, Optional

import numpy as np

from clrecon.api import METHODS, method_knobs, run
from clrecon.bench.options import parse_knobs
from clrecon.bench.options import parse_value as parse_value  # re-exported: the CLI's import
from clrecon.bench.timing import time_pipeline
from clrecon.core.device import Device, DeviceSpec, get_device
from clrecon.io import load_image, load_samples, save_image
from clrecon.metrics import evaluate
from clrecon.scenes import SCENES, get_scene, render_reference, render_samples

Variant = tuple[str, str, dict[str, Any]]
Progress = Optional[Callable[[int, int], None]]

#: the variants compared when none are given
DEFAULT_VARIANTS: tuple[Variant, ...] = (
    ("box", "box", {}),
    ("sweep 2-scale", "sweep", {"scales": 2}),
    ("sweep 4-scale", "sweep", {"scales": 4}),
    ("sweep dof-layers", "sweep", {"dof_layers": True}),
    ("sweep 2-scale ^1.3", "sweep", {"scales": 2, "exponent": 1.3}),
)

#: side of the montage crops and of the error window that places them, in pixels
CROP = 128
WINDOW = 32
GAP = 2


# -- variants ------------------------------------------------------------------------------

def parse_variant(text: str) -> Variant:
    """Parse ``[LABEL=]METHOD[:knob=value,knob=value...]`` into ``(label, method, knobs)``.

    Parameters
    ----------
    text : str
        E.g. ``"sweep:scales=4,sort=pixel"``, ``"sweep4=sweep:scales=4"`` or ``"box"``.
        A label is recognised when an ``=`` comes before the first ``:``; without one the
        label is ``text`` itself. Values are read as int, else float, else bool
        (``true``/``false``, any case), else kept as a string.

    Returns
    -------
    tuple
        ``(label, method, knobs)`` with ``knobs`` a dict (empty when none are given).

    Raises
    ------
    ValueError
        Empty label or method, a knob without ``=`` or with an empty name, a repeated knob.
    """
    text = text.strip()
    head, sep, rest = text.partition(":")
    label = None
    if "=" in head:
        label, head = (s.strip() for s in head.split("=", 1))
        if not label:
            raise ValueError(f"variant {text!r}: empty label before '='")
    method = head.strip()
    if not method:
        raise ValueError(f"variant {text!r}: no method (expected [LABEL=]METHOD[:k=v,...])")
    items = [item.strip() for item in rest.split(",") if item.strip()] if sep else []
    knobs = parse_knobs(items, f"variant {text!r}: knob")
    return (label or text, method, knobs)


def _check_variants(variants: Sequence[Variant]) -> list[Variant]:
    """Fail before any rendering on unknown methods or knobs and on repeated labels."""
    out, seen = [], set()
    for v in variants:
        try:
            label, method, knobs = v
        except (TypeError, ValueError):
            raise ValueError(f"variants: expected (label, method, knobs), got {v!r}") from None
        knobs = dict(knobs or {})
        if label in seen:
            raise ValueError(f"variants: label {label!r} used twice")
        seen.add(label)
        if method not in METHODS:
            raise ValueError(f"variant {label!r}: unknown method {method!r}; available: "
                             f"{sorted(METHODS)}")
        unknown = sorted(set(knobs) - method_knobs(method))
        if unknown:
            raise TypeError(f"variant {label!r}: method {method!r} got unknown knobs {unknown}")
        out.append((label, method, knobs))
    if not out:
        raise ValueError("variants: need at least one")
    return out


# -- crops ---------------------------------------------------------------------------------

def hardest_region(error: np.ndarray, window: int = WINDOW) -> tuple[int, int]:
    """The pixel ``(y, x)`` whose ``window x window`` neighbourhood has the largest error.

    Parameters
    ----------
    error : numpy.ndarray
        (H, W) per-pixel error, or (H, W, C) (summed over channels).
    window : int
        Side of the box filter; windows are clipped at the image border (zeros outside).

    Returns
    -------
    tuple of int
        Row and column of the first maximum of the box-filtered error.
    """
    e = np.asarray(error, np.float64)
    if e.ndim == 3:
        e = e.sum(axis=2)
    if e.ndim != 2 or e.size == 0:
        raise ValueError(f"error: expected a non-empty (H, W) or (H, W, C) array, got {e.shape}")
    e = np.where(np.isfinite(e), e, 0.0)
    h, w = e.shape
    sat = np.zeros((h + 1, w + 1))
    sat[1:, 1:] = e.cumsum(0).cumsum(1)
    lo = window // 2
    y0 = np.clip(np.arange(h) - lo, 0, h)
    y1 = np.clip(np.arange(h) - lo + window, 0, h)
    x0 = np.clip(np.arange(w) - lo, 0, w)
    x1 = np.clip(np.arange(w) - lo + window, 0, w)
    box = (sat[y1][:, x1] - sat[y0][:, x1] - sat[y1][:, x0] + sat[y0][:, x0])
    y, x = np.unravel_index(int(np.argmax(box)), box.shape)
    return int(y), int(x)


def crop_montage(images: Sequence[np.ndarray], centre: tuple[int, int], crop: int = CROP,
                 gap: int = GAP) -> np.ndarray:
    """A horizontal strip of the same crop of each image, separated by black gaps.

    Parameters
    ----------
    images : sequence of numpy.ndarray
        (H, W, 3) images of one shape.
    centre : tuple of int
        ``(y, x)`` the crop is centred on; the crop is shifted to stay inside the image.
    crop : int
        Side of the crop; an image smaller than that on a side contributes its whole extent
        on that side.
    gap : int
        Width of the black columns between crops.

    Returns
    -------
    numpy.ndarray
        float32 (min(crop, H), n * min(crop, W) + (n - 1) * gap, 3).
    """
    if not images:
        raise ValueError("images: need at least one")
    shape = np.shape(images[0])
    if len(shape) != 3 or shape[2] != 3:
        raise ValueError(f"images: expected (H, W, 3), got {shape}")
    for i, img in enumerate(images):
        if np.shape(img) != shape:
            raise ValueError(f"images[{i}]: shape {np.shape(img)} differs from {shape}")
    h, w = shape[:2]
    ch, cw = min(crop, h), min(crop, w)
    y0 = int(np.clip(centre[0] - ch // 2, 0, h - ch))
    x0 = int(np.clip(centre[1] - cw // 2, 0, w - cw))
    n = len(images)
    strip = np.zeros((ch, n * cw + (n - 1) * gap, 3), np.float32)
    for i, img in enumerate(images):
        x = i * (cw + gap)
        strip[:, x:x + cw] = np.asarray(img, np.float32)[y0:y0 + ch, x0:x0 + cw]
    return strip


# -- the table -----------------------------------------------------------------------------


def frame_sources(scenes, inputs) -> tuple[list[str], list[tuple[str, str]], list[str]]:
    """``(scenes, inputs, input names)`` of a report: built-in scenes (default: all, or none
    when the user gives frames) and the user's ``(samples, reference)`` pairs, named after
    the samples file; every name unique."""
    inputs = [(str(a), str(b)) for a, b in (inputs or [])]
    scenes = list((SCENES if not inputs else []) if scenes is None else scenes)
    if not scenes and not inputs:
        raise ValueError("scenes: need at least one (or an input frame)")
    stems = [Path(a).stem for a, _ in inputs]
    if len(set(stems) | set(scenes)) != len(stems) + len(scenes):
        raise ValueError(f"inputs: frame names must be unique and differ from the scenes: "
                         f"{stems}")
    return scenes, inputs, stems

def methods_table(scenes: Sequence[str] | None = None,
                  variants: Sequence[Variant] | None = None,
                  size: tuple[int, int] = (512, 512), spp: int = 16,
                  device: DeviceSpec | Device = None, out_dir: str | Path = "out/methods",
                  repeats: int = 5, progress: Progress = None,
                  ref_spp: int | None = None,
                  inputs: Sequence[tuple[str, str]] | None = None) -> dict:
    """Time and score each variant on each scene; write the table, its JSON and crops.

    Parameters
    ----------
    scenes : sequence of str, optional
        Built-in scene names (default: all of :data:`clrecon.scenes.SCENES`).
    variants : sequence of (label, method, knobs), optional
        Default :data:`DEFAULT_VARIANTS`; see :func:`parse_variant` for a text form.
        Labels name the table's columns and must be unique.
    size : tuple of int
        ``(width, height)`` of every frame.
    spp : int
        Samples per pixel of the reconstructed buffers.
    device : int, str, Device or None
        See :func:`clrecon.core.device.get_device`.
    out_dir : str or Path
        Receives ``methods.json``, ``methods.md`` and ``{scene}_crops.png`` (created).
    repeats : int
        Timed runs per (scene, variant), after one warm-up run.
    progress : callable, optional
        ``progress(done, total)`` after the reference, the samples and each variant.
    ref_spp : int, optional
        Reference samples per pixel (default: each scene's converged default).
    inputs : sequence of (samples path, reference path), optional
        The user's own frames, each a row named after the file's stem at its own size and
        spp. With ``inputs`` and no ``scenes``, only the user's frames run.

    Returns
    -------
    dict
        ``device``, ``size``, ``spp``, ``repeats``, ``variants``, ``rows`` (one per scene and
        variant: ``scene``, ``variant``, ``method``, ``knobs``, ``describe``, ``ms``,
        ``pass_ms``, ``psnr``, ``ssim``, ``flip``, ``device``, ``size``, ``spp``,
        ``reference_spp``) and ``markdown`` (the text of ``methods.md``).

    Raises
    ------
    ValueError
        Bad size, spp, repeats, scene, variant, or a non-finite reconstruction.
    TypeError
        A variant's knob that its method does not take.
    """
    scenes, inputs, stems = frame_sources(scenes, inputs)
    variants = _check_variants(DEFAULT_VARIANTS if variants is None else variants)
    w, h = (int(v) for v in size)
    for name, v in (("width", w), ("height", h), ("spp", spp), ("repeats", repeats)):
        if not isinstance(v, (int, np.integer)) or v < 1:
            raise ValueError(f"{name}: must be a positive integer, got {v!r}")
    if ref_spp is not None and (not isinstance(ref_spp, (int, np.integer)) or ref_spp < 1):
        raise ValueError(f"ref_spp: must be a positive integer or None, got {ref_spp!r}")
    scene_objs = {name: get_scene(name) for name in scenes}  # unknown names fail here
    dev = get_device(device)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    steps, done = (len(scenes) + len(inputs)) * (2 + len(variants)), 0

    def step():
        nonlocal done
        done += 1
        if progress:
            progress(done, steps)

    def frames():
        """(name, samples, reference, reference spp) of every scene, then every input."""
        for name, scene in scene_objs.items():
            rspp = ref_spp or scene.reference_spp
            ref = render_reference(scene, w, h, rspp, seed=1)  # on the trusted device
            step()
            buf = render_samples(scene, w, h, spp, seed=100 + spp, device=dev)
            buf.validate()
            step()
            yield name, buf, ref, rspp
        for (path, ref_path), name in zip(inputs, stems):
            ref = load_image(ref_path)
            step()
            buf = load_samples(path)
            if ref.shape != (buf.height, buf.width, 3):
                raise ValueError(f"--reference {ref_path}: {ref.shape[1]}x{ref.shape[0]} image "
                                 f"for a {buf.width}x{buf.height} frame ({path})")
            step()
            yield name, buf, ref, None

    rows = []
    for name, buf, ref, rspp in frames():
        images = []
        for label, method, knobs in variants:
            image, ms, pass_ms, desc = time_pipeline(dev, buf, method, knobs, repeats)
            try:
                q = evaluate(image, ref)
            except ValueError as exc:
                raise ValueError(f"scene {name!r}, variant {label!r}: {exc}") from None
            images.append(image)
            rows.append({"scene": name, "variant": label, "method": method, "knobs": knobs,
                         "describe": desc, "ms": ms, "pass_ms": pass_ms, **q,
                         "device": dev.info.label, "size": [buf.width, buf.height],
                         "spp": buf.spp, "reference_spp": rspp})
            step()
        box = next((img for img, v in zip(images, variants) if v[1] == "box"), None)
        if box is None:
            box = run(buf, "box", dev).image
        centre = hardest_region(np.abs(box - ref))
        save_image(out / f"{name}_crops.png", crop_montage([ref, *images], centre))
    report = {"device": dev.info.label, "size": [w, h], "spp": spp, "repeats": repeats,
              "variants": [{"label": lab, "method": m, "knobs": k} for lab, m, k in variants],
              "rows": rows}
    report["markdown"] = _markdown(report)
    (out / "methods.json").write_text(json.dumps(
        {k: v for k, v in report.items() if k != "markdown"}, indent=2, default=str))
    (out / "methods.md").write_text(report["markdown"])
    return report


def _markdown(rep: dict) -> str:
    w, h = rep["size"]
    labels = [v["label"] for v in rep["variants"]]
    cells = {(r["scene"], r["variant"]): r for r in rep["rows"]}
    scenes = list(dict.fromkeys(r["scene"] for r in rep["rows"]))
    head = "| scene | " + " | ".join(labels) + " |"
    rule = "|---|" + "---|" * len(labels)

    def table(title: str, cell: Callable[[dict, dict], str]) -> list[str]:
        lines = [f"### {title}", "", head, rule]
        for s in scenes:
            best = {k: _best([cells[s, lab][k] for lab in labels], k == "flip")
                    for k in ("psnr", "flip")}
            lines.append(f"| {s} | " + " | ".join(cell(cells[s, lab], best) for lab in labels)
                         + " |")
        return lines + [""]

    def bold(text: str, on: bool) -> str:
        return f"**{text}**" if on else text

    lines = [f"Device: {rep['device']}; {w}x{h}, {rep['spp']} spp; device ms: median of "
             f"{rep['repeats']} runs after a warm-up; best per scene in bold.", ""]
    lines += table("device ms / PSNR dB / SSIM", lambda r, b: (
        f"{r['ms']:.2f} / " + bold(f"{r['psnr']:.2f}", r["psnr"] == b["psnr"])
        + f" / {r['ssim']:.4f}"))
    lines += table("FLIP (lower is better)",
                   lambda r, b: bold(f"{r['flip']:.4f}", r["flip"] == b["flip"]))
    lines += table("device ms per pass (median)", lambda r, b: ", ".join(
        f"{k} {v:.2f}" for k, v in r["pass_ms"].items()))
    return "\n".join(lines)


def _best(values: list[float], lower: bool) -> float:
    finite = [v for v in values if not math.isnan(v)]
    if not finite:
        return math.nan
    return min(finite) if lower else max(finite)
