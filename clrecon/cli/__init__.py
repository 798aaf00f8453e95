"""The ``clrecon`` command line: a thin layer that parses, calls the library and prints.

Subcommands: ``devices``, ``scene``, ``reference``, ``reconstruct``, ``compare``, ``demo``
(the quick start's main job) and ``report`` (generator throughput, reference convergence
and box-filter quality of the built-in scenes); ``table`` compares the device time and
quality of reconstruction variants side by side; ``trade`` measures every method's
speed/accuracy knobs against ``box`` and Open Image Denoise.
"""
from __future__ import annotations

import argparse
import errno
import json
import logging
import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from clrecon.cli import sequences as cli_sequences
from clrecon.core.fsutil import cache_dir, write_atomic

log = logging.getLogger("clrecon")


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WxH (e.g. 512x512), got {text!r}") from None
    if w < 1 or h < 1:
        raise argparse.ArgumentTypeError(f"size must be positive, got {text!r}")
    return w, h


def _names(text: str) -> list[str]:
    """A comma-separated list of names (``--scenes``, ``--methods``); empty items dropped."""
    return [t for t in text.split(",") if t]


def _int_list(text: str) -> list[int]:
    try:
        return [int(v) for v in text.split(",") if v]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a comma-separated list, got {text!r}") from None


# -- what a command reads and writes -------------------------------------------------------

def _stage(args, what: str, path=None) -> None:
    """Record what the command is doing: an error that names nothing is reported with it."""
    args.stage = (what, None if path is None else str(path))


def _sample_files(path) -> list[str]:
    """The files a sample buffer path stands for (TLFR: the data file and its header)."""
    path = str(path)
    if os.path.splitext(path)[1].lower() in (".bin", ".txt"):
        return [path, path + ".header"]
    return [path]


def _same_file(a: str, b: str) -> bool:
    """Whether ``a`` and ``b`` are one file: the same path after resolving links, or (both
    existing) the same inode."""
    if os.path.realpath(a) == os.path.realpath(b):
        return True
    try:
        return os.path.samefile(a, b)
    except OSError:  # one of them does not exist (yet)
        return False


def _check_files(reads: dict[str, list[str]], writes: dict[str, list[str]]) -> None:
    """Refuse, before anything is read or written, an output that is one of the inputs or
    another output (``reads``/``writes``: the option naming them -> their files)."""
    outs = [(opt, f) for opt, files in writes.items() for f in files]
    for i, (opt, out) in enumerate(outs):
        for what, files in reads.items():
            for f in files:
                if _same_file(out, f):
                    raise ValueError(f"{opt} {out}: is the same file as the {what} {f}; "
                                     f"refusing to overwrite it (write elsewhere)")
        for opt2, out2 in outs[:i]:
            if _same_file(out, out2) and opt2 != opt:
                raise ValueError(f"{opt} {out}: is the same file as {opt2} {out2}")


def _check_output(opt: str, path, allowed: tuple[str, ...] | None = None) -> None:
    """What saving ``path`` would refuse, checked before the work that produces it: the
    extension, a missing parent folder, a folder in the file's place."""
    path = str(path)
    if allowed is not None:
        ext = os.path.splitext(path)[1].lower()
        if ext not in allowed:
            raise ValueError(f"{opt} {path}: unsupported extension {ext or '(none)'!r}; "
                             f"supported: {', '.join(allowed)}")
    parent = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(parent):
        raise FileNotFoundError(errno.ENOENT, f"no folder {parent} to write into ({opt})",
                                path)
    if os.path.isdir(path):
        raise IsADirectoryError(errno.EISDIR, f"is a directory, not a file ({opt})", path)


def _check_output_dir(opt: str, path) -> None:
    """An output folder: refuse an existing file in its place before any work."""
    if os.path.exists(path) and not os.path.isdir(path):
        raise NotADirectoryError(errno.ENOTDIR, f"exists and is not a folder ({opt})",
                                 str(path))


# -- knobs ----------------------------------------------------------------------------------

def _parse_knobs(items) -> dict:
    """``--knob NAME=VALUE`` options as a dict (values as in ``clrecon table``'s variants)."""
    from clrecon.bench.table import parse_value

    knobs = {}
    for item in items or []:
        name, eq, value = item.partition("=")
        name = name.strip()
        if not eq or not name:
            raise ValueError(f"--knob {item!r}: expected NAME=VALUE (e.g. --knob tile=8)")
        if name in knobs:
            raise ValueError(f"--knob {name}: given twice")
        knobs[name] = parse_value(value.strip())
    return knobs


def _check_knob_names(method: str, knobs: dict, what: str = "") -> None:
    """Unknown methods and knobs as a ``ValueError`` before any work (the library's
    ``make_pipeline`` says ``TypeError``, an API misuse there, a typo here)."""
    from clrecon.core.pipeline import METHODS, _load_methods, method_knobs

    _load_methods()
    if method not in METHODS:
        raise ValueError(f"{what}method: unknown {method!r}; available: {sorted(METHODS)}")
    accepted = method_knobs(method)
    unknown = sorted(set(knobs) - accepted)
    if unknown:
        raise ValueError(f"{what}method {method!r} got unknown knobs: {unknown}; it takes "
                         f"{sorted(accepted)}")


class _HelpFormatter(argparse.HelpFormatter):
    """Every option's help ends with its default, unless it already names one or there is
    none to show (``None``, a flag's ``False``); sizes as WxH, lists comma-separated."""

    def _get_help_string(self, action):
        text = action.help or ""
        default = action.default
        if (not action.option_strings or action.nargs == 0 or default is None
                or default is argparse.SUPPRESS or default is False
                or "default" in text.lower()):
            return text
        if isinstance(default, tuple) and len(default) == 2 and action.type is _size:
            shown = f"{default[0]}x{default[1]}"
        elif isinstance(default, (list, tuple)):
            shown = ",".join(map(str, default))
        else:
            shown = str(default)
        shown = shown.replace("%", "%%")
        return f"{text} (default: {shown})" if text else f"default: {shown}"


def _stderr_is_terminal() -> bool:
    try:
        return sys.stderr.isatty()
    except (AttributeError, ValueError):
        return False


def _stage_logger(command: str):
    """``log(line)`` for a command's long stages: a line on stderr where there is no terminal
    for a progress bar to show on (a log, a pipe, CI); nothing on a terminal."""
    quiet = _stderr_is_terminal()

    def log(line: str) -> None:
        if not quiet:
            print(f"clrecon {command}: {line}", file=sys.stderr, flush=True)

    return log


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


def _refuse_sample_file(what: str, path) -> None:
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


class _Bar:
    """A tqdm progress bar usable as a ``progress(done, total)`` callback."""

    def __init__(self, desc: str, unit: str = "it", scale: float = 1.0):
        from tqdm import tqdm

        self.bar = tqdm(desc=desc, unit=unit, unit_scale=True, leave=False, disable=None,
                        file=sys.stderr)
        self.scale = scale

    def __call__(self, done: int, total: int) -> None:
        self.bar.total = total * self.scale
        self.bar.n = done * self.scale
        self.bar.refresh()

    def close(self):
        self.bar.close()


def _with_bar(desc, fn, *args, **kw):
    bar = _Bar(desc, unit="samples")
    try:
        return fn(*args, progress=bar, **kw)
    finally:
        bar.close()


# -- subcommands ---------------------------------------------------------------------------

def cmd_devices(args) -> int:
    from clrecon.core.device import list_devices

    devs = list_devices()
    if args.json:
        print(json.dumps([d.__dict__ | {"atomics": d.atomics} for d in devs], indent=2))
        return 0
    for d in devs:
        print(f"[{d.index}] {d.platform} / {d.name}")
        print(f"    driver {d.driver}, {d.version}, type {d.device_type}")
        print(f"    {d.compute_units} compute units, {d.global_mem_bytes / 2**30:.1f} GiB global, "
              f"{d.local_mem_bytes / 1024:.0f} KiB local, max work-group {d.max_work_group_size}")
        print(f"    images: {'yes' if d.image_support else 'no'}; atomics: {d.atomics}")
    return 0


def cmd_scene(args) -> int:
    from clrecon.io import SAMPLE_EXTENSIONS, save_samples
    from clrecon.scenes import get_scene, render_samples

    if args.frames is not None:
        return cli_sequences.scene_sequence(args, _Bar)
    _check_output("-o", args.output, SAMPLE_EXTENSIONS)
    _stage(args, f"rendering scene {args.name}")
    scene = get_scene(args.name)
    w, h = args.size or scene.default_size
    t0 = time.perf_counter()
    if args.pinhole:  # synthesis input: S = 1, lens 0, time 0.5
        from clrecon.scenes.render import render_pinhole

        args.spp = 1
        buf = render_pinhole(scene, w, h, device=args.device)
    else:
        buf = _with_bar(f"render {args.name}", render_samples, scene, w, h, args.spp,
                        seed=args.seed, device=args.device)
    dt = time.perf_counter() - t0
    _stage(args, "writing", args.output)
    save_samples(args.output, buf)
    info = buf.inspect()
    print(f"{args.name}: {w}x{h}, {args.spp} spp, {w * h * args.spp / dt / 1e6:.1f} M samples/s "
          f"({dt * 1e3:.0f} ms); max |CoC| {info.max_abs_coc:.1f} px, max |motion| "
          f"{info.max_abs_motion:.1f} px -> {args.output}")
    return 0


def cmd_reference(args) -> int:
    from clrecon.io import IMAGE_EXTENSIONS, save_image
    from clrecon.scenes import get_scene, render_reference

    if args.frames is not None:
        return cli_sequences.reference_sequence(args, _Bar)
    _check_output("-o", args.output, IMAGE_EXTENSIONS)
    _stage(args, f"rendering the reference of scene {args.name}")
    scene = get_scene(args.name)
    w, h = args.size or scene.default_size
    t0 = time.perf_counter()
    img = _with_bar(f"reference {args.name}", render_reference, scene, w, h, args.spp,
                    seed=args.seed, device=args.device)
    dt = time.perf_counter() - t0
    _stage(args, "writing", args.output)
    save_image(args.output, img)
    spp = args.spp or scene.reference_spp
    print(f"{args.name}: reference {w}x{h} at {spp} spp in {dt:.1f} s -> {args.output}")
    return 0


def _quality(image, reference_path, ref=None) -> dict:
    from clrecon.io import load_image
    from clrecon.metrics import evaluate

    if ref is None:
        ref = load_image(reference_path)
    if ref.shape != image.shape:
        raise ValueError(f"reference {reference_path}: shape {ref.shape} does not match the "
                         f"image {image.shape}")
    return evaluate(image, ref)


def cmd_reconstruct(args) -> int:
    from clrecon.core.pipeline import run
    from clrecon.io import IMAGE_EXTENSIONS, load_samples, save_image

    knobs = _parse_knobs(args.knob)
    for name in METHOD_FLAGS:  # method flags given on the command line become knobs
        value = getattr(args, name)
        if value is not None and value is not False:
            if name in knobs:
                flag = "--" + name.replace("_", "-")
                raise ValueError(f"--knob {name}: also given as {flag}; give it once")
            knobs[name] = value
    if args.safeguard is not None:
        if "safeguard" in knobs:
            raise ValueError("--knob safeguard: also given as --safeguard; give it once")
        knobs["safeguard"] = args.safeguard
    _check_knob_names(args.method, knobs)
    reads = {"input": _sample_files(args.input)}
    if args.reference:
        reads["--reference"] = [str(args.reference)]
        _refuse_sample_file("--reference", args.reference)
    writes = {"-o": [str(args.output)]} | ({"--error": [str(args.error)]} if args.error else {})
    _check_files(reads, writes)
    _check_output("-o", args.output, IMAGE_EXTENSIONS)
    if args.error:
        _check_output("--error", args.error, (".exr",))
    _stage(args, "reading samples", args.input)
    buf = load_samples(args.input, allow_negative=args.allow_negative)
    ref = None
    if args.reference:  # read before the output is written (and before the long part)
        from clrecon.io import load_image

        _stage(args, "reading the reference", args.reference)
        ref = load_image(args.reference)
    _stage(args, f"reconstructing {args.input} with {args.method}")
    res = run(buf, args.method, args.device, allow_negative=args.allow_negative,
              estimate_error=bool(args.error), **knobs)
    _stage(args, "writing", args.output)
    save_image(args.output, res.image)
    if args.error:
        save_image(args.error, np.repeat(res.error[..., None], 3, -1))
    out = {"input": str(args.input), "output": str(args.output), "device": res.device,
           "size": [buf.width, buf.height], "spp": buf.spp, **res.method,
           "pass_ms": res.pass_ms, "device_ms": res.device_ms, "upload_ms": res.upload_ms,
           "total_ms": res.total_ms}
    if ref is not None:
        out["quality"] = _quality(res.image, args.reference, ref)
    if args.json:
        print(json.dumps(out, indent=2))
        return 0
    passes = ", ".join(f"{k} {v:.2f} ms" for k, v in res.pass_ms.items())
    print(f"{args.method} on {res.device}: {passes} (device {res.device_ms:.2f} ms, "
          f"total with upload and readback {res.total_ms:.1f} ms) -> {args.output}")
    if "quality" in out:
        q = out["quality"]
        print(f"quality vs {args.reference}: PSNR {q['psnr']:.2f} dB, SSIM {q['ssim']:.4f}, "
              f"FLIP {q['flip']:.4f}")
    return 0


def cmd_psf(args) -> int:
    from clrecon.methods.splat.precompute import SparsifyOptions, build_table, table_path

    opts = SparsifyOptions(failures=args.failures, lloyd=args.lloyd, anneal=args.anneal,
                           spacing=args.spacing)
    if args.output:
        _check_output("-o", args.output)
    _stage(args, f"building the {args.model} table")
    bar = _Bar(f"psf {args.model}", unit="cells")
    t0 = time.perf_counter()
    try:
        table = build_table(args.model, opts, progress=bar)
    finally:
        bar.close()
    dt = time.perf_counter() - t0
    out = Path(args.output) if args.output else table_path(args.model)
    _stage(args, "writing", out)
    table.save(out)
    size = out.stat().st_size
    print(f"{args.model}: {table.cells} cells, {len(table.points)} spreadlets, mean sparsity "
          f"{100 * table.sparsity().mean():.1f}%, mean L1 error {table.errors.mean():.3f}, "
          f"{size / 1e6:.2f} MB, built in {dt:.0f} s (failures {opts.failures}, lloyd "
          f"{opts.lloyd}, anneal {opts.anneal}) -> {out}")
    return 0


#: argparse destinations of ``reconstruct`` that are method knobs of the same name
METHOD_FLAGS = ("scales", "dof_layers", "exponent", "sort", "tile", "group",
                "mode", "filter", "stats_stride", "merge_threshold",  # layered
                "psf", "layers", "pyramid", "dense", "mip_radius")  # splat


def cmd_compare(args) -> int:
    from clrecon.io import load_image

    if cli_sequences.is_sequence(args.a) or cli_sequences.is_sequence(args.b):
        return cli_sequences.compare_sequences_cmd(args)
    _refuse_sample_file("", args.a)
    _refuse_sample_file("", args.b)
    _stage(args, "reading", args.a)
    image = load_image(args.a)
    _stage(args, "reading", args.b)
    q = _quality(image, args.b)
    if args.json:
        print(json.dumps(q))
    else:
        print(f"{args.a} vs {args.b}: PSNR {q['psnr']:.2f} dB, SSIM {q['ssim']:.4f}, "
              f"FLIP {q['flip']:.4f}")
    return 0


def reference_cache_dir() -> Path | None:
    """Folder of the demo's cached references, or ``None`` when caching is off:
    ``$CLRECON_CACHE_DIR/references`` (``off`` or empty: no cache), else
    ``$XDG_CACHE_HOME/clrecon/references``, else ``~/.cache/clrecon/references``."""
    return cache_dir("references")


def _reference_cache_name(scene, w: int, h: int, spp: int, seed: int, device) -> str:
    """File name of a cached reference: what it is, and a digest of everything it depends
    on (the renderer's kernel source with its headers, the host renderer, the scene's
    definition, the device that renders it: its platform, name and driver)."""
    import hashlib

    from clrecon.core.device import source_hash
    from clrecon.scenes import render as render_module

    digest = hashlib.sha256()
    for part in ("clrecon-reference/1", scene.name, f"{w}x{h}", str(spp), str(seed),
                 source_hash("raytrace"), Path(render_module.__file__).read_text(),
                 repr(scene), device.info.label, device.info.driver):
        data = part.encode()
        digest.update(len(data).to_bytes(8, "little"))
        digest.update(data)
    return f"{scene.name}_{w}x{h}_{spp}spp_seed{seed}_{digest.hexdigest()[:20]}.npy"


def _load_cached_reference(path: Path | None, w: int, h: int) -> np.ndarray | None:
    if path is None:
        return None
    try:
        img = np.load(path, allow_pickle=False)
    except FileNotFoundError:
        return None
    except Exception as exc:  # truncated or corrupt: render again (and replace it)
        log.debug("reference cache: %s unreadable (%s)", path, exc)
        return None
    if img.shape != (h, w, 3) or img.dtype != np.float32 or not np.isfinite(img).all():
        log.debug("reference cache: %s holds a %s %s array", path, img.shape, img.dtype)
        return None
    return img


def _store_cached_reference(path: Path | None, img: np.ndarray) -> bool:
    """Write ``img`` to ``path`` atomically; ``False`` (logged) where it cannot be written."""
    import io

    if path is None:
        return False
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        data = io.BytesIO()
        np.save(data, np.ascontiguousarray(img, np.float32), allow_pickle=False)
        write_atomic(path, data.getvalue())
        return True
    except OSError as exc:  # read-only or full disk: the demo goes on without it
        log.info("reference cache: could not write %s (%s)", path, exc)
        return False


def cmd_demo(args) -> int:
    from clrecon.core.device import trusted_device
    from clrecon.core.pipeline import run
    from clrecon.io import save_image
    from clrecon.metrics import evaluate
    from clrecon.scenes import get_scene, render_reference, render_samples

    methods = [m for m in args.methods.split(",") if m]
    for method in methods:
        if method != "oidn":
            _check_knob_names(method, {}, "--methods: ")
    if not methods:
        raise ValueError(f"--methods: no method in {args.methods!r}")
    _check_output_dir("-o", args.output)
    scene = get_scene(args.scene)
    # the reference judges the device under test (--device), so it never comes from it
    ref_dev = trusted_device()
    out = Path(args.output)
    _stage(args, "creating", out)
    out.mkdir(parents=True, exist_ok=True)
    _stage(args, f"rendering scene {args.scene}")
    stage_log = _stage_logger("demo")
    w, h = args.size or scene.default_size
    ref_spp = args.ref_spp or scene.reference_spp
    # the first frame of a shape pays for program build and PoCL's per-shape specialisation
    t0 = time.perf_counter()
    render_samples(scene, w, h, args.spp, seed=args.seed, device=args.device)
    stage_log(f"first render (program build): {time.perf_counter() - t0:.1f} s")
    t0 = time.perf_counter()
    buf = _with_bar("samples", render_samples, scene, w, h, args.spp, seed=args.seed,
                    device=args.device)
    t_render = time.perf_counter() - t0
    stage_log(f"samples {w}x{h} at {args.spp} spp: {t_render:.2f} s")
    folder = reference_cache_dir()
    cache = None if folder is None else \
        folder / _reference_cache_name(scene, w, h, ref_spp, args.seed + 1, ref_dev)
    t0 = time.perf_counter()
    ref = _load_cached_reference(cache, w, h)
    if ref is not None:
        t_ref = time.perf_counter() - t0
        ref_note = f"reference {ref_spp} spp from the cache ({cache})"
        stage_log(f"reference {w}x{h} at {ref_spp} spp: read from the cache {cache}")
    else:
        _stage(args, f"rendering the reference of scene {args.scene}")
        stage_log(f"reference {w}x{h} at {ref_spp} spp: rendering"
                  + ("" if cache is None else " (cached for the next run)"))
        ref = _with_bar("reference", render_reference, scene, w, h, ref_spp,
                        seed=args.seed + 1, device=ref_dev)
        t_ref = time.perf_counter() - t0
        stored = _store_cached_reference(cache, ref)
        ref_note = f"reference {ref_spp} spp in {t_ref:.1f} s" + (
            " (cached for the next run)" if stored else "")
        stage_log(f"reference {w}x{h} at {ref_spp} spp: {t_ref:.1f} s")
    _stage(args, "writing the reference into", out)
    save_image(out / f"{args.scene}_reference.exr", ref)
    save_image(out / f"{args.scene}_reference.png", ref)
    print(f"scene {args.scene} {w}x{h}: {args.spp} spp rendered in {t_render * 1e3:.0f} ms "
          f"({w * h * args.spp / t_render / 1e6:.1f} M samples/s); {ref_note}")
    print(f"reference device: {ref_dev.info.label} (references never come from the device "
          f"under test)")
    device = None
    for method in methods:
        _stage(args, f"running {method} on scene {args.scene}")
        t0 = time.perf_counter()
        if method == "oidn":
            image, device_ms, total_ms = _demo_oidn(buf, args.device)
        else:
            run(buf, method, args.device)  # warm-up: program build and first-launch costs
            res = run(buf, method, args.device)
            image, device_ms, total_ms, device = res.image, res.device_ms, res.total_ms, res.device
        q = evaluate(image, ref)
        save_image(out / f"{args.scene}_{method}.exr", image)
        save_image(out / f"{args.scene}_{method}.png", image)
        stage_log(f"{method}: {time.perf_counter() - t0:.1f} s (program build, warm-up, timed "
                  f"run, quality, images)")
        print(f"{method:8s} device {device_ms:8.2f} ms (total {total_ms:7.1f} ms)  "
              f"PSNR {q['psnr']:.2f} dB  SSIM {q['ssim']:.4f}  FLIP {q['flip']:.4f}")
    print("device ms: the passes' time on the device (profiling events; on a CPU device the "
          "kernels' wall time). total ms: the wall time of a call after a warm-up call, i.e. "
          "sample upload, sample inspection, planning (0 once cached), every pass and the "
          "image's readback; program builds are in the warm-up, not in it.")
    print(f"quality against the {ref_spp}-spp reference: PSNR (dB) and SSIM, higher is "
          "better; FLIP, lower is better. FLIP models what a viewer notices (edges, colour "
          "and contrast differences) while PSNR averages squared error, so the two can rank "
          "methods differently.")
    if "oidn" in methods:
        print("oidn: the box image denoised by Intel Open Image Denoise (pyoidn, CPU, quality "
              "high); its device and total ms are box's plus the denoiser's wall time")
    print(f"device: {device}")
    print(f"images in {out}/")
    return 0


def _demo_oidn(buf, device):
    """The baseline a user would otherwise pick: box, then Open Image Denoise on the CPU."""
    import pyoidn

    from clrecon.core.pipeline import run

    run(buf, "box", device)
    res = run(buf, "box", device)
    pyoidn.denoise(res.image, hdr=True, quality="high")  # warm-up: loads the network
    t0 = time.perf_counter()
    image = np.asarray(pyoidn.denoise(res.image, hdr=True, quality="high"), np.float32)
    ms = (time.perf_counter() - t0) * 1e3
    return image, res.device_ms + ms, res.total_ms + ms


def cmd_report(args) -> int:
    from clrecon.bench.report import foundation_report

    _check_output_dir("-o", args.output)
    _stage(args, "measuring the report into", args.output)
    bar = _Bar("report", unit="step")
    try:
        rep = foundation_report(args.scenes, size=args.size or (512, 512), spps=args.spp,
                                ref_spp=args.ref_spp, device=args.device, out_dir=args.output,
                                progress=bar)
    finally:
        bar.close()
    print(rep["markdown"])
    return 0


def _variant(text: str):
    from clrecon.bench.table import parse_variant

    try:
        return parse_variant(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def cmd_table(args) -> int:
    from clrecon.bench.table import methods_table

    for label, method, knobs in args.variant or []:
        _check_knob_names(method, knobs, f"--variant {label}: ")
    _check_output_dir("-o", args.output)
    _stage(args, "measuring the table into", args.output)
    bar = _Bar("table", unit="step")
    try:
        rep = methods_table(args.scenes, variants=args.variant, size=args.size or (512, 512),
                            spp=args.spp, device=args.device, out_dir=args.output,
                            repeats=args.repeats, progress=bar, ref_spp=args.ref_spp,
                            inputs=_user_frames(args))
    finally:
        bar.close()
    print(rep["markdown"])
    return 0


def _user_frames(args) -> list[tuple[str, str]]:
    """``--input F --reference R`` pairs (repeatable, paired in order)."""
    ins, refs = args.input or [], args.reference or []
    if len(ins) != len(refs):
        raise ValueError(f"--input/--reference: {len(ins)} inputs but {len(refs)} references "
                         "(give one --reference per --input)")
    for f in [*ins, *refs]:
        if not os.path.isfile(f):
            raise ValueError(f"--input/--reference: {f}: no such file")
    return list(zip(ins, refs))


def _user_frame_args(sp) -> None:
    sp.add_argument("--input", action="append", default=None, metavar="F",
                    help="a frame of your own (sample file; repeatable, with --reference)")
    sp.add_argument("--reference", action="append", default=None, metavar="R",
                    help="the converged reference image of the matching --input")


def _device_list(text: str):
    """``all`` or comma-separated device indices / name substrings."""
    if text.strip().lower() == "all":
        return "all"
    specs = [int(v) if v.isdigit() else v for v in (t.strip() for t in text.split(",")) if v]
    if not specs:
        raise argparse.ArgumentTypeError(f"expected 'all' or D[,D...], got {text!r}")
    return specs


def cmd_trade(args) -> int:
    from clrecon.bench.trade import trade

    for method in args.methods or []:
        _check_knob_names(method, {}, "--methods: ")
    _check_output_dir("-o", args.output)
    _stage(args, "measuring the trade into", args.output)
    bar = _Bar("trade", unit="step")

    def status(line: str) -> None:
        bar.bar.write(f"clrecon trade: {line}", file=sys.stderr)

    try:
        rep = trade(args.scenes, args.methods, spps=args.spp, size=args.size,
                    repeats=args.repeats, oidn=not args.no_oidn, device=args.device,
                    out_dir=args.output, ref_spp=args.ref_spp, progress=bar,
                    inputs=_user_frames(args), status=status)
    finally:
        bar.close()
    print(rep["markdown"])
    print(f"written: {args.output}/trade.md, trade.json, <scene>_pareto.png, <scene>_crops.png")
    return 0


class _IntsAction(argparse.Action):
    """A list of ints given as ``4 8 16``, ``4,8,16`` or both mixed (``nargs="+"`` of
    :func:`_int_list`): one flat list."""

    def __call__(self, parser, namespace, values, option_string=None):
        setattr(namespace, self.dest, [v for group in values for v in group])


def _side_or_size(text: str) -> tuple[int, int]:
    """``N`` (N x N) or ``WxH``."""
    return _size(f"{text}x{text}" if text.strip().isdigit() else text)


def cmd_converge(args) -> int:
    from clrecon.bench.convergence import converge

    for method in args.methods or []:
        _check_knob_names(method, {}, "--methods: ")
    _check_output_dir("-o", args.output)
    _stage(args, "running the convergence study into", args.output)

    def status(line: str) -> None:
        print(f"clrecon converge: {line}", file=sys.stderr, flush=True)

    rep = converge(args.scenes, args.methods, args.settings, spps=args.spp, size=args.size,
                   seeds=args.seeds, out_dir=args.output, ref_spp=args.ref_spp,
                   ablation_spp=args.ablation_spp, device=args.device, status=status,
                   keep_images=args.keep_images)
    print(rep["markdown"])
    print(f"written: {args.output}/convergence.md, convergence.json, <scene>_convergence.png")
    return 0


def cmd_errcheck(args) -> int:
    from clrecon.bench.error_check import check, markdown

    for method in args.methods:
        _check_knob_names(method, {}, "--methods: ")
    _check_output_dir("-o", args.output)

    def status(line: str) -> None:
        print(f"clrecon errcheck: {line}", file=sys.stderr, flush=True)

    rep = check(args.scenes, args.methods, size=args.size, spp=args.spp,
                out_dir=args.output, device=args.device, status=status)
    print(markdown(rep))
    print(f"written: {args.output}/errcheck.md, errcheck.json")
    return 0


def cmd_bench(args) -> int:
    from clrecon.bench.devices import bench, compare, plot_bandwidth, variant_list, write_outputs

    for label, method, knobs in args.variant or []:
        _check_knob_names(method, knobs, f"--variant {label}: ")
    for method in args.methods or []:
        _check_knob_names(method, {}, "--methods: ")
    variants = variant_list((args.variant or []) + [(m, m, {}) for m in args.methods or []],
                            only=args.only)
    writes = {k: [str(v)] for k, v in (("--json", args.json), ("--csv", args.csv),
                                       ("--plot", args.plot)) if v}
    _check_files({"--compare baseline": [str(args.compare)]} if args.compare else {}, writes)
    for opt, (path,) in writes.items():
        _check_output(opt, path, (".png",) if opt == "--plot" else None)
    old = None
    if args.compare:  # read first: a bad baseline fails before the measurements
        _stage(args, "reading the baseline", args.compare)
        try:
            old = json.loads(Path(args.compare).read_text())
        except json.JSONDecodeError as exc:  # a ValueError that would not name the file
            raise ValueError(f"--compare {args.compare}: not JSON ({exc})") from None
    _stage(args, "measuring")
    bar = _Bar("bench", unit="step")
    try:
        res = bench(args.devices, variants=variants, size=args.size, spp=args.spp,
                    repeats=args.repeats, progress=bar, scene=args.scene,
                    peak=not args.no_peak, clpeak=args.clpeak)
    finally:
        bar.close()
    _stage(args, "writing the results")
    write_outputs(res, json_path=args.json, csv_path=args.csv)
    if args.plot:
        plot_bandwidth(res, args.plot)
    print(res["markdown"])
    if old is not None:
        print(f"Change against {args.compare}:")
        print()
        print(compare(res, old))
    return 0


def cmd_tune(args) -> int:
    from clrecon.tune.session import tune_device

    bars = {}

    def progress(name, done, total):
        if name not in bars:
            for b in bars.values():
                b.close()
            bars[name] = _Bar(f"tune {name}", unit="config")
        bars[name](done, total)

    try:
        results = tune_device(args.device, args.passes, args.size, args.spp, args.budget,
                              args.runs, args.root, progress)
    finally:
        for b in bars.values():
            b.close()
    print("| pass | bucket | default | default ms | best | best ms | speed-up | paired "
          "default/best | configs ok / pruned / failed / skipped (budget) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for res, _ in results:
        st = [m.status for m in res.measurements]
        failed = sum(s in ("build_error", "run_error", "verify_failed") for s in st)
        paired = ("skipped (budget)" if res.confirm_skipped else
                  "-" if res.confirm_ratio is None else f"{res.confirm_ratio:.2f}x")
        speed = (res.default_median_ms / res.best_median_ms
                 if res.best_median_ms and res.default_median_ms else float("nan"))
        print(f"| {res.pass_name} | {res.bucket} | {json.dumps(res.default)} | "
              f"{res.default_median_ms:.2f} | {json.dumps(res.best)} | {res.best_median_ms:.2f} | "
              f"{speed:.2f}x | {paired} | {st.count('ok')} / {st.count('pruned')} / {failed} / "
              f"{st.count('skipped_budget')} |")
    skipped = [(res.pass_name, m) for res, _ in results for m in res.skipped]
    if skipped:
        print(f"\nSkipped for the budget ({len(skipped)} configurations):")
        for name, m in skipped:
            print(f"- {name} {json.dumps(m.config)}: {m.error}")
    if results.skipped:
        print(f"\nPasses not tuned for the budget ({len(results.skipped)}):")
        for name, why in results.skipped:
            print(f"- {name}: {why}")
    print(f"\nelapsed {results.elapsed_s:.1f} s of the {results.budget_s:g} s budget")
    written = sorted({p for _, p in results})
    print(f"written: {', '.join(written) if written else 'nothing'}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="clrecon", description=__doc__.splitlines()[0])
    p.add_argument("-v", "--verbose", action="store_true", help="log what the library decides")
    p.add_argument("--debug", action="store_true",
                   help="on an error, show the traceback instead of the one-line message")
    sub = p.add_subparsers(dest="command", required=True)

    def dev(sp):
        sp.add_argument("--device", default=None,
                        help="OpenCL device index or name substring (default: "
                        "$CLRECON_DEVICE, else the first GPU, else the first device)")

    sp = sub.add_parser("devices", help="list OpenCL devices")
    sp.add_argument("--json", action="store_true")
    sp.set_defaults(fn=cmd_devices)

    sp = sub.add_parser("scene", help="render a built-in scene's sample buffer")
    sp.add_argument("name")
    sp.add_argument("--size", type=_size, default=None, help="WxH (default: the scene's, 512x512)")
    sp.add_argument("--spp", type=int, default=8)
    sp.add_argument("--seed", type=int, default=0)
    sp.add_argument("-o", "--output", required=True, help=".bin/.txt (TLFR), .exr or .npz")
    sp.add_argument("--pinhole", action="store_true",
                    help="a pinhole frame (S = 1, lens 0, time 0.5): synthesis input of splat")
    sp.add_argument("--frames", type=int, default=None, metavar="N",
                    help="an animated sequence of N frames into the folder -o "
                    "(<name>_0000.<format>, ...; objects and camera move continuously)")
    sp.add_argument("--format", choices=cli_sequences.SAMPLE_FORMATS, default="npz",
                    help="file format of --frames (default: %(default)s)")
    dev(sp)
    sp.set_defaults(fn=cmd_scene)

    sp = sub.add_parser("reference", help="render a converged reference image")
    sp.add_argument("name")
    sp.add_argument("--size", type=_size, default=None)
    sp.add_argument("--spp", type=int, default=None, help="default: the scene's (1024; bokeh 4096)")
    sp.add_argument("--seed", type=int, default=1)
    sp.add_argument("-o", "--output", required=True, help=".exr (or .png)")
    sp.add_argument("--frames", type=int, default=None, metavar="N",
                    help="the references of `scene --frames N` into the folder -o")
    dev(sp)
    sp.set_defaults(fn=cmd_reference)

    sp = sub.add_parser("reconstruct", help="reconstruct an image from a sample buffer")
    sp.add_argument("input")
    sp.add_argument("-o", "--output", required=True, help=".exr or .png")
    sp.add_argument("--method", default="box")
    sp.add_argument("--reference", help="converged reference .exr: print PSNR/SSIM/FLIP")
    sp.add_argument("--knob", action="append", metavar="NAME=VALUE",
                    help="method knob (repeatable); the flags below are shorthands")
    sp.add_argument("--scales", type=int, choices=(2, 4), help="sweep: blend 2 or 4 scales")
    sp.add_argument("--dof-layers", action="store_true",
                    help="sweep: sort-free three-layer depth-of-field variant")
    sp.add_argument("--exponent", type=float,
                    help="sweep: weight exponent (paper: 1.3; at most 126 / log2(K spp), "
                         "K = 25 for 2 scales, 49 for 4: 16.5 at 8 spp)")
    sp.add_argument("--sort", choices=("block", "tile", "pixel"),
                    help="sweep: how the window is ordered (default: block on CPUs, else tile)")
    sp.add_argument("--tile", type=int,
                    help="sweep: tile size of sort=tile; layered: screen tile (power of two)")
    sp.add_argument("--group", type=int, help="sweep: 4x4 blocks per work-group of sort=block")
    sp.add_argument("--mode", choices=("practical", "lrdm"),
                    help="layered: the 2015 method or its LRDM (2014) baseline")
    sp.add_argument("--filter", choices=("sheared", "mip", "rotated"),
                    help="layered: screen-space filter (default: sheared; lrdm: rotated)")
    sp.add_argument("--stats-stride", type=int,
                    help="layered: every n-th sample in the statistics (1: all; 3*spp)")
    sp.add_argument("--merge-threshold", type=float,
                    help="layered: merge layers while the filter changes < this (0.1; <0: off)")
    sp.add_argument("--psf", choices=("simplelens", "combined", "stylized"),
                    help="splat: PSF model (default: combined with motion, else simplelens)")
    sp.add_argument("--layers", type=int, help="splat: global depth layers (default 4, at most 64)")
    sp.add_argument("--pyramid", choices=("f5", "f7"), help="splat: integration filter set")
    sp.add_argument("--dense", action="store_true",
                    help="splat: splat the dense PSF (the paper's Splatting baseline)")
    sp.add_argument("--mip-radius", type=float, metavar="R",
                    help="splat: draw each PSF on the pyramid level where its radius is <= R "
                         "level pixels (default 8; 0: the paper's spreadlets at full "
                         "resolution)")
    sp.add_argument("--safeguard", action=argparse.BooleanOptionalAction, default=None,
                    help="blend toward box where the method's estimated bias dominates "
                         "(default: on for every method but box at >= 2 spp); "
                         "--no-safeguard: the paper's method alone")
    sp.add_argument("--error", metavar="PATH",
                    help="also write the per-pixel squared-error estimate (.exr, one channel "
                         "repeated in RGB; linear radiance, mean over RGB)")
    sp.add_argument("--json", action="store_true", help="print one JSON object")
    dev(sp)
    sp.add_argument("--allow-negative", action="store_true",
                    help="accept negative radiance (every method then stays linear in it)")
    sp.set_defaults(fn=cmd_reconstruct)

    cli_sequences.add_batch_parser(sub, dev, _device_list)
    sub.choices["batch"].set_defaults(fn=lambda a: cli_sequences.cmd_batch(
        a, _Bar, _parse_knobs, _check_knob_names))

    sp = sub.add_parser("compare", help="quality of image A against reference B; of two "
                        "sequences (folders or globs, frames paired by name) with flicker")
    sp.add_argument("a")
    sp.add_argument("b")
    sp.add_argument("--json", action="store_true")
    sp.set_defaults(fn=cmd_compare)

    sp = sub.add_parser("demo", help="render a scene, reconstruct it, print time and quality",
                        description="Render a built-in scene, reconstruct it with each method "
                        "and print time and quality against a converged reference (cached "
                        "in $CLRECON_CACHE_DIR/references or ~/.cache/clrecon/references: "
                        "a second run skips its render).")
    sp.add_argument("--scene", default="fence", help="built-in scene")
    sp.add_argument("--size", type=_size, default=None, help="WxH (default: the scene's)")
    sp.add_argument("--spp", type=int, default=8, help="samples per pixel of the input")
    sp.add_argument("--ref-spp", type=int, default=None, help="default: the scene's")
    sp.add_argument("--seed", type=int, default=0, help="of the input (reference: seed + 1)")
    sp.add_argument("--methods", default="box,oidn,sweep,layered,splat",
                    help="comma-separated methods to run (oidn: box + Open Image Denoise)")
    sp.add_argument("-o", "--output", default="out", help="folder of the images")
    dev(sp)
    sp.set_defaults(fn=cmd_demo)

    sp = sub.add_parser("tune", help="autotune every pass's launch configuration on a device")
    sp.add_argument("--passes", nargs="*", default=None, help="default: every tunable pass")
    sp.add_argument("--budget", type=float, default=600.0,
                    help="seconds for all passes, a cap: a configuration or pass predicted "
                    "not to fit is skipped and listed")
    sp.add_argument("--size", type=_size, default=(640, 360), help="tuned frame size WxH")
    sp.add_argument("--spp", type=int, default=16, help="samples per pixel of the tuned frame")
    sp.add_argument("--runs", type=int, default=7, help="timed runs per configuration, at least 7")
    sp.add_argument("--root", default=None, help="database folder (default: the package's)")
    dev(sp)
    sp.set_defaults(fn=cmd_tune)

    sp = sub.add_parser("report", help="generator throughput, reference convergence, box quality")
    sp.add_argument("--scenes", nargs="*", default=None, help="default: every built-in scene")
    sp.add_argument("--size", type=_size, default=None, help="WxH (default 512x512)")
    sp.add_argument("--spp", type=_int_list, default=[4, 8, 16], metavar="N,...",
                    help="samples per pixel of the box-quality rows")
    sp.add_argument("--ref-spp", type=int, default=None, help="default: each scene's")
    sp.add_argument("-o", "--output", default="out/report", help="output folder")
    dev(sp)
    sp.set_defaults(fn=cmd_report)

    sp = sub.add_parser("table", help="device time and quality of reconstruction variants")
    sp.add_argument("--scenes", nargs="*", default=None, help="default: every built-in scene")
    sp.add_argument("--variant", action="append", type=_variant, default=None,
                    metavar="SPEC",
                    help="a column, [LABEL=]METHOD[:K=V,...], e.g. sweep4=sweep:scales=4 "
                         "(repeatable; default: box and four sweep variants)")
    sp.add_argument("--size", type=_size, default=None, help="WxH (default 512x512)")
    sp.add_argument("--spp", type=int, default=16, help="samples per pixel")
    sp.add_argument("--ref-spp", type=int, default=None, help="default: each scene's")
    sp.add_argument("--repeats", type=int, default=5, help="timed runs after a warm-up")
    _user_frame_args(sp)
    sp.add_argument("-o", "--output", default="out/methods", help="output folder")
    dev(sp)
    sp.set_defaults(fn=cmd_table)

    sp = sub.add_parser("trade", help="speed/accuracy trade of every method's knobs, with box "
                        "and Open Image Denoise, Pareto plots and crops")
    sp.add_argument("--scenes", type=_names, default=None,
                    metavar="S,...", help="built-in scenes (default: all)")
    sp.add_argument("--methods", type=_names, default=None,
                    metavar="M,...", help="methods (default: all registered; box always runs)")
    sp.add_argument("--spp", type=_int_list, nargs="+", action=_IntsAction, default=[4, 8, 16],
                    metavar="N", help="samples per pixel of the measured buffers (N N ... or "
                    "N,N,...)")
    sp.add_argument("--size", type=_size, default=(512, 512), help="WxH")
    sp.add_argument("--repeats", type=int, default=5, help="paired rounds after a warm-up")
    sp.add_argument("--ref-spp", type=int, default=None, help="default: each scene's")
    sp.add_argument("--no-oidn", action="store_true",
                    help="leave out Open Image Denoise (default: included)")
    _user_frame_args(sp)
    sp.add_argument("-o", "--output", default="out/trade",
                    help="output folder (references cached in its references/)")
    dev(sp)
    sp.set_defaults(fn=cmd_trade)

    sp = sub.add_parser("errcheck", help="how well the per-pixel error estimate ranks the "
                        "true error: Spearman over 8x8 tiles, per scene and method")
    sp.add_argument("--scenes", type=_names,
                    default=["fence", "deep", "fast_motion"], metavar="S,...")
    sp.add_argument("--methods", type=_names,
                    default=["box", "sweep", "layered", "splat"], metavar="M,...")
    sp.add_argument("--size", type=_size, default=(512, 512), help="WxH")
    sp.add_argument("--spp", type=int, default=8)
    sp.add_argument("-o", "--output", default="out/errcheck")
    dev(sp)
    sp.set_defaults(fn=cmd_errcheck)

    sp = sub.add_parser("converge", help="convergence study: MSE split into bias² and variance "
                        "against spp for every method's settings, log-log plots, an ablation")
    sp.add_argument("--scenes", type=_names, default=None,
                    metavar="S,...", help="built-in scenes (default: every one with blur)")
    sp.add_argument("--methods", type=_names, default=None,
                    metavar="M,...", help="methods (default: all registered; box always runs)")
    sp.add_argument("--settings", type=lambda t: [m.strip() for m in t.split(",") if m.strip()],
                    default=None, metavar="LABEL,...",
                    help="only these settings (labels of the study; a method's name: its "
                    "defaults; box always runs; default: every default and trade setting)")
    sp.add_argument("--size", type=_side_or_size, default=(256, 256),
                    help="N or WxH (default: 256x256)")
    sp.add_argument("--spp", type=_int_list, nargs="+", action=_IntsAction,
                    default=[4, 8, 16, 32, 64, 128], metavar="N",
                    help="samples per pixel (N N ... or N,N,...)")
    sp.add_argument("--seeds", type=int, default=4,
                    help="independent sample seeds per cell (at least 2)")
    sp.add_argument("--ref-spp", type=int, default=None, help="default: each scene's")
    sp.add_argument("--ablation-spp", type=int, default=64,
                    help="spp of the ablation of bias sources (0: none)")
    sp.add_argument("--keep-images", action="store_true",
                    help="keep every cell's image in the cache (default: removed once its "
                    "seeds are summarised)")
    sp.add_argument("-o", "--output", default="out/converge",
                    help="output folder (references and the resume cache inside it)")
    dev(sp)
    sp.set_defaults(fn=cmd_converge)

    sp = sub.add_parser("bench", help="per-pass device times on every device, tuned vs default")
    sp.add_argument("--devices", type=_device_list, default="all", metavar="all|D,...",
                    help="comma-separated device indices or name substrings, as --device "
                    "of the other commands, which bench takes too (default: all)")
    sp.add_argument("--device", dest="devices", type=_device_list,
                    default=argparse.SUPPRESS, help=argparse.SUPPRESS)
    sp.add_argument("--variant", action="append", type=_variant, default=None,
                    metavar="SPEC",
                    help="[LABEL=]METHOD[:K=V,...], run after the default variants (box, "
                         "sweep 2-scale, sweep dof-layers) (repeatable; default: none)")
    sp.add_argument("--methods", type=_names, default=None,
                    metavar="M,...", help="methods with their default knobs, run after the "
                    "default variants and --variant (default: none)")
    sp.add_argument("--only", action="store_true",
                    help="run only the --variant and --methods given, not the default variants")
    sp.add_argument("--no-peak", action="store_true",
                    help="skip measuring each device's streaming peak (copy kernel, ~1 s a "
                    "device); fractions of peak are then n/a")
    sp.add_argument("--clpeak", action="store_true",
                    help="also run clpeak's global-memory bandwidth test on each device, when "
                    "clpeak is installed (~30 s a device)")
    sp.add_argument("--scene", default=None,
                    help="built-in scene to render as input (default: a synthetic frame)")
    sp.add_argument("--size", type=_size, default=(1280, 720), help="WxH")
    sp.add_argument("--spp", type=int, default=16, help="samples per pixel")
    sp.add_argument("--repeats", type=int, default=7, help="paired timed runs after a warm-up")
    sp.add_argument("--json", default=None, metavar="F",
                    help="write the result as JSON (default: not written)")
    sp.add_argument("--csv", default=None, metavar="F",
                    help="write the long rows as CSV (default: not written)")
    sp.add_argument("--compare", default=None, metavar="OLD.json",
                    help="print the change against an earlier --json result (default: none)")
    sp.add_argument("--plot", default=None, metavar="F.png",
                    help="plot each pass's GB/s against each device's peak (default: none)")
    sp.set_defaults(fn=cmd_bench)

    sp = sub.add_parser("psf", help="splat: pre-compute a PSF model's spreadlet table")
    sp.add_argument("action", choices=("build",))
    sp.add_argument("model", choices=("simplelens", "combined", "stylized"))
    sp.add_argument("-o", "--output", default=None,
                    help="default: the package's table (clrecon/methods/splat/data/MODEL.npz)")
    sp.add_argument("--failures", type=int, default=10_000,
                    help="dart-throwing stop (consecutive failures)")
    sp.add_argument("--lloyd", type=int, default=50, help="weighted Lloyd steps")
    sp.add_argument("--anneal", type=int, default=400, help="simulated-annealing steps")
    sp.add_argument("--spacing", type=float, default=0.5, help="dart radius scale")
    sp.set_defaults(fn=cmd_psf)
    p.formatter_class = _HelpFormatter
    for sp in sub.choices.values():
        sp.formatter_class = _HelpFormatter
    return p


def _expected_errors() -> tuple[type[BaseException], ...]:
    """The error families a user can cause (bad input, files, the device, memory): one line
    on stderr and exit code 2. Anything else (``TypeError``, ``AttributeError``...) is a bug
    and keeps its traceback. ``ValueError`` includes :class:`~clrecon.core.knobs.KnobTypeError`,
    the ``TypeError`` of a knob of the wrong type."""
    import zipfile

    import pyopencl as cl

    from clrecon.core.errors import ClreconError

    return (ValueError, ClreconError, OSError, MemoryError, OverflowError,
            zipfile.BadZipFile, cl.Error)


def _message(exc: BaseException, stage) -> str:
    """One line for ``exc``: its message (first line; OSError as ``file: reason``), the
    family where the message alone would not say it, and what the command was doing when
    the message names no file."""
    import zipfile

    import pyopencl as cl

    if isinstance(exc, OSError) and exc.filename is not None and exc.strerror:
        text = f"{exc.filename}: {exc.strerror}"
        if exc.filename2 is not None:
            text += f" (and {exc.filename2})"
    else:
        text = str(exc)
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    text = lines[0] if lines else ""
    if len(lines) > 1:
        text += f" [{len(lines) - 1} more lines: run with --debug to see them]"
    kind = None
    if isinstance(exc, cl.Error):
        kind = f"OpenCL {type(exc).__name__}"
    elif isinstance(exc, MemoryError):
        kind = "out of host memory"
    elif isinstance(exc, OverflowError):
        kind = "value out of range"
    elif isinstance(exc, zipfile.BadZipFile):
        kind = "corrupt archive"
    if kind:
        text = f"{kind}: {text}" if text else kind
    elif not text:
        text = type(exc).__name__
    if stage is not None and not isinstance(exc, ValueError):
        what, path = stage
        if path is None or path not in text:
            text += f" (while {what}{'' if path is None else ' ' + path})"
    return text


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="clrecon: %(message)s")
    args.stage = None
    from clrecon.core import device as cldev

    echo = cldev.ECHO_BUILD_OUTPUT
    # what compilers write to fd 2 (PoCL's "N warnings generated.") only with -v/--debug
    cldev.ECHO_BUILD_OUTPUT = bool(args.verbose or args.debug)
    try:
        with warnings.catch_warnings():
            if not (args.verbose or args.debug):  # "Non-empty compiler output": noise
                import pyopencl as cl

                warnings.filterwarnings("ignore", category=cl.CompilerWarning)
            return args.fn(args)
    except _expected_errors() as exc:
        if args.debug:
            raise
        print(f"clrecon {args.command}: error: {_message(exc, args.stage)}", file=sys.stderr)
        return 2
    finally:
        cldev.ECHO_BUILD_OUTPUT = echo


if __name__ == "__main__":
    sys.exit(main())
