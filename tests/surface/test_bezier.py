"""Tests of surface.bezier: Loop's G1 sextic triangular Bézier surface.

Tolerances: the construction and evaluation are a few hundred floating-point
operations deep on coordinates of size ~1, so exact identities hold to
~1e-14 x the mesh size; the issue's limits (gap <= 1e-12 x size, angle <=
1e-9 rad) are used where they are stated, 1e-12 relative elsewhere.
"""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial import cKDTree

from surface import _loop_patches as lp
from surface import bezier as bz
from surface import bezier_patch, bezier_tessellation

# ----------------------------------------------------------------------------- meshes


def _o3d_arrays(mesh):
    return np.asarray(mesh.vertices).copy(), np.asarray(mesh.triangles).astype(np.int64)


def icosphere(level: int = 1):
    mesh = o3d.geometry.TriangleMesh.create_icosahedron(1.0).subdivide_midpoint(level)
    v, t = _o3d_arrays(mesh)
    return v / np.linalg.norm(v, axis=1, keepdims=True), t


def octahedron():
    return _o3d_arrays(o3d.geometry.TriangleMesh.create_octahedron(1.0))


def cube(level: int = 1):
    """Unit cube, triangulated and midpoint-subdivided: valences 3, 4, 5, 6."""
    mesh = o3d.geometry.TriangleMesh.create_box().subdivide_midpoint(level)
    return _o3d_arrays(mesh)


def band_mesh(n: int = 6, sections: int = 6, height: float = 2.0):
    """Vase-like closed mesh stitched like the direction criterion N <-> 2N.

    Sections alternate N and 2N points at equal angles; neighbouring sections
    are zipped by angle (ties advance the sparser section, as in the paper's
    triangles (o_k, e_2k, e_2k+1), (o_k, e_2k+1, o_k+1)); a pole closes each
    end.  Interior valences are 4, 6 and 8.
    """
    z = np.linspace(0.0, height, sections)
    radius = 0.6 + 0.25 * np.sin(2.2 * z) + 0.1 * z
    counts = [n if k % 2 == 0 else 2 * n for k in range(sections)]
    points, start = [], []
    for zk, rk, ck in zip(z, radius, counts, strict=True):
        theta = 2 * np.pi * np.arange(ck) / ck
        start.append(sum(len(p) for p in points))
        points.append(np.stack([rk * np.cos(theta), rk * np.sin(theta), np.full(ck, zk)], 1))
    tris = []
    for k in range(sections - 1):
        lo, up, nl, nu = start[k], start[k + 1], counts[k], counts[k + 1]
        i = j = 0
        while i < nl or j < nu:
            ahead = (i + 1) / nl - (j + 1) / nu  # ties advance the sparser section
            advance_low = j >= nu or (i < nl and (ahead < -1e-12 or (abs(ahead) <= 1e-12
                                                                     and nl < nu)))
            if advance_low:
                tris.append((lo + i % nl, lo + (i + 1) % nl, up + j % nu))
                i += 1
            else:
                tris.append((lo + i % nl, up + (j + 1) % nu, up + j % nu))
                j += 1
    vertices = np.concatenate(points + [[[0, 0, -0.4]], [[0, 0, height + 0.3]]])
    bottom, top = len(vertices) - 2, len(vertices) - 1
    n0, nk, last = counts[0], counts[-1], start[-1]
    tris += [(bottom, (i + 1) % n0, i) for i in range(n0)]
    tris += [(top, last + i, last + (i + 1) % nk) for i in range(nk)]
    return vertices.astype(np.float64), np.array(tris, dtype=np.int64)


MESHES = {
    "octahedron": octahedron,
    "icosphere": icosphere,
    "cube": cube,
    "band": band_mesh,
}


@pytest.fixture(scope="module")
def surfaces():
    return {name: (make(), bz.control_net(*make())) for name, make in MESHES.items()}


def _size(vertices):
    return float(np.linalg.norm(vertices.max(axis=0) - vertices.min(axis=0)))


def _angle(n1, n2):
    return np.arctan2(np.linalg.norm(np.cross(n1, n2), axis=-1), np.sum(n1 * n2, axis=-1))


# ----------------------------------------------------------------------------- index order / basis
def test_index_table_is_descending_i_then_j():
    table = bz.index_table()
    assert table.shape == (28, 3)
    assert np.all(table.sum(axis=1) == 6)
    assert [tuple(r) for r in table[:6]] == [(6, 0, 0), (5, 1, 0), (5, 0, 1), (4, 2, 0),
                                            (4, 1, 1), (4, 0, 2)]
    assert tuple(table[21]) == (0, 6, 0) and tuple(table[27]) == (0, 0, 6)
    assert np.array_equal(bz.control_index(*table.T), np.arange(28))
    with pytest.raises(ValueError, match="i \\+ j \\+ k"):
        bz.control_index(3, 2, 2)


def test_bernstein_basis_is_a_partition_of_unity():
    bary = np.random.default_rng(0).dirichlet([1, 1, 1], size=50)
    assert np.allclose(bz.bernstein_matrix(bary).sum(axis=1), 1.0, atol=1e-14)


def _casteljau(net, bary):
    """Direct recursive de Casteljau on a dict of (i, j, k) -> point."""
    degree = int(round((np.sqrt(8 * len(net) + 1) - 3) / 2))
    pts = {tuple(m): net[p] for p, m in enumerate(bz.index_table(degree))}
    for d in range(degree, 0, -1):
        pts = {(i, j, k): bary[0] * pts[(i + 1, j, k)] + bary[1] * pts[(i, j + 1, k)]
               + bary[2] * pts[(i, j, k + 1)] for i, j, k in bz.index_table(d - 1)}
    return pts[(0, 0, 0)]


def test_evaluate_matches_direct_de_casteljau():
    rng = np.random.default_rng(1)
    nets = rng.normal(size=(3, 28, 3))
    bary = rng.dirichlet([1, 1, 1], size=7)
    got = bz.evaluate(nets, bary)
    want = np.array([[_casteljau(net, b) for b in bary] for net in nets])
    assert np.abs(got - want).max() < 1e-13


def test_evaluate_matches_bezier_package():
    bezier = pytest.importorskip("bezier")
    rng = np.random.default_rng(2)
    net = rng.normal(size=(28, 3))
    # bezier orders nodes by k, then j ("left to right, bottom to top")
    order = sorted(range(28), key=lambda p: (bz.index_table()[p][2], bz.index_table()[p][1]))
    triangle = bezier.Triangle(np.asfortranarray(net[order].T), degree=6)
    bary = rng.dirichlet([1, 1, 1], size=9)
    want = triangle.evaluate_barycentric_multi(np.asfortranarray(bary)).T
    assert np.abs(bz.evaluate(net[None], bary)[0] - want).max() < 1e-13


def test_normals_are_unit_cross_products_of_finite_differences():
    rng = np.random.default_rng(3)
    nets = rng.normal(size=(2, 28, 3))
    bary = np.array([[0.2, 0.3, 0.5], [0.6, 0.2, 0.2]])
    step = 1e-6
    du = (bz.evaluate(nets, bary + [-step, step, 0]) - bz.evaluate(nets, bary - [-step, step, 0]))
    dv = (bz.evaluate(nets, bary + [-step, 0, step]) - bz.evaluate(nets, bary - [-step, 0, step]))
    want = np.cross(du, dv)
    want /= np.linalg.norm(want, axis=-1, keepdims=True)
    # central differences: error O(step^2 * |P'''|) ~ 1e-10 relative
    assert np.abs(bz.normals(nets, bary) - want).max() < 1e-7


def test_subdivide_children_reparametrise_the_parent():
    rng = np.random.default_rng(4)
    nets = rng.normal(size=(3, 28, 3))
    children = bz.subdivide(nets).reshape(3, 4, 28, 3)
    local = rng.dirichlet([1, 1, 1], size=6)
    for c, corners in enumerate(lp.CHILD_CORNERS):
        parent_bary = local @ corners
        assert np.abs(bz.evaluate(children[:, c], local) - bz.evaluate(nets, parent_bary)).max() \
            < 1e-13


def test_degree_elevation_keeps_the_polynomial():
    rng = np.random.default_rng(5)
    quartic = rng.normal(size=(2, 15, 3))
    sextic = bz.elevate(quartic)
    bary = rng.dirichlet([1, 1, 1], size=8)
    want = np.einsum("sn,pnd->psd", bz.bernstein_matrix(bary, 4), quartic)
    assert np.abs(bz.evaluate(sextic, bary) - want).max() < 1e-13


# ----------------------------------------------------------------------------- G1
@pytest.mark.parametrize("name", list(MESHES))
def test_g1_along_every_interior_edge(surfaces, name):
    (vertices, _), surface = surfaces[name]
    gap, angle = bz.edge_continuity(surface.control_points, surface.domain_mesh[1], samples=9)
    assert gap <= 1e-12 * _size(vertices)
    assert angle <= 1e-9


@pytest.mark.parametrize("name", list(MESHES))
def test_patches_share_one_tangent_plane_at_every_vertex(surfaces, name):
    _, surface = surfaces[name]
    tris = surface.domain_mesh[1]
    corner = bz.corner_normals(surface.control_points).reshape(-1, 3)
    vertex = tris.ravel()
    first = np.zeros((tris.max() + 1, 3))
    first[vertex[::-1]] = corner[::-1]  # normal of one patch per vertex
    assert np.all(np.linalg.norm(corner, axis=1) > 0.99)
    assert _angle(corner, first[vertex]).max() <= 1e-9


def test_edge_continuity_kernel_equals_the_dense_evaluation():
    """The sparse numba kernel against the dense (P, 28, 3) evaluation of both sides, on
    nets moved off G1 (random kinks and gaps) so the figures are far from zero."""
    rng = np.random.default_rng(3)
    surface = bz.control_net(*icosphere(2))
    cp = surface.control_points + rng.normal(0.0, 1e-3, surface.control_points.shape)
    tris = surface.domain_mesh[1]
    h1, h2 = bz._edge_pairs(tris)
    t = np.linspace(0.0, 1.0, 7)
    p1, n1 = bz._edge_samples(cp, h1, t)
    p2, n2 = bz._edge_samples(cp, h2, 1.0 - t)
    gap = np.linalg.norm(p1 - p2, axis=-1).max()
    angle = _angle(n1.reshape(-1, 3), n2.reshape(-1, 3)).max()
    got_gap, got_angle = bz.edge_continuity(cp, tris, samples=7)
    assert gap > 1e-4 and angle > 1e-3  # the perturbation broke G1 everywhere
    assert abs(got_gap - gap) <= 1e-12 * gap
    assert abs(got_angle - angle) <= 1e-9 * angle


def random_hull(seed: int):
    """Convex hull of random points on an ellipsoid: valences 3..11, sliver triangles."""
    from scipy.spatial import ConvexHull

    rng = np.random.default_rng(seed)
    points = rng.normal(size=(int(rng.integers(60, 200)), 3))
    points = points / np.linalg.norm(points, axis=1, keepdims=True) * rng.uniform(0.5, 2, 3)
    tris = ConvexHull(points).simplices.astype(np.int64)
    corner = points[tris]
    normal = np.cross(corner[:, 1] - corner[:, 0], corner[:, 2] - corner[:, 0])
    inward = np.sum(normal * points[tris].mean(axis=1), axis=1) < 0
    tris[inward] = tris[inward][:, ::-1]
    return points, tris


@pytest.mark.parametrize("seed", [0, 8, 15])
def test_g1_on_random_convex_hulls(seed):
    vertices, tris = random_hull(seed)
    surface = bz.control_net(vertices, tris)
    gap, angle = bz.edge_continuity(surface.control_points, surface.domain_mesh[1], samples=9)
    assert gap <= 1e-12 * _size(vertices)
    assert angle <= 1e-9


def test_band_mesh_has_valences_4_6_8():
    n = 6
    vertices, tris = band_mesh(n=n, sections=6)
    valence = np.bincount(tris.ravel())
    inner = valence[n:-2 - 2 * n]  # without the end sections and the poles
    assert set(inner) == {4, 6, 8}


# ----------------------------------------------------------------------------- regular reproduction
def test_box_spline_masks_rederive_from_loop_subdivision():
    assert np.abs(lp.derive_box_spline_quartic() - lp.BOX_SPLINE_QUARTIC).max() < 1e-13


def _loop_limit(vertices, triangles):
    """Loop's limit-position mask, written independently of the module."""
    n = np.bincount(triangles.ravel(), minlength=len(vertices))
    ring = np.zeros_like(vertices)
    edges = np.unique(np.sort(triangles[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1), axis=0)
    np.add.at(ring, edges[:, 0], vertices[edges[:, 1]])
    np.add.at(ring, edges[:, 1], vertices[edges[:, 0]])
    beta = (5 / 8 - (3 / 8 + np.cos(2 * np.pi / n) / 4) ** 2) / n
    chi = 1 / (3 / (8 * beta) + n)
    return (1 - n * chi)[:, None] * vertices + chi[:, None] * ring


def box():
    """open3d's box: 12 triangles, valences 3 and 6 only."""
    return _o3d_arrays(o3d.geometry.TriangleMesh.create_box())


@pytest.mark.parametrize("mesh, subdivider", [(box, "open3d"), (icosphere, "own")])
def test_regular_patches_are_the_loop_limit_surface(mesh, subdivider):
    """Where the 1-ring is regular the patch equals the Loop limit surface.

    The domain mesh is Loop-subdivided twice more; Loop's limit mask then gives
    exact limit points at the dyadic parameters (i, j, k) / 4 of every patch,
    which must lie on the regular patches to rounding.  With "open3d" the
    subdivision is open3d's ``subdivide_loop`` (Warren's weights, equal to
    Loop's for the valences 3 and 6 of the box), matched to our tracked
    subdivision by position; with "own" it is this package's.
    """
    vertices, tris = mesh()
    surface = bz.control_net(vertices, tris)
    dom_v, dom_t = surface.domain_mesh
    steps = 2
    mine_v, mine_t, root, bary = lp.subdivide_tracked(dom_v, dom_t, steps)
    if subdivider == "open3d":
        fine = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(dom_v),
                                         o3d.utility.Vector3iVector(dom_t)).subdivide_loop(steps)
        fine_v, fine_t = _o3d_arrays(fine)
        dist, match = cKDTree(fine_v).query(mine_v)
        assert dist.max() < 1e-14
    else:
        fine_v, fine_t, match = mine_v, mine_t, np.arange(len(mine_v))
    limit = _loop_limit(fine_v, fine_t)
    valence = np.bincount(dom_t.ravel())
    regular = np.all(valence[dom_t] == 6, axis=1)
    assert regular.sum() >= len(dom_t) // 4
    faces = np.flatnonzero(regular[root])
    corner_bary = bary[faces].reshape(-1, 3)
    corner_vertex = match[mine_t[faces].ravel()]
    patch = np.repeat(root[faces], 3)
    got = np.einsum("sn,snd->sd", bz.bernstein_matrix(corner_bary),
                    surface.control_points[patch])
    assert np.abs(got - limit[corner_vertex]).max() < 1e-12 * _size(vertices)


def test_regular_patches_are_degree_elevated_quartics(surfaces):
    (vertices, _), surface = surfaces["icosphere"]
    tris = surface.domain_mesh[1]
    regular = np.all(np.bincount(tris.ravel())[tris] == 6, axis=1)
    elevation = bz.elevate(np.eye(15), 6)  # (28, 15): the net of each quartic basis function
    nets = surface.control_points[regular]
    quartic = np.linalg.lstsq(elevation, nets.transpose(1, 0, 2).reshape(28, -1), rcond=None)[0]
    again = (elevation @ quartic).reshape(28, -1, 3).transpose(1, 0, 2)
    assert np.abs(again - nets).max() < 1e-13 * _size(vertices)
    # and that quartic is the box spline's: the corner is Loop's limit point
    limit = _loop_limit(*surface.domain_mesh)
    assert np.abs(nets[:, 0] - limit[tris[regular, 0]]).max() < 1e-13 * _size(vertices)


# ----------------------------------------------------------------------------- invariance
@settings(max_examples=15, deadline=None)
@given(st.lists(st.floats(-2, 2), min_size=12, max_size=12))
def test_affine_map_of_the_control_mesh_maps_the_surface(values):
    matrix = np.array(values[:9]).reshape(3, 3) + 3 * np.eye(3)  # keep it invertible
    shift = np.array(values[9:])
    vertices, tris = octahedron()
    base = bz.control_net(vertices, tris).control_points
    mapped = bz.control_net(vertices @ matrix.T + shift, tris).control_points
    scale = np.abs(base @ matrix.T + shift).max()
    assert np.abs(mapped - (base @ matrix.T + shift)).max() < 1e-12 * scale


def test_flattened_mesh_gives_a_surface_in_the_same_plane():
    """A control mesh in a plane gives a planar surface (as a squashed sphere:
    the construction is coordinate-wise, so z = 0 stays exactly 0)."""
    vertices, tris = icosphere(1)
    squashed = vertices * [1.0, 1.0, 1e-3] + [0.0, 0.0, 5.0]
    cp = bz.control_net(squashed, tris).control_points
    assert np.abs(cp[..., 2] - 5.0).max() <= 1e-3 * 1.0001
    z_scaled = bz.control_net(vertices * [1, 1, 0.5], tris).control_points
    full = bz.control_net(vertices, tris).control_points
    assert np.abs(z_scaled[..., 2] - 0.5 * full[..., 2]).max() < 1e-14


# ----------------------------------------------------------------------------- tessellation
@pytest.mark.parametrize("level", [0, 1, 3])
def test_tessellation_is_watertight_and_consistently_oriented(surfaces, level):
    _, surface = surfaces["band"]
    vertices, triangles, vertex_normals = bz.tessellate(surface, level)
    assert len(triangles) == len(surface.control_points) * 4 ** level
    directed = triangles[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    keys = directed[:, 0] * len(vertices) + directed[:, 1]
    assert len(np.unique(keys)) == len(keys)  # every directed edge once: oriented
    twin = directed[:, 1] * len(vertices) + directed[:, 0]
    assert np.all(np.isin(twin, keys))  # every edge in exactly two triangles: watertight
    assert len(vertices) - len(keys) // 2 + len(triangles) == 2  # sphere topology
    assert np.allclose(np.linalg.norm(vertex_normals, axis=1), 1.0)


def test_tessellated_vertices_lie_on_the_patches(surfaces):
    (control_vertices, _), surface = surfaces["cube"]
    level = 2
    vertices, triangles, vertex_normals = bz.tessellate(surface, level)
    bary, local_tris, _ = bz._grid(2 ** level)
    per_patch = triangles.reshape(len(surface.control_points), -1, 3)
    sample_vertex = np.empty((len(per_patch), len(bary)), dtype=np.int64)
    sample_vertex[:, local_tris.ravel()] = per_patch.reshape(len(per_patch), -1)
    points = bz.evaluate(surface.control_points, bary)
    assert np.abs(vertices[sample_vertex] - points).max() < 1e-12 * _size(control_vertices)
    patch_normals = bz.normals(surface.control_points, bary)
    assert _angle(vertex_normals[sample_vertex], patch_normals).max() < 1e-9


def test_tessellation_faces_outward_on_a_sphere(surfaces):
    _, surface = surfaces["icosphere"]
    vertices, triangles, vertex_normals = bz.tessellate(surface, 2)
    assert np.all(np.sum(vertices * vertex_normals, axis=1) > 0.9 * np.linalg.norm(vertices,
                                                                                   axis=1))
    corner = vertices[triangles]
    face_normal = np.cross(corner[:, 1] - corner[:, 0], corner[:, 2] - corner[:, 0])
    assert np.all(np.sum(face_normal * corner.mean(axis=1), axis=1) > 0)


def test_tessellate_needs_the_domain_triangles(surfaces):
    _, surface = surfaces["octahedron"]
    with pytest.raises(ValueError, match="domain triangles"):
        bz.tessellate(surface.control_points, 1)


# ----------------------------------------------------------------------------- bad input
def planar_disk(seed: int = 0, n: int = 60):
    """A random Delaunay triangulation of the square, in the plane z = 0."""
    from scipy.spatial import Delaunay

    rng = np.random.default_rng(seed)
    points = rng.uniform(-1, 1, size=(n, 2))
    tris = Delaunay(points).simplices.astype(np.int64)
    a, b, c = (points[tris[:, i]] for i in range(3))
    clockwise = (b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0] < 0
    tris[clockwise] = tris[clockwise][:, ::-1]
    return np.c_[points, np.zeros(n)], tris


def open_meshes():
    sphere_v, sphere_t = icosphere(2)
    hemisphere = (sphere_v, sphere_t[np.all(sphere_v[sphere_t][:, :, 2] > -0.1, axis=1)])
    band_v, band_t = band_mesh()
    tube = (band_v, band_t[np.all(band_t < len(band_v) - 2, axis=1)])  # poles removed
    return {"hemisphere": hemisphere, "tube": tube, "disk": planar_disk(),
            "triangle": (np.eye(3), np.array([[0, 1, 2]]))}


@pytest.mark.parametrize("name", ["hemisphere", "tube", "disk", "triangle"])
def test_bordered_meshes_are_g1_across_interior_edges(name):
    vertices, tris = open_meshes()[name]
    surface = bz.control_net(vertices, tris)
    assert len(surface.control_points) == 4 * len(tris)
    assert np.all(np.isfinite(surface.control_points))
    gap, angle = bz.edge_continuity(surface.control_points, surface.domain_mesh[1])
    assert gap <= 1e-12 * _size(vertices)
    assert angle <= 1e-9


def hex_disk(radius: int = 4, jitter: float = 0.0, seed: int = 0, shape: str = "hexagon"):
    """A hexagon (or triangle) of the regular triangular grid in the plane z = 0.

    Hexagon corners have two triangles, triangle corners one; ``jitter``
    moves the points uniformly by up to that much.
    """
    ids, points, tris = {}, [], []
    for q in range(-radius, radius + 1):
        for r in range(-radius, radius + 1):
            inside = abs(q + r) <= radius if shape == "hexagon" else q >= 0 and r >= 0 \
                and q + r <= radius
            if inside:
                ids[(q, r)] = len(points)
                points.append((q + 0.5 * r, r * np.sqrt(3) / 2))
    for q in range(-radius - 1, radius + 1):
        for r in range(-radius - 1, radius + 1):
            for tri in (((q, r), (q + 1, r), (q, r + 1)),
                        ((q + 1, r), (q + 1, r + 1), (q, r + 1))):
                if all(x in ids for x in tri):
                    tris.append([ids[x] for x in tri])
    points = np.array(points) + np.random.default_rng(seed).uniform(-jitter, jitter,
                                                                    (len(points), 2))
    return np.c_[points, np.zeros(len(points))], np.array(tris, dtype=np.int64)


@settings(max_examples=10, deadline=None)
@given(st.lists(st.floats(-2, 2), min_size=12, max_size=12), st.integers(0, 5))
def test_planar_control_mesh_gives_a_planar_surface(values, seed):
    """Any plane, any (even badly shaped) triangulation: ghosts and patches are
    affine combinations of points of the plane."""
    vertices, tris = planar_disk(seed)
    frame = np.array(values[:9]).reshape(3, 3) + 3 * np.eye(3)
    plane = vertices @ frame.T + np.array(values[9:])
    normal = np.cross(frame[:, 0], frame[:, 1])
    normal /= np.linalg.norm(normal)
    surface = bz.control_net(plane, tris)
    offset = (surface.control_points - np.array(values[9:])) @ normal
    assert np.abs(offset).max() < 1e-12 * _size(plane)


@pytest.mark.parametrize("jitter", [0.0, 0.15])
def test_planar_grid_surface_keeps_its_orientation(jitter):
    """On a (jittered) grid disk the flat surface does not fold: every normal is +z."""
    vertices, tris = hex_disk(4, jitter)
    surface = bz.control_net(vertices, tris)
    bary, _, _ = bz._grid(4)
    assert bz.normals(surface.control_points, bary)[..., 2].min() > 1 - 1e-12


def test_border_tessellation_is_consistent_and_open():
    vertices, tris = open_meshes()["tube"]
    surface = bz.control_net(vertices, tris)
    tess_v, tess_t, _ = bz.tessellate(surface, 2)
    directed = tess_t[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    keys = directed[:, 0] * len(tess_v) + directed[:, 1]
    assert len(np.unique(keys)) == len(keys)
    border = ~np.isin(directed[:, 1] * len(tess_v) + directed[:, 0], keys)
    # the removed caps leave border loops of 6 and 12 control edges; refinement
    # halves each, level 2 cuts each half in 4
    assert border.sum() == 2 * 4 * (6 + 12)


def test_rejects_inconsistent_orientation():
    vertices, tris = octahedron()
    tris = tris.copy()
    tris[0] = tris[0, ::-1]
    with pytest.raises(ValueError, match="oriented"):
        bz.control_net(vertices, tris)


def test_rejects_non_manifold_edges():
    vertices, tris = octahedron()
    extra = np.vstack([vertices, [[3.0, 3.0, 3.0]]])
    a, b = tris[0, 0], tris[0, 1]
    with pytest.raises(ValueError, match="non-manifold"):
        bz.control_net(extra, np.vstack([tris, [[b, a, len(vertices)]]]))


def test_rejects_bow_tie_vertices():
    v1, t1 = octahedron()
    v2 = v1 + [3.0, 0.0, 0.0]
    t2 = t1 + len(v1)
    t2[t2 == len(v1)] = 0  # glue one vertex of the second octahedron onto the first
    with pytest.raises(ValueError, match="non-manifold at"):
        bz.control_net(np.vstack([v1, v2]), np.vstack([t1, t2]))


def test_rejects_zero_area_triangles():
    vertices, tris = octahedron()
    vertices = vertices.copy()
    vertices[tris[0, 2]] = 0.5 * (vertices[tris[0, 0]] + vertices[tris[0, 1]])
    with pytest.raises(ValueError, match="zero-area"):
        bz.control_net(vertices, tris)


def test_rejects_nan_and_bad_indices():
    vertices, tris = octahedron()
    with pytest.raises(ValueError, match="NaN"):
        bz.control_net(np.where(np.arange(len(vertices))[:, None] == 0, np.nan, vertices), tris)
    with pytest.raises(ValueError, match="outside"):
        bz.control_net(vertices, tris + 1)
    with pytest.raises(ValueError, match="shape"):
        bz.control_net(vertices[:, :2], tris)


def test_isolated_vertices_are_ignored():
    vertices, tris = octahedron()
    extra = np.vstack([[9.0, 9.0, 9.0], vertices])
    with_isolated = bz.control_net(extra, tris + 1)
    plain = bz.control_net(vertices, tris)
    assert np.array_equal(with_isolated.control_points, plain.control_points)
    assert np.all(np.isfinite(with_isolated.control_points))


def test_source_face_maps_patches_to_control_faces(surfaces):
    (vertices, tris), surface = surfaces["band"]
    assert np.array_equal(np.bincount(surface.source_face), np.full(len(tris), 4))
    # each patch lies near its source face: its centre is closer to that face's
    # centroid than the face's own circumradius-scale
    centre = bz.evaluate(surface.control_points, np.full((1, 3), 1 / 3))[:, 0]
    centroid = vertices[tris].mean(axis=1)[surface.source_face]
    edge = np.linalg.norm(vertices[tris[:, 0]] - vertices[tris[:, 1]], axis=1).max()
    assert np.linalg.norm(centre - centroid, axis=1).max() < edge


# ----------------------------------------------------------------------------- ring operator
@pytest.mark.parametrize("n", [3, 4, 5, 7, 8, 12])
def test_fourier_ring_solve_equals_the_dense_minimum_norm_solve(n):
    assert np.abs(lp.ring_operator(n) - lp.ring_operator_dense(n)).max() < 1e-11


def test_ring_operators_kept_on_disk_are_the_ones_built(monkeypatch, tmp_path):
    """ring_operator keeps each valence's operator on disk (built once per code version);
    what it reads back is the operator bit for bit, and a damaged file is built anew."""
    monkeypatch.setattr(lp, "OPERATOR_CACHE", tmp_path)
    stale = tmp_path / "ring_operator.0000000000000000.5.npy"   # an older code's
    np.save(stale, np.zeros((140, 92)))
    lp.ring_operator.cache_clear()
    built = lp.ring_operator(5)
    (stored,) = tmp_path.glob("ring_operator.*.5.npy")
    assert stored != stale and not stale.exists()
    np.testing.assert_array_equal(built, lp.ring_operator_fft(5))
    lp.ring_operator.cache_clear()
    np.testing.assert_array_equal(lp.ring_operator(5), built)
    stored.write_bytes(b"not an array")
    lp.ring_operator.cache_clear()
    np.testing.assert_array_equal(lp.ring_operator(5), built)
    assert not lp.ring_operator(5).flags.writeable
    lp.ring_operator.cache_clear()


@pytest.mark.parametrize("n", [3, 4, 5, 7, 8, 9, 16])
def test_ring_operator_meets_every_constraint_for_any_data(n):
    """Spoke sharing and G1 rows hold for arbitrary data, except the one row per
    spoke that involves data only (G1 at the regular end, t = 1), which the
    box-spline neighbours satisfy by construction."""
    operator = lp.ring_operator(n)
    rows = np.concatenate([np.concatenate([lp._spoke_share_rows(n, i), lp._spoke_g1_rows(n, i)])
                           for i in range(n)])
    data = np.random.default_rng(n).normal(size=(operator.shape[1], 3))
    residual = (rows @ operator @ data).reshape(n, 11, 3)
    assert np.abs(residual[:, :10]).max() < 1e-10
    assert np.allclose(operator.sum(axis=1), 1.0, atol=1e-12)  # affine invariance


# ----------------------------------------------------------------------------- a-priori level
PROBES = np.array([[1, 1, 1], [2, 1, 1], [1, 2, 1], [1, 1, 2], [1, 1, 0], [0, 1, 1],
                   [1, 0, 1]]) / np.array([[3], [4], [4], [4], [2], [2], [2]])


def _chord_error(nets):
    """Observed distance patch <-> flat corner triangle at centroids and edge midpoints."""
    flat = np.einsum("sc,pcd->psd", PROBES, nets[:, [0, 21, 27]])  # corners b600, b060, b006
    return np.linalg.norm(bz.evaluate(nets, PROBES) - flat, axis=-1).max(axis=1)


@pytest.mark.parametrize("name", ["icosphere", "cube"])
def test_chord_error_bound_holds_and_the_chosen_level_meets_the_tolerance(surfaces, name):
    (vertices, _), surface = surfaces[name]
    cp = surface.control_points
    tolerance = 1e-3 * _size(vertices)
    level = bz.tessellation_level(cp, tolerance)
    assert 0 < level <= 8
    coarser, sub = None, cp
    for _ in range(level):
        coarser, sub = sub, bz.subdivide(sub)
    bound = bz.chord_error_bound(sub)
    observed = _chord_error(sub)
    assert np.all(observed <= bound * (1 + 1e-12))
    assert bound.max() <= tolerance
    assert observed.max() > bound.max() / 10  # tight, not vacuous
    assert bz.chord_error_bound(coarser).max() > tolerance  # one level less would not do


def test_second_difference_fallback_is_rigorous_and_coarser(surfaces, monkeypatch):
    (vertices, _), surface = surfaces["octahedron"]
    cp = surface.control_points
    tolerance = 1e-3 * _size(vertices)
    exact = bz.tessellation_level(cp, tolerance)
    monkeypatch.setattr(bezier_tessellation, "_LEVEL_BUDGET", 1)  # fall back at once
    fallback = bz.tessellation_level(cp, tolerance)
    assert fallback >= exact
    sub = cp
    for _ in range(fallback):
        sub = bz.subdivide(sub)
    assert _chord_error(sub).max() <= tolerance
    with pytest.raises(ValueError, match="tolerance"):
        bz.tessellation_level(cp, 0.0)


def test_tessellation_in_chunks_equals_one_pass(surfaces, monkeypatch):
    _, surface = surfaces["band"]
    whole = bz.tessellate(surface, 2)
    monkeypatch.setattr(bezier_tessellation, "_CHUNK_ROWS", 100)  # 6 patches per chunk
    chunked = bz.tessellate(surface, 2)
    assert np.array_equal(whole[1], chunked[1])  # same triangles, same vertex ids
    # same points up to the GEMM's blocking (rounding only)
    assert np.abs(whole[0] - chunked[0]).max() < 1e-13 * _size(whole[0])
    assert _angle(whole[2], chunked[2]).max() < 1e-9  # normals: cancellation in P_u x P_v


def test_ring_construction_returns_the_box_spline_at_a_regular_vertex():
    """Pushing a valence-6 vertex through the irregular-vertex path (gathering,
    Loop-limit template, G1 solve) must give back the box-spline patches."""
    vertices, tris = icosphere(2)
    surface = bz.control_net(vertices, tris)
    dom_v, dom_t = surface.domain_mesh
    mesh = lp.build_half_edges(len(dom_v), dom_t)
    inner6 = mesh.valence == 6
    regular = np.all(inner6[dom_t], axis=1)
    # a valence-6 vertex whose 2-ring is regular: all faces touching its ring are regular
    ring_ok = np.ones(len(dom_v), dtype=bool)
    np.logical_and.at(ring_ok, dom_t.ravel(), np.repeat(regular, 3))
    neighbour_ok = ring_ok.copy()
    np.logical_and.at(neighbour_ok, mesh.origin, ring_ok[mesh.dest])
    centre = np.flatnonzero(inner6 & neighbour_ok)[:3]
    assert len(centre) == 3
    nets = np.zeros((len(dom_t), 28, 3))
    quartic, nets[regular] = lp.regular_patches(mesh, dom_v, np.flatnonzero(regular))
    quartic_row = np.full(len(dom_t), -1)
    quartic_row[regular] = np.arange(int(regular.sum()))
    rebuilt = nets.copy()
    around = np.any(np.isin(dom_t, centre), axis=1)
    rebuilt[around] = 0.0  # forget the ring patches; the ring path must rebuild them
    limit = lp.limit_positions(mesh, dom_v)
    lp._irregular_patches(mesh, dom_v, limit, quartic, quartic_row, rebuilt, centre)
    assert around.sum() == 18
    assert np.abs(rebuilt - nets).max() < 1e-12 * _size(vertices)


@pytest.mark.parametrize("name, limit", [("cube", 0.01), ("icosphere", 0.005)])
def test_irregular_patches_stay_close_to_the_loop_limit(surfaces, name, limit):
    """Near irregular vertices the patches are the G1-constrained least-squares
    fit to Loop's limit surface: within a small fraction of the control edge
    (measured 0.6 % on the cube, 0.2 % on the icosphere)."""
    (vertices, tris), surface = surfaces[name]
    dom_v, dom_t = surface.domain_mesh
    fine_v, fine_t, root, bary = lp.subdivide_tracked(dom_v, dom_t, 2)
    exact = _loop_limit(fine_v, fine_t)[fine_t.ravel()]
    got = np.einsum("sn,snd->sd", bz.bernstein_matrix(bary.reshape(-1, 3)),
                    surface.control_points[np.repeat(root, 3)])
    edge = np.linalg.norm(vertices[tris[:, 0]] - vertices[tris[:, 1]], axis=1).mean()
    assert np.linalg.norm(got - exact, axis=1).max() < limit * edge


@pytest.mark.parametrize("shape, corner", [("hexagon", 2), ("triangle", 1)])
def test_border_rule_continues_a_regular_grid_exactly(shape, corner):
    """On a flat regular grid the ghosts (corners included) continue the
    lattice, so by linear precision every patch is its flat domain triangle."""
    vertices, tris = hex_disk(3, shape=shape)
    assert np.bincount(np.bincount(tris.ravel()))[corner] > 0  # corners with 2 or 1 triangles
    surface = bz.control_net(vertices, tris)
    dom_v, dom_t = surface.domain_mesh
    bary = np.random.default_rng(7).dirichlet([1, 1, 1], size=12)
    want = np.einsum("sc,pcd->psd", bary, dom_v[dom_t])
    assert np.abs(bz.evaluate(surface.control_points, bary) - want).max() < 1e-12


def test_large_outputs_are_plain_writable_arrays(monkeypatch):
    """_empty_pages maps big arrays itself; they behave as np.empty's (and outlive views)."""
    monkeypatch.setattr(bezier_patch, "_PAGES_MIN_BYTES", 1024)
    big = bezier_patch._empty_pages((100, 28, 3))
    small = bezier_patch._empty_pages((2, 3), np.int64)
    assert big.shape == (100, 28, 3) and big.dtype == np.float64 and big.flags.writeable
    assert small.dtype == np.int64 and small.flags.owndata  # below the threshold: np.empty
    big[:] = 2.0
    view = big[10:20]
    del big
    assert np.all(view == 2.0)
    surface = bz.control_net(*icosphere(1))
    whole = bz.tessellate(surface, 1)
    monkeypatch.setattr(bezier_patch, "_PAGES_MIN_BYTES", 2 ** 40)
    again = bz.tessellate(surface, 1)
    assert all(np.array_equal(x, y) for x, y in zip(whole, again, strict=True))


@pytest.mark.parametrize("level", [0, 2])
def test_tessellation_closes_gaps_in_the_domain_vertex_ids(surfaces, level, monkeypatch):
    """Unused domain vertex ids are skipped (ids made a chunk at a time, as one pass)."""
    _, surface = surfaces["icosphere"]
    cp, tris = surface.control_points, surface.domain_mesh[1]
    dense = bz.tessellate(cp, level, tris)
    monkeypatch.setattr(bezier_tessellation, "_CHUNK_ROWS", 50)  # several chunks
    gapped = bz.tessellate(cp, level, 2 * tris + 5)  # same order, ids with gaps
    assert np.array_equal(dense[1], gapped[1])
    # the chunked GEMM may round differently (see test_tessellation_in_chunks_equals_one_pass)
    assert np.abs(dense[0] - gapped[0]).max() < 1e-13 * _size(dense[0])
    assert _angle(dense[2], gapped[2]).max() < 1e-9


def test_shared_boundary_control_points_are_bit_identical():
    # Neighbouring patches are built from different stencils; control_net makes the
    # copies of every shared boundary control point one value (control_point_ids).
    mesh = o3d.geometry.TriangleMesh.create_sphere(1.0, 10)
    surface = bz.control_net(np.asarray(mesh.vertices), np.asarray(mesh.triangles))
    ids, count = bz.control_point_ids(surface.domain_mesh[1])
    flat, flat_ids = surface.control_points.reshape(-1, 3), ids.ravel()
    first = np.full(count, -1)
    first[flat_ids[::-1]] = np.arange(len(flat_ids))[::-1]
    assert flat[first[flat_ids]].tobytes() == flat.tobytes()
    # each interior id belongs to one patch, an edge id to two, a corner to its fan
    uses = np.bincount(flat_ids, minlength=count)
    n_vertices = len(surface.domain_mesh[0])
    assert np.all(uses[n_vertices:count - 10 * len(ids)] == 2)
    assert np.all(uses[count - 10 * len(ids):] == 1)


@pytest.mark.parametrize("tolerance", [3e-3, 5e-4])
def test_adaptive_tessellation_is_watertight_and_within_tolerance(tolerance):
    # an ellipsoid's patches need different cuts (curvature 0.4 .. 6): neighbours with
    # different counts meet through transitions; the mesh must stay closed and manifold
    # and every point of the exact surface within the tolerance of it (the cuts are
    # certified piece by piece on the uniform grid; measured here everywhere)
    from surface.metrics import mesh_topology, point_mesh_distance

    mesh = o3d.geometry.TriangleMesh.create_sphere(1.0, 6)
    surface = bz.control_net(np.asarray(mesh.vertices) * [1.0, 0.6, 0.4],
                             np.asarray(mesh.triangles))
    v, t, n = bz.tessellate_adaptive(surface, tolerance)
    segments = bz.certified_segments(surface.control_points, tolerance)
    assert segments.min() < segments.max()  # not one uniform level
    assert len(t) >= (segments ** 2).sum()  # transitions only add triangles
    # the parametric bound would cut more: the certified cuts are never finer than it
    # needs (on this ellipsoid they are coarser on most patches)
    bound = bz.adaptive_segments(surface.control_points, tolerance)
    assert np.mean(segments < bound) > 0.5
    topo = mesh_topology(v, t)
    assert topo["closed"] and topo["oriented"] and topo["nonmanifold_edges"] == 0
    assert topo["components"] == 1
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-12)
    rng = np.random.default_rng(2)
    exact = bz.evaluate(surface.control_points, rng.dirichlet(np.ones(3), size=12))
    distance = point_mesh_distance(exact.reshape(-1, 3), v, t)
    assert distance.max() <= tolerance
    # the vertices lie on the surface (each evaluated exactly on one patch)
    corners = bz.evaluate(surface.control_points, np.eye(3))  # (P, 3, 3)
    assert point_mesh_distance(corners.reshape(-1, 3), v, t).max() < 1e-6  # float32 inside


def test_plane_deviation_bounds_the_distance_across_the_corners_plane():
    # a flat net (its points at the Greville abscissae of a tilted triangle), one inner
    # point lifted by h along the normal and others slid within the plane: the bound is
    # h exactly (sliding moves nothing across), and the patch stays within it
    rng = np.random.default_rng(5)
    corners = rng.normal(size=(3, 3))
    normal = np.cross(corners[1] - corners[0], corners[2] - corners[0])
    normal /= np.linalg.norm(normal)
    net = (bz.index_table() / 6.0) @ corners
    net[4] += 0.5 * (corners[1] - corners[0])  # along the plane
    net[12] += 0.3 * normal  # across it
    bound = bz.plane_deviation(net[None])[0]
    assert bound == pytest.approx(0.3, rel=1e-12)
    assert bz.chord_error_bound(net[None])[0] > bound  # counts the slide too
    bary = rng.dirichlet([1.0, 1.0, 1.0], size=500)
    across = np.abs((bz.evaluate(net[None], bary)[0] - corners[0]) @ normal)
    assert across.max() <= bound and across.max() > 0.05 * bound


# ----------------------------------------------------------------------------- closest points


@pytest.mark.parametrize("mesh", [lambda: _o3d_arrays(o3d.geometry.TriangleMesh.create_sphere(
    1.0, 8)), lambda: icosphere(2)], ids=["uv-sphere", "icosphere"])
def test_closest_points_find_the_foot_on_the_exact_surface(mesh):
    """Points put at known distances ``d`` along the exact normal of random surface points
    (|d| <= 0.01, far below the surfaces' radii of curvature; not a cube's Loop surface,
    whose curvature is unbounded at its valence-3 corners) are measured at
    ``|d|`` to 3e-6 (the patch polynomial continued past an edge leaves the neighbour by
    up to ~1e-6 at the sphere's valence-8 poles), where the level-1 tessellation errs by
    about 1e-3 (300x the tolerance) -- what the sizing measured before."""
    from surface.metrics import point_mesh_distance

    surface = bz.control_net(*mesh())
    rng = np.random.default_rng(3)
    patch = rng.integers(0, len(surface.control_points), 1500)
    bary = rng.dirichlet([1.0, 1.0, 1.0], 1500)
    nets = surface.control_points[patch]
    on = np.einsum("nk,nkd->nd", bz.bernstein_matrix(bary), nets)
    normal = np.stack([bz.normals(nets[i:i + 1], bary[i:i + 1])[0, 0] for i in range(len(bary))])
    d = rng.uniform(-0.01, 0.01, len(bary))
    query = on + d[:, None] * normal
    distance, foot_patch, foot_bary = bz.closest_points(surface, query)
    np.testing.assert_allclose(distance, np.abs(d), rtol=0, atol=3e-6)
    foot = np.einsum("nk,nkd->nd", bz.bernstein_matrix(foot_bary),
                     surface.control_points[foot_patch])
    np.testing.assert_allclose(foot, on, rtol=0, atol=2e-5)
    flat = point_mesh_distance(query, *bz.tessellate(surface, 1)[:2])
    assert np.abs(flat - np.abs(d)).max() > 300 * 3e-6


def test_closest_points_of_points_on_the_surface_are_zero_and_checked():
    surface = bz.control_net(*icosphere(1))
    points = bz.evaluate(surface.control_points[:50], np.array([[0.2, 0.3, 0.5]]))[:, 0]
    distance, patch, _ = bz.closest_points(surface, points)
    assert distance.max() < 1e-9
    with pytest.raises(ValueError):
        bz.closest_points(surface, np.full((3, 3), np.nan))
