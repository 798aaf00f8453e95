"""Numerical extremes shared by the per-method extremes suites (``test_extremes_<method>.py``).

Each case builds a valid frame that pushes one quantity to an extreme: CoC 0 and > 100 px,
motion 0, sub-pixel and > 300 px, depth at the near plane and misses (inf and 1e30), one depth
layer and many, HDR highlights of 1e4-1e6 beside black, 1x1, 1xN, Nx1 and odd image sizes,
1 and 64 spp, a frame of identical samples. Frames are random but seeded; sample positions
lie inside their pixels, lens points in the disk and times in [0, 1], so every frame passes
``validate()``. Geometry need not come from a real scene: the checks below hold for any
valid frame.

The checks every method must pass (:func:`check_output`): finite everywhere, no negative
radiance beyond float noise, and on the flat variant of a case (every sample one colour) the
image mean within 1% of that colour.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import pytest

import clrecon
from clrecon.core.camera import CocModel
from clrecon.core.samples import SampleBuffer

FLAT = np.array([0.25, 0.5, 1.0], np.float32)  # the flat-field colour


@dataclass(frozen=True)
class Case:
    name: str
    shape: tuple[int, int, int]  # (H, W, S)
    coc: CocModel
    depth: Callable[[np.random.Generator, tuple], np.ndarray]
    motion: float = 0.0  # std of the motion components, pixels (0: static)
    moving: float = 1.0  # fraction of samples that move
    hdr: bool = False
    identical: bool = False


def _uniform(lo, hi):
    return lambda rng, hws: rng.uniform(lo, hi, hws)


def _log_uniform(lo, hi):
    return lambda rng, hws: np.exp(rng.uniform(np.log(lo), np.log(hi), hws))


def _with_misses(inner, fraction=0.4):
    def depth(rng, hws):
        d = inner(rng, hws)
        r = rng.uniform(size=hws)
        d[r < fraction] = np.inf
        d[r < fraction / 4] = 1e30  # the other spelling of a miss
        return d
    return depth


def _all_miss(rng, hws):
    return np.full(hws, np.inf)


DEFOCUS = CocModel.from_focus(6.0, 8.0)  # |coc| up to ~4 px over depth 3..40

CASES: tuple[Case, ...] = (
    Case("coc0", (20, 24, 8), CocModel(), _uniform(1, 50)),
    Case("coc_over_100px", (20, 24, 8), CocModel.from_focus(150.0, 10.0), _uniform(1.2, 100)),
    Case("motion_subpixel", (20, 24, 8), DEFOCUS, _uniform(3, 40), motion=0.3),
    Case("motion_over_300px", (20, 24, 8), DEFOCUS, _uniform(3, 40), motion=350.0,
         moving=0.5),
    Case("near_plane", (20, 24, 8), DEFOCUS, _uniform(1e-4, 2e-3)),
    Case("misses", (20, 24, 8), DEFOCUS, _with_misses(_uniform(3, 40)), motion=2.0),
    Case("all_miss", (12, 16, 4), DEFOCUS, _all_miss),
    Case("one_layer", (20, 24, 8), DEFOCUS, lambda rng, hws: np.full(hws, 20.0)),
    Case("many_layers", (20, 24, 8), DEFOCUS, _log_uniform(0.5, 1e4), motion=3.0),
    Case("hdr", (20, 24, 8), DEFOCUS, _uniform(3, 40), motion=2.0, hdr=True),
    Case("size_1x1", (1, 1, 4), DEFOCUS, _uniform(3, 40), motion=2.0),
    Case("size_1xN", (1, 37, 4), DEFOCUS, _uniform(3, 40), motion=2.0),
    Case("size_Nx1", (37, 1, 4), DEFOCUS, _uniform(3, 40), motion=2.0),
    Case("size_odd", (33, 17, 4), DEFOCUS, _uniform(3, 40), motion=2.0),
    Case("spp1", (20, 24, 1), DEFOCUS, _uniform(3, 40), motion=2.0),
    Case("spp64", (8, 10, 64), DEFOCUS, _uniform(3, 40), motion=2.0),
    Case("identical", (16, 16, 8), DEFOCUS, lambda rng, hws: np.full(hws, 20.0),
         identical=True),
)

IDS = [c.name for c in CASES]


def make_frame(case: Case, flat: bool, seed: int = 7) -> SampleBuffer:
    """The case's frame; ``flat`` gives every sample the colour :data:`FLAT`."""
    rng = np.random.default_rng(seed)
    h, w, s = case.shape
    buf = SampleBuffer.zeros(h, w, s, case.coc)
    hws = (h, w, s)
    buf.depth[:] = case.depth(rng, hws)
    if case.identical:
        buf.color[:] = FLAT if flat else np.float32([3.0, 0.5, 0.1])
        return buf.validate()
    buf.position[:] += rng.uniform(-0.5, 0.499, buf.position.shape)
    r = np.sqrt(rng.uniform(0, 1, hws))
    a = rng.uniform(0, 2 * np.pi, hws)
    buf.lens[:] = np.stack([r * np.cos(a), r * np.sin(a)], -1)
    buf.time[:] = rng.uniform(0, 1, hws)
    if case.motion:
        moving = rng.uniform(size=hws) < case.moving
        buf.motion[:] = np.where(moving[..., None],
                                 rng.normal(0, case.motion, buf.motion.shape), 0.0)
    if flat:
        buf.color[:] = FLAT
    elif case.hdr:
        buf.color[:] = 0.0
        hot = rng.uniform(size=hws) < 0.02
        buf.color[hot] = 10.0 ** rng.uniform(4, 6, (int(hot.sum()), 1))
        buf.color[~hot & (rng.uniform(size=hws) < 0.3)] = 1e-3
    else:
        buf.color[:] = rng.exponential(1.0, buf.color.shape)
    return buf.validate()


def check_output(image: np.ndarray, buf: SampleBuffer, flat: bool, what: str,
                 convex: bool = False) -> None:
    """The checks every method passes on every case (see the module docstring).

    ``convex``: the method is a normalized non-negative weighting of the input samples, so
    every output pixel also lies within the inputs' per-channel range (float rounding aside).
    """
    h, w, _ = buf.shape
    assert image.shape == (h, w, 3), f"{what}: shape {image.shape}"
    bad = ~np.isfinite(image)
    assert not bad.any(), f"{what}: {int(bad.sum())} non-finite values, first at " \
                          f"{np.argwhere(bad)[0].tolist()}"
    scale = max(float(buf.color.max()), 1e-30)
    assert image.min() >= -1e-5 * scale, f"{what}: negative radiance {image.min():.3g}"
    if convex:
        lo = buf.color.reshape(-1, 3).min(0)
        hi = buf.color.reshape(-1, 3).max(0)
        tol = 1e-5 * np.maximum(np.abs(hi), 1e-30)
        assert (image >= lo - tol).all() and (image <= hi + tol).all(), \
            f"{what}: outside the inputs' range [{lo}, {hi}]: [{image.min()}, {image.max()}]"
    if flat:
        mean = image.reshape(-1, 3).mean(0)
        rel = np.abs(mean / FLAT - 1)
        assert (rel <= 0.01).all(), f"{what}: flat-field mean {mean} vs {FLAT} " \
                                    f"(relative error {rel.max():.3%})"


def method_extremes_test(method: str, variants: list[dict], ids: list[str],
                         convex: bool = False, also: Callable | None = None) -> Callable:
    """The extremes test of ``method``: every case, knob variant and textured/flat frame,
    reconstructed without the safeguard and held to :func:`check_output`; ``also(img, buf,
    knobs, what)`` adds a method's own checks. Bind it to a ``test_*`` name in the method's
    suite."""
    @pytest.mark.parametrize("flat", [False, True], ids=["textured", "flat"])
    @pytest.mark.parametrize("knobs", variants, ids=ids)
    @pytest.mark.parametrize("case", CASES, ids=IDS)
    def test(device, case, knobs, flat):
        buf = make_frame(case, flat)
        img = clrecon.reconstruct(buf, method, device, **knobs, safeguard=False)
        what = f"{method} {knobs}/{case.name}"
        check_output(img, buf, flat, what, convex=convex)
        if also is not None:
            also(img, buf, knobs, what)

    return test
