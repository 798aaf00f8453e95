"""The numeric range of a valid frame, continued (test_numeric_range.py has the colour,
negative radiance, CoC and motion bounds): the minimum depth, random violations around every
bound (host and device agree on verdict, first sample and count), run() refusing
out-of-range frames through every method, and the CLI's ``--allow-negative``."""
from __future__ import annotations

import numpy as np
import pytest
from numeric_range import F32, VIDS, agreed, assert_finite, assert_flat_mean, frame, results
from sample_frames import message_of

from clrecon.core.camera import CocModel
from clrecon.core.limits import COLOR_MAX, MIN_DEPTH, MISS_DEPTH, MOTION_MAX
from clrecon.core.samples import SampleBuffer, coc_min_depth


# -- 4. depth: a minimum; every method at it ------------------------------------------------
@pytest.mark.parametrize("value", [1.4e-45, 1e-40, 1e-21,
                                   float(np.nextafter(F32(1e-20), F32(0)))], ids=str)
def test_depth_below_minimum_is_refused(device, value):
    for model in (CocModel(0.0, 3.0), CocModel.from_focus(6.0, 8.0)):
        buf = frame("misses")
        buf.coc_model = model
        buf.depth[0, 4, 6] = value
        host = agreed(device, buf)
        assert host.startswith("depth: sample (y=0, x=4, i=6) must be at least 1e-20 (inf for "
                               "a miss), got"), host


@pytest.mark.parametrize("vid", VIDS)
def test_every_method_at_the_minimum_depth(device, vid):
    """Hits at MIN_DEPTH with c0 = 0 (1 / depth = 1e20: layered's buckets, splat's layers)
    and with a tiny c0 (coc -1000 px there), a frame of that one depth, and the widest hit
    range (1e-20 .. 1e29): finite, flat fields keep their mean."""
    res = results("depth_min", device)[vid]
    for label in ("c0=0", "c0=-1e-17", "single-depth", "widest-range"):
        assert_finite(res[f"{label}-textured"], f"{vid}/{label}")
        assert_finite(res[f"{label}-flat"], f"{vid}/{label}-flat")
        assert_flat_mean(res[f"{label}-flat"], f"{vid}/{label}-flat")



@pytest.mark.parametrize("seed", range(8))
def test_random_bound_violations_agree(device, seed):
    """Random frames with values around every new bound (colour 0 and COLOR_MAX, motion
    +-MOTION_MAX, depth MIN_DEPTH and the CoC threshold): the device's verdict, first sample
    and count equal the host's, with and without allow_negative."""
    rng = np.random.default_rng(seed)
    buf = frame("misses")
    model = CocModel(float(rng.choice([-1, 1]) * 10.0 ** rng.uniform(-3, 3)),
                     float(rng.uniform(-5, 5)))
    buf.coc_model = model
    lo = max(coc_min_depth(model.c0, model.c1), F32(MIN_DEPTH))
    nxt = np.nextafter
    top, mtop = F32(COLOR_MAX), F32(MOTION_MAX)
    choices = {
        "color": [F32(0), F32(-0.0), -F32(1e-45), top, nxt(top, F32(np.inf)), -top,
                  nxt(-top, -F32(np.inf)), F32(-1.0)],
        "motion": [mtop, -mtop, nxt(mtop, F32(np.inf)), nxt(-mtop, -F32(np.inf))],
        "depth": [F32(MIN_DEPTH), nxt(F32(MIN_DEPTH), F32(0)), lo, nxt(lo, F32(0)),
                  nxt(lo, F32(1))],
    }
    hit = buf.depth < MISS_DEPTH
    buf.depth[hit] = np.maximum(buf.depth[hit], lo)
    for _ in range(int(rng.integers(1, 6))):
        name = str(rng.choice(list(choices)))
        y, x, i = (int(rng.integers(n)) for n in buf.shape)
        v = choices[name][int(rng.integers(len(choices[name])))]
        arr = getattr(buf, name)
        if arr.ndim == 4:
            arr[y, x, i, int(rng.integers(arr.shape[3]))] = v
        else:
            arr[y, x, i] = v
    for allow in (False, True):
        agreed(device, buf, allow)


# -- run() refuses out-of-range frames through every method ----------------------------------
def _break(what: str, buf: SampleBuffer) -> None:
    if what == "colour-huge":
        buf.color[1, 2, 0, 1] = 1e38
    elif what == "colour-negative":
        buf.color[1, 2, 0, 1] = -1.0
    elif what == "motion-huge":
        buf.motion[1, 2, 0, 0] = 3.5e37
    elif what == "depth-tiny":
        buf.depth[1, 2, 0] = 1.4e-45
    elif what == "coc-sample":
        buf.depth[1, 2, 0] = 1e-6  # coc = -48e6 px with c0 = -48
    else:  # coc-model
        buf.coc_model = CocModel(1e308, 1e308)


BREAKS = {"colour-huge": "color: sample (y=1, x=2, i=0)",
          "colour-negative": "color: sample (y=1, x=2, i=0)",
          "motion-huge": "motion: sample (y=1, x=2, i=0)",
          "depth-tiny": "depth: sample (y=1, x=2, i=0)",
          "coc-sample": "coc: sample (y=1, x=2, i=0)",
          "coc-model": "coc_model: coefficients must be finite with"}


@pytest.mark.parametrize("what", sorted(BREAKS))
@pytest.mark.parametrize("method", ["box", "sweep", "layered", "splat"])
def test_run_refuses_out_of_range_frames(device, method, what):
    import clrecon

    buf = frame("misses")  # CocModel.from_focus(6, 8): c0 = -48
    _break(what, buf)
    with pytest.raises(ValueError) as info:
        clrecon.reconstruct(buf, method, device)
    assert str(info.value).startswith(BREAKS[what]), str(info.value)
    assert str(info.value) == message_of(SampleBuffer.validate, buf)


def test_negative_radiance_from_a_file_through_the_cli(device, tmp_path, capsys):
    """A file with negative radiance is refused by name unless --allow-negative."""
    from clrecon.cli import main
    from clrecon.io import save_samples

    buf = SampleBuffer.zeros(4, 6, 2)
    buf.color[:] = 0.5
    buf.color[1, 2, 0, 1] = -0.25
    path = tmp_path / "neg.npz"
    np.savez(path, **buf.arrays(), coc=np.array([0.0, 0.0]), format_version=1)
    out = tmp_path / "out.exr"
    dev = ["--device", str(device.info.index)]
    assert main(["reconstruct", str(path), "-o", str(out), *dev]) == 2
    assert "color: sample (y=1, x=2, i=0)" in capsys.readouterr().err
    assert main(["reconstruct", str(path), "-o", str(out), "--allow-negative", *dev]) == 0
    with pytest.raises(ValueError, match="color"):
        save_samples(str(tmp_path / "again.npz"), buf)
