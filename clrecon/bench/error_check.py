"""How good is the per-pixel error estimate? (``clrecon errcheck``)

For each scene and method, one frame is reconstructed with ``estimate_error=True`` and the
estimate is compared with the true squared error against the converged reference (linear
radiance, mean over RGB, the same quantity the estimate is of), over 8x8 tiles:

* Spearman's rank correlation of the tiles' mean estimated and true squared error (what a
  renderer placing its next samples by the estimate relies on: the order of the tiles);
* the ratio of the frame's mean estimate to its true mean squared error (calibration).

References come from the trusted device (PoCL; :func:`clrecon.core.device.trusted_device`) and
are cached in the output folder.
"""
from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from clrecon.api import run
from clrecon.core.device import get_device, trusted_device
from clrecon.io import load_image, save_image
from clrecon.scenes import get_scene, render_reference, render_samples

TILE = 8


def tile_means(a: np.ndarray, tile: int = TILE) -> np.ndarray:
    """Means over the whole ``tile`` x ``tile`` tiles of an (H, W) array (the partial tiles
    at the right and bottom edges are left out), flattened."""
    h, w = (a.shape[0] // tile) * tile, (a.shape[1] // tile) * tile
    if h == 0 or w == 0:
        raise ValueError(f"the frame ({a.shape[1]}x{a.shape[0]}) is smaller than a tile "
                         f"({tile}x{tile})")
    return a[:h, :w].reshape(h // tile, tile, w // tile, tile).mean((1, 3)).ravel()


def _ranks(x: np.ndarray) -> np.ndarray:
    """Ranks with ties averaged (as Spearman's coefficient defines them)."""
    order = np.argsort(x, kind="stable")
    r = np.empty(len(x), np.float64)
    r[order] = np.arange(len(x), dtype=np.float64)
    xs = x[order]
    i = 0
    while i < len(xs):
        j = i
        while j + 1 < len(xs) and xs[j + 1] == xs[i]:
            j += 1
        if j > i:
            r[order[i:j + 1]] = (i + j) / 2.0
        i = j + 1
    return r


def spearman(a: np.ndarray, b: np.ndarray) -> float:
    """Spearman's rank correlation of two 1-D arrays (NaN if either is constant)."""
    a, b = np.asarray(a, np.float64).ravel(), np.asarray(b, np.float64).ravel()
    if a.shape != b.shape or a.size < 2:
        raise ValueError(f"spearman: need two arrays of one length >= 2, got {a.shape}, "
                         f"{b.shape}")
    ra, rb = _ranks(a) - (a.size - 1) / 2.0, _ranks(b) - (b.size - 1) / 2.0
    den = np.sqrt((ra * ra).sum() * (rb * rb).sum())
    return float((ra * rb).sum() / den) if den > 0 else float("nan")


def check(scenes: Sequence[str] = ("fence", "deep", "fast_motion"),
          methods: Sequence[str] = ("box", "sweep", "layered", "splat"),
          size: tuple[int, int] = (512, 512), spp: int = 8, seed: int | None = None,
          out_dir: str | Path = "out/errcheck", device=None,
          status: Callable[[str], None] | None = None) -> dict:
    """Reconstruct every (scene, method) with its default settings and ``estimate_error``;
    return and write (``errcheck.json``, ``errcheck.md``) the rank correlations."""
    w, h = (int(v) for v in size)
    seed = 100 + spp if seed is None else int(seed)
    dev = get_device(device)
    ref_dev = trusted_device()
    out = Path(out_dir)
    (out / "references").mkdir(parents=True, exist_ok=True)
    say = status or (lambda s: None)
    rows = []
    for name in scenes:
        scene = get_scene(name)
        path = out / "references" / f"{name}_{w}x{h}_seed1.exr"
        if path.exists():
            ref = load_image(path)
        else:
            say(f"{name}: reference on {ref_dev.info.label}")
            ref = render_reference(scene, w, h, seed=1, device=ref_dev)
            save_image(path, ref)
        buf = render_samples(scene, w, h, spp, seed=seed, device=dev)
        for m in methods:
            res = run(buf, method=m, device=dev, estimate_error=True)
            true = ((res.image.astype(np.float64) - ref) ** 2).mean(-1)
            est = res.error.astype(np.float64)
            rho = spearman(tile_means(est), tile_means(true))
            rows.append({"scene": name, "method": m, "spearman": rho,
                         "calibration": float(est.mean() / true.mean()),
                         "mse": float(true.mean()), "safeguard": res.method.get("safeguard")})
            say(f"{name} {m}: Spearman {rho:.3f}")
    rep = {"device": dev.info.label, "size": [w, h], "spp": spp, "seed": seed, "tile": TILE,
           "rows": rows}
    (out / "errcheck.json").write_text(json.dumps(rep, indent=1))
    (out / "errcheck.md").write_text(markdown(rep))
    return rep


def markdown(rep: dict) -> str:
    w, h = rep["size"]
    lines = [f"Device: {rep['device']}; {w}x{h}, {rep['spp']} spp (seed {rep['seed']}); "
             f"{rep['tile']}x{rep['tile']} tiles; each method's default settings.", "",
             "| scene | method | Spearman (tiles) | mean estimate / true MSE | true MSE |",
             "|---|---|---|---|---|"]
    for r in rep["rows"]:
        lines.append(f"| {r['scene']} | {r['method']} | {r['spearman']:.3f} | "
                     f"{r['calibration']:.2f} | {r['mse']:.3g} |")
    return "\n".join(lines) + "\n"
