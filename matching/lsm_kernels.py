r"""The numba kernels of :mod:`matching.lsm`: one least-squares window, batched.

:func:`_lsm_batch` solves every window of a :func:`matching.lsm.lsm_match` call in a
``prange`` loop (``nogil``: the view-pair threads of :mod:`matching.scheduler` run it side by
side); :func:`_solve_point` is one window: the template and its normal matrix (with the
footprint smoothing, :mod:`matching.lsm_template`), the template-gradient Gauss-Newton
iterations (:func:`_iterate`), the robust adjustment (:mod:`matching.lsm_robust`), the
motion-step score (:mod:`matching.lsm_step`) and the final linearisation with its
covariances (:func:`_noise_corrected`, :func:`_covariances`).  Interpolation and warp are
in :mod:`matching.lsm_interp`, the normal equations in :mod:`matching.lsm_normals`.  The
equations, the tests and their references are in ``docs/method/lsm.md``; the arguments
are :func:`matching.lsm.lsm_match`'s, checked by it (nothing here validates its input).

Results are bitwise reproducible: fast-math without ``reassoc`` and ``contract`` (``_FM``),
so a kernel compiled in the process and one loaded from numba's cache give the same bits.
"""

from __future__ import annotations

import numba
import numpy as np

from matching.lsm_interp import _FM, _ic_rhs, _inside, _residual_stats
from matching.lsm_normals import (
    _basis,
    _cholesky_back,
    _cholesky_factor,
    _cholesky_solve,
    _exact_normals,
    _expand,
    _ic_constrained,
    _ic_normals,
    _ic_step,
    _mixing,
    _reduce,
)
from matching.lsm_robust import _robust_support, _support_holds, _weighted_normals, _weighted_stats
from matching.lsm_step import _step_score
from matching.lsm_template import _template

# The TBB layer numba tries first is too old here and warns; OpenMP works on every
# platform numba wheels ship for, the work queue is the fallback.
numba.config.THREADING_LAYER_PRIORITY = ["omp", "workqueue", "tbb"]


@numba.njit(cache=True, fastmath=_FM, error_model="numpy")
def _textured(hmat, npix, min_texture, nfac):
    """The texture test: the smallest eigenvalue of the mean structure tensor against the
    gradient noise of the (smoothed) template (nfac[1] + nfac[2] = 1 unsmoothed)."""
    sxx = hmat[0, 0] / npix
    syy = hmat[3, 3] / npix
    sxy = hmat[0, 3] / npix
    lam_min = 0.5 * (sxx + syy) - np.sqrt(0.25 * (sxx - syy) ** 2 + sxy * sxy)
    return lam_min > min_texture * (nfac[1] + nfac[2])


@numba.njit(cache=True, fastmath=_FM, error_model="numpy")
def _iterate(gimg, p, q, half, kind, fv, fx, fy, hmat, approx, pm, m, constrained, max_iter,
             tol, max_shift, tmat, tt, nmat, nred):
    """The template-gradient Gauss-Newton iterations from ``p`` (updated in place).

    Returns (status, iterations, converged); status -1: the iterations ended without a
    failure (converged, or at ``max_iter``)."""
    gh, gw = gimg.shape
    hlo = np.empty((8, 8))
    h_spd = constrained > 0 or _cholesky_factor(hmat, 8, hlo)
    c = np.empty(8)
    rhs = np.empty(8)
    bred = np.empty(8)
    xred = np.empty(8)
    delta = np.empty(8)
    it = 0
    while it < max_iter:
        it += 1
        if not _inside(p, q, half, gw, gh):
            return 6, it, False
        if not _mixing(p, tmat):
            return 4, it, False
        _ic_rhs(gimg, p, q, half, kind, fv, fx, fy, c)
        if constrained == 0:
            # delta = T^{-T} H^{-1} c, with T^{-T} in closed form (docs/method/lsm.md)
            if not h_spd:
                return 7, it, False
            _cholesky_back(hlo, c, 8, xred)
            _ic_step(p, xred, delta)
        else:
            _ic_constrained(tmat, hmat, c, pm, m, tt, nmat, rhs, nred, bred)
            if not _cholesky_solve(nred, bred, m, xred):
                return 7, it, False
            _expand(xred, pm, m, delta)
        for i in range(8):
            p[i] += delta[i]
        if not np.isfinite(p[0] + p[3]):
            return 1, it, False
        if (p[0] - approx[0]) ** 2 + (p[3] - approx[1]) ** 2 > max_shift * max_shift:
            return 3, it, False
        if np.sqrt(delta[0] ** 2 + delta[3] ** 2) < tol:
            return -1, it, True
    return -1, it, False


@numba.njit(cache=True, fastmath=_FM, error_model="numpy")
def _robust_or_equal(gimg, p, q, half, kind, fv, fx, fy, hmat, approx, pm, m, tol, max_shift,
                     robust_floor, step_noise_var, offset, wts, vres):
    """The robust adjustment from the equal-weight solution ``p``: True and its support in
    ``wts`` where it finds one holding the reported pixel, else False with ``p`` and the
    equal weights restored.

    Also from an unconverged equal-weight solution: across a depth edge the equal-weight
    iterations often oscillate between the two motions (where it finds no support -- no
    convergence, a pull-in, a support without the reported pixel -- the equal-weight
    solution and its own tests stand)."""
    p_equal = p.copy()
    code = _robust_support(gimg, p, q, half, kind, fv, fx, fy, hmat, approx, pm, m,
                           tol, max_shift, robust_floor, step_noise_var, offset, wts,
                           vres)
    if code == 0 and _support_holds(wts, half, offset):
        return True
    for i in range(8):
        p[i] = p_equal[i]
    for n in range(wts.shape[0]):
        wts[n] = 1.0
    return False


@numba.njit(cache=True, fastmath=_FM, error_model="numpy")
def _exact_step(gimg, p, q, half, kind, fv, pm, m, nmat, nred, stats):
    """The final exact forward-additive step (its normal matrix gives the covariance);
    returns (False where N is not SPD, vᵀv linearised after the step, m)."""
    rhs = np.empty(8)
    bred = np.empty(8)
    xred = np.empty(8)
    delta = np.empty(8)
    _exact_normals(gimg, p, q, half, kind, fv, nmat, rhs, stats)
    m = _reduce(nmat, rhs, pm, m, nred, bred)
    if not _cholesky_solve(nred, bred, m, xred):
        return False, 0.0, m
    _expand(xred, pm, m, delta)
    vtv = stats[0]
    for i in range(m):
        vtv -= xred[i] * bred[i]  # linearised residual after the step
    for i in range(8):
        p[i] += delta[i]
    return True, vtv, m


@numba.njit(cache=True, fastmath=_FM, error_model="numpy")
def _noise_corrected(hmat, tmat, pm, m, nred, wts, half, nfac, grad_noise_var, use_robust,
                     sw, ncred):
    """Nc: the reduced normal matrix less the expected template-noise part (N itself
    without ``grad_noise_var``), into ``ncred``."""
    npix = (2 * half + 1) ** 2
    if not grad_noise_var > 0.0:
        for i in range(m):
            for j in range(m):
                ncred[i, j] = nred[i, j]
        return
    tt = np.empty((8, 8))
    for i in range(8):
        for j in range(8):
            tt[i, j] = hmat[i, j]
    # per-pixel noise (co)variances of the template's differences and values:
    # grad_noise_var = σ_n²/2 scaled by nfac / (1/2) (1, 1, 2 x unsmoothed)
    gx = 2.0 * grad_noise_var * nfac[1]
    gy = 2.0 * grad_noise_var * nfac[2]
    gxy = 2.0 * grad_noise_var * nfac[3]
    if use_robust:
        # Σ w [1, x, y]ᵀ[1, x, y] over the support (the full window's is diagonal)
        mom = np.zeros((3, 3))
        n = 0
        for iy in range(-half, half + 1):
            for ix in range(-half, half + 1):
                w = wts[n]
                mom[0, 0] += w
                mom[0, 1] += w * ix
                mom[0, 2] += w * iy
                mom[1, 1] += w * ix * ix
                mom[1, 2] += w * ix * iy
                mom[2, 2] += w * iy * iy
                n += 1
        for a in range(3):
            for b in range(a):
                mom[a, b] = mom[b, a]
        for a in range(3):
            for b in range(3):
                tt[a, b] -= gx * mom[a, b]
                tt[3 + a, 3 + b] -= gy * mom[a, b]
                tt[a, 3 + b] -= gxy * mom[a, b]
                tt[3 + a, b] -= gxy * mom[a, b]
    else:
        s2 = (2 * half + 1) * half * (half + 1) * (2 * half + 1) / 3.0
        tt[0, 0] -= gx * npix
        tt[3, 3] -= gy * npix
        tt[1, 1] -= gx * s2
        tt[2, 2] -= gx * s2
        tt[4, 4] -= gy * s2
        tt[5, 5] -= gy * s2
        tt[0, 3] -= gxy * npix
        tt[3, 0] -= gxy * npix
        tt[1, 4] -= gxy * s2
        tt[4, 1] -= gxy * s2
        tt[2, 5] -= gxy * s2
        tt[5, 2] -= gxy * s2
    tt[7, 7] -= 2.0 * grad_noise_var * nfac[0] * sw  # value noise: σ_n² Σk²
    hc = tt.copy()
    nmat = np.empty((8, 8))
    rhs = np.zeros(8)
    bred = np.empty(8)
    _ic_normals(tmat, hc, tt, nmat)
    _reduce(nmat, rhs, pm, m, ncred, bred)


@numba.njit(cache=True, fastmath=_FM, error_model="numpy")
def _covariances(ncred, pm, m, offset, sig0sq, cov_out, wcov_out, acov_out):
    """σ0² g Nc⁻¹ gᵀ of the window centre (``wcov_out``), of the pixel at ``offset``
    (``cov_out``) and of the six affine unknowns (``acov_out``); False if Nc is not SPD.

    The warped pixel (u, v) = (a0 + a1 ox + a2 oy, b0 + b1 ox + b2 oy) (+ fixed terms):
    its gradients in the 8 parameters, then through the basis: grads = g_full pm."""
    ox = offset[0]
    oy = offset[1]
    # rows 0-1: the centre (o = 0), rows 2-3: the pixel at ``offset``
    grads = np.zeros((4, 8))
    for r in range(2):
        o_x = ox if r == 1 else 0.0
        o_y = oy if r == 1 else 0.0
        for i in range(m):
            grads[2 * r, i] = pm[0, i] + o_x * pm[1, i] + o_y * pm[2, i]
            grads[2 * r + 1, i] = pm[3, i] + o_x * pm[4, i] + o_y * pm[5, i]
    xs = np.zeros((4, 8))
    unit = np.zeros(8)
    col = np.empty(8)
    for a in range(4):
        for i in range(8):
            unit[i] = grads[a, i]
        if not _cholesky_solve(ncred, unit, m, col):
            return False
        for i in range(m):
            xs[a, i] = col[i]
    for a in range(2):
        for b in range(2):
            acc = 0.0
            acw = 0.0
            for i in range(m):
                acw += grads[a, i] * xs[b, i]
                acc += grads[2 + a, i] * xs[2 + b, i]
            cov_out[a, b] = sig0sq * acc
            wcov_out[a, b] = sig0sq * acw
    # the affine unknowns a0 a1 a2 b0 b1 b2 as rows of the (reduced) unknowns
    gaff = np.zeros((6, 8))
    for k in range(6):
        for i in range(m):
            gaff[k, i] = pm[k, i]
    xa = np.zeros((6, 8))
    nlo = np.empty((8, 8))
    if not _cholesky_factor(ncred, m, nlo):
        return False
    for a in range(6):
        for i in range(8):
            unit[i] = gaff[a, i]
        _cholesky_back(nlo, unit, m, col)
        for i in range(m):
            xa[a, i] = col[i]
    for a in range(6):
        for b in range(6):
            acc = 0.0
            for i in range(m):
                acc += gaff[a, i] * xa[b, i]
            acov_out[a, b] = sig0sq * acc
    return True


@numba.njit(cache=True, fastmath=_FM, error_model="numpy")
def _correlation(stats, sw):
    """The correlation coefficient of template and resampled search patch from
    ``stats`` = [vtv, sf, sg, sff, sgg, sfg] over the weight ``sw``."""
    sf = stats[1] / sw
    sg = stats[2] / sw
    vf = stats[3] / sw - sf * sf
    vg = stats[4] / sw - sg * sg
    cfg = stats[5] / sw - sf * sg
    return cfg / np.sqrt(vf * vg) if vf > 0.0 and vg > 0.0 else 0.0


@numba.njit(cache=True, fastmath=_FM, error_model="numpy")
def _solve_point(fimg, fraw, gimg, centre, approx, init, q, direction, constrained, half,
                 kind, exact_final, max_iter, tol, max_shift, det_min, min_texture,
                 grad_noise_var, step_noise_var, offset, blur, robust, robust_floor,
                 min_corr, p_out, cov_out, wcov_out, acov_out, sig0_out, corr_out):
    """Gauss-Newton LSM for one patch; returns (status, iterations, converged).

    ``robust``: after convergence, the robust adjustment (:func:`_robust_or_equal`,
    residual scale never below ``robust_floor``), whose support then weighs every sum
    of the final linearisation (σ0² = vᵀWv / (Σw - u), N = Tᵀ H_w T); a support that
    leaves out the reported pixel or holds under half the window: status 11.

    ``cov_out``: covariance of the warped template pixel ``offset`` (relative to the
    centre); ``wcov_out``: of the window centre (the shift (a0, b0)); ``acov_out``: of
    the six affine unknowns ``a0 a1 a2 b0 b1 b2``."""
    npix = (2 * half + 1) ** 2
    fh, fw = fimg.shape
    gh, gw = gimg.shape
    cx = centre[0]
    cy = centre[1]
    if not (cx - half >= 1.0 and cy - half >= 1.0 and cx + half < fw - 2.0
            and cy + half < fh - 2.0):
        return 6, 0, False
    fv = np.empty(npix)
    fx = np.empty(npix)
    fy = np.empty(npix)
    hmat = np.empty((8, 8))
    nfac = np.empty(4)
    _template(fimg, fraw, cx, cy, half, kind, fv, fx, fy, hmat, blur, nfac)
    corr_out[1] = (hmat[0, 0] + hmat[3, 3]) / npix  # mean gradient power |∇f|²
    if not _textured(hmat, npix, min_texture, nfac):
        return 7, 0, False
    p = init.copy()
    pm = np.empty((8, 8))
    m = _basis(direction, constrained, pm)
    tmat = np.empty((8, 8))
    tt = np.empty((8, 8))
    nmat = np.empty((8, 8))
    nred = np.empty((8, 8))
    code, it, converged = _iterate(gimg, p, q, half, kind, fv, fx, fy, hmat, approx, pm, m,
                                   constrained, max_iter, tol, max_shift, tmat, tt, nmat,
                                   nred)
    if code >= 0:
        return code, it, False
    status = 0
    det = p[1] * p[5] - p[2] * p[4]
    if not (det > det_min and det < 1.0 / det_min and p[7] > det_min):
        status = 4
    if not _inside(p, q, half, gw, gh):
        return 6, it, converged
    wts = np.ones(npix)
    vres = np.empty(npix)
    sw = float(npix)
    stats = np.empty(6)
    use_robust = robust and not exact_final and status == 0
    if use_robust:
        use_robust = _robust_or_equal(gimg, p, q, half, kind, fv, fx, fy, hmat, approx, pm,
                                      m, tol, max_shift, robust_floor, step_noise_var,
                                      offset, wts, vres)
        converged = converged or use_robust
    if exact_final:
        ok, vtv, m = _exact_step(gimg, p, q, half, kind, fv, pm, m, nmat, nred, stats)
        if not ok:
            return 7, it, False
    else:
        # final linearisation with the template-gradient Jacobian J = T(p) j
        if not _mixing(p, tmat):
            return 4, it, False
        _residual_stats(gimg, p, q, half, kind, fv, stats, vres)
        if use_robust:
            # the sums over the support: H_w = Σ w j jᵀ replaces the template's H
            _weighted_normals(fv, fx, fy, vres, wts, half, hmat, np.empty(8))
            sw = _weighted_stats(fv, vres, p, wts, npix, stats)
            corr_out[1] = (hmat[0, 0] + hmat[3, 3]) / sw
        corr_out[3] = sw / npix
        _ic_normals(tmat, hmat, tt, nmat)
        m = _reduce(nmat, np.zeros(8), pm, m, nred, np.empty(8))
        vtv = stats[0]
    for i in range(8):
        p_out[i] = p[i]
    sig0sq = max(vtv, 0.0) / (sw - m)
    sig0_out[0] = np.sqrt(sig0sq)
    corr = _correlation(stats, sw)
    if not exact_final and converged and status == 0 and corr >= min_corr:
        # only a window that can pass is judged by its step score (the populations and
        # the test take the accepted ones): one the kernel rejects, or whose correlation
        # the driver's test rejects, skips it (~1/6 of a window's time)
        corr_out[2] = _step_score(fv, fx, fy, vres, wts, sw, half, 2 * (2 * half + 1),
                                  hmat, step_noise_var, np.empty(2, np.int64))
    ncred = np.empty((8, 8))
    _noise_corrected(hmat, tmat, pm, m, nred, wts, half, nfac,
                     grad_noise_var if not exact_final else 0.0, use_robust, sw, ncred)
    if not _covariances(ncred, pm, m, offset, sig0sq, cov_out, wcov_out, acov_out):
        return 7, it, False
    corr_out[0] = corr
    if (p[0] - approx[0]) ** 2 + (p[3] - approx[1]) ** 2 > max_shift * max_shift:
        return 3, it + 1, converged
    if not converged:
        return 1, it + 1, False
    return status, it + 1, converged


@numba.njit(parallel=True, nogil=True, cache=True, fastmath=_FM, error_model="numpy")
def _lsm_batch(fimg, fraw, gimg, centres, approx, init, quad, directions, constrained, half,
               kind, exact_final, max_iter, tol, max_shift, det_min, min_texture,
               grad_noise_var, step_noise_var, offsets, blurs, robust, robust_floor, min_corr,
               params,
               cov, wcov, acov, sigma0, corr, status, iters, conv):
    n = centres.shape[0]
    for i in numba.prange(n):
        s, it, cv = _solve_point(fimg, fraw, gimg, centres[i], approx[i], init[i], quad[i],
                                 directions[i], constrained, half, kind, exact_final,
                                 max_iter, tol,
                                 max_shift, det_min, min_texture, grad_noise_var,
                                 step_noise_var, offsets[i], blurs[i], robust[i],
                                 robust_floor, min_corr, params[i], cov[i],
                                 wcov[i], acov[i], sigma0[i:i + 1], corr[i])
        status[i] = s
        iters[i] = it
        conv[i] = cv
