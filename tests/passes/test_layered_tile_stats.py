"""Pass ``tile_stats`` against the NumPy reference: full and sparse statistics."""
from __future__ import annotations

import numpy as np
import pytest
from conftest import assert_close
from layered_frames import LAYOUT, bucket_coeffs, empty, frame, read, upload

from clrecon.methods.layered import layout as geom
from clrecon.methods.layered import reference as ref
from clrecon.methods.layered.tile_stats import TileStats


def test_buckets_ordered_by_depth_and_spaced_in_coc(rng):
    buf = frame(rng)
    k = bucket_coeffs(buf)
    z = np.geomspace(2.2, 40.0, 2000)
    b = ref.buckets(z, *k, 32)
    assert (np.diff(b) >= 0).all() and b[0] == 0 and b[-1] == 30
    assert ref.buckets(np.array([np.inf]), *k, 32)[0] == 31
    coc = ref.coc_of(z, buf.coc_model.c0, buf.coc_model.c1)
    near_focus = np.abs(coc) < 1.0
    # near the focus plane a bucket spans at most bucket_coc (stretched) of CoC
    for v in np.unique(b[near_focus]):
        span = np.ptp(coc[near_focus & (b == v)])
        assert span <= 0.5 * 1.5


@pytest.mark.parametrize("stride,motion", [(1, True), (12, True), (5, False), (1, False)],
                         ids=["full", "sparse", "sparse-nomotion", "full-nomotion"])
def test_tile_stats_matches_reference(device, rng, stride, motion):
    buf = frame(rng, motion=motion)
    layout = geom.Layout(**{**LAYOUT.__dict__, "has_motion": motion})
    q = device.queue
    ntx, nty = layout.tiles(buf.width, buf.height)
    k = bucket_coeffs(buf, layout)
    stats = empty(q, (ntx * nty, layout.nbuckets, geom.NSTAT))
    ev = TileStats(device.context, layout)(q, upload(q, buf), k, stride, 7, stats)
    got = read(q, stats, (ntx * nty, layout.nbuckets, geom.NSTAT), [ev])
    want = ref.tile_stats(buf.depth, buf.motion, buf.coc_model.c0, buf.coc_model.c1, k, layout,
                          stride, 7)
    assert want[..., 0].sum() > 0
    if stride == 1:
        assert want[..., 0].sum() == buf.depth.size
    else:
        assert want[..., 0].sum() < buf.depth.size / stride * 1.2
    assert_close(got, want, rtol=1e-4, atol=1e-3, what="stats")


def test_sparse_addresses_are_stratified_and_seeded():
    a = ref.stat_addresses(3, LAYOUT, 12, seed=1)
    assert len(a) == 16 * 16 * 4 // 12 + 1
    assert ((a // 12) == np.arange(len(a))).all()  # one address per run of 12
    assert (ref.stat_addresses(3, LAYOUT, 12, seed=1) == a).all()
    assert (ref.stat_addresses(3, LAYOUT, 12, seed=2) != a).any()
