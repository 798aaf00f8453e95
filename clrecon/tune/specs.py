"""Tuning specs: for each pass its tunables, candidate configurations, default and a runner
that builds and launches the real pass on a synthetic frame of the tuned size.

A configuration is a dict of the pass's tunables, or ``None`` for "runtime chooses" (local
size left to the OpenCL runtime). Adding a pass to the tuner means adding one spec here.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import pyopencl as cl

from clrecon.core.camera import CocModel
from clrecon.core.device import Device
from clrecon.core.pipeline import DeviceSamples, LocalSize
from clrecon.core.samples import SampleBuffer

LOCAL_SIZES = [(1, 1), (4, 4), (8, 8), (16, 4), (16, 8), (32, 4), (32, 8), (64, 1), (16, 16)]


def local_candidates() -> list[dict | None]:
    return [{"wg_x": x, "wg_y": y} for x, y in LOCAL_SIZES] + [None]


def local_size_of(config: dict | None) -> LocalSize:
    """The :class:`LocalSize` a local-size configuration stands for."""
    if config is None:
        return LocalSize(None)
    return LocalSize(int(config["wg_x"]), int(config["wg_y"]))


def synthetic_frame(width: int, height: int, spp: int, seed: int = 0) -> SampleBuffer:
    """A valid frame with defocus (CoC -7..7 px), some motion and misses: every branch of
    every pass runs, and the data do not depend on the scene generator."""
    rng = np.random.default_rng(seed)
    buf = SampleBuffer.zeros(height, width, spp, CocModel.from_focus(8.0, 4.0))
    buf.position[:] += rng.uniform(-0.5, 0.499, buf.position.shape)
    buf.depth[:] = rng.uniform(2.2, 40.0, buf.depth.shape)
    buf.depth[rng.uniform(size=buf.depth.shape) < 0.05] = np.inf
    r = np.sqrt(rng.uniform(0, 1, buf.depth.shape))
    a = rng.uniform(0, 2 * np.pi, buf.depth.shape)
    buf.lens[:] = np.stack([r * np.cos(a), r * np.sin(a)], -1)
    buf.time[:] = rng.uniform(0, 1, buf.time.shape)
    buf.color[:] = rng.exponential(1.0, buf.color.shape)
    moving = rng.uniform(size=buf.depth.shape) < 0.3
    buf.motion[:] = np.where(moving[..., None], rng.normal(0, 4.0, buf.motion.shape), 0.0)
    return buf


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


def pass_time_ms(handle, last: cl.Event) -> float:
    """Device time of one launch of a pass: the sum over every kernel it enqueued.

    A pass that enqueues several kernels (integrate's pyramid levels, splat's tile rounds,
    filter_rotated's u and v) lists their events in ``handle.events`` (plain events or
    ``(name, event)`` pairs) and returns the last; timing only the returned event would rank
    configurations by their last kernel alone."""
    events = [e[1] if isinstance(e, tuple) else e for e in getattr(handle, "events", None) or ()]
    if not events or events[-1] != last:
        events = [last]
    for e in events:
        e.wait()
    return sum((e.profile.end - e.profile.start) for e in events) * 1e-6


@dataclass(frozen=True)
class PassSpec:
    """How to tune one pass.

    ``default`` is what the tuner measures first and what a CPU (or any device but a GPU)
    gets without a tuning entry; ``gpu`` is what a GPU gets instead (``None``: ``default``
    suits GPUs too). :func:`clrecon.tune.runtime.default_config` fits either to the device.
    """

    name: str
    kernel_file: str
    default: dict | None
    candidates: Callable[[], list]
    runner: Callable[[Device, int, int, int], PassRunner]
    rtol: float = 1e-5
    atol: float = 1e-6
    gpu: dict | None = None


def _wg(config):
    return None if config is None else int(config["wg_x"]) * int(config["wg_y"])


def _box_runner(dev, w, h, spp):
    from clrecon.methods.box import Box

    buf = synthetic_frame(w, h, spp)
    s = DeviceSamples.upload(dev.queue, buf, ("color",))
    return PassRunner(dev, lambda c: Box(dev.context, local_size_of(c)),
                      lambda p, q, out: p(q, s["color"], out, w, h, spp), (h, w, 3), _wg)


def _prepare_runner(dev, w, h, spp):
    from clrecon.methods.sweep.prepare import SweepPrepare

    s = DeviceSamples.upload(dev.queue, synthetic_frame(w, h, spp))
    colors = cl.Buffer(dev.context, cl.mem_flags.READ_WRITE, w * h * spp * 16)
    return PassRunner(dev, lambda c: SweepPrepare(dev.context, spp, True, local_size_of(c)),
                      lambda p, q, out: p(q, s, 1.0, out, colors), (h, w, spp, 4), _wg)


def _sweep_inputs(dev, w, h, spp):
    from clrecon.methods.sweep.prepare import SweepPrepare

    s = DeviceSamples.upload(dev.queue, synthetic_frame(w, h, spp))
    rw = cl.mem_flags.READ_WRITE
    keys = cl.Buffer(dev.context, rw, w * h * spp * 16)
    colors = cl.Buffer(dev.context, rw, w * h * spp * 16)
    SweepPrepare(dev.context, spp, True)(dev.queue, s, 1.0, keys, colors).wait()
    return keys, colors


def resolve_candidates() -> list:
    tiles = [{"sort": "tile", "tile": t, "tile_merge": m} for t in (2, 4, 8)
             for m in ("serial", "bitonic")]
    pixels = [{"sort": "pixel", "wg_x": x, "wg_y": y} for x, y in ((8, 8), (16, 4), (32, 2))]
    return tiles + pixels


def resolve_group(config):
    if config is None:
        return None
    if config["sort"] == "tile":
        return int(config["tile"]) ** 2
    return int(config["wg_x"]) * int(config["wg_y"])


def make_resolve(context, spp: int, scales: int, exponent: float, config: dict):
    """A :class:`SweepResolve` for a tuning configuration."""
    from clrecon.methods.sweep.resolve import SORTS, SweepResolve

    sort = config.get("sort")
    if sort not in SORTS:
        raise ValueError(f"sort: must be one of {SORTS}, got {sort!r}")
    if sort == "tile":
        return SweepResolve(context, spp, scales, exponent, "tile", config["tile"],
                            config["tile_merge"])
    return SweepResolve(context, spp, scales, exponent, "pixel",
                        local=LocalSize(int(config["wg_x"]), int(config["wg_y"])))


def _resolve_runner(dev, w, h, spp):
    keys, colors = _sweep_inputs(dev, w, h, spp)
    return PassRunner(dev, lambda c: make_resolve(dev.context, spp, 2, 1.0, c),
                      lambda p, q, out: p(q, keys, colors, w, h, out), (h, w, 3), resolve_group)


def _block_runner(dev, w, h, spp):
    from clrecon.methods.sweep.block import SweepBlock

    s = DeviceSamples.upload(dev.queue, synthetic_frame(w, h, spp))
    return PassRunner(dev, lambda c: SweepBlock(dev.context, spp, 2, 1.0, True, c["group"]),
                      lambda p, q, out: p(q, s, 1.0, out), (h, w, 3),
                      lambda c: None if c is None else int(c["group"]))


def _layer_sums_runner(dev, w, h, spp):
    from clrecon.methods.sweep.layers import SweepLayerSums

    s = DeviceSamples.upload(dev.queue, synthetic_frame(w, h, spp), ("color", "depth"))
    return PassRunner(dev, lambda c: SweepLayerSums(dev.context, spp, local_size_of(c)),
                      lambda p, q, out: p(q, s, 1.0, out), (h, w, 3, 4), _wg)


def _layer_resolve_runner(dev, w, h, spp):
    from clrecon.methods.sweep.layers import SweepLayerResolve, SweepLayerSums

    s = DeviceSamples.upload(dev.queue, synthetic_frame(w, h, spp), ("color", "depth"))
    sums = cl.Buffer(dev.context, cl.mem_flags.READ_WRITE, w * h * 3 * 16)
    SweepLayerSums(dev.context, spp)(dev.queue, s, 1.0, sums).wait()
    return PassRunner(dev, lambda c: SweepLayerResolve(dev.context, spp, local_size_of(c)),
                      lambda p, q, out: p(q, sums, w, h, out), (h, w, 3), _wg)


def _raytrace_runner(dev, w, h, spp):
    from clrecon.scenes import get_scene
    from clrecon.scenes import render as rt

    scene = get_scene("deep")
    cam, objs, camera, light, bg = rt._common_args(scene, w, h, dev.context)
    n = w * h * spp
    wo = cl.mem_flags.WRITE_ONLY
    fields = [cl.Buffer(dev.context, wo, n * 4 * k) for k in (3, 2, 1, 2, 1, 2)]

    class Launch:
        def __init__(self, config):
            self.local = local_size_of(config)
            self.kernel = cl.Kernel(rt.get_kernel(dev.context, "raytrace", "raytrace_samples")
                                    .get_info(cl.kernel_info.PROGRAM), "raytrace_samples")

    def launch(p, q, out):
        # colour is the checked output; the other fields are written alongside
        p.kernel.set_args(*objs, np.int32(w), np.int32(h), np.int32(spp), np.int32(0),
                          np.uint32(0), *camera, light, bg, out, *fields[1:])
        g, loc = p.local.for_range(w, h)
        return cl.enqueue_nd_range_kernel(q, p.kernel, g, loc)

    return PassRunner(dev, Launch, launch, (h, w, spp, 3), _wg)


# -- method layered -----------------------------------------------------------------------

def layered_1d_candidates() -> list[dict | None]:
    """Work-group sizes of the layered passes that run one work-item (or group) per tile."""
    return [{"wg_x": x, "wg_y": 1} for x in (1, 2, 4, 8, 16, 32, 64)] + [None]


def _layered_inputs(dev, w, h, spp, **knobs):
    """A layered pipeline run once on a synthetic frame: every intermediate buffer filled."""
    from clrecon.core.pipeline import make_pipeline

    buf = synthetic_frame(w, h, spp)
    # the method's own passes: the safeguard's blend around them is not what is tuned
    pipe = make_pipeline("layered", dev.context, buf.inspect(), safeguard=False, **knobs)
    s = DeviceSamples.upload(dev.queue, buf, pipe.fields)
    out = cl.Buffer(dev.context, cl.mem_flags.READ_WRITE, w * h * 12)
    pipe(dev.queue, s, out).wait()
    ntx, nty = pipe.lay.tiles(w, h)
    return pipe, s, ntx * nty


def _zero(queue, buf):
    """Clear an output the pass writes only in part (unwritten garbage may hold NaNs, which
    would fail verification); untimed: the runner times the pass's own event."""
    return cl.enqueue_fill_buffer(queue, buf, np.float32(0), 0, buf.size)


def _tile_stats_runner(dev, w, h, spp):
    from clrecon.methods.layered.tile_stats import TileStats

    pipe, s, nt = _layered_inputs(dev, w, h, spp)
    lay, kabc = pipe.lay, pipe.bucket_params(s)
    return PassRunner(dev, lambda c: TileStats(dev.context, lay, local_size_of(c)),
                      lambda p, q, out: p(q, s, kabc, pipe.stats_stride, 0, out),
                      (nt, lay.nbuckets, 8), _wg)


def _partition_setup_runner(dev, w, h, spp):
    from clrecon.methods.layered.partition_setup import PartitionSetup

    pipe, s, nt = _layered_inputs(dev, w, h, spp)
    lay, st = pipe.lay, pipe.buffers["stats"]
    return PassRunner(dev, lambda c: PartitionSetup(dev.context, lay, local_size_of(c)),
                      lambda p, q, out: p(q, st, nt, pipe.sigma_x, pipe.merge_threshold, out),
                      (nt, lay.maxp, 20), _wg)


def _reproject_runner(dev, w, h, spp):
    from clrecon.methods.layered.reproject import Reproject

    pipe, s, nt = _layered_inputs(dev, w, h, spp)
    lay, kabc, par = pipe.lay, pipe.bucket_params(s), pipe.buffers["params"]
    return PassRunner(dev, lambda c: Reproject(dev.context, lay, False, local_size_of(c)),
                      lambda p, q, out: p(q, s, kabc, par, out, [_zero(q, out)]),
                      (nt, lay.maxp, 5, lay.dmax ** 2), _wg)


def _filter_sheared_runner(dev, w, h, spp):
    """Times filter_sheared_x and _y together (``pass_time_ms``); each launch first restores
    the reprojected grids, which filter_sheared_x filters in place."""
    from clrecon.methods.layered.filter_sheared import FilterSheared

    pipe, s, nt = _layered_inputs(dev, w, h, spp)
    lay, par = pipe.lay, pipe.buffers["params"]
    src = cl.Buffer(dev.context, cl.mem_flags.READ_WRITE, pipe.buffers["grids"].size)
    pipe.reproject(dev.queue, s, pipe.bucket_params(s), par, src).wait()
    work = pipe.buffers["grids"]

    def launch(p, q, out):
        ev = cl.enqueue_copy(q, work, src)
        return p(q, par, work, out, nt * lay.maxp, [ev, _zero(q, out)])

    return PassRunner(dev, lambda c: FilterSheared(dev.context, lay, pipe.recursions,
                                                   local_size_of(c)),
                      launch, (nt, lay.maxp, 5, lay.ft ** 2), _wg)


def _filter_rotated_runner(dev, w, h, spp):
    from clrecon.methods.layered.filter_rotated import FilterRotated

    pipe, s, nt = _layered_inputs(dev, w, h, spp, mode="lrdm")
    lay, b = pipe.lay, pipe.buffers
    return PassRunner(dev, lambda c: FilterRotated(dev.context, lay, local_size_of(c)),
                      lambda p, q, out: p(q, b["params"], b["grids"], b["tmp"], out,
                                          nt * lay.maxp, [_zero(q, out)]),
                      (nt, lay.maxp, 5, lay.ft ** 2), _wg)


def _filter_mip_runner(dev, w, h, spp):
    from clrecon.methods.layered.filter_mip import FilterMip

    pipe, s, nt = _layered_inputs(dev, w, h, spp, filter="mip")
    lay, b = pipe.lay, pipe.buffers
    return PassRunner(dev, lambda c: FilterMip(dev.context, lay, local_size_of(c)),
                      lambda p, q, out: p(q, b["params"], b["grids"], b["pyramid"], out,
                                          nt * lay.maxp, [_zero(q, out)]),
                      (nt, lay.maxp, 5, lay.ft ** 2), _wg)


def _composite_runner(dev, w, h, spp):
    from clrecon.methods.layered.composite import Composite

    pipe, s, nt = _layered_inputs(dev, w, h, spp)
    lay, b = pipe.lay, pipe.buffers
    return PassRunner(dev, lambda c: Composite(dev.context, lay, local_size_of(c)),
                      lambda p, q, out: p(q, s["color"], b["params"], b["filtered"], w, h, out),
                      (h, w, 3), _wg)


LAYERED_1D = {"wg_x": 8, "wg_y": 1}

DEFAULT_LOCAL = {"wg_x": 16, "wg_y": 4}

# GPU defaults (no tuning entry on a GPU): whole warps/wavefronts (multiples of 32 items,
# 64-256 per group) where the CPU defaults run one to eight items a group; rows of 32
# pixels for the per-pixel passes (coalesced loads), 64 items for one group (or item) per
# tile. The layered filters keep 8x8: their ranges are grids of 34-64 pixels a side, which
# 32-wide rows would pad to 64.
GPU_LOCAL = {"wg_x": 32, "wg_y": 4}
GPU_1D = {"wg_x": 64, "wg_y": 1}

SPECS: dict[str, PassSpec] = {s.name: s for s in (
    # the scene generator's kernel: the same search, default the 8x8 it was written for
    PassSpec("raytrace", "raytrace", {"wg_x": 8, "wg_y": 8}, local_candidates, _raytrace_runner),
    PassSpec("box", "box", DEFAULT_LOCAL, local_candidates, _box_runner, gpu=GPU_LOCAL),
    PassSpec("sweep_prepare", "sweep_prepare", DEFAULT_LOCAL, local_candidates, _prepare_runner,
             gpu=GPU_LOCAL),
    # float sums in a different order per configuration: relative tolerance
    # "auto": the serial merge on CPUs, the bitonic network on GPUs; the sweep fits the
    # tile to the device's local memory (an 8x8 tile holds 12x12 pixels' samples)
    PassSpec("sweep_resolve", "sweep_resolve", {"sort": "tile", "tile": 4,
                                                "tile_merge": "auto"},
             resolve_candidates, _resolve_runner, rtol=1e-4, atol=1e-5,
             gpu={"sort": "tile", "tile": 8, "tile_merge": "auto"}),
    # the whole sorted sweep per 4x4 block (sort="block"): work-items per group; the sweep
    # fits the group to the device's local memory
    PassSpec("sweep_block", "sweep_block", {"group": 1},
             lambda: [{"group": g} for g in (1, 2, 4, 8, 16)], _block_runner,
             rtol=1e-4, atol=1e-5, gpu={"group": 64}),
    PassSpec("sweep_layer_sums", "sweep_layer_sums", DEFAULT_LOCAL, local_candidates,
             _layer_sums_runner, gpu=GPU_LOCAL),
    PassSpec("sweep_layer_resolve", "sweep_layer_resolve", DEFAULT_LOCAL, local_candidates,
             _layer_resolve_runner, gpu=GPU_LOCAL),
    # method layered; float sums in a different order (atomics): relative tolerance
    PassSpec("tile_stats", "tile_stats", LAYERED_1D, layered_1d_candidates, _tile_stats_runner,
             rtol=1e-4, atol=1e-4, gpu=GPU_1D),
    PassSpec("partition_setup", "partition_setup", LAYERED_1D, layered_1d_candidates,
             _partition_setup_runner, gpu=GPU_1D),
    # one item per (tile, slot) owns its grid on a CPU; a GPU's 64 scatter with atomics
    PassSpec("reproject", "reproject", {"wg_x": 1, "wg_y": 1}, layered_1d_candidates,
             _reproject_runner, rtol=1e-4, atol=1e-4, gpu=GPU_1D),
    PassSpec("filter_sheared", "filter_sheared", {"wg_x": 8, "wg_y": 8}, local_candidates,
             _filter_sheared_runner, rtol=1e-4, atol=1e-5),
    PassSpec("filter_rotated", "filter_rotated", {"wg_x": 8, "wg_y": 8}, local_candidates,
             _filter_rotated_runner, rtol=1e-4, atol=1e-5),
    PassSpec("filter_mip", "filter_mip", {"wg_x": 8, "wg_y": 8}, local_candidates,
             _filter_mip_runner, rtol=1e-4, atol=1e-5),
    PassSpec("composite", "composite", DEFAULT_LOCAL, local_candidates, _composite_runner,
             rtol=1e-5, atol=1e-6, gpu=GPU_LOCAL),
)}


# -- method splat ----------------------------------------------------------------------------

def splat_candidates() -> list:
    return [{"wg": g} for g in (32, 64, 128, 256)] + [None]


def _splat_frame_pipeline(dev, w, h, spp):
    from clrecon.core.pipeline import make_pipeline

    buf = synthetic_frame(w, h, spp)
    s = DeviceSamples.upload(dev.queue, buf)
    return make_pipeline("splat", dev.context, buf.inspect(), psf="combined", layers=2,
                         mip_radius=0,
                         safeguard=False), s


def _splat_runner(dev, w, h, spp):
    from clrecon.methods.splat.splat import Splat

    pipe, s = _splat_frame_pipeline(dev, w, h, spp)
    n = pipe.layers * pipe.shape[0] * pipe.shape[1] * 4

    def launch(p, q, out):
        # accumulating pass: clear first (fast-track cells go to pipe.direct, not checked)
        ev = cl.enqueue_fill_buffer(q, out, np.float32(0), 0, n * 4)
        return p(q, s, pipe.device_table, pipe.inv_far, pipe.layer_scale, pipe.pad, pipe.reach,
                 out, pipe.direct, [ev])

    return PassRunner(dev, lambda c: Splat(dev.context, spp, 2, True, pipe.layers,
                                           None if c is None else int(c["wg"])),
                      launch, (n,), lambda c: None if c is None else int(c["wg"]))


def _integrate_runner(dev, w, h, spp):
    from clrecon.methods.splat.integrate import Integrate

    pipe, s = _splat_frame_pipeline(dev, w, h, spp)
    q = dev.queue
    size = pipe.layers * pipe.shape[0] * pipe.shape[1] * 16
    evs = [cl.enqueue_fill_buffer(q, b, np.float32(0), 0, size) for b in (pipe.lap, pipe.direct)]
    pipe.splat(q, s, pipe.device_table, pipe.inv_far, pipe.layer_scale, pipe.pad, pipe.reach,
               pipe.lap, pipe.direct, evs).wait()
    ring = cl.Buffer(dev.context, cl.mem_flags.READ_WRITE, pipe.layers * 16)
    return PassRunner(dev, lambda c: Integrate(dev.context, *pipe.shape, "f5", local_size_of(c)),
                      lambda p, q, out: p(q, pipe.lap, 0, out, ring),
                      (*pipe.shape, 4), _wg)  # layer 0 only


def _splat_composite_runner(dev, w, h, spp):
    from clrecon.methods.splat.composite import Composite

    pipe, s = _splat_frame_pipeline(dev, w, h, spp)
    out = cl.Buffer(dev.context, cl.mem_flags.READ_WRITE, w * h * 12)
    pipe(dev.queue, s, out).wait()
    return PassRunner(dev, lambda c: Composite(dev.context, pipe.layers, True, local_size_of(c)),
                      lambda p, q, o: p(q, pipe.prim, pipe.direct, pipe.ring, w, h, pipe.pad, o),
                      (h, w, 3), _wg)


SPECS.update({s.name: s for s in (
    # float atomics add in a different order per configuration: relative tolerance
    PassSpec("splat", "splat", {"wg": 64}, splat_candidates, _splat_runner, rtol=1e-3,
             atol=1e-6),
    PassSpec("integrate", "integrate", DEFAULT_LOCAL, local_candidates, _integrate_runner,
             rtol=1e-4, atol=1e-6, gpu=GPU_LOCAL),
    PassSpec("splat_composite", "splat_composite", DEFAULT_LOCAL, local_candidates,
             _splat_composite_runner, gpu=GPU_LOCAL),
)})

#: the configuration every pass uses on a CPU when no tuning entry applies (lookup level
#: "default"); a GPU gets :data:`GPU_DEFAULTS`, both fitted by
#: :func:`clrecon.tune.runtime.default_config`
DEFAULTS: dict[str, dict | None] = {name: spec.default for name, spec in SPECS.items()}
GPU_DEFAULTS: dict[str, dict | None] = {
    name: spec.default if spec.gpu is None else spec.gpu for name, spec in SPECS.items()}
