"""Benchmarks of method ``layered`` (excluded from the default run)."""
from __future__ import annotations

import pyopencl as cl
import pytest

from clrecon.api import make_pipeline
from clrecon.core.pipeline import DeviceSamples
from clrecon.scenes import get_scene, render_samples

pytestmark = pytest.mark.benchmark_suite


@pytest.mark.parametrize("knobs", [{}, {"filter": "mip"}, {"mode": "lrdm"}],
                         ids=["practical-sheared", "practical-mip", "lrdm"])
def test_layered_frame(benchmark, device, knobs):
    w, h, spp = 640, 360, 8
    buf = render_samples(get_scene("deep"), w, h, spp, seed=108, device=device)
    pipe = make_pipeline("layered", device.context, buf.inspect(), **knobs)
    s = DeviceSamples.upload(device.queue, buf, pipe.fields)
    out = cl.Buffer(device.context, cl.mem_flags.READ_WRITE, w * h * 12)
    pipe(device.queue, s, out).wait()  # warm-up outside the timed region

    def frame():
        pipe(device.queue, s, out)
        device.queue.finish()

    benchmark(frame)
    benchmark.extra_info.update(device=device.info.label, size=[w, h], spp=spp,
                                pass_ms=pipe.pass_times_ms())
    if benchmark.stats is not None:  # None under --benchmark-disable
        benchmark.extra_info["samples_per_s"] = w * h * spp / benchmark.stats["median"]
