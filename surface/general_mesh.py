r"""A general control mesh for what one family of parallel sections cannot organise.

A part nearly parallel to the sections (a column under a roof, a leg, an ear, a handle at a
grazing angle) is cut in few sections at a grazing angle, and the stitched mesh bridges it
with slabs or loses it.  There a control mesh that knows no axis takes over: the screened
Poisson iso-surface of the cloud (Kazhdan and Hoppe 2013 [1]_, open3d's octree solver at
cells of about a point spacing, normals by PCA of ``NORMAL_NEIGHBOURS`` neighbours oriented
by the tangent-plane graph of Hoppe et al. 1992 [2]_), its balloons past the data (vertices
beyond :func:`support_reach` of every point) pressed onto their convex hull, decimated by
quadric error (Garland and Heckbert 1997 [3]_) to triangles of the sections' spacing,
repaired to a closed 2-manifold; its control vertices are fitted to the cloud
(:func:`surface.fitting.fitted_control_mesh`; :func:`pipeline.bezier_surface.smooth_general`),
and Loop's patches (:mod:`surface.bezier`) cover the whole object with one G1 surface.

Which control mesh an object gets is decided on its fidelity to its own cloud
(:func:`cloud_fidelity`), the measures a cloud without a truth allows: ``A``, the 90th
percentile of the distance from points sampled uniformly on the surface to the nearest
cloud point (does it invent geometry: slabs, shards?); ``C``, the median distance from the
cloud's points to the surface (does it leave the data: a lost branch, a melted column?).
:func:`prefer_general` weighs validity first, then the genus the data support
(:func:`evidence_genus`: the section surface's handles that run along the points, not the
tunnels a Poisson iso-surface draws between close parts), then ``A`` and ``cp``, the mean
distance from the cloud projected onto its neighbour planes (:func:`plane_reference`; the
general mesh must be nearer on one by more than :data:`MARGIN` and not farther on the
other): the section method stays the default wherever it organises the points.

Boundary: ``points (N, 3) float64``; meshes ``(V, 3) float64`` / ``(F, 3) int64``, closed,
oriented outward.

References
----------
.. [1] M. Kazhdan, H. Hoppe, "Screened Poisson surface reconstruction", ACM TOG 32(3), 2013.
.. [2] H. Hoppe, T. DeRose, T. Duchamp, J. McDonald, W. Stuetzle, "Surface reconstruction
   from unorganized points", SIGGRAPH 1992.
.. [3] M. Garland, P. Heckbert, "Surface simplification using quadric error metrics",
   SIGGRAPH 1997.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import ConvexHull, cKDTree

from surface.metrics import edge_table, signed_volume
from surface.validate import check_shape

#: Neighbours of the PCA normals and of their orientation graph (as benchmarks/surface.py's
#: Poisson peer: the same normals the comparison uses).
NORMAL_NEIGHBOURS = 30
#: Octree depth of the screened Poisson solve: the peer's depth, 2^8 cells across the
#: cloud's largest extent (finer than the section spacing of every cloud of <= 10^6 points).
POISSON_DEPTH = 8
#: Surface samples per cloud point for ``A`` (at least :data:`MIN_SAMPLES`).
SAMPLES_PER_POINT = 1.0
MIN_SAMPLES = 20_000
#: The octree's cube over the cloud's largest extent (open3d's ``scale``): the peer's (its
#: default, 1.1) first, for cells as fine as the peer's; :data:`OPEN_SCALE` where the
#: iso-surface meets the cube's faces (data open there: the temple's unseen base).  On the
#: cow's 4·10^4 noise-free points the padded cube's coarser cells cost 20 % of Chamfer in
#: the iso-surface (4.74e-3 against 3.95e-3 at depth 8) and 15 % in the smooth surface.
POISSON_SCALE = 1.1
#: The cube padded by 50 %, so that the iso-surface closes inside it where the data are
#: open: at 1.1 the temple's base met the cube's faces and came out cut open there (64 /
#: 108 / 116 border edges at depths 6 / 7 / 8); at 1.5, none.
OPEN_SCALE = 1.5
#: Relative margin by which the general mesh must be nearer the cloud on ``A`` or ``C`` (and
#: no farther on the other) to replace the section mesh: well above the sampling spread of a
#: 90th percentile and a median of >= 10^4 samples (relative standard errors ~1-2 %), so
#: that two surfaces equally near the data never flip the choice on the last bits.
MARGIN = 0.10
#: The chance that a spot of a surface sampled as a Poisson process of the cloud's density
#: lies farther than :func:`support_reach` from every point (so counts as unseen).
UNSEEN_CHANCE = 1e-3
#: Neighbourhood sizes of the plane-projected reference (:func:`plane_reference`): from 8 (a
#: plane's 3 parameters and 5 degrees of freedom for the residual) to 48.
PLANE_NEIGHBOURS = (8, 12, 16, 24, 32, 48)


@dataclass(frozen=True)
class Fidelity:
    """A surface's fidelity to its cloud (scene units).

    Attributes
    ----------
    a90 : float
        90th percentile of surface-sample -> nearest cloud point distances.
    c50 : float
        Median of cloud point -> surface distances.
    cp : float or None
        Mean distance from the cloud projected onto its neighbour planes
        (:func:`plane_reference`) to the surface: the cloud's half of a Chamfer distance
        with the projected cloud standing in for the truth, which the choice weighs.
    """

    a90: float
    c50: float
    cp: float | None = None

    def to_json(self) -> dict:
        out = {"A": self.a90, "C": self.c50}
        if self.cp is not None:
            out["Cp"] = self.cp
        return out


def cloud_fidelity(vertices: np.ndarray, triangles: np.ndarray, points: np.ndarray,
                   samples: int | None = None, seed: int = 0,
                   reference: np.ndarray | None = None) -> Fidelity:
    """``A`` and ``C`` of a triangle mesh against a cloud, and ``cp``, the mean distance from
    the cloud projected onto its neighbour planes.

    Parameters
    ----------
    vertices : (V, 3) float64
    triangles : (F, 3) int
    points : (N, 3) float64
        The cloud.
    samples : int, optional
        Area-uniform samples on the mesh; default ``max(MIN_SAMPLES, N)``.
    seed : int
    reference : (N, 3) float64, optional
        The projected cloud (:func:`plane_reference`), when the caller has it.

    Returns
    -------
    Fidelity
    """
    from surface import metrics

    p = check_shape(points, "(N, 3)", "points", dtype=np.float64)
    count = samples or max(MIN_SAMPLES, int(SAMPLES_PER_POINT * len(p)))
    on_surface = metrics.sample_mesh(vertices, triangles, count=count, seed=seed)
    a = metrics.point_cloud_distance(on_surface, p)
    c = metrics.point_mesh_distance(p, vertices, triangles)
    if reference is None:
        reference = plane_reference(p)[0]
    plane = c if reference is p else metrics.point_mesh_distance(reference, vertices, triangles)
    return Fidelity(float(np.percentile(a, 90)), float(np.median(c)), float(np.mean(plane)))


def plane_reference(points: np.ndarray) -> tuple[np.ndarray, int]:
    """The cloud projected onto each point's ``k``-neighbour least-squares plane, ``k`` from
    the data; ``(points, 1)`` itself where no ``k`` would bring it nearer the surface.

    A point's plane through ``k`` neighbours at spacing ``s`` (radius ``r``, ``pi r^2 = k
    s^2``) has the points' noise ``sigma`` averaged to a variance ``sigma^2 / k`` at the point,
    and is biased by the surface's curvature ``kappa`` by its mean sagitta over the disc,
    ``kappa r^2 / 4`` on a sphere, whose square is 3 times the variance the curvature adds to
    the plane's residual (``kappa^2 r^4 / 48``; a cylinder's is 1 time, a saddle's 0: the
    sphere's 3 is the worst case).  The residual variance, the smallest eigenvalue of the
    neighbours' covariance times ``k / (k - 3)``, grows as ``m(k) = sigma^2 + beta k^2``
    (``r^4 ~ k^2``); its median over the points at each of :data:`PLANE_NEIGHBOURS` (corrected
    by the chi-square median ``(1 - 2 / (9 nu))^3`` of ``nu = k - 3`` degrees of freedom) fits
    ``sigma^2`` and ``beta`` by non-negative least squares.  The projection's expected squared
    error ``sigma^2 / k + 3 beta k^2`` (least near ``k = (sigma^2 / (6 beta))^(1/3)``) is taken
    at its least over the sizes tried; below the raw points' ``sigma^2`` the cloud is
    projected, else kept (a noise-free cloud lies on its surface: a plane only adds its
    sagitta).

    Returns
    -------
    reference : (N, 3) float64
    k : int
        The neighbours of each plane; 1 for the cloud itself.
    """
    from scipy.optimize import nnls

    p = check_shape(points, "(N, 3)", "points", dtype=np.float64)
    sizes = [k for k in PLANE_NEIGHBOURS if k < len(p)]
    if len(sizes) < 2:
        return p, 1
    _, index = cKDTree(p).query(p, sizes[-1])
    medians, planes = [], []
    for k in sizes:
        near = p[index[:, :k]]
        centre = near.mean(axis=1)
        offset = near - centre[:, None]
        values, vectors = np.linalg.eigh(np.einsum("nki,nkj->nij", offset, offset) / k)
        nu = k - 3
        medians.append(np.median(values[:, 0]) * k / nu / (1 - 2 / (9 * nu)) ** 3)
        planes.append((centre, vectors[:, :, 0]))
    k2 = np.asarray(sizes, float) ** 2
    (sigma2, beta), _ = nnls(np.c_[np.ones_like(k2), k2], np.asarray(medians))
    if not sigma2 > 0:
        return p, 1
    error = [sigma2 / k + 3 * beta * k * k for k in sizes]
    chosen = int(np.argmin(error))
    if not error[chosen] < sigma2:
        return p, 1
    centre, normal = planes[chosen]
    return p - np.einsum("ni,ni->n", p - centre, normal)[:, None] * normal, sizes[chosen]


def needs_general(section: Fidelity, valid: bool, noise: float | None) -> bool:
    """Whether the section surface gives cause to build the general one: it is not a valid
    solid, or no noise estimate exists, or its C exceeds what the noise explains.

    Points with noise ``sigma`` about the truth and a surface within ``sigma`` of it (the
    sizing's goal) lie at ``|N(0, 2 sigma^2)|`` from the surface, whose median is
    ``0.6745 sqrt(2) sigma``; beyond that by more than :data:`MARGIN` the surface leaves
    the data (the temple: C 2.47e-4 against 0.6745 sqrt 2 x 1.78e-4 = 1.70e-4).
    """
    if not valid or noise is None or not noise > 0:
        return True
    return bool(section.c50 > (1 + MARGIN) * 0.6745 * np.sqrt(2.0) * noise)


def support_reach(point_spacing: float, noise: float | None = None) -> float:
    """How far from every cloud point a piece of surface lies before it counts as not
    seen by the data (:func:`supported_genus`), scene units.

    Points spread over a surface at spacing ``s`` (a density of ``1/s^2``, as a Poisson
    process) leave a spot of the surface farther than ``r`` from all of them with
    probability ``exp(-pi r^2 / s^2)``; :data:`UNSEEN_CHANCE` (1e-3) gives
    ``r = s sqrt(ln(1e3) / pi) = 1.49 s``.  Noise ``sigma`` about the surface adds
    ``3 sigma``.
    """
    return float(point_spacing * np.sqrt(np.log(1.0 / UNSEEN_CHANCE) / np.pi)
                 + 3.0 * (noise or 0.0))


def supported_genus(vertices: np.ndarray, triangles: np.ndarray, points: np.ndarray,
                    reach: float) -> int | None:
    """The genus of the part of a closed surface the data see: the handles that run along
    the cloud, not those through empty space.

    The faces whose centroid is farther than ``reach`` (:func:`support_reach`) from every
    cloud point are removed; vertices pinched by the removal are split into one vertex a fan
    of faces; the genus of what is left, ``sum_c (2 - chi_c - b_c) / 2``, is returned.
    Removing a disc (a slab, a fill of an unseen base, a hole where the sampling is thin)
    leaves the genus as it was (one face and one border loop fewer); removing a band round
    a tube (a tunnel the iso-surface drew between two close parts of the object, through
    no data) lowers it by one.  ``None`` when nothing of the surface is near the data.
    """

    from surface.validity import check_solid

    v = check_shape(vertices, "(V, 3)", "vertices", dtype=np.float64)
    t = check_shape(triangles, "(F, 3)", "triangles", dtype=np.int64)
    distance, _ = cKDTree(check_shape(points, "(N, 3)", "points", dtype=np.float64)).query(
        v[t].mean(axis=1))
    kept = t[distance <= reach]
    if not len(kept):
        return None
    corners = _split_pinched(kept)
    ids, relabelled = np.unique(corners.ravel(), return_inverse=True)
    original = np.empty(len(ids), np.int64)
    original[relabelled] = kept.ravel()
    return check_solid(v[original], relabelled.reshape(-1, 3), intersections=False).genus


def evidence_genus(section_vertices: np.ndarray, section_triangles: np.ndarray,
                   points: np.ndarray, reach: float) -> int | None:
    """The genus the data support: the section surface's handles that run along the cloud
    (:func:`supported_genus` of the section surface at ``reach``).

    The section surface's topology comes from the points themselves, section by section: a
    handle is a loop seen to part and join again over several sections (the stitch's
    branch events), so it does not grow the tunnels a Poisson iso-surface draws between two
    parts of an object closer than its kernel (the cow's legs, the teapot's lid and spout
    on its body: genus 7 and 13 at 4·10^4 points, every tunnel within 1.5 spacings of the
    points, so that the data cannot tell them from a handle by distance).  A handle of the
    section surface through no data (a slab bridging a gap) is not counted.  ``None`` when
    the section surface is not a closed manifold (no genus).
    """
    from surface.validity import check_solid

    if check_solid(section_vertices, section_triangles, intersections=False).genus is None:
        return None
    return supported_genus(section_vertices, section_triangles, points, reach)


def _split_pinched(triangles: np.ndarray) -> np.ndarray:
    """Corner labels ``(F, 3)``: corners of one vertex joined across the edges of the faces
    they share, so that a vertex where two fans meet only at a point becomes two."""
    flat = edge_table(triangles).face_edge.ravel()    # slot 3f + k: side k -> k + 1 of f
    order = np.argsort(flat, kind="stable")
    same = flat[order[1:]] == flat[order[:-1]]
    (f1, k1), (f2, k2) = np.divmod(order[:-1][same], 3), np.divmod(order[1:][same], 3)
    a1, b1 = 3 * f1 + k1, 3 * f1 + (k1 + 1) % 3
    a2, b2 = 3 * f2 + k2, 3 * f2 + (k2 + 1) % 3
    corner_vertex = triangles.ravel()
    straight = corner_vertex[a1] == corner_vertex[a2]
    rows = np.r_[a1, b1]
    cols = np.r_[np.where(straight, a2, b2), np.where(straight, b2, a2)]
    n = 3 * len(triangles)
    graph = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n))
    return connected_components(graph, directed=False)[1].reshape(-1, 3)


def prefer_general(section: Fidelity, general: Fidelity, margin: float = MARGIN,
                   section_valid: bool = True, general_valid: bool = True,
                   section_genus: int | None = None, general_genus: int | None = None,
                   evidence_genus: int | None = None) -> bool:
    """Whether the general surface replaces the section surface, judged in this order:

    1. **validity**: a valid solid beats one that is not;
    2. **genus**: when exactly one of the two has ``evidence_genus``, the genus the data
       support (:func:`evidence_genus`), that one;
    3. **fidelity**: the general surface when it is nearer the cloud on A or C by more than
       ``margin`` (relative) and not farther on the other by more than it; in place of C,
       when both have it, ``cp``: the mean distance from the cloud projected onto its
       neighbour planes (:func:`plane_reference`).  Raw C rewards a surface that follows
       the noise, and a median misses a tail the truth's mean distance counts (the noisy
       vase: the section surface nearer in the median, farther in the mean).

    Without the genera (``None``) step 2 is skipped.
    """
    if section_valid != general_valid:
        return bool(general_valid)
    if None not in (section_genus, general_genus, evidence_genus):
        section_right = section_genus == evidence_genus
        if section_right != (general_genus == evidence_genus):
            return not section_right
    plane = None not in (section.cp, general.cp)
    c_section = section.cp if plane else section.c50
    c_general = general.cp if plane else general.c50
    ratios = np.array([section.a90 / max(general.a90, 1e-300),
                       c_section / max(c_general, 1e-300)])
    return bool(ratios.max() > 1 + margin and ratios.min() >= 1 / (1 + margin))


def _normals_cloud(points: np.ndarray):
    import open3d as o3d

    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(knn=NORMAL_NEIGHBOURS))
    cloud.orient_normals_consistent_tangent_plane(NORMAL_NEIGHBOURS)
    return cloud


def _largest_components(mesh, keep_share: float):
    """Drop the components of fewer than ``keep_share`` of the faces (Poisson's small
    blobs where the indicator function wobbles away from the data)."""
    labels, counts, _ = mesh.cluster_connected_triangles()
    labels, counts = np.asarray(labels), np.asarray(counts)
    small = counts < keep_share * counts.sum()
    if small.any():
        mesh.remove_triangles_by_mask(small[labels])
        mesh.remove_unreferenced_vertices()
    return mesh


def poisson_surface(points: np.ndarray, depth: int = POISSON_DEPTH, trim: float = 0.0,
                    scale: float = POISSON_SCALE) -> tuple[np.ndarray, np.ndarray]:
    """The peer: open3d's screened Poisson surface of the cloud as users run it (normals as
    :data:`NORMAL_NEIGHBOURS`, the default cube): ``(V, 3)``, ``(F, 3) int64``; ``trim`` > 0
    removes the vertices of the lowest ``trim`` share of the solver's density (users trim
    at 5 %: the surface opens where the data are thin); ``scale`` the cube over the cloud's
    largest extent (:data:`OPEN_SCALE`: closed inside it where the default cube cuts the
    iso-surface open, as at the temple's unseen base)."""
    import open3d as o3d

    p = check_shape(points, "(N, 3)", "points", dtype=np.float64)
    mesh, density = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(
        _normals_cloud(p), depth=depth, scale=scale)
    if trim > 0:
        density = np.asarray(density)
        mesh.remove_vertices_by_mask(density < np.quantile(density, trim))
    return np.asarray(mesh.vertices, np.float64), np.asarray(mesh.triangles, np.int64)


def poisson_depth(points: np.ndarray, point_spacing: float, finest: int = POISSON_DEPTH) -> int:
    """Octree depth whose cells are about one point spacing across in the padded cube (the
    cloud's largest extent times :data:`OPEN_SCALE`): finer cells only fit the noise (on the
    cow's 10^4 noisy points depths 7 and 8 grew 6 spurious handles, depth 5 none), at most
    ``finest``."""
    extent = OPEN_SCALE * float(np.ptp(points, axis=0).max())
    return int(np.clip(np.ceil(np.log2(extent / point_spacing)), 4, finest))


def _clean(mesh):
    mesh.remove_degenerate_triangles()
    mesh.remove_duplicated_triangles()
    mesh.remove_duplicated_vertices()
    mesh.remove_unreferenced_vertices()
    return np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.triangles, dtype=np.int64)


def poisson_control_mesh(points: np.ndarray, spacing: float, point_spacing: float,
                         depth: int | None = None, keep_share: float = 0.01
                         ) -> tuple[np.ndarray, np.ndarray]:
    """A closed control mesh of triangles about ``spacing`` across, from the cloud alone.

    Parameters
    ----------
    points : (N, 3) float64
    spacing : float
        Target edge length, scene units (the section spacing: the control mesh is as fine
        as the section mesh it stands in for).
    point_spacing : float
        The cloud's point spacing, scene units (:func:`poisson_depth`).
    depth : int, optional
        Screened Poisson octree depth; default :func:`poisson_depth`.
    keep_share : float
        Components with fewer than this share of the faces are dropped.

    Returns
    -------
    vertices : (V, 3) float64
    triangles : (F, 3) int64
        Closed, edge- and vertex-manifold, oriented outward.

    Raises
    ------
    ValueError
        Too few points, a non-positive spacing, or no closed manifold mesh at any depth.

    Notes
    -----
    open3d's iso-surface and its quadric decimation now and then leave a few non-manifold
    edges; a mesh that is not a closed manifold is decimated again to 30 % fewer
    triangles, then solved one octree level coarser (at most three tries each).
    """
    import open3d as o3d

    p = check_shape(points, "(N, 3)", "points", dtype=np.float64)
    if len(p) < 4 * NORMAL_NEIGHBOURS:
        raise ValueError(f"a general control mesh needs >= {4 * NORMAL_NEIGHBOURS} points, "
                         f"got {len(p)}")
    if not (spacing > 0 and point_spacing > 0):
        raise ValueError(f"spacings must be > 0, got {spacing}, {point_spacing}")
    cloud = _normals_cloud(p)
    depth = poisson_depth(p, point_spacing) if depth is None else int(depth)
    hull = _hull_planes(p)
    near, reach = cKDTree(p), support_reach(point_spacing)
    problem = ""
    for level in range(depth, max(depth - 3, 3), -1):
        # one thread: the solver's parallel sums differ run to run in the last bits, and a
        # workspace's outputs must be byte-reproducible
        for scale in (POISSON_SCALE, OPEN_SCALE):
            mesh, _ = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(
                cloud, depth=level, scale=scale, n_threads=1)
            if not _border_edges(np.asarray(mesh.triangles)):   # closed inside the cube
                break
        mesh = _largest_components(mesh, keep_share)
        vertices, triangles = _repaired(*_clean(mesh))
        # only the balloons (vertices the data do not see) are pressed onto the hull: a
        # vertex within reach of a point is on the data, and testing every vertex against
        # every hull plane was a third of the general surface's CPU
        unseen = near.query(vertices)[0] > reach
        vertices[unseen] = clamp_to_hull(vertices[unseen], hull)
        # equilateral triangles of edge h have area sqrt(3)/4 h^2
        mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(vertices),
                                         o3d.utility.Vector3iVector(triangles))
        target = max(int(mesh.get_surface_area() / (np.sqrt(3) / 4 * spacing ** 2)), 64)
        for _ in range(3):
            decimated = (mesh.simplify_quadric_decimation(target)
                         if target < len(mesh.triangles) else o3d.geometry.TriangleMesh(mesh))
            # quadric decimation keeps no topology: it can pinch a thin part off into a
            # blob of a few faces (the noisy teapot's 10^4 points: 10 faces beside 11 864,
            # cleaned to two faces back to back), dropped as the iso-surface's own blobs are
            decimated = _largest_components(decimated, keep_share)
            vertices, triangles = _repaired(*_clean(decimated))
            problem = _closed_problem(vertices, triangles)
            if not problem:
                if signed_volume(vertices, triangles) < 0:  # normals oriented inward
                    triangles = triangles[:, ::-1].copy()
                return vertices, triangles
            target = max(int(0.7 * min(target, len(mesh.triangles))), 64)
    raise ValueError(f"the general control mesh is {problem}")


def _border_edges(triangles: np.ndarray) -> int:
    """Edges of one face: where an iso-surface met its octree's cube."""
    return int(np.count_nonzero(edge_table(triangles).counts == 1)) if len(triangles) else 0


def _hull_planes(points: np.ndarray) -> np.ndarray:
    """The cloud's convex hull as outward planes ``(K, 4)``: ``n . x + d <= 0`` inside."""

    return ConvexHull(points).equations


def clamp_to_hull(vertices: np.ndarray, planes: np.ndarray, rounds: int = 30,
                  chunk: int = 8192) -> np.ndarray:
    """Vertices moved into the convex hull ``planes (K, 4)``: ``(V, 3) float64``.

    Where the data are open (an object's unseen base), the Poisson iso-surface closes in a
    balloon past every point; pressed onto the hull it becomes the flattest fill the data's
    extent allows.  Each round moves every vertex outside onto its most violated plane
    (cyclic projections onto convex sets converge into their intersection); vertices inside
    do not move.
    """
    out = np.array(vertices, dtype=np.float64, copy=True)
    normals, offsets = planes[:, :3], planes[:, 3]
    for start in range(0, len(out), chunk):
        block = out[start:start + chunk]          # a view: moved in place
        rows = np.arange(len(block))              # the vertices still outside
        for _ in range(rounds):
            violation = block[rows] @ normals.T + offsets  # (B, K)
            worst = np.argmax(violation, axis=1)
            amount = violation[np.arange(len(rows)), worst]
            outside = amount > 0
            if not outside.any():
                break
            rows = rows[outside]   # a vertex inside stays inside: never looked at again
            block[rows] -= amount[outside, None] * normals[worst[outside]]
    return out


def _repaired(vertices: np.ndarray, triangles: np.ndarray, rounds: int = 3
              ) -> tuple[np.ndarray, np.ndarray]:
    """The faces at non-manifold edges and vertices removed and each hole so made closed by
    a fan about its centroid (the holes are a few faces wide: open3d's iso-surface leaves a
    handful of such edges, 2-44 on the temple cloud at depths 7-8)."""
    from surface.open_surface import boundary_loops
    from surface.validity import check_solid

    v, t = vertices, triangles
    for _ in range(rounds):
        report = check_solid(v, t, intersections=False)
        bad = np.union1d(np.asarray(report.nonmanifold_edges).ravel(),
                         np.asarray(report.nonmanifold_vertices).ravel())
        if not bad.size and not report.boundary_edges:
            break
        if bad.size:
            t = t[~np.isin(t, bad).any(axis=1)]
        try:
            loops = boundary_loops(t)
        except (ValueError, IndexError):
            break
        fans, extra = [], []
        for loop in loops:
            centre = len(v) + len(extra)
            extra.append(v[loop].mean(axis=0))
            # a border edge (a, b) of the remaining faces is closed by the face (b, a, centre)
            fans.append(np.c_[np.roll(loop, -1), loop, np.full(len(loop), centre)])
        if extra:
            v = np.vstack([v, np.array(extra)])
            t = np.vstack([t, *fans])
        used = np.unique(t)
        remap = np.full(len(v), -1, np.int64)
        remap[used] = np.arange(len(used))
        v, t = v[used], remap[t]
    return v, t


def _closed_problem(vertices: np.ndarray, triangles: np.ndarray) -> str:
    """Why a mesh is not a closed, oriented 2-manifold ("" when it is one)."""
    from surface.validity import check_solid

    report = check_solid(vertices, triangles, intersections=False)
    if report.boundary_edges or len(report.nonmanifold_edges) or len(report.nonmanifold_vertices):
        return (f"not a closed manifold ({report.boundary_edges} border edges, "
                f"{len(report.nonmanifold_edges)} non-manifold edges, "
                f"{len(report.nonmanifold_vertices)} non-manifold vertices)")
    if report.flipped_faces.size or report.nonorientable_components:
        return f"not consistently oriented ({report.flipped_faces.size} faces)"
    # a closed manifold's vertex of two faces is a component of two faces back to back,
    # which Loop's patches cannot carry (no ring of three or more neighbours)
    faces = np.bincount(triangles.ravel(), minlength=len(vertices))
    thin = int(np.count_nonzero((faces > 0) & (faces < 3)))
    if thin:
        return f"degenerate ({thin} vertices of fewer than 3 faces)"
    return ""
