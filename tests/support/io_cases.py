"""Helpers shared by the io tests: ``tests/unit/test_io*.py`` (buffers, hand-written TLFR),
``tests/extremes/test_io_limits*.py`` (small frames, memory-limited children, raw ``.npy``)
and ``tests/extremes/test_fuzz_io*.py`` (the fuzzing harness: the base frame, byte-level
mutations, and the child process that runs a format's cases).
"""
from __future__ import annotations

import io as _io
import json
import os
import random
import re
import subprocess
import sys
import textwrap
import zipfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from clrecon.core.camera import CocModel
from clrecon.core.samples import FIELDS, SampleBuffer
from clrecon.io import EXR_SAMPLE_CHANNELS

ROOT = Path(__file__).resolve().parents[2]
SUPPORT = Path(__file__).resolve().parent


# ==========================================================================================
# buffers and TLFR files written by hand
# ==========================================================================================
H, W, S = 5, 7, 4
COC = CocModel(c0=-15.242497123456789, c1=19.053122987654321)  # not float32-representable
TLFR_FIELD_LINE = "x,y,z/w,w,u,v,t,r,g,b,a,mv_x,mv_y,mv_w,dwdx,dwdy"


def make_buffer(h=H, w=W, s=S, seed=0, coc=COC) -> SampleBuffer:
    """A random but valid buffer: HDR colour, misses with inf depth, motion in pixels."""
    rng = np.random.default_rng(seed)
    hws = (h, w, s)
    py, px = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    pos = np.stack([px, py], -1)[:, :, None, :] + rng.uniform(0.0, 1.0, hws + (2,))
    r = np.sqrt(rng.uniform(0.0, 1.0, hws))
    phi = rng.uniform(0.0, 2 * np.pi, hws)
    lens = np.stack([r * np.cos(phi), r * np.sin(phi)], -1)
    depth = np.exp(rng.uniform(np.log(0.3), np.log(200.0), hws))
    miss = rng.uniform(size=hws) < 0.2
    depth[miss] = np.inf
    color = rng.uniform(0.0, 1.0, hws + (3,)) * 10.0 ** rng.uniform(-3, 4, hws + (1,))
    motion = rng.normal(0.0, 6.0, hws + (2,))
    motion[miss] = 0.0  # TLFR stores no motion for misses
    buf = SampleBuffer(color=color, position=pos, depth=depth, lens=lens,
                       time=rng.uniform(0.0, 1.0, hws), motion=motion, coc_model=coc)
    assert np.isinf(buf.depth).any() and buf.color.max() > 1e3
    return buf.validate()


def write_tlfr(path: Path, records: np.ndarray, w: int, h: int, s: int, *, c0=-2.0, c1=1.0,
               encoding="binary", header_lines=None) -> None:
    """Write a TLFR 1.3 pair by hand, as another tool would (independent of clrecon.io)."""
    if header_lines is None:
        header_lines = [
            "Version 1.3", f"Width {w}", f"Height {h}", f"Samples per pixel {s}",
            "Motion model: perspective",
            f"CoC coefficients (coc radius = C0/w+C1): {c0:f},{c1:f}",
            f"Encoding = {encoding}", TLFR_FIELD_LINE,
        ]
    Path(str(path) + ".header").write_text("\n".join(header_lines) + "\n")
    records = np.asarray(records, np.float32).reshape(-1, 16)
    if encoding == "binary":
        Path(path).write_bytes(records.astype("<f4").tobytes())
    else:  # the reference writer: "%f," for every value, including the last
        Path(path).write_text("".join(", ".join(f"{v:f}" for v in rec) + ",\n"
                                      for rec in records))


def default_records(w: int, h: int, s: int) -> np.ndarray:
    """Valid static records at pixel centres: (h, w, s, 16)."""
    rec = np.zeros((h, w, s, 16), np.float32)
    py, px = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    rec[..., 0] = (px + 0.5)[:, :, None]
    rec[..., 1] = (py + 0.5)[:, :, None]
    rec[..., 2] = 0.5
    rec[..., 3] = 2.0
    rec[..., 6] = 0.5
    rec[..., 7:11] = 0.25
    return rec


def assert_same(a: SampleBuffer, b: SampleBuffer, *, motion_ulp: int = 0) -> None:
    assert a.coc_model == b.coc_model
    for name in FIELDS:
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype == np.float32 and x.shape == y.shape, name
        if name == "motion" and motion_ulp:
            np.testing.assert_array_max_ulp(x, y, maxulp=motion_ulp)
        else:
            np.testing.assert_array_equal(x, y, err_msg=name)


# ==========================================================================================
# limits: small frames, children under RLIMIT_AS, raw .npy members
# ==========================================================================================
def small_buffer(h=3, w=4, s=2, seed=0) -> SampleBuffer:
    """A small valid frame with motion and one miss."""
    rng = np.random.default_rng(seed)
    buf = SampleBuffer.zeros(h, w, s, CocModel(-2.0, 1.0))
    buf.color[:] = rng.uniform(0, 4, buf.color.shape)
    buf.depth[:] = rng.uniform(0.5, 50, buf.depth.shape)
    buf.depth[0, 0, 0] = np.inf
    buf.motion[:] = rng.normal(0, 2, buf.motion.shape)
    buf.motion[0, 0, 0] = 0.0
    buf.time[:] = rng.uniform(0, 1, buf.time.shape)
    return buf.validate()


def run_limited(body: str, budget_mb: int = 200, timeout: float = 120) -> str:
    """Run ``body`` in a child whose address space may grow ``budget_mb`` beyond what its
    imports took; return its stdout (the body prints one result line)."""
    prelude = textwrap.dedent(f"""
        import re, resource, sys
        import numpy as np
        import OpenImageIO as oiio
        import clrecon.io as cio
        oiio.attribute("threads", 1)
        oiio.attribute("exr_threads", 1)
        status = open("/proc/self/status").read()
        vm = int(re.search(r"VmSize:\\s+(\\d+)", status).group(1)) * 1024
        limit = vm + {budget_mb} * 2**20
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
        def report(fn):
            try:
                fn()
            except BaseException as exc:  # the parent judges the type
                print(f"{{type(exc).__name__}}|{{exc}}")
            else:
                print("loaded|")
        """)
    proc = subprocess.run([sys.executable, "-c", prelude + textwrap.dedent(body)],
                          capture_output=True, text=True, timeout=timeout, env=child_env())
    assert proc.returncode == 0, f"child died ({proc.returncode}): {proc.stderr[-2000:]}"
    return proc.stdout.strip().splitlines()[-1]


def npy_bytes(arr: np.ndarray) -> bytes:
    """``arr`` as the bytes of a ``.npy`` file (objects allowed: hostile members)."""
    f = _io.BytesIO()
    np.lib.format.write_array(f, np.asanyarray(arr), allow_pickle=True)
    return f.getvalue()


def child_env() -> dict[str, str]:
    """The environment of a child under a memory limit: few malloc arenas and threads, and
    this checkout first on the import path."""
    env = dict(os.environ, MALLOC_ARENA_MAX="2", OMP_NUM_THREADS="1")
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")])
    return env


def exr_channels(spp: int) -> list[str]:
    return [f"s{i}.{c}" for i in range(spp) for c in EXR_SAMPLE_CHANNELS]


# ==========================================================================================
# fuzzing: the base frame, byte-level mutations, the child that runs the cases
# ==========================================================================================
SEED = 20240611
#: cases per format (fixed: the seed decides what each case does, not how many there are)
CASES = {"bin": 300, "txt": 300, "exr": 250, "npz": 300}
#: address space a child may add to what its imports took
CHILD_BUDGET = 2 * 2**30
CHILD_TIMEOUT = 150

SPECIAL_NUMBERS = ["0", "-1", "1", "2", "2147483647", "2147483648", "4294967297",
                   "99999999999999999999999", "1e30", "1e39", "1e400", "-1e39", "nan", "inf",
                   "-inf", "abc", "", "2.5", "1_0", "0x10", " 3 ", "+4", "--1", "1e", "."]
SPECIAL_FLOATS = [np.nan, np.inf, -np.inf, 0.0, -0.0, -1.0, 1e-45, 1e38, 3.4e38, 1e30, 2.0,
                  0.5, 1e-38, 7.0]


def base_buffer():
    rng = np.random.default_rng(SEED)
    h, w, s = 6, 8, 2
    buf = SampleBuffer.zeros(h, w, s, CocModel(-4.0, 2.0))
    hws = (h, w, s)
    buf.position[:] += rng.uniform(-0.45, 0.45, buf.position.shape)
    r = np.sqrt(rng.uniform(0, 1, hws))
    a = rng.uniform(0, 2 * np.pi, hws)
    buf.lens[:] = np.stack([r * np.cos(a), r * np.sin(a)], -1)
    buf.time[:] = rng.uniform(0, 1, hws)
    buf.depth[:] = rng.uniform(1.0, 30.0, hws)
    miss = rng.uniform(size=hws) < 0.2
    buf.depth[miss] = np.inf
    buf.color[:] = rng.exponential(1.0, buf.color.shape)
    buf.motion[:] = np.where(miss[..., None], 0.0, rng.normal(0, 1.5, buf.motion.shape))
    return buf.validate()


def mutate_bytes(data: bytes, rng: random.Random, region: int | None = None) -> tuple[bytes, str]:
    """One random byte-level edit; ``region`` limits positions to the first bytes."""
    b = bytearray(data)
    top = max(1, min(len(b), region or len(b)))
    kind = rng.choice(["flip", "flip", "set", "truncate", "extend", "insert", "delete", "run"])
    if kind == "flip":
        for _ in range(rng.randint(1, 4)):
            b[rng.randrange(top)] ^= 1 << rng.randrange(8)
    elif kind == "set":
        for _ in range(rng.randint(1, 3)):
            b[rng.randrange(top)] = rng.randrange(256)
    elif kind == "truncate":
        b = b[:rng.randrange(len(b))]
    elif kind == "extend":
        tail = rng.choice([bytes(rng.randint(1, 64)), rng.randbytes(rng.randint(1, 64)),
                           bytes(b[:rng.randint(1, 200)])])
        b += tail
    elif kind == "insert":
        pos = rng.randrange(top)
        b[pos:pos] = rng.randbytes(rng.randint(1, 16))
    elif kind == "delete":
        pos = rng.randrange(top)
        del b[pos:pos + rng.randint(1, 16)]
    else:
        pos = rng.randrange(top)
        n = rng.randint(1, 16)
        b[pos:pos + n] = bytes([rng.choice([0, 0xFF, ord("9"), ord("-")])]) * n
    return bytes(b), kind


def base_files(folder: Path) -> dict:
    """The unmutated files of every format (and a deflated copy of the ``.npz``)."""
    from clrecon.io import save_samples

    buf = base_buffer()
    base = {"buffer": buf}
    for ext in ("bin", "txt", "exr", "npz"):
        path = folder / f"base.{ext}"
        save_samples(path, buf)
        if ext in ("bin", "txt"):
            base[ext] = {"data": path.read_bytes(),
                         "header": Path(str(path) + ".header").read_text()}
        else:
            base[ext] = path.read_bytes()
    with zipfile.ZipFile(_io.BytesIO(base["npz"])) as zin:
        out = _io.BytesIO()
        with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as zout:
            for info in zin.infolist():
                zout.writestr(info.filename, zin.read(info))
    base["npz_deflated"] = out.getvalue()
    return base


def case_rng(fmt: str, k: int) -> random.Random:
    """The random source of case ``k`` of ``fmt``, its own (any case can be rebuilt alone)."""
    return random.Random(f"{SEED}/{fmt}/{k}")


#: a format's ``build_case(fmt, k, folder, base)``: write case ``k`` of ``fmt`` into
#: ``folder``; return the path to load and a label
Builder = Callable[[str, int, Path, dict], tuple[Path, str]]


#: what validate() messages start with (they name the field, not the file)
_FIELD_MESSAGE = re.compile(r"^(color|position|depth|lens|time|motion|coc|coc_model)\b")


def names_its_subject(message: str, path: Path) -> bool:
    """A refusal names the file it read (or, from validate(), the field)."""
    return str(path) in message or bool(_FIELD_MESSAGE.match(message))


def _note(f, text: str) -> None:
    """Leave ``text`` (the running case) in the progress file, for a crash report."""
    f.seek(0)
    f.write(text[:300])
    f.truncate()
    f.flush()


def run_cases(fmt: str, folder: str, progress: str, build_case: Builder) -> dict:
    """Run every case of ``fmt``; return counts and failures (the child's entry point)."""
    import shutil
    import traceback
    import warnings

    from clrecon.core.errors import ClreconError
    from clrecon.io import load_samples

    warnings.simplefilter("ignore")
    work = Path(folder)
    base = base_files(work)
    counts = {"loaded": 0, "refused": 0}
    failures = []
    with open(progress, "w") as prog:
        for k in range(CASES[fmt]):
            case_dir = work / f"case{k}"
            case_dir.mkdir()
            label = "?"
            _note(prog, f"{fmt}#{k} (building)")
            try:
                path, label = build_case(fmt, k, case_dir, base)
            except Exception as exc:  # a bug of the test module, not of the loader
                failures.append(f"{fmt}#{k}: building the case failed: {exc!r}")
                continue
            _note(prog, f"{fmt}#{k} ({label})")
            try:
                load_samples(path).validate()
                counts["loaded"] += 1
            except ClreconError:
                counts["refused"] += 1
            except ValueError as exc:
                counts["refused"] += 1
                if not names_its_subject(str(exc), path):
                    failures.append(f"{fmt}#{k} ({label}): ValueError naming neither the file "
                                    f"nor a field: {exc}"[:600])
            except BaseException as exc:  # everything else is a failure of the loader
                failures.append(f"{fmt}#{k} ({label}): {type(exc).__name__}: {exc}"[:600]
                                + "\n" + "".join(traceback.format_tb(exc.__traceback__)[-2:]))
            shutil.rmtree(case_dir, ignore_errors=True)
    return {"counts": counts, "failures": failures, "cases": CASES[fmt]}


CHILD = textwrap.dedent("""
    import json, os, re, resource, signal, sys
    sys.path[:0] = [{tests!r}, {support!r}]
    import numpy, OpenImageIO as oiio, clrecon.io, io_cases, {module} as fuzz
    oiio.attribute("threads", 1)
    oiio.attribute("exr_threads", 1)
    oiio.attribute("limits:imagesize_MB", 1024)
    vm = int(re.search(r"VmSize:\\s+(\\d+)", open("/proc/self/status").read()).group(1))
    limit = vm * 1024 + {budget}
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    if {crash_at}:  # test of the guard itself: the loader dies in that case
        real, calls = clrecon.io.load_samples, []
        def load(path):
            calls.append(path)
            if len(calls) == {crash_at}:
                os.kill(os.getpid(), signal.SIGSEGV)
            return real(path)
        clrecon.io.load_samples = load
    result = io_cases.run_cases({fmt!r}, {folder!r}, {progress!r}, fuzz.build_case)
    with open({out!r}, "w") as f:
        json.dump(result, f)
""")


def run_child(tmp_path: Path, test_file: str, fmt: str, crash_at: int = 0) -> dict:
    """Run the cases of ``fmt`` (built by ``build_case`` of ``test_file``, a test module's
    ``__file__``) in a child; fail with the running case's id if it dies."""
    work, progress, out = tmp_path / "work", tmp_path / "progress", tmp_path / "result.json"
    work.mkdir()
    test_file = Path(test_file)
    code = CHILD.format(tests=str(test_file.parent), support=str(SUPPORT), module=test_file.stem,
                        budget=CHILD_BUDGET, fmt=fmt, folder=str(work), progress=str(progress),
                        out=str(out), crash_at=crash_at)
    try:
        proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                              timeout=CHILD_TIMEOUT, env=child_env())
    except subprocess.TimeoutExpired:
        pytest.fail(f"{fmt}: timed out after {CHILD_TIMEOUT} s in case "
                    f"{progress.read_text().strip() if progress.exists() else '?'}")
    running = progress.read_text().strip() if progress.exists() else "(before the first case)"
    assert proc.returncode == 0 and out.exists(), (
        f"{fmt}: child died with {proc.returncode} in case {running}\n{proc.stderr[-3000:]}")
    return json.loads(out.read_text())



def assert_fuzz_outcomes(result: dict, fmt: str) -> None:
    """What a format's fuzzing must show: no failure, every case an outcome, both reached."""
    assert not result["failures"], "\n".join(result["failures"][:10])
    counts = result["counts"]
    assert counts["loaded"] + counts["refused"] == CASES[fmt]
    # the cases reach both outcomes: the fuzzing is neither all noise nor all harmless
    assert counts["refused"] >= CASES[fmt] // 5 and counts["loaded"] >= CASES[fmt] // 50, counts
