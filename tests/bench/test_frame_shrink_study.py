"""The frame-shrink study (tools/frame_shrink_study.py): its forms are the safeguard's NumPy
reference's, the form it names for each spp is the pipeline's, and one tiny scene end to end
(where the script checks that form against the device's own image)."""
from __future__ import annotations

import math
import sys

import pytest
from tool_module import ROOT, load_tool

from clrecon.scenes import render

sys.path.insert(0, str(ROOT / "tools"))  # the study reads the variants script's halves
fs = load_tool("frame_shrink_study")


def test_pipeline_forms():
    assert [fs.pipeline_form(s) for s in (4, 7, 8, 15, 16, 64)] == [
        "2 se", "2 se", "q normal", "q normal", "q normal", "q normal"]
    assert set(fs.FORMS) >= {fs.pipeline_form(s) for s in range(2, 70)}


@pytest.mark.parametrize("sampler", ["lattice", "random"])
def test_tiny_scene_end_to_end(device, sampler):
    ref = render.render_reference(fs.get_scene("fence"), 24, 24, spp=64)
    forms = list(fs.FORMS)
    out, box = fs.measure("fence", 24, 8, sampler, forms, device, ref, seed=100)
    assert math.isfinite(box)
    assert set(out) == set(fs.METHODS), out
    for method in fs.METHODS:
        assert list(out[method]) == forms
        assert all(math.isfinite(v) for v in out[method].values()), out


def test_figure_of_a_tiny_scene(device, tmp_path):
    ref = render.render_reference(fs.get_scene("fence"), 24, 24, spp=64)
    images = {}
    fs.measure("fence", 24, 8, "lattice", ["untested", "q normal"], device, ref, 100, images)
    assert set(images) >= {"box", ("splat", "untested"), ("splat", "q normal"), ("splat", "z")}
    path = tmp_path / "fence_8spp_splat.png"
    fs.figure(path, ref, images, "splat", ["untested", "q normal"], "fence")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # the z histogram is the frame's: one count a noisy pixel, in the kernels' layout
    hist = images["splat", "z"]
    assert hist.shape == (2 * fs.FDR_BINS,) and 0 < hist.sum() <= 24 * 24
    zpath = tmp_path / "fence_8spp_splat_z.png"
    fs.z_figure(zpath, hist, "fence")
    assert zpath.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
