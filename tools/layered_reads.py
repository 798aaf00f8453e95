"""How many times ``layered``'s reproject reads the frame: per (tile, slot) the pixels its
gather visits (the window of its reach, clipped to the image, one pixel per block with
subsampling, as ``kernels/reproject.cl`` picks them), summed by grid spacing, as multiples of
the frame's pixels; and the slots' reach.

Run: ``python tools/layered_reads.py [--scene deep] [--size 1280x720] [--spp 8]
[--knobs '{"tile": 64}']``; prints markdown. The partitions are the pipeline's own (its
``params`` after one call), so the count is the kernel's, not a model of it.
"""
from __future__ import annotations

import argparse
import json

import numpy as np
import pyopencl as cl

from clrecon.bench.scripts import add_frame_options, emit_page, frame_of
from clrecon.bench.timing import PipelineRun
from clrecon.methods.layered.layout import NPAR, P_DIM, P_REACH, P_SCALE, subsample_cap
from clrecon.methods.layered.reference import row_hash


def slot_pixels(x0: int, y0: int, tile: int, reach: int, sub: int, w: int,
                h: int) -> np.ndarray:
    """Linear indices (y * w + x) of the pixels the slot of the tile at (x0, y0) visits:
    every pixel of its window, or with ``sub`` > 1 the one of each sub x sub block that the
    block row's hash picks."""
    ax, bx = max(0, x0 - reach), min(w, x0 + tile + reach)
    ay, by = max(0, y0 - reach), min(h, y0 + tile + reach)
    if sub == 1:
        ys, xs = np.mgrid[ay:by, ax:bx]
        return (ys * w + xs).ravel()
    cy = np.arange(ay // sub, (by + sub - 1) // sub)
    hh = row_hash(cy, sub)
    py = cy * sub + (hh >> np.uint64(16)).astype(np.int64) % sub
    ox = hh.astype(np.int64) % sub
    cx = np.arange(ax // sub, (bx + sub - 1) // sub)
    px = cx[None, :] * sub + ox[:, None]
    inside = (px >= ax) & (px < bx) & ((py >= ay) & (py < by))[:, None]
    return (np.broadcast_to(py[:, None], px.shape) * w + px)[inside]


def slot_reads(x0: int, y0: int, tile: int, reach: int, sub: int, w: int, h: int) -> int:
    """How many pixels :func:`slot_pixels` visits."""
    return int(slot_pixels(x0, y0, tile, reach, sub, w, h).size)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_frame_options(ap, repeats=1)
    ap.add_argument("--knobs", default="{}", help="the method's knobs, JSON")
    ap.add_argument("-o", "--output", default=None)
    args = ap.parse_args(argv)
    knobs = {"safeguard": False, **json.loads(args.knobs)}
    dev, buf = frame_of(args)
    run = PipelineRun(dev, buf, "layered", knobs)
    run.run()
    pb = run.pipe.buffer("params")
    params = np.empty(pb.size // 4, np.float32)
    cl.enqueue_copy(dev.queue, params, pb)
    desc = run.describe()
    tile, maxp, cap = desc["tile"], desc["max_partitions"], subsample_cap(desc["subsample"])
    params = params[: params.size // NPAR * NPAR].reshape(-1, maxp, NPAR)
    w, h = buf.width, buf.height
    ntx = -(-w // tile)
    by_scale: dict[int, list[int]] = {}
    reaches = []
    union = 0  # per tile, the pixels any of its slots visits
    for t in range(params.shape[0]):
        x0, y0 = (t % ntx) * tile, (t // ntx) * tile
        seen = []
        for p in params[t]:
            if p[P_DIM] == 0:
                continue
            s, r = int(p[P_SCALE]), int(p[P_REACH])
            px = slot_pixels(x0, y0, tile, r, min(s, cap), w, h)
            seen.append(px)
            acc = by_scale.setdefault(s, [0, 0])
            acc[0] += 1
            acc[1] += px.size
            reaches.append(r)
        if seen:
            union += np.unique(np.concatenate(seen)).size
    npix = w * h
    total = sum(v[1] for v in by_scale.values())
    lines = [f"# layered reproject's reads: {args.scene} {w}x{h}, {args.spp} spp, "
             f"knobs {json.dumps(knobs)}", "",
             f"Tiles {params.shape[0]}, slots {len(reaches)}; pixels visited "
             f"{total} = **{total / npix:.2f}x** the frame ({total * args.spp} samples). "
             f"A tile's slots visiting each pixel once for all of them would visit "
             f"{union / npix:.2f}x ({union / max(total, 1):.2f} of it).", "",
             "| grid spacing | slots | pixels visited | x frame |", "|---|---|---|---|"]
    for s in sorted(by_scale):
        n, px = by_scale[s]
        lines.append(f"| {s} | {n} | {px} | {px / npix:.2f} |")
    edges = [0, 8, 16, 32, 48, 64, 80, 97]
    hist, _ = np.histogram(reaches, bins=edges)
    lines += ["", "| reach px | " + " | ".join(f"{a}-{b - 1}" for a, b in
                                                zip(edges, edges[1:])) + " |",
              "|---|" + "---|" * len(hist), "| slots | " + " | ".join(map(str, hist)) + " |"]
    emit_page(lines, args.output)


if __name__ == "__main__":
    main()
