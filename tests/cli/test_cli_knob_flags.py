"""``clrecon reconstruct``'s method flags come from the methods' signatures: every knob of
every method has one, its help gives each method's default as the signature has it, and
the flags that existed before keep their spelling."""
from __future__ import annotations

import inspect

import pytest

from clrecon.api import METHODS, PIPELINE_KNOBS, make_pipeline
from clrecon.cli import build_parser
from clrecon.cli.knob_flags import (
    DESCRIPTIONS,
    EVERY_METHOD,
    flag_knobs,
    method_flags,
    signature_knobs,
)
from clrecon.core.local_size import LocalSize

#: constructor parameters that are no user knob, by the documented rule (launch
#: configurations; context and info have no default)
NOT_KNOBS = {"box": {"local"}}
#: pipeline knobs spelled another way: ``estimate_error`` is ``--error PATH``
OTHER_SPELLING = {"estimate_error": "--error"}
#: the method flags of the hand-written CLI, spelled as they were
EXISTING = ("--scales", "--dof-layers", "--exponent", "--sort", "--tile", "--group", "--mode",
            "--filter", "--stats-stride", "--merge-threshold", "--psf", "--layers", "--pyramid",
            "--dense", "--mip-radius", "--safeguard", "--no-safeguard")


def _reconstruct():
    p = build_parser()
    return next(a for a in p._actions if a.dest == "command").choices["reconstruct"]


def _actions() -> dict:
    return {opt: a for a in _reconstruct()._actions for opt in a.option_strings}


def test_every_knob_of_every_method_has_a_flag_with_its_default():
    actions = _actions()
    checked = 0
    for method, cls in METHODS.items():
        for name, param in inspect.signature(cls.__init__).parameters.items():
            if name in ("self", "context", "info") or name in NOT_KNOBS.get(method, ()):
                continue
            flag = "--" + name.replace("_", "-")
            assert flag in actions, f"{method}.{name}: no {flag}"
            assert actions[flag].dest == name and actions[flag].default is None
            assert f"{method} (default {param.default!r})" in actions[flag].help, \
                (method, name, actions[flag].help)
            checked += 1
    assert checked >= 30  # sweep, layered and splat have dozens between them
    for name in PIPELINE_KNOBS:
        default = inspect.signature(make_pipeline).parameters[name].default
        if name in OTHER_SPELLING:
            assert OTHER_SPELLING[name] in actions
            continue
        flag = "--" + name.replace("_", "-")
        assert f"{EVERY_METHOD} (default {default!r})" in actions[flag].help


def test_a_shared_knob_is_one_flag_naming_each_method():
    help_text = _actions()["--tile"].help
    assert "sweep (default None)" in help_text and "layered (default 32)" in help_text
    assert sum(1 for a in _reconstruct()._actions if a.dest == "tile") == 1


def test_every_description_is_of_a_knob():
    """A knob a method drops takes its description with it."""
    assert set(DESCRIPTIONS) <= {f.name for f in method_flags()}


def test_existing_flags_keep_their_spelling():
    actions = _actions()
    assert not [f for f in EXISTING if f not in actions]
    assert "--no-dense" in actions and "--no-dof-layers" in actions  # bools: --x/--no-x


def test_the_rule_leaves_out_what_is_no_knob():
    def init(self, context, info, local: LocalSize | None = None, tile: int | None = None,
             on: bool = True, mode: str = "a", x: float = 1.0, either: int | bool = 8,
             untyped=3, scale: float = 2.0):
        pass

    got = {name: (kinds, default) for name, kinds, default in signature_knobs(init)}
    assert list(got) == ["tile", "on", "mode", "x", "either", "scale"]
    assert got["tile"] == ((int,), None) and got["either"] == ((int, bool), 8)


def test_flags_become_knobs_and_absent_flags_pass_nothing():
    p = build_parser()
    args = p.parse_args(["reconstruct", "f.npz", "-o", "o.exr", "--tile", "8", "--no-dense",
                         "--subsample", "false", "--mip-radius", "0", "--no-safeguard"])
    assert flag_knobs(args, {}) == {"tile": 8, "dense": False, "subsample": False,
                                    "mip_radius": 0.0, "safeguard": False}
    args = p.parse_args(["reconstruct", "f.npz", "-o", "o.exr", "--subsample", "4",
                         "--dof-layers"])
    assert flag_knobs(args, {"scales": 4}) == {"scales": 4, "subsample": 4, "dof_layers": True}
    assert flag_knobs(p.parse_args(["reconstruct", "f.npz", "-o", "o.exr"]), {}) == {}


def test_a_value_of_another_type_is_refused(capsys):
    with pytest.raises(SystemExit):
        build_parser().parse_args(["reconstruct", "f.npz", "-o", "o.exr", "--subsample", "x"])
    assert "--subsample: expected int or bool, got 'x'" in capsys.readouterr().err
