"""The entry points: plan a method for frames like one (:func:`make_pipeline`), and reconstruct
a host frame (:func:`run`, :func:`reconstruct`).

This module sits above the methods: it imports every one of them (each registers itself in
:data:`clrecon.core.pipeline.METHODS`), and the safeguard that wraps any of them, so that the
core (:mod:`clrecon.core`) never imports a method.
"""
from __future__ import annotations

import inspect
import os
import threading
import time
from dataclasses import dataclass, field

import numpy as np
import pyopencl as cl

from clrecon.core.device import Device, DeviceSpec, get_device
from clrecon.core.knobs import check_bool
from clrecon.core.pipeline import METHODS, DeviceSamples, Pipeline, make_method, reusing
from clrecon.core.plan import BOX_PLAN
from clrecon.core.samples import FIELDS, FrameInfo, SampleBuffer
from clrecon.methods import box, layered, splat, sweep  # noqa: F401  (they register themselves)
from clrecon.methods.guided import check_radius
from clrecon.methods.hybrid import Hybrid
from clrecon.methods.nlm import check_radius as check_nlm_radius
from clrecon.methods.nlm import check_scales as check_nlm_scales
from clrecon.methods.safeguard import Safeguarded
from clrecon.tune.runtime import override_key

__all__ = ["METHODS", "PIPELINE_KNOBS", "Reconstruction", "clear_sessions", "make_pipeline",
           "method_knobs", "reconstruct", "run"]


def make_pipeline(method: str, context: cl.Context, info: FrameInfo, grow: bool = False,
                  safeguard: bool | None = None, estimate_error: bool = False,
                  guided: int = 0, guide_blend: bool = True, nlm: int = 0,
                  nlm_scales: int = 1, hybrid: bool = False, independent_samples: bool = False,
                  **knobs) -> Pipeline:
    """Plan ``method`` for frames like ``info`` on ``context``.

    ``info`` may describe a family rather than one frame: a renderer that knows its largest
    CoC and motion plans once for them (``dataclasses.replace(info, max_abs_coc=...)``).
    ``grow=True`` re-plans (kernels come from the build cache) when a frame falls outside the
    bounds instead of refusing it. Unknown knobs raise ``TypeError``.

    ``safeguard`` (default: on for every method but plain ``box`` at 2 spp or more) blends the
    method's image toward box wherever its estimated bias dominates
    (:mod:`clrecon.methods.safeguard`);
    ``safeguard=False`` is the papers' method alone. ``estimate_error=True`` also computes the
    per-pixel squared-error estimate, the temporary ``"error"`` (needs 2 spp or more).
    ``guided=R`` (1..8; 0: off) refines each half's image of the method by a local linear
    regression of that half's box image on it over (2R+1)^2 windows
    (:mod:`clrecon.methods.guided`) before the safeguard sees it; with ``safeguard=False``
    the image is the refined halves' mean. It needs 2 spp or more and a method other than
    box. ``guide_blend`` (with ``guided``) then blends each refined half toward the method's
    own image wherever the safeguard's estimator, with the refinement in box's place, says
    the method's is the better (its blurred regions, where its image is nearly noise-free).
    ``nlm=R`` (1..10; 0: off) then averages each half's image further over (2R+1)^2 pixels
    with dual-buffer non-local means, each half weighted by the other
    (:mod:`clrecon.methods.nlm`); it needs 2 spp or more. With ``box`` it filters box's own
    halves (the samples' means: Rousselle et al. 2012's dual-buffer filter, consistent
    through the safeguard's blend toward box). ``nlm_scales=S`` (1..6) also
    filters each half's low band at S - 1 coarser scales (each half the last's resolution).
    ``hybrid=True`` (with ``nlm``, not with box or ``safeguard=False``) runs the method's
    safeguarded chain and box's own halves through the same filter, and blends the two per
    pixel by their error estimates (:mod:`clrecon.methods.hybrid`; below 8 spp the chain
    alone); it always estimates its error. ``independent_samples=True`` is the renderer's
    word that a pixel's samples are independent (no stratification): the safeguard then
    takes the halves' variances as they are (no measured convergence) and shrinks its
    untested 7x7 bias mean by its significance (independent samples lost up to 4.3 dB to
    that mean's noise, stratified ones would lose up to 0.3 dB to the shrinkage at 64 spp:
    ``docs/measurements/sampler-random-pocl.md``); a pipeline without them ignores it.
    """
    safeguard = check_bool("safeguard", safeguard, none_ok=True)
    estimate_error = check_bool("estimate_error", estimate_error)
    guided = check_radius(guided)
    nlm = check_nlm_radius(nlm)
    nlm_scales = check_nlm_scales(nlm_scales)
    if nlm_scales > 1 and not nlm:
        raise ValueError(f"nlm_scales: {nlm_scales} scales of the non-local means need nlm=R "
                         f"(a search radius 1..10)")
    guide_blend = check_bool("guide_blend", guide_blend)
    hybrid = check_bool("hybrid", hybrid)
    independent_samples = check_bool("independent_samples", independent_samples)
    if hybrid:
        for bad, why in ((method == "box", "box's own chain is one of its members; pick a "
                          "method (sweep, layered or splat)"),
                         (not nlm, "needs nlm=R (box's halves are filtered by the chain's "
                          "non-local means)"),
                         (safeguard is False, "blends two safeguarded images; "
                          "safeguard=False is not one"),
                         (info.spp < 2, f"needs >= 2 samples per pixel (two independent "
                          f"halves), the frame has {info.spp}")):
            if bad:
                raise ValueError(f"hybrid: {why}")
        return _hybrid(method, context, info, grow, guided, guide_blend, nlm, nlm_scales,
                       knobs, independent_samples)
    inner = make_method(method, context, info, **knobs)
    if safeguard is None:
        safeguard = (method != "box" or bool(nlm)) and info.spp >= 2
    for name, on, other in (("guided", guided, "box has no image of its own to guide the "
                             "regression; pick a method (sweep, layered or splat)"),
                            ("safeguard", safeguard and not nlm, "box is the unbiased "
                             "estimate the safeguard blends toward; it has nothing to "
                             "safeguard (but its halves filtered by nlm=R)")):
        if on and method == "box":
            raise ValueError(f"{name}: {other}")
    # each needs two independent halves of every pixel's samples
    for name, on, hint in (("guided", guided, ""), ("nlm", nlm, ""), ("safeguard", safeguard,
                                                    "; pass safeguard=False"),
                           ("estimate_error", estimate_error, "")):
        if on and info.spp < 2:
            raise ValueError(f"{name}: needs >= 2 samples per pixel (two independent halves), "
                             f"the frame has {info.spp}{hint}")
    # a frame without blur is planned as box, with nothing to blend: the method's own
    # pipeline, unless it may grow into a blurred frame (the wrapper re-plans both)
    sg = estimate_error or guided or nlm or (safeguard and (grow or inner.plan.name != BOX_PLAN))
    if sg:
        pipe = Safeguarded(context, info, method, knobs, blend=bool(safeguard), full=inner,
                           guided=guided, guide_blend=guide_blend, nlm=nlm,
                           nlm_scales=nlm_scales, independent_samples=independent_samples)
    else:  # (independent_samples describes the frame: nothing to change without halves)
        pipe = inner
    pipe.grow, pipe.knobs = bool(grow), dict(knobs)
    return pipe


def _hybrid(method, context, info, grow, guided, guide_blend, nlm, nlm_scales, knobs,
            independent_samples=False):
    """The method's safeguarded chain and box's, blended by their error estimates."""
    def chain(at):
        return make_pipeline(method, context, at, guided=guided, guide_blend=guide_blend,
                             nlm=nlm, nlm_scales=nlm_scales, estimate_error=True,
                             independent_samples=independent_samples, **knobs)

    def boxes(at):
        return make_pipeline("box", context, at, nlm=nlm, nlm_scales=nlm_scales,
                             estimate_error=True, independent_samples=independent_samples)

    pipe = Hybrid(context, info, chain, boxes)
    pipe.grow, pipe.knobs = bool(grow), dict(knobs)
    return pipe


#: knobs every method takes through :func:`make_pipeline` (beside its class's own)
PIPELINE_KNOBS = ("safeguard", "estimate_error", "guided", "guide_blend", "nlm",
                  "nlm_scales", "hybrid", "independent_samples")


def method_knobs(method: str) -> set[str]:
    """The knob names ``method`` takes (its class's and :data:`PIPELINE_KNOBS`)."""
    cls = METHODS[method]
    return (set(inspect.signature(cls.__init__).parameters) - {"self", "context", "info"}
            | set(PIPELINE_KNOBS))


@dataclass
class Reconstruction:
    """An image with what produced it and how long each part took.

    ``pass_ms`` are device times of the plan's passes; ``upload_ms`` the host-to-device copy
    (wall); ``inspect_ms`` the device validation and inspection (wall: it reads a few bytes
    back); ``plan_ms`` planning (wall, 0 when the cached plan held; the first call of a
    process for a plan also builds its programs here); ``wall_ms`` the wall time of the
    whole call, planning included; ``frame_ms`` the same without planning: what the call
    costs once its plan is built (upload, inspection, the passes, read-back).
    """

    image: np.ndarray
    method: dict
    device: str
    pass_ms: dict[str, float] = field(default_factory=dict)
    upload_ms: float = 0.0
    wall_ms: float = 0.0
    inspect_ms: float = 0.0
    plan_ms: float = 0.0
    #: with ``estimate_error=True``: (H, W) float32 estimated squared error of ``image``
    error: np.ndarray | None = None

    @property
    def device_ms(self) -> float:
        return float(sum(self.pass_ms.values()))

    @property
    def frame_ms(self) -> float:
        return self.wall_ms - self.plan_ms


@dataclass(eq=False)
class _Session:
    """What :func:`run` keeps between frames of one method on one device."""

    pipe: Pipeline
    samples: DeviceSamples | None  # None: the last frame was read in place
    out: cl.Buffer


#: (context, method, knobs) -> session, most recent last; at most _MAX_SESSIONS
_sessions: dict[tuple, _Session] = {}
_MAX_SESSIONS = 4
_sessions_lock = threading.Lock()


def clear_sessions() -> None:
    """Release the device buffers :func:`run` keeps for the next frame."""
    _sessions.clear()


def _knob_key(knobs: dict) -> tuple:
    try:
        key = tuple(sorted(knobs.items()))
        hash(key)
        return key
    except TypeError:  # an unhashable knob value: no reuse, still correct
        return (object(),)


def run(buf: SampleBuffer, method: str = "box", device: DeviceSpec | Device = None,
        allow_negative: bool = False, estimate_error: bool = False,
        **knobs) -> Reconstruction:
    """Upload, validate and inspect on the device, plan, reconstruct and read back.

    On a CPU device the passes read ``buf``'s arrays in place (``DeviceSamples.wrap``: no
    copy; ``upload_ms`` is then ~0); elsewhere they are copied. Frame after frame of one
    method and device, the device buffers are reused and the plan
    too while the frame's description is unchanged; any other frame is planned afresh
    (kernels come from the build cache), so the image is always that of a plan made for this
    frame. Invalid samples raise the ``ValueError`` of
    :meth:`SampleBuffer.validate(allow_negative) <SampleBuffer.validate>`.

    With ``allow_negative`` negative radiance is accepted and every method gives the linear
    combination ``f(c+) - f(c-)`` of its images of the positive and negative parts: box,
    sweep and layered are linear in the colour (one run); a pipeline whose class sets
    ``color_linear = False`` (splat: its composite clamps each layer's colour at 0 against
    the integration's ringing) runs twice on a frame with negative colours, once per part,
    and the image is the difference (``pass_ms`` sums both runs).

    ``estimate_error=True`` also returns ``error``: the (H, W) float32 estimate of the
    squared error of ``image`` (linear radiance, mean over RGB) from independent halves of
    the samples (:mod:`clrecon.methods.safeguard`), for every method, box included.
    """
    estimate_error = check_bool("estimate_error", estimate_error)
    if not isinstance(buf, SampleBuffer):
        raise TypeError(f"buf must be a SampleBuffer, got {type(buf).__name__}")
    buf.check_layout()
    dev = get_device(device)
    t0 = time.perf_counter()
    # tuning overrides (the environment's, override_tuning's) decide launch configurations
    tune_env = tuple(sorted((k, v) for k, v in os.environ.items()
                            if k.startswith("CLRECON_TUNE_")))
    key = (dev.context.int_ptr, method, _knob_key(knobs), estimate_error, tune_env,
           override_key())
    with _sessions_lock:  # batch runs one thread per device
        sess = _sessions.pop(key, None)
    # a CPU device reads the host arrays in place (no copy, no second copy of the frame in
    # memory); a frame whose colours run() rewrites (negative parts) is copied
    negative = allow_negative and bool(buf.color.min() < 0)
    in_place = dev.info.device_type == "CPU" and not negative
    if in_place:
        samples = DeviceSamples.wrap(dev.context, buf, FIELDS)
    else:
        samples = DeviceSamples.upload(dev.queue, buf, FIELDS,
                                       into=None if sess is None else sess.samples)
    t1 = time.perf_counter()
    info = samples.inspect(dev.queue, allow_negative=allow_negative)
    t2 = time.perf_counter()
    spare = ()
    if sess is not None and sess.pipe.info == info:
        pipe, plan_ms = sess.pipe, 0.0
    else:
        pipe = make_pipeline(method, dev.context, info, estimate_error=estimate_error, **knobs)
        plan_ms = (time.perf_counter() - t2) * 1e3
        # the previous plan's buffers, for the new plan's temporaries of the same sizes
        spare = sess.pipe.release_buffers() if sess is not None else ()
    nbytes = buf.height * buf.width * 12
    out = sess.out if sess is not None and sess.out.size == nbytes else cl.Buffer(
        dev.context, cl.mem_flags.READ_WRITE, size=nbytes)
    split = negative and not getattr(pipe, "color_linear", True)
    if split:  # the positive part first, then the negative one into the same buffer
        cl.enqueue_copy(dev.queue, samples["color"], np.maximum(buf.color, 0),
                        is_blocking=True)
    with reusing(spare):  # a new plan allocates its temporaries on its first call
        ev = pipe(dev.queue, samples, out)
    image = np.empty((buf.height, buf.width, 3), np.float32)
    cl.enqueue_copy(dev.queue, image, out, wait_for=[ev])
    error = _read_error(dev.queue, pipe, image.shape[:2]) if estimate_error else None
    pass_ms = pipe.pass_times_ms()
    if split:
        cl.enqueue_copy(dev.queue, samples["color"], np.maximum(-buf.color, 0),
                        is_blocking=True)
        ev = pipe(dev.queue, samples, out)
        negative = np.empty_like(image)
        cl.enqueue_copy(dev.queue, negative, out, wait_for=[ev])
        image -= negative
        if error is not None:  # the parts' errors add (independent estimates)
            error += _read_error(dev.queue, pipe, image.shape[:2])
        for name, ms in pipe.pass_times_ms().items():
            pass_ms[name] = pass_ms.get(name, 0.0) + ms
    t3 = time.perf_counter()
    with _sessions_lock:  # buffers over the caller's arrays are not kept
        _sessions[key] = _Session(pipe, None if in_place else samples, out)
        while len(_sessions) > _MAX_SESSIONS:
            _sessions.pop(next(iter(_sessions)))
    return Reconstruction(
        image=image,
        method=pipe.describe(),
        device=dev.info.label,
        pass_ms=pass_ms,
        upload_ms=(t1 - t0) * 1e3,
        wall_ms=(t3 - t0) * 1e3,
        inspect_ms=(t2 - t1) * 1e3,
        plan_ms=plan_ms,
        error=error,
    )


def _read_error(queue, pipe: Pipeline, shape) -> np.ndarray:
    err = np.empty(shape, np.float32)
    cl.enqueue_copy(queue, err, pipe.buffers["error"])
    return err


def reconstruct(buf: SampleBuffer, method: str = "box", device: DeviceSpec | Device = None,
                allow_negative: bool = False, **knobs) -> np.ndarray:
    """Reconstruct a frame: the (H, W, 3) float32 linear image.

    Parameters
    ----------
    buf : SampleBuffer
        The frame's samples (validated here).
    method : str
        ``"box"`` (more as methods land: see ``clrecon.core.pipeline.METHODS``).
    device : int, str, Device or None
        See :func:`clrecon.core.device.get_device`.
    allow_negative : bool
        Accept negative colours (validation refuses them by default); every method then
        gives ``f(c+) - f(c-)``, linear in the colour (see :func:`run`).
    **knobs
        Method-specific settings; unknown names raise ``TypeError``.
    """
    return run(buf, method, device, allow_negative, **knobs).image
