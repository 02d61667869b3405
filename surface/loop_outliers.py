"""Outliers of one loop: residuals from a local quadratic fit, cut at a robust scale.

Each point's distance from a quadratic ``y = a + b x + c x²`` fitted to its ``k`` nearest
kept points (:func:`_local_residuals`, a numba kernel over power sums); a point is an
outlier when ``|r| > max(threshold·σ̂, g/2)``, σ̂ the MAD scale of the residuals, g the
mean gap; two passes (:func:`_reject`).  Used by :mod:`surface.topology`.
"""

from __future__ import annotations

import numba
import numpy as np
from scipy.spatial import cKDTree

from checks.robust import MAD_TO_SIGMA
from surface.validate import TOL

#: 1.4826 · MAD = σ for Gaussian residuals.
_MAD_TO_SIGMA = MAD_TO_SIGMA


def _local_residuals(uv: np.ndarray, reference: np.ndarray, k: int) -> np.ndarray:
    """Distance ``(M,)`` of each point from a quadratic fitted to its k nearest references.

    ``reference`` ``(R,)`` indexes the points the fits may use; a point never
    uses itself.  The 3×3 normal equations of ``y = a + b x + c x²`` are built
    from power sums of the neighbours' local coordinates and solved point by point in
    a numba kernel (:func:`_quadratic_residuals`; the array form's temporaries and
    per-loop overhead were 0.4 s of the real temple's 263 loops).
    """
    k = min(k, len(reference) - 1)
    _, nbr = cKDTree(uv[reference]).query(uv, k=k + 1)
    nbr = np.ascontiguousarray(reference[nbr])  # (M, k + 1) point indices, self among them
    return _quadratic_residuals(np.ascontiguousarray(uv, dtype=np.float64), nbr,
                                float(TOL.ridge_rel), float(TOL.zero))


@numba.njit(cache=True, nogil=True)
def _quadratic_residuals(uv, nbr, ridge, tiny):  # pragma: no cover - compiled
    """Per point: its k neighbours (``nbr[i]``, its k + 1 nearest references, less itself
    or, where it is not a reference, less the farthest) about their mean, rotated to their
    principal direction (half the angle of the second moments), x scaled by its RMS;
    ``y = a + b x + c x²`` by least squares (power sums, ridge ``ridge`` times the
    trace on the diagonal, solved by Cholesky: the system is symmetric positive
    definite); the point's distance from it across the direction."""
    m, k = nbr.shape[0], nbr.shape[1] - 1
    out = np.empty(m)
    x = np.empty(k)
    y = np.empty(k)
    near = np.empty((1, k), np.int64)
    for i in range(m):
        drop = k
        for j in range(k + 1):
            if nbr[i, j] == i:
                drop = j
                break
        at = 0
        for j in range(k + 1):
            if j != drop:
                near[0, at] = nbr[i, j]
                at += 1
        mu = 0.0
        mv = 0.0
        for j in range(k):
            mu += uv[near[0, j], 0]
            mv += uv[near[0, j], 1]
        mu /= k
        mv /= k
        suv = 0.0
        sdiff = 0.0
        for j in range(k):
            du = uv[near[0, j], 0] - mu
            dv = uv[near[0, j], 1] - mv
            suv += du * dv
            sdiff += du * du - dv * dv
        angle = 0.5 * np.arctan2(2.0 * suv, sdiff)
        c = np.cos(angle)
        s = np.sin(angle)
        sq = 0.0
        for j in range(k):
            du = uv[near[0, j], 0] - mu
            dv = uv[near[0, j], 1] - mv
            x[j] = du * c + dv * s
            y[j] = dv * c - du * s
            sq += x[j] * x[j]
        spread = max(np.sqrt(sq / k), tiny)
        s1 = 0.0
        s2 = 0.0
        s3 = 0.0
        s4 = 0.0
        t0 = 0.0
        t1 = 0.0
        t2 = 0.0
        for j in range(k):
            xs = x[j] / spread
            x2 = xs * xs
            s1 += xs
            s2 += x2
            s3 += x2 * xs
            s4 += x2 * x2
            t0 += y[j]
            t1 += xs * y[j]
            t2 += x2 * y[j]
        # the normal equations (power sums, the ridge on the diagonal) are symmetric
        # positive definite: Cholesky, then the two triangular solves
        s0 = float(k)
        lift = ridge * (s0 + s2 + s4)
        l00 = np.sqrt(s0 + lift)
        l10 = s1 / l00
        l20 = s2 / l00
        l11 = np.sqrt(max(s2 + lift - l10 * l10, tiny))
        l21 = (s3 - l20 * l10) / l11
        l22 = np.sqrt(max(s4 + lift - l20 * l20 - l21 * l21, tiny))
        y0 = t0 / l00
        y1 = (t1 - l10 * y0) / l11
        y2 = (t2 - l20 * y0 - l21 * y1) / l22
        cc = y2 / l22
        bb = (y1 - l21 * cc) / l11
        aa = (y0 - l10 * bb - l20 * cc) / l00
        ou = uv[i, 0] - mu
        ov = uv[i, 1] - mv
        x0 = (ou * c + ov * s) / spread
        y0 = ov * c - ou * s
        out[i] = abs(y0 - (aa + bb * x0 + cc * x0 * x0))
    return out


def _reject(uv: np.ndarray, gap: float, threshold: float, k: int) -> tuple[np.ndarray, float]:
    """Mask ``(M,)`` of kept points and the robust noise σ̂ (two passes, module notes)."""
    keep = np.ones(len(uv), bool)
    sigma = 0.0
    for _ in range(2):
        reference = np.flatnonzero(keep)
        if len(reference) <= 4:
            break
        resid = _local_residuals(uv, reference, k)
        sigma = _MAD_TO_SIGMA * float(np.median(resid[reference]))
        new_keep = resid <= max(threshold * sigma, 0.5 * gap)
        if np.array_equal(new_keep, keep):
            break
        keep = new_keep
    return keep, sigma
