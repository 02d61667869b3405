"""section_trees' spanning trees, components and tree walks are scipy.sparse.csgraph's.

``surface.topology`` orders each section's points along a minimum spanning tree and
splits its loops by connected components; numba kernels replaced scipy's sparse-graph
calls there (whose set-up was most of their cost on the ~300 small graphs of a real
section stack).  They must give scipy's answers exactly: the same tree edges in the same
order (Kruskal's ties broken by a stable sort of the weights over the (row, col) order),
the same component labels, the same depth-first walk (the centres' trees against the
complete graph's: ``test_topology_mst.py``).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components, depth_first_order, minimum_spanning_tree

from surface import section_trees


def _random_graph(rng, n, m, ties):
    row = rng.integers(0, n, m)
    col = rng.integers(0, n, m)
    key = np.unique(row * n + col)
    key = key[key // n != key % n]                       # no self-loops
    key = rng.permutation(key)                            # any input order, either direction
    row, col = key // n, key % n
    weight = rng.integers(1, 5, len(key)).astype(float) if ties else rng.uniform(0.1, 1, len(key))
    return row, col, weight


@pytest.mark.parametrize("seed", range(8))
@pytest.mark.parametrize("ties", [False, True])
def test_spanning_tree_is_scipys(seed, ties):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(5, 80))
    row, col, weight = _random_graph(rng, n, 4 * n, ties)
    want = minimum_spanning_tree(coo_matrix((weight, (row, col)), shape=(n, n)).tocsr()).tocoo()
    got = section_trees._spanning_tree(n, row, col, weight)
    assert np.array_equal(got.row, want.row) and np.array_equal(got.col, want.col)
    assert np.array_equal(got.data, want.data)


@pytest.mark.parametrize("seed", range(6))
def test_components_are_scipys(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(5, 120))
    row, col, _ = _random_graph(rng, n, n // 2, False)   # sparse: many components
    want_count, want = connected_components(coo_matrix((np.ones(len(row)), (row, col)),
                                                       shape=(n, n)), directed=False)
    got = section_trees._components(n, row.astype(np.int64), col.astype(np.int64))
    assert np.array_equal(got, want) and got.max() + 1 == want_count > 3


@pytest.mark.parametrize("seed", range(8))
def test_tree_walk_is_scipys_depth_first_order(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(5, 90))
    row, col, weight = _random_graph(rng, n, 5 * n, seed % 2 == 1)
    tree = section_trees._spanning_tree(n, row, col, weight)
    matrix = coo_matrix((tree.data, (tree.row, tree.col)), shape=(n, n)).tocsr()
    for start in rng.integers(0, n, 4):
        want, _ = depth_first_order(matrix, i_start=int(start), directed=False)
        got = section_trees._tree_walk(n, tree.row, tree.col, int(start))
        assert np.array_equal(got, want)
