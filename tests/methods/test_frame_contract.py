"""The frame contract: a pipeline reused frame after frame refuses a frame its plan was not
built for (naming the bound and both values), or re-plans with ``grow=True``; never a crash,
never a silently wrong image.

Anything that could crash the interpreter (a kernel trusting a stale bound) runs in a
subprocess, so that a crash fails its test instead of the whole run.
"""
from __future__ import annotations

import dataclasses
import json
import math
import os
import subprocess
import sys
import textwrap

import numpy as np
import pyopencl as cl
import pytest
from conftest import assert_close

import clrecon
from clrecon import api
from clrecon.api import make_pipeline
from clrecon.core.errors import DeviceMemoryError
from clrecon.core.pipeline import DeviceSamples
from clrecon.core.plan import BOX_PLAN, covering
from clrecon.core.samples import SampleBuffer
from clrecon.scenes import get_scene, render_samples

METHODS = [("box", {}), ("sweep", {}), ("sweep", {"dof_layers": True}),
           ("sweep", {"sort": "tile"}), ("layered", {}), ("layered", {"filter": "mip"}),
           ("layered", {"mode": "lrdm"}), ("splat", {})]
IDS = [m + "".join(f"-{k}={v}" for k, v in kn.items()) for m, kn in METHODS]


def _frame(scene: str, w: int = 40, h: int = 32, spp: int = 4, seed: int = 0, device=None):
    return render_samples(get_scene(scene), w, h, spp=spp, seed=seed, device=device)


def _out(dev, buf):
    return cl.Buffer(dev.context, cl.mem_flags.READ_WRITE, buf.height * buf.width * 12)


def _read(dev, out, buf, ev):
    img = np.empty((buf.height, buf.width, 3), np.float32)
    cl.enqueue_copy(dev.queue, img, out, wait_for=[ev])
    return img


# -- reuse across frames, in a subprocess ----------------------------------------------------
_REUSE = textwrap.dedent("""
    import json, sys, numpy as np, pyopencl as cl
    from clrecon.core.device import get_device
    from clrecon.api import make_pipeline
    from clrecon.core.pipeline import DeviceSamples
    from clrecon.scenes import get_scene, render_samples
    method, knobs = sys.argv[1], json.loads(sys.argv[2])
    dev = get_device(int(sys.argv[3]))
    def frame(scene, spp, seed=0):
        return render_samples(get_scene(scene), 40, 32, spp=spp, seed=seed, device=dev)
    built = frame("fence", 8)           # plan for this frame ...
    cases = {"fewer_spp": frame("fence", 4), "more_spp": frame("fence", 16),
             "more_blur": frame("huge_coc", 8), "more_motion": frame("fast_motion", 8)}
    pipe = make_pipeline(method, dev.context, built.inspect(), **knobs)
    res = {}
    for name, buf in cases.items():
        # no info: the executor inspects (and validates) on the device
        s = DeviceSamples.upload(dev.queue, buf)
        out = cl.Buffer(dev.context, cl.mem_flags.READ_WRITE, buf.height * buf.width * 12)
        try:
            pipe(dev.queue, s, out).wait()
            res[name] = "ran"
        except ValueError as exc:
            res[name] = "refused: " + str(exc)
    print(json.dumps(res))
""")


@pytest.mark.parametrize("method,knobs", METHODS, ids=IDS)
def test_reuse_on_other_frames_is_refused_or_runs_never_crashes(device, method, knobs):
    """4 and 16 spp into an 8-spp pipeline, and frames with far more blur or motion: each is
    refused with a ValueError naming the bound, or (box: the kernel takes spp as an
    argument) runs; the interpreter never dies."""
    proc = subprocess.run([sys.executable, "-c", _REUSE, method, json.dumps(knobs),
                           str(device.info.index)], capture_output=True, text=True,
                          timeout=600, env=os.environ | {"PYOPENCL_COMPILER_OUTPUT": "0"})
    assert proc.returncode == 0, f"rc {proc.returncode}: {proc.stderr[-2000:]}"
    res = json.loads(proc.stdout.strip().splitlines()[-1])
    for case in ("fewer_spp", "more_spp"):
        if method == "box":
            assert res[case] == "ran"
        else:
            assert res[case].startswith("refused: ") and "spp = " in res[case] \
                and "spp == 8" in res[case], res[case]
    if method in ("layered", "splat"):  # sized from the largest blur
        for case in ("more_blur", "more_motion"):
            assert res[case].startswith("refused: ") and "grow=True" in res[case], res[case]


# -- every bound is enforced ---------------------------------------------------------------
def _violating(bound, info):
    """A frame description that breaks ``bound`` (every other fact kept)."""
    grow = {"max_abs_coc": "max_abs_coc", "max_abs_motion": "max_abs_motion",
            "guard_px": "max_abs_coc"}
    if bound.op == "==":
        return dataclasses.replace(info, **{bound.name: int(bound.limit) + 1})
    if bound.name in grow:
        f = grow[bound.name]
        return dataclasses.replace(info, **{f: getattr(info, f) + 10.0 + 2 * bound.limit})
    if bound.name == "inverse_depth_span":
        return dataclasses.replace(info, min_depth=1.0, max_depth=2.0, miss_fraction=0.0)
    raise AssertionError(f"no violating frame for bound {bound}")


@pytest.mark.parametrize("scene", ["fence", "static_focus", "spheres"])
@pytest.mark.parametrize("method,knobs", METHODS, ids=IDS)
def test_each_bound_is_enforced(device, method, knobs, scene):
    """Every bound of every plan, broken alone, is reported by name with both values; the
    frame the plan was built from passes."""
    info = _frame(scene, device=device).inspect()
    pipe = make_pipeline(method, device.context, info, **knobs)
    assert pipe.check(info) == []
    assert {"width", "height"} <= {b.name for b in pipe.plan.bounds}
    for b in pipe.plan.bounds:
        bad = _violating(b, info)
        msgs = pipe.check(bad)
        assert any(m.startswith(f"frame {b.name} = ") and f"{b.name} {b.op}" in m
                   for m in msgs), (b, msgs)


def test_single_depth_splat_plan_bounds_its_depth_span(device):
    """splat collapses to one layer on a frame of a single depth; a frame with depth range
    is then refused, not composited as one layer."""
    buf = _frame("fence", device=device)
    buf.depth[:] = 3.0
    info = buf.validate().inspect()
    pipe = make_pipeline("splat", device.context, info)
    assert "inverse_depth_span <= 0" in pipe.describe()["bounds"]
    msgs = pipe.check(dataclasses.replace(info, min_depth=1.0, max_depth=5.0))
    assert any("inverse_depth_span" in m for m in msgs)


def test_refusal_names_bound_and_both_values(device):
    built = _frame("fence", spp=8, device=device)
    pipe = make_pipeline("layered", device.context, built.inspect())
    buf = _frame("fence", spp=4, device=device)
    s = DeviceSamples.upload(device.queue, buf)
    with pytest.raises(ValueError, match=r"frame spp = 4 is outside the plan's bound "
                                         r"spp == 8 \(kernels compiled for this spp\)"):
        pipe(device.queue, s, _out(device, buf))


# -- grow=True -------------------------------------------------------------------------------
@pytest.mark.parametrize("method", ["layered", "splat", "sweep"])
def test_grow_replans_and_matches_a_plan_for_both_frames(device, method):
    """With grow=True a blurrier frame re-plans for a description covering both frames; the
    image is exactly that plan's, and the next, sharper frame is then within bounds."""
    sharp, blurry = _frame("fence", device=device), _frame("huge_coc", device=device)
    pipe = make_pipeline(method, device.context, sharp.inspect(), grow=True)
    s = DeviceSamples.upload(device.queue, blurry, info=blurry.inspect())
    out = _out(device, blurry)
    got = _read(device, out, blurry, pipe(device.queue, s, out))
    want_pipe = make_pipeline(method, device.context, covering(sharp.inspect(),
                                                               blurry.inspect()))
    want = _read(device, out, blurry, want_pipe(device.queue, s, out))
    assert_close(got, want, rtol=1e-6, atol=1e-7, what=f"{method} grown")
    assert pipe.check(sharp.inspect()) == [] and pipe.grow


# -- temporaries from the caller -------------------------------------------------------------
@pytest.mark.parametrize("method,knobs", [("layered", {}), ("splat", {}),
                                          ("sweep", {"sort": "tile"}),
                                          ("sweep", {"dof_layers": True})])
def test_caller_temporaries_are_size_checked_and_used(device, method, knobs):
    buf = _frame("fence", device=device)
    info = buf.inspect()
    pipe = make_pipeline(method, device.context, info, **knobs)
    temps = pipe.plan.temporaries
    assert temps, "this plan has temporaries"
    s = DeviceSamples.upload(device.queue, buf, info=info)
    out = _out(device, buf)
    own = _read(device, out, buf, pipe(device.queue, s, out))
    rw = cl.mem_flags.READ_WRITE
    mine = {k: cl.Buffer(device.context, rw, v) for k, v in temps.items()}
    got = _read(device, out, buf, pipe(device.queue, s, out, temporaries=mine))
    assert_close(got, own, rtol=0, atol=0, what="caller temporaries")
    name = next(iter(temps))
    with pytest.raises(ValueError, match=f"temporaries: '{name}' needs {temps[name]} bytes"):
        pipe(device.queue, s, out, temporaries={name: cl.Buffer(device.context, rw, 4)})
    with pytest.raises(ValueError, match="has no \\['nosuch'\\]"):
        pipe(device.queue, s, out, temporaries={"nosuch": mine[name]})


def test_a_selection_of_steps(device):
    """steps= runs a plan's steps of those names in plan order: the later steps of layered
    on the outputs of its first ones give the whole run's image; a name the plan lacks, or
    an empty selection, is refused naming the plan's steps."""
    buf = _frame("fence", device=device)
    info = buf.inspect()
    pipe = make_pipeline("layered", device.context, info, safeguard=False)
    s = DeviceSamples.upload(device.queue, buf, info=info)
    out = _out(device, buf)
    names = [st.name for st in pipe.plan.steps]
    first = make_pipeline("layered", device.context, info, safeguard=False)
    first(device.queue, s, out, steps=tuple(names[:2]))
    # only the temporaries the two steps name are allocated (the statistics, the partitions)
    named = {n for st in first.plan.steps[:2] for n in st.inputs + st.outputs}
    assert set(first._own) == named & set(first.plan.temporaries)
    whole = _read(device, out, buf, pipe(device.queue, s, out))
    cl.enqueue_fill_buffer(device.queue, out, np.float32(0), 0, out.size).wait()
    pipe(device.queue, s, out, steps=tuple(names[:2]))
    assert [n for n, _ in pipe.events] == names[:2]
    got = _read(device, out, buf, pipe(device.queue, s, out, steps=tuple(names[2:])))
    assert "tile_stats" not in {n for n, _ in pipe.events}
    assert_close(got, whole, rtol=0, atol=0, what="the steps in two selections")
    with pytest.raises(ValueError, match="has no \\['nosuch'\\]"):
        pipe(device.queue, s, out, steps=("nosuch",))
    with pytest.raises(ValueError, match="its steps are"):
        pipe(device.queue, s, out, steps=())


def test_run_reads_the_callers_arrays_and_leaves_them_as_they_were(device):
    """On a CPU device run() reads the frame's arrays in place and keeps no reference to them
    after the call; every device leaves them unchanged, the negative-colour path (splat runs
    the positive and negative parts apart) included; a frame changed in place between calls
    is read as it is then."""
    buf = _frame("fence", device=device)
    before = {k: v.copy() for k, v in buf.arrays().items()}
    first = clrecon.run(buf, "box", device)
    for k, v in buf.arrays().items():
        assert np.array_equal(v, before[k]), k
    if device.info.device_type == "CPU":  # read in place: nothing of the frame is kept
        assert list(api._sessions.values())[-1].samples is None
    buf.color *= 2.0
    second = clrecon.run(buf, "box", device)
    assert_close(second.image, 2.0 * first.image, rtol=1e-6, atol=0, what="the changed frame")
    neg = SampleBuffer(**{k: v.copy() for k, v in buf.arrays().items()},
                       coc_model=buf.coc_model)
    neg.color[::2] *= -1.0
    kept = neg.color.copy()
    clrecon.run(neg, "splat", device, allow_negative=True, safeguard=False)
    assert np.array_equal(neg.color, kept)


# -- the device samples --------------------------------------------------------------------
def test_device_samples_need_coc_and_big_enough_buffers(device):
    buf = _frame("fence", device=device)
    s = DeviceSamples.upload(device.queue, buf)
    with pytest.raises(TypeError):
        DeviceSamples(buf.height, buf.width, buf.spp, s.buffers)  # coc left out
    with pytest.raises(ValueError, match="field 'color' needs a buffer of at least"):
        DeviceSamples(buf.height, buf.width, buf.spp * 2, s.buffers, (0.0, 0.0))
    with pytest.raises(ValueError, match="coc coefficients must be finite"):
        DeviceSamples(buf.height, buf.width, buf.spp, s.buffers, (math.inf, 0.0))
    with pytest.raises(ValueError, match="unknown field 'colour'"):
        DeviceSamples(buf.height, buf.width, buf.spp, {"colour": s["color"]}, (0.0, 0.0))


def test_missing_field_is_refused_by_name(device):
    buf = _frame("fence", device=device)
    pipe = make_pipeline("layered", device.context, buf.inspect())
    s = DeviceSamples.upload(device.queue, buf, ("color", "depth"), info=buf.inspect())
    with pytest.raises(ValueError, match=r"missing \['position', 'lens'"):
        pipe(device.queue, s, _out(device, buf))


@pytest.mark.parametrize("method", ["box", "splat", "layered"])
def test_float64_field_is_refused_before_any_kernel(device, method):
    """A field replaced by a float64 copy after construction: refused by name (the kernels
    would read it as float32 garbage, out of bounds)."""
    buf = _frame("fence", device=device)
    buf.depth = buf.depth.astype(np.float64)
    with pytest.raises(ValueError, match="depth: expected float32, got float64"):
        clrecon.run(buf, method, device)
    buf = _frame("fence", device=device)
    buf.color = np.asfortranarray(buf.color)
    with pytest.raises(ValueError, match="color: expected a C-contiguous array"):
        clrecon.run(buf, method, device)


# -- run(): plans and buffers kept frame to frame --------------------------------------------
@pytest.mark.parametrize("method", ["box", "sweep", "layered", "splat"])
def test_run_reuses_the_plan_for_the_same_frame_and_replans_for_another(device, method):
    a, b = _frame("fence", seed=1, device=device), _frame("huge_coc", seed=2, device=device)
    first = clrecon.run(a, method, device)
    again = clrecon.run(a, method, device)
    assert again.plan_ms == 0.0 and again.frame_ms == again.wall_ms
    assert first.plan_ms > 0.0 and first.frame_ms == first.wall_ms - first.plan_ms
    assert_close(again.image, first.image, rtol=0, atol=0, what="same frame again")
    other = clrecon.run(b, method, device)
    fresh = make_pipeline(method, device.context, b.inspect())
    s = DeviceSamples.upload(device.queue, b, info=b.inspect())
    out = _out(device, b)
    assert_close(other.image, _read(device, out, b, fresh(device.queue, s, out)),
                 rtol=0, atol=0, what="next frame planned afresh")


def test_box_plan_has_one_name(device):
    """Every method reports the frame it reduces to the per-pixel average as plan "box"."""
    buf = _frame("static_focus", device=device)
    for method in ("box", "sweep", "layered", "splat"):
        res = clrecon.run(buf, method, device)
        assert res.method["plan"] == BOX_PLAN and set(res.pass_ms) == {"box"}, method


def test_invalid_samples_are_refused_through_run_with_the_host_message(device):
    buf = _frame("fence", device=device)
    buf.time[3, 5, 1] = 2.0
    with pytest.raises(ValueError) as host:
        buf.validate()
    for method in ("box", "layered"):
        with pytest.raises(ValueError) as dev:
            clrecon.run(buf, method, device)
        assert str(dev.value) == str(host.value)



# -- memory: refused before anything is allocated ----------------------------------------
def test_plan_larger_than_the_device_is_refused_with_both_figures(device):
    info = dataclasses.replace(_frame("fence", device=device).inspect(), width=16384,
                               height=16384, spp=64)
    with pytest.raises(DeviceMemoryError, match=r"the layered plan for 16384x16384 at 64 spp"
                                                r".* needs [\d.]+ GiB.* more than .*[\d.]+ GiB"):
        make_pipeline("layered", device.context, info)


_ULIMIT = textwrap.dedent("""
    import dataclasses, resource, sys
    from clrecon.core.device import get_device
    from clrecon.core.errors import DeviceMemoryError
    from clrecon.api import make_pipeline
    from clrecon.scenes import get_scene, render_samples
    dev = get_device(int(sys.argv[1]))
    info = render_samples(get_scene("fence"), 32, 32, spp=4, seed=0, device=dev).inspect()
    # below the plan's 6.3 GiB whatever else the process has mapped
    resource.setrlimit(resource.RLIMIT_AS, (6_000_000_000, resource.RLIM_INFINITY))
    try:
        make_pipeline("layered", dev.context,
                      dataclasses.replace(info, width=4096, height=4096))
        print("planned")
    except DeviceMemoryError as exc:
        print("refused:", exc)
""")


def test_layered_4096_under_a_memory_cap_is_refused_not_aborted(device):
    """The issue's case: 4096x4096, 4 spp under ``ulimit -v 8000000`` aborted PoCL (the plan
    needs 6.3 GiB; the cap here is 6 GB so the refusal does not depend on what else the
    process has mapped)."""
    if not device.context.devices[0].type & cl.device_type.CPU:
        pytest.skip("the address-space limit binds host-memory (CPU) devices")
    proc = subprocess.run([sys.executable, "-c", _ULIMIT, str(device.info.index)],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.startswith("refused: the layered plan for 4096x4096"), proc.stdout


def test_grow_to_a_plan_that_reads_more_fields(device):
    """A layered plan for a static frame reads no motion; grown for a moving frame it does:
    with every field uploaded it runs, with the static plan's fields only it names the
    missing ones instead of failing inside a pass."""
    static, moving = _frame("spheres", device=device), _frame("fence", device=device)
    pipe = make_pipeline("layered", device.context, static.inspect(), grow=True)
    assert "motion" not in pipe.plan.fields
    few = DeviceSamples.upload(device.queue, moving, pipe.fields, info=moving.inspect())
    with pytest.raises(ValueError, match=r"missing \['time'\]"):
        pipe(device.queue, few, _out(device, moving))
    pipe = make_pipeline("layered", device.context, static.inspect(), grow=True)
    s = DeviceSamples.upload(device.queue, moving, info=moving.inspect())
    out = _out(device, moving)
    img = _read(device, out, moving, pipe(device.queue, s, out))
    assert "motion" in pipe.plan.fields and np.isfinite(img).all() and img.max() > 0

