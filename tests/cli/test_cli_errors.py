"""The command line's errors: every expected family is one line on stderr naming the file or
argument, exit code 2; ``--debug`` shows the traceback; a programming error keeps its
traceback; an output that is one of the inputs is refused before anything is written."""
from __future__ import annotations

import errno
import os
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pyopencl as cl
import pytest

from clrecon.cli import main
from clrecon.core import device as cldev
from clrecon.core.errors import DeviceError, DeviceMemoryError, KernelBuildError
from clrecon.core.samples import SampleBuffer
from clrecon.io import save_image, save_samples


def _one_line(capsys, *words) -> str:
    """The command's stderr: exactly one line, with every word in it."""
    cap = capsys.readouterr()
    lines = cap.err.splitlines()
    assert len(lines) == 1, cap.err
    for w in words:
        assert str(w) in lines[0], (w, lines[0])
    assert "Traceback" not in cap.err
    return lines[0]


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A small sample buffer (.npz and .exr) and an image."""
    d = tmp_path_factory.mktemp("cli")
    rng = np.random.default_rng(0)
    buf = SampleBuffer.zeros(6, 8, 2)
    buf.color[:] = rng.uniform(0, 1, buf.color.shape)
    save_samples(d / "s.npz", buf)
    save_samples(d / "s.exr", buf)
    save_image(d / "img.exr", buf.color.mean(axis=2))
    return d


def _bytes(path: Path) -> bytes:
    return path.read_bytes()


# -- one line per family ----------------------------------------------------------------------

def test_value_error_and_knob_type(files, tmp_path, capsys):
    assert main(["scene", "nope", "-o", str(tmp_path / "x.npz")]) == 2
    _one_line(capsys, "unknown 'nope'")
    out = str(tmp_path / "o.exr")
    assert main(["reconstruct", str(files / "s.npz"), "-o", out, "--method", "sweep",
                 "--knob", "tile=abc"]) == 2
    _one_line(capsys, "tile: must be an integer")  # a KnobTypeError (a TypeError too)
    assert main(["reconstruct", str(files / "s.npz"), "-o", out, "--method", "splat",
                 "--layers", "100000"]) == 2
    _one_line(capsys, "layers", "[1, 64]")
    assert main(["reconstruct", str(files / "s.npz"), "-o", out, "--method", "layered",
                 "--knob", "seed=-1"]) == 2
    _one_line(capsys, "seed", "[0, 4294967296)")


def test_device_errors(files, tmp_path, capsys, monkeypatch):
    args = ["reconstruct", str(files / "s.npz"), "-o", str(tmp_path / "o.exr")]
    assert main(args + ["--device", "no-such-device-xyz"]) == 2
    _one_line(capsys, "no OpenCL device matches 'no-such-device-xyz'")
    import clrecon.methods.box

    def bad_build(*a, **k):
        raise KernelBuildError("kernels/box.cl", ["-DWG_X=16"], "box.cl:3: error: oops\n"
                               "box.cl:4: error: again\n2 errors generated.")

    monkeypatch.setattr(clrecon.methods.box, "get_kernel", bad_build)
    assert main(args) == 2
    line = _one_line(capsys, "failed to build kernels/box.cl", "--debug")
    assert "more lines" in line
    assert not (tmp_path / "o.exr").exists()


def test_device_memory_error_from_the_plan_check(files, tmp_path, capsys, monkeypatch):
    """The real plan check (a CPU device's address-space budget made tiny) raises
    DeviceMemoryError before any allocation: one line."""
    cpus = [d.index for d in cldev.list_devices() if "CPU" in d.device_type.upper()]
    if not cpus:
        pytest.skip("no CPU OpenCL device: its budget is the one that can be shrunk")
    import clrecon.core.pipeline

    monkeypatch.setattr(clrecon.core.pipeline, "_address_space_left", lambda: 1.0)
    assert main(["reconstruct", str(files / "s.npz"), "-o", str(tmp_path / "o.exr"),
                 "--method", "splat", "--layers", "64", "--device", str(cpus[0])]) == 2
    _one_line(capsys, "the splat plan", "more than the address space")
    assert not (tmp_path / "o.exr").exists()


def test_os_errors(files, tmp_path, capsys):
    out = str(tmp_path / "o.exr")
    missing = str(tmp_path / "missing.npz")
    assert main(["reconstruct", missing, "-o", out]) == 2  # FileNotFoundError
    _one_line(capsys, missing)
    assert main(["reconstruct", str(files / "s.npz"), "-o", str(tmp_path)]) == 2
    _one_line(capsys, str(tmp_path))  # a folder with no extension: refused, named
    folder = tmp_path / "dir.exr"
    folder.mkdir()
    assert main(["reconstruct", str(files / "s.npz"), "-o", str(folder)]) == 2
    _one_line(capsys, str(folder), "is a directory")  # IsADirectoryError
    bad = tmp_path / "bad.exr"
    bad.write_bytes(os.urandom(300))  # a corrupt EXR: OpenImageIO's OSError
    assert main(["compare", str(bad), str(files / "img.exr")]) == 2
    _one_line(capsys, str(bad))
    assert main(["reconstruct", str(bad), "-o", out]) == 2
    _one_line(capsys, str(bad))
    nowhere = str(tmp_path / "no" / "such" / "o.exr")  # an unwritable output
    assert main(["reconstruct", str(files / "s.npz"), "-o", nowhere]) == 2
    _one_line(capsys, nowhere, "-o")
    assert main(["scene", "fence", "-o", str(tmp_path / "no" / "s.npz")]) == 2  # before render
    _one_line(capsys, "s.npz")
    assert main(["demo", "-o", str(files / "s.npz")]) == 2  # NotADirectoryError, no render
    _one_line(capsys, "s.npz", "not a folder")


@pytest.mark.skipif(os.geteuid() == 0, reason="root ignores file permissions")
def test_permission_error_real(files, tmp_path, capsys):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        assert main(["reconstruct", str(files / "s.npz"), "-o", str(ro / "o.exr")]) == 2
        _one_line(capsys, "o.exr")
    finally:
        ro.chmod(0o700)


def _raiser(exc):
    def fn(*a, **k):
        raise exc
    return fn


#: (where the error is raised, the exception for (input, output), words the line must hold)
INJECTED = [
    ("load_samples", lambda s, o: PermissionError(errno.EACCES, "Permission denied", s),
     ["{s}: Permission denied"]),
    ("load_samples", lambda s, o: zipfile.BadZipFile("File is not a zip file"),
     ["corrupt archive: File is not a zip file", "while reading samples {s}"]),
    ("save_image", lambda s, o: OSError(errno.ENOSPC, "No space left on device", o),
     ["{o}: No space left on device"]),
    ("save_image", lambda s, o: OSError(f"cannot write {o!r}: disk quota"),
     ["cannot write '{o}'"]),
    ("run", lambda s, o: MemoryError(), ["out of host memory", "while reconstructing {s}"]),
    ("run", lambda s, o: MemoryError("Unable to allocate 72.8 TiB for an array"),
     ["out of host memory: Unable to allocate 72.8 TiB", "{s}"]),
    ("run", lambda s, o: OverflowError("Python int too large to convert to C int"),
     ["value out of range", "while reconstructing {s} with box"]),
    ("run", lambda s, o: cl.Error("clFinish failed: OUT_OF_RESOURCES"),
     ["OpenCL Error", "OUT_OF_RESOURCES", "{s}"]),
    ("run", lambda s, o: cl.MemoryError("clEnqueueReadBuffer failed: "
                                        "MEM_OBJECT_ALLOCATION_FAILURE"),
     ["OpenCL MemoryError", "MEM_OBJECT_ALLOCATION_FAILURE", "{s}"]),
    ("run", lambda s, o: cl.LogicError("clEnqueueNDRangeKernel failed: "
                                       "INVALID_WORK_GROUP_SIZE"),
     ["OpenCL LogicError", "INVALID_WORK_GROUP_SIZE", "{s}"]),
    ("run", lambda s, o: cl.RuntimeError("clBuildProgram failed: BUILD_PROGRAM_FAILURE"),
     ["OpenCL RuntimeError", "{s}"]),
    ("run", lambda s, o: DeviceError("device lost"), ["device lost"]),
    ("run", lambda s, o: DeviceMemoryError("the box plan needs 9 GiB"), ["needs 9 GiB"]),
]


@pytest.mark.parametrize("where,make,words", INJECTED,
                         ids=[f"{w}-{type(m('S', 'O')).__name__}" for w, m, _ in INJECTED])
def test_every_family_is_one_line(files, tmp_path, capsys, monkeypatch, where, make, words):
    """Families that are hard to provoke for real, raised where the library raises them."""
    import clrecon.api
    import clrecon.io

    src, out = str(files / "s.npz"), str(tmp_path / "o.exr")
    mod = clrecon.io if where in ("load_samples", "save_image") else clrecon.api
    monkeypatch.setattr(mod, where, _raiser(make(src, out)))
    assert main(["reconstruct", src, "-o", out]) == 2
    _one_line(capsys, *(w.format(s=src, o=out) for w in words))


def test_type_error_keeps_its_traceback(files, tmp_path, monkeypatch):
    """A TypeError that is not a knob's is a bug: it propagates (a traceback), not rc 2."""
    import clrecon.api

    monkeypatch.setattr(clrecon.api, "run", _raiser(TypeError("unsupported operand")))
    with pytest.raises(TypeError, match="unsupported operand"):
        main(["reconstruct", str(files / "s.npz"), "-o", str(tmp_path / "o.exr")])
    monkeypatch.setattr(clrecon.api, "run", _raiser(AttributeError("no attribute x")))
    with pytest.raises(AttributeError):
        main(["reconstruct", str(files / "s.npz"), "-o", str(tmp_path / "o.exr")])


@pytest.mark.parametrize("argv,where,exc", [
    (["devices"], ("clrecon.core.device", "list_devices"), KeyError("index")),
    (["compare", "{img}", "{img}"], ("clrecon.metrics", "evaluate"), TypeError("bug")),
    (["scene", "spheres", "--size", "8x8", "-o", "{out}.npz"],
     ("clrecon.scenes", "render_samples"), ZeroDivisionError("bug")),
], ids=["devices-KeyError", "compare-TypeError", "scene-ZeroDivisionError"])
def test_a_bug_in_any_command_keeps_its_traceback(files, tmp_path, monkeypatch, argv, where,
                                                  exc):
    """main catches only the families a user can cause: a bug in a command propagates."""
    import importlib

    monkeypatch.setattr(importlib.import_module(where[0]), where[1], _raiser(exc))
    argv = [a.format(img=files / "img.exr", out=tmp_path / "s") for a in argv]
    with pytest.raises(type(exc)):
        main(argv)


def test_subprocess_bug_exits_1_with_a_traceback(tmp_path):
    code = ("import sys, clrecon.core.device as d; from clrecon.cli import main\n"
            "def bug(*a, **k): raise TypeError('unsupported operand')\n"
            "d.list_devices = bug; sys.exit(main(['devices']))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 1 and "Traceback" in r.stderr, r.stderr
    assert "TypeError: unsupported operand" in r.stderr and "clrecon devices: error" \
        not in r.stderr


def test_debug_shows_the_traceback(tmp_path):
    with pytest.raises(FileNotFoundError):
        main(["--debug", "reconstruct", str(tmp_path / "missing.npz"), "-o",
              str(tmp_path / "o.exr")])
    with pytest.raises(ValueError, match="unknown 'nope'"):
        main(["--debug", "scene", "nope", "-o", str(tmp_path / "x.npz")])


# -- --knob -----------------------------------------------------------------------------------

@pytest.mark.parametrize("knob,words", [
    (["--knob", "tile"], ["--knob 'tile'", "NAME=VALUE"]),
    (["--knob", "=3"], ["--knob '=3'", "NAME=VALUE"]),
    (["--knob", "tile=4", "--knob", "tile=8"], ["--knob tile", "twice"]),
    (["--knob", "tile=4", "--tile", "8"], ["--knob tile", "--tile"]),
    (["--knob", "bogus=1"], ["unknown knobs", "bogus"]),
    (["--knob", "grow=true"], ["unknown knobs", "grow"]),
], ids=["no-equals", "no-name", "twice", "and-flag", "unknown", "grow"])
def test_bad_knob_option(files, tmp_path, capsys, knob, words):
    out = tmp_path / "o.exr"
    assert main(["reconstruct", str(files / "s.npz"), "-o", str(out), "--method", "sweep",
                 *knob]) == 2
    _one_line(capsys, *words)
    assert not out.exists()


def test_variant_and_method_lists(tmp_path, capsys):
    assert main(["table", "--variant", "x=sweep:bogus=1", "-o", str(tmp_path / "t")]) == 2
    _one_line(capsys, "--variant x", "bogus")
    assert main(["trade", "--methods", "nope", "-o", str(tmp_path / "t")]) == 2
    _one_line(capsys, "unknown 'nope'")
    assert main(["demo", "--methods", "box,nope", "-o", str(tmp_path / "d")]) == 2
    _one_line(capsys, "--methods", "unknown 'nope'")
    assert not (tmp_path / "d").exists() and not (tmp_path / "t").exists()


# -- outputs that are inputs --------------------------------------------------------------------

def test_reference_equal_to_output_is_refused(files, tmp_path, capsys):
    ref = tmp_path / "ref.exr"
    ref.write_bytes(_bytes(files / "img.exr"))
    before = _bytes(ref)
    src = str(files / "s.npz")
    for out in (str(ref), f"{tmp_path}/./ref.exr", f"{tmp_path}/sub/../ref.exr"):
        (tmp_path / "sub").mkdir(exist_ok=True)
        assert main(["reconstruct", src, "-o", out, "--reference", str(ref)]) == 2
        _one_line(capsys, "--reference", "same file")
    link = tmp_path / "link.exr"
    link.symlink_to(ref)
    hard = tmp_path / "hard.exr"
    os.link(ref, hard)
    for out in (link, hard):  # a symbolic link; a hard link (the same inode)
        assert main(["reconstruct", src, "-o", str(out), "--reference", str(ref)]) == 2
        _one_line(capsys, "same file")
    assert _bytes(ref) == before
    # a reference that does not exist yet is still the output: refused, nothing written
    new = tmp_path / "new.exr"
    assert main(["reconstruct", src, "-o", str(new), "--reference", str(new)]) == 2
    _one_line(capsys, "same file")
    assert not new.exists()


def test_output_equal_to_input_is_refused(files, tmp_path, capsys):
    inp = tmp_path / "s.exr"
    inp.write_bytes(_bytes(files / "s.exr"))
    before = _bytes(inp)
    assert main(["reconstruct", str(inp), "-o", str(inp)]) == 2
    _one_line(capsys, "input", "same file", str(inp))
    assert _bytes(inp) == before
    tlfr = tmp_path / "f.bin"
    save_samples(tlfr, SampleBuffer.zeros(2, 2, 1))
    assert main(["reconstruct", str(tlfr), "-o", str(tlfr) + ".header"]) == 2
    _one_line(capsys, "same file", "f.bin.header")  # the TLFR header is an input too


def test_reference_read_before_the_output_is_written(files, tmp_path, capsys):
    out = tmp_path / "o.exr"
    assert main(["reconstruct", str(files / "s.npz"), "-o", str(out), "--reference",
                 str(tmp_path / "missing.exr")]) == 2
    _one_line(capsys, "missing.exr")
    assert not out.exists()
    assert main(["reconstruct", str(files / "s.npz"), "-o", str(out), "--reference",
                 str(files / "img.exr"), "--json"]) == 0
    assert out.is_file() and '"quality"' in capsys.readouterr().out


def test_bench_outputs_and_baseline(tmp_path, capsys):
    base = tmp_path / "old.json"
    base.write_text("{}")
    assert main(["bench", "--compare", str(base), "--json", str(base)]) == 2
    _one_line(capsys, "--json", "--compare", "same file")
    assert main(["bench", "--compare", str(base), "--csv", str(base)]) == 2
    _one_line(capsys, "--csv", "same file")
    both = str(tmp_path / "r.json")
    assert main(["bench", "--json", both, "--csv", both]) == 2
    _one_line(capsys, "--csv", "--json", "same file")
    assert base.read_text() == "{}"
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    assert main(["bench", "--compare", str(bad)]) == 2
    _one_line(capsys, "--compare", "bad.json", "not JSON")


# -- through a real process -----------------------------------------------------------------

def _cli(*args, cwd=None):
    cmd = [sys.executable, "-m", "clrecon.cli", *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=300, cwd=cwd)


@pytest.mark.parametrize("case", ["missing-input", "knob-without-equals", "reference-is-output",
                                  "no-device", "bad-layers"])
def test_subprocess_one_line_exit_2(files, tmp_path, case):
    src, out = str(files / "s.npz"), str(tmp_path / "o.exr")
    args, word = {
        "missing-input": (["reconstruct", str(tmp_path / "missing.npz"), "-o", out],
                          "missing.npz: file not found"),
        "knob-without-equals": (["reconstruct", src, "-o", out, "--knob", "tile"],
                                "--knob 'tile': expected NAME=VALUE"),
        "reference-is-output": (["reconstruct", src, "-o", out, "--reference", out],
                                "same file as the --reference"),
        "no-device": (["reconstruct", src, "-o", out, "--device", "no-such-device-xyz"],
                      "no OpenCL device matches"),
        "bad-layers": (["reconstruct", src, "-o", out, "--method", "splat", "--layers",
                        "100000"], "layers: must be an integer in [1, 64]"),
    }[case]
    r = _cli(*args)
    assert r.returncode == 2, (r.returncode, r.stderr)
    lines = r.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("clrecon reconstruct: error: "), r.stderr
    assert word in lines[0], lines[0]
    assert not Path(out).exists()


def test_subprocess_debug_traceback(tmp_path):
    r = _cli("--debug", "reconstruct", str(tmp_path / "missing.npz"), "-o",
             str(tmp_path / "o.exr"))
    assert r.returncode == 1 and "Traceback" in r.stderr and "FileNotFoundError" in r.stderr
