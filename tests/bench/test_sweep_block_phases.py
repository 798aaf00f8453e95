"""The sweep_block phase script (tools/sweep_block_phases.py): every cut applies to the
kernel as it is (a cut that silently stopped applying would time the whole kernel under a
phase's name), each cut removes what it names, and one tiny frame end to end."""
from __future__ import annotations

from tool_module import load_tool

from clrecon.core.build import kernel_source

sbp = load_tool("sweep_block_phases")


def test_every_cut_applies_to_the_current_kernel_and_removes_its_phase():
    src = kernel_source("sweep_block")
    cuts = sbp.variants(src)
    assert [name for name, _ in cuts] == ["no sweep math", "no list walk", "no sort"]
    assert all(s is not None for _, s in cuts)
    (_, no_math), (_, no_walk), (_, no_sort) = cuts
    # the per-sample update's call in the kernel body (its definition stays)
    assert src.count(sbp.STEP) == 1 and sbp.STEP not in no_math
    assert sbp.WALK in no_math and sbp.WALK not in no_walk and sbp.STEP not in no_walk
    assert sbp.SORT in no_walk and sbp.SORT not in no_sort
    assert "sweep_block_sort(__local ulong *a" in no_sort  # only the call is cut


def test_a_cut_that_does_not_apply_is_reported_not_timed():
    cuts = sbp.variants("__kernel void sweep_block() {}")
    assert [s for _, s in cuts] == [None, None, None]


def test_tiny_frame_end_to_end(tmp_path, device):
    page = tmp_path / "phases.md"
    sbp.main(["--scene", "fence", "--size", "40x24", "--spp", "4", "--repeats", "3",
              "--device", str(device.info.index), "-o", str(page)])
    text = page.read_text()
    for row in ("| current |", "| no one-box shortcut |", "| no sweep math |",
                "| no list walk |", "| no sort |"):
        assert row in text
    assert "Left out" not in text
