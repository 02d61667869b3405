r"""Volume, area and capacity of a closed surface: exact integrals over the sextic patches.

Area and volume of a Bézier surface ``S(s, t)`` (patch corners ``tri[0..2]`` at
``(s, t) = (0, 0), (1, 0), (0, 1)``; ``r = 1 - s - t``, counter-clockwise from outside):

.. math::

    A = \sum_p \int_T \lVert S_s \times S_t \rVert \, ds\, dt, \qquad
    V = \frac{1}{3} \oint x \cdot n \, dA
      = \frac{1}{3} \sum_p \int_T S \cdot (S_s \times S_t) \, ds\, dt

(divergence theorem with ``div x = 3``).  For a sextic ``S`` the volume integrand is a
polynomial of degree ``6 + 5 + 5 = 16`` in ``(s, t)``: a triangle rule exact to degree
16 makes ``V`` exact up to rounding.  The rule (:func:`triangle_rule`) is Stroud's conical
product [1]_ (``n`` Gauss-Jacobi points, weight ``1 - s``, times ``n`` Gauss-Legendre points
through the collapsed square ``s = u, t = (1 - u) v``), exact to degree ``2n - 1``, averaged
over the six permutations of ``(r, s, t)`` (``6 n^2`` points; no corner comes first).
The area integrand is not a polynomial: the same degree-17 rule, its error estimated by
the difference to the degree-13 rule.  A triangle mesh: ``V = (1/6) sum v0 . (v1 x v2)``
(signed tetrahedra), ``A = sum |e1 x e2| / 2``.

Capacity of a vessel (:func:`capacity`): the cavity ``C`` is bounded by the inner wall and
bottom below the plane ``z = h`` (``z`` along the unit axis ``a`` from ``origin``) and by
the plane's disc.  With the field ``F = (z - h) a`` (``div F = 1``, ``F = 0`` on the plane)

.. math::  V_C = \oint_{\partial C} F \cdot n_C \, dA
               = \int_{\text{inner wall}, z < h} (h - z)\, (a \cdot n) \, dA,

``n`` the solid's outward normal (``n_C = -n`` on the wall): the cap disc carries no flux.
A surface point faces the cavity when two rays from just outside it (``eps`` along the
normal) hit the surface: along ``-a`` (closed below) and radially away from the axis
(closed around).  The integral runs over the tessellation, triangles clipped at the plane
exactly (``int (h - z) dA = area (h - z_centroid)``), within the chord bound times the wet
area.  The rim height is the lowest point of the longest loop of edges between cavity and
other triangles (the lip's edge): the level at which the vessel overflows.

References
----------
.. [1] A. H. Stroud, "Approximate calculation of multiple integrals" (1971), section 2.7.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache
from itertools import permutations

import numpy as np

from surface.validate import TOL, check_finite, check_shape

__all__ = ["Capacity", "capacity", "chord_bound", "mesh_area", "mesh_volume", "surface_area",
           "surface_integrals", "surface_volume", "triangle_rule"]

#: The volume integrand S . (S_s x S_t) of a sextic patch has degree 6 + 5 + 5.
VOLUME_DEGREE = 16
#: The check rule for the area (not a polynomial integrand): the area's quadrature error
#: is estimated as the difference between the degree-17 rule (the volume's) and this one.
AREA_CHECK_DEGREE = 13
#: Patches per chunk: (3 Q, chunk, 3) float64 work arrays of ~25 MB at Q = 864.
_CHUNK = 1024


@cache
def triangle_rule(degree: int) -> tuple[np.ndarray, np.ndarray]:
    """Symmetric quadrature on the unit triangle exact for polynomials of ``degree``.

    Parameters
    ----------
    degree : int
        Total degree integrated exactly (the rule is exact to ``2n - 1 >= degree``).

    Returns
    -------
    bary : (Q, 3) float64
        Barycentric nodes ``(r, s, t)``, ``Q = 6 n^2``.
    weights : (Q,) float64
        Sum to 1/2, the area of the ``(s, t)`` triangle.
    """
    from scipy.special import roots_jacobi, roots_legendre

    n = max(1, (int(degree) + 2) // 2)
    xj, wj = roots_jacobi(n, 1.0, 0.0)  # weight (1 - x) on [-1, 1]
    xl, wl = roots_legendre(n)
    u, wu = (1.0 + xj) / 2.0, wj / 4.0  # int_0^1 g(u) (1 - u) du = sum wu g(u)
    v, wv = (1.0 + xl) / 2.0, wl / 2.0
    s = np.repeat(u, n)
    t = (1.0 - s) * np.tile(v, n)
    weights = np.outer(wu, wv).ravel()
    base = np.column_stack([1.0 - s - t, s, t])
    bary = np.concatenate([base[:, list(p)] for p in permutations(range(3))])
    weights = np.tile(weights, 6) / 6.0
    bary.flags.writeable = False
    weights.flags.writeable = False
    return bary, weights


@cache
def _basis(degree: int) -> np.ndarray:
    """``(3Q, 28)``: rows giving S, S_s and S_t at the nodes of :func:`triangle_rule`."""
    from surface import bezier

    bary, _ = triangle_rule(degree)
    du, dv = bezier._derivative_operators()
    low = bezier.bernstein_matrix(bary, bezier.DEGREE - 1)
    stacked = np.concatenate([bezier.bernstein_matrix(bary, bezier.DEGREE), low @ du, low @ dv])
    stacked.flags.writeable = False
    return stacked


def _integrands(cp: np.ndarray, degree: int, centre: np.ndarray):
    """``(Q, P)`` arrays of S . (S_s x S_t) and |S_s x S_t| at the rule's nodes."""
    from surface.bezier import _apply, _cross

    basis = _basis(degree)
    q = len(basis) // 3
    fields = _apply(basis, cp - centre)  # (3Q, P, 3): S, S_s, S_t
    normal = _cross(fields[q:2 * q], fields[2 * q:])
    return np.einsum("qpd,qpd->qp", fields[:q], normal), np.linalg.norm(normal, axis=2)


def _check_net(control_points) -> np.ndarray:
    from surface.bezier import N_CONTROL

    cp = check_shape(control_points, f"(P, {N_CONTROL}, 3)", "control_points",
                     dtype=np.float64)
    if len(cp) == 0:
        raise ValueError("control_points holds no patch")
    return check_finite(cp, "control_points")


def surface_integrals(control_points) -> dict[str, float]:
    """Volume and area of a Bézier surface, with the area's quadrature error.

    Parameters
    ----------
    control_points : (P, 28, 3) array_like, scene units
        Sextic nets (index order of :func:`surface.bezier.index_table`), oriented
        counter-clockwise from outside.

    Returns
    -------
    dict
        ``volume`` (unit³; exact up to rounding for a closed surface, the signed volume
        of the cone from the bounding-box centre otherwise), ``area`` (unit²),
        ``area_error`` (the degree-17 minus the degree-13 rule's area, in absolute value:
        an over-estimate of the degree-17 rule's error), ``patches``.
    """
    cp = _check_net(control_points)
    centre = 0.5 * (cp.reshape(-1, 3).min(axis=0) + cp.reshape(-1, 3).max(axis=0))
    _, w_volume = triangle_rule(VOLUME_DEGREE)
    _, w_check = triangle_rule(AREA_CHECK_DEGREE)
    volume = area = check = 0.0
    for start in range(0, len(cp), _CHUNK):
        part = cp[start:start + _CHUNK]
        triple, jac = _integrands(part, VOLUME_DEGREE, centre)
        volume += float(w_volume @ triple.sum(axis=1)) / 3.0
        area += float(w_volume @ jac.sum(axis=1))
        _, jac = _integrands(part, AREA_CHECK_DEGREE, centre)
        check += float(w_check @ jac.sum(axis=1))
    return {"volume": volume, "area": area, "area_error": abs(area - check),
            "patches": len(cp)}


def surface_volume(control_points) -> float:
    """Enclosed volume of a closed Bézier surface ``(P, 28, 3)`` (exact, degree-16 rule)."""
    return surface_integrals(control_points)["volume"]


def surface_area(control_points) -> float:
    """Area of a Bézier surface ``(P, 28, 3)`` (degree-17 rule)."""
    return surface_integrals(control_points)["area"]


def _check_mesh(vertices, triangles) -> tuple[np.ndarray, np.ndarray]:
    verts = check_finite(check_shape(vertices, "(V, 3)", "vertices", dtype=np.float64),
                         "vertices")
    tris = check_shape(triangles, "(F, 3)", "triangles")
    if not np.issubdtype(tris.dtype, np.integer):
        raise ValueError(f"triangles must hold integer vertex ids, got dtype {tris.dtype}")
    if tris.size and (tris.min() < 0 or tris.max() >= len(verts)):
        raise ValueError(f"triangles index vertices 0..{len(verts) - 1}, got "
                         f"{tris.min()}..{tris.max()}")
    return verts, tris.astype(np.int64)


def mesh_volume(vertices, triangles) -> float:
    """Signed volume of a closed triangle mesh, ``(1/6) sum v0 . (v1 x v2)``.

    Parameters
    ----------
    vertices : (V, 3) array_like, scene units
    triangles : (F, 3) int array_like, counter-clockwise from outside

    Returns
    -------
    float, unit³ (positive for an outward-oriented closed mesh)
    """
    verts, tris = _check_mesh(vertices, triangles)
    centre = 0.5 * (verts.min(axis=0) + verts.max(axis=0)) if len(verts) else np.zeros(3)
    v = verts[tris] - centre  # (F, 3, 3)
    return float(np.einsum("fd,fd->f", v[:, 0], np.cross(v[:, 1], v[:, 2])).sum() / 6.0)


def mesh_area(vertices, triangles) -> float:
    """Area of a triangle mesh ``(V, 3)``, ``(F, 3)``, unit²."""
    verts, tris = _check_mesh(vertices, triangles)
    v = verts[tris]
    return float(np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1).sum()
                 / 2.0)


# ----------------------------------------------------------------------------- capacity
@dataclass(frozen=True)
class Capacity:
    """The cavity of a vessel below a plane perpendicular to its axis.

    Attributes
    ----------
    volume : float
        Cavity volume below ``height``, unit³ (0 when no surface faces a cavity).
    height : float
        The plane's height along the axis from ``origin`` (the rim when not given).
    rim_height : float or nan
        Lowest point of the cavity's rim (nan: no cavity).
    wet_area : float
        Area of the cavity's wall below ``height``, unit²: ``sigma_V ~ sigma_n * wet_area``.
    cavity_triangles : (F,) bool
        The tessellation's triangles facing the cavity.
    """

    volume: float
    height: float
    rim_height: float
    wet_area: float
    cavity_triangles: np.ndarray


def _perpendicular_frame(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    helper = np.eye(3)[int(np.argmin(np.abs(axis)))]
    e1 = np.cross(axis, helper)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(axis, e1)


def _unit_axis(axis) -> np.ndarray:
    a = check_finite(check_shape(axis, "(3,)", "axis", dtype=np.float64), "axis")
    norm = float(np.linalg.norm(a))
    if norm <= TOL.zero:
        raise ValueError("axis must have non-zero length")
    return a / norm


def cavity_vertices(vertices, triangles, normals, axis, origin) -> np.ndarray:
    """Which surface points face a cavity closed below and around: ``(V,) bool``.

    A point ``p`` with outward normal ``n`` is moved to ``q = p + eps n`` (off the
    surface, on the open side); it faces a cavity when the rays from ``q`` along ``-a``
    and radially away from the axis both hit the surface.  ``eps`` is 1e-4 of the
    bounding-box diagonal: above the rounding of a ray cast, far below a wall's thickness.
    """
    import open3d as o3d

    verts, tris = _check_mesh(vertices, triangles)
    nrm = check_shape(normals, "(V, 3)", "normals", dtype=np.float64)
    a = _unit_axis(axis)
    o = check_shape(origin, "(3,)", "origin", dtype=np.float64)
    diag = float(np.linalg.norm(verts.max(axis=0) - verts.min(axis=0)))
    eps = 1e-4 * diag
    unit = nrm / np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), TOL.zero)
    q = verts + eps * unit
    radial = (q - o) - np.outer((q - o) @ a, a)
    length = np.linalg.norm(radial, axis=1, keepdims=True)
    e1, _ = _perpendicular_frame(a)
    # on the axis itself any radial direction: the cavity around it is closed all round
    radial = np.where(length > eps, radial / np.maximum(length, TOL.zero), e1)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(verts.astype(np.float32)),
                        o3d.core.Tensor(tris.astype(np.uint32)))
    origins = np.concatenate([q, q]).astype(np.float32)
    directions = np.concatenate([np.broadcast_to(-a, q.shape), radial]).astype(np.float32)
    hits = scene.cast_rays(o3d.core.Tensor(np.hstack([origins, directions])))
    t_hit = np.isfinite(hits["t_hit"].numpy()).reshape(2, -1)
    return t_hit[0] & t_hit[1]


def _rim_height(vertices: np.ndarray, triangles: np.ndarray, cavity: np.ndarray,
                z: np.ndarray) -> float:
    """Lowest point of the cavity's rim: the longest loop of edges between cavity and
    other triangles (the lip's edge; a stray patch gives a short loop) -- where it spills."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    if not np.any(cavity) or np.all(cavity):
        return float("nan")
    edges = np.sort(np.stack([triangles, np.roll(triangles, -1, axis=1)], 2).reshape(-1, 2),
                    axis=1)
    owner = np.repeat(cavity, 3)
    key = edges[:, 0] * len(vertices) + edges[:, 1]
    order = np.argsort(key, kind="stable")
    key, edges, owner = key[order], edges[order], owner[order]
    # an edge is on the rim when its two triangles are one cavity, one not
    pair = np.flatnonzero((key[:-1] == key[1:]) & (owner[:-1] != owner[1:]))
    rim = edges[pair]
    if len(rim) == 0:
        return float("nan")
    n = len(vertices)
    graph = coo_matrix((np.ones(len(rim)), (rim[:, 0], rim[:, 1])), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    length = np.linalg.norm(vertices[rim[:, 0]] - vertices[rim[:, 1]], axis=1)
    totals = np.bincount(label[rim[:, 0]], weights=length, minlength=n)
    longest = int(np.argmax(totals))
    return float(z[rim[label[rim[:, 0]] == longest]].min())


def _clip_below(tri: np.ndarray, z: np.ndarray, h: float) -> np.ndarray:
    """Pieces ``(M, 3, 3)`` of triangles ``(F, 3, 3)`` below ``z = h`` (orientation kept)."""
    below = z < h
    count = below.sum(axis=1)
    pieces = [tri[count == 3]]
    for n_below in (1, 2):
        sel = count == n_below
        if not np.any(sel):
            continue
        t, zz, b = tri[sel], z[sel], below[sel]
        odd = np.argmax(b if n_below == 1 else ~b, axis=1)  # the vertex alone on its side
        order = (odd[:, None] + np.arange(3)[None]) % 3
        t = np.take_along_axis(t, order[:, :, None], axis=1)
        zz = np.take_along_axis(zz, order, axis=1)
        f1 = ((h - zz[:, 0]) / (zz[:, 1] - zz[:, 0]))[:, None]
        f2 = ((h - zz[:, 0]) / (zz[:, 2] - zz[:, 0]))[:, None]
        p01 = t[:, 0] + f1 * (t[:, 1] - t[:, 0])
        p02 = t[:, 0] + f2 * (t[:, 2] - t[:, 0])
        if n_below == 1:
            pieces.append(np.stack([t[:, 0], p01, p02], axis=1))
        else:
            pieces.append(np.stack([p01, t[:, 1], t[:, 2]], axis=1))
            pieces.append(np.stack([p01, t[:, 2], p02], axis=1))
    return np.concatenate(pieces)


def capacity(vertices, triangles, normals, axis, origin, height=None) -> Capacity:
    """Volume of the cavity of a vessel up to its rim (or up to ``height``).

    Parameters
    ----------
    vertices : (V, 3) array_like, scene units
        A closed tessellation of the surface (outer wall, rim, inner wall and bottom).
    triangles : (F, 3) int array_like, counter-clockwise from outside
    normals : (V, 3) array_like
        Outward normals at the vertices (exact ones from the patches, or the mesh's).
    axis : (3,) array_like
        The vessel's axis, pointing from base to mouth.
    origin : (3,) array_like
        A point of the axis; heights are measured along ``axis`` from it.
    height : float, optional
        Fill level along the axis from ``origin``; default the rim (overflow) height.

    Returns
    -------
    Capacity
        ``volume`` is exact for the tessellation given; against the smooth surface it is
        within ``chord bound x wet_area``.
    """
    verts, tris = _check_mesh(vertices, triangles)
    a = _unit_axis(axis)
    o = check_shape(origin, "(3,)", "origin", dtype=np.float64)
    cavity_v = cavity_vertices(verts, tris, normals, a, o)
    # a triangle faces the cavity when most of its corners do (the rim's edge splits some)
    cavity_t = cavity_v[tris].sum(axis=1) >= 2
    z = (verts - o) @ a
    rim = _rim_height(verts, tris, cavity_t, z)
    h = rim if height is None else float(height)
    if not np.any(cavity_t) or not np.isfinite(h):
        return Capacity(0.0, h, rim, 0.0, cavity_t)
    tri = verts[tris[cavity_t]] - o
    pieces = _clip_below(tri, tri @ a, h)
    cross = np.cross(pieces[:, 1] - pieces[:, 0], pieces[:, 2] - pieces[:, 0])  # 2 A n
    depth = h - pieces.mean(axis=1) @ a
    volume = float(np.sum(depth * (cross @ a)) / 2.0)
    wet = float(np.linalg.norm(cross, axis=1).sum() / 2.0)
    return Capacity(volume, h, rim, wet, cavity_t)


def chord_bound(control_points, level: int) -> float:
    """Bound of the distance between the patches and their level-``level`` tessellation.

    The second-difference bound ``n (n - 1) M2 / 2`` of each net
    (:func:`surface.bezier.tessellation_level`'s), which shrinks by 4 per level: scene units.
    """
    from surface.bezier import _second_difference_bound

    cp = _check_net(control_points)
    return float(_second_difference_bound(cp).max()) / 4 ** int(level)
