"""The commands that make and judge images: ``scene``, ``reference``, ``reconstruct``,
``compare`` and ``psf``."""
from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from clrecon.cli.common import (
    check_files,
    check_knob_names,
    check_output,
    parse_knobs,
    sample_files,
    stage,
    timed,
    with_bar,
)
from clrecon.cli.knob_flags import flag_knobs
from clrecon.cli.sequences import (
    compare_sequences_cmd,
    is_sequence,
    reference_sequence,
    scene_sequence,
)


def _render_one(args, what: str, allowed: tuple[str, ...], render, save):
    """Render ``args.name`` with ``render(scene, w, h)`` and ``save`` it to ``-o`` (checked
    first): ``(scene, result, (w, h), seconds of the render)``."""
    from clrecon.scenes import get_scene

    check_output("-o", args.output, allowed)
    stage(args, what)
    scene = get_scene(args.name)
    w, h = args.size or scene.default_size
    result, seconds = timed(lambda: render(scene, w, h))
    stage(args, "writing", args.output)
    save(args.output, result)
    return scene, result, (w, h), seconds


def cmd_scene(args) -> int:
    from clrecon.io import SAMPLE_EXTENSIONS, save_samples
    from clrecon.scenes import render_samples

    if args.frames is not None:
        return scene_sequence(args)

    def render(scene, w, h):
        if args.pinhole:  # synthesis input: S = 1, lens 0, time 0.5
            from clrecon.scenes.render import render_pinhole

            args.spp = 1
            return render_pinhole(scene, w, h, device=args.device)
        return with_bar(f"render {args.name}", render_samples, scene, w, h, args.spp,
                        seed=args.seed, device=args.device)

    _, buf, (w, h), dt = _render_one(args, f"rendering scene {args.name}", SAMPLE_EXTENSIONS,
                                     render, save_samples)
    info = buf.inspect()
    print(f"{args.name}: {w}x{h}, {args.spp} spp, {w * h * args.spp / dt / 1e6:.1f} M samples/s "
          f"({dt * 1e3:.0f} ms); max |CoC| {info.max_abs_coc:.1f} px, max |motion| "
          f"{info.max_abs_motion:.1f} px -> {args.output}")
    return 0


def cmd_reference(args) -> int:
    from clrecon.io import IMAGE_EXTENSIONS, save_image
    from clrecon.scenes import render_reference

    if args.frames is not None:
        return reference_sequence(args)
    scene, _, (w, h), dt = _render_one(
        args, f"rendering the reference of scene {args.name}", IMAGE_EXTENSIONS,
        lambda scene, w, h: with_bar(f"reference {args.name}", render_reference, scene, w, h,
                                     args.spp, seed=args.seed, device=args.device),
        save_image)
    spp = args.spp or scene.reference_spp
    print(f"{args.name}: reference {w}x{h} at {spp} spp in {dt:.1f} s -> {args.output}")
    return 0


def quality(image, reference_path, ref=None) -> dict:
    """PSNR, SSIM and FLIP of ``image`` against ``ref`` (read from ``reference_path`` when
    not given); a reference of another shape is refused."""
    from clrecon.io import load_image
    from clrecon.metrics import evaluate

    if ref is None:
        ref = load_image(reference_path)
    if ref.shape != image.shape:
        raise ValueError(f"reference {reference_path}: shape {ref.shape} does not match the "
                         f"image {image.shape}")
    return evaluate(image, ref)


def _sample_file_spp(path) -> int | None:
    """The spp of a clrecon sample EXR (OpenImageIO header: ``clrecon:format`` is
    ``samples``, or channels ``s0.R``...), ``0`` when it is one without a readable spp,
    ``None`` when it is not a sample EXR (or cannot be read: the image reader says why)."""
    path = str(path)
    if os.path.splitext(path)[1].lower() != ".exr" or not os.path.isfile(path):
        return None
    try:
        import OpenImageIO as oiio

        inp = oiio.ImageInput.open(path)
        if inp is None:
            return None
        try:
            spec = inp.spec()
        finally:
            inp.close()
        names = list(spec.channelnames)
        fmt = spec.getattribute("clrecon:format")
        if fmt != "samples" and not (names and names[0].startswith("s0.")):
            return None
        spp = spec.getattribute("clrecon:spp")
        try:
            return max(int(spp), 0)
        except (TypeError, ValueError):
            return len({n.split(".", 1)[0] for n in names if n[:1] == "s" and "." in n})
    except Exception:  # an unreadable header: the image reader reports it
        return None


def refuse_sample_file(what: str, path) -> None:
    """An image argument (``what``: its option, or empty) that is a sample buffer: say so
    in one line, before reading it."""
    ext = os.path.splitext(str(path))[1].lower()
    kind = None
    if ext in (".npz", ".bin", ".txt"):
        kind = f"a {ext} sample buffer"
    else:
        spp = _sample_file_spp(path)
        if spp is not None:
            kind = f"a sample buffer ({spp} spp)" if spp else "a sample buffer"
    if kind is not None:
        raise ValueError(f"{what + ' ' if what else ''}{path}: is {kind}, not an image; "
                         f"reconstruct it first: clrecon reconstruct {path} -o image.exr")


def _check_reconstruct_files(args) -> None:
    """The input, ``--reference``, ``-o`` and ``--error``: no output one of the inputs, every
    output writable, before anything is read."""
    from clrecon.io import IMAGE_EXTENSIONS

    reads = {"input": sample_files(args.input)}
    if args.reference:
        reads["--reference"] = [str(args.reference)]
        refuse_sample_file("--reference", args.reference)
    writes = {"-o": [str(args.output)]} | ({"--error": [str(args.error)]} if args.error else {})
    check_files(reads, writes)
    check_output("-o", args.output, IMAGE_EXTENSIONS)
    if args.error:
        check_output("--error", args.error, (".exr",))


def cmd_reconstruct(args) -> int:
    from clrecon.api import run
    from clrecon.io import load_image, load_samples, save_image

    knobs = flag_knobs(args, parse_knobs(args.knob))
    check_knob_names(args.method, knobs)
    _check_reconstruct_files(args)
    stage(args, "reading samples", args.input)
    buf = load_samples(args.input, allow_negative=args.allow_negative)
    ref = None
    if args.reference:  # read before the output is written (and before the long part)
        stage(args, "reading the reference", args.reference)
        ref = load_image(args.reference)
    stage(args, f"reconstructing {args.input} with {args.method}")
    res = run(buf, args.method, args.device, allow_negative=args.allow_negative,
              estimate_error=bool(args.error), **knobs)
    stage(args, "writing", args.output)
    save_image(args.output, res.image)
    if args.error:
        save_image(args.error, np.repeat(res.error[..., None], 3, -1))
    _print_reconstruction(args, buf, res, ref)
    return 0


def _print_reconstruction(args, buf, res, ref) -> None:
    out = {"input": str(args.input), "output": str(args.output), "device": res.device,
           "size": [buf.width, buf.height], "spp": buf.spp, **res.method,
           "pass_ms": res.pass_ms, "device_ms": res.device_ms, "upload_ms": res.upload_ms,
           "plan_ms": res.plan_ms, "frame_ms": res.frame_ms, "wall_ms": res.wall_ms}
    if ref is not None:
        out["quality"] = quality(res.image, args.reference, ref)
    if args.json:
        print(json.dumps(out, indent=2))
        return
    passes = ", ".join(f"{k} {v:.2f} ms" for k, v in res.pass_ms.items())
    print(f"{args.method} on {res.device}: {passes} (device {res.device_ms:.2f} ms, "
          f"frame with upload and readback {res.frame_ms:.1f} ms, planning and program "
          f"builds {res.plan_ms:.1f} ms) -> {args.output}")
    if "quality" in out:
        q = out["quality"]
        print(f"quality vs {args.reference}: PSNR {q['psnr']:.2f} dB, SSIM {q['ssim']:.4f}, "
              f"FLIP {q['flip']:.4f}")


def cmd_compare(args) -> int:
    from clrecon.io import load_image

    if is_sequence(args.a) or is_sequence(args.b):
        return compare_sequences_cmd(args)
    refuse_sample_file("", args.a)
    refuse_sample_file("", args.b)
    stage(args, "reading", args.a)
    image = load_image(args.a)
    stage(args, "reading", args.b)
    q = quality(image, args.b)
    if args.json:
        print(json.dumps(q))
    else:
        print(f"{args.a} vs {args.b}: PSNR {q['psnr']:.2f} dB, SSIM {q['ssim']:.4f}, "
              f"FLIP {q['flip']:.4f}")
    return 0


def cmd_psf(args) -> int:
    from clrecon.methods.splat.precompute import SparsifyOptions, build_table, table_path

    opts = SparsifyOptions(failures=args.failures, lloyd=args.lloyd, anneal=args.anneal,
                           spacing=args.spacing)
    if args.output:
        check_output("-o", args.output)
    stage(args, f"building the {args.model} table")
    table, dt = timed(lambda: with_bar(f"psf {args.model}", build_table, args.model, opts,
                                       unit="cells"))
    out = Path(args.output) if args.output else table_path(args.model)
    stage(args, "writing", out)
    table.save(out)
    size = out.stat().st_size
    print(f"{args.model}: {table.cells} cells, {len(table.points)} spreadlets, mean sparsity "
          f"{100 * table.sparsity().mean():.1f}%, mean L1 error {table.errors.mean():.3f}, "
          f"{size / 1e6:.2f} MB, built in {dt:.0f} s (failures {opts.failures}, lloyd "
          f"{opts.lloyd}, anneal {opts.anneal}) -> {out}")
    return 0

