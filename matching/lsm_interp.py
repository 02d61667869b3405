"""Interpolation and warp of the LSM kernels (:mod:`matching.lsm_kernels`).

The tap weights of the bilinear, Keys cubic and cubic B-spline interpolants, one sample
and its gradients (:func:`_sample`), whether a warped window lies in the image
(:func:`_inside`), and the warped search values over a window with the sums that use them:
the right-hand side of the template-gradient iteration (:func:`_ic_rhs`) and the residual
statistics (:func:`_residual_stats`).  ``_FM``, the fast-math flags every kernel is
compiled with, is defined here.
"""

from __future__ import annotations

import numba
import numpy as np

#: fast-math without "no NaN / no inf", so the NaN checks stay meaningful, and without
#: "reassoc" and "contract": with them a kernel compiled in the process and the same
#: kernel loaded from numba's cache gave results different in the last bits (the
#: cloud then differed between a first run and the next ones); the same CPU time without
_FM = {"nsz", "arcp", "afn"}


@numba.njit(cache=True, inline="always", fastmath=_FM, error_model="numpy")
def _weights(t, kind, w, dw, grad):
    """The 4 tap weights (offsets -1, 0, 1, 2) for frac ``t``; derivatives if ``grad``."""
    if kind == 0:  # bilinear
        w[0] = 0.0
        w[1] = 1.0 - t
        w[2] = t
        w[3] = 0.0
        if grad:
            dw[0] = 0.0
            dw[1] = -1.0
            dw[2] = 1.0
            dw[3] = 0.0
    elif kind == 1:  # Keys cubic convolution, a = -0.5
        t2 = t * t
        t3 = t2 * t
        w[0] = -0.5 * t3 + t2 - 0.5 * t
        w[1] = 1.5 * t3 - 2.5 * t2 + 1.0
        w[2] = -1.5 * t3 + 2.0 * t2 + 0.5 * t
        w[3] = 0.5 * t3 - 0.5 * t2
        if grad:
            dw[0] = -1.5 * t2 + 2.0 * t - 0.5
            dw[1] = 4.5 * t2 - 5.0 * t
            dw[2] = -4.5 * t2 + 4.0 * t + 0.5
            dw[3] = 1.5 * t2 - t
    else:  # cubic B-spline on prefiltered coefficients
        s = 1.0 - t
        t2 = t * t
        t3 = t2 * t
        w[0] = s * s * s / 6.0
        w[1] = (3.0 * t3 - 6.0 * t2 + 4.0) / 6.0
        w[2] = (-3.0 * t3 + 3.0 * t2 + 3.0 * t + 1.0) / 6.0
        w[3] = t3 / 6.0
        if grad:
            dw[0] = -0.5 * s * s
            dw[1] = 1.5 * t2 - 2.0 * t
            dw[2] = -1.5 * t2 + t + 0.5
            dw[3] = 0.5 * t2


@numba.njit(cache=True, inline="always", fastmath=_FM, error_model="numpy")
def _sample(img, u, v, kind, wx, dwx, wy, dwy, grad, out):
    """Interpolate ``img`` at (u, v); ``out = [value, d/du, d/dv]`` (gradients if ``grad``)."""
    x0 = int(np.floor(u))
    y0 = int(np.floor(v))
    _weights(u - x0, kind, wx, dwx, grad)
    _weights(v - y0, kind, wy, dwy, grad)
    val = 0.0
    gu = 0.0
    gv = 0.0
    for r in range(4):
        row = y0 - 1 + r
        s0 = 0.0
        s1 = 0.0
        for c in range(4):
            pix = img[row, x0 - 1 + c]
            s0 += wx[c] * pix
            if grad:
                s1 += dwx[c] * pix
        val += wy[r] * s0
        if grad:
            gu += wy[r] * s1
            gv += dwy[r] * s0
    out[0] = val
    out[1] = gu
    out[2] = gv


@numba.njit(cache=True, inline="always", fastmath=_FM, error_model="numpy")
def _inside(p, q, half, width, height):
    """True when the warped patch and its 4x4 interpolation support lie in the image.

    Checked at the corners, edge midpoints and centre (exact for the affine warp; the
    fixed quadratic terms are small enough that these bound the footprint).
    """
    for sx in (-half, 0, half):
        for sy in (-half, 0, half):
            u = p[0] + p[1] * sx + p[2] * sy + q[0] * sx * sx + q[1] * sx * sy + q[2] * sy * sy
            v = p[3] + p[4] * sx + p[5] * sy + q[3] * sx * sx + q[4] * sx * sy + q[5] * sy * sy
            if not (u >= 1.0 and v >= 1.0 and u < width - 2.0 and v < height - 2.0):
                return False
    return True


@numba.njit(cache=True, inline="always", fastmath=_FM, error_model="numpy")
def _bspline_value(img, u, v):
    """The cubic B-spline interpolant of ``img`` at (u, v): :func:`_sample`'s value for
    ``kind`` 2, the same operations in the same order, its weights held in registers."""
    x0 = int(np.floor(u))
    y0 = int(np.floor(v))
    t = u - x0
    s = 1.0 - t
    t2 = t * t
    t3 = t2 * t
    wx0 = s * s * s / 6.0
    wx1 = (3.0 * t3 - 6.0 * t2 + 4.0) / 6.0
    wx2 = (-3.0 * t3 + 3.0 * t2 + 3.0 * t + 1.0) / 6.0
    wx3 = t3 / 6.0
    t = v - y0
    s = 1.0 - t
    t2 = t * t
    t3 = t2 * t
    wy0 = s * s * s / 6.0
    wy1 = (3.0 * t3 - 6.0 * t2 + 4.0) / 6.0
    wy2 = (-3.0 * t3 + 3.0 * t2 + 3.0 * t + 1.0) / 6.0
    wy3 = t3 / 6.0
    c = x0 - 1
    r = y0 - 1
    val = 0.0
    val += wy0 * (((0.0 + wx0 * img[r, c]) + wx1 * img[r, c + 1]) + wx2 * img[r, c + 2]
                  + wx3 * img[r, c + 3])
    r += 1
    val += wy1 * (((0.0 + wx0 * img[r, c]) + wx1 * img[r, c + 1]) + wx2 * img[r, c + 2]
                  + wx3 * img[r, c + 3])
    r += 1
    val += wy2 * (((0.0 + wx0 * img[r, c]) + wx1 * img[r, c + 1]) + wx2 * img[r, c + 2]
                  + wx3 * img[r, c + 3])
    r += 1
    val += wy3 * (((0.0 + wx0 * img[r, c]) + wx1 * img[r, c + 1]) + wx2 * img[r, c + 2]
                  + wx3 * img[r, c + 3])
    return val


@numba.njit(cache=True, fastmath=_FM, error_model="numpy")
def _warped_values(gimg, p, q, half, kind, gv):
    """gv = g(W(x)) over the patch, row-major (values only): :func:`_sample`'s value at
    every warped pixel, the same operations in the same order.

    For the cubic B-spline (``kind`` 2) in two loops: every pixel's tap weights and first
    tap first (no value depends on another pixel's, so that loop runs in SIMD lanes),
    then the 16 taps of each.  Without second-order terms (most windows) the warp is
    affine: the same positions (the zero terms added nothing) for fewer operations.
    """
    side = 2 * half + 1
    npix = side * side
    flat = (q[0] == 0.0 and q[1] == 0.0 and q[2] == 0.0 and q[3] == 0.0 and q[4] == 0.0
            and q[5] == 0.0)
    p0, p1, p2, p3, p4, p5 = p[0], p[1], p[2], p[3], p[4], p[5]
    q0, q1, q2, q3, q4, q5 = q[0], q[1], q[2], q[3], q[4], q[5]
    if kind != 2:
        wx = np.empty(4)
        dwx = np.empty(4)
        wy = np.empty(4)
        dwy = np.empty(4)
        out = np.empty(3)
        for n in range(npix):
            iy = n // side - half
            ix = n - (n // side) * side - half
            u = p0 + p1 * ix + p2 * iy + q0 * ix * ix + q1 * ix * iy + q2 * iy * iy
            v = p3 + p4 * ix + p5 * iy + q3 * ix * ix + q4 * ix * iy + q5 * iy * iy
            _sample(gimg, u, v, kind, wx, dwx, wy, dwy, False, out)
            gv[n] = out[0]
        return
    width = gimg.shape[1]
    g = gimg.reshape(gimg.size)
    wts = np.empty((8, npix))
    first = np.empty(npix)
    for n in range(npix):
        iy = n // side - half
        ix = n - (n // side) * side - half
        if flat:
            u = p0 + p1 * ix + p2 * iy
            v = p3 + p4 * ix + p5 * iy
        else:
            u = p0 + p1 * ix + p2 * iy + q0 * ix * ix + q1 * ix * iy + q2 * iy * iy
            v = p3 + p4 * ix + p5 * iy + q3 * ix * ix + q4 * ix * iy + q5 * iy * iy
        x0 = np.floor(u)
        y0 = np.floor(v)
        t = u - x0
        s = 1.0 - t
        t2 = t * t
        t3 = t2 * t
        wts[0, n] = s * s * s / 6.0
        wts[1, n] = (3.0 * t3 - 6.0 * t2 + 4.0) / 6.0
        wts[2, n] = (-3.0 * t3 + 3.0 * t2 + 3.0 * t + 1.0) / 6.0
        wts[3, n] = t3 / 6.0
        t = v - y0
        s = 1.0 - t
        t2 = t * t
        t3 = t2 * t
        wts[4, n] = s * s * s / 6.0
        wts[5, n] = (3.0 * t3 - 6.0 * t2 + 4.0) / 6.0
        wts[6, n] = (-3.0 * t3 + 3.0 * t2 + 3.0 * t + 1.0) / 6.0
        wts[7, n] = t3 / 6.0
        first[n] = (y0 - 1.0) * width + (x0 - 1.0)  # the first tap, exact (< 2^53)
    for n in range(npix):
        k = int(first[n])
        wx0 = wts[0, n]
        wx1 = wts[1, n]
        wx2 = wts[2, n]
        wx3 = wts[3, n]
        val = 0.0
        val += wts[4, n] * (((0.0 + wx0 * g[k]) + wx1 * g[k + 1]) + wx2 * g[k + 2]
                            + wx3 * g[k + 3])
        k += width
        val += wts[5, n] * (((0.0 + wx0 * g[k]) + wx1 * g[k + 1]) + wx2 * g[k + 2]
                            + wx3 * g[k + 3])
        k += width
        val += wts[6, n] * (((0.0 + wx0 * g[k]) + wx1 * g[k + 1]) + wx2 * g[k + 2]
                            + wx3 * g[k + 3])
        k += width
        val += wts[7, n] * (((0.0 + wx0 * g[k]) + wx1 * g[k + 1]) + wx2 * g[k + 2]
                            + wx3 * g[k + 3])
        gv[n] = val


@numba.njit(cache=True, fastmath=_FM, error_model="numpy")
def _ic_rhs(gimg, p, q, half, kind, fv, fx, fy, c):
    """c = sum j v over the patch with v = f - r0 - r1 g(W(x)) (values only).

    The warped values first (:func:`_warped_values`), then the sums, held in registers
    and written once (``c`` may alias the inputs as far as the compiler knows, which
    kept every partial sum in memory): the same operations in the same order."""
    side = 2 * half + 1
    gv = np.empty(side * side)
    _warped_values(gimg, p, q, half, kind, gv)
    p6, p7 = p[6], p[7]
    c0 = c1 = c2 = c3 = c4 = c5 = c6 = c7 = 0.0
    n = 0
    for iy in range(-half, half + 1):
        for ix in range(-half, half + 1):
            fn = fv[n]
            res = fn - p6 - p7 * gv[n]
            rx = fx[n] * res
            ry = fy[n] * res
            c0 += rx
            c1 += rx * ix
            c2 += rx * iy
            c3 += ry
            c4 += ry * ix
            c5 += ry * iy
            c6 += res
            c7 += fn * res
            n += 1
    c[0] = c0
    c[1] = c1
    c[2] = c2
    c[3] = c3
    c[4] = c4
    c[5] = c5
    c[6] = c6
    c[7] = c7


@numba.njit(cache=True, fastmath=_FM, error_model="numpy")
def _residual_stats(gimg, p, q, half, kind, fv, stats, vres):
    """stats = [vtv, sf, sg, sff, sgg, sfg] at p (values only); the residuals into vres."""
    npix = (2 * half + 1) ** 2
    gv = np.empty(npix)
    _warped_values(gimg, p, q, half, kind, gv)
    for i in range(6):
        stats[i] = 0.0
    for n in range(npix):
        gval = gv[n]
        res = fv[n] - p[6] - p[7] * gval
        vres[n] = res
        stats[0] += res * res
        stats[1] += fv[n]
        stats[2] += gval
        stats[3] += fv[n] * fv[n]
        stats[4] += gval * gval
        stats[5] += fv[n] * gval
