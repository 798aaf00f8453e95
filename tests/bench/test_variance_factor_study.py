"""The variances' factor study (tools/variance_factor_study.py): its blurred pixels' ratio
measures independent samples' variance as the halves do (a ratio near 1), is undefined
without blurred pixels, and one tiny scene end to end."""
from __future__ import annotations

import math

import numpy as np
import pytest
from tool_module import load_tool

from clrecon.core.device import get_device

vf = load_tool("variance_factor_study")


def test_blurred_ratio_of_independent_samples_is_one(rng):
    h, w, s = 40, 48, 16
    y, x = np.mgrid[0:h, 0:w]
    truth = np.stack([np.sin(x / 9.0), np.cos(y / 7.0), 0.5 + 0 * x], -1) + 2.0  # smooth
    color = truth[:, :, None, :] + rng.normal(0.0, 0.3, (h, w, s, 3))
    blur = np.full((h, w), 3.0, np.float32)
    blur[:, : w // 4] = 0.5  # a sharp strip: left out
    ratio, share = vf.blurred_ratio(color, truth, blur)
    assert abs(ratio - 1.0) < 0.1
    assert 0.6 < share < 0.75
    # the mixed factor: the blurred pixels' ratio where they hold vb, the quarters' elsewhere
    mixed = vf.mixed_factor(color, truth, blur)
    assert abs(mixed - 1.0) < 0.1
    none = np.zeros((h, w), np.float32)
    ratio, share = vf.blurred_ratio(color, truth, none)
    assert math.isnan(ratio) and share == 0.0
    assert vf.mixed_factor(color, truth, none) == vf.variance_scale(color)


def test_pixel_blur():
    depth = np.array([[[0.5, 10.0, np.inf]]])
    motion = np.array([[[[0.0, 0.0], [3.0, 4.0], [0.0, 0.0]]]])
    # |2 / z - 0.1|: 3.9, 0.1, 0.1 (inf: the CoC at infinity); with motion 0, 5, 0
    assert vf.pixel_blur(depth, None, (2.0, -0.1))[0, 0] == pytest.approx(0.1)
    assert vf.pixel_blur(depth[:, :, :2], motion[:, :, :2], (2.0, -0.1))[0, 0] == \
        pytest.approx(3.9)


def test_one_scene_end_to_end():
    row = vf.study(get_device(None), "bokeh", 24, 16, 2, "sweep")
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert cells[:2] == ["bokeh", "16"]
    exact, quarters, mixed = float(cells[2]), float(cells[3]), float(cells[5])
    assert exact > 0 and 0 <= quarters <= 1 and 0 <= mixed <= 1
