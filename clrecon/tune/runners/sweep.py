"""The runners of method sweep's passes for the tuner."""
from __future__ import annotations

import pyopencl as cl

from clrecon.core.device import Device
from clrecon.core.pipeline import DeviceSamples
from clrecon.methods.sweep.block import SweepBlock
from clrecon.methods.sweep.layers import SweepLayerResolve, SweepLayerSums
from clrecon.methods.sweep.prepare import SweepPrepare
from clrecon.methods.sweep.resolve import SweepResolve, make_resolve
from clrecon.tune.local import local_size_of
from clrecon.tune.runners.common import PassRunner, PassSpec, synthetic_frame, tunes, wg_items

#: this method's passes, as :func:`tunes` registers their runners
SPECS: list[PassSpec] = []


@tunes(SPECS, SweepPrepare.TUNABLE)
def prepare_runner(dev: Device, w: int, h: int, spp: int) -> PassRunner:
    s = DeviceSamples.upload(dev.queue, synthetic_frame(w, h, spp))
    colors = cl.Buffer(dev.context, cl.mem_flags.READ_WRITE, w * h * spp * 16)
    return PassRunner(dev, lambda c: SweepPrepare(dev.context, spp, True, local_size_of(c)),
                      lambda p, q, out: p(q, s, 1.0, out, colors), (h, w, spp, 4), wg_items)


def _sweep_inputs(dev, w, h, spp):
    """sweep_prepare's keys and colours of the synthetic frame (sweep_resolve's inputs)."""
    s = DeviceSamples.upload(dev.queue, synthetic_frame(w, h, spp))
    rw = cl.mem_flags.READ_WRITE
    keys = cl.Buffer(dev.context, rw, w * h * spp * 16)
    colors = cl.Buffer(dev.context, rw, w * h * spp * 16)
    SweepPrepare(dev.context, spp, True)(dev.queue, s, 1.0, keys, colors).wait()
    return keys, colors


def resolve_group(config: dict | None) -> int | None:
    """Work-items a group of a sweep_resolve configuration: a tile's pixels, or the pixel
    sort's local size."""
    if config is None:
        return None
    if config["sort"] == "tile":
        return int(config["tile"]) ** 2
    return wg_items(config)


@tunes(SPECS, SweepResolve.TUNABLE)
def resolve_runner(dev: Device, w: int, h: int, spp: int) -> PassRunner:
    keys, colors = _sweep_inputs(dev, w, h, spp)
    return PassRunner(dev, lambda c: make_resolve(dev.context, spp, 2, 1.0, c),
                      lambda p, q, out: p(q, keys, colors, w, h, out), (h, w, 3), resolve_group)


@tunes(SPECS, SweepBlock.TUNABLE)
def block_runner(dev: Device, w: int, h: int, spp: int) -> PassRunner:
    s = DeviceSamples.upload(dev.queue, synthetic_frame(w, h, spp))
    return PassRunner(dev, lambda c: SweepBlock(dev.context, spp, 2, 1.0, True, c["group"]),
                      lambda p, q, out: p(q, s, 1.0, out), (h, w, 3),
                      lambda c: None if c is None else int(c["group"]))


@tunes(SPECS, SweepLayerSums.TUNABLE)
def layer_sums_runner(dev: Device, w: int, h: int, spp: int) -> PassRunner:
    s = DeviceSamples.upload(dev.queue, synthetic_frame(w, h, spp), ("color", "depth"))
    return PassRunner(dev, lambda c: SweepLayerSums(dev.context, spp, local_size_of(c)),
                      lambda p, q, out: p(q, s, 1.0, out), (h, w, 3, 4), wg_items)


@tunes(SPECS, SweepLayerResolve.TUNABLE)
def layer_resolve_runner(dev: Device, w: int, h: int, spp: int) -> PassRunner:
    s = DeviceSamples.upload(dev.queue, synthetic_frame(w, h, spp), ("color", "depth"))
    sums = cl.Buffer(dev.context, cl.mem_flags.READ_WRITE, w * h * 3 * 16)
    SweepLayerSums(dev.context, spp)(dev.queue, s, 1.0, sums).wait()
    return PassRunner(dev, lambda c: SweepLayerResolve(dev.context, spp, local_size_of(c)),
                      lambda p, q, out: p(q, sums, w, h, out), (h, w, 3), wg_items)
