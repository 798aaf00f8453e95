"""Sequences and batches: animated scenes, `batch` locally and on a Dask cluster, flicker."""
from __future__ import annotations

import json
import os
import signal

import numpy as np
import pytest
from conftest import assert_close, trusted_reference

import clrecon
from clrecon.batch import batch, make_jobs
from clrecon.io import load_image, save_image, save_samples
from clrecon.scenes import get_scene, render_samples
from clrecon.scenes.animate import frame_of, frame_seed
from clrecon.temporal import compare_sequences, flicker

W, H, S = 40, 32, 4


@pytest.fixture(scope="module")
def sequence(tmp_path_factory, device):
    """Four frames of the animated fence as .npz, and their references."""
    d = tmp_path_factory.mktemp("seq")
    (d / "in").mkdir()
    (d / "ref").mkdir()
    scene = get_scene("fence")
    for k in range(4):
        sk = frame_of(scene, k)
        buf = render_samples(sk, W, H, S, seed=frame_seed(0, k), device=device)
        save_samples(str(d / "in" / f"f{k:03d}.npz"), buf)
        save_image(str(d / "ref" / f"f{k:03d}.exr"),
                   trusted_reference(sk, W, H, 64, seed=1))
    return d


def test_animation_moves_objects_and_camera_continuously():
    scene = get_scene("fence")
    f0, f1, f2 = (frame_of(scene, k) for k in range(3))
    for a, b, c in zip(f0.objects, f1.objects, f2.objects):
        step = np.subtract(b.centre, a.centre)
        assert_close(np.subtract(c.centre, b.centre), step, what="constant per-frame motion")
        # the shutter spans the frame: the blur of a frame is its motion to the next
        assert_close(step, b.velocity, what="velocity = displacement per frame")
        assert np.any(step != 0), "the camera pans: every object moves on screen"
    with pytest.raises(ValueError, match="pan"):
        frame_of(scene, 1, pan=(0.0, 0.0, 0.1))
    assert frame_seed(0, 1) != frame_seed(0, 2)


def test_batch_writes_every_frame_resumes_and_reports(sequence, device, tmp_path):
    out = tmp_path / "out"
    seen = []
    summary = batch([str(sequence / "in" / "*.npz")], str(out), method="sweep",
                    devices=[device], png=True, references=str(sequence / "ref"),
                    progress=seen.append)
    assert [r["frame"] for r in summary["frames"]] == [f"f{k:03d}" for k in range(4)]
    assert len(seen) == 4 and summary["failed"] == [] and summary["skipped"] == []
    for rec in summary["frames"]:
        img = load_image(rec["output"])
        buf = clrecon.io.load_samples(rec["input"])
        assert_close(img, clrecon.reconstruct(buf, "sweep", device), rtol=0, atol=0,
                     what="batch frame = reconstruct")
        assert os.path.exists(rec["png"]) and rec["device"] == device.info.label
        assert rec["psnr"] > 20 and rec["device_ms"] > 0
    on_disk = json.loads((out / "summary.json").read_text())
    assert on_disk["frames"][0]["frame"] == "f000"
    assert not [p for p in os.listdir(out) if p.endswith(".tmp")]
    again = batch([str(sequence / "in" / "*.npz")], str(out), method="sweep",
                  devices=[device], png=True, references=str(sequence / "ref"))
    assert again["skipped"] == [f"f{k:03d}" for k in range(4)]
    assert again["frames"][1]["psnr"] == summary["frames"][1]["psnr"]  # carried over


def test_a_failed_frame_is_reported_and_the_others_complete(sequence, device, tmp_path):
    bad = tmp_path / "in"
    bad.mkdir()
    for k in range(2):
        os.link(sequence / "in" / f"f{k:03d}.npz", bad / f"f{k:03d}.npz")
    (bad / "broken.npz").write_bytes(b"PK\x03\x04 not a zip file")
    summary = batch([str(bad / "*.npz")], str(tmp_path / "out"), devices=[device])
    assert summary["failed"] == ["broken"]
    assert "error" in summary["frames"][0] and "broken.npz" in summary["frames"][0]["error"]
    assert all((tmp_path / "out" / f"f{k:03d}.exr").exists() for k in range(2))


def test_batch_refuses_bad_arguments(sequence, tmp_path):
    with pytest.raises(ValueError, match="matches no file"):
        make_jobs([str(tmp_path / "*.npz")], str(tmp_path))
    with pytest.raises(ValueError, match="unknown 'nosuch'"):
        batch([str(sequence / "in" / "*.npz")], str(tmp_path), method="nosuch")
    with pytest.raises(ValueError, match="would overwrite"):
        make_jobs([str(sequence / "ref" / "f000.exr")], str(sequence / "ref"))


def test_flicker_separates_steady_bias_from_frame_noise(rng):
    base = rng.uniform(0.2, 0.8, (8, 8, 3))
    ref = [base] * 4  # a still shot
    biased = [r + 0.05 for r in ref]  # the same error every frame: no flicker
    noisy = [r + rng.normal(0, 0.05, r.shape) for r in ref]
    assert flicker(biased, ref)["flicker_rmse"] < 1e-6
    assert flicker(noisy, ref)["flicker_rmse"] > 0.02
    out = compare_sequences(noisy, ref)
    assert len(out["frames"]) == 4 and out["temporal_psnr"] < 40
    with pytest.raises(ValueError, match="at least 2 frames"):
        flicker(ref[:1], ref[:1])


def _dask():
    return pytest.importorskip("distributed")


def test_dask_cluster_matches_local_and_survives_a_killed_worker(sequence, device, tmp_path):
    """A LocalCluster of 2 worker processes: every frame is written, bit-identical to the
    local run, although one worker is killed (SIGKILL) after the first frame finishes."""
    distributed = _dask()
    local = batch([str(sequence / "in" / "*.npz")], str(tmp_path / "local"), method="sweep",
                  devices=[device])
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                       dashboard_address=None)
    client = distributed.Client(cluster)
    try:
        pids = client.run(os.getpid)
        killed = []

        def kill_one(rec):
            if not killed:
                pid = next(iter(pids.values()))
                os.kill(pid, signal.SIGKILL)
                killed.append(pid)

        env = {"CLRECON_DEVICE": str(device.info.index)}
        client.run(os.environ.update, env)
        farm = batch([str(sequence / "in" / "*.npz")], str(tmp_path / "farm"),
                     method="sweep", scheduler=cluster.scheduler_address, progress=kill_one)
    finally:
        client.close()
        cluster.close()
    assert killed and farm["failed"] == []
    assert len(farm["frames"]) == 4
    for a, b in zip(local["frames"], farm["frames"]):
        assert a["frame"] == b["frame"]
        assert_close(load_image(b["output"]), load_image(a["output"]), rtol=0, atol=0,
                     what=f"farm {b['frame']}")
