"""splat's mip plan as steps: clear -> bin -> draw -> upsample -> splat_composite
(:mod:`clrecon.methods.splat.mip` has the passes and the geometry). A mixin of
:class:`clrecon.methods.splat.SplatPipeline`, which chooses this plan (``mip_radius > 0``)."""
from __future__ import annotations

import logging

from clrecon.core.fill import zero_buffer
from clrecon.core.plan import Plan, Step, shape_bounds
from clrecon.core.samples import FIELDS
from clrecon.methods.splat.composite import SplatComposite
from clrecon.methods.splat.layers import layer_params
from clrecon.methods.splat.mip import MipGeometry, MipSplat
from clrecon.tune.local import local_size_of

log = logging.getLogger("clrecon.methods.splat")


class MipPlan:
    """The mip plan's construction; expects the attributes SplatPipeline's constructor sets
    (``deterministic``, ``psf``, ``layers``, ``mip_radius``, ``has_motion``, ``_own``)."""

    def _init_mip(self, context, info, scatter, config, bounds) -> None:
        """The mip plan (:mod:`clrecon.methods.splat.mip`): clear -> bin -> draw -> upsample ->
        splat_composite. ``deterministic=True`` takes the owner tiles (plain adds in a fixed
        order), the float atomics are not reproducible."""
        if self.deterministic and scatter == "atomic":
            scatter = "tiles"
        self.plan_name, self.use_lap, self.clamped = "mip", False, {}
        motion = info.max_abs_motion if self.psf == "combined" else 0.0
        self.geometry = geo = MipGeometry(info.width, info.height, self.layers,
                                          self.mip_radius, info.max_abs_coc, motion)
        if geo.clamped:
            self.clamped["mip_levels"] = {"levels": geo.nlev}
            log.warning("splat: the frame's blur exceeds %d mip levels; the largest PSF "
                        "stands in for larger blur", geo.nlev)
        self.pad = geo.pad
        self.mip = MipSplat(context, info.spp, self.has_motion and self.psf == "combined",
                            geo, scatter)
        self.composite = SplatComposite(context, self.layers, False,
                                        local_size_of(config(SplatComposite.TUNABLE)))
        tiles = self.mip.scatter == "tiles"
        temps = {"mip_image": geo.image_bytes, "mip_bins": geo.bin_bytes,
                 "ring": self.layers * 16}
        # the owner tiles' flags: a byte a bin, set where the bin pass added, what the draw
        # scans (not the bins' weights, a cache line apart)
        bin_bufs = ("mip_bins", "mip_flags") if tiles else ("mip_bins",)
        if tiles:
            temps["mip_flags"] = geo.pixels

        # the draw pass zeroes every bin (and flag) it consumes, so the pipeline's own bins
        # are clean after a frame and their clear (a fifth of the frame's bytes) is skipped;
        # bins or flags an embedder passes, or ours after a frame that stopped between bin
        # and draw, are cleared
        self._clean_bins: set[tuple[int, ...]] = set()

        def key(f):
            return tuple(f.buffers[k].int_ptr for k in bin_bufs)

        def clear(queue, f, wait):
            # clean bins get a 16-byte fill of the zeros they hold: every frame enqueues the
            # same events (what the benches pair up run to run)
            clean = key(f) in self._clean_bins
            sizes = {"mip_image": temps["mip_image"]} | {
                k: 16 if clean else temps[k] for k in bin_bufs}
            return [("clear", zero_buffer(queue, f.buffers[k], n, wait))
                    for k, n in sizes.items()]

        def flags(f):
            return f.buffers["mip_flags"] if tiles else None

        def bin_(queue, f, wait):
            inv_far, scale = layer_params(f.info, self.layers)
            self._clean_bins.discard(key(f))
            self.mip.bin(queue, f.samples, inv_far, scale, f.buffers["mip_bins"], wait,
                         flags(f))
            return self.mip.events

        def draw(queue, f, wait):
            self.mip.draw(queue, f.buffers["mip_bins"], f.buffers["mip_image"], wait, flags(f))
            if all(self._own.get(k) is f.buffers[k] for k in bin_bufs):
                self._clean_bins.add(key(f))
            return self.mip.events

        def upsample(queue, f, wait):
            self.mip.upsample(queue, f.buffers["mip_image"], wait)
            return self.mip.events

        def composite(queue, f, wait):
            b = f.buffers
            color, stride, offset = f.samples.strided("color")
            return [("splat_composite", self.composite(
                queue, b["mip_image"], b["mip_image"], b["ring"], f.width, f.height,
                geo.pad, b["out"], wait, color=color, spp=f.spp, stride=stride,
                offset=offset))]

        steps = [Step("clear", (), ("mip_image",) + bin_bufs, clear),
                 Step("bin", tuple(FIELDS), bin_bufs, bin_),
                 Step("draw", bin_bufs, ("mip_image",), draw)]
        if geo.nlev > 1:
            steps.append(Step("upsample", ("mip_image",), ("mip_image",), upsample))
        # (ring: an argument the composite does not read without the Laplacian images, bound
        # all the same: a selection of steps allocates only what its steps name)
        steps.append(Step("splat_composite", ("mip_image", "ring", "color"), ("out",),
                          composite))
        bounds = shape_bounds(info, "kernels compiled for this spp") + tuple(bounds)
        # the bin pass and the composite read their samples through strided(): a view of a
        # frame (one half, for the safeguard) is read in place
        self.sample_views = True
        self.set_plan(Plan("splat", "splat", tuple(FIELDS), tuple(steps), temps,
                           tuple(bounds)))
