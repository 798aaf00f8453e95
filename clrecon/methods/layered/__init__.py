"""Method ``layered``: Practical Layered Reconstruction (Hasselgren, Munkberg, Vaidyanathan
2015) and its baseline LRDM (Munkberg et al. 2014).

Plan (passes; knobs in brackets)::

    tile_stats [tile, stats_stride, seed, bucket_coc]
      -> partition_setup [merge_threshold, sigma_x, max_partitions, guard, reach]
      -> reproject [splat, subsample]
      -> filter_sheared (recursive, gauss) [recursions] | filter_mip (build, sample)
         | filter_rotated (u, v)
      -> layered_composite

Modes: ``practical`` (default: sparse statistics, every ``3 * spp``-th sample; layer
merging at 10%; ``filter="sheared"`` or ``"mip"``) and ``lrdm`` (full statistics, no
merging, ``filter="rotated"``: the rotated separable Gaussian with bilinear taps).
Specialisations chosen from ``info`` (reported by ``describe()``): without motion every
kernel is built with ``-D HAS_MOTION=0`` (``defocus_only``); a static frame with
``|coc| < 0.5`` px everywhere runs the box pass alone (``plan="box"``; ``specialize=False``
forces the full plan). Each choice is a bound of the plan, checked on every frame
(:mod:`clrecon.core.plan`); the bucket function comes from each frame's own depth range.

Depth buckets (``kernels/layered.h``): a bucket spans at most ``bucket_coc`` (0.5 px) of CoC
and at most 1/8 of the frame's depth range, so they are evenly spaced in CoC near the focus
plane and uniform in depth beyond; the steps are stretched when the frame needs more than
``NBUCKETS - 1 = 31`` of them; misses have a bucket of their own, the last.

Filter derivation (per partition; mean CoC ``c``, mean motion ``m`` from the statistics).
A sample with CoC ``c_i`` and motion ``m_i`` is seen at ``p_i + c_i l + (t - 1/2) m_i`` (``p_i``
its pinhole position at mid-shutter, ``l`` in the unit disc, ``t`` in [0, 1]); the frame to
reconstruct is the pinhole image convolved per surface with its disc of radius ``|c_i|`` and
its motion segment ``m_i``. Reprojection with the partition's ``A = c`` and ``b = m`` (eq. 1)
puts the sample at ``p_i + (c_i - c) l + (t - 1/2)(m_i - m)``: the residual spreads it with
variance ``(c_i - c)^2 / 4`` per axis and ``(m_i - m)(m_i - m)^T / 12``. What remains to apply
is the mean physical blur less that residual; in expectation over the partition (the cross
terms vanish because the residuals have mean zero) that is the covariance of the disc and
the segment at the means::

    S = (c^2 / 4 + sigma_x^2) I + m m^T / 12

(a uniform disc of radius r has variance r^2 / 4 per axis, a segment of length L variance
L^2 / 12 along it; ``sigma_x = 0.33`` px is the paper's spatial filter). Its principal axes
give ``sigma_u >= sigma_v`` with ``theta`` along ``m``. Samples are weighted uniformly over
lens and shutter (the uvt part of the 5D filter is constant over aperture and shutter). The
variance-matched Gaussian is also close to the L2-best Gaussian for a disc's edge profile
(sigma/r = 0.5 vs an optimum a little above 0.55), so its remaining error is the shape.

Sheared filter (eq. 9). ``B B^T = S`` gives the sheared form directly: ``s_v^2 = S_yy``,
``beta = S_xy / S_yy``, ``s_u^2 = det S / S_yy`` (equal to eq. 9). Deviations, each measured
at 512x512, 8 spp: (1) the Gaussian runs along the axis of larger variance (the transposed
form when ``S_xx > S_yy``): eq. 9's form puts one tap per row, and a thin ellipse a few
degrees off the x axis has ``s_v << 1`` row, so it collapsed to a point (fast_motion 24.6 ->
30.7 dB); (2) the recursive filter (eq. 10) runs 3 forward-backward pairs (``recursions``;
the paper: 1) whose gamma is solved for the variance of the *sampled* Gaussian, not
``exp(-sqrt 2 / s_u)`` (exact for large sigma only): fence 34.3 -> 35.4 dB.

Merging (partition_setup): front to back over populated buckets, a bucket joins the running
partition when the merged filter's ``sigma_u``, ``sigma_v`` shrink by at most
``merge_threshold`` (10%) below the largest constituent bucket's filter (the paper's test,
against the constituents so chained merges cannot drift) and grow by at most that above the
smallest (otherwise a few sharp samples are absorbed into a wide filter: spheres 41.6 ->
44.6 dB). At most ``max_partitions`` (4) remain per tile, further pairs merged by least
change. Partitions cover the bucket axis without gaps, so a sample that sparse statistics
did not see still belongs to one. Empty tiles get one in-focus static partition.

Large filters: a partition whose ``3 sigma_u`` exceeds the guard band (16 grid px) is
reprojected onto a grid of spacing ``s`` (the smallest power of two <= tile that fits) and
filtered there; composite reads it bilinearly. On such grids reproject gathers one pixel
per ``min(s, b)^2`` block, the pixel picked per block row by a hash (``subsample=b``,
default 8, ``False`` = 1: every pixel; at 512x512 8 spp within 0.2 dB of every pixel, 3-4x
faster; b = 4 -> 8 moved no scene by more than 0.11 dB). Samples are
gathered from at most ``reach`` (96) px outside a tile: wider blurs are truncated and
renormalised. Compositing divides by the accumulated opacity where nothing covers the back
and falls back to the pixel's mean where nothing covers at all.

Determinism (``deterministic``, default ``False``). ``reproject`` is the one pass that
scatters: with one work-item per slot (``wg_x = 1``, the spec's default and the tuned choice
on the CPUs measured) the item owns its slot's grid and adds in a fixed order, bit-identical
run to run as it is; with a tuned ``wg_x > 1`` the group's items add with float atomics, whose
order varies. ``deterministic=True`` makes those adds int64 fixed point (``kernels/common.h``)
into ``grids_fixed`` (twice the grids' bytes), which the group converts to the float grids
itself (plus ``color_bound``, 16 bytes: the frame's largest |colour| per channel, reduced
first). Scale: a slot reads at most ``n = (bx - ax) (by - ay) spp`` samples (its gather
window), each adding at most ``m_c`` (the channel's max |colour|; 1 for the weights) to a grid
cell, so channel c is kept in units of ``2**(ceil(log2 n) + ilogb(m_c) + 1 - 61)`` and no
sum can exceed ``2**61`` units: overflow is impossible for any valid frame. Each term is
rounded once to a unit: about ``n * 2**-60`` of the brightest colour (2^-41 for a 32 px
tile, reach 96, 8 spp); the weight channels hold counts exactly (nearest splat). Without
``cl_khr_int64_base_atomics`` a deterministic plan runs ``wg_x = 1``.
"""
from __future__ import annotations

import math

import pyopencl as cl

from clrecon.core.fixed import BOUND_BYTES
from clrecon.core.knobs import check_bool, check_choice, check_float, check_int
from clrecon.core.local_size import LocalSize
from clrecon.core.pipeline import DeviceSamples, Pipeline, register
from clrecon.core.plan import Bound, Plan, Step, coc_bound, motion_bound, shape_bounds
from clrecon.methods.box import Box, box_plan
from clrecon.methods.layered.composite import LayeredComposite
from clrecon.methods.layered.filter_mip import FilterMip, atlas_layout
from clrecon.methods.layered.filter_rotated import FilterRotated
from clrecon.methods.layered.filter_sheared import FilterSheared
from clrecon.methods.layered.layout import (
    NCH,
    NPAR,
    NSTAT,
    SUBSAMPLE_DEFAULT,
    Layout,
    bucket_params,
    mip_levels,
    subsample_cap,
)
from clrecon.methods.layered.partition_setup import PartitionSetup
from clrecon.methods.layered.reproject import Reproject
from clrecon.methods.layered.tile_stats import TileStats
from clrecon.tune.local import local_size_of
from clrecon.tune.runtime import tuned
from clrecon.tune.tunable import Tunable

MODES = ("practical", "lrdm")
FILTERS = ("sheared", "mip", "rotated")
SPLATS = ("nearest", "bilinear")
NBUCKETS = 32
STATIC_COC = 0.5  # px: below this everywhere (and no motion) the frame is reconstructed by box
#: knob ranges (beyond them nothing useful happens, or float32 kernel arguments overflow)
MAX_MERGE = 1e6  # merge_threshold in [-1e6, 1e6]; < 0: no merging
MAX_SIGMA_X = 64.0  # px: sigma_x in (0, 64]
MAX_GUARD = 256  # grid px: guard in [2, 256]
MIN_BUCKET_COC, MAX_BUCKET_COC = 1e-3, 1e3  # px: bucket_coc in [1e-3, 1e3]
MAX_REACH = 1024  # px: reach in [1, 1024]


def _guard(info, sigma_x: float, guard: int) -> int:
    """Guard band (grid px) a frame needs: 3 sigma of its largest blur, at most ``guard``."""
    sig = math.sqrt(info.max_abs_coc ** 2 / 4 + info.max_abs_motion ** 2 / 12 + sigma_x ** 2)
    return max(2, min(guard, math.ceil(3 * sig) + 1))


@register
class LayeredPipeline(Pipeline):
    name = "layered"
    fields = ("color", "position", "depth", "lens", "time", "motion")
    #: given the partitions, the filters come from the partitions' statistics, not the sample
    #: count: the safeguard's halves take the frame's (its statistics and partition setup)
    #: and it blends their mean (a halves' own partitions lost 0.39 dB on bokeh at 8 spp)
    halves_mean = True
    shared_steps = ("tile_stats", "partition_setup")

    def __init__(self, context, info, mode: str = "practical", filter: str | None = None,
                 tile: int = 32, stats_stride: int | None = None,
                 merge_threshold: float | None = None, sigma_x: float = 0.33,
                 max_partitions: int = 4, guard: int = 16, bucket_coc: float = 0.5,
                 splat: str = "nearest", seed: int = 0, has_motion: bool | None = None,
                 recursions: int = 3, specialize: bool = True, reach: int = 96,
                 subsample: int | bool = SUBSAMPLE_DEFAULT, mip_images: bool | None = None,
                 deterministic: bool = False):
        super().__init__(context, info)
        mode = check_choice("mode", mode, MODES)
        filter = check_choice("filter", filter, FILTERS, none_ok=True)
        filter = filter or ("rotated" if mode == "lrdm" else "sheared")
        splat = check_choice("splat", splat, SPLATS)
        tile = check_int("tile", tile, 2, 128, what="(a power of two)")
        if tile & (tile - 1):
            raise ValueError(f"tile: must be a power of two in [2, 128], got {tile}")
        if stats_stride is None:
            stats_stride = 1 if mode == "lrdm" else 3 * info.spp
        stats_stride = check_int("stats_stride", stats_stride, 1, 2**31, hi_open=True)
        if merge_threshold is None:
            merge_threshold = -1.0 if mode == "lrdm" else 0.1
        merge_threshold = check_float("merge_threshold", merge_threshold, -MAX_MERGE,
                                      MAX_MERGE, what="(< 0: no merging)")
        sigma_x = check_float("sigma_x", sigma_x, 0.0, MAX_SIGMA_X, lo_open=True)
        max_partitions = check_int("max_partitions", max_partitions, 1, 16)
        guard = check_int("guard", guard, 2, MAX_GUARD)
        bucket_coc = check_float("bucket_coc", bucket_coc, MIN_BUCKET_COC, MAX_BUCKET_COC)
        seed = check_int("seed", seed, 0, 2**32, hi_open=True)
        has_motion = check_bool("has_motion", has_motion, none_ok=True)
        recursions = check_int("recursions", recursions, 1, 4)
        specialize = check_bool("specialize", specialize)
        reach = check_int("reach", reach, 1, MAX_REACH)
        subsample = subsample_cap(subsample)  # false or an int in [1, 64]
        mip_images = check_bool("mip_images", mip_images, none_ok=True)
        self.deterministic = check_bool("deterministic", deterministic)
        self.fixed = False  # reproject accumulates in fixed point (deterministic, wg_x > 1)
        self.recursions = int(recursions)
        self.subsample = subsample
        if mip_images is not None and filter != "mip":
            raise ValueError(f"mip_images: applies to filter='mip' only, not {filter!r}")
        self.mip_images = None  # filter="mip": whether it reads the image atlas
        self.mode, self.filter, self.splat = mode, filter, splat
        self.stats_stride, self.merge_threshold = int(stats_stride), float(merge_threshold)
        self.sigma_x, self.bucket_coc, self.seed = float(sigma_x), float(bucket_coc), int(seed)
        motion = info.has_motion if has_motion is None else bool(has_motion)
        # the guard band need not exceed the largest blur the frame can have
        gmax = _guard(info, sigma_x, int(guard))
        self.layout = Layout(tile=tile, nbuckets=NBUCKETS, maxp=int(max_partitions),
                             gmax=gmax, spp=info.spp, has_motion=motion,
                             reach_max=int(reach))
        # the sample fields the passes read (not self.fields: that is what a caller
        # uploads, set by set_plan, and stale while re-planning)
        self.reads = ("color", "position", "depth", "lens", "time", "motion")
        if not motion:  # defocus only: shutter time and motion are never read
            self.reads = ("color", "position", "depth", "lens")
        self.tuning: dict[str, str] = {}
        # what the plan rests on (checked on every frame): the motion terms compiled out of a
        # static frame; the guard band sized from the largest blur
        bounds = []
        if has_motion is None and not motion:
            bounds.append(motion_bound(0.0, "planned for a static frame: HAS_MOTION=0"))
        # a static frame whose blur stays inside the pixel (|coc| < 0.5 px) has nothing to
        # reconstruct beyond the pixel filter: it costs, and is, a box filter
        self.box = None
        if specialize and not info.has_motion and info.max_abs_coc < STATIC_COC:
            self.box = Box(context, self._local(Box.TUNABLE))
            self.set_plan(box_plan("layered", self.box, info, [
                coc_bound(STATIC_COC, "box plan: every CoC inside the pixel", "<"),
                motion_bound(0.0, "box plan: a static frame")]))
            return
        if gmax < int(guard):
            g, sx = int(guard), self.sigma_x
            bounds.append(Bound("guard_px", "<=", gmax, "guard band sized from the largest "
                                "blur", lambda i: _guard(i, sx, g), ("depth", "motion")))
        self.bounds = shape_bounds(info, "kernels compiled for this spp") + tuple(bounds)
        self.stats_pass = TileStats(context, self.layout, self._local(TileStats.TUNABLE))
        self.setup = PartitionSetup(context, self.layout, self._local(PartitionSetup.TUNABLE))
        local = self._local(Reproject.TUNABLE)
        if self.deterministic and local is not None and (local.x or 1) > 1:
            if all("cl_khr_int64_base_atomics" in d.extensions.split()
                   for d in context.devices):
                self.fixed = True
            else:  # no int64 atomics: the owned grid is deterministic as it is
                local = LocalSize(1, 1)
        self.reproject = Reproject(context, self.layout, splat == "bilinear", local,
                                   self.subsample, fixed=self.fixed)
        if filter == "sheared":
            self.filter_pass = FilterSheared(context, self.layout, self.recursions,
                                             self._local(FilterSheared.TUNABLE))
        elif filter == "mip":
            ntx, nty = self.layout.tiles(info.width, info.height)
            nslots = ntx * nty * self.layout.maxp
            atlas = self._mip_atlas(mip_images, nslots)
            self.mip_images = atlas is not None
            self.filter_pass = FilterMip(context, self.layout, self._local(FilterMip.TUNABLE),
                                         atlas)
        else:
            self.filter_pass = FilterRotated(context, self.layout,
                                             self._local(FilterRotated.TUNABLE))
        self.composite_pass = LayeredComposite(context, self.layout,
                                               self._local(LayeredComposite.TUNABLE))
        self.set_plan(self._plan(info))
        # every pass reads through strided(); the fixed-point colour bound reads the frame
        self.sample_views = not self.fixed

    def _mip_atlas(self, want: bool | None, nslots: int) -> dict | None:
        """The atlas filter_mip reads through the linear sampler, or None for buffers: asked
        for, or by default on GPUs with image support whose 2D images hold the atlas (on CPUs
        the sampler is software, slower than the buffer variant)."""
        dev = self.context.devices[0]
        atlas, fits = atlas_layout(dev, self.layout, nslots)
        if want is None:
            want = bool(dev.image_support and dev.type & cl.device_type.GPU and fits)
        elif want and not dev.image_support:
            raise ValueError("mip_images: the device has no image support")
        elif want and not fits:
            raise ValueError(f"mip_images: the atlas ({atlas['width']}x{atlas['height']}) "
                             f"exceeds the device's 2D image limit ({dev.image2d_max_width}x"
                             f"{dev.image2d_max_height})")
        return atlas if want else None

    def _local(self, tunable: Tunable) -> LocalSize:
        """The tuned local size of the pass ``tunable`` declares; its source goes into
        ``describe()["tuning"]``."""
        found = tuned(self.context, tunable, self.info)
        self.tuning[tunable.name] = found.source
        return local_size_of(found.config)

    def buffer_sizes(self, width: int, height: int) -> dict[str, int]:
        """Bytes of each temporary this plan allocates for a ``width x height`` frame."""
        if self.box is not None:
            return {}
        layout = self.layout
        ntx, nty = layout.tiles(width, height)
        slots = ntx * nty * layout.maxp
        sizes = {"stats": ntx * nty * layout.nbuckets * NSTAT * 4,
                 "params": slots * NPAR * 4,
                 "grids": slots * NCH * layout.dmax ** 2 * 4,
                 "filtered": slots * NCH * layout.filtered_side ** 2 * 4,
                 "buckets": Reproject.buckets_bytes(width, height, layout.spp)}
        if self.fixed:
            sizes |= {"grids_fixed": 2 * sizes["grids"], "color_bound": BOUND_BYTES}
        if self.filter == "rotated":
            sizes["tmp"] = sizes["grids"]
        if self.filter == "mip":
            sizes["pyramid"] = slots * NCH * mip_levels(layout.dmax)[1] * 4
            if self.mip_images:
                a = self.filter_pass.atlas
                sizes["atlas"] = a["width"] * a["height"] * (16 + 4)  # owned by filter_mip
        return sizes

    def _plan(self, info) -> Plan:
        temps = {k: v for k, v in self.buffer_sizes(info.width, info.height).items()
                 if k != "atlas"}  # the atlas is filter_mip's own
        ntx, nty = self.layout.tiles(info.width, info.height)
        nslots = ntx * nty * self.layout.maxp
        fields = self.reads

        def stats(queue, f, wait):
            coeffs = self.bucket_params(f.samples, f.info)
            return [("tile_stats", self.stats_pass(queue, f.samples, coeffs, self.stats_stride,
                                                   self.seed, f.buffers["stats"], wait))]

        def setup(queue, f, wait):
            b = f.buffers
            return [("partition_setup", self.setup(queue, b["stats"], ntx * nty, self.sigma_x,
                                                   self.merge_threshold, b["params"], wait))]

        def reproject(queue, f, wait):
            b = f.buffers
            bucket_coeffs = self.bucket_params(f.samples, f.info)
            self.reproject(queue, f.samples, bucket_coeffs, b["params"], b["grids"], wait,
                           b.get("grids_fixed"), b.get("color_bound"), b["buckets"])
            return list(self.reproject.events)

        def filter_grids(queue, f, wait):
            b = f.buffers
            work = {"sheared": (), "mip": ("pyramid",), "rotated": ("tmp",)}[self.filter]
            self.filter_pass(queue, b["params"], b["grids"], *(b[k] for k in work),
                             b["filtered"], nslots, wait)
            return list(self.filter_pass.events)

        def composite(queue, f, wait):
            b = f.buffers
            color, stride, offset = f.samples.strided("color")
            return [("layered_composite", self.composite_pass(queue, color, b["params"],
                                                              b["filtered"], f.width, f.height,
                                                              b["out"], wait, stride, offset))]

        work = tuple(k for k in ("pyramid", "tmp") if k in temps)
        fixed = ("grids_fixed", "color_bound") if self.fixed else ()
        return Plan("layered", f"{self.mode}/{self.filter}", fields, (
            Step("tile_stats", ("depth",), ("stats",), stats),
            Step("partition_setup", ("stats",), ("params",), setup),
            Step("reproject", fields + ("params",), ("buckets", "grids") + fixed, reproject),
            Step(f"filter_{self.filter}", ("params", "grids"), work + ("filtered",),
                 filter_grids),
            Step("layered_composite", ("color", "params", "filtered"), ("out",), composite)),
            temps, self.bounds)

    @property
    def joint_steps(self) -> tuple[str, ...]:
        """What the safeguard may run once on the frame for both halves
        (:meth:`joint_halves`): reproject, unless the plan is box or fixed point."""
        return () if self.box is not None or self.fixed else ("reproject",)

    def joint_halves(self, queue, samples: DeviceSamples, ha: int, grids_b: cl.Buffer,
                     wait_for=None) -> list | None:
        """The safeguard's hook: after the shared steps ran on the frame ``samples``, reproject
        both halves at once (:meth:`Reproject.joint_halves`), half A into this pipeline's
        ``grids`` and B into ``grids_b``; the events, or None where the plan cannot (box,
        fixed point: :attr:`joint_steps` is empty there)."""
        if not self.joint_steps:
            return None
        self.reproject.joint_halves(queue, samples, ha, self.bucket_params(samples),
                                    self.buffer("params"), self.buffer("grids"), grids_b,
                                    self.buffer("buckets"), wait_for)
        return list(self.reproject.events)

    def describe(self) -> dict:
        return {"method": "layered", "mode": self.mode, "filter": self.filter,
                "defocus_only": not self.layout.has_motion,
                "plan": self.plan.name, "tile": self.layout.tile,
                "stats_stride": self.stats_stride, "merge_threshold": self.merge_threshold,
                "sigma_x": self.sigma_x, "max_partitions": self.layout.maxp,
                "guard": self.layout.gmax, "reach": self.layout.reach_max,
                "bucket_coc": self.bucket_coc, "splat": self.splat,
                "subsample": self.subsample, "deterministic": self.deterministic,
                "accumulation": ("box" if self.box is not None else "fixed point"
                                 if self.fixed else "owner" if self.reproject.local.x == 1
                                 else "float atomics"),
                "recursions": self.recursions if self.filter == "sheared" else None,
                "mip_images": self.mip_images,
                "device_bytes": sum(self.buffer_sizes(self.info.width,
                                                      self.info.height).values()),
                "bounds": [b.describe() for b in self.plan.bounds], "tuning": self.tuning}

    def bucket_params(self, samples: DeviceSamples, info=None) -> tuple:
        """The bucket function's coefficients for a frame: from its own lens model and depth
        range (a kernel argument, not a bound: any frame gets its own buckets)."""
        info = info or samples.info or self.info
        c0, c1 = samples.coc
        return bucket_params(c0, c1, info.min_depth, info.max_depth, self.layout.nbuckets,
                             self.bucket_coc)
