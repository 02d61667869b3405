r"""Adaptive least-squares correlation (Gruen 1985), batched over all patches.

For every pixel :math:`(x, y)` of a square template patch centred on a point of
the template image :math:`f`, the observation equation is

.. math::

    f(x, y) - e(x, y) = r_0 + r_1\, g(a_0 + a_1 x + a_2 y,\; b_0 + b_1 x + b_2 y)

with :math:`(x, y)` in pixels relative to the template centre, six affine
unknowns :math:`a_0 \ldots b_2`, two radiometric unknowns (offset
:math:`r_0`, gain :math:`r_1`) and the search image :math:`g` resampled at the
warped position.  :math:`(a_0, b_0)` is therefore the position of the template
centre in the search image.  The system is linearised and solved by
Gauss-Newton until the shift update :math:`\lVert(\delta a_0, \delta b_0)\rVert`
is below ``TOL.lsm_shift_stop_px`` or ``max_iter`` is reached.  The precision
of the match is :math:`\sigma_0^2 (A^\mathsf{T}A)^{-1}` with
:math:`\sigma_0^2 = v^\mathsf{T}v / (n - u)` from the final linearisation.

Jacobian.  The iterations use the *template-gradient* Jacobian (the idea behind
inverse-compositional alignment, Baker & Matthews 2004): at the solution
:math:`r_1 \nabla g(W(x)) = A^{-\mathsf{T}} \nabla f(x)` and
:math:`g(W(x)) = (f - r_0)/r_1`, so the Jacobian is a fixed 8x8 mixing
:math:`J = T(p)\,j` of template quantities :math:`j = [f_x, f_x x, f_x y, f_y,
f_y x, f_y y, 1, f]` whose normal matrix :math:`H = \sum j j^\mathsf{T}` is
computed and factored once per patch; an iteration only resamples :math:`g`
(values, no gradients), accumulates :math:`\sum j\,v` and solves
:math:`\delta = T^{-\mathsf{T}} H^{-1} \sum j v` in closed form.  The
reported precision is :math:`\sigma_0^2 (J^\mathsf{T}J)^{-1}` of that final
linearisation, :math:`J^\mathsf{T}J = T H T^\mathsf{T}` (``jacobian="template"``,
default).  ``jacobian="search"`` adds Gruen's textbook final step, one exact
forward-additive Gauss-Newton step with the resampled search-image gradients,
and reports :math:`\sigma_0^2 (A^\mathsf{T}A)^{-1}` of that step.  Measured
(Monte Carlo: 300 noise draws on 3 patches of a 15-grey-level texture; 120 in
``tests/matching/test_lsm.py``): with
noise in the search image the search-gradient solution errs 1.5-2.3x its
reported σ and 20-30 % more than the template-gradient one, whose σ is right
within 5 %: the noise of the resampled gradients correlates with the resampled
residual (the bias of gradient-based registration, Robinson & Milanfar 2004),
while a central-difference template gradient is independent of the residual
at its own pixel.  All patches run in one numba ``prange`` kernel.

Real images.  Where the search view is foreshortened its pixels cover more than one
template pixel, and the template holds detail the search image lacks; ``footprint_var``
smooths the template by the Gaussian of the two footprints' difference,
:math:`c\,(A^{-1}A^{-\mathsf{T}} - I)_+` (shape-adapted smoothing, Lindeberg & Gårding
1997 [5]_), inside the kernel.  The σ0 test (``sigma0_model="gradient"``) predicts each
window's σ0 from its texture, :math:`\sigma_0^2 = \alpha + \beta\,\overline{|\nabla f|^2}`
(a residual misregistration δ of the texture leaves :math:`v \approx \delta\cdot\nabla f`),
fitted to the population (:func:`sigma0_gradient_model`).

Depth edges.  A window across a depth edge holds two motions; a large jump leaves a
residual the σ0 test rejects, a small one (a fraction of a pixel, or any jump where a
blur difference or real images' model error already raises every σ0) moves the match to
a compromise of the two motions, many σ from the centre pixel's own.  The motion-step
test looks for that structure in the residual: for each line splitting the window (4
orientations, every offset leaving two rows of pixels on either side) the score test of
one extra unknown, a shift of one side, with the 8 template columns and a blur
difference (the template's Laplacian) projected out (:func:`_step_score`;
``LSMResult.step_score`` is the largest over the lines, ~χ²(2) each under one motion).
Measured on rendered two-plane pairs (``tests/matching/test_lsm.py``): a 0.5 px step
with a 0.7 px blur between the views, 93 -> 12 windows across the edge beyond 3σ; a
0.2 px step without blur scores 14-25 (median by distance to the edge) against a null
median of 8.5 and a limit of 30, and stays (its windows err up to half the step,
median 3-7σ): the test's detection limit.  A straight edge between uniform regions
(the aperture problem) is rejected as textureless; with weak texture (4 grey levels) it
is accepted with σ along the edge ~10x σ across it, both right (errors 1.15 and 1.08
of their σ RMS: the full covariance ``cov``; ``sigma`` is their RMS).

Robust adjustment (``robust``).  Equal-weight least squares lets the pixels of a window
that do not follow its warp (another surface across a depth edge) pull the match.  From
the equal-weight solution, the line the motion-step test finds most likely to split two
motions gives the start: least squares over the reported pixel's side of it (from the
equal-weight compromise Tukey's weights would not move, every pixel misfitting alike).
Then iteratively reweighted least squares with Tukey's biweight [6]_, c = 4.685 (95 %
efficiency at Gaussian residuals) times the residuals' robust scale 1.4826 median|v|
(never below the two images' noise), and a pixel needs 5 of its 3 x 3 neighbourhood
weighted (another surface's uncorrelated texture fits by chance in scattered pixels).
The final *support* is the weighted pixels less those 4-adjacent to an unweighted one
(boundary pixels mix both surfaces), connected to the reported pixel; least squares over
it gives the match, σ0² = vᵀWv / (Σw - u) and N = Jᵀ W J (the template-noise correction
over the support), so that σ is the support's own.  A support without the reported
pixel, or under half the window, or a failed iteration: the equal-weight solution and
its tests stand.  Measured on rendered two-plane pairs (``tests/matching/test_robust_lsm.py``):
windows across a 3.7 px edge whose centre lies >= 3 px from it, median error 0.296 ->
0.012 px; accepted across the edge 0 -> 187 of 266, 1 beyond 3σ (3.09σ); windows clear
of the edge unchanged (within 0.2σ).

References
----------
.. [1] A. W. Gruen, "Adaptive least squares correlation: a powerful image
   matching technique", South African Journal of Photogrammetry, Remote
   Sensing and Cartography 14(3), 175-187 (1985).
.. [2] S. Baker, I. Matthews, "Lucas-Kanade 20 years on: a unifying
   framework", IJCV 56(3), 221-255 (2004).
.. [3] J. Immerkaer, "Fast noise variance estimation", Computer Vision and
   Image Understanding 64(2), 300-302 (1996).
.. [4] D. Robinson, P. Milanfar, "Fundamental performance limits in image
   registration", IEEE Trans. Image Processing 13(9), 1185-1199 (2004).
.. [5] T. Lindeberg, J. Gårding, "Shape-adapted smoothing in estimation of 3-D shape
   cues from affine deformations of local 2-D brightness structure", Image and Vision
   Computing 15(6), 415-434 (1997).
.. [6] P. W. Holland, R. E. Welsch, "Robust regression using iteratively reweighted
   least-squares", Communications in Statistics - Theory and Methods 6(9), 813-827
   (1977).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

import numba
import numpy as np
from scipy import ndimage

from matching.validate import TOL, check_shape

# The TBB layer numba tries first is too old here and warns; OpenMP works on every
# platform numba wheels ship for, the work queue is the fallback.
numba.config.THREADING_LAYER_PRIORITY = ["omp", "workqueue", "tbb"]


class Status(IntEnum):
    """Why a point was accepted or rejected (``LSMResult.status``)."""

    #: accepted
    OK = 0
    #: no shift update below the stop threshold within ``max_iter`` (or NaN)
    NO_CONVERGENCE = 1
    #: residual σ0 an outlier of the σ0 distribution (or above ``sigma0_factor`` x reference)
    SIGMA0_TOO_LARGE = 2
    #: the solution moved farther than ``max_shift_px`` from the approximation
    PULL_IN = 3
    #: det of the affine part outside [affine_det_min, 1/affine_det_min]
    DEGENERATE_AFFINE = 4
    #: correlation coefficient below ``min_correlation``
    LOW_CORRELATION = 5
    #: template or warped search patch (plus interpolation support) leaves the image
    OUTSIDE_IMAGE = 6
    #: template gradient energy not above the noise's (or singular normal matrix)
    TEXTURELESS = 7
    #: the residual holds a motion step: one part of the window moves against the rest
    #: (a depth edge), ``LSMResult.step_score`` above ``step_limit`` (codes 8-10 are
    #: :mod:`matching.pair`'s)
    TWO_MOTIONS = 11


#: ``status code -> name`` for every value :class:`Status` takes.
STATUS_NAMES = {int(s): s.name.lower() for s in Status}

INTERPOLATIONS = ("bilinear", "bicubic", "spline")
_KIND = {"bilinear": 0, "bicubic": 1, "spline": 2}
#: Default resampling: the cubic B-spline (see ``benchmarks/matching.py``: its
#: zero-noise bias is ~4x below bilinear's for ~1.3x the time).
DEFAULT_INTERPOLATION = "spline"


@dataclass(frozen=True)
class LSMResult:
    """Per-point output of :func:`lsm_match` (arrays over the N points).

    Attributes
    ----------
    position : (N, 2) float64
        Matched position of the template centre (or of the eccentric template pixel
        ``lsm_match``'s ``offset`` names) in the search image, px.
    affine : (N, 6) float64
        ``a0 a1 a2 b0 b1 b2`` (``a0, b0``: the template centre's position).
    radiometric : (N, 2) float64
        ``r0`` (offset, grey levels), ``r1`` (gain).
    converged : (N,) bool
        Gauss-Newton met the shift stop threshold.
    iterations : (N,) int32
        Gauss-Newton iterations used (the final exact step included).
    sigma0 : (N,) float64
        A-posteriori σ of unit weight, grey levels.
    cov : (N, 2, 2) float64
        Covariance of ``position``, px².
    correlation : (N,) float64
        Correlation coefficient of template and resampled search patch.
    status : (N,) uint8
        :class:`Status` code (``STATUS_NAMES`` gives the names).
    noise_sigma0 : float
        The reference σ0 the ``SIGMA0_TOO_LARGE`` test used, grey levels.
    window_cov : (N, 2, 2) float64 or None
        With eccentric windows (``lsm_match``'s ``offset``): the covariance of the
        window centre's shift, px² (the window's own precision, before the transfer to
        the offset pixel); None: ``cov`` is the centre's.
    affine_cov : (N, 6, 6) float64 or None
        Covariance of ``affine`` (``a0 a1 a2 b0 b1 b2``; px², px, 1), the same
        σ0² Nc⁻¹ as ``cov`` (rank 5 with an epipolar constraint): the warp's precision
        away from the centre (:func:`matching.precision.midpoint_variance_factor`).
    grad_power : (N,) float64 or None
        The template's mean gradient power (|∇f|² averaged over the window, of the
        smoothed template with ``footprint_var``), grey levels²/px²: what the σ0 test's
        ``sigma0_model="gradient"`` predicts σ0 from.
    step_score : (N,) float64 or None
        The motion-step test's statistic (module docstring, :func:`_step_score`): the
        largest score, over the lines splitting the window, of a shift of one side
        against the other, in units of the residual variance (NaN with
        ``jacobian="search"``, where no solution was reached, and where the kernel
        rejected the window: not converged, degenerate affine).
    support : (N,) float64 or None
        Robust LSM (``lsm_match``'s ``robust``): the share of the window's pixels in the
        final support; NaN where the equal-weight solution stands (not robust, or no
        support found).
    """

    position: np.ndarray
    affine: np.ndarray
    radiometric: np.ndarray
    converged: np.ndarray
    iterations: np.ndarray
    sigma0: np.ndarray
    cov: np.ndarray
    correlation: np.ndarray
    status: np.ndarray
    noise_sigma0: float
    window_cov: np.ndarray | None = None
    affine_cov: np.ndarray | None = None
    grad_power: np.ndarray | None = None
    step_score: np.ndarray | None = None
    support: np.ndarray | None = None

    @property
    def accepted(self) -> np.ndarray:
        """(N,) bool: status OK."""
        return self.status == Status.OK

    @property
    def sigma(self) -> np.ndarray:
        """(N,) float64: RMS of the two position σ's, sqrt(trace(cov)/2), px."""
        return np.sqrt(np.maximum(np.trace(self.cov, axis1=1, axis2=2), 0.0) / 2.0)

    @property
    def window_sigma(self) -> np.ndarray:
        """(N,) float64: :attr:`sigma` of the window centre (= ``sigma`` without
        eccentric windows), px: the matching precision the texture gives."""
        cov = self.cov if self.window_cov is None else self.window_cov
        return np.sqrt(np.maximum(np.trace(cov, axis1=1, axis2=2), 0.0) / 2.0)


# --------------------------------------------------------------------------------------
# numba kernels
# --------------------------------------------------------------------------------------

#: fast-math without "no NaN / no inf", so the NaN checks stay meaningful, and without
#: "reassoc" and "contract": with them a kernel compiled in the process and the same
#: kernel loaded from numba's cache gave results different in the last bits (the
#: cloud then differed between a first run and the next ones); the same CPU time without
_FM = {"nsz", "arcp", "afn"}
#: Default pixel footprint variance of ``lsm_match``'s ``footprint_var``, px² per axis.
#: Measured, not derived: a box pixel alone has 1/12, but the smoothing also takes the
#: weight off the band the foreshortened view aliases, and every case measured is best
#: near 0.25 (flat from 0.2 to 0.33; one sweep on 2026-12-02, the value changed by hand
#: in benchmarks/_real_matching.py -- no benchmark row repeats it): graffiti (21x21,
#: first pass, the wall) residual to
#: the smooth mapping 0.227 px without, 0.218 / 0.195 / 0.182 / 0.187 at 1/12 / 0.15 /
#: 0.25 / 0.33; graf1 re-rendered through the homography (box pixels) 0.134 px without,
#: 0.107 / 0.076 / 0.074 / 0.083; two box-pixel cameras 0.55x foreshortened
#: (``tests/matching/test_lsm.py``) 0.0136 -> 0.0104 px at 0.25, 1/12 nearly nothing.
DEFAULT_FOOTPRINT_VAR = 0.25
#: Largest radius of the template's footprint smoothing (``lsm_match``'s
#: ``footprint_var``), px: a Gaussian of σ up to 4/3 px is sampled to 3σ.
_MAX_BLUR_RADIUS = 4

# --------------------------------------------------------------------------------------
# --------------------------------------------------------------------------------------


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
    """T(p): template-gradient Jacobian J = T j (module docstring); False if det(A) ~ 0."""
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
    sm = np.empty((side, side))
    for a in range(side):
        for b in range(side):
            acc = 0.0
            for ka in range(kw):
                for kb in range(kw):
                    acc += kern[ka, kb] * raw[a + ka, b + kb]
            sm[a, b] = acc
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
    for i in range(8):
        for j in range(8):
            hmat[i, j] = 0.0
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
                    hmat[i, j] += jv[i] * jv[j]
            n += 1
    for i in range(8):
        for j in range(i + 1, 8):
            hmat[i, j] = hmat[j, i]


@numba.njit(cache=True, fastmath=_FM, error_model="numpy")
def _ic_rhs(gimg, p, q, half, kind, fv, fx, fy, c):
    """c = sum j v over the patch with v = f - r0 - r1 g(W(x)) (values only)."""
    wx = np.empty(4)
    dwx = np.empty(4)
    wy = np.empty(4)
    dwy = np.empty(4)
    out = np.empty(3)
    for i in range(8):
        c[i] = 0.0
    n = 0
    # without second-order terms (most windows) the warp is affine: the same values
    # (the zero terms added nothing) for fewer operations in every iteration
    flat = (q[0] == 0.0 and q[1] == 0.0 and q[2] == 0.0 and q[3] == 0.0 and q[4] == 0.0
            and q[5] == 0.0)
    for iy in range(-half, half + 1):
        for ix in range(-half, half + 1):
            if flat:
                u = p[0] + p[1] * ix + p[2] * iy
                v = p[3] + p[4] * ix + p[5] * iy
            else:
                u = (p[0] + p[1] * ix + p[2] * iy + q[0] * ix * ix + q[1] * ix * iy
                     + q[2] * iy * iy)
                v = (p[3] + p[4] * ix + p[5] * iy + q[3] * ix * ix + q[4] * ix * iy
                     + q[5] * iy * iy)
            _sample(gimg, u, v, kind, wx, dwx, wy, dwy, False, out)
            res = fv[n] - p[6] - p[7] * out[0]
            rx = fx[n] * res
            ry = fy[n] * res
            c[0] += rx
            c[1] += rx * ix
            c[2] += rx * iy
            c[3] += ry
            c[4] += ry * ix
            c[5] += ry * iy
            c[6] += res
            c[7] += fv[n] * res
            n += 1


@numba.njit(cache=True, fastmath=_FM, error_model="numpy")
def _residual_stats(gimg, p, q, half, kind, fv, stats, vres):
    """stats = [vtv, sf, sg, sff, sgg, sfg] at p (values only); the residuals into vres."""
    wx = np.empty(4)
    dwx = np.empty(4)
    wy = np.empty(4)
    dwy = np.empty(4)
    out = np.empty(3)
    for i in range(6):
        stats[i] = 0.0
    n = 0
    for iy in range(-half, half + 1):
        for ix in range(-half, half + 1):
            u = p[0] + p[1] * ix + p[2] * iy + q[0] * ix * ix + q[1] * ix * iy + q[2] * iy * iy
            v = p[3] + p[4] * ix + p[5] * iy + q[3] * ix * ix + q[4] * ix * iy + q[5] * iy * iy
            _sample(gimg, u, v, kind, wx, dwx, wy, dwy, False, out)
            gval = out[0]
            res = fv[n] - p[6] - p[7] * gval
            vres[n] = res
            stats[0] += res * res
            stats[1] += fv[n]
            stats[2] += gval
            stats[3] += fv[n] * fv[n]
            stats[4] += gval * gval
            stats[5] += fv[n] * gval
            n += 1


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
    Gaussian residuals).  Returns 0, or the :class:`Status` code of a failure (1: no
    convergence, 3: pull-in, 4: degenerate, 6: outside, 7: singular).
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
                 grad_noise_var, step_noise_var, offset, blur, robust, robust_floor, p_out,
                 cov_out, wcov_out, acov_out, sig0_out, corr_out):
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
            # delta = T^{-T} H^{-1} c, with T^{-T} in closed form (module docstring)
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
    if not exact_final and converged and status == 0:
        # only a window the kernel accepts is judged by its step score (the populations
        # and the test take the accepted ones): the rest skip its ~1/6 of the kernel
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
    sf = stats[1] / sw
    sg = stats[2] / sw
    vf = stats[3] / sw - sf * sf
    vg = stats[4] / sw - sg * sg
    cfg = stats[5] / sw - sf * sg
    corr_out[0] = cfg / np.sqrt(vf * vg) if vf > 0.0 and vg > 0.0 else 0.0
    if (p[0] - approx[0]) ** 2 + (p[3] - approx[1]) ** 2 > max_shift * max_shift:
        return 3, it + 1, converged
    if not converged:
        return 1, it + 1, False
    return status, it + 1, converged


@numba.njit(parallel=True, nogil=True, cache=True, fastmath=_FM, error_model="numpy")
def _lsm_batch(fimg, fraw, gimg, centres, approx, init, quad, directions, constrained, half,
               kind, exact_final, max_iter, tol, max_shift, det_min, min_texture,
               grad_noise_var, step_noise_var, offsets, blurs, robust, robust_floor, params,
               cov, wcov, acov, sigma0, corr, status, iters, conv):
    n = centres.shape[0]
    for i in numba.prange(n):
        s, it, cv = _solve_point(fimg, fraw, gimg, centres[i], approx[i], init[i], quad[i],
                                 directions[i], constrained, half, kind, exact_final,
                                 max_iter, tol,
                                 max_shift, det_min, min_texture, grad_noise_var,
                                 step_noise_var, offsets[i], blurs[i], robust[i],
                                 robust_floor, params[i], cov[i],
                                 wcov[i], acov[i], sigma0[i:i + 1], corr[i])
        status[i] = s
        iters[i] = it
        conv[i] = cv


# --------------------------------------------------------------------------------------
# public API
# --------------------------------------------------------------------------------------


#: Block side of :func:`estimate_noise`'s flat-block estimate, px.
NOISE_BLOCK_PX = 16
#: Quantile of the block estimates taken as the noise (the flattest tenth).
NOISE_BLOCK_QUANTILE = 0.10
#: Relative spread of one block's Immerkaer estimate on white noise, times the block
#: side (Monte Carlo, 5 draws of 800x640 Gaussian noise: 1.37 at 16, 24 and 32 px);
#: the quantile of the block estimates is divided by 1 - z_q * this / side
#: (z_0.1 = 1.2816: 0.890 at 16 px, measured 0.890).
_NOISE_BLOCK_SPREAD = 1.37
#: Fewer unsaturated blocks than this: the global estimate alone.
_NOISE_MIN_BLOCKS = 20


def _immerkaer_abs(img: np.ndarray) -> np.ndarray:
    """|I * N| over the interior, N = [[1,-2,1],[-2,4,-2],[1,-2,1]], (H-2, W-2)."""
    return np.abs(img[:-2, :-2] - 2 * img[:-2, 1:-1] + img[:-2, 2:]
                  - 2 * img[1:-1, :-2] + 4 * img[1:-1, 1:-1] - 2 * img[1:-1, 2:]
                  + img[2:, :-2] - 2 * img[2:, 1:-1] + img[2:, 2:])


def estimate_noise(image: np.ndarray, flat_blocks: bool = True) -> float:
    """Image noise σ (grey levels) by Immerkaer's Laplacian-difference estimator [3]_.

    Immerkaer's σ = sqrt(π/2) / (6 (W-2)(H-2)) Σ |I * N| counts texture as noise: on
    a textured photograph it is an upper bound far above the noise (graffiti
    ``graf1.png``: 2.61 grey levels over the whole image, against 1.2-1.4 in its
    flattest tenth of 21x21 windows), and every threshold derived from it (the texture
    test, the noise correction of the covariance) then rejects real texture.  With
    ``flat_blocks`` (default) the estimate is taken where the texture adds least: the
    same estimator over ``NOISE_BLOCK_PX`` blocks, the 10th percentile of the blocks
    (corrected for the spread of a block estimate on pure noise, so that a noise image
    gives σ; where only a share s of the blocks is flat it is the (0.1/s)-th quantile of
    the flat ones, up to 1.11σ at s = 0.1), never above the global value.  Blocks
    holding a saturated pixel (the image's minimum or maximum value) are left out:
    clipping removes noise.

    Parameters
    ----------
    image : (H, W) array_like
        Grey image.
    flat_blocks : bool
        Use the flattest blocks (default); False: the global estimate.

    Returns
    -------
    float
        σ, grey levels.
    """
    img = np.asarray(image, dtype=np.float64)
    if img.ndim != 2 or min(img.shape) < 3:
        raise ValueError(f"image must be a 2-D array of at least 3x3, got shape {img.shape}")
    lap = _immerkaer_abs(img)
    scale = np.sqrt(np.pi / 2.0) / 6.0
    overall = float(scale * lap.mean())
    b = NOISE_BLOCK_PX
    ny, nx = lap.shape[0] // b, lap.shape[1] // b
    if not flat_blocks or ny * nx < _NOISE_MIN_BLOCKS:
        return overall
    blocks = lap[:ny * b, :nx * b].reshape(ny, b, nx, b).mean(axis=(1, 3))
    inner = img[1:1 + ny * b, 1:1 + nx * b]
    lo, hi = img.min(), img.max()
    clipped = ((inner <= lo) | (inner >= hi)).reshape(ny, b, nx, b).any(axis=(1, 3))
    usable = blocks[~clipped]
    if len(usable) < _NOISE_MIN_BLOCKS:
        return overall
    z = 1.2815515655446004  # standard normal 90 % quantile
    flat = scale * float(np.quantile(usable, NOISE_BLOCK_QUANTILE))
    flat /= 1.0 - z * _NOISE_BLOCK_SPREAD / b
    return min(overall, flat)


@dataclass(frozen=True)
class PreparedImage:
    """An image ready for :func:`lsm_match`'s resampler.

    Attributes
    ----------
    values : (H, W) float64
        Pixel values, or cubic B-spline coefficients for ``interpolation == "spline"``.
    raw : (H, W) float64
        The pixel values themselves (templates at integer centres read them directly).
    noise : float
        Immerkaer noise estimate of the original image, grey levels.
    interpolation : str
        The resampler ``values`` is meant for.
    """

    values: np.ndarray
    raw: np.ndarray
    noise: float
    interpolation: str


def prepare_image(image, interpolation: str = DEFAULT_INTERPOLATION) -> PreparedImage:
    """Prepare an image once for several :func:`lsm_match` calls (prefilter + noise).

    Parameters
    ----------
    image : (H, W) array_like
        Grey image, grey levels.
    interpolation : {"bilinear", "bicubic", "spline"}
    """
    if interpolation not in _KIND:
        raise ValueError(f"interpolation must be one of {INTERPOLATIONS}, got {interpolation!r}")
    img = np.ascontiguousarray(image, dtype=np.float64)
    if img.ndim != 2:
        raise ValueError(f"image must be a 2-D grey image, got shape {img.shape}")
    noise = estimate_noise(img)
    values = img
    if interpolation == "spline":
        values = ndimage.spline_filter(img, order=3, mode="mirror", output=np.float64)
    return PreparedImage(values=values, raw=img, noise=noise, interpolation=interpolation)


def footprint_blur(initial, footprint_var: float | None) -> np.ndarray:
    """Template smoothing of :func:`lsm_match`'s ``footprint_var`` from the initial affine.

    Parameters
    ----------
    initial : (N, 8) array_like
        ``a0 a1 a2 b0 b1 b2 r0 r1`` (A = [[a1, a2], [b1, b2]], template -> search).
    footprint_var : float or None
        The pixel footprint's variance per axis, px² (None or 0: no smoothing).

    Returns
    -------
    (N, 3) float64
        ``(sxx, sxy, syy)`` of ``footprint_var`` (A⁻¹A⁻ᵀ - I), eigenvalues clipped to
        [0, (4/3)²] px² (zeros where A is singular or not finite), px².
    """
    init = np.asarray(initial, dtype=np.float64)
    out = np.zeros((len(init), 3))
    if footprint_var is None or footprint_var == 0.0:
        return out
    if not (np.isfinite(footprint_var) and footprint_var > 0):
        raise ValueError(f"footprint_var must be positive, got {footprint_var!r}")
    a = init[:, [1, 2, 4, 5]].reshape(-1, 2, 2)
    ok = np.isfinite(a).all(axis=(1, 2))
    ok[ok] = np.abs(np.linalg.det(a[ok])) > TOL.zero
    if not ok.any():
        return out
    inv = np.linalg.inv(a[ok])
    m = footprint_var * (inv @ np.swapaxes(inv, 1, 2) - np.eye(2))
    w, v = np.linalg.eigh(m)
    w = np.clip(w, 0.0, (_MAX_BLUR_RADIUS / 3.0) ** 2)
    c = (v * w[:, None, :]) @ np.swapaxes(v, 1, 2)
    out[ok] = np.column_stack([c[:, 0, 0], c[:, 0, 1], c[:, 1, 1]])
    return out


#: Median of ``LSMResult.step_score`` over correct matches with white noise (Monte Carlo:
#: 2 x 2464 windows 15x15 of test_lsm.py's noisy pair, 8.4-8.6; 99.9 % quantile 22-24).
STEP_SCORE_NULL_MEDIAN = 8.5
#: Default limit of the motion-step test (``lsm_match``'s ``step_limit``): above the
#: largest score of those 4900 correct windows (26-28; 26 at 9, 15 and 21 px).
STEP_SCORE_LIMIT = 30.0

#: Population slices of :func:`sigma0_gradient_model`'s fit (by gradient power).
_SIGMA0_MODEL_BINS = 8


def sigma0_gradient_model(sigma0, grad_power, fixed_intercept: float | None = None):
    """σ0² = α + β |∇f|² of a population of accepted matches, or None.

    A correct match leaves the noise (α: both images' σ_n², with the gain) and what the
    model does not follow -- a residual misregistration, blur or shading difference of
    the texture across the window, δ, leaves v ≈ δ·∇f, so E v² = β |∇f|² with β the
    variance of δ (px²).  On real images the second term dominates where the texture is
    strong (temple pair (0, 1): median σ0 1.8 grey levels in the weakest eighth of the
    windows by |∇f|², 16 in the strongest), so a σ0 test against one population median
    rejects the best-textured windows; against this model it rejects what the window's
    own texture does not explain.  Fit: the population sorted by |∇f|² in
    ``_SIGMA0_MODEL_BINS`` equal slices, the median σ0² and |∇f|² of each, a least-squares
    line through the slice medians with β >= 0 (α >= 1 % of the weakest slice's median
    σ0², so the prediction never vanishes); with ``fixed_intercept`` α is that.

    Parameters
    ----------
    sigma0 : (M,) array_like
        σ0 of accepted matches, grey levels.
    grad_power : (M,) array_like
        Their templates' mean |∇f|², grey levels²/px².
    fixed_intercept : float, optional
        α, grey levels² (a known noise).

    Returns
    -------
    (alpha, beta) or None
        None with fewer than 30 finite values.
    """
    s2 = np.asarray(sigma0, dtype=np.float64) ** 2
    gp = np.asarray(grad_power, dtype=np.float64)
    keep = np.isfinite(s2) & np.isfinite(gp)
    s2, gp = s2[keep], gp[keep]
    if len(s2) < 30:
        return None
    order = np.argsort(gp, kind="stable")
    slices = np.array_split(order, _SIGMA0_MODEL_BINS)
    x = np.array([np.median(gp[sl]) for sl in slices])
    y = np.array([np.median(s2[sl]) for sl in slices])
    floor = 0.01 * y[0]
    if fixed_intercept is not None:
        alpha = float(fixed_intercept)
        xx = float(np.sum(x * x))
        beta = max(float(np.sum(x * (y - alpha)) / xx), 0.0) if xx > 0 else 0.0
        return alpha, beta
    xm, ym = x.mean(), y.mean()
    sxx = float(np.sum((x - xm) ** 2))
    beta = max(float(np.sum((x - xm) * (y - ym)) / sxx), 0.0) if sxx > 0 else 0.0
    alpha = ym - beta * xm
    if alpha < floor:  # refit the slope through (0, floor)
        alpha = floor
        xx = float(np.sum(x * x))
        beta = max(float(np.sum(x * (y - alpha)) / xx), 0.0) if xx > 0 else 0.0
    if beta == 0.0:
        alpha = float(np.median(s2))
    return float(alpha), float(beta)


def step_score_limit(scores, limit: float, population=None) -> float:
    """Limit of :func:`lsm_match`'s motion-step test.

    ``limit`` x max(1, median(scores) / ``STEP_SCORE_NULL_MEDIAN``, median(population) /
    ``STEP_SCORE_NULL_MEDIAN``), each median only from 30 or more finite values: where
    the residual is not white (correlated noise, the model errors of real images) every
    window's score grows by about the same factor, which the median measures.  A batch
    is judged no more strictly than the population of accepted matches it belongs to
    (a region-growing front of a few windows on the temple would otherwise meet the bare
    limit: pair (5, 6) 44.4 -> 41.5 % accepted), nor than its own typical window (the
    fronts are harder than the seeds: judged by the population's median alone the
    synthetic graffiti wall lost 2.5 % of its windows for 0.001 px).
    """
    factor = 1.0
    for values in (scores, population):
        if values is None:
            continue
        values = np.asarray(values, dtype=np.float64)
        values = values[np.isfinite(values)]
        if len(values) >= 30:
            factor = max(factor, float(np.median(values)) / STEP_SCORE_NULL_MEDIAN)
    return float(limit) * factor


def robust_upper_limit(values: np.ndarray, k: float, dof: int) -> float:
    """``median + k·s`` of a population of σ-like values (σ0 or σ of LSM matches).

    ``s`` is the larger of the robust spread 1.4826·MAD and the spread the
    values' own estimation error gives, ``median/sqrt(2·dof)`` (the chi
    distribution of a σ estimated with ``dof`` degrees of freedom), so that a
    population whose values differ only by that error loses nothing.
    """
    values = np.asarray(values, dtype=np.float64)
    med = float(np.median(values))
    spread = max(1.4826 * float(np.median(np.abs(values - med))), med / np.sqrt(2.0 * dof))
    return med + k * spread


def lsm_match(template_image, search_image, points, approx, *, patch: int = 15,
              interpolation: str = DEFAULT_INTERPOLATION, direction=None,
              max_iter: int = 20, shift_stop_px: float | None = None,
              max_shift_px: float | None = None, noise_sigma: float | None = None,
              sigma0_factor: float = 2.5, sigma0_mad_k: float = 4.0,
              min_correlation: float = 0.7,
              min_texture_snr: float = 2.0, initial=None, quadratic=None,
              jacobian: str = "template", noise_correction: bool = True,
              offset=None, sigma0_population=None, population_grad_power=None,
              footprint_var: float | None = None,
              sigma0_model: str = "gradient", step_limit: float | None = STEP_SCORE_LIMIT,
              population_step_score=None, rigid_across: bool = False,
              robust=False) -> LSMResult:
    """Match square patches of ``template_image`` into ``search_image`` by LSM [1]_.

    Parameters
    ----------
    template_image, search_image : (H, W) array_like or PreparedImage
        Grey images (any real dtype; float32 and float64 give the same answer to
        float32 precision).  The two may differ in size.  Pass :class:`PreparedImage`
        (same ``interpolation``) to match several point sets without refiltering.
    points : (N, 2) array_like
        Template centres (x, y) in the template image, px (integer values avoid
        resampling the template).
    approx : (N, 2) array_like
        Approximate positions of the centres in the search image, px; must lie within
        the pull-in range (about a quarter of the patch for band-limited texture).
    patch : int
        Odd patch side, px (default 15).
    interpolation : {"bilinear", "bicubic", "spline"}
        Resampler of the search image: bilinear, Keys cubic convolution (a = -0.5) or
        cubic B-spline interpolation (default; lowest zero-noise bias).
    direction : (N, 2) or (2,) array_like, optional
        Epipolar constraint: the shift (a0, b0) only moves along this direction from
        ``approx`` (``(1, 0)`` for a rectified pair).  The covariance is then rank 1.
    max_iter : int
        Maximum Gauss-Newton iterations (default 20).
    shift_stop_px : float, optional
        Stop threshold on the shift update, px (default ``TOL.lsm_shift_stop_px``).
    max_shift_px : float, optional
        Pull-in range: reject a solution farther than this from ``approx`` (default
        ``patch / 4``: a Gauss-Newton linearisation over the patch holds for shifts
        below about a quarter of its width on texture the patch resolves).
    noise_sigma : float, optional
        Image noise σ, grey levels; the reference σ0 is then σ sqrt(1 + r1²).  Default:
        the median σ0 of the converged points when there are at least 30 of them (the
        matching noise measured on the data), else the two images' Immerkaer noise
        estimates combined.
    sigma0_factor : float
        Reject when σ0 > ``sigma0_factor`` x reference (default 2.5: 6x the noise
        variance; a correct match has σ0/σ ~ 1 ± sqrt(1/(2(n-u))) ≈ 1 ± 0.05).
    sigma0_mad_k : float
        With 30 or more converged points also reject σ0 > median + k·s, s the larger of
        1.4826 MAD(σ0) and the chi-distribution's spread median/sqrt(2(n-u)) (default
        k = 4: beyond 4 s the residual is not noise but a model failure -- occlusion,
        a depth edge, a resolution mismatch).
    min_correlation : float
        Reject when the correlation coefficient is below this (default 0.7: the
        signal explains under half the patch variance).
    initial : (N, 8) array_like, optional
        Starting ``a0 a1 a2 b0 b1 b2 r0 r1`` (default: ``approx``, identity, 0, 1); the
        pull-in test still measures from ``approx``.
    quadratic : (N, 6) array_like, optional
        Fixed (not estimated) second-order warp terms ``(qu_xx, qu_xy, qu_yy, qv_xx,
        qv_xy, qv_yy)`` added to the affine map: ``u += qu_xx x² + qu_xy x y + qu_yy y²``
        and likewise ``v``, px/px².  An affine fit of a curved mapping is biased by about
        ``<x²>(qu_xx + qu_yy)`` (18.7 px² x curvature for a 15 px patch);
        :func:`matching.second_order.second_order_terms` estimates these terms from the
        neighbours' affine parameters.
    min_texture_snr : float
        Reject as textureless when the smaller eigenvalue of the template's mean
        structure tensor is below ``min_texture_snr`` x σ_n²/2 (σ_n²/2 = what noise of
        σ_n alone gives a central-difference gradient), σ_n = Immerkaer's estimate for
        the template image (and never below ``TOL.zero``).

    offset : (N, 2) array_like, optional
        Eccentric windows: report the match of the template pixel ``points + offset``
        (px, inside the patch: ``|offset| <= patch // 2`` per axis) instead of the
        centre's -- its position through the estimated warp, (a0 + a1 ox + a2 oy,
        b0 + b1 ox + b2 oy) plus the fixed second-order terms, and its covariance
        σ0² gᵀ N⁻¹ g with g the gradient of that position in the unknowns (the affine
        unknowns' uncertainty grows it with |o|).  A point near a depth or texture edge
        is matched with a window moved off the edge (shiftable windows); ``approx``
        stays the approximation of the window's centre.  Default: the centres.

    jacobian : {"template", "search"}
        Jacobian of the final linearisation (module docstring): the template-gradient
        one (default; unbiased under search-image noise, σ right within 5 %) or one
        exact forward-additive step with search-image gradients (Gruen's textbook form).
    noise_correction : bool
        With the template Jacobian, report σ0² Nc⁻¹, Nc = N less its expected
        template-noise part (each central difference carries σ_n²/2 of noise, each value
        σ_n²; σ_n = ``noise_sigma`` or Immerkaer's estimate of the template image), the
        normal matrix of the noise-free template.  Without it σ0² N⁻¹ is too small on
        weak texture: measured actual/reported 1.11 at SNR 5 and 1.3 at SNR 2.7 (SNR =
        λ_min / (σ_n²/2)), against 0.98 and 0.97 with it.  Exact for integer centres.

    sigma0_population : (M,) array_like, optional
        σ0 of accepted matches of the same images and patch made elsewhere (e.g. the
        seeds of a region-growing front, :mod:`matching.grow`): the σ0 test then takes
        its reference (median) and robust limit from them and from this call's
        converged points together, so that a small batch is judged like a large one.

    population_grad_power : (M,) array_like, optional
        The mean template gradient power (``LSMResult.grad_power``) of each value of
        ``sigma0_population``, for ``sigma0_model="gradient"`` (without it that model
        falls back to the constant one when a population is given).
    sigma0_model : {"gradient", "constant"}
        Reference of the σ0 tests (``sigma0_factor``, ``sigma0_mad_k``): "gradient"
        (default, with 30 or more values) predicts each window's σ0 from its texture,
        σ0² = α + β |∇f|², fitted to the population (:func:`sigma0_gradient_model`: on
        real images the model error grows with the texture's strength), and tests
        σ0 / prediction; "constant": σ0 against the population median (or
        ``noise_sigma``), as if only noise were left.
    footprint_var : float, optional
        Shape-adapted smoothing of the template (Lindeberg & Gårding 1997) [5]_: a
        pixel of either image integrates the scene over a footprint of variance
        ``footprint_var`` (px²; ``DEFAULT_FOOTPRINT_VAR`` = 0.25 is the measured value
        ``matching.pair.match_pair`` uses) per axis; seen
        in the template through the initial affine A (template -> search), the search
        pixel's footprint has covariance ``footprint_var`` A⁻¹A⁻ᵀ.  Where the search view
        is foreshortened (A contracts) the search image lacks the template's finest
        detail and LSM's model f = r0 + r1 g(W x) does not hold: the template is then
        smoothed by the Gaussian of the difference, ``footprint_var`` (A⁻¹A⁻ᵀ - I),
        clipped to its positive part (a direction in which the search image is the
        sharper is left as it is) and to σ <= 4/3 px, so that both patches carry the
        same band.  The texture test and the noise correction take the smoothed
        template's noise.  Default None: no smoothing.
    step_limit : float or None
        Motion-step test (module docstring, ``Status.TWO_MOTIONS``): reject an accepted
        window whose ``step_score`` exceeds ``step_limit`` x max(1, population median /
        ``STEP_SCORE_NULL_MEDIAN``) (:func:`step_score_limit`: the larger of this
        call's accepted windows' median and ``population_step_score``'s).  Default
        ``STEP_SCORE_LIMIT`` (30: above every one of 4900 correct windows); None: off.
        Only with ``jacobian="template"``.
    population_step_score : (M,) array_like, optional
        ``step_score`` of accepted matches made elsewhere (as ``sigma0_population``).
    rigid_across : bool
        With ``direction``: every pixel of the window, not only its centre, stays on its
        epipolar line -- with n ⟂ d the warp satisfies nᵀA = nᵀ, A = I + d wᵀ, so the
        shift along d and the shape w along d are estimated (5 unknowns with the
        radiometry instead of 7) and the initial A is projected onto that form.  Exact for
        a rectified pair (d = (1, 0): b1 = 0, b2 = 1, rows map to rows); there the
        freed b1, b2 are determined only by the texture's y-gradients, and on texture
        that has little of them (flutes, horizontal edges) wander and drag the window
        (``matching.pair`` uses it for rectified pairs).  Default False.
    robust : bool or (N,) array_like of bool
        Robust LSM (module docstring, *Robust adjustment*) for every window or for those
        flagged: from the converged equal-weight solution, iteratively reweighted least
        squares with Tukey's biweight (c = ``TUKEY_C`` = 4.685 robust σ of the window's
        residuals, never below the two images' noise) finds the pixels that follow one
        warp, and least squares over them gives the match, σ0 and the covariance
        (σ0² = vᵀWv / (Σw - u), N = Jᵀ W J, the noise correction over the support).  A
        window whose support leaves out its centre (or ``offset`` pixel) or holds under
        half its pixels is rejected as ``two_motions``.  Only with ``jacobian="template"``.
        Default False.

    Notes
    -----
    The covariance is σ0² N⁻¹ of the final linearisation restricted to the shift,
    σ0² = vᵀv/(n - u), n = patch², u = 8 (7 with the epipolar constraint).
    """
    if interpolation not in _KIND:
        raise ValueError(f"interpolation must be one of {INTERPOLATIONS}, got {interpolation!r}")
    if not (isinstance(patch, int | np.integer) and patch >= 5 and patch % 2 == 1):
        raise ValueError(f"patch must be an odd integer >= 5, got {patch!r}")
    if sigma0_model not in ("gradient", "constant"):
        raise ValueError(f"sigma0_model must be 'gradient' or 'constant', got {sigma0_model!r}")
    if jacobian not in ("template", "search"):
        raise ValueError(f"jacobian must be 'template' or 'search', got {jacobian!r}")
    if max_iter < 1:
        raise ValueError(f"max_iter must be >= 1, got {max_iter}")
    if rigid_across and direction is None:
        raise ValueError("rigid_across needs a direction (the epipolar constraint)")
    points = check_shape(points, "(N, 2)", "points", dtype=np.float64)
    robust_flags = np.broadcast_to(np.asarray(robust), (len(points),))
    if robust_flags.dtype != np.bool_:
        raise ValueError(f"robust must be a bool or (N,) bools, got dtype {robust_flags.dtype}")
    if robust_flags.any() and jacobian != "template":
        raise ValueError("robust needs jacobian='template'")
    approx = check_shape(approx, "(N, 2)", "approx", dtype=np.float64)
    if len(points) != len(approx):
        raise ValueError(f"points and approx must have the same length, got {len(points)} "
                         f"and {len(approx)}")
    images = []
    for name, img in (("template_image", template_image), ("search_image", search_image)):
        if not isinstance(img, PreparedImage):
            if np.ndim(img) != 2:
                raise ValueError(f"{name} must be a 2-D grey image, got shape {np.shape(img)}")
            img = prepare_image(img, interpolation)
        elif img.interpolation != interpolation:
            raise ValueError(f"{name} was prepared for {img.interpolation!r}, "
                             f"not {interpolation!r}")
        images.append(img)
    fprep, gprep = images
    constrained = direction is not None
    if constrained:
        dirs = np.broadcast_to(np.asarray(direction, dtype=np.float64), points.shape).copy()
        norm = np.linalg.norm(dirs, axis=1)
        if not np.all(norm > TOL.zero):
            raise ValueError("direction must be non-zero for every point")
        dirs /= norm[:, None]
    else:
        dirs = np.zeros_like(points)
    n = len(points)
    if initial is None:
        init = np.zeros((n, 8))
        init[:, [0, 3]] = approx
        init[:, [1, 5, 7]] = 1.0
    else:
        init = check_shape(initial, "(N, 8)", "initial", dtype=np.float64)
    quad = (np.zeros((n, 6)) if quadratic is None else
            check_shape(quadratic, "(N, 6)", "quadratic", dtype=np.float64))
    if len(init) != n or len(quad) != n:
        raise ValueError(f"initial and quadratic must have {n} rows, got {len(init)} and "
                         f"{len(quad)}")
    if offset is None:
        offs = np.zeros((n, 2))
    else:
        offs = check_shape(offset, "(N, 2)", "offset", dtype=np.float64)
        if len(offs) != n:
            raise ValueError(f"offset must have {n} rows, got {len(offs)}")
        if not (np.isfinite(offs).all() and np.abs(offs).max(initial=0.0) <= patch // 2):
            raise ValueError(f"offset must be finite and inside the patch (|offset| <= "
                             f"{patch // 2} px per axis), got up to "
                             f"{np.abs(offs).max(initial=0.0):g}")
    mode = (2 if rigid_across else 1) if constrained else 0
    if mode == 2:
        # A = I + d dᵀ (A - I): the initial shape along d kept, across it the identity
        init = init.copy()
        amat = init[:, [1, 2, 4, 5]].reshape(n, 2, 2) - np.eye(2)
        amat = np.eye(2) + dirs[:, :, None] * np.einsum("ni,nij->nj", dirs, amat)[:, None, :]
        init[:, [1, 2, 4, 5]] = amat.reshape(n, 4)
    blur = footprint_blur(init, footprint_var)
    tol = TOL.lsm_shift_stop_px if shift_stop_px is None else float(shift_stop_px)
    max_shift = 0.25 * patch if max_shift_px is None else float(max_shift_px)
    fimg, gimg = fprep.values, gprep.values
    noise_f = fprep.noise
    min_texture = max(min_texture_snr * 0.5 * noise_f**2, TOL.zero)
    template_noise = noise_f if noise_sigma is None else float(noise_sigma)
    grad_noise_var = 0.5 * template_noise**2 if noise_correction else 0.0
    params = np.full((n, 8), np.nan)
    cov = np.full((n, 2, 2), np.nan)
    wcov = np.full((n, 2, 2), np.nan)
    acov = np.full((n, 6, 6), np.nan)
    sigma0 = np.full(n, np.nan)
    # correlation, the template's mean |∇f|², step score, robust support share
    corr = np.full((n, 4), np.nan)
    status = np.zeros(n, np.uint8)
    iters = np.zeros(n, np.int32)
    conv = np.zeros(n, np.bool_)
    finite = (np.isfinite(points).all(1) & np.isfinite(approx).all(1)
              & np.isfinite(init).all(1) & np.isfinite(quad).all(1))
    status[~finite] = Status.NO_CONVERGENCE
    idx = np.flatnonzero(finite)
    if len(idx):
        sub = [params[idx], cov[idx], wcov[idx], acov[idx], sigma0[idx], corr[idx],
               status[idx], iters[idx], conv[idx]]
        _lsm_batch(fimg, fprep.raw, gimg, np.ascontiguousarray(points[idx]),
                   np.ascontiguousarray(approx[idx]), np.ascontiguousarray(init[idx]),
                   np.ascontiguousarray(quad[idx]), np.ascontiguousarray(dirs[idx]),
                   mode, patch // 2, _KIND[interpolation], jacobian == "search",
                   int(max_iter), tol,
                   max_shift, TOL.affine_det_min, min_texture, grad_noise_var,
                   0.25 * (fprep.noise**2 + gprep.noise**2), np.ascontiguousarray(offs[idx]),
                   np.ascontiguousarray(blur[idx]),
                   np.ascontiguousarray(robust_flags[idx]),
                   float(np.hypot(fprep.noise, gprep.noise)), *sub)
        for full, part in zip((params, cov, wcov, acov, sigma0, corr, status, iters, conv),
                              sub, strict=True):
            full[idx] = part
    corr, grad_power, step, support = (corr[:, 0].copy(), corr[:, 1].copy(),
                                       corr[:, 2].copy(), corr[:, 3].copy())
    good = status == Status.OK
    population = sigma0[good]
    pop_power = grad_power[good]
    if sigma0_population is not None:
        extra = np.asarray(sigma0_population, dtype=np.float64).ravel()
        extra_power = (np.full(len(extra), np.nan) if population_grad_power is None else
                       np.asarray(population_grad_power, dtype=np.float64).ravel())
        if len(extra_power) != len(extra):
            raise ValueError(f"population_grad_power must have {len(extra)} values, got "
                             f"{len(extra_power)}")
        keep = np.isfinite(extra)
        population = np.concatenate([population, extra[keep]])
        pop_power = np.concatenate([pop_power, extra_power[keep]])
    pop_step = (np.zeros(0) if population_step_score is None else
                np.asarray(population_step_score, dtype=np.float64).ravel())
    dof = (patch * patch) - _MODE_UNKNOWNS[mode]
    # both images carry noise: v = f - r0 - r1 g  ->  σ0² = σ² (1 + r1²)
    gain = float(np.median(params[good, 7])) if good.any() else 1.0
    model = None
    if sigma0_model == "gradient" and len(population) >= 30 and np.isfinite(pop_power).all():
        fixed = None if noise_sigma is None else float(noise_sigma) ** 2 * (1.0 + gain**2)
        model = sigma0_gradient_model(population, pop_power, fixed_intercept=fixed)
    if model is not None:
        # σ0 against what the window's texture predicts: σ0² = α + β |∇f|² (module
        # docstring of sigma0_gradient_model); the same tests on the ratio
        alpha, beta = model
        ratio = sigma0 / np.sqrt(alpha + beta * np.maximum(grad_power, 0.0))
        pop_ratio = population / np.sqrt(alpha + beta * pop_power)
        ref = float(np.sqrt(alpha + beta * np.median(pop_power)))
        limit = min(sigma0_factor * float(np.median(pop_ratio)),
                    robust_upper_limit(pop_ratio, sigma0_mad_k, dof))
        ok = status == Status.OK
        status[ok & ~(ratio <= limit)] = Status.SIGMA0_TOO_LARGE
    else:
        if noise_sigma is not None:
            ref = float(noise_sigma) * np.sqrt(1.0 + gain**2)
        elif len(population) >= 30:
            ref = float(np.median(population))
        else:
            ref = float(np.hypot(fprep.noise, gprep.noise))
        limit = sigma0_factor * ref
        if len(population) >= 30:
            limit = min(limit, robust_upper_limit(population, sigma0_mad_k, dof))
        ok = status == Status.OK
        status[ok & (sigma0 > limit)] = Status.SIGMA0_TOO_LARGE
    ok = status == Status.OK
    status[ok & ~(corr >= min_correlation)] = Status.LOW_CORRELATION
    if step_limit is not None and jacobian == "template":
        ok = status == Status.OK
        limit = step_score_limit(step[ok], step_limit, pop_step)
        status[ok & (step > limit)] = Status.TWO_MOTIONS  # NaN (no residual left): kept
    position = params[:, [0, 3]]
    if offset is not None:
        ox, oy = offs[:, 0], offs[:, 1]
        position = position + np.column_stack([
            params[:, 1] * ox + params[:, 2] * oy
            + quad[:, 0] * ox * ox + quad[:, 1] * ox * oy + quad[:, 2] * oy * oy,
            params[:, 4] * ox + params[:, 5] * oy
            + quad[:, 3] * ox * ox + quad[:, 4] * ox * oy + quad[:, 5] * oy * oy])
    return LSMResult(position=position, affine=params[:, :6],
                     radiometric=params[:, 6:], converged=conv, iterations=iters,
                     sigma0=sigma0, cov=cov, correlation=corr, status=status,
                     noise_sigma0=float(ref), window_cov=wcov if offset is not None else None,
                     affine_cov=acov, grad_power=grad_power, step_score=step,
                     support=support)
