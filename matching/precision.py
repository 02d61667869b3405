r"""The variance factor of LSM matches from independent neighbouring windows.

LSM's covariance :math:`\sigma_0^2 N^{-1}` (Gruen 1985) holds for white noise and a
model that fits.  Real photographs add correlated noise (demosaicing, compression:
fewer independent observations than pixels), blur and shading differences between
the views and the affine model's own error, none of which :math:`\sigma_0` sees.  The
data measure them where the scene is smooth: each accepted match :math:`x_i` is
compared with the value a local quadratic mapping, fitted to the matches of the
*independent* windows around it (centres between one patch side and ``radius_px``
away, so that no pixel of its own window is in theirs), predicts at its centre,

.. math::

    d_i = x_i - \hat x_i, \qquad
    E\,|d_i|^2 = k^2 \left(\operatorname{tr}\Sigma_i + v_{0,i}\,
    \overline{\operatorname{tr}\Sigma_j}\right),

:math:`v_{0,i}` the fit's variance factor at the centre (:math:`(X^\mathsf{T}X)^{-1}_{00}`,
grown by :math:`n_i / n_{eff}`: neighbours closer than a patch share pixels, and the
ring holds about :math:`n_{eff} = \pi(R^2 - s^2)/s^2` independent windows of side s).
The variance factor :math:`k^2`, estimated robustly as the median of
:math:`r_i = |d_i|^2 / E_0|d_i|^2` over its Gaussian value (ln 2 for full covariances,
0.455 -- χ²₁'s median -- for the rank-1 ones of an epipolar constraint), is the
factor by which the reported variances must grow (a variance-component estimate from
redundant observations, Förstner 1979); the matches' covariances are then
:math:`k^2 \Sigma`.  Depth edges and surfaces curved more than a
quadratic over ``radius_px`` inflate some :math:`d_i`; the median ignores them while
they are fewer than half (``used`` marks the residuals within the χ²₂ 99 % point).
What the local fit cannot see is an error that is smooth over the radius (a relief
of the scene itself is not a matching error).

Unlike forward-backward matching (:mod:`matching.consistency`), whose two matches read
the same pixels and so share their noise, the windows compared here share none.

References
----------
.. [1] A. W. Gruen, "Adaptive least squares correlation: a powerful image matching
   technique", South African Journal of Photogrammetry, Remote Sensing and
   Cartography 14(3), 175-187 (1985).
.. [2] W. Förstner, "Ein Verfahren zur Schätzung von Varianz- und Kovarianzkomponenten",
   Allgemeine Vermessungs-Nachrichten 86, 446-453 (1979).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from scipy.spatial import cKDTree

from matching.validate import TOL, check_shape

numba.config.THREADING_LAYER_PRIORITY = ["omp", "workqueue", "tbb"]

#: χ²(2 dof) 99 % point.
_CHI2_2_99 = 9.21
#: Fewer independent neighbours than this: no prediction (6 unknowns per axis).
_MIN_NEIGHBOURS = 12


@dataclass(frozen=True)
class VarianceFactor:
    """Result of :func:`variance_factor` (arrays over the N matches).

    Attributes
    ----------
    factor : float
        ``k²`` (NaN: fewer than 30 predictions).
    residual : (N, 2) float64
        ``d = x - x̂``, px (NaN: not predicted).
    expected : (N,) float64
        Reported ``E|d|²`` before the factor, px².
    used : (N,) bool
        Matches in the estimate (predicted, not trimmed).
    """

    factor: float
    residual: np.ndarray
    expected: np.ndarray
    used: np.ndarray


@numba.njit(parallel=True, nogil=True, cache=True, error_model="numpy")
def _local_quadratic(points, values, var, starts, nbrs, min_nb, det_tol, pred, v0, nbvar):
    """Quadratic fit of ``values`` over each point's neighbours ``nbrs[starts[i]:...]``."""
    for i in numba.prange(len(points)):
        s, e = starts[i], starts[i + 1]
        if e - s < min_nb:
            continue
        a = np.zeros((6, 6))
        b = np.zeros((6, 2))
        acc = 0.0
        for t in range(s, e):
            j = nbrs[t]
            dx = points[j, 0] - points[i, 0]
            dy = points[j, 1] - points[i, 1]
            row = np.array([1.0, dx, dy, dx * dx, dx * dy, dy * dy])
            for r in range(6):
                for c in range(6):
                    a[r, c] += row[r] * row[c]
                b[r, 0] += row[r] * values[j, 0]
                b[r, 1] += row[r] * values[j, 1]
            acc += var[j]
        scale = a[0, 0]
        if not np.linalg.det(a / scale) > det_tol:
            continue
        inv = np.linalg.inv(a)
        coef = inv @ b
        pred[i, 0] = coef[0, 0]
        pred[i, 1] = coef[0, 1]
        v0[i] = inv[0, 0]
        nbvar[i] = acc / (e - s)


def variance_factor(points, positions, cov, valid=None, *, patch: int = 15,
                    radius_px: float | None = None) -> VarianceFactor:
    """Estimate the variance factor of LSM matches (module docstring).

    Parameters
    ----------
    points : (N, 2) array_like
        Template window centres, px.
    positions : (N, 2) array_like
        Matched positions in the search image, px.
    cov : (N, 2, 2) array_like
        Reported covariances, px².
    valid : (N,) bool, optional
        Matches to use (default: all finite).
    patch : int
        Patch side, px: neighbours closer than this share pixels and are left out.
    radius_px : float, optional
        Outer radius of the neighbourhood, px (default 2.5 ``patch``: the ring between
        one and 2.5 patch sides holds ~5 windows' worth of independent matches).

    Returns
    -------
    VarianceFactor
    """
    points = check_shape(points, "(N, 2)", "points", dtype=np.float64)
    positions = check_shape(positions, "(N, 2)", "positions", dtype=np.float64)
    cov = check_shape(cov, "(N, 2, 2)", "cov", dtype=np.float64)
    n = len(points)
    if len(positions) != n or len(cov) != n:
        raise ValueError(f"points, positions and cov must have the same length, got {n}, "
                         f"{len(positions)}, {len(cov)}")
    outer = 2.5 * patch if radius_px is None else float(radius_px)
    if not (np.isfinite(outer) and outer > patch):
        raise ValueError(f"radius_px must exceed the patch side {patch}, got {radius_px!r}")
    var = np.trace(cov, axis1=1, axis2=2)
    ok = (np.isfinite(points).all(1) & np.isfinite(positions).all(1) & np.isfinite(var))
    if valid is not None:
        ok &= np.asarray(valid, dtype=bool)
    idx = np.flatnonzero(ok)
    residual = np.full((n, 2), np.nan)
    expected = np.full(n, np.nan)
    used = np.zeros(n, bool)
    if len(idx) < 30:
        return VarianceFactor(float("nan"), residual, expected, used)
    p = np.ascontiguousarray(points[idx])
    pairs = cKDTree(p).query_pairs(outer, output_type="ndarray")
    d = np.linalg.norm(p[pairs[:, 0]] - p[pairs[:, 1]], axis=1)
    pairs = pairs[d >= patch]  # independent windows only
    both = np.concatenate([pairs, pairs[:, ::-1]])
    order = np.argsort(both[:, 0], kind="stable")
    nbrs = np.ascontiguousarray(both[order, 1], dtype=np.int64)
    starts = np.zeros(len(idx) + 1, np.int64)
    np.cumsum(np.bincount(both[:, 0], minlength=len(idx)), out=starts[1:])
    pred = np.full((len(idx), 2), np.nan)
    v0 = np.full(len(idx), np.nan)
    nbvar = np.full(len(idx), np.nan)
    _local_quadratic(p, np.ascontiguousarray(positions[idx]), np.ascontiguousarray(var[idx]),
                     starts, nbrs, _MIN_NEIGHBOURS, TOL.zero, pred, v0, nbvar)
    # neighbours closer than a patch share pixels, so their errors are correlated: the
    # ring holds about ring_area / patch² independent windows, not its n matches, and the
    # fit's variance grows by n / that (white-noise warps: k² 1.28 -> ~1 with it)
    count = np.diff(starts).astype(np.float64)
    ring = np.pi * (outer**2 - patch**2)
    inflation = np.maximum(1.0, count * patch**2 / ring)
    res = positions[idx] - pred
    exp = var[idx] + v0 * nbvar * inflation
    residual[idx] = res
    expected[idx] = exp
    r = np.sum(res**2, axis=1) / exp
    good = np.isfinite(r)
    if good.sum() < 30:
        return VarianceFactor(float("nan"), residual, expected, used)
    # robust: the median of r against its value for Gaussian errors -- half a chi-square
    # of 2 dof (ln 2) for full covariances, a chi-square of 1 dof (0.455) for the rank-1
    # ones of an epipolar constraint -- so that depth edges and curvature beyond the
    # quadratic (which can be most of a temple's facade) do not set the factor
    rank1 = np.abs(np.linalg.det(cov[idx])) <= 1e-9 * var[idx] ** 2
    ref = np.where(rank1, 0.45493642, np.log(2.0))
    k2 = float(np.median(r[good] / ref[good]))
    keep = good & (r <= _CHI2_2_99 * k2)
    used[idx[keep]] = True
    return VarianceFactor(k2, residual, expected, used)
