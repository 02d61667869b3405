r"""Two- and multi-view triangulation with 3D covariance propagation.

For a point :math:`X` seen at pixels :math:`x_v` in views :math:`v`, the maximum-likelihood
estimate under Gaussian image noise with covariances :math:`\Sigma_v` minimises

.. math::

    E(X) = \sum_v r_v^T \Sigma_v^{-1} r_v, \qquad r_v = x_v - \pi_v(X),

with :math:`\pi_v` the full projection of view :math:`v`, lens distortion
included.  The start is the linear (DLT) solution of Hartley & Zisserman [1]_
§12.2 on undistorted, normalised image coordinates, :math:`A \tilde X = 0`
with two rows :math:`x\,p^{3T} - p^{1T}`, :math:`y\,p^{3T} - p^{2T}` per view,
solved in its inhomogeneous form (:math:`\tilde X = (X, 1)`, linear least squares)
after centring and scaling the world frame (Hartley's conditioning).  Gauss-Newton then
refines all points at once: with :math:`J_v = \partial \pi_v / \partial X` (2×3),

.. math::

    H = \sum_v J_v^T \Sigma_v^{-1} J_v, \qquad
    g = \sum_v J_v^T \Sigma_v^{-1} r_v, \qquad
    X \leftarrow X + H^{-1} g,

a 3×3 system per point, solved as one batched array operation.  At the solution,
first-order propagation gives :math:`\Sigma_X = H^{-1} = (J^T W J)^{-1}` ([1]_ §5.2.1,
Result 5.10), and :math:`E(X)` follows a :math:`\chi^2` law with :math:`2V - 3` degrees of
freedom, the test for a large reprojection error.

Rejection reasons (``Triangulation.reason``, names in :data:`REASON_NAMES`; the first
in this order wins): 0 ``ok``; 1 ``too_few_views``, seen in fewer than two views;
2 ``ill_conditioned``, rays (nearly) parallel, a point at infinity or a non-finite result
(cond(H) > ``TOL.triangulation_cond_max``); 3 ``behind_camera``, depth <= 0 in a view that
sees the point; 4 ``large_reprojection``, :math:`E(X)` above the :math:`\chi^2_{2V-3}`
quantile ``reject_p``, or an RMS error above ``max_reprojection_px``.

References
----------
.. [1] R. Hartley and A. Zisserman, "Multiple View Geometry in Computer
   Vision", 2nd ed., Cambridge University Press (2004).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from matching.cameras import Camera
from matching.validate import TOL, check_shape

__all__ = [
    "Triangulation",
    "REASON_NAMES",
    "OK",
    "TOO_FEW_VIEWS",
    "ILL_CONDITIONED",
    "BEHIND_CAMERA",
    "LARGE_REPROJECTION",
    "triangulate_pair",
    "triangulate_multiview",
    "observations_from_tracks",
]

OK, TOO_FEW_VIEWS, ILL_CONDITIONED, BEHIND_CAMERA, LARGE_REPROJECTION = range(5)
#: Rejection code -> name.
REASON_NAMES = {
    OK: "ok",
    TOO_FEW_VIEWS: "too_few_views",
    ILL_CONDITIONED: "ill_conditioned",
    BEHIND_CAMERA: "behind_camera",
    LARGE_REPROJECTION: "large_reprojection",
}
#: Gauss-Newton converges quadratically from the DLT start; 10 steps is ample.
_MAX_ITERATIONS = 10


@dataclass(frozen=True, eq=False)
class Triangulation:
    """Triangulated points with their precision.

    Attributes
    ----------
    points : (N, 3) float64, scene units
        NaN where the point could not be computed (``too_few_views``,
        non-finite); otherwise filled even for rejected points.
    cov : (N, 3, 3) float64, scene units²
        First-order covariance :math:`(J^T W J)^{-1}`.  When no image
        covariance was given it is the covariance for 1 px isotropic image
        noise: multiply by σ_px².
    sigma : (N,) float64, scene units
        Square root of the largest eigenvalue of ``cov``: the standard
        deviation along the worst-determined direction (the depth direction
        for a stereo pair).
    reprojection_error : (N,) float64, px
        RMS over the observing views of the residual length |x_v − π_v(X)|,
        in the observed (distorted) image.
    chi2 : (N,) float64
        :math:`\\sum_v r_v^T \\Sigma_v^{-1} r_v`, dimensionless.
    n_views : (N,) int64
        Number of views that see the point.
    valid : (N,) bool
        ``reason == OK``.
    reason : (N,) int8
        Codes of :data:`REASON_NAMES`.
    """

    points: np.ndarray
    cov: np.ndarray
    sigma: np.ndarray
    reprojection_error: np.ndarray
    chi2: np.ndarray
    n_views: np.ndarray
    valid: np.ndarray
    reason: np.ndarray

    def __len__(self) -> int:
        return len(self.points)

    def reason_counts(self) -> dict[str, int]:
        """Number of points per reason name (zero counts left out)."""
        codes, counts = np.unique(self.reason, return_counts=True)
        return {REASON_NAMES[int(c)]: int(n) for c, n in zip(codes, counts, strict=True)}


# ----------------------------------------------------------------- public API
def triangulate_pair(cam_left: Camera, cam_right: Camera, x_left, x_right, cov_left=None,
                     cov_right=None, refine: bool = True, reject_p: float | None = 0.999,
                     max_reprojection_px: float | None = None) -> Triangulation:
    """Triangulate corresponding pixels of two views.

    Parameters
    ----------
    cam_left, cam_right : Camera
    x_left, x_right : (N, 2) float64, px
        Observed (distorted) pixel coordinates, OpenCV convention.
    cov_left, cov_right : (N, 2, 2) float64, px², optional
        Covariance of each observation (e.g. LSM's σ0²(AᵀA)⁻¹ of the shift;
        the template position can be given a small or zero-like covariance
        only if it is positive definite).  Default: identity (1 px).
    refine : bool
        Gauss-Newton refinement after the linear solution.
    reject_p : float or None
        Probability of the χ² test on the weighted residual (2V − 3 = 1
        degree of freedom for a pair); ``None`` disables the test.
    max_reprojection_px : float, optional
        Also reject points whose RMS reprojection error exceeds this.

    Returns
    -------
    Triangulation
    """
    x_left = check_shape(x_left, "(N, 2)", "x_left", dtype=np.float64)
    x_right = check_shape(x_right, "(N, 2)", "x_right", dtype=np.float64)
    if len(x_left) != len(x_right):
        raise ValueError(f"x_left and x_right must have the same length, got {len(x_left)} "
                         f"and {len(x_right)}")
    n = len(x_left)
    cov = None
    if cov_left is not None or cov_right is not None:
        eye = np.broadcast_to(np.eye(2), (n, 2, 2))
        cl = eye if cov_left is None else check_shape(cov_left, "(N, 2, 2)", "cov_left",
                                                      dtype=np.float64)
        cr = eye if cov_right is None else check_shape(cov_right, "(N, 2, 2)", "cov_right",
                                                       dtype=np.float64)
        if len(cl) != n or len(cr) != n:
            raise ValueError(f"cov_left and cov_right must have length {n}, got {len(cl)} "
                             f"and {len(cr)}")
        cov = np.stack([cl, cr], axis=1)
    return triangulate_multiview([cam_left, cam_right], np.stack([x_left, x_right], axis=1),
                                 cov, refine=refine, reject_p=reject_p,
                                 max_reprojection_px=max_reprojection_px)


def triangulate_multiview(cameras: Sequence[Camera], observations, cov=None,
                          refine: bool = True, reject_p: float | None = 0.999,
                          max_reprojection_px: float | None = None) -> Triangulation:
    """Triangulate points seen in two or more of V views.

    Parameters
    ----------
    cameras : sequence of V Camera
    observations : (N, V, 2) float64, px
        Observed (distorted) pixels; NaN (both coordinates) where view v does
        not see point n.  Build it from track index arrays with
        :func:`observations_from_tracks`.
    cov : (N, V, 2, 2) float64, px², optional
        Observation covariances (entries of unseen observations are ignored).
        Default: identity (1 px isotropic).
    refine, reject_p, max_reprojection_px :
        As in :func:`triangulate_pair`; the χ² test has 2V − 3 degrees of
        freedom, V the number of views seeing the point.

    Returns
    -------
    Triangulation
    """
    cameras = list(cameras)
    for i, cam in enumerate(cameras):
        if not isinstance(cam, Camera):
            raise ValueError(f"cameras[{i}] must be a Camera, got {type(cam).__name__}")
    obs = check_shape(observations, "(N, V, 2)", "observations", dtype=np.float64)
    n, n_cams = obs.shape[:2]
    if n_cams != len(cameras):
        raise ValueError(f"observations has {n_cams} views but {len(cameras)} cameras were given")
    seen = np.all(np.isfinite(obs), axis=2)  # (N, V)
    if np.any(np.isfinite(obs).any(axis=2) & ~seen):
        raise ValueError("observations has entries with one NaN and one finite coordinate")
    weights = _weights(cov, seen, n, n_cams)
    if reject_p is not None and not 0.0 < reject_p < 1.0:
        raise ValueError(f"reject_p must be in (0, 1) or None, got {reject_p}")
    if max_reprojection_px is not None and not max_reprojection_px > 0:
        raise ValueError(f"max_reprojection_px must be positive, got {max_reprojection_px}")

    n_views = seen.sum(axis=1)
    enough = n_views >= 2
    points = np.full((n, 3), np.nan)
    points[enough] = _dlt(cameras, obs[enough], seen[enough])
    if refine:
        points = _gauss_newton(cameras, obs, seen, weights, points)
    return _assess(cameras, obs, seen, weights, points, n_views, reject_p, max_reprojection_px)


def observations_from_tracks(point_index, view_index, xy, n_points: int,
                             n_views: int) -> np.ndarray:
    """Scatter track observations into the dense ``(N, V, 2)`` array with NaN holes.

    Parameters
    ----------
    point_index, view_index : (M,) int
        Which point and which view each observation belongs to.
    xy : (M, 2) float64, px
    n_points, n_views : int

    Returns
    -------
    (n_points, n_views, 2) float64
    """
    xy = check_shape(xy, "(M, 2)", "xy", dtype=np.float64)
    point_index = np.asarray(point_index, dtype=np.int64).reshape(-1)
    view_index = np.asarray(view_index, dtype=np.int64).reshape(-1)
    if not (len(point_index) == len(view_index) == len(xy)):
        raise ValueError("point_index, view_index and xy must have the same length")
    if len(xy) and (point_index.min() < 0 or point_index.max() >= n_points
                    or view_index.min() < 0 or view_index.max() >= n_views):
        raise ValueError("point_index or view_index out of range")
    out = np.full((n_points, n_views, 2), np.nan)
    out[point_index, view_index] = xy
    return out


# ----------------------------------------------------------------- kernels
def _weights(cov, seen: np.ndarray, n: int, n_cams: int) -> np.ndarray:
    """(N, V, 2, 2) inverse covariances; identity where none is given or unseen."""
    weights = np.broadcast_to(np.eye(2), (n, n_cams, 2, 2)).copy()
    if cov is None:
        return weights
    cov = check_shape(cov, "(N, V, 2, 2)", "cov", dtype=np.float64)
    if cov.shape[:2] != (n, n_cams):
        raise ValueError(f"cov must have shape ({n}, {n_cams}, 2, 2), got {cov.shape}")
    c = cov[seen]
    if not np.all(np.isfinite(c)):
        raise ValueError("cov contains NaN/inf for observed points")
    if not np.allclose(c, np.swapaxes(c, 1, 2), rtol=1e-9, atol=TOL.zero):
        raise ValueError("cov must be symmetric")
    det = c[:, 0, 0] * c[:, 1, 1] - c[:, 0, 1] * c[:, 1, 0]
    if np.any(c[:, 0, 0] <= 0) or np.any(det <= 0):
        bad = int(np.count_nonzero((c[:, 0, 0] <= 0) | (det <= 0)))
        raise ValueError(f"cov must be positive definite; {bad} observation covariances are not")
    weights[seen] = np.linalg.inv(c)
    return weights


def _conditioning(cameras: Sequence[Camera]) -> np.ndarray:
    """(4, 4) T mapping conditioned coordinates to world, X = T X' (centre, scale)."""
    centers = np.stack([cam.center for cam in cameras])
    origin = centers.mean(axis=0)
    scale = float(np.linalg.norm(centers - origin, axis=1).mean())
    scale = scale if scale > TOL.zero else 1.0  # all centres equal: leave the unit alone
    T = np.eye(4)
    T[:3, :3] *= scale
    T[:3, 3] = origin
    return T


def _dlt(cameras: Sequence[Camera], obs: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """Linear triangulation (H&Z §12.2) of (N, V, 2) observations; NaN at infinity."""
    n, n_cams = seen.shape
    T = _conditioning(cameras)
    A = np.zeros((n, 2 * n_cams, 4))
    for v, cam in enumerate(cameras):  # loop over views, not points
        rows = seen[:, v]
        if not rows.any():
            continue
        xn = cam.normalized(obs[rows, v])  # (M, 2) undistorted, K removed
        P = np.hstack([cam.R, cam.t[:, None]]) @ T  # (3, 4) in conditioned frame
        a = xn[:, :, None] * P[2][None, None, :] - P[None, :2, :]  # (M, 2, 4)
        A[rows, 2 * v:2 * v + 2] = a / np.linalg.norm(a, axis=2, keepdims=True)
    # Inhomogeneous form (H&Z §12.2, w = 1): least squares A[:, :3] X = -A[:, 3]
    # through 3×3 normal equations, 2x faster than a batched 4×4 SVD; a point
    # at infinity makes them singular and is returned as NaN.
    A3 = A[:, :, :3]
    M = np.einsum("nki,nkj->nij", A3, A3)  # (N, 3, 3)
    b = -np.einsum("nki,nk->ni", A3, A[:, :, 3])  # (N, 3)
    Xc, ok = _solve_3x3(M, b)
    X = Xc @ T[:3, :3].T + T[:3, 3]
    X[~ok] = np.nan
    return X


def _normal_equations(cameras, obs, seen, weights, points, active):
    """Sums over the views for the ``active`` points (M of them).

    Returns H (M, 3, 3), g (M, 3), χ² (M,), the sum of squared residual
    lengths (M,) in px², and whether the point is behind a seeing camera (M,).
    """
    m = int(active.sum())
    H, g, energy = np.zeros((m, 3, 3)), np.zeros((m, 3)), np.zeros(m)
    sq_sum, behind = np.zeros(m), np.zeros(m, dtype=bool)
    X_active, obs_active, w_active = points[active], obs[active], weights[active]
    for v, cam in enumerate(cameras):
        rows = seen[active, v]
        if not rows.any():
            continue
        X = X_active[rows]
        proj, J = cam.project(X, with_jacobian=True)  # (M_v, 2), (M_v, 2, 3)
        r = obs_active[rows, v] - proj
        W = w_active[rows, v]
        JtW = np.einsum("mki,mkl->mil", J, W)  # (M_v, 3, 2)
        H[rows] += JtW @ J
        g[rows] += np.einsum("mil,ml->mi", JtW, r)
        energy[rows] += np.einsum("mk,mkl,ml->m", r, W, r)
        sq_sum[rows] += np.einsum("mk,mk->m", r, r)
        behind[rows] |= cam.depth(X) <= 0
    return H, g, energy, sq_sum, behind


def _solve_3x3(H: np.ndarray, g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Solve H s = g for (M, 3, 3) symmetric H by the adjugate; zero step where H is singular.

    A cheap conditioning proxy replaces the eigenvalues inside the loop:
    det(H) / (tr(H)/3)³ ≈ λ_min λ_mid / λ_max² (the final test in ``_assess``
    uses the true condition number).
    """
    adj = np.cross(H[:, [1, 2, 0]], H[:, [2, 0, 1]])  # rows of the adjugate (transposed)
    det = np.einsum("mi,mi->m", H[:, 0], adj[:, 0])
    trace = np.trace(H, axis1=1, axis2=2)
    with np.errstate(divide="ignore", invalid="ignore"):
        ok = det / (trace / 3.0) ** 3 > 1.0 / TOL.triangulation_cond_max
    ok &= np.isfinite(det)
    step = np.zeros_like(g)
    step[ok] = np.einsum("mji,mj->mi", adj[ok], g[ok]) / det[ok, None]
    return step, ok


def _gauss_newton(cameras, obs, seen, weights, points):
    """Batched Gauss-Newton on every finite point; returns the refined (N, 3)."""
    points = points.copy()
    active = np.all(np.isfinite(points), axis=1)
    scale = _conditioning(cameras)[0, 0]
    for _ in range(_MAX_ITERATIONS):
        if not active.any():
            break
        H, g = _normal_equations(cameras, obs, seen, weights, points, active)[:2]
        step, solvable = _solve_3x3(H, g)
        idx = np.flatnonzero(active)
        points[idx] += step
        small = np.linalg.norm(step, axis=1) <= TOL.triangulation_step_rel * scale
        active[idx[small | ~solvable]] = False
    return points


def _assess(cameras, obs, seen, weights, points, n_views, reject_p, max_reprojection_px):
    """Covariance, σ, residuals and the rejection reason of every point."""
    n = len(points)
    finite = np.all(np.isfinite(points), axis=1)
    H, _, energy, sq_finite, behind_finite = _normal_equations(cameras, obs, seen, weights,
                                                                points, finite)
    cov = np.full((n, 3, 3), np.nan)
    chi2_value = np.full(n, np.nan)
    chi2_value[finite] = energy
    # one eigen-decomposition of H gives both the condition number and σ:
    # the eigenvalues of cov = H⁻¹ are the reciprocals of H's
    eig = np.linalg.eigvalsh(H)  # (M, 3) ascending
    with np.errstate(divide="ignore", invalid="ignore"):
        cond_h = np.where(eig[:, 0] > 0, eig[:, -1] / eig[:, 0], np.inf)
    well = np.zeros(n, dtype=bool)
    well[finite] = np.isfinite(cond_h) & (cond_h < TOL.triangulation_cond_max)
    ok_h = well[finite]
    cov[well] = np.linalg.inv(H[ok_h])
    sigma = np.full(n, np.nan)
    sigma[well] = 1.0 / np.sqrt(eig[ok_h, 0])

    rms = np.full(n, np.nan)
    rms[finite] = np.sqrt(sq_finite / n_views[finite])
    behind = np.zeros(n, dtype=bool)
    behind[finite] = behind_finite

    large = np.zeros(n, dtype=bool)
    if reject_p is not None:
        dof = np.maximum(2 * n_views - 3, 1)
        levels, inverse = np.unique(dof, return_inverse=True)
        large |= chi2_value > chi2.ppf(reject_p, levels)[inverse]
    if max_reprojection_px is not None:
        large |= rms > max_reprojection_px

    reason = np.full(n, OK, dtype=np.int8)
    reason[large] = LARGE_REPROJECTION
    reason[behind] = BEHIND_CAMERA
    reason[~well] = ILL_CONDITIONED
    reason[n_views < 2] = TOO_FEW_VIEWS
    return Triangulation(points=points, cov=cov, sigma=sigma, reprojection_error=rms,
                         chi2=chi2_value, n_views=n_views.astype(np.int64),
                         valid=reason == OK, reason=reason)
