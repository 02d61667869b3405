"""Caps of the ends: flat quality caps with guard rings, domes over the cap points, end
windows, holes in the data (the uncovered share of a cap)."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numba
import numpy as np
from scipy.spatial import cKDTree

from checks.robust import mad_sigma
from surface.polygon import INSIDE_PAIRS
from surface.polygon import inside_polygon as _inside
from surface.validate import TOL

__all__ = ['cap_triangles']

# --------------------------------------------------------------------------- caps
def cap_triangles(ring2d: np.ndarray, outward_up: bool,
                  holes: Sequence[np.ndarray] = ()) -> np.ndarray:
    """Ear-clipping triangulation of a closed planar contour, with holes.

    Parameters
    ----------
    ring2d : (n, 2) float64
        Contour in the section plane's (e1, e2) coordinates (either winding).
    outward_up : bool
        Orient faces counter-clockwise in (e1, e2) (normal ``+axis``) if True,
        clockwise (normal ``-axis``) otherwise.
    holes : sequence of (n_h, 2) float64
        Contours inside ``ring2d`` bounding holes of the cap (an annulus for a
        rim between a wall's outer and inner loop).

    Returns
    -------
    (m, 3) int64
        Faces over ``0 .. n-1`` then each hole's points in turn;
        ``m == n + Σ n_h - 2 + 2 h`` for a simple polygon with h holes (fewer
        when earcut meets a self-intersecting contour).
    """
    import mapbox_earcut

    rings = [np.asarray(ring2d, np.float64)] + [np.asarray(h, np.float64) for h in holes]
    centre = rings[0].mean(axis=0)
    pts = np.ascontiguousarray(np.vstack(rings) - centre, dtype=np.float64)
    ends = np.cumsum([len(r) for r in rings]).astype(np.uint32)
    flat = mapbox_earcut.triangulate_float64(pts, ends)
    tri = np.asarray(flat, dtype=np.int64).reshape(-1, 3)
    if len(tri) == 0:
        return tri
    p = pts[tri]
    twice = ((p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1])
             - (p[:, 1, 1] - p[:, 0, 1]) * (p[:, 2, 0] - p[:, 0, 0]))
    flip = (twice < 0) if outward_up else (twice > 0)
    tri[flip] = tri[flip][:, ::-1]
    return tri


#: Fewest cap points inside a loop that place its cap (a plane fit needs 3; the
#: median of a dozen is robust to a few wall points leaking in).
CAP_MIN_POINTS = 12
#: Cap points count for a loop's cap when inside its contour shrunk by this factor
#: about its centroid, and outside its holes grown by the inverse (keeps walls out).
CAP_SHRINK = 0.9


def _scaled(ring2d: np.ndarray, factor: float) -> np.ndarray:
    centre = ring2d.mean(axis=0)
    return centre + factor * (ring2d - centre)


def _cap_step(outer2d, holes2d, height, up, cap_points, frame, base_heights) -> float:
    """Axial offset from a loop's plane to the median height of the cap points over it.

    Looks between ``height`` and the next section plane in the cap's direction
    (``up``: above), at the points inside ``outer2d`` (shrunk by
    :data:`CAP_SHRINK`) and outside every hole (grown by its inverse); 0 when
    fewer than :data:`CAP_MIN_POINTS` are there.
    """
    pts = np.asarray(cap_points, np.float64)
    if len(pts) == 0:
        return 0.0
    h = pts @ frame[2]
    beyond = base_heights[base_heights > height + TOL.zero] if up else \
        base_heights[base_heights < height - TOL.zero]
    if len(beyond):
        limit = float(beyond.min() if up else beyond.max())
    else:
        limit = height + (1 if up else -1) * 2 * float(np.median(np.abs(np.diff(base_heights))))
    lo, hi = (height, limit) if up else (limit, height)
    near = np.flatnonzero((h > lo) & (h < hi))
    if len(near) < CAP_MIN_POINTS:
        return 0.0
    flat = pts[near] @ frame[:2].T
    keep = _inside(flat, _scaled(outer2d, CAP_SHRINK))
    for hole in holes2d:
        keep &= ~_inside(flat, _scaled(hole, 1 / CAP_SHRINK))
    if np.count_nonzero(keep) < CAP_MIN_POINTS:
        return 0.0
    return float(np.median(h[near[keep]])) - height


#: Rings added inside a flat cap beyond its support ring, each a further support distance
#: in (:func:`stitch_rings`).  Loop's patch over a triangle reads the control mesh up to
#: two rings of edges around it (one refinement step, then the refined corners' 1-rings),
#: so with the support ring alone every cap triangle with a corner on it reads the wall's
#: support ring too and bends out of the cap plane (measured on the 10^5-point vase's
#: sized surface: the cap 0.00033 from its plane on average, the stitched cap 0.00002);
#: one guard ring keeps every triangle inside it two rings from the wall: planar.
CAP_GUARD_RINGS = 1


#: Bits below the contour's size at which :func:`_quality_cap` snaps its points: 2^-26
#: of the size (~1.5e-8), far below any modelling scale and 10⁸ times the last-bit noise
#: of the rings (~1e-16 relative).  At 2^-32 the 10⁴-point torus moved by 1e-12 still
#: crossed grid lines often enough to change a cap in 3 of 8 runs
#: (``benchmarks/last_bits.py``); at 2^-26, in none.
SNAP_BITS = 26


def _snapped(points: np.ndarray) -> np.ndarray:
    """``points`` rounded to a grid of 2^-SNAP_BITS of their extent (a power of two).

    Triangle's quality refinement (``q``) decides where to add points by exact
    in-circle tests, and a ring sampled evenly round a rounded end is nearly cocircular:
    the last bits of its coordinates (another BLAS, another CPU, a solver changed
    elsewhere) chose other Steiner points and another number of cap triangles (the
    10⁴-point torus's dense mesh: 12 106-12 168 triangles under perturbations of 1e-13
    of the coordinates, 2026-12-06).  Snapped, perturbations that small give the same
    input and so the same triangulation, unless a coordinate sits within them of a
    rounding boundary (a chance of about their size / 1.5e-8 each).
    """
    scale = float(np.abs(points).max(initial=0.0))
    if not scale > 0 or not np.isfinite(scale):
        return points
    grid = 2.0 ** (math.floor(math.log2(scale)) - SNAP_BITS)
    return np.round(points / grid) * grid


#: Smallest angle (degrees) of the triangles inside a cap with support rings
#: (Shewchuk's Triangle, ``q``): the ear-clipped cap of a ring of n points has
#: slivers of ~180°/n whose Bezier patches have near-singular Jacobians, where
#: normals lose digits (measured 1.7e-8 rad across an edge that is G1 exactly).
CAP_MIN_ANGLE = 25.0


def _quality_cap(ring2d: np.ndarray, outward_up: bool,
                 max_area: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Constrained quality Delaunay triangulation of a closed planar contour.

    The contour's points and edges are kept as they are (no point added on
    them); points are added inside until every angle is at least
    :data:`CAP_MIN_ANGLE` (Triangle grades them: triangles the contour's edge
    length at the contour, larger inside, so a flat cap costs O(n) triangles).

    Parameters
    ----------
    ring2d : (n, 2) float64
        The contour, counter-clockwise, in the section plane's coordinates.
    outward_up : bool
        As in :func:`cap_triangles`.
    max_area : float, optional
        Largest triangle area (Triangle's ``a`` switch): a dome's height field is
        sampled as finely inside as along its contour.

    Returns
    -------
    added : (k, 2) float64
        The points added inside, plane coordinates.
    triangles : (m, 3) int64
        Over the contour's ``0 .. n-1`` then the added ``n .. n+k-1``.

    Raises
    ------
    ValueError
        The contour is not simple (self-intersecting, or repeated points): the
        triangles do not cover its shoelace area exactly once, or a contour
        point is not a corner.
    """
    import triangle

    n = len(ring2d)
    centre = ring2d.mean(axis=0)
    pts = _snapped(ring2d - centre)
    edge = float(np.mean(np.linalg.norm(np.roll(pts, -1, axis=0) - pts, axis=1)))
    segments = np.stack([np.arange(n), (np.arange(n) + 1) % n], axis=1)
    switches = f"pYq{CAP_MIN_ANGLE:g}" + (f"a{max_area:.15f}" if max_area else "")  # no exponent
    out = triangle.triangulate({"vertices": pts, "segments": segments}, switches)
    verts = np.asarray(out.get("vertices", np.zeros((0, 2))), np.float64)
    tri = np.asarray(out.get("triangles", np.zeros((0, 3))), np.int64).reshape(-1, 3)
    if (len(verts) < n or not np.allclose(verts[:n], pts, rtol=0, atol=TOL.zero * (1 + edge))
            or len(np.unique(tri[tri < n])) < n):
        raise ValueError("the contour's points are not all corners of the triangulation")
    p = verts[tri]
    twice = ((p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1])
             - (p[:, 1, 1] - p[:, 0, 1]) * (p[:, 2, 0] - p[:, 0, 0]))
    x, y = pts[:, 0], pts[:, 1]
    polygon = 0.5 * abs(float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)))
    if abs(0.5 * float(np.abs(twice).sum()) - polygon) > TOL.planar_rel * (1.0 + polygon) * n:
        raise ValueError("contour is not simple (triangles do not cover its area once)")
    flip = (twice < 0) if outward_up else (twice > 0)
    tri[flip] = tri[flip][:, ::-1]
    return verts[n:] + centre, tri


#: Cap points each dome height is fitted to (a local quadratic: the standard error of
#: its value at the centre of a disk of k uniform points is about 1.6 σ/√k, σ/4 here).
DOME_NEIGHBOURS = 48
#: A cap is a dome when the cap points' robust spread about their best plane exceeds
#: this many times their spread about local quadratics (the noise): a flat cap's ratio
#: is ~1 (measured 1.0-1.2 on the benchmark clouds' flat ends).
DOME_RATIO = 2.0


#: Cap points the dome test fits its local quadratics at, at most (evenly spaced through
#: the cap points when there are more): the test compares two robust spreads, whose medians
#: 20 000 points fix to about 1 % (DOME_RATIO is 2 against the flat caps' 1.0-1.2), while
#: the cap points grow with the cloud (10^6-point vase: 2 x ~10^5 a candidate surface).
DOME_TEST_POINTS = 20_000
#: Query points of one batch of :func:`_local_quadratic` (bounds its memory: the
#: ``(Q, k, 6)`` design and its neighbours take ~3 kB a query point with k = 48).
QUADRATIC_BATCH = 8192


@numba.njit(cache=True, nogil=True)
def _quadratic_heights(flat: np.ndarray, h: np.ndarray, query: np.ndarray,
                       near: np.ndarray) -> tuple:  # pragma: no cover - numba
    """Value at each query point of the least-squares quadratic through its neighbours
    ``near[q]`` (see :func:`_local_quadratic`), and its variance over σ² (``(NᵀN)⁻¹``'s
    first diagonal element): normal equations accumulated per query, solved by Gaussian
    elimination with partial pivoting for the heights and for the unit vector."""
    out = np.empty(len(query))
    var = np.empty(len(query))
    normal = np.empty((6, 6))
    rhs = np.empty((6, 2))
    row = np.empty(6)
    for q in range(len(query)):
        qx, qy = query[q, 0], query[q, 1]
        scale = 0.0
        for j in range(near.shape[1]):
            p = near[q, j]
            scale = max(scale, abs(flat[p, 0] - qx), abs(flat[p, 1] - qy))
        scale = max(scale, 1e-12)
        normal[:] = 0.0
        rhs[:] = 0.0
        rhs[0, 1] = 1.0
        for j in range(near.shape[1]):
            p = near[q, j]
            u = (flat[p, 0] - qx) / scale
            v = (flat[p, 1] - qy) / scale
            row[0], row[1], row[2], row[3], row[4], row[5] = 1.0, u, v, u * u, u * v, v * v
            for a in range(6):
                rhs[a, 0] += row[a] * h[p]
                for b in range(a, 6):
                    normal[a, b] += row[a] * row[b]
        for a in range(6):
            normal[a, a] += 1e-9
            for b in range(a):
                normal[a, b] = normal[b, a]
        for c in range(6):                       # elimination, partial pivoting
            piv = c
            for r in range(c + 1, 6):
                if abs(normal[r, c]) > abs(normal[piv, c]):
                    piv = r
            if piv != c:
                for b in range(6):
                    normal[c, b], normal[piv, b] = normal[piv, b], normal[c, b]
                for b in range(2):
                    rhs[c, b], rhs[piv, b] = rhs[piv, b], rhs[c, b]
            for r in range(c + 1, 6):
                f = normal[r, c] / normal[c, c]
                for b in range(c, 6):
                    normal[r, b] -= f * normal[c, b]
                for b in range(2):
                    rhs[r, b] -= f * rhs[c, b]
        for c in range(5, -1, -1):
            for e in range(2):
                acc = rhs[c, e]
                for b in range(c + 1, 6):
                    acc -= normal[c, b] * rhs[b, e]
                rhs[c, e] = acc / normal[c, c]
        out[q] = rhs[0, 0]
        var[q] = rhs[0, 1]
    return out, var


def _local_quadratic(flat: np.ndarray, h: np.ndarray, query: np.ndarray,
                     k: int, variance: bool = False):
    """Heights ``(Q,)`` at ``query`` of least-squares quadratics through k nearest points.

    ``h ≈ c0 + c1 u + c2 v + c3 u² + c4 uv + c5 v²`` in the offsets (u, v) from
    each query point (scaled by their largest); ``c0`` is the height there.  The k-d
    tree of ``flat`` is built once; the queries go in batches of
    :data:`QUADRATIC_BATCH` neighbours' worth (memory), each point's fit its own
    (:func:`_quadratic_heights`, numba: the batched numpy normal equations spent 90 %
    of their time building ``(Q, k, 6)`` designs).  With ``variance`` also each height's
    variance over σ² ``(Q,)``.
    """
    flat = np.ascontiguousarray(flat, dtype=np.float64)
    h = np.ascontiguousarray(h, dtype=np.float64)
    query = np.ascontiguousarray(query, dtype=np.float64).reshape(-1, 2)
    k = min(k, len(flat))
    tree = cKDTree(flat)
    heights, factors = np.empty(len(query)), np.empty(len(query))
    size = max(256, QUADRATIC_BATCH * DOME_NEIGHBOURS // max(k, 1))   # memory ~ size x k
    for s in range(0, len(query), size):
        batch = query[s:s + size]
        _, near = tree.query(batch, k=k)                          # (Q, k)
        heights[s:s + len(batch)], factors[s:s + len(batch)] = _quadratic_heights(
            flat, h, batch, np.asarray(near, np.int64).reshape(len(batch), k))
    return (heights, factors) if variance else heights


#: Share of a contour's inside the cap points may leave uncovered for it to be capped by
#: their height field (:func:`_dome`); more is a hole in the data (:func:`uncovered_share`).
HOLE_SHARE = 0.05
#: A point of a contour's inside is covered when a cap point lies within this many of
#: their median nearest-neighbour distances ν: for points spread at random with density
#: ρ, ν ≈ 0.47 / √ρ, and an empty disc of radius 4ν holds no point with probability
#: exp(-π ρ (4ν)²) ≈ 1.5e-5, so a covered cap is never taken for a hole.
COVER_RADIUS = 4.0


def uncovered_share(ring2d: np.ndarray, holes2d: list, flat: np.ndarray) -> float:
    """Share of the region inside ``ring2d`` and outside each of ``holes2d`` (``(n, 2)``
    contours) farther than :data:`COVER_RADIUS` ν from every point of ``flat`` ``(P, 2)``.

    Measured on a grid of cell 2ν (ν the points' median nearest-neighbour distance);
    1.0 with fewer than 3 points, 0.0 when the region holds no grid point.
    """
    inside = flat[_inside(flat, ring2d)] if len(flat) else flat
    for hole in holes2d:
        inside = inside[~_inside(inside, hole)]
    if len(inside) < 3:
        return 1.0
    tree = cKDTree(inside)
    nu = float(np.median(tree.query(inside, k=2)[0][:, 1]))
    lo, hi = ring2d.min(axis=0), ring2d.max(axis=0)
    cell = 2.0 * max(nu, TOL.zero * float(np.ptp(ring2d, axis=0).max()))
    steps = np.ceil((hi - lo) / cell).astype(np.int64) + 1
    if steps.prod() > INSIDE_PAIRS // 4:     # a coarser grid past ~500 000 cells
        cell *= float(np.sqrt(steps.prod() / (INSIDE_PAIRS // 4)))
        steps = np.ceil((hi - lo) / cell).astype(np.int64) + 1
    gx, gy = np.meshgrid(lo[0] + cell * np.arange(steps[0]), lo[1] + cell * np.arange(steps[1]))
    grid = np.column_stack([gx.ravel(), gy.ravel()])
    grid = grid[_inside(grid, ring2d)]
    for hole in holes2d:
        grid = grid[~_inside(grid, hole)]
    if len(grid) == 0:
        return 0.0
    far = tree.query(grid, distance_upper_bound=COVER_RADIUS * nu)[0] == np.inf
    return float(far.mean())


def _closes(close_ends, end: int) -> bool:
    """Whether end ``end`` (0 the first section, -1 the last) is capped: ``close_ends``
    is one bool for both or a pair."""
    if np.ndim(close_ends) == 0:
        return bool(close_ends)
    return bool(close_ends[0 if end == 0 else 1])


def _dome(ring2d: np.ndarray, lo: float, hi: float, cap_points: np.ndarray | None,
          frame: np.ndarray, field_ring: np.ndarray | None = None,
          rim: tuple[float, bool] | None = None, reach: float | None = None):
    """The cap points' height field over an end contour, or None for a flat cap.

    The section planes stop where the surface turns within 60° of them
    (``reconstruct.MIN_WALL_SINE``); beyond the last contour a rounded end (a
    capsule's hemisphere, a torus' crown) is a height field over the plane,
    sampled by the cap points; so is a branch's rounded end between two
    sections (a handle's lowest point).  Those inside the contour (shrunk by
    :data:`CAP_SHRINK`) with heights in ``(lo, hi)`` (an end cap: from two
    spacings back on; an inner cap: up to the next section plane) are taken;
    the cap is a dome when their robust spread (1.4826 × median
    absolute deviation) about their least-squares plane exceeds
    :data:`DOME_RATIO` times that about local quadratics of
    :data:`DOME_NEIGHBOURS` points (the noise), the latter measured at no more
    than :data:`DOME_TEST_POINTS` of them, and they cover the contour: where more than
    :data:`HOLE_SHARE` of its inside lies farther from every one of them than
    :data:`COVER_RADIUS` spacings (:func:`uncovered_share`: the scanner never saw the
    middle of an animal's base, a bust's cut, a dome's pole), the quadratics would run
    on from the hole's rim into a dome far from every point, so the heights are held
    within those of the points over the contour (a plateau over the hole at the height
    its rim allows).  The height field is fitted to the points
    over ``field_ring`` (default ``ring2d``: a ringed cap decides on its innermost ring
    and fits over its rim), each height to as many of them as the dome's shape allows
    (:func:`_dome_neighbours`).  With ``rim = (height, up)`` the heights are held on the
    cap's side of the contour's plane (``up``: at or above ``height``): the strips the
    contour ends lie on the other side, and a dome dipping back through the plane would
    cross them (the quadratics near the rim also take the wall's last points below it).
    With ``reach`` as well they are held short of that height (``up``: at or below it):
    where a loop vanishes under one section and another appears over the next, both
    inside the slab between them, their two domes are fitted to the same points and
    cross wherever the contours overlap; each is held to its half of the slab.

    Returns
    -------
    callable or None
        ``(Q, 2)`` plane points -> ``(Q,)`` heights along the axis (local
        quadratics, :func:`_local_quadratic`).
    """
    if cap_points is None or len(cap_points) < 2 * DOME_NEIGHBOURS:
        return None
    pts = np.asarray(cap_points, np.float64)
    h = pts @ frame[2]
    side = (h > lo) & (h < hi)
    window, h_window = pts[side] @ frame[:2].T, h[side]
    within = _inside(window, ring2d)
    every, h_every = window[within], h_window[within]
    inside = _inside(every, _scaled(ring2d, CAP_SHRINK))
    flat, h = every[inside], h_every[inside]
    if len(flat) < 2 * DOME_NEIGHBOURS:
        return None
    hole = uncovered_share(_scaled(ring2d, CAP_SHRINK), [], flat) > HOLE_SHARE
    design = np.column_stack([np.ones(len(flat)), flat])
    plane = h - design @ np.linalg.lstsq(design, h, rcond=None)[0]
    test = np.unique(np.linspace(0, len(flat) - 1, min(len(flat), DOME_TEST_POINTS)).astype(
        np.int64))                                                # every point when few
    local = h[test] - _local_quadratic(flat, h, flat[test], DOME_NEIGHBOURS)

    def spread(r):
        return float(mad_sigma(r))
    if spread(plane) <= DOME_RATIO * max(spread(local), TOL.zero):
        return None
    # The height field is fitted to every point over the contour: near the rim the
    # dome meets the wall's last points, which hold it there (no extrapolation).
    if field_ring is not None:
        within = _inside(window, field_ring)
        every, h_every = window[within], h_window[within]
    test = np.unique(np.linspace(0, len(flat) - 1, min(len(flat), DOME_WIDTH_TEST_POINTS))
                     .astype(np.int64))
    noise, chosen = spread(local), []

    def field(query) -> np.ndarray:
        # the neighbour count on the first call: a caller that only asks "a dome?"
        # (reconstruct.extend_to_caps) does not pay for it
        if not chosen:
            chosen.append(_dome_neighbours(every, h_every, flat[test], noise))
        heights = _local_quadratic(every, h_every, np.asarray(query, np.float64), chosen[0])
        # over a hole the quadratics run on from its rim: held within the points' heights
        if hole:
            heights = np.clip(heights, h_every.min(), h_every.max())
        if rim is not None:   # never back through the contour's plane, into the strips
            heights = np.maximum(heights, rim[0]) if rim[1] else np.minimum(heights, rim[0])
            if reach is not None:     # nor past the half-slab of a facing cap
                heights = np.minimum(heights, reach) if rim[1] else np.maximum(heights, reach)
        return heights
    return field


def end_window(height: float, up: bool, spacing: float) -> tuple[float, float]:
    """Heights of the cap points an end's dome test takes: beyond its last contour, which
    may lie up to two section spacings inside the data (``up``: the end faces +axis)."""
    return (height - 2 * spacing, np.inf) if up else (-np.inf, height + 2 * spacing)


#: Most cap points one dome height is fitted to (the doubling of :func:`_dome_neighbours`
#: stops there: SE 0.08 σ; 384 points spread over ~π (0.17 r)² of a unit dome's plane at
#: 10⁵ points, and the cost grows with it: ~Q k for Q heights).
DOME_MAX_NEIGHBOURS = 384
#: Median of the χ² distribution with one degree of freedom (a robust mean square).
CHI2_1_MEDIAN = 0.454936
#: Points the neighbour count is chosen at (evenly through the cap points).
DOME_WIDTH_TEST_POINTS = 512


def _dome_neighbours(flat: np.ndarray, h: np.ndarray, test: np.ndarray, noise: float) -> int:
    """Cap points per dome height: as many as the dome's shape allows (Lepski's rule).

    A local quadratic's height of k points has a standard error of about 1.6 σ/√k: at
    :data:`DOME_NEIGHBOURS` a dome's vertices were 2-3× noisier than the wall's rings
    beside them (10⁵-point capsule: 0.00054 against 0.0002-0.0003), and the smooth
    surface interpolates them.  k is doubled while the wider fit differs from the
    narrower one by no more than their noise explains: for nested least-squares fits the
    difference's variance is the narrower's less the wider's (each ``σ² (NᵀN)⁻¹₀₀`` of its
    own neighbours, so one-sided fits near the rim count as what they are); the median
    of the squared standardised differences at up to :data:`DOME_WIDTH_TEST_POINTS` cap
    points (``noise``: the cap points' scatter about the narrowest fits) must stay within
    twice χ²₁'s, i.e. the wider fit's bias from the dome's curvature change stays below
    its noise.  Never beyond :data:`DOME_MAX_NEIGHBOURS` nor a quarter of the points.
    """
    k = DOME_NEIGHBOURS
    if not noise > 0:
        return k
    fit, var = _local_quadratic(flat, h, test, k, variance=True)
    while 2 * k <= min(DOME_MAX_NEIGHBOURS, len(flat) // 4):
        wider, var_wider = _local_quadratic(flat, h, test, 2 * k, variance=True)
        # nested fits: the difference's variance is the narrower's less the wider's
        z2 = (wider - fit) ** 2 / (noise ** 2 * np.maximum(var - var_wider, TOL.zero))
        if float(np.median(z2)) / CHI2_1_MEDIAN > 2.0:
            break
        k, fit, var = 2 * k, wider, var_wider
    return k


def _inset_ring(ring: np.ndarray, d: float) -> np.ndarray:
    """``ring`` moved ``d`` towards its centroid (in its plane): the cap's support ring."""
    to_centre = ring.mean(axis=0) - ring
    length = np.maximum(np.linalg.norm(to_centre, axis=1), TOL.zero)[:, None]
    return ring + np.minimum(d, 0.5 * length) * to_centre / length
