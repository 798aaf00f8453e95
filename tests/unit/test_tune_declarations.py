"""Each pass declares its tunables beside its class; the run-time lookup takes the
declaration and imports no pass, no runner and no tuner session; the API override of the
lookup checks pass names before any method is imported."""
from __future__ import annotations

import subprocess
import sys

import pytest

from clrecon.api import make_pipeline
from clrecon.tune.runners import SPECS, synthetic_frame
from clrecon.tune.runtime import override_tuning
from clrecon.tune.tunable import PASS_NAMES, Tunable, local_candidates


def test_every_declared_pass_has_a_runner_and_is_known():
    assert set(SPECS) == PASS_NAMES
    for name, spec in SPECS.items():
        assert spec.tunable.name == name and spec.name == name


def test_renamed_passes_say_their_method():
    """One pass per name and kernel file: layered's and splat's composites and splat's
    integration name their method."""
    from clrecon.methods.layered.composite import LayeredComposite
    from clrecon.methods.splat.composite import SplatComposite
    from clrecon.methods.splat.integrate import SplatIntegrate

    assert (LayeredComposite.TUNABLE.name, LayeredComposite.TUNABLE.kernel_file) == \
        ("layered_composite", "layered_composite")
    assert (SplatIntegrate.TUNABLE.name, SplatIntegrate.TUNABLE.kernel_file) == \
        ("splat_integrate", "splat_integrate")
    assert SplatComposite.TUNABLE.name == "splat_composite"
    assert not {"composite", "integrate"} & set(SPECS)


def test_an_undeclared_pass_name_is_refused():
    with pytest.raises(ValueError, match="PASS_NAMES"):
        Tunable("nope", "box", None, local_candidates)
    with pytest.raises(ValueError, match="unknown pass 'composite'"):
        with override_tuning({"composite": None}):
            pass
    with pytest.raises(ValueError, match="expected 'default'"):
        with override_tuning("tuned"):
            pass


def _fresh(code: str) -> str:
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          check=True).stdout.strip()


def test_the_lookup_imports_no_pass_and_no_runner():
    """Looking a configuration up, and overriding it, needs neither the methods nor the
    tuner's runners: no import cycle through the lookup, and a light import."""
    loaded = _fresh(
        "import sys\n"
        "from clrecon.tune.runtime import override_tuning, tuned\n"
        "with override_tuning({'layered_composite': None, 'splat_integrate': {'wg_x': 8, "
        "'wg_y': 8}}):\n"
        "    pass\n"
        "print(' '.join(sorted(m for m in sys.modules if m.startswith('clrecon.'))))")
    heavy = [m for m in loaded.split() if m.startswith(
        ("clrecon.methods", "clrecon.scenes", "clrecon.tune.runners", "clrecon.tune.session"))]
    assert not heavy, heavy


def test_override_tuning_sets_the_source(device):
    """Pipelines built inside the block take the override (source "default" or
    "override"); after it, the usual chain."""
    info = synthetic_frame(16, 12, 2).inspect()

    def box():
        return make_pipeline("box", device.context, info, safeguard=False).describe()

    with override_tuning("default"):
        assert box()["tuning"] == {"box": "default"}
    with override_tuning({"box": {"wg_x": 2, "wg_y": 2}}):
        got = box()
    assert got["tuning"] == {"box": "override"} and got["local_size"] == [2, 2]
    assert box()["tuning"]["box"] != "override"
