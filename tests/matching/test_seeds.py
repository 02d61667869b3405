"""Tests of matching.seeds: texture measure, point selection, exact rectification mapping,
SGBM approximations."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from matching.cameras import Camera, StereoRig
from matching.pair import match_pair
from matching.seeds import (
    approximate_calibrated,
    approximate_rectified,
    disparity_range,
    left_to_rectified,
    rectified_to_original,
    rectify,
    select_points,
    texture_map,
    window_offsets,
)
from testkit.warps import sample, texture_coefficients


def test_texture_map_of_sinusoids_is_analytic():
    """f = sin(kx) + sin(ky), k = 2π/5: over 15 px (3 periods) the mean squared central
    difference is sin²(k)/2 in each direction and the cross term vanishes, so
    λ_min = sin²(k)/2 exactly."""
    k = 2 * np.pi / 5
    ys, xs = np.mgrid[0:60, 0:60].astype(np.float64)
    f = np.sin(k * xs) + np.sin(k * ys)
    lam = texture_map(f, 15)
    np.testing.assert_allclose(lam[20:40, 20:40], np.sin(k) ** 2 / 2, rtol=1e-9)
    assert (lam[:8] == 0).all()  # border


def test_texture_map_of_a_ramp_is_zero():
    """A plane has a gradient in one direction only: λ_min = 0 (aperture problem)."""
    ys, xs = np.mgrid[0:40, 0:40].astype(np.float64)
    np.testing.assert_allclose(texture_map(3 * xs + 2 * ys, 9), 0.0, atol=1e-9)


def test_select_points_one_per_cell_and_threshold():
    coef = texture_coefficients(100, seed=3)
    ys, xs = np.mgrid[0:100, 0:100].astype(np.float64)
    img = sample(coef, xs, ys)
    img[:, 50:] = 90.0  # textureless right half
    img += np.random.default_rng(0).normal(0, 2.0, img.shape)
    cand = select_points(img, spacing=5, patch=11)
    cells = (cand.points // 5).astype(int)
    assert len(np.unique(cells, axis=0)) == len(cells)  # one per cell
    lam = texture_map(img, 11)
    lam[:7], lam[-7:], lam[:, :7], lam[:, -7:] = -1, -1, -1, -1  # the margin is excluded
    # each is the maximum of its cell
    for (x, y), c in zip(cand.points.astype(int)[::7], cells[::7], strict=True):
        block = lam[c[1] * 5:c[1] * 5 + 5, c[0] * 5:c[0] * 5 + 5]
        assert lam[y, x] == pytest.approx(block.max())
    flat = cand.points[:, 0] - 5 > 50
    assert not cand.textured[flat].any()
    assert cand.textured[cand.points[:, 0] + 6 < 50].all()
    assert abs(cand.noise - 2.0) < 0.5  # Immerkaer on a half-textured image
    assert cand.threshold == pytest.approx(2.0 * cand.noise**2 / 2)
    # the margin keeps every template inside the image
    assert cand.points.min() >= 11 // 2 + 2 and cand.points.max() < 100 - 11 // 2 - 2


def test_select_points_mask_and_bad_arguments():
    img = np.random.default_rng(0).normal(100, 20, (60, 60))
    mask = np.zeros((60, 60), bool)
    mask[20:40, 20:40] = True
    cand = select_points(img, spacing=4, mask=mask)
    assert mask[cand.points[:, 1].astype(int), cand.points[:, 0].astype(int)].all()
    with pytest.raises(ValueError, match="spacing must be a positive integer"):
        select_points(img, spacing=0)
    with pytest.raises(ValueError, match="mask must have the image's shape"):
        select_points(img, mask=np.ones((10, 10), bool))


def _rig(dist=(-0.12, 0.05, 0.001, -0.0005, 0.0)):
    K = np.array([[400.0, 0, 159.5], [0, 400.0, 119.5], [0, 0, 1]])
    angle = np.deg2rad(8.0)
    R = np.array([[np.cos(angle), 0, -np.sin(angle)], [0, 1, 0],
                  [np.sin(angle), 0, np.cos(angle)]])
    t = np.array([-0.5, 0.02, 0.05])
    left = Camera(K, np.array(dist), np.eye(3), np.zeros(3), 320, 240, "l")
    right = Camera(K * [[1.01], [1.01], [1]], np.array(dist) * 0.8, R, t, 320, 240, "r")
    return StereoRig(left, right)


def test_rectification_maps_points_exactly():
    """3D points project into both (distorted) images; through the rectification both
    land on one row, and the rectified -> original mapping inverts the forward one."""
    rig = _rig()
    rect = rectify(rig)
    rng = np.random.default_rng(0)
    X = np.column_stack([rng.uniform(-0.6, 0.6, 200), rng.uniform(-0.4, 0.4, 200),
                         rng.uniform(2.5, 4.0, 200)])
    xl, xr = rig.left.project(X), rig.right.project(X)
    rl = left_to_rectified(rect, rig.left, xl)
    # right image -> rectified by the same exact undistortion with R2, P2
    rr = cv2.undistortPoints(xr.reshape(-1, 1, 2), rig.right.K, rig.right.dist, R=rect.R2,
                             P=rect.P2, criteria=(cv2.TERM_CRITERIA_COUNT
                                                  | cv2.TERM_CRITERIA_EPS, 100, 1e-15))
    rr = rr.reshape(-1, 2)
    np.testing.assert_allclose(rl[:, 1], rr[:, 1], atol=1e-6)  # same row
    np.testing.assert_allclose(rectified_to_original(rect, rig.right, rr), xr, atol=1e-6)
    np.testing.assert_allclose(rectified_to_original(rect, rig.left, rl, which="left"), xl,
                               atol=1e-6)


def test_rectify_rejects_zero_baseline():
    rig = _rig()
    same = StereoRig(rig.left, Camera(rig.right.K, rig.right.dist, np.eye(3), np.zeros(3),
                                      320, 240))
    with pytest.raises(ValueError, match="zero baseline"):
        rectify(same)


def _shifted_pair(disparity=12.3, noise=2.0, size=(160, 200)):
    coef = texture_coefficients(220, seed=5)
    ys, xs = np.mgrid[0:size[0], 0:size[1]].astype(np.float64)
    left = sample(coef, xs + 10, ys + 10)
    right = sample(coef, xs + 10 + disparity, ys + 10)  # x_right = x_left - d
    rng = np.random.default_rng(1)
    return left + rng.normal(0, noise, left.shape), right + rng.normal(0, noise, right.shape)


def test_disparity_range_and_sgbm_approximations_on_a_rectified_pair():
    left, right = _shifted_pair()
    dmin, count = disparity_range(left, right)
    assert dmin <= 12.3 - 8 and dmin + count >= 12.3 + 8 and count % 16 == 0
    pts = np.column_stack([np.arange(40, 180, 7.0), np.full(20, 80.0)])
    approx = approximate_rectified(left, right, pts)
    err = approx.x_right - (pts - [12.3, 0.0])
    good = np.isfinite(err[:, 0])
    assert good.mean() > 0.9
    # SGBM is a pixel-level matcher with sub-pixel interpolation: within 1 px
    assert np.abs(err[good, 0]).max() < 1.0
    np.testing.assert_array_equal(approx.direction, np.broadcast_to([1.0, 0.0], pts.shape))


def test_no_overlap_is_reported():
    flat = np.full((120, 160), 100.0)
    with pytest.raises(ValueError, match="no overlap"):
        disparity_range(flat, flat)


def test_calibrated_approximations_follow_the_epipolar_curve():
    """Plane Z = 3 in front of a distorted rig: the approximation and its epipolar
    direction in the original right image agree with the projection of the truth."""
    rig = _rig(dist=(-0.05, 0.0, 0.0, 0.0, 0.0))
    coef = texture_coefficients(160, blur=1.2, seed=9)
    # texture painted on the plane: value at (X, Y) -> oversampled texture coordinates
    w, h = 320, 240

    def render(cam):
        ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
        origin, ray = cam.ray(np.column_stack([xs.ravel(), ys.ravel()]))
        s = (3.0 - origin[:, 2]) / ray[:, 2]
        P = origin + s[:, None] * ray
        return sample(coef, 80 + 50 * P[:, 0], 80 + 50 * P[:, 1]).reshape(h, w)

    left, right = render(rig.left), render(rig.right)
    cand = select_points(left, spacing=12)
    pts = cand.points[cand.textured]
    approx = approximate_calibrated(rig, left, right, pts)
    origin, ray = rig.left.ray(pts)
    X = origin + ((3.0 - origin[:, 2]) / ray[:, 2])[:, None] * ray
    truth = rig.right.project(X)
    good = np.isfinite(approx.x_right[:, 0])
    inside = (truth[:, 0] > 20) & (truth[:, 0] < w - 20)
    assert good[inside].mean() > 0.8
    err = np.linalg.norm(approx.x_right[good & inside] - truth[good & inside], axis=1)
    assert np.percentile(err, 95) < 1.5  # within LSM's pull-in range
    # direction: the truth lies on the line through the approximation (curve ~ straight)
    d = approx.direction[good & inside]
    off = approx.x_right[good & inside] - truth[good & inside]
    perp = np.abs(off[:, 0] * d[:, 1] - off[:, 1] * d[:, 0])
    assert np.percentile(perp, 95) < 0.05


# ---------------------------------------------------------------- precision prediction


def test_structure_tensors_equal_the_window_sums():
    from matching.seeds import structure_tensors

    img = np.random.default_rng(2).normal(100, 20, (40, 50))
    gx = np.zeros_like(img)
    gy = np.zeros_like(img)
    gx[:, 1:-1] = 0.5 * (img[:, 2:] - img[:, :-2])
    gy[1:-1] = 0.5 * (img[2:] - img[:-2])
    pts = np.array([[10.0, 12.0], [25.0, 20.0], [4.0, 4.0], [45.0, 30.0]])
    st = structure_tensors(img, pts, [5, 9])
    assert st.shape == (2, 4, 3)
    for k, side in enumerate((5, 9)):
        h = side // 2
        for i, (x, y) in enumerate(pts.astype(int)):
            if min(x - h, y - h) < 1 or x + h + 1 > 49 or y + h + 1 > 39:
                assert np.isnan(st[k, i]).all()  # within 1 px of the border
                continue
            win = np.s_[y - h:y + h + 1, x - h:x + h + 1]
            np.testing.assert_allclose(st[k, i], [(gx[win] ** 2).sum(), (gy[win] ** 2).sum(),
                                                  (gx[win] * gy[win]).sum()], rtol=1e-9)
    assert np.isnan(st[1, 2]).all() and np.isfinite(st[0, 2]).all()


def test_shift_precision_of_sinusoids_is_analytic():
    """f = A (sin kx + sin ky), k = 2π/5, over whole periods (15 = 3 periods): the
    central-difference structure tensor is n A² sin²(k)/2 I, so the shift σ per unit σ0
    is 1/sqrt(n A² sin²(k)/2 - n σ_n²/2) and Förstner's q = 1, 1/sqrt(2w) the same σ."""
    from matching.seeds import forstner, shift_precision

    k, amp = 2 * np.pi / 5, 10.0
    ys, xs = np.mgrid[0:60, 0:60].astype(np.float64)
    f = amp * (np.sin(k * xs) + np.sin(k * ys))
    pts = np.array([[30.0, 30.0], [27.0, 33.0]])
    n = 15 * 15
    for noise in (0.0, 3.0):
        p = shift_precision(f, pts, [15], noise=noise)[0]
        expected = 1.0 / np.sqrt(n * amp**2 * np.sin(k) ** 2 / 2 - n * noise**2 / 2)
        np.testing.assert_allclose(p, expected, rtol=1e-9)
    w, q = forstner(f, pts, 15)
    np.testing.assert_allclose(q, 1.0, rtol=1e-9)
    np.testing.assert_allclose(1 / np.sqrt(2 * w), shift_precision(f, pts, [15], noise=0.0)[0],
                               rtol=1e-9)
    # a ramp has no texture across its gradient: q = 0 and no finite precision
    ramp = 3 * xs + 2 * ys
    assert forstner(ramp, pts, 15)[1] == pytest.approx([0.0, 0.0], abs=1e-9)
    assert np.isinf(shift_precision(ramp, pts, [15], noise=0.0)).all()


def test_shift_precision_predicts_the_lsm_sigma_ratio_between_sides():
    """Ratios between sides carry over to LSM's reported σ (the adaptive patch rule)."""
    from matching.lsm import lsm_match
    from matching.seeds import shift_precision
    from testkit.warps import grid_points, start_near, truth_of, warped_pair

    f, g = warped_pair(size=160, noise=2.0, seed=5)
    pts = grid_points(160, 7, margin=24)
    approx = start_near(truth_of(pts))
    pred = shift_precision(f, pts, [15, 21], noise=2.0)
    s15 = lsm_match(f, g, pts, approx, patch=15)
    s21 = lsm_match(f, g, pts, approx, patch=21)
    ok = s15.accepted & s21.accepted
    measured = s21.sigma[ok] / s15.sigma[ok]
    predicted = pred[1, ok] / pred[0, ok]
    # the structure tensor leaves out the affine unknowns, whose coupling to the shift
    # falls slightly with the side: measured ratios run ~3 % below the prediction
    # (the rule grows a little more than needed, never less); per point σ0 of the two
    # fits differs by ~1/sqrt(2 (n - 8)) = 5 % each, and the two σ0 are independent
    # draws only in part: 90 % of points within 20 %
    dev = measured / predicted
    assert 0.9 < np.median(dev) < 1.02, np.median(dev)
    assert np.quantile(np.abs(dev - 1), 0.9) < 0.2


# ------------------------------------------------------------------ eccentric windows
RIM_ROW = 70  # rows above are uniform background (20 grey levels + noise) in both views


def _rim_pair(noise=2.0):
    left, right = _shifted_pair(noise=noise)
    rng = np.random.default_rng(7)
    for img in (left, right):
        img[:RIM_ROW] = 20.0 + rng.normal(0, noise, img[:RIM_ROW].shape)
    return left, right


def test_window_offsets_move_windows_off_the_background():
    left, _ = _rim_pair()
    cand = select_points(left, spacing=4, patch=15)
    offset, edge = window_offsets(cand, left, patch=15, spacing=4)
    y = cand.points[:, 1]
    moved = np.any(offset != 0, axis=1)
    # windows whose centred 15 px square reaches above the rim are moved down, mostly
    # straight (the nearest clear window; a few px sideways near the image border and
    # where the texture next to the edge is weak), and then end at most 2 px above the
    # rim (the fine 5 px texture test finds the edge to half its window); a candidate
    # within the test's reach (3 px) of where it traced the edge counts as off the
    # surface and is flagged instead (2 of 101 here, 1 px inside the rim); that 3 px
    # growth also moves one window 5 px sideways where the traced edge bulges
    band = cand.textured & (y >= RIM_ROW) & (y < RIM_ROW + 7)
    assert band.sum() >= 40 and (moved[band] | edge[band]).all()
    assert np.mean(edge[band]) <= 0.05
    band &= moved
    assert (offset[band, 1] > 0).all() and (np.abs(offset[band, 0]) <= 5).all()
    assert np.mean(offset[band, 0] == 0) > 0.8
    top = y[moved] + offset[moved, 1] - 7
    assert top.min() >= RIM_ROW - 2
    # points off the surface (in the background beyond the edge) get no window
    assert (y[moved] >= RIM_ROW - 2).all()
    far = y < RIM_ROW - 3
    assert not moved[far].any() and not (cand.textured[far] & ~edge[far]).any()
    # windows clear of the background are left where they are
    assert not moved[y >= RIM_ROW + 9].any()
    assert np.abs(offset).max() <= 7


def test_match_pair_eccentric_windows_reach_the_rim_accurately():
    """A fronto-parallel plane: the warp is a pure shift, so the transfer is exact and
    the eccentric points err only by noise, scaled by their larger reported σ."""
    left, right = _rim_pair()
    m = match_pair(left, right, rectified=True, eccentric=True)
    ok = m.accepted
    err = (m.x_left[:, 0] - m.x_right[:, 0]) - 12.3
    ecc = ok & np.any(m.offset != 0, axis=1)
    centred = ok & ~ecc
    y = m.x_left[:, 1]
    assert np.count_nonzero(ecc & (y < RIM_ROW + 3)) >= 20  # within 3 px of the rim
    assert not (ok & (y < RIM_ROW - 2)).any()
    sig = m.sigma
    # error/σ ~ 1 for both (Gaussian RMS; bound 1.5 for a few hundred points, and the
    # σ0 test's sampling), eccentric σ larger (the affine unknowns' share)
    for sel in (ecc, centred):
        assert np.sqrt(np.mean((err[sel] / sig[sel]) ** 2)) < 1.5
    assert np.median(sig[ecc]) > 1.3 * np.median(sig[centred])
    plain = match_pair(left, right, rectified=True)
    # without eccentric windows nothing moves; the straddling windows are only flagged:
    # away from the image borders (where SGBM leaves pixels unmatched) every flagged
    # candidate lies within half a window (+ the 2 px edge margin) of the rim
    assert not np.any(plain.offset)
    x, y = plain.x_left[plain.edge].T
    inner = (x > 50) & (x < 170) & (y > 20) & (y < 135)  # SGBM: no disparity left of ~35
    assert inner.sum() >= 40 and np.all(np.abs(y[inner] - RIM_ROW) <= 7 + 3)
