r"""Second-order warp terms of an LSM patch from its neighbours' affine parameters.

The affine part of a least-squares match (:mod:`matching.lsm`, Gruen 1985) is the
local Jacobian of the image-to-image mapping: over a symmetric patch the odd moments
vanish, so the affine fit of a curved mapping (a curved surface seen in perspective)
returns its first derivatives at the centre, and its shift is biased by about
:math:`\langle x^2\rangle (q_{u,xx} + q_{u,yy})`.  The second derivatives follow from
the spatial change of the affine parameters over the accepted neighbours: a plane fit

.. math::

    a_k(x, y) \approx c_0 + c_1 (x - x_0) + c_2 (y - y_0), \qquad k \in \{a_1, a_2, b_1, b_2\}

around each point gives :math:`u_{xx} = \partial a_1/\partial x`,
:math:`u_{xy} = (\partial a_1/\partial y + \partial a_2/\partial x)/2`,
:math:`u_{yy} = \partial a_2/\partial y` (and ``v`` from ``b1 b2``), i.e. the fixed
``quadratic`` terms :func:`matching.lsm.lsm_match` adds to the affine warp.  Each term
is shrunk by :math:`\max(0, 1 - (se/q)^2)` (its standard error from the plane fit's
residuals), a James-Stein-like shrinkage so that a curvature the neighbours do not
resolve adds no noise.

A different algorithm from the LSM kernel itself (a local regression over matched
points, not an image alignment), hence its own module; moved out of ``matching/lsm.py``
unchanged.

References
----------
.. [1] A. W. Gruen, "Adaptive least squares correlation: a powerful image
   matching technique", South African Journal of Photogrammetry, Remote
   Sensing and Cartography 14(3), 175-187 (1985).
"""

from __future__ import annotations

import numba
import numpy as np

from matching.validate import TOL, check_shape

# as in matching.lsm: OpenMP first (the TBB layer here is too old and warns)
numba.config.THREADING_LAYER_PRIORITY = ["omp", "workqueue", "tbb"]

@numba.njit(nogil=True, cache=True, error_model="numpy")
def _plane_terms(points, fields, x0, y0, nb, cnt, min_neighbours, det_tol, out, r):
    """Plane fits of the 4 affine fields over ``nb[:cnt]`` around ``(x0, y0)`` -> ``out[r]``.

    Normal equations of ``field = c0 + c1 dx + c2 dy`` (3x3, inverted by the adjugate),
    residual variances, standard errors of the slopes and the shrinkage of
    :func:`second_order_terms`; too few neighbours or a singular fit leave ``out[r]``.
    """
    a = np.zeros((3, 3))
    b = np.zeros((3, 4))
    for t in range(cnt):
        j = nb[t]
        d0, d1, d2 = 1.0, points[j, 0] - x0, points[j, 1] - y0
        a[0, 0] += d0 * d0
        a[0, 1] += d0 * d1
        a[0, 2] += d0 * d2
        a[1, 1] += d1 * d1
        a[1, 2] += d1 * d2
        a[2, 2] += d2 * d2
        for f in range(4):
            v = fields[j, f]
            b[0, f] += d0 * v
            b[1, f] += d1 * v
            b[2, f] += d2 * v
    a[1, 0], a[2, 0], a[2, 1] = a[0, 1], a[0, 2], a[1, 2]
    c00 = a[1, 1] * a[2, 2] - a[1, 2] * a[2, 1]
    c01 = a[1, 2] * a[2, 0] - a[1, 0] * a[2, 2]
    c02 = a[1, 0] * a[2, 1] - a[1, 1] * a[2, 0]
    det = a[0, 0] * c00 + a[0, 1] * c01 + a[0, 2] * c02
    if cnt < min_neighbours or not det > det_tol * max(a[0, 0], 1.0) ** 3:
        return
    inv = np.empty((3, 3))
    inv[0, 0] = c00 / det
    inv[1, 0] = c01 / det
    inv[2, 0] = c02 / det
    inv[0, 1] = (a[0, 2] * a[2, 1] - a[0, 1] * a[2, 2]) / det
    inv[1, 1] = (a[0, 0] * a[2, 2] - a[0, 2] * a[2, 0]) / det
    inv[2, 1] = (a[0, 1] * a[2, 0] - a[0, 0] * a[2, 1]) / det
    inv[0, 2] = (a[0, 1] * a[1, 2] - a[0, 2] * a[1, 1]) / det
    inv[1, 2] = (a[0, 2] * a[1, 0] - a[0, 0] * a[1, 2]) / det
    inv[2, 2] = (a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0]) / det
    coef = inv @ b  # (3, 4)
    s2 = np.zeros(4)
    for t in range(cnt):
        j = nb[t]
        d1, d2 = points[j, 0] - x0, points[j, 1] - y0
        for f in range(4):
            e = fields[j, f] - (coef[0, f] + d1 * coef[1, f] + d2 * coef[2, f])
            s2[f] += e * e
    dof = max(cnt - 3, 1)
    vx = inv[1, 1] * s2 / dof  # variances of d(field)/dx, d(field)/dy
    vy = inv[2, 2] * s2 / dof
    q = (0.5 * coef[1, 0], 0.5 * (coef[2, 0] + coef[1, 1]), 0.5 * coef[2, 1],
         0.5 * coef[1, 2], 0.5 * (coef[2, 2] + coef[1, 3]), 0.5 * coef[2, 3])
    se = (0.5 * np.sqrt(vx[0]), 0.5 * np.sqrt(vy[0] + vx[1]), 0.5 * np.sqrt(vy[1]),
          0.5 * np.sqrt(vx[2]), 0.5 * np.sqrt(vy[2] + vx[3]), 0.5 * np.sqrt(vy[3]))
    for c in range(6):
        if q[c] == 0.0:
            continue
        ratio = se[c] / q[c]
        shrink = min(max(1.0 - ratio * ratio, 0.0), 1.0)
        if np.isfinite(shrink):
            out[r, c] = q[c] * shrink


@numba.njit(parallel=True, nogil=True, cache=True, error_model="numpy")
def _second_order_kernel(points, fields, centres, order, starts, origin, cell, ncx, ncy,
                         radius, cap, min_neighbours, det_tol, out, over):
    """Per centre: every point strictly within ``radius`` from a grid hash -> plane terms.

    ``points`` are bucketed in square cells of side ``cell`` >= ``radius`` (cell
    ``(i, j)`` holds ``order[starts[j * ncx + i]:starts[j * ncx + i + 1]]``), so the
    ball of a centre lies in its own and the 8 surrounding cells.  The test is
    ``dx² + dy² < radius²`` (``cKDTree.query(distance_upper_bound=radius)``'s strict
    bound).  Centres with more than ``cap`` neighbours are flagged in ``over`` and left
    to the caller (which keeps the nearest ``cap``).
    """
    r2 = radius * radius
    for r in numba.prange(len(centres)):
        x0, y0 = centres[r, 0], centres[r, 1]
        gx = int(np.floor((x0 - origin[0]) / cell))
        gy = int(np.floor((y0 - origin[1]) / cell))
        nb = np.empty(cap, np.int64)
        cnt = 0
        for j in range(max(gy - 1, 0), min(gy + 1, ncy - 1) + 1):
            for i in range(max(gx - 1, 0), min(gx + 1, ncx - 1) + 1):
                c = j * ncx + i
                for s in range(starts[c], starts[c + 1]):
                    p = order[s]
                    dx, dy = points[p, 0] - x0, points[p, 1] - y0
                    if dx * dx + dy * dy < r2:
                        if cnt < cap:
                            nb[cnt] = p
                        cnt += 1
        if cnt > cap:
            over[r] = True
            continue
        _plane_terms(points, fields, x0, y0, nb, cnt, min_neighbours, det_tol, out, r)


@numba.njit(parallel=True, nogil=True, cache=True, error_model="numpy")
def _second_order_rows(points, fields, centres, nb, counts, min_neighbours, det_tol, out):
    """:func:`_plane_terms` for centres whose neighbours are given, ``nb[r, :counts[r]]``."""
    for r in numba.prange(len(centres)):
        _plane_terms(points, fields, centres[r, 0], centres[r, 1], nb[r], counts[r],
                     min_neighbours, det_tol, out, r)


#: Cap on the neighbours of one plane fit in :func:`second_order_terms` (cost bound:
#: a radius of 1.5 patches at a 2 px grid holds ~400).
_MAX_PLANE_NEIGHBOURS = 512


def second_order_terms(points, affine, valid=None, radius_px: float = 12.0,
                       min_neighbours: int = 6) -> np.ndarray:
    """Second-order warp terms from the spatial change of the neighbours' affine parameters.

    An affine patch fit of a curved mapping (a curved surface seen in perspective) is
    biased by about ``<x²> (qu_xx + qu_yy)`` in the shift.  The affine part of every
    fit is the local Jacobian of the mapping (odd moments of a symmetric patch vanish),
    so the second derivatives follow from fitting a plane to each of ``a1 a2 b1 b2``
    over all accepted neighbours within ``radius_px`` (at most 512):
    ``u_xx = da1/dx``, ``u_xy = (da1/dy + da2/dx)/2``, ``u_yy = da2/dy`` (and ``v`` from
    ``b1 b2``), giving ``quadratic = (u_xx/2, u_xy, u_yy/2, v_xx/2, v_xy, v_yy/2)`` for
    :func:`lsm_match`.  Each term is shrunk by ``max(0, 1 - (se/q)²)``, se its standard
    error from the plane fits' residuals, so that a curvature the neighbours do not
    resolve adds no noise.

    Parameters
    ----------
    points : (N, 2) array_like
        Template centres, px.
    affine : (N, 6) array_like
        ``a0 a1 a2 b0 b1 b2`` of a first LSM pass.
    valid : (N,) bool, optional
        Points whose affine parameters may be used (default: all finite).
    radius_px : float
        Neighbourhood radius, px.
    min_neighbours : int
        Fewer valid neighbours (the point itself included) give zero terms.

    Returns
    -------
    (N, 6) float64, px/px²
    """
    points = check_shape(points, "(N, 2)", "points", dtype=np.float64)
    affine = check_shape(affine, "(N, 6)", "affine", dtype=np.float64)
    if not (np.isfinite(radius_px) and radius_px > 0):
        raise ValueError(f"radius_px must be positive, got {radius_px!r}")
    fields = affine[:, [1, 2, 4, 5]]
    ok = np.isfinite(fields).all(1) & np.isfinite(points).all(1)
    if valid is not None:
        ok &= np.asarray(valid, dtype=bool)
    out = np.zeros((len(points), 6))
    idx_ok = np.flatnonzero(ok)
    if len(idx_ok) < min_neighbours:
        return out
    # every neighbour within the radius: a fixed nearest-32 cap cut the radius to ~13 px
    # at a 4 px grid, and the slopes' noise falls as radius^-2 at a fixed point density
    # (15x15 patches on the vase: 0.0371 -> 0.0350 px RMS at radius 20 px).  The ball
    # comes from a grid hash of cell side ~radius (each centre scans 3x3 cells: ~2.9x
    # the ball's points, O(N) build, no tree) - the same set as cKDTree's
    # distance_upper_bound query at a fraction of the cost (0.27 -> 0.03 s for 9k points)
    pts_ok = np.ascontiguousarray(points[idx_ok])
    f_ok = np.ascontiguousarray(fields[idx_ok])
    radius = float(radius_px)
    cell = radius * (1.0 + 1e-9)  # floor((x - o) / cell) of two points < radius apart
    origin = pts_ok.min(0)        # differ by at most 1 despite rounding
    ncx, ncy = (np.floor((pts_ok.max(0) - origin) / cell).astype(np.int64) + 1)
    key = (np.floor((pts_ok[:, 1] - origin[1]) / cell).astype(np.int64) * ncx
           + np.floor((pts_ok[:, 0] - origin[0]) / cell).astype(np.int64))
    order = np.argsort(key, kind="stable")
    starts = np.zeros(ncx * ncy + 1, np.int64)
    np.cumsum(np.bincount(key, minlength=ncx * ncy), out=starts[1:])
    query = np.isfinite(points).all(1)
    centres = np.ascontiguousarray(points[query])
    quad = np.zeros((len(centres), 6))
    over = np.zeros(len(centres), bool)
    cap = int(min(len(idx_ok), _MAX_PLANE_NEIGHBOURS))
    _second_order_kernel(pts_ok, f_ok, centres, order, starts, origin, cell, int(ncx),
                         int(ncy), radius, cap, int(min_neighbours), TOL.zero, quad, over)
    if over.any():  # denser than the cap: the nearest `cap` (rare; a 2 px grid holds ~400)
        from scipy.spatial import cKDTree

        dist, nb = cKDTree(pts_ok).query(centres[over], k=cap, distance_upper_bound=radius)
        counts = np.isfinite(dist).sum(1)
        dense = np.zeros((len(nb), 6))
        _second_order_rows(pts_ok, f_ok, centres[over], np.ascontiguousarray(nb, np.int64),
                           counts, int(min_neighbours), TOL.zero, dense)
        quad[over] = dense
    out[query] = quad
    return out
