"""The tuner's side of every tunable pass: a runner that builds and launches the real pass
on a synthetic frame of the tuned size, beside the pass's declaration.

A pass declares its :class:`~clrecon.tune.tunable.Tunable` beside its class; its runner
lives in the module of its method here (:mod:`.box`, :mod:`.sweep`, :mod:`.layered`,
:mod:`.splat`, :mod:`.scenes` for the scene generator's ``raytrace``), what they share in
:mod:`.common`. Adding a pass to the tuner means declaring it and decorating its runner
with :func:`~.common.tunes`. Importing this package imports every pass:
the run-time lookup (:mod:`clrecon.tune.runtime`) never does.
"""
from __future__ import annotations

from clrecon.tune.runners import box, layered, scenes, splat, sweep
from clrecon.tune.runners.common import PassRunner, PassSpec, pass_time_ms, synthetic_frame

#: name -> how to tune it, in the order a whole tuning session runs them
SPECS: dict[str, PassSpec] = {s.name: s for s in (
    *scenes.SPECS, *box.SPECS, *sweep.SPECS, *layered.SPECS, *splat.SPECS)}

#: the configuration every pass uses on a CPU when no tuning entry applies (lookup level
#: "default"); a GPU gets :data:`GPU_DEFAULTS`, both fitted by
#: :func:`clrecon.tune.runtime.default_config`
DEFAULTS: dict[str, dict | None] = {name: spec.default for name, spec in SPECS.items()}
GPU_DEFAULTS: dict[str, dict | None] = {
    name: spec.tunable.default_for("GPU") for name, spec in SPECS.items()}

__all__ = ["DEFAULTS", "GPU_DEFAULTS", "SPECS", "PassRunner", "PassSpec", "pass_time_ms",
           "synthetic_frame"]
