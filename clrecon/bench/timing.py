"""How every report times things: one module, so that ``clrecon trade``, ``table``, ``report``,
``bench``, ``demo`` and the measurement scripts under ``tools/`` measure the same way.

- **Device time** of a pipeline is the sum of its passes' profiled kernel times
  (:meth:`clrecon.core.pipeline.Pipeline.pass_times_ms`) for one call on a warm pipeline:
  the program builds, the upload and the read-back are not in it.
- **Wall time** is ``time.perf_counter()`` around a call, after one warm-up call.
- Reports give medians. Side-by-side comparisons run their variants in *paired rounds*
  (each round runs every variant once), so that a noisy machine slows all of them alike.
"""
from __future__ import annotations

import statistics
import time
from collections.abc import Callable

import numpy as np
import pyopencl as cl

from clrecon.core.device import Device
from clrecon.core.pipeline import DeviceSamples, make_pipeline


def median_wall_s(fn: Callable[[], object], repeats: int, warmup: bool = True) -> float:
    """Median wall time of ``fn()`` in seconds over ``repeats`` calls, after one warm-up."""
    if repeats < 1:
        raise ValueError(f"repeats: need at least 1, got {repeats}")
    if warmup:
        fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def duration_text(seconds: float) -> str:
    """A duration as a person reads it: ``4.2 s``, ``37 s``, ``12 min``, ``1.6 h``."""
    seconds = max(0.0, float(seconds))
    if seconds < 10:
        return f"{seconds:.1f} s"
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


class PipelineRun:
    """One method's pipeline on one frame, built and uploaded once.

    ``run()`` enqueues one call, waits, and returns its device time in ms (the sum of the
    passes' profiled times); ``pass_ms`` collects every call's per-pass times."""

    def __init__(self, dev: Device, buf, method: str, knobs: dict):
        self.dev = dev
        self.pipe = make_pipeline(method, dev.context, buf.inspect(), **knobs)
        self.samples = DeviceSamples.upload(dev.queue, buf, self.pipe.fields)
        self.out = cl.Buffer(dev.context, cl.mem_flags.READ_WRITE,
                             size=buf.height * buf.width * 12)
        self.shape = (buf.height, buf.width, 3)
        self.pass_ms: dict[str, list[float]] = {}

    def describe(self) -> dict:
        return self.pipe.describe()

    def run(self) -> float:
        self.pipe(self.dev.queue, self.samples, self.out).wait()
        times = self.pipe.pass_times_ms()
        for k, v in times.items():
            self.pass_ms.setdefault(k, []).append(v)
        return float(sum(times.values()))

    def median_pass_ms(self) -> dict[str, float]:
        return {k: statistics.median(v) for k, v in self.pass_ms.items()}

    def image(self) -> np.ndarray:
        img = np.empty(self.shape, np.float32)
        cl.enqueue_copy(self.dev.queue, img, self.out)
        return img


def time_pipeline(dev: Device, buf, method: str, knobs: dict, repeats: int):
    """Build once, upload once, warm up, time ``repeats`` calls:
    ``(last image, median device ms, median ms per pass, describe())``."""
    runner = PipelineRun(dev, buf, method, knobs)
    runner.run()  # warm-up
    runner.pass_ms.clear()
    totals = [runner.run() for _ in range(repeats)]
    return runner.image(), statistics.median(totals), runner.median_pass_ms(), runner.describe()


def _version(dist: str) -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(dist)
    except PackageNotFoundError:
        return "?"


class OidnRun:
    """The box image denoised by Open Image Denoise on the CPU (``pyoidn``, HDR).

    ``run()`` returns the wall ms of box (device time) plus the denoise (wall time around
    ``pyoidn.denoise``); ``pass_ms`` keeps the two parts."""

    def __init__(self, dev: Device, buf, quality: str):
        import pyoidn

        self.pyoidn, self.quality = pyoidn, quality
        self.box = PipelineRun(dev, buf, "box", {})
        self.pass_ms: dict[str, list[float]] = {}
        self.result = None

    def describe(self) -> dict:
        return {"method": "oidn", "mode": f"box + OIDN {self.quality} (CPU, hdr)",
                "pyoidn": _version("pyoidn")}

    def run(self) -> float:
        box_ms = self.box.run()
        t0 = time.perf_counter()
        self.result = self.pyoidn.denoise(self.box.image(), hdr=True, quality=self.quality)
        oidn_ms = (time.perf_counter() - t0) * 1e3
        self.pass_ms.setdefault("box", []).append(box_ms)
        self.pass_ms.setdefault("oidn", []).append(oidn_ms)
        return box_ms + oidn_ms

    def image(self) -> np.ndarray:
        return np.asarray(self.result, np.float32)
