"""The numeric range of a valid frame (clrecon.core.samples: colour, depth, CoC and motion
bounds): what validation refuses, host and device alike, and that every method holds at the
bounds (finite, no float32 overflow), treats negative radiance alike (``allow_negative``) and
keeps its host arithmetic within range.

Each defect this suite pins down once broke a method: colours of 5e37 and up made
``layered`` all NaN, 1e38 made ``box`` all inf, 3e38 gave ``splat`` inf pixels; negative
colour came out -1 from box, layered and sweep and 0 from splat; ``CocModel(1e308, 1e308)``
gave an all-black splat image; depth 1.4e-45 made layered raise OverflowError; splat
motions of 1e12 and 3.5e37 px overflowed the host's int32 arguments and 1e9 px ran for
minutes. Method runs happen in a subprocess (a kernel that overflowed an index could take
the interpreter down), one per scenario, every method variant inside it
(tests/support/numeric_range.py). Depth, random violations, run() and the CLI:
test_numeric_range_checks.py.
"""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from numeric_range import (
    F32,
    SUPPORT,
    VIDS,
    agreed,
    assert_finite,
    assert_flat_mean,
    frame,
    results,
    signed,
)

from clrecon.core.camera import CocModel
from clrecon.core.samples import COC_MAX, COLOR_MAX, MISS_DEPTH, coc_min_depth


# -- 1. colours: bounded; every method sums them without overflow ---------------------------
@pytest.mark.parametrize("value", [5e37, 1e38, 3e38, float(np.nextafter(F32(1e30), F32(2e30))),
                                   -1e31], ids=str)
def test_colour_beyond_bound_is_refused(device, value):
    buf = frame("misses")
    buf.color[2, 3, 1, 2] = value
    buf.color[4, 0, 0] = value
    want = ("color: sample (y=2, x=3, i=1) must be finite and in [-1e+30, 1e+30], got")
    for allow in (False, True):
        host = agreed(device, buf, allow)
        if allow:
            assert host.startswith(want) and host.endswith("(2 bad samples)"), host
        assert host.startswith("color: sample (y=2, x=3, i=1)"), host


def test_colour_at_bound_is_valid():
    buf = frame("misses")
    buf.color[0, 0, 0] = F32(COLOR_MAX)
    buf.validate()
    buf.color[0, 0, 1] = -F32(COLOR_MAX)
    buf.validate(allow_negative=True)


@pytest.mark.parametrize("vid", VIDS)
def test_every_method_sums_colours_at_the_bound(device, vid):
    """Frames scaled so that their largest colour is COLOR_MAX (a plain, an HDR and a
    > 100 px CoC frame): finite, and the image scales with the colours (homogeneity within
    1e-4 of the unscaled image's maximum); flat fields of 1e30 keep their mean, also
    negated (allow_negative)."""
    res = results("colour_bound", device)[vid]
    for case in ("misses", "hdr", "coc_over_100px"):
        r = res[case]
        assert_finite(r, f"{vid}/{case}")
        assert r["homogeneity"] <= 1e-4, f"{vid}/{case}: {r}"
    assert_finite(res["flat"], f"{vid}/flat")
    assert_flat_mean(res["flat"], f"{vid}/flat", COLOR_MAX)
    assert_finite(res["flat_negative"], f"{vid}/flat negative")
    assert_flat_mean(res["flat_negative"], f"{vid}/flat negative", -COLOR_MAX)


# -- 2. negative radiance: refused by default; with allow_negative linear everywhere --------
def test_negative_colour_is_refused_unless_allowed(device):
    c, _, _ = signed(frame("misses"))
    msg = agreed(device, c)
    assert msg.startswith("color: sample (") and "allow_negative=True" in msg, msg
    assert agreed(device, c, True) is None
    # -0.0 is not negative
    buf = frame("misses")
    buf.color[:] = -0.0
    buf.validate()


@pytest.mark.parametrize("vid", VIDS)
def test_negative_radiance_is_linear_in_every_method(device, vid):
    """With allow_negative=True every method gives reconstruct(c+) - reconstruct(c-) (within
    1e-5 of the largest |colour|; splat reconstructs the parts apart, the others are linear),
    a negative flat field comes out negative with its mean, and without the flag run()
    refuses the frame."""
    res = results("negative", device)[vid]
    assert res["linear_error"] <= 1e-5, f"{vid}: {res['linear_error']}"
    assert_finite(res["signed"], vid)
    assert res["signed"]["min"] < 0, res["signed"]
    assert isinstance(res["refused"], str) and res["refused"].startswith(
        "ValueError: color: sample ("), res["refused"]
    assert_flat_mean(res["flat_negative"], f"{vid}/flat negative", -1.0)
    assert res["flat_negative"]["max"] < 0


# -- 3. CoC and motion: bounded coefficients, per-sample CoC and motion ---------------------
@pytest.mark.parametrize("c0,c1", [(1e308, 1e308), (0.0, COC_MAX * 1.0000001), (0.0, -2e6),
                                   (-1.1e36, 1.0), (math.nan, 1.0), (1.0, math.inf)], ids=str)
def test_coc_coefficients_beyond_bound_are_refused(device, c0, c1):
    buf = frame("misses")
    buf.coc_model = CocModel(c0, c1)
    host = agreed(device, buf)
    assert host.startswith("coc_model: coefficients must be finite with |c1| <= 1048576 px"), host


def test_coc_coefficients_at_bound_are_valid(device):
    for c0, c1 in [(0.0, COC_MAX), (0.0, -COC_MAX), (COC_MAX * MISS_DEPTH, -COC_MAX),
                   (-COC_MAX * MISS_DEPTH, COC_MAX)]:
        buf = frame("all_miss")  # no hit: only the coefficients matter
        buf.coc_model = CocModel(c0, c1)
        assert agreed(device, buf) is None


def test_sample_coc_beyond_bound_is_refused(device):
    """A hit whose |c0 / w + c1| exceeds COC_MAX is refused by name (rule ``coc``, after the
    coefficients), on the host and the device alike; the threshold depth is exact."""
    model = CocModel.from_focus(6.0, 8.0)  # c0 = -48
    lo = coc_min_depth(model.c0, model.c1)
    assert abs(model.coc(np.array([lo], F32))[0]) <= COC_MAX
    assert abs(model.coc(np.array([np.nextafter(lo, F32(0))], F32))[0]) > COC_MAX
    buf = frame("misses")
    buf.coc_model = model
    buf.depth[1, 5, 2] = np.nextafter(lo, F32(0))
    buf.depth[3, 0, 0] = F32(1e-6)
    buf.depth[3, 0, 1] = lo  # at the bound: valid
    host = agreed(device, buf)
    assert host.startswith("coc: sample (y=1, x=5, i=2) must have |coc(depth)| <= 1048576 px, "
                           "got coc -1048576.") and host.endswith("(2 bad samples)"), host
    buf.depth[1, 5, 2] = lo
    buf.depth[3, 0, 0] = lo
    assert agreed(device, buf) is None


@pytest.mark.parametrize("value", [3.5e37, 1e12, 1e9, float(np.nextafter(F32(65536), F32(1e6))),
                                   -65537.0], ids=str)
def test_motion_beyond_bound_is_refused(device, value):
    buf = frame("misses")
    buf.motion[2, 2, 3, 1] = value
    host = agreed(device, buf)
    assert host.startswith("motion: sample (y=2, x=2, i=3) must be finite with components in "
                           "[-65536, 65536] px, got"), host


@pytest.mark.parametrize("vid", VIDS)
def test_every_method_at_the_coc_bound(device, vid):
    """Misses at |coc| = COC_MAX (c1), hits at the smallest depth within the bound (c0),
    and |c0| at its bound on finite misses (c0max): finite, flat fields keep their mean."""
    res = results("coc_bound", device)[vid]
    for label in ("c1", "c0", "c0max+1", "c0max-1"):
        for kind in ("textured", "flat"):
            r = res[f"{label}-{kind}"]
            assert_finite(r, f"{vid}/{label}-{kind}")
            if kind == "flat":
                assert_flat_mean(r, f"{vid}/{label}-flat")


@pytest.mark.parametrize("vid", VIDS)
def test_every_method_at_the_motion_bound(device, vid):
    """A quarter of the samples moving (+-65536, +-65536) px: finite, flat mean kept."""
    res = results("motion_bound", device)[vid]
    assert_finite(res["textured"], f"{vid}/textured")
    assert_finite(res["flat"], f"{vid}/flat")
    assert_flat_mean(res["flat"], f"{vid}/flat")


_SPLAT_HOST = textwrap.dedent("""
    import dataclasses, json, sys
    import numpy as np, pyopencl as cl
    sys.path[:0] = [sys.argv[1]]
    from numeric_range import frame
    from clrecon.core.device import get_device
    from clrecon.api import make_pipeline
    from clrecon.core.pipeline import DeviceSamples
    from clrecon.methods.splat.splat import Splat
    dev = get_device(int(sys.argv[2]))
    buf = frame("misses")
    out = {"tile": [Splat.tile_size(60, s, 4) for s in (3.5e37, 1e12, float("inf"))]}
    for motion in (3.5e37, 1e12, float("inf")):
        for scatter in ("tiles", "atomic"):
            info = dataclasses.replace(buf.inspect(), max_abs_motion=motion)
            pipe = make_pipeline("splat", dev.context, info, scatter=scatter, mip_radius=0)
            s = DeviceSamples.upload(dev.queue, buf, info=buf.inspect())
            o = cl.Buffer(dev.context, cl.mem_flags.READ_WRITE, buf.height * buf.width * 12)
            img = np.empty((buf.height, buf.width, 3), np.float32)
            cl.enqueue_copy(dev.queue, img, o, wait_for=[pipe(dev.queue, s, o)])
            out[f"{motion}-{scatter}"] = [pipe.describe()["motion_split"],
                                          bool(np.isfinite(img).all())]
    print("RESULT " + json.dumps(out))
""")


def test_splat_host_arithmetic_takes_any_motion(device):
    """A frame description that vouches for motions validation refuses (3.5e37 once raised
    'Python int too large to convert to C long', 1e12 'out of bounds for int32'): the host
    clamps before int(), the plan builds and runs (one tile over the frame)."""
    proc = subprocess.run([sys.executable, "-c", _SPLAT_HOST, str(SUPPORT),
                           str(device.info.index)], capture_output=True, text=True,
                          timeout=600, env=os.environ | {"PYOPENCL_COMPILER_OUTPUT": "0"})
    assert proc.returncode == 0, f"rc {proc.returncode}: {proc.stderr[-3000:]}"
    res = json.loads([x for x in proc.stdout.splitlines() if x.startswith("RESULT ")][-1][7:])
    assert all(0 < t < 2**31 for t in res.pop("tile")), res
    for key, (split, finite) in res.items():
        assert 1 <= split <= 2**31 and finite, (key, split, finite)
