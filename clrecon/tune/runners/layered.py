"""The runners of method layered's passes for the tuner: each on the buffers one run of
the method's pipeline leaves on a synthetic frame."""
from __future__ import annotations

import pyopencl as cl

from clrecon.api import make_pipeline
from clrecon.core.device import Device
from clrecon.core.pipeline import DeviceSamples
from clrecon.methods.layered.composite import LayeredComposite
from clrecon.methods.layered.filter_mip import FilterMip
from clrecon.methods.layered.filter_rotated import FilterRotated
from clrecon.methods.layered.filter_sheared import FilterSheared
from clrecon.methods.layered.partition_setup import PartitionSetup
from clrecon.methods.layered.reproject import Reproject
from clrecon.methods.layered.tile_stats import TileStats
from clrecon.tune.local import local_size_of
from clrecon.tune.runners.common import (
    PassRunner,
    PassSpec,
    clear_output,
    synthetic_frame,
    tunes,
    wg_items,
)

#: this method's passes, as :func:`tunes` registers their runners
SPECS: list[PassSpec] = []


def _layered_inputs(dev, w, h, spp, **knobs):
    """A layered pipeline run once on a synthetic frame: every intermediate buffer filled."""
    buf = synthetic_frame(w, h, spp)
    # the method's own passes: the safeguard's blend around them is not what is tuned
    pipe = make_pipeline("layered", dev.context, buf.inspect(), safeguard=False, **knobs)
    s = DeviceSamples.upload(dev.queue, buf, pipe.fields)
    out = cl.Buffer(dev.context, cl.mem_flags.READ_WRITE, w * h * 12)
    pipe(dev.queue, s, out).wait()
    ntx, nty = pipe.layout.tiles(w, h)
    return pipe, s, ntx * nty


@tunes(SPECS, TileStats.TUNABLE)
def tile_stats_runner(dev: Device, w: int, h: int, spp: int) -> PassRunner:
    pipe, s, nt = _layered_inputs(dev, w, h, spp)
    layout, bucket_coeffs = pipe.layout, pipe.bucket_params(s)
    return PassRunner(dev, lambda c: TileStats(dev.context, layout, local_size_of(c)),
                      lambda p, q, out: p(q, s, bucket_coeffs, pipe.stats_stride, 0, out),
                      (nt, layout.nbuckets, 8), wg_items)


@tunes(SPECS, PartitionSetup.TUNABLE)
def partition_setup_runner(dev: Device, w: int, h: int, spp: int) -> PassRunner:
    pipe, s, nt = _layered_inputs(dev, w, h, spp)
    layout, st = pipe.layout, pipe.buffers["stats"]
    return PassRunner(dev, lambda c: PartitionSetup(dev.context, layout, local_size_of(c)),
                      lambda p, q, out: p(q, st, nt, pipe.sigma_x, pipe.merge_threshold, out),
                      (nt, layout.maxp, 20), wg_items)


@tunes(SPECS, Reproject.TUNABLE)
def reproject_runner(dev: Device, w: int, h: int, spp: int) -> PassRunner:
    pipe, s, nt = _layered_inputs(dev, w, h, spp)
    layout, bucket_coeffs, par = pipe.layout, pipe.bucket_params(s), pipe.buffers["params"]
    return PassRunner(dev, lambda c: Reproject(dev.context, layout, False, local_size_of(c)),
                      lambda p, q, out: p(q, s, bucket_coeffs, par, out, [clear_output(q, out)]),
                      (nt, layout.maxp, 5, layout.dmax ** 2), wg_items)


@tunes(SPECS, FilterSheared.TUNABLE)
def filter_sheared_runner(dev: Device, w: int, h: int, spp: int) -> PassRunner:
    """Times both of filter_sheared's kernels together (``pass_time_ms``); each launch first
    restores the reprojected grids, which the first kernel filters in place."""
    pipe, s, nt = _layered_inputs(dev, w, h, spp)
    layout, par = pipe.layout, pipe.buffers["params"]
    src = cl.Buffer(dev.context, cl.mem_flags.READ_WRITE, pipe.buffers["grids"].size)
    pipe.reproject(dev.queue, s, pipe.bucket_params(s), par, src).wait()
    work = pipe.buffers["grids"]

    def launch(p, q, out):
        ev = cl.enqueue_copy(q, work, src)
        return p(q, par, work, out, nt * layout.maxp, [ev, clear_output(q, out)])

    return PassRunner(dev, lambda c: FilterSheared(dev.context, layout, pipe.recursions,
                                                   local_size_of(c)),
                      launch, (nt, layout.maxp, 5, layout.filtered_side ** 2), wg_items)


def _filter_runner(cls, scratch: str, dev, w, h, spp, **knobs) -> PassRunner:
    """A filter pass ``cls`` that reads the grids and the pipeline's buffer ``scratch``
    (filter_rotated's temporary, filter_mip's pyramid) in a pipeline built with ``knobs``."""
    pipe, s, nt = _layered_inputs(dev, w, h, spp, **knobs)
    layout, b = pipe.layout, pipe.buffers
    return PassRunner(dev, lambda c: cls(dev.context, layout, local_size_of(c)),
                      lambda p, q, out: p(q, b["params"], b["grids"], b[scratch], out,
                                          nt * layout.maxp, [clear_output(q, out)]),
                      (nt, layout.maxp, 5, layout.filtered_side ** 2), wg_items)


@tunes(SPECS, FilterRotated.TUNABLE)
def filter_rotated_runner(dev: Device, w: int, h: int, spp: int) -> PassRunner:
    return _filter_runner(FilterRotated, "tmp", dev, w, h, spp, mode="lrdm")


@tunes(SPECS, FilterMip.TUNABLE)
def filter_mip_runner(dev: Device, w: int, h: int, spp: int) -> PassRunner:
    return _filter_runner(FilterMip, "pyramid", dev, w, h, spp, filter="mip")


@tunes(SPECS, LayeredComposite.TUNABLE)
def composite_runner(dev: Device, w: int, h: int, spp: int) -> PassRunner:
    pipe, s, nt = _layered_inputs(dev, w, h, spp)
    layout, b = pipe.layout, pipe.buffers
    return PassRunner(dev, lambda c: LayeredComposite(dev.context, layout, local_size_of(c)),
                      lambda p, q, out: p(q, s["color"], b["params"], b["filtered"], w, h, out),
                      (h, w, 3), wg_items)
