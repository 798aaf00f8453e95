"""Pass ``layered_composite`` against the NumPy reference; the blending rule on hand-made layers."""
from __future__ import annotations

import numpy as np
import pytest
from conftest import assert_close
from layered_frames import LAYOUT, bucket_coeffs, empty, fields, frame, read, to_device
from test_layered_reproject import params_of

from clrecon.methods.layered import layout as geom
from clrecon.methods.layered import reference as ref
from clrecon.methods.layered.composite import LayeredComposite


@pytest.mark.parametrize("tile,width", [(16, 4), (16, 8), (16, 16), (8, 8), (2, 1)],
                         ids=["float4-lanes", "float8-lanes", "float16-lanes", "tile-8",
                              "one-pixel"])
@pytest.mark.parametrize("wide", [False, True], ids=["frame", "view"])
def test_composite_matches_reference(device, rng, tile, width, wide):
    """4, 8 or 16 pixels per work-item (tiles >= 4; 19 px wide, so the last set of lanes is
    partial) and one per work-item (tile 2) give the reference's image; so does a frame that
    is samples 2 .. 2 + S - 1 of a buffer with S + 3 per pixel (a view,
    DeviceSamples.strided), read where no layer covers (the pixel means)."""
    layout = geom.Layout(**{**LAYOUT.__dict__, "tile": tile})
    buf = frame(rng, h=35, w=19)
    params = params_of(buf, layout)
    p64 = params.astype(np.float64)
    grids = ref.reproject(fields(buf), p64, bucket_coeffs(buf, layout), layout)
    filtered = ref.filter_sheared_y(p64, ref.filter_sheared_x(p64, grids), layout)
    filtered[0, 0] = 0.0  # a tile whose front layer covers nothing
    filtered[1] = 0.0  # a tile whose layers cover nothing: its pixels are means
    s = buf.spp
    color, stride, offset = buf.color, s, 0
    if wide:
        color = rng.uniform(50.0, 60.0, (buf.height, buf.width, s + 3, 3)).astype(np.float32)
        color[:, :, 2:2 + s] = buf.color
        stride, offset = s + 3, 2
    q = device.queue
    out = empty(q, (buf.height, buf.width, 3))
    comp = LayeredComposite(device.context, layout, width=width)
    assert comp.width == width
    used = params[..., geom.P_DIM] > 0
    assert len(set(params[..., geom.P_SCALE][used].tolist())) > 1  # bilinear reads too
    ev = comp(
        q, to_device(q, color), to_device(q, params), to_device(q, filtered), buf.width,
        buf.height, out, sample_stride=stride, sample_offset=offset)
    got = read(q, out, (buf.height, buf.width, 3), [ev])
    want = ref.composite(buf.color, p64, filtered, layout)
    assert_close(got, want, rtol=1e-4, atol=1e-5, what="composite")


def test_composite_refuses_widths_it_cannot_run(device):
    for tile, width in [(16, 3), (16, 32), (8, 16), (2, 4)]:
        layout = geom.Layout(**{**LAYOUT.__dict__, "tile": tile})
        with pytest.raises(ValueError, match=f"{width} pixels a work-item with tile {tile}"):
            LayeredComposite(device.context, layout, width=width)


def test_front_to_back_blend():
    """Two layers: front opacity 0.25 red over an opaque blue: 0.25 red + 0.75 blue."""
    layout = geom.Layout(tile=2, nbuckets=4, maxp=2, gmax=2, spp=1)
    p = np.zeros((1, 2, geom.NPAR))
    p[0, :, geom.P_DIM] = 6
    p[0, :, geom.P_SCALE] = 1
    f = np.zeros((1, 2, geom.NCH, 16))
    f[0, 0, :, :] = np.array([1.0, 0, 0, 1.0, 3.0])[:, None]  # w 1, behind 3, colour sum 1
    f[0, 1, :, :] = np.array([0, 0, 2.0, 2.0, 0.0])[:, None]
    img = ref.composite(np.zeros((2, 2, 1, 3)), p, f, layout)
    assert_close(img, np.broadcast_to([0.25, 0, 0.75], (2, 2, 3)), what="blend")
    f[0, 1] = 0.0  # nothing behind: renormalised by the front layer's opacity
    img = ref.composite(np.zeros((2, 2, 1, 3)), p, f, layout)
    assert_close(img, np.broadcast_to([1.0, 0, 0], (2, 2, 3)), what="renormalised")
