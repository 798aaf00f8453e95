"""Shared fixtures: every device test runs on every OpenCL device present (pyopencl style)."""
from __future__ import annotations

import numpy as np
import pytest

from clrecon import device as cldev

_DEVICES = cldev.list_devices()


def _ids():
    return [f"{d.index}:{d.name[:24]}" for d in _DEVICES]


@pytest.fixture(params=[d.index for d in _DEVICES], ids=_ids(), scope="session")
def device(request) -> cldev.Device:
    """A :class:`clrecon.device.Device` for each OpenCL device on the machine."""
    return cldev.get_device(request.param)


@pytest.fixture
def rng():
    return np.random.default_rng(1234)


def assert_close(actual, expected, rtol=1e-5, atol=1e-6, what="values"):
    """The one tolerance helper of the test suite: reports the worst offender."""
    actual = np.asarray(actual, np.float64)
    expected = np.asarray(expected, np.float64)
    assert actual.shape == expected.shape, f"{what}: shape {actual.shape} != {expected.shape}"
    err = np.abs(actual - expected)
    bound = atol + rtol * np.abs(expected)
    bad = ~(err <= bound)
    if bad.any():
        i = np.unravel_index(np.argmax(np.where(bad, err - bound, -np.inf)), err.shape)
        raise AssertionError(
            f"{what}: {int(bad.sum())} of {bad.size} differ; worst at {i}: "
            f"{actual[i]!r} vs {expected[i]!r} (err {err[i]:.3g}, bound {bound[i]:.3g})"
        )
