r"""The numba kernels of :mod:`matching.lsm`: one least-squares window, batched.

:func:`_lsm_batch` solves every window of a :func:`matching.lsm.lsm_match` call in a
``prange`` loop (``nogil``: the view-pair threads of :mod:`matching.scheduler` run it side by
side); :func:`_solve_point` is one window: the template and its normal matrix (with the
footprint smoothing, :func:`_template`), the template-gradient Gauss-Newton iterations, the
robust adjustment (:func:`_robust_support`), the motion-step score (:func:`_step_score`) and
the final linearisation with its covariances.  The equations, the tests and their
references are in ``docs/method/lsm.md``; the arguments are :func:`matching.lsm.lsm_match`'s,
checked by it (nothing here validates its input).

Results are bitwise reproducible: fast-math without ``reassoc`` and ``contract`` (``_FM``),
so a kernel compiled in the process and one loaded from numba's cache give the same bits.
"""

from __future__ import annotations

import numba
import numpy as np

# The TBB layer numba tries first is too old here and warns; OpenMP works on every
# platform numba wheels ship for, the work queue is the fallback.
numba.config.THREADING_LAYER_PRIORITY = ["omp", "workqueue", "tbb"]

#: fast-math without "no NaN / no inf", so the NaN checks stay meaningful, and without
#: "reassoc" and "contract": with them a kernel compiled in the process and the same
#: kernel loaded from numba's cache gave results different in the last bits (the
#: cloud then differed between a first run and the next ones); the same CPU time without
_FM = {"nsz", "arcp", "afn"}
#: Largest radius of the template's footprint smoothing (``lsm_match``'s
#: ``footprint_var``), px: a Gaussian of σ up to 4/3 px is sampled to 3σ.
_MAX_BLUR_RADIUS = 4


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
    """N = T H T^T: normal matrix of the template-gradient Jacobian."""
    for i in range(8):
        for j in range(8):
            s = 0.0
            for k in range(8):
                s += tmat[i, k] * hmat[k, j]
            tt[i, j] = s
    for i in range(8):
        for j in range(8):
            s = 0.0
            for k in range(8):
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


@numba.njit(cache=True, fastmath=_FM, error_model="numpy")
def _blurred_template(fimg, fraw, cx, cy, half, kind, blur, fv, fx, fy, noise_fac):
    """The template smoothed by the Gaussian of covariance ``blur`` (sxx, sxy, syy), px².

    The raw template (pixels read directly at an integer centre, clamped at the image
    border, else B-spline samples) on the patch grid plus a border of 1 + R px, R =
    ceil(3 σ_max) (at most ``_MAX_BLUR_RADIUS``), is convolved with the sampled and
    normalised Gaussian; values and central differences of the result fill ``fv fx fy``.
    ``noise_fac`` = [Σk², Σ(∂x k)², Σ(∂y k)², Σ ∂x k ∂y k]: the per-pixel variances (and
    the x-y covariance) of white template noise after the smoothing, in units of σ_n²
    (1, 1/2, 1/2, 0 without smoothing).
    """
    sxx = blur[0]
    sxy = blur[1]
    syy = blur[2]
    det = sxx * syy - sxy * sxy
    big = 0.5 * (sxx + syy) + np.sqrt(0.25 * (sxx - syy) ** 2 + sxy * sxy)
    rad = min(int(np.ceil(3.0 * np.sqrt(max(big, 0.0)))), _MAX_BLUR_RADIUS)
    kw = 2 * rad + 1
    kern = np.zeros((kw, kw))
    if det > 1e-12:
        ixx = syy / det
        ixy = -sxy / det
        iyy = sxx / det
    else:  # degenerate (a line): regularised
        e = 1e-3
        d2 = (sxx + e) * (syy + e) - sxy * sxy
        ixx = (syy + e) / d2
        ixy = -sxy / d2
        iyy = (sxx + e) / d2
    tot = 0.0
    for a in range(kw):
        for b in range(kw):
            dy = a - rad
            dx = b - rad
            w = np.exp(-0.5 * (ixx * dx * dx + 2.0 * ixy * dx * dy + iyy * dy * dy))
            kern[a, b] = w
            tot += w
    for a in range(kw):
        for b in range(kw):
            kern[a, b] /= tot
    # noise factors: Σk², and of the central differences of the smoothed image
    s_v = 0.0
    s_x = 0.0
    s_y = 0.0
    s_xy = 0.0
    for a in range(-1, kw + 1):
        for b in range(-1, kw + 1):
            k0 = kern[a, b] if 0 <= a < kw and 0 <= b < kw else 0.0
            kxm = kern[a, b - 1] if 0 <= a < kw and 0 <= b - 1 < kw else 0.0
            kxp = kern[a, b + 1] if 0 <= a < kw and 0 <= b + 1 < kw else 0.0
            kym = kern[a - 1, b] if 0 <= a - 1 < kw and 0 <= b < kw else 0.0
            kyp = kern[a + 1, b] if 0 <= a + 1 < kw and 0 <= b < kw else 0.0
            dkx = 0.5 * (kxm - kxp)
            dky = 0.5 * (kym - kyp)
            s_v += k0 * k0
            s_x += dkx * dkx
            s_y += dky * dky
            s_xy += dkx * dky
    noise_fac[0] = s_v
    noise_fac[1] = s_x
    noise_fac[2] = s_y
    noise_fac[3] = s_xy
    side = 2 * half + 3
    rside = side + 2 * rad
    raw = np.empty((rside, rside))
    integer = cx == np.floor(cx) and cy == np.floor(cy)
    icx = int(cx)
    icy = int(cy)
    fh, fw = fraw.shape
    wx = np.empty(4)
    dwx = np.empty(4)
    wy = np.empty(4)
    dwy = np.empty(4)
    out = np.empty(3)
    off = half + 1 + rad
    for a in range(rside):
        for b in range(rside):
            if integer:
                r = min(max(icy + a - off, 0), fh - 1)
                q = min(max(icx + b - off, 0), fw - 1)
                raw[a, b] = fraw[r, q]
            else:
                u = min(max(cx + b - off, 1.0), fw - 2.001)
                v = min(max(cy + a - off, 1.0), fh - 2.001)
                _sample(fimg, u, v, kind, wx, dwx, wy, dwy, False, out)
                raw[a, b] = out[0]
    # each output's sum in the kernel's order (ka, kb), the outputs of a row side by side
    # (independent sums, so the loop over b runs in SIMD lanes): the same operations
    sm = np.empty((side, side))
    acc = np.empty(side)
    for a in range(side):
        for b in range(side):
            acc[b] = 0.0
        for ka in range(kw):
            for kb in range(kw):
                k = kern[ka, kb]
                for b in range(side):
                    acc[b] += k * raw[a + ka, b + kb]
        for b in range(side):
            sm[a, b] = acc[b]
    n = 0
    for a in range(1, side - 1):
        for b in range(1, side - 1):
            fv[n] = sm[a, b]
            fx[n] = 0.5 * (sm[a, b + 1] - sm[a, b - 1])
            fy[n] = 0.5 * (sm[a + 1, b] - sm[a - 1, b])
            n += 1


@numba.njit(cache=True, fastmath=_FM, error_model="numpy")
def _template(fimg, fraw, cx, cy, half, kind, fv, fx, fy, hmat, blur, noise_fac):
    """Sample the template patch and its gradients; accumulate H = sum j j^T.

    At an integer centre the pixels are read directly and the gradients are central
    differences (they only steer the iterations; the final step uses exact gradients).
    """
    integer = cx == np.floor(cx) and cy == np.floor(cy)
    icx = int(cx)
    icy = int(cy)
    wx = np.empty(4)
    dwx = np.empty(4)
    wy = np.empty(4)
    dwy = np.empty(4)
    out = np.empty(3)
    jv = np.empty(8)
    # H summed in a local array (``hmat`` may alias the images as far as the compiler
    # knows, which kept every partial sum in memory), the same operations in order
    h = np.zeros((8, 8))
    smoothed = blur[0] + blur[2] > 0.0
    noise_fac[0] = 1.0
    noise_fac[1] = 0.5
    noise_fac[2] = 0.5
    noise_fac[3] = 0.0
    if smoothed:
        _blurred_template(fimg, fraw, cx, cy, half, kind, blur, fv, fx, fy, noise_fac)
    n = 0
    for iy in range(-half, half + 1):
        for ix in range(-half, half + 1):
            if smoothed:
                out[0] = fv[n]
                out[1] = fx[n]
                out[2] = fy[n]
            elif integer:
                r = icy + iy
                q = icx + ix
                out[0] = fraw[r, q]
                out[1] = 0.5 * (fraw[r, q + 1] - fraw[r, q - 1])
                out[2] = 0.5 * (fraw[r + 1, q] - fraw[r - 1, q])
            else:
                _sample(fimg, cx + ix, cy + iy, kind, wx, dwx, wy, dwy, True, out)
            fv[n] = out[0]
            fx[n] = out[1]
            fy[n] = out[2]
            _affine_row(jv, out[1], out[2], ix, iy, out[0])
            for i in range(8):
                for j in range(i + 1):
                    h[i, j] += jv[i] * jv[j]
            n += 1
    for i in range(8):
        for j in range(i + 1):
            hmat[i, j] = h[i, j]
    for i in range(8):
        for j in range(i + 1, 8):
            hmat[i, j] = hmat[j, i]


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


#: Tukey biweight's tuning constant: 95 % asymptotic efficiency at Gaussian residuals
#: (Holland & Welsch 1977 [6]_); the residuals are measured in their robust scale.
TUKEY_C = 4.685
#: 1 / Φ⁻¹(3/4): the median absolute residual of a Gaussian over its σ.
_MAD_TO_SIGMA = 1.4826
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


@numba.njit(cache=True, inline="always", fastmath=_FM, error_model="numpy")
def _forward(lo, b, m, z):
    """z = lo⁻¹ b (forward substitution only): then bᵀH⁻¹b' = z·z' for H = lo loᵀ."""
    for i in range(m):
        s = b[i]
        for k in range(i):
            s -= lo[i, k] * z[k]
        z[i] = s / lo[i, i]


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


@numba.njit(cache=True, fastmath=_FM, error_model="numpy")
def _solve_point(fimg, fraw, gimg, centre, approx, init, q, direction, constrained, half,
                 kind, exact_final, max_iter, tol, max_shift, det_min, min_texture,
                 grad_noise_var, step_noise_var, offset, blur, robust, robust_floor,
                 min_corr, p_out, cov_out, wcov_out, acov_out, sig0_out, corr_out):
    """Gauss-Newton LSM for one patch; returns (status, iterations, converged).

    ``robust``: after convergence, the robust adjustment (:func:`_robust_support`,
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
    # texture: smallest eigenvalue of the mean structure tensor, against the gradient
    # noise of the (smoothed) template (nfac[1] + nfac[2] = 1 unsmoothed)
    sxx = hmat[0, 0] / npix
    syy = hmat[3, 3] / npix
    sxy = hmat[0, 3] / npix
    lam_min = 0.5 * (sxx + syy) - np.sqrt(0.25 * (sxx - syy) ** 2 + sxy * sxy)
    if not lam_min > min_texture * (nfac[1] + nfac[2]):
        return 7, 0, False
    d = direction
    p = np.empty(8)
    for k in range(8):
        p[k] = init[k]
    hlo = np.empty((8, 8))
    h_spd = constrained > 0 or _cholesky_factor(hmat, 8, hlo)
    pm = np.empty((8, 8))
    m = _basis(d, constrained, pm)
    tmat = np.empty((8, 8))
    tt = np.empty((8, 8))
    nmat = np.empty((8, 8))
    nred = np.empty((8, 8))
    c = np.empty(8)
    rhs = np.empty(8)
    bred = np.empty(8)
    xred = np.empty(8)
    delta = np.empty(8)
    stats = np.empty(6)
    converged = False
    it = 0
    status = 0
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
            converged = True
            break
    det = p[1] * p[5] - p[2] * p[4]
    if not (det > det_min and det < 1.0 / det_min and p[7] > det_min):
        status = 4
    if not _inside(p, q, half, gw, gh):
        return 6, it, converged
    wts = np.ones(npix)
    vres = np.empty(npix)
    sw = float(npix)
    # the robust adjustment also from an unconverged equal-weight solution: across a
    # depth edge the equal-weight iterations often oscillate between the two motions
    # (where it finds no support -- no convergence, a pull-in, a support without the
    # reported pixel -- the equal-weight solution and its own tests stand)
    use_robust = robust and not exact_final and status == 0
    if use_robust:
        p_equal = p.copy()
        code = _robust_support(gimg, p, q, half, kind, fv, fx, fy, hmat, approx, pm, m,
                               tol, max_shift, robust_floor, step_noise_var, offset, wts,
                               vres)
        if code == 0 and _support_holds(wts, half, offset):
            converged = True
        else:
            use_robust = False
            for i in range(8):
                p[i] = p_equal[i]
            for n in range(npix):
                wts[n] = 1.0
    if exact_final:
        # final exact forward-additive step: its normal matrix gives the covariance
        _exact_normals(gimg, p, q, half, kind, fv, nmat, rhs, stats)
        m = _reduce(nmat, rhs, pm, m, nred, bred)
        if not _cholesky_solve(nred, bred, m, xred):
            return 7, it, False
        _expand(xred, pm, m, delta)
        vtv = stats[0]
        for i in range(m):
            vtv -= xred[i] * bred[i]  # linearised residual after the step
        for i in range(8):
            p[i] += delta[i]
    else:
        # final linearisation with the template-gradient Jacobian J = T(p) j
        if not _mixing(p, tmat):
            return 4, it, False
        _residual_stats(gimg, p, q, half, kind, fv, stats, vres)
        if use_robust:
            # the sums over the support: H_w = Σ w j jᵀ replaces the template's H
            _weighted_normals(fv, fx, fy, vres, wts, half, hmat, c)
            sw = _weighted_stats(fv, vres, p, wts, npix, stats)
            corr_out[1] = (hmat[0, 0] + hmat[3, 3]) / sw
        corr_out[3] = sw / npix
        _ic_normals(tmat, hmat, tt, nmat)
        for i in range(8):
            rhs[i] = 0.0
        m = _reduce(nmat, rhs, pm, m, nred, bred)
        vtv = stats[0]
    for i in range(8):
        p_out[i] = p[i]
    sig0sq = max(vtv, 0.0) / (sw - m)
    sig0_out[0] = np.sqrt(sig0sq)
    # correlation coefficient of template and resampled search patch
    sf = stats[1] / sw
    sg = stats[2] / sw
    vf = stats[3] / sw - sf * sf
    vg = stats[4] / sw - sg * sg
    cfg = stats[5] / sw - sf * sg
    corr = cfg / np.sqrt(vf * vg) if vf > 0.0 and vg > 0.0 else 0.0
    if not exact_final and converged and status == 0 and corr >= min_corr:
        # only a window that can pass is judged by its step score (the populations and
        # the test take the accepted ones): one the kernel rejects, or whose correlation
        # the driver's test rejects, skips it (~1/6 of a window's time)
        split = np.empty(2, np.int64)
        corr_out[2] = _step_score(fv, fx, fy, vres, wts, sw, half, 2 * (2 * half + 1),
                                  hmat, step_noise_var, split)
    # covariance of the shift unknown(s): sigma0^2 Nc^-1 with Nc the normal matrix less
    # the expected template-noise part (Nc = N without correction)
    ncred = np.empty((8, 8))
    if grad_noise_var > 0.0 and not exact_final:
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
        _ic_normals(tmat, hc, tt, nmat)
        _reduce(nmat, rhs, pm, m, ncred, bred)
    else:
        for i in range(m):
            for j in range(m):
                ncred[i, j] = nred[i, j]
    # the warped pixel (u, v) = (a0 + a1 ox + a2 oy, b0 + b1 ox + b2 oy) (+ fixed terms):
    # its gradients g_u, g_v in the (reduced) unknowns, covariance sigma0^2 g^T Nc^-1 g
    # rows 0-1: the centre (o = 0), rows 2-3: the pixel at ``offset``
    ox = offset[0]
    oy = offset[1]
    # (in the 8 parameters, then through the basis: grads = g_full pm)
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
            return 7, it, False
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
    # the affine unknowns a0 a1 a2 b0 b1 b2 as rows of the (reduced) unknowns:
    # sigma0^2 G Nc^-1 G^T
    gaff = np.zeros((6, 8))
    for k in range(6):
        for i in range(m):
            gaff[k, i] = pm[k, i]
    xa = np.zeros((6, 8))
    nlo = np.empty((8, 8))
    if not _cholesky_factor(ncred, m, nlo):
        return 7, it, False
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
