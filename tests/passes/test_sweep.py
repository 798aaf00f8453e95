"""Method ``sweep``: every pass against the literal NumPy reference of Appendices A/B and
the three-layer variant, on frames whose denoising diameters span all scales."""
from __future__ import annotations

import numpy as np
import pytest
from conftest import assert_close, trusted_reference
from sweep_frames import frame

import clrecon
from clrecon.core.samples import POSITION_TOLERANCE
from clrecon.methods.sweep import reference as ref
from clrecon.scenes import get_scene, render_samples

CASES = [
    dict(scales=2, sort="tile"), dict(scales=2, sort="pixel"),
    dict(scales=4, sort="tile"), dict(scales=4, sort="pixel"),
    dict(scales=2, exponent=1.3), dict(scales=2, smooth_motion=False),
    dict(scales=2, diameter_scale=0.5), dict(scales=2, sort="tile", tile=8),
    dict(scales=2, tile_merge="serial"), dict(scales=2, tile_merge="bitonic"),
    dict(scales=4, tile_merge="serial", tile=8), dict(scales=4, tile_merge="bitonic"),
    dict(scales=2, sort="block"), dict(scales=4, sort="block"),
    dict(scales=2, sort="block", exponent=1.3), dict(scales=4, sort="block", exponent=1.3),
    dict(scales=2, sort="block", smooth_motion=False, diameter_scale=0.5),
    dict(scales=2, sort="block", group=4), dict(scales=4, sort="block", group=2),
]


@pytest.mark.parametrize("knobs", CASES, ids=lambda k: ",".join(f"{a}={b}" for a, b in k.items()))
def test_sorted_sweep_matches_reference(device, rng, knobs):
    buf = frame(rng)
    d = ref.denoising_diameter(buf, knobs.get("smooth_motion", True),
                               knobs.get("diameter_scale", 1.0))
    assert d.min() < 1 and d.max() > 7, "the frame must exercise every scale"
    hw = ("sort", "tile", "tile_merge", "group")
    want = ref.reconstruct(buf, **{k: v for k, v in knobs.items() if k not in hw})
    got = clrecon.reconstruct(buf, "sweep", device, **knobs, safeguard=False)
    assert_close(got, want, rtol=2e-4, atol=2e-5, what=f"sweep {knobs}")


@pytest.mark.parametrize("shape", [(1, 1, 1), (3, 17, 2), (9, 5, 8)],
                         ids=lambda s: "x".join(map(str, s)))
@pytest.mark.parametrize("knobs", [dict(scales=2, sort="tile"), dict(scales=4, sort="pixel"),
                                   dict(scales=2, sort="block"), dict(scales=4, sort="block"),
                                   dict(dof_layers=True)],
                         ids=["2tile", "4pixel", "2block", "4block", "layers"])
def test_odd_sizes(device, rng, shape, knobs):
    buf = frame(rng, *shape)
    got = clrecon.reconstruct(buf, "sweep", device, **knobs, safeguard=False)
    want = ref.reconstruct(buf, **{k: v for k, v in knobs.items() if k != "sort"})
    assert_close(got, want, rtol=2e-4, atol=2e-5, what="sweep")


@pytest.mark.parametrize("sort", ["block", "tile", "pixel"])
@pytest.mark.parametrize("scales", [2, 4])
def test_positions_on_pixel_edges(device, rng, sort, scales):
    """Positions on (and up to the validation tolerance past) their pixel's edges: the
    window is the pixels around, whatever the box filters of a neighbouring pixel say."""
    buf = frame(rng, h=13, w=14, s=4)
    ys, xs = np.mgrid[0:13, 0:14]
    edge = rng.integers(0, 4, buf.depth.shape)
    tol = 0.9 * POSITION_TOLERANCE
    lo_x, lo_y = (xs - tol)[..., None], (ys - tol)[..., None]
    buf.position[..., 0] = np.where(edge == 0, lo_x, np.where(edge == 1, lo_x + 1 + 2 * tol,
                                                               buf.position[..., 0]))
    buf.position[..., 1] = np.where(edge == 2, lo_y, np.where(edge == 3, lo_y + 1 + 2 * tol,
                                                               buf.position[..., 1]))
    buf.validate()
    want = ref.reconstruct(buf, scales=scales)
    got = clrecon.reconstruct(buf, "sweep", device, scales=scales, sort=sort, safeguard=False)
    assert_close(got, want, rtol=2e-4, atol=2e-5, what=f"edges {sort}")


def test_block_sort_is_the_cpu_default_and_falls_back(device, rng):
    import pyopencl as cl

    res = clrecon.run(frame(rng), "sweep", device, safeguard=False)
    cpu = bool(device.device.type & cl.device_type.CPU)
    assert (res.method["sort"] == "block") == cpu
    if cpu:
        assert set(res.pass_ms) == {"sweep_block"} and res.method["group"] >= 1
        # the block sort packs the sample index in 8 bits: 256 spp takes the tile sort, or
        # the pixel sort where local memory holds no tile (Oclgrind's 32 KiB)
        res = clrecon.run(frame(rng, h=3, w=5, s=256), "sweep", device, scales=2,
                          safeguard=False)
        assert res.method["sort"] in ("tile", "pixel")
    with pytest.raises(ValueError, match="spp"):
        clrecon.reconstruct(frame(rng, h=2, w=2, s=256), "sweep", device, sort="block",
                            safeguard=False)


@pytest.mark.parametrize("supers", [1, 2])
@pytest.mark.parametrize("shape", [(1, 1, 3), (11, 13, 4), (9, 20, 2), (17, 6, 5)],
                         ids=lambda s: "x".join(map(str, s)))
@pytest.mark.parametrize("knobs", [dict(scales=2), dict(scales=4),
                                   dict(scales=2, exponent=1.3, smooth_motion=False)],
                         ids=["2", "4", "2exp-static"])
def test_block_kernel_one_or_four_blocks_per_work_item(device, rng, supers, shape, knobs):
    """sweep_block with one 4x4 block per work-item and with 2x2 blocks sharing one sorted
    window (the default where local memory holds it): both the reference's image, on
    sizes that leave partial blocks and work-items whose blocks lie past the image; the
    local memory the kernel declares is what block_local_bytes says."""
    import pyopencl as cl

    from clrecon.core.pipeline import DeviceSamples
    from clrecon.methods.sweep.block import SweepBlock, block_local_bytes

    buf = frame(rng, *shape)
    h, w, s = shape
    scales, exponent = knobs["scales"], knobs.get("exponent", 1.0)
    motion = knobs.get("smooth_motion", True)
    if block_local_bytes(scales, s, 1, supers) > device.device.local_mem_size:
        pytest.skip("the device's local memory does not hold the window")
    sweep = SweepBlock(device.context, s, scales, exponent, motion, supers=supers)
    info = cl.kernel_work_group_info.LOCAL_MEM_SIZE
    assert sweep.kernel.get_work_group_info(info, device.device) == \
        block_local_bytes(scales, s, 1, supers)
    samples = DeviceSamples.upload(device.queue, buf)
    out = cl.Buffer(device.context, cl.mem_flags.READ_WRITE, h * w * 12)
    sweep(device.queue, samples, 1.0, out).wait()
    got = np.empty((h, w, 3), np.float32)
    cl.enqueue_copy(device.queue, got, out).wait()
    want = ref.reconstruct(buf, scales=scales, exponent=exponent, smooth_motion=motion)
    assert_close(got, want, rtol=2e-4, atol=2e-5, what=f"block supers={supers} {knobs}")


def _banded_frame(rng, spp=4):
    """A frame of five 24-row bands: every sample far out of focus (blend 1 / the 7x7 box),
    in focus and still (blend 0 / 1x1), D in 3.2-3.9 (mixed blends / the 3x3 box), D in
    5.5-6.7 (mixed / 5x5), and the random frame; so sweep_block meets windows whose every
    sample weighs in one box, of each radius, and mixed ones."""
    band = 24
    buf = frame(rng, 5 * band, 20, spp)
    ranges = [(20.0, 40.0), (3.95, 4.05), (5.0, 5.3), (6.1, 6.9)]
    for b, (lo, hi) in enumerate(ranges):
        rows = slice(b * band, (b + 1) * band)
        buf.depth[rows] = rng.uniform(lo, hi, buf.depth[rows].shape)
        buf.motion[rows] = 0.0
    buf.depth[:band][rng.uniform(size=buf.depth[:band].shape) < 0.1] = np.inf  # misses
    buf.motion[:band, :, :2] = rng.normal(0.0, 1.0, buf.motion[:band, :, :2].shape)
    buf = buf.validate()
    d = ref.denoising_diameter(buf)
    want = [(12.0, 17.0), (0.0, 0.5), (3.1, 4.0), (5.3, 6.9)]
    for b, (lo, hi) in enumerate(want):  # the bands' diameters, as designed
        db = d[b * band:(b + 1) * band]
        assert lo < db.min() and db.max() < hi, (b, db.min(), db.max())
    return buf, d


def _box_radius(d, scales):
    """NumPy's sweep_block_radius of diameters d: the one box that weighs each sample alone
    (-1: mixed)."""
    if scales == 2:
        blend = np.clip((d - 1) / 5, 0, 1)
        return np.where(blend >= 1, 2, np.where(blend == 0, 0, -1))
    return np.select([d > 7, d > 5, d > 3], [3, 2, 1], 0)


@pytest.mark.parametrize("supers", [1, 2])
@pytest.mark.parametrize("scales", [2, 4])
@pytest.mark.parametrize("exponent", [1.0, 1.3])
def test_block_kernel_windows_of_one_box(device, rng, supers, scales, exponent):
    """A window whose every sample weighs in one box alone is that box's mean, computed
    without the sort: the image is the reference's, and the sorted sweep's (UNIFORM_BOX=0)
    to float rounding, on a frame that has such windows of every radius and mixed ones."""
    import pyopencl as cl

    from clrecon.core.pipeline import DeviceSamples
    from clrecon.methods.sweep.block import BLOCK, SweepBlock, block_local_bytes

    if block_local_bytes(scales, 4, 1, supers) > device.device.local_mem_size:
        pytest.skip("the device's local memory does not hold the window")
    buf, d = _banded_frame(rng)
    h, w = buf.height, buf.width
    # the work-items' windows this frame gives: one box alone in some (of each radius the
    # scales have), mixed in others
    r, side = (2 if scales == 2 else 3), BLOCK * supers
    k = _box_radius(d, scales)
    seen = set()
    for y0 in range(-r, h - r, side):
        for x0 in range(-r, w - r, side):
            kw = k[max(0, y0):y0 + side + 2 * r, max(0, x0):x0 + side + 2 * r]
            seen.add(int(kw.min()) if kw.min() == kw.max() else -1)
    assert seen == ({-1, 0, 2} if scales == 2 else {-1, 0, 1, 2, 3}), seen
    samples = DeviceSamples.upload(device.queue, buf)
    images = []
    for uniform in (True, False):
        sweep = SweepBlock(device.context, 4, scales, exponent, True, supers=supers,
                           uniform_box=uniform)
        out = cl.Buffer(device.context, cl.mem_flags.READ_WRITE, h * w * 12)
        sweep(device.queue, samples, 1.0, out).wait()
        got = np.empty((h, w, 3), np.float32)
        cl.enqueue_copy(device.queue, got, out).wait()
        images.append(got)
    want = ref.reconstruct(buf, scales=scales, exponent=exponent)
    assert_close(images[0], want, rtol=2e-4, atol=2e-5, what="one-box windows vs reference")
    assert_close(images[0], images[1], rtol=2e-5, atol=2e-6, what="one-box vs sorted sweep")


@pytest.mark.parametrize("plan", [dict(sort="tile", tile=4, tile_merge="serial"),
                                  dict(sort="tile", tile=8, tile_merge="bitonic"),
                                  dict(sort="pixel")], ids=["tile4serial", "tile8bitonic", "pixel"])
@pytest.mark.parametrize("scales", [2, 4])
def test_resolve_windows_of_one_box(device, rng, plan, scales):
    """sweep_resolve's tile and pixel plans take the one-box shortcut too (a tile's window,
    or a pixel's, whose every sample weighs in one box: that box's mean): the reference's
    image, and the full sweep's (UNIFORM_BOX=0) to float rounding."""
    import pyopencl as cl

    from clrecon.methods.sweep.prepare import SweepPrepare
    from clrecon.methods.sweep.resolve import SweepResolve, tile_local_bytes

    if plan["sort"] == "tile" and (
            tile_local_bytes(plan["tile"], scales, 4) > device.device.local_mem_size
            or plan["tile"] ** 2 > device.device.max_work_group_size):
        pytest.skip("the device does not hold the tile")
    buf, _ = _banded_frame(rng)
    want = ref.reconstruct(buf, scales=scales)
    got = clrecon.reconstruct(buf, "sweep", device, scales=scales, safeguard=False, **plan)
    assert_close(got, want, rtol=2e-4, atol=2e-5, what=f"{plan} vs reference")
    # the shortcut off: the same prepared keys resolved both ways
    from clrecon.core.pipeline import DeviceSamples

    h, w = buf.height, buf.width
    samples = DeviceSamples.upload(device.queue, buf)
    prep = SweepPrepare(device.context, 4, True)
    mf = cl.mem_flags.READ_WRITE
    keys, colors = (cl.Buffer(device.context, mf, h * w * 4 * 16) for _ in range(2))
    prep(device.queue, samples, 1.0, keys, colors).wait()
    knobs = {k: v for k, v in plan.items() if k != "sort"}
    images = []
    for uniform in (True, False):
        res = SweepResolve(device.context, 4, scales, sort=plan["sort"], uniform_box=uniform,
                           **knobs)
        out = cl.Buffer(device.context, mf, h * w * 12)
        res(device.queue, keys, colors, w, h, out).wait()
        img = np.empty((h, w, 3), np.float32)
        cl.enqueue_copy(device.queue, img, out).wait()
        images.append(img)
    assert_close(images[0], want, rtol=2e-4, atol=2e-5, what=f"{plan} resolve vs reference")
    assert_close(images[0], images[1], rtol=2e-5, atol=2e-6, what=f"{plan}: one-box vs sweep")


def test_one_box_windows_in_the_safeguards_halves(device, rng, monkeypatch):
    """The safeguard runs sweep_block on each half read in place (stride = the frame's spp,
    offset = the half's first sample): the one-box windows there give the full sweep's
    image too, through the whole default pipeline."""
    import pyopencl as cl

    from clrecon.api import clear_sessions
    from clrecon.methods.sweep.block import SweepBlock

    if not device.device.type & cl.device_type.CPU:  # the block plan is the CPU default
        pytest.skip("the block plan is the default on CPUs only")
    buf, _ = _banded_frame(rng, spp=8)
    clear_sessions()
    res = clrecon.run(buf, "sweep", device)
    assert res.method["sort"] == "block" and res.method["safeguard"] is True
    assert "sweep_block (halves)" in res.pass_ms
    full = SweepBlock.__init__
    monkeypatch.setattr(SweepBlock, "__init__",
                        lambda self, *a, **k: full(self, *a, **{**k, "uniform_box": False}))
    clear_sessions()
    off = clrecon.run(buf, "sweep", device)
    clear_sessions()
    assert_close(res.image, off.image, rtol=2e-5, atol=2e-6, what="halves: one-box vs sweep")


def test_block_kernel_refuses_bad_supers(device):
    from clrecon.methods.sweep.block import SweepBlock

    with pytest.raises(ValueError, match="supers: must be one of"):
        SweepBlock(device.context, 4, 2, supers=3)


@pytest.mark.parametrize("scale", [1.0, 0.4])
def test_dof_layers_match_reference(device, rng, scale):
    buf = frame(rng, motion=False)
    want = ref.reconstruct(buf, dof_layers=True, diameter_scale=scale)
    got = clrecon.reconstruct(buf, "sweep", device, dof_layers=True, diameter_scale=scale,
                              safeguard=False)
    assert_close(got, want, rtol=2e-4, atol=2e-5, what="layers")


def test_dof_layers_equal_sorted_sweep_without_partial_blends(rng):
    """Section 3.1: with every blend 0 or 1 and layers separated in depth, the layered sums
    give exactly Algorithm 2's image (here: the NumPy two-scale sweep)."""
    buf = frame(rng, motion=False, ties=False)
    coc = buf.coc()
    # push every sample to a pure layer: |coc| < 0.5 (narrow) or |coc| > 3 (wide)
    wide = np.abs(coc) > 1.5
    buf.depth[:] = np.where(wide, np.where(coc < 0, 2.5, 30.0), 4.0)
    buf.depth[:] += np.arange(buf.depth.size).reshape(buf.depth.shape) * 1e-5
    d = ref.denoising_diameter(buf, smooth_motion=False)
    assert set(np.unique(np.clip((d - 1) / 5, 0, 1))) <= {0.0, 1.0}
    assert_close(ref.sweep_dof_layers(buf, d), ref.sweep_two_scale(buf, d), rtol=1e-9,
                 what="layers vs sweep")


def test_in_focus_static_frame_is_the_box_filter(device, rng):
    buf = frame(rng, motion=False)
    buf.depth[:] = 4.0  # everything in focus: D = 0, only the 1x1 scale
    box = buf.color.astype(np.float64).mean(axis=2)
    for knobs in (dict(scales=2), dict(scales=4), dict(dof_layers=True),
                  dict(scales=2, sort="block"), dict(scales=4, sort="tile")):
        assert_close(clrecon.reconstruct(buf, "sweep", device, **knobs,
                                         safeguard=False), box, rtol=1e-5,
                     what=f"in focus {knobs}")


@pytest.mark.parametrize("scales,coc_diameter,plan", [
    (2, 0.9, "box"), (2, 1.6, "sweep"), (4, 2.9, "box"), (4, 3.5, "sweep")])
def test_default_plan_is_the_box_filter_when_only_1x1_can_weigh(device, rng, scales,
                                                                  coc_diameter, plan):
    """'Model only what a scene requires': diameters <= 1 (<= 3 for four scales) leave
    every weight at 1/spp on the pixel's own samples; the plan is then the box pass, and
    the image is still the reference's."""
    buf = frame(rng, motion=False, ties=False)
    coc = buf.coc_model.coc(buf.depth)
    buf.depth[:] = np.where(np.abs(coc) > coc_diameter / 2, 4.0, buf.depth)  # clip to |coc|
    res = clrecon.run(buf, "sweep", device, scales=scales, safeguard=False)
    assert (res.method["plan"] == "box") == (plan == "box")
    assert (set(res.pass_ms) == {"box"}) == (plan == "box")
    want = ref.reconstruct(buf, scales=scales)
    assert_close(res.image, want, rtol=2e-4, atol=2e-5, what=f"{scales} {coc_diameter}")


def test_flat_field_energy_and_finite(device, rng):
    buf = frame(rng, h=16, w=16, s=8)
    buf.color[:] = 0.7
    for knobs in CASES[:4] + [dict(dof_layers=True)]:
        img = clrecon.reconstruct(buf, "sweep", device, **knobs, safeguard=False)
        assert np.isfinite(img).all()
        assert_close(img, np.full_like(img, 0.7), rtol=1e-5, what=f"flat {knobs}")


def test_beats_box_on_a_defocused_scene(device):
    """Sanity of the whole method on rendered data (the quality report covers every scene)."""
    from clrecon.metrics import psnr

    sc = get_scene("spheres")
    ref_img = trusted_reference(sc, 96, 96, 256, seed=1)
    buf = render_samples(sc, 96, 96, 4, seed=2, device=device)
    box = psnr(clrecon.reconstruct(buf, "box", device), ref_img)
    sweep = psnr(clrecon.reconstruct(buf, "sweep", device, safeguard=False), ref_img)
    assert sweep > box + 1.0


def test_knob_errors(device, rng):
    buf = frame(rng)
    with pytest.raises(ValueError, match="scales"):
        clrecon.reconstruct(buf, "sweep", device, scales=3, safeguard=False)
    with pytest.raises(ValueError, match="sort"):
        clrecon.reconstruct(buf, "sweep", device, sort="bubble", safeguard=False)
    with pytest.raises(ValueError, match="local memory"):
        clrecon.reconstruct(buf, "sweep", device, tile=512, safeguard=False)
    with pytest.raises(TypeError, match="unknown knobs"):
        clrecon.reconstruct(buf, "sweep", device, nonsense=1, safeguard=False)


def test_describe_reports_mode_and_knobs(device, rng):
    res = clrecon.run(frame(rng), "sweep", device, scales=4, sort="pixel", safeguard=False)
    assert res.method["mode"] == "4-scale" and res.method["sort"] == "pixel"
    assert set(res.pass_ms) == {"sweep_prepare", "sweep_resolve"}
    res = clrecon.run(frame(rng), "sweep", device, sort="block", group=2, safeguard=False)
    assert res.method["sort"] == "block" and res.method["group"] == 2
    assert set(res.pass_ms) == {"sweep_block"}
    res = clrecon.run(frame(rng, motion=False), "sweep", device, safeguard=False)
    assert res.method["smooth_motion"] is False  # no motion in the frame: no motion term
    res = clrecon.run(frame(rng), "sweep", device, dof_layers=True, safeguard=False)
    assert res.method["mode"] == "dof_layers"
    assert set(res.pass_ms) == {"sweep_layer_sums", "sweep_layer_resolve"}


@pytest.mark.parametrize("knobs", [dict(scales=2), dict(scales=4), dict(dof_layers=True)],
                         ids=["2-scale", "4-scale", "dof-layers"])
@pytest.mark.parametrize("coc", [0.0, 0.45, 1.4], ids=lambda c: f"coc{c}")
def test_box_equivalent_specialization(device, rng, knobs, coc):
    """With every denoising diameter inside the narrow block the plan is the box pass; the
    full sweep (specialize=False) gives the same image, and a wider frame is not specialized."""
    buf = frame(rng, motion=False, ties=False)
    buf.depth[:] = 4.0  # the focus depth of frame(): coc 0 ...
    if coc:  # ... or a CoC of `coc` px everywhere
        buf.depth[:] = buf.coc_model.depth_at_coc(coc)
    buf.lens[:] = 0.0
    buf.validate()
    res = clrecon.run(buf, "sweep", device, **knobs, safeguard=False)
    narrow = 3.0 if knobs.get("scales") == 4 else 1.0
    expect_box = 2 * coc <= narrow
    assert (res.method["plan"] == "box") is expect_box
    assert (set(res.pass_ms) == {"box"}) is expect_box
    full = clrecon.reconstruct(buf, "sweep", device, specialize=False, **knobs, safeguard=False)
    assert_close(res.image, full, rtol=1e-5, atol=1e-6, what="specialized vs full sweep")
