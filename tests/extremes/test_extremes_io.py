"""Sample IO at the numerical extremes of :mod:`extremes`: every case survives every format
(npz, EXR, TLFR binary and text) bit for bit, HDR colours and both spellings of a miss
included. TLFR's two documented departures are checked as such: motion is stored times w
(one ulp on the way back) and a miss carries no motion."""
from __future__ import annotations

import numpy as np
import pytest
from extremes import CASES, IDS, make_frame

from clrecon.core.samples import FIELDS, MISS_DEPTH
from clrecon.io import load_samples, save_samples


@pytest.mark.parametrize("ext", [".npz", ".exr", ".bin", ".txt"])
@pytest.mark.parametrize("case", CASES, ids=IDS)
def test_round_trip_extremes(tmp_path, case, ext):
    buf = make_frame(case, flat=False)
    path = tmp_path / f"frame{ext}"
    save_samples(path, buf)
    back = load_samples(str(path)).validate()
    assert back.coc_model == buf.coc_model
    tlfr = ext in (".bin", ".txt")
    for name in FIELDS:
        got, want = getattr(back, name), getattr(buf, name)
        assert got.shape == want.shape and got.dtype == np.float32, name
        if name == "motion" and tlfr:
            hit = buf.depth < MISS_DEPTH
            assert (got[~hit] == 0).all(), "a TLFR miss has no motion"
            np.testing.assert_array_max_ulp(got[hit], want[hit], maxulp=1)
        elif name == "depth":
            # inf and 1e30 are both misses; a format may keep either spelling
            miss = want >= MISS_DEPTH
            assert (got[miss] >= MISS_DEPTH).all(), "a miss stays a miss"
            np.testing.assert_array_equal(got[~miss], want[~miss], err_msg=name)
        else:
            np.testing.assert_array_equal(got, want, err_msg=name)
