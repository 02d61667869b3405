r"""Projection, surface normals and visibility by z-buffer for the multi-view check.

* :func:`project`: :math:`x = (P [X\,1])_{1,2} / (P [X\,1])_3` in one numba pass, with
  the Jacobian :math:`(K_{1,2} - x K_3) R / (K X_c)_3`;
* :func:`normals`: PCA normals of the 12 nearest points, oriented towards a viewpoint;
* :func:`zbuffer`: all points splatted into a view (nearest depth per pixel), then a
  minimum filter over the splat spacing closes the gaps between samples; a point is
  hidden in that view when its depth exceeds the buffer by more than the depth change
  a surface at the largest accepted incidence makes across the window;
* :func:`plane_affine`: the template-pixel -> view-k mapping through the point's tangent
  plane (rays of the unit pixel steps cut the plane and are projected into k), the
  initial affine of the further-view LSM.
"""

from __future__ import annotations

import cv2
import numba
import numpy as np
from scipy.spatial import cKDTree

from matching.cameras import Camera
from matching.validate import TOL

__all__ = ["project", "normals", "zbuffer", "plane_affine"]

#: Nearest pair points for the PCA normal (12: a 3x3 grid ring plus slack).
_NORMAL_NEIGHBOURS = 12


def project(camera: Camera, X: np.ndarray, with_jacobian: bool = False):
    """:meth:`Camera.project` for a camera without distortion, in one numba pass.

    ``x = (P [X 1])_{1,2} / (P [X 1])_3`` with ``P = K [R | t]``; the Jacobian is
    ``(K_{1,2} - x K_3) R / (K X_c)_3``.  Agrees with ``cv2.projectPoints`` to rounding
    (~1e-12 px); the consistency step projects every pair point ~50 times per pair
    (cv2: ~3x the cost, numpy's two skinny matmuls ~7 CPU s of a spacing-3 ring).
    Cameras with distortion go through :meth:`Camera.project`.

    Parameters
    ----------
    camera : Camera
    X : (N, 3) float64, scene units
    with_jacobian : bool

    Returns
    -------
    x : (N, 2) float64, px
    J : (N, 2, 3) float64, px per scene unit (only if ``with_jacobian``)
    """
    if camera.has_distortion:
        return camera.project(X, with_jacobian=with_jacobian)
    X = np.ascontiguousarray(X, dtype=np.float64)
    h = np.empty((len(X), 3))
    _homogeneous(X, np.ascontiguousarray(camera.P), h)  # (N, 3) homogeneous pixels
    x = h[:, :2] / h[:, 2:3]
    if not with_jacobian:
        return x
    K = camera.K
    jac = (K[None, :2, :] - x[:, :, None] * K[None, 2:3, :]) / h[:, 2, None, None]  # (N, 2, 3)
    return x, jac @ camera.R


@numba.njit(cache=True, nogil=True, fastmath=False, error_model="numpy")
def _homogeneous(X, P, out):
    """out = [X 1] Pᵀ for (N, 3) X and a 3x4 projection P."""
    for i in range(X.shape[0]):
        x, y, z = X[i, 0], X[i, 1], X[i, 2]
        for r in range(3):
            out[i, r] = P[r, 0] * x + P[r, 1] * y + P[r, 2] * z + P[r, 3]


@numba.njit(cache=True, nogil=True, fastmath=False, error_model="numpy")
def _splat_nearest(X, P, w, h, buf):
    """buf[y w + x] = min(depth) of the points projecting to pixel (x, y) in front."""
    for i in range(X.shape[0]):
        x, y, z = X[i, 0], X[i, 1], X[i, 2]
        hz = P[2, 0] * x + P[2, 1] * y + P[2, 2] * z + P[2, 3]
        if not hz > 0.0:
            continue
        u = np.rint((P[0, 0] * x + P[0, 1] * y + P[0, 2] * z + P[0, 3]) / hz)
        v = np.rint((P[1, 0] * x + P[1, 1] * y + P[1, 2] * z + P[1, 3]) / hz)
        if u >= 0 and u < w and v >= 0 and v < h:
            k = int(v) * w + int(u)
            if hz < buf[k]:
                buf[k] = hz


def normals(points: np.ndarray, towards: np.ndarray) -> np.ndarray:
    """(M, 3) unit PCA normals of the nearest pair points, oriented towards ``towards``."""
    k = min(_NORMAL_NEIGHBOURS, len(points))
    if k < 3:
        return np.full_like(points, np.nan)
    _, idx = cKDTree(points).query(points, k=k)
    nb = points[idx] - points[idx].mean(axis=1, keepdims=True)  # (M, k, 3)
    _, vec = np.linalg.eigh(np.einsum("mki,mkj->mij", nb, nb))
    n = vec[:, :, 0]
    flip = np.einsum("mi,mi->m", n, towards - points) < 0
    n[flip] *= -1
    return n


def zbuffer(camera: Camera, points: np.ndarray, window: int) -> np.ndarray:
    """(H, W) nearest depth of ``points`` splatted into ``camera``, min-filtered.

    Parameters
    ----------
    camera : Camera
    points : (N, 3) float64
    window : int
        Side of the minimum filter, px (the splat spacing, so that the samples'
        gaps are closed).

    Returns
    -------
    (H, W) float64, scene units; +inf where no point falls.
    """
    w, h = camera.size
    buf = np.full(h * w, np.inf)
    if camera.has_distortion:
        depth = camera.depth(points)
        front = depth > 0
        x = np.rint(project(camera, points[front])).astype(np.int64)
        inside = (x[:, 0] >= 0) & (x[:, 0] < w) & (x[:, 1] >= 0) & (x[:, 1] < h)
        np.minimum.at(buf, x[inside, 1] * w + x[inside, 0], depth[front][inside])
    else:  # one pass: project, keep the nearest depth per pixel (K's last row is 0 0 1)
        _splat_nearest(np.ascontiguousarray(points, dtype=np.float64),
                       np.ascontiguousarray(camera.P), int(w), int(h), buf)
    # a square minimum filter is a grey erosion (OpenCV's is ~4x faster than ndimage's;
    # BORDER_REPLICATE is ndimage's mode="nearest", the result is identical)
    return cv2.erode(buf.reshape(h, w), np.ones((int(window), int(window)), np.uint8),
                     borderType=cv2.BORDER_REPLICATE)


def plane_affine(cam_t: Camera, cam_k: Camera, x_t: np.ndarray, X: np.ndarray,
                  normal: np.ndarray) -> np.ndarray:
    """(M, 2, 2) Jacobian of the template-pixel -> view-k mapping through the tangent plane."""
    out = np.empty((len(X), 2, 2))
    base = project(cam_k, X)
    for col, step in enumerate(([1.0, 0.0], [0.0, 1.0])):
        origin, d = cam_t.ray(x_t + step)
        denom = np.einsum("mi,mi->m", d, normal)
        s = np.einsum("mi,mi->m", X - origin, normal) / np.where(np.abs(denom) > TOL.zero,
                                                                 denom, np.nan)
        out[:, :, col] = project(cam_k, origin + s[:, None] * d) - base
    return out
