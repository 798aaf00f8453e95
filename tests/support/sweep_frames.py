"""Frames shared by the sweep tests and the tests of its tuning and local-memory fits."""
from __future__ import annotations

from sample_frames import method_frame


def frame(rng, h=11, w=13, s=4, motion=True, ties=True):
    """Random valid frame: CoC from -7 to +7 px (D 0..14), optional motion, and depth ties
    (misses at inf and a repeated depth) so that the tie order is exercised."""
    return method_frame(rng, h, w, s, misses=ties, focus_ties=ties, motion=motion)
