"""Robust LSM across depth edges: ``lsm_match(robust=...)``.

Rendered rectified pairs of a textured front plane before a textured back plane
(``tests/matching/_edges.py``: exact truth per pixel, 2 grey levels of noise), matched
along the rows with 15 x 15 windows from the truth + 0.3 px.  A window is *across* the
edge when the edge line meets it; its centre's truth is the layer the centre sees.
"""

from __future__ import annotations

import numpy as np
import pytest

from matching.lsm import Status, lsm_match
from tests.matching._edges import layered_pair
from tests.matching.test_lsm import _edge_windows

CASES = {
    "textured front 3.7 px before textured back": {},
    "the same, edge at 30 degrees": {"angle_deg": 30.0},
    "a 1.5 px step": {"d_front": 4.2, "d_back": 2.7},
}

#: σ0, correlation and motion-step tests off: every converged window is kept, so that
#: the two estimators are compared on the same windows.
NO_TESTS = dict(sigma0_factor=1e9, sigma0_mad_k=1e9, step_limit=None, min_correlation=-1.0)


def _windows(pair, patch=15, margin=12, step=2):
    """Integer left points with truth; (points, truth, across, clear, distance)."""
    pts, truth, across, clear = _edge_windows(pair, patch, step=step, margin=margin)
    return pts, truth, across, clear, np.abs(pair.edge_distance(pts))


def _match(pair, pts, truth, robust, **options):
    return lsm_match(pair.left, pair.right, pts, truth + [0.3, 0.0], patch=15,
                     direction=(1.0, 0.0), robust=robust, **options)


@pytest.mark.parametrize("case", list(CASES))
def test_robust_error_across_the_edge(case):
    """Windows across the edge whose centre lies >= 3 px from it (its side is the
    window's majority), every converged one kept: equal-weight LSM settles between the
    two motions, robust LSM on the centre's.  Measured median |error| 0.296 -> 0.012 px
    (3.7 px step), 0.153 -> 0.0085 (30 degrees), 0.204 -> 0.017 (1.5 px step); 90th
    percentile 0.91 / 0.87 / 0.38 -> 0.030 / 0.022 / 0.042 px.  Asserted: robust's
    median below 0.03 px and below 1/5 of the equal-weight one."""
    pair = layered_pair(size=(100, 140), edge_x=70.3, **CASES[case])
    pts, truth, across, _, dist = _windows(pair)
    major = across & (dist >= 3.0)
    err = {}
    for robust in (False, True):
        res = _match(pair, pts, truth, robust, **NO_TESTS)
        assert res.accepted[major].mean() > 0.95
        err[robust] = np.abs(res.position[major & res.accepted, 0]
                             - truth[major & res.accepted, 0])
    assert np.median(err[True]) < 0.03
    assert np.median(err[True]) < 0.2 * np.median(err[False])


@pytest.mark.parametrize("case", list(CASES))
def test_robust_accepts_across_the_edge_within_its_sigma(case):
    """With every test on, equal-weight LSM rejects nearly all windows across the edge
    (σ0 test; accepted 0 / 26 / 0 of 266 / 420 / 266).  Robust LSM accepts
    187 / 282 / 115 of them, with 1 / 0 / 1 beyond 3σ (largest 3.09σ: what Gaussian
    errors give, 0.27 % beyond 3σ) -- σ from the support's own σ0 and normal matrix.
    Asserted: at least 40 % accepted, at most 1 % beyond 3σ, none beyond 3.5σ."""
    pair = layered_pair(size=(100, 140), edge_x=70.3, **CASES[case])
    pts, truth, across, _, _ = _windows(pair)
    res = _match(pair, pts, truth, True)
    ok = res.accepted & across
    z = np.abs(res.position[:, 0] - truth[:, 0]) / np.sqrt(res.cov[:, 0, 0])
    assert ok.sum() >= 0.4 * across.sum()
    assert np.mean(z[ok] > 3.0) <= 0.01
    assert z[ok].max() < 3.5
    plain = _match(pair, pts, truth, False)
    assert plain.accepted[across].sum() < 0.25 * ok.sum()


def test_robust_leaves_clear_windows_alone():
    """Windows clear of the edge hold one motion: robust LSM's support is the whole
    window and it returns the equal-weight match.  Measured on the three pairs: the
    same windows accepted, positions within 0.20σ of each other (median 0.03σ: the two
    iterations stop at different points within the shift tolerance), σ within 0.1 %."""
    for options in CASES.values():
        pair = layered_pair(size=(100, 140), edge_x=70.3, **options)
        pts, truth, _, clear, _ = _windows(pair)
        plain = _match(pair, pts, truth, False)
        robust = _match(pair, pts, truth, True)
        textured = clear & (plain.status != Status.TEXTURELESS)
        assert np.array_equal(plain.accepted[textured], robust.accepted[textured])
        both = plain.accepted & robust.accepted & clear
        sigma = np.sqrt(plain.cov[both, 0, 0])
        shift = np.abs(plain.position[both, 0] - robust.position[both, 0]) / sigma
        assert np.median(shift) < 0.1 and shift.max() < 0.3
        np.testing.assert_allclose(np.sqrt(robust.cov[both, 0, 0]), sigma, rtol=0.005)


def test_robust_per_window_flags_and_validation():
    """``robust`` takes one flag per window: flagged windows match as with True,
    the others as with False (bit for bit); bad values raise."""
    pair = layered_pair(size=(100, 140), edge_x=70.3)
    pts, truth, across, _, _ = _windows(pair)
    flags = across.copy()
    mixed = _match(pair, pts, truth, flags)
    # the kernel's solutions (before the population tests) are each mode's own
    np.testing.assert_array_equal(mixed.position[~flags],
                                  _match(pair, pts, truth, False).position[~flags])
    np.testing.assert_array_equal(mixed.position[flags],
                                  _match(pair, pts, truth, True).position[flags])
    with pytest.raises(ValueError, match="robust"):
        lsm_match(pair.left, pair.right, pts, truth, robust=np.zeros(len(pts)))
    with pytest.raises(ValueError, match="robust"):
        lsm_match(pair.left, pair.right, pts, truth, robust=True, jacobian="search")


def test_match_pair_robust_edge_windows():
    """``match_pair(robust="edge")`` on a uniform front before a textured back, the right
    view blurred 0.7 px (SGBM starts, growth, adaptive patch, variance factor): of the
    150 candidates whose window meets the edge, 12 accepted (0 equal-weight), none
    beyond 3σ (largest 2.04σ); the textured candidates clear of it as equal-weight
    (99.2 % against 99.0 %)."""
    from scipy import ndimage

    from matching.pair import match_pair

    pair = layered_pair(size=(100, 160), edge_x=80.3, front="uniform", front_level=100.0)
    right = ndimage.gaussian_filter(pair.right, 0.7)
    out = {}
    for robust in (False, "edge"):
        m = match_pair(pair.left, right, rectified=True, spacing=3, search_range=(0, 16),
                       robust=robust)
        truth = pair.truth(m.x_left)
        has = np.isfinite(truth).all(1)
        dist = np.abs(pair.edge_distance(m.x_left))
        across, clear = has & (dist <= 7), has & (dist > 16)
        z = np.abs(m.x_right[:, 0] - truth[:, 0]) / np.sqrt(m.cov[:, 0, 0])
        textured = clear & ~np.isin(m.status, (Status.TEXTURELESS, Status.OUTSIDE_IMAGE))
        out[robust] = (m.accepted[across].sum(), m.accepted[textured].mean())
        assert not (z[m.accepted & across] > 3.0).any()
    assert out["edge"][0] >= out[False][0] + 5
    assert out["edge"][1] >= out[False][1] - 0.005
    with pytest.raises(ValueError, match="robust"):
        match_pair(pair.left, right, rectified=True, robust="all")
