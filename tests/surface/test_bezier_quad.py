"""Two control triangles as one quadrilateral face (surface/bezier_quad.py)."""

from __future__ import annotations

import numpy as np
import pytest

from surface import bezier
from surface import bezier_merge as bm
from surface import bezier_quad as bq
from testkit.nets import ellipsoid_net


@pytest.fixture(scope="module")
def ellipsoid():
    """Valence 4, 5 and 6 vertices: the patches around the irregular ones are G1 only."""
    return ellipsoid_net()


def test_pairs_share_an_edge_and_no_triangle_twice(ellipsoid):
    topo = bm.control_triangles(ellipsoid.domain_mesh[1], ellipsoid.source_face)
    chains = bm._chains(ellipsoid.control_points, topo["patches"])
    angles = bq.corner_angles(chains)
    # the corners of a curved triangle: each angle inside (0, pi); on this convex
    # surface the three sum to at least pi
    assert (angles > 0).all() and (angles < np.pi).all()
    assert (angles.sum(axis=1) > 0.9 * np.pi).all()
    pairs = bq.pair_triangles(topo["corners"], bq._corner_xyz(ellipsoid.control_points,
                                                             topo["patches"]),
                              angles, bq.MAX_ANGLE)
    assert len(np.unique(pairs)) == pairs.size
    shared = [len(set(topo["corners"][a]) & set(topo["corners"][b])) for a, b in pairs]
    assert shared == [2] * len(pairs)
    assert len(pairs) >= 0.8 * len(topo["corners"]) / 2
    # with no angle allowed, nothing pairs
    assert len(bq.pair_triangles(topo["corners"], bq._corner_xyz(
        ellipsoid.control_points, topo["patches"]), angles, 0.0)) == 0


def test_quads_keep_the_patch_edges_and_the_tangent_plane(ellipsoid):
    cp, tris = ellipsoid.control_points, ellipsoid.domain_mesh[1]
    quad = bq.quad_faces(cp, tris, ellipsoid.source_face)
    topo = quad["triangles"]
    chains = bm._chains(cp, topo["patches"])
    # side A -> B is the first triangle's two patch edges, bit for bit, either way round
    first = topo["corners"][quad["pairs"][:, 0]]
    a, b = quad["corners"][:, 0], quad["corners"][:, 1]
    for k, (p, q) in enumerate(((0, 1), (1, 2), (0, 2))):
        fwd = (first[:, p] == a) & (first[:, q] == b)
        back = (first[:, p] == b) & (first[:, q] == a)
        assert np.array_equal(quad["poles"][fwd, :, 0], chains[quad["pairs"][fwd, 0], k])
        assert np.array_equal(quad["poles"][back, :, 0],
                              chains[quad["pairs"][back, 0], k, ::-1])
    # most quads lie on the patches far below the patches' own level-1 chord bound and
    # keep their tangent plane along the sides; the rest (beside the valence-4 vertices)
    # are what write_cad's gate sends back to triangle faces
    chord = float(bezier.chord_error_bound(bezier.subdivide(cp)).max())
    assert np.median(quad["deviation"]) < 0.01 * chord
    assert np.degrees(np.median(quad["angle"])) < 0.01
    assert np.count_nonzero(np.degrees(quad["angle"]) < 0.24) >= 0.8 * len(quad["pairs"])
    assert quad["inner_angle"].max() < np.pi / 2  # none folds
