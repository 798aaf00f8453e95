"""Method ``sweep`` at the numerical extremes of :mod:`extremes`, every variant: finite,
non-negative, inside the inputs' range (the sweep is a normalized weighting), energy-preserving
on flat fields, and within tolerance of the float64 NumPy reference of Appendices A/B."""
from __future__ import annotations

import numpy as np
import pytest
from conftest import assert_close
from extremes import FLAT, check_output, method_extremes_test

import clrecon
from clrecon.core.samples import SampleBuffer
from clrecon.methods.sweep import reference as ref

VARIANTS = [dict(scales=2), dict(scales=4), dict(dof_layers=True), dict(scales=2, sort="pixel")]
VIDS = ["2-scale", "4-scale", "dof-layers", "2-scale-pixel"]


def _matches_reference(img, buf, knobs, what):
    """Within tolerance of the float64 reference of Appendices A/B."""
    plain = {k: v for k, v in knobs.items() if k != "sort"}
    want = ref.reconstruct(buf, smooth_motion=buf.inspect().has_motion, **plain)
    # relative to the frame's largest colour: HDR cases put 1e6 beside 1e-3
    assert_close(img, want, rtol=1e-3, atol=1e-5 * float(buf.color.max()), what=what)


test_sweep_extremes = method_extremes_test("sweep", VARIANTS, VIDS, convex=True,
                                           also=_matches_reference)


@pytest.mark.parametrize("corner", [(-0.5, -0.5), (0.5, 0.5), (-0.5, 0.5)], ids=str)
@pytest.mark.parametrize("knobs", VARIANTS, ids=VIDS)
def test_samples_on_pixel_edges(device, knobs, corner):
    """Validation accepts a sample on its pixel's edge; it must count for that pixel (it once
    counted for none: 0/0 at 1 spp)."""
    buf = SampleBuffer.zeros(6, 7, 1)  # 1 spp, in focus, static: each pixel has one sample
    buf.color[:] = FLAT
    buf.position[:] += np.float32(corner)
    buf.validate()
    img = clrecon.reconstruct(buf, "sweep", device, **knobs, safeguard=False)
    check_output(img, buf, True, f"sweep {knobs} on pixel corners", convex=True)
    plain = {k: v for k, v in knobs.items() if k != "sort"}
    assert_close(img, ref.reconstruct(buf, smooth_motion=False, **plain), rtol=1e-5,
                 what="vs reference")
