"""``clrecon converge``: the bias/variance split against NumPy on images whose answer is
known, the settings list (defaults, the safeguard axis, trade settings that are the default
spelled out), a tiny end-to-end study, its resume cache, and bad options."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from clrecon.bench import convergence as cv
from clrecon.bench.trade import TRADES
from clrecon.cli import main
from clrecon.core import device as cldev
from clrecon.core.errors import DeviceError
from clrecon.core.resources import code_digest

# -- the measure ------------------------------------------------------------------------------

def test_bias_variance_on_known_images(rng):
    """Reference 0, images b + noise of variance s^2: bias^2 -> mean(b^2), variance -> s^2.
    The noise is large against the bias, so the uncorrected mean-image error (b^2 + s^2/n)
    would be three times the answer."""
    n, h, w = 4, 128, 128
    b = rng.uniform(0.05, 0.15, (h, w, 3))
    sigma = 0.3
    images = b + rng.normal(0.0, sigma, (n, h, w, 3))
    ref = np.zeros((h, w, 3))
    got = cv.bias_variance(images.astype(np.float32), ref)
    # the same numbers computed directly
    m = images.mean(axis=0)
    s2 = images.var(axis=0, ddof=1)
    assert got["variance"] == pytest.approx(s2.mean(), rel=1e-6)
    assert got["bias2"] == pytest.approx(((m - ref) ** 2).mean() - s2.mean() / n, rel=1e-5)
    assert got["mse"] == pytest.approx(((images - ref) ** 2).mean(), rel=1e-6)
    assert got["mse"] == pytest.approx(got["bias2"] + got["variance"], rel=1e-9)
    # and against the truth
    assert got["variance"] == pytest.approx(sigma ** 2, rel=0.05)
    assert got["bias2"] == pytest.approx((b ** 2).mean(), rel=0.08)
    assert abs(got["bias2"] - (b ** 2).mean()) < 4 * got["bias2_se"]
    assert ((m - ref) ** 2).mean() > 2.5 * (b ** 2).mean(), "the correction must matter here"
    assert got["bias_share"] == pytest.approx(got["bias2"] / got["mse"])
    assert len(got["mse_seed"]) == n


def test_bias_variance_of_an_unbiased_estimator(rng):
    ref = rng.uniform(0, 2, (48, 48, 3))
    images = ref + rng.normal(0.0, 0.2, (3, 48, 48, 3))
    got = cv.bias_variance(images, ref)
    assert abs(got["bias2"]) < 4 * got["bias2_se"]
    assert got["bias2_se"] < 0.01 * got["variance"]
    assert got["variance"] == pytest.approx(0.04, rel=0.05)


def test_bias_variance_rejects_bad_input():
    with pytest.raises(ValueError, match="at least 2"):
        cv.bias_variance(np.zeros((1, 4, 4, 3)), np.zeros((4, 4, 3)))
    with pytest.raises(ValueError, match="expected"):
        cv.bias_variance(np.zeros((2, 4, 4, 3)), np.zeros((4, 5, 3)))


def test_reference_noise(rng):
    truth = rng.uniform(0, 1, (64, 64, 3))
    a = truth + rng.normal(0, 0.05, truth.shape)
    b = truth + rng.normal(0, 0.05, truth.shape)
    assert cv.reference_noise(a, b) == pytest.approx(0.05 ** 2, rel=0.05)


def test_sample_seeds_are_independent_of_each_other_and_of_the_references():
    seeds = [cv.sample_seed(i, spp) for i in range(8) for spp in (1, 2, 4, 64, 128, 999)]
    assert len(set(seeds)) == len(seeds)
    assert not set(seeds) & set(cv.REFERENCE_SEEDS)


# -- settings ---------------------------------------------------------------------------------

class FakeProbe:
    """Knob support and defaults without a device: ``takes`` says whether the methods take
    ``safeguard``; the defaults are the library's (sweep 2 scales, layered sheared, splat
    f7, the safeguard on)."""

    DEFAULTS = {"scales": 2, "filter": "sheared", "pyramid": "f7", "safeguard": True,
                "layers": 4, "dense": False}

    def __init__(self, safeguard: bool):
        self.safeguard = safeguard

    def takes(self, method, knob, value):
        return knob == "safeguard" and self.safeguard

    def is_default(self, method, knob, value):
        return knob in self.DEFAULTS and self.DEFAULTS[knob] == value


@pytest.mark.parametrize("safeguard", [False, True])
def test_study_settings(safeguard):
    probe = FakeProbe(safeguard)
    got = cv.study_settings(probe=probe)
    labels = [s.label for s in got]
    assert labels[0] == "box" and got[0].kind == "box"
    assert len(set(s.key for s in got)) == len(got), "no reconstruction twice"
    for m in ("sweep", "layered", "splat"):
        defaults = [s for s in got if s.kind == "default" and s.method == m]
        if safeguard:  # the default at both values, the paper's method is safeguard=False
            assert [(s.label, s.knobs) for s in defaults] == [
                (f"{m} +safeguard", {"safeguard": True}),
                (f"{m} -safeguard", {"safeguard": False})]
        else:
            assert [(s.label, s.knobs) for s in defaults] == [(m, {})]
        trades = [s.label for s in got if s.kind == "trade" and s.method == m]
        assert set(trades) <= {lab for lab, _ in TRADES[m]}
    if safeguard:  # the default spelled out (TRADES: safeguard=False, the paper's method)
        assert "sweep 2-scale" not in labels and "layered sheared" not in labels
        assert "splat +safeguard" in labels and "splat" not in labels
    assert "sweep 4-scale" in labels and "layered mip" in labels
    box_only = cv.study_settings(methods=["sweep"], settings=["sweep"], probe=probe)
    assert [s.method for s in box_only][0] == "box"
    assert {s.kind for s in box_only} == {"box", "default"}
    with pytest.raises(ValueError, match="unknown \\['nope'\\]; available"):
        cv.study_settings(settings=["nope"], probe=probe)
    with pytest.raises(ValueError, match="methods: unknown 'nope'"):
        cv.study_settings(methods=["nope"], probe=probe)


def test_ablation_settings_run_the_method_alone():
    abl = cv.ablation_settings(["layered"], probe=FakeProbe(True))
    base = abl[0]
    assert base.label == "layered -safeguard" and base.knobs == {"safeguard": False}
    assert [s.label for s in abl[1:]] == [f"layered {lab}" for lab, _, _ in
                                          cv.ABLATIONS["layered"]]
    for s in abl[1:]:
        assert s.base == base.label and s.knobs["safeguard"] is False and s.source


def test_blur_scenes():
    names = cv.blur_scenes()
    assert "fence" in names and "huge_coc" in names
    assert "static_focus" not in names and "empty" not in names


# -- the study ----------------------------------------------------------------------------------

def _trusted():
    try:
        cldev.trusted_device()
    except DeviceError as exc:
        pytest.skip(f"references come from the trusted device: {exc}")


def _study(device, out, **kw):
    return cv.converge(["fence"], methods=["sweep"], settings=["sweep"], spps=(2, 4),
                       size=(24, 16), seeds=2, out_dir=out, ref_spp=16, ablation_spp=0,
                       device=device, **kw)


def test_converge_end_to_end_and_resume(device, tmp_path, monkeypatch):
    _trusted()
    lines = []
    rep = _study(device, tmp_path, status=lines.append, keep_images=True)
    errors = [r["error"] for r in rep["rows"] if "error" in r]
    assert not errors
    settings = [s["label"] for s in rep["settings"]]
    assert settings[0] == "box" and len(settings) >= 2
    assert len(rep["rows"]) == 2 * len(settings)
    for r in rep["rows"]:
        assert r["mse"] == pytest.approx(r["bias2"] + r["variance"], rel=1e-9)
        assert r["seeds"] == [cv.sample_seed(i, r["spp"]) for i in range(2)]
        assert math.isfinite(r["psnr_median"]) and len(r["psnr_seed"]) == 2
    assert rep["references"]["fence"]["noise_var"] > 0
    assert any("seed 2/2" in ln for ln in lines) and "left" in lines[-1]

    # box's row is the NumPy split of the per-pixel means of the same samples
    from clrecon.io import load_image
    from clrecon.scenes import get_scene, render_samples

    ref = load_image(tmp_path / "references" / "fence_24x16_16spp_seed1.exr")
    bufs = [render_samples(get_scene("fence"), 24, 16, 4, seed=cv.sample_seed(i, 4),
                           device=device) for i in range(2)]
    want = cv.bias_variance(np.stack([b.color.mean(axis=2) for b in bufs]), ref)
    box = next(r for r in rep["rows"] if r["setting"] == "box" and r["spp"] == 4)
    assert box["mse"] == pytest.approx(want["mse"], rel=1e-4)
    assert box["variance"] == pytest.approx(want["variance"], rel=1e-4)

    saved = json.loads((tmp_path / "convergence.json").read_text())
    assert len(saved["rows"]) == len(rep["rows"])
    md = (tmp_path / "convergence.md").read_text()
    assert "### fence" in md and "fence_convergence.png" in md and "noise variance" in md
    assert (tmp_path / "fence_convergence.png").stat().st_size > 1000

    # a re-run reads every number from the cache: no sample buffer of the study is rendered
    # (the probe's small frames are) and nothing is reconstructed
    def refuse(*a, **k):
        raise AssertionError("the cache should have served this")

    real_render = cv.render_samples

    def render(scene, w, h, *a, **k):
        if (w, h) == (24, 16):
            refuse()
        return real_render(scene, w, h, *a, **k)

    monkeypatch.setattr(cv, "render_samples", render)
    monkeypatch.setattr(cv, "run", refuse)
    monkeypatch.setattr(cv, "render_reference", refuse)
    again = _study(device, tmp_path)
    assert again["rows"] == rep["rows"]
    # a group without its summary is summarised again from the cached images
    cells = tmp_path / "cells" / code_digest() / "24x16" / "fence"
    summary = next(cells.glob("box-*/spp4_ref16.json"))
    summary.unlink()
    def numbers(rows):  # run_s: the wall time of runs, none when only summarised
        return [{k: v for k, v in r.items() if k != "run_s"} for r in rows]

    assert numbers(_study(device, tmp_path)["rows"]) == numbers(rep["rows"])
    assert summary.exists()
    # other code (a changed module or kernel: another digest) reuses nothing: it measures
    monkeypatch.setattr(cv, "code_digest", lambda: "0" * 16)
    with pytest.raises(AssertionError, match="the cache should have served this"):
        _study(device, tmp_path)


def test_code_digest_follows_the_code():
    """The digest covers the package's modules and the kernels, and is stable in a process."""
    from clrecon.core import resources
    d = code_digest()
    assert len(d) == 16 and int(d, 16) >= 0 and code_digest() == d
    resources.code_digest.cache_clear()
    assert resources.code_digest() == d  # the same files, the same digest


def test_converge_with_the_random_sampler(device, tmp_path):
    """``sampler="random"``: its cells apart from the lattice's, the sampler in the report,
    and box's row the NumPy split of the same independent samples."""
    _trusted()
    from clrecon.io import load_image
    from clrecon.scenes import get_scene, render_samples

    rep = _study(device, tmp_path, sampler="random")
    assert rep["config"]["sampler"] == "random"
    assert (tmp_path / "cells" / code_digest() / "24x16-random" / "fence").is_dir()
    assert not (tmp_path / "cells" / code_digest() / "24x16").exists()
    assert "samples: random" in (tmp_path / "convergence.md").read_text()
    ref = load_image(tmp_path / "references" / "fence_24x16_16spp_seed1.exr")
    bufs = [render_samples(get_scene("fence"), 24, 16, 4, seed=cv.sample_seed(i, 4),
                           device=device, sampler="random") for i in range(2)]
    want = cv.bias_variance(np.stack([b.color.mean(axis=2) for b in bufs]), ref)
    box = next(r for r in rep["rows"] if r["setting"] == "box" and r["spp"] == 4)
    assert box["mse"] == pytest.approx(want["mse"], rel=1e-4)


def test_converge_removes_summarised_images(device, tmp_path):
    _trusted()
    _study(device, tmp_path)
    cells = tmp_path / "cells" / code_digest() / "24x16" / "fence"
    summaries = list(cells.glob("*/spp*_ref16.json"))
    assert summaries
    for path in summaries:
        spp = path.name.split("_")[0]
        assert not list(path.parent.glob(f"{spp}_seed*.npy")), path


@pytest.mark.parametrize("kw, match", [
    ({"spps": [0, 4]}, "spp: need positive integers"),
    ({"spps": [4, 1000]}, "below 1000"),
    ({"seeds": 1}, "seeds: need an integer >= 2"),
    ({"scenes": ["nope"]}, "unknown 'nope'"),
    ({"size": (0, 8)}, "size: must be positive"),
    ({"ablation_spp": -1}, "ablation_spp"),
    ({"ref_spp": 0}, "ref_spp"),
    ({"sampler": "sobol"}, "sampler: one of"),
])
def test_converge_rejects_bad_options(tmp_path, kw, match):
    """Checked before any device work (no device is opened)."""
    args = {"scenes": ["fence"], "spps": (2, 4), "size": (8, 8), "seeds": 2,
            "out_dir": tmp_path} | kw
    with pytest.raises(ValueError, match=match):
        cv.converge(**args)
    assert not (tmp_path / "convergence.json").exists()


def test_converge_cli_rejects_bad_options(tmp_path, capsys):
    assert main(["converge", "--seeds", "1", "-o", str(tmp_path)]) == 2
    assert "seeds" in capsys.readouterr().err
    assert main(["converge", "--methods", "nope", "-o", str(tmp_path)]) == 2
    assert "nope" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["converge", "--size", "0", "-o", str(tmp_path)])
    assert "size must be positive" in capsys.readouterr().err


def test_converge_cli_parses_spp_and_size():
    from clrecon.cli import build_parser

    p = build_parser()
    args = p.parse_args(["converge", "--spp", "4", "8", "--size", "128"])
    assert args.spp == [4, 8] and args.size == (128, 128)
    assert p.parse_args(["converge", "--size", "64x32"]).size == (64, 32)
    assert p.parse_args(["converge"]).spp == list(cv.DEFAULT_SPPS)


def test_summarize():
    """Box falls like 1/spp; a biased setting gains 31%, 23%, 15%, 9% per doubling: flat
    from 16 spp, and box is better from 32 spp."""
    rows = []
    for spp in (4, 8, 16, 32, 64):
        rows.append({"setting": "box", "spp": spp, "mse": 1.0 / spp, "bias_share": 0.0})
        rows.append({"setting": "m", "spp": spp, "mse": 0.03 + 0.2 / spp,
                     "bias_share": 0.03 / (0.03 + 0.2 / spp)})
    got = {s["setting"]: s for s in cv.summarize(rows)}
    assert got["box"]["per_doubling"] == pytest.approx(0.5)
    assert got["box"]["flat_from"] is None and got["box"]["box_better_from"] is None
    assert got["m"]["flat_from"] == 16
    assert got["m"]["box_better_from"] == 32  # 1/32 < 0.03625; 1/16 > 0.0425
    assert got["m"]["per_doubling"] == pytest.approx(0.033125 / 0.03625)
    assert got["m"]["bias_share_top"] == pytest.approx(0.03 / 0.033125)


def test_converge_records_a_setting_that_fails(device, tmp_path, monkeypatch):
    """A setting whose image has NaN is recorded as an error of its rows (and the .md);
    the other settings are measured, nothing of the failed one is cached as done."""
    _trusted()
    real_run = cv.run

    def run(buf, method, dev, **knobs):
        res = real_run(buf, method, dev, **knobs)
        if method != "box":
            res.image[0, 0] = np.nan
        return res

    monkeypatch.setattr(cv, "run", run)
    rep = _study(device, tmp_path)
    for r in rep["rows"]:
        if r["setting"] == "box":
            assert "error" not in r and r["mse"] > 0
        else:
            assert "1 non-finite pixels" in r["error"] and "mse" not in r
    assert "non-finite" in (tmp_path / "convergence.md").read_text()
    assert not list((tmp_path / "cells").glob("*/*/*/sweep-*/spp*_ref16.json"))
