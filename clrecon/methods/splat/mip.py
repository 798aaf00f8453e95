"""Method ``splat``'s mip plan (``mip_radius``): the PSFs drawn on a pyramid, so that the cost
per sample does not grow with the blur (``kernels/splat_mip_bin.cl``, ``kernels/splat_mip_draw.cl``,
``kernels/splat_mip.h``).

Why not the paper's spreadlets: a PSF's Laplacian is non-zero along its outline, so the
spreadlets of a disc grow with its perimeter (231 for a disc of radius 15, 3,149 for a
defocused 100-px motion streak in the Combined table), and the cells whose sparse error is
large are drawn densely, whose cost grows with the area. On ``deep`` at 1280x720 that is ~400
adds per sample. Here a sample goes to the level ``l`` of the pyramid (level pixel ``2^l``
frame pixels) where its CoC radius is at most ``R0 = mip_radius`` and its motion at most
``M0 = 4 R0`` level pixels; samples of one layer that land in one level pixel are merged into
a bin (weighted sums of colour, radius, motion and position); every non-empty bin draws one
analytic PSF (disc or swept disc) of its mean radius and motion at its centroid; the levels
are then upsampled into level 0 and composited as the dense layers are. The cost per sample
is one bin add; the cost per bin at most ``(2 R0 + M0 + 3)^2`` pixels, and the bins of a
level are ``1 / 4^l`` of the pixels, so a frame's time is flat in its blur.

What it trades: a PSF at level ``l`` is resolved to ``2^l`` pixels (the bin and the bilinear
upsampling blur its outline by about one level pixel, i.e. ``1/R0`` to ``2/R0`` of its
radius); samples of one bin share one PSF (their mean radius and motion: mixed only where a
layer holds a depth or motion edge inside one level pixel). ``mip_radius`` is the knob:
larger is sharper and slower (cost ~ ``R0^2`` per bin).
"""
from __future__ import annotations

import math

import numpy as np
import pyopencl as cl

from clrecon.core.device import cpu_context, get_kernel
from clrecon.core.pipeline import DeviceSamples
from clrecon.methods.splat.splat import Splat, owner_phases

#: motion length per level, in multiples of the radius: M0 = MOTION_RATIO * R0
MOTION_RATIO = 4.0
#: the coarse levels' radius grows as 2^(l/2) up to this factor (:func:`level_radii`)
RADIUS_GROWTH = 4.0
#: at most this many levels (2^15 px level pixels: beyond any frame's blur)
MAX_LEVELS = 16
#: knob range of mip_radius (level pixels)
MIN_RADIUS, MAX_RADIUS = 1.0, 32.0
PHASES = 4
#: level pixels around a level's frame region that the upsampling into it fills: a child
#: frame pixel reads its parent within 1 pixel of the parent's frame region, and the margin
#: m of the level below needs ceil((m + 1) / 2) + 1 <= 3 here
UP_MARGIN = 3


def level_radii(radius: float, levels: int) -> tuple[np.ndarray, np.ndarray]:
    """Per level, the largest PSF radius and length it holds (level pixels, float32):
    ``RL = radius * min(2^(l/2), RADIUS_GROWTH)``, ``ML = MOTION_RATIO * RL``. A coarse
    level has few bins (``1/4^l`` of the pixels), so it can resolve its PSFs more finely at
    little cost: per frame pixel a level's cost is at most ``pi RL^2 / 4^l``, falling with
    ``l``."""
    lv = np.arange(levels, dtype=np.float64)
    rl = (float(radius) * np.minimum(2.0 ** (lv / 2), RADIUS_GROWTH)).astype(np.float32)
    return rl, (np.float32(MOTION_RATIO) * rl).astype(np.float32)


class MipGeometry:
    """Sizes of the mip plan for a frame of ``width x height`` whose largest |CoC| and
    |motion| are ``max_coc`` and ``max_motion`` (pixels)."""

    def __init__(self, width: int, height: int, layers: int, radius: float, max_coc: float,
                 max_motion: float):
        self.width, self.height, self.layers = int(width), int(height), int(layers)
        self.r0 = float(radius)
        rl, ml = level_radii(self.r0, MAX_LEVELS)
        scale = 2.0 ** np.arange(MAX_LEVELS)
        # a level's thresholds in frame pixels; the frame needs the lowest level whose
        # thresholds hold its largest blur
        tr, tm = (rl * scale).astype(np.float32), (ml * scale).astype(np.float32)
        fits = np.nonzero((tr >= max_coc) & (tm >= max_motion))[0]
        self.nlev = int(fits[0]) + 1 if len(fits) else MAX_LEVELS
        self.clamped = not len(fits)
        n = self.nlev
        self.rl, self.ml, self.tr, self.tm = rl[:n], ml[:n], tr[:n], tm[:n]
        # per level: reach E (a PSF within E level pixels of its bin) and pad P = 2 E (a
        # centre lies within RL + ML / 2 level pixels of its frame pixel)
        self.reaches = [int(math.ceil(float(r) + 0.5 * float(m))) + 2
                        for r, m in zip(self.rl, self.ml)]
        self.reach = max(self.reaches)
        s = 2 ** (n - 1)
        # how far a bin can lie from its sample's pixel (frame pixels): the re-centring
        # (clamped at the top level) plus one level pixel of rounding
        self.shift = (min(max_coc, float(rl[n - 1]) * s)
                      + 0.5 * min(max_motion, float(ml[n - 1]) * s) + s + 1)
        rows, first = [], 0
        for level in range(n):
            pad = 2 * self.reaches[level]
            nw = -(-self.width // 2**level) + 2 * pad
            nh = -(-self.height // 2**level) + 2 * pad
            rows.append((first, nw, nh, pad))
            first += self.layers * nw * nh
        self.levels = np.asarray(rows, np.int32)
        self.pixels = first
        self.pad = int(self.levels[0, 3])  # level 0's, what the composite reads

    def defines(self) -> dict:
        def floats(a):
            return ",".join(f"{float(v)!r}f" for v in a)

        return {"NLEV": self.nlev, "TR": floats(self.tr), "TM": floats(self.tm),
                "RL": floats(self.rl), "ML": floats(self.ml)}

    @property
    def image_bytes(self) -> int:
        return self.pixels * 16

    @property
    def bin_bytes(self) -> int:
        return self.pixels * 48


def bin_lanes(context: cl.Context) -> int:
    """Samples a step of the owner tiles' record loop (``BIN_VW``): 8 on a CPU, 1 elsewhere.

    PoCL 3.1 ran the scalar loop scalar (divisions and compares one sample at a time); the
    same expressions as float8 lanes took the bin pass of deep 1280x720 8 spp from 143-150 to
    91-93 ms (the halves': 186-193 to 134-145), and loading the lanes as vectors instead of
    gathers to 50-57 ms (the halves': 80-99)."""
    return 8 if cpu_context(context) else 1


def draw_local(context: cl.Context) -> tuple[int, int, int] | None:
    """The draw's work-group size: one owner tile a work-group on a CPU (None elsewhere: the
    implementation's choice).

    A tile's cost is its bins' PSFs, and the bins crowd where the frame's layers are; with a
    NULL local size the halves' draw ran only 1.24x faster on 2 threads than on 1 (likely:
    PoCL's own work-groups held several tiles, one core drawing a crowded group while the
    other idled). One tile a group lets its threads take the next tile as they finish:
    deep 1280x720 8 spp, the halves' draw 369 -> 291 ms (median of 5 paired runs, per-run
    ratios 0.69-0.88), bit-identical images (each tile adds in its own fixed order either
    way)."""
    return (1, 1, 1) if cpu_context(context) else None


class MipSplat:
    """The bin, draw and upsample passes of the mip plan (``scatter``: ``"tiles"``, owner
    tiles with plain adds, bit-reproducible; or ``"atomic"``, float atomics)."""

    def __init__(self, context: cl.Context, spp: int, has_motion: bool, geometry: MipGeometry,
                 scatter: str):
        self.geo, self.scatter, self.spp = geometry, scatter, int(spp)
        # the bin pass's owner tile (a kernel argument: one program serves every frame size)
        self.bin_tile = min(Splat.tile_size(0, geometry.shift, PHASES),
                            max(geometry.width, geometry.height))
        defines = {"SPP": spp, "HAS_MOTION": int(has_motion), "NLAYERS": geometry.layers,
                   **geometry.defines()}
        names = ("splat_mip_bin_tiles", "splat_mip_draw_tiles") if scatter == "tiles" else \
            ("splat_mip_bin_samples", "splat_mip_draw_bins")
        # the owner tiles' records, 8 samples a step as float8 lanes on a CPU
        self.bin_lanes = bin_lanes(context) if scatter == "tiles" else 1
        self._defines = {**defines, "BIN_VW": self.bin_lanes}
        self.bin_kernel = get_kernel(context, "splat_mip_bin", names[0], self._defines)
        self.draw_kernel = get_kernel(context, "splat_mip_draw", names[1], defines)
        self.up_kernel = get_kernel(context, "splat_mip_draw", "splat_mip_upsample", defines)
        self.draw_local = draw_local(context)
        self.levels = cl.Buffer(context, cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR,
                                hostbuf=geometry.levels)
        self._joint_kernel: cl.Kernel | None = None  # bin_joint's, built on first use
        self.events: list[tuple[str, cl.Event]] = []

    def bin_joint(self, queue, samples: DeviceSamples, inv_far: float, layer_scale: float,
                  bins: cl.Buffer, flags: cl.Buffer, bins_b: cl.Buffer, flags_b: cl.Buffer,
                  wait_for=None) -> cl.Event:
        """Both of the safeguard's equal halves of a whole frame in one pass (owner tiles):
        samples ``0 .. spp/2 - 1`` of each pixel into ``bins``/``flags``, the rest into
        ``bins_b``/``flags_b`` (each zero before), the same bins bit for bit as :meth:`bin`
        on each half's view. The frame's samples are read once, contiguously: a half's view
        reads every other run of each pixel's samples, and the two views together took
        1.7-1.8x the frame's own pass (deep 512x512, 8-64 spp, PoCL)."""
        if self.scatter != "tiles" or self.spp % 2 or samples.spp != self.spp \
                or samples.is_view:
            raise ValueError(f"bin_joint: the owner tiles' pass over a whole frame of an even "
                             f"spp ({self.spp}); got {samples.spp} spp"
                             + (", a view" if samples.is_view else "")
                             + f", scatter {self.scatter!r}")
        if self._joint_kernel is None:
            self._joint_kernel = get_kernel(queue.context, "splat_mip_bin",
                                            "splat_mip_bin_tiles",
                                            {**self._defines, "JOINT_HA": self.spp // 2})
        return self._bin_tiles(queue, self._joint_kernel, samples, inv_far, layer_scale, bins,
                               flags, wait_for, (bins_b, flags_b))

    def bin(self, queue, samples: DeviceSamples, inv_far: float, layer_scale: float,
            bins: cl.Buffer, wait_for=None, flags: cl.Buffer | None = None) -> cl.Event:
        """The samples into ``bins`` (zero before); the owner tiles also set ``flags``
        (``geo.pixels`` bytes, zero before) where a bin was added to."""
        if self.scatter == "tiles" and flags is None:
            raise ValueError("bin: the owner tiles need the bins' flags")
        if self.scatter == "atomic":
            return self._bin_atomic(queue, samples, inv_far, layer_scale, bins, wait_for)
        return self._bin_tiles(queue, self.bin_kernel, samples, inv_far, layer_scale, bins,
                               flags, wait_for)

    def _bin_args(self, samples: DeviceSamples, inv_far: float, layer_scale: float,
                  bins: cl.Buffer) -> list:
        c0, c1 = samples.coc
        # a view of a frame (the safeguard's halves) is read in place: samples.strided()
        _, stride, offset = samples.strided("color")
        args = [samples.strided(f)[0] for f in ("color", "position", "depth", "lens", "time",
                                                 "motion")]
        return args + [np.int32(stride), np.int32(offset), np.float32(c0), np.float32(c1),
                       np.float32(inv_far), np.float32(layer_scale), self.levels, bins]

    def _bin_atomic(self, queue, samples, inv_far, layer_scale, bins, wait_for) -> cl.Event:
        n = samples.width * samples.height * samples.spp
        self.bin_kernel.set_args(*self._bin_args(samples, inv_far, layer_scale, bins),
                                 np.int32(n))
        ev = cl.enqueue_nd_range_kernel(queue, self.bin_kernel, (n,), None, wait_for=wait_for)
        self.events = [("splat_mip_bin", ev)]
        return ev

    def _bin_tiles(self, queue, kernel, samples, inv_far, layer_scale, bins, flags, wait_for,
                   extra=()) -> cl.Event:
        w, h = samples.width, samples.height
        args = self._bin_args(samples, inv_far, layer_scale, bins)
        self.events = []
        k, tile = PHASES, self.bin_tile
        nx, ny = -(-w // tile), -(-h // tile)
        evs = wait_for
        for px, py, gx, gy in owner_phases(nx, ny, k):
            kernel.set_args(*args, np.int32(w), np.int32(h), np.int32(tile), np.int32(k),
                            np.int32(px), np.int32(py), flags, *extra)
            # one work-item per work-group: the tiles spread over the compute units
            ev = cl.enqueue_nd_range_kernel(queue, kernel, (gx, gy), (1, 1), wait_for=evs)
            self.events.append(("splat_mip_bin", ev))
            evs = [ev]
        return self.events[-1][1]

    def draw(self, queue, bins: cl.Buffer, img: cl.Buffer, wait_for=None,
             flags: cl.Buffer | None = None) -> cl.Event:
        """One PSF per non-empty bin into ``img``; each drawn bin (and with the owner tiles
        its flag) is zeroed."""
        if self.scatter == "tiles" and flags is None:
            raise ValueError("draw: the owner tiles need the bins' flags")
        g = self.geo
        # the widest level (a coarse level's larger pad can outgrow level 0 on tiny frames)
        nw, nh = int(g.levels[:, 1].max()), int(g.levels[:, 2].max())
        z = g.nlev * g.layers
        self.events = []
        if self.scatter == "atomic":
            self.draw_kernel.set_args(bins, img, self.levels)
            ev = cl.enqueue_nd_range_kernel(queue, self.draw_kernel, (nw, nh, z), None,
                                            wait_for=wait_for)
            self.events.append(("splat_mip_draw", ev))
            return ev
        k = PHASES
        tile = max((2 * g.reach - 1) // (k - 1) + 1, 8)
        nx, ny = -(-nw // tile), -(-nh // tile)
        evs = wait_for
        for px, py, gx, gy in owner_phases(nx, ny, k):
            self.draw_kernel.set_args(bins, img, self.levels, np.int32(tile), np.int32(k),
                                      np.int32(px), np.int32(py), flags)
            ev = cl.enqueue_nd_range_kernel(queue, self.draw_kernel, (gx, gy, z),
                                            self.draw_local, wait_for=evs)
            self.events.append(("splat_mip_draw", ev))
            evs = [ev]
        return self.events[-1][1]

    def upsample(self, queue, img: cl.Buffer, wait_for=None) -> cl.Event | None:
        g = self.geo
        self.events = []
        ev = None
        for level in range(g.nlev - 1, 0, -1):
            # the child's frame region and a margin (3 holds what the next level down reads)
            margin = 0 if level == 1 else UP_MARGIN
            _, nw, nh, pad = (int(v) for v in g.levels[level - 1])
            gx, gy = nw - 2 * pad + 2 * margin, nh - 2 * pad + 2 * margin
            self.up_kernel.set_args(img, self.levels, np.int32(level), np.int32(margin))
            ev = cl.enqueue_nd_range_kernel(queue, self.up_kernel, (gx, gy), None,
                                            wait_for=wait_for)
            self.events.append(("splat_mip_upsample", ev))
            wait_for = [ev]
        return ev
