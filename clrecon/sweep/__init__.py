"""Method ``sweep``: local reconstruction by a front-to-back sweep (Shirley et al. 2011).

Plans (knobs in brackets):

* sorted sweep [``scales=2`` (Appendix A, 1x1/5x5 blended) or ``4`` (Appendix B)]:
  ``sweep_prepare`` -> ``sweep_resolve`` [``sort="tile"|"pixel"``, ``tile``,
  ``tile_merge="auto"|"serial"|"bitonic"``, ``exponent``];
* ``dof_layers=True``: the sort-free three-layer depth-of-field variant,
  ``sweep_layer_sums`` -> ``sweep_layer_resolve`` (defocus only: motion is not smoothed).

``diameter_scale`` scales the denoising diameter ``max(2|coc|, |motion|)``;
``smooth_motion`` (default: whether the frame has motion) adds the motion term.

Model only what the frame requires: when no sample's denoising diameter exceeds the smallest
block (1 px for two scales and the three layers, 3 px for four scales: ``max_diameter`` from
the frame inspection), every sample falls in the narrow scale, and Appendix A/B's weights
reduce exactly to the per-pixel average, so the plan is the one ``box`` pass
(``specialize=False`` keeps the full sweep; the tests check both agree).
"""
from __future__ import annotations

import pyopencl as cl

from ..box import BoxPipeline
from ..pipeline import DeviceSamples, Pipeline, register
from ..tune.runtime import tuned
from ..tune.specs import DEFAULTS, local_size_of, make_resolve
from .layers import SweepLayerResolve, SweepLayerSums
from .prepare import SweepPrepare


@register
class SweepPipeline(Pipeline):
    name = "sweep"

    def __init__(self, context, info, scales: int = 2, dof_layers: bool = False,
                 exponent: float = 1.0, smooth_motion: bool | None = None,
                 diameter_scale: float = 1.0, sort: str | None = None, tile: int | None = None,
                 tile_merge: str | None = None, specialize: bool = True):
        super().__init__(context, info)
        if not diameter_scale >= 0:
            raise ValueError(f"diameter_scale: must be >= 0, got {diameter_scale}")
        if scales not in (2, 4):
            raise ValueError(f"scales: must be 2 or 4, got {scales!r}")
        self.scales, self.dof_layers, self.exponent = int(scales), bool(dof_layers), exponent
        self.smooth_motion = info.has_motion if smooth_motion is None else bool(smooth_motion)
        self.diameter_scale = float(diameter_scale)
        motion = info.max_abs_motion if self.smooth_motion and not self.dof_layers else 0.0
        self.max_diameter = self.diameter_scale * max(2.0 * info.max_abs_coc, motion)
        narrow = 3.0 if self.scales == 4 and not self.dof_layers else 1.0
        self.box_equivalent = bool(specialize) and self.max_diameter <= narrow
        if self.box_equivalent:
            self.fields = BoxPipeline.fields
            self.inner = BoxPipeline(context, info)
            self.tuning = self.inner.tuning
            return
        spp = info.spp
        npix = info.width * info.height
        rw = cl.mem_flags.READ_WRITE
        self.tuning: dict[str, str] = {}

        def local(pass_name):
            found = tuned(context, pass_name, info)
            self.tuning[pass_name] = found.source
            return local_size_of(found.config)

        if self.dof_layers:
            self.fields = ("color", "depth")
            self.sums_pass = SweepLayerSums(context, spp, local("sweep_layer_sums"))
            self.combine = SweepLayerResolve(context, spp, local("sweep_layer_resolve"))
            self.sums = cl.Buffer(context, rw, npix * 3 * 16)
        else:
            self.fields = ("color", "position", "depth", "motion")
            self.prepare = SweepPrepare(context, spp, self.smooth_motion, local("sweep_prepare"))
            given = {k: v for k, v in (("sort", sort), ("tile", tile), ("tile_merge", tile_merge))
                     if v is not None}
            if given:  # the caller's knobs win over tuning; the rest from the pass default
                config = {"sort": "tile", "tile": 4, "tile_merge": "auto"} | given
                if config["sort"] == "pixel":
                    config = {"sort": "pixel", "wg_x": 16, "wg_y": 4}
                self.tuning["sweep_resolve"] = "api"
            else:
                found = tuned(context, "sweep_resolve", info)
                config = found.config or DEFAULTS["sweep_resolve"]
                self.tuning["sweep_resolve"] = found.source
            self.resolve = make_resolve(context, spp, self.scales, exponent, config)
            self.keys = cl.Buffer(context, rw, npix * spp * 16)
            self.colors = cl.Buffer(context, rw, npix * spp * 16)

    def describe(self) -> dict:
        d = {"method": "sweep", "diameter_scale": self.diameter_scale, "tuning": self.tuning,
             "max_diameter_px": round(self.max_diameter, 3),
             "box_equivalent": self.box_equivalent}
        if self.box_equivalent:
            return d | {"mode": "box (every denoising diameter within the narrow block)",
                        "requested": "dof_layers" if self.dof_layers else f"{self.scales}-scale"}
        if self.dof_layers:
            return d | {"mode": "dof_layers", "smooth_motion": False}
        return d | {"mode": f"{self.scales}-scale", "scales": self.scales,
                    "exponent": self.exponent, "smooth_motion": self.smooth_motion,
                    "sort": self.resolve.sort, "tile": self.resolve.tile,
                    "tile_merge": self.resolve.tile_merge}

    def enqueue(self, queue, samples: DeviceSamples, out, wait_for=None):
        w, h = samples.width, samples.height
        if self.box_equivalent:
            self.inner.events = []
            ev = self.inner.enqueue(queue, samples, out, wait_for)
            self.events = self.inner.events
            return ev
        if self.dof_layers:
            ev = self.sums_pass(queue, samples, self.diameter_scale, self.sums, wait_for)
            self.events.append(("sweep_layer_sums", ev))
            ev = self.combine(queue, self.sums, w, h, out, [ev])
            self.events.append(("sweep_layer_resolve", ev))
            return ev
        ev = self.prepare(queue, samples, self.diameter_scale, self.keys, self.colors, wait_for)
        self.events.append(("sweep_prepare", ev))
        ev = self.resolve(queue, self.keys, self.colors, w, h, out, [ev])
        self.events.append(("sweep_resolve", ev))
        return ev
