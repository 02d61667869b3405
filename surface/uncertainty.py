r"""Where the surface is uncertain: each surface point's 1σ along its normal.

The surface is fitted to points that each carry a σ (``acquire``'s per-point σ).
At a surface point ``x`` the fit is, locally, a weighted mean of the ``K`` nearest
points' offsets from the surface (the ring fits average the points of a section near
a ring sample; the patches blend neighbouring ring samples): with Gaussian weights
``w_i = exp(-(d_i^2 - d_1^2) / h^2)`` (``h`` the median distance to the K-th point)

    m(x) = sum w_i r_i / sum w_i,    r_i = (p_i - y_i) . n(y_i),
    s_prop^2(x) = sum w_i^2 max(sigma_i^2, v) / (sum w_i)^2,

``y_i`` the surface point nearest ``p_i`` (not ``x``'s tangent plane, which over
the reach ``h`` holds the surface's own bend ``kappa h^2 / 2``),
``v`` the points' weighted scatter about ``m`` (a point's σ as stated, or as the
points show it where they scatter more).  Given each point's view pair, the pairs'
disagreement scales the σ and measures the correlation ``rho`` of one pair's neighbouring
errors, whose cross terms ``rho w_i w_j s_i s_j`` join ``s_prop^2`` (:func:`_pair_statistics`).
``m`` is the surface's offset from the points' local mean: a bias ``b`` plus the mean's error, of
variance ``s_prop^2``, so ``<m^2> = b^2 + s_prop^2`` (``<.>`` the mean over the
``K_v`` nearest surface points).  The deviation from the truth is ``-b ± s_prop``:

    sigma_data^2 = b^2 + s_prop^2 = max(<m^2>, s_prop^2)

(``<m^2> + s_prop^2`` counts the points' noise twice where the surface follows
the points' local mean).

Where the surface bridges a gap or closes a cap there are no points within the
fit's support: ``g = max(0, d_0 - h)``, ``d_0`` the distance to the nearest point
(on a covered surface ``d_0`` is about the points' spacing, far below ``h``).
The bridge is a smooth curve across ``2 g`` whose bend no point measured: it may
miss a bend of the object's typical curvature ``kappa`` (the median over the
covered part, from the normals; not the bridge's own, whose rim is often a crease)
by the sagitta ``kappa g^2 / 2``, taken as the bridge's 1σ beside the covered
part's median data term (a bridge's nearest points lie on other parts), so

    sigma^2 = sigma_data^2 + (kappa g^2 / 2)^2.

Units: scene units.  Validated against rendered scenes' truth meshes in
``benchmarks/uncertainty.py`` (share of true deviations within 1σ and 2σ).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from surface.validate import check_finite, check_shape

__all__ = ["NormalSigma", "normal_sigma"]

#: Points in a surface point's local fit: a ring sample's share of a section's points
#: (a few) times the neighbouring samples a patch blends (a few): 16.
K_POINTS = 16
#: Surface points the bias estimate is averaged over.
K_SURFACE = 8
#: Median of a chi-square variable of one degree of freedom.
CHI2_MEDIAN = 0.454936


@dataclass(frozen=True)
class NormalSigma:
    """Per surface point, scene units: ``sigma`` the total 1σ along the normal,
    ``propagated`` the points' σ through the local fit, ``offset`` the surface's RMS
    offset from the points' local mean, ``gap`` the bridged distance beyond the data's
    reach (0 where covered); ``curvature`` the bridges' bend, 1 / scene units."""

    sigma: np.ndarray
    propagated: np.ndarray
    offset: np.ndarray
    gap: np.ndarray
    curvature: float


def _unit(normals: np.ndarray) -> np.ndarray:
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    return normals / np.where(length > 0, length, 1.0)


def _pair_statistics(points, sigma, offset, source) -> tuple[float, float]:
    """``(k2, rho)`` from points seen by different view pairs (``source``, negative:
    fused): over each point's 16 nearest, the median of ``(r_i - r_j)^2 / (s_i^2 + s_j^2)``
    (a chi-square(1), median 0.455 when the σ are right) across pairs, whose errors are
    independent, gives the σ's scale ``k2``; within one pair it is ``k2 (1 - rho)``, ``rho``
    the correlation of one pair's neighbouring points (shared windows, a shared pose).
    The surface's own error is common to near points and cancels.  ``(1, 0)`` without
    enough of either."""
    known = source >= 0
    _, near = cKDTree(points).query(points, k=K_POINTS + 1)
    i, j = np.repeat(np.arange(len(points)), K_POINTS), near[:, 1:].ravel()
    both = known[i] & known[j]
    q = (offset[i] - offset[j]) ** 2 / (sigma[i] ** 2 + sigma[j] ** 2)
    same = both & (source[i] == source[j])
    across = both & (source[i] != source[j])
    if same.sum() < 100 or across.sum() < 100 or not np.isfinite(q[across]).any():
        return 1.0, 0.0
    k2 = float(np.nanmedian(q[across])) / CHI2_MEDIAN
    rho = 1.0 - float(np.nanmedian(q[same])) / CHI2_MEDIAN / k2
    return k2, min(max(rho, 0.0), 1.0)


def normal_sigma(vertices, normals, points, sigma, source=None) -> NormalSigma:
    """1σ of the surface along its normal at each vertex.

    Parameters
    ----------
    vertices, normals : (V, 3) array_like
        Surface points (e.g. a tessellation's vertices) and their normals.
    points : (N, 3) array_like
        The points the surface was fitted to.
    sigma : (N,) array_like
        Their 1σ (isotropic), scene units; NaN where unknown (the points' scatter
        stands in).
    source : (N,) array_like of int, optional
        Each point's view pair (negative: from no one pair).  Given, the points'
        spread across pairs scales their σ and measures how one pair's neighbouring
        errors correlate (:func:`_pair_statistics`); the propagation counts that
        correlation.

    Returns
    -------
    NormalSigma
    """
    x = check_finite(check_shape(vertices, "(V, 3)", "vertices", dtype=np.float64), "vertices")
    n = _unit(check_shape(normals, "(V, 3)", "normals", dtype=np.float64))
    p = check_finite(check_shape(points, "(N, 3)", "points", dtype=np.float64), "points")
    s = np.asarray(sigma, dtype=np.float64).reshape(-1)
    if len(s) != len(p) or len(p) < K_POINTS:
        raise ValueError(f"need at least {K_POINTS} points, each with a sigma")
    tree = cKDTree(p)
    d, idx = tree.query(x, k=K_POINTS)
    h = float(np.median(d[:, -1])) or 1.0
    # Gaussian weights relative to the nearest point's (no underflow far from the data)
    w = np.exp(-(d ** 2 - d[:, :1] ** 2) / h ** 2)
    wsum = w.sum(axis=1)
    surface_tree = cKDTree(x)
    # each point's offset from the surface (its nearest surface point's tangent plane),
    # not from x's tangent plane: over the fit's reach the latter holds the surface's
    # own sagitta, kappa h^2 / 2 at the reach's edge, which is no error of the fit
    _, foot = surface_tree.query(p)
    offsets = np.einsum("nd,nd->n", p - x[foot], n[foot])
    r = offsets[idx]
    m = (w * r).sum(axis=1) / wsum
    k2, rho = 1.0, 0.0
    if source is not None:
        src = np.asarray(source).reshape(-1)
        if len(src) != len(p):
            raise ValueError("need one source per point")
        k2, rho = _pair_statistics(p, s, offsets, src)
        s = s * np.sqrt(k2)
    scatter = (w * (r - m[:, None]) ** 2).sum(axis=1) / wsum
    # each point's sigma, or the points' scatter about their local mean where larger or
    # where the sigma is unknown (NaN)
    each = np.fmax(s[idx] ** 2, scatter[:, None])
    prop2 = (w ** 2 * each).sum(axis=1) / wsum ** 2
    if rho > 0:  # one pair's neighbouring errors correlate: their cross terms
        a = w * np.sqrt(each)
        group = src[idx]
        same = (group[:, :, None] == group[:, None, :]) & (group[:, :, None] >= 0)
        cross = np.einsum("vi,vij,vj->v", a, same, a) - (a ** 2).sum(axis=1)
        prop2 = prop2 + rho * cross / wsum ** 2
    _, near = surface_tree.query(x, k=min(K_SURFACE, len(x)))
    near = near.reshape(len(x), -1)
    offset2 = (m ** 2)[near].mean(axis=1)
    d0 = d[:, 0]
    gap = np.maximum(0.0, d0 - h)
    # curvature from the normals: |n_i - n_j| / |x_i - x_j|, median over a vertex's neighbours
    dn = np.linalg.norm(n[near[:, 1:]] - n[:, None, :], axis=2)
    dx = np.linalg.norm(x[near[:, 1:]] - x[:, None, :], axis=2)
    kappa_v = np.median(np.where(dx > 0, dn / np.where(dx > 0, dx, 1.0), 0.0), axis=1)
    covered = gap == 0
    kappa = float(np.median(kappa_v[covered])) if covered.any() else 0.0
    if covered.any() and not covered.all():
        # a bridge's nearest points belong to other parts (a cap's are on the wall below
        # its rim, and so are its rim's, across a crease): it takes the covered part's
        # median data term
        prop2[~covered] = np.median(prop2[covered])
        offset2[~covered] = np.median(offset2[covered])
    # <m^2> holds the bias and the local mean's own noise (prop2): the bias is what
    # exceeds the noise, and sigma_data^2 = bias^2 + prop2
    total = np.sqrt(np.maximum(prop2, offset2) + (kappa * gap ** 2 / 2.0) ** 2)
    return NormalSigma(sigma=total, propagated=np.sqrt(prop2), offset=np.sqrt(offset2),
                       gap=gap, curvature=kappa)
