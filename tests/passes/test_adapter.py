"""Input adapter (``kernels/adapt.cl``, :mod:`clrecon.core.adapter`): interleaved records unpacked
into the structure of arrays on the device, against the TLFR loader and the source arrays.

Run as a script (``python tests/passes/test_adapter.py [H W S]``) to time the TLFR unpack.
"""
from __future__ import annotations

import sys

import numpy as np
import pyopencl as cl
import pytest
from conftest import assert_close

from clrecon import io
from clrecon.core.adapter import COMPONENTS, RecordLayout, Unpack, allocate
from clrecon.core.camera import CocModel
from clrecon.core.samples import FIELDS, SampleBuffer

#: TLFR motion tolerance, relative: 4 float32 ulps (the kernel divides in float, within
#: OpenCL's 2.5 ulp for division when it is not correctly rounded; the loader in float64,
#: then rounds once)
MOTION_RTOL = 4 * 2.0**-23
#: general ``mv_w != 0``: absolute error bound per unit of the cancelling terms' size
#: (|mv_xy| + |mv_w| (|position| + |coc lens|)) w / (w0 w1), see ``_general_scale``
MOTION_TERMS_EPS = 16 * 2.0**-24
F32_MISS = np.float32(1e30)


def _upload(ctx, arr, flags=cl.mem_flags.READ_ONLY) -> cl.Buffer:
    arr = np.ascontiguousarray(arr)
    return cl.Buffer(ctx, flags | cl.mem_flags.COPY_HOST_PTR, hostbuf=arr)


def _download(queue, out, shape, fields=None) -> dict[str, np.ndarray]:
    got = {}
    for name in fields or out:
        host = np.empty(shape + FIELDS[name], np.float32)
        cl.enqueue_copy(queue, host, out[name])
        got[name] = host
    return got


def _bits(a) -> np.ndarray:
    return np.ascontiguousarray(a, np.float32).view(np.uint32)


def _assert_bits(got, want, what):
    g, w = _bits(got), _bits(want)
    assert g.shape == w.shape, f"{what}: shape {g.shape} != {w.shape}"
    bad = g != w
    if bad.any():
        i = tuple(int(k) for k in np.argwhere(bad)[0])
        raise AssertionError(f"{what}: {int(bad.sum())} values differ in bits; first at {i}: "
                             f"{g[i]:#010x} vs {w[i]:#010x}")


def _unpack_tlfr(device, records, shape, coc, unpack=None):
    ctx, q = device.context, device.queue
    unpack = unpack or Unpack(ctx, RecordLayout.tlfr())
    out = unpack.allocate(ctx, *shape)
    ev = unpack(q, _upload(ctx, records), *shape, coc, out)
    assert isinstance(ev, cl.Event)
    return _download(q, out, shape, unpack.fields)


# ==========================================================================================
# (1) TLFR
# ==========================================================================================
def test_tlfr_layout_matches_the_tlfr_columns():
    lay = RecordLayout.tlfr()
    assert lay.stride == 64 and lay.motion == "tlfr"
    want = {"position": 0, "depth": 12, "lens": 16, "time": 24, "color": 28, "motion": 44}
    assert dict(lay.offsets) == want
    cols = {"position": ("x", "y"), "depth": ("w",), "lens": ("u", "v"), "time": ("t",),
            "color": ("r", "g", "b"), "motion": ("mv_x", "mv_y", "mv_w")}
    for name, names in cols.items():
        k = io.TLFR_FIELDS.index(names[0])
        assert io.TLFR_FIELDS[k:k + len(names)] == names and lay.offset(name) == 4 * k
        assert lay.components(name) == len(names)
    # the same layout described by a dtype
    dt = np.dtype([(c.replace("/", "_"), "<f4") for c in io.TLFR_FIELDS])
    members = {"position": "x", "depth": "w", "lens": "u", "time": "t", "color": "r",
               "motion": "mv_x"}
    packed = np.dtype({"names": list(members),
                       "formats": [("<f4", lay.components(n)) if lay.components(n) > 1
                                   else "<f4" for n in members],
                       "offsets": [dt.fields[m][1] for m in members.values()],
                       "itemsize": dt.itemsize})
    assert RecordLayout.from_dtype(packed, motion="tlfr") == lay
    assert hash(lay) == hash(RecordLayout.tlfr())


def test_tlfr_file_matches_loader(device, tmp_path):
    """A rendered frame with misses, saved as binary TLFR: the raw file bytes, unpacked on
    the device, equal io.load_samples of the same file (motion within MOTION_RTOL)."""
    from clrecon.scenes import get_scene, render_samples

    buf = render_samples(get_scene("fast_motion"), 32, 24, spp=4, seed=0)
    rng = np.random.default_rng(7)
    miss = rng.random(buf.depth.shape) < 0.15
    buf.depth[miss] = np.where(rng.random(int(miss.sum())) < 0.5, np.inf, F32_MISS)
    buf.validate()
    assert buf.inspect().has_motion and np.ptp(buf.depth[~miss]) > 1
    path = tmp_path / "frame.bin"
    io.save_samples(path, buf)
    raw = np.fromfile(path, np.uint8)
    ref = io.load_samples(path)
    assert raw.size == ref.depth.size * 64

    got = _unpack_tlfr(device, raw, buf.shape, (ref.coc_model.c0, ref.coc_model.c1))
    for name in ("color", "position", "depth", "lens", "time"):
        _assert_bits(got[name], getattr(ref, name), name)
    assert_close(got["motion"], ref.motion, rtol=MOTION_RTOL, atol=0.0, what="motion")
    assert (got["motion"][miss] == 0).all()
    assert np.abs(got["motion"]).max() > 1  # the frame really moves


def _general_records(rng, h, w, s):
    """Hand-made TLFR records with perspective motion (mv_w != 0), never crossing."""
    n = h * w * s
    rec = rng.standard_normal((n, 16)).astype(np.float32)  # z/w, a, dwdx, dwdy: noise
    ys, xs = np.divmod(np.arange(n) // s, w)
    rec[:, 0] = xs + rng.random(n)
    rec[:, 1] = ys + rng.random(n)
    depth = np.exp(rng.uniform(np.log(0.05), np.log(2000.0), n))
    rec[:, 3] = depth
    r, a = np.sqrt(rng.random(n)), rng.uniform(0, 2 * np.pi, n)
    rec[:, 4], rec[:, 5] = r * np.cos(a), r * np.sin(a)
    rec[:, 6] = rng.random(n)
    rec[:, 7:10] = rng.exponential(2.0, (n, 3))
    rec[:, 11:13] = rng.uniform(-20, 20, (n, 2)) * depth[:, None]
    rec[:, 13] = rng.uniform(-0.9, 0.9, n) * depth  # |mv_w| < w: w0, w1 > 0
    rec[::7, 13] = 0.0                               # screen-space motion only
    rec[::11, 11:14] = 0.0                           # no motion at all
    # extremes of the hit range, and misses / invalid depths (zero motion whatever mv)
    rec[1, 3], rec[2, 3] = 1e-20, 1e20
    rec[3, 3] = np.nextafter(F32_MISS, np.float32(0))
    rec[1:4, 11:14] = rec[1:4, 3:4] * np.float32([0.5, -0.25, 0.125])
    for k, d in enumerate([np.inf, F32_MISS, 3e30, np.nan, 0.0, -2.0]):
        rec[4 + k, 3] = d
        rec[4 + k, 11:14] = [5.0, -3.0, 0.5]
    return rec


def _general_scale(rec, model):
    """(n, 1) size of the terms the general formula subtracts, times w / (w0 w1)."""
    r = rec.astype(np.float64)
    w, t, vw = r[:, 3], r[:, 6], r[:, 13]
    with np.errstate(all="ignore"):
        coc = np.abs(model.c0 / w + model.c1)
        terms = np.abs(r[:, 11:13]) + (np.abs(vw) * (np.abs(r[:, 0:2]).max(1)
                                                     + coc * np.abs(r[:, 4:6]).max(1)))[:, None]
        scale = terms * (w / ((w - t * vw) * (w + (1 - t) * vw)))[:, None]
    hit = (w > 0) & (w < F32_MISS)
    return np.where(hit[:, None], scale, 0.0)


def test_tlfr_general_motion_matches_loader(device):
    h, w, s = 5, 7, 6
    rec = _general_records(np.random.default_rng(3), h, w, s)
    model = CocModel.from_focus(6.0, 3.0)
    ref = io._tlfr_motion(rec.reshape(h, w, s, 16), model, "<records>")
    got = _unpack_tlfr(device, rec, (h, w, s), (model.c0, model.c1))
    motion = got["motion"].reshape(-1, 2)
    atol = MOTION_TERMS_EPS * _general_scale(rec, model)
    assert_close(motion, ref.reshape(-1, 2), rtol=MOTION_RTOL, atol=atol, what="motion")
    assert (motion[4:10] == 0).all() and (motion[::11] == 0).all()
    assert np.isfinite(motion).all() and np.abs(motion[1:4]).min() > 0


def test_tlfr_crossing_camera_plane_gives_nan_motion(device):
    h, w, s = 2, 3, 2
    rec = _general_records(np.random.default_rng(5), h, w, s)
    rec[0, 3], rec[0, 6], rec[0, 13] = 2.0, 1.0, 2.0   # w0 = w - t mv_w = 0
    rec[11, 3], rec[11, 6], rec[11, 13] = 2.0, 0.0, -3.0  # w1 = w + (1 - t) mv_w < 0
    model = CocModel.from_focus(2.0, 1.0)
    with pytest.raises(ValueError, match="crosses the camera plane"):
        io._tlfr_motion(rec.reshape(h, w, s, 16), model, "<records>")
    got = _unpack_tlfr(device, rec, (h, w, s), (model.c0, model.c1))
    motion = got["motion"].reshape(-1, 2)
    assert np.isnan(motion[[0, 11]]).all()
    assert np.isfinite(np.delete(motion, [0, 11], axis=0)).all()
    frame = SampleBuffer(**got, coc_model=model)
    frame.depth[~(frame.depth > 0)] = np.inf  # only motion may fail validation
    # the first bad motion is the crossing sample (random records may add motions beyond
    # the validated range, counted too)
    with pytest.raises(ValueError, match=r"^motion: sample \(y=0, x=0, i=0\) must be finite"
                                         r".* got \[nan, nan\]"):
        frame.validate()


# ==========================================================================================
# (2) a user struct via from_dtype
# ==========================================================================================
USER_DTYPE = np.dtype({
    "names": ["time", "id", "motion", "color", "depth", "lens", "position"],
    "formats": ["<f4", "<u4", ("<f4", 2), ("<f4", 3), "<f4", ("<f4", 2), ("<f4", 2)],
    "offsets": [0, 4, 8, 20, 36, 44, 56],   # gaps at 16, 32, 40, 52 and 64..72
    "itemsize": 72,
})


def _user_frame(rng, h, w, s):
    hws = (h, w, s)
    src = {name: rng.standard_normal(hws + tail).astype(np.float32)
           for name, tail in FIELDS.items()}
    special = np.array([-0.0, 1e-40, np.inf, -np.inf, 3.4e38, 0.0], np.float32)
    payload = np.uint32(0x7FC01234).view(np.float32)  # a quiet NaN with a payload
    for k, name in enumerate(FIELDS):
        flat = src[name].reshape(-1)
        flat[k:k + special.size] = special
        flat[-1 - k] = payload
    recs = np.frombuffer(rng.bytes(h * w * s * USER_DTYPE.itemsize), USER_DTYPE).copy()
    for name in FIELDS:
        recs[name] = src[name].reshape((-1,) + FIELDS[name])
    return src, recs


@pytest.mark.parametrize("tun", [dict(), dict(wg=32, items=3, stage=True),
                                 dict(wg=1, items=2)], ids=["default", "staged", "wg1"])
def test_user_struct_bit_exact(device, tun):
    h, w, s = 9, 13, 3  # 351 samples: not a multiple of wg * items
    src, recs = _user_frame(np.random.default_rng(11), h, w, s)
    lay = RecordLayout.from_dtype(USER_DTYPE)
    assert lay.stride == 72 and lay.motion == "screen" and set(lay.fields) == set(FIELDS)
    assert lay.offset("color") == 20 and lay.offset("position") == 56
    ctx, q = device.context, device.queue
    unpack = Unpack(ctx, lay, FIELDS, **tun)
    out = allocate(ctx, h, w, s)
    unpack(q, _upload(ctx, recs.view(np.uint8)), h, w, s, (0.0, 0.0), out).wait()
    got = _download(q, out, (h, w, s))
    for name in FIELDS:
        _assert_bits(got[name], src[name], name)


def test_subset_of_fields_and_bigger_buffers(device):
    h, w, s = 4, 5, 2
    src, recs = _user_frame(np.random.default_rng(2), h, w, s)
    ctx, q = device.context, device.queue
    unpack = Unpack(ctx, RecordLayout.from_dtype(USER_DTYPE), ("depth", "color"))
    assert unpack.fields == ("color", "depth")
    out = unpack.allocate(ctx, h, w, s)
    assert set(out) == {"color", "depth"}
    sentinel = np.full(h * w * s + 16, 0xDEADBEEF, np.uint32)  # past the end: untouched
    out["depth"] = _upload(ctx, sentinel, cl.mem_flags.READ_WRITE)
    records = cl.Buffer(ctx, cl.mem_flags.READ_ONLY, size=recs.nbytes + 100)
    cl.enqueue_copy(q, records, recs.view(np.uint8))
    unpack(q, records, h, w, s, (0.0, 0.0), out).wait()
    got = _download(q, out, (h, w, s))
    _assert_bits(got["color"], src["color"], "color")
    _assert_bits(got["depth"], src["depth"], "depth")
    tail = np.empty(16, np.uint32)
    cl.enqueue_copy(q, tail, out["depth"], src_offset=4 * h * w * s)
    assert (tail == 0xDEADBEEF).all(), "the kernel wrote past the last sample"


def test_from_dtype_names_mapping():
    dt = np.dtype([("rgb", "<f4", 3), ("w", "<f4"), ("pad", "<f4")])
    lay = RecordLayout.from_dtype(dt, names={"color": "rgb", "depth": "w"})
    assert lay.stride == 20 and lay.offsets == (("color", 0), ("depth", 12))
    one = np.dtype([("depth", "<f4", (1,)), ("time", "<f4")])
    assert RecordLayout.from_dtype(one).fields == ("depth", "time")


# ==========================================================================================
# (3) bad layouts and buffers
# ==========================================================================================
@pytest.mark.parametrize("kwargs, match", [
    (dict(stride=64, offsets={"colour": 0}), "unknown field 'colour'"),
    (dict(stride=64, offsets={"depth": 6}), "depth: byte offset must be a non-negative multiple"),
    (dict(stride=64, offsets={"depth": -4}), "depth: byte offset"),
    (dict(stride=64, offsets={"color": 56}), "color: 3 float32 at byte 56 end at byte 68, past"),
    (dict(stride=16, offsets={"lens": 0, "time": 4}), "time: .*overlap field lens"),
    (dict(stride=16, offsets={"color": 4, "depth": 0, "time": 12}), "time: .*overlap field color"),
    (dict(stride=62, offsets={"depth": 0}), "stride: must be a positive multiple of 4"),
    (dict(stride=0, offsets={"depth": 0}), "stride"),
    (dict(stride=8.0, offsets={"depth": 0}), "stride: expected an integer"),
    (dict(stride=64, offsets={}), "at least one field"),
    (dict(stride=64, offsets=(("depth", 0), ("depth", 4))), "depth: listed twice"),
    (dict(stride=64, offsets={"depth": 0}, motion="world"), "motion: expected one of"),
    (dict(stride=64, offsets={"motion": 0, "depth": 12}, motion="tlfr"),
     "motion: .*lacks position, lens, time"),
    (dict(stride=64, offsets={"motion": 0, "depth": 8, "position": 12, "lens": 20, "time": 28},
          motion="tlfr"), "depth: .*overlap field motion"),
])
def test_bad_layouts(kwargs, match):
    with pytest.raises(ValueError, match=match):
        RecordLayout(**kwargs)


@pytest.mark.parametrize("dtype, kwargs, match", [
    (np.dtype("<f4"), {}, "expected a structured dtype"),
    (np.dtype([("a", "<f4")]), {}, "no member is named after a clrecon field"),
    (np.dtype([("color", "<f4", 2)]), {}, r"color: member 'color' must hold 3 float32"),
    (np.dtype([("depth", "<f8")]), {}, "depth: member 'depth' must be little-endian float32"),
    (np.dtype([("depth", ">f4")]), {}, "must be little-endian float32"),
    (np.dtype([("lens", "<f4", (1, 2))]), {}, "lens: member 'lens' must hold 2"),
    (np.dtype([("motion", "<f4", 2)]), dict(motion="tlfr"), "motion: .*must hold 3"),
    (np.dtype([("depth", "<f4")]), dict(names={"depth": "z"}), "depth: dtype has no member 'z'"),
    (np.dtype([("depth", "<f4")]), dict(names={"z": "depth"}), "unknown field 'z'"),
    (np.dtype({"names": ["depth"], "formats": ["<f4"], "offsets": [2], "itemsize": 8}), {},
     "depth: byte offset must be a non-negative multiple of 4, got 2"),
])
def test_bad_dtypes(dtype, kwargs, match):
    with pytest.raises(ValueError, match=match):
        RecordLayout.from_dtype(dtype, **kwargs)


def test_bad_fields_and_buffers(device):
    ctx, q = device.context, device.queue
    lay = RecordLayout(stride=16, offsets={"color": 0, "depth": 12})
    with pytest.raises(ValueError, match="needs lens, motion, which the record layout lacks"):
        Unpack(ctx, lay, ("color", "lens", "motion"))
    with pytest.raises(ValueError, match="unknown 'rgb'"):
        Unpack(ctx, lay, ("rgb",))
    with pytest.raises(ValueError, match="wg: expected an integer"):
        Unpack(ctx, lay, ("depth",), wg=2.5)
    unpack = Unpack(ctx, lay, ("color", "depth"))
    h, w, s = 3, 4, 2
    n = h * w * s
    records = cl.Buffer(ctx, cl.mem_flags.READ_ONLY, size=n * 16)
    out = unpack.allocate(ctx, h, w, s)
    small = dict(out, color=cl.Buffer(ctx, cl.mem_flags.READ_WRITE, size=n * 12 - 4))
    with pytest.raises(ValueError, match=f"color: output buffer holds {n * 12 - 4} bytes, "
                                         f"needs {n * 12}"):
        unpack(q, records, h, w, s, (0.0, 0.0), small)
    short = cl.Buffer(ctx, cl.mem_flags.READ_ONLY, size=n * 16 - 16)
    with pytest.raises(ValueError, match=f"records: buffer holds {n * 16 - 16} bytes, needs "
                                         f"{n * 16}"):
        unpack(q, short, h, w, s, (0.0, 0.0), out)
    with pytest.raises(ValueError, match="out: no buffer for depth"):
        unpack(q, records, h, w, s, (0.0, 0.0), {"color": out["color"]})
    with pytest.raises(ValueError, match="out: this pass does not write lens"):
        unpack(q, records, h, w, s, (0.0, 0.0), dict(out, lens=out["color"]))
    with pytest.raises(ValueError, match="height, width, spp: must be positive"):
        unpack(q, records, 0, w, s, (0.0, 0.0), out)
    with pytest.raises(ValueError, match="coc: coefficients must be finite"):
        unpack(q, records, h, w, s, (np.nan, 0.0), out)
    unpack(q, records, h, w, s, (0.0, 0.0), out).wait()  # the right sizes pass
    assert COMPONENTS == {"color": 3, "position": 2, "depth": 1, "lens": 2, "time": 1,
                          "motion": 2}


# ==========================================================================================
# timing (not a test): python tests/passes/test_adapter.py [H W S]
# ==========================================================================================
def _bench(height=720, width=1280, spp=8, repeats=5):
    from clrecon.core.device import event_ms, get_device

    dev = get_device()
    ctx, q = dev.context, dev.queue
    n = height * width * spp
    rng = np.random.default_rng(0)
    rec = _general_records(rng, 1, 1024, 1)  # a block of valid records, tiled
    rec = np.tile(rec, (-(-n // len(rec)), 1))[:n]
    records = _upload(ctx, rec)
    unpack = Unpack(ctx, RecordLayout.tlfr())
    out = unpack.allocate(ctx, height, width, spp)
    unpack(q, records, height, width, spp, (-1.0, 1.0), out).wait()  # warm-up
    times = []
    for _ in range(repeats):
        ev = unpack(q, records, height, width, spp, (-1.0, 1.0), out)
        ev.wait()
        times.append(event_ms(ev))
    ms = float(np.median(times))
    read, written = n * 64, n * 4 * sum(COMPONENTS.values())
    print(f"{dev.info.label}: {width}x{height} x {spp} spp = {n} records; unpack median "
          f"{ms:.2f} ms of {[round(t, 2) for t in times]}; {read / 1e6:.0f} MB read + "
          f"{written / 1e6:.0f} MB written -> {(read + written) / ms / 1e6:.2f} GB/s")


if __name__ == "__main__":
    _bench(*(int(a) for a in sys.argv[1:4]))
