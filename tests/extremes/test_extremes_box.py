"""Method ``box`` at the numerical extremes of :mod:`extremes`: finite, non-negative, inside the
inputs' range, energy-preserving on flat fields, and equal to the float64 per-pixel mean."""
from __future__ import annotations

import numpy as np
import pytest
from conftest import assert_close
from extremes import CASES, IDS, check_output, make_frame

import clrecon


@pytest.mark.parametrize("flat", [False, True], ids=["textured", "flat"])
@pytest.mark.parametrize("case", CASES, ids=IDS)
def test_box_extremes(device, case, flat):
    buf = make_frame(case, flat)
    img = clrecon.reconstruct(buf, "box", device)
    check_output(img, buf, flat, f"box/{case.name}", convex=True)
    assert_close(img, buf.color.astype(np.float64).mean(2), rtol=1e-5, atol=1e-30,
                 what=f"box/{case.name} vs float64 mean")


def test_checks_can_fail():
    """The shared checks reject what they exist to reject."""
    case = CASES[0]
    buf = make_frame(case, flat=True)
    good = buf.color.mean(2)
    check_output(good, buf, True, "mean")
    for broken, match, convex in ((np.where(good > 0.4, np.nan, good), "non-finite", False),
                                  (good - 0.3, "negative", False),
                                  (good * 0.98, "flat-field", False),
                                  (good * 1.5, "outside", True)):
        with pytest.raises(AssertionError, match=match):
            check_output(broken.astype(np.float32), buf, True, "broken", convex=convex)
