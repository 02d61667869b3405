r"""The variance factor of LSM matches from independent neighbouring windows.

LSM's covariance :math:`\sigma_0^2 N^{-1}` (Gruen 1985) holds for white noise and a model
that fits.  Real photographs add correlated noise (demosaicing, compression), blur and
shading differences between the views and the affine model's own error, none of which
:math:`\sigma_0` sees.  The data measure them by redundancy: two windows whose centres
:math:`p_i, p_j` are at least a patch side apart share no pixel, and each one's affine warp
:math:`W_i(p) = x_i + A_i (p - p_i)` predicts where their midpoint :math:`m` goes.  For any
mapping quadratic between the two centres the predictions agree exactly (the trapezoidal
rule), so a slanted or curved surface gives no disagreement, only the matching errors do:

.. math::

    d_{ij} = W_i(m) - W_j(m), \qquad
    E\,[d_{ij} d_{ij}^\mathsf{T}] = k^2 \left(G_i \Sigma_i G_i^\mathsf{T}
    + G_j \Sigma_j G_j^\mathsf{T}\right),

:math:`\Sigma_i` the reported 6x6 covariance of the warp
(:attr:`matching.lsm.LSMResult.affine_cov`), :math:`G_i` the gradient of :math:`W_i(m)` in
it.  The variance factor :math:`k^2` (a variance-component estimate, Förstner 1979) is the
median of :math:`d^\mathsf{T} E^{-1} d` over its value for Gaussian errors (2 ln 2, the
median of χ²₂): robust to pairs across a depth edge or an occlusion while they are fewer
than half.  Pairs are taken between one and 1.5 patch sides apart.

It cannot see an error both windows share: one smooth over the two (lens distortion,
relief: geometry, not matching error), a bias the same texture gives both, or a relief
finer than a window, which every window smooths alike (``benchmarks/matching.py``'s
rippled vase errs 2.2x the σ with the factor, 6.8x without; forward-backward loops see
even less, 0.54x σ).  Unlike forward-backward matching (:mod:`matching.forward_backward`), whose
two matches read the same pixels and share their noise, the windows compared here share
none.  ``match_pair`` applies one factor per window class (:func:`class_variance_factors`).
Figures: ``docs/decisions/stereo-matching.md``.

References: A. W. Gruen, "Adaptive least squares correlation: a powerful image matching
technique", S. Afr. J. Photogramm. Remote Sens. Cartogr. 14(3), 175-187 (1985);
W. Förstner, "Ein Verfahren zur Schätzung von Varianz- und Kovarianzkomponenten",
Allgemeine Vermessungs-Nachrichten 86, 446-453 (1979).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree
from scipy.stats import chi2

from checks.robust import mad_sigma
from matching.validate import check_shape

#: Pairs between one and this many (mean) patch sides apart.
PAIR_REACH = 1.5
#: At most this many windows enter the estimate (a dense map is thinned on a grid:
#: the factor is one number per pair of images; 20 000 windows give ~10⁵ pairs).
MAX_WINDOWS = 20000


@dataclass(frozen=True)
class VarianceFactor:
    """Result of :func:`midpoint_variance_factor`.

    Attributes
    ----------
    factor : float
        ``k²`` (NaN: fewer than ``min_pairs`` pairs).
    pairs : (P, 2) int64
        Indices of the window pairs compared (into the N matches).
    d2 : (P,) float64
        Their Mahalanobis distances ``dᵀ E⁻¹ d`` before the factor.
    """

    factor: float
    pairs: np.ndarray
    d2: np.ndarray


def variance_factor(d2, dof: int = 2, min_count: int = 30, at_least: float = 1.0) -> float:
    """Robust a-posteriori variance factor of χ²-distributed squared distances.

    ``median(d2) / median(χ²_dof)`` (the median of χ²₂ is 2 ln 2 = 1.386), never below
    ``at_least`` (default 1: the reported covariances are the white-noise bound);
    ``at_least`` (or 1 if that is 0) when fewer than ``min_count`` finite values.

    Parameters
    ----------
    d2 : (M,) array_like
        Squared Mahalanobis distances of residuals against their reported covariances.
    dof : int
        Their degrees of freedom (2 for image points).
    """
    d2 = np.asarray(d2, dtype=np.float64).ravel()
    d2 = d2[np.isfinite(d2)]
    if len(d2) < min_count:
        return float(at_least) if at_least > 0 else 1.0
    return float(max(at_least, np.median(d2) / chi2.ppf(0.5, dof)))


def _thin(points: np.ndarray, idx: np.ndarray, max_windows: int) -> np.ndarray:
    """At most ~``max_windows`` of ``idx``: the first per cell of a grid (deterministic)."""
    if len(idx) <= max_windows:
        return idx
    p = points[idx]
    lo, hi = p.min(0), p.max(0)
    cell = float(np.sqrt(np.prod(np.maximum(hi - lo, 1.0)) / max_windows))
    while True:
        key = np.floor((p - lo) / cell).astype(np.int64)
        _, first = np.unique(key[:, 0] * (key[:, 1].max() + 1) + key[:, 1],
                             return_index=True)
        if len(first) <= max_windows:
            return idx[np.sort(first)]
        cell *= 1.2


def midpoint_variance_factor(points, affine, affine_cov, valid=None, *, patch=15,
                             min_pairs: int = 30,
                             max_windows: int = MAX_WINDOWS) -> VarianceFactor:
    """Estimate the variance factor of LSM matches (module docstring).

    Parameters
    ----------
    points : (N, 2) array_like
        Template window centres, px.
    affine : (N, 6) array_like
        Their warps ``a0 a1 a2 b0 b1 b2`` (``(a0, b0)``: the centre's match, px).
    affine_cov : (N, 6, 6) array_like
        Reported covariances of ``affine`` (:attr:`matching.lsm.LSMResult.affine_cov`).
    valid : (N,) bool, optional
        Matches to use (default: all finite).
    patch : int or (N,) array_like of int
        Patch side(s), px: windows closer than the mean side of the two share pixels
        and are not paired.
    min_pairs : int
        Fewer pairs: factor NaN.
    max_windows : int
        More valid windows: thinned on a grid first.

    Returns
    -------
    VarianceFactor
    """
    points = check_shape(points, "(N, 2)", "points", dtype=np.float64)
    affine = check_shape(affine, "(N, 6)", "affine", dtype=np.float64)
    acov = check_shape(affine_cov, "(N, 6, 6)", "affine_cov", dtype=np.float64)
    n = len(points)
    if len(affine) != n or len(acov) != n:
        raise ValueError(f"points, affine and affine_cov must have the same length, got "
                         f"{n}, {len(affine)}, {len(acov)}")
    sides = np.broadcast_to(np.asarray(patch, dtype=np.float64), (n,))
    if not np.all(np.isfinite(sides) & (sides >= 1)):
        raise ValueError("patch must be a positive side (or one per point)")
    ok = (np.isfinite(points).all(1) & np.isfinite(affine).all(1)
          & np.isfinite(acov).all(axis=(1, 2)))
    if valid is not None:
        ok &= np.asarray(valid, dtype=bool)
    idx = _thin(points, np.flatnonzero(ok), max_windows)
    empty = VarianceFactor(float("nan"), np.zeros((0, 2), np.int64), np.zeros(0))
    if len(idx) < 2:
        return empty
    p = points[idx]
    s = sides[idx]
    pairs = cKDTree(p).query_pairs(PAIR_REACH * s.max(), output_type="ndarray")
    if not len(pairs):
        return empty
    a, b = pairs[:, 0], pairs[:, 1]
    delta = p[a] - p[b]  # (P, 2)
    dist = np.linalg.norm(delta, axis=1)
    mean_side = 0.5 * (s[a] + s[b])
    keep = (dist >= mean_side) & (dist <= PAIR_REACH * mean_side)
    a, b, delta = a[keep], b[keep], delta[keep]
    if len(a) < min_pairs:
        return VarianceFactor(float("nan"), idx[np.column_stack([a, b])], np.zeros(0))
    fa, fb = affine[idx[a]], affine[idx[b]]
    # W_a(m) - W_b(m), m = (p_a + p_b)/2: offsets -delta/2 from a, +delta/2 from b
    half = 0.5 * delta
    d = np.column_stack([
        fa[:, 0] - fb[:, 0] - (fa[:, 1] + fb[:, 1]) * half[:, 0]
        - (fa[:, 2] + fb[:, 2]) * half[:, 1],
        fa[:, 3] - fb[:, 3] - (fa[:, 4] + fb[:, 4]) * half[:, 0]
        - (fa[:, 5] + fb[:, 5]) * half[:, 1]])
    expected = (_warp_cov(acov[idx[a]], -half) + _warp_cov(acov[idx[b]], half))
    d2, dof = _mahalanobis(d, expected)
    factor = variance_factor(d2, dof, min_pairs, at_least=0.0)
    if np.isfinite(d2).sum() < min_pairs:
        factor = float("nan")
    return VarianceFactor(factor, idx[np.column_stack([a, b])], d2)


def class_variance_factors(points, affine, affine_cov, valid, classes, *, patch=15,
                           min_pairs: int = 30) -> tuple[np.ndarray, np.ndarray]:
    """:func:`midpoint_variance_factor` per class of windows, never below 1.

    One factor for a pair's matches assumes one population; a window that reaches
    over a silhouette, an occlusion or an untextured region (``match_pair``'s ``edge``)
    holds a second motion or none, a model error its σ0 does not carry, while a window
    clear of them has only the image's.  Pooled, the factor is the majority's: on the
    temple pairs (about half the windows are edge windows) the cross-pair check found
    the clear windows' errors at 0.30 of their σ k and the edge windows' at 0.97-1.11
    (``benchmarks/matching.py --part temple``).  Each class gets the factor of the
    window pairs inside it; a class with fewer than ``min_pairs`` pairs gets the pooled
    one.

    Parameters
    ----------
    points, affine, affine_cov, valid, patch
        As :func:`midpoint_variance_factor`.
    classes : (N,) array_like of int
        Class of each window.

    Returns
    -------
    per_point : (N,) float64
        The factor of each window's class (1 where nothing is known).
    factors : (C,) float64
        Per class ``0..C-1`` (pooled where too few pairs).
    """
    classes = np.asarray(classes, dtype=np.int64)
    valid = np.ones(len(classes), bool) if valid is None else np.asarray(valid, dtype=bool)
    pooled = midpoint_variance_factor(points, affine, affine_cov, valid, patch=patch,
                                      min_pairs=min_pairs).factor
    pooled = max(1.0, pooled) if np.isfinite(pooled) else 1.0
    n_classes = int(classes.max()) + 1 if len(classes) else 0
    factors = np.full(n_classes, pooled)
    for c in range(n_classes):
        own = midpoint_variance_factor(points, affine, affine_cov, valid & (classes == c),
                                       patch=patch, min_pairs=min_pairs).factor
        if np.isfinite(own):
            factors[c] = max(1.0, own)
    per_point = factors[classes] if n_classes else np.ones(0)
    return per_point, factors


#: A 2x2 covariance whose eigenvalue ratio is below this is rank 1 (a shift held to the
#: epipolar line, every window pixel on its own line: ``lsm_match(rigid_across=True)``).
_RANK1_RATIO = 1e-9


def _mahalanobis(d: np.ndarray, expected: np.ndarray) -> tuple[np.ndarray, int]:
    """Squared Mahalanobis distances of (P, 2) ``d`` against (P, 2, 2) ``expected`` and
    their degrees of freedom.

    Where every covariance is rank 1 (the matches of a rectified pair with the window's
    rows held by the geometry: no spread across the epipolar line, none to compare), the
    distance along the one direction with spread, 1 degree of freedom; else the 2-D
    distance over the full-rank pairs, 2.
    """
    eig, vec = np.linalg.eigh(expected)  # ascending
    with np.errstate(invalid="ignore", divide="ignore"):
        rank1 = eig[:, 0] <= _RANK1_RATIO * eig[:, 1]
        if rank1.mean() > 0.5:
            along = np.einsum("pi,pi->p", d, vec[:, :, 1])
            d2 = along**2 / eig[:, 1]
            d2[~(rank1 & (eig[:, 1] > 0))] = np.nan
            return d2, 1
        det = expected[:, 0, 0] * expected[:, 1, 1] - expected[:, 0, 1] ** 2
        d2 = (expected[:, 1, 1] * d[:, 0] ** 2 - 2 * expected[:, 0, 1] * d[:, 0] * d[:, 1]
              + expected[:, 0, 0] * d[:, 1] ** 2) / det
    d2[~(det > 0) | rank1] = np.nan
    return d2, 2


def _warp_cov(cov6: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """(P, 2, 2) covariance of ``W(p + offset)`` from the (P, 6, 6) affine covariance."""
    g = np.zeros((len(offset), 2, 6))
    g[:, 0, 0] = g[:, 1, 3] = 1.0
    g[:, 0, 1] = g[:, 1, 4] = offset[:, 0]
    g[:, 0, 2] = g[:, 1, 5] = offset[:, 1]
    return np.einsum("pik,pkl,pjl->pij", g, cov6, g)


# --------------------------------------------------------------- cross-pair redundancy
# Cross-pair check of rectified disparities (the precision a pair's σ must match).
#
# A match of pair P = (i, j) (rectified: left pixel ``x``, right column ``x_r``) fixes a
# 3D point on the left ray through ``x``; with exact cameras that point projects into a
# pair Q = (k, l) that shares no view with P at ``u`` (Q's rectified left) and ``v``
# (Q's rectified right, the same row).  Q's own match nearest ``u`` predicts, through
# its affine warp, the right column at ``u``; the discrepancy
#
# .. math::  \delta = x^Q_r(u) - v_x = \varepsilon_Q - c\,\varepsilon_P,
#    \qquad E[\delta^2] = v_Q + \overline{c^2}\, v_P,
#
# involves only the two pairs' disparity errors (no image is shared, so no noise is
# shared), ``c`` the derivative of :math:`\delta` in P's right column (through the
# point's move along P's left ray).  One comparison gives one equation in two unknown
# variances; a network of three or more pairs that see the same surface determines
# each pair's own error variance (the "three-cornered hat" of clock comparisons,
# Gray & Allan 1974), whatever the method that produced the disparities -- the same
# equations judge LSM and SGBM on the same pixels.


@dataclass(frozen=True)
class Transfer:
    """Pair P's matches carried into pair Q's rectified frame (:func:`transfer_matches`).

    Attributes
    ----------
    u : (N, 2) float64
        The triangulated point in Q's rectified left image, px.
    v_x : (N,) float64
        Its column in Q's rectified right image, px.
    du, dv_x : (N, 2), (N,) float64
        Their derivatives in P's right column (px per px).
    """

    u: np.ndarray
    v_x: np.ndarray
    du: np.ndarray
    dv_x: np.ndarray


def _triangulate(cam_left, cam_right, x_left, x_right_col):
    """Rectified pair: the point on ``cam_left``'s ray through ``x_left`` whose right
    column is ``x_right_col`` ((N, 3); the rows are the left's)."""
    pl, pr = cam_left.P, cam_right.P
    xr = np.column_stack([x_right_col, x_left[:, 1]])
    # DLT, 4 equations per point (exact for consistent rows)
    rows = np.stack([x_left[:, :1] * pl[2] - pl[0], x_left[:, 1:2] * pl[2] - pl[1],
                     xr[:, :1] * pr[2] - pr[0], xr[:, 1:2] * pr[2] - pr[1]], axis=1)
    out = np.full((len(x_left), 3), np.nan)
    fin = np.isfinite(rows).all(axis=(1, 2))
    if fin.any():
        h = np.linalg.svd(rows[fin])[2][:, -1]
        out[fin] = h[:, :3] / h[:, 3:]
    return out


def _project(cam, X):
    q = X @ cam.P[:, :3].T + cam.P[:, 3]
    return q[:, :2] / q[:, 2:]


def transfer_matches(cams_p, x_left, x_right, cams_q, step: float = 0.01) -> Transfer:
    """Carry pair P's rectified matches into pair Q's rectified frame.

    Parameters
    ----------
    cams_p, cams_q : (Camera, Camera)
        The rectified left and right pinhole cameras of P and Q
        (:func:`matching.multiview.rectify_pair`'s second and third results).
    x_left : (N, 2) array_like
        P's left pixels, px.
    x_right : (N, 2) or (N,) array_like
        P's right matches (only the column is used: the row is the left's), px.
    step : float
        Finite-difference step of the derivatives, px.

    Returns
    -------
    Transfer
    """
    x_left = check_shape(x_left, "(N, 2)", "x_left", dtype=np.float64)
    col = np.asarray(x_right, dtype=np.float64)
    col = col[:, 0] if col.ndim == 2 else col
    if len(col) != len(x_left):
        raise ValueError(f"x_left and x_right must have the same length, got "
                         f"{len(x_left)} and {len(col)}")
    out = []
    for shift in (0.0, step):
        X = _triangulate(cams_p[0], cams_p[1], x_left, col + shift)
        out.append((_project(cams_q[0], X), _project(cams_q[1], X)[:, 0]))
    (u, v), (u1, v1) = out
    return Transfer(u=u, v_x=v, du=(u1 - u) / step, dv_x=(v1 - v) / step)


def lsm_column_at(u, x_left, x_right, affine, valid, radius: float = 1.0):
    """Q's right column at ``u`` from its nearest accepted match within ``radius``.

    The match's affine warp carries it from its left pixel to ``u``
    (``x_r + a1 (u_x - x_x) + a2 (u_y - x_y)``); within a pixel the warp's own
    uncertainty adds at most ~5 % of the match's variance for a 15-px window.

    Returns
    -------
    column : (M,) float64
        NaN where no accepted match lies within ``radius``.
    index : (M,) int64
        The match used (-1: none).
    slope : (M, 2) float64
        ``(a1, a2)``: the column's derivative in ``u``.
    """
    u = check_shape(u, "(N, 2)", "u", dtype=np.float64)
    ok = np.flatnonzero(np.asarray(valid, bool) & np.isfinite(x_right[:, 0]))
    column = np.full(len(u), np.nan)
    index = np.full(len(u), -1, np.int64)
    slope = np.full((len(u), 2), np.nan)
    if not len(ok) or not len(u):
        return column, index, slope
    fin = np.isfinite(u).all(1)
    dist, near = cKDTree(x_left[ok]).query(u[fin], distance_upper_bound=radius)
    hit = np.isfinite(dist)
    rows = np.flatnonzero(fin)[hit]
    m = ok[near[hit]]
    slope[rows] = affine[m][:, 1:3]
    column[rows] = x_right[m, 0] + np.sum(slope[rows] * (u[rows] - x_left[m]), axis=1)
    index[rows] = m
    return column, index, slope


def map_column_at(u, disparity):
    """Right column ``u_x - D(u)`` at ``u`` from a dense disparity map (bilinear over the
    four pixels around ``u``; NaN if any is missing), and its derivative in ``u``.

    Returns ``column (M,)``, ``slope (M, 2)``.
    """
    u = check_shape(u, "(N, 2)", "u", dtype=np.float64)
    h, w = disparity.shape
    col = np.full(len(u), np.nan)
    slope = np.full((len(u), 2), np.nan)
    fin = np.isfinite(u).all(1)
    x0 = np.floor(np.where(fin, u[:, 0], -1)).astype(np.int64)
    y0 = np.floor(np.where(fin, u[:, 1], -1)).astype(np.int64)
    ok = fin & (x0 >= 0) & (y0 >= 0) & (x0 < w - 1) & (y0 < h - 1)
    x0, y0, uu = x0[ok], y0[ok], u[ok]
    tx, ty = uu[:, 0] - x0, uu[:, 1] - y0
    d00, d01 = disparity[y0, x0], disparity[y0, x0 + 1]
    d10, d11 = disparity[y0 + 1, x0], disparity[y0 + 1, x0 + 1]
    d = ((1 - ty) * ((1 - tx) * d00 + tx * d01) + ty * ((1 - tx) * d10 + tx * d11))
    col[ok] = uu[:, 0] - d
    slope[ok, 0] = 1.0 - ((1 - ty) * (d01 - d00) + ty * (d11 - d10))
    slope[ok, 1] = -((1 - tx) * (d10 - d00) + tx * (d11 - d01))
    return col, slope


def discrepancy(transfer: Transfer, column, slope):
    """``δ = column - v_x`` and ``c = ∂δ/∂(P's right column)`` ((M,), (M,))."""
    delta = np.asarray(column, np.float64) - transfer.v_x
    c = np.sum(np.asarray(slope, np.float64) * transfer.du, axis=1) - transfer.dv_x
    return delta, c


def robust_sigma(values) -> float:
    """1.4826 × the median absolute deviation from the median (NaN if empty)."""
    values = np.asarray(values, np.float64)
    values = values[np.isfinite(values)]
    if not len(values):
        return float("nan")
    return float(mad_sigma(values))


@dataclass(frozen=True)
class NetworkVariances:
    """Result of :func:`network_variances`.

    Attributes
    ----------
    variance : (K,) float64
        Each pair's own error variance, px² (NaN: not determined by the network).
    residual : (E,) float64
        The equations' relative residuals (fit / measured - 1).
    """

    variance: np.ndarray
    residual: np.ndarray


def network_variances(n_pairs: int, p_index, q_index, measured, coef_p, coef_q,
                      count) -> NetworkVariances:
    r"""Each pair's own error variance (or variance scale) from cross-pair comparisons.

    Solves :math:`m_e = b_e\, x_{p_e} + a_e\, x_{q_e}` over the comparisons ``e`` by
    non-negative least squares, each equation weighted by the relative precision of
    its measured variance (:math:`\sqrt{n_e} / m_e`).  With ``m`` the variance of δ,
    ``b`` the mean ``c²`` and ``a = 1``, ``x`` are the pairs' error variances (px²);
    with ``m`` the variance of δ over its reported σ, ``a`` and ``b`` the two pairs'
    mean shares of that σ², ``x`` are the factors by which each pair's reported
    variances must grow.

    Parameters
    ----------
    n_pairs : int
    p_index, q_index : (E,) array_like of int
        The compared pair (its error enters through ``c``) and the checking pair.
    measured : (E,) array_like
        ``m``, per comparison.
    coef_p, coef_q : (E,) array_like
        ``b`` and ``a``.
    count : (E,) array_like
        Points per comparison.

    Returns
    -------
    NetworkVariances
        A pair's value is NaN unless the equations determine it (its column is not
        in the span of the others': it needs a cycle of comparisons through three
        or more pairs).
    """
    from scipy.optimize import nnls

    p = np.asarray(p_index, np.int64)
    q = np.asarray(q_index, np.int64)
    m = np.asarray(measured, np.float64)
    bp = np.asarray(coef_p, np.float64)
    aq = np.asarray(coef_q, np.float64)
    n = np.asarray(count, np.float64)
    if not (len(p) == len(q) == len(m) == len(bp) == len(aq) == len(n)):
        raise ValueError("p_index, q_index, measured, coef_p, coef_q and count must have "
                         "the same length")
    variance = np.full(n_pairs, np.nan)
    residual = np.full(len(p), np.nan)
    use = np.isfinite(m) & (m > 0) & np.isfinite(bp) & np.isfinite(aq) & (n > 0)
    if not use.any():
        return NetworkVariances(variance, residual)
    rows = np.flatnonzero(use)
    design = np.zeros((len(rows), n_pairs))
    np.add.at(design, (np.arange(len(rows)), q[rows]), aq[rows])
    np.add.at(design, (np.arange(len(rows)), p[rows]), bp[rows])
    weight = np.sqrt(n[rows]) / m[rows]
    a = design * weight[:, None]
    involved = np.flatnonzero(np.abs(design).sum(0) > 0)
    if len(involved) < 3:
        return NetworkVariances(variance, residual)
    sol, _ = nnls(a[:, involved], m[rows] * weight)
    rank = np.linalg.matrix_rank(a[:, involved])
    for col, k in enumerate(involved):
        others = np.delete(a[:, involved], col, axis=1)
        if np.linalg.matrix_rank(others) < rank:
            variance[k] = sol[col]
    residual[rows] = (design[:, involved] @ sol) / m[rows] - 1.0
    return NetworkVariances(variance, residual)


def core_spread(values, bound: float, iterations: int = 50) -> tuple[float, float, float]:
    """Spread of a Gaussian core among outliers spread evenly over ``[-bound, bound]``.

    A two-component mixture ``(1 - π) N(μ, σ²) + π U(-bound, bound)`` fitted by EM to
    the values within the bound (Dempster, Laird and Rubin 1977): the matches of a
    point another pair sees occluded, or on another surface, scatter over the whole
    window of accepted discrepancies, and the median absolute deviation (break-down
    50 %) grows long before that.

    Returns
    -------
    sigma, mu, outlier_share : float
        NaN with fewer than 10 values.
    """
    v = np.asarray(values, np.float64)
    v = v[np.isfinite(v) & (np.abs(v) <= bound)]
    if len(v) < 10:
        return float("nan"), float("nan"), float("nan")
    mu = float(np.median(v))
    sigma = max(robust_sigma(v), 1e-6)
    share = 0.1
    flat = 1.0 / (2.0 * bound)
    for _ in range(iterations):
        core = (1 - share) * np.exp(-0.5 * ((v - mu) / sigma) ** 2) / (np.sqrt(2 * np.pi) * sigma)
        w = core / (core + share * flat)
        total = w.sum()
        mu_new = float(np.sum(w * v) / total)
        sigma_new = float(max(np.sqrt(np.sum(w * (v - mu_new) ** 2) / total), 1e-6))
        share_new = float(1.0 - total / len(v))
        done = abs(sigma_new - sigma) < 1e-6 * sigma and abs(share_new - share) < 1e-6
        mu, sigma, share = mu_new, sigma_new, share_new
        if done:
            break
    return sigma, mu, share


def ray_angle(cam_a, cam_b, x_left, x_right_col, cams_p) -> np.ndarray:
    """(N,) angle (degrees) at P's triangulated points between the rays from the
    centres of ``cam_a`` and ``cam_b``."""
    X = _triangulate(cams_p[0], cams_p[1], np.asarray(x_left, np.float64),
                     np.asarray(x_right_col, np.float64))
    ra, rb = X - cam_a.center, X - cam_b.center
    cos = np.sum(ra * rb, axis=1) / (np.linalg.norm(ra, axis=1) * np.linalg.norm(rb, axis=1))
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def geometric_trend(u, disparity, delta, bound: float = 3.0, iterations: int = 5):
    """Remove what inexact cameras add to cross-pair discrepancies.

    An error of a view's rotation shifts the transferred points by a smooth function
    of their image position, one of its centre by that times the inverse depth (the
    disparity): ``δ ≈ q(u) + (α + β u_x + γ u_y) d`` with ``q`` quadratic -- 9
    unknowns, fitted robustly (4 × :func:`robust_sigma`, 5 rounds) over the
    comparison's points, which no matching error of a window shares.

    Parameters
    ----------
    u : (M, 2) array_like
        The points in Q's rectified left image, px.
    disparity : (M,) array_like
        Their disparity in Q, px.
    delta : (M,) array_like
        Discrepancies, px.

    Returns
    -------
    residual, trend : (M,) float64
    """
    u = check_shape(u, "(N, 2)", "u", dtype=np.float64)
    delta = np.asarray(delta, np.float64)
    x, y = ((u - np.median(u, axis=0)) / 100.0).T
    d = (np.asarray(disparity, np.float64) - np.median(disparity)) / 100.0
    design = np.column_stack([np.ones_like(x), x, y, x * x, x * y, y * y, d, d * x, d * y])
    keep = np.abs(delta - np.median(delta)) <= bound
    coef = np.zeros(design.shape[1])
    for _ in range(iterations):
        if keep.sum() <= 2 * design.shape[1]:
            break
        coef = np.linalg.lstsq(design[keep], delta[keep], rcond=None)[0]
        res = delta - design @ coef
        keep = np.abs(res) < min(4.0 * robust_sigma(res[keep]), bound)
    trend = design @ coef
    return delta - trend, trend
