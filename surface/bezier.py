r"""Loop's tangent-plane-continuous sextic triangular Bézier surface.

Each triangle of the (once Loop-refined) control mesh carries one sextic patch

.. math::

    P(r, s, t) = \sum_{i+j+k=6} b_{ijk} \, B_{ijk}(r, s, t), \qquad
    B_{ijk} = \frac{6!}{i!\,j!\,k!} r^i s^j t^k, \quad r + s + t = 1,

after C. Loop, SIGGRAPH 1994 [1]_; ``(r, s, t)`` weight the domain corners ``tri[0..2]``
(counter-clockwise from outside).  The 28 control points ``(P, 28, 3)`` are stored
descending in i, then in j: ``index(i, j, k) = m (m + 1) / 2 + k``, ``m = 6 - i``
(:func:`index_table`, :func:`control_index`; the same rule for every degree here).

Construction (:func:`control_net`): (1) one Loop subdivision step [2]_, after which a
triangle has at most one vertex of valence != 6; (2) regular patches are the quartic box
spline of Loop subdivision, degree-elevated to 6 (C2 between them: the limit surface
itself); (3) around an irregular vertex of valence n the patches meet Loop's limit point,
join their regular neighbours C1, and satisfy the scalar G1 condition across each spoke

.. math::  D_l(t) + D_r(t) = \lambda(t)\, D_e(t), \qquad
           \lambda(t) = 2\cos(2\pi/n)\,(1 - t) + t;

the free points are the constrained least-squares fit to Loop's limit surface at 45 points
a patch (a fixed linear map per valence, split by a DFT into n small problems), instead of
Loop's explicit formulas: close to, not equal to, the limit surface there (at most 0.6 % of
the control edge on a subdivided cube).  Borders are closed by two layers of reflected
ghost triangles (``g = a + b - c``); only the input faces' patches are returned, G1 across
every interior edge.  Bad meshes raise ``ValueError``; in full: ``docs/method/bezier.md``.

Here: the construction, shared control points, tensor-product form, closest points; the
patch algebra (:mod:`surface.bezier_patch`), tessellation (:mod:`surface.bezier_tessellation`)
and G1 report (:mod:`surface.bezier_continuity`) are offered here by name too.

References
----------
.. [1] C. Loop, "Smooth spline surfaces over irregular meshes", SIGGRAPH 94, 303-310.
.. [2] C. Loop, "Smooth subdivision surfaces based on triangles", MSc thesis, Utah (1987).
.. [3] G. Farin, "Triangular Bernstein-Bézier patches", CAGD 3 (1986) 83-127.
"""

from __future__ import annotations

from fractions import Fraction
from functools import cache
from math import factorial

import numba
import numpy as np

from surface._blas import one_blas_thread
from surface._loop_patches import build_surface
from surface.bezier_continuity import (  # noqa: F401  (offered here too)
    _edge_pairs,
    _edge_samples,
    corner_normals,
    edge_continuity,
)
from surface.bezier_patch import (  # noqa: F401  (the patch algebra, offered here too)
    _EXTEND,
    DEGREE,
    N_CONTROL,
    BezierSurface,
    _apply,
    _bernstein,
    _blossom_matrix,
    _check_control_points,
    _clipped_trial,
    _cross,
    _derivative_operators,
    _empty_pages,
    bernstein_matrix,
    control_index,
    elevate,
    evaluate,
    index_table,
    normals,
    subdivide,
)
from surface.bezier_tessellation import (  # noqa: F401  (offered here too)
    _edge_ids,
    _global_sample_ids,
    _grid,
    _patches_and_domain,
    _SampleLayout,
    _second_difference_bound,
    adaptive_segments,
    certified_segments,
    chord_error_bound,
    plane_deviation,
    tessellate,
    tessellate_adaptive,
    tessellation_level,
)
from surface.validate import TOL, check_finite, check_shape

__all__ = [
    "DEGREE",
    "N_CONTROL",
    "BezierSurface",
    "bernstein_matrix",
    "chord_error_bound",
    "control_index",
    "control_net",
    "control_point_ids",
    "corner_normals",
    "edge_continuity",
    "elevate",
    "evaluate",
    "index_table",
    "normals",
    "share_boundaries",
    "subdivide",
    "tensor_product_nets",
    "adaptive_segments",
    "certified_segments",
    "closest_points",
    "tessellate",
    "tessellate_adaptive",
    "tessellation_level",
]

# ----------------------------------------------------------------------------- the surface
@one_blas_thread
def control_net(vertices, triangles) -> BezierSurface:
    """Loop's G1 sextic Bézier surface over a triangle mesh (closed or bordered).

    Parameters
    ----------
    vertices : (V, 3) array_like, scene units
    triangles : (F, 3) int array_like
        Counter-clockwise seen from outside, 2-manifold (closed or with
        borders).

    Returns
    -------
    BezierSurface
        ``4F`` patches over the once Loop-refined mesh (see the module notes).

    Raises
    ------
    ValueError
        Non-finite vertices, out-of-range indices, non-manifold edges or
        vertices, inconsistent orientation, degenerate (zero-area) triangles.

    Notes
    -----
    Borders are allowed and handled by the ghost-layer rule of the module
    notes; vertices used by no triangle are dropped before refinement.
    """
    verts = check_shape(vertices, "(V, 3)", "vertices", dtype=np.float64)
    check_finite(verts, "vertices")
    tris = check_shape(triangles, "(F, 3)", "triangles")
    if not np.issubdtype(tris.dtype, np.integer):
        raise ValueError(f"triangles must hold integer vertex ids, got dtype {tris.dtype}")
    tris = tris.astype(np.int64)
    cp, source, refined_vertices, refined_tris = build_surface(verts, tris)
    share_boundaries(cp, refined_tris)
    return BezierSurface(cp, source, (refined_vertices, refined_tris))


def control_point_ids(triangles) -> tuple[np.ndarray, int]:
    """Topological id of every control point: shared boundary points get one id.

    Control point ``(i, j, k)`` of patch ``p`` is numbered as a sample of a
    degree-6 grid over the domain triangle (:func:`_global_sample_ids` with 6
    segments): a corner by its domain vertex, a point on an edge (one index 0)
    by the undirected domain edge and its position counted from the edge's lower
    vertex id, an interior point (no index 0) per patch.  Neighbouring patches
    therefore give their common boundary points the same id.

    Parameters
    ----------
    triangles : (P, 3) int array_like
        Domain triangles of the patches (``BezierSurface.domain_mesh[1]``),
        every vertex id in ``0 .. max`` used.

    Returns
    -------
    ids : (P, 28) int64
        Id of control point ``m`` of patch ``p``, in the module's index order.
    count : int
        ``V + 5 E + 10 P`` distinct ids (V domain vertices, E domain edges).
    """
    tris = check_shape(triangles, "(P, 3)", "triangles", dtype=np.int64)
    layout = _SampleLayout.of(tris, DEGREE, index_table())
    return _global_sample_ids(tris, DEGREE, index_table(), layout), layout.n_ids


def gather_shared(control_points: np.ndarray, ids: np.ndarray, count: int
                  ) -> tuple[np.ndarray, np.ndarray] | None:
    """The distinct points of a net numbered by ``ids``, or ``None`` where copies differ.

    Parameters
    ----------
    control_points : (P, N, 3) float64
    ids : (P, N) int64
        Id of every control point in ``0 .. count - 1`` (e.g. :func:`control_point_ids`).
    count : int

    Returns
    -------
    points : (count, 3) float64
        ``points[ids] == control_points`` (ids no point has are left zero).
    used : (count,) bool
        The ids some point has.
    Or ``None`` when two points of one id differ (``!=``).
    """
    cp = np.ascontiguousarray(control_points, dtype=np.float64)
    points = np.zeros((int(count), 3))
    used = np.zeros(int(count), dtype=np.bool_)
    ok = _gather_shared(cp, np.ascontiguousarray(ids, dtype=np.int64), points, used)
    return (points, used) if ok else None


@numba.njit(cache=True, nogil=True)
def _gather_shared(cp, ids, points, seen):  # pragma: no cover
    """One pass: the first copy of an id is stored, every later one compared (``!=``, as
    ``numpy.array_equal``; the nets are finite)."""
    for p in range(ids.shape[0]):
        for m in range(ids.shape[1]):
            g = ids[p, m]
            if not seen[g]:
                seen[g] = True
                for d in range(3):
                    points[g, d] = cp[p, m, d]
            else:
                for d in range(3):
                    if points[g, d] != cp[p, m, d]:
                        return False
    return True


def share_boundaries(control_points: np.ndarray, triangles: np.ndarray) -> float:
    """Make the boundary control points that neighbouring patches share bit-identical, in place.

    The construction computes a shared boundary point on both sides of an edge
    from different stencils (a box-spline GEMM per patch, or a ring operator),
    so the two copies agree only to rounding (measured on the demo's control
    mesh: a few units in the last place).  Each id of :func:`control_point_ids`
    takes the value one of its patches gave, so the surface is exactly
    watertight and its control net can be stored once per id
    (``pipeline.export`` format version 2).

    Parameters
    ----------
    control_points : (P, 28, 3) float64, changed in place
    triangles : (P, 3) int64
        Domain triangles, as for :func:`control_point_ids`.

    Returns
    -------
    float
        The largest change made (scene units).
    """
    ids, count = control_point_ids(triangles)
    if not control_points.flags.c_contiguous:
        raise ValueError("share_boundaries changes control_points in place: give a "
                         "C-contiguous array")
    return float(_share_rows(control_points.reshape(-1, 3), ids.ravel(), np.empty((count, 3))))


@numba.njit(cache=True, nogil=True)
def _share_rows(flat, ids, shared):  # pragma: no cover
    """``flat[r] = shared[ids[r]]`` with each id's value its last row's (rows in order, as
    a numpy fancy assignment leaves it); returns the largest coordinate change."""
    for r in range(len(ids)):
        for d in range(3):
            shared[ids[r], d] = flat[r, d]
    change = 0.0
    for r in range(len(ids)):
        for d in range(3):
            value = shared[ids[r], d]
            change = max(change, abs(value - flat[r, d]))
            flat[r, d] = value
    return change


# ----------------------------------------------------------------------------- tensor-product form
@cache
def _quad_matrix(corner: int) -> np.ndarray:
    """See :func:`_corner_quad_matrix`; the other corners by relabelling the net."""
    if corner == 0:
        return _corner_quad_matrix()
    # corner c of the net is corner 0 of the net relabelled (c, c + 1, c + 2) -> (0, 1, 2):
    # its point (i', j', k') is the original point whose exponent at corner c is i', ...
    multi = index_table()
    original = np.roll(multi, corner, axis=1)  # (i', j', k') -> exponents at (0, 1, 2)
    columns = control_index(original[:, 0], original[:, 1], original[:, 2])
    out = np.empty_like(_corner_quad_matrix())
    out[:, columns] = _corner_quad_matrix()
    out.flags.writeable = False
    return out


@cache
def _corner_quad_matrix() -> np.ndarray:
    """``(49, 28)`` map from a sextic triangular net to the degree (6, 6) tensor-product
    net of its quadrilateral at ``corner`` (corner, edge midpoint, centroid, edge midpoint).

    The quadrilateral is the image of the unit square under the bilinear map
    ``x(u, v) = (1-u)(1-v) e_c + u(1-v) m_{c,c+1} + u v g + (1-u) v m_{c,c+2}``
    (barycentric), so ``P(x(u, v))`` is a polynomial of degree 6 in u and in v,
    i.e. exactly a tensor-product Bézier patch.  Its net is found by
    interpolation at the 7 x 7 grid ``(a/6, b/6)`` in exact rational arithmetic
    (``fractions.Fraction``), so the matrix is exact to the last bit of each
    entry and its zeros are zeros (a quadrilateral's boundary row on the
    triangle's edge depends on that edge's 7 control points only).
    Row ``7 k + l`` is the pole of u-index k and v-index l.
    """
    def bernstein1(k, x):
        return Fraction(factorial(DEGREE), factorial(k) * factorial(DEGREE - k)) \
            * x ** k * (1 - x) ** (DEGREE - k)

    eye = [[Fraction(int(a == b)) for b in range(3)] for a in range(3)]
    half = Fraction(1, 2)
    e_c, e_next, e_prev = eye[0], eye[1], eye[2]
    m_next = [half * (a + b) for a, b in zip(e_c, e_next, strict=True)]
    m_prev = [half * (a + b) for a, b in zip(e_c, e_prev, strict=True)]
    centroid = [Fraction(1, 3)] * 3
    nodes = [Fraction(a, DEGREE) for a in range(DEGREE + 1)]
    multi = index_table()
    weights = [Fraction(factorial(DEGREE), factorial(i) * factorial(j) * factorial(k))
               for i, j, k in multi.tolist()]
    values = []  # (49, 28): the triangle's Bernstein basis at the grid's images
    for u in nodes:
        for v in nodes:
            bary = [(1 - u) * (1 - v) * a + u * (1 - v) * b + u * v * c + (1 - u) * v * d
                    for a, b, c, d in zip(e_c, m_next, centroid, m_prev, strict=True)]
            values.append([w * bary[0] ** i * bary[1] ** j * bary[2] ** k
                           for w, (i, j, k) in zip(weights, multi.tolist(), strict=True)])
    # 1-D Bernstein collocation matrix and its inverse (Gauss-Jordan on fractions)
    n = DEGREE + 1
    aug = [[bernstein1(k, x) for k in range(n)] + [Fraction(int(r == c)) for c in range(n)]
           for r, x in enumerate(nodes)]
    for col in range(n):
        pivot = next(r for r in range(col, n) if aug[r][col] != 0)
        aug[col], aug[pivot] = aug[pivot], aug[col]
        scale = aug[col][col]
        aug[col] = [x / scale for x in aug[col]]
        for r in range(n):
            if r != col and aug[r][col] != 0:
                factor = aug[r][col]
                aug[r] = [x - factor * y for x, y in zip(aug[r], aug[col], strict=True)]
    inverse = [row[n:] for row in aug]
    out = np.zeros((n, n, N_CONTROL))
    for m in range(N_CONTROL):  # C = V^-1 X V^-T for each basis function's grid values X
        half_way = [[sum(inverse[k][a] * values[n * a + b][m] for a in range(n))
                     for b in range(n)] for k in range(n)]
        for k in range(n):
            for l in range(n):
                out[k, l, m] = float(sum(half_way[k][b] * inverse[l][b] for b in range(n)))
    out = out.reshape(n * n, N_CONTROL)
    out.flags.writeable = False
    return out


def tensor_product_nets(control_points) -> np.ndarray:
    """Each sextic triangular patch as three degree (6, 6) tensor-product Bézier patches.

    The triangle is split at its centroid and edge midpoints into three
    quadrilaterals, one per corner; each is exactly a non-degenerate
    tensor-product patch (:func:`_quad_matrix`), the form CAD kernels and STEP
    store (``B_SPLINE_SURFACE_WITH_KNOTS`` of degree 6 x 6 with Bézier knots).

    Parameters
    ----------
    control_points : (P, 28, 3) array_like

    Returns
    -------
    (P, 3, 7, 7, 3) float64
        ``out[p, c, k, l]`` is the pole ``(k, l)`` of the quadrilateral at corner
        ``c`` of patch ``p``: u runs from the corner to the midpoint of edge
        ``c -> c + 1``, v to the midpoint of edge ``c -> c + 2``, so
        ``dS/du x dS/dv`` points the way the triangle's normal does (outward for
        a counter-clockwise domain triangle); ``(6, 6)`` is the centroid.
    """
    cp = _check_control_points(control_points)
    stacked = np.concatenate([_quad_matrix(c) for c in range(3)])  # (147, 28)
    out = _apply(stacked, cp)  # (147, P, 3)
    return out.reshape(3, 7, 7, len(cp), 3).transpose(3, 0, 1, 2, 4)


# ----------------------------------------------------------------------------- closest points
def closest_points(control_points, points, triangles=None, level: int = 1,
                   iterations: int = 4, tessellated=None):
    """Nearest points of the smooth surface itself (not of a tessellation) to ``points``.

    A flat tessellation lies inside a convex surface by its chord error, ``κ e² / 8``
    for edges ``e``: at the level-1 tessellation of a control mesh of edge ``h``
    (``e = h / 4``) that is ``κ h² / 128`` -- on the demo's sized candidates (h ≈ 0.08,
    κ ≈ 1) 5e-5, as large as the noise the sizing compares distances with, and growing
    as h², so that it, not the surface, decided how coarse a candidate could be.
    Here each point's nearest triangle of the level-``level`` tessellation (open3d's
    ``RaycastingScene.compute_closest_points``) gives its patch and a starting
    parameter, and Gauss-Newton on that patch's sextic ``P(r, s, t)`` (normal
    equations of the 2×2 tangent system, the parameter kept in the domain triangle)
    finds the foot of the perpendicular.  Vectorised over the points.

    A foot point past its start patch's edge (the start triangle belonged to the
    neighbour's side) is taken on the patch's polynomial continued past the edge
    (barycentrics down to ``-_EXTEND``): patches join C2 (box-spline regions) or G1,
    so the continuation leaves the neighbour by the jump of a higher derivative times
    the overshoot's cube -- measured on a unit sphere's surface (open3d resolution 8, points
    up to 0.01 off it), about 1e-6 at most (at the valence-8 poles) where a foot point kept
    inside its start patch erred by up to 7.5e-4 and the level-1 tessellation by 0.0024.
    A foot point that does not settle (no step below 1e-6 of the patch) or settles more
    than ``_EXTEND / 2`` past the edges keeps its start, a point of the surface.

    Parameters
    ----------
    control_points : (P, 28, 3) array_like or BezierSurface
    points : (N, 3) array_like
    triangles : (P, 3) int array_like, optional
        Domain triangles, required with a plain array (as :func:`tessellate`).
    level : int
        Tessellation level of the start (1: edges a quarter of the control mesh's).
    iterations : int
        Gauss-Newton steps (quadratic convergence from the tessellation's foot point;
        4 reach float64 round-off on the demo's patches).
    tessellated : surface.metrics.MeshDistance, optional
        The distance function of this surface's level-``level`` tessellation
        (:func:`tessellate`'s triangles in its order), if the caller has one: its
        raycasting scene is used instead of building another.

    Returns
    -------
    distance : (N,) float64
    patch : (N,) int64
        Patch of each foot point.
    bary : (N, 3) float64
        Its barycentric parameter on that patch.
    """
    cp, tris = _patches_and_domain(control_points, triangles, "closest_points",
                                   "to weld patch edges")
    p = check_shape(points, "(N, 3)", "points", dtype=np.float64)
    check_finite(p, "points")
    patch, start = _start_on_tessellation(cp, tris, p, int(level), tessellated)
    nets = cp[patch]                                                    # (N, 28, 3)
    bary, here, moved = _foot_points(nets, p, start, iterations)
    # a foot point that did not settle, or settled far past the patch's edges, is not on
    # the surface: such points keep the tessellation's start (a point of the surface)
    trusted = (moved < 1e-6) & (bary.min(axis=1) > -_EXTEND / 2)
    bary = np.where(trusted[:, None], bary, start)
    foot = np.where(trusted[:, None], here, _at(nets, start))
    return np.linalg.norm(p - foot, axis=1), patch, bary


def _start_on_tessellation(cp, tris, p, level: int, tessellated):
    """Each point's nearest triangle of the level-``level`` tessellation: its patch
    ``(N,) int64`` and the foot's barycentrics on it ``(N, 3)`` (closest_points' start)."""
    import open3d as o3d

    if tessellated is None:
        vertices, faces, _ = tessellate(cp, level, tris)
        centre = vertices.mean(axis=0)
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(o3d.core.Tensor((vertices - centre).astype(np.float32)),
                            o3d.core.Tensor(faces.astype(np.uint32)))
    else:
        scene, centre = tessellated.scene, tessellated.centre
    found = scene.compute_closest_points(o3d.core.Tensor((p - centre).astype(np.float32)))
    primitive = found["primitive_ids"].numpy().astype(np.int64)
    uv = found["primitive_uvs"].numpy().astype(np.float64)
    per_patch = 4 ** level
    patch = primitive // per_patch
    grid_bary, local_tris, _ = _grid(2 ** level)
    corners = grid_bary[local_tris[primitive % per_patch]]            # (N, 3 corners, 3)
    weights = np.stack([1.0 - uv[:, 0] - uv[:, 1], uv[:, 0], uv[:, 1]], axis=1)
    return patch, np.einsum("nc,ncb->nb", weights, corners)


def _at(nets, bary, rows=None):
    """Points of the patches ``nets`` (N, 28, 3) (or their ``rows``) at ``bary``: a batched
    matrix product (several times einsum's speed here)."""
    return np.matmul(_bernstein(bary, DEGREE)[:, None, :],
                     nets if rows is None else nets[rows])[:, 0]


def _foot_points(nets, p, bary, iterations: int):
    """Gauss-Newton from ``bary`` to the feet of the perpendiculars from ``p`` on ``nets``:
    ``bary``, the feet ``(N, 3)`` and the last step's length (0 where it moved away)."""
    du, dv = _derivative_operators()
    moved = np.zeros(len(p))
    here = _at(nets, bary)
    for _ in range(max(0, int(iterations))):
        low = _bernstein(bary, DEGREE - 1)
        pu = np.matmul((low @ du)[:, None, :], nets)[:, 0]
        pv = np.matmul((low @ dv)[:, None, :], nets)[:, 0]
        r = p - here
        a, b, c = (np.einsum("nd,nd->n", pu, pu), np.einsum("nd,nd->n", pu, pv),
                   np.einsum("nd,nd->n", pv, pv))
        gu, gv = np.einsum("nd,nd->n", pu, r), np.einsum("nd,nd->n", pv, r)
        det = a * c - b * b
        ok = det > TOL.zero * np.maximum(a * c, TOL.zero)
        safe = np.where(ok, det, 1.0)
        step = np.stack([np.where(ok, (c * gu - b * gv) / safe, 0.0),
                         np.where(ok, (a * gv - b * gu) / safe, 0.0)], axis=1)
        # Gauss-Newton, its step halved (up to 3 times) where it would move away
        # (the halvings evaluate only the points that moved away)
        old = np.einsum("nd,nd->n", r, r)

        trial = _clipped_trial(bary, step)
        there = _at(nets, trial)
        worse = np.einsum("nd,nd->n", p - there, p - there) > old
        for _halving in range(3):
            redo = np.flatnonzero(worse)
            if not len(redo):
                break
            step[redo] *= 0.5
            trial[redo] = _clipped_trial(bary[redo], step[redo])
            there[redo] = _at(nets, trial[redo], redo)
            gap = p[redo] - there[redo]
            worse[redo] = np.einsum("nd,nd->n", gap, gap) > old[redo]
        keep = worse[:, None]
        bary = np.where(keep, bary, trial)
        here = np.where(keep, here, there)
        moved = np.where(worse, 0.0, np.hypot(step[:, 0], step[:, 1]))
    return bary, here, moved
