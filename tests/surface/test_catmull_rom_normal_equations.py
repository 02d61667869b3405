"""The least-squares fit's normal equations equal the sparse-matrix products they replace.

``catmull_rom._least_squares`` accumulates ``AᵀA`` in band storage and ``Aᵀx``
point by point (numba) instead of forming the sparse design matrix; both add
each entry's terms in point order, so the solution is the same to the bit
(the test allows rounding, 1e-12 of the coordinates, should a BLAS differ).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import sparse
from scipy.sparse.linalg import spsolve

from surface import catmull_rom as cr
from surface import cyclic_band


def _sparse_reference(pts, n_ctrl, smoothing):
    """The sparse design-matrix construction (the code before the band kernel)."""
    m = len(pts)
    window = max(int(round(smoothing)), int(np.ceil(np.sqrt(m))))
    t = cr._data_parameters(pts, window, n_ctrl)
    seg = np.minimum(np.floor(t).astype(np.int64), n_ctrl - 1)
    weights = cr._basis(t - seg)
    cols = (seg[:, None] + np.arange(-1, 3)) % n_ctrl
    design = sparse.csr_matrix(
        (weights.ravel(), (np.repeat(np.arange(m), 4), cols.ravel())), shape=(m, n_ctrl))
    normal = (design.T @ design).tocsc()
    fair = cyclic_band.periodic_third_difference(n_ctrl)
    system = (normal + cr._FAIRNESS * normal.diagonal().mean() * (fair.T @ fair)).tocsc()
    return np.asarray(spsolve(system, design.T @ pts)).reshape(n_ctrl, 3), t


def _noisy_ellipse(m, seed=0):
    rng = np.random.default_rng(seed)
    phi = np.sort(rng.uniform(0, 2 * np.pi, m))
    pts = np.stack([2 * np.cos(phi), np.sin(phi), np.full(m, 0.5)], axis=1)
    return pts + rng.normal(scale=0.01, size=pts.shape) * [1, 1, 0]


@pytest.mark.parametrize("m, n_ctrl", [(40, 4), (40, 5), (40, 6), (40, 7), (300, 37),
                                       (1500, 190)])
def test_band_normal_equations_equal_the_sparse_products(m, n_ctrl):
    pts = _noisy_ellipse(m)
    got, t = cr._least_squares(pts, n_ctrl, m / n_ctrl)
    want, t_ref = _sparse_reference(pts, n_ctrl, m / n_ctrl)
    assert np.array_equal(t, t_ref)
    assert np.abs(got - want).max() <= 1e-12 * np.abs(want).max()


def test_shared_arc_parameters_give_the_same_fit():
    pts = _noisy_ellipse(900, seed=1)
    arcs = {}
    for smoothing in (4.0, 8.0, 16.0):  # the same window (ceil(sqrt(900)) = 30): one memo entry
        n_ctrl = round(900 / smoothing)
        shared = cr._least_squares(pts, n_ctrl, smoothing, arcs)
        alone = cr._least_squares(pts, n_ctrl, smoothing)
        assert np.array_equal(shared[0], alone[0]) and np.array_equal(shared[1], alone[1])
    assert len(arcs) == 1


def test_auto_smoothing_reuses_the_chosen_fit_exactly():
    pts = _noisy_ellipse(700, seed=2)
    auto = cr.fit(pts, "auto")
    again = cr.fit(pts, auto.smoothing)  # refits at the chosen level from scratch
    assert np.array_equal(auto.control_points, again.control_points)


@pytest.mark.parametrize("seed", range(4))
def test_uniform_evaluation_is_scipys_spline_to_the_bit(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(4, 300))
    ctrl = rng.normal(size=(n, 3)) * rng.uniform(0.01, 10.0)
    t = np.concatenate([rng.uniform(0, n, 2000), [0.0, 1.0, n - 1.0, n - 1e-12, float(n)]])
    spline = cr._build(ctrl, "uniform", np.eye(3), np.zeros(3)).spline
    position, derivative = cr._uniform_points_and_derivatives(ctrl, t)
    assert np.array_equal(position, spline(t))
    assert np.array_equal(derivative, spline(t, 1))


@pytest.mark.parametrize("n", [7, 8, 9, 13, 64, 301])
def test_third_difference_band_is_the_sparse_gram(n):
    """The constant band (the stencil's autocorrelation) is DᵀD of the periodic third
    difference, entry (i, j) at [j, (i − j + 3) mod n], exactly."""
    fair = cyclic_band.periodic_third_difference(n)
    gram = (fair.T @ fair).toarray()
    j = np.arange(n)[:, None]
    assert np.array_equal(cyclic_band.third_difference_band(n), gram[(j + np.arange(-3, 4)) % n, j])
    assert np.count_nonzero(gram) == 7 * n
