"""What the numeric-range tests (tests/extremes/test_numeric_range*.py) share: the method
variants, the frames at the bounds, the worker that runs every variant on a scenario's
frames in a subprocess (this module, imported there by name from the support folder), and
the host / device message agreement."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pyopencl as cl
from extremes import CASES, make_frame
from sample_frames import message_of

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
SUPPORT = Path(__file__).resolve().parent

#: every method variant the bounds are checked on
VARIANTS = [("box", {}), ("sweep", {"scales": 2}), ("sweep", {"scales": 4}),
            ("sweep", {"dof_layers": True}), ("layered", {}), ("layered", {"filter": "mip"}),
            ("layered", {"mode": "lrdm"}), ("splat", {}), ("splat", {"dense": True,
                                                                    "layers": 1})]
VIDS = [m + "".join(f"-{k}={v}" for k, v in kn.items()) for m, kn in VARIANTS]


# -- frames (also built in the worker subprocess) -------------------------------------------
def frame(name: str, flat: bool = False) -> SampleBuffer:
    """A valid frame of the extremes case ``name`` (tests/support/extremes.py)."""
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
    sys.path[:0] = [sys.argv[1]]
    import numpy as np
    np.seterr(all="ignore")
    import numeric_range as t
    from clrecon.core.device import get_device
    print("RESULT " + json.dumps(t.scenario(sys.argv[2], get_device(int(sys.argv[3])))))
""")

_results: dict = {}


def results(name: str, device) -> dict:
    """The worker's results for scenario ``name`` (run once per session)."""
    key = (name, device.info.index)
    if key not in _results:
        proc = subprocess.run(
            [sys.executable, "-c", _WORKER, str(SUPPORT), name, str(device.info.index)],
            capture_output=True, text=True, timeout=900,
            env=os.environ | {"PYOPENCL_COMPILER_OUTPUT": "0"})
        assert proc.returncode == 0, f"rc {proc.returncode}: {proc.stderr[-3000:]}"
        line = [x for x in proc.stdout.splitlines() if x.startswith("RESULT ")][-1]
        _results[key] = json.loads(line[len("RESULT "):])
    return _results[key]


def assert_finite(res, what):
    assert not isinstance(res, str), f"{what}: {res}"
    assert res["finite"], f"{what}: {res['nonfinite']} non-finite pixels"


def assert_flat_mean(res, what, scale=1.0):
    want = np.array([0.25, 0.5, 1.0]) * scale
    rel = np.abs(np.array(res["mean"]) / want - 1)
    assert (rel <= 0.01).all(), f"{what}: flat-field mean {res['mean']} vs {want.tolist()}"


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


def agreed(device, buf: SampleBuffer, allow_negative: bool = False) -> str | None:
    """The host's validation message for ``buf`` (``None``: valid), after checking that the
    device inspection pass gives the very same."""
    host = message_of(lambda b: b.validate(allow_negative=allow_negative), buf)
    assert device_message(device, buf, allow_negative) == host
    return host
