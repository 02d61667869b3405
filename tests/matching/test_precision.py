"""Tests of matching.precision (variance factor from independent neighbouring windows)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from matching.lsm import lsm_match
from matching.precision import variance_factor
from tests.matching.test_lsm import grid_points, start_near, truth_of, warped_pair


def _factor(f, g, patch=15):
    pts = grid_points(200, 3)
    res = lsm_match(f, g, pts, start_near(truth_of(pts)), patch=patch)
    return variance_factor(pts, res.position, res.cov, res.accepted, patch=patch), res, pts


def test_white_noise_gives_a_factor_of_one():
    """White noise on an exact affine warp: LSM's σ is right (test_lsm: within 5 %) and a
    quadratic fits the mapping, so k² = 1; ~3000 residuals, neighbouring ones correlated
    through shared windows (~30 independent per window area): k² good to ~10 %."""
    f, g = warped_pair(size=200, noise=2.0, seed=8)
    vf, res, _ = _factor(f, g)
    assert vf.used.sum() > 0.8 * res.accepted.sum()
    assert 0.8 < vf.factor < 1.25


def test_correlated_noise_is_found():
    """Noise low-passed by a 1 px Gaussian (as demosaicing does): fewer independent
    observations than pixels, so σ0²N⁻¹ is too small; the factor finds it, and the
    scaled σ matches the actual error to 25 %."""
    f, g = warped_pair(size=200, noise=0.0, seed=8)
    rng = np.random.default_rng(9)
    for img in (f, g):
        noise = ndimage.gaussian_filter(rng.normal(0.0, 1.0, img.shape), 1.0)
        img += 2.0 * noise / noise.std()
    vf, res, pts = _factor(f, g)
    assert vf.factor > 2.0
    ok = res.accepted
    actual = np.sqrt(np.mean(np.sum((res.position[ok] - truth_of(pts[ok])) ** 2, axis=1)))
    scaled = np.sqrt(vf.factor * np.mean(np.trace(res.cov[ok], axis1=1, axis2=2)))
    assert actual == pytest.approx(scaled, rel=0.25)


def test_bad_arguments():
    pts = np.zeros((5, 2))
    with pytest.raises(ValueError, match="radius_px"):
        variance_factor(pts, pts, np.zeros((5, 2, 2)), patch=15, radius_px=10)
    with pytest.raises(ValueError, match="same length"):
        variance_factor(pts, pts[:3], np.zeros((5, 2, 2)))
