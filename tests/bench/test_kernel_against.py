"""tools/kernel_against.py: a kernel file at a revision builds into the pipeline in place of
the working tree's, and a tiny frame runs end to end (the same source at HEAD and in the
tree when the file is unchanged: bit-identical images)."""
from __future__ import annotations

import subprocess

import pytest
from tool_module import ROOT, load_tool

from clrecon.core.build import kernel_source

ka = load_tool("kernel_against")


def _in_git() -> bool:
    r = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True)
    return r.returncode == 0


pytestmark = pytest.mark.skipif(not _in_git(), reason="needs the project's git history")


def test_sources_at_head_are_the_committed_files():
    text = ka.sources_at("HEAD", ["tile_stats.cl"])["tile_stats"]
    assert "__kernel void tile_stats" in text


def test_the_replaced_source_is_built(device):
    from clrecon.scenes import get_scene, render_samples
    buf = render_samples(get_scene("deep"), 48, 32, 4, seed=3, device=device)
    src = kernel_source("tile_stats") + "\n__kernel void marker_of_the_replacement(void) {}\n"
    run = ka.pipeline_with(device, buf, "layered", {"safeguard": False}, {"tile_stats": src})
    program = run.pipe.stats_pass.kernel.program
    assert "marker_of_the_replacement" in program.kernel_names


def test_tiny_frame_end_to_end(tmp_path, device):
    page = tmp_path / "against.md"
    ka.main(["--files", "tile_stats", "--scene", "deep", "--size", "48x32", "--spp", "4",
             "--repeats", "3", "--device", str(device.info.index), "-o", str(page)])
    text = page.read_text()
    assert "| tile_stats |" in text and "| **total** |" in text
    if not subprocess.run(["git", "diff", "--quiet", "HEAD", "--", "kernels/tile_stats.cl"],
                          cwd=ROOT).returncode:
        assert "bit-identical: True" in text
