"""Tests of matching.second_order (second-order warp terms from neighbours' affine fits).

The synthetic pairs and helpers are those of ``tests/matching/test_lsm.py``.
"""

from __future__ import annotations

import numpy as np
import pytest

from matching.lsm import lsm_match
from matching.second_order import second_order_terms
from testkit.warps import grid_points, sample, start_near, texture_coefficients


def test_second_order_terms_remove_the_curvature_bias():
    """Right image = left seen through u = x + c (x - x0)², v = y (no noise).

    An affine 15x15 fit is biased by c <x²> = c · 18.67 px² in u (0.019 px for
    c = 1e-3); the neighbours' a1 field gives u_xx = 2c, the second pass removes the bias.
    """
    size, c, x0 = 160, 1e-3, 80.0
    coef = texture_coefficients(size, seed=21)
    ys, xs = np.mgrid[0:size, 0:size].astype(np.float64)
    f = sample(coef, xs, ys)
    # inverse of u = x + c (x - x0)^2 on the right image's pixel grid
    src_x = x0 + (-1 + np.sqrt(1 + 4 * c * (xs - x0))) / (2 * c)
    g = sample(coef, src_x, ys)
    pts = grid_points(size, 4, margin=25)
    truth = np.column_stack([pts[:, 0] + c * (pts[:, 0] - x0) ** 2, pts[:, 1]])
    first = lsm_match(f, g, pts, start_near(truth, 0.5))
    bias = np.mean(first.position[first.accepted, 0] - truth[first.accepted, 0])
    assert bias == pytest.approx(c * 56 / 3, rel=0.15)  # <x²> = 7·8/3 for x in -7..7
    quad = second_order_terms(pts, first.affine, first.accepted, radius_px=16)
    inner = first.accepted & (np.abs(pts - 80) < 40).all(1)
    np.testing.assert_allclose(quad[inner, 0], c, rtol=0.1)  # qu_xx = u_xx / 2 = c
    assert np.abs(quad[inner, 1:]).max() < 1e-4
    second = lsm_match(f, g, pts, start_near(truth, 0.5), quadratic=quad)
    err = second.position[inner] - truth[inner]
    assert np.abs(err.mean(0)).max() < 0.002


def test_second_order_terms_use_every_neighbour_within_the_radius():
    """The plane fits take all valid neighbours within ``radius_px`` (a 2 px grid holds
    ~314 within 20 px), not a fixed nearest few: with a linear a1 field plus white noise
    of σ, the slope da1/dx from N points of spread s has standard error σ / (s sqrt(N)),
    and the terms equal an explicit least-squares plane fit over the ball."""
    rng = np.random.default_rng(4)
    ys, xs = np.mgrid[0:120:2, 0:120:2].astype(np.float64)
    pts = np.column_stack([xs.ravel(), ys.ravel()])
    slope, noise = 2e-3, 1e-3
    affine = np.zeros((len(pts), 6))
    affine[:, 1] = 1.0 + slope * pts[:, 0] + noise * rng.standard_normal(len(pts))
    affine[:, 5] = 1.0 + noise * rng.standard_normal(len(pts))
    radius = 20.0
    quad = second_order_terms(pts, affine, radius_px=radius)
    centre = np.flatnonzero((np.abs(pts - 60) < 10).all(1))
    for i in centre[:5]:
        ball = np.linalg.norm(pts - pts[i], axis=1) < radius  # cKDTree: strictly within
        design = np.column_stack([np.ones(ball.sum()), pts[ball] - pts[i]])
        coef = np.linalg.lstsq(design, affine[ball, 1], rcond=None)[0]
        resid = affine[ball, 1] - design @ coef
        se = np.sqrt(np.linalg.inv(design.T @ design)[1, 1] * resid @ resid
                     / (ball.sum() - 3))
        shrink = max(0.0, 1 - (se / coef[1]) ** 2)
        np.testing.assert_allclose(quad[i, 0], 0.5 * coef[1] * shrink, rtol=1e-9)
    # a ball of ~314 points: se(slope) ~ 1e-3 / (10 px sqrt(314)) = 6e-6, 0.3 % of 2e-3
    np.testing.assert_allclose(quad[centre, 0], slope / 2, rtol=0.03)


def _second_order_reference(points, affine, valid, radius, cap=512, min_neighbours=6):
    """The cKDTree formulation: the nearest <= cap valid points strictly within radius,
    one explicit least-squares plane per field, the terms' shrinkage - point by point."""
    from scipy.spatial import cKDTree

    fields = affine[:, [1, 2, 4, 5]]
    ok = np.isfinite(fields).all(1) & np.isfinite(points).all(1) & valid
    idx = np.flatnonzero(ok)
    out = np.zeros((len(points), 6))
    dist, nb = cKDTree(points[idx]).query(np.nan_to_num(points), k=min(cap, len(idx)),
                                          distance_upper_bound=radius)
    for i in np.flatnonzero(np.isfinite(points).all(1)):
        ball = idx[nb[i][np.isfinite(dist[i])]]
        if len(ball) < min_neighbours:
            continue
        design = np.column_stack([np.ones(len(ball)), points[ball] - points[i]])
        coef, *_ = np.linalg.lstsq(design, fields[ball], rcond=None)  # (3, 4)
        resid = fields[ball] - design @ coef
        inv = np.linalg.inv(design.T @ design)
        s2 = (resid ** 2).sum(0) / max(len(ball) - 3, 1)
        vx, vy = inv[1, 1] * s2, inv[2, 2] * s2
        q = 0.5 * np.array([coef[1, 0], coef[2, 0] + coef[1, 1], coef[2, 1],
                            coef[1, 2], coef[2, 2] + coef[1, 3], coef[2, 3]])
        se = 0.5 * np.sqrt([vx[0], vy[0] + vx[1], vy[1], vx[2], vy[2] + vx[3], vy[3]])
        with np.errstate(divide="ignore", invalid="ignore"):
            shrink = np.clip(1 - (se / q) ** 2, 0, 1)
        out[i] = np.where(np.isfinite(shrink), q * shrink, 0.0)
    return out


@pytest.mark.parametrize("step, jitter, radius", [(4, True, 22.5), (3, False, 15.0),
                                                  (1, False, 16.0)])
def test_second_order_terms_grid_hash_equals_the_kdtree_ball(step, jitter, radius):
    """The grid-hash ball search gives the terms of the cKDTree formulation: integer
    grid points put neighbours exactly on the radius (strictly-within excludes them),
    invalid and NaN points are skipped as neighbours, NaN centres give 0, and a 1 px
    grid holds ~680 valid points within 16 px, over the 512 cap (nearest 512 kept).  Only the
    arithmetic differs (normal equations vs lstsq): agreement to 1e-10 of the terms'
    scale, where one neighbour more or less moves a slope by ~1/N of its noise, ~1e-4."""
    rng = np.random.default_rng(step)
    ys, xs = np.mgrid[0:40 * step:step, 0:36 * step:step].astype(np.float64)
    pts = np.column_stack([xs.ravel(), ys.ravel()])
    if jitter:  # candidates are the best pixel of each cell: anywhere inside it
        pts += rng.integers(0, step, pts.shape)
    affine = np.zeros((len(pts), 6))
    affine[:, [1, 5]] = 1.0
    affine[:, [1, 2, 4, 5]] += (1e-3 * pts[:, [0]] * [1, -0.5, 0.2, 0.7] / step
                                + 1e-3 * rng.standard_normal((len(pts), 4)))
    valid = rng.random(len(pts)) < 0.85
    pts[rng.integers(0, len(pts), 5)] = np.nan
    affine[rng.integers(0, len(pts), 5), 2] = np.nan
    quad = second_order_terms(pts, affine, valid, radius_px=radius)
    ref = _second_order_reference(pts, affine, valid, radius)
    assert np.count_nonzero(ref) > 0.5 * ref.size  # most terms resolved (not shrunk to 0)
    np.testing.assert_allclose(quad, ref, rtol=0, atol=1e-10 * np.abs(ref).max())
