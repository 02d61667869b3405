"""The neighbours' disparity plane that admits a window's disparities where SGBM gave none
(matching.pair_verify._neighbour_planes): right on one plane, silent across a depth edge."""

import numpy as np

from matching.pair_verify import _neighbour_planes

SIGMA = 0.1  # px, the verified matches' disparity noise


def _lattice(step=3.0, size=60):
    ys, xs = np.mgrid[0:size:step, 0:size:step]
    return np.column_stack([xs.ravel(), ys.ravel()]).astype(np.float64)


def test_one_plane_predicts_within_its_sigma():
    """Verified matches on d = 40 + 0.2 x - 0.1 y with noise σ; windows inside the
    lattice and 20 px beyond its edge (extrapolated): every prediction within 3.29 of its
    σ of the truth, the σ at least the matches' own and larger where extrapolated."""
    rng = np.random.default_rng(0)
    verified_xy = _lattice()
    cand_xy = np.array([[10.5, 20.5], [30.5, 31.5], [80.0, 30.0], [30.0, 80.0]])
    xl = np.vstack([verified_xy, cand_xy])
    truth = 40.0 + 0.2 * xl[:, 0] - 0.1 * xl[:, 1]
    disparity = truth + rng.normal(0, SIGMA, len(xl))
    sigma = np.full(len(xl), SIGMA)
    verified = np.arange(len(verified_xy))
    cand = np.arange(len(verified_xy), len(xl))
    pred, sigma_pred = _neighbour_planes(xl, disparity, sigma, verified, cand, 12)
    assert np.isfinite(pred).all()
    assert np.all(np.abs(pred - truth[cand]) <= 3.29 * sigma_pred)
    assert np.all(sigma_pred >= SIGMA)
    assert sigma_pred[2:].min() > sigma_pred[:2].max()  # beyond the lattice


def test_a_depth_edge_gives_no_plane():
    """Half the neighbours 30 px of disparity nearer (a depth edge through the window):
    no plane is claimed there; windows well away from the edge still get theirs."""
    rng = np.random.default_rng(1)
    verified_xy = _lattice()
    cand_xy = np.array([[30.0, 30.5], [6.0, 30.5], [54.0, 30.5]])
    xl = np.vstack([verified_xy, cand_xy])
    disparity = 40.0 + np.where(xl[:, 0] > 30.0, 30.0, 0.0) + rng.normal(0, SIGMA, len(xl))
    sigma = np.full(len(xl), SIGMA)
    verified = np.arange(len(verified_xy))
    cand = np.arange(len(verified_xy), len(xl))
    pred, _ = _neighbour_planes(xl, disparity, sigma, verified, cand, 12)
    assert np.isnan(pred[0])
    assert abs(pred[1] - 40.0) < 1.0 and abs(pred[2] - 70.0) < 1.0
