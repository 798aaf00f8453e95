"""Pass ``reproject`` against the NumPy reference: own/behind channels, guard band, scale."""
from __future__ import annotations

import numpy as np
import pyopencl as cl
import pytest
from conftest import assert_close
from layered_frames import LAYOUT, bucket_coeffs, empty, fields, frame, read, to_device, upload

from clrecon.core.local_size import LocalSize
from clrecon.methods.layered import layout as geom
from clrecon.methods.layered import reference as ref
from clrecon.methods.layered.reproject import Reproject


def params_of(buf, layout, threshold=0.1, sigma_x=0.33):
    st = ref.tile_stats(buf.depth, buf.motion, buf.coc_model.c0, buf.coc_model.c1,
                        bucket_coeffs(buf, layout), layout, 1)
    return ref.partition_setup(st, layout, sigma_x, threshold).astype(np.float32)


def frame_and_params(rng, spp):
    """A random frame of ``spp`` samples, its layout, partitions, grid shape and bucket
    coefficients."""
    buf = frame(rng, s=spp)
    layout = geom.Layout(**{**LAYOUT.__dict__, "spp": spp})
    params = params_of(buf, layout)
    shape = params.shape[:2] + (geom.NCH, layout.dmax * layout.dmax)
    return buf, layout, params, shape, bucket_coeffs(buf, layout)


def assert_grids_close(got, want):
    assert_close(np.concatenate([x.ravel() for x in got]),
                 np.concatenate([x.ravel() for x in want]), rtol=1e-4, atol=2e-4, what="grids")


@pytest.mark.parametrize("bilinear,wg,motion,sub", [(False, 1, True, 8), (True, 1, True, 8),
                                                    (False, 16, True, 8),
                                                    (True, 8, False, 8),
                                                    (False, 1, True, False),
                                                    (False, 1, True, 2)],
                         ids=["nearest", "bilinear", "nearest-atomic", "bilinear-atomic-nomo",
                              "no-subsample", "subsample-2"])
def test_reproject_matches_reference(device, rng, bilinear, wg, motion, sub):
    buf = frame(rng, motion=motion)
    layout = geom.Layout(**{**LAYOUT.__dict__, "has_motion": motion})
    params = params_of(buf, layout)
    assert (params[..., geom.P_SCALE] > 1).any()  # coarse grids (and subsampling) occur
    q = device.queue
    shape = params.shape[:2] + (geom.NCH, layout.dmax * layout.dmax)
    grids = empty(q, shape)
    k = bucket_coeffs(buf, layout)
    ev = Reproject(device.context, layout, bilinear, LocalSize(wg, 1), sub)(
        q, upload(q, buf), k, to_device(q, params), grids)
    got = read(q, grids, shape, [ev])
    want = ref.reproject(fields(buf), params.astype(np.float64), k, layout, bilinear, sub)
    g, w = ref.used_grid(got, params), ref.used_grid(want, params)
    assert sum(x[4].sum() for x in w) > 0 and sum(x[3].sum() for x in w) > 0
    # own weight: every sample of the tile lands in exactly one slot of its tile (or the band)
    assert_grids_close(g, w)


@pytest.mark.parametrize("spp", [1, 3, 8, 16])
def test_reproject_every_vector_width_matches_reference(device, rng, spp):
    """The kernel reprojects a pixel's samples 8 or 4 at a time (SIMD) when spp allows, one at
    a time otherwise: every width must give the reference's grids."""
    buf, layout, params, shape, k = frame_and_params(rng, spp)
    q = device.queue
    grids = empty(q, shape)
    ev = Reproject(device.context, layout, False, LocalSize(1, 1))(
        q, upload(q, buf), k, to_device(q, params), grids)
    got = read(q, grids, shape, [ev])
    want = ref.reproject(fields(buf), params.astype(np.float64), k, layout)
    g, w = ref.used_grid(got, params), ref.used_grid(want, params)
    assert sum(x[3].sum() for x in w) > 0
    assert_grids_close(g, w)


def test_reprojection_of_one_sample():
    """A sample at (5.3, 6.1) with lens (0.5, 0), t = 1, CoC-mean 2 and motion (4, 0)
    lands at x' = 5.3 - 2 * 0.5 - 0.5 * 4 = 2.3 (grid x = 2.3 + G)."""
    layout = geom.Layout(tile=8, nbuckets=4, maxp=1, gmax=4, spp=1)
    p = np.zeros((1, 1, geom.NPAR))
    at = [geom.P_HI, geom.P_A, geom.P_BX, geom.P_SCALE, geom.P_GUARD, geom.P_REACH, geom.P_DIM]
    p[0, 0, at] = [3, 2.0, 4.0, 1, 4, 8, 16]
    f = {"color": np.ones((8, 8, 1, 3), np.float32), "position": np.zeros((8, 8, 1, 2)),
         "depth": np.full((8, 8, 1), 5.0), "lens": np.zeros((8, 8, 1, 2)),
         "time": np.zeros((8, 8, 1)), "motion": np.zeros((8, 8, 1, 2))}
    f["depth"][:] = np.inf  # misses: bucket 3, own partition
    f["color"][:] = 0.0
    f["color"][6, 5, 0] = 1.0
    f["position"][6, 5, 0] = (5.3, 6.1)
    f["lens"][6, 5, 0] = (0.5, 0.0)
    f["time"][6, 5, 0] = 1.0
    g = ref.reproject(f, p, (0.0, 0.0, 0.0), layout)[0, 0, 0].reshape(-1)[:256].reshape(16, 16)
    assert g[6 + 4, 2 + 4] == 1.0 and g.sum() == 1.0


@pytest.mark.parametrize("spp", [3, 4, 8])
def test_reproject_buckets_are_the_references(device, rng, spp):
    """reproject_buckets writes every sample's depth bucket (a byte, read by the slots instead
    of the depth): exactly the reference's, misses in the last bucket, for the scalar (spp 3)
    and both vector widths."""
    buf, layout, params, shape, k = frame_and_params(rng, spp)
    q = device.queue
    n = buf.depth.size
    buckets = cl.Buffer(device.context, cl.mem_flags.READ_WRITE, n)
    ev = Reproject(device.context, layout, False, LocalSize(1, 1))(
        q, upload(q, buf), k, to_device(q, params), empty(q, shape), buckets=buckets)
    got = np.empty(n, np.uint8)
    cl.enqueue_copy(q, got, buckets, wait_for=[ev]).wait()
    want = ref.buckets(buf.depth, *k, layout.nbuckets).ravel()
    assert (want == layout.nbuckets - 1).any() and len(np.unique(want)) > 3
    np.testing.assert_array_equal(got, want)


def test_reproject_refuses_a_short_buckets_buffer(device, rng):
    buf = frame(rng)
    params = params_of(buf, LAYOUT)
    q = device.queue
    shape = params.shape[:2] + (geom.NCH, LAYOUT.dmax * LAYOUT.dmax)
    short = cl.Buffer(device.context, cl.mem_flags.READ_WRITE, buf.depth.size - 1)
    with pytest.raises(ValueError, match=f"buckets: needs {buf.depth.size} bytes"):
        Reproject(device.context, LAYOUT)(q, upload(q, buf), bucket_coeffs(buf),
                                          to_device(q, params), empty(q, shape), buckets=short)


@pytest.mark.parametrize("spp", [4, 8])
def test_reproject_local_accumulation_gives_the_same_grids(device, rng, spp):
    """The owner of a slot adds its channels into local memory (a float4 and a float per cell)
    where they fit, else into the grids' planes: the same adds in the same order, so the same
    bits."""
    buf, layout, params, shape, k = frame_and_params(rng, spp)
    q = device.queue
    samples, dparams = upload(q, buf), to_device(q, params)
    got = {}
    for local_acc in (True, False):
        rp = Reproject(device.context, layout, False, LocalSize(1, 1), local_acc=local_acc)
        assert rp.local_acc is local_acc
        grids = empty(q, shape)
        got[local_acc] = ref.used_grid(read(q, grids, shape,
                                            [rp(q, samples, k, dparams, grids)]), params)
    want = ref.used_grid(ref.reproject(fields(buf), params.astype(np.float64), k, layout), params)
    assert sum(x[3].sum() for x in want) > 0
    for a, b in zip(got[True], got[False]):
        assert np.array_equal(a, b)
    assert_grids_close(got[True], want)


def test_reproject_local_accumulation_needs_the_room(device):
    layout = geom.Layout(tile=128, gmax=256)  # 20 * (640^2 + 8) bytes: beyond any local memory
    with pytest.raises(ValueError, match="local_acc: needs 8192160 bytes"):
        Reproject(device.context, layout, False, LocalSize(1, 1), local_acc=True)
