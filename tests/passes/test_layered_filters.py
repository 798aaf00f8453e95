"""Passes ``filter_sheared`` (x recursive, y sheared Gaussian) and ``filter_rotated`` (LRDM)
against the NumPy reference, and the sheared decomposition against the rotated Gaussian."""
from __future__ import annotations

import numpy as np
import pyopencl as cl
import pytest
from conftest import assert_close
from layered_frames import LAYOUT, bucket_coeffs, empty, fields, frame, read, to_device
from test_layered_reproject import params_of

from clrecon.methods.layered import layout as geom
from clrecon.methods.layered import reference as ref
from clrecon.methods.layered.filter_mip import FilterMip, atlas_layout
from clrecon.methods.layered.filter_rotated import FilterRotated
from clrecon.methods.layered.filter_sheared import FilterSheared, recursive_channels
from clrecon.methods.layered.passes import local_for
from clrecon.methods.layered.reference_filters import mip_pyramid


def inputs(rng, layout=LAYOUT):
    buf = frame(rng, h=33, w=20)
    params = params_of(buf, layout)
    grids = ref.reproject(fields(buf), params.astype(np.float64), bucket_coeffs(buf, layout),
                          layout)
    return params, grids


@pytest.mark.parametrize("lines,gmax,width", [(1, 8, 4), (4, 8, 8), (8, 8, 16), (8, 8, 4),
                                              (8, 72, 8)])
def test_filter_sheared_matches_reference(device, rng, lines, gmax, width):
    """Both passes against the reference, with the recursive filter run 1, 4 or 8 grid lines
    a work-item (the vector kernel's lanes; grids whose side is no multiple of the width
    leave a partial set of lanes) and the Gaussian 4, 8 or 16 outputs a work-item, and with
    a guard band so wide (DMAX 160) that the vector kernel filters one channel at a time."""
    layout = geom.Layout(**{**LAYOUT.__dict__, "gmax": gmax})
    params, grids = inputs(rng, layout)
    used = params[..., geom.P_DIM] > 0
    # both decompositions (the kernel's float4 lanes run along u or w), fine and coarse grids
    # (the wide guard band's frame plans one scale)
    assert set(params[..., geom.P_AXIS][used].tolist()) == {0.0, 1.0}
    assert len(set(params[..., geom.P_SCALE][used].tolist())) > (1 if gmax == 8 else 0)
    dims = set(params[..., geom.P_DIM][used].astype(int).tolist())
    if lines > 1:
        assert any(d % lines for d in dims), dims  # a partial set of lanes
        assert any(d > lines for d in dims), dims  # more than one work-item a grid
        # axis 0's full sets of lines move in lines x lines blocks and a transpose, the rest
        # of a line element by element: a grid with both
        ax0 = params[..., geom.P_DIM][used & (params[..., geom.P_AXIS] == 0)].astype(int)
        assert any(d >= lines for d in ax0.tolist()), ax0
        assert gmax != 8 or any(d >= 2 * lines and d % lines for d in ax0.tolist()), ax0
    q = device.queue
    nslots = params.shape[0] * params.shape[1]
    fshape = params.shape[:2] + (geom.NCH, layout.filtered_side ** 2)
    d_grids, filtered = to_device(q, grids), empty(q, fshape)
    fs = FilterSheared(device.context, layout, lines=lines, width=width)
    assert (fs.lines, fs.width) == (lines, width)
    channels = recursive_channels(layout.dmax, lines)
    assert channels == (1 if gmax == 72 else geom.NCH)
    ev = fs(q, to_device(q, params), d_grids, filtered, nslots)
    got_x = read(q, d_grids, grids.shape, [ev])
    got = read(q, filtered, fshape, [ev])
    p64 = params.astype(np.float64)
    want_x = ref.filter_sheared_x(p64, grids)
    want = ref.filter_sheared_y(p64, want_x, layout)
    assert_close(np.concatenate([g.ravel() for g in ref.used_grid(got_x, params)]),
                 np.concatenate([g.ravel() for g in ref.used_grid(want_x, params)]),
                 rtol=1e-4, atol=1e-4, what="sheared x")
    assert_close(np.concatenate([g.ravel() for g in ref.used_filtered(got, params, layout)]),
                 np.concatenate([g.ravel() for g in ref.used_filtered(want, params, layout)]),
                 rtol=1e-4, atol=1e-4, what="sheared y")


def test_filter_sheared_at_a_production_layout(device, rng):
    """The recursive filter's vector kernel at the default layout (DMAX 64: a 10 KB private
    array a work-item at 8 lines) over 256 slots, a 256x256 frame's: the launch on which
    PoCL 3.1, picking the local size itself (8 x 128), crashed inside the pipeline (here
    alone it ran; the kernel now runs 1 x 1). Every tile's first slot holds a grid
    (both axes, both scales); they must match the reference."""
    layout = geom.Layout(tile=32, nbuckets=32, maxp=4, gmax=16, spp=8, has_motion=True,
                         reach_max=96)
    assert layout.dmax == 64
    fields = (geom.P_SHU, geom.P_SHV, geom.P_BETA, geom.P_AXIS)
    params, grids = crafted_slots(rng, layout, fields,
                                  [(3.0, 1.5, 0.3, 0, 1, 16), (2.0, 1.0, -0.4, 1, 2, 9),
                                   (0.7, 0.5, 0.0, 1, 1, 4), (5.0, 2.0, 0.1, 0, 1, 16)] * 16)
    q = device.queue
    nslots = params.shape[0] * params.shape[1]
    assert nslots == 256
    fshape = params.shape[:2] + (geom.NCH, layout.filtered_side ** 2)
    d_params, d_grids = to_device(q, params), to_device(q, grids)
    filtered = empty(q, fshape)
    for lines in (1, 8):
        cl.enqueue_copy(q, d_grids, grids)
        fs = FilterSheared(device.context, layout, lines=lines)
        ev = fs(q, d_params, d_grids, filtered, nslots)
        got = read(q, filtered, fshape, [ev])
        p64 = params.astype(np.float64)
        want = ref.filter_sheared_y(p64, ref.filter_sheared_x(p64, grids), layout)
        assert_filtered_close(got, want, params, layout, 1e-4, f"{lines} lines",
                              relative=True)


def test_filter_sheared_refuses_other_line_counts(device):
    for lines in (3, 16):
        with pytest.raises(ValueError, match=f"{lines} lines a work-item"):
            FilterSheared(device.context, LAYOUT, lines=lines)
    for width in (1, 6, 32):
        with pytest.raises(ValueError, match=f"{width} outputs a work-item"):
            FilterSheared(device.context, LAYOUT, width=width)


def crafted_slots(rng, layout, fields, slots):
    """Params with slot 0 of tile t set from ``slots[t]`` (values for ``fields``, plus scale
    and guard last; None: empty), its grid of random values; every other slot empty."""
    params = np.zeros((len(slots), layout.maxp, geom.NPAR), np.float32)
    grids = np.zeros(params.shape[:2] + (geom.NCH, layout.dmax ** 2), np.float32)
    for t, values in enumerate(slots):
        if values is None:
            continue
        p = params[t, 0]
        p[list(fields) + [geom.P_SCALE, geom.P_GUARD]] = values
        dim = layout.tile // int(p[geom.P_SCALE]) + 2 * int(p[geom.P_GUARD])
        p[geom.P_DIM] = dim
        grids[t, 0, :, :dim * dim] = rng.random((geom.NCH, dim * dim))
    return params, grids


def assert_filtered_close(got, want, params, layout, tol, what, relative=False):
    """The used part of two filtered-slot arrays agree to ``tol`` (times the largest value of
    ``want`` with ``relative``)."""
    g = np.concatenate([x.ravel() for x in ref.used_filtered(got, params, layout)])
    w = np.concatenate([x.ravel() for x in ref.used_filtered(want, params, layout)])
    scale = max(np.abs(w).max(), 1e-6) if relative else 1.0
    assert_close(g / scale, w / scale, rtol=tol, atol=tol, what=what)


@pytest.mark.parametrize("width", [4, 8, 16])
@pytest.mark.parametrize("axis", [0, 1])
@pytest.mark.parametrize("beta", [-2.7, 0.4, 3.1])
def test_filter_sheared_y_where_shear_leaves_the_grid(device, rng, axis, beta, width):
    """A steep shear and a thin guard band move taps past every edge of the grid, where the
    kernel's vector lanes fall back to lane-by-lane taps; the result must still be the
    reference's (taps outside the grid dropped)."""
    layout = LAYOUT
    params, grids = crafted_slots(rng, layout, (geom.P_SHV, geom.P_BETA, geom.P_AXIS),
                                  [(2.3, beta, axis, 1, 3), (2.3, beta, axis, 2, 2)])
    q = device.queue
    fshape = params.shape[:2] + (geom.NCH, layout.filtered_side ** 2)
    filtered = empty(q, fshape)
    fs = FilterSheared(device.context, layout, width=width)
    d_params, d_grids = to_device(q, params), to_device(q, grids)  # alive until read
    fs.gauss.set_args(d_params, d_grids, filtered)
    side = layout.filtered_side
    gsz, loc = local_for(fs.local, (-(-side // width), side, params.shape[0] * layout.maxp))
    ev = cl.enqueue_nd_range_kernel(q, fs.gauss, gsz, loc)
    got = read(q, filtered, fshape, [ev])
    want = ref.filter_sheared_y(params.astype(np.float64), grids.astype(np.float64), layout)
    assert_filtered_close(got, want, params, layout, 1e-4, "sheared y at the edges")


def test_filter_rotated_matches_reference(device, rng):
    layout = geom.Layout(**{**LAYOUT.__dict__, "maxp": 2})
    params, grids = inputs(rng, layout)
    q = device.queue
    nslots = params.shape[0] * params.shape[1]
    fshape = params.shape[:2] + (geom.NCH, layout.filtered_side ** 2)
    filtered, tmp = empty(q, fshape), empty(q, grids.shape)
    ev = FilterRotated(device.context, layout)(q, to_device(q, params), to_device(q, grids), tmp,
                                               filtered, nslots)
    got = read(q, filtered, fshape, [ev])
    _, want = ref.filter_rotated(params.astype(np.float64), grids, layout)
    assert_close(np.concatenate([g.ravel() for g in ref.used_filtered(got, params, layout)]),
                 np.concatenate([g.ravel() for g in ref.used_filtered(want, params, layout)]),
                 rtol=2e-4, atol=2e-4, what="rotated")


@pytest.mark.parametrize("coc,motion", [(2.0, (5.0, 3.0)), (2.0, (3.0, 5.0)),
                                        (0.2, (12.0, 1.5)), (0.2, (1.0, -12.0))],
                         ids=["diag", "diag-steep", "thin-shallow", "thin-steep"])
def test_sheared_and_rotated_agree_on_an_impulse(coc, motion):
    """Both filters spread an impulse with the covariance of the partition (eq. 5 = eq. 7):
    second moments of the filtered impulse match S within the truncation/recursion error.
    The thin ellipses a few degrees off an axis are the case where eq. 9's form, one tap
    per row, collapsed to a point (the transposed form is chosen there)."""
    layout = geom.Layout(tile=16, nbuckets=4, maxp=1, gmax=16, spp=1)
    mx, my = motion
    s = np.array([1, coc, coc * coc, mx, my, mx * mx, my * my, mx * my])
    p = ref._params(s, 0, 3, 0.33, layout)[None, None]
    assert p[0, 0, geom.P_SCALE] == 1
    dim = int(p[0, 0, geom.P_DIM])
    grids = np.zeros((1, 1, geom.NCH, layout.dmax ** 2))
    grids[0, 0, 3, (dim // 2) * dim + dim // 2] = 1.0
    sh = ref.filter_sheared_y(p, ref.filter_sheared_x(p, grids), layout)
    _, ro = ref.filter_rotated(p, grids, layout)
    su, sv, a, xy, b = ref.partition_filter(s, 0.33)
    n = layout.tile + 2
    yy, xx = np.mgrid[0:n, 0:n] - (dim // 2 - int(p[0, 0, geom.P_GUARD]) + 1)
    for img in (sh, ro):
        im = img[0, 0, 3].reshape(n, n)
        m = im / im.sum()
        cov = [(m * xx * xx).sum(), (m * xx * yy).sum(), (m * yy * yy).sum()]
        assert_close(cov, [a, xy, b], rtol=0.15, atol=0.15, what="impulse covariance")


def run_mip(device, layout, params, grids, images=False):
    """filter_mip (build and sample; with ``images`` through the atlas and the linear
    sampler) on the device: the filtered slots."""
    q = device.queue
    nslots = params.shape[0] * params.shape[1]
    fshape = params.shape[:2] + (geom.NCH, layout.filtered_side ** 2)
    filtered = empty(q, fshape)
    atlas = atlas_layout(device.context.devices[0], layout, nslots)[0] if images else None
    fm = FilterMip(device.context, layout, atlas=atlas)
    pyr = empty(q, (nslots, geom.NCH, fm.plane))
    d_params, d_grids = to_device(q, params), to_device(q, grids)  # alive until read
    ev = fm(q, d_params, d_grids, pyr, filtered, nslots)
    return read(q, filtered, fshape, [ev])


def test_filter_mip_matches_reference(device, rng):
    layout = geom.Layout(**{**LAYOUT.__dict__, "maxp": 2})
    params, grids = inputs(rng, layout)
    got = run_mip(device, layout, params, grids)
    want = ref.filter_mip(params.astype(np.float64), grids, layout)
    assert_filtered_close(got, want, params, layout, 2e-4, "mip")


@pytest.mark.parametrize("theta", [0.0, 0.6, 2.2])
def test_filter_mip_where_probes_leave_the_grid(device, rng, theta):
    """Long, thin footprints on a thin guard band put probes past the grid's edges and
    corners, where the kernel's four-texel fast path gives way to the texel-by-texel one."""
    layout = geom.Layout(**{**LAYOUT.__dict__, "maxp": 2})
    c, s = np.cos(theta), np.sin(theta)
    params, grids = crafted_slots(rng, layout, (geom.P_SU, geom.P_SV, geom.P_COS, geom.P_SIN),
                                  [(9.0, 0.6, c, s, 1, 2), (14.0, 3.0, c, s, 2, 3)])
    got = run_mip(device, layout, params, grids)
    want = ref.filter_mip(params.astype(np.float64), grids.astype(np.float64), layout)
    assert_filtered_close(got, want, params, layout, 2e-4, "mip at the edges")


#: the image variant interpolates with the sampler's own fraction: float on PoCL, a few
#: bits on GPUs (8 on NVIDIA: 1/256 of a texel step)
IMAGE_TOL = 4e-3


@pytest.mark.parametrize("edges", [False, True], ids=["frame", "edges"])
def test_filter_mip_images_match_reference(device, rng, edges):
    """The atlas and linear-sampler variant gives the reference's filtered slots, inside
    the grid and where probes leave it (the zero ring)."""
    if not device.info.image_support:
        pytest.skip("device without image support")
    layout = geom.Layout(**{**LAYOUT.__dict__, "maxp": 2})
    if edges:
        params, grids = crafted_slots(
            rng, layout, (geom.P_SU, geom.P_SV, geom.P_COS, geom.P_SIN),
            [(9.0, 0.6, 1.0, 0.0, 1, 2), (14.0, 3.0, 0.8, 0.6, 2, 3), (3.0, 2.0, 0.6, 0.8, 1, 4)])
    else:
        params, grids = inputs(rng, layout)
    got = run_mip(device, layout, params, grids, images=True)
    want = ref.filter_mip(params.astype(np.float64), grids.astype(np.float64), layout)
    assert_filtered_close(got, want, params, layout, IMAGE_TOL, "mip images", relative=True)


def test_mip_atlas_layout():
    """Level boxes of a DMAX grid fit their slot's region, regions tile the atlas."""
    for dmax in (6, 20, 64, 96):
        nlev, _ = geom.mip_levels(dmax)
        a = geom.mip_atlas(dmax, nlev, 37, 512)
        boxes = [-(-dmax // (1 << lv)) + 2 for lv in range(nlev)]
        assert a["rw"] >= boxes[0] + (boxes[1] if nlev > 1 else 0) + (boxes[2] if nlev > 2 else 0)
        assert a["rh"] >= boxes[0] and a["rh"] >= sum(boxes[2:])
        assert a["per_row"] * a["rw"] <= 512 or a["per_row"] == 1
        assert a["per_row"] * (a["height"] // a["rh"]) >= 37


def test_mip_pyramid_keeps_the_mean():
    planes = np.random.default_rng(3).uniform(size=(geom.NCH, 16, 16))
    levels = mip_pyramid(planes)
    assert [lv.shape[-1] for lv in levels] == [16, 8, 4, 2, 1]
    assert_close([lv.mean() for lv in levels], [planes.mean()] * 5, rtol=1e-12, what="mean")
