"""The motion-step score of an LSM window (:mod:`matching.lsm_kernels`): the largest
F-like score, over lines of four orientations, of one window part moving against the
rest (:func:`_step_score`; the test is in ``docs/method/lsm.md``).
"""

from __future__ import annotations

import numba
import numpy as np

from matching.lsm_interp import _FM
from matching.lsm_normals import _affine_row, _cholesky_factor, _forward

#: Orientations of :func:`_step_score`'s split lines: the part is ``k(x, y) <= c`` with
#: k = x, y, x + y, x - y (a vertical, horizontal and the two diagonal lines).
_STEP_ORIENTATIONS = 4


#: Nuisance columns of :func:`_step_score`: the 8 of the template Jacobian and Δf.
_STEP_NUISANCE = 9


@numba.njit(cache=True, fastmath=_FM, error_model="numpy")
def _step_sums(fv, fx, fy, vres, wts, half, acc, hmat, c):
    """One pass over the window for :func:`_step_score`; returns vᵀWv.

    ``hmat`` = Σ K Kᵀ of the nuisance columns K = [j, Δf]: its 8 x 8 block, the
    template's H, is given; the Δf row is added here.  ``c`` = Σ K v; ``acc[o, b]`` the
    sums over bin b of orientation o of [E_x K (9), E_y K (9), E_x², E_x E_y, E_y²,
    E_x v, E_y v, 1] with [E_x, E_y] = [f_x, f_y].  Every row is weighted by √w of
    ``wts`` (robust LSM's 0/1 support; ones otherwise); the counts stay pixel counts.
    """
    side = 2 * half + 1
    nk = _STEP_NUISANCE
    nacc = 2 * nk + 6
    jv = np.empty(nk)
    q = np.empty(nacc)
    vtv = 0.0
    n = 0
    for iy in range(-half, half + 1):
        for ix in range(-half, half + 1):
            sw = np.sqrt(wts[n])
            gx = sw * fx[n]
            gy = sw * fy[n]
            res = sw * vres[n]
            _affine_row(jv, gx, gy, ix, iy, sw * fv[n])
            jv[6] = sw
            jv[8] = 0.0
            if abs(ix) < half and abs(iy) < half:  # Laplacian from the central differences
                jv[8] = sw * 0.5 * (fx[n + 1] - fx[n - 1] + fy[n + side] - fy[n - side])
            vtv += res * res
            for i in range(nk):
                c[i] += jv[i] * res
                hmat[nk - 1, i] += jv[nk - 1] * jv[i]
                q[i] = gx * jv[i]
                q[nk + i] = gy * jv[i]
            q[2 * nk] = gx * gx
            q[2 * nk + 1] = gx * gy
            q[2 * nk + 2] = gy * gy
            q[2 * nk + 3] = gx * res
            q[2 * nk + 4] = gy * res
            q[2 * nk + 5] = 1.0
            b0 = ix + half
            b1 = iy + half
            b2 = ix + iy + 2 * half
            b3 = ix - iy + 2 * half
            for k in range(nacc):
                acc[0, b0, k] += q[k]
                acc[1, b1, k] += q[k]
                acc[2, b2, k] += q[k]
                acc[3, b3, k] += q[k]
            n += 1
    for i in range(nk - 1):
        hmat[i, nk - 1] = hmat[nk - 1, i]
    return vtv


@numba.njit(cache=True, fastmath=_FM, error_model="numpy")
def _best_split(acc, lo, zc, half, min_part, split):
    """max over the splits of rᵀ M⁻¹ r (:func:`_step_score`), from prefix sums of ``acc``.

    ``split`` = (orientation, last bin of the first part) of the best line.

    ``lo``: Cholesky factor of H; ``zc`` = lo⁻¹ Kᵀv (so EᵀK H⁻¹ Kᵀv = (lo⁻¹ KᵀE)ᵀ zc).
    """
    side = 2 * half + 1
    npix = side * side
    nk = _STEP_NUISANCE
    nacc = acc.shape[2]
    x0 = np.empty(nk)
    x1 = np.empty(nk)
    e0 = np.empty(nk)
    e1 = np.empty(nk)
    part = np.empty(nacc)
    best = 0.0
    for o in range(_STEP_ORIENTATIONS):
        bins = side if o < 2 else 2 * side - 1
        for k in range(nacc):
            part[k] = 0.0
        for b in range(bins - 1):
            for k in range(nacc):
                part[k] += acc[o, b, k]
            count = part[2 * nk + 5]
            if count < min_part or npix - count < min_part:
                continue
            for i in range(nk):
                e0[i] = part[i]
                e1[i] = part[nk + i]
            _forward(lo, e0, nk, x0)
            _forward(lo, e1, nk, x1)
            r0 = part[2 * nk + 3]
            r1 = part[2 * nk + 4]
            m00 = part[2 * nk]
            m01 = part[2 * nk + 1]
            m11 = part[2 * nk + 2]
            for i in range(nk):
                r0 -= x0[i] * zc[i]
                r1 -= x1[i] * zc[i]
                m00 -= x0[i] * x0[i]
                m01 -= x0[i] * x1[i]
                m11 -= x1[i] * x1[i]
            det = m00 * m11 - m01 * m01
            if not det > 1e-12 * (part[2 * nk] * part[2 * nk + 2] + 1e-300):
                continue
            score = (m11 * r0 * r0 - 2.0 * m01 * r0 * r1 + m00 * r1 * r1) / det
            if score > best:
                best = score
                split[0] = o
                split[1] = b
    return best


@numba.njit(cache=True, fastmath=_FM, error_model="numpy")
def _step_score(fv, fx, fy, vres, wts, npix_used, half, min_part, htemplate, noise_var,
                split):
    """Largest score statistic of a motion step along a straight line through the window.

    The nuisance columns are the 8 of the template Jacobian j = [f_x, f_x x, f_x y, f_y,
    f_y x, f_y y, 1, f] and a blur difference, the template's Laplacian Δf (zero on the
    patch's border; a Gaussian blur of variance s between the views leaves
    v ≈ -(s/2) Δf, which would otherwise read as steps): K = [j, Δf], H = Σ K Kᵀ.  For
    every split of the window by a line of ``_STEP_ORIENTATIONS`` orientations at every
    offset leaving at least ``min_part`` pixels on each side, the two columns
    E = m [f_x, f_y] (m: the part's indicator) are the extra unknowns of a shift of
    that part alone.  With K projected out, the score of E is r = Eᵀv - EᵀK H⁻¹ Kᵀv,
    its covariance σ² M, M = EᵀE - EᵀK H⁻¹ KᵀE, and S = rᵀ M⁻¹ r / σ² ~ χ²(2) when
    the window holds one motion and white noise (σ² = |v - K H⁻¹ Kᵀv|² / (n - 9)).
    Prefix sums over the lines' bins give every offset from one pass over the pixels.
    ``htemplate``: the template's H = Σ j jᵀ (8 x 8).  σ² is never taken below
    ``noise_var`` (a quarter of the two images' noise variance, below what noise leaves
    where there is any, so that the test's null distribution stays χ²'s): where almost
    no noise is left the
    residual is the convergence's remaining misregistration (δ·∇f, |δ| < the shift
    stop), itself structured (measured: identical noise-free images, 8 of 20 windows
    over the limit without the floor).  ``wts``: the pixels' weights (robust LSM's
    support, ones otherwise), ``npix_used`` their sum; ``htemplate`` is then Σ w j jᵀ.
    ``split`` receives the best line (:func:`_best_split`; -1 if none).
    Returns max S (NaN if H is singular).
    """
    side = 2 * half + 1
    nk = _STEP_NUISANCE
    split[0] = -1
    split[1] = -1
    acc = np.zeros((_STEP_ORIENTATIONS, 2 * side - 1, 2 * nk + 6))
    hmat = np.zeros((nk, nk))
    for i in range(nk - 1):
        for j in range(nk - 1):
            hmat[i, j] = htemplate[i, j]
    c = np.zeros(nk)
    vtv = _step_sums(fv, fx, fy, vres, wts, half, acc, hmat, c)
    lo = np.empty((nk, nk))
    if not _cholesky_factor(hmat, nk, lo):
        return np.nan
    zc = np.empty(nk)
    _forward(lo, c, nk, zc)
    for i in range(nk):
        vtv -= zc[i] * zc[i]  # |v|² - vᵀK H⁻¹ Kᵀv
    sig2 = max(vtv / (npix_used - nk), noise_var)
    if not sig2 > 0.0:
        return np.nan
    return _best_split(acc, lo, zc, half, min_part, split) / sig2
