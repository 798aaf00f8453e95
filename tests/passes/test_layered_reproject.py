"""Pass ``reproject`` against the NumPy reference: own/behind channels, guard band, scale."""
from __future__ import annotations

import numpy as np
import pyopencl as cl
import pytest
from conftest import assert_close
from layered_frames import LAY, empty, fields, frame, kabc, read, to_device, upload

from clrecon.core.pipeline import LocalSize
from clrecon.methods.layered import reference as ref
from clrecon.methods.layered.reproject import Reproject


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


@pytest.mark.parametrize("spp", [3, 4, 8])
def test_reproject_buckets_are_the_references(device, rng, spp):
    """reproject_buckets writes every sample's depth bucket (a byte, read by the slots instead
    of the depth): exactly the reference's, misses in the last bucket, for the scalar (spp 3)
    and both vector widths."""
    buf = frame(rng, s=spp)
    lay = ref.Layout(**{**LAY.__dict__, "spp": spp})
    params = params_of(buf, lay)
    q = device.queue
    shape = params.shape[:2] + (ref.NCH, lay.dmax * lay.dmax)
    k = kabc(buf, lay)
    n = buf.depth.size
    buckets = cl.Buffer(device.context, cl.mem_flags.READ_WRITE, n)
    ev = Reproject(device.context, lay, False, LocalSize(1, 1))(
        q, upload(q, buf), k, to_device(q, params), empty(q, shape), buckets=buckets)
    got = np.empty(n, np.uint8)
    cl.enqueue_copy(q, got, buckets, wait_for=[ev]).wait()
    want = ref.buckets(buf.depth, *k, lay.nbuckets).ravel()
    assert (want == lay.nbuckets - 1).any() and len(np.unique(want)) > 3
    np.testing.assert_array_equal(got, want)


def test_reproject_refuses_a_short_buckets_buffer(device, rng):
    buf = frame(rng)
    params = params_of(buf, LAY)
    q = device.queue
    shape = params.shape[:2] + (ref.NCH, LAY.dmax * LAY.dmax)
    short = cl.Buffer(device.context, cl.mem_flags.READ_WRITE, buf.depth.size - 1)
    with pytest.raises(ValueError, match=f"buckets: needs {buf.depth.size} bytes"):
        Reproject(device.context, LAY)(q, upload(q, buf), kabc(buf), to_device(q, params),
                                       empty(q, shape), buckets=short)


@pytest.mark.parametrize("spp", [4, 8])
def test_reproject_local_accumulation_gives_the_same_grids(device, rng, spp):
    """The owner of a slot adds its own channels into local memory (a float4 per cell) where
    it fits, else into the grids' planes: the same adds in the same order, so the same bits."""
    buf = frame(rng, s=spp)
    lay = ref.Layout(**{**LAY.__dict__, "spp": spp})
    params = params_of(buf, lay)
    q = device.queue
    shape = params.shape[:2] + (ref.NCH, lay.dmax * lay.dmax)
    k = kabc(buf, lay)
    samples, dparams = upload(q, buf), to_device(q, params)
    got = {}
    for local_acc in (True, False):
        rp = Reproject(device.context, lay, False, LocalSize(1, 1), local_acc=local_acc)
        assert rp.local_acc is local_acc
        grids = empty(q, shape)
        got[local_acc] = ref.used_grid(read(q, grids, shape,
                                            [rp(q, samples, k, dparams, grids)]), params)
    want = ref.used_grid(ref.reproject(fields(buf), params.astype(np.float64), k, lay), params)
    assert sum(x[3].sum() for x in want) > 0
    for a, b in zip(got[True], got[False]):
        assert np.array_equal(a, b)
    assert_close(np.concatenate([x.ravel() for x in got[True]]),
                 np.concatenate([x.ravel() for x in want]), rtol=1e-4, atol=2e-4, what="grids")


def test_reproject_local_accumulation_needs_the_room(device):
    lay = ref.Layout(tile=128, gmax=256)  # 16 * 640^2 bytes: beyond any device's local memory
    with pytest.raises(ValueError, match="local_acc: needs 6553600 bytes"):
        Reproject(device.context, lay, False, LocalSize(1, 1), local_acc=True)
