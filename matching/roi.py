r"""The object, not the scene: the region the cameras look at and a support plane cut.

**Where the cameras look.**  The point closest to all optical axes (centre
:math:`C_i`, unit direction :math:`d_i`) in the least-squares sense solves

.. math::  \Big(\sum_i (I - d_i d_i^\mathsf{T})\Big) X = \sum_i (I - d_i d_i^\mathsf{T}) C_i .

The axes *converge* (a ring, an orbit, a hemisphere of views) when the smallest
eigenvalue of :math:`\tfrac1n\sum_i (I - d_i d_i^\mathsf{T})` is at least
:math:`\sin^2 10^\circ`: the axes then span more than ~10 degrees in every direction
and :math:`X` is determined.  The region is the ball about :math:`X` that the views
see: radius the median over the views of :math:`D_i \sin\alpha_i` (:math:`D_i` the
distance of the camera from :math:`X`, :math:`\alpha_i` half its field of view across
the longer image side).  Otherwise the views form a *path* (walking past a facade,
parallel axes): each view keeps the depth range it actually matched (the 1st to 99th
percentile of the depths of the points it saw) and the region is the union of those
truncated frusta.

**A support plane.**  The largest planes of the kept points (up to three, largest
first; RANSAC, open3d's ``segment_plane`` [1]_, inlier band
:math:`\tau = \max(3\tilde\sigma, 2\tilde s)`: three times the points' median σ, at
least twice their median spacing) are tried as the ground or a table; the first that
lies *under the object* is cut: its normal is within 30 degrees of the cameras' mean
image "up" (:math:`-R_i^\mathsf{T} e_y`, so a facade or a wall the cameras face is never
cut; nothing is cut when that mean is shorter than 0.5: views rolled every way), it
holds at least 5 % of the points, at least 90 % of the other points lie above it (on
the cameras' side), and it reaches past them: at least half its points lie outside the
convex hull of the others' footprint on it (an object's own flat bottom lies inside
its footprint).  Then the points within :math:`\tau` of it and below it go.

References
----------
.. [1] M. A. Fischler and R. C. Bolles, "Random Sample Consensus", Communications of
   the ACM 24(6), 381-395 (1981).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from matching.validate import check_shape

__all__ = ["RoiResult", "axes_convergence", "camera_region", "support_plane", "select_object"]

#: Smallest eigenvalue (per view) of the axes' normal matrix for a convergent capture.
CONVERGENCE_MIN = float(np.sin(np.radians(10.0)) ** 2)
#: Largest angle (degrees) between a support plane's normal and the cameras' "up".
PLANE_UP_DEG = 30.0
#: Smallest share of the points on a support plane.
MIN_PLANE_SHARE = 0.05
#: Planes tried, largest first (a facade's own wall is the largest; the ground next).
MAX_PLANES = 3
#: Points a plane is searched among (a seeded sample when there are more): a support
#: plane holds at least MIN_PLANE_SHARE of them, 2 500 of a sample this size, ample for
#: RANSAC's 3-point draws; its inliers are then every point within the band.
PLANE_SAMPLE = 50_000


@dataclass(frozen=True)
class RoiResult:
    """What :func:`select_object` kept.

    Attributes
    ----------
    keep : (N,) bool
        Points kept.
    method : str
        ``"convergence"`` (a ball about the axes' meeting point) or ``"path"``
        (each view's matched depth range).
    outside : int
        Points outside the cameras' region.
    plane : int
        Points of the support plane (and below it) cut.
    info : dict
        Plain-type figures: centre and radius, or the plane's coefficients, the band.
    """

    keep: np.ndarray
    method: str
    outside: int
    plane: int
    info: dict = field(default_factory=dict)

    def report(self) -> dict:
        return {"roi": self.method, "roi_kept": int(self.keep.sum()),
                "roi_outside": int(self.outside), "roi_support_plane": int(self.plane),
                **self.info}


def _axes(cameras) -> tuple[np.ndarray, np.ndarray]:
    centres = np.array([np.asarray(c.center, dtype=np.float64) for c in cameras])
    directions = np.array([np.asarray(c.R, dtype=np.float64)[2] for c in cameras])  # (V, 3)
    return centres, directions


def axes_convergence(cameras: Sequence) -> tuple[np.ndarray, float]:
    """The point closest to every optical axis and the smallest eigenvalue per view of
    the normal matrix (module docstring; below :data:`CONVERGENCE_MIN`: no meeting point).

    Returns
    -------
    point : (3,) float64
    conditioning : float in [0, 1]
    """
    centres, d = _axes(cameras)
    projector = np.eye(3)[None] - d[:, :, None] * d[:, None, :]  # (V, 3, 3)
    A, b = projector.sum(axis=0), np.einsum("vij,vj->i", projector, centres)
    conditioning = float(np.linalg.eigvalsh(A)[0] / len(centres))
    point = np.linalg.lstsq(A, b, rcond=None)[0]
    return point, conditioning


def _half_field(cam) -> float:
    """Half the field of view across the image's longer side, radians."""
    if cam.width >= cam.height:
        return float(np.arctan2(max(cam.K[0, 2] + 0.5, cam.width - cam.K[0, 2] - 0.5),
                                cam.K[0, 0]))
    return float(np.arctan2(max(cam.K[1, 2] + 0.5, cam.height - cam.K[1, 2] - 0.5),
                            cam.K[1, 1]))


def camera_region(points, cameras: Sequence, views=None) -> tuple[np.ndarray, str, dict]:
    """Points inside the region the cameras look at (module docstring).

    Parameters
    ----------
    points : (N, 3) float64
    cameras : sequence of V Camera
    views : (N, V) bool, optional
        Which views matched each point (the path rule's depth ranges); default every
        view in front of which the point projects into the image.

    Returns
    -------
    inside : (N,) bool
    method : {"convergence", "path"}
    info : dict
    """
    points = check_shape(points, "(N, 3)", "points", dtype=np.float64)
    centre, conditioning = axes_convergence(cameras)
    if conditioning >= CONVERGENCE_MIN:
        distances = [np.linalg.norm(np.asarray(c.center) - centre) for c in cameras]
        radius = float(np.median([dist * np.sin(_half_field(c))
                                  for dist, c in zip(distances, cameras, strict=True)]))
        inside = np.linalg.norm(points - centre, axis=1) <= radius
        return inside, "convergence", {"roi_centre": [round(float(v), 6) for v in centre],
                                       "roi_radius": round(radius, 6),
                                       "roi_conditioning": round(conditioning, 4)}
    inside = np.zeros(len(points), dtype=bool)
    for v, cam in enumerate(cameras):
        depth = cam.depth(points)
        front = depth > 0
        uv = np.full((len(points), 2), -1.0)
        uv[front] = cam.project(points[front])
        seen = front & (uv[:, 0] >= -0.5) & (uv[:, 0] < cam.width - 0.5) & \
            (uv[:, 1] >= -0.5) & (uv[:, 1] < cam.height - 0.5)
        matched = seen if views is None else np.asarray(views)[:, v] & front
        if matched.sum() < 10:
            continue
        lo, hi = np.percentile(depth[matched], [1.0, 99.0])
        inside |= seen & (depth >= lo) & (depth <= hi)
    return inside, "path", {"roi_conditioning": round(conditioning, 4)}


def support_plane(points, sigma, cameras: Sequence, seed: int = 0) -> tuple[np.ndarray, dict]:
    """Points of a support plane under the object and below it (module docstring).

    Parameters
    ----------
    points : (N, 3) float64
    sigma : (N,) float64 or None
        Each point's σ (scene units); None: the band is from the spacing alone.
    cameras : sequence of Camera
    seed : int
        open3d's RANSAC seed (repeatable runs).

    Returns
    -------
    cut : (N,) bool
        True for the points cut (all False when no plane qualifies).
    info : dict
        ``plane`` ``[a, b, c, d]`` (unit normal towards the cameras), ``band``, and
        ``plane_reason`` when a plane was found but kept.
    """
    import open3d as o3d
    from scipy.spatial import cKDTree

    points = check_shape(points, "(N, 3)", "points", dtype=np.float64)
    cut = np.zeros(len(points), dtype=bool)
    if len(points) < 100:
        return cut, {}
    spacing = float(np.median(cKDTree(points).query(points, k=2)[0][:, 1]))
    band = max(3.0 * float(np.median(sigma)) if sigma is not None else 0.0, 2.0 * spacing)
    o3d.utility.random.seed(int(seed))
    centres, _ = _axes(cameras)
    up = np.mean([-np.asarray(c.R, dtype=np.float64)[1] for c in cameras], axis=0)
    pool = np.ones(len(points), dtype=bool)  # not yet in a plane tried
    info, reasons = {"band": round(band, 6)}, []
    if np.linalg.norm(up) <= 0.5:  # views rolled every way (a turntable's top views...)
        info["plane_reason"] = "the cameras share no up direction"
        return cut, info
    rng = np.random.default_rng(seed)
    for _ in range(MAX_PLANES):
        if pool.sum() < 100:
            break
        index = np.flatnonzero(pool)
        # RANSAC's 1 000 draws scored on a sample (~7 CPU-s a plane over 650 000 points,
        # 0.5 over the sample), the plane's points then all those of the pool in its band
        sample = index if len(index) <= PLANE_SAMPLE else np.sort(
            rng.choice(index, PLANE_SAMPLE, replace=False))
        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points[sample]))
        model, inliers = cloud.segment_plane(distance_threshold=band, ransac_n=3,
                                             num_iterations=1000)
        normal, offset = np.asarray(model[:3], dtype=np.float64), float(model[3])
        scale = np.linalg.norm(normal)
        normal, offset = normal / scale, offset / scale
        if np.median(centres @ normal + offset) < 0:  # the cameras' side is positive
            normal, offset = -normal, -offset
        height = points @ normal + offset
        if sample is index:  # all of the pool searched: RANSAC's own inliers, as ever
            on = np.zeros(len(points), dtype=bool)
            on[index[np.asarray(inliers, dtype=np.int64)]] = True
        else:
            on = pool & (np.abs(height) <= band)
        pool &= ~on
        reason = _not_support(points, on, height, normal, up)
        plane = [round(float(v), 6) for v in (*normal, offset)]
        if not reason:
            info["plane"] = plane
            return height <= band, info
        info.setdefault("plane", plane)  # the largest plane, kept
        reasons.append(reason)
    if reasons:
        info["plane_reason"] = "; ".join(reasons)
    return cut, info


def _not_support(points: np.ndarray, on: np.ndarray, height: np.ndarray, normal: np.ndarray,
                 up: np.ndarray) -> str:
    """Why the plane of the points ``on`` is not a support plane ("" when it is one)."""
    angle = float(np.degrees(np.arccos(np.clip(abs(up @ normal) / np.linalg.norm(up), 0, 1))))
    others = ~on
    if angle > PLANE_UP_DEG:
        return f"a plane {angle:.0f} degrees from the cameras' up (a wall, not a floor)"
    if on.mean() < MIN_PLANE_SHARE:
        return f"a level plane with {100 * on.mean():.1f} % of the points"
    if others.sum() < 50 or np.mean(height[others] > 0) < 0.9:
        return "a level plane the other points do not stand on"
    outside = _outside_footprint(points[on], points[others], normal)
    if outside < 0.5:
        return (f"a level plane with {100 * outside:.0f} % of its points beyond the others' "
                "footprint (the object's own flat face)")
    return ""


def _outside_footprint(plane_points: np.ndarray, others: np.ndarray,
                       normal: np.ndarray) -> float:
    """Share of ``plane_points`` outside the convex hull of ``others`` projected on the
    plane (in-plane coordinates)."""
    from scipy.spatial import ConvexHull, Delaunay, QhullError

    basis = np.linalg.svd(np.eye(3) - np.outer(normal, normal))[0][:, :2]  # (3, 2)
    flat = others @ basis
    try:
        hull = Delaunay(flat[ConvexHull(flat).vertices])
    except QhullError:  # the others' footprint is a line: nothing lies inside it
        return 1.0
    return float(np.mean(hull.find_simplex(plane_points @ basis) < 0))


def select_object(points, cameras: Sequence, sigma=None, views=None,
                  plane: bool = True, seed: int = 0) -> RoiResult:
    """The points of the object: inside the cameras' region, support plane cut.

    Parameters
    ----------
    points : (N, 3) float64
    cameras : sequence of V Camera
    sigma : (N,) float64, optional
    views : (N, V) bool, optional
        As :func:`camera_region`.
    plane : bool
        Look for a support plane (:func:`support_plane`).
    seed : int

    Returns
    -------
    RoiResult
    """
    points = check_shape(points, "(N, 3)", "points", dtype=np.float64)
    if len(cameras) < 2:
        raise ValueError(f"select_object needs at least 2 cameras, got {len(cameras)}")
    inside, method, info = camera_region(points, cameras, views)
    keep = inside.copy()
    cut_count = 0
    if plane and keep.sum() >= 100:
        index = np.flatnonzero(keep)
        cut, plane_info = support_plane(points[index], None if sigma is None else
                                        np.asarray(sigma)[index], cameras, seed)
        info.update(plane_info)
        keep[index[cut]] = False
        cut_count = int(cut.sum())
    return RoiResult(keep=keep, method=method, outside=int((~inside).sum()), plane=cut_count,
                     info=info)
