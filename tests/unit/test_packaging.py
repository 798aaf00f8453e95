"""Kernels and tuning files ship as package data: a plain ``pip install .`` into a fresh
venv (not editable) finds them from any working directory and runs a kernel."""
from __future__ import annotations

import os
import subprocess
import sys
import sysconfig
import venv
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

PROBE = """
import clrecon, numpy as np
from clrecon.core.resources import kernels_dir, tuning_dir
k = kernels_dir()
assert str(k).startswith(PREFIX), (str(k), PREFIX)
assert (k / "common.h").is_file() and (k / "box.cl").is_file() and (k / "raytrace.cl").is_file()
assert tuning_dir().is_dir()
buf = clrecon.SampleBuffer.zeros(3, 4, 2)
buf.color[:] = 2.0
img = clrecon.reconstruct(buf, method="box")
assert np.allclose(img, 2.0)
print("ok", k)
"""


@pytest.mark.slow
def test_plain_install_into_fresh_venv_ships_kernels(tmp_path):
    env_dir = tmp_path / "venv"
    venv.EnvBuilder(with_pip=True).create(env_dir)
    py = env_dir / "bin" / "python"
    # dependencies come from the running interpreter (no network); the package itself is a
    # plain, non-editable install built from the source tree
    subprocess.run([str(py), "-m", "pip", "install", "-q", "--no-deps",
                    str(ROOT)], check=True, cwd=tmp_path)
    site_new = subprocess.run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()"
                               "['purelib'])"], check=True, capture_output=True, text=True,
                              cwd=tmp_path).stdout.strip()
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([site_new, sysconfig.get_paths()["purelib"]]))
    out = subprocess.run([str(py), "-c", f"PREFIX = {site_new!r}\n" + PROBE], cwd=tmp_path,
                         env=env, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith("ok")
    assert sys.prefix not in out.stdout
