"""Look-at cameras and ray casting: the one helper behind the synthetic scenes
(:mod:`pipeline.scenes`) and the renders of meshes (:mod:`pipeline.render`).

Cameras follow OpenCV: world→camera ``x_c = R X + t``, image x right, y down, the camera
looking along +z.  :func:`look_at_rotation` builds ``R`` from the viewing direction
(rows: right, down, forward; right = forward × up), :func:`look_at` from a position and a
target, :func:`direction` gives the unit vector of an azimuth about +z from +x and an
elevation above the xy-plane.  :class:`RayCaster` wraps open3d's CPU
``RaycastingScene`` (Embree) around one mesh, with a float64 refinement of the hits by
Möller–Trumbore (T. Möller, B. Trumbore, "Fast, minimum storage ray-triangle
intersection", Journal of Graphics Tools 2(1), 21–28, 1997).
"""

from __future__ import annotations

import math

import numpy as np

#: Denominator guard of the float64 ray/triangle refinement.
ZERO = 1e-300


def direction(azimuth_deg: float, elevation_deg: float) -> np.ndarray:
    """Unit vector ``(3,)`` at ``azimuth_deg`` about +z from +x, ``elevation_deg`` above xy."""
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    return np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])


def look_at_rotation(forward: np.ndarray, up=(0.0, 0.0, 1.0),
                     fallback_right: np.ndarray | None = None) -> np.ndarray:
    """World→camera rotation ``(3, 3)`` of a camera looking along the unit ``forward``.

    Rows: right = forward × up (normalised), down = forward × right, forward; image y
    points down.  ``fallback_right`` is used when ``forward`` is (nearly, 1e-6) parallel
    to ``up``, where the cross product has no direction; without one that is an error.
    """
    forward = np.asarray(forward, dtype=np.float64)
    right = np.cross(forward, np.asarray(up, dtype=np.float64))
    if np.linalg.norm(right) < 1e-6:
        if fallback_right is None:
            raise ValueError("look_at_rotation: forward is parallel to up; give fallback_right")
        right = np.asarray(fallback_right, dtype=np.float64)
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    return np.stack([right, down, forward])


def look_at(position: np.ndarray, target: np.ndarray, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """World→camera rotation of a camera at ``position (3,)`` looking at ``target (3,)``."""
    forward = target - position
    return look_at_rotation(forward / np.linalg.norm(forward), up)


class RayCaster:
    """open3d's CPU ``RaycastingScene`` around one mesh, with float64 refinement of hits.

    Parameters
    ----------
    vertices : (V, 3) float64
        Kept in float64 for :meth:`refine`; the scene holds them in float32.
    triangles : (F, 3) int
    """

    def __init__(self, vertices: np.ndarray, triangles: np.ndarray):
        import open3d as o3d

        self.vertices = np.asarray(vertices, dtype=np.float64)
        self.triangles = np.asarray(triangles, dtype=np.int64)
        self._scene = o3d.t.geometry.RaycastingScene()
        self._scene.add_triangles(o3d.core.Tensor(self.vertices.astype(np.float32)),
                                  o3d.core.Tensor(self.triangles.astype(np.uint32)))

    def cast_rays(self, rays: np.ndarray) -> dict[str, np.ndarray]:
        """open3d's hits of ``rays (..., 6) float32`` (origin, direction) as numpy arrays,
        flattened: ``t_hit`` (inf on a miss), ``primitive_ids``, ``primitive_uvs``,
        ``primitive_normals``, ``geometry_ids``."""
        import open3d as o3d

        hits = self._scene.cast_rays(o3d.core.Tensor(np.asarray(rays).reshape(-1, 6)))
        return {key: value.numpy() for key, value in hits.items()}

    def cast(self, origin: np.ndarray, directions: np.ndarray) -> dict:
        """Cast rays from one ``origin (3,)``; return ``t (N,) float32`` (inf on a miss),
        ``ids (N,) int64`` (-1 on a miss) and barycentric ``uv (N, 2) float32``
        (point = (1-u-v) v0 + u v1 + v v2)."""
        import open3d as o3d

        rays = np.empty((len(directions), 6), dtype=np.float32)
        rays[:, :3] = np.broadcast_to(origin, (len(directions), 3))
        rays[:, 3:] = directions
        hit = self._scene.cast_rays(o3d.core.Tensor(rays))
        t = hit["t_hit"].numpy()
        ids = hit["primitive_ids"].numpy().astype(np.int64)
        ids[~np.isfinite(t)] = -1
        return {"t": t, "ids": ids, "uv": hit["primitive_uvs"].numpy()}

    def refine(self, origin: np.ndarray, directions: np.ndarray, ids: np.ndarray) -> np.ndarray:
        """Float64 ray parameter of the intersection with triangle ``ids`` (Möller–Trumbore).

        ``origin (3,) or (N, 3)``, ``directions (N, 3)``, ``ids (N,)`` all valid; returns ``(N,)``.
        """
        tri = self.vertices[self.triangles[ids]]  # (N, 3, 3)
        e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
        p = np.cross(directions, e2)
        det = np.einsum("ij,ij->i", e1, p)
        q = np.cross(origin - tri[:, 0], e1)
        det = np.where(np.abs(det) > ZERO, det, ZERO)
        return np.einsum("ij,ij->i", e2, q) / det
