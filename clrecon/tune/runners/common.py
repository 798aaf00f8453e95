"""What the runners of every method share: the :class:`PassRunner` the tuner drives, the
device time of a launch, and the synthetic frame the passes are tuned on."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import pyopencl as cl

from clrecon.core.camera import CocModel
from clrecon.core.device import Device
from clrecon.core.samples import SampleBuffer
from clrecon.tune.tunable import Tunable


def random_lens_time_color(buf: SampleBuffer, rng: np.random.Generator) -> None:
    """Fill ``buf``'s lens positions (uniform on the unit disc), times (uniform) and colours
    (exponential, mean 1) from ``rng``, in that order."""
    r = np.sqrt(rng.uniform(0, 1, buf.depth.shape))
    a = rng.uniform(0, 2 * np.pi, buf.depth.shape)
    buf.lens[:] = np.stack([r * np.cos(a), r * np.sin(a)], -1)
    buf.time[:] = rng.uniform(0, 1, buf.time.shape)
    buf.color[:] = rng.exponential(1.0, buf.color.shape)


def synthetic_frame(width: int, height: int, spp: int, seed: int = 0) -> SampleBuffer:
    """A valid frame with defocus (CoC -7..7 px), some motion and misses: every branch of
    every pass runs, and the data do not depend on the scene generator."""
    rng = np.random.default_rng(seed)
    buf = SampleBuffer.zeros(height, width, spp, CocModel.from_focus(8.0, 4.0))
    buf.position[:] += rng.uniform(-0.5, 0.499, buf.position.shape)
    buf.depth[:] = rng.uniform(2.2, 40.0, buf.depth.shape)
    buf.depth[rng.uniform(size=buf.depth.shape) < 0.05] = np.inf
    random_lens_time_color(buf, rng)
    moving = rng.uniform(size=buf.depth.shape) < 0.3
    buf.motion[:] = np.where(moving[..., None], rng.normal(0, 4.0, buf.motion.shape), 0.0)
    return buf


def pass_time_ms(handle, last: cl.Event) -> float:
    """Device time of one launch of a pass: the sum over every kernel it enqueued.

    A pass that enqueues several kernels (splat_integrate's pyramid levels, splat's tile
    rounds, filter_rotated's u and v) lists their events in ``handle.events`` (plain events
    or ``(name, event)`` pairs) and returns the last; timing only the returned event would
    rank configurations by their last kernel alone."""
    events = [e[1] if isinstance(e, tuple) else e for e in getattr(handle, "events", None) or ()]
    if not events or events[-1] != last:
        events = [last]
    for e in events:
        e.wait()
    return sum((e.profile.end - e.profile.start) for e in events) * 1e-6


class PassRunner:
    """Builds a pass object for a configuration and launches it on fixed device inputs."""

    def __init__(self, device: Device, make: Callable, launch: Callable, out_shape: tuple,
                 group_size: Callable[[dict | None], int | None]):
        self.device, self.make, self.launch = device, make, launch
        self.out_shape, self.group_size = out_shape, group_size
        self.out = cl.Buffer(device.context, cl.mem_flags.READ_WRITE,
                             int(np.prod(out_shape)) * 4)

    def build(self, config):
        return self.make(config)

    def local_size(self, config) -> int | None:
        return self.group_size(config)

    def max_work_group_size(self, handle) -> int | None:
        return int(handle.kernel.get_work_group_info(cl.kernel_work_group_info.WORK_GROUP_SIZE,
                                                     self.device.device))

    def run(self, handle):
        q = self.device.queue
        ev = self.launch(handle, q, self.out)
        ev.wait()
        host = np.empty(self.out_shape, np.float32)
        cl.enqueue_copy(q, host, self.out)
        return host, pass_time_ms(handle, ev)


#: ``runner(device, width, height, spp)``: a :class:`PassRunner` on inputs of that size
RunnerFactory = Callable[[Device, int, int, int], PassRunner]


@dataclass(frozen=True)
class PassSpec:
    """How to tune one pass: its declaration (:class:`~clrecon.tune.tunable.Tunable`, which
    lives beside the pass) and the runner that builds and launches it for the tuner."""

    tunable: Tunable
    runner: RunnerFactory

    def __getattr__(self, name: str):
        """The declaration's fields read through: ``spec.default`` is
        ``spec.tunable.default`` (likewise ``name``, ``kernel_file``, ``candidates``...)."""
        if name == "tunable":  # not set yet (a copy being made)
            raise AttributeError(name)
        return getattr(self.tunable, name)


def tunes(specs: list[PassSpec], tunable: Tunable) -> Callable[[RunnerFactory], RunnerFactory]:
    """Decorator: the function is the tuner's runner of the pass ``tunable`` declares; its
    :class:`PassSpec` is appended to ``specs`` (its method's list, in definition order)."""

    def register(runner: RunnerFactory) -> RunnerFactory:
        specs.append(PassSpec(tunable, runner))
        return runner

    return register


def wg_items(config: dict | None) -> int | None:
    """Work-items a group of a ``{"wg_x", "wg_y"}`` configuration (``None``: the runtime
    chooses)."""
    return None if config is None else int(config["wg_x"]) * int(config["wg_y"])


def clear_output(queue: cl.CommandQueue, buf: cl.Buffer) -> cl.Event:
    """Clear an output the pass writes only in part (unwritten garbage may hold NaNs, which
    would fail verification); untimed: the runner times the pass's own event."""
    return cl.enqueue_fill_buffer(queue, buf, np.float32(0), 0, buf.size)
