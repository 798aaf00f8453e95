"""Pass ``partition_setup`` against the NumPy reference; merging and filter derivation."""
from __future__ import annotations

import numpy as np
import pytest
from conftest import assert_close
from layered_frames import LAYOUT, bucket_coeffs, empty, frame, read, to_device

from clrecon.methods.layered import layout as geom
from clrecon.methods.layered import reference as ref
from clrecon.methods.layered.partition_setup import PartitionSetup


def stats_of(buf, layout=LAYOUT, stride=1):
    return ref.tile_stats(buf.depth, buf.motion, buf.coc_model.c0, buf.coc_model.c1,
                          bucket_coeffs(buf, layout), layout, stride).astype(np.float32)


def run_setup(device, layout, stats, sigma_x=0.33, threshold=0.1):
    q = device.queue
    nt = stats.shape[0]
    params = empty(q, (nt, layout.maxp, geom.NPAR))
    ev = PartitionSetup(device.context, layout)(q, to_device(q, stats), nt, sigma_x, threshold,
                                                params)
    return read(q, params, (nt, layout.maxp, geom.NPAR), [ev])


@pytest.mark.parametrize("threshold,maxp", [(0.1, 4), (-1.0, 4), (0.3, 2), (-1.0, 8)],
                         ids=["merge", "nomerge-cap", "merge-cap2", "nomerge"])
def test_partition_setup_matches_reference(device, rng, threshold, maxp):
    buf = frame(rng)
    layout = geom.Layout(**{**LAYOUT.__dict__, "maxp": maxp})
    stats = stats_of(buf, layout)
    got = run_setup(device, layout, stats, threshold=threshold)
    want = ref.partition_setup(stats.astype(np.float64), layout, 0.33, threshold)
    assert (want[..., geom.P_DIM] > 0).sum() > stats.shape[0]  # several partitions per tile
    # theta is ill-conditioned where the filter is nearly isotropic (float32 vs float64)
    iso = (want[..., geom.P_SU] - want[..., geom.P_SV]) < 1e-2 * want[..., geom.P_SU]
    for k in (geom.P_COS, geom.P_SIN):
        got[..., k] = np.where(iso, want[..., k], got[..., k])
    assert (~iso & (want[..., geom.P_DIM] > 0)).sum() > 4  # anisotropic filters are compared
    assert_close(got, want, rtol=2e-4, atol=2e-4, what="params")


def test_partitions_cover_buckets_front_to_back(rng):
    buf = frame(rng)
    p = ref.partition_setup(stats_of(buf).astype(np.float64), LAYOUT, 0.33, 0.1)
    for tile in p:
        used = tile[tile[:, geom.P_DIM] > 0]
        assert used[0, geom.P_LO] == 0 and used[-1, geom.P_HI] == LAYOUT.nbuckets - 1
        assert (used[1:, geom.P_LO] == used[:-1, geom.P_HI] + 1).all()
        assert (used[:, geom.P_SU] >= used[:, geom.P_SV]).all()


def test_merging_reduces_partitions(rng):
    buf = frame(rng, h=64, w=64)
    stats = stats_of(buf).astype(np.float64)
    wide = geom.Layout(**{**LAYOUT.__dict__, "maxp": 16})
    n_off = (ref.partition_setup(stats, wide, 0.33, -1.0)[..., geom.P_DIM] > 0).sum()
    n_on = (ref.partition_setup(stats, wide, 0.33, 0.1)[..., geom.P_DIM] > 0).sum()
    assert n_on < n_off


def test_filter_of_known_partition():
    """Mean CoC 4 px, mean motion (6, 0): S = diag(4 + 36/12, 4) + sigma_x^2."""
    s = np.array([10, 40, 160, 60, 0, 360, 0, 0], float)
    su, sv, a, xy, b = ref.partition_filter(s, 0.33)
    assert np.isclose(su ** 2, 4 + 3 + 0.1089) and np.isclose(sv ** 2, 4 + 0.1089)
    layout = geom.Layout(tile=16, gmax=16)
    p = ref._params(s, 0, 5, 0.33, layout)  # 3 sigma_u = 7.999 px: G = 9 grid px at s = 1
    assert p[geom.P_SCALE] == 1 and p[geom.P_GUARD] == 9 and p[geom.P_DIM] == 34
    p = ref._params(s * [1, 10, 100, 1, 1, 1, 1, 1], 0, 5, 0.33, layout)  # CoC 40: coarser grid
    assert p[geom.P_SCALE] == 8 and p[geom.P_GUARD] == 9  # 3 sigma_u = 60 px


def test_empty_tile_gets_one_static_partition(device):
    layout = LAYOUT
    stats = np.zeros((2, layout.nbuckets, geom.NSTAT), np.float32)
    got = run_setup(device, layout, stats)
    assert (got[:, 0, geom.P_DIM] > 0).all() and (got[:, 1:, geom.P_DIM] == 0).all()
    assert (got[:, 0, geom.P_HI] == layout.nbuckets - 1).all()
    assert np.isclose(got[0, 0, geom.P_SU], 0.33, rtol=1e-4)
