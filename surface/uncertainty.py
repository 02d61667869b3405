r"""Where the surface is uncertain: each surface point's 1σ along its normal.

The surface is fitted to points that each carry a σ (``acquire``'s per-point σ).
At a surface point ``x`` with unit normal ``n`` the fit is, locally, a weighted
mean of the ``K`` nearest points' offsets along ``n`` (the ring fits average the
points of a section near a ring sample; the patches blend neighbouring ring
samples): with Gaussian weights ``w_i = exp(-(d_i / h)^2)`` (``h`` the median
distance to the K-th point over the surface)

    m(x) = sum w_i r_i / sum w_i,         r_i = (p_i - x) . n,
    s_prop^2(x) = sum w_i^2 sigma_i^2 / (sum w_i)^2    (the mean's variance).

``m`` is what the data say the surface is off by; its square estimates
``bias^2 + s_prop^2`` (an unbiased fit has ``E m^2 = s_prop^2``), so the bias the
fit leaves (smoothing, the chord of the patches) is ``b^2 = max(0, <m^2> - s_prop^2)``,
``<.>`` the mean over the ``K_v`` nearest surface points, and

    sigma_data^2 = s_prop^2 + b^2.

Where the surface bridges a gap or closes a cap there are no points within the
fit's support: ``g = max(0, d_0 - h)``, ``d_0`` the distance to the nearest point
(on a covered surface ``d_0`` is about the points' spacing, far below ``h``).
The bridge is a smooth curve across ``2 g`` whose curvature is not measured: it may miss a bend of curvature up to
``kappa`` (the 90th percentile of the surface's own curvature, from its normals,
over the covered part) by the sagitta ``kappa g^2 / 2``, so

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


@dataclass(frozen=True)
class NormalSigma:
    """Per surface point, scene units: ``sigma`` the total 1σ along the normal,
    ``propagated`` the points' σ through the local fit, ``bias`` the fit's bias,
    ``gap`` the bridged distance beyond the data's reach (0 where covered)."""

    sigma: np.ndarray
    propagated: np.ndarray
    bias: np.ndarray
    gap: np.ndarray
    curvature: float


def _unit(normals: np.ndarray) -> np.ndarray:
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    return normals / np.where(length > 0, length, 1.0)


def normal_sigma(vertices, normals, points, sigma) -> NormalSigma:
    """1σ of the surface along its normal at each vertex.

    Parameters
    ----------
    vertices, normals : (V, 3) array_like
        Surface points (e.g. a tessellation's vertices) and their normals.
    points : (N, 3) array_like
        The points the surface was fitted to.
    sigma : (N,) array_like
        Their 1σ (isotropic), scene units.

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
    w = np.exp(-(d / h) ** 2)
    wsum = w.sum(axis=1)
    r = np.einsum("vkd,vd->vk", p[idx] - x[:, None, :], n)
    m = (w * r).sum(axis=1) / wsum
    prop2 = (w ** 2 * s[idx] ** 2).sum(axis=1) / wsum ** 2
    surface_tree = cKDTree(x)
    _, near = surface_tree.query(x, k=min(K_SURFACE, len(x)))
    near = near.reshape(len(x), -1)
    bias2 = np.maximum(0.0, (m ** 2)[near].mean(axis=1) - prop2[near].mean(axis=1))
    d0 = d[:, 0]
    gap = np.maximum(0.0, d0 - h)
    # curvature from the normals: |n_i - n_j| / |x_i - x_j| over a vertex's neighbours
    dn = np.linalg.norm(n[near[:, 1:]] - n[:, None, :], axis=2)
    dx = np.linalg.norm(x[near[:, 1:]] - x[:, None, :], axis=2)
    kappa_v = np.where(dx > 0, dn / np.where(dx > 0, dx, 1.0), 0.0).max(axis=1)
    covered = gap == 0
    kappa = float(np.percentile(kappa_v[covered], 90)) if covered.any() else 0.0
    total = np.sqrt(prop2 + bias2 + (kappa * gap ** 2 / 2.0) ** 2)
    return NormalSigma(sigma=total, propagated=np.sqrt(prop2), bias=np.sqrt(bias2), gap=gap,
                       curvature=kappa)
