"""References are never rendered on the device under test, and every device's reference
kernel agrees with the NumPy tracer: Intel's CPU compiler once vectorised
``raytrace_reference`` into garbage in SIMD lanes 6-7 (kernels/raytrace.cl says why), and
tests that took their reference from the same device agreed with it."""
from __future__ import annotations

import numpy as np
import pytest
from conftest import numpy_reference, trusted_reference
from test_scenes import MIXED

import clrecon
from clrecon.cli import main
from clrecon.core import device as cldev
from clrecon.core.errors import DeviceError
from clrecon.scenes import get_scene, render_reference
from clrecon.scenes import render as render_module


def _pocl_or_skip() -> cldev.Device:
    try:
        return cldev.trusted_device()
    except DeviceError:
        pytest.skip("no PoCL device registered (the trusted device)")


@pytest.mark.parametrize("scene", ["spheres", "fence", "bokeh", "mixed"])
def test_reference_kernel_matches_numpy_tracer(device, scene):
    """24x16 (three 8-wide SIMD groups per row) at 40 spp: two launches of the kernel
    (REFERENCE_CHUNK = 32), the second from sample 32. A ray grazing an edge may hit in
    float32 and miss in float64: a few pixels may differ by one sample's share."""
    sc = MIXED if scene == "mixed" else get_scene(scene)
    w, h, spp = 24, 16, 40
    got = render_reference(sc, w, h, spp, seed=3, device=device)
    want = numpy_reference(sc, w, h, spp, seed=3)
    assert np.isfinite(got).all(), f"{scene}: non-finite reference on {device.info.label}"
    err = np.abs(got.astype(np.float64) - want).max(-1)
    bad = err > 1e-4 + 1e-4 * want.max(-1)
    assert bad.mean() <= 0.01, (
        f"{scene} on {device.info.label}: {int(bad.sum())} of {bad.size} pixels differ from "
        f"the NumPy tracer; worst {err.max():.3g} at {np.unravel_index(err.argmax(), err.shape)}"
        f" (columns mod 8 of those pixels: {np.bincount(np.nonzero(bad)[1] % 8, minlength=8)})")


def test_trusted_device_is_pocl_whatever_the_device_choice(monkeypatch):
    pocl = _pocl_or_skip()
    assert pocl.info.platform == cldev.TRUSTED_PLATFORM
    if any(d.platform == cldev.TRUSTED_PLATFORM and d.device_type == "CPU"
           for d in cldev.list_devices()):
        assert pocl.info.device_type == "CPU"
    # a choice that names no device at all: get_device() would fail, the reference may not
    monkeypatch.setenv(cldev.ENV_DEVICE, "no such device, on purpose")
    with pytest.raises(DeviceError):
        cldev.get_device()
    assert cldev.trusted_device() is pocl
    sc = get_scene("spheres")
    assert np.array_equal(render_reference(sc, 16, 8, 4, seed=2),
                          render_reference(sc, 16, 8, 4, seed=2, device=pocl))


def test_no_pocl_is_an_error_naming_the_way_out(monkeypatch):
    others = [d for d in cldev._all_devices()
              if d.platform.name.strip() != cldev.TRUSTED_PLATFORM]
    monkeypatch.setattr(cldev, "_all_devices", lambda: others)
    with pytest.raises(DeviceError, match="no trusted device for references.*run.sh setup"):
        cldev.trusted_device()
    with pytest.raises(DeviceError, match="no trusted device"):
        render_reference(get_scene("spheres"), 8, 8, 4)
    # the tests' references fall back on the NumPy tracer
    sc = get_scene("fence")
    assert np.array_equal(trusted_reference(sc, 16, 8, 4, seed=1),
                          numpy_reference(sc, 16, 8, 4, seed=1))


def test_demo_takes_its_reference_from_the_trusted_device(tmp_path, monkeypatch, capsys):
    """Whatever --device the demo runs on, its reference is rendered on PoCL, and it says so."""
    pocl = _pocl_or_skip()
    others = [d for d in cldev.list_devices() if d.platform != cldev.TRUSTED_PLATFORM]
    # the quickest device that is not PoCL: a CPU before a simulator
    chosen = min(others, key=lambda d: d.device_type != "CPU", default=pocl.info)
    seen = []

    def spy(*args, **kw):
        seen.append(kw.get("device"))
        return render_module.render_reference(*args, **kw)

    monkeypatch.setenv("CLRECON_CACHE_DIR", "off")
    monkeypatch.setattr(clrecon.scenes, "render_reference", spy)
    assert main(["demo", "--scene", "spheres", "--size", "16x8", "--spp", "2", "--ref-spp", "4",
                 "--methods", "box", "--device", str(chosen.index),
                 "-o", str(tmp_path / "d")]) == 0
    out = capsys.readouterr().out
    assert seen == [pocl]
    assert f"reference device: {pocl.info.label}" in out, out
