"""Autotuning of the OpenCL passes: the search (:mod:`.tuner`, measuring each configuration
with :mod:`.measure`) and the database (:mod:`.db`).

These are pure logic (no OpenCL import): the search talks to a :class:`Runner`, the
database reads and writes JSON files under ``tuning/<runtime>/<device>.json``. Each pass
declares what is tunable beside its class (:class:`.tunable.Tunable`); the passes look
their configuration up with :func:`.runtime.tuned`, which imports no pass; the tuner's
runners (:mod:`.runners`, which import every pass) and the session (:mod:`.session`) are
imported only to tune.
"""
from clrecon.tune.db import (
    SCHEMA_VERSION,
    Lookup,
    bucket_for,
    clear_cache,
    db_path,
    entry_key,
    env_var,
    load,
    lookup,
    save_result,
    slug,
)
from clrecon.tune.tuner import (
    MIN_RUNS,
    STATUSES,
    Config,
    Measurement,
    Runner,
    TuneResult,
    config_key,
    config_sort_key,
    tune,
)

__all__ = [
    "SCHEMA_VERSION", "Lookup", "bucket_for", "clear_cache", "db_path", "entry_key", "env_var",
    "load", "lookup", "save_result", "slug",
    "MIN_RUNS", "STATUSES", "Config", "Measurement", "Runner", "TuneResult", "config_key",
    "config_sort_key", "tune",
]
