"""Method ``layered`` at the numerical extremes of :mod:`extremes`, each mode and filter:
finite, non-negative, inside the inputs' range (every stage is a normalized non-negative
weighting and the composite a convex blend), energy-preserving on flat fields."""
from __future__ import annotations

import pytest
from extremes import CASES, IDS, check_output, make_frame

import clrecon

VARIANTS = [dict(), dict(filter="mip"), dict(mode="lrdm"), dict(stats_stride=1, tile=16)]
VIDS = ["sheared", "mip", "lrdm", "full-stats-tile16"]


@pytest.mark.parametrize("flat", [False, True], ids=["textured", "flat"])
@pytest.mark.parametrize("knobs", VARIANTS, ids=VIDS)
@pytest.mark.parametrize("case", CASES, ids=IDS)
def test_layered_extremes(device, case, knobs, flat):
    buf = make_frame(case, flat)
    img = clrecon.reconstruct(buf, "layered", device, **knobs, safeguard=False)
    check_output(img, buf, flat, f"layered {knobs}/{case.name}", convex=True)
