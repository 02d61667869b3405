r"""The variance factor of LSM matches from independent neighbouring windows.

LSM's covariance :math:`\sigma_0^2 N^{-1}` (Gruen 1985) holds for white noise and a
model that fits.  Real photographs add correlated noise (demosaicing, compression:
fewer independent observations than pixels), blur and shading differences between
the views and the affine model's own error, none of which :math:`\sigma_0` sees.  The
data measure them by redundancy: two windows whose centres :math:`p_i, p_j` are at
least a patch side apart share no pixel, and each one's estimated affine warp
:math:`W_i(p) = x_i + A_i (p - p_i)` predicts where their midpoint
:math:`m = (p_i + p_j)/2` goes.  For any mapping that is quadratic between the two
centres the two predictions agree exactly (the trapezoidal rule: the difference of
the two is :math:`x_i - x_j - \tfrac12 (A_i + A_j)(p_i - p_j)`), so a slanted or
curved surface -- a temple's facade, a wall seen 40 degrees apart -- gives no
disagreement, only the matching errors do:

.. math::

    d_{ij} = W_i(m) - W_j(m), \qquad
    E\,[d_{ij} d_{ij}^\mathsf{T}] = k^2 \left(G_i \Sigma_i G_i^\mathsf{T}
    + G_j \Sigma_j G_j^\mathsf{T}\right),

:math:`\Sigma_i` the reported 6x6 covariance of :math:`(a_0, a_1, a_2, b_0, b_1, b_2)`
(:attr:`matching.lsm.LSMResult.affine_cov`) and :math:`G_i` the gradient of
:math:`W_i(m)` in them.  The variance factor :math:`k^2` -- the factor by which the
reported variances must grow, a variance-component estimate from redundant
observations (Förstner 1979) -- is the median of the Mahalanobis distances
:math:`d^\mathsf{T} E^{-1} d` over its value for Gaussian errors (2 ln 2, the median of
χ²₂): robust to the pairs across a depth edge or an occlusion, which disagree by
far more, while they are fewer than half.  Pairs are taken between one and 1.5 patch
sides apart (the nearest independent windows: the least model error between them).

What it cannot see is an error that both windows share: one smooth over the two
windows (a lens distortion, a relief of the scene: these are geometry, not matching
error), a bias the same texture gives both, or a relief finer than a window, which
every window smooths alike (the affine patch's model error against the centre pixel:
``benchmarks/matching.py``'s rippled vase errs 2.2x the σ with the factor, 6.8x
without; forward-backward loops see even less of it, 0.54x σ).

Measured (``benchmarks/matching.py``, one full run): rendered vase pair 1024x768
k² = 1.27 (actual / reported σ 1.27 -> 1.01), 320x240 with 1 px correlated noise
9.5 (3.0 -> 0.98); graffiti 21x21 7.1 (the forward-backward lower bound 3.2); temple
pairs 10.5 to 76 (the old estimator -- residuals to a local quadratic over 2.5 patch
sides -- gave ~745 on pair (0, 1): the facade's depth structure).  Unlike forward-backward matching
(:mod:`matching.consistency`), whose two matches read the same pixels and so share
their noise, the windows compared here share none.

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

import numpy as np
from scipy.spatial import cKDTree
from scipy.stats import chi2

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
