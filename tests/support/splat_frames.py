"""Frames, the splat pass's run on its own and its reference, shared by the splat tests."""
from __future__ import annotations

import numpy as np
import pyopencl as cl
from sample_frames import method_frame

from clrecon.core.pipeline import DeviceSamples
from clrecon.methods.splat import reference as ref


def frame(rng, h=11, w=13, s=4, motion=True, aperture=8.0, misses=True):
    """Random valid frame: CoC up to ~|aperture| px, optional motion up to ~20 px, misses."""
    return method_frame(rng, h, w, s, aperture=aperture, misses=misses, motion=motion,
                        moving=0.5, motion_sigma=8.0)


def splat_layers(device, pipe, buf) -> tuple[np.ndarray, np.ndarray]:
    """The splat pass of ``pipe`` alone on ``buf``: its (laplacian, direct) layer images."""
    q = device.queue
    samples = DeviceSamples.upload(q, buf, pipe.fields)
    size = pipe.layers * pipe.shape[0] * pipe.shape[1] * 16
    evs = [cl.enqueue_fill_buffer(q, b, np.float32(0), 0, size) for b in {pipe.lap, pipe.direct}]
    pipe.splat(q, samples, pipe.device_table, pipe.inv_far, pipe.layer_scale, pipe.pad,
               pipe.reach, pipe.lap, pipe.direct, evs, pipe.shift)
    shape = (pipe.layers, *pipe.shape, 4)
    lap, direct = np.empty(shape, np.float32), np.empty(shape, np.float32)
    cl.enqueue_copy(q, lap, pipe.lap)
    cl.enqueue_copy(q, direct, pipe.direct)
    q.finish()
    return lap, direct


def reference_splat(pipe, buf) -> tuple[np.ndarray, np.ndarray]:
    """The NumPy reference of the splat pass with ``pipe``'s table, layers, pad and reach."""
    t = pipe.table
    inv_near = pipe.inv_far + pipe.layers / pipe.layer_scale if pipe.layer_scale else pipe.inv_far
    return ref.splat(buf, t.as_tuple(), t.model.cell_of, pipe.layers, (pipe.inv_far, inv_near),
                     pipe.pad, pipe.reach, t.fast.astype(bool), rotate=len(t.model.n) == 2,
                     smax=t.model.smax)
