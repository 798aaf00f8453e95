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
the interpreter down), one per scenario, every method variant inside it.
"""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pyopencl as cl
import pytest
from extremes import CASES, make_frame

from clrecon.core.camera import CocModel
from clrecon.core.inspect import inspect_device
from clrecon.core.samples import (
    C0_MAX,
    COC_MAX,
    COLOR_MAX,
    MIN_DEPTH,
    MISS_DEPTH,
    MOTION_MAX,
    SampleBuffer,
    coc_min_depth,
)

F32 = np.float32
TESTS = Path(__file__).resolve().parent

#: every method variant the bounds are checked on
VARIANTS = [("box", {}), ("sweep", {"scales": 2}), ("sweep", {"scales": 4}),
            ("sweep", {"dof_layers": True}), ("layered", {}), ("layered", {"filter": "mip"}),
            ("layered", {"mode": "lrdm"}), ("splat", {}), ("splat", {"dense": True,
                                                                    "layers": 1})]
VIDS = [m + "".join(f"-{k}={v}" for k, v in kn.items()) for m, kn in VARIANTS]


# -- frames (also built in the worker subprocess) -------------------------------------------
def frame(name: str, flat: bool = False) -> SampleBuffer:
    """A valid frame of the extremes case ``name`` (tests/extremes.py)."""
    return make_frame(next(c for c in CASES if c.name == name), flat)


def scaled_to_bound(buf: SampleBuffer) -> tuple[SampleBuffer, float]:
    """``buf`` with its colours scaled so that the largest is float32(COLOR_MAX)."""
    k = F32(COLOR_MAX) / buf.color.max()
    big = _copy(buf)
    big.color[:] = np.minimum(buf.color * k, F32(COLOR_MAX))
    return big.validate(), float(k)


def _copy(buf: SampleBuffer, **fields) -> SampleBuffer:
    arrays = {n: a.copy() for n, a in buf.arrays().items()}
    arrays.update(fields)
    return SampleBuffer(**arrays, coc_model=buf.coc_model)


def signed(buf: SampleBuffer, seed: int = 5) -> tuple[SampleBuffer, SampleBuffer, SampleBuffer]:
    """``(c, c+, c-)`` frames: colours ``c = c+ - c-`` with a third of the channels negative."""
    rng = np.random.default_rng(seed)
    pos = buf.color.copy()
    neg = np.where(rng.uniform(size=pos.shape) < 1 / 3,
                   rng.exponential(1.0, pos.shape), 0.0).astype(F32)
    pos[neg > 0] = 0.0
    return (_copy(buf, color=pos - neg), _copy(buf, color=pos), _copy(buf, color=neg))


def at_min_depth(model: CocModel, share: float = 0.3, far: float | None = None) -> SampleBuffer:
    """The ``misses`` frame with ``share`` of its hits at MIN_DEPTH (the rest at ``far``)."""
    buf = frame("misses")
    buf.coc_model = model
    rng = np.random.default_rng(2)
    hit = buf.depth < MISS_DEPTH
    buf.depth[hit & (rng.uniform(size=buf.depth.shape) < share)] = F32(MIN_DEPTH)
    if far is not None:
        buf.depth[hit & (buf.depth > F32(MIN_DEPTH))] = far
    return buf.validate()


# -- the worker: every variant on a scenario's frames, results as JSON ---------------------
def _stats(img) -> dict | str:
    if isinstance(img, str):  # refused: the message
        return img
    f = np.isfinite(img)
    return {"finite": bool(f.all()), "nonfinite": int((~f).sum()),
            "min": float(img[f].min(initial=np.inf)), "max": float(img[f].max(initial=-np.inf)),
            "mean": img.reshape(-1, 3).astype(np.float64).mean(0).tolist()}


def _run(buf, method, knobs, dev, **kw):
    import clrecon

    try:
        return clrecon.reconstruct(buf, method, dev, **kw, **knobs)
    except (ValueError, OverflowError) as exc:
        return f"{type(exc).__name__}: {exc}"


def scenario(name: str, dev) -> dict:
    """Per variant id: what the scenario measures (see the tests below)."""
    out = {}
    for vid, (method, knobs) in zip(VIDS, VARIANTS):
        res = out[vid] = {}
        if name == "colour_bound":
            for case in ("misses", "hdr", "coc_over_100px"):
                small = frame(case)
                big, k = scaled_to_bound(small)
                a, b = _run(small, method, knobs, dev), _run(big, method, knobs, dev)
                if isinstance(b, str):
                    res[case] = b
                    continue
                err = float(np.max(np.abs(b.astype(np.float64) / k - a)) / np.abs(a).max())
                res[case] = {**_stats(b), "homogeneity": err}
            flat = frame("misses", flat=True)
            flat.color *= F32(COLOR_MAX)
            res["flat"] = _stats(_run(flat.validate(), method, knobs, dev))
            neg = _copy(flat, color=-flat.color)
            res["flat_negative"] = _stats(_run(neg, method, knobs, dev, allow_negative=True))
        elif name == "negative":
            c, cp, cn = signed(frame("misses"))
            img = _run(c, method, knobs, dev, allow_negative=True)
            lin = _run(cp, method, knobs, dev).astype(np.float64) - _run(cn, method, knobs, dev)
            res["linear_error"] = float(np.max(np.abs(img - lin)) / np.abs(c.color).max())
            res["signed"] = _stats(img)
            res["refused"] = _run(c, method, knobs, dev)
            flat = frame("misses", flat=True)
            res["flat_negative"] = _stats(_run(_copy(flat, color=-flat.color), method, knobs,
                                               dev, allow_negative=True))
        elif name == "coc_bound":
            # every miss at |coc| = COC_MAX, and hits at the smallest depth within the bound
            for label, model in (("c1", CocModel(0.0, COC_MAX)),
                                 ("c0", CocModel(-3.0e6, 2.0))):
                for flat in (False, True):
                    buf = frame("misses", flat)
                    buf.coc_model = model
                    lo = coc_min_depth(model.c0, model.c1)
                    if lo > 0:  # c0 = 0: every depth is within the bound
                        hit = buf.depth < MISS_DEPTH
                        buf.depth[hit] = np.maximum(buf.depth[hit], lo)
                        buf.depth[:, ::3][hit[:, ::3]] = lo
                    res[f"{label}-{'flat' if flat else 'textured'}"] = _stats(
                        _run(buf.validate(), method, knobs, dev))
            # |c0| at its bound: only misses are valid, finite ones (1e30 .. 3e38) have
            # c0 / w + c1 up to 2 COC_MAX in the kernels that do not special-case misses
            for sign in (1.0, -1.0):
                for flat in (False, True):
                    buf = frame("all_miss", flat)
                    buf.depth[:, ::2] = F32(MISS_DEPTH)
                    buf.depth[::2, 1::2] = F32(3e38)
                    buf.coc_model = CocModel(sign * C0_MAX, -sign * COC_MAX)
                    res[f"c0max{sign:+.0f}-{'flat' if flat else 'textured'}"] = _stats(
                        _run(buf.validate(), method, knobs, dev))
        elif name == "motion_bound":
            for flat in (False, True):
                buf = frame("misses", flat)
                rng = np.random.default_rng(4)
                moving = rng.uniform(size=buf.depth.shape) < 0.25
                buf.motion[moving] = F32(MOTION_MAX) * rng.choice([-1.0, 1.0], (moving.sum(), 2))
                res["flat" if flat else "textured"] = _stats(_run(buf.validate(), method, knobs,
                                                                  dev))
        elif name == "depth_min":
            for label, model, far in (("c0=0", CocModel(0.0, 3.0), None),
                                      ("c0=-1e-17", CocModel(-1e-17, 3.0), None),
                                      ("single-depth", CocModel(0.0, 3.0), F32(MIN_DEPTH)),
                                      ("widest-range", CocModel(0.0, 3.0), F32(1e29))):
                for flat in (False, True):
                    buf = at_min_depth(model, far=far)
                    if flat:
                        buf.color[:] = np.array([0.25, 0.5, 1.0], F32)
                    res[f"{label}-{'flat' if flat else 'textured'}"] = _stats(
                        _run(buf, method, knobs, dev))
        else:
            raise ValueError(name)
    return out


_WORKER = textwrap.dedent("""
    import json, sys
    sys.path[:0] = [sys.argv[1], sys.argv[1] + '/../support']
    import numpy as np
    np.seterr(all="ignore")
    import test_numeric_range as t
    from clrecon.core.device import get_device
    print("RESULT " + json.dumps(t.scenario(sys.argv[2], get_device(int(sys.argv[3])))))
""")

_results: dict = {}


def results(name: str, device) -> dict:
    """The worker's results for scenario ``name`` (run once per session)."""
    key = (name, device.info.index)
    if key not in _results:
        proc = subprocess.run(
            [sys.executable, "-c", _WORKER, str(TESTS), name, str(device.info.index)],
            capture_output=True, text=True, timeout=900,
            env=os.environ | {"PYOPENCL_COMPILER_OUTPUT": "0"})
        assert proc.returncode == 0, f"rc {proc.returncode}: {proc.stderr[-3000:]}"
        line = [x for x in proc.stdout.splitlines() if x.startswith("RESULT ")][-1]
        _results[key] = json.loads(line[len("RESULT "):])
    return _results[key]


def _finite(res, what):
    assert not isinstance(res, str), f"{what}: {res}"
    assert res["finite"], f"{what}: {res['nonfinite']} non-finite pixels"


def _flat_mean(res, what, scale=1.0):
    want = np.array([0.25, 0.5, 1.0]) * scale
    rel = np.abs(np.array(res["mean"]) / want - 1)
    assert (rel <= 0.01).all(), f"{what}: flat-field mean {res['mean']} vs {want.tolist()}"


# -- 1. colours: bounded; every method sums them without overflow ---------------------------
@pytest.mark.parametrize("value", [5e37, 1e38, 3e38, float(np.nextafter(F32(1e30), F32(2e30))),
                                   -1e31], ids=str)
def test_colour_beyond_bound_is_refused(device, value):
    buf = frame("misses")
    buf.color[2, 3, 1, 2] = value
    buf.color[4, 0, 0] = value
    want = ("color: sample (y=2, x=3, i=1) must be finite and in [-1e+30, 1e+30], got")
    for allow in (False, True):
        host = _message(lambda b, a=allow: b.validate(allow_negative=a), buf)
        if allow:
            assert host.startswith(want) and host.endswith("(2 bad samples)"), host
        assert host.startswith("color: sample (y=2, x=3, i=1)"), host
        assert device_message(device, buf, allow) == host


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
        _finite(r, f"{vid}/{case}")
        assert r["homogeneity"] <= 1e-4, f"{vid}/{case}: {r}"
    _finite(res["flat"], f"{vid}/flat")
    _flat_mean(res["flat"], f"{vid}/flat", COLOR_MAX)
    _finite(res["flat_negative"], f"{vid}/flat negative")
    _flat_mean(res["flat_negative"], f"{vid}/flat negative", -COLOR_MAX)


# -- 2. negative radiance: refused by default; with allow_negative linear everywhere --------
def test_negative_colour_is_refused_unless_allowed(device):
    c, _, _ = signed(frame("misses"))
    msg = _message(SampleBuffer.validate, c)
    assert msg.startswith("color: sample (") and "allow_negative=True" in msg, msg
    assert device_message(device, c, False) == msg
    assert _message(lambda b: b.validate(allow_negative=True), c) is None
    assert device_message(device, c, True) is None
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
    _finite(res["signed"], vid)
    assert res["signed"]["min"] < 0, res["signed"]
    assert isinstance(res["refused"], str) and res["refused"].startswith(
        "ValueError: color: sample ("), res["refused"]
    _flat_mean(res["flat_negative"], f"{vid}/flat negative", -1.0)
    assert res["flat_negative"]["max"] < 0


# -- 3. CoC and motion: bounded coefficients, per-sample CoC and motion ---------------------
@pytest.mark.parametrize("c0,c1", [(1e308, 1e308), (0.0, COC_MAX * 1.0000001), (0.0, -2e6),
                                   (-1.1e36, 1.0), (math.nan, 1.0), (1.0, math.inf)], ids=str)
def test_coc_coefficients_beyond_bound_are_refused(device, c0, c1):
    buf = frame("misses")
    buf.coc_model = CocModel(c0, c1)
    host = _message(SampleBuffer.validate, buf)
    assert host.startswith("coc_model: coefficients must be finite with |c1| <= 1048576 px"), host
    assert device_message(device, buf, False) == host


def test_coc_coefficients_at_bound_are_valid(device):
    for c0, c1 in [(0.0, COC_MAX), (0.0, -COC_MAX), (COC_MAX * MISS_DEPTH, -COC_MAX),
                   (-COC_MAX * MISS_DEPTH, COC_MAX)]:
        buf = frame("all_miss")  # no hit: only the coefficients matter
        buf.coc_model = CocModel(c0, c1)
        assert _message(SampleBuffer.validate, buf) is None
        assert device_message(device, buf, False) is None


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
    host = _message(SampleBuffer.validate, buf)
    assert host.startswith("coc: sample (y=1, x=5, i=2) must have |coc(depth)| <= 1048576 px, "
                           "got coc -1048576.") and host.endswith("(2 bad samples)"), host
    assert device_message(device, buf, False) == host
    buf.depth[1, 5, 2] = lo
    buf.depth[3, 0, 0] = lo
    assert _message(SampleBuffer.validate, buf) is None
    assert device_message(device, buf, False) is None


@pytest.mark.parametrize("value", [3.5e37, 1e12, 1e9, float(np.nextafter(F32(65536), F32(1e6))),
                                   -65537.0], ids=str)
def test_motion_beyond_bound_is_refused(device, value):
    buf = frame("misses")
    buf.motion[2, 2, 3, 1] = value
    host = _message(SampleBuffer.validate, buf)
    assert host.startswith("motion: sample (y=2, x=2, i=3) must be finite with components in "
                           "[-65536, 65536] px, got"), host
    assert device_message(device, buf, False) == host


@pytest.mark.parametrize("vid", VIDS)
def test_every_method_at_the_coc_bound(device, vid):
    """Misses at |coc| = COC_MAX (c1), hits at the smallest depth within the bound (c0),
    and |c0| at its bound on finite misses (c0max): finite, flat fields keep their mean."""
    res = results("coc_bound", device)[vid]
    for label in ("c1", "c0", "c0max+1", "c0max-1"):
        for kind in ("textured", "flat"):
            r = res[f"{label}-{kind}"]
            _finite(r, f"{vid}/{label}-{kind}")
            if kind == "flat":
                _flat_mean(r, f"{vid}/{label}-flat")


@pytest.mark.parametrize("vid", VIDS)
def test_every_method_at_the_motion_bound(device, vid):
    """A quarter of the samples moving (+-65536, +-65536) px: finite, flat mean kept."""
    res = results("motion_bound", device)[vid]
    _finite(res["textured"], f"{vid}/textured")
    _finite(res["flat"], f"{vid}/flat")
    _flat_mean(res["flat"], f"{vid}/flat")


_SPLAT_HOST = textwrap.dedent("""
    import dataclasses, json, sys
    import numpy as np, pyopencl as cl
    sys.path[:0] = [sys.argv[1], sys.argv[1] + '/../support']
    from test_numeric_range import frame
    from clrecon.core.device import get_device
    from clrecon.core.pipeline import DeviceSamples, make_pipeline
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
    proc = subprocess.run([sys.executable, "-c", _SPLAT_HOST, str(TESTS),
                           str(device.info.index)], capture_output=True, text=True,
                          timeout=600, env=os.environ | {"PYOPENCL_COMPILER_OUTPUT": "0"})
    assert proc.returncode == 0, f"rc {proc.returncode}: {proc.stderr[-3000:]}"
    res = json.loads([x for x in proc.stdout.splitlines() if x.startswith("RESULT ")][-1][7:])
    assert all(0 < t < 2**31 for t in res.pop("tile")), res
    for key, (split, finite) in res.items():
        assert 1 <= split <= 2**31 and finite, (key, split, finite)


# -- 4. depth: a minimum; every method at it ------------------------------------------------
@pytest.mark.parametrize("value", [1.4e-45, 1e-40, 1e-21,
                                   float(np.nextafter(F32(1e-20), F32(0)))], ids=str)
def test_depth_below_minimum_is_refused(device, value):
    for model in (CocModel(0.0, 3.0), CocModel.from_focus(6.0, 8.0)):
        buf = frame("misses")
        buf.coc_model = model
        buf.depth[0, 4, 6] = value
        host = _message(SampleBuffer.validate, buf)
        assert host.startswith("depth: sample (y=0, x=4, i=6) must be at least 1e-20 (inf for "
                               "a miss), got"), host
        assert device_message(device, buf, False) == host


@pytest.mark.parametrize("vid", VIDS)
def test_every_method_at_the_minimum_depth(device, vid):
    """Hits at MIN_DEPTH with c0 = 0 (1 / depth = 1e20: layered's buckets, splat's layers)
    and with a tiny c0 (coc -1000 px there), a frame of that one depth, and the widest hit
    range (1e-20 .. 1e29): finite, flat fields keep their mean."""
    res = results("depth_min", device)[vid]
    for label in ("c0=0", "c0=-1e-17", "single-depth", "widest-range"):
        _finite(res[f"{label}-textured"], f"{vid}/{label}")
        _finite(res[f"{label}-flat"], f"{vid}/{label}-flat")
        _flat_mean(res[f"{label}-flat"], f"{vid}/{label}-flat")


# -- host / device agreement of the new rules -------------------------------------------------
def _message(fn, buf) -> str | None:
    try:
        fn(buf)
    except ValueError as exc:
        return str(exc)
    return None


def device_message(device, buf: SampleBuffer, allow_negative: bool) -> str | None:
    mf = cl.mem_flags
    bufs = {n: cl.Buffer(device.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=a)
            for n, a in buf.arrays().items()}
    try:
        inspect_device(device.queue, bufs, *buf.shape, (buf.coc_model.c0, buf.coc_model.c1),
                       allow_negative=allow_negative)
    except ValueError as exc:
        return str(exc)
    return None


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
        host = _message(lambda b, a=allow: b.validate(allow_negative=a), buf)
        assert device_message(device, buf, allow) == host


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
    assert str(info.value) == _message(SampleBuffer.validate, buf)


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
