"""``clrecon demo``, the quick start's job: render a built-in scene, reconstruct it with each
method, print time and quality against a converged reference (cached between runs) and write
the images. Timed as every report times (:mod:`clrecon.bench.timing`)."""
from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from clrecon.cli.common import (
    check_knob_names,
    check_output_dir,
    stage,
    stage_logger,
    timed,
    with_bar,
)
from clrecon.core.fsutil import cache_dir, write_atomic

log = logging.getLogger("clrecon")

NOTES = (
    "device ms: the passes' time on the device (profiling events; on a CPU device the "
    "kernels' wall time). total ms: the wall time of a call after a warm-up call, i.e. "
    "sample upload, sample inspection, planning (0 once cached), every pass and the "
    "image's readback; program builds are in the warm-up, not in it.")
OIDN_NOTE = (
    "oidn: the box image denoised by Intel Open Image Denoise (pyoidn, CPU, quality "
    "high); its device ms are box's plus the denoiser's wall time, its total ms the wall "
    "time of box on the uploaded samples, the readback and the denoiser")


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


def _samples(args, scene, w: int, h: int, stage_log):
    """The input buffer and its render's seconds (the first render of a shape pays for the
    program build and PoCL's per-shape specialisation: it is a warm-up, logged apart)."""
    from clrecon.scenes import render_samples

    _, first_s = timed(lambda: render_samples(scene, w, h, args.spp, seed=args.seed,
                                              device=args.device))
    stage_log(f"first render (program build): {first_s:.1f} s")
    buf, seconds = timed(lambda: with_bar("samples", render_samples, scene, w, h, args.spp,
                                          seed=args.seed, device=args.device))
    stage_log(f"samples {w}x{h} at {args.spp} spp: {seconds:.2f} s")
    return buf, seconds


def _reference(args, scene, w: int, h: int, ref_spp: int, ref_dev, stage_log):
    """The converged reference, from the cache or rendered (and cached): ``(image, note)``."""
    from clrecon.scenes import render_reference

    folder = reference_cache_dir()
    cache = None if folder is None else \
        folder / _reference_cache_name(scene, w, h, ref_spp, args.seed + 1, ref_dev)
    ref = _load_cached_reference(cache, w, h)
    if ref is not None:
        stage_log(f"reference {w}x{h} at {ref_spp} spp: read from the cache {cache}")
        return ref, f"reference {ref_spp} spp from the cache ({cache})"
    stage(args, f"rendering the reference of scene {args.scene}")
    stage_log(f"reference {w}x{h} at {ref_spp} spp: rendering"
              + ("" if cache is None else " (cached for the next run)"))
    ref, seconds = timed(lambda: with_bar("reference", render_reference, scene, w, h, ref_spp,
                                          seed=args.seed + 1, device=ref_dev))
    stored = _store_cached_reference(cache, ref)
    stage_log(f"reference {w}x{h} at {ref_spp} spp: {seconds:.1f} s")
    return ref, f"reference {ref_spp} spp in {seconds:.1f} s" + (
        " (cached for the next run)" if stored else "")


def _method(buf, method: str, device):
    """One row: ``(image, device ms, total ms, device label or None)`` of the timed call
    after a warm-up call (program build and first-launch costs)."""
    if method == "oidn":  # the baseline a user would otherwise pick: box, then OIDN (CPU)
        from clrecon.bench.timing import OidnRun
        from clrecon.core.device import get_device

        runner = OidnRun(get_device(device), buf, "high")
        device_ms, seconds = timed(runner.run, warmup=True)  # the warm-up loads the network
        return runner.image(), device_ms, seconds * 1e3, None
    from clrecon.api import run

    name, knobs = _spec(method)
    res, seconds = timed(lambda: run(buf, name, device, **knobs), warmup=True)
    return res.image, res.device_ms, seconds * 1e3, res.device


#: the demo's spellings of the steps inside the safeguard, as suffixes of a method:
#: ``METHOD+guided`` (clrecon.methods.guided), ``METHOD+guided+nlm`` (clrecon.methods.nlm)
GUIDED_SUFFIX, GUIDED_RADIUS = "+guided", 2
NLM_SUFFIX, NLM_RADIUS, NLM_SCALES = "+nlm", 3, 4


def _spec(entry: str) -> tuple[str, dict]:
    """A ``--methods`` entry as (method, knobs)."""
    knobs = {}
    if entry.endswith(NLM_SUFFIX):
        entry, knobs = entry[:-len(NLM_SUFFIX)], {"nlm": NLM_RADIUS, "nlm_scales": NLM_SCALES}
    if entry.endswith(GUIDED_SUFFIX):
        entry, knobs = entry[:-len(GUIDED_SUFFIX)], {"guided": GUIDED_RADIUS, **knobs}
    return entry, knobs


def _row(args, buf, ref, method: str, out: Path):
    """Run ``method``, judge it against ``ref``, write its images: ``(device ms, total ms,
    device label or None, quality)``."""
    from clrecon.io import save_image
    from clrecon.metrics import evaluate

    image, device_ms, total_ms, label = _method(buf, method, args.device)
    q = evaluate(image, ref)
    save_image(out / f"{args.scene}_{method}.exr", image)
    save_image(out / f"{args.scene}_{method}.png", image)
    return device_ms, total_ms, label, q


def cmd_demo(args) -> int:
    from clrecon.core.device import trusted_device
    from clrecon.io import save_image
    from clrecon.scenes import get_scene

    methods = [m for m in args.methods.split(",") if m]
    for method in methods:
        if method != "oidn":
            name, knobs = _spec(method)
            check_knob_names(name, knobs, "--methods: ")
            if knobs and name == "box":
                raise ValueError(f"--methods: {method}: box has no image of its own to guide "
                                 f"the regression or to filter")
    if not methods:
        raise ValueError(f"--methods: no method in {args.methods!r}")
    check_output_dir("-o", args.output)
    scene = get_scene(args.scene)
    # the reference judges the device under test (--device), so it never comes from it
    ref_dev = trusted_device()
    out = Path(args.output)
    stage(args, "creating", out)
    out.mkdir(parents=True, exist_ok=True)
    stage(args, f"rendering scene {args.scene}")
    stage_log = stage_logger("demo")
    w, h = args.size or scene.default_size
    ref_spp = args.ref_spp or scene.reference_spp
    buf, t_render = _samples(args, scene, w, h, stage_log)
    ref, ref_note = _reference(args, scene, w, h, ref_spp, ref_dev, stage_log)
    stage(args, "writing the reference into", out)
    save_image(out / f"{args.scene}_reference.exr", ref)
    save_image(out / f"{args.scene}_reference.png", ref)
    print(f"scene {args.scene} {w}x{h}: {args.spp} spp rendered in {t_render * 1e3:.0f} ms "
          f"({w * h * args.spp / t_render / 1e6:.1f} M samples/s); {ref_note}")
    print(f"reference device: {ref_dev.info.label} (references never come from the device "
          f"under test)")
    device, col = None, max(12, *(len(m) for m in methods))
    for method in methods:
        stage(args, f"running {method} on scene {args.scene}")
        (device_ms, total_ms, label, q), seconds = timed(
            lambda m=method: _row(args, buf, ref, m, out))
        device = label or device
        stage_log(f"{method}: {seconds:.1f} s (program build, warm-up, timed run, quality, "
                  f"images)")
        print(f"{method:{col}s} device {device_ms:8.2f} ms (total {total_ms:7.1f} ms)  "
              f"PSNR {q['psnr']:.2f} dB  SSIM {q['ssim']:.4f}  FLIP {q['flip']:.4f}")
    _print_notes(methods, ref_spp, device, out)
    return 0


def _print_notes(methods, ref_spp: int, device, out: Path) -> None:
    print(NOTES)
    print(f"quality against the {ref_spp}-spp reference: PSNR (dB) and SSIM, higher is "
          "better; FLIP, lower is better. FLIP models what a viewer notices (edges, colour "
          "and contrast differences) while PSNR averages squared error, so the two can rank "
          "methods differently.")
    if "oidn" in methods:
        print(OIDN_NOTE)
    for m in methods:
        name, knobs = _spec(m) if m != "oidn" else (m, {})
        steps = ([f"the guided refinement (guided={GUIDED_RADIUS}: each half's box image "
                  f"regressed window by window on the method's image of that half; README: "
                  f"The guided refinement)"] if "guided" in knobs else []) + (
            [f"non-local means on each half (nlm={NLM_RADIUS}, nlm_scales={NLM_SCALES}: "
             f"weights from the other half, at {NLM_SCALES} scales; README: Non-local means "
             f"on the halves)"] if "nlm" in knobs else [])
        if steps:
            print(f"{m}: {name} with " + ", then ".join(steps) + ", then the safeguard")
    print(f"device: {device}")
    print(f"images in {out}/")
