"""Benchmarks of the foundation (excluded from the default run; ``pytest -m benchmark_suite``):
scene-generator throughput and the box filter, warm-up outside the timed region."""
from __future__ import annotations

import pyopencl as cl
import pytest

from clrecon.api import make_pipeline
from clrecon.core.pipeline import DeviceSamples
from clrecon.scenes import SCENES, get_scene, render_samples

pytestmark = pytest.mark.benchmark_suite

W, H, S = 512, 512, 16


@pytest.mark.parametrize("name", sorted(SCENES))
def test_generator_throughput(benchmark, device, name):
    scene = get_scene(name)
    render_samples(scene, 16, 16, 1, device=device)  # program build
    benchmark.pedantic(render_samples, args=(scene, W, H, S), kwargs={"device": device},
                       rounds=5, warmup_rounds=1)
    _record(benchmark, device)


def _record(benchmark, device):
    benchmark.extra_info["device"] = device.info.label
    if benchmark.stats is not None:  # None under --benchmark-disable
        benchmark.extra_info["samples_per_s"] = W * H * S / benchmark.stats.stats.median


def test_box_pass(benchmark, device):
    buf = render_samples(get_scene("fence"), W, H, S, device=device)
    pipe = make_pipeline("box", device.context, buf.inspect())
    samples = DeviceSamples.upload(device.queue, buf, pipe.fields)
    out = cl.Buffer(device.context, cl.mem_flags.WRITE_ONLY, W * H * 12)

    def once():
        pipe(device.queue, samples, out)
        device.queue.finish()

    once()
    benchmark.pedantic(once, rounds=20, warmup_rounds=2)
    _record(benchmark, device)
