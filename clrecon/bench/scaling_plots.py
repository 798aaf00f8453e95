"""The scaling study's pictures (``OUT/*.png`` of ``tools/scaling_study.py``): device time
against resolution, blur and spp, one line per method, and the passes' shares and achieved
bandwidth at the shares frame."""
from __future__ import annotations

import math
from pathlib import Path

from clrecon.bench.figures import pyplot, save_png
from clrecon.bench.scaling_report import ms_text, timed_ms


def _series_lines(ax, res: dict, name: str, x_of, logx: bool = True) -> bool:
    """One line per method: median device ms against the series' x; skipped points named.
    Returns whether any point was drawn."""
    drawn = False
    for k, m in enumerate(res["methods"]):
        pts, missing = [], []
        for p in res["series"][name]:
            fr = res["frames"][p["frame"]]
            ms = timed_ms(fr["results"].get(m["label"]))
            if ms is None:
                missing.append(p["frame"])
            else:
                pts.append((x_of(p, fr), ms))
        label = m["label"] + (f" ({len(missing)} not timed)" if missing else "")
        xs, ys = zip(*pts) if pts else ((), ())
        ax.plot(xs, ys, marker="os^vDP"[k % 6], color=f"C{k}", label=label)
        drawn = drawn or bool(pts)
    if drawn:
        ax.set_yscale("log")
        if logx:
            from matplotlib.ticker import ScalarFormatter

            ax.set_xscale("log", base=2)
            ax.xaxis.set_major_formatter(ScalarFormatter())
    else:  # every frame skipped or failed: no axis to scale logarithmically
        ax.text(0.5, 0.5, "nothing timed", ha="center", transform=ax.transAxes)
    ax.set_ylabel("device ms (median)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    return drawn


def plots(res: dict, out: Path) -> list[Path]:
    """Draw every series the study has, and the pass charts, into ``out``; the files."""
    plt = pyplot()
    written = []
    title = f"{res['scene']}, {res['device']}"
    if res["series"]["resolution"]:
        fig, ax = plt.subplots(figsize=(7, 5), dpi=110)
        if _series_lines(ax, res, "resolution", lambda p, fr: fr["width"] * fr["height"],
                         logx=False):
            ax.set_xscale("log")
        pts = res["series"]["resolution"]
        ax.set_xticks([p["x"] for p in pts])
        ax.set_xticklabels([p["frame"].split()[0] for p in pts], fontsize=7)
        ax.minorticks_off()
        ax.set_xlabel(f"pixels ({res['frames'][pts[0]['frame']]['spp']} spp)")
        ax.set_title(f"Device time vs resolution: {title}", fontsize=9)
        fig.tight_layout()
        save_png(fig, out / "resolution.png")
        written.append(out / "resolution.png")
    if res["series"]["coc"] or res["series"]["motion"]:
        fig, axes = plt.subplots(1, 2, figsize=(11, 4.8), dpi=110)
        if res["series"]["coc"]:
            _series_lines(axes[0], res, "coc", lambda p, fr: fr["max_abs_coc"])
        axes[0].set_xlabel("frame max |CoC| px (measured; nothing moves)")
        if res["series"]["motion"]:
            _series_lines(axes[1], res, "motion", lambda p, fr: fr["max_abs_motion"],
                          logx=False)
            coc = res["frames"][res["series"]["motion"][0]["frame"]]["target_coc"]
            axes[1].set_xlabel(f"frame max |motion| px (measured; max |CoC| {coc:g} px)")
        fig.suptitle(f"Device time vs blur: {title}", fontsize=9)
        fig.tight_layout()
        save_png(fig, out / "blur.png")
        written.append(out / "blur.png")
    if res["series"]["spp"]:
        fig, ax = plt.subplots(figsize=(7, 5), dpi=110)
        _series_lines(ax, res, "spp", lambda p, fr: fr["spp"])
        pts = res["series"]["spp"]
        ax.set_xticks([p["x"] for p in pts])
        ax.set_xticklabels([f"{p['x']:g}" for p in pts])
        ax.set_xlabel("samples per pixel")
        ax.set_title(f"Device time vs spp: {title}", fontsize=9)
        fig.tight_layout()
        save_png(fig, out / "spp.png")
        written.append(out / "spp.png")
    written += _pass_plots(res, out, plt)
    return written


def _base(name: str) -> str:
    return name.replace(" (halves)", "")


def _pass_plots(res: dict, out: Path, plt) -> list[Path]:
    """The pass-share stacked bars and the per-pass bandwidth at the shares frame."""
    fr = res["frames"][res["shares_frame"]]
    where = f"{fr['width']}x{fr['height']} {fr['spp']} spp"
    ok = [(m["label"], fr["results"][m["label"]]) for m in res["methods"]
          if fr["results"].get(m["label"], {}).get("status") == "ok"]
    names = list(dict.fromkeys(_base(p["name"]) for _, r in ok for p in r["passes"]))
    cmap = plt.get_cmap("tab20")
    colour = {n: cmap(i % 20) for i, n in enumerate(names)}
    fig, ax = plt.subplots(figsize=(max(6.0, 1.6 * len(res["methods"]) + 4), 5.5), dpi=110)
    shown = set()
    for i, m in enumerate(res["methods"]):
        r = fr["results"].get(m["label"])
        if r is None or r["status"] != "ok":
            ax.text(i, 0.5, "not timed", ha="center", rotation=90, fontsize=8)
            continue
        bottom = 0.0
        for p in r["passes"]:
            b = _base(p["name"])
            ax.bar(i, p["share"], bottom=bottom, color=colour[b], edgecolor="white",
                   hatch="//" if b != p["name"] else None,
                   label=b if b not in shown else None)
            shown.add(b)
            if p["share"] > 0.06:
                ax.text(i, bottom + p["share"] / 2, f"{100 * p['share']:.0f}%", ha="center",
                        va="center", fontsize=7)
            bottom += p["share"]
        ax.text(i, 1.01, f"{ms_text(r['total_ms']['median'])} ms", ha="center", va="bottom",
                fontsize=7)
    ax.set_xticks(range(len(res["methods"])))
    ax.set_xticklabels([m["label"] for m in res["methods"]], fontsize=8)
    ax.set_ylim(0, 1.08)
    ax.set_ylabel("share of the frame's device time")
    ax.set_title(f"Pass shares at {where} ({res['scene']}); hatched: the safeguard's "
                 "half-frame runs", fontsize=9)
    if shown:
        ax.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.0, 0.5))
    fig.tight_layout()
    save_png(fig, out / "shares.png")

    peak = res["peak"]["gb_per_s"]
    xs = [(lab, p) for lab, r in ok for p in r["passes"]]
    fig, ax = plt.subplots(figsize=(max(7.0, 0.28 * len(xs) + 2), 6), dpi=110)
    for i, (_lab, p) in enumerate(xs):
        if p["gb_per_s"] > 0 and math.isfinite(p["gb_per_s"]):
            ax.scatter(i, p["gb_per_s"], color=colour[_base(p["name"])], zorder=3, s=24)
    ax.axhline(peak, color="k", lw=1.2, label=f"copy_float4 peak {peak:.1f} GB/s")
    ax.set_yscale("log")
    ax.set_xticks(range(len(xs)))
    ax.set_xticklabels([f"{lab}: {p['name'].replace(' (halves)', ' (h)')}" for lab, p in xs],
                       rotation=70, ha="right", fontsize=6)
    ax.set_ylabel("achieved GB/s (floor: compulsory bytes / device time)")
    ax.set_title(f"Achieved bandwidth per pass at {where} ({res['scene']}); (h): half-frame "
                 "runs", fontsize=9)
    ax.grid(True, which="both", axis="y", alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    save_png(fig, out / "bandwidth.png")
    return [out / "shares.png", out / "bandwidth.png"]
