"""The sweep's front-to-back order at its depth precision (kernels/sweep_order.h): depths
that agree in their top 12 significant bits are ties, which keep window order, in every
sorting plan and in the NumPy reference; ``exact_depth_order=True`` orders by the exact
depths. The frame has near-tied depths (relative differences below the order's step) in
random order, so the two orders give different images."""
from __future__ import annotations

import numpy as np
import pytest
from conftest import assert_close
from sweep_frames import frame

import clrecon
from clrecon.methods.sweep import reference as ref

PLANS = [dict(scales=2, sort="block"), dict(scales=4, sort="block"),
         dict(scales=2, sort="tile"), dict(scales=2, sort="pixel"),
         dict(scales=4, sort="tile", tile_merge="bitonic")]


def near_ties(rng):
    """A frame whose finite depths sit on five levels, each sample's moved by a relative
    amount below 2^-12: far below what the method sees, but an exact sort reorders them."""
    buf = frame(rng, h=12, w=13, s=4)
    z = buf.depth
    fin = np.isfinite(z)
    levels = np.quantile(z[fin], [0.1, 0.3, 0.5, 0.7, 0.9])
    snap = levels[np.abs(z[..., None] - levels).argmin(-1)]
    jitter = 1.0 + rng.uniform(0.0, 2.0 ** -12, z.shape)
    buf.depth = np.where(fin, snap * jitter, z).astype(np.float32)
    buf.validate()
    return buf


def test_depth_order_key():
    z = np.array([0.5, 1.0, 1.0 + 2.0 ** -20, 1.0 + 2.0 ** -10, 3.0, np.inf], np.float32)
    exact = ref.depth_order_key(z, 0)
    assert np.array_equal(exact, z.view(np.uint32))
    key = ref.depth_order_key(z)
    assert np.all(np.diff(key.astype(np.int64)) >= 0)  # monotone: the depths' order
    assert key[1] == key[2] and key[2] < key[3]  # 2^-20 apart: tied; 2^-10: not
    with pytest.raises(ValueError, match="shift"):
        ref.depth_order_key(z, 21)


@pytest.mark.parametrize("knobs", PLANS, ids=lambda k: ",".join(f"{a}={b}" for a, b in k.items()))
def test_every_plan_orders_at_the_references_precision(device, rng, knobs):
    buf = near_ties(rng)
    scales = knobs["scales"]
    coarse = ref.reconstruct(buf, scales=scales)
    exact = ref.reconstruct(buf, scales=scales, exact_depth_order=True)
    # the test can tell the two orders apart
    assert np.abs(coarse - exact).max() > 1e-3
    got = clrecon.reconstruct(buf, "sweep", device, **knobs, safeguard=False)
    assert_close(got, coarse, rtol=2e-4, atol=2e-5, what=f"sweep {knobs}")
    got_exact = clrecon.reconstruct(buf, "sweep", device, **knobs, exact_depth_order=True,
                                    safeguard=False)
    assert_close(got_exact, exact, rtol=2e-4, atol=2e-5, what=f"sweep exact {knobs}")

