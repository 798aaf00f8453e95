"""Render sample buffers and converged references of a :class:`Scene` with
``kernels/raytrace.cl``. Long renders run in chunks and report through ``progress(done,
total)``; the library itself never prints. References are rendered on the trusted device
(PoCL) unless a device is given."""
from __future__ import annotations

from typing import Callable, Optional

import numpy as np
import pyopencl as cl

from clrecon.core.device import Device, DeviceSpec, get_kernel, trusted_device
from clrecon.core.device import get_device as _get_device
from clrecon.core.samples import FrameInfo, SampleBuffer
from clrecon.scenes.primitives import Scene
from clrecon.tune.local import local_size_of
from clrecon.tune.runtime import tuned
from clrecon.tune.tunable import Tunable, local_candidates

Progress = Optional[Callable[[int, int], None]]

#: samples per launch when rendering sample buffers (bounds latency of one launch)
CHUNK_SAMPLES = 1 << 22
#: samples per pixel per launch of the reference kernel
REFERENCE_CHUNK = 32

#: the scene generator's kernel as a tunable pass (no pass class of its own: a module
#: constant): the same search as the per-pixel passes, default the 8x8 it was written for
RAYTRACE = Tunable("raytrace", "raytrace", {"wg_x": 8, "wg_y": 8}, local_candidates)


def _local_size(context: cl.Context, width: int, height: int, spp: int):
    """The tuned local size of pass ``raytrace`` (see clrecon.tune) for this frame shape."""
    info = FrameInfo(width, height, spp, 0.0, 0.0, 0.0, 0.0, 0.0)
    return local_size_of(tuned(context, RAYTRACE, info).config)


def _check_size(width: int, height: int, spp: int) -> None:
    for name, v in (("width", width), ("height", height), ("spp", spp)):
        if not isinstance(v, (int, np.integer)) or v < 1:
            raise ValueError(f"{name}: must be a positive integer, got {v!r}")


def _common_args(scene: Scene, width: int, height: int, ctx: cl.Context):
    cam = scene.camera(width, height)
    ro = cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR
    dobjs = cl.Buffer(ctx, ro, hostbuf=scene.pack())
    dbounds = cl.Buffer(ctx, ro, hostbuf=scene.screen_bounds(width, height))
    cx, cy = cam.centre
    bg = np.array([*scene.background, 0.0], np.float32)
    camera = [np.float32(cx), np.float32(cy), np.float32(cam.focal_px),
              np.float32(cam.focus_depth), np.float32(cam.lens_radius)]
    return cam, (dobjs, dbounds, np.int32(len(scene.objects))), camera, scene.light(), bg


#: how render_samples draws a pixel's samples: ``"lattice"``, the tracer's rank-1 lattice
#: with a random shift per pixel (stratified); ``"random"``, independent uniform samples
SAMPLERS = ("lattice", "random")


def check_sampler(sampler: str) -> str:
    """``sampler`` if it is one of :data:`SAMPLERS`, else a ``ValueError``."""
    if sampler not in SAMPLERS:
        raise ValueError(f"sampler: one of {SAMPLERS}, got {sampler!r}")
    return sampler


def render_samples(scene: Scene, width: int, height: int, spp: int, seed: int = 0,
                   device: DeviceSpec | Device = None, progress: Progress = None,
                   sampler: str = "lattice") -> SampleBuffer:
    """Trace ``spp`` stochastic samples per pixel; the buffer follows the convention exactly.

    ``sampler="lattice"`` (default): sample ``i`` of a pixel is point ``i`` of the tracer's
    rank-1 lattice shifted at random per pixel (``kernels/raytrace.cl``): stratified, as a
    production renderer's samples are. ``"random"``: every sample independent and uniform in
    pixel, lens and shutter (a renderer without stratification, whose halves of a pixel's
    samples are independent, and whose error falls exactly as ``1/spp``): sample ``k`` is
    the first lattice point of a render of its own seed, whose per-pixel shift is a hash of
    that seed, so the same tracer serves both."""
    check_sampler(sampler)
    _check_size(width, height, spp)
    if sampler == "random":
        return _render_random(scene, width, height, spp, seed, device, progress)
    dev = _get_device(device)
    ctx, q = dev.context, dev.queue
    cam, objs, camera, light, bg = _common_args(scene, width, height, ctx)
    n = width * height * spp
    hws = (height, width, spp)
    host = {"color": np.empty(hws + (3,), np.float32), "position": np.empty(hws + (2,), np.float32),
            "depth": np.empty(hws, np.float32), "lens": np.empty(hws + (2,), np.float32),
            "time": np.empty(hws, np.float32), "motion": np.empty(hws + (2,), np.float32)}
    # CPU devices write straight into the host arrays (no second copy of ~44 bytes/sample)
    zero_copy = bool(dev.device.type & cl.device_type.CPU)
    flags = cl.mem_flags.WRITE_ONLY | (cl.mem_flags.USE_HOST_PTR if zero_copy else 0)
    dbufs = {k: cl.Buffer(ctx, flags, hostbuf=a) if zero_copy else cl.Buffer(ctx, flags, a.nbytes)
             for k, a in host.items()}
    kernel = get_kernel(ctx, "raytrace", "raytrace_samples")
    rows = max(1, CHUNK_SAMPLES // (width * spp))
    local = _local_size(ctx, width, height, spp)
    for row0 in range(0, height, rows):
        count = min(rows, height - row0)
        kernel.set_args(*objs, np.int32(width), np.int32(height), np.int32(spp),
                        np.int32(row0), np.uint32(seed & 0xFFFFFFFF), *camera, light, bg,
                        *(dbufs[k] for k in host))
        gsize, lsize = local.for_range(width, count)
        cl.enqueue_nd_range_kernel(q, kernel, gsize, lsize)
        if progress is not None:
            q.finish()
            progress((row0 + count) * width * spp, n)
    for k, a in host.items():
        if zero_copy:  # mapping makes the device's writes visible in the host array
            mapped, _ = cl.enqueue_map_buffer(q, dbufs[k], cl.map_flags.READ, 0, a.shape, a.dtype)
            mapped.base.release(q)
        else:
            cl.enqueue_copy(q, a, dbufs[k])
    q.finish()
    return SampleBuffer(**host, coc_model=cam.coc_model)


def random_seed(seed: int, k: int) -> int:
    """The seed of sample ``k`` of ``render_samples(..., seed, sampler="random")``: a 32-bit
    hash of both (the tracer hashes it with the pixel into its lattice shifts)."""
    h = (int(seed) * 0x9E3779B1 + (int(k) + 1) * 0x85EBCA6B) & 0xFFFFFFFF
    h ^= h >> 15
    h = (h * 0x2C1B3C6D) & 0xFFFFFFFF
    return h ^ (h >> 12)


def _render_random(scene, width, height, spp, seed, device, progress) -> SampleBuffer:
    """``spp`` one-sample renders of seeds :func:`random_seed`, stacked per pixel."""
    parts = []
    for k in range(spp):
        parts.append(render_samples(scene, width, height, 1, seed=random_seed(seed, k),
                                    device=device).arrays())
        if progress is not None:
            progress((k + 1) * width * height, width * height * spp)
    fields = {name: np.concatenate([p[name] for p in parts], axis=2) for name in parts[0]}
    return SampleBuffer(**fields, coc_model=scene.camera(width, height).coc_model)


def render_reference(scene: Scene, width: int, height: int, spp: int | None = None,
                     seed: int = 1, device: DeviceSpec | Device = None,
                     progress: Progress = None) -> np.ndarray:
    """Converged image: lens, shutter and pixel area integrated with ``spp`` samples per pixel
    (box pixel filter; default ``scene.reference_spp``), accumulated in float64 on the host.

    ``device=None`` renders on :func:`~clrecon.core.device.trusted_device` (PoCL), not on the
    device ``CLRECON_DEVICE`` chooses: a reference is what a device's output is judged by,
    so it must not come from the device under test. Pass a device to render on it anyway
    (a test of that device's tracer)."""
    spp = scene.reference_spp if spp is None else spp
    _check_size(width, height, spp)
    dev = trusted_device() if device is None else _get_device(device)
    ctx, q = dev.context, dev.queue
    cam, objs, camera, light, bg = _common_args(scene, width, height, ctx)
    kernel = get_kernel(ctx, "raytrace", "raytrace_reference")
    dout = cl.Buffer(ctx, cl.mem_flags.WRITE_ONLY, size=width * height * 12)
    acc = np.zeros((height, width, 3), np.float64)
    part = np.empty((height, width, 3), np.float32)
    gsize, lsize = _local_size(ctx, width, height, spp).for_range(width, height)
    for first in range(0, spp, REFERENCE_CHUNK):
        count = min(REFERENCE_CHUNK, spp - first)
        kernel.set_args(*objs, np.int32(width), np.int32(height), np.uint32(first),
                        np.uint32(count), np.uint32(seed & 0xFFFFFFFF), *camera, light, bg, dout)
        cl.enqueue_nd_range_kernel(q, kernel, gsize, lsize)
        cl.enqueue_copy(q, part, dout)
        acc += part.astype(np.float64) * count
        if progress is not None:
            progress(first + count, spp)
    return (acc / spp).astype(np.float32)


def render_pinhole(scene: Scene, width: int, height: int,
                   device: DeviceSpec | Device = None) -> SampleBuffer:
    """The pinhole frame of ``scene`` (synthesis input): S = 1, every sample at its pixel
    centre with lens (0, 0) and time 0.5; depth, motion and the CoC model as
    :func:`render_samples` records them."""
    _check_size(width, height, 1)
    dev = _get_device(device)
    ctx, q = dev.context, dev.queue
    cam, objs, camera, light, bg = _common_args(scene, width, height, ctx)
    hws = (height, width, 1)
    host = {"color": np.empty(hws + (3,), np.float32), "position": np.empty(hws + (2,), np.float32),
            "depth": np.empty(hws, np.float32), "lens": np.empty(hws + (2,), np.float32),
            "time": np.empty(hws, np.float32), "motion": np.empty(hws + (2,), np.float32)}
    dbufs = {k: cl.Buffer(ctx, cl.mem_flags.WRITE_ONLY, a.nbytes) for k, a in host.items()}
    kernel = get_kernel(ctx, "raytrace_pinhole", "raytrace_pinhole")
    kernel.set_args(*objs, np.int32(width), np.int32(height), np.int32(0), *camera, light, bg,
                    *(dbufs[k] for k in host))
    gsize, lsize = _local_size(ctx, width, height, 1).for_range(width, height)
    cl.enqueue_nd_range_kernel(q, kernel, gsize, lsize)
    for k, a in host.items():
        cl.enqueue_copy(q, a, dbufs[k])
    q.finish()
    return SampleBuffer(**host, coc_model=cam.coc_model)
