r"""Control meshes for Loop's limit surface: interpolating a mesh, or fitted to a cloud.

Loop subdivision (and the sextic Bézier surface of :mod:`surface.bezier`, which
reproduces its limit) *approximates* its control mesh: a control vertex ``v`` of valence
``n`` with neighbours ``w_1 .. w_n`` lands on the limit surface at

.. math::

    L(v) = (1 - n \beta_\infty)\, v + \beta_\infty \sum_{i=1}^{n} w_i, \qquad
    \beta_\infty = \frac{1}{n + 3 / (8 \beta(n))}

(Loop 1987 [1]_; Hoppe et al. 1994 [2]_ use the same mask to fit data).  On a curved
surface ``L(v) - v`` is a Laplacian: it moves the surface inward by about
``h^2 (k_1 + k_2) / 8`` for edge length ``h`` and rounds off creases.

- :func:`interpolating_control_mesh` solves the sparse system ``L(X) = P`` (one
  ``spsolve``; the matrix :func:`limit_matrix`) so that the surface over ``X`` passes
  through every vertex of ``P``; ``keep`` holds some vertices as they are
  (:func:`sharp_vertices`, :func:`convex_creases`, :func:`flat_vertices`: where an
  interpolating G1 surface overshoots a crease).
- :func:`folded_faces` and :func:`surface_folds` find where the correction ``X - P``
  folds the control mesh or the surface over it (tests of sign, no tolerance;
  ``docs/decisions/smooth-folds.md``).
- :func:`fitted_control_mesh` fits the surface to a cloud instead: least squares on the
  limit mesh two subdivision steps down (:func:`subdivision_matrix`) with a bending
  penalty whose weight is chosen on cubes of the cloud held out
  (:func:`held_out_blocks`; ``docs/decisions/complex-shapes.md``).

Closed meshes only: the ghost-layer border rule of :mod:`surface.bezier` has no one-ring
limit mask, so a mesh with borders is a ``ValueError``.

References
----------
.. [1] C. Loop, "Smooth subdivision surfaces based on triangles", M.S. thesis,
   Department of Mathematics, University of Utah, 1987.
.. [2] H. Hoppe, T. DeRose, T. Duchamp, M. Halstead, H. Jin, J. McDonald,
   J. Schweitzer, W. Stuetzle, "Piecewise smooth surface reconstruction",
   SIGGRAPH 1994, pp. 295-302.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import LinearOperator, cg, spsolve

from surface import bezier
from surface.loop_weights import limit_weight, loop_beta
from surface.metrics import edge_table
from surface.validate import check_finite, check_shape
from surface.validity import check_solid, self_intersections

__all__ = ["convex_creases", "fitted_control_mesh", "flat_vertices", "folded_faces",
           "grow_vertices", "held_out_blocks", "subdivision_matrix",
           "interpolating_control_mesh", "surface_folds",
           "limit_matrix", "limit_positions", "sharp_vertices"]


def _adjacency(triangles: np.ndarray, count: int) -> sp.csr_matrix:
    """Symmetric 0/1 vertex adjacency ``(V, V)`` of a closed 2-manifold mesh."""
    half = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    key = np.sort(half, axis=1)
    _, uses = np.unique(key[:, 0] * count + key[:, 1], return_counts=True)
    if np.any(uses != 2):
        bad = int(np.sum(uses != 2))
        kind = "border" if np.any(uses == 1) else "non-manifold"
        raise ValueError(f"triangles: {bad} edges are not shared by exactly two triangles "
                         f"({kind} edges); interpolating_control_mesh needs a closed "
                         f"2-manifold mesh")
    adjacency = sp.coo_matrix((np.ones(len(half)), (half[:, 0], half[:, 1])),
                              shape=(count, count)).tocsr()
    adjacency = ((adjacency + adjacency.T) > 0).astype(np.float64)
    return adjacency.tocsr()


def _check_mesh(vertices, triangles) -> tuple[np.ndarray, np.ndarray]:
    v = check_finite(check_shape(vertices, "(V, 3)", "vertices", dtype=np.float64), "vertices")
    t = check_shape(triangles, "(F, 3)", "triangles", dtype=np.int64)
    if len(t) == 0:
        raise ValueError("triangles: empty mesh (0 triangles)")
    if t.min() < 0 or t.max() >= len(v):
        raise ValueError(f"triangles: vertex ids must be in 0..{len(v) - 1}, got "
                         f"{int(t.min())}..{int(t.max())}")
    if np.any((t[:, 0] == t[:, 1]) | (t[:, 1] == t[:, 2]) | (t[:, 2] == t[:, 0])):
        raise ValueError("triangles: a triangle repeats a vertex id")
    return v, t


def limit_matrix(triangles, count: int) -> sp.csr_matrix:
    """Loop's limit-position operator ``M`` (``(V, V)``, sparse): ``L = M @ vertices``.

    Parameters
    ----------
    triangles : (F, 3) int array_like
        Closed 2-manifold mesh.
    count : int
        Number of vertices ``V``; every vertex must be used by a triangle.

    Raises
    ------
    ValueError
        Border or non-manifold edges, isolated vertices.
    """
    t = check_shape(triangles, "(F, 3)", "triangles", dtype=np.int64)
    adjacency = _adjacency(t, int(count))
    valence = np.asarray(adjacency.sum(axis=1)).ravel()
    if np.any(valence == 0):
        raise ValueError(f"vertices: {int(np.sum(valence == 0))} isolated vertices (used by no "
                         f"triangle, e.g. vertex {int(np.argmin(valence))}); remove them first")
    beta_limit = limit_weight(valence)  # Loop's chi(n): surface/loop_weights.py
    return (sp.diags(1.0 - valence * beta_limit) + sp.diags(beta_limit) @ adjacency).tocsr()


def limit_positions(vertices, triangles) -> np.ndarray:
    """Loop limit positions of the control vertices, ``(V, 3)``, scene units."""
    v, t = _check_mesh(vertices, triangles)
    return limit_matrix(t, len(v)) @ v


def _interior_edges(v: np.ndarray, t: np.ndarray):
    """Unit face normals ``(F, 3)`` and each interior edge's vertices ``(E, 2)`` and two
    faces ``(E,)``, ``(E,)``."""
    normal = np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
    half = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
    face = np.tile(np.arange(len(t)), 3)
    key = np.sort(half, axis=1)
    key = key[:, 0] * len(v) + key[:, 1]
    order = np.argsort(key, kind="stable")
    pair = key[order][1:] == key[order][:-1]
    a, b = order[:-1][pair], order[1:][pair]  # the two half-edges of an interior edge
    return normal, half[a], face[a], face[b]


def sharp_vertices(vertices, triangles, angle: float = np.pi / 6, rings: int = 1) -> np.ndarray:
    """Vertices on or next to a sharp edge (dihedral angle above ``angle``), ``(V,) bool``.

    ``rings`` grows the set by that many one-rings.  These are where an interpolating
    G1 surface overshoots (a crease, or a rim held by support rings a noise width
    away): :func:`interpolating_control_mesh` can keep them as they are.
    """
    v, t = _check_mesh(vertices, triangles)
    normal, edge, fa, fb = _interior_edges(v, t)
    cos = np.einsum("ij,ij->i", normal[fa], normal[fb])
    sharp = np.zeros(len(v), dtype=bool)
    sharp[edge[cos < np.cos(angle)].ravel()] = True
    return grow_vertices(sharp, t, rings)


def convex_creases(vertices, triangles, angle: float = np.pi / 6) -> np.ndarray:
    """Vertices on a sharp edge (dihedral angle above ``angle``) whose sharp edges are all
    convex -- ridges, the other face lying behind each face's plane -- ``(V,) bool``.

    A vertex on a valley (a handle's or a floor's junction with a wall) is not one: an
    interpolating G1 surface through a valley's vertices overshoots into the solid
    (measured on 2026-12-06: a mug's Chamfer +25-31 %, ``surface.sizing.interpolating_control``).
    """
    v, t = _check_mesh(vertices, triangles)
    normal, edge, fa, fb = _interior_edges(v, t)
    sharp = np.einsum("ij,ij->i", normal[fa], normal[fb]) < np.cos(angle)
    centroid = v[t].mean(axis=1)
    convex = np.einsum("ij,ij->i", normal[fa], centroid[fb] - centroid[fa]) < 0.0
    on = np.zeros(len(v), dtype=bool)
    valley = np.zeros(len(v), dtype=bool)
    on[edge[sharp].ravel()] = True
    valley[edge[sharp & ~convex].ravel()] = True
    return on & ~valley


def grow_vertices(mask: np.ndarray, triangles: np.ndarray, rings: int = 1) -> np.ndarray:
    """``mask`` grown by ``rings`` one-rings (the vertices of every face touching the set),
    ``(V,) bool``."""
    t = np.asarray(triangles, dtype=np.int64)
    mask = np.asarray(mask, dtype=bool)
    for _ in range(int(rings)):
        mask = mask | (np.bincount(t[mask[t].any(axis=1)].ravel(), minlength=len(mask)) > 0)
    return mask


def flat_vertices(vertices, triangles, angle: float = 1e-6) -> np.ndarray:
    """Vertices whose incident faces all lie in one plane (normals within ``angle``
    radians of each other's mean), ``(V,) bool``: the stitch's planar caps.

    Loop's limit position of such a vertex lies in that plane, so interpolating it
    moves it only within the plane -- no nearer the data, and next to a sharp rim the
    interpolating solve rings there: on the demo's step-7 thinning a cap's guard-ring
    vertex 0.008 inside the rim got a control point 0.066 outside it and the surface
    a lip 0.011 past the truth in the cap plane.  :func:`interpolating_control_mesh`
    can keep them as they are.
    """
    v, t = _check_mesh(vertices, triangles)
    normal = np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
    mean = np.zeros_like(v)
    for k in range(3):
        np.add.at(mean, t[:, k], normal)
    mean /= np.maximum(np.linalg.norm(mean, axis=1, keepdims=True), 1e-300)
    worst = np.ones(len(v))
    for k in range(3):
        np.minimum.at(worst, t[:, k], np.einsum("ij,ij->i", normal, mean[t[:, k]]))
    return worst >= np.cos(angle)


def interpolating_control_mesh(vertices, triangles, keep=None, at=None) -> np.ndarray:
    """Control vertices whose Loop limit positions are ``vertices``.

    Parameters
    ----------
    vertices : (V, 3) array_like, scene units
        Target positions (e.g. the stitched mesh, whose vertices lie on the data).
    triangles : (F, 3) int array_like
        Closed, 2-manifold, every vertex used; the connectivity of the result.
    keep : (V,) bool array_like, optional
        Vertices that stay as they are (e.g. :func:`sharp_vertices`): the surface
        approximates them and interpolates the others.
    at : (V, 3) array_like, optional
        Where the ``keep`` vertices are held (default: ``vertices``, as they are).

    Notes
    -----
    The matrix ``M = diag(1 - n beta_inf) + diag(beta_inf) A`` (``A`` the adjacency) is the
    row-scaled identity-plus-Laplacian of the limit mask; on a regular grid its
    eigenvalues lie in [1/4, 1], so noise in ``P`` is amplified at most 4x in ``X``.

    Returns
    -------
    (V, 3) float64
        ``X`` with ``limit_positions(X, triangles) == vertices`` (to the sparse
        LU's rounding).  Build the smooth surface over ``(X, triangles)``, e.g.
        ``surface.bezier.control_net(X, triangles)``: it passes through every
        target vertex.

    Raises
    ------
    ValueError
        Non-finite vertices, bad indices, border or non-manifold edges,
        isolated vertices, or a singular limit system.
    """
    v, t = _check_mesh(vertices, triangles)
    matrix = limit_matrix(t, len(v))
    if keep is not None and np.any(keep):
        # kept vertices stay control vertices; the others interpolate: M_ff X_f = P_f - M_fk P_k
        keep = np.asarray(keep, dtype=bool)
        free = np.flatnonzero(~keep)
        solution = v.copy() if at is None else np.array(at, dtype=np.float64).reshape(v.shape)
        if len(free):
            rhs = v[free] - matrix[free][:, np.flatnonzero(keep)] @ solution[keep]
            part = np.asarray(spsolve(matrix[free][:, free].tocsc(), rhs)).reshape(-1, 3)
            solution[free] = part
    else:
        solution = np.asarray(spsolve(matrix.tocsc(), v))
    if solution.shape != v.shape or not np.all(np.isfinite(solution)):
        raise ValueError("triangles: the Loop limit-position system of this mesh is singular "
                         "(no control mesh interpolates the vertices)")
    return solution


def folded_faces(target, control, triangles, intersections: bool = True,
                 target_pairs=None) -> np.ndarray:
    """Faces of the control mesh folded by the interpolating correction, ``(F,) bool``.

    A face is folded when its normal in ``control`` points against its normal in
    ``target`` (the same connectivity; the correction turned it over), or, with
    ``intersections``, when it crosses another face of ``control`` while the two faces do
    not cross in ``target`` (:func:`surface.validity.check_solid`'s pairs;
    ``target_pairs``, ``(K, 2)``, when known already).  Both are
    tests of sign, no tolerance: a fold of the control polygon is a fold of the G1
    surface over it (Loop's patches lie near their control triangles), and a crossing
    the target mesh already has is not the correction's doing.
    """
    p, t = _check_mesh(target, triangles)
    x, _ = _check_mesh(control, t)

    def normals(v):
        return np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]])

    folded = np.einsum("ij,ij->i", normals(p), normals(x)) < 0.0
    if intersections:
        crossing = np.asarray(check_solid(x, t).intersecting_pairs, dtype=np.int64).reshape(-1, 2)
        if len(crossing):
            if target_pairs is None:
                target_pairs = check_solid(p, t).intersecting_pairs
            before = np.asarray(target_pairs, dtype=np.int64).reshape(-1, 2)
            key = np.sort(crossing, axis=1) @ np.array([len(t), 1])
            old = np.sort(before, axis=1) @ np.array([len(t), 1]) if len(before) else key[:0]
            folded[crossing[~np.isin(key, old)].ravel()] = True
    return folded


def surface_folds(target, control, triangles, faces=None, target_pairs=None,
                  level: int = 1, rings: int = 1) -> np.ndarray:
    """Faces of the control mesh over which Loop's surface folds, ``(F,) bool``.

    The surface over ``(control, triangles)`` (:func:`surface.bezier.control_net`) is
    tessellated at ``level`` over the patches of ``faces`` (all when None) and ``rings``
    rings of their neighbours; a face is folded when a triangle of its patches crosses
    another (:func:`surface.validity.self_intersections`) or is turned against the
    target face it lies over (normals of opposite sign).  Pairs that involve a face of
    ``target_pairs`` (``(K, 2)``, the target mesh's own crossings) or one of its
    neighbours are the target's, not the correction's, and are left out.  Both are
    tests of sign, no tolerance.

    A level-1 tessellation missed crossings a finer one showed (the sizing looks at level
    2: ``surface.sizing.FOLD_LEVEL``).  A folded *control* face (:func:`folded_faces`) is
    where the surface may fold: on
    the 10⁴-point cylinder of ``benchmarks/surface.py`` 249 of 1 340 control faces were
    folded and the surface over them crossed itself on 5 faces' patches
    (``docs/decisions/smooth-folds.md``).
    """
    p, t = _check_mesh(target, triangles)
    x, _ = _check_mesh(control, t)
    count = len(t)
    chosen = np.ones(count, dtype=bool) if faces is None else np.asarray(faces, dtype=bool)
    folded = np.zeros(count, dtype=bool)
    if not chosen.any():
        return folded
    region = chosen.copy()
    for _ in range(int(rings)):
        near = np.zeros(len(p), dtype=bool)
        near[t[region].ravel()] = True
        region = near[t].any(axis=1)
    own = np.zeros(count, dtype=bool)
    if target_pairs is not None and len(target_pairs):
        own[np.asarray(target_pairs, dtype=np.int64).ravel()] = True
        near = np.zeros(len(p), dtype=bool)
        near[t[own].ravel()] = True
        own = near[t].any(axis=1)
    surface = bezier.control_net(x, t)
    patches = np.flatnonzero(region[surface.source_face])
    per = 4 ** int(level)
    tv, tt, _ = bezier.tessellate(surface.control_points[patches], int(level),
                                  surface.domain_mesh[1][patches])
    face_of = surface.source_face[patches][np.arange(len(tt)) // per]
    normal = np.cross(tv[tt[:, 1]] - tv[tt[:, 0]], tv[tt[:, 2]] - tv[tt[:, 0]])
    target_normal = np.cross(p[t[:, 1]] - p[t[:, 0]], p[t[:, 2]] - p[t[:, 0]])
    turned = np.einsum("ij,ij->i", normal, target_normal[face_of]) < 0.0
    folded[face_of[turned]] = True
    pairs = face_of[self_intersections(tv, tt)]
    if len(pairs):
        pairs = pairs[~own[pairs].any(axis=1)]
        folded[pairs.ravel()] = True
    folded &= ~own
    return folded


#: The general mesh's vertices as a prior in :func:`fitted_control_mesh`, each counted as
#: this many cloud points (per point of the cloud per control vertex).  None: the mesh is
#: an iso-surface of the whole cloud, held-out points included, so a fit held to it looks
#: near them whatever it does (on the noisy 10^4-point torus weight 10's held-out error
#: was 0.73 of the points' own noise variance about the truth: a leak, not a fit).
FIT_WEIGHTS = (0.0,)
#: The control mesh's bending (its uniform umbrella ``U X``, squared), each vertex
#: counted as this many points per point a vertex has: the bends tried, smallest first,
#: until the held-out error rises (noise-free data stop at the first or second, the
#: noisy corpus rows at 0.1 of the diagonal's 5e-4 reach 1-3).
FIT_BENDS = (0.03, 0.1, 0.3, 1.0, 3.0)
#: Share of the cloud held out to choose the weight.
FIT_HOLD_OUT = 0.1
#: Side of the cubes the cloud is held out in, in the control mesh's median edges: the
#: held-out points are whole cubes, not single points, so that a neighbour whose error
#: is correlated with a held-out point's (the stereo matcher's window spans several
#: points) is held out with it and cannot make a rough surface look near.  Three edges
#: span a control vertex's support (its two-ring), what one vertex's move can follow.
FIT_BLOCK_EDGES = 3.0
#: Subdivision steps of the limit mesh the points' feet are found on: its chords lie
#: inside the surface by their sagitta, ``(h / 2^L)^2 / (8 r)`` for control edges ``h`` on
#: a radius ``r``, which the fit would otherwise push outward.  Two steps make that 1/16 of
#: the control mesh's own: on a torus of tube radius 0.35 with edges of 0.05, 6e-5.
FIT_LEVELS = 2
#: Foot-point rounds of each fit tried on the held-out cubes (the chosen one is then fitted
#: to the whole cloud in :data:`FIT_ROUNDS`).
FIT_SELECT_ROUNDS = 2
#: Foot-point rounds of the fit (each: nearest surface spot of every point, then one
#: sparse least-squares solve).
FIT_ROUNDS = 2


def subdivision_matrix(triangles, count: int) -> tuple[sp.csr_matrix, np.ndarray]:
    """One step of Loop subdivision of a closed 2-manifold mesh as a sparse operator.

    Returns ``S`` ``(V + E, V)`` (vertex points ``(1 - n beta) v + beta sum(w)``, then one
    edge point ``3/8 (a + b) + 1/8 (c + d)`` per undirected edge of
    :func:`surface.metrics.edge_table`) and the refined triangles ``(4F, 3)``.
    """
    t = check_shape(triangles, "(F, 3)", "triangles", dtype=np.int64)
    table = edge_table(t)
    if np.any(table.counts != 2):
        raise ValueError("triangles: subdivision_matrix needs a closed 2-manifold mesh")
    n_edges = len(table.edges)
    face_edge = table.face_edge
    # slot 3f + k is side k -> k + 1 of face f; the vertex opposite it is corner k + 2
    order = np.argsort(face_edge.ravel(), kind="stable")
    opposite = t[:, [2, 0, 1]].ravel()[order].reshape(-1, 2)
    a, b = table.edges[:, 0], table.edges[:, 1]
    adjacency = sp.coo_matrix((np.ones(2 * n_edges), (np.r_[a, b], np.r_[b, a])),
                              shape=(count, count)).tocsr()
    valence = np.asarray(adjacency.sum(axis=1)).ravel()
    beta = loop_beta(np.maximum(valence, 1))
    even = sp.diags(1.0 - valence * beta) + sp.diags(beta) @ adjacency
    odd = sp.coo_matrix((np.tile([3 / 8, 3 / 8, 1 / 8, 1 / 8], n_edges),
                         (np.repeat(np.arange(n_edges), 4), np.c_[a, b, opposite].ravel())),
                        shape=(n_edges, count))
    m01, m12, m20 = (count + face_edge[:, k] for k in range(3))
    t0, t1, t2 = t.T
    refined = np.concatenate([np.c_[t0, m01, m20], np.c_[t1, m12, m01], np.c_[t2, m20, m12],
                              np.c_[m01, m12, m20]])
    return sp.vstack([even, odd]).tocsr(), refined


def _feet(vertices: np.ndarray, triangles: np.ndarray, points: np.ndarray):
    """Each point's nearest spot on a triangle mesh: face ``(N,)``, barycentric weights
    ``(N, 3)`` and the spot ``(N, 3)`` (open3d's BVH, single precision)."""
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(vertices.astype(np.float32)),
                        o3d.core.Tensor(triangles.astype(np.uint32)))
    hit = scene.compute_closest_points(o3d.core.Tensor(points.astype(np.float32)))
    uv = hit["primitive_uvs"].numpy().astype(np.float64)
    return (hit["primitive_ids"].numpy().astype(np.int64),
            np.c_[1.0 - uv.sum(axis=1), uv], hit["points"].numpy().astype(np.float64))


def _solve_normal(matrix: sp.spmatrix, rhs: np.ndarray, start: np.ndarray) -> np.ndarray:
    """``matrix @ x = rhs`` for a symmetric positive definite ``matrix`` (normal equations
    with a positive definite term), ``(V, 3)``: conjugate gradients from ``start`` with the
    diagonal as preconditioner (10x less CPU than a sparse LU on a general mesh of 6 000
    vertices: 0.04 against 0.6 s, answers within 4e-8 of each other), the sparse LU where
    they do not converge."""
    matrix = matrix.tocsr()
    inverse = 1.0 / matrix.diagonal()
    jacobi = LinearOperator(matrix.shape, matvec=lambda r: inverse * r.ravel())
    out = np.empty_like(start)
    for k in range(rhs.shape[1]):
        out[:, k], info = cg(matrix, rhs[:, k], x0=start[:, k], rtol=1e-10,
                             maxiter=10 * len(start), M=jacobi)
        if info != 0:
            return np.asarray(spsolve(matrix.tocsc(), rhs)).reshape(start.shape)
    return out


def held_out_blocks(points: np.ndarray, side: float, share: float = FIT_HOLD_OUT,
                    seed: int = 0) -> np.ndarray:
    """Points held out in whole cubes of ``side`` (scene units), ``(N,) bool``: the cubes
    of a grid are drawn at random, each with chance ``share``, until at least one cube
    is drawn and one is not (fewer than two cubes: single points at random)."""
    p = np.asarray(points, dtype=np.float64)
    rng = np.random.default_rng(seed)
    if not side > 0:
        return rng.random(len(p)) < share
    _, cube = np.unique(np.floor((p - p.min(axis=0)) / side).astype(np.int64), axis=0,
                        return_inverse=True)
    cube = cube.ravel()
    count = int(cube.max()) + 1 if len(cube) else 0
    if count < 2:
        return rng.random(len(p)) < share
    drawn = rng.random(count) < share
    if not drawn.any() or drawn.all():
        drawn[:] = False
        drawn[rng.integers(count)] = True
    return drawn[cube]


def fitted_control_mesh(vertices, triangles, points, start=None,
                        weights=FIT_WEIGHTS, hold_out: float = FIT_HOLD_OUT,
                        rounds: int = FIT_ROUNDS, levels: int = FIT_LEVELS,
                        seed: int = 0, block: float | None = None,
                        bends=FIT_BENDS,
                        select_rounds: int = FIT_SELECT_ROUNDS) -> tuple[np.ndarray, dict]:
    r"""Control vertices whose Loop surface is fitted to a cloud, ``(V, 3)``, and the fit's
    figures.

    The surface is represented by its limit mesh ``levels`` subdivision steps down,
    ``M X`` with ``M = limit_matrix(refined) @ S`` (:func:`subdivision_matrix`; its
    chords' sagitta: :data:`FIT_LEVELS`), linear in the control vertices ``X``.  Each
    round finds every point's nearest spot on it (a face and its barycentric weights
    ``B``) and solves

    .. math:: \min_X \|B M X - p\|^2 + \frac{N}{V} \bigl(w \|M_0 X - P\|^2
              + b \|U X\|^2\bigr)

    (Hoppe et al. 1994's fit with the parameters held by the foot points): ``U`` is the
    control mesh's uniform umbrella operator (``x_i`` minus its neighbours' mean), whose
    square penalises bending: it carries the surface where no point is (the flattest
    fill) and averages the noise; ``w`` holds the limit positions ``M_0 X`` at the mesh's
    own vertices ``P`` (:data:`FIT_WEIGHTS`: none by default).  ``(w, b)`` is chosen
    among ``weights`` x ``bends`` (bends smallest first, stopping when the error rises) by
    the fit's mean squared distance to ``hold_out`` of the points, left out of the fit in
    whole cubes (:func:`held_out_blocks`, side ``block``, default :data:`FIT_BLOCK_EDGES`
    median edges; 0: single points at random): noise-free data choose the smallest bend,
    noisy data a larger one.

    Parameters
    ----------
    vertices : (V, 3) float64
        The control mesh's target (a closed 2-manifold), e.g. a decimated iso-surface.
    triangles : (F, 3) int64
    points : (N, 3) float64
        The cloud.
    start : (V, 3) float64, optional
        Control vertices to start from (default :func:`interpolating_control_mesh`).

    Returns
    -------
    X : (V, 3) float64
    info : dict
        ``weight`` and ``bend`` chosen, ``choices`` tried and each one's ``held_out`` mean
        squared distance.
    """
    v, t = _check_mesh(vertices, triangles)
    p = check_finite(check_shape(points, "(N, 3)", "points", dtype=np.float64), "points")
    step, refined = sp.identity(len(v), format="csr"), t
    for _ in range(levels):
        once, refined = subdivision_matrix(refined, step.shape[0])
        step = (once @ step).tocsr()
    fine = (limit_matrix(refined, step.shape[0]) @ step).tocsr()
    coarse = limit_matrix(t, len(v))
    held = coarse.T @ coarse
    adjacency = _adjacency(t, len(v))
    umbrella = (sp.identity(len(v)) - sp.diags(1.0 / np.asarray(adjacency.sum(axis=1)).ravel())
                @ adjacency).tocsr()
    bend_matrix = (umbrella.T @ umbrella).tocsr()
    x0 = interpolating_control_mesh(v, t) if start is None else np.asarray(start, np.float64)

    def fit(data: np.ndarray, choice: tuple[float, float], rounds: int = rounds) -> np.ndarray:
        x = x0
        w, b = (c * len(data) / len(v) for c in choice)
        for _ in range(rounds):
            face, bary, _ = _feet(fine @ x, refined, data)
            feet = sp.coo_matrix((bary.ravel(), (np.repeat(np.arange(len(data)), 3),
                                                 refined[face].ravel())),
                                 shape=(len(data), fine.shape[0])).tocsr() @ fine
            x = _solve_normal(feet.T @ feet + w * held + b * bend_matrix,
                              feet.T @ data + w * (coarse.T @ v), x)
        return x

    if block is None:
        edges = v[t] - v[np.roll(t, 1, axis=1)]
        block = FIT_BLOCK_EDGES * float(np.median(np.linalg.norm(edges, axis=2)))
    out = held_out_blocks(p, block, hold_out, seed)
    choices = [(float(w), float(b)) for w in weights for b in sorted(bends)]
    if not all(w > 0 or b > 0 for w, b in choices):
        raise ValueError("weights, bends: each (weight, bend) needs one of them > 0")
    errors, tried = [], []
    if len(choices) > 1 and out.any() and (~out).any():
        for choice in choices:
            if len(tried) > 1 and tried[-1][0] == tried[-2][0] == choice[0] \
                    and errors[-1] > errors[-2]:
                continue    # this weight's held-out error rose with the bend: past its best
            x = fit(p[~out], choice, select_rounds)
            errors.append(float(np.mean(np.sum((_feet(fine @ x, refined, p[out])[2]
                                                 - p[out]) ** 2, axis=1))))
            tried.append(choice)
        choice = tried[int(np.argmin(errors))]
    else:
        choice = choices[0]
    x = fit(p, choice)
    if not np.all(np.isfinite(x)):
        raise ValueError("points: the least-squares fit of the control mesh is singular")
    return x, {"weight": choice[0], "bend": choice[1], "weights": list(weights),
               "bends": list(bends), "choices": tried, "held_out": errors,
               "block": float(block)}
