"""The stitch's cap helpers at cloud scale: the even-odd test over the
straddling pairs only, the batched local quadratics and the sampled dome test give
the answers of their all-at-once forms."""

import numpy as np
import pytest

import surface.polygon as polygon_module
import surface.stitch.caps as stitch_caps
from surface.stitch import _dome, _inside, _local_quadratic

FRAME = np.eye(3)  # plane axes x, y; the axis z


def _inside_all_pairs(points, polygon):
    """The dense P x n even-odd test (the form it replaced), as the reference."""
    x, y = points[:, 0:1], points[:, 1:2]
    x0, y0 = polygon[:, 0], polygon[:, 1]
    x1, y1 = np.roll(x0, -1), np.roll(y0, -1)
    straddle = (y0 > y) != (y1 > y)
    dy = np.where(y1 == y0, 1.0, y1 - y0)
    x_cross = x0 + (y - y0) * (x1 - x0) / dy
    return np.count_nonzero(straddle & (x < x_cross), axis=1) % 2 == 1


@pytest.mark.parametrize("pairs", [1, 37, 1 << 21])
@pytest.mark.parametrize("seed", range(6))
def test_inside_equals_all_pairs_test(monkeypatch, seed, pairs):
    # Star-shaped, self-intersecting and grid-snapped polygons (points on vertices and
    # on horizontal edges), batches of 1 pair up to one batch: the same answer, exactly.
    monkeypatch.setattr(polygon_module, "INSIDE_PAIRS", pairs)
    rng = np.random.default_rng(seed)
    n = int(rng.integers(3, 80))
    theta = np.sort(rng.random(n)) * 2 * np.pi
    r = 1.0 + 0.5 * rng.random(n)
    polygons = [np.c_[r * np.cos(theta), r * np.sin(theta)], rng.normal(size=(n, 2)),
                np.round(rng.normal(size=(n, 2)) * 4) / 4]
    points = rng.uniform(-1.6, 1.6, (2000, 2))
    points[:500] = np.round(points[:500] * 4) / 4
    for polygon in polygons:
        np.testing.assert_array_equal(_inside(points, polygon),
                                      _inside_all_pairs(points, polygon))


def test_inside_regular_polygon_known_answer():
    # A regular 1000-gon of circumradius 1 contains the disk of radius cos(pi/1000)
    # and nothing beyond radius 1.
    theta = 2 * np.pi * np.arange(1000) / 1000
    polygon = np.c_[np.cos(theta), np.sin(theta)]
    rng = np.random.default_rng(1)
    radius = rng.uniform(0.0, 1.5, 50_000)
    angle = rng.uniform(0.0, 2 * np.pi, 50_000)
    points = np.c_[radius * np.cos(angle), radius * np.sin(angle)]
    got = _inside(points, polygon)
    assert got[radius < np.cos(np.pi / 1000) - 1e-12].all()
    assert not got[radius > 1.0 + 1e-12].any()
    assert _inside(np.zeros((0, 2)), polygon).shape == (0,)


def test_local_quadratic_batches_give_one_batch_answer(monkeypatch):
    # Each query point's fit is its own: batches of 7 give one batch's heights (to
    # rounding: einsum may block differently), and an exact quadratic is reproduced.
    rng = np.random.default_rng(2)
    flat = rng.uniform(-1, 1, (3000, 2))
    h = 0.3 + 0.2 * flat[:, 0] - 0.1 * flat[:, 1] + 0.5 * flat[:, 0] ** 2 \
        - 0.25 * flat[:, 0] * flat[:, 1] + 0.4 * flat[:, 1] ** 2
    noisy = h + rng.normal(0.0, 0.01, len(h))
    query = rng.uniform(-0.9, 0.9, (500, 2))
    monkeypatch.setattr(stitch_caps, "QUADRATIC_BATCH", 10 ** 6)
    whole = _local_quadratic(flat, noisy, query, 48)
    exact = _local_quadratic(flat, h, query, 48)
    monkeypatch.setattr(stitch_caps, "QUADRATIC_BATCH", 7)
    np.testing.assert_allclose(_local_quadratic(flat, noisy, query, 48), whole,
                               rtol=0, atol=1e-12)
    truth = 0.3 + 0.2 * query[:, 0] - 0.1 * query[:, 1] + 0.5 * query[:, 0] ** 2 \
        - 0.25 * query[:, 0] * query[:, 1] + 0.4 * query[:, 1] ** 2
    np.testing.assert_allclose(exact, truth, rtol=0, atol=1e-8)


def _disk_cap(count, dome, seed):
    """``count`` cap points over the unit disk at z = 1 + dome (1 - r²) plus σ = 0.002."""
    rng = np.random.default_rng(seed)
    radius = np.sqrt(rng.random(count))
    angle = rng.uniform(0.0, 2 * np.pi, count)
    x, y = radius * np.cos(angle), radius * np.sin(angle)
    z = 1.0 + dome * (1.0 - radius ** 2) + rng.normal(0.0, 0.002, count)
    return np.c_[x, y, z]


@pytest.mark.parametrize("count", [5_000, 60_000])
def test_dome_test_on_sampled_points(count):
    # More cap points than DOME_TEST_POINTS (60 000): the test fits its quadratics at
    # a sample of them and still tells a flat end (spread ratio ~1) from a dome of
    # height 0.05 (plane residual spread ~0.015 against noise 0.002, ratio ~7).
    theta = 2 * np.pi * np.arange(400) / 400
    ring = 1.02 * np.c_[np.cos(theta), np.sin(theta)]
    assert count < stitch_caps.DOME_TEST_POINTS or count > 2 * stitch_caps.DOME_TEST_POINTS
    assert _dome(ring, 0.9, 1.2, _disk_cap(count, 0.0, 3), FRAME) is None
    height = _dome(ring, 0.9, 1.2, _disk_cap(count, 0.05, 4), FRAME)
    assert height is not None
    query = np.array([[0.0, 0.0], [0.5, 0.0], [0.0, -0.7]])
    truth = 1.0 + 0.05 * (1.0 - (query ** 2).sum(axis=1))
    # σ/4 per fit (48 points; DOME_NEIGHBOURS' note): 0.0005, 6 σ bound
    np.testing.assert_allclose(height(query), truth, rtol=0, atol=0.003)


def test_pca_normals_denser_than_the_noise_use_a_subset(monkeypatch):
    # A plane z = 0 with σ = 0.002 sampled at spacing ~0.0009 (well below σ): the
    # 12-neighbour fits of the whole cloud see the noise (median tilt ~40°); on a
    # subset of 1/16 (spacing ~0.0035) they see the plane again, and so do the default
    # neighbours chosen from the noise.  At or below NORMAL_POINTS the normals are the
    # whole cloud's.
    from surface import section_slicing as slicing

    rng = np.random.default_rng(5)
    cloud = np.c_[rng.uniform(0, 0.3, (120_000, 2)), rng.normal(0.0, 0.002, 120_000)]
    query = np.arange(0, 120_000, 7)

    def median_tilt(normals):
        return float(np.degrees(np.median(np.arccos(np.abs(normals[:, 2])))))

    whole = slicing._pca_normals(cloud, query, k=12)
    # the default neighbours follow the noise (reconstruct.normal_neighbours) and see the
    # plane on the whole cloud too
    assert slicing.normal_neighbours(cloud) > 12
    assert median_tilt(slicing._pca_normals(cloud, query)) < 0.6 * median_tilt(whole)
    monkeypatch.setattr(slicing, "NORMAL_POINTS", 7_500)
    subset = slicing._pca_normals(cloud, query, k=12)
    assert median_tilt(whole) > 25.0
    assert median_tilt(subset) < 0.6 * median_tilt(whole)
    monkeypatch.setattr(slicing, "NORMAL_POINTS", 120_000)
    np.testing.assert_array_equal(slicing._pca_normals(cloud, query, k=12), whole)
