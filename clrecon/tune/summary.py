"""What a tuning session found, as the text ``clrecon tune`` prints: one table row per pass
and bucket, then what the budget left out and the time it took. Pure: formats
:func:`clrecon.tune.session.tune_device`'s results, measures nothing."""
from __future__ import annotations

import json

#: measurement statuses counted as failed in the table
FAILED = ("build_error", "run_error", "verify_failed")
HEADER = ("| pass | bucket | default | default ms | best | best ms | speed-up | paired "
          "default/best | configs ok / pruned / failed / skipped (budget) |")


def _row(res) -> str:
    """A :class:`~clrecon.tune.tuner.TuneResult` as one table row."""
    st = [m.status for m in res.measurements]
    failed = sum(s in FAILED for s in st)
    paired = ("skipped (budget)" if res.confirm_skipped else
              "-" if res.confirm_ratio is None else f"{res.confirm_ratio:.2f}x")
    speed = float("nan") if res.speedup is None else res.speedup
    return (f"| {res.pass_name} | {res.bucket} | {json.dumps(res.default)} | "
            f"{res.default_median_ms:.2f} | {json.dumps(res.best)} | {res.best_median_ms:.2f} | "
            f"{speed:.2f}x | {paired} | {st.count('ok')} / {st.count('pruned')} / {failed} / "
            f"{st.count('skipped_budget')} |")


def results_markdown(results) -> str:
    """The session's summary: the table, the configurations and passes skipped for the
    budget, and the elapsed time against it.

    Parameters
    ----------
    results : clrecon.tune.session.SessionResults
        ``(TuneResult, database path)`` pairs with ``skipped`` (``(pass, why)``),
        ``elapsed_s`` and ``budget_s``.
    """
    lines = [HEADER, "|---|---|---|---|---|---|---|---|---|"]
    lines += [_row(res) for res, _ in results]
    skipped = [(res.pass_name, m) for res, _ in results for m in res.skipped]
    if skipped:
        lines.append(f"\nSkipped for the budget ({len(skipped)} configurations):")
        lines += [f"- {name} {json.dumps(m.config)}: {m.error}" for name, m in skipped]
    if results.skipped:
        lines.append(f"\nPasses not tuned for the budget ({len(results.skipped)}):")
        lines += [f"- {name}: {why}" for name, why in results.skipped]
    lines.append(f"\nelapsed {results.elapsed_s:.1f} s of the {results.budget_s:g} s budget")
    return "\n".join(lines)
