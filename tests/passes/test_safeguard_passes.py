"""The safeguard's kernels (``kernels/safeguard.cl`` through
:class:`clrecon.methods.safeguard_passes.SafeguardPasses`) against the NumPy reference
(:func:`clrecon.methods.safeguard.reference`), at every vector width the window passes are
built for and at widths that leave a partial vector, for the three blend modes."""
from __future__ import annotations

import numpy as np
import pyopencl as cl
import pytest
from conftest import assert_close

from clrecon.methods import safeguard as sg
from clrecon.methods.safeguard_passes import SafeguardPasses


def _run(device, color, m, ma, mb, mode, vw, z7=0.0):
    ctx, q = device.context, device.queue
    h, w, s, _ = color.shape
    passes = SafeguardPasses(ctx, vw)
    mf = cl.mem_flags

    def up(a):
        return cl.Buffer(ctx, mf.READ_WRITE | mf.COPY_HOST_PTR,
                         hostbuf=np.ascontiguousarray(a, np.float32))

    bufs = {k: up(v) for k, v in dict(color=color, m=m, ma=ma, mb=mb).items()}
    box = cl.Buffer(ctx, mf.READ_WRITE, h * w * 12)
    # NaN where a pass leaves its buffer unwritten: the padding must be written, not assumed
    stats = up(np.full(passes.stats_bytes(w, h) // 4, np.nan))
    rows = up(np.full(passes.rows_bytes(w, h) // 4, np.nan))
    out = cl.Buffer(ctx, mf.READ_WRITE, h * w * 12)
    err = cl.Buffer(ctx, mf.READ_WRITE, h * w * 4)
    has = 0 if mode == sg.MODE_BOX else 1
    m_in = bufs["m"] if has else box
    ev = passes.run_stats(q, bufs["color"], m_in, bufs["ma"], bufs["mb"], box, stats, w, h, s,
                          has)
    passes.run_blend(q, stats, rows, box, m_in, out, err, w, h, mode, 1, [ev],
                     z7)[-1][1].wait()
    img, e = np.empty((h, w, 3), np.float32), np.empty((h, w), np.float32)
    cl.enqueue_copy(q, img, out)
    cl.enqueue_copy(q, e, err)
    return img, e


CASES = [(vw, w, mode, 1.0) for vw in (1, 4, 8, 16) for w in (5, 16, 17, 37)
         for mode in (sg.MODE_BOX, sg.MODE_METHOD, sg.MODE_BLEND)]
# dim and bright frames: each pixel's statistics in units of its own exponent, the padding's
# below every pixel's (a padding exponent of 0 would flush a 1e-30 frame's border windows)
CASES += [(vw, 17, sg.MODE_BLEND, scale) for vw in (1, 16) for scale in (1e-30, 1e15)]
CASES = [(*c, 0.0) for c in CASES]
# the 7x7 bias mean tested at 2 standard errors (the guided refinement's chain)
CASES += [(vw, w, sg.MODE_BLEND, scale, 2.0) for vw in (1, 8, 16) for w in (5, 37)
          for scale in (1.0, 1e15)]


@pytest.mark.parametrize("vw,w,mode,scale,z7", CASES)
def test_kernels_match_reference(device, vw, w, mode, scale, z7):
    rng = np.random.default_rng(w + 100 * vw + 7 * mode + int(1000 * z7))
    h, s = 9, 5
    color = rng.random((h, w, s, 3)) * rng.choice([0.5, 4.0], (h, w, 1, 1)) * scale
    ma, mb = (color.mean(2) + 0.2 * scale * rng.random((h, w, 3)) for _ in range(2))
    m = 0.5 * (ma + mb)
    m[h // 2, :] += 0.8 * scale  # a biased row: the bias estimate and the weight vary across it
    img, err = _run(device, color, m, ma, mb, mode, vw, z7)
    want_img, want_err = sg.reference(color.astype(np.float32), m.astype(np.float32),
                                      ma.astype(np.float32), mb.astype(np.float32), mode=mode,
                                      z7=z7)
    if z7:  # the test changes the image: the case can tell a kernel that ignores it
        other, _ = sg.reference(color.astype(np.float32), m.astype(np.float32),
                                ma.astype(np.float32), mb.astype(np.float32), mode=mode)
        assert np.abs(other - want_img).max() > 1e-3 * float(np.abs(want_img).max())
    scale = float(np.abs(want_img).max())
    assert_close(img, want_img, rtol=1e-4, atol=1e-5 * scale, what=f"image vw={vw} w={w}")
    # the error image is float32: below its subnormals (a 1e-30 frame's ~1e-61) it is 0
    assert_close(err, want_err, rtol=1e-3, atol=max(1e-6 * float(want_img.max()) ** 2, 6e-45),
                 what=f"error vw={vw} w={w}")


def test_vector_width_is_checked(device):
    with pytest.raises(ValueError, match="vector width 3"):
        SafeguardPasses(device.context, 3)
