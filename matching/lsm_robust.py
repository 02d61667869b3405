"""Robust weights of the LSM kernels (:mod:`matching.lsm_kernels`): Tukey's biweight
on the residuals in their robust scale, the coherent support it leaves, the weighted
normal equations and statistics, the robust adjustment (:func:`_robust_support`) and the
tests of the final support.
"""

from __future__ import annotations

import numba
import numpy as np

from checks.robust import MAD_TO_SIGMA
from matching.lsm_interp import _FM, _inside, _residual_stats
from matching.lsm_normals import _affine_row, _cholesky_solve, _expand, _ic_constrained, _mixing
from matching.lsm_step import _step_score

#: Tukey biweight's tuning constant: 95 % asymptotic efficiency at Gaussian residuals
#: (Holland & Welsch 1977 [6]_); the residuals are measured in their robust scale.
TUKEY_C = 4.685
#: 1 / Φ⁻¹(3/4): the median absolute residual of a Gaussian over its σ.
_MAD_TO_SIGMA = MAD_TO_SIGMA
#: Most IRLS passes of the robust adjustment (:func:`_robust_support`); the support is
#: final when it no longer changes.
_ROBUST_ITER = 10


@numba.njit(cache=True, fastmath=_FM, error_model="numpy")
def _coherent(wts, half, keep):
    """Zero the weight of pixels with fewer than 5 of their 3 x 3 neighbourhood (itself
    included, the window's border clipped: of those present, over half) weighted: a
    surface that does not follow the warp misfits by a random amount where its texture
    is uncorrelated with what the warp brings, so that Tukey's weights keep a scatter of
    its pixels (a quarter of them, at the usual contrasts); the pixels of one surface
    are contiguous."""
    side = 2 * half + 1
    for iy in range(side):
        for ix in range(side):
            on = 0
            there = 0
            for dy in range(-1, 2):
                for dx in range(-1, 2):
                    y = iy + dy
                    x = ix + dx
                    if 0 <= y < side and 0 <= x < side:
                        there += 1
                        if wts[y * side + x] > 0.0:
                            on += 1
            keep[iy * side + ix] = 2 * on > there
    for n in range(side * side):
        if not keep[n]:
            wts[n] = 0.0


@numba.njit(cache=True, fastmath=_FM, error_model="numpy")
def _tukey_weights(vres, npix, floor, wts):
    """Tukey biweights of the residuals in their robust scale; returns the scale.

    scale = max(1.4826 median |v|, ``floor``) (the median absolute residual: the
    window's majority, with 50 % breakdown; ``floor``: the images' noise, so that a
    noise-free residual does not shrink the scale to nothing), w = (1 - (v / c s)²)²
    inside c s, c = ``TUKEY_C``, else 0.
    """
    absv = np.empty(npix)
    for n in range(npix):
        absv[n] = abs(vres[n])
    scale = max(_MAD_TO_SIGMA * np.median(absv), floor)
    cs = TUKEY_C * scale
    for n in range(npix):
        u = vres[n] / cs
        wts[n] = (1.0 - u * u) ** 2 if u * u < 1.0 else 0.0
    return scale


@numba.njit(cache=True, fastmath=_FM, error_model="numpy")
def _weighted_normals(fv, fx, fy, vres, wts, half, hmat, c):
    """H_w = Σ w j jᵀ and c = Σ w j v of the template-gradient Jacobian rows j."""
    jv = np.empty(8)
    for i in range(8):
        c[i] = 0.0
        for j in range(8):
            hmat[i, j] = 0.0
    n = 0
    for iy in range(-half, half + 1):
        for ix in range(-half, half + 1):
            w = wts[n]
            if w > 0.0:
                _affine_row(jv, fx[n], fy[n], ix, iy, fv[n])
                wv = w * vres[n]
                for i in range(8):
                    c[i] += jv[i] * wv
                    wj = w * jv[i]
                    for j in range(i + 1):
                        hmat[i, j] += wj * jv[j]
            n += 1
    for i in range(8):
        for j in range(i + 1, 8):
            hmat[i, j] = hmat[j, i]


@numba.njit(cache=True, fastmath=_FM, error_model="numpy")
def _weighted_stats(fv, vres, p, wts, npix, stats):
    """stats = [Σ w v², Σ w f, Σ w g, Σ w f², Σ w g², Σ w f g] with g = (f - r0 - v) / r1
    (the resampled search value of each pixel); returns Σ w."""
    for i in range(6):
        stats[i] = 0.0
    sw = 0.0
    for n in range(npix):
        w = wts[n]
        g = (fv[n] - p[6] - vres[n]) / p[7]
        sw += w
        stats[0] += w * vres[n] * vres[n]
        stats[1] += w * fv[n]
        stats[2] += w * g
        stats[3] += w * fv[n] * fv[n]
        stats[4] += w * g * g
        stats[5] += w * fv[n] * g
    return sw


@numba.njit(cache=True, inline="always", fastmath=_FM, error_model="numpy")
def _split_bin(orientation, ix, iy, half):
    """Bin of window pixel (ix, iy) along a split line's normal (:func:`_step_sums`)."""
    if orientation == 0:
        return ix + half
    if orientation == 1:
        return iy + half
    if orientation == 2:
        return ix + iy + 2 * half
    return ix - iy + 2 * half


@numba.njit(cache=True, fastmath=_FM, error_model="numpy")
def _robust_support(gimg, p, q, half, kind, fv, fx, fy, hmat, approx, pm, m, tol,
                    max_shift, floor, step_noise_var, offset, wts, vres):
    """Robust LSM from a converged equal-weight solution ``p`` (updated in place).

    Iteratively reweighted least squares with Tukey's biweight of the residuals
    (:func:`_tukey_weights`), each pass one Gauss-Newton step of the weighted normal
    equations (template-gradient Jacobian, the basis ``pm``); then the *support* -- the
    pixels of nonzero weight -- is fixed (``wts`` 0/1) and the ordinary adjustment is
    iterated over it, so that the estimate and its covariance are those of least squares
    over the pixels that follow one warp (Tukey's weights are < 1 near the threshold:
    with them in σ0² and the normal matrix the covariance would be ~10 % too small for
    Gaussian residuals).  Returns 0, or the :class:`matching.lsm.Status` code of a
    failure (1: no convergence, 3: pull-in, 4: degenerate, 6: outside, 7: singular).
    """
    npix = (2 * half + 1) ** 2
    stats = np.empty(6)
    # start: least squares over the side of the reported pixel of the line the
    # motion-step test finds most likely to split two motions (:func:`_step_score`), so
    # that the IRLS begins at that pixel's motion and not at the compromise of two
    # motions the equal-weight solution is across an edge (from which Tukey's weights
    # would not move: every pixel misfits alike).  One motion: any half is a start.
    for n in range(npix):
        wts[n] = 1.0
    _residual_stats(gimg, p, q, half, kind, fv, stats, vres)
    split = np.empty(2, np.int64)
    _step_score(fv, fx, fy, vres, wts, float(npix), half, 2 * (2 * half + 1), hmat,
                step_noise_var, split)
    if split[0] >= 0:
        ox = min(max(int(np.floor(offset[0] + 0.5)), -half), half)
        oy = min(max(int(np.floor(offset[1] + 0.5)), -half), half)
        mine = _split_bin(split[0], ox, oy, half) <= split[1]
        n = 0
        for iy in range(-half, half + 1):
            for ix in range(-half, half + 1):
                wts[n] = 1.0 if (_split_bin(split[0], ix, iy, half) <= split[1]) == mine else 0.0
                n += 1
        code = _robust_iterate(gimg, p, q, half, kind, fv, fx, fy, approx, pm, m, tol,
                               max_shift, wts, vres, False, floor)
        if code != 0:
            return code
    # IRLS: Tukey's weights from each pass's residuals
    code = _robust_iterate(gimg, p, q, half, kind, fv, fx, fy, approx, pm, m, tol,
                           max_shift, wts, vres, True, floor)
    if code != 0:
        return code
    # the support fixed: least squares over the pixels that follow the warp
    if not _final_support(wts, half, offset):
        return 11
    return _robust_iterate(gimg, p, q, half, kind, fv, fx, fy, approx, pm, m, tol,
                           max_shift, wts, vres, False, floor)


@numba.njit(cache=True, fastmath=_FM, error_model="numpy")
def _robust_iterate(gimg, p, q, half, kind, fv, fx, fy, approx, pm, m, tol, max_shift,
                    wts, vres, reweight, floor):
    """Gauss-Newton on the weighted normal equations (:func:`_robust_support`'s three
    stages).  ``reweight`` False: the weights ``wts`` fixed, until the shift update is
    below ``tol`` (status 1 if it never is).  True: Tukey's weights of each pass's
    residuals (scale floored at ``floor``, :func:`_tukey_weights`, made coherent,
    :func:`_coherent`) for at most :data:`_ROBUST_ITER` passes, ending from the second
    on when the update is below ``tol`` (the weights have settled), else after the
    last.  Returns 0 or a status code."""
    npix = (2 * half + 1) ** 2
    keep = np.empty(npix, np.bool_)
    hw = np.empty((8, 8))
    c = np.empty(8)
    tmat = np.empty((8, 8))
    tt = np.empty((8, 8))
    nmat = np.empty((8, 8))
    rhs = np.empty(8)
    nred = np.empty((8, 8))
    bred = np.empty(8)
    xred = np.empty(8)
    delta = np.empty(8)
    stats = np.empty(6)
    for it in range(_ROBUST_ITER):
        if not _inside(p, q, half, gimg.shape[1], gimg.shape[0]):
            return 6
        if not _mixing(p, tmat):
            return 4
        _residual_stats(gimg, p, q, half, kind, fv, stats, vres)
        if reweight:
            _tukey_weights(vres, npix, floor, wts)
            _coherent(wts, half, keep)
        _weighted_normals(fv, fx, fy, vres, wts, half, hw, c)
        _ic_constrained(tmat, hw, c, pm, m, tt, nmat, rhs, nred, bred)
        if not _cholesky_solve(nred, bred, m, xred):
            return 7
        _expand(xred, pm, m, delta)
        for i in range(8):
            p[i] += delta[i]
        if not np.isfinite(p[0] + p[3]):
            return 1
        if (p[0] - approx[0]) ** 2 + (p[3] - approx[1]) ** 2 > max_shift * max_shift:
            return 3
        if np.sqrt(delta[0] ** 2 + delta[3] ** 2) < tol and (it >= 1 or not reweight):
            return 0
    return 0 if reweight else 1


@numba.njit(cache=True, fastmath=_FM, error_model="numpy")
def _final_support(wts, half, offset):
    """The 0/1 support of the final adjustment from the IRLS weights ``wts`` (in place).

    The weighted pixels (at least half the window: the median's breakdown point), less
    those 4-adjacent to an unweighted one (a pixel on the boundary between two surfaces
    mixes both, within Tukey's limit yet off either motion), and of the rest only the
    4-connected region holding the reported pixel (``offset``; what remains of the other
    surface's chance fits is cut off from it).  False: no support holds that pixel.
    """
    side = 2 * half + 1
    npix = side * side
    total = 0
    for n in range(npix):
        if wts[n] > 0.0:
            total += 1
    if 2 * total < npix:
        return False
    eroded = np.zeros(npix, np.bool_)
    for iy in range(side):
        for ix in range(side):
            n = iy * side + ix
            if not wts[n] > 0.0:
                continue
            inside = True
            if ix > 0 and not wts[n - 1] > 0.0:
                inside = False
            if ix < side - 1 and not wts[n + 1] > 0.0:
                inside = False
            if iy > 0 and not wts[n - side] > 0.0:
                inside = False
            if iy < side - 1 and not wts[n + side] > 0.0:
                inside = False
            eroded[n] = inside
    ox = min(max(int(np.floor(offset[0] + 0.5)), -half), half) + half
    oy = min(max(int(np.floor(offset[1] + 0.5)), -half), half) + half
    for n in range(npix):
        wts[n] = 0.0
    start = oy * side + ox
    if not eroded[start]:
        return False
    stack = np.empty(npix, np.int64)
    top = 0
    stack[top] = start
    top += 1
    wts[start] = 1.0
    while top > 0:
        top -= 1
        n = stack[top]
        iy = n // side
        ix = n - iy * side
        for k in range(4):
            jx = ix + (1 if k == 0 else -1 if k == 1 else 0)
            jy = iy + (1 if k == 2 else -1 if k == 3 else 0)
            if 0 <= jx < side and 0 <= jy < side:
                j = jy * side + jx
                if eroded[j] and wts[j] == 0.0:
                    wts[j] = 1.0
                    stack[top] = j
                    top += 1
    return True


@numba.njit(cache=True, fastmath=_FM, error_model="numpy")
def _support_holds(wts, half, offset):
    """Robust LSM's support holds the window's majority and the reported pixel: at
    least half of the pixels, and 5 of the 3 x 3 around ``offset`` (the centre, or the
    eccentric window's pixel).  Otherwise the warp found is another surface's."""
    side = 2 * half + 1
    total = 0.0
    for n in range(side * side):
        total += wts[n]
    if total < 0.5 * side * side:
        return False
    ox = int(np.floor(offset[0] + 0.5))
    oy = int(np.floor(offset[1] + 0.5))
    near = 0.0
    for dy in range(-1, 2):
        for dx in range(-1, 2):
            ix = min(max(ox + dx, -half), half)
            iy = min(max(oy + dy, -half), half)
            near += wts[(iy + half) * side + ix + half]
    return near >= 5.0
