"""Tiling the strip between two rings: by angle (:func:`zip_rings`), or by the shortest
total span (:func:`tile_min_span`, Fuchs, Kedem and Uselton 1977)."""

from __future__ import annotations

import numba
import numpy as np
from scipy.spatial import cKDTree

from surface.polygon import inside_polygon as _inside
from surface.stitch.checks import loops_cross
from surface.validate import TOL, check_finite, check_shape
from surface.validity import self_intersections

__all__ = ['zip_rings', 'axis_frame']

# --------------------------------------------------------------------------- frames and parameters
def axis_frame(axis: np.ndarray) -> np.ndarray:
    """Right-handed orthonormal frame ``(3, 3)``, rows ``e1, e2, axis/|axis|``."""
    a = check_shape(axis, "(3,)", "axis", dtype=np.float64)
    check_finite(a, "axis")
    norm = float(np.linalg.norm(a))
    if norm <= TOL.zero:
        raise ValueError(f"axis must have non-zero length, got {a.tolist()}")
    a = a / norm
    helper = np.eye(3)[int(np.argmin(np.abs(a)))]
    e1 = np.cross(helper, a)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(a, e1)
    return np.stack([e1, e2, a])


def _ring_order_and_parameter(ring2d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Counter-clockwise order and absolute merge parameter of one planar ring.

    Parameters
    ----------
    ring2d : (n, 2) float64
        Ring points in the section plane's (e1, e2) coordinates.

    Returns
    -------
    order : (n,) int64
        Index permutation making the ring counter-clockwise, ``order[0] == 0``.
    param : (n,) float64
        Increasing parameter of ``ring2d[order]``, in turns: the polar angle
        about the ring centroid over 2π when the ring is star-shaped about it,
        otherwise the normalised arc length, both offset by the angle of the
        first point so that rings are aligned by direction.
    """
    n = len(ring2d)
    x, y = ring2d[:, 0], ring2d[:, 1]
    twice_area = float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))
    order = np.arange(n)
    if twice_area < 0:
        order = np.concatenate([[0], np.arange(n - 1, 0, -1)])
    pts = ring2d[order]
    centre = pts.mean(axis=0)
    theta = np.arctan2(pts[:, 1] - centre[1], pts[:, 0] - centre[0])
    step = np.mod(np.diff(theta), 2 * np.pi)
    star = bool(np.all(step > TOL.angle)) and float(step.sum()) < 2 * np.pi
    if star:
        relative = np.concatenate([[0.0], np.cumsum(step)]) / (2 * np.pi)
    else:
        chord = np.linalg.norm(np.diff(np.vstack([pts, pts[:1]]), axis=0), axis=1)
        relative = np.concatenate([[0.0], np.cumsum(chord[:-1])]) / chord.sum()
    return order, theta[0] / (2 * np.pi) + relative


# --------------------------------------------------------------------------- side strips
def zip_rings(param_lower: np.ndarray, param_upper: np.ndarray) -> np.ndarray:
    """Triangulate the strip between two closed rings by merging their parameters.

    Parameters
    ----------
    param_lower : (n_a,) float64
        Increasing angular parameter (in turns) of the lower ring, counter-
        clockwise about the axis; its span is less than one turn.
    param_upper : (n_b,) float64
        The same for the upper ring, in the same angular frame.

    Returns
    -------
    (n_a + n_b, 3) int64
        Faces over local indices: lower ring ``0 .. n_a - 1``, upper ring
        ``n_a .. n_a + n_b - 1``; outward (away from the axis) when the rings
        run counter-clockwise and the upper ring lies further along the axis.

    Notes
    -----
    The upper ring is started at its point closest in angle to the lower
    ring's first point; every later step adds the triangle that advances the
    ring whose next point comes first.  Ties (within ``TOL.angle``) advance the
    coarser ring first: for ``n_b = 2 n_a`` this is exactly the paper's
    (o_k, e_2k, e_2k+1), (o_k, e_2k+1, o_k+1), (o_k+1, e_2k+1, e_2k+2).
    """
    n_a, n_b = len(param_lower), len(param_upper)
    u_a = param_lower - param_lower[0]
    rel_b = np.mod(param_upper - param_lower[0], 1.0)
    start = int(np.argmin(np.minimum(rel_b, 1.0 - rel_b)))
    index_b = np.roll(np.arange(n_b), -start)
    u_b = np.mod(param_upper[index_b] - param_lower[0], 1.0)
    u_b = u_b[0] - 1.0 * (u_b[0] > 0.5) + np.concatenate(
        [[0.0], np.cumsum(np.mod(np.diff(u_b), 1.0))])
    # Events: each ring's points 1..n and its closing step back to point 0.
    ev_a = np.append(u_a[1:], 1.0)
    ev_b = np.append(u_b[1:], u_b[0] + 1.0)
    tie = TOL.angle / (2 * np.pi)
    bias_a = tie if n_a <= n_b else 0.0  # the coarser (or the lower, if equal) goes first
    bias_b = 0.0 if n_a <= n_b else tie
    keys = np.concatenate([ev_a - bias_a, ev_b - bias_b])
    is_a = np.concatenate([np.ones(n_a, bool), np.zeros(n_b, bool)])
    order = np.argsort(keys, kind="stable")
    is_a = is_a[order]
    i_a = np.cumsum(is_a) - is_a        # lower-ring position before each event
    i_b = np.cumsum(~is_a) - ~is_a      # upper-ring position before each event
    a0 = i_a % n_a
    a1 = (i_a + 1) % n_a
    b0 = n_a + index_b[i_b % n_b]
    b1 = n_a + index_b[(i_b + 1) % n_b]
    return np.where(is_a[:, None],
                    np.stack([a0, a1, b0], axis=1),
                    np.stack([a0, b1, b0], axis=1)).astype(np.int64)


def _nested_angles(lower: np.ndarray, upper: np.ndarray) -> tuple | None:
    """Both counter-clockwise rings' angles (in turns) about the inner one's centroid,
    when one lies inside the other and both are star-shaped about that point; else None.

    A branch's loop inside its bridged sub-loop (a horn in a head's outline) is tiled by
    these angles (:func:`zip_rings`): the shortest-span tiling between a small dense loop
    and a large sparse one fans the small loop to one far point and the large one to a
    few points behind it, and the fans cross (the noisy cow's horn: 68 pairs).
    """
    def area(ring):
        return float(np.sum(ring[:, 0] * np.roll(ring[:, 1], -1)
                            - np.roll(ring[:, 0], -1) * ring[:, 1]))
    inner, outer = (lower, upper) if area(lower) < area(upper) else (upper, lower)
    if not _inside(inner, outer).all():
        return None
    return _angles_about(lower, upper, inner.mean(axis=0))


def _common_angles(lower: np.ndarray, upper: np.ndarray) -> tuple | None:
    """Both counter-clockwise rings' angles (in turns) about one point, halfway between
    their centroids, when both are star-shaped about it; else None.

    The direction criterion's angle is one for the whole strip.  Each ring's angle about
    its own centroid is not: the centroid (a mean of the points) follows the ring's
    sampling, and two rings of one wall sampled unlike (a support ring carrying the
    bottom ring's points beside one carrying the next ring's) were zipped a few degrees
    apart, their faces sheared along the wall and crossing (the temple ring's bottom
    strips: 5 pairs, rings 0.009 apart in centroid, 0.0006 in height).
    """
    return _angles_about(lower, upper, 0.5 * (lower.mean(axis=0) + upper.mean(axis=0)))


def _angles_about(lower: np.ndarray, upper: np.ndarray, centre: np.ndarray) -> tuple | None:
    """Both rings' increasing polar angles (in turns) about ``centre``, or None where a
    ring is not star-shaped about it."""
    params = []
    for ring in (lower, upper):
        theta = np.arctan2(ring[:, 1] - centre[1], ring[:, 0] - centre[0])
        step = np.mod(np.diff(theta), 2 * np.pi)
        if not (np.all(step > TOL.angle) and float(step.sum()) < 2 * np.pi):
            return None
        params.append(theta[0] / (2 * np.pi)
                      + np.concatenate([[0.0], np.cumsum(step)]) / (2 * np.pi))
    return params[0], params[1]


def _star_shaped(ring2d: np.ndarray) -> bool:
    """Whether a counter-clockwise ring's polar angle about its centroid increases.

    The test :func:`_ring_order_and_parameter` makes before taking the angle as
    the ring's parameter (otherwise it falls back to the arc length).
    """
    theta = np.arctan2(ring2d[:, 1] - ring2d[:, 1].mean(), ring2d[:, 0] - ring2d[:, 0].mean())
    step = np.mod(np.diff(theta), 2 * np.pi)
    return bool(np.all(step > TOL.angle)) and float(step.sum()) < 2 * np.pi


MIN_SPAN_STARTS = 4
"""Start pairs :func:`tile_min_span` tries, spread evenly round the lower ring."""
MIN_SPAN_TIE = 1e-9
"""Relative shortening another start's tiling needs to replace the closest pair's: the
same tiling from another start sums its spans in another order (rounding)."""


@numba.njit(cache=True, nogil=True)
def _min_span_moves(a: np.ndarray, b: np.ndarray, a2: np.ndarray, b2: np.ndarray,
                    side_a: np.ndarray, side_b: np.ndarray,
                    penalty: float) -> np.ndarray:  # pragma: no cover - numba
    """Moves of the shortest monotone path through the span lengths ``|a_i - b_j|``.

    ``D[i, j] = |a_(i mod n) - b_(j mod m)| + min(D[i-1, j] + p_a, D[i, j-1] + p_b)`` from
    ``(0, 0)`` to ``(n, m)``; returns ``n + m`` moves, 1 advancing ``a``, 0 ``b``.  The
    move's triangle pays ``penalty`` where, in the plan ``a2``, ``b2``, its third vertex
    lies on the wrong side of its ring edge (``side_a[i]``, ``side_b[j]``: the sign the
    cross product of edge ``i -> i+1`` and the other ring's vertex should have; 0: any).
    """
    n, m = a.shape[0], b.shape[0]
    cost = np.full((n + 1, m + 1), np.inf)
    came_a = np.zeros((n + 1, m + 1), np.bool_)
    cost[0, 0] = 0.0
    for i in range(n + 1):
        for j in range(m + 1):
            if i == 0 and j == 0:
                continue
            d = 0.0
            for k in range(3):
                d += (a[i % n, k] - b[j % m, k]) ** 2
            d = np.sqrt(d)
            from_a = np.inf
            if i > 0:
                from_a = cost[i - 1, j]
                p, q, r = a2[(i - 1) % n], a2[i % n], b2[j % m]
                o = (q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0])
                if o * side_a[(i - 1) % n] < 0.0:
                    from_a += penalty
            from_b = np.inf
            if j > 0:
                from_b = cost[i, j - 1]
                p, q, r = b2[(j - 1) % m], b2[j % m], a2[i % n]
                o = (q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0])
                if o * side_b[(j - 1) % m] < 0.0:
                    from_b += penalty
            came_a[i, j] = from_a <= from_b
            cost[i, j] = d + min(from_a, from_b)
    moves = np.empty(n + m, np.bool_)
    i, j = n, m
    for step in range(n + m - 1, -1, -1):
        moves[step] = came_a[i, j]
        if came_a[i, j]:
            i -= 1
        else:
            j -= 1
    return moves


def _edge_sides(ring2d: np.ndarray, other2d: np.ndarray) -> np.ndarray:
    """``(n,)`` the sign the plan cross product of ``ring2d``'s edge ``i -> i+1`` and a
    vertex of ``other2d`` tiled to it should have: towards the side where the other ring
    lies near that edge (its nearest point to the edge's midpoint inside or outside
    ``ring2d``), so that the strip's faces cover the plan between the rings once; 0 for
    a degenerate ring."""
    area2 = float(np.sum(ring2d[:, 0] * np.roll(ring2d[:, 1], -1)
                         - np.roll(ring2d[:, 0], -1) * ring2d[:, 1]))
    if len(ring2d) < 3 or len(other2d) < 3 or area2 == 0.0:
        return np.zeros(len(ring2d))
    mid = 0.5 * (ring2d + np.roll(ring2d, -1, axis=0))
    near = other2d[cKDTree(other2d).query(mid)[1]]
    inside = _inside(near, ring2d)
    return np.where(inside, 1.0, -1.0) * np.sign(area2)


def tile_min_span(lower: np.ndarray, upper: np.ndarray,
                  axis: np.ndarray | None = None) -> np.ndarray:
    """Triangulate the strip between two closed rings by the shortest total span.

    The optimal tiling of Fuchs, Kedem and Uselton (1977) [5]_ as a shortest
    path in the toroidal graph of spans (edges from a lower to an upper ring
    point), here with the sum of the spans' lengths as the cost (the
    "shortest diagonal" criterion of Christiansen and Sederberg 1978, made
    global by dynamic programming): O(n_a n_b), started at the closest pair of
    points.  Used where a ring is not star-shaped about its centroid (a
    branch's bump on a wall): there the angle is no parameter, and the arc
    length fraction of two rings whose bumps differ in size drifts, twisting
    the strip across the wall (the mug's and amphora's handle joins).

    With the ``axis``, a face whose third vertex lies, in the plan, on the side of its
    ring edge away from the other ring (there: :func:`_edge_sides`) costs more than any
    tiling without one: the strip then covers the plan between the rings once where it
    can.  A ring with a narrow spike the other lacks was fanned from one point over both
    sides of the spike, the far side's faces folded over the near side's (the temple
    ring's top: 179 crossing pairs).

    Parameters
    ----------
    lower, upper : (n_a, 3), (n_b, 3) float64
        The rings, both counter-clockwise about the axis, ``upper`` further
        along it.
    axis : (3,) float64, optional
        The section normal (the plan is the plane across it).  Without it, span
        lengths alone.

    Returns
    -------
    (n_a + n_b, 3) int64
        Faces over local indices as :func:`zip_rings`'s (lower ``0 .. n_a - 1``,
        upper ``n_a ..``), oriented the same way.

    References
    ----------
    .. [5] H. Fuchs, Z. M. Kedem, S. P. Uselton, "Optimal surface
       reconstruction from planar contours", Communications of the ACM 20
       (1977), 693-702.
    """
    lower = np.asarray(lower, np.float64)
    upper = np.asarray(upper, np.float64)
    n_a = len(lower)
    gap, nearest = cKDTree(upper).query(lower)
    i0 = int(np.argmin(gap))
    # The path is forced through its start pair.  The closest pair can sit at a pinch
    # (a spur's or a stick's root, where one ring enters the spur as the other leaves
    # it): through it, one ring's whole spur fans to one point of the other and the two
    # fans overlap.  So the path is also started at the nearest pairs a quarter, a half
    # and three quarters round the lower ring, and the shortest of the four is kept (the
    # closest pair's unless another is shorter beyond rounding).
    plan_a, plan_b = np.zeros((n_a, 2)), np.zeros((len(upper), 2))
    none = (plan_a, plan_b, np.zeros(n_a), np.zeros(len(upper)), 0.0)
    if axis is None:
        return _shortest_tiling(lower, upper, i0, nearest, none)
    frame = axis_frame(np.asarray(axis, np.float64))
    plan_a, plan_b = lower @ frame[:2].T, upper @ frame[:2].T
    both = np.vstack([lower, upper])
    # more than any tiling's whole span: fewer wrong-sided faces always win
    penalty = float((len(both) + 1) * np.linalg.norm(np.ptp(both, axis=0)))
    sided = (plan_a, plan_b, _edge_sides(plan_a, plan_b), _edge_sides(plan_b, plan_a), penalty)
    # Rings apart in the plan: the sided tiling first.  Its side is judged by the other
    # ring's nearest point, which can lie across a narrow gap (a column's sub-loop beside
    # its neighbour).  Rings crossing in the plan: the plain tiling first, since the side
    # changes along them and the nearest point misplaces a hook's faces; the sided one
    # serves a hairpin of one ring at a sharp edge, fanned over both its sides.  Either
    # way the other is taken only where the first crosses itself and the other less
    # (the cases and their figures: docs/method/stitching.md).
    first, second = (none, sided) if loops_cross([plan_a, plan_b]) else (sided, none)
    tiling = _shortest_tiling(lower, upper, i0, nearest, first)
    crossings = len(self_intersections(both, tiling))
    if crossings:
        other = _shortest_tiling(lower, upper, i0, nearest, second)
        if len(self_intersections(both, other)) < crossings:
            return other
    return tiling


def _shortest_tiling(lower: np.ndarray, upper: np.ndarray, i0: int, nearest: np.ndarray,
                     plan: tuple) -> np.ndarray:
    """:func:`tile_min_span`'s shortest of its start pairs' tilings (``plan``: the rings in
    the plan, their edges' sides and the wrong side's penalty, 0 for none)."""
    n_a = len(lower)
    best = None
    for k in range(MIN_SPAN_STARTS):
        i_s = (i0 + (k * n_a) // MIN_SPAN_STARTS) % n_a
        if k and i_s == best[0]:
            continue
        tiling = _min_span_from(lower, upper, i_s, int(nearest[i_s]), plan)
        if best is None or tiling[1] < best[2] * (1.0 - MIN_SPAN_TIE):
            best = (i_s, *tiling)
    return best[1]


def _min_span_from(lower: np.ndarray, upper: np.ndarray, i0: int, j0: int,
                   plan: tuple) -> tuple:
    """:func:`tile_min_span`'s faces for the path started at the pair ``(i0, j0)``, and
    the path's total span length plus its wrong-sided faces' penalties (``plan``: the
    rings in the plan, their edges' sides and the penalty)."""
    n_a, n_b = len(lower), len(upper)
    ia = (i0 + np.arange(n_a + 1)) % n_a
    jb = (j0 + np.arange(n_b + 1)) % n_b
    plan_a, plan_b, side_a, side_b, penalty = plan
    moves = _min_span_moves(lower[ia[:-1]], upper[jb[:-1]], plan_a[ia[:-1]], plan_b[jb[:-1]],
                            side_a[ia[:-1]], side_b[jb[:-1]], penalty)
    pos_a = np.concatenate([[0], np.cumsum(moves)])[:-1]      # before each move
    pos_b = np.concatenate([[0], np.cumsum(~moves)])[:-1]
    # (a position may reach n_a once a's moves are done: its "next" is then unused)
    a0, a1 = ia[np.minimum(pos_a, n_a)], ia[np.minimum(pos_a + 1, n_a)]
    b0, b1 = jb[np.minimum(pos_b, n_b)], jb[np.minimum(pos_b + 1, n_b)]
    # every span of the path once: the one each move ends on
    span = np.linalg.norm(lower[np.where(moves, a1, a0)] - upper[np.where(moves, b0, b1)],
                          axis=1).sum()
    faces = np.where(moves[:, None], np.stack([a0, a1, n_a + b0], axis=1),
                     np.stack([a0, n_a + b1, n_a + b0], axis=1)).astype(np.int64)
    if penalty > 0.0:
        p = np.where(moves[:, None, None], np.stack([plan_a[a0], plan_a[a1], plan_b[b0]], axis=1),
                     np.stack([plan_b[b0], plan_b[b1], plan_a[a0]], axis=1))
        o = ((p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1])
             - (p[:, 1, 1] - p[:, 0, 1]) * (p[:, 2, 0] - p[:, 0, 0]))
        span += penalty * np.count_nonzero(o * np.where(moves, side_a[a0], side_b[b0]) < 0.0)
    return faces, float(span)
