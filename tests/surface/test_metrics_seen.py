"""Which points on a surface the cameras see (``surface.metrics.seen_by_cameras``)."""

from __future__ import annotations

import numpy as np


def test_a_camera_sees_the_near_cap_of_a_sphere_and_nothing_behind_it():
    import open3d as o3d

    from matching.cameras import Camera
    from surface.metrics import sample_mesh, seen_by_cameras

    sphere = o3d.geometry.TriangleMesh.create_sphere(1.0, 60)
    v, t = np.asarray(sphere.vertices), np.asarray(sphere.triangles, np.int64)
    K = np.array([[400.0, 0, 320], [0, 400.0, 240], [0, 0, 1]])
    # camera on the +z axis at 10 radii looking down -z (x_c = R X + t, centre (0, 0, 10))
    R = np.diag([1.0, -1.0, -1.0])
    camera = Camera(K, np.zeros(0), R, -R @ np.array([0.0, 0.0, 10.0]), 640, 480)
    points = sample_mesh(v, t, 4_000, seed=0)
    seen = seen_by_cameras(v, t, points, [camera])
    # seen: the cap within the tangent cone from 10 radii, z > 1/10 (the chords' facets
    # blur the rim by well under 0.05)
    z = points[:, 2]
    assert seen[z > 0.15].all() and not seen[z < 0.05].any()
    # a camera looking away sees nothing
    away = Camera(K, np.zeros(0), np.eye(3), -np.array([0.0, 0.0, 10.0]), 640, 480)
    assert not seen_by_cameras(v, t, points, [away]).any()
