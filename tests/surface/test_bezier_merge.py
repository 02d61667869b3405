"""One face per control triangle (surface/bezier_merge.py): against the four patches."""

from __future__ import annotations

import numpy as np
import pytest

from surface import bezier
from surface import bezier_merge as bm
from testkit.nets import ellipsoid_net


def _torus():
    """Loop's surface over a torus triangulated on a regular grid: every vertex of
    valence 6, so each control triangle's four patches are pieces of one quartic box
    spline patch (degree-elevated), a single polynomial."""
    import open3d as o3d

    mesh = o3d.geometry.TriangleMesh.create_torus(1.0, 0.4, 12, 8)
    return bezier.control_net(np.asarray(mesh.vertices), np.asarray(mesh.triangles)), mesh


@pytest.fixture(scope="module")
def ellipsoid():
    """Valence 4, 5 and 6 vertices: the patches around the irregular ones are G1 only."""
    return ellipsoid_net()


def test_control_triangles_are_found_in_either_orientation(ellipsoid):
    tris, source = ellipsoid.domain_mesh[1], ellipsoid.source_face
    topo = bm.control_triangles(tris, source)
    assert topo is not None and len(topo["corners"]) == len(tris) // 4
    # every control edge is shared by two control triangles, once each way: closed, oriented
    corners = topo["corners"]
    directed = np.concatenate([corners[:, [0, 1]], corners[:, [1, 2]], corners[:, [2, 0]]])
    assert len({tuple(e) for e in directed.tolist()}) == len(directed)
    assert {tuple(e[::-1]) for e in directed.tolist()} == {tuple(e) for e in directed.tolist()}
    flipped = bm.control_triangles(tris[:, [0, 2, 1]], source)
    assert np.array_equal(flipped["corners"], corners[:, [0, 2, 1]])
    # patches not four per control triangle, or in another order: not recognised
    assert bm.control_triangles(tris, np.arange(len(tris))) is None
    assert bm.control_triangles(tris[:, [1, 2, 0]], source) is None


@pytest.mark.parametrize("spans", [1, 2])
def test_faces_reproduce_a_regular_surface_to_rounding(spans):
    surface, mesh = _torus()
    merged = bm.merged_faces(surface.control_points, surface.domain_mesh[1],
                             surface.source_face, spans=spans)
    size = float(np.ptp(surface.control_points.reshape(-1, 3), axis=0).max())
    # a single polynomial: the fit's space holds it, so only rounding is left (the
    # one-span edges and the one-sided differences of the cross derivative are exact for
    # a polynomial of degree 6 up to the difference's O(h^2) term, ~1e-7 of the size)
    assert merged["deviation"].max() < 1e-9 * size
    assert merged["slide"].max() < 1e-6 * size
    assert np.degrees(merged["angle"].max()) < 1e-4
    assert len(merged["poles"]) == len(np.asarray(mesh.triangles))


def test_two_span_faces_keep_the_patch_edges_and_the_tangent_plane(ellipsoid):
    cp, tris = ellipsoid.control_points, ellipsoid.domain_mesh[1]
    merged = bm.merged_faces(cp, tris, ellipsoid.source_face, spans=2)
    poles, patches = merged["poles"], merged["patches"]
    # the side A -> B is the two patch edges' control points, bit for bit
    k = np.arange(7)
    edge01 = bezier.control_index(6 - k, k, 0 * k)
    assert np.array_equal(poles[:, :7, 0], cp[patches[:, 0]][:, edge01])
    assert np.array_equal(poles[:, 6:, 0], cp[patches[:, 1]][:, edge01])
    # the faces at the patches' parameters: offsets along the normal far below the
    # patches' own chord bound at level 1 (what the pipeline tessellates), kinks tiny
    chord = float(bezier.chord_error_bound(bezier.subdivide(cp)).max())
    assert merged["deviation"].max() < 0.05 * chord
    assert np.degrees(merged["angle"].max()) < 0.05
    # the faces at random parameters lie on the patches (closest points) as closely
    rng = np.random.default_rng(3)
    u, v = rng.uniform(0, 2, 40), rng.uniform(0, 2, 40)
    points = bm.face_points(poles[::7], u, v).reshape(-1, 3)
    distance, _, _ = bezier.closest_points(cp, points, tris)
    assert distance.max() <= merged["deviation"].max() * 1.5 + 1e-12


def test_merged_faces_refuse_a_bad_span_count(ellipsoid):
    with pytest.raises(ValueError, match="spans"):
        bm.merged_faces(ellipsoid.control_points, ellipsoid.domain_mesh[1],
                        ellipsoid.source_face, spans=3)
