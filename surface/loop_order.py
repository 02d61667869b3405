"""Order of one loop's points: a closed tour through grid-cell centres, then θ or arc length.

The points' grid-cell centres (``h = max(3 g, 6 σ̂, D/128)``, :func:`_grid_centres`) are
joined by a closed tour (θ order, or a depth-first walk of their minimum spanning tree
where θ jumps), improved by best-improvement 2-opt within :data:`TWO_OPT_WORK`
(:func:`_centre_tour`).  Where the tour is star-shaped about the centroid
(:func:`_is_star`) and the noise does not scramble θ (:func:`_theta_resolves`) the points
go in θ order, else by the arc length of their foot on the tour; the order starts at
θ_min (:func:`_order_loop`).  Used by :mod:`surface.topology`.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from scipy.spatial import cKDTree

from surface.section_trees import _centre_mst, _tree_walk
from surface.validate import TOL


def _grid_centres(uv: np.ndarray, cell: float) -> np.ndarray:
    """Mean ``(C, 2)`` of the points in each occupied grid cell."""
    key = np.floor((uv - uv.min(axis=0)) / cell).astype(np.int64)  # (M, 2), >= 0
    # one int64 per cell, in the lexicographic order of (row, column): the same cells,
    # numbered as np.unique(key, axis=0) numbers them, without its structured sort
    flat = key[:, 0] * (int(key[:, 1].max()) + 1) + key[:, 1]
    _, inverse = np.unique(flat, return_inverse=True)
    count = np.bincount(inverse)
    sums = np.stack([np.bincount(inverse, uv[:, d]) for d in range(2)], axis=1)
    return sums / count[:, None]


def _tour_length(points: np.ndarray, tour: np.ndarray) -> float:
    ring = points[tour]
    return float(np.linalg.norm(np.roll(ring, -1, axis=0) - ring, axis=1).sum())


#: Candidate moves :func:`_two_opt` evaluates at most, in all (~15 s on this machine at load 4:
#: 2e8 took 66 s on a 3 000-point disk; a loop of thousands of points needs far fewer).
TWO_OPT_WORK = 50_000_000


def _two_opt(points: np.ndarray, tour: np.ndarray) -> np.ndarray:
    """Best-improvement 2-opt of a closed tour through ``points`` ``(n, 2)``.

    A move replaces edges (a, b), (c, d) by (a, c), (b, d); it can only
    shorten the tour when ``|ac| < |ab| + |cd| ≤ 2·(longest edge)``, so the
    candidate moves are the vertex pairs closer than that (a k-d tree query,
    renewed when the longest edge outgrows it), and every move takes the
    candidate of the largest gain (:func:`_two_opt_moves`, a numba kernel since
    2026-12-06: the array form spent 0.5 s of the real temple's 3 s of curves in
    per-move array calls; the same moves, the same tours).

    The work is bounded: at most ``10 n`` moves and :data:`TWO_OPT_WORK` candidate
    evaluations in all, after which the tour is returned as it stands (still a
    permutation, only less short).  A loop is a curve and its candidates are few; a
    filled disk of points (a cap taken for a section) has a long edge, so every pair is a
    candidate at every move: on the first 10⁷-point vase two such sections of 197 433 and
    368 516 points kept this loop busy for over 20 minutes (2026-12-03).
    """
    n = len(tour)
    if n < 5:
        return tour
    points = np.ascontiguousarray(points, dtype=np.float64)
    tree = cKDTree(points)
    tol = TOL.zero * float(np.ptp(points, axis=0).max())
    tour = np.array(tour, dtype=np.int64)
    moves, work = 0, 0
    while True:
        ring = points[tour]
        longest = float(np.linalg.norm(np.roll(ring, -1, axis=0) - ring, axis=1).max())
        radius = 2.0 * longest * (1.0 + 1e-9)
        pairs = np.ascontiguousarray(tree.query_pairs(radius, output_type="ndarray"),
                                     dtype=np.int64)
        if len(pairs) == 0:
            return tour
        moves, work, more = _two_opt_moves(points, tour, pairs, radius, tol, moves, 10 * n,
                                           work, TWO_OPT_WORK)
        if not more:
            return tour


@numba.njit(cache=True, nogil=True)
def _two_opt_moves(points, tour, pairs, radius, tol, moves, max_moves, work, max_work):
    """Best-improvement 2-opt moves on ``tour`` (in place) among the candidate ``pairs``
    found within ``radius``, until none shortens the tour by more than ``tol``, the
    move or work budget is spent, or the longest edge outgrows the candidates
    (``2·longest > radius``: returns ``more = True`` for new pairs).  Returns
    ``(moves, work, more)``.  The arithmetic of the array form before it (edge lengths
    ``sqrt(dx² + dy²)``, gains ``|ac| + |bd| − |ab| − |cd|`` in that order, the first
    of equal gains in pair order), so the same moves."""
    n = len(tour)
    edge = np.empty(n)
    pos = np.empty(n, np.int64)
    while moves < max_moves:
        if work > max_work:
            return moves, work, False
        longest = 0.0
        for k in range(n):
            a, b = tour[k], tour[(k + 1) % n]
            dx, dy = points[b, 0] - points[a, 0], points[b, 1] - points[a, 1]
            edge[k] = math.sqrt(dx * dx + dy * dy)
            longest = max(longest, edge[k])
        if 2.0 * longest > radius:
            return moves, work, True
        for k in range(n):
            pos[tour[k]] = k
        best, best_i, best_j, found = np.inf, -1, -1, False
        for p in range(len(pairs)):
            i, j = pos[pairs[p, 0]], pos[pairs[p, 1]]
            if i > j:
                i, j = j, i
            if j - i < 2 or (i == 0 and j == n - 1):
                continue
            found = True
            a, b, c, d = tour[i], tour[(i + 1) % n], tour[j], tour[(j + 1) % n]
            dx, dy = points[a, 0] - points[c, 0], points[a, 1] - points[c, 1]
            ex, ey = points[b, 0] - points[d, 0], points[b, 1] - points[d, 1]
            gain = math.sqrt(dx * dx + dy * dy) + math.sqrt(ex * ex + ey * ey) - edge[i] \
                - edge[j]
            if gain < best:
                best, best_i, best_j = gain, i, j
        if not found:
            return moves, work, False
        work += len(pairs)
        if best >= -tol:
            return moves, work, False
        tour[best_i + 1:best_j + 1] = tour[best_i + 1:best_j + 1][::-1].copy()
        moves += 1
    return moves, work, False


def _centre_tour(centres: np.ndarray, theta_order: np.ndarray, cell: float) -> np.ndarray:
    """A short closed tour through the centres (θ order or MST walk, then 2-opt)."""
    n = len(centres)
    tour = theta_order
    ring = centres[tour]
    if np.linalg.norm(np.roll(ring, -1, axis=0) - ring, axis=1).max() > 3.0 * cell:
        # θ order jumps (a fold): try a depth-first walk of the minimum spanning tree
        tree = _centre_mst(centres)
        walk = _tree_walk(n, tree.row, tree.col, int(theta_order[0]))
        if len(walk) == n and _tour_length(centres, walk) < _tour_length(centres, tour):
            tour = walk
    return _two_opt(centres, np.asarray(tour))


def _is_star(ring_rel: np.ndarray, cell: float) -> bool:
    """θ increases along the counter-clockwise tour, up to folds below two cells.

    The winding number about the centroid must be one, and θ may never fall
    back from its running maximum by more than the angle ``2·cell/R`` that two
    grid cells subtend at radius R (grid jitter, not a fold of the curve).
    """
    phi = np.arctan2(ring_rel[:, 1], ring_rel[:, 0])
    dphi = np.mod(np.diff(np.append(phi, phi[0])) + np.pi, 2 * np.pi) - np.pi
    if round(dphi.sum() / (2 * np.pi)) != 1:
        return False
    unwrapped = np.concatenate([[0.0], np.cumsum(dphi)[:-1]])
    # start the running maximum at the tour's smallest unwrapped θ; the vertices
    # before it in the tour come after it, one turn later
    start = int(np.argmin(unwrapped))
    unwrapped = np.roll(unwrapped, -start)
    unwrapped[len(unwrapped) - start :] += 2 * np.pi
    radius = np.maximum(np.roll(np.hypot(ring_rel[:, 0], ring_rel[:, 1]), -start), TOL.zero)
    fall = np.maximum.accumulate(unwrapped) - unwrapped
    return bool(np.all(fall <= 2.0 * cell / radius))


#: θ orders two points a gap g apart along a curve crossing the rays from the centroid
#: at angle α when their angular step g sin α / R exceeds this many times their angular
#: noise σ cos α / R (:func:`_theta_resolves`).
THETA_NOISE_RATIO = 3.0

#: Consecutive tour centres where θ does not resolve the order that make a loop
#: ordered along its tour instead (one or two are grid jitter).
THETA_RUN = 3


def _theta_resolves(ring_rel: np.ndarray, sigma: float, gap: float) -> bool:
    """Whether θ orders the points of a star-shaped tour despite their noise.

    Where the curve runs nearly along the rays from the centroid (the sides of
    a long thin lobe: a handle's section merging with a wall), consecutive
    points differ in θ by ``g sin α / R`` while noise σ across the curve moves
    them by ``σ cos α / R``: θ scrambles their order when
    ``tan α < THETA_NOISE_RATIO σ / g`` (measured: the amphora's handle lobe,
    α ≈ 5°, ordered by θ zig-zagged along its sides and shrank its ring by half
    its width).  α is taken at every centre from the chord of its two tour
    neighbours; a run of :data:`THETA_RUN` failing centres decides.
    """
    if sigma <= 0 or gap <= 0 or len(ring_rel) < 2 * THETA_RUN:
        return True
    chord = np.roll(ring_rel, -1, axis=0) - np.roll(ring_rel, 1, axis=0)       # (n, 2)
    cross = np.abs(chord[:, 0] * ring_rel[:, 1] - chord[:, 1] * ring_rel[:, 0])
    dot = np.abs(np.einsum("ij,ij->i", chord, ring_rel))
    fails = cross * gap < THETA_NOISE_RATIO * sigma * dot
    if not fails.any():
        return True
    if fails.all():
        return False
    run = np.roll(fails, -int(np.argmin(fails)))       # start at a centre that passes
    edges = np.diff(np.concatenate([[0], run.astype(np.int8), [0]]))
    return int((np.flatnonzero(edges == -1) - np.flatnonzero(edges == 1)).max()) < THETA_RUN


def _order_loop(uv: np.ndarray, cell: float, link: float, sigma: float = 0.0,
                gap: float = 0.0):
    """Ordering ``(M,)`` of a loop's points, star-shaped flag and closed flag.

    ``sigma`` and ``gap`` (the noise σ̂ and the mean gap g) let
    :func:`_theta_resolves` veto the θ order where the noise scrambles it.
    """
    centre = uv.mean(axis=0)
    rel = uv - centre
    theta = np.mod(np.arctan2(rel[:, 1], rel[:, 0]), 2 * np.pi)
    centres = _grid_centres(uv, cell)
    if len(centres) < 4:
        return _from_theta_min(np.argsort(theta, kind="stable"), theta), True, True
    c_rel = centres - centre
    c_theta = np.mod(np.arctan2(c_rel[:, 1], c_rel[:, 0]), 2 * np.pi)
    tour = _centre_tour(centres, np.argsort(c_theta, kind="stable"), cell)
    ring = centres[tour]
    x, y = ring[:, 0], ring[:, 1]
    if np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y) < 0:
        tour, ring = tour[::-1], ring[::-1]
    edge = np.linalg.norm(np.roll(ring, -1, axis=0) - ring, axis=1)
    closed = bool(edge.max() <= link)
    star = _is_star(ring - centre, cell) and _theta_resolves(ring - centre, sigma, gap)
    if star:
        order = np.argsort(theta, kind="stable")
    else:
        order = np.argsort(_polyline_parameter(uv, ring, edge), kind="stable")
    return _from_theta_min(order, theta), star, closed


def _polyline_parameter(uv: np.ndarray, ring: np.ndarray, edge: np.ndarray) -> np.ndarray:
    """Arc length ``(M,)`` of each point's foot on the closed polyline ``ring``."""
    n = len(ring)
    cum = np.concatenate([[0.0], np.cumsum(edge)[:-1]])
    _, nearest = cKDTree(ring).query(uv)
    best_s = np.zeros(len(uv))
    best_d = np.full(len(uv), np.inf)
    for seg in ((nearest - 1) % n, nearest):  # the two edges at the nearest vertex
        a, b = ring[seg], ring[(seg + 1) % n]
        ab = b - a
        t = np.clip(np.einsum("mi,mi->m", uv - a, ab) / np.maximum(edge[seg] ** 2, TOL.zero), 0, 1)
        d = np.linalg.norm(a + t[:, None] * ab - uv, axis=1)
        better = d < best_d
        best_d = np.where(better, d, best_d)
        best_s = np.where(better, cum[seg] + t * edge[seg], best_s)
    return best_s


def _from_theta_min(order: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """Rotate a cyclic order so it starts at the point of smallest θ."""
    start = int(np.argmin(theta[order]))
    return np.roll(order, -start)
