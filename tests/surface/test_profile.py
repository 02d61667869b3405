"""Profiles (surface.profile): plane sections, walls, measures against exact vessels."""

import numpy as np
import pytest

from surface.profile import (
    half_profile,
    measure_profile,
    plane_section,
    principal_azimuths,
    revolve,
    silhouette,
)
from testkit import cup as _cup

Z = np.array([0.0, 0.0, 1.0])
ORIGIN = np.zeros(3)


def test_plane_section_of_a_sphere_is_one_closed_planar_loop():
    import open3d as o3d

    mesh = o3d.geometry.TriangleMesh.create_sphere(2.0, 20)
    vertices, triangles = np.asarray(mesh.vertices), np.asarray(mesh.triangles)
    normal = np.array([0.2, -0.4, 1.0])
    origin = np.array([0.1, 0.3, 0.5])
    loops = plane_section(vertices, triangles, origin, normal)
    assert len(loops) == 1
    points, closed = loops[0]
    assert closed
    unit = normal / np.linalg.norm(normal)
    assert np.abs((points - origin) @ unit).max() < 1e-12
    # consecutive points share a triangle: steps no longer than the longest edge
    edges = np.linalg.norm(vertices[triangles] - vertices[np.roll(triangles, 1, 1)], axis=2)
    assert np.linalg.norm(np.diff(points, axis=0, append=points[:1]), axis=1).max() <= edges.max()
    # the loop is counter-clockwise about the plane normal for an outward-oriented mesh?
    # (either way it must be consistent): its signed area is that of a circle ~ pi r^2
    centre = points.mean(axis=0)
    area = 0.5 * np.cross(points - centre, np.roll(points, -1, 0) - centre) @ unit
    r2 = 4.0 - ((centre) @ unit) ** 2
    assert abs(abs(area.sum()) - np.pi * r2) < 0.05 * np.pi * r2


def _cup_mesh(n=48):
    return revolve(_cup.cup_profile(), n)


def test_cup_profile_splits_into_outer_and_inner_walls():
    vertices, triangles = _cup_mesh()
    profile = half_profile(vertices, triangles, Z, ORIGIN, 0.0)
    assert profile.inner is not None and not profile.others
    # through the mesh's vertices (azimuth 0 is a ring vertex): the cut is the profile itself
    expected = _cup.cup_profile()
    assert np.allclose(profile.outer[[0, -1]], [[0.0, 0.0], [_cup.RT - _cup.W / 2, _cup.H]],
                       atol=1e-9)
    assert profile.inner[-1] == pytest.approx([0.0, _cup.ZB], abs=1e-9)
    got = np.vstack([profile.outer, profile.inner[1:]])
    assert got.shape == expected.shape
    assert np.abs(got - expected).max() < 1e-9


def test_cup_measures_are_exact_through_the_vertices():
    vertices, triangles = _cup_mesh()
    right = half_profile(vertices, triangles, Z, ORIGIN, 0.0)
    left = half_profile(vertices, triangles, Z, ORIGIN, np.pi)
    heights = [20.0, 50.0, 80.0]
    m = measure_profile(right, left, heights, tolerance=0.0)
    assert m["height"] == pytest.approx(_cup.H, abs=1e-9)
    # base: taken in a band of the merge distance (1e-9 x size) above the lowest point,
    # where the tapered wall is K x 5e-8 wider
    assert m["base_diameter"] == pytest.approx(2 * _cup.RB, abs=1e-6)
    # the widest point of the round lip is the top of the outer wall
    assert m["rim_diameter"] == pytest.approx(2 * _cup.RT, abs=1e-9)
    assert m["max_diameter"] == pytest.approx(2 * _cup.RT, abs=1e-9)
    assert m["max_diameter_height"] == pytest.approx(_cup.H - _cup.W / 2, abs=1e-9)
    # straight walls W apart horizontally: W / sqrt(1 + K^2) along their normal
    for h in heights:
        assert m["thickness"][h] == pytest.approx(_cup.W / np.hypot(1.0, _cup.K), abs=1e-9)


def test_measures_between_vertices_within_the_polygon_sagitta():
    n = 48
    vertices, triangles = _cup_mesh(n)
    phi = 0.3 * 2 * np.pi / n  # between two ring vertices
    m = measure_profile(half_profile(vertices, triangles, Z, ORIGIN, phi),
                        half_profile(vertices, triangles, Z, ORIGIN, phi + np.pi),
                        [50.0], tolerance=0.0)
    # a chord of the n-gon lies inside the circle by at most r (1 - cos(pi/n))
    sag = _cup.RT * (1 - np.cos(np.pi / n))
    assert 2 * _cup.RT - 2 * sag <= m["max_diameter"] <= 2 * _cup.RT + 1e-9
    assert 2 * _cup.RB - 2 * sag <= m["base_diameter"] <= 2 * _cup.RB + 1e-6
    assert m["thickness"][50.0] == pytest.approx(_cup.W / np.hypot(1.0, _cup.K), abs=sag)


def test_profile_does_not_depend_on_the_pose():
    vertices, triangles = _cup_mesh()
    axis = np.array([1.0, 1.0, 0.2])
    axis /= np.linalg.norm(axis)
    v = np.cross(Z, axis)
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    rot = np.eye(3) + vx + vx @ vx / (1 + axis[2])
    shift = np.array([5.0, -2.0, 7.0])
    moved = vertices @ rot.T + shift
    a = measure_profile(half_profile(vertices, triangles, Z, ORIGIN, 0.4),
                        half_profile(vertices, triangles, Z, ORIGIN, 0.4 + np.pi), [40.0])
    # the same half-plane in the moved frame: azimuth measured from frame(axis)[0]
    from surface.profile import frame

    e1, e2, _ = frame(axis)
    u = rot @ np.array([np.cos(0.4), np.sin(0.4), 0.0])
    phi = np.arctan2(u @ e2, u @ e1)
    b = measure_profile(half_profile(moved, triangles, axis, shift, phi),
                        half_profile(moved, triangles, axis, shift, phi + np.pi), [40.0])
    for key in ("height", "rim_diameter", "base_diameter", "max_diameter"):
        assert b[key] == pytest.approx(a[key], abs=1e-9)
    assert b["thickness"][40.0] == pytest.approx(a["thickness"][40.0], abs=1e-9)


def test_principal_profiles_of_an_oval_vessel():
    vertices, triangles = _cup_mesh(96)
    oval = vertices * [1.0, 0.6, 1.0]  # widths 2r and 1.2r at every height
    angle = 0.5
    rot = np.array([[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0],
                    [0, 0, 1]])
    oval = oval @ rot.T
    major, minor, widths, centre = principal_azimuths(oval, triangles, Z, ORIGIN)
    from surface.profile import frame

    e1, e2, _ = frame(Z)
    u = np.array([np.cos(angle), np.sin(angle), 0.0])  # the long axis
    expected = np.arctan2(u @ e2, u @ e1)
    # directions are defined mod pi; within half a degree
    assert np.cos(2 * (major - expected)) > np.cos(2 * np.radians(0.5))
    assert np.cos(2 * (minor - expected - np.pi / 2)) > np.cos(2 * np.radians(0.5))
    assert widths[1] / widths[0] == pytest.approx(0.6, rel=2e-3)
    assert np.linalg.norm(centre) < 1e-6


def test_silhouette_is_the_largest_radius_per_height():
    vertices, triangles = _cup_mesh()
    outline = silhouette(vertices, triangles, Z, ORIGIN)
    assert outline[0] == pytest.approx([0.0, 0.0]) and outline[-1] == pytest.approx([0.0, _cup.H])
    # the outer wall's radius at each height below the lip: the n-gon's vertices lie on
    # the circle of radius r(z)
    body = outline[1:-1][outline[1:-1, 1] < _cup.H - _cup.W / 2]
    expected = _cup.RB + _cup.K * body[:, 1]
    assert len(body) > 10
    assert np.abs(body[:, 0] - expected).max() < 1e-9


def test_closed_body_has_no_inner_wall():
    import open3d as o3d

    mesh = o3d.geometry.TriangleMesh.create_sphere(1.0, 24)
    vertices, triangles = np.asarray(mesh.vertices), np.asarray(mesh.triangles)
    profile = half_profile(vertices, triangles, Z, ORIGIN, 0.2)
    assert profile.inner is None
    assert profile.outer[:, 1].min() == pytest.approx(-1.0, abs=1e-9)


def test_half_plane_missing_the_surface_is_refused():
    import open3d as o3d

    mesh = o3d.geometry.TriangleMesh.create_sphere(1.0, 8)
    with pytest.raises(ValueError, match="meets no surface"):
        half_profile(np.asarray(mesh.vertices), np.asarray(mesh.triangles), Z,
                     np.array([5.0, 0.0, 0.0]), np.pi)


def test_mustard_bottle_profile_against_its_mesh(real_data_dir):
    from pipeline import cmd_profile

    path = real_data_dir / "scans" / "ycb_mustard_bottle" / "mesh.obj"
    if not path.is_file():
        pytest.skip(f"{path} not found")
    surface = cmd_profile.read_surface(path)
    figures = cmd_profile.profile_figures(surface, Z)
    v, f = surface["vertices"], surface["triangles"]
    assert not figures["circular"]  # an oval bottle: both principal profiles
    assert len(figures["profiles"]) == 2
    assert figures["height"] == pytest.approx(np.ptp(v[:, 2]), abs=1e-12)
    edges = np.linalg.norm(v[f[:, 1]] - v[f[:, 0]], axis=1)
    from surface.profile import frame

    e1, e2, _ = frame(Z)
    for p in figures["profiles"]:
        phi = np.radians(p["azimuth_deg"])
        direction = np.cos(phi) * e1 + np.sin(phi) * e2
        extent = np.ptp(v @ direction)
        # the widest vertex may lie off the profile plane by up to one edge e: the plane
        # then cuts the mesh at most e^2 / (2 r) inside it, on either side; the two
        # halves' radii are summed at one height, so never more than the extent
        slack = 2 * edges.max() ** 2 / p["max_diameter"]
        assert extent - slack <= p["max_diameter"] <= extent + 1e-12
        # the cut's height can only miss a top off the plane
        assert p["height"] <= figures["height"] + 1e-12
    assert figures["volume"] == pytest.approx(
        __import__("surface.measure", fromlist=["x"]).mesh_volume(v, f), rel=1e-12)
    assert figures["capacity"] is None  # a closed bottle holds nothing
