"""Even-odd point-in-polygon test of many points against one closed 2-D ring, exact and batched.

Shared by the stitch's caps and ends (:mod:`surface.stitch`), the loop graph's nesting
(:mod:`surface.loop_graph`) and the sections' organisation (:mod:`surface.reconstruct`).  Points
``(P, 2) float64`` and the ring ``(n, 2) float64`` in one plane's coordinates; the ring's last point
joins its first (not repeated).
"""

from __future__ import annotations

import numpy as np

__all__ = ["INSIDE_PAIRS", "inside_polygon", "polygon_area"]


#: Point-edge pairs :func:`inside_polygon` forms at once (about 60 bytes each: bounds its memory).
INSIDE_PAIRS = 1 << 21


def inside_polygon(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """Even-odd point-in-polygon test, ``(P, 2)`` points against an ``(n, 2)`` ring.

    A point's rightward ray crosses edge (p0, p1) when ``min(y0, y1) <= y <
    max(y0, y1)`` and ``x`` is left of the edge's x at that height.  With the
    points sorted by y, each edge's candidates are one run of the sorted order
    (``searchsorted``), so only the straddling (point, edge) pairs are formed,
    about two a point on a star-shaped ring instead of all P n of them, in
    batches of at most :data:`INSIDE_PAIRS` pairs; each pair's crossing is the
    same expression as the dense test's, so the answer is the same bit for bit.

    Returns
    -------
    (P,) bool
    """
    count = len(points)
    if count == 0 or len(polygon) == 0:
        return np.zeros(count, bool)
    x, y = points[:, 0], points[:, 1]
    order = np.argsort(y, kind="stable")
    x0, y0 = polygon[:, 0], polygon[:, 1]                        # (n,)
    x1, y1 = np.roll(x0, -1), np.roll(y0, -1)
    dy = np.where(y1 == y0, 1.0, y1 - y0)
    start = np.searchsorted(y[order], np.minimum(y0, y1), side="left")
    runs = np.searchsorted(y[order], np.maximum(y0, y1), side="left") - start
    edges = np.flatnonzero(runs > 0)
    ends = np.cumsum(runs[edges])
    batch = (ends - runs[edges]) // INSIDE_PAIRS                 # batch of each edge's first pair
    crossings = np.zeros(count, np.int64)
    for b in np.unique(batch):
        e = edges[batch == b]
        run = runs[e]
        edge = np.repeat(e, run)                                 # (pairs,)
        first = np.cumsum(run) - run
        point = order[np.arange(len(edge)) - np.repeat(first - start[e], run)]
        x_cross = x0[edge] + (y[point] - y0[edge]) * (x1[edge] - x0[edge]) / dy[edge]
        crossings += np.bincount(point[x[point] < x_cross], minlength=count)
    return crossings % 2 == 1


def polygon_area(polygon: np.ndarray) -> float:
    """Area of the closed ring ``polygon`` ``(n, 2)`` (shoelace; its last point joins its
    first)."""
    x, y = polygon[:, 0], polygon[:, 1]
    x1, y1 = np.concatenate([x[1:], x[:1]]), np.concatenate([y[1:], y[:1]])
    return 0.5 * abs(float(np.sum(x * y1 - x1 * y)))
