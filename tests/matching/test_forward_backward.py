"""Tests of matching.forward_backward (forward-backward loops and the variance factor)."""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from matching.forward_backward import forward_backward
from matching.lsm import lsm_match
from testkit.warps import grid_points, start_near, truth_of, warped_pair


def _factor(f, g):
    pts = grid_points(160, 6)
    res = lsm_match(f, g, pts, start_near(truth_of(pts)))
    return forward_backward(f, g, pts, res), res


def test_loops_share_the_noise_and_understate_the_error():
    """White noise, where LSM's σ is right (test_lsm: within 5 %): the backward match
    reads the same pixels, their noise cancels in the loop, so the loops are far
    below the reported σ (k² = 0.045 measured; independent matches would give 1)."""
    f, g = warped_pair(size=160, noise=2.0, seed=8)
    fb, res = _factor(f, g)
    assert fb.used.sum() > 0.8 * res.accepted.sum()
    assert fb.variance_factor < 0.2
    assert np.isfinite(fb.loop[fb.used]).all()


def test_direction_dependent_error_shows_in_the_loops():
    """A blur difference between the views (the right image low-passed by 1 px) is an
    error that depends on the direction: the loops grow with it."""
    f, g = warped_pair(size=160, noise=2.0, seed=8)
    sharp, _ = _factor(f, g)
    blurred, _ = _factor(f, ndimage.gaussian_filter(g, 1.0))
    assert blurred.loop_rms > 2.0 * sharp.loop_rms
