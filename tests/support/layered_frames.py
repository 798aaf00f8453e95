"""Small frames and device helpers shared by the tests of method ``layered``."""
from __future__ import annotations

import numpy as np
import pyopencl as cl
from sample_frames import disc_points

from clrecon.core.camera import CocModel
from clrecon.core.pipeline import DeviceSamples
from clrecon.core.samples import SampleBuffer
from clrecon.methods.layered import layout as geom

LAYOUT = geom.Layout(tile=16, nbuckets=32, maxp=4, gmax=8, spp=4, has_motion=True, reach_max=48)


def frame(rng, h=37, w=35, s=4, motion=True, misses=True, aperture=8.0):
    """A valid random frame: depths 2.2..40 (CoC about -6.5..+7 px), misses, some motion."""
    buf = SampleBuffer.zeros(h, w, s, CocModel.from_focus(aperture, 4.0))
    buf.position[:] += rng.uniform(-0.5, 0.499, buf.position.shape)
    # a few depth layers per tile plus jitter: populated and empty buckets both occur
    layers = np.array([2.5, 3.6, 4.0, 6.0, 15.0, 40.0])
    buf.depth[:] = rng.choice(layers, buf.depth.shape) * rng.uniform(0.98, 1.02, buf.depth.shape)
    if misses:
        buf.depth[rng.uniform(size=buf.depth.shape) < 0.08] = np.inf
    buf.lens[:] = disc_points(rng, buf.depth.shape)
    buf.time[:] = rng.uniform(0, 1, buf.time.shape)
    buf.color[:] = rng.exponential(1.0, buf.color.shape)
    if motion:
        # motion by depth layer, so that partitions have a coherent motion
        mv = np.where(buf.depth[..., None] < 5.0, [6.0, -3.0], [0.0, 0.0])
        buf.motion[:] = mv + rng.normal(0, 0.3, buf.motion.shape)
    return buf.validate()


def bucket_coeffs(buf, layout=LAYOUT, bucket_coc=0.5):
    info = buf.inspect()
    return geom.bucket_params(buf.coc_model.c0, buf.coc_model.c1, info.min_depth,
                              info.max_depth, layout.nbuckets, bucket_coc)


def to_device(queue, array) -> cl.Buffer:
    host = np.ascontiguousarray(array, np.float32)
    d = cl.Buffer(queue.context, cl.mem_flags.READ_WRITE, max(host.nbytes, 4))
    cl.enqueue_copy(queue, d, host)
    return d


def empty(queue, shape) -> cl.Buffer:
    return cl.Buffer(queue.context, cl.mem_flags.READ_WRITE, int(np.prod(shape)) * 4)


def read(queue, d, shape, wait=None) -> np.ndarray:
    host = np.empty(shape, np.float32)
    cl.enqueue_copy(queue, host, d, wait_for=wait)
    return host


def upload(queue, buf) -> DeviceSamples:
    return DeviceSamples.upload(queue, buf)


def fields(buf) -> dict:
    return {k: getattr(buf, k) for k in ("color", "position", "depth", "lens", "time",
                                         "motion")}
