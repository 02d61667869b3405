"""Volume, area and capacity (surface.measure) against exact and analytic answers."""

from math import factorial

import numpy as np
import pytest

from surface import bezier, measure
from surface.profile import revolve
from testkit import cup as _cup


def _normals(vertices, triangles):
    from pipeline.export import vertex_normals

    return vertex_normals(vertices, triangles)


@pytest.mark.parametrize("degree", [13, 16, 17])
def test_triangle_rule_integrates_monomials_exactly(degree):
    # int_T s^a t^b ds dt = a! b! / (a + b + 2)! for every a + b <= degree
    bary, weights = measure.triangle_rule(degree)
    assert weights.sum() == pytest.approx(0.5, rel=1e-14)
    for a in range(degree + 1):
        for b in range(degree + 1 - a):
            exact = factorial(a) * factorial(b) / factorial(a + b + 2)
            got = weights @ (bary[:, 1] ** a * bary[:, 2] ** b)
            assert got == pytest.approx(exact, rel=1e-11)


def test_triangle_rule_is_symmetric():
    bary, weights = measure.triangle_rule(16)
    for perm in ([1, 0, 2], [0, 2, 1], [2, 1, 0]):
        swapped = {tuple(np.round(b, 12)) for b in bary[:, perm]}
        assert swapped == {tuple(np.round(b, 12)) for b in bary}


def _polyhedron():
    """A non-convex closed polyhedron: a box with a tetrahedral dent, rotated off-axis."""
    import open3d as o3d

    box = o3d.geometry.TriangleMesh.create_box(2.0, 3.0, 5.0)
    vertices = np.asarray(box.vertices).copy()
    triangles = np.asarray(box.triangles).copy()
    # push the centre of the top face down: split the top two triangles into a fan
    top = np.flatnonzero(np.all(vertices[triangles][:, :, 2] == 5.0, axis=1))
    centre = len(vertices)
    vertices = np.vstack([vertices, [1.0, 1.5, 3.5]])
    rim = [(a, b) for t in triangles[top] for a, b in zip(t, np.roll(t, -1), strict=True)]
    boundary = [e for e in rim if (e[1], e[0]) not in rim]
    fan = np.array([[a, b, centre] for a, b in boundary])
    triangles = np.vstack([np.delete(triangles, top, axis=0), fan])
    angle = 0.7
    rot = np.array([[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0],
                    [0, 0, 1]]) @ np.array([[1, 0, 0], [0, np.cos(0.4), -np.sin(0.4)],
                                            [0, np.sin(0.4), np.cos(0.4)]])
    return vertices @ rot.T + [3.0, -1.0, 7.0], triangles


def test_flat_patches_give_the_polyhedron_volume_exactly():
    # degree-elevated flat triangles: the integrand is a polynomial of degree 16 on each
    # patch, so the degree-17 rule must reproduce the polyhedron's volume to rounding
    vertices, triangles = _polyhedron()
    net = bezier.elevate(vertices[triangles], 6)  # (F, 28, 3); index order of degree 1 = tri
    result = measure.surface_integrals(net)
    exact = 2.0 * 3.0 * 5.0 - (2.0 * 3.0) * 1.5 / 3.0  # box minus the pyramid dent
    assert measure.mesh_volume(vertices, triangles) == pytest.approx(exact, rel=1e-13)
    assert result["volume"] == pytest.approx(exact, rel=1e-12)
    assert result["area"] == pytest.approx(measure.mesh_area(vertices, triangles), rel=1e-12)


def test_mesh_volume_changes_sign_with_orientation():
    vertices, triangles = _polyhedron()
    assert measure.mesh_volume(vertices, triangles[:, ::-1]) == pytest.approx(
        -measure.mesh_volume(vertices, triangles), rel=1e-14)


def _radial_deviation(cp, distance):
    """Largest |distance| of the patches from the analytic surface at the rule's nodes."""
    bary, _ = measure.triangle_rule(16)
    points = bezier.evaluate(cp, bary).reshape(-1, 3)
    return float(np.abs(distance(points)).max())


@pytest.mark.parametrize("shape", ["sphere", "torus"])
def test_volume_and_area_of_smooth_closed_surfaces(shape):
    import open3d as o3d

    if shape == "sphere":
        mesh = o3d.geometry.TriangleMesh.create_sphere(1.0, 16)
        volume, area = 4.0 / 3.0 * np.pi, 4.0 * np.pi

        def distance(p):
            return np.linalg.norm(p, axis=1) - 1.0
    else:
        big, small = 2.0, 0.6
        mesh = o3d.geometry.TriangleMesh.create_torus(big, small, 40, 16)
        volume, area = 2 * np.pi ** 2 * big * small ** 2, 4 * np.pi ** 2 * big * small

        def distance(p):
            return np.hypot(np.hypot(p[:, 0], p[:, 1]) - big, p[:, 2]) - small
    net = bezier.control_net(np.asarray(mesh.vertices), np.asarray(mesh.triangles))
    result = measure.surface_integrals(net.control_points)
    dev = _radial_deviation(net.control_points, distance)
    # a surface within dev of the analytic one along the normal encloses a volume within
    # dev x area of it (first order); the area moves by dev x (total curvature) x area /
    # radius, bounded here by 2 dev / smallest radius of curvature x area
    assert abs(result["volume"] - volume) <= dev * area
    radius = 1.0 if shape == "sphere" else small
    assert abs(result["area"] - area) <= 2 * dev / radius * area * 1.05
    assert result["area_error"] < 1e-6 * area


def test_capacity_of_a_polygonal_cup_is_exact():
    # every horizontal section of the revolved mesh's inner wall is a regular n-gon of
    # circumradius r_in(z): the cavity is pi r^2 times the n-gon's share sin(2pi/n) n/(2pi)
    n = 48
    vertices, triangles = revolve(_cup.cup_profile(), n)
    share = n * np.sin(2 * np.pi / n) / (2 * np.pi)
    for h in (30.0, 60.0):
        cap = measure.capacity(vertices, triangles, _normals(vertices, triangles),
                               [0, 0, 1.0], [0, 0, 0.0], height=h)
        assert cap.volume == pytest.approx(share * _cup.analytic_capacity(h), rel=1e-9)
    full = measure.capacity(vertices, triangles, _normals(vertices, triangles),
                            [0, 0, 1.0], [0, 0, 0.0])
    # the overflow level: the lip's top, H, to within the lip's highest ring below it
    lip_gap = _cup.W / 2 * (1 - np.cos(np.pi / 8))
    assert _cup.H - lip_gap - 1e-9 <= full.rim_height <= _cup.H + 1e-9


def test_capacity_is_rotation_and_translation_invariant():
    vertices, triangles = revolve(_cup.cup_profile(), 32)
    axis = np.array([0.3, -0.5, 0.8])
    axis /= np.linalg.norm(axis)
    # a rotation taking z to axis (Rodrigues about z x axis)
    v = np.cross([0, 0, 1.0], axis)
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    rot = np.eye(3) + vx + vx @ vx / (1 + axis[2])
    moved = vertices @ rot.T + [10.0, -4.0, 2.0]
    a = measure.capacity(vertices, triangles, _normals(vertices, triangles), [0, 0, 1.0],
                         [0, 0, 0.0], height=50.0)
    b = measure.capacity(moved, triangles, _normals(moved, triangles), axis,
                         np.array([10.0, -4.0, 2.0]), height=50.0)
    assert b.volume == pytest.approx(a.volume, rel=1e-9)


def test_closed_body_has_no_capacity():
    import open3d as o3d

    mesh = o3d.geometry.TriangleMesh.create_sphere(1.0, 12)
    vertices, triangles = np.asarray(mesh.vertices), np.asarray(mesh.triangles)
    cap = measure.capacity(vertices, triangles, _normals(vertices, triangles), [0, 0, 1.0],
                           [0, 0, 0.0])
    assert cap.volume == 0.0 and not cap.cavity_triangles.any()


def _profile_distance(rz: np.ndarray) -> float:
    """Largest distance of points (r, z) from the analytic cup's profile: nearest of its
    points sampled 1e-3 apart (so over-estimated by at most 5e-4)."""
    from scipy.spatial import cKDTree

    fine = _cup.cup_profile()
    steps = np.maximum(1, np.ceil(np.linalg.norm(np.diff(fine, axis=0), axis=1) / 1e-3))
    dense = np.vstack([np.linspace(a, b, int(k), endpoint=False)
                       for a, b, k in zip(fine[:-1], fine[1:], steps, strict=True)])
    return float(cKDTree(dense).query(rz)[0].max()) + 5e-4


def test_capacity_of_the_smooth_cup_against_the_analytic_integral():
    vertices, triangles = revolve(_cup.cup_profile(wall=24, base=10, lip=7), 96)
    net = bezier.control_net(vertices, triangles)
    level = 1
    tv, tt, tn = bezier.tessellate(net, level)
    h = 60.0
    cap = measure.capacity(tv, tt, tn, [0, 0, 1.0], [0, 0, 0.0], height=h)
    truth = _cup.analytic_capacity(h)
    # the smooth surface's own distance from the analytic cup (its vertices against the
    # profile) and the tessellation's chord bound, times the wetted area: the first-order
    # bound of the volume difference
    rz = np.column_stack([np.hypot(tv[:, 0], tv[:, 1]), tv[:, 2]])
    dev = _profile_distance(rz)
    bound = (dev + measure.chord_bound(net.control_points, level)) * cap.wet_area
    assert abs(cap.volume - truth) <= bound
    assert abs(cap.volume / truth - 1) < 0.005
