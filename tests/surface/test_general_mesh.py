"""The general control mesh: closed, of the shape's genus, near its cloud; the choice rule."""

from __future__ import annotations

import numpy as np
import pytest

from surface import general_mesh
from surface.general_mesh import Fidelity, clamp_to_hull, prefer_general
from testkit import shapes

SIGMA = 0.002


@pytest.fixture(scope="module")
def torus_mesh():
    """A noisy torus cloud, its point spacing and its general control mesh (edge 2 spacings)."""
    from surface.sections import point_spacing

    cloud = shapes.sample("torus", 6_000, seed=3, sigma=SIGMA)
    spacing = point_spacing(cloud)
    return spacing, *general_mesh.poisson_control_mesh(cloud, 2 * spacing, spacing)


def test_poisson_control_mesh_is_a_closed_manifold_of_the_torus_genus(torus_mesh):
    from surface.validity import check_solid

    spacing, v, t = torus_mesh
    report = check_solid(v, t, intersections=False)
    assert report.boundary_edges == 0 and report.components == 1
    assert report.genus == shapes.genus("torus")
    # triangles of about the asked edge: the torus's area 4 pi^2 R r = 13.8 over
    # sqrt(3)/4 (2 s)^2 each, within a factor 2 (decimation stops at whole collapses)
    expected = 4 * np.pi ** 2 * 1.0 * 0.35 / (np.sqrt(3) / 4 * (2 * spacing) ** 2)
    assert 0.5 * expected < len(t) < 2 * expected


def test_loop_surface_over_it_stays_within_the_noise_of_the_truth(torus_mesh):
    from pipeline.bezier_surface import smooth_mesh
    from surface.fitting import interpolating_control_mesh

    _, v, t = torus_mesh
    smooth = smooth_mesh(interpolating_control_mesh(v, t), t, 1, check=False)
    distance = shapes.distance_to_truth("torus", smooth.vertices)
    # the vertices' distance to the exact torus: the points' noise sigma averaged over the
    # Poisson cells' neighbours, plus the chord/curvature error of cells ~ a spacing
    # (0.05 across on r = 0.35: sagitta 0.05^2 / (8 x 0.35) ~ 1e-3): a few sigma at most
    assert np.median(distance) < 2 * SIGMA
    assert np.percentile(distance, 99) < 6 * SIGMA
    assert smooth.g1_angle < 1e-6


def test_fidelity_measures_a_shifted_surface_by_its_shift():
    import open3d as o3d

    from pipeline.mesh_io import read_mesh  # noqa: F401  (open3d through the package)
    from surface.metrics import sample_mesh

    sphere = o3d.geometry.TriangleMesh.create_sphere(1.0, 80)
    v, t = np.asarray(sphere.vertices), np.asarray(sphere.triangles, np.int64)
    cloud = sample_mesh(v, t, 40_000, seed=1)
    near = general_mesh.cloud_fidelity(v, t, cloud)
    far = general_mesh.cloud_fidelity(1.02 * v, t, cloud)
    # a sphere grown by 2 %: every cloud point 0.02 from it (C), every surface sample at
    # least 0.02 from the cloud (A); on the sphere itself both stay at the point spacing
    assert far.c50 == pytest.approx(0.02, rel=0.05)
    assert far.a90 > 0.02 and near.a90 < 0.02 and near.c50 < 1e-3


def test_clamp_moves_outside_vertices_onto_the_hull_and_leaves_the_inside():
    from scipy.spatial import ConvexHull

    corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float)
    planes = ConvexHull(corners).equations
    vertices = np.array([[0.5, 0.5, 0.5], [0.5, 0.5, 1.3], [1.4, 0.5, -0.2]])
    out = clamp_to_hull(vertices, planes)
    np.testing.assert_array_equal(out[0], vertices[0])
    np.testing.assert_allclose(out[1], [0.5, 0.5, 1.0], atol=1e-12)
    np.testing.assert_allclose(out[2], [1.0, 0.5, 0.0], atol=1e-9)


def test_a_component_of_two_faces_back_to_back_is_refused_before_loop_s_patches():
    """Quadric decimation can pinch a thin part off into two faces back to back: closed and
    edge-manifold, but its vertices have two faces each, no ring for Loop's patches."""
    octahedron = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]],
                          float)
    faces = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4],
                      [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    assert general_mesh._closed_problem(octahedron, faces) == ""
    pillow = np.array([[3, 0, 0], [4, 0, 0], [3, 1, 0]], float)
    vertices = np.vstack([octahedron, pillow])
    triangles = np.vstack([faces, [[6, 7, 8], [6, 8, 7]]])
    assert general_mesh._closed_problem(vertices, triangles) == (
        "degenerate (3 vertices of fewer than 3 faces)")


@pytest.mark.parametrize("section, general, expected", [
    (Fidelity(1.0, 1.0), Fidelity(1.0, 1.0), False),       # equal: the sections stay
    (Fidelity(1.0, 2.0), Fidelity(1.0, 1.0), True),        # the sections leave the data
    (Fidelity(1.0, 2.0), Fidelity(1.5, 1.0), False),       # ... but the general invents
    (Fidelity(1.05, 1.05), Fidelity(1.0, 1.0), False),     # within the margin
    (Fidelity(1.5, 1.0), Fidelity(1.0, 1.05), True),       # slabs gone, data as near
])
def test_prefer_general(section, general, expected):
    assert prefer_general(section, general) is expected


def test_prefer_general_a_valid_solid_beats_one_that_is_not():
    near, farther = Fidelity(1.0, 1.0), Fidelity(1.5, 1.5)
    # the valid one wins whatever A and C say (the cow: a valid general surface 0.80x
    # Poisson's Chamfer against a crossing section surface nearer on C)
    assert prefer_general(near, farther, section_valid=False)
    assert not prefer_general(farther, near, general_valid=False)
    # ... and whatever the genus says
    assert prefer_general(near, farther, section_valid=False, section_genus=1,
                          general_genus=3, evidence_genus=1)


def test_prefer_general_then_the_genus_the_data_support():
    near, farther = Fidelity(1.0, 1.0), Fidelity(1.5, 1.5)
    # both valid: the general surface nearer, but with tunnels the data do not see (the
    # teapot: genus 13 against the evidence's 1) -> the sections' genus-1 surface stays
    assert not prefer_general(farther, near, section_genus=1, general_genus=13,
                              evidence_genus=1)
    # the sections miss a handle the data show: the general one, though farther
    assert prefer_general(near, farther, section_genus=0, general_genus=1, evidence_genus=1)
    # neither or both of the evidence's genus: A and C decide
    assert prefer_general(farther, near, section_genus=2, general_genus=3, evidence_genus=1)
    assert not prefer_general(near, farther, section_genus=1, general_genus=1,
                              evidence_genus=1)
    assert prefer_general(farther, near, section_genus=1, general_genus=13)  # no evidence


def test_plane_reference_projects_a_noisy_cloud_and_keeps_a_noise_free_one():
    from surface.general_mesh import plane_reference

    rng = np.random.default_rng(5)
    unit = rng.normal(size=(4_000, 3))
    unit /= np.linalg.norm(unit, axis=1, keepdims=True)
    # noise-free: every plane only adds its sagitta, so the cloud itself is the reference
    reference, k = plane_reference(unit)
    assert k == 1 and reference is unit
    # sigma = 0.01 on a unit sphere at spacing ~0.056: the planes average the noise over
    # k points (variance sigma^2 / k) at a sagitta far below sigma, so the projected
    # points lie nearer the sphere than the raw ones by well over 2x in RMS
    noisy = unit * (1 + 0.01 * rng.normal(size=(len(unit), 1)))
    reference, k = plane_reference(noisy)
    raw = np.sqrt(np.mean((np.linalg.norm(noisy, axis=1) - 1) ** 2))
    projected = np.sqrt(np.mean((np.linalg.norm(reference, axis=1) - 1) ** 2))
    assert k > 1 and projected < raw / 2


def test_prefer_general_weighs_c_against_the_projected_cloud_when_both_have_it():
    # raw C favours the sections (they follow the noise), the projected C the general one
    section, general = Fidelity(1.0, 1.0, 1.3), Fidelity(1.0, 1.05, 1.0)
    assert prefer_general(section, general)
    assert not prefer_general(Fidelity(1.0, 1.0), Fidelity(1.0, 1.05))
    assert not prefer_general(section, Fidelity(1.0, 1.05))       # one without: raw C


def test_needs_general_when_the_sections_leave_the_data_beyond_their_noise():
    from surface.general_mesh import needs_general

    sigma = 1e-3
    explained = 0.6745 * np.sqrt(2.0) * sigma        # median |N(0, 2 sigma^2)|
    assert not needs_general(Fidelity(1.0, explained), True, sigma)
    assert needs_general(Fidelity(1.0, 1.5 * explained), True, sigma)
    assert needs_general(Fidelity(1.0, explained), False, sigma)      # not a valid solid
    assert needs_general(Fidelity(1.0, explained), True, None)        # no noise estimate


@pytest.fixture(scope="module")
def torus_and_cloud():
    """A fine torus mesh (R = 1, r = 0.5: genus 1) and 20 000 points on it."""
    import open3d as o3d

    from surface.metrics import sample_mesh

    torus = o3d.geometry.TriangleMesh.create_torus(1.0, 0.5, 120, 60)
    v, t = np.asarray(torus.vertices), np.asarray(torus.triangles, np.int64)
    return v, t, sample_mesh(v, t, 20_000, seed=2)


def test_supported_genus_drops_a_handle_through_no_data_and_keeps_holes(torus_and_cloud):
    from surface.general_mesh import support_reach, supported_genus
    from surface.sections import point_spacing

    v, t, cloud = torus_and_cloud
    reach = support_reach(point_spacing(cloud))
    assert supported_genus(v, t, cloud, reach) == 1            # every handle seen
    # no points across a band of the tube (0.6 rad wide: >= 0.3 apart, 6 reaches): the
    # handle runs through no data, as an iso-surface's tunnel between two close parts
    angle = np.arctan2(cloud[:, 1], cloud[:, 0])
    assert 0.3 > 6 * reach
    assert supported_genus(v, t, cloud[np.abs(angle) > 0.3], reach) == 0
    # a hole in the data (a disc, as an unseen base) leaves the genus as it was
    hole = np.linalg.norm(cloud - [1.5, 0.0, 0.0], axis=1) < 0.3
    assert supported_genus(v, t, cloud[~hole], reach) == 1
    assert support_reach(1.0, 0.1) == pytest.approx(np.sqrt(np.log(1e3) / np.pi) + 0.3)


def test_smooth_general_takes_the_plain_interpolation_when_it_is_a_valid_solid(torus_mesh):
    from pipeline.bezier_surface import smooth_general

    _, v, t = torus_mesh
    smooth = smooth_general(v, t, 1)
    assert smooth.solid["valid"] and smooth.solid["genus"] == 1
    assert smooth.solid["general_control"] == "interpolating"
    assert np.median(shapes.distance_to_truth("torus", smooth.vertices)) < 2 * SIGMA


def test_evidence_genus_is_the_section_surface_s_supported_genus(torus_and_cloud):
    from surface.general_mesh import evidence_genus, support_reach
    from surface.sections import point_spacing

    v, t, cloud = torus_and_cloud
    reach = support_reach(point_spacing(cloud))
    assert evidence_genus(v, t, cloud, reach) == 1
    # a surface that is no closed manifold (a face doubled) has no genus to give
    assert evidence_genus(v, np.vstack([t, t[:1]]), cloud, reach) is None
