"""The scaling study's page (``OUT.md`` of ``tools/scaling_study.py``): the frames, device
time against resolution, blur and spp, and the passes' shares and bandwidth at one frame.
:mod:`clrecon.bench.scaling_study` measures, :mod:`clrecon.bench.scaling_plots` draws."""
from __future__ import annotations

from pathlib import Path

from clrecon.bench.scaling_study import SKIPPED


def timed_ms(r: dict | None) -> float | None:
    """A method's median frame ms on a frame, ``None`` when it was not timed."""
    return r["total_ms"]["median"] if r and r.get("status") == "ok" else None


def ms_text(ms: float) -> str:
    """Milliseconds with three or four significant digits (0.012 to 12345)."""
    return f"{ms:.0f}" if ms >= 100 else f"{ms:.1f}" if ms >= 10 else f"{ms:.3g}"


def _cell(r: dict | None) -> str:
    if r is None:
        return "-"
    if r["status"] == "ok":
        t = r["total_ms"]
        return f"{ms_text(t['median'])} ({ms_text(t['min'])}-{ms_text(t['max'])})"
    if r["status"] == SKIPPED:
        why = (f"warm-up {r['warmup_ms'] / 1e3:.1f} s" if "warmup_ms" in r
               else f"predicted {r['predicted_s']:.1f} s")
        return f"skipped ({why})"
    return r["status"].split(":", 1)[0] + " (see below)"


def _series_table(res: dict, name: str, head: str, x_of) -> list[str]:
    labels = [m["label"] for m in res["methods"]]
    lines = [f"| {head} | frame max abs CoC px | max abs motion px | "
             + " | ".join(f"{lab} ms" for lab in labels) + " |",
             "|---|---|---|" + "---|" * len(labels)]
    for p in res["series"][name]:
        fr = res["frames"][p["frame"]]
        cells = [_cell(fr["results"].get(lab)) for lab in labels]
        lines.append(f"| {x_of(p, fr)} | {fr['max_abs_coc']:.2f} | {fr['max_abs_motion']:.2f} "
                     "| " + " | ".join(cells) + " |")
    return lines


def markdown(res: dict, out: Path) -> str:
    """The page of a study's results ``res``, its pictures under ``out`` (see
    :func:`clrecon.bench.scaling_plots.plots`)."""
    sub = out.name
    lines = [*_frames_section(res), *_series_sections(res, sub), *_passes_section(res, sub)]
    failed = [(k, lab, r) for k, fr in res["frames"].items()
              for lab, r in fr["results"].items() if r["status"].startswith("failed")]
    if failed:
        lines += ["", "## Failures", ""] + [f"- {k}, {lab}: {r['status']} (at `{r['where']}`)"
                                            for k, lab, r in failed]
    lines += ["", f"Everything measured (every frame's passes): `{sub}/results.json`.", ""]
    return "\n".join(lines)


def _frames_section(res: dict) -> list[str]:
    """The page's title, command, method and the table of its frames."""
    lines = [f"# Scaling study: {res['scene']}, {res['device']}", "",
             f"Command ({res['date']}, {res['elapsed_s'] / 60:.1f} min; device "
             f"{res['device']}; host CPU (`lscpu`): {res['host_cpu']}):", "",
             "```", res["command"], "```", "",
             f"Device ms: the sum of a launch's kernel profiling events; each cell is the "
             f"median (min-max) of {res['repeats']} launch(es) after one warm-up. Each method "
             "runs with its defaults (the safeguard included: its split, half-frame runs, "
             "statistics and blend are passes of the method) unless the label gives knobs. "
             f"A method's frame predicted (from its earlier frames of the series) or warmed "
             f"up above {res['max_seconds_per_frame']:g} s is skipped.", "",
             "## Frames", "",
             f"All frames are the built-in scene `{res['scene']}` (seed {res['seed']}). The "
             "resolution and spp series render it as it is: its CoC and motion in pixels "
             "grow with the width. The blur family renders it with its lens radius and every "
             "object's velocity scaled (`clrecon/bench/scaling.py`): CoC is linear in the "
             "lens radius, screen motion in the velocity, so each scale is refined from the "
             "measured maxima of a render until the frame's max |CoC| and |motion| "
             "(`SampleBuffer.inspect()`) are within 2% of the asked values; geometry, focus "
             "and the samples' random numbers stay, so every sample's CoC (and motion) is "
             "scaled by one factor. The renderer traces each sample from its position, lens "
             "point and time, so positions, lens, time and motion stay consistent.", "",
             "| frame | measured max abs CoC px | measured max abs motion px | lens radius x "
             "| velocity x | renders | miss fraction |", "|---|---|---|---|---|---|---|"]
    for key, fr in res["frames"].items():
        lines.append(f"| {key} | {fr['max_abs_coc']:.3f} | {fr['max_abs_motion']:.3f} | "
                     f"{fr['lens_scale']:.4g} | {fr['motion_scale']:.4g} | {fr['renders']} | "
                     f"{fr['miss_fraction']:.3f} |")
    return lines


def _series_sections(res: dict, sub: str) -> list[str]:
    """Device time against resolution, blur size and spp: each series the study has."""
    lines = []
    if res["series"]["resolution"]:
        lines += ["", "## Device time against resolution", "",
                  f"![time vs pixels]({sub}/resolution.png)", "",
                  *_series_table(res, "resolution", "size",
                                 lambda p, fr: f"{fr['width']}x{fr['height']} {fr['spp']} spp")]
    if res["series"]["coc"] or res["series"]["motion"]:
        lines += ["", "## Device time against blur size", "",
                  f"![time vs blur]({sub}/blur.png)", "",
                  "Box's and the safeguard's split, which do not depend on blur, show the "
                  f"machine's noise across these frames (`{sub}/results.json` has every "
                  "pass).", ""]
        if res["series"]["coc"]:
            lines += ["Max |CoC| series (nothing moves):", "",
                      *_series_table(res, "coc", "asked max abs CoC px",
                                     lambda p, fr: f"{p['x']:g}"), ""]
        if res["series"]["motion"]:
            lines += ["Max |motion| series:", "",
                      *_series_table(res, "motion", "asked max abs motion px",
                                     lambda p, fr: f"{p['x']:g}")]
    if res["series"]["spp"]:
        lines += ["", "## Device time against spp", "", f"![time vs spp]({sub}/spp.png)", "",
                  *_series_table(res, "spp", "spp", lambda p, fr: f"{fr['spp']}")]
    return lines


def _passes_section(res: dict, sub: str) -> list[str]:
    """Each method's passes at the shares frame: time, share, bytes, GB/s, of peak."""
    peak = res["peak"]
    shares_frame = res["frames"][res["shares_frame"]]
    sw, sh, spp = shares_frame["width"], shares_frame["height"], shares_frame["spp"]
    lines = ["", f"## Passes at {sw}x{sh} {spp} spp: share of the time, achieved bandwidth",
              "", f"![pass shares]({sub}/shares.png)", "",
              f"![bandwidth]({sub}/bandwidth.png)", "",
              "Byte model (a lower bound: compulsory traffic): a pass is a leaf step of the "
              "plan (`clrecon/core/plan.py`); its bytes are the sizes of the buffers its step "
              "names "
              "as inputs (each read once) and outputs (each written once), as bound for the "
              "call: sample fields as uploaded (or split into halves; a half read in place "
              "counts the frame's fields), temporaries as planned, "
              "`out` H x W x 12. Re-reads of a neighbourhood, gathers and scattered atomics "
              "are not counted, nor a CPU's write-allocate reads, so GB/s is a floor of what "
              "the pass moved. Share: the pass's median ms over the sum of the passes' medians. "
              f"Peak: `copy_float4` (`clrecon/bench/bandwidth.py`), {peak['gb_per_s']:.2f} GB/s "
              f"(runs {min(peak['runs_gb_per_s']):.2f}-{max(peak['runs_gb_per_s']):.2f}, "
              f"{peak['buffer_bytes'] / 2**20:.0f} MiB buffers), the higher of its medians "
              "before the first frame and after the last ("
              + " and ".join(f"{g:.2f}" for g in res["peaks_gb_per_s"]) + " GB/s); a pass "
              "above 100% ran while the machine was less busy than at both, or its buffers "
              "fit in a cache.", "",
              "| method | pass | median ms | share | MB moved (floor) | GB/s | of peak |",
              "|---|---|---|---|---|---|---|"]
    shares = shares_frame["results"]
    for m in res["methods"]:
        r = shares.get(m["label"])
        if r is None or r["status"] != "ok":
            lines.append(f"| {m['label']} | {_cell(r)} | | | | | |")
            continue
        for p in r["passes"]:
            lines.append(f"| {m['label']} | {p['name']} | {ms_text(p['median_ms'])} | "
                         f"{100 * p['share']:.1f}% | {p['bytes'] / 1e6:.1f} | "
                         f"{p['gb_per_s']:.2f} | {100 * p['fraction_of_peak']:.1f}% |")
        lines.append(f"| {m['label']} | **frame** ({r['plan']} plan) | "
                     f"{ms_text(r['total_ms']['median'])} | 100% | {r['bytes'] / 1e6:.1f} | "
                     f"{r['gb_per_s']:.2f} | {100 * r['gb_per_s'] / peak['gb_per_s']:.1f}% |")
    return lines
