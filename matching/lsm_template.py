"""The template of an LSM window (:mod:`matching.lsm_kernels`): its values, gradients and
H = Σ j jᵀ, optionally smoothed by the footprint Gaussian (:func:`_blurred_template`).
"""

from __future__ import annotations

import numba
import numpy as np

from matching.lsm_interp import _FM, _sample

#: Largest radius of the template's footprint smoothing (``lsm_match``'s
#: ``footprint_var``), px: a Gaussian of σ up to 4/3 px is sampled to 3σ.
_MAX_BLUR_RADIUS = 4


@numba.njit(cache=True, fastmath=_FM, error_model="numpy")
def _footprint_kernel(blur, noise_fac):
    """The sampled, normalised Gaussian of covariance ``blur`` (sxx, sxy, syy), px², on
    (2R + 1)² taps, R = ceil(3 σ_max) (at most ``_MAX_BLUR_RADIUS``); returns (kernel, R).

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
    return kern, rad


@numba.njit(cache=True, fastmath=_FM, error_model="numpy")
def _blurred_template(fimg, fraw, cx, cy, half, kind, blur, fv, fx, fy, noise_fac):
    """The template smoothed by the Gaussian of covariance ``blur`` (sxx, sxy, syy), px².

    The raw template (pixels read directly at an integer centre, clamped at the image
    border, else B-spline samples) on the patch grid plus a border of 1 + R px, is
    convolved with :func:`_footprint_kernel`'s Gaussian (``noise_fac`` from it); values
    and central differences of the result fill ``fv fx fy``.
    """
    kern, rad = _footprint_kernel(blur, noise_fac)
    kw = 2 * rad + 1
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
            n += 1
    # H = Σ j jᵀ (its lower triangle) in 36 scalar sums over the pixels in order: the
    # operations of :func:`_affine_row`'s row and ``h[i, j] += j_i j_j``, in registers
    h00 = h10 = h11 = h20 = h21 = h22 = h30 = h31 = h32 = h33 = h40 = h41 = 0.0
    h42 = h43 = h44 = h50 = h51 = h52 = h53 = h54 = h55 = h60 = h61 = h62 = 0.0
    h63 = h64 = h65 = h66 = h70 = h71 = h72 = h73 = h74 = h75 = h76 = h77 = 0.0
    n = 0
    for iy in range(-half, half + 1):
        for ix in range(-half, half + 1):
            j0 = fx[n]
            j1 = j0 * ix
            j2 = j0 * iy
            j3 = fy[n]
            j4 = j3 * ix
            j5 = j3 * iy
            j6 = 1.0
            j7 = fv[n]
            h00 += j0 * j0
            h10 += j1 * j0
            h11 += j1 * j1
            h20 += j2 * j0
            h21 += j2 * j1
            h22 += j2 * j2
            h30 += j3 * j0
            h31 += j3 * j1
            h32 += j3 * j2
            h33 += j3 * j3
            h40 += j4 * j0
            h41 += j4 * j1
            h42 += j4 * j2
            h43 += j4 * j3
            h44 += j4 * j4
            h50 += j5 * j0
            h51 += j5 * j1
            h52 += j5 * j2
            h53 += j5 * j3
            h54 += j5 * j4
            h55 += j5 * j5
            h60 += j6 * j0
            h61 += j6 * j1
            h62 += j6 * j2
            h63 += j6 * j3
            h64 += j6 * j4
            h65 += j6 * j5
            h66 += j6 * j6
            h70 += j7 * j0
            h71 += j7 * j1
            h72 += j7 * j2
            h73 += j7 * j3
            h74 += j7 * j4
            h75 += j7 * j5
            h76 += j7 * j6
            h77 += j7 * j7
            n += 1
    h[0, 0] = h00
    h[1, 0] = h10
    h[1, 1] = h11
    h[2, 0] = h20
    h[2, 1] = h21
    h[2, 2] = h22
    h[3, 0] = h30
    h[3, 1] = h31
    h[3, 2] = h32
    h[3, 3] = h33
    h[4, 0] = h40
    h[4, 1] = h41
    h[4, 2] = h42
    h[4, 3] = h43
    h[4, 4] = h44
    h[5, 0] = h50
    h[5, 1] = h51
    h[5, 2] = h52
    h[5, 3] = h53
    h[5, 4] = h54
    h[5, 5] = h55
    h[6, 0] = h60
    h[6, 1] = h61
    h[6, 2] = h62
    h[6, 3] = h63
    h[6, 4] = h64
    h[6, 5] = h65
    h[6, 6] = h66
    h[7, 0] = h70
    h[7, 1] = h71
    h[7, 2] = h72
    h[7, 3] = h73
    h[7, 4] = h74
    h[7, 5] = h75
    h[7, 6] = h76
    h[7, 7] = h77
    for i in range(8):
        for j in range(i + 1):
            hmat[i, j] = h[i, j]
    for i in range(8):
        for j in range(i + 1, 8):
            hmat[i, j] = hmat[j, i]
