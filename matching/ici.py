r"""LSM's window side per point by the intersection of confidence intervals (ICI).

A larger LSM window is more precise (σ ∝ 1/side on uniform texture, Gruen 1985 [4]_) but
its warp holds less well over a curved or broken surface.  Lepski's rule, as Goldenshluger
& Nemirovski's and Katkovnik's intersection of confidence intervals [1]_ [2]_ [3]_: for a
ladder of sides ``s_1 < s_2 < ...`` with estimates ``x_j`` and standard deviations ``σ_j``
(per axis, scaled by each side's variance factor,
:func:`matching.precision.midpoint_variance_factor`), the intervals
``[x_j − Γσ_j, x_j + Γσ_j]`` are intersected in order of growing side and a point keeps the
largest side before the intersection becomes empty or a window is not accepted;
``Γ`` = :data:`ICI_GAMMA` (2, within Katkovnik's 1.5-3).  A small window that slipped (its
interval misses every larger window's while those agree) is skipped
(``ici_choice(robust=True)``, :func:`_outvoted`).

*Population rule* (:func:`population_sides`, ``match_pair(adaptive_patch="population")``).
Without bias the difference ``d`` of two nested windows has covariance
:math:`k^2(\Sigma_i - \Sigma_j)` (Hausman's test [5]_), so
:math:`T_{ij} = d^\mathsf{T}(k^2(\Sigma_i - \Sigma_j))^{-1} d \sim \chi^2_\nu`; the larger side
lowers the mean-square error while :math:`E[T] < 2\nu`.  Per window class of a pair
(``edge`` or not) the largest side whose ``median(T) / median(χ²_ν)`` stays below
:data:`POPULATION_RISK_RATIO` against every smaller side is kept (``k²`` the clear windows'
at Gruen's sides; σ0 the smaller window's).

Both are options of :func:`matching.pair.match_pair`, not its default: they meet the
graffiti wall's goals but make the temple's cross-pair check worse than Gruen's adaptive
patch (the figures: ``docs/decisions/stereo-matching.md``).  Written here: no library
applies ICI to least-squares image matching.

References
----------
.. [1] O. V. Lepski, Theory Probab. Appl. 35 (1990) 454-466.
.. [2] A. Goldenshluger, A. Nemirovski, Math. Methods Statist. 6 (1997) 135-170.
.. [3] V. Katkovnik, IEEE Trans. Signal Processing 47 (1999) 2567-2571.
.. [4] A. Gruen, "Adaptive least squares correlation: a powerful image matching
   technique", S. Afr. J. Photogramm. Remote Sens. Cartogr. 14 (1985) 175-187.
.. [5] J. A. Hausman, "Specification tests in econometrics", Econometrica 46 (1978)
   1251-1271.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import fields, replace

import numpy as np

from matching.lsm import LSMResult, lsm_match
from matching.precision import midpoint_variance_factor
from matching.validate import check_shape

#: Half-width of the ICI intervals in standard deviations (per axis).
ICI_GAMMA = 2.0
#: The default ladder of window sides, px: each side about 1.5 x the previous (σ falls
#: by about that factor on uniform texture, so neighbouring intervals differ in width).
ICI_SIDES = (15, 21, 31, 41)

__all__ = ["ICI_GAMMA", "ICI_SIDES", "POPULATION_MIN_WINDOWS", "POPULATION_RISK_RATIO",
           "ici_choice", "ici_ladder", "interval_sigmas", "lsm_match_ici", "nested_statistics",
           "population_choice", "population_sides", "select_results"]


def ici_ladder(patch: int) -> tuple[int, ...]:
    """Window sides ``patch``, ~1.5 x and ~2 x it (odd): the ladder ``match_pair``'s
    ``adaptive_patch="ici"`` and the graffiti benchmark try."""
    return tuple(int(2 * round((patch * f - 1) / 2) + 1) for f in (1.0, 1.5, 2.0))


def ici_choice(positions, sigmas, accepted, gamma: float = ICI_GAMMA,
               robust: bool = True) -> np.ndarray:
    """Index of the side each point keeps (ICI, module docstring).

    Parameters
    ----------
    positions : (S, N, 2) array_like
        The estimates of the S sides, smallest first, px.
    sigmas : (S, N, 2) array_like
        Their standard deviations per axis, px (NaN: not accepted; 0 on one axis: the
        estimate is held there, e.g. by an epipolar constraint, and that axis is free).
    accepted : (S, N) array_like of bool
        Each side's acceptance.
    gamma : float
        Interval half-width in σ (> 0).
    robust : bool
        Skip a side whose interval meets none of the others' while those (two or more)
        all meet each other (:func:`_outvoted`: a slipped window, not a bias).

    Returns
    -------
    (N,) int64
        Index into the ladder; -1 where no side is kept (the smallest not accepted).
    """
    pos = np.asarray(positions, dtype=np.float64)
    sig = np.asarray(sigmas, dtype=np.float64)
    ok = np.asarray(accepted, dtype=bool)
    if pos.ndim != 3 or pos.shape[2] != 2 or sig.shape != pos.shape or ok.shape != pos.shape[:2]:
        raise ValueError(f"positions and sigmas must be (S, N, 2) and accepted (S, N), got "
                         f"{pos.shape}, {sig.shape}, {ok.shape}")
    if not (np.isfinite(gamma) and gamma > 0):
        raise ValueError(f"gamma must be a positive number, got {gamma!r}")
    count, sides = pos.shape[1], pos.shape[0]
    valid = ok & np.isfinite(pos).all(axis=2) & np.isfinite(sig).all(axis=2) \
        & (sig > 0).any(axis=2)
    # σ = 0 on an axis: the estimate is held there (an epipolar constraint along the
    # other axis), which says nothing about the window: no bound on that axis
    width = np.where(sig > 0, gamma * sig, np.inf)
    with np.errstate(invalid="ignore"):
        lo, hi = pos - width, pos + width
        # meets[j, k]: the intervals of sides j and k intersect (both valid)
        meets = ((np.maximum(lo[:, None], lo[None]) <= np.minimum(hi[:, None], hi[None]))
                 .all(axis=3) & valid[:, None] & valid[None])
    outvoted = _outvoted(meets, valid) if robust else np.zeros_like(valid)
    lower = np.full((count, 2), -np.inf)
    upper = np.full((count, 2), np.inf)
    alive = np.ones(count, dtype=bool)
    choice = np.full(count, -1, dtype=np.int64)
    for j in range(sides):
        skip = outvoted[j] & alive
        with np.errstate(invalid="ignore"):
            new_lower = np.where(skip[:, None], lower, np.maximum(lower, lo[j]))
            new_upper = np.where(skip[:, None], upper, np.minimum(upper, hi[j]))
            agree = (new_lower <= new_upper).all(axis=1)
        lower, upper = new_lower, new_upper
        alive &= skip | (valid[j] & agree)
        choice[alive & ~skip] = j
    return choice


def _outvoted(meets: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """(S, N) bool: side j's estimate is a gross error -- its interval meets none of the
    other valid sides' while those (at least two) all meet each other.  A bias from a
    window's reach grows with the side, so the sides past it disagree with each other
    too; one window in a consistent ladder that misses all the others has slipped (an
    accepted blunder: on graffiti's real pair, where ICI kept the 21 px side because
    the larger ones disagreed with it, that side erred by 1.0 px (median) and the 31 /
    41 px ones by 0.18 / 0.14)."""
    sides = meets.shape[0]
    out = np.zeros_like(valid)
    if sides < 3:
        return out
    for j in range(sides):
        others = [k for k in range(sides) if k != j]
        other_valid = valid[others]
        enough = other_valid.sum(axis=0) >= 2
        misses_all = ~np.any(meets[j][others] & other_valid, axis=0)
        consistent = np.ones(valid.shape[1], bool)
        for a in others:
            for b in others:
                if a < b:
                    consistent &= ~(valid[a] & valid[b]) | meets[a, b]
        out[j] = valid[j] & enough & misses_all & consistent
    return out


def select_results(results: Sequence[LSMResult], choice) -> LSMResult:
    """One :class:`LSMResult` whose row i is ``results[choice[i]]``'s (``results[0]``'s where
    ``choice[i] < 0``).  Optional fields stay None unless every result has them."""
    choice = np.asarray(choice, dtype=np.int64)
    if not results:
        raise ValueError("no results to select from")
    pick = np.maximum(choice, 0)
    rows = np.arange(len(choice))
    out = {}
    for f in fields(LSMResult):
        values = [getattr(r, f.name) for r in results]
        if f.name == "noise_sigma0":
            out[f.name] = values[0]
        elif any(v is None for v in values):
            out[f.name] = None
        else:
            out[f.name] = np.stack([np.asarray(v) for v in values])[pick, rows]
    return replace(results[0], **out)


def interval_sigmas(result: LSMResult, points: np.ndarray, side: int,
                    variance_factor=None) -> tuple[np.ndarray, np.ndarray | float]:
    """Per-axis σ ``(N, 2)`` of ``result``'s positions scaled by the variance factor k²
    (a number or one per window, e.g. ``matching.precision.class_variance_factors``; by
    default :func:`matching.precision.midpoint_variance_factor` of the result, 1 where it
    cannot be estimated; never below 1), and that k²."""
    if variance_factor is None:
        factor = midpoint_variance_factor(points, result.affine, result.affine_cov,
                                          result.accepted, patch=side).factor
        variance_factor = float(factor) if np.isfinite(factor) else 1.0
    k2 = np.maximum(1.0, np.asarray(variance_factor, dtype=np.float64))
    diag = np.stack([result.cov[:, 0, 0], result.cov[:, 1, 1]], axis=1)
    with np.errstate(invalid="ignore"):
        sigma = np.sqrt(np.where(diag >= 0, diag * np.reshape(k2, (-1, 1)), np.nan))
    return sigma, (float(k2) if k2.ndim == 0 else k2)


def lsm_match_ici(template_image, search_image, points, approx, *,
                  sides: Sequence[int] = ICI_SIDES, gamma: float = ICI_GAMMA,
                  variance_factors: Sequence[float] | None = None, initial=None,
                  **options) -> tuple[LSMResult, np.ndarray, dict]:
    """:func:`matching.lsm.lsm_match` at every side of ``sides`` and, per point, the side
    the ICI rule keeps (module docstring).

    Each side starts from the previous side's solution where it was accepted (the
    warp carries over; the pull-in is then the smaller window's), else from ``initial``
    / ``approx``.

    Parameters
    ----------
    template_image, search_image, points, approx, initial
        As ``lsm_match``.
    sides : sequence of int
        Odd window sides, increasing.
    gamma : float
        ICI interval half-width in σ.
    variance_factors : sequence of float, optional
        k² per side; default each side's own
        (:func:`matching.precision.midpoint_variance_factor`, 1 where it cannot be
        estimated).
    **options
        More of ``lsm_match``'s (not ``patch``).

    Returns
    -------
    (LSMResult, (N,) int32, dict)
        The chosen side's result per point, the sides (px; the smallest where none is
        accepted) and ``{"variance_factors": [...], "chosen": {side: count}}``.
    """
    sides = [int(s) for s in sides]
    if not sides or any(s < 3 or s % 2 == 0 for s in sides) or sides != sorted(set(sides)):
        raise ValueError(f"sides must be odd, >= 3 and increasing, got {sides}")
    if "patch" in options:
        raise ValueError("give the window sides as sides=, not patch=")
    if variance_factors is not None and len(variance_factors) != len(sides):
        raise ValueError(f"need one variance factor per side ({len(sides)}), got "
                         f"{len(variance_factors)}")
    points = check_shape(points, "(N, 2)", "points", dtype=np.float64)
    start = None if initial is None else np.asarray(initial, dtype=np.float64)
    results, sigmas, factors = [], [], []
    for j, side in enumerate(sides):
        result = lsm_match(template_image, search_image, points, approx, patch=side,
                           initial=start, **options)
        sigma, k2 = interval_sigmas(result, points, side,
                                     None if variance_factors is None else variance_factors[j])
        results.append(result)
        sigmas.append(sigma)
        factors.append(k2)
        carried = np.column_stack([result.affine, result.radiometric])
        good = result.accepted & np.isfinite(carried).all(axis=1)
        if start is None:
            start = np.full((len(points), 8), np.nan)
            start[:, 0], start[:, 3] = np.asarray(approx, np.float64).T
            start[:, 1] = start[:, 5] = start[:, 7] = 1.0
            start[:, [2, 4, 6]] = 0.0
        start = np.where(good[:, None], carried, start)
    choice = ici_choice(np.stack([r.position for r in results]), np.stack(sigmas),
                        np.stack([r.accepted for r in results]), gamma)
    chosen = np.asarray(sides, np.int32)[np.maximum(choice, 0)]
    counts = {int(s): int(np.sum((choice >= 0) & (chosen == s))) for s in sides}
    return select_results(results, choice), chosen, {"variance_factors": factors,
                                                     "chosen": counts}


#: The larger side is kept while, in the core of a window population, its departure from
#: a smaller side is below twice the noise the two do not share: the mean-square error
#: balance ``b² < k² tr(Σ_i - Σ_j)`` (bias against the variance removed) reads
#: ``E[T] < 2 E[χ²_ν]`` for the nested statistic ``T`` (:func:`nested_statistics`).
POPULATION_RISK_RATIO = 2.0
#: Fewer windows of a class accepted at two sides: no growth for that class.
POPULATION_MIN_WINDOWS = 30


def nested_statistics(positions, covs, k2, sigma0=None) -> tuple[np.ndarray, np.ndarray]:
    r"""Nested-window statistics ``T[i, j]`` (i < j) and the degrees of freedom ν.

    A larger LSM window holds the smaller one's pixels: under the null of no bias the
    larger estimate is the efficient one and the difference of the two has the
    covariance :math:`\Sigma_i - \Sigma_j` (Hausman 1978 [5]_; the white-noise covariances
    scaled by the image's variance factor ``k2``), so
    :math:`T_{ij} = d^\mathsf{T} (k^2 (\Sigma_i - \Sigma_j))^{-1} d \sim \chi^2_\nu`, ν = 1
    where an axis is held (σ = 0 there: an epipolar constraint) and 2 otherwise.

    Parameters
    ----------
    positions : (S, N, 2) array_like, px
    covs : (S, N, 2, 2) array_like, px²
        Reported (white-noise) covariances, smallest side first.
    k2 : float or (N,) array_like
        Variance factor.
    sigma0 : (S, N) array_like, optional
        Each side's σ0: the larger side's covariance is rescaled to the smaller one's σ0
        (one noise level for the pixels both hold; a larger window's σ0 also holds its
        model error, which would make :math:`\Sigma_i - \Sigma_j` indefinite -- on the
        temple pairs for ~25 % of the windows).

    Returns
    -------
    T : (S, S, N) float64
        Symmetric; NaN on the diagonal and where the difference's covariance is not
        positive definite.
    dof : (N,) int64
    """
    pos = np.asarray(positions, dtype=np.float64)
    cov = np.asarray(covs, dtype=np.float64)
    if pos.ndim != 3 or pos.shape[2] != 2 or cov.shape != pos.shape + (2,):
        raise ValueError(f"positions must be (S, N, 2) and covs (S, N, 2, 2), got {pos.shape} "
                         f"and {cov.shape}")
    sides, count = pos.shape[:2]
    k2 = np.broadcast_to(np.asarray(k2, dtype=np.float64), (count,))
    held_y = cov[0, :, 1, 1] == 0
    held_x = cov[0, :, 0, 0] == 0
    stats = np.full((sides, sides, count), np.nan)
    for i in range(sides):
        for j in range(i + 1, sides):
            d = pos[i] - pos[j]
            if sigma0 is None:
                m = (cov[i] - cov[j]) * k2[:, None, None]
            else:
                # one noise level for the shared pixels: the smaller window's σ0 (the
                # larger one's also holds its model error)
                s0 = np.asarray(sigma0, dtype=np.float64)
                with np.errstate(invalid="ignore", divide="ignore"):
                    m = (cov[i] - cov[j] * (s0[i] / s0[j])[:, None, None] ** 2) \
                        * k2[:, None, None]
            a, b, c = m[:, 0, 0], m[:, 0, 1], m[:, 1, 1]
            det = a * c - b * b
            with np.errstate(invalid="ignore", divide="ignore"):
                full = (c * d[:, 0] ** 2 - 2 * b * d[:, 0] * d[:, 1] + a * d[:, 1] ** 2) / det
                t = np.where(held_y, d[:, 0] ** 2 / a, np.where(held_x, d[:, 1] ** 2 / c, full))
            good = np.where(held_y, a > 0, np.where(held_x, c > 0, (a > 0) & (det > 0)))
            stats[i, j] = stats[j, i] = np.where(good, t, np.nan)
    return stats, np.where(held_x | held_y, 1, 2).astype(np.int64)


def population_sides(positions, covs, accepted, k2, classes, sigma0=None,
                     ratio: float = POPULATION_RISK_RATIO,
                     min_windows: int = POPULATION_MIN_WINDOWS) -> np.ndarray:
    """The largest side per window class whose departures from every smaller side stay,
    in the class's core, within the mean-square-error balance (module docstring).

    For each class and sides i < j: the median over the windows accepted at both of
    ``T_ij / median(χ²_ν)`` (:func:`nested_statistics`); side j is allowed when that is
    at most ``ratio`` for every smaller allowed side i, and the class keeps the largest
    allowed side reached without a refused one.

    Parameters
    ----------
    positions, covs : (S, N, 2), (S, N, 2, 2) array_like
        Estimates and white-noise covariances of the S sides, smallest first.
    accepted : (S, N) array_like of bool
    k2 : float or (N,) array_like
        The image's variance factor (the clear windows' at the smallest side).
    classes : (N,) array_like of int
        Window class (``match_pair``'s ``edge``).
    sigma0 : (S, N) array_like, optional
        As :func:`nested_statistics`.
    ratio, min_windows : float, int
        :data:`POPULATION_RISK_RATIO`, :data:`POPULATION_MIN_WINDOWS`.

    Returns
    -------
    (C,) int64
        Index of the side per class ``0..C-1`` (0 where too few windows).
    """
    from scipy.stats import chi2

    ok = np.asarray(accepted, dtype=bool)
    classes = np.asarray(classes, dtype=np.int64)
    stats, dof = nested_statistics(positions, covs, k2, sigma0)
    scaled = stats / chi2.ppf(0.5, dof)
    n_classes = int(classes.max()) + 1 if len(classes) else 0
    out = np.zeros(n_classes, np.int64)
    for c in range(n_classes):
        mine = classes == c
        for j in range(1, len(ok)):
            values = [scaled[i, j, mine & ok[i] & ok[j]] for i in range(j)]
            values = [v[np.isfinite(v)] for v in values]
            if any(len(v) < min_windows or np.median(v) > ratio for v in values):
                break
            out[c] = j
    return out


def population_choice(accepted, side_index) -> np.ndarray:
    """(N,) index of the side each point keeps: its class's side (``side_index`` (N,))
    where accepted there, else the largest smaller accepted side (0 if none)."""
    ok = np.asarray(accepted, dtype=bool)
    sides = ok.shape[0]
    choice = np.zeros(ok.shape[1], np.int64)
    for j in range(1, sides):
        choice = np.where(ok[j] & (j <= side_index), j, choice)
    return choice
