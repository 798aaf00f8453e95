"""What the convergence study writes: ``convergence.json`` and ``convergence.md`` (per scene
the MSE with its bias share and the median PSNR per setting and spp, an overview over the
scenes, the ablation, the bias sources without a knob) and each scene's
``<scene>_convergence.png``. :mod:`clrecon.bench.convergence` measures."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from clrecon.bench.convergence_settings import UNSWITCHED
from clrecon.bench.convergence_stats import FLAT_GAIN, by_setting, summarize
from clrecon.bench.figures import pyplot
from clrecon.core.fsutil import write_atomic


def write_report(out: Path, report: dict) -> None:
    """``convergence.json`` and ``.md`` of the scenes done so far (rewritten after each)."""
    report["markdown"] = _markdown(report)
    write_atomic(out / "convergence.json", json.dumps(
        {k: v for k, v in report.items() if k != "markdown"}, indent=1, default=str).encode(),
        0o644)
    write_atomic(out / "convergence.md", report["markdown"].encode(), 0o644)


def _sci(v) -> str:
    if v is None or not math.isfinite(v):
        return "-"
    return f"{v:.2e}".replace("e-0", "e-").replace("e+0", "e")

def _markdown(rep: dict) -> str:
    cfg = rep["config"]
    w, h = cfg["size"]
    lines = [
        f"Device: {cfg['device']}; {w}x{h}; {cfg['seeds']} sample seeds per cell "
        f"({cfg['sample_seed']}"
        + ("" if cfg.get("sampler", "lattice") == "lattice" else
           f"; samples: {cfg['sampler']}, independent")
        + "); references on the trusted device (seeds 1 and 2).", "",
        "MSE: linear radiance, mean over pixels and RGB, against the seed-1 reference, mean "
        "over seeds; in brackets the bias share, bias² / MSE, with bias² = mean((mean image "
        "- ref)²) - variance / seeds and variance the per-pixel spread across seeds (MSE = "
        "bias² + variance). bias² includes the reference's own noise (the floor no setting "
        "gets below; box measures it). PSNR: clrecon.metrics.psnr (tone mapped, clipped), "
        "median over seeds. Per doubling: MSE ratio per doubling of spp over the last two "
        f"spp (0.50: like 1/spp; 1.00: not improving); flat from: the spp from which every "
        f"doubling gains less than {100 * FLAT_GAIN:.0f}% MSE.", ""]
    lines += _overview(rep)
    for scene in dict.fromkeys(r["scene"] for r in rep["rows"]):
        lines += _scene_section(rep, scene)
    lines += _ablation_section(rep)
    lines += ["### Bias sources without a knob", ""]
    for method, items in UNSWITCHED.items():
        lines += [f"- {method}: " + "; ".join(items)]
    lines.append("")
    return "\n".join(lines)


def _scene_section(rep: dict, scene: str) -> list[str]:
    """One scene: its reference, then per setting MSE (bias share) and median PSNR per spp."""
    rows = [r for r in rep["rows"] if r["scene"] == scene]
    lines: list[str] = []
    spps = sorted({r["spp"] for r in rows})
    ref = rep["references"][scene]
    table = by_setting(rows)
    box = table.get("box", {}).get(spps[-1], {})
    box_line = "" if "bias2" not in box else (
        f" Box's bias² at {spps[-1]} spp: {_sci(box['bias2'])} ± {_sci(box['bias2_se'])} "
        "(box is unbiased, so this is the reference's noise seen from the other side).")
    lines += [f"### {scene}", "",
              f"Reference {ref['ref_spp']} spp; its noise variance (half the mean squared "
              f"difference of seeds 1 and 2): {_sci(ref['noise_var'])}.{box_line}", "",
              "| setting | " + " | ".join(f"{s} spp" for s in spps)
              + " | per doubling | flat from | box better from |",
              "|---|" + "---|" * (len(spps) + 3)]
    summ = {s["setting"]: s for s in summarize(rows)}
    for label, cells in table.items():
        vals = []
        for spp in spps:
            r = cells.get(spp, {})
            vals.append("error" if "error" in r else
                        f"{_sci(r['mse'])} ({100 * r['bias_share']:.0f}%)" if r else "-")
        sm = summ[label]
        per = "-" if sm["per_doubling"] is None else f"{sm['per_doubling']:.2f}"
        better = "-" if label == "box" else (
            f"{sm['box_better_from']} spp" if sm["box_better_from"] else "never")
        flat = f"{sm['flat_from']} spp" if sm["flat_from"] else "-"
        lines.append(f"| {label} | " + " | ".join(vals) + f" | {per} | {flat} | {better} |")
    lines += ["", "Median PSNR dB:", "",
              "| setting | " + " | ".join(f"{s} spp" for s in spps) + " |",
              "|---|" + "---|" * len(spps)]
    for label, cells in table.items():
        lines.append(f"| {label} | " + " | ".join(
            f"{cells[s]['psnr_median']:.2f}" if "psnr_median" in cells.get(s, {}) else "-"
            for s in spps) + " |")
    errs = [(label, s, c["error"]) for label, cs in table.items() for s, c in cs.items()
            if "error" in c]
    lines += [""] + [f"- {label} at {s} spp: {e}" for label, s, e in errs]
    lines += [""] * bool(errs) + [f"![{scene}]({scene}_convergence.png)", ""]
    return lines


def _ablation_section(rep: dict) -> list[str]:
    """Per method: the base's bias² and each ablation knob's, per scene."""
    lines: list[str] = []
    cfg = rep["config"]
    if rep["ablation"]:
        scenes = list(dict.fromkeys(a["scene"] for a in rep["ablation"]))
        lines += [f"### Ablation at {cfg['ablation_spp']} spp", "",
                  "bias² of each method alone (the base row) and, per knob that switches a "
                  "bias source, its bias² with the change against the base in brackets "
                  "(variance change after the slash); `*`: the change exceeds twice the "
                  "combined standard error of the two bias² estimates (pixels taken as "
                  "independent).", ""]
        for method in dict.fromkeys(a["method"] for a in rep["ablation"]):
            rows = [a for a in rep["ablation"] if a["method"] == method]
            lines += [f"#### {method}", "", "| setting | bias source | "
                      + " | ".join(scenes) + " |", "|---|---|" + "---|" * len(scenes)]
            base = {a["scene"]: a for a in rows}
            lines.append(f"| {rows[0]['base']} | (base) | " + " | ".join(
                _sci(base[s]["base_bias2"]) if s in base else "-" for s in scenes) + " |")
            for label in dict.fromkeys(a["setting"] for a in rows):
                cells = {a["scene"]: a for a in rows if a["setting"] == label}
                src = next(iter(cells.values()))["source"]
                lines.append(f"| {label} | {src} | " + " | ".join(
                    _ablation_cell(cells.get(s)) for s in scenes) + " |")
            lines.append("")
    return lines


def _overview(rep: dict) -> list[str]:
    """One table over the scenes: per setting, where it is flat and its bias share there."""
    scenes = list(dict.fromkeys(r["scene"] for r in rep["rows"]))
    if not scenes:
        return []
    per = {s: {x["setting"]: x for x in summarize([r for r in rep["rows"]
                                                    if r["scene"] == s])} for s in scenes}
    top = max(r["spp"] for r in rep["rows"])
    lines = ["### Overview", "", f"Per scene: the spp from which the MSE is flat, the bias "
             f"share at {top} spp, and MSE at {top} spp relative to box's.", "",
             "| setting | " + " | ".join(scenes) + " |", "|---|" + "---|" * len(scenes)]
    for label in dict.fromkeys(r["setting"] for r in rep["rows"]):
        cells = []
        for s in scenes:
            sm = per[s].get(label)
            mine = next((r for r in rep["rows"] if r["scene"] == s and r["setting"] == label
                         and r["spp"] == top), {})
            box = next((r for r in rep["rows"] if r["scene"] == s and r["setting"] == "box"
                        and r["spp"] == top), {})
            if sm is None or "mse" not in mine:
                cells.append("-")
                continue
            flat = f"{sm['flat_from']}" if sm["flat_from"] else "-"
            rel = f", x{mine['mse'] / box['mse']:.2f}" if box.get("mse") else ""
            cells.append(f"{flat} / {100 * mine['bias_share']:.0f}%{rel}")
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return lines + [""]


def _ablation_cell(a: dict | None) -> str:
    if a is None:
        return "-"
    if a.get("error") or a.get("bias2") is None:
        return "error"
    b, b0, v, v0 = a["bias2"], a["base_bias2"], a["variance"], a["base_variance"]
    if b0 is None:
        return f"{_sci(b)} (base: error)"
    db = "" if b0 == 0 else f" ({100 * (b - b0) / abs(b0):+.0f}%"
    dv = "" if not db or not v0 else f" / {100 * (v - v0) / v0:+.0f}%"
    sig = "*" if abs(b - b0) > 2 * math.hypot(a["bias2_se"], a["base_bias2_se"]) else ""
    return f"{_sci(b)}{sig}{db}{dv}{')' if db else ''}"


def save_plot(path: Path, scene: str, rows: list[dict], noise_var: float) -> None:
    """``<scene>_convergence.png``: MSE against spp (log-log) and, beside it, bias² and
    variance, with the reference's noise as a floor."""
    plt = pyplot()
    table = by_setting(rows)
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(12, 5.2), dpi=100, sharey=True)
    cmap = plt.get_cmap("tab10" if len(table) <= 10 else "tab20")
    k = 0
    for label, cells in table.items():
        spps = sorted(s for s, r in cells.items() if "mse" in r)
        if not spps:
            continue
        xs = np.array(spps, float)
        got = {key: np.array([cells[s][key] for s in spps], float)
               for key in ("mse", "bias2", "variance")}
        if label == "box":
            colour, style, lw = "black", "--", 2.0
        else:
            colour, style, lw = cmap(k % cmap.N), "-", 1.6
            k += 1
        ax.plot(xs, got["mse"], style, color=colour, lw=lw, marker="o", ms=3, label=label)
        bias = got["bias2"]
        ax2.plot(xs, np.where(bias > 0, bias, np.nan), style, color=colour, lw=0.9)
        ax2.plot(xs, got["variance"], ":", color=colour, lw=0.9)
    for a in (ax, ax2):
        if noise_var > 0:
            a.axhline(noise_var, color="grey", lw=0.8, ls="-.")
        a.set_xscale("log", base=2)
        a.set_yscale("log")
        a.set_xlabel("samples per pixel")
        a.grid(True, which="both", alpha=0.3)
        xs = sorted({r["spp"] for r in rows})
        a.set_xticks(xs, [str(x) for x in xs])
    ax.set_ylabel("MSE (linear radiance, mean over RGB)")
    ax.set_title(f"{scene}: MSE against the reference (box dashed; dash-dot: the "
                 "reference's noise)", fontsize=9)
    ax2.set_title("bias² (solid; box dashed) and variance (dotted), same colours", fontsize=9)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
