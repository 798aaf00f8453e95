"""``clrecon tune``'s summary (:func:`clrecon.tune.summary.results_markdown`): pure text from
a session's results, pinned line by line."""
from __future__ import annotations

import math

from clrecon.tune.session import SessionResults
from clrecon.tune.summary import results_markdown
from clrecon.tune.tuner import Measurement, TuneResult


def _result(name, statuses, best_ms=1.0, default_ms=2.0, **kw) -> TuneResult:
    ms = [Measurement({"local": [8 * i, 4]}, st, error="predicted 9 s" if st ==
                      "skipped_budget" else None) for i, st in enumerate(statuses, 1)]
    return TuneResult(name, "640x360", {"local": [16, 4]}, {"local": [8, 4]}, best_ms,
                      default_ms, ms, 1.0, **kw)


def test_table_rows_and_counts():
    results = SessionResults(60)
    results.append((_result("box", ["ok", "ok", "pruned", "build_error", "verify_failed"],
                            confirm_ratio=1.96), "tuning/a.json"))
    results.append((_result("sweep_resolve", ["ok"], confirm_skipped=True), "tuning/a.json"))
    results.elapsed_s = 12.34
    lines = results_markdown(results).splitlines()
    assert lines[0].startswith("| pass | bucket | default | default ms | best | best ms |")
    assert lines[1] == "|---|---|---|---|---|---|---|---|---|"
    assert lines[2] == ('| box | 640x360 | {"local": [16, 4]} | 2.00 | {"local": [8, 4]} | 1.00 | '
                        '2.00x | 1.96x | 2 / 1 / 2 / 0 |')
    assert lines[3].endswith("| 2.00x | skipped (budget) | 1 / 0 / 0 / 0 |")
    assert lines[4:] == ["", "elapsed 12.3 s of the 60 s budget"]


def test_skipped_configurations_and_passes():
    results = SessionResults(5)
    results.append((_result("box", ["ok", "skipped_budget"]), "t.json"))
    results.skipped.append(("splat", "the 5 s budget was spent before it"))
    text = results_markdown(results)
    assert '| - | 1 / 0 / 0 / 1 |' in text  # no confirmation run: "-"
    assert ('\n\nSkipped for the budget (1 configurations):\n- box {"local": [16, 4]}: '
            'predicted 9 s\n') in text
    assert ("\n\nPasses not tuned for the budget (1):\n- splat: the 5 s budget was spent "
            "before it\n") in text
    assert text.endswith("\n\nelapsed 0.0 s of the 5 s budget")


def test_no_best_time_is_nan():
    results = SessionResults(1)
    results.append((_result("box", ["build_error"], best_ms=0.0), "t.json"))
    row = results_markdown(results).splitlines()[2]
    assert f"| {math.nan:.2f}x |" in row and "| 0 / 0 / 1 / 0 |" in row
