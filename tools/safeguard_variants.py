"""Variants of the safeguard's estimator, measured on the methods' own halves (issue 13).

The safeguard (``clrecon/methods/safeguard.py``) blends each method's image toward box by
``w = vb' / (vb' + b2 + mean3(vm))``. This runs every method's default on the device, reads
its halves' images ``mA``, ``mB`` back, and recomputes the blend on the host in float64 with
each variant of the estimator below; ``shipped`` is the estimator as it is (checked against
the device's own image to 0.02 dB). A variant changes one thing:

* ``pixel 3sd``: also ``b2 >= e - 3 sqrt(2) (mean3(vm) + vb')``, a pixel's own excess beyond
  three standard deviations of its noise (a bias along a thin edge);
* ``strat``: box's and the method's variances from the halves scaled by ``2 r``,
  ``r = mean7(v_half) / mean7(v_quarter)`` (clipped to [0, 1/2]): how a half's variance
  compares with a quarter's tells how the renderer's samples converge, where independent
  halves assume ``1/spp`` (needs >= 4 spp; stratified samples converge faster);
  ``strat frame``: the same with one ratio for the frame, ``mean(v_half) / mean(v_quarter)``
  over every pixel (shipped from 16 spp since 2026-12-03, as
  :func:`clrecon.methods.safeguard_reference.variance_scale`; here from 4 spp);
* ``se7 1`` / ``se7 2``: the 7x7 mean of ``e`` only where it stands 1 / 2 standard errors
  above zero, as the 3x3 one does;
* ``shrink7``: the 7x7 mean shrunk by its significance, ``mu7 max(0, 1 - se7^2 / mu7^2)``;
* ``cov``: the bias estimate with the covariance of ``m`` and box added back as the halves
  estimate it, ``e = d2 - vm - vb + 2 k <mA - mB, boxA - boxB>``: ``m`` averages the pixel's
  own samples too, so ``E d2 = bias^2 + vm + vb - 2 cov(m, box)`` and ``d2 - vm - vb`` is
  biased low; ``cov vm``: the covariance modelled as ``vm`` (``e = d2 + vm - vb``, what the
  library ships from 16 spp since 2026-12-07: ``safeguard_passes.models_covariance``) at every
  sample count;
* ``no 3x3``: the bias term without its 3x3 test (the 7x7 mean alone); ``se7 2 no 3x3``:
  the 7x7 mean tested at 2 standard errors alone, as the guided chain's blend runs below
  8 spp (``safeguard_passes.bias_tests``); ``untested 7x7``: the 7x7 mean as it comes (the
  library's from 8 spp, and below 8 spp until 2026-12-07).

``shipped`` is the library's estimator at the frame's sample count (below 8 spp its 7x7
mean is tested at 2 standard errors: ``safeguard_passes.bias_tests``, since 2026-12-07, when
``se7 2`` was this page's 4-spp winner; from 8 spp, since 2026-12-08 (8-15 spp since
2026-12-07), scaled by the frame's q-value: ``safeguard_passes.shrinks_by_frame``; from 16
spp its bias term models the covariance);
the others change one thing from the untested form (``cov``: the covariance's estimate in
place of the model).
None of these constants is fitted to the scenes.
Run: ``python tools/safeguard_variants.py [--size 128] [--spp 8,64] [--scenes ...]``.
Samples ``seed = 2000 + spp``; references from the trusted device (PoCL).
"""
from __future__ import annotations

import argparse
from datetime import datetime, timezone

import numpy as np
import pyopencl as cl

import clrecon.api  # noqa: F401  (registers the methods)
from clrecon.bench.scripts import emit_page
from clrecon.core.device import get_device
from clrecon.core.pipeline import DeviceSamples
from clrecon.methods import safeguard as sg
from clrecon.methods.safeguard_passes import bias_tests, models_covariance, shrinks_by_frame
from clrecon.methods.safeguard_reference import (
    _lum2,
    _window_count,
    _window_mean,
    fdr_shrink,
    halves,
    variance_scale,
)
from clrecon.metrics import psnr
from clrecon.scenes.builtin import get_scene
from clrecon.scenes.render import render_reference, render_samples

VARIANTS = ("shipped", "pixel 3sd", "strat", "strat frame", "se7 1", "se7 2", "shrink7",
            "no 3x3", "se7 2 no 3x3", "untested 7x7", "cov", "cov vm")
METHODS = ("sweep", "layered", "splat")


def _se(e: np.ndarray, r: int) -> tuple[np.ndarray, np.ndarray]:
    """The (2r+1)^2 window mean of ``e`` and its standard error."""
    mu = _window_mean(e, r)
    var = np.maximum(_window_mean(e * e, r) - mu * mu, 0.0)
    return mu, np.sqrt(var / _window_count(e.shape, r))


def blend(color: np.ndarray, ma: np.ndarray, mb: np.ndarray, variant: str) -> np.ndarray:
    """The safeguard's image from the samples' colours (H, W, S, 3) and the method's halves'
    images (H, W, 3), with the estimator ``variant`` (float64)."""
    s = color.shape[2]
    ha, hb = halves(s)
    ma, mb = ma.astype(np.float64), mb.astype(np.float64)
    m = (ha * ma + hb * mb) / s
    c = color.astype(np.float64)
    sa, sb = c[:, :, :ha].sum(2), c[:, :, ha:].sum(2)
    box = (sa + sb) / s
    k = ha * hb / (s * s)
    vb = k * _lum2(sa / ha - sb / hb)
    vm = k * _lum2(ma - mb)
    if variant in ("strat", "strat frame") and s >= 4:
        qa, qb = ha // 2, hb // 2
        q = [c[:, :, :qa].mean(2), c[:, :, qa:ha].mean(2), c[:, :, ha:ha + qb].mean(2),
             c[:, :, ha + qb:].mean(2)]
        v_quarter = 0.25 * (_lum2(q[0] - q[1]) + _lum2(q[2] - q[3]))
        v_half = 0.5 * _lum2(sa / ha - sb / hb)
        tiny = np.finfo(float).tiny
        r = np.clip(v_half.mean() / max(v_quarter.mean(), tiny) if variant == "strat frame"
                    else _window_mean(v_half, 3) / np.maximum(_window_mean(v_quarter, 3), tiny),
                    0.0, 0.5)
        fac = 2 * r
    else:  # the shipped factor (1 below 16 spp; from 16, ``strat frame``'s own)
        fac = variance_scale(color)
    vb, vm = vb * fac, vm * fac
    e = _lum2(m - box) - vm - vb
    if variant == "cov":  # + 2 cov(m, box) from the halves, scaled as vb and vm are
        e = e + 2.0 * fac * k * np.mean((ma - mb) * (sa / ha - sb / hb), axis=-1)
    elif variant == "cov vm" or models_covariance(s):  # + 2 cov modelled as vm
        e = e + 2.0 * vm
    mu3, se3 = _se(e, 1)
    mu7, se7 = _se(e, 3)
    rel = np.divide(se7, mu7, out=np.full_like(mu7, np.inf), where=mu7 > 0)  # se7 / mu7
    test7, _ = bias_tests(False, s)  # the library's own tests of a method's halves
    shipped7 = mu7 - 2 * se7 if test7 else mu7
    if shrinks_by_frame(False, s):  # from 8 spp: the frame's q-value
        shipped7 = fdr_shrink(mu7, se7 * se7, _window_mean(vb, 3) > 0)
    t7 = {"se7 1": mu7 - se7, "se7 2": mu7 - 2 * se7, "se7 2 no 3x3": mu7 - 2 * se7,
          "untested 7x7": mu7,
          "shrink7": np.where(mu7 > 0, mu7 * np.maximum(0.0, 1.0 - rel * rel), 0.0)
          }.get(variant, shipped7)
    b2 = np.maximum(0.0, t7 if variant.endswith("no 3x3") else np.maximum(t7, mu3 - 2.0 * se3))
    vm3 = _window_mean(vm, 1)
    vbw = np.maximum(_window_mean(vb, 1), _window_mean(vb, 3))
    if variant == "pixel 3sd":
        b2 = np.maximum(b2, e - 3.0 * np.sqrt(2.0) * (vm3 + vbw))
    den = vbw + b2 + vm3
    w = np.where(den > 0, vbw / np.where(den > 0, den, 1.0), 0.0)
    return box + w[..., None] * (m - box)


def halves_images(dev, buf, method: str):
    """The device's safeguarded image and the method's halves' images, or None where the
    frame is planned as box (nothing to blend)."""
    n = buf.width * buf.height
    pipe = sg.Safeguarded(dev.context, buf.inspect(), method, {})
    if pipe.mode != sg.MODE_BLEND:
        return None
    s = DeviceSamples.upload(dev.queue, buf, pipe.fields)
    out = cl.Buffer(dev.context, cl.mem_flags.READ_WRITE, n * 12)
    pipe(dev.queue, s, out).wait()
    imgs = [np.empty((buf.height, buf.width, 3), np.float32) for _ in range(3)]
    for img, b in zip(imgs, (out, pipe.buffers["ma"], pipe.buffers["mb"])):
        cl.enqueue_copy(dev.queue, img, b)
    dev.queue.finish()
    return imgs


def measure(name: str, size: int, spp: int, dev) -> dict[str, dict[str, float]]:
    """PSNR (dB) per method and variant, and box's, for one scene and spp."""
    ref = render_reference(get_scene(name), size, size)  # the trusted device's
    buf = render_samples(get_scene(name), size, size, spp, seed=2000 + spp, device=dev)
    out = {"box": {"box": psnr(buf.color.mean(2).astype(np.float32), ref)}}
    for method in METHODS:
        imgs = halves_images(dev, buf, method)
        if imgs is None:
            continue
        got, ma, mb = imgs
        row = {v: psnr(blend(buf.color, ma, mb, v).astype(np.float32), ref) for v in VARIANTS}
        if abs(row["shipped"] - psnr(got, ref)) > 0.02:
            raise AssertionError(f"{name} {spp} {method}: the host's shipped estimator gives "
                                 f"{row['shipped']:.3f} dB, the device {psnr(got, ref):.3f}")
        out[method] = row
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", default="fence,spheres,bokeh,deep,huge_coc,fast_motion")
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--spp", default="8,64")
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    dev = get_device(None)
    stamp = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    lines = [f"# Safeguard estimator variants ({args.size}x{args.size})", "",
             f"`python tools/safeguard_variants.py --size {args.size} --spp {args.spp}` on "
             f"{dev.info.label}, {stamp}; PSNR dB against the converged reference; samples "
             "seed 2000 + spp; each variant's change against `shipped` in brackets.", "",
             "| scene | spp | box | method | " + " | ".join(VARIANTS) + " |",
             "|---|---|---|---|" + "---|" * len(VARIANTS)]
    for name in args.scenes.split(","):
        for spp in (int(s) for s in args.spp.split(",")):
            res = measure(name, args.size, spp, dev)
            box = res.pop("box")["box"]
            for method, row in res.items():
                cells = [f"{row['shipped']:.2f}"] + [
                    f"{row[v]:.2f} ({row[v] - row['shipped']:+.2f})" for v in VARIANTS[1:]]
                lines.append(f"| {name} | {spp} | {box:.2f} | {method} | "
                             + " | ".join(cells) + " |")
            print(f"{name} {spp}: done", flush=True)
    emit_page(lines, args.out)


if __name__ == "__main__":
    main()
