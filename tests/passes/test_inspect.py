"""Pass ``inspect``: device validation and inspection agree with the host SampleBuffer."""
from __future__ import annotations

import math

import numpy as np
import pyopencl as cl
import pytest
from conftest import assert_close

from clrecon.core.camera import CocModel
from clrecon.core.inspect import NSLOT, RULES, Inspect, inspect_device, udiv_magic
from clrecon.core.samples import (
    FIELDS,
    LENS_TOLERANCE,
    POSITION_TOLERANCE,
    SampleBuffer,
    pixel_centres,
)

FULL = tuple(FIELDS)
F32 = np.float32
COC = CocModel.from_focus(3.5, 4.0)


def random_frame(rng, h, w, s, *, miss=0.2, inf_share=0.5, motion=True, coc=COC):
    """A valid random frame; ``miss`` of the samples are misses, ``inf_share`` of those inf
    (the others finite depths >= 1e30)."""
    hws = (h, w, s)
    depth = rng.uniform(0.25, 40.0, hws)
    is_miss = rng.random(hws) < miss
    far = np.where(rng.random(hws) < inf_share, np.inf, rng.uniform(1e30, 3e38, hws))
    depth[is_miss] = far[is_miss]
    r = np.sqrt(rng.random(hws))
    phi = rng.uniform(0, 2 * np.pi, hws)
    return SampleBuffer(
        color=rng.exponential(2.0, hws + (3,)),
        position=pixel_centres(h, w, s) + rng.uniform(-0.5, 0.5, hws + (2,)).astype(F32),
        depth=depth,
        lens=np.stack([r * np.cos(phi), r * np.sin(phi)], -1),
        time=rng.random(hws),
        motion=rng.normal(0.0, 4.0, hws + (2,)) if motion else np.zeros(hws + (2,)),
        coc_model=coc,
    )


def upload(ctx, buf: SampleBuffer, fields=FULL) -> dict[str, cl.Buffer]:
    mf = cl.mem_flags
    return {n: cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=getattr(buf, n))
            for n in fields}


def coc_of(buf: SampleBuffer) -> tuple[float, float]:
    return buf.coc_model.c0, buf.coc_model.c1


def run(device, buf, fields=FULL, validate=True, pass_=None):
    bufs = upload(device.context, buf, fields)
    if pass_ is None:
        return inspect_device(device.queue, bufs, buf.height, buf.width, buf.spp, coc_of(buf),
                              validate=validate)
    ev = pass_(device.queue, bufs, buf.height, buf.width, buf.spp, coc_of(buf))
    return pass_.read(device.queue, [ev])


def check_info(got, buf: SampleBuffer, motion=True):
    """Exact where the device is exact; coc and motion within a few float32 ulp."""
    ref = buf.inspect()
    assert (got.width, got.height, got.spp) == (ref.width, ref.height, ref.spp)
    assert got.min_depth == ref.min_depth
    assert got.max_depth == ref.max_depth
    assert got.miss_fraction == ref.miss_fraction
    m = buf.coc_model
    hit = buf.depth[buf.depth < 1e30]
    scale = abs(m.c0) / float(hit.min()) + abs(m.c1) if hit.size else abs(m.c1)
    assert_close(got.max_abs_coc, ref.max_abs_coc, rtol=1e-6, atol=1e-6 * scale,
                 what="max_abs_coc")
    if motion:
        assert_close(got.max_abs_motion, ref.max_abs_motion, rtol=1e-6, atol=0.0,
                     what="max_abs_motion")
    else:
        assert got.max_abs_motion == 0.0
    assert got.has_motion == ref.has_motion and got.has_defocus == ref.has_defocus


def has_fp64(device) -> bool:
    """Without fp64 the device evaluates the lens rule in float (documented): samples within
    a float32 ulp of the bound may then be judged differently from the host."""
    return "cl_khr_fp64" in device.device.extensions.split()


def host_error(buf: SampleBuffer) -> str | None:
    try:
        buf.validate()
    except ValueError as exc:
        return str(exc)
    return None


def device_error(device, buf: SampleBuffer, fields=FULL) -> str | None:
    try:
        run(device, buf, fields)
    except ValueError as exc:
        return str(exc)
    return None


# -- inspection -----------------------------------------------------------------------------

SHAPES = [(1, 1, 1), (1, 1, 64), (1, 53, 3), (29, 1, 8), (7, 13, 3), (9, 31, 64),
          (33, 65, 8), (64, 80, 1)]


@pytest.mark.parametrize("shape", SHAPES, ids=lambda s: "x".join(map(str, s)))
def test_inspect_matches_host(device, shape):
    rng = np.random.default_rng(shape[0] * 10007 + shape[1] * 101 + shape[2])
    buf = random_frame(rng, *shape)
    check_info(run(device, buf), buf)


@pytest.mark.parametrize("case", ["no_hits", "far_misses", "no_misses", "zero_motion",
                                  "pinhole", "behind_only"])
def test_inspect_special_frames(device, case):
    rng = np.random.default_rng(7)
    kw = {"no_hits": dict(miss=1.0), "far_misses": dict(miss=1.0, inf_share=0.0),
          "no_misses": dict(miss=0.0), "zero_motion": dict(motion=False),
          "pinhole": dict(coc=CocModel()), "behind_only": dict(coc=CocModel(0.0, 2.5))}[case]
    buf = random_frame(rng, 5, 7, 3, **kw)
    got = run(device, buf)
    check_info(got, buf, motion=case != "zero_motion")
    if case in ("no_hits", "far_misses"):
        assert got.min_depth == got.max_depth == math.inf and got.miss_fraction == 1.0
    if case == "pinhole":
        assert got.max_abs_coc == 0.0 and not got.has_defocus


@pytest.mark.parametrize("contiguous", [False, True], ids=["interleaved", "contiguous"])
def test_small_groups_and_tails(device, contiguous):
    """Many work-groups with partial tails: 32 x 3 samples per group, N not a multiple."""
    p = Inspect(device.context, FULL, local_size=32, items=3, contiguous=contiguous)
    rng = np.random.default_rng(11)
    for shape in [(1, 1, 1), (1, 1, 64), (3, 5, 7), (11, 17, 3)]:
        buf = random_frame(rng, *shape)
        res = run(device, buf, pass_=p)
        ref = buf.inspect()
        assert res["hits"] == int((buf.depth < 1e30).sum())
        assert res["min_depth"] == ref.min_depth and res["max_depth"] == ref.max_depth
        assert_close(res["max_abs_motion"], ref.max_abs_motion, rtol=1e-6, atol=0.0)
        assert res["first_bad"] == {n: None for n in RULES}
        assert res["bad_count"] == {n: 0 for n in RULES}
    # bad samples in several groups: the smallest index wins, all are counted
    buf = random_frame(rng, 11, 17, 3)
    flat = buf.time.reshape(-1)
    for i in (400, 97, 560, 96):
        flat[i] = 2.0
    res = run(device, buf, pass_=p)
    assert res["first_bad"]["time"] == 96 and res["bad_count"]["time"] == 4


# -- validation -------------------------------------------------------------------------------

NAN, INF = float("nan"), float("inf")

# rule -> list of (linear sample indices, value(s) written there)
BAD_CASES = {
    "depth": [([5], 0.0), ([17, 3], -1.0), ([200], NAN), ([0], -0.0), ([269], -INF)],
    "color": [([8], (1.0, 2.0, INF)), ([30, 31, 32], (NAN, 0.0, 0.0)), ([269], (0.0, -INF, 1.0))],
    "motion": [([44], (NAN, 0.0)), ([1, 250], (0.0, INF))],
    "time": [([12], -1e-7), ([13], 1.0000001), ([14, 100], NAN)],
    "lens": [([20], (1.0001, 0.0)), ([21], (NAN, 0.0)), ([22, 23], (0.0, -INF)),
             ([24], (0.75, 0.7))],
    "position": [([6], "left"), ([7], "right"), ([8], "above"), ([9, 10], "below"),
                 ([11], "nan")],
}
CASES = [(rule, k) for rule, cases in BAD_CASES.items() for k in range(len(cases))]


def inject(buf: SampleBuffer, rule: str, indices, value):
    arr = getattr(buf, rule)
    flat = arr.reshape(-1, *arr.shape[3:])
    for i in indices:
        if rule == "position":
            py, rem = divmod(i, buf.width * buf.spp)
            px = rem // buf.spp
            x, y = px + 0.5, py + 0.5
            x, y = {"left": (px - 2e-4, y), "right": (px + 1 + 2e-4, y),
                    "above": (x, py - 2e-4), "below": (x, py + 1 + 3e-4),
                    "nan": (NAN, y)}[value]
            flat[i] = (x, y)
        else:
            flat[i] = value


@pytest.mark.parametrize("rule,k", CASES, ids=[f"{r}{k}" for r, k in CASES])
def test_validation_message_matches_host(device, rule, k):
    if (rule, k) == ("lens", 0) and not has_fp64(device):
        pytest.skip("lens bound within a float32 ulp needs fp64 on the device")
    buf = random_frame(np.random.default_rng(3), 6, 9, 5)  # N = 270
    indices, value = BAD_CASES[rule][k]
    inject(buf, rule, indices, value)
    expected = host_error(buf)
    assert expected is not None and expected.startswith(f"{rule}: ")
    assert device_error(device, buf) == expected


def test_valid_frame_passes_and_boundaries(device):
    """Samples exactly on the tolerance bounds (valid) and one float32 step beyond them."""
    buf = random_frame(np.random.default_rng(5), 4, 6, 2)
    tol, r_max = F32(POSITION_TOLERANCE), (1 + LENS_TOLERANCE) ** 2
    # the largest float32 x with x^2 <= (1 + tol)^2 in float64: valid; the next one is not
    x = F32(math.sqrt(r_max))
    while float(x) ** 2 > r_max:
        x = np.nextafter(x, F32(0))
    while float(np.nextafter(x, F32(2))) ** 2 <= r_max:
        x = np.nextafter(x, F32(2))
    lens_exact = has_fp64(device)  # else the lens rule runs in float (documented)
    if lens_exact:
        buf.lens[0, 0, 0] = (x, 0.0)
        buf.lens[0, 0, 1] = (0.0, -x)
    buf.position[1, 2, 0] = (F32(2) - tol, F32(1) - tol)
    buf.position[1, 2, 1] = (F32(3) + tol, F32(2) + tol)
    buf.time[2, 3] = (0.0, 1.0)
    assert host_error(buf) is None
    assert device_error(device, buf) is None
    check_info(run(device, buf), buf)
    # one step beyond each bound fails, with the host's message
    for name, idx, value in [
        *([("lens", (0, 0, 1), (0.0, -np.nextafter(x, F32(2))))] if lens_exact else []),
        ("position", (1, 2, 0), (np.nextafter(F32(2) - tol, F32(0)), F32(1) - tol)),
        ("position", (1, 2, 1), (F32(3) + tol, np.nextafter(F32(2) + tol, F32(3)))),
        ("time", (2, 3, 1), np.nextafter(F32(1), F32(2))),
    ]:
        bad = random_frame(np.random.default_rng(5), 4, 6, 2)
        getattr(bad, name)[idx] = value
        expected = host_error(bad)
        assert expected is not None and expected.startswith(name)
        assert device_error(device, bad) == expected


def test_two_bad_rules_report_validate_order(device):
    rng = np.random.default_rng(9)
    buf = random_frame(rng, 6, 9, 5)
    buf.time.reshape(-1)[3] = 7.0           # earlier sample, later rule
    buf.depth.reshape(-1)[200] = -2.0       # later sample, first rule
    expected = host_error(buf)
    assert expected.startswith("depth: ")
    assert device_error(device, buf) == expected
    buf = random_frame(rng, 6, 9, 5)
    inject(buf, "position", [0], "left")
    inject(buf, "color", [150, 151], (INF, 0.0, 0.0))
    buf.lens.reshape(-1, 2)[7] = (2.0, 0.0)
    expected = host_error(buf)
    assert expected.startswith("color: ")
    assert device_error(device, buf) == expected


def test_coc_model_must_be_finite(device):
    for c0, c1 in [(NAN, 1.0), (-3.0, INF)]:
        buf = random_frame(np.random.default_rng(1), 3, 4, 2, coc=CocModel(c0, c1))
        expected = host_error(buf)
        assert expected.startswith("coc_model: ")
        assert device_error(device, buf) == expected
        inspect_device(device.queue, upload(device.context, buf), 3, 4, 2, (c0, c1),
                       validate=False)


def with_valid_rest(buf: SampleBuffer, fields, rng) -> SampleBuffer:
    """A frame holding ``buf``'s ``fields`` and valid values in every other field."""
    full = random_frame(rng, *buf.shape)
    for name in fields:
        getattr(full, name)[:] = getattr(buf, name)
    return full


@pytest.mark.parametrize("fields", [("color", "depth"), ("depth",)], ids=["color", "depth"])
def test_partial_fields_skip_absent_rules(device, fields):
    rng = np.random.default_rng(13)
    buf = random_frame(rng, 7, 5, 3)
    # garbage in every field that is not uploaded: its rule must be skipped
    buf.motion[0, 0, 0] = (NAN, 1e6)
    buf.time[1, 1, 1] = -3.0
    buf.lens[2, 2, 2] = (5.0, 5.0)
    buf.position[3, 3, 0] = (-100.0, NAN)
    if "color" not in fields:
        buf.color[4, 4, 1] = (INF, NAN, 0.0)
    assert host_error(buf) is not None and device_error(device, buf, fields) is None
    check_info(run(device, buf, fields), buf, motion=False)
    # a bad sample of a present field is still reported as validate() reports it
    if "color" in fields:
        buf.color[6, 4, 2] = (0.0, NAN, 0.0)
        expected = host_error(with_valid_rest(buf, fields, rng))
        assert expected.startswith("color: ")
        assert device_error(device, buf, fields) == expected
    buf.depth[6, 0, 1] = NAN
    expected = host_error(with_valid_rest(buf, fields, rng))
    assert expected.startswith("depth: ")
    assert device_error(device, buf, fields) == expected


def test_nan_does_not_poison_without_validation(device):
    buf = random_frame(np.random.default_rng(17), 6, 7, 4)
    buf.depth[1, 2, 3] = NAN
    buf.depth[4, 4, 0] = -0.5  # a negative hit counts as a host hit too
    buf.motion[2, 2, 2] = (NAN, 3.0)
    buf.motion[3, 3, 3] = (1e30, 0.0)  # huge but finite: no overflow in the length
    assert host_error(buf).startswith("depth: ")
    got = run(device, buf, validate=False)
    ref = buf.inspect()  # NaN poisons the host's max of coc and motion, not the device's
    coc = np.abs(buf.coc())
    assert_close(got.max_abs_coc, np.nanmax(coc), rtol=1e-6, atol=1e-6)
    assert_close(got.max_abs_motion, 1e30, rtol=1e-6, atol=0.0)
    assert got.min_depth == ref.min_depth == F32(-0.5)
    assert got.max_depth == ref.max_depth and got.miss_fraction == ref.miss_fraction


def test_call_does_not_block(device):
    """__call__ only enqueues: it returns while its wait_for event is still pending."""
    buf = random_frame(np.random.default_rng(19), 4, 4, 2)
    bufs = upload(device.context, buf)
    p = Inspect(device.context, FULL)
    gate = cl.UserEvent(device.context)
    ev = p(device.queue, bufs, 4, 4, 2, coc_of(buf), wait_for=[gate])
    assert isinstance(ev, cl.Event)
    assert ev.command_execution_status != cl.command_execution_status.COMPLETE
    gate.set_status(cl.command_execution_status.COMPLETE)
    res = p.read(device.queue, [ev])
    assert res["hits"] == int((buf.depth < 1e30).sum())


def test_host_preconditions(device):
    ctx, q = device.context, device.queue
    small = {"depth": cl.Buffer(ctx, cl.mem_flags.READ_ONLY, size=64)}
    with pytest.raises(ValueError, match="fewer than 2\\*\\*31"):
        inspect_device(q, small, 2**16, 2**15, 1, (0.0, 0.0))
    with pytest.raises(ValueError, match="depth: buffer of 64 bytes"):
        inspect_device(q, small, 2**16, 2**15 - 1, 1, (0.0, 0.0))
    with pytest.raises(ValueError, match="empty frame"):
        inspect_device(q, small, 0, 4, 1, (0.0, 0.0))
    with pytest.raises(ValueError, match="needs the depth field"):
        Inspect(ctx, ("color",))
    with pytest.raises(ValueError, match="unknown sample fields"):
        Inspect(ctx, ("depth", "colour"))
    with pytest.raises(ValueError, match="color: no buffer"):
        Inspect(ctx, ("depth", "color"))(q, small, 1, 1, 1, (0.0, 0.0))
    assert NSLOT == 19


def test_udiv_magic_is_exact():
    rng = np.random.default_rng(23)
    a = np.concatenate([np.arange(4096), rng.integers(0, 2**31, 20000),
                        np.arange(2**31 - 4096, 2**31)]).astype(np.uint64)
    for d in [*range(1, 70), 720, 1280, 3**19, 2**30 + 1, 2**31 - 1,
              *rng.integers(1, 2**31, 30)]:
        m, sh = udiv_magic(int(d))
        assert m < 2**32
        np.testing.assert_array_equal((a * np.uint64(m)) >> np.uint64(sh), a // np.uint64(d))
