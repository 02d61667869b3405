r"""Is a stereo match unique along its epipolar line?  The cost profile over the search range.

For a window :math:`W` (side :math:`s`, :math:`n = s^2` pixels) at a left pixel of a
*rectified* pair, the zero-mean normalised cross-correlation :math:`c(d)` with the right
window at disparity :math:`d` is evaluated at every integer :math:`d` of the search range
(box filters over the whole image, one per disparity).  Noise of σ grey levels moves
:math:`c(d)` by about :math:`\sigma / (s_f \sqrt n)` (:math:`s_f`: the template's standard
deviation), so values closer than :math:`m = k \sqrt{2/n}\,\sigma / s_f`, :math:`k = 3`,
cannot be told apart.  The near-best set :math:`A = \{d : c(d) \ge c_{\max} - m\}` is

* one run of consecutive disparities: one peak -- **unique**;
* two or more runs: a second optimum as good as the first within the noise (a repeated
  pattern) -- **ambiguous** (the peak-ratio idea of [1]_, [2]_ with the ratio's threshold
  replaced by the noise margin); one run wider than ``max_width`` px (an edge along the
  line) -- ambiguous too;
* :math:`s_f \le` ``min_snr`` σ: no signal (a white square) -- **blank**.

:func:`verify_matches` judges a least-squares match by the matcher itself: every separated
local maximum the matcher could accept is matched again from there, and the match is
ambiguous when such a rival is accepted outside the solution's lobe within the margin of
its correlation.  :func:`anchored` resolves an ambiguous match by its unique neighbours'
predictions (at least two, within 3σ).  ``strict`` (a calibrated pair's epipolar pass):
a rival within the margin is ambiguous unless the matcher refutes it, and a survivor's σ
carries the rivals' mixture variance (:class:`Verification`).  The profile's formula,
why the plain profile cannot judge a match alone, and the measurements:
``docs/decisions/stereo-uniqueness.md``.

Shapes: candidates (N, 2) float64 px in the rectified left image; profiles (N, D).

References
----------
.. [1] H. Hirschmüller, D. Scharstein, "Evaluation of stereo matching costs on images
   with radiometric differences", IEEE TPAMI 31(9), 1582-1599 (2009).
.. [2] X. Hu, P. Mordohai, "A quantitative evaluation of confidence measures for stereo
   vision", IEEE TPAMI 34(11), 2121-2133 (2012).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import cKDTree
from scipy.special import ndtr

from matching.validate import check_shape

#: noise margin factor k of the module docstring: 3 standard deviations of the
#: difference of two correlation estimates
MARGIN_K = 3.0
#: no signal: template standard deviation at most this many noise σ
MIN_SNR = 2.0

UNIQUE, AMBIGUOUS, BLANK, OUTSIDE = 0, 1, 2, 3
#: verdict code -> name
VERDICT_NAMES = {UNIQUE: "unique", AMBIGUOUS: "ambiguous", BLANK: "blank", OUTSIDE: "outside"}


@dataclass(frozen=True)
class Profiles:
    """ZNCC profiles of N windows over a disparity range.

    Attributes
    ----------
    disparities : (D,) int64
        The integer disparities x_left - x_right, px.
    cost : (N, D) float32
        ZNCC per window and disparity (NaN where the right window leaves the image).
    template_std : (N,) float64
        :math:`s_f`, grey levels.
    margin : (N,) float64
        :math:`m`, correlation units.
    """

    disparities: np.ndarray
    cost: np.ndarray
    template_std: np.ndarray
    margin: np.ndarray


def zncc_profiles(left_rect, right_rect, points, disparity_range: tuple[int, int],
                  window: int, noise: float) -> Profiles:
    """ZNCC of each left window against the right row over the disparity range.

    Parameters
    ----------
    left_rect, right_rect : (H, W) array_like
        Rectified grey images (rows are epipolar lines), grey levels.
    points : (N, 2) array_like
        Window centres in the rectified left image, px (rounded to the nearest pixel).
    disparity_range : (int, int)
        (min_disparity, count): disparities min .. min + count - 1, px.
    window : int
        Window side, px (odd).
    noise : float or (N,) array_like
        Noise σ each window sees, grey levels (the image's, :func:`matching.lsm.estimate_noise`,
        or a match's own residual σ0 where that is larger).

    Returns
    -------
    Profiles
    """
    points = check_shape(points, "(N, 2)", "points", dtype=np.float64)
    if not (window >= 3 and window % 2 == 1):
        raise ValueError(f"window must be an odd integer >= 3, got {window!r}")
    left = np.asarray(left_rect, dtype=np.float32)
    right = np.asarray(right_rect, dtype=np.float32)
    h, w = left.shape
    dmin, count = int(disparity_range[0]), int(disparity_range[1])
    disparities = np.arange(dmin, dmin + max(count, 1), dtype=np.int64)
    n = len(points)
    cost = np.full((n, len(disparities)), np.nan, np.float32)
    xi = np.rint(points[:, 0]).astype(np.int64)
    yi = np.rint(points[:, 1]).astype(np.int64)
    half = window // 2
    inside = (xi >= half) & (xi < w - half) & (yi >= half) & (yi < h - half)
    xs, ys = xi[inside], yi[inside]
    box = (window, window)

    def mean(img):
        return cv2.boxFilter(img, cv2.CV_32F, box, normalize=True,
                             borderType=cv2.BORDER_REFLECT)

    mf, mg = mean(left), mean(right)
    vf = np.maximum(mean(left * left) - mf * mf, 0.0)
    vg = np.maximum(mean(right * right) - mg * mg, 0.0)
    template_std = np.zeros(n)
    template_std[inside] = np.sqrt(vf[ys, xs])
    # only the rows holding a candidate window are filtered
    rows = np.unique(ys)
    lo, hi = (int(rows.min()) - half, int(rows.max()) + half + 1) if len(rows) else (0, 0)
    sub_f = left[lo:hi]
    sub_y = ys - lo
    col = np.flatnonzero(inside)
    for k, d in enumerate(disparities):
        xr = xs - d
        ok = (xr >= half) & (xr < w - half)
        if not ok.any():
            continue
        shifted = np.zeros_like(sub_f)
        if d >= 0:
            shifted[:, d:] = right[lo:hi, :w - d] if d < w else 0.0
        else:
            shifted[:, :w + d] = right[lo:hi, -d:] if -d < w else 0.0
        cross = mean(sub_f * shifted)[sub_y[ok], xs[ok]]
        cov = cross - mf[ys[ok], xs[ok]] * mg[ys[ok], xr[ok]]
        denom = np.sqrt(vf[ys[ok], xs[ok]] * vg[ys[ok], xr[ok]])
        with np.errstate(divide="ignore", invalid="ignore"):
            cost[col[ok], k] = np.where(denom > 0, cov / denom, np.nan)
    with np.errstate(divide="ignore"):
        margin = (MARGIN_K * np.sqrt(2.0 / (window * window))
                  * np.broadcast_to(np.asarray(noise, np.float64), (n,)) / template_std)
    return Profiles(disparities=disparities, cost=cost, template_std=template_std,
                    margin=margin)


def near_best_runs(cost: np.ndarray, margin: np.ndarray) -> tuple[np.ndarray, ...]:
    """The near-best set of each profile: its runs, best index and run bounds.

    Returns ``runs`` (N,) int64 (number of runs of the near-best set; 0: all NaN),
    ``best`` (N,) int64 (index of the maximum), ``run_lo``, ``run_hi`` (N,) int64 (the
    first and last index of the run holding the maximum).
    """
    n, dcount = cost.shape
    filled = np.where(np.isfinite(cost), cost, -np.inf)
    best = np.argmax(filled, axis=1)
    top = filled[np.arange(n), best]
    near = filled >= (top - margin)[:, None]  # (N, D)
    near &= np.isfinite(top)[:, None]
    padded = np.pad(near, ((0, 0), (1, 1)))
    starts = padded[:, 1:-1] & ~padded[:, :-2]
    runs = starts.sum(axis=1)
    idx = np.arange(dcount)
    # the run holding the best index: the last start at or before it, the first end after it
    start_at = np.where(starts, idx, -1)
    before = np.where(idx[None, :] <= best[:, None], start_at, -1)
    run_lo = before.max(axis=1)
    ends = padded[:, 1:-1] & ~padded[:, 2:]
    end_at = np.where(ends & (idx[None, :] >= best[:, None]), idx, dcount)
    run_hi = end_at.min(axis=1)
    return runs, best, run_lo, run_hi


def classify(profiles: Profiles, noise: float, max_width: float,
             min_snr: float = MIN_SNR) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Verdict per window, the best disparity and the near-best run's bounds.

    Parameters
    ----------
    profiles : Profiles
    noise : float or (N,) array_like
        Noise σ per window, grey levels (as for :func:`zncc_profiles`).
    max_width : float
        Widest near-best run a window may have, px (wider: no structure along the line).
    min_snr : float
        Blank below ``min_snr`` σ of template standard deviation.

    Returns
    -------
    verdict : (N,) uint8
        ``UNIQUE``, ``AMBIGUOUS``, ``BLANK`` or ``OUTSIDE`` (no profile).
    best : (N,) float64
        Disparity of the profile's maximum, px (NaN: none).
    run : (N, 2) float64
        Disparities bounding the maximum's run, px.
    """
    runs, best, lo, hi = near_best_runs(profiles.cost, profiles.margin)
    d = profiles.disparities
    verdict = np.full(len(runs), UNIQUE, np.uint8)
    width = (hi - lo + 1).astype(np.float64)
    verdict[(runs > 1) | (width > max_width)] = AMBIGUOUS
    verdict[profiles.template_std <= min_snr * np.asarray(noise, np.float64)] = BLANK
    verdict[runs == 0] = OUTSIDE
    best_d = np.where(runs > 0, d[np.minimum(best, len(d) - 1)].astype(np.float64), np.nan)
    run = np.column_stack([d[np.clip(lo, 0, len(d) - 1)], d[np.clip(hi, 0, len(d) - 1)]])
    return verdict, best_d, run.astype(np.float64)


def check_solution(disparity: np.ndarray, verdict: np.ndarray, run: np.ndarray,
                   tolerance: float = 1.0) -> np.ndarray:
    """(N,) bool: the solution's disparity lies in the best peak's run of a unique profile.

    ``tolerance`` px: the profile is sampled at integer disparities of the rounded
    window centre, so a sub-pixel solution may lie up to one pixel outside the run.
    """
    inside = (disparity >= run[:, 0] - tolerance) & (disparity <= run[:, 1] + tolerance)
    return (verdict == UNIQUE) & inside


def solution_lobe(cost: np.ndarray, solution_index: np.ndarray) -> tuple[np.ndarray, ...]:
    """The peak a solution sits on and the lobe around it (to the adjacent minima).

    Parameters
    ----------
    cost : (N, D) float
        Profiles (NaN: no value).
    solution_index : (N,) int64
        Index of each solution's disparity in the profile (clipped to 0 .. D-1).

    Returns
    -------
    peak, lo, hi : (N,) int64
        The local maximum within one step of the solution, and the adjacent local
        minima (or the profile's ends) bounding its lobe.
    """
    n, dcount = cost.shape
    filled = np.where(np.isfinite(cost), cost, -np.inf)
    rows = np.arange(n)
    s = np.clip(solution_index, 0, dcount - 1)
    near = np.stack([filled[rows, np.clip(s + k, 0, dcount - 1)] for k in (-1, 0, 1)], axis=1)
    peak = np.clip(s + np.argmax(near, axis=1) - 1, 0, dcount - 1)
    padded = np.pad(filled, ((0, 0), (1, 1)), constant_values=-np.inf)
    # a local minimum: not above either neighbour (the ends count as minima)
    is_min = (filled <= padded[:, :-2]) & (filled <= padded[:, 2:])
    is_min[:, 0] = is_min[:, -1] = True
    idx = np.arange(dcount)
    lo = np.where(is_min & (idx[None, :] < peak[:, None]), idx, 0).max(axis=1)
    hi = np.where(is_min & (idx[None, :] > peak[:, None]), idx, dcount - 1).min(axis=1)
    return peak, lo, hi


def separated_peaks(profiles: Profiles, solution_disparity: np.ndarray, floor: float,
                    max_peaks: int = 4) -> np.ndarray:
    """Disparities of the strongest local maxima outside each solution's lobe.

    Parameters
    ----------
    profiles : Profiles
    solution_disparity : (N,) float64
        Disparity of each match, px.
    floor : float
        Only maxima with ZNCC at least this (a correlation the matcher would accept).
    max_peaks : int
        At most this many per window, strongest first.

    Returns
    -------
    (N, max_peaks) float64
        Disparities, px (NaN: none).
    """
    cost = profiles.cost
    n, dcount = cost.shape
    d0 = int(profiles.disparities[0])
    sol = np.rint(solution_disparity - d0)
    sol = np.where(np.isfinite(sol), sol, 0).astype(np.int64)
    _, lo, hi = solution_lobe(cost, sol)
    filled = np.where(np.isfinite(cost), cost, -np.inf)
    padded = np.pad(filled, ((0, 0), (1, 1)), constant_values=-np.inf)
    is_max = (filled >= padded[:, :-2]) & (filled >= padded[:, 2:]) & (filled >= floor)
    idx = np.arange(dcount)
    outside = (idx[None, :] < lo[:, None]) | (idx[None, :] > hi[:, None])
    score = np.where(is_max & outside, filled, -np.inf)
    k = min(max_peaks, dcount)
    top = np.argsort(-score, axis=1)[:, :k]
    chosen = np.take_along_axis(score, top, axis=1)
    out = np.where(np.isfinite(chosen), (top + d0).astype(np.float64), np.nan)
    if k < max_peaks:
        out = np.pad(out, ((0, 0), (0, max_peaks - k)), constant_values=np.nan)
    return out


def correlation_margin(window: int, noise, template_std) -> np.ndarray:
    """:math:`m = k \\sqrt{2/n}\\, \\sigma / s_f` per window (module docstring)."""
    with np.errstate(divide="ignore"):
        return (MARGIN_K * np.sqrt(2.0 / (window * window)) * np.asarray(noise, np.float64)
                / np.asarray(template_std, np.float64))


@dataclass(frozen=True)
class Verification:
    r"""What :func:`verify_matches` found (arrays over the N matches given).

    Attributes
    ----------
    verdict : (N,) uint8
        ``UNIQUE``, ``AMBIGUOUS`` (a separated peak matched as well within the margin),
        ``BLANK`` (no signal) or ``OUTSIDE`` (not checked: no profile, or not accepted).
    peaks_tried : (N,) int64
        Separated peaks re-matched per window.
    margin : (N,) float64
        Correlation margin m, correlation units.
    lobe : (N, 2) float64
        Disparities bounding the solution's lobe, px.
    peak : (N,) float64
        Sub-pixel disparity of the profile's peak at the solution (parabola through the
        three samples around it), px.
    peak_sigma : (N,) float64
        :math:`\sqrt{2 m / \kappa}`: the disparity change over which the peak (curvature
        :math:`\kappa`) drops by the margin m -- how far the noise lets the peak move, px.
    rival_var : (N,) float64
        What the rivals leave to a unique match's disparity, px²:
        :math:`\sum_p P_p (d_p - d)^2` over its separated peaks, :math:`P_p =
        \Phi(-3 (c - c_p) / m)` the chance that noise (the difference of two correlation
        estimates has standard deviation m/3) puts the rival peak :math:`c_p` above the
        solution's :math:`c` (the variance of the two-hypothesis mixture; 0: no rival).
    """

    verdict: np.ndarray
    peaks_tried: np.ndarray
    margin: np.ndarray
    lobe: np.ndarray
    peak: np.ndarray
    peak_sigma: np.ndarray
    rival_var: np.ndarray | None = None


def verify_matches(match, points, result, left_rect, right_rect, xl_rect,
                   xr_rect, rect_to_right, search_range: tuple[int, int], noise: float,
                   patch: int, min_correlation: float = 0.7, max_peaks: int = 4,
                   shape=None, strict: bool = False, interval=None) -> Verification:
    """Check every accepted match for a second solution along its epipolar line.

    The plain ZNCC profile (:func:`zncc_profiles`) finds the candidates cheaply; it cannot
    decide alone: perspective lowers the truth's correlation, while a repeat elsewhere may
    be less distorted (chessboard pair 02: 0.95 at the truth, 0.99 one period off).
    So each separated local maximum the matcher could accept (ZNCC >= its
    ``min_correlation``) is matched again by the matcher itself from there, with the
    solution's shape and radiometry: the match is ambiguous when such a re-match is
    accepted, lands outside the solution's lobe, and correlates within the margin
    ``m`` of the solution (its residual σ0 as the noise).

    Parameters
    ----------
    match : callable
        ``match(index, approx, initial, sigma0_population, direction) -> LSMResult``:
        the pair's matcher (``lsm_match`` with the pair's options) for the windows
        ``points[index]`` started at ``approx`` (M, 2) with ``initial`` (M, 8), the shift
        constrained to ``direction`` (M, 2).
    points : (N, 2) float64
        Template centres in the left image, px.
    result : LSMResult
        The matches (N).
    left_rect, right_rect : (H', W') float
        The rectified pair.
    xl_rect, xr_rect : (N, 2) float64
        Template centres and matched positions in the rectified frame, px.
    rect_to_right : callable
        Rectified right pixels (M, 2) -> right-image pixels (M, 2) of ``match``.
    search_range : (int, int)
        (min_disparity, count), px.
    noise : float
        Image noise σ, grey levels.
    patch : int
        Window side, px.
    min_correlation : float
        The matcher's acceptance floor: only profile peaks at least this high are
        re-matched.
    max_peaks : int
        Separated peaks re-matched per window at most.
    shape : (N, 8) array_like, optional
        Warp and radiometry ``a0 a1 a2 b0 b1 b2 r0 r1`` to start each rival's re-match from
        (its shift replaced by the rival's; default: identity shape and radiometry).
    strict : bool
        The rule of a match that must show it is unique: a rival peak whose plain ZNCC
        is within the margin m of the solution's (or above it) makes the match
        ambiguous unless its re-match refutes it (accepted in the solution's lobe, or
        outside it with a correlation lower by more than m); default False: only an
        accepted rival as good within m, or a failed re-match of a peak above the
        solution's by more than m, does.
    interval : (N, 2) array_like, optional
        The disparities (px) geometry admits per match (not from its window: its verified
        neighbours' plane); the profile outside is not searched (default: none).

    Returns
    -------
    Verification
    """
    n = len(points)
    verdict = np.full(n, OUTSIDE, np.uint8)
    tried = np.zeros(n, np.int64)
    margin, peak, peak_sigma = (np.full(n, np.nan) for _ in range(3))
    lobe = np.full((n, 2), np.nan)
    ok = np.flatnonzero(result.status == 0)
    rival_var = np.zeros(n)
    if not len(ok):
        return Verification(verdict, tried, margin, lobe, peak, peak_sigma, rival_var)
    solution = xl_rect[ok, 0] - xr_rect[ok, 0]
    window_noise = np.maximum(float(noise), np.nan_to_num(result.sigma0[ok], nan=0.0))
    prof = zncc_profiles(left_rect, right_rect, xl_rect[ok], search_range, patch,
                         window_noise)
    if interval is not None:
        bounds = np.asarray(interval, np.float64)[ok]
        d = prof.disparities[None, :]
        prof.cost[(d < bounds[:, :1]) | (d > bounds[:, 1:])] = np.nan
    has = np.isfinite(prof.cost).any(axis=1)
    d0 = int(prof.disparities[0])
    sol = np.clip(np.rint(np.nan_to_num(solution - d0)), 0, prof.cost.shape[1] - 1)
    top, lo, hi = solution_lobe(prof.cost, sol.astype(np.int64))
    lobe[ok] = np.column_stack([lo + d0, hi + d0])
    m = correlation_margin(patch, window_noise, prof.template_std)
    margin[ok] = m
    # the solution away from the profile's best peak, below the matcher's floor
    filled, at_solution, not_best = _best_elsewhere(prof, sol, m, min_correlation)
    peaks = separated_peaks(prof, solution, float(min_correlation), max_peaks)  # (M, K)
    rows, cols = np.nonzero(np.isfinite(peaks) & has[:, None])
    ambiguous = not_best.copy()
    if len(rows):
        _rematch_peaks(match, result, xl_rect, rect_to_right, shape, strict, ok, rows,
                       peaks[rows, cols], (lo, hi, d0), m, filled, at_solution, solution,
                       ambiguous, tried, rival_var)
    peak[ok], peak_sigma[ok] = _peak_at(prof.cost, top, d0, m)
    v = np.where(ambiguous, AMBIGUOUS, UNIQUE).astype(np.uint8)
    v[prof.template_std <= MIN_SNR * float(noise)] = BLANK
    v[~has] = OUTSIDE
    verdict[ok] = v
    return Verification(verdict, tried, margin, lobe, peak, peak_sigma, rival_var)


def _best_elsewhere(prof: Profiles, sol, m, min_correlation):
    """:func:`verify_matches`' plain profile around each solution: the profile with NaN as
    -inf, its best within one step of the solution, and where its best peak is elsewhere
    by more than the margin ``m`` while the solution's is below the matcher's floor."""
    # the solution away from the profile's best peak, where the plain window would not
    # even be accepted (ZNCC below the matcher's floor): the affine warp was bent to fit
    # a lesser repeat (chessboard pair 02: slips at ZNCC 0.4-0.6, the truth at 0.99);
    # above the floor the plain profile is not trusted over LSM -- foreshortening lowers
    # the true peak's plain ZNCC (temple pairs)
    filled = np.where(np.isfinite(prof.cost), prof.cost, -np.inf)
    rows_all = np.arange(len(filled))
    at_solution = np.max(np.stack([filled[rows_all, np.clip(sol.astype(np.int64) + k, 0,
                                                            filled.shape[1] - 1)]
                                   for k in (-1, 0, 1)]), axis=0)
    best_index = np.argmax(filled, axis=1)
    not_best = ((filled[rows_all, best_index] > at_solution + m)
                & (np.abs(best_index - sol) > 1) & (at_solution < min_correlation))
    return filled, at_solution, not_best


def _rematch_peaks(match, result, xl_rect, rect_to_right, shape, strict, ok, rows, d,
                   lobe_range, m, filled, at_solution, solution, ambiguous, tried,
                   rival_var) -> None:
    """:func:`verify_matches`' re-match of the separated peaks ``d`` (of the windows
    ``ok[rows]``) along the epipolar line: marks ``ambiguous`` (per ok window) where a
    rival stands, counts ``tried`` and adds each rival's share of the two-hypothesis
    mixture's variance to ``rival_var`` (both per window), in place."""
    lo, hi, d0 = lobe_range
    i = ok[rows]
    start = rect_to_right(np.column_stack([xl_rect[i, 0] - d, xl_rect[i, 1]]))
    # started as the first pass starts (identity shape and radiometry): the
    # solution's own warp may be the distortion that fitted a wrong repeat
    init = np.zeros((len(i), 8))
    if shape is not None:
        init[:] = np.asarray(shape, np.float64)[i]
    else:
        init[:, [1, 5, 7]] = 1.0
    init[:, [0, 3]] = start
    # along the epipolar line only: a free 2-D shift slides along the straight edges
    # of a repeated pattern (a chessboard's) and leaves the pull-in range
    ahead = rect_to_right(np.column_stack([xl_rect[i, 0] - d + 1.0, xl_rect[i, 1]]))
    direction = ahead - start
    direction /= np.maximum(np.linalg.norm(direction, axis=1, keepdims=True), 1e-12)
    again = match(i, start, init, result.sigma0[ok], direction)
    # where each re-match landed, as a disparity in the rectified frame
    landed = _rectified_disparity(again.position, xl_rect[i], rect_to_right, start, d)
    outside_lobe = (landed < lo[rows] + d0 - 1.0) | (landed > hi[rows] + d0 + 1.0)
    rival = ((again.status == 0) & outside_lobe
             & (again.correlation >= result.correlation[i] - m[rows]))
    # a peak the plain profile prefers to the solution by more than the margin, where
    # the matcher cannot confirm either way (its re-match fails): undecided, not
    # unique (chessboard pair 04: the truth at ZNCC 0.99 beside a slip at 0.85, its
    # re-match out of pull-in range on the tilted board)
    peak_c = filled[rows, np.clip(d.astype(np.int64) - d0, 0, filled.shape[1] - 1)]
    rival |= (again.status != 0) & (peak_c > at_solution[rows] + m[rows])
    if strict:
        # a second optimum as good within the noise that the matcher does not refute
        refuted = (again.status == 0) & (~outside_lobe | (again.correlation
                                                         < result.correlation[i] - m[rows]))
        rival |= (peak_c >= at_solution[rows] - m[rows]) & ~refuted
    np.logical_or.at(ambiguous, rows, rival)
    np.add.at(tried, i, 1)
    # the two-hypothesis mixture's variance: each rival peak's chance of being the
    # better one under the noise (the difference of two correlation estimates has
    # standard deviation m / 3), times its squared distance
    with np.errstate(divide="ignore", invalid="ignore"):
        z = 3.0 * (at_solution[rows] - peak_c) / m[rows]
    chance = np.where(np.isfinite(z), ndtr(-z), 1.0)
    sol_d = solution[rows]
    np.add.at(rival_var, i, chance * (d - sol_d) ** 2)


def _peak_at(cost, top, d0: int, m):
    """:func:`verify_matches`' sub-pixel peak at each solution's profile maximum ``top``
    (index; ``d0`` the first disparity) and how far the margin ``m`` lets it move."""
    sub, curvature = _parabola(cost, top)
    with np.errstate(divide="ignore", invalid="ignore"):
        return top + d0 + sub, np.where(curvature > 0, np.sqrt(2.0 * m / curvature), np.inf)


def _parabola(cost, index):
    """Sub-pixel offset (N,) and curvature κ = -(c₋ - 2c₀ + c₊) (N,) of the parabola
    through the profile samples around ``index`` (κ <= 0: not a peak)."""
    n, dcount = cost.shape
    rows = np.arange(n)
    c0 = cost[rows, index].astype(np.float64)
    cm = cost[rows, np.maximum(index - 1, 0)].astype(np.float64)
    cp = cost[rows, np.minimum(index + 1, dcount - 1)].astype(np.float64)
    kappa = -(cm - 2.0 * c0 + cp)
    with np.errstate(divide="ignore", invalid="ignore"):
        sub = np.where(kappa > 0, 0.5 * (cp - cm) / kappa, 0.0)
    return np.clip(np.nan_to_num(sub), -0.5, 0.5), np.nan_to_num(kappa, nan=-1.0)


def _rectified_disparity(position, xl_rect, rect_to_right, start, d_start):
    """Disparity (rectified frame) of right-image positions near ``start`` (at ``d_start``).

    Linearised: one pixel along the rectified row maps to ``rect_to_right(x + 1) - start``
    in the right image; the position's offset from ``start`` projected on that step
    (divided by its squared length) is the disparity change (sign: disparity falls as x
    grows).
    """
    ahead = rect_to_right(np.column_stack([xl_rect[:, 0] - d_start + 1.0, xl_rect[:, 1]]))
    step = ahead - start
    shift = position - start
    along = np.einsum("ij,ij->i", shift, step) / np.maximum(np.einsum("ij,ij->i", step, step),
                                                           1e-12)
    return d_start - along


def anchored(points, position, sigma, affine, anchors, candidates, radius: float,
             max_offset=None, neighbours: int = 4, max_rounds: int = 500) -> np.ndarray:
    """Ambiguous matches resolved by their unique neighbours: which agree with them.

    A match whose window alone is ambiguous is kept when its position agrees with the
    prediction of its accepted neighbours (each neighbour's affine warp,
    :math:`\\hat x(q) = (a_0, b_0)_p + A_p (q - p)`, median over the nearest
    ``neighbours`` within ``radius``) to within :math:`3\\sqrt{\\sigma_q^2 + \\sigma_p^2}`,
    at least 1 px.  Every rival of an ambiguous window lies outside its solution's lobe,
    two or more profile samples (px) away, so agreement within 1 px cannot pick a rival
    -- a one-period slip is a period off the prediction.  Resolved matches become
    anchors for the next round (region growing over the resolved set: a repeated pattern
    is carried from where its period is pinned, e.g. the board's border, inwards).

    Parameters
    ----------
    points : (N, 2) float64
        Template centres, px.
    position : (N, 2) float64
        Matched positions, px.
    sigma : (N,) float64
        Their σ, px.
    affine : (N, 6) float64
        ``a0 a1 a2 b0 b1 b2`` of each match.
    anchors, candidates : (N,) bool
        Unique accepted matches; ambiguous ones to resolve.
    radius : float
        Largest neighbour distance, px.
    max_offset : (N,) float64, optional
        Largest accepted disagreement per match, px (default: none): the distance from
        the solution to the edge of its lobe, so that σ, however large, cannot reach a
        rival.

    Returns
    -------
    (N,) bool
        The candidates resolved.
    """
    anchor = np.asarray(anchors, bool).copy()
    todo = np.asarray(candidates, bool) & ~anchor
    resolved = np.zeros(len(points), bool)
    for _ in range(max_rounds):
        acc = np.flatnonzero(anchor)
        cand = np.flatnonzero(todo)
        if not len(acc) or not len(cand):
            break
        k = min(neighbours, len(acc))
        tree = cKDTree(points[acc])
        dist, nb = tree.query(points[cand], k=k, distance_upper_bound=radius)
        dist, nb = dist.reshape(len(cand), k), nb.reshape(len(cand), k)
        found = np.isfinite(dist)
        reach = found[:, 0]
        if not reach.any():
            break
        j = acc[np.where(found, nb, 0)]  # (M, k)
        aff = affine[j]
        d = points[cand][:, None, :] - points[j]
        pu = aff[..., 0] + aff[..., 1] * d[..., 0] + aff[..., 2] * d[..., 1]
        pv = aff[..., 3] + aff[..., 4] * d[..., 0] + aff[..., 5] * d[..., 1]
        off = np.hypot(pu - position[cand, 0:1], pv - position[cand, 1:2])  # (M, k)
        tol = np.maximum(3.0 * np.sqrt(sigma[cand, None] ** 2 + sigma[j] ** 2), 1.0)
        if max_offset is not None:
            tol = np.minimum(tol, np.maximum(max_offset[cand], 1.0)[:, None])
        # every anchor in reach agrees, and at least two do: a lone wrong anchor (one
        # slip that passed as unique) cannot carry its slip into the ambiguous region
        # around it
        agree_each = found & (off <= tol)
        disagree = (found & ~(off <= tol)).any(axis=1)
        agree = reach & ~disagree & (agree_each.sum(axis=1) >= 2)
        if not agree.any():
            break
        anchor[cand[agree]] = True
        resolved[cand[agree]] = True
        todo[cand[agree]] = False
    return resolved
