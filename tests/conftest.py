"""Shared fixtures: every device test runs on every OpenCL device present (pyopencl style)
but the simulators, or on those ``--device SPEC`` matches; references come from a trusted
device."""
from __future__ import annotations

import math
import os

import numpy as np
import pytest

from clrecon.core import device as cldev
from clrecon.core.errors import DeviceError

_DEVICES = cldev.list_devices()


def default_devices(devices: list[cldev.DeviceInfo]) -> list[cldev.DeviceInfo]:
    """The devices of ``devices`` the run takes without ``--device``: all but the simulators
    (``cldev.SIMULATOR_PLATFORMS``: on Oclgrind the suite takes hours and a worker can pass
    20 GB); ``--device`` names them, ``--device all`` adds them."""
    return [d for d in devices if not cldev.is_simulator(d.platform)]


#: the devices the ``device`` fixture runs on: every one but the simulators, or those
#: ``--device`` matches
_SELECTED = default_devices(_DEVICES)
_ENV_BEFORE: list[str | None] = []


def pytest_addoption(parser):
    parser.addoption(
        "--device", default=None, metavar="SPEC",
        help="run the device tests only on the OpenCL devices SPEC matches: an index of "
        "`clrecon devices`, a case-insensitive substring of 'platform / device', or 'all' "
        "(default: every device but the simulators, Oclgrind); also sets CLRECON_DEVICE "
        "for the session, for tests that let get_device() choose")


def select_devices(spec: str, devices: list[cldev.DeviceInfo]) -> list[cldev.DeviceInfo]:
    """The devices of ``devices`` that ``spec`` names: the one of that index (digits), else
    every one whose ``platform / device`` label contains it, ignoring case (as
    :func:`clrecon.core.device.get_device` matches, which takes the first of them)."""
    spec = spec.strip()
    if spec.isdigit():
        return [d for d in devices if d.index == int(spec)]
    return [d for d in devices if spec and spec.lower() in d.label.lower()]


def pytest_configure(config):
    spec = config.getoption("--device")
    if spec is None:
        left_out = [d for d in _DEVICES if d not in _SELECTED]
        if left_out and not _SELECTED:
            raise pytest.UsageError(
                "the only OpenCL devices are simulators, which the default run leaves out "
                f"({', '.join(d.label for d in left_out)}): pass --device to run on them")
        return
    chosen = (list(_DEVICES) if spec.strip().lower() == "all"
              else select_devices(spec, _DEVICES))
    if not chosen:
        labels = ", ".join(f"[{d.index}] {d.label}" for d in _DEVICES) or "none"
        raise pytest.UsageError(
            f"--device {spec!r} matches no OpenCL device (give an index, a substring of "
            f"'platform / device' or 'all'); devices: {labels}")
    _SELECTED[:] = chosen
    _ENV_BEFORE.append(os.environ.get(cldev.ENV_DEVICE))
    os.environ[cldev.ENV_DEVICE] = (str(chosen[0].index) if spec.strip().lower() == "all"
                                    else spec.strip())


def pytest_report_header(config):
    lines = [f"devices under test: {', '.join(f'[{d.index}] {d.label}' for d in _SELECTED)}"]
    left_out = [d for d in _DEVICES if d not in _SELECTED]
    if left_out:
        lines.append(f"devices left out: {', '.join(f'[{d.index}] {d.label}' for d in left_out)}"
                     " (--device SPEC or --device all to include them)")
    return lines


def pytest_unconfigure(config):
    if _ENV_BEFORE:
        before = _ENV_BEFORE.pop()
        if before is None:
            os.environ.pop(cldev.ENV_DEVICE, None)
        else:
            os.environ[cldev.ENV_DEVICE] = before


def pytest_generate_tests(metafunc):
    if "device" in metafunc.fixturenames:
        metafunc.parametrize("device", [d.index for d in _SELECTED], indirect=True,
                             ids=[f"{d.index}:{d.name[:24]}" for d in _SELECTED],
                             scope="session")


@pytest.fixture(scope="session")
def device(request) -> cldev.Device:
    """A :class:`clrecon.core.device.Device` for each OpenCL device on the machine but the
    simulators (or each that ``--device`` matches)."""
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


# -- trusted references -----------------------------------------------------------------------

def trusted_reference(scene, width: int, height: int, spp: int, seed: int = 1) -> np.ndarray:
    """The converged reference a test judges a device's output by, never rendered on the
    device under test: ``render_reference`` on :func:`clrecon.core.device.trusted_device` (PoCL),
    else (no PoCL registered, e.g. ``OCL_ICD_VENDORS`` naming Oclgrind alone) the float64
    NumPy tracer on the same samples (:func:`numpy_reference`, slower: kept for the session)."""
    from clrecon.scenes import render_reference

    try:
        dev = cldev.trusted_device()
    except DeviceError:
        key = (repr(scene), width, height, spp, seed)
        if key not in _NUMPY_REFERENCES:
            _NUMPY_REFERENCES[key] = numpy_reference(scene, width, height, spp, seed)
        return _NUMPY_REFERENCES[key].copy()
    return render_reference(scene, width, height, spp, seed=seed, device=dev)


_NUMPY_REFERENCES: dict[tuple, np.ndarray] = {}


_M32 = 0xFFFFFFFF
#: kernels/raytrace.cl's R5 lattice steps (32-bit fixed-point fractions)
_R5_ALPHA = (0xE19B01AA, 0xC6D1D6C8, 0xAF36D01E, 0x9A69443F, 0x881403B9)


def _hash_u32(x):
    x = x & _M32
    x = ((x ^ (x >> 16)) * 0x7FEB352D) & _M32
    x = ((x ^ (x >> 15)) * 0x846CA68B) & _M32
    return x ^ (x >> 16)


def lattice_samples(width: int, height: int, spp: int, seed: int, rows: range | None = None):
    """Samples ``0 .. spp - 1`` of the pixels of ``rows`` (default: all) as
    kernels/raytrace.cl draws them (the R5 lattice with the per-pixel shifts of
    ``pixel_shifts``): position (R, W, spp, 2) in float32 as the kernel rounds it, lens
    (R, W, spp, 2) and time (R, W, spp) in float64."""
    rows = range(height) if rows is None else rows
    py, px = (a.astype(np.uint64) for a in np.mgrid[rows.start:rows.stop, 0:width])
    shifts = [_hash_u32(seed ^ _hash_u32(((px * 0x9E3779B1) & _M32) ^ _hash_u32(py)))]
    for _ in range(4):
        shifts.append(_hash_u32(shifts[-1] + 0x632BE5AB))
    i = np.arange(spp, dtype=np.uint64)

    def lattice(dim):
        h = (i * _R5_ALPHA[dim] + shifts[dim][..., None]) & _M32
        return (h >> 8).astype(np.float64) * (1.0 / 16777216.0)

    # float32 as the kernel: px + jitter rounds, then stays below the pixel's far edge
    pos = np.stack([px.astype(np.float32)[..., None] + lattice(0).astype(np.float32),
                    py.astype(np.float32)[..., None] + lattice(1).astype(np.float32)], -1)
    far = np.stack([px, py], -1).astype(np.float32)[..., None, :] + np.float32(0.99999994)
    pos = np.minimum(pos, far)
    sx, sy = 2.0 * lattice(2) - 1.0, 2.0 * lattice(3) - 1.0  # the concentric disk map
    with np.errstate(divide="ignore", invalid="ignore"):
        wide = np.abs(sx) > np.abs(sy)
        r = np.where(wide, sx, sy)
        phi = np.where(wide, (math.pi / 4) * (sy / sx), math.pi / 2 - (math.pi / 4) * (sx / sy))
    lens = np.stack([r * np.cos(phi), r * np.sin(phi)], -1)
    lens[(sx == 0) & (sy == 0)] = 0.0
    return pos, lens, lattice(4)


def numpy_reference(scene, width: int, height: int, spp: int, seed: int = 1,
                    chunk: int = 1 << 18) -> np.ndarray:
    """``render_reference`` in float64 NumPy: the samples of :func:`lattice_samples` traced
    by raytrace_ref.retrace and averaged per pixel (float32 result); ``chunk`` rays at a
    time."""
    from raytrace_ref import retrace

    out = np.zeros((height, width, 3))
    step = max(1, chunk // (width * spp))
    for y0 in range(0, height, step):
        rows = range(y0, min(height, y0 + step))
        pos, lens, time = lattice_samples(width, height, spp, seed, rows)
        color, _, _ = retrace(scene, width, height, pos.reshape(-1, 2), lens.reshape(-1, 2),
                              time.reshape(-1))
        out[y0:rows.stop] = color.reshape(len(rows), width, spp, 3).mean(2)
    return out.astype(np.float32)
