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
#: the safeguard's halves share one bin pass from this spp (B's bins: a second buffer,
#: +106 MB at 512x512, +339 MB at 1280x720). Measured on deep, paired (PoCL, AVX-512 AMD
#: EPYC): the halves' bin 123.5 -> 89.0 ms at 64 spp, 37.5 -> 30.5 at 16, the frame 13% and
#: 3% faster; at 8 spp the frame gained 1-3% (bin 29.0 -> 24.0 ms, 58.8 -> 52.5 at 720p),
#: too little for the memory
JOINT_MIN_SPP = 16


def _bins_key(bufs) -> tuple[int, ...]:
    """What identifies a set of bins and flags buffers in the plan's record of clean ones."""
    return tuple(b.int_ptr for b in bufs)


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
            return _bins_key(f.buffers[k] for k in bin_bufs)

        def clear(queue, f, wait):
            return [("clear", zero_buffer(queue, f.buffers["mip_image"], temps["mip_image"],
                                          wait))]

        def clear_bins(queue, f, wait):
            return self._clear_bins(queue, [f.buffers[k] for k in bin_bufs], wait)

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

        steps = [Step("clear", (), ("mip_image",), clear),
                 Step("clear_bins", (), bin_bufs, clear_bins),
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

    def _clear_bins(self, queue, bufs: list, wait) -> list:
        """Zero the bins and flags ``bufs``; clean ones (the draw zeroes what it consumes)
        get a 16-byte fill of the zeros they hold: every frame enqueues the same events (what
        the benches pair up run to run)."""
        key = _bins_key(bufs)
        clean = key in self._clean_bins
        self._clean_bins.discard(key)
        sizes = (self.geometry.bin_bytes, self.geometry.pixels)
        return [("clear", zero_buffer(queue, b, 16 if clean else n, wait))
                for b, n in zip(bufs, sizes)]

    @property
    def joint_steps(self) -> tuple[str, ...]:
        """What the safeguard may run once on the frame for both halves
        (:meth:`joint_halves`): the bins of the owner tiles' mip plan, for an even spp
        (equal halves) from :data:`JOINT_MIN_SPP`."""
        spp = self.info.spp
        ok = self.plan_name == "mip" and self.mip.scatter == "tiles" and spp % 2 == 0 \
            and spp >= JOINT_MIN_SPP
        return ("clear_bins", "bin") if ok else ()

    def joint_halves(self, queue, samples, ha: int, bins_b, flags_b, wait_for=None):
        """The safeguard's hook: both halves' bins from one read of the frame ``samples``
        (:meth:`MipSplat.bin_joint`), half A into this pipeline's ``mip_bins``/``mip_flags``
        and B into ``bins_b``/``flags_b``; the events, or None where the plan cannot."""
        if not self.joint_steps or 2 * ha != samples.spp:
            return None
        a = [self.buffer("mip_bins"), self.buffer("mip_flags")]
        evs = self._clear_bins(queue, a, wait_for) + self._clear_bins(
            queue, [bins_b, flags_b], wait_for)
        # (the frame's description: the executor inspected it before the steps ran)
        inv_far, scale = layer_params(samples.info or self.info, self.layers)
        self.mip.bin_joint(queue, samples, inv_far, scale, *a, bins_b, flags_b,
                           [ev for _, ev in evs])
        return evs + list(self.mip.events)

    def joint_drawn(self, bins_b, flags_b) -> None:
        """The safeguard's word that both halves' draws are enqueued after
        :meth:`joint_halves`: their bins are zero again (each draw zeroes what it consumes)."""
        for bufs in ((self.buffer("mip_bins"), self.buffer("mip_flags")), (bins_b, flags_b)):
            self._clean_bins.add(_bins_key(bufs))
