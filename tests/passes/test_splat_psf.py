"""splat pre-computation: PSF models, the nested grid (paper Fig. 5: 9x9 -> 28 cells) and the
sparsification (pure NumPy)."""
from __future__ import annotations

import numpy as np
import pytest

from clrecon.methods.splat.precompute import (
    SparsifyOptions,
    laplacian5,
    poisson_fft,
    sparsify,
    splat_points,
)
from clrecon.methods.splat.psf import Combined, NestedGrid, SimpleLens, Stylized


def test_nested_grid_9x9_has_28_cells():
    grid = NestedGrid((9, 9))
    assert grid.cells == 28
    boxes = grid.boxes()
    assert len(boxes) == 28
    # the cells tile the square exactly once
    area = np.prod(boxes[:, :, 1] - boxes[:, :, 0], axis=1)
    assert area.sum() == 81
    assert sorted(set(np.prod(boxes[:, :, 1] - boxes[:, :, 0], axis=1).tolist())) == [1, 4, 9]


@pytest.mark.parametrize("n", [(9, 9), (24, 24), (7, 30), (30, 5)])
def test_nested_grid_forward_map_finds_the_containing_box(rng, n):
    grid = NestedGrid(n)
    boxes = grid.boxes()
    g = rng.uniform(0, 1, (5000, 2)) * np.asarray(n)
    g[:50] = np.floor(g[:50])  # cell corners: the level boundaries of the triangular root
    idx = grid.index(g)
    inside = (boxes[idx, :, 0] <= g) & (g < boxes[idx, :, 1])
    assert inside.all()


@pytest.mark.parametrize("model,params", [
    (SimpleLens(), [0.0]), (SimpleLens(), [7.3]), (SimpleLens(), [40.0]),
    (Combined(), [0.0, 0.0]), (Combined(), [5.0, 30.0]), (Combined(), [0.2, 17.0]),
    (Stylized(), [12.0])], ids=lambda v: str(v) if isinstance(v, list) else v.name)
def test_psf_unit_energy_and_shape(model, params):
    f = model.dense([params])
    assert f.sum() == pytest.approx(1.0, abs=1e-12)
    assert f.min() >= 0
    cy, cx = f.shape[0] // 2, f.shape[1] // 2
    assert f[cy, cx] > 0
    # symmetric about the centre (disc, capsule and hexagon are point-symmetric)
    np.testing.assert_allclose(f, f[::-1, ::-1], atol=1e-12)


def test_disc_area_and_motion_extent():
    f = SimpleLens().dense([[20.0]])
    area = (f / f.max()).sum()  # covered area in pixels (rim pixels partly)
    assert area == pytest.approx(np.pi * 400, rel=0.01)
    g = Combined().dense([[3.0, 40.0]])
    cols = np.nonzero(g.sum(0) > 1e-9)[0]
    rows = np.nonzero(g.sum(1) > 1e-9)[0]
    assert 40 + 6 - 2 <= cols[-1] - cols[0] + 1 <= 40 + 6 + 2  # length + diameter along x
    assert rows[-1] - rows[0] + 1 <= 6 + 1


def test_stylized_is_a_hexagon_not_a_disc():
    f = Stylized().dense([[30.0]])
    c = f.shape[0] // 2
    # flat sides up/down at r * sqrt(3)/2 = 26 px, corners left/right at 30 px
    assert f[c - 28, c] == 0 and f[c - 24, c] > 0
    assert f[c, c + 29] > 0


def test_fft_poisson_inverts_the_laplacian(rng):
    f = np.pad(rng.uniform(0, 1, (30, 40)), 3)
    np.testing.assert_allclose(poisson_fft(laplacian5(f)), f, atol=1e-10)


def test_sparsify_disc_is_sparse_and_accurate():
    f = np.pad(SimpleLens().dense([[30.0]]), 2)
    pts, vals, err = sparsify(f, SparsifyOptions(lloyd=10, anneal=20))
    dense = (f > 0).sum()
    assert len(pts) < 0.25 * dense, "spreadlets must be far fewer than the disc's pixels"
    assert abs(vals.sum()) < 1e-9  # a Laplacian sums to zero
    rec = poisson_fft(splat_points(f.shape, pts, vals))
    assert np.abs(rec - f).sum() == pytest.approx(err, rel=1e-9)
    assert err < 0.05  # L1 over a unit-energy PSF
    assert len(np.unique(pts, axis=0)) == len(pts)  # coincident points merged


def test_annealing_does_not_increase_the_error():
    f = np.pad(Combined().dense([[6.0, 25.0]]), 2)
    _, _, e0 = sparsify(f, SparsifyOptions(lloyd=10, anneal=0))
    _, _, e1 = sparsify(f, SparsifyOptions(lloyd=10, anneal=40))
    assert e1 <= e0 * 1.10  # early Boltzmann acceptance may cost a little; never much
