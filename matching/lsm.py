r"""Adaptive least-squares correlation (Gruen 1985) [1]_, batched over all windows: the driver.

For every pixel :math:`(x, y)` of a square template window (pixels relative to its centre)

.. math::

    f(x, y) - e(x, y) = r_0 + r_1\, g(a_0 + a_1 x + a_2 y,\; b_0 + b_1 x + b_2 y)

with six affine unknowns (:math:`(a_0, b_0)`: the centre's match), offset and gain, and the
search image :math:`g` resampled at the warped position.  Gauss-Newton with the
template-gradient Jacobian (Baker & Matthews [2]_: its normal matrix is factored once per
window) until the shift update is below ``TOL.lsm_shift_stop_px``; the precision is
σ0² N⁻¹ of the final linearisation, N less the template's expected noise part.

:func:`lsm_match` (settings: :class:`LSMOptions`, or keywords of the same names) checks its
input, solves every window in one ``prange`` kernel (:mod:`matching.lsm_kernels`) and then
applies the tests that need the batch's population:
σ0 against what each window's texture predicts (:func:`sigma0_gradient_model`), the
correlation, and the motion-step test for depth edges (:func:`step_score_limit`).  Options:
the epipolar constraint, eccentric windows, fixed second-order warp terms, the template's
footprint smoothing [5]_, robust LSM with Tukey's biweight [6]_.  Images are prepared once by
:mod:`matching.lsm_image` (noise estimate [3]_, B-spline prefilter).  The equations, each
test, and the measurements behind the defaults (including why the template-gradient
Jacobian's σ is right where the search-gradient one is biased [4]_): ``docs/method/lsm.md``.

References
----------
.. [1] A. W. Gruen, "Adaptive least squares correlation: a powerful image matching
   technique", S. Afr. J. Photogramm. Remote Sens. Cartogr. 14(3), 175-187 (1985).
.. [2] S. Baker, I. Matthews, "Lucas-Kanade 20 years on: a unifying framework", IJCV 56(3),
   221-255 (2004).
.. [3] J. Immerkaer, "Fast noise variance estimation", CVIU 64(2), 300-302 (1996).
.. [4] D. Robinson, P. Milanfar, "Fundamental performance limits in image
   registration", IEEE Trans. Image Processing 13(9), 1185-1199 (2004).
.. [5] T. Lindeberg, J. Gårding, "Shape-adapted smoothing in estimation of 3-D shape
   cues from affine deformations of local 2-D brightness structure", Image and Vision
   Computing 15(6), 415-434 (1997).
.. [6] P. W. Holland, R. E. Welsch, "Robust regression using iteratively reweighted
   least-squares", Commun. Stat. Theory Methods 6(9), 813-827 (1977).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from enum import IntEnum

import numpy as np

from checks.robust import MAD_TO_SIGMA
from matching.lsm_image import (
    _KIND,
    DEFAULT_INTERPOLATION,
    INTERPOLATIONS,
    NOISE_BLOCK_PX,
    NOISE_BLOCK_QUANTILE,
    PreparedImage,
    estimate_noise,
    prepare_image,
)
from matching.lsm_kernels import _lsm_batch
from matching.lsm_normals import _MODE_UNKNOWNS
from matching.lsm_robust import TUKEY_C
from matching.lsm_template import _MAX_BLUR_RADIUS
from matching.validate import TOL, check_shape

__all__ = [
    "DEFAULT_FOOTPRINT_VAR", "DEFAULT_INTERPOLATION", "INTERPOLATIONS", "NOISE_BLOCK_PX",
    "NOISE_BLOCK_QUANTILE", "STATUS_NAMES", "STEP_SCORE_LIMIT", "STEP_SCORE_NULL_MEDIAN",
    "TUKEY_C", "LSMOptions", "LSMResult", "PreparedImage", "Status", "estimate_noise",
    "footprint_blur", "lsm_match", "prepare_image", "robust_upper_limit",
    "sigma0_gradient_model", "step_score_limit",
]


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
        The motion-step test's statistic (``docs/method/lsm.md``,
        :func:`matching.lsm_kernels._step_score`): the largest score, over the lines
        splitting the window, of a shift of one side against the other, in units of the
        residual variance (NaN with ``jacobian="search"``, where no solution was reached,
        where the kernel rejected the window -- not converged, degenerate affine -- and
        where the correlation is below ``min_correlation``: windows the test never judges).
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
    spread = max(MAD_TO_SIGMA * float(np.median(np.abs(values - med))), med / np.sqrt(2.0 * dof))
    return med + k * spread


@dataclass(frozen=True)
class LSMOptions:
    """The settings of :func:`lsm_match`, the same for every window of a call.

    :func:`lsm_match` takes them as ``options`` or as keywords of the same names (the
    keywords override ``options``' values); each is checked here.

    Attributes
    ----------
    patch : int
        Odd patch side, px (default 15).
    interpolation : {"bilinear", "bicubic", "spline"}
        Resampler of the search image: bilinear, Keys cubic convolution (a = -0.5) or
        cubic B-spline interpolation (default; lowest zero-noise bias).
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
    min_texture_snr : float
        Reject as textureless when the smaller eigenvalue of the template's mean
        structure tensor is below ``min_texture_snr`` x σ_n²/2 (σ_n²/2 = what noise of
        σ_n alone gives a central-difference gradient), σ_n = Immerkaer's estimate for
        the template image (and never below ``TOL.zero``).
    jacobian : {"template", "search"}
        Jacobian of the final linearisation (``docs/method/lsm.md``): the template-gradient
        one (default; unbiased under search-image noise, σ right within 5 %) or one
        exact forward-additive step with search-image gradients (Gruen's textbook form).
    noise_correction : bool
        With the template Jacobian, report σ0² Nc⁻¹, Nc = N less its expected
        template-noise part (each central difference carries σ_n²/2 of noise, each value
        σ_n²; σ_n = ``noise_sigma`` or Immerkaer's estimate of the template image), the
        normal matrix of the noise-free template.  Without it σ0² N⁻¹ is too small on
        weak texture: measured actual/reported 1.11 at SNR 5 and 1.3 at SNR 2.7 (SNR =
        λ_min / (σ_n²/2)), against 0.98 and 0.97 with it.  Exact for integer centres.
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
        Motion-step test (``docs/method/lsm.md``, ``Status.TWO_MOTIONS``): reject an accepted
        window whose ``step_score`` exceeds ``step_limit`` x max(1, population median /
        ``STEP_SCORE_NULL_MEDIAN``) (:func:`step_score_limit`: the larger of this
        call's accepted windows' median and ``population_step_score``'s).  Default
        ``STEP_SCORE_LIMIT`` (30: above every one of 4900 correct windows); None: off.
        Only with ``jacobian="template"``.
    rigid_across : bool
        With ``direction``: every pixel of the window, not only its centre, stays on its
        epipolar line -- with n ⟂ d the warp satisfies nᵀA = nᵀ, A = I + d wᵀ, so the
        shift along d and the shape w along d are estimated (5 unknowns with the
        radiometry instead of 7) and the initial A is projected onto that form.  Exact for
        a rectified pair (d = (1, 0): b1 = 0, b2 = 1, rows map to rows); there the
        freed b1, b2 are determined only by the texture's y-gradients, and on texture
        that has little of them (flutes, horizontal edges) wander and drag the window
        (``matching.pair`` uses it for rectified pairs).  Default False.
    """

    patch: int = 15
    interpolation: str = DEFAULT_INTERPOLATION
    max_iter: int = 20
    shift_stop_px: float | None = None
    max_shift_px: float | None = None
    noise_sigma: float | None = None
    sigma0_factor: float = 2.5
    sigma0_mad_k: float = 4.0
    min_correlation: float = 0.7
    min_texture_snr: float = 2.0
    jacobian: str = "template"
    noise_correction: bool = True
    sigma0_model: str = "gradient"
    footprint_var: float | None = None
    step_limit: float | None = STEP_SCORE_LIMIT
    rigid_across: bool = False

    def __post_init__(self):
        if self.interpolation not in _KIND:
            raise ValueError(f"interpolation must be one of {INTERPOLATIONS}, got "
                             f"{self.interpolation!r}")
        patch = self.patch
        if not (isinstance(patch, int | np.integer) and patch >= 5 and patch % 2 == 1):
            raise ValueError(f"patch must be an odd integer >= 5, got {patch!r}")
        if self.sigma0_model not in ("gradient", "constant"):
            raise ValueError(f"sigma0_model must be 'gradient' or 'constant', got "
                             f"{self.sigma0_model!r}")
        if self.jacobian not in ("template", "search"):
            raise ValueError(f"jacobian must be 'template' or 'search', got {self.jacobian!r}")
        if self.max_iter < 1:
            raise ValueError(f"max_iter must be >= 1, got {self.max_iter}")


@dataclass(frozen=True)
class _Windows:
    """The windows of one :func:`lsm_match` call, checked: centres, approximations,
    epipolar directions (zeros: none), initial parameters, fixed second-order terms,
    eccentric offsets (zeros: none), robust flags and the kernel's mode (0 free, 1
    epipolar, 2 rigid across the line)."""

    points: np.ndarray
    approx: np.ndarray
    dirs: np.ndarray
    init: np.ndarray
    quad: np.ndarray
    offs: np.ndarray
    robust: np.ndarray
    mode: int


def _prepared(template_image, search_image, interpolation: str):
    """Both images as :class:`PreparedImage` for ``interpolation`` (prepared here unless
    they already are)."""
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
    return images


def _checked_points(points, approx, robust, opts: LSMOptions):
    """``points``, ``approx`` (N, 2) and the (N,) robust flags, checked."""
    points = check_shape(points, "(N, 2)", "points", dtype=np.float64)
    robust_flags = np.broadcast_to(np.asarray(robust), (len(points),))
    if robust_flags.dtype != np.bool_:
        raise ValueError(f"robust must be a bool or (N,) bools, got dtype {robust_flags.dtype}")
    if robust_flags.any() and opts.jacobian != "template":
        raise ValueError("robust needs jacobian='template'")
    approx = check_shape(approx, "(N, 2)", "approx", dtype=np.float64)
    if len(points) != len(approx):
        raise ValueError(f"points and approx must have the same length, got {len(points)} "
                         f"and {len(approx)}")
    return points, approx, robust_flags


def _windows(points, approx, robust_flags, direction, initial, quadratic, offset,
             opts: LSMOptions) -> _Windows:
    """The per-window inputs of the kernel: unit directions, the start (projected onto
    ``rigid_across``'s form), the second-order terms and offsets, checked."""
    n = len(points)
    constrained = direction is not None
    if constrained:
        dirs = np.broadcast_to(np.asarray(direction, dtype=np.float64), points.shape).copy()
        norm = np.linalg.norm(dirs, axis=1)
        if not np.all(norm > TOL.zero):
            raise ValueError("direction must be non-zero for every point")
        dirs /= norm[:, None]
    else:
        dirs = np.zeros_like(points)
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
        if not (np.isfinite(offs).all() and np.abs(offs).max(initial=0.0) <= opts.patch // 2):
            raise ValueError(f"offset must be finite and inside the patch (|offset| <= "
                             f"{opts.patch // 2} px per axis), got up to "
                             f"{np.abs(offs).max(initial=0.0):g}")
    mode = (2 if opts.rigid_across else 1) if constrained else 0
    if mode == 2:
        # A = I + d dᵀ (A - I): the initial shape along d kept, across it the identity
        init = init.copy()
        amat = init[:, [1, 2, 4, 5]].reshape(n, 2, 2) - np.eye(2)
        amat = np.eye(2) + dirs[:, :, None] * np.einsum("ni,nij->nj", dirs, amat)[:, None, :]
        init[:, [1, 2, 4, 5]] = amat.reshape(n, 4)
    return _Windows(points, approx, dirs, init, quad, offs, robust_flags, mode)


def _solve(fprep: PreparedImage, gprep: PreparedImage, w: _Windows, opts: LSMOptions):
    """Every window with finite inputs through the kernel (:func:`_lsm_batch`); the
    others ``NO_CONVERGENCE``.  Returns the kernel's per-window arrays: ``params`` (N, 8),
    ``cov``, ``wcov`` (N, 2, 2), ``acov`` (N, 6, 6), ``sigma0`` (N,), ``corr`` (N, 4:
    correlation, mean |∇f|², step score, robust support), ``status``, ``iters``,
    ``conv``."""
    n = len(w.points)
    blur = footprint_blur(w.init, opts.footprint_var)
    tol = TOL.lsm_shift_stop_px if opts.shift_stop_px is None else float(opts.shift_stop_px)
    max_shift = 0.25 * opts.patch if opts.max_shift_px is None else float(opts.max_shift_px)
    noise_f = fprep.noise
    min_texture = max(opts.min_texture_snr * 0.5 * noise_f**2, TOL.zero)
    template_noise = noise_f if opts.noise_sigma is None else float(opts.noise_sigma)
    grad_noise_var = 0.5 * template_noise**2 if opts.noise_correction else 0.0
    out = {"params": np.full((n, 8), np.nan), "cov": np.full((n, 2, 2), np.nan),
           "wcov": np.full((n, 2, 2), np.nan), "acov": np.full((n, 6, 6), np.nan),
           "sigma0": np.full(n, np.nan), "corr": np.full((n, 4), np.nan),
           "status": np.zeros(n, np.uint8), "iters": np.zeros(n, np.int32),
           "conv": np.zeros(n, np.bool_)}
    finite = (np.isfinite(w.points).all(1) & np.isfinite(w.approx).all(1)
              & np.isfinite(w.init).all(1) & np.isfinite(w.quad).all(1))
    out["status"][~finite] = Status.NO_CONVERGENCE
    idx = np.flatnonzero(finite)
    if len(idx):
        sub = [a[idx] for a in out.values()]
        _lsm_batch(fprep.values, fprep.raw, gprep.values, np.ascontiguousarray(w.points[idx]),
                   np.ascontiguousarray(w.approx[idx]), np.ascontiguousarray(w.init[idx]),
                   np.ascontiguousarray(w.quad[idx]), np.ascontiguousarray(w.dirs[idx]),
                   w.mode, opts.patch // 2, _KIND[opts.interpolation],
                   opts.jacobian == "search", int(opts.max_iter), tol,
                   max_shift, TOL.affine_det_min, min_texture, grad_noise_var,
                   0.25 * (fprep.noise**2 + gprep.noise**2), np.ascontiguousarray(w.offs[idx]),
                   np.ascontiguousarray(blur[idx]),
                   np.ascontiguousarray(w.robust[idx]),
                   float(np.hypot(fprep.noise, gprep.noise)), float(opts.min_correlation), *sub)
        for full, part in zip(out.values(), sub, strict=True):
            full[idx] = part
    return out


def _sigma0_test(status, sigma0, grad_power, gain_column, population, pop_power,
                 fprep: PreparedImage, gprep: PreparedImage, mode: int,
                 opts: LSMOptions) -> float:
    """``SIGMA0_TOO_LARGE`` in ``status`` (in place): σ0 against the texture's prediction
    (:func:`sigma0_gradient_model`) or against the population's median; returns the
    reference σ0 (``LSMResult.noise_sigma0``)."""
    good = status == Status.OK
    dof = (opts.patch * opts.patch) - _MODE_UNKNOWNS[mode]
    # both images carry noise: v = f - r0 - r1 g  ->  σ0² = σ² (1 + r1²)
    gain = float(np.median(gain_column[good])) if good.any() else 1.0
    noise_sigma = opts.noise_sigma
    model = None
    if opts.sigma0_model == "gradient" and len(population) >= 30 and np.isfinite(pop_power).all():
        fixed = None if noise_sigma is None else float(noise_sigma) ** 2 * (1.0 + gain**2)
        model = sigma0_gradient_model(population, pop_power, fixed_intercept=fixed)
    if model is not None:
        # σ0 against what the window's texture predicts: σ0² = α + β |∇f|² (module
        # docstring of sigma0_gradient_model); the same tests on the ratio
        alpha, beta = model
        ratio = sigma0 / np.sqrt(alpha + beta * np.maximum(grad_power, 0.0))
        pop_ratio = population / np.sqrt(alpha + beta * pop_power)
        ref = float(np.sqrt(alpha + beta * np.median(pop_power)))
        limit = min(opts.sigma0_factor * float(np.median(pop_ratio)),
                    robust_upper_limit(pop_ratio, opts.sigma0_mad_k, dof))
        ok = status == Status.OK
        status[ok & ~(ratio <= limit)] = Status.SIGMA0_TOO_LARGE
    else:
        if noise_sigma is not None:
            ref = float(noise_sigma) * np.sqrt(1.0 + gain**2)
        elif len(population) >= 30:
            ref = float(np.median(population))
        else:
            ref = float(np.hypot(fprep.noise, gprep.noise))
        limit = opts.sigma0_factor * ref
        if len(population) >= 30:
            limit = min(limit, robust_upper_limit(population, opts.sigma0_mad_k, dof))
        ok = status == Status.OK
        status[ok & (sigma0 > limit)] = Status.SIGMA0_TOO_LARGE
    return ref


def _population(status, sigma0, grad_power, sigma0_population, population_grad_power):
    """The σ0 test's population: this call's accepted windows and ``sigma0_population``
    (with their gradient powers, NaN where not given)."""
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
    return population, pop_power


def _reported_position(params, quad, offs, eccentric: bool):
    """(N, 2) the centre's match, or with ``eccentric`` windows the offset pixel's
    through the warp (its affine and fixed second-order terms)."""
    position = params[:, [0, 3]]
    if eccentric:
        ox, oy = offs[:, 0], offs[:, 1]
        position = position + np.column_stack([
            params[:, 1] * ox + params[:, 2] * oy
            + quad[:, 0] * ox * ox + quad[:, 1] * ox * oy + quad[:, 2] * oy * oy,
            params[:, 4] * ox + params[:, 5] * oy
            + quad[:, 3] * ox * ox + quad[:, 4] * ox * oy + quad[:, 5] * oy * oy])
    return position


def _tested(status, sigma0, grad_power, corr, step, params, fprep, gprep, mode,
            opts: LSMOptions, populations: tuple) -> float:
    """The σ0, correlation and motion-step tests on the kernel's windows, ``status`` set
    in place; ``populations`` is ``(sigma0_population, population_grad_power,
    population_step_score)`` as :func:`lsm_match`'s.  Returns the σ0 test's reference."""
    sigma0_population, population_grad_power, population_step_score = populations
    population, pop_power = _population(status, sigma0, grad_power, sigma0_population,
                                        population_grad_power)
    pop_step = (np.zeros(0) if population_step_score is None else
                np.asarray(population_step_score, dtype=np.float64).ravel())
    ref = _sigma0_test(status, sigma0, grad_power, params[:, 7], population, pop_power,
                       fprep, gprep, mode, opts)
    ok = status == Status.OK
    status[ok & ~(corr >= opts.min_correlation)] = Status.LOW_CORRELATION
    if opts.step_limit is not None and opts.jacobian == "template":
        ok = status == Status.OK
        limit = step_score_limit(step[ok], opts.step_limit, pop_step)
        status[ok & (step > limit)] = Status.TWO_MOTIONS  # NaN (no residual left): kept
    return ref


def lsm_match(template_image, search_image, points, approx, *,
              options: LSMOptions | None = None, direction=None, initial=None,
              quadratic=None, offset=None, robust=False, sigma0_population=None,
              population_grad_power=None, population_step_score=None,
              **settings) -> LSMResult:
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
    options : LSMOptions, optional
        The settings shared by every window (:class:`LSMOptions`: patch side, resampler,
        stop and pull-in thresholds, the σ0, correlation and motion-step tests, footprint
        smoothing, the Jacobian); default ``LSMOptions()``.
    direction : (N, 2) or (2,) array_like, optional
        Epipolar constraint: the shift (a0, b0) only moves along this direction from
        ``approx`` (``(1, 0)`` for a rectified pair).  The covariance is then rank 1.
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
    offset : (N, 2) array_like, optional
        Eccentric windows: report the match of the template pixel ``points + offset``
        (px, inside the patch: ``|offset| <= patch // 2`` per axis) instead of the
        centre's -- its position through the estimated warp, (a0 + a1 ox + a2 oy,
        b0 + b1 ox + b2 oy) plus the fixed second-order terms, and its covariance
        σ0² gᵀ N⁻¹ g with g the gradient of that position in the unknowns (the affine
        unknowns' uncertainty grows it with |o|).  A point near a depth or texture edge
        is matched with a window moved off the edge (shiftable windows); ``approx``
        stays the approximation of the window's centre.  Default: the centres.
    robust : bool or (N,) array_like of bool
        Robust LSM (``docs/method/lsm.md``, *Robust adjustment*) for every window or for those
        flagged: from the converged equal-weight solution, iteratively reweighted least
        squares with Tukey's biweight (c = ``TUKEY_C`` = 4.685 robust σ of the window's
        residuals, never below the two images' noise) finds the pixels that follow one
        warp, and least squares over them gives the match, σ0 and the covariance
        (σ0² = vᵀWv / (Σw - u), N = Jᵀ W J, the noise correction over the support).  A
        window whose support leaves out its centre (or ``offset`` pixel) or holds under
        half its pixels is rejected as ``two_motions``.  Only with ``jacobian="template"``.
        Default False.
    sigma0_population : (M,) array_like, optional
        σ0 of accepted matches of the same images and patch made elsewhere (e.g. the
        seeds of a region-growing front, :mod:`matching.grow`): the σ0 test then takes
        its reference (median) and robust limit from them and from this call's
        converged points together, so that a small batch is judged like a large one.
    population_grad_power : (M,) array_like, optional
        The mean template gradient power (``LSMResult.grad_power``) of each value of
        ``sigma0_population``, for ``sigma0_model="gradient"`` (without it that model
        falls back to the constant one when a population is given).
    population_step_score : (M,) array_like, optional
        ``step_score`` of accepted matches made elsewhere (as ``sigma0_population``).
    **settings
        Any field of :class:`LSMOptions` by name, overriding ``options``' value
        (``lsm_match(f, g, p, a, patch=21)``).

    Notes
    -----
    The covariance is σ0² N⁻¹ of the final linearisation restricted to the shift,
    σ0² = vᵀv/(n - u), n = patch², u = 8 (7 with the epipolar constraint).
    """
    opts = LSMOptions(**settings) if options is None else replace(options, **settings)
    if opts.rigid_across and direction is None:
        raise ValueError("rigid_across needs a direction (the epipolar constraint)")
    points, approx, robust_flags = _checked_points(points, approx, robust, opts)
    fprep, gprep = _prepared(template_image, search_image, opts.interpolation)
    w = _windows(points, approx, robust_flags, direction, initial, quadratic, offset, opts)
    k = _solve(fprep, gprep, w, opts)
    params, sigma0, status = k["params"], k["sigma0"], k["status"]
    corr = k["corr"]
    corr, grad_power, step, support = (corr[:, 0].copy(), corr[:, 1].copy(),
                                       corr[:, 2].copy(), corr[:, 3].copy())
    ref = _tested(status, sigma0, grad_power, corr, step, params, fprep, gprep, w.mode, opts,
                  (sigma0_population, population_grad_power, population_step_score))
    return LSMResult(position=_reported_position(params, w.quad, w.offs, offset is not None),
                     affine=params[:, :6], radiometric=params[:, 6:], converged=k["conv"],
                     iterations=k["iters"], sigma0=sigma0, cov=k["cov"], correlation=corr,
                     status=status, noise_sigma0=float(ref),
                     window_cov=k["wcov"] if offset is not None else None,
                     affine_cov=k["acov"], grad_power=grad_power, step_score=step,
                     support=support)
