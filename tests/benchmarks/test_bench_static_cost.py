""""Model only what a scene requires": a static in-focus frame (``static_focus``, 1280x720,
8 spp) through every method's trade settings, timed beside ``box`` in paired rounds. The
target is <= 1.5x box; ``extra_info['x_box']`` is the median per-round ratio (excluded from the
default run; ``pytest -m benchmark_suite --benchmark-enable tests/benchmarks``)."""
from __future__ import annotations

import statistics

import pytest

from clrecon.bench.timing import PipelineRun
from clrecon.bench.trade import trade_variants
from clrecon.scenes import get_scene, render_samples

pytestmark = pytest.mark.benchmark_suite

W, H, S = 1280, 720, 8
VARIANTS = [v for v in trade_variants() if v[1] != "box"]


@pytest.fixture(scope="module")
def frame(device):
    return render_samples(get_scene("static_focus"), W, H, S, device=device)


@pytest.mark.parametrize("variant", VARIANTS, ids=[v[0] for v in VARIANTS])
def test_static_frame_cost(benchmark, device, frame, variant):
    label, method, knobs = variant
    ours, box = PipelineRun(device, frame, method, knobs), PipelineRun(device, frame, "box", {})
    ours.run(), box.run()  # warm-up
    ratios = [ours.run() / max(box.run(), 1e-6) for _ in range(7)]
    benchmark.pedantic(ours.run, rounds=7, warmup_rounds=1)
    benchmark.extra_info.update(device=device.info.label, x_box=statistics.median(ratios),
                                mode=ours.describe().get("mode", ""))
