"""Method ``splat`` at the numerical extremes of :mod:`extremes` (the lead's suite), every
main variant: finite, non-negative, energy-preserving on flat fields."""
from __future__ import annotations

import pytest
from extremes import CASES, IDS, check_output, make_frame

import clrecon

VARIANTS = [dict(), dict(psf="combined", layers=2, pyramid="f5"), dict(scatter="atomic"),
            dict(dense=True, layers=1)]
VIDS = ["auto", "combined-f5", "atomic", "dense"]


@pytest.mark.parametrize("flat", [False, True], ids=["textured", "flat"])
@pytest.mark.parametrize("knobs", VARIANTS, ids=VIDS)
@pytest.mark.parametrize("case", CASES, ids=IDS)
def test_splat_extremes(device, case, knobs, flat):
    buf = make_frame(case, flat)
    img = clrecon.reconstruct(buf, "splat", device, **knobs, safeguard=False)
    check_output(img, buf, flat, f"splat {knobs}/{case.name}")
