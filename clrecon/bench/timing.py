"""How every report times things: one module, so that ``clrecon trade``, ``table``, ``report``,
``bench``, ``demo`` and the measurement scripts under ``tools/`` measure the same way.

- **Device time** of a pipeline is the sum of its passes' profiled kernel times
  (:meth:`clrecon.core.pipeline.Pipeline.pass_times_ms`) for one call on a warm pipeline:
  the program builds, the upload and the read-back are not in it.
- **Wall time** is ``time.perf_counter()`` around a call, after one warm-up call.
- **Per leaf step**: where a report needs more than the per-kernel times (``clrecon bench``,
  ``tools/scaling_study.py``), :class:`LeafRun` finds the plan's leaf steps on its warm-up
  launch and sums each one's kernels per call, with the bytes its buffers hold.
- Reports give medians. Side-by-side comparisons run their variants in *paired rounds*
  (:func:`paired_rounds`: each round runs every variant once, the order rotated), so that
  a noisy machine slows all of them alike.
"""
from __future__ import annotations

import math
import platform
import statistics
import subprocess
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import TypeVar

import numpy as np
import pyopencl as cl

from clrecon.api import make_pipeline
from clrecon.core.device import Device, event_ms
from clrecon.core.pipeline import DeviceSamples, Pipeline

T = TypeVar("T")


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


def paired_rounds(calls: Sequence[Callable[[], T]], repeats: int) -> list[list[T]]:
    """``repeats`` rounds, each calling every one of ``calls`` once, round ``r`` starting at
    call ``r mod n`` (rotated order: with two calls, they alternate which goes first), so
    that the machine's drifting load falls on all of them alike. Returns each call's results
    in round order."""
    results: list[list[T]] = [[] for _ in calls]
    n = len(calls)
    for r in range(repeats):
        for i in [*range(r % n, n), *range(r % n)]:
            results[i].append(calls[i]())
    return results


def host_cpu() -> str:
    """The host CPU's model name, for a report's header: ``lscpu``'s, else
    ``/proc/cpuinfo``'s, else the platform's."""
    try:
        text = subprocess.run(["lscpu"], capture_output=True, text=True, timeout=10).stdout
        for line in text.splitlines():
            if line.startswith("Model name:"):
                return line.split(":", 1)[1].strip()
    except (OSError, subprocess.SubprocessError):
        pass
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


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


@dataclass
class LeafPasses:
    """What a report times per pass: each *leaf* plan step (one that runs kernels itself,
    not through a sub-pipeline), named after the kernels it launched.

    ``owners[i]`` is the pass of the top pipeline's ``events[i]``; ``bytes`` the bytes of each
    pass's bound buffers (inputs + outputs, summed over its invocations); ``kernels`` the
    kernel (event) names of each pass in launch order."""

    owners: list[str]
    bytes: dict[str, int]
    kernels: dict[str, list[str]]


def sub_pipelines(pipe: Pipeline) -> list[Pipeline]:
    """``pipe`` and every pipeline it holds as an attribute (a safeguarded method's full-frame
    and half-frame pipelines), recursively, each once."""
    out, todo = [], [pipe]
    while todo:
        p = todo.pop()
        if any(p is q for q in out):
            continue
        out.append(p)
        todo += [v for v in vars(p).values() if isinstance(v, Pipeline)]
    return out


def _counted(step, calls: list[tuple[int, list[int]]], nested: list[bool]):
    """``step`` noting, when no other step ran inside it (a leaf), its buffers' bytes and the
    handles of the events it returned in ``calls``."""
    def run(q, frame, wait_for):
        nested[0] = False
        evs = step.run(q, frame, wait_for)
        if not nested[0]:
            sizes = {n: int(frame.buffers[n].size) for n in step.inputs + step.outputs}
            calls.append((sum(sizes[n] for n in step.inputs)
                          + sum(sizes[n] for n in step.outputs),
                          [ev.int_ptr for _, ev in evs]))
        nested[0] = True  # the enclosing step, if any, is not a leaf
        return evs
    return replace(step, run=run)


def _leaf_passes(pipe: Pipeline, queue: cl.CommandQueue, samples: DeviceSamples,
                 out: cl.Buffer) -> LeafPasses:
    """One launch, waited for, that also finds the passes (see :class:`LeafRun`)."""
    calls: list[tuple[int, list[int]]] = []  # leaf calls: (bytes, event handles)
    nested = [False]  # did a step run since the current one started?
    pipes = sub_pipelines(pipe)
    plans = [p.plan for p in pipes]
    for p in pipes:
        p.plan = replace(p.plan, steps=tuple(_counted(st, calls, nested)
                                             for st in p.plan.steps))
    try:
        pipe(queue, samples, out).wait()
    finally:
        for p, plan in zip(pipes, plans):
            p.plan = plan
    call_of = {h: i for i, (_, handles) in enumerate(calls) for h in handles}
    names_of: dict[int, list[str]] = {}
    for name, ev in pipe.events:
        i = call_of.get(ev.int_ptr, -1)
        if name not in names_of.setdefault(i, []):
            names_of[i].append(name)
    label = {i: " + ".join(names) for i, names in names_of.items() if i >= 0}
    passes = LeafPasses([], {}, {})
    for name, ev in pipe.events:
        i = call_of.get(ev.int_ptr, -1)
        passes.owners.append(label.get(i, name))  # an event no leaf returned: by its name
    for i, (nbytes, _) in enumerate(calls):
        if i in label:
            passes.bytes[label[i]] = passes.bytes.get(label[i], 0) + nbytes
            passes.kernels.setdefault(label[i], names_of[i])
    return passes


class LeafRun:
    """A built pipeline on uploaded samples, timed per kernel and per leaf plan step.

    Construction is the warm-up launch (PoCL specialises on the first), waited for, that
    also finds the passes (:attr:`passes`): for this launch only, every step of ``pipe``
    and of its sub-pipelines is wrapped (the plan is data: the same steps, each noting the
    buffers it was given and the events it returned; every plan is restored afterwards). A
    step during which no other step ran is a leaf; its bytes are the sizes of the buffers
    its ``inputs`` and ``outputs`` name as bound for that call, and it owns the events it
    returned. A leaf is named after its kernels as the top pipeline names them
    (``"filter_sheared_recursive + filter_sheared_gauss"`` for a two-kernel step; a
    safeguarded method's half-frame runs keep their ``" (halves)"``)."""

    def __init__(self, pipe: Pipeline, queue: cl.CommandQueue, samples: DeviceSamples,
                 out: cl.Buffer):
        self.pipe, self.queue, self.samples, self.out = pipe, queue, samples, out
        self.passes = _leaf_passes(pipe, queue, samples, out)

    def run(self) -> tuple[dict[str, float], dict[str, float]]:
        """One launch, waited for: per-kernel device ms plus ``"frame"`` (their sum), and
        per pass the sum of its kernels (NaN should the launch enqueue other events than
        the warm-up's)."""
        pipe = self.pipe
        pipe(self.queue, self.samples, self.out).wait()
        times = dict(pipe.pass_times_ms())
        times["frame"] = float(sum(times.values()))
        steps: dict[str, float] = {}
        if len(pipe.events) == len(self.passes.owners):
            for owner, (_, ev) in zip(self.passes.owners, pipe.events):
                steps[owner] = steps.get(owner, 0.0) + event_ms(ev)
        else:
            steps = {name: math.nan for name in self.passes.bytes}
        return times, steps
