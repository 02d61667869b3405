"""Normal equations of the LSM kernels (:mod:`matching.lsm_kernels`).

Small dense Cholesky solves, the template-gradient mixing matrix T(p) and the normal
matrix N = T H Tᵀ, the epipolar modes' bases and the projection of the 8 x 8 system onto
them, and the exact forward-additive normal equations of the final step.
"""

from __future__ import annotations

import numba
import numpy as np

from matching.lsm_interp import _FM, _sample


@numba.njit(cache=True, fastmath=_FM, error_model="numpy")
def _cholesky_factor(a, m, lo):
    """Lower Cholesky factor of the SPD ``a[:m, :m]`` into ``lo``; False if not SPD."""
    for i in range(m):
        for j in range(i + 1):
            s = a[i, j]
            for k in range(j):
                s -= lo[i, k] * lo[j, k]
            if i == j:
                if not s > 1e-300:
                    return False
                lo[i, i] = np.sqrt(s)
            else:
                lo[i, j] = s / lo[j, j]
    return True


@numba.njit(cache=True, fastmath=_FM, error_model="numpy")
def _cholesky_back(lo, b, m, x):
    """Solve ``lo lo^T x = b`` (forward then back substitution)."""
    _forward(lo, b, m, x)
    for i in range(m - 1, -1, -1):
        s = x[i]
        for k in range(i + 1, m):
            s -= lo[k, i] * x[k]
        x[i] = s / lo[i, i]


@numba.njit(cache=True, fastmath=_FM, error_model="numpy")
def _cholesky_solve(a, b, m, x):
    """Solve the SPD system ``a[:m, :m] x = b[:m]`` in place of ``x``; False if not SPD."""
    lo = np.empty((8, 8))
    if not _cholesky_factor(a, m, lo):
        return False
    _cholesky_back(lo, b, m, x)
    return True


@numba.njit(cache=True, inline="always", fastmath=_FM, error_model="numpy")
def _ic_step(p, y, delta):
    """delta = T(p)^{-T} y: shifts and affine columns by A = [[a1, a2], [b1, b2]], radiometry."""
    for k in range(3):
        delta[k] = p[1] * y[k] + p[2] * y[3 + k]
        delta[3 + k] = p[4] * y[k] + p[5] * y[3 + k]
    delta[7] = p[7] * y[7]
    delta[6] = y[6] + p[6] * y[7]


@numba.njit(cache=True, fastmath=_FM, error_model="numpy")
def _ic_normals(tmat, hmat, tt, nmat):
    """N = T H T^T: normal matrix of the template-gradient Jacobian.

    Each sum over T's nonzero entries only (two a row, :func:`_mixing`), in the order of
    the full sum: the terms left out are exact zeros, which change no sum (at most the
    sign of a zero result), so N is the full product's, bit for bit, for finite H."""
    cols = np.empty((8, 8), np.int64)
    count = np.zeros(8, np.int64)
    for i in range(8):
        for k in range(8):
            if tmat[i, k] != 0.0:
                cols[i, count[i]] = k
                count[i] += 1
    for i in range(8):
        for j in range(8):
            s = 0.0
            for c in range(count[i]):
                k = cols[i, c]
                s += tmat[i, k] * hmat[k, j]
            tt[i, j] = s
    for i in range(8):
        for j in range(8):
            s = 0.0
            for c in range(count[j]):
                k = cols[j, c]
                s += tt[i, k] * tmat[j, k]
            nmat[i, j] = s


@numba.njit(cache=True, fastmath=_FM, error_model="numpy")
def _ic_constrained(tmat, hmat, c, pm, m, tt, nmat, rhs, nred, bred):
    """Reduced normal equations of the template-gradient Jacobian in the basis ``pm``."""
    _ic_normals(tmat, hmat, tt, nmat)
    for i in range(8):
        s = 0.0
        for k in range(8):
            s += tmat[i, k] * c[k]
        rhs[i] = s
    _reduce(nmat, rhs, pm, m, nred, bred)


#: Unknowns of the epipolar modes (``constrained`` of the kernel): 0 none (8), 1 the
#: shift along ``d`` (7: s, a1, a2, b1, b2, r0, r1), 2 the shift and the shape along
#: ``d`` with the warp across it the template's own (5: s, w1, w2, r0, r1).
_MODE_UNKNOWNS = (8, 7, 5)


@numba.njit(cache=True, inline="always", fastmath=_FM, error_model="numpy")
def _basis(d, mode, pm):
    """The unknowns' basis: p = p0 + pm[:, :m] x (8 x m); returns m.

    Mode 2 keeps every window pixel on its own epipolar line: with n ⟂ d,
    nᵀA = nᵀ, i.e. A = I + d wᵀ (a rectified pair, d = (1, 0): b1 = 0, b2 = 1) --
    the shift s d and the shape w along d are estimated, the rest is geometry.
    """
    for i in range(8):
        for j in range(8):
            pm[i, j] = 0.0
    if mode == 0:
        for i in range(8):
            pm[i, i] = 1.0
        return 8
    pm[0, 0] = d[0]
    pm[3, 0] = d[1]
    if mode == 1:
        pm[1, 1] = 1.0
        pm[2, 2] = 1.0
        pm[4, 3] = 1.0
        pm[5, 4] = 1.0
        pm[6, 5] = 1.0
        pm[7, 6] = 1.0
        return 7
    pm[1, 1] = d[0]  # w1: A += d (1, 0)
    pm[4, 1] = d[1]
    pm[2, 2] = d[0]  # w2: A += d (0, 1)
    pm[5, 2] = d[1]
    pm[6, 3] = 1.0
    pm[7, 4] = 1.0
    return 5


@numba.njit(cache=True, inline="always", fastmath=_FM, error_model="numpy")
def _affine_row(jv, gx, gy, ix, iy, value):
    """The Jacobian row of the affine + linear radiometric model at window pixel (ix, iy):
    ``[gx, gx ix, gx iy, gy, gy ix, gy iy, 1, value]`` into ``jv[:8]``."""
    jv[0] = gx
    jv[1] = gx * ix
    jv[2] = gx * iy
    jv[3] = gy
    jv[4] = gy * ix
    jv[5] = gy * iy
    jv[6] = 1.0
    jv[7] = value


@numba.njit(cache=True, inline="always", fastmath=_FM, error_model="numpy")
def _reduce(nmat, rhs, pm, m, nred, bred):
    """Project the 8x8 system onto the m unknowns of the basis ``pm`` (:func:`_basis`)."""
    if m == 8:
        for i in range(8):
            bred[i] = rhs[i]
            for j in range(8):
                nred[i, j] = nmat[i, j]
        return 8
    for i in range(m):
        s = 0.0
        for k in range(8):
            s += pm[k, i] * rhs[k]
        bred[i] = s
        for j in range(m):
            s = 0.0
            for k in range(8):
                if pm[k, i] != 0.0:
                    for r in range(8):
                        s += pm[k, i] * nmat[k, r] * pm[r, j]
            nred[i, j] = s
    return m


@numba.njit(cache=True, inline="always", fastmath=_FM, error_model="numpy")
def _expand(xred, pm, m, delta):
    """delta = pm[:, :m] xred: the update of the 8 parameters."""
    for i in range(8):
        s = 0.0
        for j in range(m):
            s += pm[i, j] * xred[j]
        delta[i] = s


@numba.njit(cache=True, inline="always", fastmath=_FM, error_model="numpy")
def _mixing(p, tmat):
    """T(p): template-gradient Jacobian J = T j (``docs/method/lsm.md``); False if det(A) ~ 0."""
    det = p[1] * p[5] - p[2] * p[4]
    if abs(det) < 1e-12 or abs(p[7]) < 1e-12:
        return False
    # B = A^{-T}, A = [[a1, a2], [b1, b2]]
    b00 = p[5] / det
    b01 = -p[4] / det
    b10 = -p[2] / det
    b11 = p[1] / det
    for i in range(8):
        for j in range(8):
            tmat[i, j] = 0.0
    for k in range(3):
        tmat[k, k] = b00
        tmat[k, 3 + k] = b01
        tmat[3 + k, k] = b10
        tmat[3 + k, 3 + k] = b11
    tmat[6, 6] = 1.0
    tmat[7, 7] = 1.0 / p[7]
    tmat[7, 6] = -p[6] / p[7]
    return True


@numba.njit(cache=True, inline="always", fastmath=_FM, error_model="numpy")
def _forward(lo, b, m, z):
    """z = lo⁻¹ b (forward substitution only): then bᵀH⁻¹b' = z·z' for H = lo loᵀ."""
    for i in range(m):
        s = b[i]
        for k in range(i):
            s -= lo[i, k] * z[k]
        z[i] = s / lo[i, i]


@numba.njit(cache=True, fastmath=_FM, error_model="numpy")
def _exact_normals(gimg, p, q, half, kind, fv, nmat, rhs, stats):
    """Exact forward-additive normal equations at p; stats = [vtv, sf, sg, sff, sgg, sfg]."""
    wx = np.empty(4)
    dwx = np.empty(4)
    wy = np.empty(4)
    dwy = np.empty(4)
    out = np.empty(3)
    jv = np.empty(8)
    for i in range(8):
        rhs[i] = 0.0
        for j in range(8):
            nmat[i, j] = 0.0
    for i in range(6):
        stats[i] = 0.0
    n = 0
    for iy in range(-half, half + 1):
        for ix in range(-half, half + 1):
            u = p[0] + p[1] * ix + p[2] * iy + q[0] * ix * ix + q[1] * ix * iy + q[2] * iy * iy
            v = p[3] + p[4] * ix + p[5] * iy + q[3] * ix * ix + q[4] * ix * iy + q[5] * iy * iy
            _sample(gimg, u, v, kind, wx, dwx, wy, dwy, True, out)
            gval = out[0]
            gu = p[7] * out[1]
            gv = p[7] * out[2]
            res = fv[n] - p[6] - p[7] * gval
            _affine_row(jv, gu, gv, ix, iy, gval)
            for i in range(8):
                rhs[i] += jv[i] * res
                for j in range(i + 1):
                    nmat[i, j] += jv[i] * jv[j]
            stats[0] += res * res
            stats[1] += fv[n]
            stats[2] += gval
            stats[3] += fv[n] * fv[n]
            stats[4] += gval * gval
            stats[5] += fv[n] * gval
            n += 1
    for i in range(8):
        for j in range(i + 1, 8):
            nmat[i, j] = nmat[j, i]
