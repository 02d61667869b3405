"""section_trees._centre_mst: the Delaunay-edge MST equals the complete graph's, ties included.

Kruskal in scipy breaks weight ties by the edges' row-major position; the
Delaunay subgraph keeps the complete graph's orientation (row < column) and
order, so tree, stored order and depth-first walk (``section_trees._tree_walk``, against
scipy's ``depth_first_order`` of the dense graph's tree) must come out identical.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import depth_first_order, minimum_spanning_tree

from surface import section_trees
from surface.validate import TOL


def _dense_tree(points):
    """scipy's tree of the complete graph: every ordered pair, distances floored at
    TOL.zero x the largest.  (A dense matrix would not do: scipy's ``csgraph_from_dense``
    drops entries within 1e-8 of zero, absolute, so coincident centres lost their edge
    there — the code's fallback did that until 2026-12-06.)"""
    n = len(points)
    dist = np.linalg.norm(points[:, None, :] - points[None, :, :], axis=2)
    row, col = np.nonzero(~np.eye(n, dtype=bool))
    weight = np.maximum(dist, TOL.zero * max(dist.max(), TOL.zero))[row, col]
    return minimum_spanning_tree(coo_matrix((weight, (row, col)), shape=(n, n)).tocsr())


def _assert_same_tree(points):
    got, want = section_trees._centre_mst(points), _dense_tree(points)
    coo = want.tocoo()
    assert np.array_equal(got.row, coo.row) and np.array_equal(got.col, coo.col)
    assert np.array_equal(got.data, coo.data)
    for start in (0, len(points) // 2):
        assert np.array_equal(section_trees._tree_walk(len(points), got.row, got.col, start),
                              depth_first_order(want, start, directed=False)[0])


@pytest.mark.parametrize("seed", range(5))
def test_random_fold_shaped_centres(seed):
    rng = np.random.default_rng(seed)
    phi = np.sort(rng.uniform(0, 2 * np.pi, 300))
    radius = 1.0 + 0.4 * np.sin(5 * phi)  # a star with deep folds
    points = np.stack([radius * np.cos(phi), radius * np.sin(phi)], axis=1)
    _assert_same_tree(points + rng.normal(scale=0.01, size=points.shape))


@pytest.mark.parametrize("shape", [(6, 7), (12, 3)])
def test_grid_with_many_equal_distances(shape):
    """Every edge of a grid ties with many others: the tie-break must be the dense one."""
    i, j = np.meshgrid(np.arange(shape[0]), np.arange(shape[1]), indexing="ij")
    points = np.stack([i.ravel(), j.ravel()], axis=1).astype(np.float64)
    _assert_same_tree(points[np.random.default_rng(1).permutation(len(points))])


def test_collinear_and_coincident_centres_take_the_complete_graph():
    line = np.stack([np.linspace(0, 1, 20), np.zeros(20)], axis=1)
    _assert_same_tree(line)
    twice = np.concatenate([line[:5] + [0, 1], line[:5] + [0, 1]])  # coincident pairs
    _assert_same_tree(np.concatenate([twice, [[0.5, 3.0], [0.2, -1.0]]]))


def _qhull_mst(uv, monkeypatch):
    with monkeypatch.context() as patch:
        patch.setattr(section_trees, "_triangle_edges", lambda uv: None)  # the qhull graph
        return section_trees._mst(uv, float(np.ptp(uv, axis=0).max()))


@pytest.mark.parametrize("case", ["noisy ring", "grid ties", "duplicates", "collinear"])
def test_section_mst_from_triangle_equals_qhull(case, monkeypatch):
    rng = np.random.default_rng(7)
    if case == "noisy ring":
        phi = rng.uniform(0, 2 * np.pi, 800)
        uv = np.stack([np.cos(phi), 0.6 * np.sin(phi)], 1) + rng.normal(scale=0.01, size=(800, 2))
    elif case == "grid ties":
        i, j = np.meshgrid(np.arange(9), np.arange(7), indexing="ij")
        uv = np.stack([i.ravel(), j.ravel()], 1).astype(np.float64)
    elif case == "duplicates":  # Triangle drops them: qhull's path joins them instead
        uv = rng.normal(size=(200, 2))
        uv = np.concatenate([uv, uv[:5]])
    else:
        uv = np.stack([np.linspace(0, 1, 30), np.linspace(0, 2, 30)], 1)
    if case in ("duplicates", "collinear"):
        assert section_trees._triangle_edges(uv) is None
    got = section_trees._mst(uv, float(np.ptp(uv, axis=0).max()))
    want = _qhull_mst(uv, monkeypatch)
    assert np.array_equal(got.row, want.row) and np.array_equal(got.col, want.col)
    assert np.array_equal(got.data, want.data)
