"""The foundation report: scene-generator throughput, reference convergence and the box
filter's quality on every built-in scene (``clrecon report``).

Throughput is the median wall time of ``render_samples`` over ``repeats`` runs after one
warm-up (kernel plus read-back into host arrays). Convergence is the PSNR between two
references rendered with different seeds. Box quality is measured against the first of them.
"""
from __future__ import annotations

import json
import time
from pathlib import Path

from clrecon.api import run
from clrecon.bench.timing import median_wall_s
from clrecon.core.device import get_device
from clrecon.io import save_image
from clrecon.metrics import evaluate, psnr
from clrecon.scenes import SCENES, get_scene, render_reference, render_samples


def foundation_report(scenes=None, size=(512, 512), spps=(4, 8, 16), ref_spp=None,
                      device=None, out_dir="out/report", repeats=3, progress=None) -> dict:
    """Measure and write ``report.md``, ``report.json`` and per-scene PNGs into ``out_dir``."""
    scenes = list(scenes or SCENES)
    w, h = size
    dev = get_device(device)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    steps, done = len(scenes) * (3 + len(spps)), 0

    def step():
        nonlocal done
        done += 1
        if progress:
            progress(done, steps)

    for name in scenes:
        scene = get_scene(name)
        t = median_wall_s(lambda sc=scene: render_samples(sc, w, h, 16, seed=0, device=dev),
                         repeats)
        step()
        t0 = time.perf_counter()
        rspp = ref_spp or scene.reference_spp
        ref_a = render_reference(scene, w, h, rspp, seed=1)  # trusted device
        t_ref = time.perf_counter() - t0
        step()
        ref_b = render_reference(scene, w, h, rspp, seed=2)
        step()
        save_image(out / f"{name}_reference.png", ref_a)
        row = {"scene": name, "reference_spp": rspp, "msamples_per_s": w * h * 16 / t / 1e6,
               "reference_s": t_ref, "reference_psnr_between_seeds": psnr(ref_b, ref_a), "box": {}}
        for spp in spps:
            buf = render_samples(scene, w, h, spp, seed=100 + spp, device=dev)
            res = run(buf, "box", dev)
            row["box"][spp] = evaluate(res.image, ref_a) | {"device_ms": res.device_ms}
            save_image(out / f"{name}_box{spp}.png", res.image)
            step()
        rows.append(row)
    report = {"device": dev.info.label, "size": [w, h],
              "spps": list(spps), "rows": rows}
    report["markdown"] = _markdown(report)
    (out / "report.json").write_text(json.dumps({k: v for k, v in report.items()
                                                 if k != "markdown"}, indent=2))
    (out / "report.md").write_text(report["markdown"])
    return report


def _markdown(rep: dict) -> str:
    w, h = rep["size"]
    spps = rep["spps"]
    lines = [f"Device: {rep['device']}; {w}x{h}.", "",
             "| scene | generator M samples/s (16 spp) | reference spp | reference s | "
             "ref A vs B PSNR dB | "
             + " | ".join(f"box {s} spp PSNR / SSIM / FLIP" for s in spps) + " |",
             "|---|---|---|---|---|" + "---|" * len(spps)]
    for r in rep["rows"]:
        cells = [f"{r['box'][s]['psnr']:.2f} / {r['box'][s]['ssim']:.4f} / "
                 f"{r['box'][s]['flip']:.4f}" for s in spps]
        lines.append(f"| {r['scene']} | {r['msamples_per_s']:.1f} | {r['reference_spp']} | "
                     f"{r['reference_s']:.1f} | "
                     f"{r['reference_psnr_between_seeds']:.2f} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"
