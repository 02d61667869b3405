"""Triangulation: exact recovery, covariance against Monte Carlo, rejection reasons."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from matching.cameras import Camera
from matching.sfm import transform_cameras
from matching.triangulate import (
    BEHIND_CAMERA,
    ILL_CONDITIONED,
    LARGE_REPROJECTION,
    OK,
    TOO_FEW_VIEWS,
    observations_from_tracks,
    triangulate_multiview,
    triangulate_pair,
)

K = np.array([[800.0, 0.0, 319.5], [0.0, 800.0, 239.5], [0.0, 0.0, 1.0]])


def look_at(center, target=(0.0, 0.0, 0.0), up=(0.0, -1.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """World->camera R, t of a camera at ``center`` looking at ``target`` (y down)."""
    center = np.asarray(center, float)
    z = np.asarray(target, float) - center
    z /= np.linalg.norm(z)
    x = np.cross(np.asarray(up, float), z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    return R, -R @ center


def ring_cameras(n=4, radius=5.0, dist=()) -> list[Camera]:
    cams = []
    for i, phi in enumerate(np.linspace(-0.6, 0.6, n)):
        R, t = look_at([radius * np.sin(phi), 0.3 * i, -radius * np.cos(phi)])
        cams.append(Camera(K, np.asarray(dist, float), R, t, 640, 480, f"v{i}"))
    return cams


def scene_points(rng, n) -> np.ndarray:
    return rng.uniform(-0.8, 0.8, size=(n, 3))


@pytest.mark.parametrize("dist", [(), (-0.2, 0.05, 0.001, -0.001, 0.01)])
def test_noise_free_pair_is_exact(dist):
    cams = ring_cameras(2, dist=dist)
    X = scene_points(np.random.default_rng(0), 500)
    result = triangulate_pair(cams[0], cams[1], cams[0].project(X), cams[1].project(X))
    assert result.valid.all()
    # relative 1e-9 of the scene size: double precision leaves ~1e-13 after Gauss-Newton
    np.testing.assert_allclose(result.points, X, rtol=0, atol=1e-9)
    assert result.reprojection_error.max() < 1e-8
    assert result.points.shape == (500, 3) and result.cov.shape == (500, 3, 3)


def test_linear_only_is_exact_without_noise():
    cams = ring_cameras(3)
    X = scene_points(np.random.default_rng(1), 100)
    obs = np.stack([c.project(X) for c in cams], axis=1)
    result = triangulate_multiview(cams, obs, refine=False)
    np.testing.assert_allclose(result.points, X, atol=1e-9)


def test_propagated_covariance_matches_monte_carlo():
    """Mahalanobis error of each noisy point: E[e^T Σ^-1 e] = 3 (χ²₃).

    Over N = 3000 points the mean of χ²₃ has relative standard deviation
    sqrt(6 / N) / 3 ≈ 1.5 %; ±10 % leaves room for the first-order
    (linearisation) bias, which at σ = 0.5 px and depth/baseline ≈ 2 is well below 1 %.
    The same holds along the depth (largest-eigenvalue) direction: E[(e·v₁)²/λ₁] = 1.
    """
    rng = np.random.default_rng(2)
    cams = ring_cameras(2, dist=(-0.1, 0.02, 0, 0))
    n, sigma_px = 3000, 0.5
    X = scene_points(rng, n)
    xl = cams[0].project(X) + rng.normal(scale=sigma_px, size=(n, 2))
    xr = cams[1].project(X) + rng.normal(scale=sigma_px, size=(n, 2))
    cov = np.broadcast_to(np.eye(2) * sigma_px**2, (n, 2, 2))
    result = triangulate_pair(cams[0], cams[1], xl, xr, cov, cov, reject_p=None)
    e = result.points - X
    maha = np.einsum("ni,nij,nj->n", e, np.linalg.inv(result.cov), e)
    assert np.mean(maha) == pytest.approx(3.0, rel=0.10)
    eigval, eigvec = np.linalg.eigh(result.cov)
    along = np.einsum("ni,ni->n", e, eigvec[:, :, -1]) ** 2 / eigval[:, -1]
    assert np.mean(along) == pytest.approx(1.0, rel=0.10)
    np.testing.assert_allclose(result.sigma, np.sqrt(eigval[:, -1]))
    # the weighted residual is χ² with 2V - 3 = 1 degree of freedom
    assert np.mean(result.chi2) == pytest.approx(1.0, rel=0.10)


def test_default_covariance_is_per_pixel():
    """Without image covariances, cov is for 1 px: scaling by σ² gives the σ-px covariance."""
    rng = np.random.default_rng(3)
    cams = ring_cameras(2)
    X = scene_points(rng, 50)
    xl, xr = cams[0].project(X), cams[1].project(X)
    unit = triangulate_pair(cams[0], cams[1], xl, xr)
    cov = np.broadcast_to(np.eye(2) * 0.04, (50, 2, 2))
    scaled = triangulate_pair(cams[0], cams[1], xl, xr, cov, cov)
    np.testing.assert_allclose(scaled.cov, unit.cov * 0.04, rtol=1e-9)
    np.testing.assert_allclose(scaled.sigma, unit.sigma * 0.2, rtol=1e-9)


def test_more_views_give_smaller_sigma():
    rng = np.random.default_rng(4)
    cams = ring_cameras(4)
    X = scene_points(rng, 200)
    obs = np.stack([c.project(X) for c in cams], axis=1)
    pair = triangulate_multiview(cams[:2], obs[:, :2])
    four = triangulate_multiview(cams, obs)
    assert four.valid.all()
    assert np.all(four.sigma < pair.sigma)


def test_missing_views_and_tracks():
    rng = np.random.default_rng(5)
    cams = ring_cameras(4, dist=(0.05, 0.0, 0.0, 0.0))
    X = scene_points(rng, 300)
    obs = np.stack([c.project(X) for c in cams], axis=1)
    hidden = rng.random((300, 4)) < 0.4
    obs[hidden] = np.nan
    n_seen = (~hidden).sum(axis=1)
    result = triangulate_multiview(cams, obs)
    np.testing.assert_array_equal(result.n_views, n_seen)
    np.testing.assert_array_equal(result.reason == TOO_FEW_VIEWS, n_seen < 2)
    ok = n_seen >= 2
    assert result.valid[ok].all()
    np.testing.assert_allclose(result.points[ok], X[ok], atol=1e-9)
    assert np.isnan(result.points[~ok]).all()
    # the same observations given as tracks
    point_idx, view_idx = np.nonzero(~hidden)
    dense = observations_from_tracks(point_idx, view_idx, obs[point_idx, view_idx], 300, 4)
    np.testing.assert_array_equal(np.isnan(dense), np.isnan(obs))


def test_point_behind_camera_is_rejected():
    cams = ring_cameras(2)
    X = scene_points(np.random.default_rng(6), 20)
    # mirror a point through the left camera centre: it projects to a valid
    # pixel (same ray, other side) but lies behind that camera
    behind = 2 * cams[0].center - X[:5] * 0.1
    Xall = np.vstack([X, behind])
    result = triangulate_pair(cams[0], cams[1], cams[0].project(Xall), cams[1].project(Xall))
    assert np.all(result.reason[20:] == BEHIND_CAMERA)
    assert np.all(result.reason[:20] == OK)


def test_large_reprojection_error_is_rejected():
    rng = np.random.default_rng(7)
    cams = ring_cameras(2)
    X = scene_points(rng, 40)
    xl, xr = cams[0].project(X), cams[1].project(X)
    xr[:10, 1] += 8.0  # 8 px off the epipolar line: χ²₁ = 16 > 10.8 (p = 0.999) at σ = 1 px
    result = triangulate_pair(cams[0], cams[1], xl, xr)
    assert np.all(result.reason[:10] == LARGE_REPROJECTION)
    assert np.all(result.valid[10:])
    capped = triangulate_pair(cams[0], cams[1], xl, xr, reject_p=None, max_reprojection_px=1.0)
    assert np.all(capped.reason[:10] == LARGE_REPROJECTION)


def test_parallel_rays_are_ill_conditioned():
    """Identical pixels in two cameras with the same orientation: the point is at infinity."""
    R = np.eye(3)
    left = Camera(K, [], R, np.zeros(3), 640, 480)
    right = Camera(K, [], R, np.array([-0.1, 0.0, 0.0]), 640, 480)
    x = np.array([[100.0, 200.0], [300.0, 240.0]])
    result = triangulate_pair(left, right, x, x)
    assert np.all(result.reason == ILL_CONDITIONED)
    assert not result.valid.any()


def test_bad_input():
    cams = ring_cameras(2)
    x = np.zeros((3, 2))
    with pytest.raises(ValueError, match="x_right must have shape"):
        triangulate_pair(cams[0], cams[1], x, np.zeros((3, 3)))
    with pytest.raises(ValueError, match="same length"):
        triangulate_pair(cams[0], cams[1], x, np.zeros((4, 2)))
    with pytest.raises(ValueError, match="positive definite"):
        triangulate_pair(cams[0], cams[1], x, x, cov_left=np.zeros((3, 2, 2)))
    with pytest.raises(ValueError, match="3 views but 2 cameras"):
        triangulate_multiview(cams, np.zeros((3, 3, 2)))


def test_rotation_conventions_with_opencv():
    """Agreement with cv2.triangulatePoints on undistorted pixels."""
    cams = ring_cameras(2)
    X = scene_points(np.random.default_rng(8), 30)
    xl, xr = cams[0].project(X), cams[1].project(X)
    Xh = cv2.triangulatePoints(cams[0].P, cams[1].P, xl.T, xr.T)
    np.testing.assert_allclose((Xh[:3] / Xh[3]).T, X, atol=1e-6)
    result = triangulate_pair(cams[0], cams[1], xl, xr)
    np.testing.assert_allclose(result.points, X, atol=1e-9)


@settings(max_examples=15, deadline=None)
@given(rotvec=st.lists(st.floats(-3.0, 3.0), min_size=3, max_size=3),
       scale=st.floats(1e-2, 1e2), shift=st.lists(st.floats(-100, 100), min_size=3, max_size=3))
def test_similarity_invariance(rotvec, scale, shift):
    """Moving the world by X' = sRX + t moves the triangulated points the same way,
    scales σ by s, and leaves the pixel residuals unchanged (a gauge freedom)."""
    cams = ring_cameras(3, dist=(-0.1, 0.01, 0.0, 0.0))
    rng = np.random.default_rng(11)
    X = scene_points(rng, 40)
    obs = np.stack([c.project(X) for c in cams], axis=1) + rng.normal(scale=0.3, size=(40, 3, 2))
    R = cv2.Rodrigues(np.array(rotvec))[0]
    t = np.array(shift)
    moved = transform_cameras(cams, scale, R, t)
    a = triangulate_multiview(cams, obs)
    b = triangulate_multiview(moved, obs)
    np.testing.assert_allclose(b.points, scale * a.points @ R.T + t, rtol=0,
                               atol=1e-7 * max(scale, 1.0) * (1 + np.abs(t).max()))
    np.testing.assert_allclose(b.sigma, scale * a.sigma, rtol=1e-6)
    np.testing.assert_allclose(b.reprojection_error, a.reprojection_error, atol=1e-7)
