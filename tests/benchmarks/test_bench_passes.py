"""Benchmarks of every pass and every whole method on a synthetic frame (excluded from the
default run; ``pytest -m benchmark_suite``).

Each pass is launched alone on inputs its pipeline has prepared (one full pipeline run before
timing); warm-up happens outside the timed region and ``queue.finish()`` inside it. The frame
is 512x512 at 16 spp; ``CLRECON_BENCH_SIZE=WxH`` and ``CLRECON_BENCH_SPP=S`` shrink it for a
quick sanity run (e.g. with ``--benchmark-disable``).
"""
from __future__ import annotations

import os

import pyopencl as cl
import pytest

from clrecon.api import make_pipeline
from clrecon.core.device import event_ms
from clrecon.core.pipeline import DeviceSamples
from clrecon.tune.runners import synthetic_frame

pytestmark = pytest.mark.benchmark_suite


def _frame_shape() -> tuple[int, int, int]:
    text = os.environ.get("CLRECON_BENCH_SIZE", "512x512")
    try:
        w, h = (int(v) for v in text.lower().split("x"))
        s = int(os.environ.get("CLRECON_BENCH_SPP", "16"))
    except ValueError:
        raise ValueError(f"CLRECON_BENCH_SIZE={text!r}: expected WxH") from None
    return w, h, s


W, H, S = _frame_shape()

VARIANTS = {
    "box": ("box", {}),
    "sweep 2-scale": ("sweep", {"scales": 2, "sort": "tile"}),
    "sweep 2-scale block": ("sweep", {"scales": 2, "sort": "block"}),
    "sweep dof-layers": ("sweep", {"dof_layers": True}),
}

#: per variant, each pass as ``launch(pipe, queue, samples, out) -> cl.Event`` (the same calls
#: as the plan's steps, on the temporaries the pipeline owns)
PASSES = {
    "box": {
        "box": lambda p, q, s, o: p.box(q, s["color"], o, s.width, s.height, s.spp),
    },
    "sweep 2-scale": {
        "sweep_prepare": lambda p, q, s, o: p.prepare(q, s, p.diameter_scale,
                                                      p.buffers["keys"], p.buffers["colors"]),
        "sweep_resolve": lambda p, q, s, o: p.resolve(q, p.buffers["keys"], p.buffers["colors"],
                                                      s.width, s.height, o),
    },
    "sweep 2-scale block": {
        "sweep_block": lambda p, q, s, o: p.block(q, s, p.diameter_scale, o),
    },
    "sweep dof-layers": {
        "sweep_layer_sums": lambda p, q, s, o: p.sums_pass(q, s, p.diameter_scale,
                                                           p.buffers["sums"]),
        "sweep_layer_resolve": lambda p, q, s, o: p.combine(q, p.buffers["sums"], s.width,
                                                            s.height, o),
    },
}


@pytest.fixture(scope="module")
def frame():
    return synthetic_frame(W, H, S)


def _setup(device, frame, label):
    method, knobs = VARIANTS[label]
    try:
        pipe = make_pipeline(method, device.context, frame.inspect(), **knobs)
    except ValueError as exc:  # e.g. the block sort's local memory on a small GPU
        pytest.skip(str(exc))
    samples = DeviceSamples.upload(device.queue, frame, pipe.fields)
    out = cl.Buffer(device.context, cl.mem_flags.READ_WRITE, W * H * 12)
    pipe(device.queue, samples, out).wait()  # build, first launch, fills the temporaries
    return pipe, samples, out


def _report(benchmark, device, extra: dict) -> None:
    benchmark.extra_info.update(device=device.info.label, size=f"{W}x{H}", spp=S, **extra)
    if benchmark.stats is not None:  # None under --benchmark-disable
        benchmark.extra_info["samples_per_s"] = W * H * S / benchmark.stats.stats.median


@pytest.mark.parametrize("label,pass_name", [(lab, p) for lab in VARIANTS for p in PASSES[lab]])
def test_pass(benchmark, device, frame, label, pass_name):
    pipe, samples, out = _setup(device, frame, label)
    launch = PASSES[label][pass_name]
    q = device.queue
    last = []

    def once():
        last[:] = [launch(pipe, q, samples, out)]
        q.finish()

    once()  # warm-up outside the timed region
    benchmark.pedantic(once, rounds=5, warmup_rounds=1)
    assert pipe.describe()["tuning"][pass_name]
    _report(benchmark, device, {"variant": label, "pass": pass_name,
                                "tuning": pipe.describe()["tuning"][pass_name],
                                "device_ms": event_ms(last[0])})


@pytest.mark.parametrize("label", list(VARIANTS))
def test_method(benchmark, device, frame, label):
    pipe, samples, out = _setup(device, frame, label)
    q = device.queue

    def once():
        pipe(q, samples, out)
        q.finish()

    once()  # warm-up outside the timed region
    benchmark.pedantic(once, rounds=5, warmup_rounds=1)
    assert [n for n, _ in pipe.events] == list(PASSES[label])  # the pass table is complete
    _report(benchmark, device, {"variant": label, "tuning": pipe.describe()["tuning"],
                                "pass_ms": pipe.pass_times_ms()})
