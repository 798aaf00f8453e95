"""The picture of a ``clrecon bench`` result: each pass's achieved bandwidth against each
device's streaming peak (:func:`plot_bandwidth`)."""
from __future__ import annotations

import math
from pathlib import Path

from clrecon.bench.devices_report import PathLike, _index, _pass_order
from clrecon.bench.figures import pyplot, save_png


def plot_bandwidth(result: dict, path: PathLike) -> Path:
    """Plot each pass's achieved GB/s (tuned) against each device's peak, as a PNG.

    x: the plan steps of every variant in launch order (a multi-kernel step as one), and the
    frame; y: GB/s on a log scale; one colour per device, its ``copy_float4`` peak a solid
    line and clpeak's (when measured) a dashed one. A roofline without the compute roof: the
    passes' arithmetic intensities are not counted, so distance below the line is all the
    plot says.

    Parameters
    ----------
    result : dict
        What :func:`~clrecon.bench.devices.bench` returned.
    path : str or Path
        The PNG to write (parent folders are created).

    Returns
    -------
    pathlib.Path
    """
    plt = pyplot()
    vals = _index(result["rows"])
    devs = result["devices"]
    xs: list[tuple[str, str]] = []  # (variant, pass)
    for run in result["runs"]:
        for name in _pass_order(result, run):
            key = (run["method"], name)
            if key not in xs and (run["device"], *key, "tuned", "gb_per_s") in vals:
                xs.append(key)
    fig, ax = plt.subplots(figsize=(max(8.0, 0.26 * len(xs) + 1.5), 6.5), dpi=110)
    width = 0.8 / max(len(devs), 1)
    shown: list[float] = []  # every value drawn, to leave the legend a decade below them
    platforms = [d.split(" / ")[0] for d in devs]
    short = platforms if len(set(platforms)) == len(devs) else devs
    for k, (d, name) in enumerate(zip(devs, short)):
        colour = f"C{k}"
        pk = result.get("peaks", {}).get(d, {})
        pts = [(i, vals.get((d, m, n, "tuned", "gb_per_s"))) for i, (m, n) in enumerate(xs)]
        pts = [(i, v) for i, v in pts if v is not None and math.isfinite(v) and v > 0]
        if pts:
            ix, ys = zip(*pts)
            shown += ys
            ax.scatter([i + (k - (len(devs) - 1) / 2) * width for i in ix], ys, color=colour,
                       marker="os^vD"[k % 5], s=26, zorder=3, label=name)
        copy = (pk.get("copy") or {}).get("gb_per_s")
        if copy:
            shown.append(copy)
            ax.axhline(copy, color=colour, lw=1.2, label=f"{name}: copy peak {copy:.1f} GB/s")
        clp = (pk.get("clpeak") or {}).get("best_gb_per_s")
        if clp:
            shown.append(clp)
            ax.axhline(clp, color=colour, lw=1.0, ls="--",
                       label=f"{name}: clpeak {clp:.1f} GB/s")
    ax.set_yscale("log")
    if shown:
        ax.set_ylim(min(shown) / 15, max(shown) * 1.6)
    ax.set_xlim(-0.6, len(xs) - 0.4)
    first = 0
    for i, (m, _) in enumerate(xs):  # a band per variant, its name on top
        if i + 1 == len(xs) or xs[i + 1][0] != m:
            if i + 1 < len(xs):
                ax.axvline(i + 0.5, color="grey", lw=0.6, alpha=0.6)
            ax.text((first + i) / 2, 1.01, m, transform=ax.get_xaxis_transform(),
                    ha="center", va="bottom", fontsize=7)
            first = i + 1
    ax.set_xticks(range(len(xs)))
    ax.set_xticklabels([n.replace(" (halves)", " (h)") for _, n in xs], rotation=60,
                       ha="right", fontsize=7)
    ax.set_ylabel("achieved GB/s (log): bytes of the pass's buffers / device time", fontsize=8)
    w, h = result["size"]
    src = "synthetic frame" if result.get("scene") is None else result["scene"]
    fig.suptitle(f"{src} {w}x{h} {result['spp']} spp: achieved bandwidth per pass (tuned) vs "
                 "each device's streaming peak; (h): the safeguard's half-frame runs",
                 fontsize=9)
    ax.grid(True, which="both", axis="y", alpha=0.3)
    ax.legend(fontsize=7, loc="lower left", ncol=2, framealpha=0.85)
    fig.tight_layout()
    return save_png(fig, Path(path))
