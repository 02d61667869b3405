"""Edge-crossing tests of closed polygons in the plane: one loop crossing itself, two
loops crossing each other (candidate pairs from a k-d tree, the exact orientation test)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


def self_intersects(uv: np.ndarray) -> bool:
    """Whether the closed polygon ``uv`` ``(n, 2)`` crosses itself (:func:`_edges_cross`
    over its non-adjacent edges; edges that only touch or overlap along a line do not
    count)."""
    return len(uv) >= 4 and _edges_cross([uv], between_loops=False)


def loops_cross(uvs: list) -> bool:
    """Whether two of the closed polygons ``uvs`` (each ``(n, 2)``: one section's loops)
    cross each other (:func:`_edges_cross` over pairs of edges from different loops;
    loops that only touch do not count)."""
    loops = [uv for uv in uvs if len(uv) >= 3]
    return len(loops) >= 2 and _edges_cross(loops, between_loops=True)


def _edges_cross(loops: list, between_loops: bool) -> bool:
    """Whether two edges of the closed polygons ``loops`` cross: pairs from different
    loops (``between_loops``) or non-adjacent pairs of one loop.  Two edges that cross
    have midpoints closer than the longest edge: candidate pairs come from a k-d tree of
    the midpoints (``cKDTree.query_pairs``), each tested exactly by the signs of its four
    orientations."""
    loops = [np.asarray(uv, dtype=np.float64) for uv in loops]
    a = np.concatenate(loops)
    b = np.concatenate([np.roll(uv, -1, axis=0) for uv in loops])
    sizes = np.array([len(uv) for uv in loops])
    owner = np.repeat(np.arange(len(loops)), sizes)
    longest = float(np.linalg.norm(b - a, axis=1).max())
    pairs = cKDTree(0.5 * (a + b)).query_pairs(longest, output_type="ndarray")
    i, j = pairs[:, 0], pairs[:, 1]
    if between_loops:
        keep = owner[i] != owner[j]
    else:                                   # one loop: not sharing a vertex
        step = np.abs(i - j)
        keep = (owner[i] == owner[j]) & (step != 1) & (step != sizes[owner[i]] - 1)
    i, j = i[keep], j[keep]

    def orientation(p, q, r):
        return np.sign((q[:, 0] - p[:, 0]) * (r[:, 1] - p[:, 1])
                       - (q[:, 1] - p[:, 1]) * (r[:, 0] - p[:, 0]))

    crosses = ((orientation(a[i], b[i], a[j]) * orientation(a[i], b[i], b[j]) < 0)
               & (orientation(a[j], b[j], a[i]) * orientation(a[j], b[j], b[i]) < 0))
    return bool(crosses.any())
