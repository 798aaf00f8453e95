"""The sequence commands end to end: `scene`/`reference --frames`, `batch`, `compare` of two
sequences, and `trade`/`table` on the user's own frames."""
from __future__ import annotations

import json

from clrecon.cli import main


def test_sequence_batch_compare_and_trade_on_user_frames(device, tmp_path, capsys):
    dev = ["--device", str(device.info.index)]
    seq, refs, out = tmp_path / "seq", tmp_path / "refs", tmp_path / "out"
    assert main(["scene", "fence", "--size", "24x16", "--spp", "2", "--frames", "3",
                 "-o", str(seq), *dev]) == 0
    assert sorted(p.name for p in seq.iterdir()) == [f"fence_000{k}.npz" for k in range(3)]
    assert main(["reference", "fence", "--size", "24x16", "--spp", "16", "--frames", "3",
                 "-o", str(refs), *dev]) == 0
    assert main(["batch", str(seq / "*.npz"), "-o", str(out), "--method", "sweep", "--png",
                 "--references", str(refs), "--devices", str(device.info.index)]) == 0
    printed = capsys.readouterr().out
    assert "3 frames reconstructed, 0 already done, 0 failed" in printed
    assert "mean PSNR" in printed
    summary = json.loads((out / "summary.json").read_text())
    assert [r["frame"] for r in summary["frames"]] == [f"fence_000{k}" for k in range(3)]
    assert all((out / f"fence_000{k}.png").exists() for k in range(3))
    assert main(["batch", str(seq / "*.npz"), "-o", str(out), "--method", "sweep"]) == 0
    assert "0 frames reconstructed, 3 already done" in capsys.readouterr().out
    assert main(["compare", str(out), str(refs)]) == 0
    printed = capsys.readouterr().out
    assert "fence_0002: PSNR" in printed and "flicker" in printed
    (seq / "fence_0009.npz").write_bytes(b"not a zip")
    assert main(["batch", str(seq / "*.npz"), "-o", str(out)]) == 1
    assert "frame fence_0009 failed" in capsys.readouterr().err
    assert main(["trade", "--input", str(seq / "fence_0001.npz"), "--reference",
                 str(refs / "fence_0001.exr"), "--methods", "sweep", "--no-oidn",
                 "--repeats", "1", "-o", str(tmp_path / "trade"), *dev]) == 0
    assert "### fence_0001" in (tmp_path / "trade" / "trade.md").read_text()
    assert main(["table", "--input", str(seq / "fence_0001.npz"), "--reference",
                 str(refs / "fence_0001.exr"), "--variant", "box", "--repeats", "1",
                 "-o", str(tmp_path / "table"), *dev]) == 0
    rows = json.loads((tmp_path / "table" / "methods.json").read_text())["rows"]
    assert [r["scene"] for r in rows] == ["fence_0001"] and rows[0]["spp"] == 2
    capsys.readouterr()
    assert main(["trade", "--input", str(seq / "fence_0001.npz"), "-o", str(tmp_path)]) == 2
    assert "one --reference per --input" in capsys.readouterr().err
