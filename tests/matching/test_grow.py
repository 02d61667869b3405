"""Tests of matching.grow (region growing of LSM matches from accepted neighbours)."""

from __future__ import annotations

import numpy as np
import pytest

from matching.grow import grow_matches
from matching.lsm import Status, lsm_match, prepare_image
from matching.pair import NO_APPROXIMATION, match_pair
from testkit.warps import grid_points, start_near, truth_of, warped_pair
from tests.matching.test_pair import render, scene, truth_right  # noqa: F401


@pytest.fixture(scope="module")
def noisy():
    f, g = warped_pair(size=160, noise=2.0, seed=3)
    return prepare_image(f), prepare_image(g)


def test_growth_from_one_percent_of_seeds_matches_like_full_approximations(noisy):
    """Seeds: 1 in 100 grid points with an approximation; the rest are grown front by
    front from their neighbours' affine warps.  Every point the full-approximation run
    accepts is reached, and the grown points err like the others: the RMS of a few
    hundred points is good to ~5 %, allowed 15 %."""
    fp, gp = noisy
    pts = grid_points(160, 3)
    truth = truth_of(pts)
    approx = start_near(truth)
    full = lsm_match(fp, gp, pts, approx)
    seeds = np.zeros(len(pts), bool)
    seeds[::100] = True
    sparse = np.where(seeds[:, None], approx, np.nan)
    first = lsm_match(fp, gp, pts, sparse)
    assert first.accepted.sum() <= seeds.sum()
    growth = grow_matches(fp, gp, pts, first, sparse)
    res = growth.result
    assert growth.rounds >= 2  # fronts, not one step
    assert res.accepted.sum() >= 0.98 * full.accepted.sum()
    ok = res.accepted & full.accepted
    rms_grown = np.sqrt(np.mean((res.position[ok] - truth[ok]) ** 2))
    rms_full = np.sqrt(np.mean((full.position[ok] - truth[ok]) ** 2))
    assert rms_grown < 1.15 * rms_full
    assert growth.grown[res.accepted & ~seeds].all()
    assert np.isfinite(growth.approx[growth.grown]).all()


def test_growth_does_not_enter_an_untextured_region():
    """The right half of both images is flat noise: the fronts stop at its edge (the
    texture test rejects it, no prediction makes a match there)."""
    f, g = warped_pair(size=160, noise=2.0, seed=4)
    rng = np.random.default_rng(5)
    f[:, 90:] = 128.0 + rng.normal(0.0, 2.0, f[:, 90:].shape)
    g[:, 90:] = 128.0 + rng.normal(0.0, 2.0, g[:, 90:].shape)
    pts = grid_points(160, 4)
    truth = truth_of(pts)
    sparse = np.full_like(truth, np.nan)
    sparse[:3] = start_near(truth[:3])
    growth = grow_matches(f, g, pts, lsm_match(f, g, pts, sparse), sparse)
    res = growth.result
    full = lsm_match(f, g, pts, start_near(truth))
    flat = pts[:, 0] - 7 > 90  # window wholly in the flat half
    textured = pts[:, 0] + 7 < 90
    assert res.accepted[textured].sum() >= 0.95 * full.accepted[textured].sum()
    assert not res.accepted[flat].any()


def test_match_pair_grows_where_sgbm_gives_no_approximation(scene, monkeypatch):  # noqa: F811
    """SGBM's approximations are withheld for every candidate in a band of columns (as
    where SGBM finds no disparity): without growth they are lost as
    ``no_approximation``; with it they are matched from their neighbours, as accurately
    as the rest (RMS within 25 % of the seeded matches' -- ~100 points each)."""
    import matching.pair as pair_module

    real = pair_module.approximate_calibrated

    def withheld(rig, left, right, points, **kwargs):
        approx = real(rig, left, right, points, **kwargs)
        band = (points[:, 0] > 120) & (points[:, 0] < 220)
        approx.x_right[band] = np.nan
        return approx

    monkeypatch.setattr(pair_module, "approximate_calibrated", withheld)
    rig, left, right = scene
    plain = match_pair(left, right, rig, spacing=6, grow=False)
    grown = match_pair(left, right, rig, spacing=6)
    band = (plain.x_left[:, 0] > 120) & (plain.x_left[:, 0] < 220)
    lost = plain.status == NO_APPROXIMATION
    assert lost[band].mean() > 0.95, plain.status_counts()
    assert (grown.status[band] == NO_APPROXIMATION).mean() < 0.05, grown.status_counts()
    assert grown.accepted[band].mean() > 0.9
    gained = grown.accepted & band
    both = grown.accepted & plain.accepted
    err = grown.x_right - truth_right(rig, grown.x_left)
    rms_gained = np.sqrt(np.mean(err[gained] ** 2))
    rms_both = np.sqrt(np.mean(err[both] ** 2))
    assert rms_gained < 1.25 * rms_both, (rms_gained, rms_both)
    assert (grown.status[grown.accepted] == Status.OK).all()
