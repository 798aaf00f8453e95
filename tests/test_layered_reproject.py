"""Pass ``reproject`` against the NumPy reference: own/behind channels, guard band, scale."""
from __future__ import annotations

import numpy as np
import pytest
from conftest import assert_close
from layered_frames import LAY, empty, fields, frame, kabc, read, to_device, upload

from clrecon.layered import reference as ref
from clrecon.layered.reproject import Reproject
from clrecon.pipeline import LocalSize


def params_of(buf, lay, threshold=0.1, sigma_x=0.33):
    st = ref.tile_stats(buf.depth, buf.motion, buf.coc_model.c0, buf.coc_model.c1,
                        kabc(buf, lay), lay, 1)
    return ref.partition_setup(st, lay, sigma_x, threshold).astype(np.float32)


@pytest.mark.parametrize("bilinear,wg,motion,sub", [(False, 1, True, True), (True, 1, True, True),
                                                    (False, 16, True, True),
                                                    (True, 8, False, True),
                                                    (False, 1, True, False),
                                                    (False, 1, True, 2)],
                         ids=["nearest", "bilinear", "nearest-atomic", "bilinear-atomic-nomo",
                              "no-subsample", "subsample-2"])
def test_reproject_matches_reference(device, rng, bilinear, wg, motion, sub):
    buf = frame(rng, motion=motion)
    lay = ref.Layout(**{**LAY.__dict__, "has_motion": motion})
    params = params_of(buf, lay)
    assert (params[..., ref.P_SCALE] > 1).any()  # coarse grids (and subsampling) occur
    q = device.queue
    shape = params.shape[:2] + (ref.NCH, lay.dmax * lay.dmax)
    grids = empty(q, shape)
    k = kabc(buf, lay)
    ev = Reproject(device.context, lay, bilinear, LocalSize(wg, 1), sub)(
        q, upload(q, buf), k, to_device(q, params), grids)
    got = read(q, grids, shape, [ev])
    want = ref.reproject(fields(buf), params.astype(np.float64), k, lay, bilinear, sub)
    g, w = ref.used_grid(got, params), ref.used_grid(want, params)
    assert sum(x[4].sum() for x in w) > 0 and sum(x[3].sum() for x in w) > 0
    # own weight: every sample of the tile lands in exactly one slot of its tile (or the band)
    assert_close(np.concatenate([x.ravel() for x in g]), np.concatenate([x.ravel() for x in w]),
                 rtol=1e-4, atol=2e-4, what="grids")


@pytest.mark.parametrize("spp", [1, 3, 8, 16])
def test_reproject_every_vector_width_matches_reference(device, rng, spp):
    """The kernel reprojects a pixel's samples 8 or 4 at a time (SIMD) when spp allows, one at
    a time otherwise: every width must give the reference's grids."""
    buf = frame(rng, s=spp)
    lay = ref.Layout(**{**LAY.__dict__, "spp": spp})
    params = params_of(buf, lay)
    q = device.queue
    shape = params.shape[:2] + (ref.NCH, lay.dmax * lay.dmax)
    grids = empty(q, shape)
    k = kabc(buf, lay)
    ev = Reproject(device.context, lay, False, LocalSize(1, 1))(
        q, upload(q, buf), k, to_device(q, params), grids)
    got = read(q, grids, shape, [ev])
    want = ref.reproject(fields(buf), params.astype(np.float64), k, lay)
    g, w = ref.used_grid(got, params), ref.used_grid(want, params)
    assert sum(x[3].sum() for x in w) > 0
    assert_close(np.concatenate([x.ravel() for x in g]), np.concatenate([x.ravel() for x in w]),
                 rtol=1e-4, atol=2e-4, what="grids")


def test_reprojection_of_one_sample():
    """A sample at (5.3, 6.1) with lens (0.5, 0), t = 1, CoC-mean 2 and motion (4, 0)
    lands at x' = 5.3 - 2 * 0.5 - 0.5 * 4 = 2.3 (grid x = 2.3 + G)."""
    lay = ref.Layout(tile=8, nbuckets=4, maxp=1, gmax=4, spp=1)
    p = np.zeros((1, 1, ref.NPAR))
    p[0, 0, [ref.P_HI, ref.P_A, ref.P_BX, ref.P_SCALE, ref.P_GUARD, ref.P_REACH, ref.P_DIM]] = \
        [3, 2.0, 4.0, 1, 4, 8, 16]
    f = {"color": np.ones((8, 8, 1, 3), np.float32), "position": np.zeros((8, 8, 1, 2)),
         "depth": np.full((8, 8, 1), 5.0), "lens": np.zeros((8, 8, 1, 2)),
         "time": np.zeros((8, 8, 1)), "motion": np.zeros((8, 8, 1, 2))}
    f["depth"][:] = np.inf  # misses: bucket 3, own partition
    f["color"][:] = 0.0
    f["color"][6, 5, 0] = 1.0
    f["position"][6, 5, 0] = (5.3, 6.1)
    f["lens"][6, 5, 0] = (0.5, 0.0)
    f["time"][6, 5, 0] = 1.0
    g = ref.reproject(f, p, (0.0, 0.0, 0.0), lay)[0, 0, 0].reshape(-1)[:256].reshape(16, 16)
    assert g[6 + 4, 2 + 4] == 1.0 and g.sum() == 1.0
