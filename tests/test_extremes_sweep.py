"""Method ``sweep`` at the numerical extremes of :mod:`extremes`, every variant: finite,
non-negative, inside the inputs' range (the sweep is a normalized weighting), energy-preserving
on flat fields, and within tolerance of the float64 NumPy reference of Appendices A/B."""
from __future__ import annotations

import pytest
from conftest import assert_close
from extremes import CASES, IDS, check_output, make_frame

import clrecon
from clrecon.sweep import reference as ref

VARIANTS = [dict(scales=2), dict(scales=4), dict(dof_layers=True), dict(scales=2, sort="pixel")]
VIDS = ["2-scale", "4-scale", "dof-layers", "2-scale-pixel"]


@pytest.mark.parametrize("flat", [False, True], ids=["textured", "flat"])
@pytest.mark.parametrize("knobs", VARIANTS, ids=VIDS)
@pytest.mark.parametrize("case", CASES, ids=IDS)
def test_sweep_extremes(device, case, knobs, flat):
    buf = make_frame(case, flat)
    img = clrecon.reconstruct(buf, "sweep", device, **knobs)
    what = f"sweep {knobs}/{case.name}"
    check_output(img, buf, flat, what, convex=True)
    plain = {k: v for k, v in knobs.items() if k != "sort"}
    want = ref.reconstruct(buf, smooth_motion=buf.inspect().has_motion, **plain)
    # relative to the frame's largest colour: HDR cases put 1e6 beside 1e-3
    assert_close(img, want, rtol=1e-3, atol=1e-5 * float(buf.color.max()), what=what)
