"""The CLI's sequence commands: animated scenes and references (``scene``/``reference
--frames``), ``batch``, and ``compare`` of two sequences. Thin: parse, call, print."""
from __future__ import annotations

import argparse
import glob
import json
import os
import sys
from pathlib import Path

from clrecon.cli.common import Bar, check_knob_names, device_list, parse_knobs, timed

SAMPLE_FORMATS = ("npz", "bin", "txt", "exr")


def frame_name(scene: str, k: int) -> str:
    return f"{scene}_{k:04d}"


def _sequence_dir(opt: str, path: str) -> Path:
    out = Path(path)
    if out.exists() and not out.is_dir():
        raise ValueError(f"{opt}: {path} is a file; with --frames it names a folder")
    out.mkdir(parents=True, exist_ok=True)
    return out


def _frames(n) -> int:
    if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= 100_000:
        raise ValueError(f"--frames: must be an integer in [1, 100000], got {n!r}")
    return n


def _render_sequence(args, what: str, render, save, ext: str):
    """Render frame ``k`` of the animated scene with ``render(scene_k, w, h, seed)`` and
    ``save(path, result)`` it as ``DIR/<name>_<k>.<ext>``: ``(frames, size, seconds, dir,
    scene)``."""
    from clrecon.scenes import get_scene
    from clrecon.scenes.animate import frame_of, frame_seed

    n = _frames(args.frames)
    out = _sequence_dir("-o", args.output)
    scene = get_scene(args.name)
    w, h = args.size or scene.default_size
    bar = Bar(f"{what} {args.name}", unit="frame")

    def frames():
        for k in range(n):
            result = render(frame_of(scene, k), w, h, frame_seed(args.seed, k))
            save(str(out / f"{frame_name(args.name, k)}.{ext}"), result)
            bar(k + 1, n)

    try:
        _, seconds = timed(frames)
    finally:
        bar.close()
    return n, (w, h), seconds, out, scene


def scene_sequence(args) -> int:
    """``clrecon scene NAME --frames N -o DIR``: DIR/NAME_0000.<format>, ..."""
    from clrecon.io import save_samples
    from clrecon.scenes import render_samples

    n, (w, h), dt, out, _ = _render_sequence(
        args, "scene", lambda sc, w, h, seed: render_samples(
            sc, w, h, args.spp, seed=seed, device=args.device), save_samples, args.format)
    print(f"{args.name}: {n} frames {w}x{h}, {args.spp} spp in {dt:.1f} s "
          f"-> {out}/{frame_name(args.name, 0)}.{args.format} ...")
    return 0


def reference_sequence(args) -> int:
    """``clrecon reference NAME --frames N -o DIR``: DIR/NAME_0000.exr, ... (the stems of
    ``scene --frames``, so ``batch --references DIR`` pairs them)."""
    from clrecon.io import save_image
    from clrecon.scenes import render_reference

    n, (w, h), dt, out, scene = _render_sequence(
        args, "reference", lambda sc, w, h, seed: render_reference(
            sc, w, h, args.spp, seed=seed, device=args.device), save_image, "exr")
    spp = args.spp or scene.reference_spp
    print(f"{args.name}: {n} reference frames {w}x{h} at {spp} spp in {dt:.1f} s -> {out}/")
    return 0


def cmd_batch(args) -> int:
    from clrecon.batch import batch

    knobs = parse_knobs(args.knob)
    check_knob_names(args.method, knobs, "--knob: ")
    devices = None
    if args.devices is not None:
        from clrecon.core.device import list_devices

        devices = ([d.index for d in list_devices()] if args.devices == "all"
                   else list(args.devices))
    bar = Bar(f"batch {args.method}", unit="frame")
    done = [0]
    total = [0]

    def progress(rec):
        done[0] += 1
        bar(done[0], max(total[0], done[0]))
        if "error" in rec:
            print(f"clrecon batch: frame {rec['frame']} failed: {rec['error']}",
                  file=sys.stderr)

    from clrecon.batch import make_jobs

    total[0] = len(make_jobs(args.inputs, args.output, args.png, args.references))
    try:
        summary = batch(args.inputs, args.output, args.method, knobs, devices, args.png,
                        args.references, args.workers, args.scheduler,
                        resume=not args.no_resume, progress=progress)
    finally:
        bar.close()
    ok = [r for r in summary["frames"] if "error" not in r and not r.get("skipped")]
    line = (f"{len(ok)} frames reconstructed, {len(summary['skipped'])} already done, "
            f"{len(summary['failed'])} failed in {summary['wall_s']:.1f} s")
    if ok:
        line += f"; {sum(r['device_ms'] for r in ok) / len(ok):.1f} ms per frame on the device"
    with_q = [r for r in ok if "psnr" in r]
    if with_q:
        line += f"; mean PSNR {sum(r['psnr'] for r in with_q) / len(with_q):.2f} dB"
    print(f"{line} -> {args.output}/summary.json")
    return 1 if summary["failed"] else 0


def _image_sequence(path: str) -> list[str]:
    if os.path.isdir(path):
        files = sorted(glob.glob(os.path.join(path, "*.exr")) +
                       glob.glob(os.path.join(path, "*.png")))
    else:
        files = sorted(glob.glob(path))
    if not files:
        raise ValueError(f"compare: {path} holds no .exr or .png image")
    return files


def is_sequence(path: str) -> bool:
    return os.path.isdir(path) or glob.has_magic(path)


def compare_sequences_cmd(args) -> int:
    """``clrecon compare DIR_A DIR_B``: frames paired by file stem; per-frame quality and
    the flicker of the sequence."""
    from clrecon.io import load_image
    from clrecon.temporal import compare_sequences

    a, b = _image_sequence(args.a), _image_sequence(args.b)
    refs = {Path(f).stem: f for f in b}
    missing = [Path(f).stem for f in a if Path(f).stem not in refs]
    if missing:
        raise ValueError(f"compare: no reference in {args.b} for {', '.join(missing[:5])}"
                         f"{' ...' if len(missing) > 5 else ''}")
    names = [Path(f).stem for f in a]
    res = compare_sequences([load_image(f) for f in a], [load_image(refs[n]) for n in names],
                            names)
    if args.json:
        print(json.dumps(res))
        return 0
    for f in res["frames"]:
        print(f"{f['frame']}: PSNR {f['psnr']:.2f} dB, SSIM {f['ssim']:.4f}, "
              f"FLIP {f['flip']:.4f}")
    tail = ""
    if "flicker_rmse" in res:
        tail = (f"; flicker {res['flicker_rmse']:.4f} (temporal PSNR "
                f"{res['temporal_psnr']:.2f} dB)")
    print(f"{len(names)} frames: mean PSNR {res['mean_psnr']:.2f} dB, SSIM "
          f"{res['mean_ssim']:.4f}, FLIP {res['mean_flip']:.4f}{tail}")
    return 0


def add_batch_parser(sub) -> None:
    sp = sub.add_parser("batch", help="reconstruct many frames on every device or a Dask "
                        "cluster, resumable, with a JSON summary")
    sp.add_argument("inputs", nargs="+", help="sample files or globs (.bin/.txt/.exr/.npz)")
    sp.add_argument("-o", "--output", required=True, help="output folder: <stem>.exr")
    sp.add_argument("--method", default="box", help="default: %(default)s")
    sp.add_argument("--knob", action="append", default=[], metavar="K=V")
    sp.add_argument("--devices", type=device_list, default=None, metavar="all|D,...",
                    help="devices working in parallel; --device D,... is the same option "
                    "(default: the default device)")
    sp.add_argument("--device", dest="devices", type=device_list, default=argparse.SUPPRESS,
                    help=argparse.SUPPRESS)
    sp.add_argument("--workers", type=int, default=None,
                    help="run on a local Dask cluster of N worker processes")
    sp.add_argument("--scheduler", default=None, metavar="ADDRESS",
                    help="run on the Dask cluster at ADDRESS (tcp://host:8786)")
    sp.add_argument("--png", action="store_true", help="also write <stem>.png")
    sp.add_argument("--references", default=None, metavar="DIR",
                    help="score each frame against DIR/<stem>.exr")
    sp.add_argument("--no-resume", action="store_true",
                    help="reconstruct frames whose outputs exist too")
    sp.set_defaults(fn=cmd_batch)
