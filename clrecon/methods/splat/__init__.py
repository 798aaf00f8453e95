"""Method ``splat``: Laplacian kernel splatting (Leimkühler et al. 2018), synthesis from a
pinhole frame (S = 1, lens 0, time 0.5) and reconstruction from stochastic samples.

Plan: clear -> ``splat`` (per-sample spreadlets into per-layer Laplacian images, small PSFs
densely into per-layer direct images) -> ``splat_integrate`` (convolution pyramid per layer) ->
``splat_composite`` (back to front with coverage re-weighting).

Knobs: ``psf`` (``"simplelens"``, ``"combined"``, ``"stylized"``; default from the frame:
``combined`` when it has motion, else ``simplelens``), ``layers`` (global depth layers,
uniform in 1/depth; 1 when the frame has a single depth), ``pyramid`` (``"f7"`` default:
bokeh synthesis SSIM .972 against .961 with ``"f5"``),
``dense`` (the dense PSF splatted directly: the paper's "Splatting" baseline), ``fast_ratio``
(a cell is drawn densely when its dense PSF has at most this many times its spreadlet count),
``max_error`` (a cell is also drawn densely when its spreadlets' L1 error exceeds this; default
0.05: 8 of Combined's sparse cells have errors of 0.2-0.3, and a defocused background that
reaches them comes out blotched, e.g. `deep` at 8 spp 28.3 dB sparse against 38.5 dB dense),
``scatter`` (``"atomic"`` or ``"tiles"``; default ``"tiles"`` on CPU devices, see
:mod:`clrecon.methods.splat.splat`), ``deterministic`` (default ``False``; ``True``: bit-identical
images run to run, below).

Determinism. The owner tiles add in a fixed order, so ``scatter="tiles"`` is bit-identical
run to run as it is. The atomic scatter adds floats in whatever order the device schedules
(last bits vary); with ``deterministic=True`` it accumulates in int64 fixed point instead
(integer sums do not depend on order; ``kernels/common.h``) and converts to float images
after: plan steps ``color_bound`` (the frame's largest |colour| per channel) -> ``splat``
into ``direct_fixed`` / ``lap_fixed`` -> ``fixed_to_float``. The scale: a pixel receives
from the samples of the pixels within ``R = reach + shift + 1`` of it (the owner tiles rest
on the same bound), each at most ``L1 * |colour| / spp`` (``L1`` the largest L1 norm of a
table cell, motion sub-segments share the weight), so its sum of ``|weight * value|`` per
unit of colour is below ``2**klog2 = npix * L1``, ``npix = min(2R + 1, W) * min(2R + 1,
H)``; channel c is kept in units of ``2**(klog2 + ilogb(m_c) + 1 - 61)`` (``m_c`` the
channel's max |colour|, 1 for coverage), so no sum can exceed ``2**61`` units: overflow is
impossible for any valid frame (colours up to 1e30 included). Precision: each term is
rounded once to a unit, at most ``2**(klog2 - 60)`` of the channel's brightest colour
(``describe()["fixed_resolution"]``; klog2 is 16-21 for the built-in scenes at 256x256 and
512x512, fast_motion 512x512 the largest: 2^-44 to 2^-39): far finer than float32 for
values near the brightest, but a value ``2**-k`` of it keeps only ``60 - klog2 - k`` bits
(float32 keeps 24), so a frame with a 1e30 highlight quantises the same channel's ordinary
colours to units of about 1e30 * 2^-42 = 2e17 (nothing of them is left). Needs
``cl_khr_int64_base_atomics``: without it the default scatter becomes ``"tiles"`` and an
explicit ``"atomic"`` is refused.
When every cell the frame can reach is on the fast track the Laplacian images and the
integration are skipped; when moreover every such PSF is the unit pixel and no sample moves
from its pixel (a static in-focus frame), the plan is the box filter (``plan`` in
:meth:`describe`).
"""
from __future__ import annotations

import logging

import numpy as np
import pyopencl as cl

from clrecon.core.fill import zero_buffer
from clrecon.core.fixed import BOUND_BYTES
from clrecon.core.knobs import check_bool, check_choice, check_float, check_int
from clrecon.core.pipeline import Pipeline, register
from clrecon.core.plan import Bound, Plan, Step, coc_bound, motion_bound, shape_bounds
from clrecon.core.samples import FIELDS
from clrecon.methods.box import Box, box_plan
from clrecon.methods.splat.composite import SplatComposite
from clrecon.methods.splat.integrate import SplatIntegrate
from clrecon.methods.splat.layers import inv_span, layer_params
from clrecon.methods.splat.mip import MAX_RADIUS, MIN_RADIUS
from clrecon.methods.splat.mip_plan import MipPlan
from clrecon.methods.splat.psf import MODELS
from clrecon.methods.splat.reference import PYRAMIDS
from clrecon.methods.splat.splat import SCATTERS, Splat
from clrecon.methods.splat.tables import DeviceTable, host_table
from clrecon.tune.local import local_size_of
from clrecon.tune.runtime import tuned

log = logging.getLogger(__name__)
PSF_MODELS = tuple(MODELS)
#: default ``max_error``: spreadlet L1 error above which a cell is drawn densely
MAX_ERROR = 0.05
#: default ``mip_radius`` (the mip plan, :mod:`clrecon.methods.splat.mip`); 0: the paper's
#: plan. Chosen on cost (~R0^2 per bin) against sharpness, not per scene (the trade 4 / 6 /
#: 8 / 12 on every built-in scene: docs/measurements/splat-mip-pocl.md)
MIP_RADIUS = 8.0
#: the longest motion the host arithmetic takes from a frame description (validated frames
#: stay below MOTION_MAX * sqrt(2); beyond this the count of sub-segments is clamped)
_HOST_MOTION_LIMIT = 2.0**31
#: knob ranges: ``layers`` in [1, 64] (each layer is three full-frame float4 images);
#: ``fast_ratio`` in [0, 1e6] (beyond any PSF's dense/sparse size ratio: every cell dense)
MAX_LAYERS = 64
MAX_FAST_RATIO = 1e6


@register
class SplatPipeline(MipPlan, Pipeline):
    name = "splat"
    fields = tuple(FIELDS)
    #: splat_composite clamps each layer's colour at 0 (the integration rings below it):
    #: not linear in the colour, so run(allow_negative=True) reconstructs the positive and
    #: negative parts of a frame apart and subtracts them
    color_linear = False
    #: each sample's PSF comes from its own CoC and motion (not the sample count)
    halves_mean = True

    def __init__(self, context, info, psf: str | None = None, layers: int = 4,
                 pyramid: str = "f7", dense: bool = False, fast_ratio: float = 1.0,
                 max_error: float = MAX_ERROR, scatter: str | None = None,
                 deterministic: bool = False, mip_radius: float | None = None):
        super().__init__(context, info)
        psf = check_choice("psf", psf, sorted(MODELS), none_ok=True)
        pyramid = check_choice("pyramid", pyramid, sorted(PYRAMIDS))
        layers = check_int("layers", layers, 1, MAX_LAYERS)
        dense = check_bool("dense", dense)
        fast_ratio = check_float("fast_ratio", fast_ratio, 0.0, MAX_FAST_RATIO)
        max_error = check_float("max_error", max_error, 0.0, allow_inf=True,
                                what="(inf: never drawn densely for its error)")
        scatter = check_choice("scatter", scatter, SCATTERS, none_ok=True)
        self.deterministic = check_bool("deterministic", deterministic)
        # None: the mip plan unless the knobs ask for the paper's (dense, the hexagon)
        self.mip_source = "api" if mip_radius is not None else "default"
        if mip_radius is None:
            mip_radius = 0.0 if dense is True or psf == "stylized" else MIP_RADIUS
        if not isinstance(mip_radius, (bool, np.bool_)) and mip_radius == 0:
            mip_radius = None
        self.mip_radius = None if mip_radius is None else check_float(
            "mip_radius", mip_radius, MIN_RADIUS, MAX_RADIUS,
            what="(0: the paper's spreadlets at full resolution; None: 8, or 0 with "
                 "dense=True or psf='stylized')")
        if self.mip_radius is not None and (psf == "stylized" or dense):
            raise ValueError("mip_radius: the mip plan draws discs and swept discs (psf "
                             "'simplelens' or 'combined', dense=False); "
                             f"psf={psf!r}, dense={dense} needs mip_radius=None")
        self.psf = psf or ("combined" if info.has_motion else "simplelens")
        self.psf_source = "api" if psf else "inspect"
        self.dense, self.fast_ratio = bool(dense), float(fast_ratio)
        self.max_error = float(max_error)
        self.table = host_table(self.psf, self.dense, self.fast_ratio, self.max_error)
        ndim = len(self.table.model.n)
        reach = self.table.reachable(info)
        # reach: |offset| bound of every reachable PSF (rotation and rounding: + 1). The pad
        # holds any PSF whose centre is within reach of the frame (a centre lies at most
        # |coc| + |motion| / 2 from its sample); samples further out cannot touch the frame
        # and the kernel skips them.
        self.reach = int(np.ceil(self.table.radius[reach].max(initial=0.0))) + 1
        smax = self.table.model.smax
        # the table's CoC range: a larger CoC is drawn with the largest disc (clamped), which
        # is too small; describe() and a warning say so. Motion beyond the range is drawn as
        # ceil(|motion| / smax) sub-segments (exact up to the sub-PSFs' rounding).
        self.clamped = {}
        if info.max_abs_coc > smax[0]:
            self.clamped["coc"] = {"frame_px": round(info.max_abs_coc, 2),
                                   "table_max_px": smax[0]}
            log.warning("splat: the %s table covers CoC <= %g px, this frame reaches %.1f px: "
                        "the largest PSF stands in for larger blur", self.psf, smax[0],
                        info.max_abs_coc)
        motion = info.max_abs_motion if ndim == 2 else 0.0
        # validation bounds |motion| (components <= MOTION_MAX); a description that vouches
        # for more (even inf) is clamped before int() so that the host arithmetic holds
        split = min(motion, _HOST_MOTION_LIMIT) / smax[-1]
        self.motion_split = int(np.ceil(split)) if split > 1 else 1
        # how far a (sub-)PSF's centre lies from its sample: |coc| + |motion| / 2, and up to
        # |coc| + |motion| for the outer sub-segments of a split one
        self.shift = min(info.max_abs_coc, smax[0]) + (
            motion if self.motion_split > 1 else 0.5 * motion)
        self.pad = self.reach + int(np.ceil(min(self.shift, float(self.reach)))) + 2
        self.requested_layers = int(layers)
        self.layers = int(layers) if layer_params(info, 1)[1] > 0 else 1
        self.inv_far, self.layer_scale = layer_params(info, self.layers)
        self.use_lap = not bool(np.all(self.table.fast[reach]))
        self.has_motion = info.has_motion
        self.tuning: dict[str, str] = {}
        # what the plan rests on: reach, pad, sub-segments and the integration are sized
        # from the largest blur; motion compiled out of a static frame; one layer for a
        # frame of a single depth
        bounds = [coc_bound(info.max_abs_coc, "reach and pad sized from the largest CoC"),
                  motion_bound(info.max_abs_motion, "reach, pad and motion sub-segments "
                               "sized from the longest motion")]
        if self.layers == 1 and self.requested_layers > 1:
            bounds.append(Bound("inverse_depth_span", "<=", 0.0, "one layer: a frame of a "
                                "single depth", lambda i: inv_span(i), ("depth",)))
        # static and in focus: every sample lands, whole, in its own pixel -> the box filter
        self.plan_name = "box" if self.shift == 0.0 and self._delta_only(reach) else "splat"
        if self.plan_name == "box":
            self.use_lap, self.layers, self.pad = False, 1, 0
            found = tuned(context, Box.TUNABLE, info)
            self.tuning["box"] = found.source
            self.box = Box(context, local_size_of(found.config))
            self.set_plan(box_plan("splat", self.box, info, bounds))
            return

        def config(tunable):
            found = tuned(context, tunable, info)
            self.tuning[tunable.name] = found.source
            return found.config

        int64 = all("cl_khr_int64_base_atomics" in d.extensions.split()
                    for d in context.devices)
        if scatter is None:  # CAS float atomics cost ~10 plain adds on CPUs
            cpu = bool(context.devices[0].type & cl.device_type.CPU)
            scatter = "tiles" if cpu or (self.deterministic and not int64) else "atomic"
        elif self.deterministic and scatter == "atomic" and not int64 \
                and self.mip_radius is None:
            raise ValueError("deterministic: scatter='atomic' accumulates in int64 fixed point, "
                             "which needs cl_khr_int64_base_atomics; the device lacks it "
                             "(scatter='tiles' is deterministic as it is)")
        if self.mip_radius is not None:
            self._init_mip(context, info, scatter, config, bounds)
            return
        ph, pw = info.height + 2 * self.pad, info.width + 2 * self.pad
        self.shape = (ph, pw)
        self.device_table = DeviceTable(context, self.table)
        self.fixed = self.deterministic and scatter == "atomic"
        self.klog2 = self._fixed_klog2(info) if self.fixed else 0
        cfg = config(Splat.TUNABLE)
        self.splat = Splat(context, info.spp, ndim, self.has_motion, self.layers,
                           None if cfg is None else int(cfg["wg"]), scatter, fixed=self.fixed)
        self.composite = SplatComposite(context, self.layers, self.use_lap,
                                        local_size_of(config(SplatComposite.TUNABLE)))
        self.pyramid = pyramid
        self.integrate = SplatIntegrate(context, ph, pw, pyramid, local_size_of(
            config(SplatIntegrate.TUNABLE))) if self.use_lap else None
        self.set_plan(self._plan(info, shape_bounds(info, "kernels compiled for this spp")
                                 + tuple(bounds)))

    def _fixed_klog2(self, info) -> int:
        """``deterministic``: ``klog2`` with ``2**klog2`` >= the sum of ``|weight * value|``
        any pixel receives per unit of colour (module docstring)."""
        r = self.reach + int(np.ceil(min(self.shift, 2.0**30))) + 1
        npix = min(2 * r + 1, info.width) * min(2 * r + 1, info.height)
        t = self.table
        l1 = max(_cell_l1(t.vals, t.offs), _cell_l1(t.dvals, t.doffs))
        return max(0, int(np.ceil(np.log2(max(npix * l1, 1.0)))))

    def _plan(self, info, bounds) -> Plan:
        img = self.layers * self.shape[0] * self.shape[1] * 16
        temps = {"direct": img, "ring": self.layers * 16}
        if self.use_lap:
            temps |= {"lap": img, "prim": img}
        lap = "lap" if self.use_lap else "direct"
        prim = "prim" if self.use_lap else "direct"
        # what the splat step accumulates into: the float images, or (fixed) int64 ones
        acc = {k: k + "_fixed" if self.fixed else k for k in ("direct", lap)}
        if self.fixed:
            temps |= {acc[k]: 2 * img for k in acc} | {"color_bound": BOUND_BYTES}
        targets = tuple(acc.values())

        def clear(queue, f, wait):
            return [("clear", zero_buffer(queue, f.buffers[k], temps[k], wait))
                    for k in targets]

        def color_bound(queue, f, wait):
            self.splat.color_bound(queue, f.samples, f.buffers["color_bound"], wait)
            clear_ev, ev = self.splat.events
            return [("clear", clear_ev), ("splat_color_bound", ev)]

        def splat(queue, f, wait):
            b = f.buffers
            inv_far, scale = layer_params(f.info, self.layers)
            self.splat(queue, f.samples, self.device_table, inv_far, scale, self.pad,
                       self.reach, b[acc[lap]], b[acc["direct"]], wait, self.shift,
                       b.get("color_bound"), self.klog2)
            return [("splat", e) for e in self.splat.events]

        def to_float(queue, f, wait):
            b, npix = f.buffers, img // 16
            return [("splat_fixed_to_float", self.splat.to_float(
                queue, b[acc[k]], b[k], npix, b["color_bound"], self.klog2, wait))
                for k in acc]

        def integrate(queue, f, wait):
            b, evs = f.buffers, []
            for layer in range(self.layers):
                ev = self.integrate(queue, b["lap"], layer, b["prim"], b["ring"], wait)
                evs += [("splat_integrate", e) for e in self.integrate.events]
                wait = [ev]
            return evs

        def composite(queue, f, wait):
            b = f.buffers
            return [("splat_composite", self.composite(
                queue, b[prim], b["direct"], b["ring"], f.width, f.height, self.pad,
                b["out"], wait, color=b["color"], spp=f.spp))]

        steps = [Step("clear", (), targets, clear)]
        if self.fixed:
            steps.append(Step("color_bound", ("color",), ("color_bound",), color_bound))
        steps.append(Step("splat", tuple(FIELDS) + (("color_bound",) if self.fixed else ()),
                          targets, splat))
        if self.fixed:
            steps.append(Step("fixed_to_float", targets + ("color_bound",), tuple(acc),
                              to_float))
        if self.use_lap:
            steps.append(Step("splat_integrate", ("lap",), ("prim", "ring"), integrate))
        steps.append(Step("splat_composite", (prim, "direct", "ring", "color"), ("out",),
                          composite))
        return Plan("splat", "splat", tuple(FIELDS), tuple(steps),
                    temps, tuple(bounds))

    # the pipeline's own temporaries under the names the tuner's runners use
    @property
    def direct(self):
        return self.buffers["direct"]

    @property
    def lap(self):
        return self.buffers["lap" if self.use_lap else "direct"]

    @property
    def prim(self):
        return self.buffers["prim" if self.use_lap else "direct"]

    @property
    def ring(self):
        return self.buffers["ring"]

    def _delta_only(self, reach: np.ndarray) -> bool:
        """Whether every reachable cell is drawn densely as the unit pixel at offset 0."""
        t = self.table
        for c in np.nonzero(reach)[0]:
            a, b = t.doffs[c], t.doffs[c + 1]
            if not t.fast[c] or b - a != 1 or np.any(t.dpts[a] != 0) \
                    or abs(float(t.dvals[a]) - 1.0) > 1e-6:
                return False
        return True

    def describe(self) -> dict:
        if self.plan_name == "box":
            return {"method": "splat", "plan": "box", "psf": self.psf,
                    "psf_source": self.psf_source, "has_motion": False, "layers": 1,
                    "integrate": False, "deterministic": self.deterministic,
                    "accumulation": "box", "tuning": self.tuning}
        if self.plan_name == "mip":
            g = self.geometry
            return {"method": "splat", "plan": "mip", "psf": self.psf,
                    "psf_source": self.psf_source, "mode": "mip", "layers": self.layers,
                    "mip_radius": g.r0, "levels": g.nlev,
                    "level_radii": [round(float(r), 3) for r in g.rl], "pad": g.pad,
                    "reach": g.reach, "integrate": False, "has_motion": self.has_motion,
                    "clamped": self.clamped, "scatter": self.mip.scatter,
                    "deterministic": self.deterministic,
                    "accumulation": ("owner tiles" if self.mip.scatter == "tiles"
                                     else "float atomics"),
                    "bounds": [b.describe() for b in self.plan.bounds], "tuning": self.tuning}
        return {"method": "splat", "plan": self.plan.name, "psf": self.psf,
                "psf_source": self.psf_source,
                "mode": "dense" if self.dense else "sparse", "layers": self.layers,
                "pyramid": self.pyramid if self.use_lap else None,
                "integrate": self.use_lap, "has_motion": self.has_motion, "pad": self.pad,
                "reach": self.reach, "fast_ratio": self.fast_ratio,
                "max_error": self.max_error if np.isfinite(self.max_error) else None,
                "clamped": self.clamped, "motion_split": self.motion_split,
                "scatter": self.splat.scatter, "deterministic": self.deterministic,
                "accumulation": ("fixed point" if self.fixed else "owner tiles"
                                 if self.splat.scatter == "tiles" else "float atomics"),
                "fixed_resolution": 2.0 ** (self.klog2 - 60) if self.fixed else None,
                "fast_cells": int(self.table.fast.sum()), "cells": len(self.table.fast),
                "bounds": [b.describe() for b in self.plan.bounds], "tuning": self.tuning}


def _cell_l1(vals: np.ndarray, offs: np.ndarray) -> float:
    """The largest L1 norm of a cell's values (cells ``offs[i]:offs[i + 1]``)."""
    csum = np.concatenate([[0.0], np.cumsum(np.abs(vals.astype(np.float64)))])
    offs = np.asarray(offs, np.int64)
    return float((csum[offs[1:]] - csum[offs[:-1]]).max(initial=0.0))
