"""Closed Catmull-Rom curves through the control points of a section.

The method's eq. (3,5), segment ``i`` for ``t ∈ [0, 1]``::

    Q_i(t) = ½ · [t³ t² t 1] · M_CR · [P_{i−3} P_{i−2} P_{i−1} P_i]ᵀ,
    M_CR = [[−1, 3, −3, 1], [2, −5, 4, −1], [−1, 0, 1, 0], [0, 2, 0, 0]]

interpolates its control points with tangents ``m_j = (P_{j+1} − P_{j−1})/2``: the periodic
cubic Hermite interpolant, evaluated by :class:`scipy.interpolate.CubicHermiteSpline` [1]_.
Global parameter ``t ∈ [0, n)``, ``Q(j) = P_j``; moving ``P_j`` changes 4 segments only.
``parametrisation="centripetal"`` / ``"chordal"`` use knot intervals ``|ΔP|^α`` (α = ½, 1) and
the Barry–Goldman tangent, which avoids cusps and self-intersections [2]_.

*Smoothing* (a priori): ``smoothing`` data points per control point.  M ordered points are
fitted by ``n = max(4, round(M / smoothing))`` control points, linear least squares in the
Catmull-Rom basis plus a light fairness term on third differences (weight ``λ' = 0.01 g_0``),
the data parametrised by arc length along a moving average; the curve's noise is about
``σ/√smoothing`` for point noise σ.  ``smoothing ≤ 1`` interpolates.

*Gaps* (:func:`bridge_gaps`, in :func:`fit_loop`): a step longer than the loop's expected
largest step (``topology.Loop.bridge``) and than :data:`BRIDGE_SHARE` of its length gets
points along its chord before the fit, so the curve is flat where nothing was seen.

*Precision* (:func:`precision_factor`): with ``K = AᵀA + λDᵀD`` the control points'
covariance is ``σ² K⁻¹AᵀA K⁻¹``; for data spread evenly in ``t`` every matrix is circulant
and the curve's mean variance is ``σ² (n / M) ρ(n)``,
``ρ(n) = (1/n) Σ_ω [ĝ(ω) / (ĝ(ω) + λ' d̂(ω))]²``, ``ĝ`` the symbol of the basis' Gram matrix
(``g_0 = 57/70``, ``g_±1 = 71/560``, ``g_±2 = −1/28``, ``g_±3 = 1/560``), ``d̂ = (2 − 2 cos ω)³``
(ρ ≈ 0.73 for n ≥ 8).  Derivations and measurements: ``docs/method/catmull-rom.md``.

References
----------
.. [1] E. Catmull and R. Rom, "A class of local interpolating splines",
   Computer Aided Geometric Design, Academic Press (1974), 317–326.
.. [2] C. Yuksel, S. Schaefer and J. Keyser, "Parameterization and
   applications of Catmull-Rom curves", Computer-Aided Design 43 (2011) 747–755.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from functools import lru_cache

import numba
import numpy as np
from scipy.interpolate import CubicHermiteSpline

from surface.cyclic_band import (
    band_rows,
    cholesky_cyclic_band,
    cyclic_band,
    interleaved,
    normal_equations_band,
    solve_band,
    third_difference_band,
    third_difference_gram,
)
from surface.sections import common_frame
from surface.validate import TOL, check_finite, check_shape

__all__ = [
    "M_CR",
    "ClosedCurve",
    "bridge_gaps",
    "branch_ring_size",
    "perimeter",
    "RingFit",
    "choose_smoothing",
    "fit",
    "fit_loop",
    "predict_ring",
    "precision_factor",
    "predict_sections",
    "ring_size",
]

#: The paper's basis matrix (eq. 3,5), to be used with the factor ½.
M_CR = np.array(
    [[-1.0, 3.0, -3.0, 1.0], [2.0, -5.0, 4.0, -1.0], [-1.0, 0.0, 1.0, 0.0], [0.0, 2.0, 0.0, 0.0]]
)
_ALPHA = {"uniform": 0.0, "centripetal": 0.5, "chordal": 1.0}
#: Bisection steps: halves [0, h] down to below double precision.
_BISECT_STEPS = 64
#: Dense samples per segment for arc length (chord error ~ (h/64)^2 κ).
_ARC_SAMPLES = 64
#: Weight of the third-difference fairness term relative to one data point (see _least_squares).
_FAIRNESS = 1e-2


def _next(a: np.ndarray) -> np.ndarray:
    """``np.roll(a, -1, axis=0)`` (each row's successor, cyclically) without its overhead."""
    return np.concatenate([a[1:], a[:1]])


def _previous(a: np.ndarray) -> np.ndarray:
    """``np.roll(a, 1, axis=0)``."""
    return np.concatenate([a[-1:], a[:-1]])


def _check_curve_input(points, name: str, parametrisation: str) -> np.ndarray:
    """``(n, 3)`` finite float64 points, n >= 4 (a closed cubic needs 4), and a known
    parametrisation; ``ValueError`` naming ``name`` otherwise."""
    pts = check_shape(points, "(N, 3)", name, dtype=np.float64)
    check_finite(pts, name)
    if len(pts) < 4:
        raise ValueError(f"{name} needs at least 4 points to make a closed curve, got {len(pts)}")
    if parametrisation not in _ALPHA:
        raise ValueError(
            f"parametrisation must be one of {sorted(_ALPHA)}, got {parametrisation!r}"
        )
    return pts



@dataclass(frozen=True, eq=False)
class ClosedCurve:
    """A closed Catmull-Rom curve in a section plane.

    Build it with :meth:`from_control_points` or :func:`fit`.

    Attributes
    ----------
    control_points : (n, 3) float64
        Interpolated points, world coordinates, counter-clockwise seen from
        ``+frame[2]`` when built by :func:`fit`.
    knots : (n + 1,) float64
        Parameter of each control point, ``knots[0] = 0``; the last is the
        period (``n`` for the uniform curve).
    tangents : (n, 3) float64
        dQ/dt at each control point.
    frame : (3, 3) float64
        Rows ``e1, e2, axis`` of the section frame (θ is measured in it).
    centroid : (3,) float64
        Centre about which θ is measured (the loop centroid).
    parametrisation : str
        ``"uniform"`` (the paper), ``"centripetal"`` or ``"chordal"``.
    spline : scipy.interpolate.CubicHermiteSpline
        Periodic evaluator; ``spline.c`` has shape ``(4, n, 3)``.
    smoothing : float
        Data points per control point of the fit (the chosen one for
        ``smoothing="auto"``); 1.0 for an interpolating curve.
    """

    control_points: np.ndarray
    knots: np.ndarray
    tangents: np.ndarray
    frame: np.ndarray
    centroid: np.ndarray
    parametrisation: str
    spline: CubicHermiteSpline
    #: Data points per control point used by :func:`fit` (1.0: interpolating).
    smoothing: float = 1.0

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_control_points(
        cls,
        control_points: np.ndarray,
        parametrisation: str = "uniform",
        frame: np.ndarray | None = None,
        centroid: np.ndarray | None = None,
    ) -> ClosedCurve:
        """Closed curve interpolating ``control_points`` ``(n, 3)``, n ≥ 4 (in order).

        ``frame`` defaults to a frame whose axis is the normal of the points'
        best-fit plane; ``centroid`` to the control points' mean.
        """
        pts = _check_curve_input(control_points, "control_points", parametrisation)
        if frame is None:
            frame = _plane_frame(pts)
        frame = check_shape(frame, "(3, 3)", "frame", np.float64)
        if centroid is None:
            centroid = pts.mean(axis=0)
        centroid = check_shape(centroid, "(3,)", "centroid", np.float64)
        return _build(pts.copy(), parametrisation, frame, centroid)

    @property
    def n(self) -> int:
        """Number of control points (= number of segments)."""
        return int(self.control_points.shape[0])

    @property
    def period(self) -> float:
        """Parameter length of one turn."""
        return float(self.knots[-1])

    # ------------------------------------------------------------------ evaluation
    def evaluate(self, t) -> np.ndarray:
        """Points ``Q(t)``, shape ``t.shape + (3,)``; t is taken modulo the period."""
        return self.spline(np.asarray(t, dtype=np.float64))

    def derivative(self, t, order: int = 1) -> np.ndarray:
        """``d^order Q / dt^order`` at ``t``, shape ``t.shape + (3,)``."""
        return self.spline(np.asarray(t, dtype=np.float64), order)

    def to_plane(self, points: np.ndarray) -> np.ndarray:
        """World points ``(..., 3)`` → coordinates ``(..., 2)`` about the centroid."""
        return (np.asarray(points) - self.centroid) @ self.frame[:2].T

    def theta(self, points: np.ndarray) -> np.ndarray:
        """Angle in [0, 2π) of world points about the centroid, in the frame."""
        uv = self.to_plane(points)
        return np.mod(np.arctan2(uv[..., 1], uv[..., 0]), 2 * np.pi)

    def signed_area(self) -> float:
        """Area enclosed by the control polygon in the frame (> 0: counter-clockwise)."""
        uv = self.to_plane(self.control_points)
        x, y = uv[:, 0], uv[:, 1]
        return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))

    def is_star_shaped(self) -> bool:
        """True when θ about the centroid increases strictly along the control polygon.

        Every ray from the centroid then meets the polygon once (winding one,
        no fold back), the condition for :meth:`resample_theta`.
        """
        phi = self.theta(self.control_points)
        dphi = np.mod(np.roll(phi, -1) - phi + np.pi, 2 * np.pi) - np.pi  # in [-π, π)
        return bool(np.all(dphi > 0) and round(dphi.sum() / (2 * np.pi)) == 1)

    # ------------------------------------------------------------------ resampling
    def resample_theta(self, n: int, theta0: float = 0.0) -> np.ndarray:
        """Points of the curve at θ = theta0 + 2πk/n about the centroid, ``(n, 3)``.

        Each ray from the centroid is intersected with the segment whose end
        control points bracket its angle; the root of
        ``cross(d, Q(τ) − C) = 0`` is found by vectorised bisection to double
        precision, so ``θ(point_k)`` equals the requested angle to ~1e-15 rad.

        Raises
        ------
        ValueError
            ``n < 1`` or the curve is not star-shaped about its centroid (use
            :meth:`resample_arclength`).
        """
        n = _check_count(n, "n")
        if not self.is_star_shaped():
            raise ValueError(
                "curve is not star-shaped about its centroid: resample_theta cannot "
                "place one point per ray; use resample_arclength"
            )
        phi = self.theta(self.control_points)
        dphi = np.mod(np.diff(np.append(phi, phi[0])) + np.pi, 2 * np.pi) - np.pi
        unwrapped = phi[0] + np.concatenate([[0.0], np.cumsum(dphi)])  # (n_c + 1,)
        targets = theta0 + 2 * np.pi * np.arange(n) / n
        local = phi[0] + np.mod(targets - phi[0], 2 * np.pi)  # in [phi0, phi0 + 2π)
        seg = np.clip(np.searchsorted(unwrapped, local, side="right") - 1, 0, self.n - 1)
        direction = np.stack([np.cos(targets), np.sin(targets)], axis=1)  # (n, 2)
        t = self._ray_roots(seg, direction)
        return self.evaluate(t)

    def _ray_roots(self, seg: np.ndarray, direction: np.ndarray) -> np.ndarray:
        """Global parameter where each ray meets its segment (bisection, vectorised).

        On segment ``s`` the curve is the cubic ``Σ_k c_k τ^(3−k)`` (``spline.c``);
        ``f(τ) = cross(d, Q(τ) − C)`` is then a scalar cubic evaluated by Horner's
        rule, so each bisection step is a few array operations on the rays.
        """
        coeffs = self.spline.c[:, seg, :] @ self.frame[:2].T  # (4, n, 2) in the plane
        coeffs[3] -= (self.centroid @ self.frame[:2].T)[None, :]
        cubic = direction[None, :, 0] * coeffs[:, :, 1] - direction[None, :, 1] * coeffs[:, :, 0]
        hi = np.diff(self.knots)[seg]
        return self.knots[seg] + _bisect_cubics(np.ascontiguousarray(cubic), hi, _BISECT_STEPS)

    def resample_arclength(self, n: int, theta0: float = 0.0) -> np.ndarray:
        """``n`` points at equal arc length, counter-clockwise, ``(n, 3)``.

        The first point is where the curve crosses the ray at ``theta0`` from
        the centroid (the outermost crossing if several; the point of θ
        closest to ``theta0`` if the ray misses the curve), so rings of
        adjacent sections start at the same angle.  Arc length is measured on
        64 samples per segment (relative error ~1e-5 for smooth sections).
        """
        n = _check_count(n, "n")
        t_dense = np.linspace(0.0, self.period, self.n * _ARC_SAMPLES + 1)
        t_start = self._start_parameter(t_dense, theta0)
        t_dense = t_start + t_dense  # one turn from the start (periodic evaluation)
        pts = self.evaluate(t_dense)
        cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
        targets = cum[-1] * np.arange(n) / n
        return self.evaluate(np.interp(targets, cum, t_dense))

    def _start_parameter(self, t_dense: np.ndarray, theta0: float) -> float:
        uv = self.to_plane(self.evaluate(t_dense))
        d = np.array([np.cos(theta0), np.sin(theta0)])
        cross = d[0] * uv[:, 1] - d[1] * uv[:, 0]
        along = uv @ d
        crossing = np.flatnonzero((cross[:-1] <= 0) & (cross[1:] > 0) & (along[:-1] > 0))
        if crossing.size == 0:
            ang = np.abs(np.mod(np.arctan2(uv[:, 1], uv[:, 0]) - theta0 + np.pi, 2 * np.pi) - np.pi)
            return float(t_dense[int(np.argmin(ang))])
        best = crossing[np.argmax(along[crossing])]
        seg_t = t_dense[[best]]
        step = t_dense[1] - t_dense[0]
        lo, hi = 0.0, float(step)
        for _ in range(_BISECT_STEPS):  # invariant cross(lo) <= 0 < cross(hi)
            mid = 0.5 * (lo + hi)
            q = self.to_plane(self.evaluate(seg_t + mid))[0]
            if d[0] * q[1] - d[1] * q[0] <= 0:
                lo = mid
            else:
                hi = mid
        return float(seg_t[0] + 0.5 * (lo + hi))

    # ------------------------------------------------------------------ local update
    def update_point(self, index: int, new_point) -> ClosedCurve:
        """A new curve with control point ``index`` moved to ``new_point`` ``(3,)``.

        Only the tangents at ``index−1, index, index+1`` change, hence only
        the 4 segments from ``P_{index−2}`` to ``P_{index+2}``; the others'
        polynomial coefficients are bitwise identical.  Frame and centroid
        are kept (θ stays measured about the same centre).
        """
        if not -self.n <= int(index) < self.n:
            raise ValueError(f"index must be in [-{self.n}, {self.n}), got {index}")
        new_point = check_shape(new_point, "(3,)", "new_point", dtype=np.float64)
        check_finite(new_point, "new_point")
        pts = self.control_points.copy()
        pts[int(index) % self.n] = new_point
        curve = _build(pts, self.parametrisation, self.frame, self.centroid)
        return replace(curve, smoothing=self.smoothing)

    def segment_coefficients(self) -> np.ndarray:
        """Power-basis coefficients ``(4, n, 3)`` of each segment (``spline.c``)."""
        return self.spline.c


def _check_count(n, name: str) -> int:
    if int(n) != n or n < 1:
        raise ValueError(f"{name} must be a positive integer, got {n!r}")
    return int(n)


def _plane_frame(points: np.ndarray) -> np.ndarray:
    centred = points - points.mean(axis=0)
    _, vecs = np.linalg.eigh(centred.T @ centred)
    normal = vecs[:, 0]
    normal = normal if normal[np.argmax(np.abs(normal))] > 0 else -normal
    return common_frame(normal)


def _build(pts, parametrisation, frame, centroid) -> ClosedCurve:
    """Knots, tangents and the periodic Hermite spline of a control polygon."""
    alpha = _ALPHA[parametrisation]
    prev, nxt = np.roll(pts, 1, axis=0), np.roll(pts, -1, axis=0)
    if alpha == 0.0:
        intervals = np.ones(len(pts))
        tangents = 0.5 * (nxt - prev)  # central differences: exactly eq. (3,5)
    else:
        chord = np.linalg.norm(nxt - pts, axis=1)
        floor = TOL.zero * max(float(chord.max()), TOL.zero)
        intervals = np.maximum(chord, floor) ** alpha  # d_j: knot interval j → j+1
        d_prev = np.roll(intervals, 1)
        tangents = (
            (pts - prev) / d_prev[:, None]
            - (nxt - prev) / (d_prev + intervals)[:, None]
            + (nxt - pts) / intervals[:, None]
        )
    knots = np.concatenate([[0.0], np.cumsum(intervals)])
    spline = CubicHermiteSpline(
        knots,
        np.vstack([pts, pts[:1]]),
        np.vstack([tangents, tangents[:1]]),
        axis=0,
        extrapolate="periodic",
    )
    return ClosedCurve(pts, knots, tangents, frame, np.asarray(centroid), parametrisation, spline)


# ----------------------------------------------------------------------------- fitting
def _basis(u: np.ndarray) -> np.ndarray:
    """Weights ``(M, 4)`` of P_{j−1}, P_j, P_{j+1}, P_{j+2} at local u ∈ [0, 1] (eq. 3,5)."""
    powers = np.stack([u**3, u**2, u, np.ones_like(u)], axis=1)
    return 0.5 * powers @ M_CR


def _data_parameters(points: np.ndarray, window: int, n_ctrl: int) -> np.ndarray:
    """Parameters ``(M,)`` in [0, n_ctrl) proportional to arc length along the loop.

    ``n_ctrl · arc / total`` modulo ``n_ctrl`` with ``arc, total`` from
    :func:`_arc_parameters`.
    """
    arc, total = _arc_parameters(points, window)
    return np.mod(n_ctrl * arc / total, n_ctrl)


def _arc_parameters(points: np.ndarray, window: int) -> tuple[np.ndarray, float]:
    """Arc length ``(M,)`` of each point's foot along the smoothed loop, and its length.

    The arc length is measured on a circular moving average ``s_j`` of width
    ``window`` (noise would inflate it), and each point is placed at its own
    foot on that polyline to first order, ``cum_j + (x_j − s_j)·T_j`` with
    ``T_j`` the unit tangent (without that term the parameter of ``x_j`` would
    be the window's mean position, off by ~√window gaps).
    """
    m = len(points)
    # At most half the loop: a window of the whole loop averages every point to
    # the centroid (a zero-length polyline) even when the points are distinct.
    window = int(min(max(window, 1), max(1, m // 2)))
    if window > 1:  # circular moving average by a cumulative sum, O(M)
        half = window // 2
        padded = np.concatenate([points[m - half :], points, points[: window - half]])
        csum = np.concatenate([np.zeros((1, 3)), np.cumsum(padded, axis=0)])
        smooth = (csum[window : window + m] - csum[:m]) / window
    else:
        smooth = points
    step = np.linalg.norm(_next(smooth) - smooth, axis=1)
    total = float(step.sum())
    if total <= TOL.zero:
        raise ValueError("points all coincide: cannot fit a curve")
    cum = np.concatenate([[0.0], np.cumsum(step)[:-1]])
    tangent = _next(smooth) - _previous(smooth)
    tangent /= np.maximum(np.linalg.norm(tangent, axis=1), TOL.zero)[:, None]
    arc = cum + np.einsum("mi,mi->m", points - smooth, tangent)
    return arc, total


def fit(
    points: np.ndarray,
    smoothing: float | str = 8.0,
    *,
    frame: np.ndarray | None = None,
    centroid: np.ndarray | None = None,
    parametrisation: str = "uniform",
) -> ClosedCurve:
    """Fit a closed Catmull-Rom curve to an ordered noisy section.

    Parameters
    ----------
    points : (M, 3) float64, M ≥ 4
        Points in their order around the loop (e.g. ``Loop.points``).
    smoothing : float or "auto"
        Data points per control point (module notes): ``≤ 1`` interpolates
        every point; ``s > 1`` fits ``max(4, round(M/s))`` control points by
        least squares, reducing point noise σ to about ``σ/√s``.  ``"auto"``
        picks s by generalised cross-validation (see :func:`choose_smoothing`).
    frame : (3, 3) float64, optional
        Section frame (rows e1, e2, axis); default from the best-fit plane.
    centroid : (3,) float64, optional
        Centre for θ; default the points' mean.
    parametrisation : {"uniform", "centripetal", "chordal"}
        Knot spacing of the final curve.  The least-squares step always uses
        the uniform basis of eq. (3,5).

    Returns
    -------
    ClosedCurve
        Control points oriented counter-clockwise seen from ``+frame[2]``;
        ``curve.smoothing`` is the level used.
    """
    pts = _check_curve_input(points, "points", parametrisation)
    if isinstance(smoothing, str):
        if smoothing != "auto":
            raise ValueError(f"smoothing must be a number >= 0 or 'auto', got {smoothing!r}")
    elif not (np.isfinite(smoothing) and smoothing >= 0):
        raise ValueError(f"smoothing must be a finite number >= 0 or 'auto', got {smoothing!r}")
    if frame is None:
        frame = _plane_frame(pts)
    frame = check_shape(frame, "(3, 3)", "frame", np.float64)
    if centroid is None:
        centroid = pts.mean(axis=0)
    centroid = check_shape(centroid, "(3,)", "centroid", np.float64)
    m = len(pts)
    fitted = {}
    if smoothing == "auto":
        smoothing, fitted = _choose_smoothing(pts, frame)
    n_ctrl = m if smoothing <= 1 else max(4, min(m, int(round(m / smoothing))))
    if n_ctrl == m:
        ctrl = pts
    elif smoothing in fitted:  # GCV fitted this level already (same points, same n)
        ctrl = fitted[smoothing]
    else:
        ctrl = _least_squares(pts, n_ctrl, smoothing)[0]
    uv = (ctrl - centroid) @ frame[:2].T
    area = 0.5 * np.sum(uv[:, 0] * np.roll(uv[:, 1], -1) - np.roll(uv[:, 0], -1) * uv[:, 1])
    if area < 0:
        ctrl = ctrl[::-1]
    curve = _build(np.ascontiguousarray(ctrl), parametrisation, frame, centroid)
    return replace(curve, smoothing=float(max(smoothing, 1.0)))


def choose_smoothing(points: np.ndarray, frame: np.ndarray) -> float:
    """Smoothing level (points per control point) minimising generalised cross-validation.

    ``GCV(s) = M·RSS / (M − n)²`` [3]_ with ``n = round(M/s)`` control points
    (the trace of the least-squares hat matrix) and RSS the sum of squared
    residuals *normal* to the curve, in the section plane (tangential
    residuals only reflect the parametrisation).  Candidates: s = 4, 8, 16, …
    while n ≥ 8, then the neighbours ×√2 around the best, never below 4 (below
    4 the curve keeps noise, σ/√s > σ/2, and on sparse elongated loops GCV's
    pick of 2.8 overshot the data by a third of its size).  On the vase
    sections it picks what the analytic truth would (ring RMS 0.00046 against
    the best fixed level's 0.00045).

    Parameters
    ----------
    points : (M, 3) float64, ordered, M ≥ 4
    frame : (3, 3) float64

    Returns
    -------
    float
        s ≥ 1: with fewer than 32 points (no GCV ladder) ``min(4, M/4)``,
        i.e. 4 unless that leaves fewer than 4 control points (1 interpolates
        the 4-point minimum).

    References
    ----------
    .. [3] P. Craven and G. Wahba, "Smoothing noisy data with spline
       functions", Numerische Mathematik 31 (1979) 377–403.
    """
    return _choose_smoothing(points, frame)[0]


def _choose_smoothing(points: np.ndarray, frame: np.ndarray) -> tuple[float, dict]:
    """:func:`choose_smoothing`, and the control points ``{s: (n, 3)}`` it fitted."""
    m = len(points)
    ladder = [4.0 * 2**k for k in range(32) if m / (4.0 * 2**k) >= 8]
    if not ladder:  # too few points to cross-validate: the least smoothing above, as
        return max(1.0, min(4.0, m / 4.0)), {}  # far as 4 control points allow
    arcs, fitted = {}, {}  # the arc parameters depend on the window only: shared
    scores = {s: _gcv(points, s, frame, arcs, fitted) for s in ladder}
    best = min(scores, key=scores.get)
    for s in (best / math.sqrt(2), best * math.sqrt(2)):
        if s >= 4.0 and m / s >= 8:  # below 4 the noise stays (see above)
            scores[s] = _gcv(points, s, frame, arcs, fitted)
    return float(min(scores, key=scores.get)), fitted


def _gcv(points: np.ndarray, smoothing: float, frame: np.ndarray, arcs: dict | None = None,
         fitted: dict | None = None) -> float:
    m = len(points)
    n_ctrl = max(4, min(m, int(round(m / smoothing))))
    ctrl, t = _least_squares(points, n_ctrl, smoothing, arcs)
    if fitted is not None:
        fitted[smoothing] = ctrl
    position, derivative = _uniform_points_and_derivatives(ctrl, t)
    resid = (points - position) @ frame[:2].T  # (m, 2)
    tangent = derivative @ frame[:2].T
    normal = np.stack([-tangent[:, 1], tangent[:, 0]], axis=1)
    normal /= np.maximum(np.linalg.norm(normal, axis=1), TOL.zero)[:, None]
    rss = float(np.sum(np.einsum("mi,mi->m", resid, normal) ** 2))
    return m * rss / max(m - n_ctrl, 1) ** 2


def _uniform_points_and_derivatives(ctrl: np.ndarray, t: np.ndarray):
    """``Q(t)`` and ``dQ/dt`` ``(m, 3)`` of the closed uniform curve through ``ctrl`` ``(n, 3)``.

    What ``_build(ctrl, "uniform", ...).spline`` gives at ``t`` and ``(t, 1)``, to
    the bit: scipy's Hermite coefficients for unit knot steps and its power-sum
    evaluation order, without building the spline object twice per GCV candidate
    (a test compares them on random curves).
    """
    n = len(ctrl)
    after, before = _next(ctrl), _previous(ctrl)
    tangent = 0.5 * (after - before)
    slope = after - ctrl  # knot steps of 1
    excess = tangent + _next(tangent) - 2 * slope
    x = t % n  # the periodic wrap of PPoly
    segment = np.minimum(np.floor(x).astype(np.int64), n - 1)
    local = (x - segment)[:, None]
    square = local * local
    c0, c1 = excess[segment], (slope - tangent)[segment] - excess[segment]
    c2, c3 = tangent[segment], ctrl[segment]
    position = ((c3 + c2 * local) + c1 * square) + c0 * (square * local)
    derivative = (c2 + (c1 * local) * 2.0) + (c0 * square) * 3.0
    return position, derivative


def _least_squares(pts: np.ndarray, n_ctrl: int, smoothing: float, arcs: dict | None = None):
    """Control points ``(n_ctrl, 3)`` minimising Σ|Q(t_j) − x_j|² + λ·Σ|Δ³P_i|², and t.

    Parameters ``t_j`` from :func:`_data_parameters`; the system is sparse
    (4 basis functions per row) and solved by sparse LU.  The fairness term
    on third differences of the control points (weight ``λ = 0.01`` × the mean
    diagonal of ``AᵀA``, i.e. 1 % of one data point's pull) vanishes on
    control polygons that are locally quadratic in the index, so it barely
    biases smooth sections (a circle at 8 points per control point: 4e-8
    relative) but keeps the fit regular where random gaps leave a control
    point with little data: at 2 points per control point the curve's error
    drops from 45σ to 0.7σ.  (Foot-point re-parametrisation was tried and
    dropped: on noisy data it lets the curve chase the noise, 2× worse.)
    """
    m = len(pts)
    # parameter window: at least sqrt(M) points, so the moving average's step
    # noise √2·σ/w stays below the point gap even where σ exceeds the gap
    window = max(int(round(smoothing)), int(np.ceil(np.sqrt(m))))
    if arcs is None:
        t = _data_parameters(pts, window, n_ctrl)
    else:  # memo {window: (arc, total)} of _arc_parameters, shared by the GCV candidates
        if window not in arcs:
            arcs[window] = _arc_parameters(pts, window)
        arc, total = arcs[window]
        t = np.mod(n_ctrl * arc / total, n_ctrl)
    seg = np.minimum(np.floor(t).astype(np.int64), n_ctrl - 1)
    weights = _basis(t - seg)  # (m, 4)
    cols = (seg[:, None] + np.arange(-1, 3)) % n_ctrl
    # AᵀA and Aᵀx of the sparse design matrix A (row j: weights at cols[j]), adding every
    # entry's terms in point order, as scipy's sparse products do
    if n_ctrl > 6:
        # band storage: entry (i, j) at [j, (i − j + 3) mod n], |i − j| ≤ 3 cyclically
        normal = np.zeros((n_ctrl, 7))
        rhs = np.zeros((n_ctrl, 3))
        normal_equations_band(cols, weights, pts, normal, rhs)
        system = normal + _FAIRNESS * normal[:, 3].mean() * third_difference_band(n_ctrl)
        ctrl = np.empty((n_ctrl, 3))
        if cholesky_cyclic_band(system, rhs, interleaved(n_ctrl), ctrl):
            return ctrl, t
        # not positive definite to rounding (no data near some control point): pivoting LU
        rows, order = band_rows(n_ctrl)
        return solve_band(np.take_along_axis(system, order, axis=1), rows, rhs), t
    rhs = np.stack([np.bincount(cols.ravel(), (weights * pts[:, d, None]).ravel(),
                                minlength=n_ctrl) for d in range(3)], axis=1)
    # n_ctrl <= 6: the band wraps onto itself, a dense system
    products = (weights[:, :, None] * weights[:, None, :]).ravel()
    normal = np.bincount((cols[:, :, None] * n_ctrl + cols[:, None, :]).ravel(), products,
                         minlength=n_ctrl * n_ctrl).reshape(n_ctrl, n_ctrl)
    system = normal + _FAIRNESS * np.diagonal(normal).mean() * third_difference_gram(n_ctrl)
    rows, cols_all = cyclic_band(n_ctrl)
    return solve_band(system[rows, cols_all], rows, rhs), t


@numba.njit(cache=True, nogil=True)
def _bisect_cubics(cubic, hi, steps):  # pragma: no cover - compiled
    """Root of each cubic ``cubic[:, r]`` (coefficients of τ³, τ², τ, 1) in ``[0, hi[r]]``
    by ``steps`` bisections, the midpoint of the last bracket: the invariant
    f(lo) <= 0 < f(hi) (the ray's angle lies between the segment's ends); comparing with 0,
    not the sign at lo, keeps a ray through a knot exact.  The array form's arithmetic,
    one ray at a time (it was 64 passes of array operations a ring)."""
    out = np.empty(hi.shape[0])
    for r in range(hi.shape[0]):
        lo, up = 0.0, hi[r]
        c0, c1, c2, c3 = cubic[0, r], cubic[1, r], cubic[2, r], cubic[3, r]
        for _ in range(steps):
            mid = 0.5 * (lo + up)
            if ((c0 * mid + c1) * mid + c2) * mid + c3 <= 0:
                lo = mid
            else:
                up = mid
        out[r] = 0.5 * (lo + up)
    return out


#: Shortest gap, as a share of its loop's length, that :func:`bridge_gaps` bridges.  Over
#: a shorter gap the fairness term continues the loop's bend, closer than a chord, which
#: cuts ~4.9 f² r inside a circle of radius r over a share f (1.2 % of r at 5 %): the
#: demo vase's 7 rings with gaps of 1.5-3.3 % are 0.00013-0.00018 RMS from the truth
#: unbridged, up to 0.00056 with chords.  Over a longer one the continuation bulges (a
#: quarter of a circle unseen, 23 %: 0.73 r past the chord; the real temple: 0.136).
BRIDGE_SHARE = 0.05


def bridge_gaps(points: np.ndarray, link: float, closed: bool = True) -> np.ndarray:
    """The ordered closed loop ``points`` (or, with ``closed`` false, the open arc: no
    step from its last point back to its first) with straight chords across its wide
    gaps.

    Parameters
    ----------
    points : (M, 3) float64
        Points in their order around the loop (cyclic) or along the arc.
    link : float
        Gaps between consecutive points longer than this, and than
        :data:`BRIDGE_SHARE` of the loop's length, are bridged.
    closed : bool
        The points go round a loop (default); false: an open arc, fewer than 3 points
        returned as they are.

    Returns
    -------
    (M + K, 3) float64
        The points, with ``⌈d / h⌉ − 1`` points inserted evenly along each such gap
        of length d (h: the median of the other gaps), in order; the input itself
        when no gap is that wide.
    """
    pts = np.asarray(points, dtype=np.float64)
    if not closed and len(pts) < 3:
        return pts
    step = np.roll(pts, -1, axis=0) - pts if closed else np.diff(pts, axis=0)
    length = np.linalg.norm(step, axis=1)
    wide = (length > link) & (length > BRIDGE_SHARE * length.sum())
    if not wide.any() or wide.all():
        return pts
    spacing = float(np.median(length[~wide]))
    if spacing <= TOL.zero:
        return pts
    count = np.where(wide, np.ceil(length / spacing).astype(np.int64) - 1, 0)
    if not closed:                                    # the last point starts no step
        count = np.append(count, 0)
        step = np.vstack([step, np.zeros((1, 3))])
    source = np.repeat(np.arange(len(pts)), count + 1)  # each output point's start point
    first = np.repeat(np.cumsum(count + 1) - (count + 1), count + 1)
    fraction = (np.arange(len(source)) - first) / (count[source] + 1)
    return pts[source] + fraction[:, None] * step[source]


def fit_loop(loop, smoothing: float | str = 8.0, parametrisation: str = "uniform") -> ClosedCurve:
    """:func:`fit` to a ``topology.Loop`` (its ordered points, frame and centroid), its
    gaps wider than ``loop.bridge`` bridged (:func:`bridge_gaps`)."""
    return fit(
        bridge_gaps(loop.points, getattr(loop, "bridge", math.inf)),
        smoothing,
        frame=loop.frame,
        centroid=loop.centroid,
        parametrisation=parametrisation,
    )


# ----------------------------------------------------------------------------- precision
@lru_cache(maxsize=1)
def _gram_stencil() -> np.ndarray:
    """``g_k = ∫ φ(t) φ(t − k) dt``, k = −3 … 3, of the uniform Catmull-Rom basis φ (exact).

    From the segment Gram ``¼ M_CRᵀ H M_CR`` of the power basis ``(u³, u², u, 1)``,
    ``H_ab = 1 / (e_a + e_b + 1)``: ``g_k`` sums its entries ``(a, a + k)``.
    """
    exponents = np.array([3, 2, 1, 0])
    segment = 0.25 * M_CR.T @ (1.0 / (exponents[:, None] + exponents[None, :] + 1)) @ M_CR
    return np.array([sum(segment[a, a + k] for a in range(4) if 0 <= a + k < 4)
                     for k in range(-3, 4)])


@lru_cache(maxsize=256)
def _fairness_variance_ratio(n: int) -> float:
    """ρ(n) of the module notes: the fairness term's share of the curve's variance."""
    g = _gram_stencil()
    omega = 2.0 * np.pi * np.arange(n) / n
    symbol = sum(g[k + 3] * np.cos(k * omega) for k in range(-3, 4))
    third = (2.0 - 2.0 * np.cos(omega)) ** 3
    return float(np.mean((symbol / (symbol + _FAIRNESS * g[3] * third)) ** 2))


def precision_factor(controls: int, points: int) -> float:
    """σ of a least-squares fitted curve per unit σ of its points: ``√(ρ(n) · n / M)``.

    Module notes ("Precision of the fitted curve"); 1 for an interpolating curve
    (``controls >= points``).

    Parameters
    ----------
    controls : int
        n, control points of the fit (>= 4).
    points : int
        M, data points fitted (>= 1).

    Returns
    -------
    float
        In (0, 1]: the curve's RMS error across the curve, averaged over its
        parameter, is this times the points' σ.
    """
    controls, points = int(controls), int(points)
    if controls < 1 or points < 1:
        raise ValueError(f"need controls >= 1 and points >= 1, got {controls}, {points}")
    if controls >= points:
        return 1.0
    return float(np.sqrt(_fairness_variance_ratio(controls) * controls / points))


@dataclass(frozen=True)
class RingFit:
    """How one ring's curve was fitted, and its precision.

    Attributes
    ----------
    smoothing : float
        s, data points per control point (GCV's choice for ``"auto"``; 1: interpolating).
    controls : int
        n, control points of the curve.
    points : int
        M, the loop's points fitted.
    noise : float
        σ̂ of the loop's points across the curve (``topology.Loop.noise``), scene units;
        NaN when the loop has none.
    precision : float
        ``noise · precision_factor(controls, points)``: the ring's own RMS error across
        the curve from the points' noise, scene units.
    """

    smoothing: float
    controls: int
    points: int
    noise: float
    precision: float


def _ring_fit(loop, curve: ClosedCurve) -> RingFit:
    m = len(loop.points)
    noise = float(getattr(loop, "noise", np.nan))
    return RingFit(float(curve.smoothing), curve.n, m, noise,
                   noise * precision_factor(curve.n, m))


# ----------------------------------------------------------------------------- prediction
#: Fewest ring points N of one loop in a section of several (its even sections get 2N).
MIN_BRANCH_RING = 8


def perimeter(points: np.ndarray) -> float:
    """Length of the closed polyline through ``points (M, 3)`` in their order."""
    pts = np.asarray(points, dtype=np.float64)
    return float(np.linalg.norm(_next(pts) - pts, axis=1).sum())


def branch_ring_size(n: int, length: float, largest: float) -> int:
    """N of one loop in a section of several: ``n`` scaled by the root of its perimeter.

    ``n`` places the largest loop's points (perimeter ``largest``) about a section
    spacing Δ apart (``reconstruct.ring_count``).  The stitched mesh is linear between
    ring points: a chord of length h across a loop of radius r lies h²/8r inside it, so
    a loop of a smaller radius keeps the largest loop's chord error with its points
    √(r/R) as far apart, ``N = n·√(length / largest)`` (at least :data:`MIN_BRANCH_RING`,
    at most ``n``).  Every loop with the full ``n`` crowded the thin branches: on the
    real temple ring a column's loop (a ninth of the plinth's perimeter) had 209 / 418
    points 0.0002 apart with sections 0.0015 apart; now about 70 / 140.  Measured
    (``benchmarks/branches.py --quick``, against the full ``n``): Chamfer within -2 to
    +4 % on the torus, mug and amphora, their stitch 1.2-5x faster; scaling by the
    perimeter itself (points Δ apart on every loop) lost up to 9 %.
    """
    if largest <= 0:
        return int(n)
    return int(min(n, max(MIN_BRANCH_RING, math.ceil(n * math.sqrt(length / largest)))))


def ring_size(section_index: int, n: int) -> int:
    """Points on the ring of section ``section_index`` (0-based): N, 2N, N, 2N, ….

    Index 0 is the paper's section 1 ("odd": N points at θ = 2πj/N); index 1
    its section 2 ("even": 2N points at θ = πj/N).
    """
    return n if section_index % 2 == 0 else 2 * n


def predict_ring(
    loop,
    n_points: int,
    smoothing: float | str = 8.0,
    parametrisation: str = "uniform",
    theta0: float = 0.0,
    fit: bool = False,
):
    """Ring ``(n_points, 3)`` of one loop: at equal θ if star-shaped, else equal arc length.

    Point ``j`` sits at ``θ = theta0 + 2πj/n_points`` about the loop centroid
    in the common frame (star-shaped), or at arc length ``j·L/n_points`` from
    the crossing with the ray at ``theta0`` (not star-shaped).  ``fit=True``
    returns ``(ring, RingFit)``.
    """
    curve = fit_loop(loop, smoothing, parametrisation)
    if curve.is_star_shaped():
        ring = curve.resample_theta(n_points, theta0)
    else:
        ring = curve.resample_arclength(n_points, theta0)
    return (ring, _ring_fit(loop, curve)) if fit else ring


def predict_sections(
    loops_per_section: Sequence,
    n: int,
    smoothing: float | str = 8.0,
    parametrisation: str = "uniform",
    fits: bool = False,
):
    """Predict the stitching rings: N points on odd sections, 2N on even ones.

    Parameters
    ----------
    loops_per_section : sequence
        One entry per section in height order; an entry is a ``Loop`` or a
        sequence of Loops (several loops in one section).
    n : int
        N, points on the odd sections (0-based indices 0, 2, 4, …).
    smoothing, parametrisation
        Passed to :func:`fit`.
    fits : bool
        Also return how each ring was fitted (:class:`RingFit`: the smoothing chosen,
        the points' noise and the ring's precision), mirroring the rings.

    Returns
    -------
    list, or (list, list) with ``fits``
        Mirrors the input: for a Loop entry an ``(n_k, 3)`` array, for a
        sequence entry a list of such arrays; ``n_k = ring_size(k, n)``, for a
        loop in a sequence of several ``ring_size(k, branch_ring_size(n, its
        perimeter, the largest loop's))``.
        Ring point ``j`` is at ``θ = 2πj/n_k`` (star-shaped loop) or at equal
        arc length starting at θ = 0 (not star-shaped).
    """
    n = _check_count(n, "n")
    largest = max((perimeter(lp.points) for entry in loops_per_section
                   for lp in ([entry] if hasattr(entry, "points") else entry)), default=0.0)
    rings, records = [], []
    for k, entry in enumerate(loops_per_section):
        n_k = ring_size(k, n)
        if hasattr(entry, "points"):
            ring, record = predict_ring(entry, n_k, smoothing, parametrisation, fit=True)
        else:
            several = len(entry) > 1  # a lone loop in a list keeps N, as a Loop entry does
            pairs = [predict_ring(lp, ring_size(k, branch_ring_size(n, perimeter(lp.points),
                                                                    largest)) if several
                                  else n_k, smoothing, parametrisation, fit=True)
                     for lp in entry]
            ring, record = [r for r, _ in pairs], [f for _, f in pairs]
        rings.append(ring)
        records.append(record)
    return (rings, records) if fits else rings
