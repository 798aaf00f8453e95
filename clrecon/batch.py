"""Reconstruct many frames: every OpenCL device of the machine at once, or a Dask cluster.

A *job* is one input sample file and where its image goes (``OUTDIR/<stem>.exr``, and
``<stem>.png`` with ``png=True``). :func:`batch` runs a list of jobs:

- locally (default): one thread per device, all pulling from one queue of frames; each
  device keeps its plan and buffers from frame to frame (:func:`clrecon.run` re-plans only
  when a frame's description changes; kernels come from the build cache);
- on Dask distributed (``scheduler="tcp://host:8786"``, or ``workers=N`` for a local
  cluster of N processes): one task per frame, each worker on its own default OpenCL
  device (``CLRECON_DEVICE`` in the worker's environment chooses another), keeping its
  plans between the frames it gets. A worker that dies mid-frame loses nothing: the
  scheduler re-runs its frames elsewhere, and images are only ever written whole.

Every image is written atomically (:func:`clrecon.io.save_image`: a temporary file, then a
rename), so a frame whose outputs exist is complete: with ``resume=True`` (default) such
frames are skipped. A frame that fails is recorded with its error and the others go on. The
summary (``OUTDIR/summary.json``, also returned) has one record per frame: input, outputs,
device, device and wall milliseconds, PSNR/SSIM/FLIP when a reference is found, or the
error.
"""
from __future__ import annotations

import glob
import json
import os
import queue
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass
from pathlib import Path

from clrecon.api import METHODS, run
from clrecon.core.device import get_device
from clrecon.core.fsutil import write_atomic
from clrecon.io import load_image, load_samples, save_image
from clrecon.metrics import evaluate

SAMPLE_EXTENSIONS = (".bin", ".txt", ".exr", ".npz")


@dataclass(frozen=True)
class Job:
    name: str
    input: str
    output: str
    png: str | None = None
    reference: str | None = None

    def done(self) -> bool:
        return os.path.exists(self.output) and (self.png is None or os.path.exists(self.png))


def expand_inputs(inputs: Iterable[str]) -> list[str]:
    """Files and globs -> sorted unique sample files (``.header`` companions left out)."""
    found: dict[str, None] = {}
    for pattern in inputs:
        matches = sorted(glob.glob(pattern)) if glob.has_magic(pattern) else [pattern]
        if not matches:
            raise ValueError(f"inputs: {pattern!r} matches no file")
        for m in matches:
            if m.endswith(".header"):
                continue
            if not os.path.isfile(m):
                raise ValueError(f"inputs: {m!r} is not a file")
            if not m.lower().endswith(SAMPLE_EXTENSIONS):
                raise ValueError(f"inputs: {m!r} is not a sample file "
                                 f"({', '.join(SAMPLE_EXTENSIONS)})")
            found[os.path.realpath(m)] = None
    return list(found)


def make_jobs(inputs: Iterable[str], outdir: str, png: bool = False,
              references: str | None = None) -> list[Job]:
    """One job per input; outputs named after the input's stem (stems must be unique)."""
    files = expand_inputs(inputs)
    out = Path(outdir)
    jobs, seen = [], {}
    for f in files:
        stem = Path(f).stem
        if stem in seen:
            raise ValueError(f"inputs: {seen[stem]} and {f} would both write {stem}.exr")
        seen[stem] = f
        ref = None
        if references is not None:
            cand = Path(references) / f"{stem}.exr"
            ref = str(cand) if cand.is_file() else None
        output = str(out / f"{stem}.exr")
        if os.path.realpath(output) in (os.path.realpath(f), ref and os.path.realpath(ref)):
            raise ValueError(f"-o: {output} would overwrite an input or a reference")
        jobs.append(Job(stem, f, output, str(out / f"{stem}.png") if png else None, ref))
    return jobs


def run_frame(job: Job, method: str, knobs: dict, device=None) -> dict:
    """Reconstruct one job and write its images; the record of :func:`batch`'s summary."""
    t0 = time.perf_counter()
    rec = {"frame": job.name, "input": job.input, "output": job.output, "png": job.png}
    try:
        buf = load_samples(job.input)
        res = run(buf, method, device, **knobs)
        save_image(job.output, res.image)
        if job.png:
            save_image(job.png, res.image)
        rec |= {"device": res.device, "device_ms": round(res.device_ms, 3),
                "plan": res.method.get("plan")}
        if job.reference:
            rec |= {"reference": job.reference} | evaluate(res.image, load_image(job.reference))
    except Exception as exc:  # noqa: BLE001  (a frame that fails is reported; the run goes on)
        rec["error"] = f"{type(exc).__name__}: {exc}"
    rec["wall_ms"] = round((time.perf_counter() - t0) * 1e3, 3)
    return rec


def _run_local(jobs: list[Job], method: str, knobs: dict, devices: list,
               progress: Callable[[dict], None]) -> list[dict]:
    todo: queue.Queue = queue.Queue()
    for j in jobs:
        todo.put(j)
    records: list[dict] = []
    lock = threading.Lock()

    def worker(dev):
        while True:
            try:
                job = todo.get_nowait()
            except queue.Empty:
                return
            rec = run_frame(job, method, knobs, dev)
            with lock:
                records.append(rec)
                progress(rec)

    threads = [threading.Thread(target=worker, args=(d,), daemon=True) for d in devices]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return records


def _run_dask(jobs: list[Job], method: str, knobs: dict, scheduler: str | None,
              workers: int | None, progress: Callable[[dict], None]) -> list[dict]:
    try:
        from distributed import Client, LocalCluster, as_completed
    except ImportError as exc:
        raise ValueError("--scheduler/--workers need Dask distributed: "
                         "pip install clrecon[farm]") from exc
    cluster = None
    if scheduler is None:
        cluster = LocalCluster(n_workers=int(workers), threads_per_worker=1, processes=True,
                               dashboard_address=None)
        client = Client(cluster)
    else:
        client = Client(scheduler)
    try:
        futures = [client.submit(run_frame, j, method, knobs, key=f"clrecon-{j.name}",
                                 retries=3, pure=False) for j in jobs]
        records = []
        for fut in as_completed(futures):
            rec = fut.result()
            records.append(rec)
            progress(rec)
        return records
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def batch(inputs: Iterable[str], outdir: str, method: str = "box", knobs: dict | None = None,
          devices: list | None = None, png: bool = False, references: str | None = None,
          workers: int | None = None, scheduler: str | None = None, resume: bool = True,
          progress: Callable[[dict], None] | None = None) -> dict:
    """Reconstruct every input into ``outdir``; returns (and writes) the summary.

    ``devices``: the devices to use locally (``clrecon.core.device.get_device`` specs or
    ``Device`` objects; default: the default device). ``workers``/``scheduler``: run on Dask
    instead. ``progress(record)`` is called once per finished frame.
    """
    knobs = dict(knobs or {})
    if method not in METHODS:
        raise ValueError(f"--method: unknown {method!r}; available: {sorted(METHODS)}")
    if workers is not None and (isinstance(workers, bool) or int(workers) < 1):
        raise ValueError(f"--workers: must be >= 1, got {workers!r}")
    jobs = make_jobs(inputs, outdir, png, references)
    Path(outdir).mkdir(parents=True, exist_ok=True)
    progress = progress or (lambda rec: None)
    skipped = [j for j in jobs if resume and j.done()]
    todo = [j for j in jobs if j not in skipped]
    t0 = time.perf_counter()
    if scheduler is not None or workers is not None:
        records = _run_dask(todo, method, knobs, scheduler, workers, progress)
    else:
        devs = [get_device(d) for d in (devices or [None])]
        records = _run_local(todo, method, knobs, devs, progress)
    previous = _previous_records(Path(outdir) / "summary.json")
    for j in skipped:
        rec = previous.get(j.name, {"frame": j.name, "input": j.input, "output": j.output})
        records.append(rec | {"skipped": True})
        progress(records[-1])
    order = {j.name: k for k, j in enumerate(jobs)}
    records.sort(key=lambda r: order.get(r["frame"], len(order)))
    summary = {"method": method, "knobs": knobs, "frames": records,
               "failed": [r["frame"] for r in records if "error" in r],
               "skipped": [j.name for j in skipped], "wall_s": time.perf_counter() - t0,
               "jobs": [asdict(j) for j in jobs]}
    _write_json(Path(outdir) / "summary.json", summary)
    return summary


def _previous_records(path: Path) -> dict:
    try:
        return {r["frame"]: r for r in json.loads(path.read_text())["frames"]
                if "error" not in r}
    except (OSError, ValueError, KeyError, TypeError):
        return {}


def _write_json(path: Path, data: dict) -> None:
    write_atomic(path, json.dumps(data, indent=1, default=str).encode())
