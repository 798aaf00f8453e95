"""kernels/limits.h is the kernels' copy of clrecon/core/limits.py: the two must agree, to
the bit, or a kernel and the host would disagree on what a miss or a valid value is."""
from __future__ import annotations

import re

import numpy as np

from clrecon.core import limits
from clrecon.core.resources import kernels_dir

#: limits.h name -> (limits.py value, the C type it is compared in)
EXPECTED = {
    "MISS_DEPTH": (limits.MISS_DEPTH, np.float32),
    "POS_TOL": (limits.POSITION_TOLERANCE, np.float32),
    "LENS_R2_MAX": ((1 + limits.LENS_TOLERANCE) ** 2, np.float64),
    "MIN_DEPTH": (limits.MIN_DEPTH, np.float32),
    "COLOR_MAX": (limits.COLOR_MAX, np.float32),
    "MOTION_MAX": (limits.MOTION_MAX, np.float32),
}


def _defines() -> dict[str, str]:
    text = (kernels_dir() / "limits.h").read_text()
    return dict(re.findall(r"^#define (\w+) (\S+)", text, flags=re.M))


def test_limits_header_matches_the_library():
    found = _defines()
    assert set(EXPECTED) <= set(found), sorted(set(EXPECTED) - set(found))
    for name, (value, ctype) in EXPECTED.items():
        literal = found[name]
        assert literal.endswith("f") == (ctype is np.float32), (name, literal)
        parsed = ctype(float.fromhex(literal.rstrip("f")))
        assert parsed == ctype(value), (name, literal, ctype(value))


def test_no_kernel_defines_its_own_miss_depth():
    """One copy in the kernels: every other file includes limits.h."""
    own = [p.name for p in sorted(kernels_dir().glob("*.[ch]*"))
           if p.name != "limits.h" and re.search(r"#define \w*MISS_DEPTH\b", p.read_text())]
    assert not own, own
