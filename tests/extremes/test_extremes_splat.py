"""Method ``splat`` at the numerical extremes of :mod:`extremes` (the lead's suite), every
main variant: finite, non-negative, energy-preserving on flat fields."""
from __future__ import annotations

from extremes import method_extremes_test

VARIANTS = [dict(), dict(psf="combined", layers=2, pyramid="f5"), dict(scatter="atomic"),
            dict(dense=True, layers=1)]
VIDS = ["auto", "combined-f5", "atomic", "dense"]

test_splat_extremes = method_extremes_test("splat", VARIANTS, VIDS)
