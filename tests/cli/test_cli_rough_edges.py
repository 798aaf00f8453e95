"""Rough edges a new user meets on the command line: error messages that leave things out,
help without defaults, long runs that say nothing, compiler chatter, a sample file given
where an image belongs."""
from __future__ import annotations

import os
import subprocess
import sys
import uuid
from pathlib import Path

import numpy as np
import pytest

import clrecon.scenes
from clrecon.bench.trade import TRADES
from clrecon.cli import build_parser, main
from clrecon.core import device as cldev
from clrecon.core.errors import KernelBuildError

ROOT = Path(__file__).resolve().parents[2]


def _cli(*args, env=None):
    return subprocess.run([sys.executable, "-m", "clrecon.cli", *args], capture_output=True,
                          text=True, timeout=300, cwd=ROOT,
                          env={**os.environ, **(env or {})})


def _subparser(name):
    p = build_parser()
    sub = next(a for a in p._actions if a.dest == "command")
    return sub.choices[name]


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    """A small sample buffer (npz and EXR) and a box image of it."""
    d = tmp_path_factory.mktemp("frames")
    assert main(["scene", "spheres", "--size", "24x16", "--spp", "4", "-o",
                 str(d / "s.npz")]) == 0
    assert main(["scene", "spheres", "--size", "24x16", "--spp", "4", "-o",
                 str(d / "s.exr")]) == 0
    assert main(["reconstruct", str(d / "s.npz"), "-o", str(d / "box.exr")]) == 0
    return d


def _one_line(capsys):
    err = capsys.readouterr().err
    lines = err.splitlines()
    assert len(lines) == 1, err
    return lines[0]


# -- 1. the sort error lists every plan ------------------------------------------------------

def test_sort_error_lists_every_plan(frames, capsys):
    capsys.readouterr()
    assert main(["reconstruct", str(frames / "s.npz"), "-o", str(frames / "o.exr"),
                 "--method", "sweep", "--knob", "sort=heap"]) == 2
    line = _one_line(capsys)
    for plan in ("'block'", "'tile'", "'pixel'", "'heap'"):
        assert plan in line, line
    assert "CPUs" in line, line  # and what leaving it out picks


# -- 2. help shows defaults; trade says what it runs and how long ----------------------------

@pytest.mark.parametrize("command", ["tune", "bench", "trade", "demo", "table", "report"])
def test_help_shows_every_default(command):
    sp = _subparser(command)
    fmt = sp._get_formatter()
    missing = []
    for action in sp._actions:
        if (not action.option_strings or action.help == "==SUPPRESS==" or action.nargs == 0
                or action.default is None):
            continue
        if "default" not in fmt._expand_help(action):
            missing.append(action.option_strings[0])
    assert not missing, f"{command} --help: no default shown for {missing}"
    assert "%(default" not in sp.format_help()


def test_help_defaults_are_readable():
    text = " ".join(_subparser("trade").format_help().split())
    assert "(default: 4,8,16)" in text and "(default: 512x512)" in text
    text = " ".join(_subparser("bench").format_help().split())
    assert "(default: 1280x720)" in text and "(default: 7)" in text
    assert "(default: 16)" in " ".join(_subparser("tune").format_help().split())


def test_trade_says_what_it_runs_and_how_long(tmp_path, capsys):
    assert main(["trade", "--scenes", "spheres", "--methods", "sweep", "--spp", "2,4",
                 "--size", "16x8", "--repeats", "1", "--ref-spp", "4", "--no-oidn", "-o",
                 str(tmp_path)]) == 0
    lines = capsys.readouterr().err.splitlines()
    assert lines, "trade printed nothing on stderr"
    first = lines[0]
    n = 1 + len(TRADES["sweep"])  # box and sweep's settings
    assert "1 scenes x 2 spp" in first and f"x {n} settings = {2 * n} measurements" in first, \
        first
    assert "1 paired round" in first and "1 references to render at 4 spp" in first, first
    assert any("left" in line and "spheres at 2 spp" in line for line in lines), lines
    # a second run finds the reference cached and says so
    assert main(["trade", "--scenes", "spheres", "--methods", "box", "--spp", "2",
                 "--size", "16x8", "--repeats", "1", "--ref-spp", "4", "--no-oidn", "-o",
                 str(tmp_path)]) == 0
    first = capsys.readouterr().err.splitlines()[0]
    n = len(TRADES["box"])  # box named: its own settings too
    assert f"= {n} measurements" in first and "1 references cached" in first, first


def test_trade_progress_total_known_from_the_start(tmp_path):
    from clrecon.bench.trade import trade

    calls = []
    trade(["spheres"], ["box"], spps=(2,), size=(16, 8), repeats=1, oidn=False,
          out_dir=tmp_path, ref_spp=4, progress=lambda d, t: calls.append((d, t)))
    assert calls[0] == (0, calls[-1][1]) and calls[-1][0] == calls[-1][1]


# -- 3. --device on bench and batch ----------------------------------------------------------

@pytest.mark.parametrize("argv", [["bench"], ["batch", "x.npz", "-o", "out"]])
def test_device_is_an_option_of_bench_and_batch(argv):
    """Not by argparse's prefix matching of --devices: spelled out."""
    p = build_parser()
    sp = next(a for a in p._actions if a.dest == "command").choices[argv[0]]
    sp.allow_abbrev = False
    assert p.parse_args([*argv, "--device", "0"]).devices == [0]
    assert p.parse_args([*argv, "--device", "0,CPU"]).devices == [0, "CPU"]
    assert p.parse_args([*argv, "--devices", "all"]).devices == "all"
    assert "--device" in sp.format_help().replace("--devices", "")


# -- 4, 5. the demo: its reference cached, its stages logged, its table explained ------------

def _demo(out, *extra):
    return main(["demo", "--scene", "spheres", "--size", "24x16", "--ref-spp", "16",
                 "--methods", "box", "-o", str(out), *extra])


def test_demo_caches_its_reference(tmp_path, monkeypatch, capsys):
    monkeypatch.delenv("CLRECON_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    assert _demo(tmp_path / "a") == 0
    cold = capsys.readouterr()
    cached = list((tmp_path / "cache" / "clrecon" / "references").glob("spheres_24x16_*.npy"))
    assert len(cached) == 1, cached
    assert "(cached for the next run)" in cold.out
    # stderr is no terminal here: a line per stage instead of a silent bar
    assert "clrecon demo: reference 24x16 at 16 spp: rendering" in cold.err, cold.err
    assert "clrecon demo: box:" in cold.err, cold.err

    def no_render(*a, **k):
        raise AssertionError("the cached reference was rendered again")

    monkeypatch.setattr(clrecon.scenes, "render_reference", no_render)
    assert _demo(tmp_path / "b") == 0
    warm = capsys.readouterr()
    assert "from the cache" in warm.out and "read from the cache" in warm.err
    box = [line for line in cold.out.splitlines() if line.startswith("box ")]
    assert box and box[0].split("PSNR")[1] == \
        next(x for x in warm.out.splitlines() if x.startswith("box ")).split("PSNR")[1]
    # another seed is another reference; a corrupt entry is rendered again
    with pytest.raises(AssertionError, match="rendered again"):
        _demo(tmp_path / "c", "--seed", "5")
    monkeypatch.undo()
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    monkeypatch.delenv("CLRECON_CACHE_DIR", raising=False)
    cached[0].write_bytes(b"not a numpy file")
    assert _demo(tmp_path / "d") == 0
    assert "(cached for the next run)" in capsys.readouterr().out
    assert np.load(cached[0]).shape == (16, 24, 3)
    assert not list(cached[0].parent.glob("*.tmp"))


def test_demo_reference_cache_off(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("CLRECON_CACHE_DIR", "off")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    assert _demo(tmp_path / "a") == 0
    out = capsys.readouterr().out
    assert "cached for the next run" not in out and "from the cache" not in out
    assert not (tmp_path / "cache").exists()


def test_demo_explains_its_table(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    monkeypatch.delenv("CLRECON_CACHE_DIR", raising=False)
    assert _demo(tmp_path / "a") == 0
    out = capsys.readouterr().out
    tail = out[out.index("\nbox "):]
    assert "total ms:" in tail and "readback" in tail and "upload" in tail
    assert "higher is better" in tail and "FLIP, lower is better" in tail
    assert "rank" in tail  # why FLIP and PSNR can disagree


# -- 6. compiler chatter ---------------------------------------------------------------------

def _pocl(dev) -> bool:
    return "portable computing language" in dev.info.platform.lower()


def test_sweep_block_build_prints_nothing_without_verbose(frames, tmp_path):
    """PoCL's compiler writes warnings to fd 2 building sweep_block ('30 warnings
    generated.' for pthread-haswell; none for skylake-avx512); a fresh POCL_CACHE_DIR makes
    it compile, and a macro defined twice in the build options (PYOPENCL_BUILD_OPTIONS)
    makes every clang-based compiler warn, whatever its target."""
    args = ["reconstruct", str(frames / "s.npz"), "-o", str(tmp_path / "o.exr"), "--method",
            "sweep", "--sort", "block"]
    chatter = {"PYOPENCL_BUILD_OPTIONS": "-DCLRECON_CHATTER=1 -DCLRECON_CHATTER=2"}
    r = _cli(*args, env={"POCL_CACHE_DIR": str(tmp_path / "pocl"), **chatter})
    assert r.returncode == 0, r.stderr
    assert r.stderr == "", r.stderr
    r = _cli("-v", *args, env={"POCL_CACHE_DIR": str(tmp_path / "pocl-v"), **chatter})
    assert r.returncode == 0, r.stderr
    if _pocl(cldev.get_device()):
        assert "warning" in r.stderr, r.stderr  # with -v the chatter is shown


def test_build_output_is_captured_and_logged(device, capfd, caplog):
    token = uuid.uuid4().hex  # a source PoCL has not cached: it compiles
    src = (f"// {token}\n#warning clrecon-rough-edges\n"
           "__kernel void k(__global float *o) { o[0] = 1.0f; }\n")
    capfd.readouterr()
    with caplog.at_level("DEBUG", logger="clrecon.core.device"):
        cldev.build_source(device.context, src, label="chatty.cl")
    err = capfd.readouterr().err
    assert "warning" not in err, err
    if _pocl(device):
        assert any("chatty.cl" in r.getMessage() and "warning" in r.getMessage()
                   for r in caplog.records), [r.getMessage() for r in caplog.records]
    # fd 2 works again afterwards
    os.write(2, b"after the build\n")
    assert "after the build" in capfd.readouterr().err


def test_build_failure_keeps_its_log(device, capfd):
    src = f"// {uuid.uuid4().hex}\n__kernel void k(__global float *o) {{ o[0] = nosuch_id; }}\n"
    capfd.readouterr()
    with pytest.raises(KernelBuildError) as info:
        cldev.build_source(device.context, src, label="broken.cl")
    assert "nosuch_id" in str(info.value) and "broken.cl" in str(info.value)
    assert capfd.readouterr().err == ""
    if _pocl(device):
        assert "error generated" in info.value.log, info.value.log


# -- 7. compare on a sample file -------------------------------------------------------------

@pytest.mark.parametrize("which", ["a", "b"])
def test_compare_names_a_sample_exr(frames, capsys, which):
    a, b = str(frames / "s.exr"), str(frames / "box.exr")
    if which == "b":
        a, b = b, a
    capsys.readouterr()
    assert main(["compare", a, b]) == 2
    line = _one_line(capsys)
    assert "sample buffer (4 spp)" in line and "reconstruct it first" in line, line
    assert "s1.R" not in line and len(line) < 240, line


def test_compare_names_an_npz_sample_file(frames, capsys):
    capsys.readouterr()
    assert main(["compare", str(frames / "s.npz"), str(frames / "box.exr")]) == 2
    assert "sample buffer" in _one_line(capsys)


# -- 8. a bad --methods fails before the demo's long part -----------------------------------

def test_demo_bad_method_fails_before_rendering(tmp_path, monkeypatch, capsys):
    def no_render(*a, **k):
        raise AssertionError("rendered before checking --methods")

    monkeypatch.setattr(clrecon.scenes, "render_reference", no_render)
    monkeypatch.setattr(clrecon.scenes, "render_samples", no_render)
    assert main(["demo", "--methods", "box,nosuch", "-o", str(tmp_path / "d")]) == 2
    line = _one_line(capsys)
    assert "nosuch" in line and "--methods" in line, line
    assert not (tmp_path / "d").exists()
    assert main(["demo", "--methods", "box,box+guided", "-o", str(tmp_path / "d")]) == 2
    line = _one_line(capsys)
    assert "box+guided" in line and "guide" in line, line
    assert not (tmp_path / "d").exists()
