"""Invalid input through every registered method: the validation error naming the field and
the first bad sample, never a silent wrong image."""
from __future__ import annotations

import numpy as np
import pytest
from extremes import CASES, make_frame

import clrecon
from clrecon.api import METHODS

BREAKS = {
    "color": lambda b: b.color.__setitem__((1, 2, 0, 1), np.nan),
    "depth": lambda b: b.depth.__setitem__((1, 2, 0), -1.0),
    "lens": lambda b: b.lens.__setitem__((1, 2, 0), (0.9, 0.9)),
    "time": lambda b: b.time.__setitem__((1, 2, 0), 1.5),
    "motion": lambda b: b.motion.__setitem__((1, 2, 0, 0), np.inf),
    "position": lambda b: b.position.__setitem__((1, 2, 0, 0), 7.5),
}


@pytest.mark.parametrize("field", sorted(BREAKS))
@pytest.mark.parametrize("method", sorted(METHODS))
def test_invalid_input_raises(device, method, field):
    buf = make_frame(CASES[2], flat=False)
    BREAKS[field](buf)
    with pytest.raises(ValueError, match=rf"{field}: sample \(y=1, x=2, i=0\)"):
        clrecon.reconstruct(buf, method, device)
