r"""Reconstruction quality and mesh-health measures.

Distances (Tanks and Temples conventions, Knapitsch et al. [1]_).  With :math:`R` the
reconstruction and :math:`T` the truth, both sampled uniformly by area,

.. math::

    d_{R\to T}(r) = \min_{t \in T} \lVert r - t \rVert,\quad
    \text{Chamfer} = \tfrac12(\operatorname{mean}_r d_{R\to T} + \operatorname{mean}_t d_{T\to R}),

    P(\tau) = \Pr[d_{R\to T} < \tau],\ R(\tau) = \Pr[d_{T\to R} < \tau],\
    F(\tau) = \frac{2PR}{P + R},\
    \text{Hausdorff} = \max(\max_r d_{R\to T}, \max_t d_{T\to R}).

Chamfer is the mean of the two *mean unsquared* distances (accuracy and completeness, in
scene units), not a sum of squares.  Against a mesh the distance is the exact
point-to-triangle one (open3d's ``RaycastingScene.compute_distance``: no sampling bias of
its own); against a point cloud, the nearest neighbour (scipy ``cKDTree``).

Mesh health.  From the edge table (every undirected edge with its faces): *edge-manifold*
when no edge has more than two faces, *closed* when every edge has exactly two, *oriented*
when each interior edge is traversed once each way; components are the face-connected
pieces; :math:`\chi = V - E + F`.  The *Delaunay fraction* is the share of interior edges
whose opposite angles sum to at most :math:`\pi` (Lawson [2]_); the *G1 measure* the
largest angle between the normals on the two sides of an interior edge.  The signed volume
:math:`\tfrac16\sum_f \det[v_0, v_1, v_2]` is positive for a closed mesh whose triangles
are counter-clockwise seen from outside.

References
----------
.. [1] A. Knapitsch, J. Park, Q.-Y. Zhou, V. Koltun, "Tanks and Temples:
   Benchmarking Large-Scale Scene Reconstruction", ACM Trans. Graphics 36(4)
   (2017).
.. [2] C. L. Lawson, "Software for C1 surface interpolation", in Mathematical
   Software III, Academic Press (1977), 161-194.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from surface.validate import TOL, check_finite, check_shape

__all__ = [
    "silhouette_scores",
    "seen_by_cameras",
    "EdgeTable",
    "MeshDistance",
    "edge_table",
    "triangle_areas",
    "face_normals",
    "sample_mesh",
    "point_mesh_distance",
    "point_cloud_distance",
    "distance_scores",
    "compare_meshes",
    "opposite_angle_sums",
    "delaunay_fraction",
    "interior_normal_pairs",
    "g1_angle",
    "signed_volume",
    "is_watertight",
    "mesh_topology",
]


# --------------------------------------------------------------------------- edge table
@dataclass(frozen=True)
class EdgeTable:
    """Undirected edges of a triangle mesh and the faces using them.

    Attributes
    ----------
    edges : (E, 2) int64
        Vertex pairs, ``edges[:, 0] < edges[:, 1]``, sorted lexicographically.
    face_edge : (F, 3) int64
        ``face_edge[f, k]`` is the edge from corner ``k`` to corner ``k+1``
        (mod 3) of face ``f``.
    counts : (E,) int64
        Number of faces using each edge (2 on a closed manifold).
    forward : (E,) int64
        Number of faces traversing the edge from ``edges[:, 0]`` to
        ``edges[:, 1]``; an oriented interior edge has ``forward == 1``.
    """

    edges: np.ndarray
    face_edge: np.ndarray
    counts: np.ndarray
    forward: np.ndarray

    def interior(self) -> np.ndarray:
        """Indices of the edges used by exactly two faces, shape ``(I,)``."""
        return np.flatnonzero(self.counts == 2)

    def edge_faces(self) -> tuple[np.ndarray, np.ndarray]:
        """For every edge with exactly two faces: ``(edge ids (I,), faces (I, 2), corners (I, 2))``.

        Returns the edge ids, the two faces and, for each face, the corner
        ``k`` at which the edge starts (so the opposite vertex is corner
        ``k + 2``).
        """
        flat = self.face_edge.ravel()
        order = np.argsort(flat, kind="stable")
        sorted_edges = flat[order]
        first = np.searchsorted(sorted_edges, np.arange(self.edges.shape[0]))
        interior = self.interior()
        slot0 = order[first[interior]]
        slot1 = order[first[interior] + 1]
        faces = np.stack([slot0 // 3, slot1 // 3], axis=1)
        corners = np.stack([slot0 % 3, slot1 % 3], axis=1)
        return interior, faces, corners


def edge_table(triangles: np.ndarray) -> EdgeTable:
    """Build the undirected edge table of a triangle list.

    Parameters
    ----------
    triangles : (F, 3) int
        Vertex indices of each face.

    Returns
    -------
    EdgeTable
    """
    tri = np.asarray(triangles, dtype=np.int64)
    directed = np.stack([tri, np.roll(tri, -1, axis=1)], axis=2).reshape(-1, 2)  # (3F, 2)
    lo = np.minimum(directed[:, 0], directed[:, 1])
    hi = np.maximum(directed[:, 0], directed[:, 1])
    # One int64 key per undirected edge: a 1-D unique is ~20x faster than unique(axis=0).
    n_vertices = int(tri.max()) + 1 if tri.size else 1
    unique_keys, inverse = np.unique(lo * n_vertices + hi, return_inverse=True)
    edges = np.stack([unique_keys // n_vertices, unique_keys % n_vertices], axis=1)
    inverse = inverse.reshape(-1)
    n_edges = edges.shape[0]
    counts = np.bincount(inverse, minlength=n_edges).astype(np.int64)
    forward = np.bincount(inverse, weights=(directed[:, 0] == lo), minlength=n_edges)
    return EdgeTable(edges=edges.astype(np.int64), face_edge=inverse.reshape(-1, 3),
                     counts=counts, forward=forward.astype(np.int64))


# --------------------------------------------------------------------------- geometry
def face_normals(vertices: np.ndarray, triangles: np.ndarray, unit: bool = True) -> np.ndarray:
    """Face normals ``(v1 - v0) x (v2 - v0)``, shape ``(F, 3)``; unit length if ``unit``.

    Degenerate faces (area below ``TOL.zero``) get a zero normal.
    """
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    cross = np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]])
    if not unit:
        return cross
    norm = np.linalg.norm(cross, axis=1, keepdims=True)
    return np.divide(cross, norm, out=np.zeros_like(cross), where=norm > TOL.zero)


def triangle_areas(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Area of every face, shape ``(F,)``, in squared scene units."""
    return 0.5 * np.linalg.norm(face_normals(vertices, triangles, unit=False), axis=1)


def signed_volume(vertices: np.ndarray, triangles: np.ndarray) -> float:
    """Signed enclosed volume ``(1/6) sum det[v0, v1, v2]`` in cubed scene units.

    Positive for a closed mesh oriented counter-clockwise seen from outside;
    meaningful only for a closed mesh (open meshes give an origin-dependent
    number).
    """
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    # Centre on the centroid to keep the determinants small (less cancellation).
    v = v - v.mean(axis=0) if len(v) else v
    return float(np.einsum("ij,ij->i", v[t[:, 0]], np.cross(v[t[:, 1]], v[t[:, 2]])).sum() / 6.0)


# --------------------------------------------------------------------------- sampling and distances
def sample_mesh(vertices: np.ndarray, triangles: np.ndarray, count: int | None = None,
                density: float | None = None, seed: int = 0) -> np.ndarray:
    """Sample points uniformly by area on a triangle mesh.

    Parameters
    ----------
    vertices : (V, 3) float64
    triangles : (F, 3) int
    count : int, optional
        Number of samples.
    density : float, optional
        Samples per unit area (scene units⁻²); ``count = ceil(density * area)``.
        Exactly one of ``count`` and ``density`` is given.
    seed : int
        Seed of the ``numpy.random.default_rng`` used.

    Returns
    -------
    (count, 3) float64
        Points, each face chosen with probability proportional to its area and
        a uniform point inside it (``u = 1 - sqrt(r1)``, ``v = sqrt(r1) (1 - r2)``,
        ``w = sqrt(r1) r2``).
    """
    v = check_shape(vertices, "(V, 3)", "vertices", dtype=np.float64)
    t = check_shape(triangles, "(F, 3)", "triangles", dtype=np.int64)
    if (count is None) == (density is None):
        raise ValueError("give exactly one of count and density")
    areas = triangle_areas(v, t)
    total = float(areas.sum())
    if total <= TOL.zero:
        raise ValueError(f"mesh has zero area ({total}); cannot sample it")
    if count is None:
        if not density > 0:
            raise ValueError(f"density must be > 0, got {density}")
        count = int(np.ceil(density * total))
    if count < 1:
        raise ValueError(f"count must be >= 1, got {count}")
    rng = np.random.default_rng(seed)
    face = rng.choice(len(t), size=count, p=areas / total)
    r1 = np.sqrt(rng.random(count))
    r2 = rng.random(count)
    a, b, c = v[t[face, 0]], v[t[face, 1]], v[t[face, 2]]
    return ((1.0 - r1)[:, None] * a + (r1 * (1.0 - r2))[:, None] * b + (r1 * r2)[:, None] * c)


def _centred_scene(v: np.ndarray, t: np.ndarray):
    """The mesh's centre and its open3d ``RaycastingScene`` (BVH) built about it: shifted
    to the centre so that float32 keeps small distances and hits near the object exact."""
    import open3d as o3d

    centre = v.mean(axis=0)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor((v - centre).astype(np.float32)),
                        o3d.core.Tensor(t.astype(np.uint32)))
    return centre, scene


class MeshDistance:
    """Distances to one triangle mesh, its open3d ``RaycastingScene`` (BVH) built once.

    Parameters
    ----------
    vertices : (V, 3) float64
    triangles : (F, 3) int

    Notes
    -----
    Calling it with ``points (N, 3)`` returns ``(N,) float64`` distances, as
    :func:`point_mesh_distance` (which builds one of these per call): build it once to
    measure several point sets against the same mesh.
    """

    def __init__(self, vertices: np.ndarray, triangles: np.ndarray):
        v = check_shape(vertices, "(V, 3)", "vertices", dtype=np.float64)
        t = check_shape(triangles, "(F, 3)", "triangles", dtype=np.int64)
        if len(t) == 0:
            raise ValueError("triangles is empty; no mesh to measure distances to")
        self.centre, self._scene = _centred_scene(v, t)
        self.scene = self._scene

    def __call__(self, points: np.ndarray, signed: bool = False) -> np.ndarray:
        import open3d as o3d

        p = check_shape(points, "(N, 3)", "points", dtype=np.float64)
        query = o3d.core.Tensor((p - self.centre).astype(np.float32))
        distance = self._scene.compute_signed_distance(query) if signed else \
            self._scene.compute_distance(query)
        return distance.numpy().astype(np.float64)


def point_mesh_distance(points: np.ndarray, vertices: np.ndarray,
                        triangles: np.ndarray, signed: bool = False) -> np.ndarray:
    """Distance from each point to the nearest point of a triangle mesh.

    Parameters
    ----------
    points : (N, 3) float64
    vertices : (V, 3) float64
    triangles : (F, 3) int
    signed : bool
        Negative inside the mesh (meaningful for a closed mesh: :func:`is_watertight`).

    Returns
    -------
    (N,) float64
        Distances in scene units, computed by open3d's
        ``RaycastingScene.compute_distance`` (``compute_signed_distance``; float32
        inside: the absolute error is about 1e-7 times the coordinate magnitude).
        :class:`MeshDistance` keeps the scene for further point sets.
    """
    p = check_shape(points, "(N, 3)", "points", dtype=np.float64)
    return MeshDistance(vertices, triangles)(p, signed=signed)


def point_cloud_distance(points: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Distance from each of ``points (N, 3)`` to its nearest neighbour in ``reference (M, 3)``.

    Returns ``(N,) float64`` in scene units (scipy ``cKDTree``).
    """
    p = check_shape(points, "(N, 3)", "points", dtype=np.float64)
    r = check_shape(reference, "(M, 3)", "reference", dtype=np.float64)
    if len(r) == 0:
        raise ValueError("reference point cloud is empty")
    distance, _ = cKDTree(r).query(p, k=1)
    return distance


def distance_scores(d_rec_to_truth: np.ndarray, d_truth_to_rec: np.ndarray,
                    tau: float) -> dict[str, float]:
    """Accuracy, completeness, Chamfer, precision/recall/F-score at ``tau``, Hausdorff.

    Parameters
    ----------
    d_rec_to_truth : (N,) float64
        Distances from reconstruction samples to the truth.
    d_truth_to_rec : (M,) float64
        Distances from truth samples to the reconstruction.
    tau : float
        F-score threshold in scene units (see Notes for the comparison).

    Notes
    -----
    A sample is "within" ``tau`` when ``d <= tau`` (Tanks and Temples uses
    ``d < tau``; the two differ only on a set of measure zero).  The means of N
    independent samples carry the sampling error (standard error) ``s / sqrt(N)``,
    ``s`` the distances' sample standard deviation: ``accuracy_se``,
    ``completeness_se`` and ``chamfer_se = sqrt(se_a^2 + se_c^2) / 2``.
    """
    a = np.asarray(d_rec_to_truth, dtype=np.float64)
    c = np.asarray(d_truth_to_rec, dtype=np.float64)
    if a.size == 0 or c.size == 0:
        raise ValueError("distance arrays must not be empty")
    if not tau > 0:
        raise ValueError(f"tau must be > 0, got {tau}")
    precision = float(np.mean(a <= tau))
    recall = float(np.mean(c <= tau))
    denom = precision + recall
    fscore = 2.0 * precision * recall / denom if denom > 0 else 0.0
    accuracy = float(a.mean())
    completeness = float(c.mean())
    se_a = float(a.std(ddof=1) / np.sqrt(a.size)) if a.size > 1 else float("inf")
    se_c = float(c.std(ddof=1) / np.sqrt(c.size)) if c.size > 1 else float("inf")
    return {
        "accuracy": accuracy,
        "completeness": completeness,
        "chamfer": 0.5 * (accuracy + completeness),
        "precision": precision,
        "recall": recall,
        "fscore": fscore,
        "tau": float(tau),
        "hausdorff": float(max(a.max(), c.max())),
        "accuracy_median": float(np.median(a)),
        "completeness_median": float(np.median(c)),
        "accuracy_se": se_a,
        "completeness_se": se_c,
        "chamfer_se": 0.5 * float(np.hypot(se_a, se_c)),
    }


def compare_meshes(vertices: np.ndarray, triangles: np.ndarray, truth_vertices: np.ndarray,
                   truth_triangles: np.ndarray, tau: float, count: int = 100_000,
                   seed: int = 0, distance: MeshDistance | None = None,
                   truth_distance: MeshDistance | None = None) -> dict[str, float]:
    """Score a reconstructed mesh against a truth mesh.

    Both meshes are sampled uniformly by area with ``count`` points each
    (:func:`sample_mesh`, seeds ``seed`` and ``seed + 1``) and each sample's
    exact distance to the *other mesh* is measured
    (:func:`point_mesh_distance`).

    Parameters
    ----------
    vertices, triangles : (V, 3) float64, (F, 3) int
        The reconstruction.
    truth_vertices, truth_triangles : (V', 3) float64, (F', 3) int
        The truth.
    tau : float
        F-score threshold, scene units.
    count : int
        Samples per mesh.
    seed : int
    distance, truth_distance : MeshDistance, optional
        Distances to the reconstruction and to the truth, already built (the same
        figures; one BVH per mesh however many comparisons use it).

    Returns
    -------
    dict
        The keys of :func:`distance_scores` (with the sampling errors of the means)
        plus ``samples``.
    """
    rec = sample_mesh(vertices, triangles, count=count, seed=seed)
    truth = sample_mesh(truth_vertices, truth_triangles, count=count, seed=seed + 1)
    distance = MeshDistance(vertices, triangles) if distance is None else distance
    truth_distance = MeshDistance(truth_vertices, truth_triangles) \
        if truth_distance is None else truth_distance
    scores = distance_scores(truth_distance(rec), distance(truth), tau)
    scores["samples"] = int(count)
    return scores


# --------------------------------------------------------------------------- Delaunay and G1
def _corner_angle(vertices: np.ndarray, apex: np.ndarray, a: np.ndarray,
                  b: np.ndarray) -> np.ndarray:
    """Angle at ``apex`` between the rays to ``a`` and ``b`` (index arrays), radians."""
    u = vertices[a] - vertices[apex]
    w = vertices[b] - vertices[apex]
    # atan2(|u x w|, u.w) is accurate at 0 and pi, unlike arccos.
    return np.arctan2(np.linalg.norm(np.cross(u, w), axis=1), np.einsum("ij,ij->i", u, w))


def opposite_angle_sums(vertices: np.ndarray, triangles: np.ndarray,
                        table: EdgeTable | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Sum of the two angles opposite every interior edge.

    Returns
    -------
    edge_ids : (I,) int64
        Indices into ``table.edges`` of the edges with exactly two faces.
    sums : (I,) float64
        Opposite-angle sums in radians; an edge is locally Delaunay when the
        sum is at most :math:`\\pi`.
    """
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    table = edge_table(t) if table is None else table
    edge_ids, faces, corners = table.edge_faces()
    total = np.zeros(len(edge_ids))
    for side in range(2):
        f, k = faces[:, side], corners[:, side]
        a = t[f, k]
        b = t[f, (k + 1) % 3]
        c = t[f, (k + 2) % 3]
        total += _corner_angle(v, c, a, b)
    return edge_ids, total


def delaunay_fraction(vertices: np.ndarray, triangles: np.ndarray,
                      edge_mask: np.ndarray | None = None) -> float:
    """Share of interior edges meeting the local Delaunay criterion.

    Parameters
    ----------
    vertices : (V, 3) float64
    triangles : (F, 3) int
    edge_mask : (E,) bool, optional
        Restrict to these edges of ``edge_table(triangles).edges`` (for
        instance the edges a constrained triangulation may flip).

    Returns
    -------
    float
        Fraction in [0, 1] of interior edges whose opposite angles sum to at
        most ``pi + TOL.angle``; 1.0 when there is no interior edge.
    """
    table = edge_table(triangles)
    edge_ids, sums = opposite_angle_sums(vertices, triangles, table)
    if edge_mask is not None:
        keep = np.asarray(edge_mask, dtype=bool)[edge_ids]
        sums = sums[keep]
    if sums.size == 0:
        return 1.0
    return float(np.mean(sums <= np.pi + TOL.angle))


def g1_angle(normals_a: np.ndarray, normals_b: np.ndarray) -> float:
    """Largest angle between paired normals, radians.

    Parameters
    ----------
    normals_a, normals_b : (M, 3) float64
        The normals on the two sides of each interior edge (any length, not
        zero).  For a G1 surface every pair agrees and the result is 0.

    Returns
    -------
    float
        ``max_i angle(normals_a[i], normals_b[i])`` in ``[0, pi]``; 0.0 when
        ``M == 0``.
    """
    a = check_shape(normals_a, "(M, 3)", "normals_a", dtype=np.float64)
    b = check_shape(normals_b, "(M, 3)", "normals_b", dtype=np.float64)
    if a.shape != b.shape:
        raise ValueError(f"normals_a and normals_b must have the same shape, "
                         f"got {a.shape} and {b.shape}")
    if a.shape[0] == 0:
        return 0.0
    angle = np.arctan2(np.linalg.norm(np.cross(a, b), axis=1), np.einsum("ij,ij->i", a, b))
    return float(angle.max())


def interior_normal_pairs(vertices: np.ndarray,
                          triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Face normals on the two sides of every interior edge, each ``(I, 3)`` unit.

    ``g1_angle(*interior_normal_pairs(v, t))`` is the largest dihedral kink of
    a flat-faced mesh.
    """
    normals = face_normals(vertices, triangles)
    _, faces, _ = edge_table(triangles).edge_faces()
    return normals[faces[:, 0]], normals[faces[:, 1]]


# --------------------------------------------------------------------------- topology
def face_components(triangles: np.ndarray, table: EdgeTable | None = None) -> np.ndarray:
    """Label of the edge-connected component of every face, shape ``(F,)`` int.

    The components of the bipartite face-edge graph (node ``f`` for face ``f``, node
    ``F + e`` for edge ``e``, one arc per face side): two faces are joined exactly when
    they share an edge (also a non-manifold one), and no sort of the edges is needed.
    """
    t = np.asarray(triangles, dtype=np.int64)
    if len(t) == 0:
        return np.zeros(0, dtype=np.int64)
    table = edge_table(t) if table is None else table
    n_faces, n_edges = len(t), len(table.edges)
    faces = np.repeat(np.arange(n_faces), 3)
    graph = coo_matrix((np.ones(faces.size, dtype=np.int8),
                        (faces, n_faces + table.face_edge.ravel())),
                       shape=(n_faces + n_edges, n_faces + n_edges)).tocsr()
    _, labels = connected_components(graph, directed=False)
    # every edge node has a face, and the face nodes come first: the labels are numbered
    # in order of each component's first face
    return labels[:n_faces].astype(np.int64)


def is_watertight(triangles: np.ndarray) -> bool:
    """Closed and oriented: every edge has two faces, traversing it once each way.

    The cheap part of :func:`mesh_topology` (``closed and oriented``) for a mesh whose
    vertices are not needed; ``triangles (F, 3)`` int.
    """
    t = check_shape(triangles, "(F, 3)", "triangles", dtype=np.int64)
    if len(t) == 0:
        return False
    table = edge_table(t)
    return bool(np.all(table.counts == 2) and np.all(table.forward == 1))


def mesh_topology(vertices: np.ndarray, triangles: np.ndarray) -> dict:
    """Manifold, closed, oriented, component and Euler figures of a mesh.

    Parameters
    ----------
    vertices : (V, 3) float64
    triangles : (F, 3) int

    Returns
    -------
    dict
        ``vertices``, ``faces``, ``edges``, ``boundary_edges`` (one face),
        ``nonmanifold_edges`` (three or more faces), ``edge_manifold``,
        ``closed`` (edge-manifold with no boundary), ``oriented`` (every
        interior edge traversed once each way), ``components`` (edge-connected
        face sets), ``euler`` (V_used - E + F), ``degenerate_faces`` (repeated
        vertex or zero area) and ``signed_volume`` (only if closed, else None).
    """
    v = check_shape(vertices, "(V, 3)", "vertices", dtype=np.float64)
    t = check_shape(triangles, "(F, 3)", "triangles", dtype=np.int64)
    check_finite(v, "vertices")
    if len(t) and (t.min() < 0 or t.max() >= len(v)):
        raise ValueError(f"triangles index vertices outside [0, {len(v)})")
    table = edge_table(t)
    boundary = int(np.count_nonzero(table.counts == 1))
    nonmanifold = int(np.count_nonzero(table.counts > 2))
    interior = table.counts == 2
    oriented = bool(np.all(table.forward[interior] == 1)) and nonmanifold == 0
    labels = face_components(t, table)
    seen = np.zeros(len(v), dtype=bool)
    seen[t.ravel()] = True
    used = int(np.count_nonzero(seen))
    repeated = (t[:, 0] == t[:, 1]) | (t[:, 1] == t[:, 2]) | (t[:, 0] == t[:, 2])
    scale = float(np.ptp(v, axis=0).max()) if len(v) else 1.0
    tiny = triangle_areas(v, t) <= TOL.zero * max(scale, 1.0) ** 2
    closed = len(t) > 0 and boundary == 0 and nonmanifold == 0
    return {
        "vertices": int(len(v)),
        "faces": int(len(t)),
        "edges": int(len(table.edges)),
        "boundary_edges": boundary,
        "nonmanifold_edges": nonmanifold,
        "edge_manifold": nonmanifold == 0,
        "closed": bool(closed),
        "oriented": oriented,
        "components": int(labels.max() + 1) if len(labels) else 0,
        "euler": int(used - len(table.edges) + len(t)),
        "degenerate_faces": int(np.count_nonzero(repeated | tiny)),
        "signed_volume": signed_volume(v, t) if closed else None,
    }


def silhouette_scores(vertices: np.ndarray, triangles: np.ndarray, cameras, silhouettes,
                      margin_px: int = 5) -> dict:
    """How a surface's outline agrees with the object's silhouettes in calibrated views.

    The check that real photographs allow without a surface truth (e.g. the
    Middlebury temple: its silhouettes are the pixels brighter than the black cloth):
    a view's mask of the surface is the pixels whose viewing ray through the pixel
    centre hits it (open3d ``RaycastingScene``, one ray per pixel), compared with the
    silhouette.

    Parameters
    ----------
    vertices : (V, 3) float64
    triangles : (F, 3) int64
    cameras : sequence of ``matching.cameras.Camera`` (``ray``, ``width``, ``height``)
    silhouettes : sequence of (H, W) bool
    margin_px : int
        Disk radius of the tolerance band around the silhouette's outline: edge pixels
        are half object, and the calibration is good to a pixel or so.

    Returns
    -------
    dict
        Per view (lists in the cameras' order): ``iou`` (surface mask against the
        silhouette), ``inside`` (share of the surface's pixels within the silhouette
        dilated by ``margin_px``: no surface where the object is not), ``covered``
        (share of the silhouette eroded by ``margin_px`` that the surface covers: no
        object left out).
    """
    import cv2
    import open3d as o3d

    v = check_shape(vertices, "(V, 3)", "vertices", dtype=np.float64)
    t = check_shape(triangles, "(F, 3)", "triangles", dtype=np.int64)
    centre, scene = _centred_scene(v, t)
    disk = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * margin_px + 1, 2 * margin_px + 1))
    out = {"iou": [], "inside": [], "covered": []}
    for cam, silhouette in zip(cameras, silhouettes, strict=True):
        silhouette = np.asarray(silhouette, bool)
        rows, cols = np.indices(silhouette.shape)
        origin, direction = cam.ray(np.column_stack([cols.ravel(), rows.ravel()])
                                    .astype(np.float64))
        rays = np.hstack([origin - centre, direction]).astype(np.float32)
        hit = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
        mask = np.isfinite(hit).reshape(silhouette.shape)
        grown = cv2.dilate(silhouette.astype(np.uint8), disk) > 0
        core = cv2.erode(silhouette.astype(np.uint8), disk) > 0
        out["iou"].append(float((mask & silhouette).sum() / max((mask | silhouette).sum(), 1)))
        out["inside"].append(float((mask & grown).sum() / max(mask.sum(), 1)))
        out["covered"].append(float((mask & core).sum() / max(core.sum(), 1)))
    return out


def seen_by_cameras(vertices: np.ndarray, triangles: np.ndarray, points: np.ndarray,
                    cameras) -> np.ndarray:
    """Which points on a surface some camera sees: in front of it, inside its image, and
    the first hit of the ray from its centre (open3d ``RaycastingScene``) -- so the fill a
    closed surface needs under an unseen base is told from what the photographs show.

    Parameters
    ----------
    vertices : (V, 3) float64
    triangles : (F, 3) int64
    points : (S, 3) float64
        Points on the surface (e.g. :func:`sample_mesh`).
    cameras : sequence of ``matching.cameras.Camera`` (``center``, ``project``, ``depth``,
        ``width``, ``height``)

    Returns
    -------
    (S,) bool

    Notes
    -----
    A point counts as the first hit when the hit lies no nearer the camera than the point
    less ``1e-4`` of the surface's extent: float32 hits are exact to ~1e-7 of the distance,
    so the slack covers rays at grazing angles, and stays far below a point spacing.
    """
    import open3d as o3d

    v = check_shape(vertices, "(V, 3)", "vertices", dtype=np.float64)
    t = check_shape(triangles, "(F, 3)", "triangles", dtype=np.int64)
    p = check_shape(points, "(S, 3)", "points", dtype=np.float64)
    centre, scene = _centred_scene(v, t)
    slack = 1e-4 * float(np.ptp(v, axis=0).max())
    seen = np.zeros(len(p), bool)
    for cam in cameras:
        origin = np.asarray(cam.center, np.float64)
        towards = p - origin
        length = np.linalg.norm(towards, axis=1)
        pixel = cam.project(p)
        inside = ((cam.depth(p) > 0) & (pixel[:, 0] >= 0) & (pixel[:, 0] < cam.width)
                  & (pixel[:, 1] >= 0) & (pixel[:, 1] < cam.height))
        rays = np.hstack([np.broadcast_to(origin - centre, p.shape), towards / length[:, None]])
        hit = scene.cast_rays(o3d.core.Tensor(rays.astype(np.float32)))["t_hit"].numpy()
        seen |= inside & (hit >= length - slack)
    return seen
