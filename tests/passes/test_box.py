"""Method ``box`` against its NumPy reference."""
from __future__ import annotations

import numpy as np
import pytest
from conftest import assert_close

import clrecon
from clrecon.api import make_pipeline
from clrecon.core.local_size import LocalSize
from clrecon.core.samples import SampleBuffer


def _random_buffer(rng, h, w, s):
    buf = SampleBuffer.zeros(h, w, s)
    buf.color[:] = rng.exponential(2.0, buf.color.shape).astype(np.float32)
    return buf


@pytest.mark.parametrize("shape", [(1, 1, 1), (3, 17, 4), (33, 20, 16), (8, 8, 64)],
                         ids=lambda s: "x".join(map(str, s)))
def test_box_matches_numpy(device, rng, shape):
    buf = _random_buffer(rng, *shape)
    got = clrecon.reconstruct(buf, method="box", device=device)
    assert got.shape == (shape[0], shape[1], 3) and got.dtype == np.float32
    assert_close(got, buf.color.astype(np.float64).mean(axis=2), rtol=1e-6, what="box")


@pytest.mark.parametrize("local", [LocalSize(16, 4), LocalSize(1, 1), LocalSize(None)],
                         ids=["16x4", "1x1", "runtime"])
def test_box_local_sizes_agree(device, rng, local):
    buf = _random_buffer(rng, 13, 29, 4)
    img = clrecon.run(buf, "box", device, local=local).image
    assert_close(img, buf.color.mean(axis=2), rtol=1e-6, what="box")


def test_reports_pass_times(device, rng):
    res = clrecon.run(_random_buffer(rng, 16, 16, 4), "box", device)
    assert set(res.pass_ms) == {"box"} and res.pass_ms["box"] >= 0
    assert res.method["method"] == "box"


def test_unknown_method_and_knob(device, rng):
    buf = _random_buffer(rng, 4, 4, 2)
    with pytest.raises(ValueError, match="unknown 'nope'"):
        clrecon.reconstruct(buf, method="nope", device=device)
    with pytest.raises(TypeError, match="unknown knobs"):
        make_pipeline("box", device.context, buf.inspect(),
                      bogus=1)


def test_invalid_input_is_refused(device, rng):
    buf = _random_buffer(rng, 4, 4, 2)
    buf.color[2, 1, 0, 1] = np.nan
    with pytest.raises(ValueError, match=r"color: sample \(y=2, x=1, i=0\)"):
        clrecon.reconstruct(buf, device=device)
