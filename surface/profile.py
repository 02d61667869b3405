r"""Profile of an object with an axis: its section by a half-plane through the axis.

The surface (a closed triangle mesh: the tessellated Bézier surface or a stitched mesh) is
cut by the plane through the axis ``a`` (through ``origin``) at azimuth ``phi``, the
plane with normal ``m = a x u``, ``u = cos(phi) e1 + sin(phi) e2``.  Each edge whose ends
lie on opposite sides (``d = (x - o) . m``; ``d = 0`` counts as positive, so every
triangle is crossed by 0 or 2 edges) gives one point ``x_i + d_i/(d_i - d_j) (x_j - x_i)``;
a triangle joins its two edges, in the order its counter-clockwise corners enter and leave
the positive side, so the segments chain into consistently oriented loops (trimesh's
``mesh_plane`` [1]_, chained by shared edges instead of merged by distance).  Points are
written in profile coordinates ``r = (x - o) . u``, ``z = (x - o) . a`` and cut at ``r = 0``.

The half on ``r >= 0`` of the loop that reaches the axis is the wall's section; on a
vessel it runs from the base (on the axis) up the outer wall to the rim (its highest point)
and down the inner wall to the inner bottom: split there into the outer and inner profile.
The outer silhouette (the outline seen from outside) is the largest radius over all
azimuths at each height.

Measures (:func:`measure_profile`): height, rim, base and maximum diameters (and the
height of the maximum), wall thickness at given heights (distance from the outer profile's
point to the inner profile: the nearest point, so along the inner wall's normal).  A
diameter is the sum of the outer radii at ``phi`` and ``phi + pi``, so an object need not
be centred on its axis.  For a non-circular object the two principal profiles are the
azimuths of the principal axes of the section at mid height (:func:`principal_azimuths`).

References
----------
.. [1] M. Dawson-Haggerty et al., trimesh, ``trimesh/intersections.py:mesh_plane``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numba
import numpy as np

from surface.measure import _check_mesh, _perpendicular_frame, _unit_axis
from surface.validate import TOL, check_shape

__all__ = ["HalfProfile", "frame", "half_profile", "measure_profile", "plane_section",
           "principal_azimuths", "revolve", "silhouette"]


def frame(axis) -> np.ndarray:
    """``(3, 3)`` rows ``e1, e2, a``: the axis and two directions perpendicular to it."""
    a = _unit_axis(axis)
    e1, e2 = _perpendicular_frame(a)
    return np.stack([e1, e2, a])


@numba.njit(cache=True)
def _walk(following: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover
    """Order nodes along ``following`` pointers: (order, chain starts, closed flags)."""
    n = len(following)
    has_prev = np.zeros(n, np.bool_)
    for i in range(n):
        if following[i] >= 0:
            has_prev[following[i]] = True
    seen = np.zeros(n, np.bool_)
    order = np.empty(n, np.int64)
    starts = np.empty(n + 1, np.int64)
    closed = np.zeros(n, np.bool_)
    pos = 0
    chains = 0
    for phase in range(2):  # open chains first (from their heads), then loops
        for s in range(n):
            if seen[s] or (phase == 0 and has_prev[s]):
                continue
            starts[chains] = pos
            node = s
            while node >= 0 and not seen[node]:
                seen[node] = True
                order[pos] = node
                pos += 1
                node = following[node]
            closed[chains] = node == s
            chains += 1
    starts[chains] = pos
    return order, starts[:chains + 1], closed[:chains]


def plane_section(vertices, triangles, origin, normal) -> list[tuple[np.ndarray, bool]]:
    """Section of a triangle mesh by a plane, chained into polylines.

    Parameters
    ----------
    vertices : (V, 3) array_like
    triangles : (F, 3) int array_like, counter-clockwise from outside
    origin : (3,) array_like
        A point of the plane.
    normal : (3,) array_like
        The plane's normal (any length).

    Returns
    -------
    list of ((M, 3) float64, bool)
        Each polyline's points and whether it is closed (its last point joins the first).
    """
    verts, tris = _check_mesh(vertices, triangles)
    m = _unit_axis(normal)
    o = check_shape(origin, "(3,)", "origin", dtype=np.float64)
    d = (verts - o) @ m
    side = d >= 0
    half = np.stack([tris, np.roll(tris, -1, axis=1)], axis=2).reshape(-1, 2)  # (3F, 2)
    crosses = side[half[:, 0]] != side[half[:, 1]]
    if not np.any(crosses):
        return []
    key = np.sort(half, axis=1)
    _, edge_id = np.unique(key[:, 0] * len(verts) + key[:, 1], return_inverse=True)
    edge_id = edge_id.reshape(-1, 3)
    cross3 = crosses.reshape(-1, 3)
    hit = cross3.sum(axis=1) == 2
    # in a crossed triangle, the edge entering the positive side and the one leaving it
    entering = cross3 & ~side[tris]
    hit_ids = edge_id[hit]
    enter = np.take_along_axis(hit_ids, np.argmax(entering[hit], axis=1)[:, None], 1)[:, 0]
    leaving = cross3 & side[tris]
    leave = np.take_along_axis(hit_ids, np.argmax(leaving[hit], axis=1)[:, None], 1)[:, 0]
    nodes, local = np.unique(np.concatenate([enter, leave]), return_inverse=True)
    following = np.full(len(nodes), -1, np.int64)
    following[local[:len(enter)]] = local[len(enter):]
    # the crossing point of each node's edge
    first = np.full(edge_id.max() + 1, -1, np.int64)
    first[edge_id.ravel()[crosses]] = np.flatnonzero(crosses)
    ends = half[first[nodes]]
    di, dj = d[ends[:, 0]], d[ends[:, 1]]
    frac = (di / (di - dj))[:, None]
    points = verts[ends[:, 0]] + frac * (verts[ends[:, 1]] - verts[ends[:, 0]])
    order, starts, closed = _walk(following)
    # a vertex on the plane is reached by every edge from its negative side: one point
    merge = TOL.merge_rel * float(np.linalg.norm(np.ptp(verts, axis=0)))
    out = []
    for c in range(len(closed)):
        chain = points[order[starts[c]:starts[c + 1]]]
        step = np.linalg.norm(np.diff(chain, axis=0, append=chain[:1]), axis=1)
        keep = step > merge
        if not closed[c]:
            keep[-1] = True
        if np.any(keep):
            out.append((chain[keep], bool(closed[c])))
    return out


def _cut_at_axis(rz: np.ndarray, closed: bool) -> list[np.ndarray]:
    """Pieces of a polyline ``(M, 2)`` in (r, z) on ``r >= 0``, ends on ``r = 0`` inserted."""
    if closed:
        rz = np.vstack([rz, rz[:1]])
    pos = rz[:, 0] >= 0
    change = np.flatnonzero(pos[:-1] != pos[1:])
    if len(change) == 0:
        return [rz[:-1] if closed else rz] if pos[0] else []
    a, b = rz[change], rz[change + 1]
    frac = a[:, 0] / (a[:, 0] - b[:, 0])
    at_axis = np.column_stack([np.zeros(len(change)), a[:, 1] + frac * (b[:, 1] - a[:, 1])])
    pieces = []
    bounds = np.concatenate([[-1], change, [len(rz) - 1]])
    for k in range(len(bounds) - 1):
        lo, hi = bounds[k] + 1, bounds[k + 1] + 1
        if not pos[lo]:
            continue
        piece = [rz[lo:hi]]
        if k > 0:
            piece.insert(0, at_axis[k - 1:k])
        if k < len(change):
            piece.append(at_axis[k:k + 1])
        pieces.append(np.vstack(piece))
    if closed and pos[0] and len(pieces) > 1 and bounds[1] >= 0:
        # the piece through the loop's start: its two parts are one piece
        pieces[0] = np.vstack([pieces.pop()[:-1], pieces[0]])
    return pieces


@dataclass(frozen=True)
class HalfProfile:
    """The section of a surface by the half-plane through its axis at one azimuth.

    Attributes
    ----------
    azimuth : float
        Radians from ``e1`` towards ``e2`` of :func:`frame`.
    outer : (M, 2) float64
        ``(r, z)`` from the base up to the rim (the whole contour when there is no
        inner wall); ``r`` from the axis, ``z`` along it from ``origin``.
    inner : (K, 2) float64 or None
        ``(r, z)`` from the rim down to the inner bottom; None for a closed body.
    section : (S, 2) float64
        The cut wall as a closed polygon (outer, inner, closed along the axis).
    others : list of (L, 2) float64
        Further pieces of the section (a handle, a knob) on this half.
    """

    azimuth: float
    outer: np.ndarray
    inner: np.ndarray | None
    section: np.ndarray
    others: list = field(default_factory=list)


#: A piece whose path descends after its highest point by less than this share of the
#: object's height is one closed contour (a cap's dimple), not an outer and inner wall:
#: a drawing convention, not a measured figure.
INNER_DEPTH_SHARE = 0.25


def half_profile(vertices, triangles, axis, origin, azimuth: float = 0.0) -> HalfProfile:
    """The profile at ``azimuth`` of a closed mesh around ``axis`` through ``origin``.

    Parameters
    ----------
    vertices : (V, 3) array_like, scene units
    triangles : (F, 3) int array_like, counter-clockwise from outside
    axis : (3,) array_like
        From base to mouth.
    origin : (3,) array_like
        A point of the axis.
    azimuth : float
        Radians from ``frame(axis)[0]`` towards ``frame(axis)[1]``.

    Returns
    -------
    HalfProfile

    Raises
    ------
    ValueError
        When the half-plane meets no surface.
    """
    e1, e2, a = frame(axis)
    o = check_shape(origin, "(3,)", "origin", dtype=np.float64)
    u = np.cos(azimuth) * e1 + np.sin(azimuth) * e2
    pieces = []
    for points, closed in plane_section(vertices, triangles, o, np.cross(a, u)):
        rz = np.column_stack([(points - o) @ u, (points - o) @ a])
        for piece in _cut_at_axis(rz, closed):
            # a vertex on the axis and the cut's own point there: one point
            step = np.linalg.norm(np.diff(piece, axis=0), axis=1)
            pieces.append(piece[np.concatenate([[True], step > TOL.merge_rel * (
                1.0 + np.abs(piece).max())])])
    if not pieces:
        raise ValueError(f"the half-plane at azimuth {np.degrees(azimuth):.1f} deg meets no "
                         "surface: is the axis inside the object?")
    lengths = [np.linalg.norm(np.diff(p, axis=0), axis=1).sum() for p in pieces]
    main = pieces[int(np.argmax(lengths))]
    others = [p for k, p in enumerate(pieces) if k != int(np.argmax(lengths))]
    outer, inner = _split_walls(main)
    section = np.vstack([outer, inner[1:]]) if inner is not None else main
    return HalfProfile(float(azimuth), outer, inner, section, others)


def _split_walls(piece: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """Outer (base -> rim) and inner (rim -> bottom) walls of the main piece."""
    if piece[0, 1] > piece[-1, 1]:
        piece = piece[::-1]  # start at the lower end: the outer base
    top = int(np.argmax(piece[:, 1]))
    height = piece[:, 1].max() - piece[:, 1].min()
    descent = piece[top, 1] - piece[-1, 1]
    if top == len(piece) - 1 or descent < INNER_DEPTH_SHARE * height:
        return piece, None
    return piece[:top + 1], piece[top:]


def silhouette(vertices, triangles, axis, origin, bins: int | None = None) -> np.ndarray:
    """The outer outline seen from outside: largest radius over all azimuths per height.

    At each of ``bins`` heights the mesh's section by the plane perpendicular to the axis
    is a polygon whose vertices are the edges' crossings; its largest radius is at one of
    them, so the outline is exact for the mesh at those heights.

    Parameters
    ----------
    vertices : (V, 3) array_like
    triangles : (F, 3) int array_like
    bins : int, optional
        Heights; default ``sqrt(V)`` (about one per vertex ring of a tessellated
        surface of revolution).

    Returns
    -------
    (B + 2, 2) float64
        ``(r, z)`` from the lowest point on the axis up to the highest on the axis.
    """
    verts, tris = _check_mesh(vertices, triangles)
    _, _, a = frame(axis)
    rel = verts - np.asarray(origin, np.float64)
    z = rel @ a
    lo, hi = float(z.min()), float(z.max())
    bins = int(bins or max(8, np.sqrt(len(verts))))
    heights = lo + (np.arange(bins) + 0.5) * (hi - lo) / bins
    edges = np.unique(np.sort(np.stack([tris, np.roll(tris, -1, axis=1)], 2).reshape(-1, 2),
                              axis=1), axis=0)
    z0, z1 = z[edges[:, 0]], z[edges[:, 1]]
    step = (hi - lo) / bins
    first = np.ceil((np.minimum(z0, z1) - lo) / step - 0.5).astype(np.int64)
    last = np.floor((np.maximum(z0, z1) - lo) / step - 0.5).astype(np.int64)
    first, last = np.maximum(first, 0), np.minimum(last, bins - 1)
    count = np.maximum(last - first + 1, 0)
    edge = np.repeat(np.arange(len(edges)), count)
    k = first[edge] + (np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count))
    dz = z1[edge] - z0[edge]
    frac = np.where(dz != 0, (heights[k] - z0[edge]) / np.where(dz == 0, 1.0, dz), 0.0)
    point = rel[edges[edge, 0]] + frac[:, None] * (rel[edges[edge, 1]] - rel[edges[edge, 0]])
    radius = np.linalg.norm(point - np.outer(point @ a, a), axis=1)
    best = np.full(bins, -1.0)
    np.maximum.at(best, k, radius)
    keep = best >= 0
    return np.vstack([[0.0, lo], np.column_stack([best[keep], heights[keep]]), [0.0, hi]])


def principal_azimuths(vertices, triangles, axis, origin, height: float | None = None):
    """Azimuths of the major and minor principal axes of the section at ``height``.

    The section (plane perpendicular to ``axis`` at ``height``, default mid height)
    weighted by segment length; its 2x2 covariance in ``(e1, e2)`` gives the directions.

    Returns
    -------
    (major, minor) : float, radians
    widths : (2,) float64
        The section's extent along the major and minor directions.
    centre : (3,) float64
        The section's centroid (a point of the axis for a symmetric object).
    """
    verts, tris = _check_mesh(vertices, triangles)
    e1, e2, a = frame(axis)
    o = np.asarray(origin, np.float64)
    z = (verts - o) @ a
    h = 0.5 * (z.min() + z.max()) if height is None else float(height)
    loops = plane_section(verts, tris, o + h * a, a)
    if not loops:
        raise ValueError(f"no section at height {h:.6g} along the axis")
    segs = np.concatenate([np.stack([p, np.roll(p, -1, axis=0)], 1)[: len(p) - (not c)]
                           for p, c in loops])
    mid = segs.mean(axis=1)
    w = np.linalg.norm(segs[:, 1] - segs[:, 0], axis=1)
    centre = (w @ mid) / w.sum()
    xy = np.column_stack([(mid - centre) @ e1, (mid - centre) @ e2])
    cov = (xy * w[:, None]).T @ xy / w.sum()
    _, vec = np.linalg.eigh(cov)
    major, minor = vec[:, 1], vec[:, 0]
    pts = np.concatenate([p for p, _ in loops]) - centre
    proj = np.column_stack([pts @ e1, pts @ e2])
    widths = np.array([np.ptp(proj @ major), np.ptp(proj @ minor)])
    return (float(np.arctan2(major[1], major[0])), float(np.arctan2(minor[1], minor[0])),
            widths, centre - ((centre - o) @ a) * a)


#: Heights (or points) per block in the (G, S) work arrays against polyline segments:
#: ~10 MB a block at 5 000 segments.
_BLOCK = 256


def _radius_at(polyline: np.ndarray, heights: np.ndarray) -> np.ndarray:
    """Largest ``r`` where ``polyline`` (M, 2) crosses each height ``(G,)`` (nan: none)."""
    if len(heights) > _BLOCK:
        return np.concatenate([_radius_at(polyline, heights[k:k + _BLOCK])
                               for k in range(0, len(heights), _BLOCK)])
    a, b = polyline[:-1], polyline[1:]
    lo, hi = np.minimum(a[:, 1], b[:, 1]), np.maximum(a[:, 1], b[:, 1])
    z = heights[:, None]
    inside = (z >= lo) & (z <= hi)
    dz = b[:, 1] - a[:, 1]
    frac = np.where(np.abs(dz) > 0, (z - a[:, 1]) / np.where(dz == 0, 1.0, dz), 0.0)
    r = np.where(inside, a[:, 0] + frac * (b[:, 0] - a[:, 0]), -np.inf)
    # a horizontal segment at the height: its outer end
    r = np.where(inside & (dz == 0), np.maximum(a[:, 0], b[:, 0]), r)
    best = r.max(axis=1)
    return np.where(np.isfinite(best), best, np.nan)


def _distance_to_polyline(points: np.ndarray, polyline: np.ndarray) -> np.ndarray:
    """Distance of each point ``(G, 2)`` to a polyline ``(M, 2)``."""
    if len(points) > _BLOCK:
        return np.concatenate([_distance_to_polyline(points[k:k + _BLOCK], polyline)
                               for k in range(0, len(points), _BLOCK)])
    a, b = polyline[:-1], polyline[1:]
    ab = b - a
    t = np.clip(np.einsum("gsd,sd->gs", points[:, None] - a[None], ab)
                / np.maximum((ab * ab).sum(axis=1), TOL.zero), 0.0, 1.0)
    nearest = a[None] + t[..., None] * ab[None]
    return np.linalg.norm(points[:, None] - nearest, axis=2).min(axis=1)


def measure_profile(profile: HalfProfile, opposite: HalfProfile, heights=(),
                    tolerance: float = 0.0) -> dict:
    """Height, diameters and wall thickness of a profile.

    Parameters
    ----------
    profile, opposite : HalfProfile
        The profile at ``phi`` and at ``phi + pi`` (a diameter is the sum of their radii).
    heights : sequence of float
        Heights above the base (the lowest point) where the wall thickness is wanted.
    tolerance : float
        Band above the base and below the top in which the base and rim diameters are
        taken (the surface's uncertainty; 0 takes the extreme heights only).

    Returns
    -------
    dict
        ``height``, ``base_z``, ``rim_diameter``, ``base_diameter``, ``max_diameter``,
        ``max_diameter_height`` (above the base), ``thickness`` {height: value}, in the
        surface's unit; ``rim_diameter`` is taken at the lip's widest point within the
        wall's thickness below the top.
    """
    outer, other = profile.outer, opposite.outer
    base, top = outer[:, 1].min(), outer[:, 1].max()
    grid = np.unique(np.concatenate([outer[:, 1], other[:, 1]]))
    grid = grid[(grid >= max(base, other[:, 1].min())) & (grid <= min(top, other[:, 1].max()))]
    diam = _radius_at(outer, grid) + _radius_at(other, grid)
    k = int(np.nanargmax(diam))
    thickness = {}
    if profile.inner is not None and len(heights):
        zs = base + np.asarray(heights, np.float64)
        r_out = _radius_at(outer, zs)
        ok = np.isfinite(r_out)
        dist = np.full(len(zs), np.nan)
        if np.any(ok):
            dist[ok] = _distance_to_polyline(np.column_stack([r_out[ok], zs[ok]]),
                                             profile.inner)
        thickness = {float(h): float(t) for h, t in zip(heights, dist, strict=True)}
    # rounding: a band never narrower than the merge distance
    tolerance = max(tolerance, TOL.merge_rel * (1.0 + np.abs(outer).max()))
    lip = tolerance
    if profile.inner is not None:
        # the lip is as thick as the wall just below it: the rim diameter is the widest
        # point of the top within that depth (a rounded lip's outer face)
        lip = max(lip, _top_thickness(profile))
    # each half's own top and base: the halves of an object off its axis end apart
    rim = _band_diameter(outer, other, lip, top=True)
    base_d = _band_diameter(outer, other, tolerance, top=False)
    return {"height": float(top - base), "base_z": float(base),
            "rim_diameter": rim, "base_diameter": base_d,
            "max_diameter": float(diam[k]), "max_diameter_height": float(grid[k] - base),
            "thickness": thickness}


def _top_thickness(profile: HalfProfile) -> float:
    """A first guess of the wall's thickness at the rim: the rim point's distance from
    the inner wall a tenth of the inner depth down."""
    inner = profile.inner
    depth = inner[0, 1] - inner[:, 1].min()
    probe = np.array([inner[0, 1] - 0.1 * depth])
    r_out = _radius_at(profile.outer, probe)
    if not np.isfinite(r_out[0]):
        return 0.0
    return float(_distance_to_polyline(np.column_stack([r_out, probe]), inner)[0])


def _band_diameter(outer: np.ndarray, other: np.ndarray, band: float, top: bool) -> float:
    """Sum of both halves' largest radii within ``band`` of each half's top (or base)."""
    def widest(poly):
        z = poly[:, 1]
        lo, hi = (z.max() - band, z.max()) if top else (z.min(), z.min() + band)
        inside = poly[(z >= lo) & (z <= hi), 0]
        ends = _radius_at(poly, np.array([lo, hi]))
        return float(np.max(np.concatenate([inside, ends[np.isfinite(ends)]])))
    return widest(outer) + widest(other)


def revolve(rz, segments: int) -> tuple[np.ndarray, np.ndarray]:
    """Closed triangle mesh of the surface of revolution of a profile about ``z``.

    Parameters
    ----------
    rz : (M, 2) array_like
        ``(r, z)`` from a point on the axis (``r = 0``) to another, the solid on the
        left walking along it seen with ``r`` to the right and ``z`` up (counter-clockwise
        round the half-section); interior points have ``r > 0``.
    segments : int
        Points on each ring.

    Returns
    -------
    vertices : (2 + (M - 2) segments, 3) float64
    triangles : (F, 3) int64, counter-clockwise from outside
    """
    rz = check_shape(rz, "(M, 2)", "rz", dtype=np.float64)
    if len(rz) < 3 or rz[0, 0] != 0 or rz[-1, 0] != 0 or np.any(rz[1:-1, 0] <= 0):
        raise ValueError("rz must start and end on the axis (r = 0) with r > 0 between")
    theta = 2 * np.pi * np.arange(segments) / segments
    ring = rz[1:-1]
    rings = np.stack([ring[:, :1] * np.cos(theta), ring[:, :1] * np.sin(theta),
                      np.broadcast_to(ring[:, 1:], (len(ring), segments))], axis=2)
    vertices = np.vstack([[0.0, 0.0, rz[0, 1]], rings.reshape(-1, 3), [0.0, 0.0, rz[-1, 1]]])
    n = segments
    j = np.arange(n)
    jn = (j + 1) % n
    ids = 1 + np.arange(len(ring))[:, None] * n + j  # (R, n)
    first = np.column_stack([np.zeros(n, np.int64), ids[0, jn], ids[0, j]])
    last_id = len(vertices) - 1
    last = np.column_stack([np.full(n, last_id), ids[-1, j], ids[-1, jn]])
    a, b = ids[:-1], ids[1:]
    an, bn = a[:, jn], b[:, jn]
    quads = np.concatenate([np.stack([a, an, bn], -1).reshape(-1, 3),
                            np.stack([a, bn, b], -1).reshape(-1, 3)])
    tris = np.vstack([first, quads, last]).astype(np.int64)
    return vertices, tris
