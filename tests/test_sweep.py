"""Method ``sweep``: every pass against the literal NumPy reference of Appendices A/B and
the three-layer variant, on frames whose denoising diameters span all scales."""
from __future__ import annotations

import numpy as np
import pytest
from conftest import assert_close

import clrecon
from clrecon.camera import CocModel
from clrecon.samples import SampleBuffer
from clrecon.scenes import get_scene, render_samples
from clrecon.sweep import reference as ref


def frame(rng, h=11, w=13, s=4, motion=True, ties=True):
    """Random valid frame: CoC from -7 to +7 px (D 0..14), optional motion, and depth ties
    (misses at inf and a repeated depth) so that the tie order is exercised."""
    model = CocModel.from_focus(aperture_px=8.0, focus_depth=4.0)
    buf = SampleBuffer.zeros(h, w, s, model)
    buf.position[:] = buf.position - 0.5 + rng.uniform(0.0, 0.999, buf.position.shape)
    buf.depth[:] = rng.uniform(2.2, 40.0, buf.depth.shape)
    if ties:
        buf.depth[rng.uniform(size=buf.depth.shape) < 0.1] = np.inf
        buf.depth[rng.uniform(size=buf.depth.shape) < 0.1] = 4.0  # in focus, all equal
    r = np.sqrt(rng.uniform(0, 1, (h, w, s)))
    a = rng.uniform(0, 2 * np.pi, (h, w, s))
    buf.lens[:] = np.stack([r * np.cos(a), r * np.sin(a)], -1)
    buf.time[:] = rng.uniform(0, 1, buf.time.shape)
    buf.color[:] = rng.exponential(1.0, buf.color.shape)
    if motion:
        moving = rng.uniform(size=buf.depth.shape) < 0.3
        buf.motion[:] = np.where(moving[..., None], rng.normal(0, 4.0, buf.motion.shape), 0.0)
    return buf.validate()


CASES = [
    dict(scales=2, sort="tile"), dict(scales=2, sort="pixel"),
    dict(scales=4, sort="tile"), dict(scales=4, sort="pixel"),
    dict(scales=2, exponent=1.3), dict(scales=2, smooth_motion=False),
    dict(scales=2, diameter_scale=0.5), dict(scales=2, sort="tile", tile=8),
    dict(scales=2, tile_merge="serial"), dict(scales=2, tile_merge="bitonic"),
    dict(scales=4, tile_merge="serial", tile=8), dict(scales=4, tile_merge="bitonic"),
]


@pytest.mark.parametrize("knobs", CASES, ids=lambda k: ",".join(f"{a}={b}" for a, b in k.items()))
def test_sorted_sweep_matches_reference(device, rng, knobs):
    buf = frame(rng)
    d = ref.denoising_diameter(buf, knobs.get("smooth_motion", True),
                               knobs.get("diameter_scale", 1.0))
    assert d.min() < 1 and d.max() > 7, "the frame must exercise every scale"
    hw = ("sort", "tile", "tile_merge")
    want = ref.reconstruct(buf, **{k: v for k, v in knobs.items() if k not in hw})
    got = clrecon.reconstruct(buf, "sweep", device, **knobs)
    assert_close(got, want, rtol=2e-4, atol=2e-5, what=f"sweep {knobs}")


@pytest.mark.parametrize("shape", [(1, 1, 1), (3, 17, 2), (9, 5, 8)],
                         ids=lambda s: "x".join(map(str, s)))
@pytest.mark.parametrize("knobs", [dict(scales=2), dict(scales=4, sort="pixel"),
                                   dict(dof_layers=True)], ids=["2tile", "4pixel", "layers"])
def test_odd_sizes(device, rng, shape, knobs):
    buf = frame(rng, *shape)
    got = clrecon.reconstruct(buf, "sweep", device, **knobs)
    want = ref.reconstruct(buf, **{k: v for k, v in knobs.items() if k != "sort"})
    assert_close(got, want, rtol=2e-4, atol=2e-5, what="sweep")


@pytest.mark.parametrize("scale", [1.0, 0.4])
def test_dof_layers_match_reference(device, rng, scale):
    buf = frame(rng, motion=False)
    want = ref.reconstruct(buf, dof_layers=True, diameter_scale=scale)
    got = clrecon.reconstruct(buf, "sweep", device, dof_layers=True, diameter_scale=scale)
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
    for knobs in (dict(scales=2), dict(scales=4), dict(dof_layers=True)):
        assert_close(clrecon.reconstruct(buf, "sweep", device, **knobs), box, rtol=1e-5,
                     what=f"in focus {knobs}")


def test_flat_field_energy_and_finite(device, rng):
    buf = frame(rng, h=16, w=16, s=8)
    buf.color[:] = 0.7
    for knobs in CASES[:4] + [dict(dof_layers=True)]:
        img = clrecon.reconstruct(buf, "sweep", device, **knobs)
        assert np.isfinite(img).all()
        assert_close(img, np.full_like(img, 0.7), rtol=1e-5, what=f"flat {knobs}")


def test_beats_box_on_a_defocused_scene(device):
    """Sanity of the whole method on rendered data (the quality report covers every scene)."""
    from clrecon.metrics import psnr
    from clrecon.scenes import render_reference

    sc = get_scene("spheres")
    ref_img = render_reference(sc, 96, 96, 256, seed=1, device=device)
    buf = render_samples(sc, 96, 96, 4, seed=2, device=device)
    box = psnr(clrecon.reconstruct(buf, "box", device), ref_img)
    sweep = psnr(clrecon.reconstruct(buf, "sweep", device), ref_img)
    assert sweep > box + 1.0


def test_knob_errors(device, rng):
    buf = frame(rng)
    with pytest.raises(ValueError, match="scales"):
        clrecon.reconstruct(buf, "sweep", device, scales=3)
    with pytest.raises(ValueError, match="sort"):
        clrecon.reconstruct(buf, "sweep", device, sort="bubble")
    with pytest.raises(ValueError, match="local memory"):
        clrecon.reconstruct(buf, "sweep", device, tile=512)
    with pytest.raises(TypeError, match="unknown knobs"):
        clrecon.reconstruct(buf, "sweep", device, nonsense=1)


def test_describe_reports_mode_and_knobs(device, rng):
    res = clrecon.run(frame(rng), "sweep", device, scales=4, sort="pixel")
    assert res.method["mode"] == "4-scale" and res.method["sort"] == "pixel"
    assert set(res.pass_ms) == {"sweep_prepare", "sweep_resolve"}
    res = clrecon.run(frame(rng, motion=False), "sweep", device)
    assert res.method["smooth_motion"] is False  # no motion in the frame: no motion term
    res = clrecon.run(frame(rng), "sweep", device, dof_layers=True)
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
    res = clrecon.run(buf, "sweep", device, **knobs)
    narrow = 3.0 if knobs.get("scales") == 4 else 1.0
    expect_box = 2 * coc <= narrow
    assert res.method["box_equivalent"] is expect_box
    assert (set(res.pass_ms) == {"box"}) is expect_box
    full = clrecon.reconstruct(buf, "sweep", device, specialize=False, **knobs)
    assert_close(res.image, full, rtol=1e-5, atol=1e-6, what="specialized vs full sweep")
