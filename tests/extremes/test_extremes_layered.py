"""Method ``layered`` at the numerical extremes of :mod:`extremes`, each mode and filter:
finite, non-negative, inside the inputs' range (every stage is a normalized non-negative
weighting and the composite a convex blend), energy-preserving on flat fields."""
from __future__ import annotations

from extremes import method_extremes_test

VARIANTS = [dict(), dict(filter="mip"), dict(mode="lrdm"), dict(stats_stride=1, tile=16)]
VIDS = ["sheared", "mip", "lrdm", "full-stats-tile16"]

test_layered_extremes = method_extremes_test("layered", VARIANTS, VIDS, convex=True)
