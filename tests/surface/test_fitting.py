"""surface.fitting: control meshes whose Loop limit positions are given points."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest

from surface import bezier
from surface.fitting import interpolating_control_mesh, limit_matrix, limit_positions


def _arrays(mesh):
    return np.asarray(mesh.vertices).copy(), np.asarray(mesh.triangles).astype(np.int64)


def icosphere(level: int = 2):
    v, t = _arrays(o3d.geometry.TriangleMesh.create_icosahedron(1.0).subdivide_midpoint(level))
    return v / np.linalg.norm(v, axis=1, keepdims=True), t


def cube(level: int = 1):
    """Triangulated unit cube: valences 3, 4, 5, 6 (and a sharp crease everywhere)."""
    return _arrays(o3d.geometry.TriangleMesh.create_box().subdivide_midpoint(level))


def test_limit_mask_weights():
    # Loop's limit mask: valence 6 (beta = 1/16) gives 1/2 for the vertex and 1/12 per
    # neighbour; valence 5 (beta = 0.0797...) gives beta_lim = 1/(5 + 3/(8 beta)); rows
    # sum to 1 (affine invariance) -- exact arithmetic up to rounding (1e-15).
    v, t = icosphere(2)
    m = limit_matrix(t, len(v)).toarray()
    valence = (m > 0).sum(axis=1) - 1
    assert set(valence) == {5, 6}
    np.testing.assert_allclose(m.sum(axis=1), 1.0, atol=1e-15)
    six = np.flatnonzero(valence == 6)[0]
    np.testing.assert_allclose(m[six, six], 0.5, atol=1e-15)
    np.testing.assert_allclose(np.sort(m[six][m[six] > 0])[:6], 1.0 / 12.0, atol=1e-15)
    beta5 = (5 / 8 - (3 / 8 + np.cos(2 * np.pi / 5) / 4) ** 2) / 5
    five = np.flatnonzero(valence == 5)[0]
    np.testing.assert_allclose(m[five, five], 1 - 5 / (5 + 3 / (8 * beta5)), atol=1e-15)


@pytest.mark.parametrize("mesh", [icosphere, cube])
def test_limit_positions_of_result_equal_targets(mesh):
    # The solve is a sparse LU of a well-conditioned matrix (eigenvalues ~[1/4, 1] on
    # regular parts) with O(1) data: residual ~1e-15, asserted at 1e-10.
    v, t = mesh()
    x = interpolating_control_mesh(v, t)
    np.testing.assert_allclose(limit_positions(x, t), v, rtol=0, atol=1e-10)
    # and it actually changed the mesh: the plain limit of a convex mesh shrinks it
    assert np.max(np.abs(limit_positions(v, t) - v)) > 1e-3
    assert np.max(np.abs(x - v)) > 1e-3


def test_bezier_surface_passes_through_targets():
    # End to end: Loop's sextic surface (surface.bezier) over the fitted control mesh
    # has its patch corners at the original vertices' Loop limit points, i.e. at the
    # targets.  The original vertices keep their ids in the refined domain mesh.
    v, t = icosphere(1)
    x = interpolating_control_mesh(v, t)
    surf = bezier.control_net(x, t)
    domain = surf.domain_mesh[1]
    corners = surf.control_points[:, [0, 21, 27]]  # b_600, b_060, b_006
    ids, pts = domain.ravel(), corners.reshape(-1, 3)
    original = ids < len(v)
    assert np.unique(ids[original]).size == len(v)
    np.testing.assert_allclose(pts[original], v[ids[original]], rtol=0, atol=1e-10)
    # the sphere's vertices lie on the unit sphere: so do the surface's corner points
    # there, while the approximating surface over v sits inside it
    plain = bezier.control_net(v, t).control_points[:, [0, 21, 27]].reshape(-1, 3)
    assert np.max(np.linalg.norm(plain[original], axis=1)) < 1.0 - 1e-3


def test_affine_invariance():
    # Rows summing to 1 make the fit commute with affine maps (1e-12: LU rounding).
    v, t = cube()
    a = np.array([[1.0, 0.2, 0.0], [0.0, 2.0, 0.3], [0.1, 0.0, 0.5]])
    b = np.array([0.3, -1.0, 2.0])
    np.testing.assert_allclose(interpolating_control_mesh(v @ a.T + b, t),
                               interpolating_control_mesh(v, t) @ a.T + b, atol=1e-12)


def test_bad_input():
    v, t = icosphere(1)
    with pytest.raises(ValueError, match="border"):
        interpolating_control_mesh(v, t[1:])
    with pytest.raises(ValueError, match="isolated"):
        interpolating_control_mesh(np.vstack([v, [[5.0, 5.0, 5.0]]]), t)
    bad = v.copy()
    bad[3, 1] = np.nan
    with pytest.raises(ValueError, match="vertices"):
        interpolating_control_mesh(bad, t)
    with pytest.raises(ValueError, match="triangles"):
        interpolating_control_mesh(v, t + len(v))
    with pytest.raises(ValueError, match="non-manifold"):
        interpolating_control_mesh(v, np.vstack([t, t[:1]]))
