"""The command line end to end, in-process (``clrecon.cli.main``)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from clrecon.cli import main
from clrecon.io import load_image, load_samples


def test_devices_lists_every_device(capsys):
    assert main(["devices"]) == 0
    out = capsys.readouterr().out
    assert "[0]" in out and "compute units" in out and "atomics" in out
    assert main(["devices", "--json"]) == 0
    devs = json.loads(capsys.readouterr().out)
    assert devs[0]["index"] == 0 and "atomics" in devs[0]


def test_scene_reference_reconstruct_json(tmp_path, capsys):
    f, ref, out = tmp_path / "f.bin", tmp_path / "ref.exr", tmp_path / "f.exr"
    assert main(["scene", "fence", "--size", "64x48", "--spp", "4", "-o", str(f)]) == 0
    assert (tmp_path / "f.bin.header").is_file()
    assert load_samples(f).shape == (48, 64, 4)
    assert main(["reference", "fence", "--size", "64x48", "--spp", "64", "-o", str(ref)]) == 0
    capsys.readouterr()
    assert main(["reconstruct", str(f), "--method", "box", "-o", str(out), "--reference",
                 str(ref), "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["method"] == "box" and rep["spp"] == 4 and rep["size"] == [64, 48]
    assert rep["pass_ms"]["box"] >= 0
    q = rep["quality"]
    assert 15 < q["psnr"] < 60 and 0 < q["ssim"] <= 1 and 0 <= q["flip"] < 1
    img = load_image(out)
    assert img.shape == (48, 64, 3) and np.isfinite(img).all()
    assert main(["compare", str(out), str(ref), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["psnr"] == pytest.approx(q["psnr"])


def test_errors_exit_2_with_a_message(tmp_path, capsys):
    assert main(["scene", "nope", "-o", str(tmp_path / "x.npz")]) == 2
    assert "unknown 'nope'" in capsys.readouterr().err
    assert main(["reconstruct", str(tmp_path / "missing.bin"), "-o", str(tmp_path / "o.exr")]) == 2
    assert main(["scene", "empty", "--size", "8x8", "-o", str(tmp_path / "e.npz")]) == 0
    capsys.readouterr()
    assert main(["reconstruct", str(tmp_path / "e.npz"), "-o", str(tmp_path / "o.exr"),
                 "--method", "bogus"]) == 2
    assert "unknown 'bogus'" in capsys.readouterr().err


def test_demo_writes_images(tmp_path, capsys):
    assert main(["demo", "--scene", "spheres", "--size", "48x32", "--ref-spp", "64", "-o",
                 str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "PSNR" in out and "M samples/s" in out
    assert "box" in out and "sweep" in out and "splat+guided" in out
    assert "with the guided refinement" in out
    assert "splat+guided+nlm" in out and "then non-local means on each half" in out
    for name in ("spheres_reference.png", "spheres_box.png", "spheres_box.exr",
                 "spheres_sweep.png", "spheres_splat+guided.png",
                 "spheres_splat+guided+nlm.png"):
        assert (tmp_path / name).is_file()


def test_tlfr_from_another_tool_reconstructs(tmp_path, capsys):
    """A text TLFR file written the way the reference tool writes it (no Motion-model line,
    '%f' numbers, trailing commas) loads and reconstructs through the CLI."""
    w, h, s = 3, 2, 2
    rng = np.random.default_rng(3)
    colors = rng.uniform(0, 4, (h, w, s, 3))
    lines = []
    for y in range(h):
        for x in range(w):
            for i in range(s):
                r, g, b = colors[y, x, i]
                rec = [x + 0.25 + 0.5 * i, y + 0.5, 0.5, 4.0, 0.3, -0.2, 0.25 + 0.5 * i, r, g, b,
                       1.0, 0.8, 0.0, 0.0, 0.0, 0.0]
                lines.append(",".join(f"{v:f}" for v in rec) + ",")
    data = tmp_path / "other.txt"
    data.write_text("\n".join(lines) + "\n")
    (tmp_path / "other.txt.header").write_text(
        f"Version 1.3\nWidth {w}\nHeight {h}\nSamples per pixel {s}\n"
        "CoC coefficients (coc radius = C0/w+C1): -2.000000,1.000000\nEncoding = text\n")
    out = tmp_path / "o.exr"
    assert main(["reconstruct", str(data), "-o", str(out), "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["spp"] == s and rep["size"] == [w, h]
    want = np.round(colors, 6).mean(axis=2)  # '%f' keeps six decimals
    np.testing.assert_allclose(load_image(out), want, rtol=1e-5, atol=1e-6)
    buf = load_samples(data)
    np.testing.assert_allclose(buf.motion[..., 0], 0.8 / 4.0, rtol=1e-6)


def test_reconstruct_sweep_flags(tmp_path, capsys):
    f = tmp_path / "s.npz"
    assert main(["scene", "spheres", "--size", "40x32", "--spp", "4", "-o", str(f)]) == 0
    capsys.readouterr()
    for flags, mode in ((["--scales", "4"], "4-scale"), (["--dof-layers"], "dof_layers"),
                        (["--sort", "block", "--group", "2"], "2-scale"),
                        (["--exponent", "1.3", "--sort", "pixel"], "2-scale")):
        assert main(["reconstruct", str(f), "--method", "sweep", "-o", str(tmp_path / "o.exr"),
                     "--json", *flags]) == 0
        rep = json.loads(capsys.readouterr().out)
        assert rep["mode"] == mode, flags
        if "--group" in flags:
            assert rep["sort"] == "block" and rep["group"] == 2
    assert rep["exponent"] == 1.3 and rep["sort"] == "pixel"
    assert main(["reconstruct", str(f), "-o", str(tmp_path / "o.exr"), "--scales", "4"]) == 2
    assert "unknown knobs" in capsys.readouterr().err  # box takes no scales
