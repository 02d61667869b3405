"""Control nets of Loop's surface over small closed meshes, shared by the tests of the
face merging (``surface.bezier_merge``, ``surface.bezier_quad``)."""

from __future__ import annotations

import numpy as np

from surface import bezier


def ellipsoid_net():
    """Loop's control net over an icosphere (open3d, 4 subdivisions) scaled to the
    ellipsoid of semi-axes 1, 0.7, 0.5: vertices of valence 4, 5 and 6, so the patches
    around the irregular ones are G1 only."""
    import open3d as o3d

    mesh = o3d.geometry.TriangleMesh.create_sphere(1.0, 4)
    return bezier.control_net(np.asarray(mesh.vertices) * [1.0, 0.7, 0.5],
                              np.asarray(mesh.triangles))
