"""surface.stitch's dome height field: local quadratics, their variance, and how many
points each height is fitted to (Lepski's rule, :func:`surface.stitch._dome_neighbours`)."""

from __future__ import annotations

import numpy as np
import pytest

from surface.stitch import DOME_MAX_NEIGHBOURS, _dome_neighbours, _local_quadratic

SIGMA = 0.002


def _disk(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    r, t = np.sqrt(rng.uniform(0, 1, n)), rng.uniform(0, 2 * np.pi, n)
    return np.column_stack([r * np.cos(t), r * np.sin(t)])


def test_local_quadratic_variance_is_the_scatter_of_its_heights():
    """The returned variance factor σ²(NᵀN)⁻¹₀₀ against 200 noise draws: the empirical
    variance over the predicted one has median 0.99 (5-95 %: 0.84-1.13) at 200 query
    points, interior and on the rim; a paraboloid is reproduced exactly."""
    flat = _disk(20_000, seed=0)
    shape = 0.3 * (flat ** 2).sum(axis=1)
    query = flat[:200]
    exact, var = _local_quadratic(flat, shape, query, 96, variance=True)
    assert np.abs(exact - shape[:200]).max() < 1e-10
    draws = np.array([_local_quadratic(flat, shape + np.random.default_rng(s).normal(
        0, SIGMA, len(flat)), query, 96) for s in range(200)])
    ratio = draws.var(axis=0) / (SIGMA ** 2 * var)
    assert 0.9 < np.median(ratio) < 1.1
    assert np.percentile(ratio, 95) < 1.35 and np.percentile(ratio, 5) > 0.7


@pytest.mark.parametrize("frequency, best_at_most", [(8, DOME_MAX_NEIGHBOURS), (12, 192),
                                                     (24, 96)])
def test_dome_neighbours_follow_the_shape(frequency, best_at_most):
    """A paraboloid with a ripple of amplitude 5σ: the wider the ripple, the more points
    a height may average.  Measured (RMS error at 512 points against the truth, k = 48 /
    96 / 192 / 384): frequency 8: 0.00058 / 0.00043 / 0.00029 / 0.00025, chosen 384;
    12: 0.00058 / 0.00043 / 0.00032 / 0.00051, chosen 192; 24: 0.00061 / 0.00062 /
    0.00140 / 0.00334, chosen 96.  The chosen k's error is within 15 % of the best of the
    four, and under half the narrowest fit's error where the ripple allows (0.43)."""
    flat = _disk(20_000, seed=0)
    rng = np.random.default_rng(1)
    truth = 0.3 * (flat ** 2).sum(axis=1) + 0.01 * np.sin(frequency * flat[:, 0]) * np.sin(
        frequency * flat[:, 1])
    h = truth + rng.normal(0, SIGMA, len(flat))
    test = flat[:512]
    k = _dome_neighbours(flat, h, test, SIGMA)
    assert k <= best_at_most
    errors = {kk: float(np.sqrt(np.mean((_local_quadratic(flat, h, test, kk)
                                         - truth[:512]) ** 2))) for kk in (48, 96, 192, 384)}
    assert errors[k] <= 1.15 * min(errors.values())
    if frequency == 8:
        assert errors[k] < 0.5 * errors[48]


def test_no_noise_estimate_keeps_the_narrowest_fit():
    flat = _disk(2_000, seed=2)
    assert _dome_neighbours(flat, np.zeros(len(flat)), flat[:100], 0.0) == 48


def test_a_capsule_pole_averages_more_points():
    """3·10⁴ points on a capsule (σ = 0.002): the dome vertices within 0.1 of the poles
    lie 0.00025 / 0.00026 RMS off the sphere (k = 192 chosen) where every height fitted to
    48 points gave 0.00059 / 0.00061."""
    from surface.reconstruct import surface_from_points
    from tests.surface.test_extrapolate import _capsule_cloud

    mesh = surface_from_points(_capsule_cloud(30_000, SIGMA, seed=4), axis="z")
    v = mesh.vertices
    for poles, centre in ((v[:, 2] < -0.9, 0.0), (v[:, 2] > 2.9, 2.0)):
        radial = np.linalg.norm(v[poles] - [0, 0, centre], axis=1) - 1
        assert poles.sum() > 1000
        assert np.sqrt(np.mean(radial ** 2)) < 0.00035
