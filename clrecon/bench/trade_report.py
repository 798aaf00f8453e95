"""What ``clrecon trade`` writes (:func:`clrecon.bench.trade.trade` measures): the verdicts
against Open Image Denoise, ``trade.md``, the (time, PSNR) plot of each scene with its Pareto
fronts and the crops of the best setting of each method."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from clrecon.bench.figures import pyplot
from clrecon.bench.table import CROP, hardest_region
from clrecon.io import tonemap_srgb


def verdicts(rows: list[dict]) -> list[dict]:
    """Per scene and spp and OIDN mode: the clrecon settings faster and better than it."""
    out = []
    keys = list(dict.fromkeys((r["scene"], r["spp"]) for r in rows))
    for scene, spp in keys:
        group = [r for r in rows if (r["scene"], r["spp"]) == (scene, spp)]
        # clrecon's settings: all but OIDN and the plain box filter they are measured against
        ours = [r for r in group if r["method"] != "oidn" and r["variant"] != "box"]
        for o in (r for r in group if r["method"] == "oidn"):
            wins = [r["variant"] for r in ours if r["ms"] < o["ms"] and r["psnr"] > o["psnr"]]
            best = max(ours, key=lambda r: r["psnr"], default=None)
            out.append({"scene": scene, "spp": spp, "oidn": o["variant"], "oidn_ms": o["ms"],
                        "oidn_psnr": o["psnr"], "wins": wins,
                        "best": None if best is None else best["variant"],
                        "best_psnr": None if best is None else best["psnr"],
                        "best_ms": None if best is None else best["ms"]})
    return out


def markdown(rep: dict) -> str:
    """``trade.md``: per scene the settings' time, ratio to box, quality and mode (the Pareto
    front in bold), then the verdicts against OIDN."""
    w, h = rep["size"]
    sampler = rep.get("sampler", "lattice")
    lines = [f"Device: {rep['device']}; {w}x{h}; "
             + ("" if sampler == "lattice" else f"samples: {sampler} (independent); ")
             + f"time: median of {rep['repeats']} paired rounds "
             "(device ms from profiling events; OIDN: box pass + denoiser wall time on the "
             "host CPU); x box: median per-round ratio to the box filter; quality against the "
             "converged reference; **bold**: on the (time, PSNR) Pareto front of its scene and "
             "spp.", ""]
    for scene in dict.fromkeys(r["scene"] for r in rep["rows"]):
        lines += [f"### {scene}", "", "| spp | setting | ms | x box | PSNR dB | SSIM | FLIP | "
                  "mode |", "|---|---|---|---|---|---|---|---|"]
        for r in (r for r in rep["rows"] if r["scene"] == scene):
            label = f"**{r['variant']}**" if r["pareto"] else r["variant"]
            mode = r["describe"].get("mode", "")
            lines.append(f"| {r['spp']} | {label} | {r['ms']:.1f} | {r['x_box']:.1f} | "
                         f"{r['psnr']:.2f} | {r['ssim']:.4f} | {r['flip']:.4f} | {mode} |")
        lines.append("")
    if rep["verdicts"]:
        lines += ["### Against Open Image Denoise", "",
                  "| scene | spp | OIDN | OIDN ms / dB | clrecon settings faster and better | "
                  "best clrecon ms / dB |", "|---|---|---|---|---|---|"]
        for v in rep["verdicts"]:
            wins = ", ".join(v["wins"]) if v["wins"] else "none"
            best = "-" if v["best"] is None else \
                f"{v['best']}: {v['best_ms']:.1f} / {v['best_psnr']:.2f}"
            lines.append(f"| {v['scene']} | {v['spp']} | {v['oidn']} | "
                         f"{v['oidn_ms']:.1f} / {v['oidn_psnr']:.2f} | {wins} | {best} |")
        lines.append("")
    return "\n".join(lines)

def save_plot(path: Path, scene: str, rows: list[dict]) -> None:
    """``{scene}_pareto.png``: time (log) against PSNR, one colour per spp, its front drawn."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(8, 5.5), dpi=110)
    markers = {"box": "s", "oidn": "D", "sweep": "o", "layered": "^", "splat": "v"}
    for k, spp in enumerate(dict.fromkeys(r["spp"] for r in rows)):
        group = [r for r in rows if r["spp"] == spp]
        colour = f"C{k}"
        for r in group:
            ax.scatter(r["ms"], r["psnr"], marker=markers.get(r["method"], "x"), color=colour,
                       edgecolor="black" if r["pareto"] else "none", s=40, zorder=3)
            ax.annotate(r["variant"], (r["ms"], r["psnr"]), fontsize=6, xytext=(3, 2),
                        textcoords="offset points")
        front = sorted((r["ms"], r["psnr"]) for r in group if r["pareto"])
        if front:
            xs, ys = zip(*front)
            ax.step(xs, ys, where="post", color=colour, label=f"{spp} spp front", zorder=2)
    ax.set_xscale("log")
    ax.set_xlabel("time per frame, ms (log)")
    ax.set_ylabel("PSNR dB vs converged reference")
    ax.set_title(f"{scene}: speed vs accuracy (markers: s box, D OIDN, o sweep, ^ layered, "
                 "v splat)", fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def save_crops(path: Path, scene: str, ref: np.ndarray, group: list) -> None:
    """Reference, box, OIDN, and the best-PSNR setting of each method, one crop each."""
    plt = pyplot()
    best: dict[str, tuple[dict, np.ndarray]] = {}
    for row, img in group:
        key = row["variant"] if row["method"] in ("box", "oidn") else row["method"]
        if key not in best or row["psnr"] > best[key][0]["psnr"]:
            best[key] = (row, img)
    box_img = next(img for row, img in group if row["method"] == "box")
    y, x = hardest_region(np.abs(box_img - ref))
    hh, ww = ref.shape[:2]
    ch, cw = min(CROP, hh), min(CROP, ww)
    y0, x0 = int(np.clip(y - ch // 2, 0, hh - ch)), int(np.clip(x - cw // 2, 0, ww - cw))
    panels = [("reference", ref)] + [
        (f"{row['variant']}\n{row['psnr']:.2f} dB, {row['ms']:.0f} ms", img)
        for row, img in best.values()]
    fig, axes = plt.subplots(1, len(panels), figsize=(2.2 * len(panels), 2.6), dpi=110)
    for ax, (title, img) in zip(np.atleast_1d(axes), panels):
        ax.imshow(tonemap_srgb(img[y0:y0 + ch, x0:x0 + cw]), interpolation="nearest")
        ax.set_title(title, fontsize=7)
        ax.axis("off")
    fig.suptitle(f"{scene}, {group[0][0]['spp']} spp, crop at x={x0}, y={y0}", fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def write_outputs(out: Path, report: dict, frames: list[str]) -> None:
    """``trade.json`` (all but the markdown), ``trade.md`` and each frame's
    ``{name}_pareto.png``."""
    (out / "trade.json").write_text(json.dumps(
        {k: v for k, v in report.items() if k != "markdown"}, indent=2, default=str))
    (out / "trade.md").write_text(report["markdown"])
    for name in frames:
        save_plot(out / f"{name}_pareto.png", name,
                  [r for r in report["rows"] if r["scene"] == name])
