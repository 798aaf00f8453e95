"""The small shared pieces of the bench: the text forms of options (sizes, knobs), the paired
rounds every side-by-side timing runs in, and the page a measurement script prints."""
from __future__ import annotations

import argparse

import pytest

from clrecon.bench.options import SizeError, parse_knobs, parse_size
from clrecon.bench.scripts import emit_page
from clrecon.bench.timing import paired_rounds


def test_parse_size():
    assert parse_size("640x360") == (640, 360)
    assert parse_size("64X32") == (64, 32)
    with pytest.raises(ValueError, match="expected WxH"):
        parse_size("640")
    with pytest.raises(ValueError, match="size must be positive"):
        parse_size("0x8")
    assert issubclass(SizeError, argparse.ArgumentTypeError)


def test_parse_size_as_an_argparse_type(capsys):
    """argparse shows the message itself (not "invalid parse_size value")."""
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", type=parse_size)
    assert ap.parse_args(["--size", "8x4"]).size == (8, 4)
    with pytest.raises(SystemExit):
        ap.parse_args(["--size", "0x4"])
    assert "size must be positive, got '0x4'" in capsys.readouterr().err


def test_parse_knobs():
    assert parse_knobs(["scales=4", "exponent=1.3", "dof_layers=True", "sort=pixel"],
                       "here") == {"scales": 4, "exponent": 1.3, "dof_layers": True,
                                   "sort": "pixel"}
    with pytest.raises(ValueError, match=r"--knob 'tile': expected NAME=VALUE \(e.g."):
        parse_knobs(["tile"], "--knob", " (e.g. --knob tile=8)")
    with pytest.raises(ValueError, match="here '=3': expected NAME=VALUE$"):
        parse_knobs(["=3"], "here")
    with pytest.raises(ValueError, match="here tile: given twice"):
        parse_knobs(["tile=2", "tile=4"], "here")


def test_paired_rounds_rotate_the_order():
    calls = []

    def call(i):
        def run():
            calls.append(i)
            return 10 * len(calls) + i
        return run

    got = paired_rounds([call(0), call(1), call(2)], 3)
    assert calls == [0, 1, 2, 1, 2, 0, 2, 0, 1]
    assert got == [[10, 60, 80], [21, 41, 91], [32, 52, 72]]
    two = []
    paired_rounds([lambda: two.append("a"), lambda: two.append("b")], 4)
    assert two == ["a", "b", "b", "a", "a", "b", "b", "a"]  # with two: alternating


def test_emit_page(tmp_path, capsys):
    path = tmp_path / "page.md"
    assert emit_page(["# t", "", "x"], path) == "# t\n\nx\n"
    assert path.read_text() == "# t\n\nx\n"
    assert "# t" in capsys.readouterr().out
    assert emit_page(["y"]) == "y\n"
