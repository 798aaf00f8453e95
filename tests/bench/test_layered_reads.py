"""tools/layered_reads.py: its per-slot count is the pixels reproject visits (checked against
the NumPy reference's own block pick, clipped windows included), and a tiny frame end to
end."""
from __future__ import annotations

import numpy as np
import pytest
from tool_module import load_tool

from clrecon.methods.layered.reference import row_hash

lr = load_tool("layered_reads")


def brute_force(x0, y0, tile, reach, sub, w, h):
    """The reference's pick (clrecon/methods/layered/reference.py: reproject), pixel by
    pixel over the clipped window."""
    ys, xs = np.mgrid[max(0, y0 - reach):min(h, y0 + tile + reach),
                      max(0, x0 - reach):min(w, x0 + tile + reach)]
    if sub == 1:
        return ys.size
    hh = row_hash(ys // sub, sub)
    return int(((xs % sub == hh % sub) & (ys % sub == (hh >> np.uint64(16)) % sub)).sum())


@pytest.mark.parametrize("x0,y0,reach,sub", [(0, 0, 3, 1), (64, 32, 20, 2), (0, 96, 37, 4),
                                             (96, 0, 96, 8), (32, 64, 50, 16),
                                             (64, 96, 11, 3)])
def test_slot_reads_is_the_kernels_pick(x0, y0, reach, sub):
    w, h = 128, 120  # the last tile row is clipped
    got = lr.slot_reads(x0, y0, 32, reach, sub, w, h)
    assert got == brute_force(x0, y0, 32, reach, sub, w, h)
    px = lr.slot_pixels(x0, y0, 32, reach, sub, w, h)
    assert np.unique(px).size == px.size and px.min() >= 0 and px.max() < w * h
    assert 0 < got <= (min(w, x0 + 32 + reach) - max(0, x0 - reach)) * h


def test_tiny_frame_end_to_end(tmp_path, device):
    page = tmp_path / "reads.md"
    lr.main(["--scene", "deep", "--size", "96x64", "--spp", "4",
             "--device", str(device.info.index), "-o", str(page)])
    text = page.read_text()
    assert "the frame" in text and "| grid spacing | slots |" in text
    assert "| reach px |" in text
