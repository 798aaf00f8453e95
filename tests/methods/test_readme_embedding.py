"""The README's embedding example runs as written: it is the documentation's test."""
from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pyopencl as cl

README = Path(__file__).resolve().parents[2] / "README.md"


def _example() -> str:
    text = README.read_text()
    section = text[text.index("## Embedding"):]
    blocks = re.findall(r"```python\n(.*?)```", section, re.S)
    assert blocks, "README: no python block in the Embedding section"
    return blocks[0]


def _ctx_spec(dev: cl.Device) -> str:
    """``PYOPENCL_CTX`` naming ``dev`` (what ``cl.create_some_context`` reads)."""
    for pi, platform in enumerate(cl.get_platforms()):
        for di, d in enumerate(platform.get_devices()):
            if d == dev:
                return f"{pi}:{di}"
    raise AssertionError(f"device {dev.name} not found among the platforms")


def test_readme_embedding_example_runs(device, tmp_path):
    """In a subprocess on this device (a crash fails the test, not the run): every frame is
    finite and non-negative, the 4-spp frame is refused by name, then re-planned."""
    script = tmp_path / "embed.py"
    script.write_text(_example())
    env = os.environ | {"PYOPENCL_CTX": _ctx_spec(device.context.devices[0]),
                        "PYOPENCL_COMPILER_OUTPUT": "0"}
    proc = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                          timeout=600, env=env)
    assert proc.returncode == 0, proc.stderr[-3000:]
    lines = proc.stdout.splitlines()
    assert sum(line.startswith("frame ") and " ms on the device" in line for line in lines) == 4
    assert any("refused: layered pipeline: frame spp = 4 is outside the plan's bound spp == 8"
               in line for line in lines), proc.stdout
