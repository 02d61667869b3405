r"""LSM's window side per point by the intersection of confidence intervals (ICI).

A larger LSM window holds more texture: its shift is more precise (σ ∝ 1/side on
uniform texture, Gruen 1985).  It also reaches farther: over a curved or broken
surface its affine (or second-order) warp holds less well and over a depth edge not at
all.  Which side is best is a property of each point, not of the image.  The rule here
is Lepski's, in the form of Goldenshluger & Nemirovski's and Katkovnik's *intersection
of confidence intervals* for local estimates of growing support [1]_ [2]_ [3]_ (used
for adaptive windows in image denoising and stereo): for the sides of a ladder
``s_1 < s_2 < ...`` with estimates ``x_j`` and standard deviations ``σ_j`` (per axis),
the intervals ``D_j = [x_j − Γσ_j, x_j + Γσ_j]`` are intersected in order of growing
side, and a point keeps the largest side before the running intersection becomes
empty -- the largest window that agrees with every smaller one within their noise --
or before a window is not accepted.  As long as a window's bias stays below its noise
the larger one wins; once the bias shows, the intervals part.

The σ's must be honest for the rule to mean what it says: LSM's reported covariance is
scaled per side by the variance factor of independent neighbouring windows
(:func:`matching.precision.midpoint_variance_factor`, what ``match_pair`` applies), when
there are enough windows to estimate it.  ``Γ`` = :data:`ICI_GAMMA` (2: an interval of
±2σ per axis, Katkovnik's range 1.5-3 for the bias-variance balance).

A window that slips (an accepted blunder of the small window: its interval misses every
larger window's while those agree with each other) would stop the plain rule at the
blunder; such a side is skipped (``ici_choice(robust=True)``, :func:`_outvoted`).

Written here: no library applies ICI to least-squares image matching.

Measured (one run each, session 12):

- graffiti (``benchmarks/matching.py --part graffiti``: 22 312 textured candidates on the wall,
  21 px windows, the homography + 1 px starts, region growing; ladder 21 / 31 / 41):
  residual to the smooth mapping 0.190 px at 21 px, 0.138 at 31, 0.114 at 41 px alone,
  **0.128 px** with ICI (581 / 951 / 19 276 points at 21 / 31 / 41), residual / σk **1.37**
  (1.62 at 21 px), 0.1 % beyond 2 px; the plain rule (no skipped slips) 0.162 px: where it
  kept the 21 px side, that side erred by 1.0 px (median) and the 31 / 41 px ones by 0.18 /
  0.14 px.  402 points/s against 5 837 for the 21 px pass with growing (one run).
- rendered two-plane pair (``tests/matching/test_ici.py``, ``match_pair(adaptive_patch=
  "ici")``, 4 grey levels of noise): windows clear of the depth edge 0.0199 -> 0.0148 px,
  those within 12 px of it kept small and kept (107 -> 118 accepted, none beyond 3σ).
- the temple's ring pairs (cross-pair check of ``benchmarks/matching.py --part temple``,
  one-off run of its functions): *worse* -- median LSM discrepancy 0.436 px with the
  default adaptive patch, 0.626 with ICI over 15 / 23 / 29 and 0.591 over 11 / 15 / 21
  (SGBM/LSM 1.20 -> 0.88 / 1.05; windows clear of edges below 35°: 0.131 -> 0.159 /
  0.151 px).  The temple's variance factors are large (k² 5-240 by window class, and σk
  pessimistic there by the cross-pair check), so the intervals are too wide to see the
  larger windows' bias over its relief.  Hence ICI is an option, not the default.

Session 14 (issue 13, item 3: a window rule that could be ``match_pair``'s default) --
what was tried, each on the temple's cross-pair check (all 17 ring pairs, one-off runs of
``_real_matching._pair_data`` / ``cross_pair_comparisons`` / ``cross_pair_summary``; the
default: median LSM δ 0.436 px, SGBM/LSM 1.20, windows clear of edges below 35° 0.131 px,
edge windows 0.711 px):

- the ICI intervals scaled by the smallest side's factor (per class), not each side's:
  0.619 px (graffiti 21/31/41: 0.133 px, residual / σk 1.39); by the clear windows'
  factor at the smallest side for every class: 0.597 px.
- a sharper per-point test, the nested (Hausman) statistic of :func:`nested_statistics`
  at the 95.4 % χ² quantile (as Γ = 2) instead of the intervals: 0.596-0.605 px
  (graffiti 0.148 px, 1.41).  The temple's σk at 15 px is 0.10-0.37 px for the clear
  windows and 0.6-1.0 px for the edge windows: a larger window's bias below that cannot
  be seen per point, yet costs more than the noise it removes.
- the *population rule* (below): 0.578 px; with the larger windows also held clear of
  edges (``window_offsets`` at their side): **0.482 px**, SGBM/LSM 1.13, below 35° 0.258
  (default 0.290), clear windows below 35° 0.152, edge windows 0.733; per benchmark pair
  δ/σ 0.69 / 0.85 / 0.85 / 0.68 (default 0.77 / 0.93 / 0.94 / 0.75).  Graffiti
  (``benchmarks/matching.py --part graffiti``, its population row): every window at 41 px,
  0.120 px, 1.31; rendered vase 1024x768 (``match_pair`` as ``--part vase``'s default row,
  one-off): RMS 0.0276 -> 0.0241 px, actual / σ 1.00 -> 0.93, accepted 96.7 -> 97.8 %.

So no rule found here meets graffiti's goals without making the temple worse than Gruen's
adaptive patch: the temple's clear windows grown past 21 px err more by the cross-pair
check although their departures from the smaller windows are, in the population's core,
within the noise the midpoint factor (k² 5-85 there, pessimistic by that check) allows.
The default stays Gruen's; ``"ici"`` and ``"population"`` are options.

Population rule (:func:`population_sides`, ``match_pair(adaptive_patch="population")``).
The larger window holds the smaller one's pixels, so without bias the difference of the
two has the covariance :math:`k^2(\Sigma_i - \Sigma_j)` (Hausman's specification test
[5]_) and :math:`T_{ij} = d^\mathsf{T}(k^2(\Sigma_i - \Sigma_j))^{-1} d \sim \chi^2_\nu`.
The larger side lowers the mean-square error when its bias b is below the variance it
removes, :math:`b^2 < k^2\,\mathrm{tr}(\Sigma_i - \Sigma_j)`, i.e. :math:`E[T] < 2\nu`.
One point's T cannot tell (its noise is the size of the bias that matters); a class of
windows can: per window class of a pair (``edge`` or not) the largest side whose
``median(T) / median(χ²_ν)`` stays below :data:`POPULATION_RISK_RATIO` against every
smaller side is kept.  ``k²`` is the image's (the clear windows' at Gruen's sides) for
every class, and σ0 the smaller window's (a larger window's σ0 holds its model error).
Graffiti: ``median(T)/median(χ²)`` 0.86 (21 -> 31) and 1.19 (21 -> 41).

References
----------
.. [1] O. V. Lepski, "On a problem of adaptive estimation in Gaussian white noise",
   Theory Probab. Appl. 35 (1990) 454-466.
.. [2] A. Goldenshluger, A. Nemirovski, "On spatially adaptive estimation of
   nonparametric regression", Math. Methods Statist. 6 (1997) 135-170.
.. [3] V. Katkovnik, "A new method for varying adaptive bandwidth selection", IEEE
   Trans. Signal Processing 47 (1999) 2567-2571.
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
