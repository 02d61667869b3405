"""Tests of surface.metrics against analytic answers."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from surface import metrics as M

# A cube [-1, 1]^3, 12 faces counter-clockwise seen from outside.
CUBE_V = np.array([[x, y, z] for x in (-1.0, 1.0) for y in (-1.0, 1.0) for z in (-1.0, 1.0)])
CUBE_F = np.array([
    [0, 1, 3], [0, 3, 2],   # x = -1
    [4, 6, 7], [4, 7, 5],   # x = +1
    [0, 4, 5], [0, 5, 1],   # y = -1
    [2, 3, 7], [2, 7, 6],   # y = +1
    [0, 2, 6], [0, 6, 4],   # z = -1
    [1, 5, 7], [1, 7, 3],   # z = +1
])


def square(z: float, n: int = 1, half: float = 1.0):
    """An (n x n)-cell square at height z, 2 n^2 triangles, normal +z."""
    g = np.linspace(-half, half, n + 1)
    x, y = np.meshgrid(g, g, indexing="ij")
    v = np.stack([x.ravel(), y.ravel(), np.full(x.size, z)], axis=1)
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    a = (i * (n + 1) + j).ravel()
    b, c, d = a + (n + 1), a + (n + 1) + 1, a + 1
    return v, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


def unit_sphere(resolution: int = 20):
    import open3d as o3d

    mesh = o3d.geometry.TriangleMesh.create_sphere(radius=1.0, resolution=resolution)
    return np.asarray(mesh.vertices), np.asarray(mesh.triangles, dtype=np.int64)


# ----------------------------------------------------------------------------- topology
def test_cube_topology_and_volume():
    topo = M.mesh_topology(CUBE_V, CUBE_F)
    assert topo["closed"] and topo["oriented"] and topo["edge_manifold"]
    assert topo["components"] == 1
    assert topo["euler"] == 2
    assert topo["edges"] == 18
    # Side 2: volume 8 exactly (sum of exact determinants of small integers).
    assert topo["signed_volume"] == pytest.approx(8.0, abs=1e-12)


def test_flipped_face_is_not_oriented_and_volume_changes_sign():
    bad = CUBE_F.copy()
    bad[0] = bad[0, ::-1]
    assert not M.mesh_topology(CUBE_V, bad)["oriented"]
    assert M.signed_volume(CUBE_V, CUBE_F[:, ::-1]) == pytest.approx(-8.0)


def test_removed_face_opens_three_edges():
    topo = M.mesh_topology(CUBE_V, CUBE_F[1:])
    assert not topo["closed"]
    assert topo["boundary_edges"] == 3
    assert topo["signed_volume"] is None
    assert topo["euler"] == 1  # a disc


def test_two_cubes_two_components_and_nonmanifold_edge():
    v = np.vstack([CUBE_V, CUBE_V + 5.0])
    f = np.vstack([CUBE_F, CUBE_F + 8])
    topo = M.mesh_topology(v, f)
    assert topo["components"] == 2 and topo["euler"] == 4 and topo["closed"]
    # Three faces on the edge (0, 1): not edge-manifold.
    fan = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]])
    topo = M.mesh_topology(CUBE_V, fan)
    assert topo["nonmanifold_edges"] == 1 and not topo["edge_manifold"] and not topo["closed"]


def test_edge_table_counts_and_interior_faces():
    table = M.edge_table(CUBE_F)
    assert np.all(table.counts == 2) and np.all(table.forward == 1)
    ids, faces, corners = table.edge_faces()
    assert len(ids) == 18
    # The two faces really share the edge they are listed for.
    for e, (f1, f2), (k1, k2) in zip(ids, faces, corners, strict=True):
        want = set(table.edges[e])
        assert {CUBE_F[f1, k1], CUBE_F[f1, (k1 + 1) % 3]} == want
        assert {CUBE_F[f2, k2], CUBE_F[f2, (k2 + 1) % 3]} == want


# ----------------------------------------------------------------------------- Delaunay, G1
def test_delaunay_fraction_rhombus():
    # Rhombus (+-1, 0), (0, +-0.5).  Short diagonal: opposite angles 2 atan(1/2) each,
    # sum 106.3 deg <= 180 (Delaunay); long diagonal: 2 atan(2) each, sum 253.7 deg.
    v = np.array([[-1.0, 0, 0], [1.0, 0, 0], [0, -0.5, 0], [0, 0.5, 0]])
    short = np.array([[2, 3, 0], [3, 2, 1]])
    long = np.array([[0, 1, 3], [1, 0, 2]])
    assert M.delaunay_fraction(v, short) == 1.0
    assert M.delaunay_fraction(v, long) == 0.0
    _, sums = M.opposite_angle_sums(v, long)
    assert sums[0] == pytest.approx(4 * np.arctan(2.0), abs=1e-12)


def test_g1_angle():
    a = np.array([[0, 0, 1.0], [0, 0, 2.0]])
    b = np.array([[0, 1.0, 1.0], [0, 0, 5.0]])
    assert M.g1_angle(a, b) == pytest.approx(np.pi / 4, abs=1e-12)
    assert M.g1_angle(np.zeros((0, 3)), np.zeros((0, 3))) == 0.0
    # A cube's faces meet at right angles (and its diagonal splits are flat).
    assert M.g1_angle(*M.interior_normal_pairs(CUBE_V, CUBE_F)) == pytest.approx(np.pi / 2)
    with pytest.raises(ValueError, match="same shape"):
        M.g1_angle(a, b[:1])


# ----------------------------------------------------------------------------- sampling
def test_sample_mesh_is_area_uniform():
    # A square of 2 x 8 x 8 triangles plus one triangle 4x larger than the square.
    v, f = square(0.0, n=8)
    big = np.array([[3.0, 0, 0], [7.0, 0, 0], [3.0, 2.0, 0]])  # area 4
    v = np.vstack([v, big])
    f = np.vstack([f, [[len(v) - 3, len(v) - 2, len(v) - 1]]])
    n = 50_000
    p = M.sample_mesh(v, f, count=n, seed=3)
    share = np.mean(p[:, 0] > 2.0)
    # Binomial: the big triangle holds 4/8 of the area; 5 sigma = 5 sqrt(.25/n).
    assert abs(share - 0.5) < 5 * np.sqrt(0.25 / n)
    # Inside the big triangle the mean is its centroid (uniform density), 5 sigma.
    inside = p[p[:, 0] > 2.0]
    centroid = big.mean(axis=0)
    sigma = inside.std(axis=0) / np.sqrt(len(inside))
    assert np.all(np.abs(inside.mean(axis=0) - centroid) <= 5 * sigma + 1e-12)
    assert len(M.sample_mesh(v, f, density=100.0)) == int(np.ceil(100.0 * 8.0))
    with pytest.raises(ValueError, match="exactly one"):
        M.sample_mesh(v, f)


# ----------------------------------------------------------------------------- distances
def test_point_mesh_distance_sphere():
    v, f = unit_sphere()
    normals = M.face_normals(v, f)
    # The polyhedron lies between the sphere of radius h_min (closest face plane) and 1.
    h_min = float(np.min(np.einsum("ij,ij->i", normals, v[f[:, 0]])))
    rng = np.random.default_rng(0)
    d = rng.standard_normal((2000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    dist = M.point_mesh_distance(2.0 * d, v, f)
    # float32 inside open3d: 1e-6 slack.
    assert np.all(dist >= 1.0 - 1e-6) and np.all(dist <= 2.0 - h_min + 1e-6)


def test_known_offset_gives_chamfer_equal_to_offset():
    # Two equal squares 0.01 apart: the nearest point of every sample is straight
    # above/below it, so every distance is exactly the offset.
    offset = 0.01
    v0, f0 = square(0.0, n=4)
    v1, f1 = square(offset, n=3)
    s = M.compare_meshes(v1, f1, v0, f0, tau=2 * offset, count=5000)
    for key in ("accuracy", "completeness", "chamfer", "hausdorff"):
        assert s[key] == pytest.approx(offset, abs=1e-6)
    assert s["fscore"] == 1.0
    s = M.compare_meshes(v1, f1, v0, f0, tau=offset / 2, count=5000)
    assert s["fscore"] == 0.0 and s["precision"] == 0.0 and s["recall"] == 0.0


def test_identical_meshes_score_zero_and_point_cloud_distance():
    s = M.compare_meshes(CUBE_V, CUBE_F, CUBE_V, CUBE_F, tau=1e-3, count=4000)
    assert s["chamfer"] < 1e-6 and s["fscore"] == 1.0
    p = np.array([[0.0, 0, 0], [3.0, 4.0, 0]])
    assert np.allclose(M.point_cloud_distance(p, np.zeros((1, 3))), [0.0, 5.0])


def test_distance_scores_conventions():
    acc = np.array([0.0, 0.1, 0.2, 0.3])
    comp = np.array([0.0, 0.0, 0.5])
    s = M.distance_scores(acc, comp, tau=0.15)
    assert s["accuracy"] == pytest.approx(0.15)
    assert s["completeness"] == pytest.approx(0.5 / 3)
    assert s["chamfer"] == pytest.approx(0.5 * (0.15 + 0.5 / 3))
    assert s["precision"] == 0.5 and s["recall"] == pytest.approx(2 / 3)
    assert s["fscore"] == pytest.approx(2 * 0.5 * (2 / 3) / (0.5 + 2 / 3))
    assert s["hausdorff"] == 0.5
    with pytest.raises(ValueError, match="tau"):
        M.distance_scores(acc, comp, tau=0.0)


def test_bad_input_named():
    with pytest.raises(ValueError, match="vertices"):
        M.mesh_topology(np.zeros((3, 2)), CUBE_F)
    with pytest.raises(ValueError, match="outside"):
        M.mesh_topology(CUBE_V[:4], CUBE_F)
    with pytest.raises(ValueError, match="empty"):
        M.point_mesh_distance(np.zeros((1, 3)), CUBE_V, np.zeros((0, 3), np.int64))


# ----------------------------------------------------------------------------- invariance
@settings(max_examples=10, deadline=None)
@given(angles=st.tuples(*[st.floats(-np.pi, np.pi)] * 3),
       shift=st.tuples(*[st.floats(-5.0, 5.0)] * 3))
def test_scores_and_topology_are_rigid_invariant(angles, shift):
    from scipy.spatial.transform import Rotation

    rot = Rotation.from_euler("xyz", angles).as_matrix()
    v_rec = CUBE_V * 1.05                       # a cube 5 % larger than the truth
    move = lambda v: v @ rot.T + np.array(shift)
    here = M.compare_meshes(v_rec, CUBE_F, CUBE_V, CUBE_F, tau=0.03, count=3000)
    there = M.compare_meshes(move(v_rec), CUBE_F, move(CUBE_V), CUBE_F, tau=0.03, count=3000)
    # Same samples (same seeds, rigidly moved); float32 distances inside open3d.
    for key in ("accuracy", "completeness", "chamfer", "hausdorff"):
        assert there[key] == pytest.approx(here[key], abs=1e-5)
    # Faces 0.05 apart: every distance is 0.05 on the faces' inner parts, more near edges.
    assert here["accuracy"] >= 0.05 - 1e-6
    assert M.signed_volume(move(CUBE_V), CUBE_F) == pytest.approx(8.0, rel=1e-9)
    assert M.mesh_topology(move(CUBE_V), CUBE_F)["closed"]


def test_is_watertight_needs_closed_and_oriented():
    import open3d as o3d

    sphere = o3d.geometry.TriangleMesh.create_icosahedron()
    v = np.asarray(sphere.vertices, np.float64)
    t = np.asarray(sphere.triangles, np.int64)
    assert M.is_watertight(t)
    topo = M.mesh_topology(v, t)
    assert topo["closed"] and topo["oriented"]
    flipped = t.copy()
    flipped[0] = flipped[0, ::-1]  # closed, but one face against its neighbours
    assert not M.is_watertight(flipped) and M.mesh_topology(v, flipped)["closed"]
    assert not M.is_watertight(t[1:])  # a hole
    assert not M.is_watertight(np.zeros((0, 3), np.int64))


def test_signed_point_mesh_distance_is_negative_inside():
    import open3d as o3d

    sphere = o3d.geometry.TriangleMesh.create_sphere(1.0, 40)
    v = np.asarray(sphere.vertices, np.float64)
    t = np.asarray(sphere.triangles, np.int64)
    points = np.array([[0.0, 0.0, 0.5], [0.0, 0.0, 1.5], [2.0, 0.0, 0.0]])
    # the faceted sphere lies inside the unit sphere by at most 1 - cos(pi/40) = 3.1e-3
    expected = np.array([-0.5, 0.5, 1.0])
    np.testing.assert_allclose(M.point_mesh_distance(points, v, t, signed=True), expected,
                               atol=3.2e-3)
    np.testing.assert_allclose(M.point_mesh_distance(points, v, t), np.abs(expected),
                               atol=3.2e-3)


def test_sampling_error_covers_the_exact_chamfer_distance():
    # The square z = a x over [-1, 1]^2 against the flat one: a sample (x, y, a x) is
    # |a x| above the flat square, a flat sample is |a x| / sqrt(1 + a^2) from the
    # tilted plane (its foot moves towards x = 0, inside the square), and both are
    # uniform in x: means a / 2 and a / (2 sqrt(1 + a^2)), standard deviations
    # a / sqrt(12) and a / sqrt(12 (1 + a^2)).
    a, count = 0.2, 4000
    v0, f0 = square(0.0, n=8)
    v1, f1 = square(0.0, n=8)
    v1[:, 2] = a * v1[:, 0]
    exact = 0.5 * (a / 2 + a / (2 * np.sqrt(1 + a * a)))
    se = 0.5 * np.sqrt((a * a / 12 + a * a / (12 * (1 + a * a))) / count)
    distance, truth_distance = M.MeshDistance(v1, f1), M.MeshDistance(v0, f0)
    for seed in range(3):
        s = M.compare_meshes(v1, f1, v0, f0, tau=0.1, count=count, seed=seed,
                             distance=distance, truth_distance=truth_distance)
        assert s["chamfer_se"] == pytest.approx(se, rel=0.1)
        assert abs(s["chamfer"] - exact) <= 4 * s["chamfer_se"]
        assert s["accuracy_se"] == pytest.approx(a / np.sqrt(12 * count), rel=0.1)
    # the prebuilt distances are the same figures as building them per call
    assert M.compare_meshes(v1, f1, v0, f0, tau=0.1, count=500) == M.compare_meshes(
        v1, f1, v0, f0, tau=0.1, count=500, distance=distance, truth_distance=truth_distance)


def test_face_components_of_three_pieces_numbered_by_first_face():
    # two cubes and a lone triangle, interleaved: labels follow each piece's first face
    v = np.vstack([CUBE_V, CUBE_V + 5.0, np.eye(3) + 20.0])
    f = np.vstack([CUBE_F[:6], CUBE_F[:6] + 8, [[16, 17, 18]], CUBE_F[6:], CUBE_F[6:] + 8])
    labels = M.face_components(f)
    assert labels.tolist() == [0] * 6 + [1] * 6 + [2] + [0] * 6 + [1] * 6
    topology = M.mesh_topology(v, f)
    assert topology["components"] == 3 and topology["boundary_edges"] == 3


def test_silhouette_scores_of_a_sphere_against_its_exact_disk():
    """A unit sphere 5 units in front of a camera outlines a disk of radius
    f / sqrt(5^2 - 1) px exactly; shifted by half its radius, it leaves part of it."""
    import open3d as o3d

    from matching.cameras import Camera
    from surface.metrics import silhouette_scores

    sphere = o3d.geometry.TriangleMesh.create_sphere(1.0, resolution=60)
    v, t = np.asarray(sphere.vertices), np.asarray(sphere.triangles)
    f, w, h = 200.0, 160, 120
    cam = Camera(np.array([[f, 0, 79.5], [0, f, 59.5], [0, 0, 1]]), [], np.eye(3),
                 np.array([0.0, 0.0, 5.0]), w, h, "c")
    rows, cols = np.indices((h, w))
    disk = np.hypot(cols - 79.5, rows - 59.5) < f / np.sqrt(24.0)
    exact = silhouette_scores(v, t, [cam], [disk], margin_px=2)
    # the polygonal sphere lies inside the true one by <= 1 - cos(pi / 60): 0.07 px here
    assert exact["iou"][0] > 0.98 and exact["inside"][0] == 1.0 and exact["covered"][0] == 1.0
    moved = silhouette_scores(v + [0.5, 0.0, 0.0], t, [cam], [disk], margin_px=2)
    assert moved["iou"][0] < 0.7 and moved["inside"][0] < 0.8 and moved["covered"][0] < 0.8
