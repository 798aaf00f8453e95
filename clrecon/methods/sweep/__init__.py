"""Method ``sweep``: local reconstruction by a front-to-back sweep (Shirley et al. 2011).

Plans (knobs in brackets):

* sorted sweep [``scales=2`` (Appendix A, 1x1/5x5 blended) or ``4`` (Appendix B),
  ``exponent``], by one of three plans, same image (``sort``):

  - ``"block"`` (default on CPUs): ``sweep_block`` alone [``group``]: one work-item per 2x2
    blocks of 4x4 pixels (one block where local memory does not hold two a side)
    radix-sorts their shared window once, splits it into each block's window and sweeps it
    in float16 lanes;
  - ``"tile"`` (default elsewhere): ``sweep_prepare`` -> ``sweep_resolve`` [``tile``,
    ``tile_merge="auto"|"serial"|"bitonic"``]: one sort per tile in local memory, then every
    pixel walks the tile's list;
  - ``"pixel"``: ``sweep_prepare`` -> ``sweep_resolve``: each pixel merges its window's
    per-pixel sorted runs (the straightforward version, for comparison);
* ``dof_layers=True``: the sort-free three-layer depth-of-field variant,
  ``sweep_layer_sums`` -> ``sweep_layer_resolve`` (defocus only: motion is not smoothed).

``diameter_scale`` scales the denoising diameter ``max(2|coc|, |motion|)``;
``smooth_motion`` (default: whether the frame has motion) adds the motion term.
The front-to-back order compares depths to 12 significant bits (``kernels/sweep_order.h``:
depths within a relative 2^-11 of each other are ties, which keep window order): it halves
the block sort's digit passes (``sweep_block`` 0.88-0.92x at deep 1280x720 8 spp, PoCL) and
moved no built-in scene's PSNR at 512x512 8 spp by more than 0.001 dB.
``exact_depth_order=True`` orders by the exact depths (the paper).

Model only what the frame requires: when the frame inspection says no sample's denoising
diameter exceeds the narrow block (1 px for two scales and the three layers, 3 px for four
scales), every sample falls in the narrow scale and Appendix A/B's weights reduce exactly to
the per-pixel average, so the plan is the one ``box`` pass. ``specialize=False``, or an
explicit ``sort``/``tile``/``tile_merge``/``group``, runs the sweep (the tests check both
agree).
"""
from __future__ import annotations

import math

import numpy as np
import pyopencl as cl

from clrecon.core.device import describe
from clrecon.core.knobs import (
    INT32_MAX,
    KnobTypeError,
    check_bool,
    check_choice,
    check_float,
    check_int,
)
from clrecon.core.pipeline import Pipeline, register
from clrecon.core.plan import Plan, Step, coc_bound, motion_bound, shape_bounds
from clrecon.methods.box import Box, box_plan
from clrecon.methods.sweep.block import SweepBlock, block_local_bytes
from clrecon.methods.sweep.layers import SweepLayerResolve, SweepLayerSums
from clrecon.methods.sweep.prepare import SweepPrepare
from clrecon.methods.sweep.reference import DEPTH_KEY_SHIFT
from clrecon.methods.sweep.resolve import (
    TILE_MERGES,
    SweepResolve,
    make_resolve,
    tile_local_bytes,
    tile_samples_fit,
)
from clrecon.tune.local import local_size_of
from clrecon.tune.runtime import default_config, fit_config, tuned
from clrecon.tune.tunable import DEFAULT_LOCAL, GPU_LOCAL

#: the plans of ``sort``: every one, whatever the device (``None`` picks one)
SORTS = ("block", "tile", "pixel")


def fit_tile(dev: cl.Device, scales: int, spp: int, hi: int) -> int:
    """The largest tile <= ``hi`` the device takes for ``sort="tile"``: ``tile x tile``
    work-items within its max work-group size, the tile's samples and sort in its local
    memory (:func:`~clrecon.methods.sweep.resolve.tile_local_bytes`); 0 when none does."""
    side = min(int(hi), math.isqrt(dev.max_work_group_size))
    return _largest(lambda t: tile_samples_fit(t, scales, spp)
                    and tile_local_bytes(t, scales, spp) <= dev.local_mem_size, side)


def fit_group(dev: cl.Device, scales: int, spp: int, hi: int) -> int:
    """The largest group <= ``hi`` of 4x4 blocks the device takes for ``sort="block"``
    (work-items within its max work-group size, their windows in its local memory:
    :func:`~clrecon.methods.sweep.block.block_local_bytes`); 0 when none does or spp > 255."""
    if spp > 255:
        return 0
    return _largest(lambda g: block_local_bytes(scales, spp, g) <= dev.local_mem_size,
                    min(int(hi), dev.max_work_group_size))


def default_sort(context, scales: int, spp: int) -> str:
    """``"block"`` on CPUs (measured fastest there) where it fits, else ``"tile"`` where
    a tile fits the device's local memory, else ``"pixel"`` (no local memory)."""
    dev = context.devices[0]
    if dev.type & cl.device_type.CPU and fit_group(dev, scales, spp, 1):
        return "block"
    return "tile" if fit_tile(dev, scales, spp, dev.max_work_group_size) else "pixel"


def pixel_config(dev: cl.Device) -> dict:
    """``sort="pixel"`` with the per-pixel passes' default local size for the device."""
    local = GPU_LOCAL if dev.type & cl.device_type.GPU else DEFAULT_LOCAL
    return {"sort": "pixel"} | fit_config(local, dev.max_work_group_size)


#: largest ``diameter_scale``: the scaled diameters stay far inside the float32 range
MAX_DIAMETER_SCALE = 1e6
#: float32 weights must stay at or above the smallest normal float32, 2^-126
_WEIGHT_EXP2_MIN = 126
#: a pixel's own samples get a weight of at least 1 / (K * spp): K = 25 (the 5x5 box of
#: two scales) or 49 (the 7x7 box of four scales)
_WEIGHT_BOX = {2: 25, 4: 49}


def max_exponent(scales: int, spp: int) -> float:
    """The largest ``exponent`` whose weights stay finite for ``scales`` at ``spp``.

    A pixel's own samples get a weight of at least ``w = 1 / (K spp)`` (``K`` = 25 with two
    scales, 49 with four: the widest box), so ``w ** exponent`` is a normal float32
    (``>= 2^-126``) for ``exponent <= 126 / log2(K spp)``: 16.5 at 8 spp with two scales
    (14.6 with four), 12.8 (11.6) at 32 spp. Beyond it every weight of a frame whose samples
    are all in the widest scale flushes to zero on a device without float32 denormals, and
    the image is NaN (measured on PoCL, which keeps denormals: 0 NaN pixels at 1.02x this
    bound, all NaN beyond ``149 / log2(K spp)``, the denormal floor).
    """
    k = _WEIGHT_BOX[scales] * max(int(spp), 1)
    return math.floor(100 * _WEIGHT_EXP2_MIN / math.log2(k)) / 100


def _largest(fits, hi: int) -> int:
    """The largest n in [1, hi] with ``fits(n)`` (``fits`` monotone), 0 when none."""
    best, lo = 0, 1
    while lo <= hi:
        mid = (lo + hi) // 2
        if fits(mid):
            best, lo = mid, mid + 1
        else:
            hi = mid - 1
    return best


def _fitted(name: str, value, hi: int, why: str, advice: str) -> int:
    """``value`` of the knob ``name`` checked against ``hi``, the largest that fits the
    device (``why`` says for what); none fitting is a ``ValueError`` ending in ``advice``."""
    if hi == 0:
        check_int(name, value, 1, INT32_MAX)
        raise ValueError(f"{name}: no {name} fits {why}{advice}")
    return check_int(name, value, 1, hi, what=why)


def check_knobs(context, info, scales, dof_layers, exponent, smooth_motion, diameter_scale,
                sort, tile, tile_merge, group, specialize) -> tuple:
    """Every knob of :class:`SweepPipeline` checked (type and range; see
    :mod:`clrecon.core.knobs`), in the signature's order."""
    if isinstance(scales, (bool, np.bool_)) or not isinstance(scales, (int, np.integer)):
        raise KnobTypeError(f"scales: must be 2 or 4, got {scales!r} ({type(scales).__name__})")
    if scales not in (2, 4):
        raise ValueError(f"scales: must be 2 or 4, got {scales!r}")
    scales = int(scales)
    dof_layers = check_bool("dof_layers", dof_layers)
    e_max = max_exponent(scales, info.spp)
    exponent = check_float("exponent", exponent, 0.0, e_max, lo_open=True,
                           what=f"for {scales} scales at {info.spp} spp (float32 weights "
                                f">= 1/({_WEIGHT_BOX[scales]} spp) raised to it must stay "
                                f">= 2^-126)")
    smooth_motion = check_bool("smooth_motion", smooth_motion, none_ok=True)
    diameter_scale = check_float("diameter_scale", diameter_scale, 0.0, MAX_DIAMETER_SCALE)
    if isinstance(sort, str) and sort not in SORTS:  # every plan, and what None picks
        raise ValueError(f"sort: must be one of {', '.join(map(repr, SORTS))} (or None: "
                         f"'block' on CPUs where it fits, else 'tile'), got {sort!r}")
    sort = check_choice("sort", sort, SORTS, none_ok=True)
    tile_merge = check_choice("tile_merge", tile_merge, TILE_MERGES, none_ok=True)
    specialize = check_bool("specialize", specialize)
    dev = context.devices[0]
    given = {k: v for k, v in (("sort", sort), ("tile", tile), ("tile_merge", tile_merge))
             if v is not None}
    plan = given.get("sort", "tile" if given else default_sort(context, scales, info.spp))
    # a tile (group) the plan does not use is checked for its type only
    if tile is not None and plan != "tile":
        tile = check_int("tile", tile, 1, INT32_MAX, what=f"(unused by sort={plan!r})")
    if group is not None and plan != "block":
        group = check_int("group", group, 1, INT32_MAX, what=f"(unused by sort={plan!r})")
    limits = (f"local memory {dev.local_mem_size} bytes, max work-group size "
              f"{dev.max_work_group_size})")
    if tile is not None and plan == "tile":
        tile = _fitted("tile", tile, fit_tile(dev, scales, info.spp, dev.max_work_group_size),
                       f"for sort='tile' with {scales} scales at {info.spp} spp on this "
                       f"device ({limits}", "; use sort='pixel'")
    if group is not None and plan == "block":
        group = _fitted("group", group, fit_group(dev, scales, info.spp,
                                                  dev.max_work_group_size),
                        f"for sort='block' with {scales} scales at {info.spp} spp on this "
                        f"device (4x4 blocks per work-group; {limits}",
                        ("; the block sort takes at most 255 spp" if info.spp > 255 else "")
                        + ": use sort='tile' or 'pixel'")
    return (scales, dof_layers, exponent, smooth_motion, diameter_scale, sort, tile,
            tile_merge, group, specialize)


@register
class SweepPipeline(Pipeline):
    name = "sweep"
    #: Shirley's weights come from each sample's blur alone (not the sample count)
    halves_mean = True

    def __init__(self, context, info, scales: int = 2, dof_layers: bool = False,
                 exponent: float = 1.0, smooth_motion: bool | None = None,
                 diameter_scale: float = 1.0, sort: str | None = None, tile: int | None = None,
                 tile_merge: str | None = None, group: int | None = None,
                 specialize: bool = True, exact_depth_order: bool = False):
        super().__init__(context, info)
        # the order's depth precision (kernels/sweep_order.h): 12 significant bits, or exact
        self.exact_depth_order = check_bool("exact_depth_order", exact_depth_order)
        shift = 0 if self.exact_depth_order else DEPTH_KEY_SHIFT
        scales, dof_layers, exponent, smooth_motion, diameter_scale, sort, tile, tile_merge, \
            group, specialize = check_knobs(context, info, scales, dof_layers, exponent,
                                            smooth_motion, diameter_scale, sort, tile,
                                            tile_merge, group, specialize)
        self.scales, self.dof_layers, self.exponent = int(scales), bool(dof_layers), exponent
        self.smooth_motion = info.has_motion if smooth_motion is None else bool(smooth_motion)
        self.diameter_scale = float(diameter_scale)
        spp = info.spp
        npix = info.width * info.height
        dev = context.devices[0]
        self.tuning: dict[str, str] = {}
        self.block = self.box = None

        def local(tunable):
            found = tuned(context, tunable, info)
            self.tuning[tunable.name] = found.source
            return local_size_of(found.config)

        # every sample's diameter within the narrow block: only the 1x1 box ever gets weight,
        # every weight is 1/spp, and the sweep is the box filter
        motion = info.max_abs_motion if self.smooth_motion and not self.dof_layers else 0.0
        self.max_diameter = self.diameter_scale * max(2.0 * info.max_abs_coc, motion)
        narrow = 3.0 if self.scales == 4 and not self.dof_layers else 1.0
        explicit = (sort, tile, tile_merge, group) != (None,) * 4
        self.box_equivalent = bool(specialize) and not explicit and self.max_diameter <= narrow
        # what the plan rests on: the motion term compiled out of a static frame, and the
        # box plan chosen because every diameter is within the narrow block
        bounds = []
        if smooth_motion is None and not self.smooth_motion and not self.dof_layers:
            bounds.append(motion_bound(0.0, "planned for a static frame: no motion term"))
        if self.box_equivalent:
            self.box = Box(context, local(Box.TUNABLE))
            if self.diameter_scale > 0:
                bounds.append(coc_bound(narrow / (2 * self.diameter_scale),
                                        f"box plan: every diameter <= {narrow:g} px"))
                if self.smooth_motion and not self.dof_layers:
                    bounds.append(motion_bound(narrow / self.diameter_scale,
                                               f"box plan: every diameter <= {narrow:g} px"))
            self.set_plan(box_plan("sweep", self.box, info, bounds))
            return
        bounds = shape_bounds(info, "kernels compiled for this spp") + tuple(bounds)
        if self.dof_layers:
            self.sums_pass = SweepLayerSums(context, spp, local(SweepLayerSums.TUNABLE))
            self.combine = SweepLayerResolve(context, spp, local(SweepLayerResolve.TUNABLE))
            ds = self.diameter_scale

            def sums(queue, f, wait):
                return [("sweep_layer_sums",
                         self.sums_pass(queue, f.samples, ds, f.buffers["sums"], wait))]

            def resolve(queue, f, wait):
                return [("sweep_layer_resolve", self.combine(
                    queue, f.buffers["sums"], f.width, f.height, f.buffers["out"], wait))]

            self.set_plan(Plan("sweep", "dof_layers", ("color", "depth"), (
                Step("sweep_layer_sums", ("color", "depth"), ("sums",), sums),
                Step("sweep_layer_resolve", ("sums",), ("out",), resolve)),
                {"sums": npix * 3 * 16}, bounds))
            return
        fields = ("color", "position", "depth", "motion")
        given = {k: v for k, v in (("sort", sort), ("tile", tile), ("tile_merge", tile_merge))
                 if v is not None}
        if given.get("sort", "tile" if given else default_sort(context, self.scales, spp)) \
                == "block":
            if group is None:
                found = tuned(context, SweepBlock.TUNABLE, info)
                want = (found.config or default_config(SweepBlock.TUNABLE,
                                                       describe(dev)))["group"]
                # a group tuned at fewer spp may not fit this frame's windows: the largest
                # that does (none: SweepBlock names what one block needs and the limit)
                group = want if found.source in ("env", "override") else \
                    fit_group(dev, self.scales, spp, want) or 1
                self.tuning["sweep_block"] = found.source
            else:
                self.tuning["sweep_block"] = "api"
            self.block = SweepBlock(context, spp, self.scales, exponent, self.smooth_motion,
                                    group, depth_key_shift=shift)

            def block(queue, f, wait):
                return [("sweep_block", self.block(queue, f.samples, self.diameter_scale,
                                                   f.buffers["out"], wait))]

            reads = ("color", "depth", "motion")  # sweep_block needs no positions
            self.sample_views = True  # it reads a view of a frame in place (strided())
            self.set_plan(Plan("sweep", "block", reads,
                               (Step("sweep_block", reads, ("out",), block),), {}, bounds))
            return
        self.prepare = SweepPrepare(context, spp, self.smooth_motion,
                                    local(SweepPrepare.TUNABLE), depth_key_shift=shift)
        if given:  # the caller's knobs win over tuning; the rest from the pass default
            config = default_config(SweepResolve.TUNABLE, describe(dev)) | given
            if config["sort"] == "pixel":
                config = pixel_config(dev)
            self.tuning["sweep_resolve"] = "api"
        else:
            found = tuned(context, SweepResolve.TUNABLE, info)
            config = found.config or default_config(SweepResolve.TUNABLE, describe(dev))
            self.tuning["sweep_resolve"] = found.source
        if config["sort"] == "tile" and "tile" not in given and \
                self.tuning["sweep_resolve"] not in ("env", "override"):
            # a tile tuned (or defaulted) at fewer spp may not fit this frame's samples in
            # local memory: the largest that does, else the pixel sort (none needed)
            fitted = fit_tile(dev, self.scales, spp, int(config["tile"]))
            if fitted:
                config = config | {"tile": fitted}
            elif "sort" not in given and "tile_merge" not in given:
                config = pixel_config(dev)
        self.resolve = make_resolve(context, spp, self.scales, exponent, config)

        def prepare(queue, f, wait):
            b = f.buffers
            return [("sweep_prepare", self.prepare(queue, f.samples, self.diameter_scale,
                                                   b["keys"], b["colors"], wait))]

        def resolve_(queue, f, wait):
            b = f.buffers
            return [("sweep_resolve", self.resolve(queue, b["keys"], b["colors"], f.width,
                                                   f.height, b["out"], wait))]

        self.set_plan(Plan("sweep", self.resolve.sort, fields, (
            Step("sweep_prepare", fields, ("keys", "colors"), prepare),
            Step("sweep_resolve", ("keys", "colors"), ("out",), resolve_)),
            {"keys": npix * spp * 16, "colors": npix * spp * 16}, bounds))

    def describe(self) -> dict:
        d = {"method": "sweep", "plan": self.plan.name, "diameter_scale": self.diameter_scale,
             "tuning": self.tuning, "max_diameter_px": round(self.max_diameter, 3),
             "bounds": [b.describe() for b in self.plan.bounds]}
        if self.box is not None:
            return d | {"mode": "box (every denoising diameter within the narrow block)",
                        "requested": "dof_layers" if self.dof_layers else f"{self.scales}-scale",
                        "sort": None}
        if self.dof_layers:
            return d | {"mode": "dof_layers", "smooth_motion": False}
        d |= {"mode": f"{self.scales}-scale", "scales": self.scales, "exponent": self.exponent,
              "smooth_motion": self.smooth_motion, "exact_depth_order": self.exact_depth_order}
        if self.block is not None:
            return d | {"sort": "block", "group": self.block.group}
        return d | {"sort": self.resolve.sort, "tile": self.resolve.tile,
                    "tile_merge": self.resolve.tile_merge}
