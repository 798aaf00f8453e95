"""Platforms and test devices: ``pytest --device SPEC``, ``clrecon devices``, and the
registration of OpenCL platforms by ``tools/setup_platforms.sh`` (``bash run.sh setup``)."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import conftest
import pyopencl as cl
import pytest

from clrecon.cli import main
from clrecon.core import device as cldev

ROOT = Path(__file__).resolve().parents[2]
SETUP = ROOT / "tools" / "setup_platforms.sh"


def _info(index: int, platform: str, name: str) -> cldev.DeviceInfo:
    return cldev.DeviceInfo(index, platform, "OpenCL 3.0", name, "v", "1", "OpenCL 3.0", "CPU",
                            1, 1 << 30, 1 << 16, 256, True, True, False)


def test_select_devices_by_index_or_name_substring():
    devs = [_info(0, "Oclgrind", "Oclgrind Simulator"), _info(1, "Intel(R) OpenCL", "AMD EPYC"),
            _info(2, "Portable Computing Language", "pthread-haswell-AMD EPYC")]
    pick = conftest.select_devices
    assert [d.index for d in pick("1", devs)] == [1]
    assert [d.index for d in pick(" intel ", devs)] == [1]
    assert [d.index for d in pick("amd epyc", devs)] == [1, 2]
    assert [d.index for d in pick("Portable Computing Language / pthread", devs)] == [2]
    assert pick("7", devs) == [] and pick("cuda", devs) == [] and pick(" ", devs) == []
    assert [d.index for d in conftest.default_devices(devs)] == [1, 2]  # no simulator


def test_default_device_is_the_first_real_gpu_else_the_first_real_device():
    def fake(platform, kind):
        return SimpleNamespace(platform=SimpleNamespace(name=platform), type=kind)
    gpu, cpu = cl.device_type.GPU, cl.device_type.CPU
    grind, pocl = fake("Oclgrind", gpu), fake("Portable Computing Language", cpu)
    assert cldev._default_index([grind, pocl]) == 1
    assert cldev._default_index([pocl, fake("NVIDIA CUDA", gpu), grind]) == 1
    assert cldev._default_index([fake("Intel(R) OpenCL", cpu), pocl, grind]) == 0
    assert cldev._default_index([grind]) == 0  # nothing else: the simulator
    assert cldev.is_simulator(" oclgrind ") and not cldev.is_simulator("Intel(R) OpenCL")


def test_device_option_reaches_get_device(pytestconfig):
    """Run with ``--device`` (test_device_option_runs_only_the_matching_devices does): tests
    that let get_device() choose get the first matching device through CLRECON_DEVICE."""
    spec = pytestconfig.getoption("--device")
    if spec is None:
        assert conftest._SELECTED == conftest.default_devices(conftest._DEVICES)
        if os.environ.get(cldev.ENV_DEVICE) is None:  # clrecon's own choice: no simulator
            assert cldev.get_device().info in conftest._SELECTED
        return
    if spec.strip().lower() == "all":
        assert conftest._SELECTED == conftest._DEVICES
        return
    assert os.environ[cldev.ENV_DEVICE] == spec.strip()
    assert cldev.get_device().info.index == conftest._SELECTED[0].index


def _pytest(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                           *args], cwd=ROOT, capture_output=True, text=True, timeout=600)


def _quick_device() -> cldev.DeviceInfo:
    """A device that runs a small test fast: a CPU before a simulated GPU."""
    devs = cldev.list_devices()
    if not devs:
        pytest.skip("no OpenCL device")
    return min(devs, key=lambda d: d.device_type != "CPU")


def test_device_option_runs_only_the_matching_devices():
    dev = _quick_device()
    res = _pytest("tests/unit/test_platforms.py::test_device_option_reaches_get_device",
                  "tests/unit/test_scenes.py::test_samples_are_stratified",
                  "--device", str(dev.index))
    assert res.returncode == 0, res.stdout + res.stderr
    assert "2 passed" in res.stdout, res.stdout
    # a name substring: every device whose label holds it, and no other
    word = dev.platform.split()[0]
    res = _pytest("--collect-only", "tests/unit/test_scenes.py::test_samples_are_stratified",
                  "--device", word)
    assert res.returncode == 0, res.stdout + res.stderr
    ids = {line.split("[", 1)[1].split(":", 1)[0] for line in res.stdout.splitlines()
           if "test_samples_are_stratified[" in line}
    want = {str(d.index) for d in conftest.select_devices(word, cldev.list_devices())}
    assert ids == want and str(dev.index) in ids


def test_default_run_leaves_the_simulator_out(tmp_path):
    """With Oclgrind (a GPU) registered beside PoCL (a CPU), the run without --device
    collects PoCL's device only, names Oclgrind as left out, and get_device() takes PoCL;
    --device all takes both; get_device("Oclgrind") is still the simulator."""
    lib = Path("/usr/lib/oclgrind/liboclgrind-rt-icd.so")
    if not lib.exists():
        pytest.skip("Oclgrind (Debian's oclgrind) is not installed")
    (tmp_path / "pocl.icd").write_text(_pocl_icd_text() + "\n")
    (tmp_path / "oclgrind.icd").write_text(f"{lib}\n")
    env = {**os.environ, "OCL_ICD_VENDORS": str(tmp_path)}
    env.pop(cldev.ENV_DEVICE, None)
    test = "tests/unit/test_scenes.py::test_samples_are_stratified"

    def collect(*args):
        res = subprocess.run([sys.executable, "-m", "pytest", "-p", "no:cacheprovider",
                              "--collect-only", test, *args], cwd=ROOT, env=env,
                             capture_output=True, text=True, timeout=600)
        assert res.returncode == 0, res.stdout + res.stderr
        return res.stdout

    out = collect("-q")
    ids = [line for line in out.splitlines() if line.startswith(test)]
    assert len(ids) == 1 and "Oclgrind" not in ids[0], out
    header = [line for line in collect().splitlines() if line.startswith("devices ")]
    assert len(header) == 2 and "Oclgrind" not in header[0] and "Oclgrind" in header[1], header
    assert len([line for line in collect("-q", "--device", "all").splitlines()
                if line.startswith(test)]) == 2
    res = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                          "tests/unit/test_platforms.py::test_device_option_reaches_get_device"],
                         cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    assert res.returncode == 0 and "1 passed" in res.stdout, res.stdout + res.stderr
    res = subprocess.run([sys.executable, "-c", "from clrecon.core import device as d; "
                          "print(d.get_device().info.platform, '|', "
                          "d.get_device('oclgrind').info.platform)"],
                         cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    assert res.stdout.split() and res.stdout.strip() == (
        "Portable Computing Language | Oclgrind"), res.stdout + res.stderr


def test_device_option_matching_nothing_is_a_usage_error():
    res = _pytest("--collect-only", "tests/unit/test_scenes.py", "--device", "no such device 42")
    assert res.returncode == 4, res.stdout + res.stderr
    assert "--device 'no such device 42' matches no OpenCL device" in res.stderr, res.stderr


def test_devices_lists_every_device_of_every_platform(capsys):
    devs = cldev.list_devices()
    assert main(["devices"]) == 0
    lines = [x for x in capsys.readouterr().out.splitlines() if x.startswith("[")]
    assert lines == [f"[{d.index}] {d.platform} / {d.name}" for d in devs]
    assert main(["devices", "--json"]) == 0
    assert [d["index"] for d in json.loads(capsys.readouterr().out)] == [d.index for d in devs]


# -- platform set-up ----------------------------------------------------------------------------

def _setup(*args: str, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(["bash", str(SETUP), *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=600, env={**os.environ, **(env or {})})


def _debian_package(name: str) -> bool:
    if shutil.which("dpkg-query") is None:
        return False
    res = subprocess.run(["dpkg-query", "-W", "-f", "${Status}", name], capture_output=True,
                         text=True)
    return "install ok installed" in res.stdout


def _pocl_icd_text() -> str:
    if not _debian_package("pocl-opencl-icd"):
        pytest.skip("Debian's pocl-opencl-icd is not installed")
    files = subprocess.run(["dpkg-query", "-L", "pocl-opencl-icd"], capture_output=True,
                           text=True).stdout.split()
    return Path(next(f for f in files if f.endswith(".icd"))).read_text().strip()


@pytest.mark.parametrize("args", [["--platforms", "pocl,cuda"], ["--platforms", ""],
                                  ["--icd"], ["--platforms"]])
def test_setup_refuses_bad_options_before_installing(args, tmp_path):
    res = _setup(*args, env={"XDG_CACHE_HOME": str(tmp_path)})
    assert res.returncode == 2 and res.stdout == ""
    assert res.stderr.startswith("setup: ") and len(res.stderr.splitlines()) == 1, res.stderr
    assert not any(tmp_path.iterdir())
    run = subprocess.run(["bash", str(ROOT / "run.sh"), "setup", *args], cwd=ROOT, text=True,
                         capture_output=True, timeout=600)
    assert run.returncode == 2 and run.stderr == res.stderr


def _platforms_under(folder: Path) -> list[str]:
    """The platforms a process sees with OCL_ICD_VENDORS=folder, sorted."""
    code = ("import json; from clrecon.core.device import list_devices; "
            "print(json.dumps(sorted({d.platform for d in list_devices()})))")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=300, env={**os.environ, "OCL_ICD_VENDORS": str(folder)})
    assert res.returncode == 0, res.stderr
    return json.loads(res.stdout)


def test_setup_registers_pocl_in_a_folder_once(tmp_path):
    text = _pocl_icd_text()
    icd = tmp_path / "icd"
    res = _setup("--platforms", "pocl", "--icd-dir", str(icd))
    assert res.returncode == 0, res.stderr
    assert res.stdout.splitlines()[-1] == f"export OCL_ICD_VENDORS={icd}"
    assert (icd / "pocl.icd").read_text().strip() == text
    assert _platforms_under(icd) == [cldev.TRUSTED_PLATFORM]
    stamp = (icd / "pocl.icd").stat().st_mtime_ns
    again = _setup("--platforms", "pocl", "--icd-dir", str(icd))
    assert again.returncode == 0 and "registered " + str(icd / "pocl.icd") not in again.stderr
    assert (icd / "pocl.icd").stat().st_mtime_ns == stamp
    assert again.stdout == res.stdout


def test_setup_puts_pocl_beside_oclgrind(tmp_path):
    """With OCL_ICD_VENDORS set, ocl-icd reads that folder alone: it must list PoCL too."""
    text = _pocl_icd_text()
    if not _debian_package("oclgrind"):
        pytest.skip("Debian's oclgrind is not installed")
    res = _setup("--platforms", "oclgrind", "--icd-dir", str(tmp_path))
    assert res.returncode == 0, res.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["oclgrind.icd", "pocl.icd"]
    assert (tmp_path / "pocl.icd").read_text().strip() == text
    assert Path((tmp_path / "oclgrind.icd").read_text().strip()).is_file()
    assert _platforms_under(tmp_path) == sorted(["Oclgrind", cldev.TRUSTED_PLATFORM])


@pytest.mark.skipif(os.geteuid() != 0, reason="registers in the system's folder as root only")
def test_setup_as_root_registers_in_the_system_folder(tmp_path):
    text = _pocl_icd_text()
    res = _setup("--platforms", "pocl", env={"CLRECON_SYSTEM_VENDORS": str(tmp_path)})
    assert res.returncode == 0 and res.stdout == "", res.stdout + res.stderr
    assert (tmp_path / "pocl.icd").read_text().strip() == text
    again = _setup("--platforms", "pocl", env={"CLRECON_SYSTEM_VENDORS": str(tmp_path)})
    assert again.returncode == 0 and "registered " + str(tmp_path / "pocl.icd") not in again.stderr
