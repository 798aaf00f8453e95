"""A multi-scale version of the halves' non-local means, prototyped in NumPy (not shipped).

``nlm=R`` averages over (2R+1)^2 pixels, so noise whose grain is coarser than that window
stays: on ``huge_coc`` at 512x512 the guided chain's halves keep low-frequency blotches on
the far wall, and Open Image Denoise (multi-scale) removes them. Here each filtered half
``n`` (the pipeline's ``na``, ``nb``) gets its low band replaced, scale by scale, by a
non-local means of its low band at half the resolution (dual buffers there too: each half's
weights from the other half's low band):

    low(x) = up(down(x)),  n_s = n - low(n) + up(m_{s+1}),  m_{s+1} = NLM(down(n_s-level))

``down``: 2x2 means; ``up``: nearest, then a [1/4, 1/2, 1/4] tent along each axis. With
``scales = 1`` the result is the pipeline's own (the halves' mean without the safeguard).

Run: ``python tools/nlm_scales.py [--cases huge_coc:4,fence:4,...] [--size 512] [--scales 3]
[--refs DIR]`` (references: ``DIR/<scene>_<W>x<H>_<spp>spp_seed1.exr`` as ``clrecon trade``
caches them, else rendered on the trusted device); prints PSNR of ``splat guided nlm3``
(safeguard off), of the same with 2..``scales`` scales, and of OIDN high.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from clrecon.methods import nlm
from clrecon.methods.safeguard_passes import halves


def down2(x: np.ndarray) -> np.ndarray:
    """2x2 means (an odd last row or column is left out)."""
    h, w = x.shape[0] // 2 * 2, x.shape[1] // 2 * 2
    x = x[:h, :w]
    return 0.25 * (x[0::2, 0::2] + x[1::2, 0::2] + x[0::2, 1::2] + x[1::2, 1::2])


def up2(x: np.ndarray, shape) -> np.ndarray:
    """``x`` at twice the resolution into ``shape`` (edge-replicated where ``shape`` is odd):
    nearest, then a [1/4, 1/2, 1/4] tent along each axis."""
    y = np.repeat(np.repeat(x, 2, 0), 2, 1)
    h, w = shape[:2]
    y = np.pad(y, ((0, h - y.shape[0]), (0, w - y.shape[1])) + ((0, 0),) * (y.ndim - 2),
               mode="edge")
    for axis in (0, 1):
        p = np.pad(y, [(1, 1) if a == axis else (0, 0) for a in range(y.ndim)], mode="edge")
        lo = [slice(None)] * y.ndim
        mid, hi = list(lo), list(lo)
        lo[axis], mid[axis], hi[axis] = slice(0, -2), slice(1, -1), slice(2, None)
        y = 0.25 * p[tuple(lo)] + 0.5 * p[tuple(mid)] + 0.25 * p[tuple(hi)]
    return y


def multiscale(na: np.ndarray, nb: np.ndarray, spp: int, r: int, scales: int):
    """(A, B): the filtered halves with their low bands from ``scales - 1`` coarser
    non-local means (float64)."""
    na, nb = np.asarray(na, np.float64), np.asarray(nb, np.float64)
    if scales <= 1 or min(na.shape[:2]) < 2:
        return na, nb
    ca, cb = nlm.reference(down2(na), down2(nb), spp, r)
    ca, cb = multiscale(ca, cb, spp, r, scales - 1)
    return (na - up2(down2(na), na.shape) + up2(ca, na.shape),
            nb - up2(down2(nb), nb.shape) + up2(cb, nb.shape))


def main() -> None:
    import pyoidn

    from clrecon.core.device import get_device
    from clrecon.io import load_image
    from clrecon.metrics import psnr
    from clrecon.scenes import get_scene, render_reference, render_samples

    ap = argparse.ArgumentParser()
    ap.add_argument("--cases", default="huge_coc:4,huge_coc:8,fence:4,deep:4,bokeh:4,"
                    "fast_motion:8,spheres:8")
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--scales", type=int, default=3)
    ap.add_argument("--refs", default="out/trade-nlm2/references")
    args = ap.parse_args()
    import sys
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "support"))
    from pipeline_run import read_buffer, run_plan

    dev, n = get_device(None), args.size
    for case in args.cases.split(","):
        name, spp = case.split(":")
        spp, scene = int(spp), get_scene(name)
        path = Path(args.refs) / f"{name}_{n}x{n}_{scene.reference_spp}spp_seed1.exr"
        ref = load_image(path) if path.exists() else render_reference(scene, n, n, seed=1)
        buf = render_samples(scene, n, n, spp, seed=100 + spp, device=dev)
        pipe, _ = run_plan(dev, buf, "splat", guided=2, nlm=3, safeguard=False)
        na, nb = (read_buffer(pipe, dev.queue, k, (n, n, 3)) for k in ("na", "nb"))
        ha, hb = halves(spp)
        row = []
        for s in range(1, args.scales + 1):
            a, b = multiscale(na, nb, spp, 3, s)
            row.append(f"{s} scale{'s' if s > 1 else ''} {psnr((ha * a + hb * b) / spp, ref):.2f}")
        oidn = pyoidn.denoise(buf.color.mean(2), hdr=True, quality="high")
        print(f"{name} {spp} spp: " + ", ".join(row) + f", OIDN high {psnr(oidn, ref):.2f}",
              flush=True)


if __name__ == "__main__":
    main()
