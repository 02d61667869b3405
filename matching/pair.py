r"""A stereo pair to matched points and 3D points with per-point precision.

The pair-level pipeline, reused by the multi-view stage:

1. **select** the best-textured pixel of every ``spacing`` x ``spacing`` cell of the
   left image (:func:`matching.seeds.select_points`);
2. **approximate** its right-image position: rectification + SGBM for a calibrated
   pair, SGBM on the images for an already rectified pair (:mod:`matching.seeds`);
3. **refine** by least-squares matching in the *original* images
   (:func:`matching.lsm.lsm_match`, Gruen 1985), optionally constrained to the local
   epipolar direction (always for a rectified pair: every window row held on its row,
   ``rigid_across``: b1 = 0, b2 = 1 are geometry, not unknowns);
4. **triangulate** (:func:`matching.triangulate.triangulate_pair`) with the LSM
   covariance, giving each 3D point its σ.

Precision control (second pass).  LSM's shift σ is noise-limited,
:math:`\sigma \approx \sigma_0 / \sqrt{2 w}` with Förstner's weight
:math:`w = \det N / \operatorname{tr} N` of the template's structure tensor N
(Förstner & Gülch 1987).  Two rules act on the first pass's validated σ: the
**adaptive patch** (Gruen's "adaptive": a point whose σ is worse than the median σ τ
of the accepted matches is re-matched with the smallest odd side up to ``max_patch``
whose predicted σ reaches τ, :func:`adaptive_sides`; a first-pass match the second
pass loses keeps its first-pass result) and the **precision test** (σ beyond the
median by more than ``max_sigma_mad_k`` robust spreads: ``imprecise``).

Epipolar pass (calibrated pairs, ``epipolar_pass``): windows re-matched in the
rectified images with the y-shift fixed by the rig (Gruen & Baltsavias 1988),
rejected where ill-conditioned along the line (``aperture``, tested at the window's
least-variance point), reported at the pixel nearest that point, the pair's
edge-polarity bias removed.  Every candidate keeps a status code
(:data:`PAIR_STATUS_NAMES`; their meanings: ``docs/method/acquire.md``).  What was
measured for each rule: ``docs/decisions/stereo-matching.md``, ``stereo-epipolar.md``,
``stereo-information-centre.md``, ``stereo-edges.md``.

References
----------
.. [1] A. W. Gruen, "Adaptive least squares correlation: a powerful image
   matching technique", S. Afr. J. Photogramm. Remote Sens. Cartogr. 14(3) (1985).
.. [2] W. Förstner, E. Gülch, "A fast operator for detection and precise location of
   distinct points, corners and centres of circular features", ISPRS Intercommission
   Conference on Fast Processing of Photogrammetric Data, Interlaken, 281-305 (1987).
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from types import SimpleNamespace

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from matching import uniqueness
from matching.grow import grow_matches
from matching.lsm import (
    DEFAULT_FOOTPRINT_VAR,
    DEFAULT_INTERPOLATION,
    STATUS_NAMES,
    LSMResult,
    PreparedImage,
    Status,
    lsm_match,
    prepare_image,
    robust_upper_limit,
)
from matching.precision import class_variance_factors
from matching.second_order import second_order_terms
from matching.seeds import (
    DEFAULT_SPACING,
    Candidates,
    approximate_calibrated,
    approximate_rectified,
    disparity_valid_left,
    rectify,
    select_points,
    shift_precision,
    window_offsets,
)
from matching.validate import TOL, check_shape

NO_APPROXIMATION = 8
TRIANGULATION = 9
IMPRECISE = 10
AMBIGUOUS = 12
BLANK = 13
BACKWARD = 14
APERTURE = 15
#: ``aperture``: the shift's variance along the row may be at most this many times what
#: the template's gradients along the row alone give (σ0² / Σ f_x²)
MAX_INFLATION = 2.0
OFF_SURFACE = 16
#: median of χ² with one degree of freedom
CHI2_1_MEDIAN = 0.45494
#: two-sided 99.9 % bound of a normal variable
OUTLIER_Z = 3.29
#: Every pair status code -> name (LSM's codes 0-7 and 11, then 8-10 and 12-14).
PAIR_STATUS_NAMES = {**STATUS_NAMES, NO_APPROXIMATION: "no_approximation",
                     TRIANGULATION: "triangulation", IMPRECISE: "imprecise",
                     AMBIGUOUS: "ambiguous", BLANK: "blank", BACKWARD: "backward",
                     APERTURE: "aperture", OFF_SURFACE: "off_surface"}


@dataclass(frozen=True)
class PairMatches:
    """Matched candidates of a pair (arrays over the N candidates).

    Attributes
    ----------
    x_left : (N, 2) float64
        Candidates in the left image (integer pixels), px: the matched points (their
        LSM window is centred at ``x_left + offset``; with the epipolar pass an accepted
        match is the pixel nearest its window's information centre, ``centre_points``).
    x_right : (N, 2) float64
        Matched positions in the right image, px (NaN where no LSM result).
    approx : (N, 2) float64
        The approximations LSM started from, px (NaN: none).
    cov : (N, 2, 2) float64
        Covariance of ``x_right`` relative to ``x_left`` (σ0²(AᵀA)⁻¹), px².
    sigma : (N,) float64
        sqrt(trace(cov) / 2), px.
    sigma0 : (N,) float64
        LSM residual σ, grey levels.
    correlation : (N,) float64
    iterations : (N,) int32
    affine : (N, 6) float64
        ``a0 a1 a2 b0 b1 b2``.
    radiometric : (N, 2) float64
        ``r0 r1`` (offset, gain).
    patch : (N,) int32
        Patch side the final match used, px (0: not matched).
    texture : (N,) float64
        Template λ_min of the structure tensor, grey levels²/px².
    status : (N,) uint8
        Codes of :data:`PAIR_STATUS_NAMES`.
    offset : (N, 2) float64
        Window centre minus ``x_left``, px: non-zero for an eccentric window moved off a
        textureless cell (:func:`matching.seeds.window_offsets`), or for a match the
        epipolar pass reports at its window's information centre; ``x_right`` and
        ``cov`` are then ``x_left``'s, transferred through the warp.
    edge : (N,) bool
        The window still reaches into an untextured region or unmatched pixels (no
        offset within the patch clears it, or ``eccentric`` is off): it straddles a
        silhouette, a rim or an untextured region.
    rectified : bool
        The images were given rectified (rows correspond).
    image_size : (int, int)
        Left image (width, height), px.
    sigma_factor : float
        The variance factor k² that ``cov`` and ``sigma`` of the windows clear of an
        edge (``~edge``) already carry (:func:`matching.precision.class_variance_factors`;
        1: not applied).
    sigma_factor_edge : float
        The same for the ``edge`` windows (estimated from the window pairs among them;
        ``sigma_factor`` where there are none).
    density_deficit : int
        Cells of the matched surface whose first-lattice candidate gave no point
        (rejected, or a straddler; :func:`density_deficit`); 0 when ``densify`` is off
        or the pair had too few accepted matches to densify.
    densified : int
        Second-lattice candidates matched (:func:`_densify`); they are the last
        ``densified`` entries of the arrays.
    """

    x_left: np.ndarray
    x_right: np.ndarray
    approx: np.ndarray
    cov: np.ndarray
    sigma: np.ndarray
    sigma0: np.ndarray
    correlation: np.ndarray
    iterations: np.ndarray
    affine: np.ndarray
    radiometric: np.ndarray
    patch: np.ndarray
    texture: np.ndarray
    status: np.ndarray
    rectified: bool
    image_size: tuple[int, int]
    offset: np.ndarray
    edge: np.ndarray
    sigma_factor: float = 1.0
    sigma_factor_edge: float = 1.0
    density_deficit: int = 0
    densified: int = 0

    def __len__(self) -> int:
        return len(self.x_left)

    @property
    def accepted(self) -> np.ndarray:
        """(N,) bool: status ok."""
        return self.status == Status.OK

    def status_counts(self) -> dict[str, int]:
        """Number of candidates per status name (zero counts left out)."""
        codes, counts = np.unique(self.status, return_counts=True)
        return {PAIR_STATUS_NAMES[int(c)]: int(n) for c, n in zip(codes, counts, strict=True)}

    def disparity_map(self) -> np.ndarray:
        """(H, W) float32 ``x_left - x_right`` at the accepted left pixels, NaN elsewhere."""
        w, h = self.image_size
        out = np.full((h, w), np.nan, np.float32)
        ok = self.accepted
        xi = self.x_left[ok].astype(np.intp)
        out[xi[:, 1], xi[:, 0]] = self.x_left[ok, 0] - self.x_right[ok, 0]
        return out

    def sigma_map(self) -> np.ndarray:
        """(H, W) float32 σ of ``disparity_map``'s values (sqrt of ``cov[0, 0]``: along the
        rows), px, NaN where not accepted."""
        w, h = self.image_size
        out = np.full((h, w), np.nan, np.float32)
        ok = self.accepted
        xi = self.x_left[ok].astype(np.intp)
        out[xi[:, 1], xi[:, 0]] = np.sqrt(np.maximum(self.cov[ok, 0, 0], 0.0))
        return out

    def as_dict(self) -> dict[str, np.ndarray]:
        """Every array field, plus ``status_names`` (for ``np.savez``)."""
        out = {f.name: np.asarray(getattr(self, f.name)) for f in fields(self)}
        out["status_names"] = np.array([PAIR_STATUS_NAMES[k] for k in sorted(PAIR_STATUS_NAMES)])
        return out


def _grey(image, name: str) -> np.ndarray:
    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] in (3, 4):
        img = img[..., :3].astype(np.float64) @ np.array([0.114, 0.587, 0.299])  # BGR
    if img.ndim != 2:
        raise ValueError(f"{name} must be a grey (H, W) or colour (H, W, 3) image, "
                         f"got shape {img.shape}")
    if min(img.shape) < 32:
        raise ValueError(f"{name} is too small to match: {img.shape[1]}x{img.shape[0]} px")
    return np.asarray(img, dtype=np.float64)


def match_pair(left_img, right_img, rig=None, *, rectified: bool = False,
               spacing: int = DEFAULT_SPACING,
               patch: int = 15, interpolation: str = DEFAULT_INTERPOLATION,
               epipolar: bool | None = None, min_texture_snr: float = 2.0, mask=None,
               sgbm_block: int = 5, second_order: bool = True,
               adaptive_patch: bool | str | tuple = True,
               max_patch: int | None = None, max_sigma_mad_k: float | None = 4.0,
               eccentric: bool = False, grow: bool = True, sigma_factor: bool = True,
               search_range: tuple[int, int] | None = None,
               footprint_var: float | None = DEFAULT_FOOTPRINT_VAR,
               densify: bool | str = False, robust: bool | str = False,
               unique: bool = True, epipolar_pass: bool = False,
               regrow_ambiguous: bool = True, centre_points: bool = True,
               aperture_k: float | None = 1.0, **lsm_options) -> PairMatches:
    """Match a stereo pair densely by LSM.

    Parameters
    ----------
    left_img, right_img : (H, W) or (H, W, 3) array_like, or matching.lsm.PreparedImage
        The images (colour is converted to grey, OpenCV's BGR order); a
        :class:`~matching.lsm.PreparedImage` for ``interpolation`` is not refiltered.
    rig : matching.cameras.StereoRig, optional
        Calibration; required unless ``rectified``.
    rectified : bool
        The images are already rectified (corresponding points share a row).
    spacing : int
        One candidate per ``spacing`` x ``spacing`` cell, px.
    patch : int
        LSM patch side, px (odd).
    interpolation : {"bilinear", "bicubic", "spline"}
        LSM resampler.
    epipolar : bool, optional
        Constrain the LSM shift to the epipolar direction (default: yes for a
        rectified pair, no for a calibrated one, whose y-parallax then checks the
        calibration in the triangulation's χ² test).
    min_texture_snr : float
        Texture threshold factor (:func:`matching.seeds.select_points`).
    mask : (H, W) bool, optional
        Only left pixels where true are candidates.
    sgbm_block : int
        SGBM block side, px.
    second_order : bool
        Run LSM twice: the second pass adds the fixed second-order warp terms that
        :func:`matching.second_order.second_order_terms` derives from the first pass's affine
        parameters within ``max(20, 5 spacing)`` px (removes the curvature bias of an
        affine patch fit: 0.023 px -> 0.001 px on the noise-free vase, 15 px patches).
    adaptive_patch : bool, "ici", "population" or tuple of int
        Second pass with a patch grown, where the first pass's σ is worse than the
        image's median, to the smallest side whose predicted σ reaches that median
        (:func:`adaptive_sides`; Gruen's "adaptive" patch).  Default on.  ``"ici"``: the
        second pass at every side of ``patch``, ~1.5x and ~2x it
        (:func:`matching.ici.ici_ladder`), each point keeping the largest side that agrees
        with every smaller one within ±2σk (:mod:`matching.ici`); a tuple: those sides
        (odd, increasing).  ``"population"``: Gruen's sides, then the sides of the ICI
        ladder above them, each window class (``edge`` or not) grown to the largest side
        whose departures from the smaller ones stay within the mean-square-error balance
        in the class's core (:func:`matching.ici.population_sides`), a point only where
        its grown window is accepted and clear of edges (:mod:`matching.ici`, *Population
        rule*: graffiti and the rendered vase gain, the temple ring loses; not the
        default).  Each side costs one second pass.
    max_patch : int, optional
        Largest grown side, px (odd; default: the largest odd side with at most twice
        the pixels of ``patch``, 21 for 15).
    max_sigma_mad_k : float or None
        Reject (``imprecise``) accepted matches whose σ exceeds the median σ of the
        accepted matches by more than k robust spreads (1.4826 MAD, at least
        median/sqrt(2(patch² - 8))); default 4, as the σ0 test; None: no precision test.
    eccentric : bool
        Candidates whose window holds a textureless cell (a silhouette, a rim, an
        untextured region) are matched with the window moved off it and the point
        transferred through the warp (:func:`matching.seeds.window_offsets`,
        ``lsm_match``'s ``offset``); their σ includes the transfer's share of the
        affine unknowns but not the warp model's own error over the transfer, so they
        err more than σ says (measured on the 1024x768 ring, pair (0, 1): 7 % of the
        points, RMS 0.090 px against 0.031 px for centred windows, error/σ 1.74 against
        1.39; 320x240: 20 %, 0.21 px, 3.2).  Default off here: a single pair has no
        further view to confirm them; :func:`matching.multiview.reconstruct_view_pair`
        turns it on (its points reach a rim to within about a pixel instead of half
        a window).
    densify : {False, True, "auto"}
        Rectified pairs: a second candidate lattice, shifted by half a cell, matched
        where the four first-lattice matches around each of its candidates were
        accepted with centred windows, started from their affine warps (:func:`_densify`).
        True: at every such candidate; ``"auto"``: only as many as the first lattice
        falls short of the requested density (one point per ``spacing`` x ``spacing``
        cell) on the matched surface, nearest its holes first (:func:`density_deficit`:
        nothing where every candidate of the matched surface gave a point); default
        False here (:func:`matching.multiview.reconstruct_view_pair` defaults to
        ``"auto"``).
    grow : bool
        Region growing (:func:`matching.grow.grow_matches`, Otto & Chau 1989): candidates
        without an SGBM approximation, or whose SGBM start failed, are matched from the
        affine warps of their accepted neighbours (default on); off: they stay
        ``no_approximation`` / their first status.
    sigma_factor : bool
        Scale the covariances by the variance factor k² that independent neighbouring
        windows give (:func:`matching.precision.midpoint_variance_factor`: two windows
        a patch apart predict their midpoint through their own affine warps, which
        agree for any locally quadratic surface): what real images add to σ0²N⁻¹
        (correlated noise, blur and shading differences, model error), one factor for
        the windows clear of an edge and one for the ``edge`` windows
        (:func:`matching.precision.class_variance_factors`: two populations; pooled, the
        temple pairs' clear windows erred 0.30 of their σ k by the cross-pair check of
        ``benchmarks/matching.py --part temple``).  Never below 1
        (σ0²N⁻¹ is the white-noise bound); needs >= 30 window pairs (a class with
        fewer: the pooled factor; fewer overall: k² = 1).
        Default on (measured, ``benchmarks/matching.py``: rendered vase pair 1024x768
        k² 1.27, actual / reported σ 1.27 -> 1.01; 320x240 with 1 px correlated noise
        9.5, 3.0 -> 0.98; graffiti 7.1; temple pairs 10.5-76).  It cannot see what every
        window shares -- a relief finer than the window, which each window smooths
        alike (rendered ripple: actual / reported still 2.2 with k² 9.9).
    search_range : (int, int), optional
        SGBM's (min_disparity, num_disparities) of a rectified pair, from the geometry
        (:func:`matching.search_range.pair_disparity_range`); default: from SIFT
        matches.
    footprint_var : float or None
        Shape-adapted smoothing of the template where the right view is foreshortened
        (``lsm_match``'s ``footprint_var``; the affine start of the growth and of the
        second pass sets it, the first pass starts from the identity); default
        ``matching.lsm.DEFAULT_FOOTPRINT_VAR`` (graffiti wall: the figures with and
        without it are ``benchmarks/matching.py``'s, in benchmarks/README.md); None: off.
    robust : {False, True, "edge"}
        Robust LSM (``lsm_match``'s ``robust``: Tukey IRLS from the equal-weight solution,
        least squares over the pixels that follow one warp) for every window (True), for
        the ``edge`` windows only ("edge"), or none (False, default: on a rendered ring the
        edge windows it adds err 0.21-0.25 px RMS, 3-13 % beyond 3σ, while those both
        accept improve, e.g. 0.099 -> 0.086 px; README, *Robust LSM*).  The region growing
        stays equal-weight; the second pass re-matches every window with it.  With
        ``eccentric`` the windows moved off their edge are not ``edge`` windows here.
    unique : bool
        Uniqueness along the epipolar line (default on): every accepted match is checked
        for a rival over the pair's disparity search range (:func:`matching.uniqueness.
        verify_matches`), an ambiguous one kept only where its unique neighbours pin it
        (:func:`matching.uniqueness.anchored`), and every survivor's backward
        (right-to-left) LSM loop must close (:func:`_loop_closes`).  Measured
        (``benchmarks/matching.py --part chessboard``, docs/decisions/stereo-uniqueness.md):
        a real chessboard pair's points one period or more off the board 8.7 % -> 0.5 %;
        a temple pair's accepted share 77.1 % -> 66.4 %.  With the epipolar pass the test
        runs in the rectified frame with the constrained matcher and is strict (a rival
        within the noise margin that the matcher does not refute rejects the match;
        :func:`_verify_unique_rectified`), the survivors' σ along the line includes the
        rivals' mixture variance, the backward loop is constrained too
        (:func:`_loop_closes_rectified`), and the growth runs from verified matches only
        (:func:`_grow_verified`).
    epipolar_pass : bool
        Calibrated pairs (default off here; ``photosurf stereo`` and ``photosurf match
        --rig`` turn it on): every window LSM tried is matched again in the
        rectified images with the y-shift fixed by the rig -- shift and shape along the row
        only (:func:`_epipolar_refine`) -- and rejected as ``aperture`` where it is
        ill-conditioned along the line; the covariance is then rank 1 along the line.
        Measured on the real chessboard rig (``benchmarks/matching.py --part chessboard``,
        docs/decisions/stereo-epipolar.md): blunders 20-70 % -> 0-9 % per pair, at the cost
        of points; on the rendered vase the error along the line 0.0376 -> 0.0404 px and σ
        less honest on a specular highlight (actual / reported 1.66 against <= 1.45), so not
        the library default (nor multiview's).
    regrow_ambiguous : bool
        Epipolar pass: grow the ambiguous windows again from verified neighbours too, not
        only those that failed from their approximation (:func:`_grow_verified`).  Default
        on: with one-edge windows reported at their edge and the matches off their
        neighbours' plane rejected, it adds points on the chessboard rig and no blunders
        (pairs 03/04/12, one-signed windows in one class: 1529/263/252 -> 1833/483/423
        board points, blunders 1.0/1.1/2.0 -> 1.1/0.8/1.2 %; docs/decisions/stereo-edges.md).
    centre_points : bool
        Epipolar pass: report each accepted match at the left pixel nearest its window's
        information centre (where the warp's shift is best determined; ``x_left`` moves
        off the candidate lattice by up to half a window, ``offset`` keeps the window
        centre) instead of at the candidate (:func:`_information_centres`).  Default on.
    aperture_k : float or None
        The ``aperture`` test's bound on the rig's row error carried through the window's
        edge slope, in units of the match's own σ along the line (default 1: it may not
        exceed it); None: that part of the test off.
    **lsm_options
        Passed to :func:`matching.lsm.lsm_match` (``max_iter``, ``sigma0_factor``...).

    Returns
    -------
    PairMatches

    Raises
    ------
    ValueError
        Images of different sizes or not matching the rig, no rig and not rectified,
        no overlap between the views.
    """
    if not (isinstance(patch, int | np.integer) and patch >= 5 and patch % 2 == 1):
        raise ValueError(f"patch must be an odd integer >= 5, got {patch!r}")
    if not (isinstance(spacing, int | np.integer) and spacing >= 1):
        raise ValueError(f"spacing must be a positive integer, got {spacing!r}")
    ladder = None
    population = isinstance(adaptive_patch, str) and adaptive_patch == "population"
    if isinstance(adaptive_patch, str) and adaptive_patch == "ici":
        from matching.ici import ici_ladder
        ladder = ici_ladder(patch)
    elif isinstance(adaptive_patch, tuple | list):
        ladder = tuple(int(side) for side in adaptive_patch)
        if (len(ladder) < 2 or ladder != tuple(sorted(set(ladder)))
                or any(side < 5 or side % 2 == 0 for side in ladder)):
            raise ValueError(f"adaptive_patch sides must be odd, >= 5 and increasing, got "
                             f"{adaptive_patch!r}")
    elif not (isinstance(adaptive_patch, bool) or population):
        raise ValueError(f"adaptive_patch must be True, False, 'ici', 'population' or a tuple "
                         f"of sides, got {adaptive_patch!r}")
    if max_patch is not None and not (isinstance(max_patch, int | np.integer)
                                      and max_patch >= patch and max_patch % 2 == 1):
        raise ValueError(f"max_patch must be an odd integer >= patch ({patch}), "
                         f"got {max_patch!r}")
    if max_sigma_mad_k is not None and not (np.isfinite(max_sigma_mad_k)
                                            and max_sigma_mad_k > 0):
        raise ValueError(f"max_sigma_mad_k must be positive or None, got {max_sigma_mad_k!r}")
    if not (isinstance(robust, bool | np.bool_) or robust == "edge"):
        raise ValueError(f"robust must be True, False or 'edge', got {robust!r}")
    if not (isinstance(densify, bool | np.bool_) or densify == "auto"):
        raise ValueError(f"densify must be True, False or 'auto', got {densify!r}")
    corr = lsm_options.get("min_correlation", 0.7)
    if not (np.isfinite(corr) and -1.0 <= corr <= 1.0):
        raise ValueError(f"min_correlation must be in [-1, 1], got {corr!r}")
    # PreparedImage inputs (same interpolation) are used as they are, not refiltered
    preps = [img if isinstance(img, PreparedImage) and img.interpolation == interpolation
             else None for img in (left_img, right_img)]
    left = _grey(left_img.raw if isinstance(left_img, PreparedImage) else left_img,
                 "left image")
    right = _grey(right_img.raw if isinstance(right_img, PreparedImage) else right_img,
                  "right image")
    if rig is None and not rectified:
        raise ValueError("give a rig (calibrated pair) or rectified=True")
    if rectified and left.shape != right.shape:
        raise ValueError(f"images must have the same size, got left {left.shape[1]}x"
                         f"{left.shape[0]} and right {right.shape[1]}x{right.shape[0]}")
    if rig is not None and not rectified:
        for name, img, cam in (("left", left, rig.left), ("right", right, rig.right)):
            if (img.shape[1], img.shape[0]) != cam.size:
                raise ValueError(f"{name} image is {img.shape[1]}x{img.shape[0]} px but the rig's "
                                 f"{name} camera is {cam.size[0]}x{cam.size[1]} px")
    epipolar = rectified if epipolar is None else bool(epipolar)
    cand = select_points(left, spacing=spacing, patch=patch, min_texture_snr=min_texture_snr,
                         mask=mask, noise=None if preps[0] is None else preps[0].noise)
    n = len(cand.points)
    offset, edge = np.zeros((n, 2)), np.zeros(n, bool)
    status = np.full(n, Status.TEXTURELESS, np.uint8)
    out = {
        "x_right": np.full((n, 2), np.nan), "approx": np.full((n, 2), np.nan),
        "cov": np.full((n, 2, 2), np.nan), "sigma": np.full(n, np.nan),
        "sigma0": np.full(n, np.nan), "correlation": np.full(n, np.nan),
        "iterations": np.zeros(n, np.int32), "affine": np.full((n, 6), np.nan),
        "radiometric": np.full((n, 2), np.nan), "patch": np.zeros(n, np.int32),
    }
    factor, factor_edge, deficit, densified = 1.0, 1.0, 0, 0
    x_left_out = None  # the candidates' pixels, or where the epipolar pass reports them
    textured = np.flatnonzero(cand.textured)
    if len(textured):
        rect = None if rectified else rectify(rig)

        def approximate(pts, reuse=None):
            if rectified:
                return approximate_rectified(left, right, pts, block=sgbm_block, patch=patch,
                                             reuse=reuse, search_range=search_range)
            return approximate_calibrated(rig, left, right, pts, rect=rect, block=sgbm_block,
                                          patch=patch, reuse=reuse)

        approx = approximate(cand.points[textured])
        x_right, direction_all = approx.x_right.copy(), approx.direction.copy()
        # windows reaching into an untextured region or pixels SGBM left unmatched
        # (background, occlusions): moved off them and approximated at their new centres
        # (eccentric), else only flagged (``edge``)
        # (the SGBM map of a calibrated pair is taken back to the left image only when
        # windows are moved: its full-grid undistortion costs ~1 s at 1024x768)
        valid = (disparity_valid_left(approx, left.shape, None if rectified else rig, rect)
                 if rectified or eccentric else None)
        offset, edge = window_offsets(cand, left, patch, spacing, mask, valid,
                                      move=eccentric)
        if eccentric:
            moved = np.flatnonzero(np.any(offset[textured] != 0.0, axis=1))
            if len(moved):
                again = approximate(cand.points[textured[moved]] + offset[textured[moved]],
                                    reuse=approx)
                x_right[moved], direction_all[moved] = again.x_right, again.direction
        centres = cand.points + offset  # window centres
        has = np.isfinite(x_right).all(1) & np.isfinite(direction_all).all(1)
        x_right[~has] = np.nan
        if grow:
            idx = textured
        else:
            status[textured[~has]] = NO_APPROXIMATION
            idx = textured[has]
        out["approx"][textured] = x_right
        if len(idx):
            fprep = preps[0] if preps[0] is not None else prepare_image(left, interpolation)
            gprep = preps[1] if preps[1] is not None else prepare_image(right, interpolation)
            sub = has if not grow else np.ones(len(textured), bool)
            points, start = centres[idx], x_right[sub]
            shifted = np.any(offset[idx] != 0.0, axis=1)
            direction = _fill_directions(points, direction_all[sub]) if epipolar else None
            # a rectified pair maps rows to rows: the window's shape across them is
            # geometry, not an unknown (lsm_match's rigid_across)
            lsm_options.setdefault("rigid_across", bool(rectified and epipolar))
            options = dict(patch=patch, interpolation=interpolation, direction=direction,
                           min_texture_snr=min_texture_snr, footprint_var=footprint_var,
                           **lsm_options)
            if shifted.any():
                options["offset"] = -offset[idx]
            # "edge": the edge windows left where they are (an eccentric window was
            # moved off its edge)
            robust_flags = (edge[idx] & ~shifted if robust == "edge" else
                            np.full(len(idx), bool(robust)))
            res = lsm_match(fprep, gprep, points, start, robust=robust_flags, **options)
            if grow and res.accepted.any():
                # approximations from accepted neighbours (their affine warps) for the
                # candidates SGBM gave none, or whose SGBM start failed
                growth = grow_matches(
                    fprep, gprep, points, res, start,
                    candidates=res.status != Status.TEXTURELESS, same_row=bool(rectified),
                    **options)
                res, start = growth.result, growth.approx
                out["approx"][idx] = start
            if grow:
                unapproximated = ~np.isfinite(start).all(1)
            sides = np.full(len(points), patch, np.int32)
            population_grown = False
            quad = None
            # a calibrated pair's epipolar pass re-matches every window with its own
            # second-order terms and grown sides: the 2-D second pass would be redone
            epipolar_next = epipolar_pass and not rectified
            if ((second_order or adaptive_patch) and res.accepted.sum() >= 8
                    and not epipolar_next):
                quad = (second_order_terms(points, res.affine, res.accepted,
                                           radius_px=max(20.0, 5.0 * spacing))
                        if second_order else None)
                if adaptive_patch and ladder is None:
                    sides = adaptive_sides(left, points, res.window_sigma, res.accepted,
                                           patch, max_patch, noise=fprep.noise)
                    # a grown eccentric window would reach over the edge it was moved off
                    sides[shifted] = patch
                options["robust"] = robust_flags
                if ladder is not None:
                    second, sides = _rematch_ici(fprep, gprep, points, start, res, quad,
                                                 ladder, options, shifted, edge[idx])
                else:  # the accepted windows: a rejected one was tried from its start
                    # and by growth from up to two neighbours (acquire-profile decision)
                    second = _rematch(fprep, gprep, points, start, res, quad, sides, options,
                                      only=res.accepted, into=res)
                # a grown window that fails (its search window leaves the image, or it
                # reaches over a depth or shading edge the base window stays clear of):
                # back to the base patch -- growing is for precision, not to lose points
                failed_grown = (second.status != Status.OK) & (sides != patch)
                if failed_grown.any():
                    sides[failed_grown] = patch
                    second = _rematch(fprep, gprep, points, start, res, quad, sides,
                                      options, only=failed_grown, into=second)
                # a first-pass match the refinement loses (second-order terms taken from
                # neighbours across a depth edge) keeps its first-pass result, which
                # passed the same tests
                lost = res.accepted & (second.status != Status.OK)
                if lost.any():
                    second = _keep_first(second, res, lost)
                    sides[lost] = patch
                if population:
                    clear_at = _clear_at_sides(cand, left, patch, spacing, mask, valid,
                                               idx, int(sides.max()))
                    second, sides, population_grown = _grow_population(
                        fprep, gprep, points, start, res, quad, second, sides, patch,
                        options, shifted, edge[idx], clear_at)
                res = second
            geo_var, first_pass = None, None
            if epipolar_pass and not rectified and res.accepted.sum() >= 30:
                # Gruen & Baltsavias' geometric constraint: the y-shift is the rig's,
                # only the shift and shape along the epipolar line are solved
                first_pass = res
                res, geo_var, epi_dirs, sides, epi_factor, frame = _epipolar_refine(
                    left, right, rig, rect, points, start, res, sides, options, aperture_k,
                    interpolation, second_order=second_order, spacing=spacing,
                    classes=edge[idx], scale_cov=bool(sigma_factor),
                    at_best_point=centre_points)
                status_ill = res.accepted & ~np.isfinite(geo_var)
                res = replace(res, status=np.where(status_ill, APERTURE, res.status)
                              .astype(res.status.dtype))
            verdict, rival_var = None, None
            if unique and res.accepted.any():
                if first_pass is not None:
                    verdict, rival_var = _verify_unique_rectified(frame, points, res,
                                                                  approx.range, patch)
                else:
                    verdict = _verify_unique(left, right, rig, rect, rectified, fprep,
                                             gprep, points, res, approx.range, patch,
                                             options)
            status[idx] = res.status
            if verdict is not None:
                status[idx[verdict == uniqueness.AMBIGUOUS]] = AMBIGUOUS
                status[idx[verdict == uniqueness.BLANK]] = BLANK
                survivors = verdict == uniqueness.UNIQUE
                closes = (_loop_closes_rectified(frame, survivors) if first_pass is not None
                          else _loop_closes(fprep, gprep, points, res, survivors, patch,
                                            options))
                status[idx[survivors & ~closes]] = BACKWARD
            if grow:
                status[idx[unapproximated]] = NO_APPROXIMATION
            if rival_var is not None:
                # what the rivals along the line leave (rectified px² -> right px²); a
                # match whose uncertainty they dominate -- more than the texture and the
                # rig leave -- is not unique at any precision it could claim
                rival_stretch = np.ones(len(idx))
                rival_stretch[frame["index"]] = np.nan_to_num(frame["stretch"], nan=1.0)
                own = np.einsum("ni,nij,nj->n", epi_dirs, res.cov, epi_dirs)
                dominated = rival_var * rival_stretch > own + np.nan_to_num(geo_var)
                status[idx[(status[idx] == Status.OK) & dominated]] = AMBIGUOUS
            if first_pass is not None and unique and grow:
                def refine(start_, sub, sides_):
                    return _epipolar_refine(
                        left, right, rig, rect, points, start_, sub, sides_, options,
                        aperture_k, interpolation, second_order=second_order,
                        spacing=spacing, classes=edge[idx], scale_cov=bool(sigma_factor),
                        fixed=frame, at_best_point=centre_points)

                local = status[idx].copy()
                res, grown_mask = _grow_verified(local, points, res, frame, geo_var, epi_dirs,
                                                 sides, refine, patch,
                                                 reach=max(patch / 2.0, 1.5 * spacing),
                                                 ambiguous=regrow_ambiguous)
                status[idx] = local
                # pinned by their verified neighbours within the pull-in range: the
                # rivals a period away are excluded
                rival_var[grown_mask] = 0.0
            if first_pass is not None:
                local = status[idx].copy()
                res, epi_dirs, offset, x_left_out, polarity_var = _report_epipolar(
                    frame, rect, rig, res, epi_dirs, local, cand.points, idx, points, offset,
                    x_left_out, left.shape[1], centre_points, bool(sigma_factor))
                status[idx] = local
            out["patch"][idx] = sides
            if max_sigma_mad_k is not None:
                status[idx[_imprecise(res, max_sigma_mad_k, patch,
                                      None if ladder is None and not population_grown
                                      else sides)]] = IMPRECISE
            factor, factor_edge, per_window = 1.0, 1.0, np.ones(len(idx))
            if sigma_factor:
                ok_final = status[idx] == Status.OK
                # σ0²N⁻¹ is the white-noise precision, a lower bound: what real images
                # add only grows it (an estimate below 1 is the estimator's own scatter,
                # ~10 % for a few thousand matches); windows clear of and reaching over
                # an edge are two populations (class_variance_factors)
                if first_pass is None:
                    per_window, factors = class_variance_factors(
                        points, res.affine, res.affine_cov, ok_final,
                        edge[idx].astype(np.int64), patch=sides)
                else:  # the epipolar pass's covariances carry their own factors
                    per_window, factors = np.ones(len(idx)), np.array(epi_factor)
                factor = float(factors[0]) if len(factors) else 1.0
                factor_edge = float(factors[1]) if len(factors) > 1 else factor
            out["x_right"][idx] = res.position
            out["cov"][idx] = res.cov * per_window[:, None, None]
            if geo_var is not None:
                # what the rig's epipolar error leaves along the line (_epipolar_refine)
                along = np.nan_to_num(geo_var) + polarity_var
                if rival_var is not None:
                    # what the rivals along the line leave (rectified px² -> right px²);
                    # a match whose uncertainty they dominate -- more than the texture and
                    # the rig leave -- is not unique at any precision it could claim
                    along = along + rival_var * rival_stretch
                out["cov"][idx] += (along[:, None, None]
                                    * epi_dirs[:, :, None] * epi_dirs[:, None, :])
            out["sigma"][idx] = np.sqrt(np.trace(out["cov"][idx], axis1=1, axis2=2) / 2.0)
            if geo_var is not None and max_sigma_mad_k is not None:
                # the precision test again on the σ reported, with what the rig, the
                # rivals and the edges leave along the line
                status[idx[_above_limit(out["sigma"][idx], status[idx] == Status.OK,
                                        max_sigma_mad_k, patch)]] = IMPRECISE
            out["sigma0"][idx] = res.sigma0
            out["correlation"][idx] = res.correlation
            out["iterations"][idx] = res.iterations
            out["affine"][idx] = res.affine
            out["radiometric"][idx] = res.radiometric
            if densify and rectified and spacing >= 2 and res.accepted.sum() >= 30:
                quad_all = None
                if second_order and quad is not None:
                    quad_all = np.full((n, 6), np.nan)
                    quad_all[idx] = quad
                n_first = len(status)
                dense = _densify(left, fprep, gprep, cand, status, edge, offset, out,
                                 res, spacing, patch, mask, valid, quad_all,
                                 max_sigma_mad_k, factor, options, auto=densify == "auto")
                cand, status, edge, offset, out, deficit = dense
                densified = len(status) - n_first
    return PairMatches(x_left=cand.points if x_left_out is None else x_left_out,
                       texture=cand.texture, status=status,
                       rectified=bool(rectified), image_size=(left.shape[1], left.shape[0]),
                       offset=offset, edge=edge, sigma_factor=float(factor),
                       sigma_factor_edge=float(factor_edge),
                       density_deficit=int(deficit), densified=int(densified), **out)


def _verify_unique(left, right, rig, rect, rectified, fprep, gprep, points, res: LSMResult,
                   search_range, patch: int, options: dict) -> np.ndarray:
    """(N,) uint8 :mod:`matching.uniqueness` verdict per match after the ambiguous ones
    were given their chance to be resolved by unique neighbours (:func:`uniqueness.anchored`).

    The profiles run in the rectified frame (the given images for a rectified pair);
    the rivals are re-matched by the first pass's matcher (base ``patch``, no
    second-order terms) in the original images.
    """
    from matching.rectify import (
        left_to_rectified,
        rectified_to_original,
        rectify_images,
        right_to_rectified,
    )

    ok = res.accepted
    xr_rect = np.full((len(points), 2), np.nan)
    if rectified:
        left_rect, right_rect, xl_rect = left, right, points
        xr_rect[ok] = res.position[ok]

        def to_right(p):
            return p
    else:
        left_rect, right_rect = rectify_images(rect, left, right)
        xl_rect = left_to_rectified(rect, rig.left, points)
        xr_rect[ok] = right_to_rectified(rect, rig.right, res.position[ok])

        def to_right(p):
            return rectified_to_original(rect, rig.right, p)

    def match(index, start, init, population, direction):
        opts = {k: v for k, v in options.items() if v is not None and k != "quadratic"}
        opts["direction"] = direction
        opts["max_shift_px"] = float(patch)
        for key in ("offset", "robust"):  # per-window options
            if key in opts and np.ndim(opts[key]) >= 1 and len(opts[key]) == len(points):
                opts[key] = np.asarray(opts[key])[index]
        return lsm_match(fprep, gprep, points[index], start, initial=init,
                         sigma0_population=population, **opts)

    ver = uniqueness.verify_matches(match, points, res, left_rect, right_rect, xl_rect,
                                    xr_rect, to_right, search_range, fprep.noise, patch,
                                    float(options.get("min_correlation", 0.7)))
    verdict = ver.verdict.copy()
    solution = xl_rect[:, 0] - xr_rect[:, 0]
    ambiguous = verdict == uniqueness.AMBIGUOUS
    if ambiguous.any():
        # anchors: unique with no rival peak in the profile at all (a unique verdict
        # whose rival re-match failed may still be the slip: pair 02, 30 of 284 slips)
        anchors = ok & (verdict == uniqueness.UNIQUE) & (ver.peaks_tried == 0)
        resolved = uniqueness.anchored(points, res.position, res.sigma, res.affine,
                                       anchors, ambiguous & ok, radius=float(patch),
                                       max_offset=np.minimum(solution - ver.lobe[:, 0],
                                                             ver.lobe[:, 1] - solution))
        verdict[resolved] = uniqueness.UNIQUE
    return verdict


def _verify_unique_rectified(frame: dict, points, res: LSMResult, search_range,
                             patch: int) -> tuple[np.ndarray, np.ndarray]:
    """Uniqueness of the epipolar pass's matches, judged in the rectified frame by the
    matcher that made them (:mod:`matching.uniqueness` ``strict``).

    Every separated peak of the plain ZNCC profile along the row that is as good as the
    solution's within the noise margin (or better) makes the match ambiguous unless the
    constrained matcher, started there with the solution's shape and radiometry, refutes
    it.  Ambiguous matches are not resolved by their neighbours here (measured on the
    chessboard rig, pair 06: the 228 that :func:`matching.uniqueness.anchored` would pin
    put 13.6 % of themselves beyond the blunder band against 4.3 % of the rest): the
    region growing from verified matches (:func:`_grow_verified`) is where geometry
    pins a window.  Returns the (N,) verdicts and (N,) variance the rivals leave along
    the row (rectified px², ``Verification.rival_var``).
    """

    n = len(points)
    ok = frame["index"]
    status = np.where(res.status[ok] == Status.OK, 0, 1)
    sub = SimpleNamespace(status=status, sigma0=frame["sigma0"],
                          correlation=frame["correlation"])
    shape = np.concatenate([frame["affine"], frame["radiometric"]], axis=1)
    fprep, gprep, frac = frame["fprep"], frame["gprep"], frame["frac"]
    sides = frame["sides"]

    def match(index, start, init, population, direction):
        # the rival's window centre on the template's pixel grid (the point is eccentric
        # by ``frac``), the search centre moved by the shape
        a0 = start[:, 0] - init[:, 1] * frac[index, 0] - init[:, 2] * frac[index, 1]
        init = init.copy()
        init[:, 0], init[:, 3] = a0, frame["centre"][index, 1]
        init[:, 4], init[:, 5] = 0.0, 1.0
        approx = init[:, [0, 3]]
        status_r = np.full(len(index), Status.PULL_IN, np.uint8)
        position = np.full((len(index), 2), np.nan)
        corr = np.full(len(index), np.nan)
        opts = dict(frame["opts"])
        opts["max_shift_px"] = float(patch) / 4.0
        for side in np.unique(sides[index]):
            sel = np.flatnonzero(sides[index] == side)
            opts["patch"] = int(side)
            r = lsm_match(fprep, gprep, frame["centre"][index[sel]], approx[sel],
                          initial=init[sel], direction=(1.0, 0.0), rigid_across=True,
                          offset=frac[index[sel]], sigma0_population=population, **opts)
            status_r[sel], position[sel], corr[sel] = r.status, r.position, r.correlation
        return SimpleNamespace(status=status_r, position=position, correlation=corr)

    ver = uniqueness.verify_matches(match, frame["xl"], sub, fprep.raw, gprep.raw,
                                    frame["xl"], frame["position"], lambda q: q,
                                    search_range, fprep.noise, patch,
                                    float(frame["opts"].get("min_correlation", 0.7)),
                                    shape=shape, strict=True)
    verdict = np.full(n, uniqueness.OUTSIDE, np.uint8)
    verdict[ok] = ver.verdict
    rival_var = np.zeros(n)
    rival_var[ok] = ver.rival_var
    return verdict, rival_var


def _structure_tensors(image: np.ndarray, points: np.ndarray, sides: np.ndarray) -> np.ndarray:
    """(N, 2, 2) mean structure tensor (central differences) of each ``sides`` x ``sides``
    window of ``image`` centred on the integer ``points``."""
    import cv2

    img = np.asarray(image, dtype=np.float64)
    gx = np.zeros_like(img)
    gy = np.zeros_like(img)
    gx[:, 1:-1] = 0.5 * (img[:, 2:] - img[:, :-2])
    gy[1:-1, :] = 0.5 * (img[2:, :] - img[:-2, :])
    xi = np.rint(points).astype(np.intp)
    xi[:, 0] = np.clip(xi[:, 0], 0, img.shape[1] - 1)
    xi[:, 1] = np.clip(xi[:, 1], 0, img.shape[0] - 1)
    out = np.zeros((len(points), 2, 2))
    for side in np.unique(sides):
        sel = np.flatnonzero(sides == side)
        box = [cv2.boxFilter(p, -1, (int(side), int(side)), borderType=cv2.BORDER_REFLECT)
               for p in (gx * gx, gx * gy, gy * gy)]
        vals = [b[xi[sel, 1], xi[sel, 0]] for b in box]
        out[sel] = np.stack([np.stack([vals[0], vals[1]], -1),
                             np.stack([vals[1], vals[2]], -1)], -2)
    return out


def _jacobians(fn, points: np.ndarray, step: float = 0.5) -> np.ndarray:
    """(N, 2, 2) central-difference Jacobians of the point map ``fn`` at ``points``."""
    cols = [(fn(points + e) - fn(points - e)) / (2.0 * step)
            for e in (np.array([step, 0.0]), np.array([0.0, step]))]
    return np.stack(cols, axis=2)


def _odd_at_least(value) -> np.ndarray:
    """Smallest odd integers >= ``value`` (array_like)."""
    side = np.ceil(np.asarray(value, dtype=np.float64) - 1e-9).astype(np.int32)
    return side + 1 - side % 2


def _epipolar_refine(left, right, rig, rect, points, start, res: LSMResult, sides,
                     options: dict,
                     aperture_k: float | None, interpolation: str,
                     max_inflation: float | None = MAX_INFLATION, grow_sides=(1.5, 2.0),
                     second_order: bool = True, spacing: int = DEFAULT_SPACING,
                     classes=None, scale_cov: bool = True, fixed: dict | None = None,
                     at_best_point: bool = True):
    """LSM constrained to the epipolar line of a calibrated pair (Gruen & Baltsavias 1988).

    Every window LSM tried (the 2-D solution where it was accepted, else the approximation
    ``start``) is matched again in the rectified images (cubic B-spline resampling at the
    maps' exact coordinates), where the y-shift is the rig's: the template on the rectified
    pixel grid with the left point reported through the warp (``offset``), the search
    window started on the left point's row, the 2-D warp taken into the rectified frame
    through the rectifications' Jacobians (Jr A Jl⁻¹), and only the shift and the shape
    along the row solved with the radiometry (``lsm_match``'s ``direction`` (1, 0) +
    ``rigid_across``: rows map to rows, exact), then once more with fixed second-order
    terms along the row from the neighbours (``second_order``).

    Ill-conditioned along the line (``aperture``), tried again at ``grow_sides`` x the
    side (a window reaching the texture's next corner is conditioned), rejected if still:

    * the shape unknowns take the shift's information: its variance exceeds
      ``max_inflation`` x σ0² / Σ f_x², what the template's x-gradients alone give (a
      single edge off the window's centre trades the shift for the scale along the row),
      at the window's least-variance point where that is inside it and ``at_best_point``
      (the match is reported there, :func:`_information_centres`; a window reported
      elsewhere is tested again where it is, :func:`_shape_dominated`), else at its centre;
    * the rig's own row error δy, moved by the edge slope ``|N_xy / N_xx|`` of the window's
      structure tensor into the column, exceeds ``aperture_k`` x the match's σ along the
      line (δy's spread σ_g: 1.4826 MAD of the accepted 2-D matches' rectified row
      differences over windows textured in both directions, λmin/λmax >= 1/4).

    Returns the result in the original images (rank-1 covariance along the line, with the
    constrained matches' own variance factor per window class ``classes``, unless
    ``scale_cov`` is off; a window the pass loses keeps its rejection), the variance
    ``(slope σ_g)²`` along the line (px²; NaN: ``aperture``), the (N, 2) line directions
    in the right image, the sides used, the variance factors (clear windows, edge
    windows) and the rectified frame's matches (a dict of (N, ...) arrays, NaN where the
    pass did not run, with the prepared rectified images; ``fixed``: σ_g and the
    variance factors taken from an earlier call's frame instead of estimated).
    """
    from matching.rectify import (
        left_to_rectified,
        rectified_to_original,
        rectify_images,
        right_to_rectified,
    )

    n = len(points)
    accepted = res.accepted
    # every window LSM tried from an approximation: the 2-D solution where it was
    # accepted, else the approximation (a 2-D window sliding along an edge fails the
    # pull-in test that the constrained one passes)
    tried = accepted | (np.isfinite(start).all(1) & ~np.isin(
        res.status, (Status.TEXTURELESS, Status.OUTSIDE_IMAGE)))
    ok = np.flatnonzero(tried)
    from_2d = accepted[ok]
    x_start = np.where(from_2d[:, None], res.position[ok], start[ok])
    xl_r = left_to_rectified(rect, rig.left, points[ok])
    xr_r = right_to_rectified(rect, rig.right, x_start)
    dy = (xr_r[:, 1] - xl_r[:, 1])[from_2d]
    if fixed is not None and "fprep" in fixed:  # the earlier call's rectified pair
        left_r, right_r = fixed["fprep"].raw, fixed["gprep"].raw
    else:
        left_r, right_r = rectify_images(rect, left, right, interpolation="spline")
    jl = _jacobians(lambda p: left_to_rectified(rect, rig.left, p), points[ok])
    jr = _jacobians(lambda p: right_to_rectified(rect, rig.right, p), x_start)
    # the 2-D warp (template -> search) in the rectified frame: Jr A Jl⁻¹ (A = I
    # from an approximation)
    amat = np.tile(np.eye(2), (len(ok), 1, 1))
    amat[from_2d] = res.affine[ok[from_2d]][:, [1, 2, 4, 5]].reshape(-1, 2, 2)
    a_rect = jr @ amat @ np.linalg.inv(jl)
    init = np.zeros((len(ok), 8))
    # the template window on the rectified image's pixel grid (a template resampled at a
    # fraction of a pixel smooths its noise: σ0²N⁻¹ would under-report), the left point
    # reported through the warp as an eccentric pixel (lsm_match's ``offset``)
    centre_r = np.rint(xl_r)
    frac = xl_r - centre_r
    init[:, [1, 2, 4, 5]] = a_rect.reshape(-1, 4)
    init[:, 0] = xr_r[:, 0] - a_rect[:, 0, 0] * frac[:, 0] - a_rect[:, 0, 1] * frac[:, 1]
    init[:, 3] = centre_r[:, 1]
    init[:, 6], init[:, 7] = 0.0, 1.0
    init[from_2d, 6:] = res.radiometric[ok[from_2d]]
    if fixed is not None and "fprep" in fixed:
        fprep, gprep = fixed["fprep"], fixed["gprep"]
    else:
        fprep = prepare_image(left_r, interpolation)
        gprep = prepare_image(right_r, interpolation)
    opts = {k: v for k, v in options.items()
            if k not in ("offset", "robust", "quadratic", "direction", "rigid_across")}
    m = len(ok)
    side_of = np.asarray(sides, np.int32)[ok].copy()
    base = side_of.copy()
    sigma_g = 0.0
    found = {"status": np.array(res.status[ok]), "position": np.full((m, 2), np.nan),
             "cov": np.full((m, 2, 2), np.nan), "sigma0": np.full(m, np.nan),
             "correlation": np.full(m, np.nan), "inflation": np.full(m, np.nan),
             "unit": np.full(m, np.nan),
             "slope": np.full(m, np.nan), "affine": np.full((m, 6), np.nan),
             "radiometric": np.full((m, 2), np.nan),
             "affine_cov": np.full((m, 6, 6), np.nan)}
    todo = np.ones(m, bool)
    for step, factor in enumerate((1.0,) + tuple(grow_sides)):
        # the base side, then (where the window is ill-conditioned along the line) the
        # larger ones: a window that reaches the next corner of the texture is
        side_of[todo] = _odd_at_least(factor * base[todo])
        for side in np.unique(side_of[todo]):
            sel = np.flatnonzero(todo & (side_of == side))
            tensor = _structure_tensors(left_r, centre_r[sel], np.full(len(sel), side))
            with np.errstate(divide="ignore", invalid="ignore"):
                found["slope"][sel] = np.abs(tensor[:, 0, 1] / tensor[:, 0, 0])
            opts["patch"] = int(side)
            r = lsm_match(fprep, gprep, centre_r[sel], init[sel][:, [0, 3]],
                          initial=init[sel], direction=(1.0, 0.0), rigid_across=True,
                          offset=frac[sel], **opts)
            found["status"][sel] = r.status
            found["position"][sel] = r.position
            found["cov"][sel] = r.cov
            found["sigma0"][sel], found["correlation"][sel] = r.sigma0, r.correlation
            found["affine"][sel], found["affine_cov"][sel] = r.affine, r.affine_cov
            found["radiometric"][sel] = r.radiometric
            with np.errstate(divide="ignore", invalid="ignore"):
                # what the shape unknowns take from the shift: its variance over the one
                # the texture's gradients along the line alone give, σ0² / Σ f_x², at
                # the window's centre and at its least-variance point (where the match
                # is reported when that is inside the window: _information_centres)
                unit = tensor[:, 0, 0] * side**2 / r.sigma0**2
                found["unit"][sel] = unit
                var_best = (_least_variance_point(r.affine_cov, side // 2)[1]
                            if at_best_point else np.full(len(sel), np.nan))
                found["inflation"][sel] = np.where(np.isfinite(var_best), var_best,
                                                   r.cov[:, 0, 0]) * unit
        if step == 0 and fixed is not None:
            sigma_g = fixed["sigma_g"]
        elif step == 0:
            # the rig's row error, from the windows textured in both directions
            eig = np.linalg.eigvalsh(_structure_tensors(left_r, centre_r[from_2d],
                                                        base[from_2d]))
            round_ = eig[:, 0] >= 0.25 * eig[:, 1]
            ref = dy[round_] if round_.sum() >= 30 else dy
            sigma_g = (1.4826 * float(np.median(np.abs(ref - np.median(ref))))
                       if len(ref) else 0.0)
        good = found["status"] == Status.OK
        if step == 0 and fixed is not None:
            cls = (np.zeros(n, np.int64) if classes is None
                   else np.asarray(classes, np.int64))[ok]
            k2_classes = np.asarray(fixed["factors"], np.float64)
            k2_each = np.maximum(k2_classes[np.minimum(cls, len(k2_classes) - 1)], 1.0)
            k2 = float(k2_classes[0])
        elif step == 0:
            # the variance factor of the constrained matches (independent neighbouring
            # windows predicting their midpoint, along the row: 1 degree of freedom);
            # the rectified images' resampling correlates their noise
            # per window class (``edge`` windows reach over an untextured region: a
            # second population, class_variance_factors)
            k2_each, k2_classes = class_variance_factors(
                centre_r, found["affine"], found["affine_cov"], good,
                (np.zeros(n, np.int64) if classes is None
                 else np.asarray(classes, np.int64))[ok], patch=side_of)
            k2_each = np.maximum(k2_each, 1.0)
            k2 = float(k2_classes[0]) if len(k2_classes) else 1.0
        cond = good.copy()
        geo_r = (found["slope"] * sigma_g) ** 2  # rectified px²
        if aperture_k is not None:
            cond &= geo_r <= aperture_k**2 * k2_each * found["cov"][:, 0, 0]
        if max_inflation is not None:
            cond &= found["inflation"] <= max_inflation
        todo = todo & good & ~cond
        if not todo.any():
            break
    good = found["status"] == Status.OK
    # the final warp and its covariance (the second-order pass's where it ran) and the
    # fixed second-order terms: where the window's shift is best determined
    # (_information_centres)
    found["affine_fin"] = found["affine"].copy()
    found["affine_cov_fin"] = found["affine_cov"].copy()
    found["quad"] = np.zeros((m, 6))
    if second_order and good.sum() >= 8:
        # the fixed second-order terms along the row from the neighbours' shapes (the
        # curvature bias of an affine window, :mod:`matching.second_order`), one more pass
        quad = second_order_terms(centre_r, found["affine"], good,
                                  radius_px=max(20.0, 5.0 * float(spacing)))
        quad[:, 3:] = 0.0
        again = np.concatenate([found["affine"], init[:, 6:]], axis=1)
        for side in np.unique(side_of[good]):
            sel = np.flatnonzero(good & (side_of == side))
            opts["patch"] = int(side)
            r = lsm_match(fprep, gprep, centre_r[sel], init[sel][:, [0, 3]],
                          initial=again[sel], direction=(1.0, 0.0), rigid_across=True,
                          offset=frac[sel], quadratic=np.nan_to_num(quad[sel]), **opts)
            keep = r.accepted
            sub = sel[keep]
            found["position"][sub], found["cov"][sub] = r.position[keep], r.cov[keep]
            found["affine_fin"][sub] = r.affine[keep]
            found["affine_cov_fin"][sub] = r.affine_cov[keep]
            found["quad"][sub] = np.nan_to_num(quad[sub])
            found["sigma0"][sub] = r.sigma0[keep]
            found["correlation"][sub] = r.correlation[keep]
    position, cov = np.array(res.position), np.array(res.cov)
    status = np.array(res.status)
    status[ok] = found["status"]
    sigma0, corr = np.array(res.sigma0), np.array(res.correlation)
    dirs = np.tile([1.0, 0.0], (n, 1))
    geo = np.full(n, np.nan)
    good = np.flatnonzero(found["status"] == Status.OK)
    g = ok[good]
    position[g] = rectified_to_original(rect, rig.right, found["position"][good])
    jinv = np.linalg.inv(_jacobians(lambda p: right_to_rectified(rect, rig.right, p),
                                    position[g]))
    scale = k2_each[good, None, None] if scale_cov else 1.0  # (sigma_factor off: σ0²N⁻¹)
    cov[g] = scale * jinv @ found["cov"][good] @ jinv.transpose(0, 2, 1)
    d = jinv[:, :, 0]  # right-image step of one rectified column
    stretch = np.einsum("ni,ni->n", d, d)
    dirs[g] = d / np.sqrt(stretch)[:, None]
    geo[g] = (found["slope"][good] * sigma_g) ** 2 * stretch
    stretch_ok = np.full(len(ok), np.nan)
    stretch_ok[good] = stretch
    geo[g[todo[good]]] = np.nan  # ill-conditioned at every side: aperture
    sigma0[g], corr[g] = found["sigma0"][good], found["correlation"][good]
    new_sides = np.asarray(sides, np.int32).copy()
    new_sides[ok] = side_of
    # the warp back in the original images (Jr⁻¹ A Jl), for the backward loop and the maps
    affine, radiometric = np.array(res.affine), np.array(res.radiometric)
    a_rect = found["affine"][good][:, [1, 2, 4, 5]].reshape(-1, 2, 2)
    affine[np.ix_(g, [1, 2, 4, 5])] = (jinv @ a_rect @ jl[good]).reshape(-1, 4)
    affine[:, 0], affine[:, 3] = position[:, 0], position[:, 1]
    radiometric[g] = found["radiometric"][good]
    out = replace(res, radiometric=radiometric, position=position, cov=cov,
                  status=status.astype(res.status.dtype), sigma0=sigma0, correlation=corr,
                  affine=affine, window_cov=None)
    factors = (k2, float(k2_classes[1]) if len(k2_classes) > 1 else k2)
    # the rectified frame's matches, for the uniqueness test and the backward loop there
    frame = {"fprep": fprep, "gprep": gprep, "opts": opts, "sigma_g": sigma_g,
             "factors": factors, "index": np.arange(n)}
    for key, value in (("centre", centre_r), ("frac", frac), ("xl", xl_r),
                       ("position", found["position"]), ("affine", found["affine"]),
                       ("radiometric", found["radiometric"]), ("cov", found["cov"]),
                       ("sides", side_of), ("k2", k2_each), ("sigma0", found["sigma0"]),
                       ("correlation", found["correlation"]), ("stretch", stretch_ok),
                       ("affine_fin", found["affine_fin"]),
                       ("affine_cov_fin", found["affine_cov_fin"]), ("quad", found["quad"]),
                       ("unit", found["unit"])):
        value = np.asarray(value)
        full = (np.full(n, -1, np.int32) if key == "sides"
                else np.full((n,) + value.shape[1:], np.nan))
        full[ok] = value
        frame[key] = full
    return out, geo, dirs, new_sides, factors, frame


def _loop_closes(fprep, gprep, points, res: LSMResult, which, patch: int,
                 options: dict) -> np.ndarray:
    """(N,) bool: the backward (right-to-left) LSM from each solution in ``which`` returns
    to its template centre within the loop's 99.9 % bound (σ_fwd² + σ_bwd², the
    white-noise σ of both solutions, times the loops' own variance factor); True where
    not checked or where the backward match itself failed.

    Started at the solution with the inverse warp and radiometry (f = r0 + r1 g, so
    g = -r0/r1 + f/r1); a solution LSM reached in a biased minimum -- a window sliding
    along a straight edge, a warp bent to fit a repeat -- is not the minimum of the
    window centred at its answer, and the loop opens.
    """
    out = np.ones(len(points), bool)
    sel = np.flatnonzero(which)
    if not len(sel):
        return out
    aff = res.affine[sel]
    jac = np.stack([aff[:, 1:3], aff[:, 4:6]], axis=1)  # (M, 2, 2)
    det = np.linalg.det(jac)
    good = np.abs(det) > TOL.zero
    sel, jac = sel[good], jac[good]
    out[np.flatnonzero(which)[~good]] = False
    inv = np.linalg.inv(jac)
    r0, r1 = res.radiometric[sel, 0], res.radiometric[sel, 1]
    init = np.column_stack([points[sel, 0], inv[:, 0, 0], inv[:, 0, 1], points[sel, 1],
                            inv[:, 1, 0], inv[:, 1, 1], -r0 / r1, 1.0 / r1])
    opts = {k: v for k, v in options.items()
            if k in ("interpolation", "min_texture_snr", "min_correlation", "max_iter")}
    back = lsm_match(gprep, fprep, res.position[sel], points[sel], initial=init,
                     patch=patch, **opts)
    loop = np.linalg.norm(back.position - points[sel], axis=1)
    ratio = loop / np.hypot(res.sigma[sel], back.sigma)
    converged = back.status == Status.OK
    # σ0²N⁻¹ is optimistic on real images by a variance factor k (matching.precision);
    # the loops give their own: a 2-D loop of per-axis σ k has its median at
    # sqrt(2 ln 2) σ k (Rayleigh), and 99.9 % of loops within sqrt(2 ln 1000) σ k
    k = 1.0
    if converged.sum() >= 30:
        k = max(1.0, float(np.median(ratio[converged])) / np.sqrt(2.0 * np.log(2.0)))
    # a backward match that fails its own tests (pull-in, σ0, convergence: 30 % of a
    # temple pair's, whose forward matches are sound) gives no verdict
    out[sel] = ~converged | (ratio <= np.sqrt(2.0 * np.log(1000.0)) * k)
    return out


#: LSM failures a better approximation may turn into a match (grown again from verified
#: neighbours); the others are properties of the window (texture, conditioning) or of
#: what it holds: a window that converged to a residual above the image noise
#: (``SIGMA0_TOO_LARGE``) or a low correlation holds what one affine plane does not fit
#: (an occluding rim, background), and a new start only finds a biased fit of it
#: (docs/decisions/stereo-ambiguity.md)
_REGROW = (Status.NO_CONVERGENCE, Status.PULL_IN, Status.DEGENERATE_AFFINE,
           NO_APPROXIMATION)


def _grow_verified(status, points, res: LSMResult, frame: dict, geo, dirs, sides,
                   refine, patch: int, max_rounds: int = 60, reach: float | None = None,
                   ambiguous: bool = False):
    """Region growing in the rectified frame from the matches already shown unique.

    A candidate whose window failed from its approximation (``_REGROW``; with
    ``ambiguous`` also the ambiguous ones) is started at the median prediction of its
    verified accepted neighbours within ``reach`` px (default half the patch)
    (their warps, at least two within 1 px of each other; shape and radiometry of the
    nearest), matched by the epipolar pass (``refine``: :func:`_epipolar_refine` with
    the first call's σ_g and variance factors), and kept only where every verified
    neighbour in reach agrees with it within 3σ (:func:`matching.uniqueness.anchored`,
    at least two: a one-period slip is a period off every prediction) and its backward
    loop closes (:func:`_loop_closes_rectified`).  Rounds until the front stops: only
    verified matches seed, so growth cannot carry a slip across a repeated pattern.
    Updates ``status``, ``geo``, ``dirs``, ``sides`` and ``frame`` in place; returns the
    updated result and the (N,) mask of the matches grown.
    """

    n = len(points)
    reach = float(patch) / 2.0 if reach is None else float(reach)
    tried = np.zeros(n, bool)
    grown = np.zeros(n, bool)
    position, cov = np.array(res.position), np.array(res.cov)
    affine, radiometric = np.array(res.affine), np.array(res.radiometric)
    sigma0, corr = np.array(res.sigma0), np.array(res.correlation)
    for _ in range(max_rounds):
        verified = np.flatnonzero(status == Status.OK)
        regrow = _REGROW + ((AMBIGUOUS,) if ambiguous else ())
        cand = np.flatnonzero(np.isin(status, regrow) & ~tried)
        if len(verified) < 2 or not len(cand):
            break
        tree = cKDTree(points[verified])
        k = min(4, len(verified))
        dist, nb = tree.query(points[cand], k=k, distance_upper_bound=reach)
        dist, nb = dist.reshape(len(cand), k), nb.reshape(len(cand), k)
        found = np.isfinite(dist)
        j = verified[np.where(found, nb, 0)]
        d = points[cand][:, None, :] - points[j]
        aff = affine[j]
        pu = aff[..., 0] + aff[..., 1] * d[..., 0] + aff[..., 2] * d[..., 1]
        pv = aff[..., 3] + aff[..., 4] * d[..., 0] + aff[..., 5] * d[..., 1]
        pu, pv = np.where(found, pu, np.nan), np.where(found, pv, np.nan)
        two = found.sum(axis=1) >= 2
        # the median of the predictions (nearest first; NaN where not found)
        mu = np.full(len(cand), np.nan)
        mv = np.full(len(cand), np.nan)
        if two.any():
            mu[two] = np.nanmedian(pu[two], axis=1)
            mv[two] = np.nanmedian(pv[two], axis=1)
        off = np.hypot(pu - mu[:, None], pv - mv[:, None])
        spread = np.max(np.where(found, off, 0.0), axis=1)
        usable = two & (spread <= 1.0)
        if not usable.any():
            break
        tried[cand[usable]] = True
        sel, nearest = cand[usable], j[usable, 0]
        start_aff = affine[nearest].copy()
        start_aff[:, 0], start_aff[:, 3] = mu[usable], mv[usable]
        sub_status = np.full(n, Status.TEXTURELESS, np.uint8)
        sub_status[sel] = Status.OK
        sub_pos = np.full((n, 2), np.nan)
        sub_pos[sel] = start_aff[:, [0, 3]]
        sub_aff = np.full((n, 6), np.nan)
        sub_aff[sel] = start_aff
        sub_rad = np.full((n, 2), np.nan)
        sub_rad[sel] = radiometric[nearest]
        sub = replace(res, status=sub_status, position=sub_pos, affine=sub_aff,
                      radiometric=sub_rad)
        out, geo_s, dirs_s, sides_s, _, frame_s = refine(sub_pos, sub, sides)
        ok_s = sel[(out.status[sel] == Status.OK) & np.isfinite(geo_s[sel])]
        if not len(ok_s):
            continue
        new = np.zeros(n, bool)
        new[ok_s] = True
        sigma_now = np.sqrt(np.maximum(np.trace(cov, axis1=1, axis2=2), 0.0) / 2.0)
        pinned = uniqueness.anchored(points, np.where(new[:, None], out.position, position),
                                     np.where(new, out.sigma, sigma_now),
                                     np.where(new[:, None], out.affine, affine),
                                     status == Status.OK, new, radius=float(patch),
                                     max_rounds=1)
        keep = ok_s[pinned[ok_s]]
        if len(keep):
            mask = np.zeros(n, bool)
            mask[keep] = True
            frame_s["loop_k"] = frame.get("loop_k", 1.0)
            closes = _loop_closes_rectified(frame_s, mask)
            keep = keep[closes[keep]]
        if not len(keep):
            continue
        position[keep], cov[keep] = out.position[keep], out.cov[keep]
        affine[keep], radiometric[keep] = out.affine[keep], out.radiometric[keep]
        sigma0[keep], corr[keep] = out.sigma0[keep], out.correlation[keep]
        geo[keep], dirs[keep], sides[keep] = geo_s[keep], dirs_s[keep], sides_s[keep]
        for key, value in frame.items():
            if isinstance(value, np.ndarray) and value.shape[:1] == (n,) and key != "index":
                value[keep] = frame_s[key][keep]
        status[keep] = Status.OK
        grown[keep] = True
    res = replace(res, position=position, cov=cov, affine=affine, radiometric=radiometric,
                  sigma0=sigma0, correlation=corr,
                  status=np.where(status == Status.OK, Status.OK, res.status).astype(
                      res.status.dtype))
    return res, grown


def _least_variance_point(affine_cov: np.ndarray, half) -> tuple[np.ndarray, np.ndarray]:
    """The least-variance point of constrained warps along the row and its variance.

    The warp x' = a0 + a1 x + a2 y gives the match of every template pixel (x, y) (from the
    window's centre) with variance gᵀ C g, g = (1, x, y), C the covariance of a0 a1 a2
    (the first three of ``affine_cov`` (N, >= 3, >= 3)); it is least at
    p* = -C₁₁⁻¹ c₁₀ (Förstner's optimal point of a window).  Returns p* (N, 2) and its
    variance (N,), NaN where p* is undefined or outside the window (|p*| > ``half``).
    """
    c3 = np.asarray(affine_cov)[:, :3, :3]
    with np.errstate(divide="ignore", invalid="ignore"):
        det = c3[:, 1, 1] * c3[:, 2, 2] - c3[:, 1, 2] ** 2
        px = -(c3[:, 2, 2] * c3[:, 1, 0] - c3[:, 1, 2] * c3[:, 2, 0]) / det
        py = -(c3[:, 1, 1] * c3[:, 2, 0] - c3[:, 1, 2] * c3[:, 1, 0]) / det
    pstar = np.column_stack([px, py])
    inside = (np.isfinite(pstar).all(axis=1)
              & (np.abs(pstar) <= np.asarray(half, np.float64).reshape(-1, 1)).all(axis=1))
    g = np.column_stack([np.ones(len(c3)), pstar])
    var = np.where(inside, np.einsum("ni,nij,nj->n", np.nan_to_num(g), c3, np.nan_to_num(g)),
                   np.nan)
    pstar[~inside] = np.nan
    return pstar, var


def _report_epipolar(frame: dict, rect, rig, res: LSMResult, epi_dirs, status, cand_points,
                     idx, points, offset, x_left_out, width: int, centre_points: bool,
                     scale_cov: bool):
    """Where and how the epipolar pass's accepted matches are reported.

    Each at the left pixel nearest its window's information centre (``centre_points``:
    :func:`_information_centres`; its shape's extrapolation elsewhere carries the cameras'
    blur differences); one whose variance where it is reported the shape dominates is
    ``aperture`` (:func:`_shape_dominated`); the pair's edge-polarity bias removed, the
    one-signed windows' variance factor applied, and a match off its neighbours' plane
    rejected (:func:`_correct_polarity`).  ``status`` (over ``idx``) is updated in place.
    Returns the result, line directions, offsets, reported left points (None: the
    candidates) and the variance the polarity estimate leaves along the line (px²).
    """
    if centre_points:
        keys = (np.rint(cand_points[:, 1]) * width
                + np.rint(cand_points[:, 0])).astype(np.int64)
        plain = ~np.any(offset[idx] != 0.0, axis=1)  # eccentric windows stay
        mv, q, right_q, cov_q, dir_q = _information_centres(
            frame, rect, rig, (status == Status.OK) & plain, points, keys, width,
            scale_cov=scale_cov)
        if len(mv):
            position, cov_r = np.array(res.position), np.array(res.cov)
            position[mv], cov_r[mv] = right_q, cov_q
            res = replace(res, position=position, cov=cov_r)
            epi_dirs = np.array(epi_dirs)
            epi_dirs[mv] = dir_q
            x_left_out = np.array(cand_points) if x_left_out is None else x_left_out
            offset = offset.copy()
            offset[idx[mv]] = points[mv] - q  # the window centre from the point
            x_left_out[idx[mv]] = q
    # a window passed at its least-variance point but reported elsewhere
    reported = cand_points if x_left_out is None else x_left_out
    status[_shape_dominated(frame, rect, rig, status == Status.OK, reported[idx])] = APERTURE
    # the cameras' edge rendering: a rising and a falling edge matched δ apart
    polarity_var, edge_factor, off = _correct_polarity(frame, status == Status.OK)
    status[off] = OFF_SURFACE
    res = replace(res, position=res.position + frame["polarity_shift"][:, None] * epi_dirs,
                  cov=res.cov * edge_factor[:, None, None])
    return res, epi_dirs, offset, x_left_out, polarity_var


def _edge_polarity(image: np.ndarray, points: np.ndarray, sides: np.ndarray) -> np.ndarray:
    """(N,) the information-weighted polarity of each ``sides`` x ``sides`` window of
    ``image`` centred on the integer ``points``: Σ sign(f_x) f_x² / Σ f_x² (1: every
    gradient along the row rises, -1: every one falls, 0: balanced, e.g. a corner of a
    chessboard).  The shift along the row is Σ f_x e / Σ f_x², so a shift ±δ of the edges
    of each sign moves it by δ times this."""
    import cv2

    img = np.asarray(image, dtype=np.float64)
    gx = np.zeros_like(img)
    gx[:, 1:-1] = 0.5 * (img[:, 2:] - img[:, :-2])
    xi = np.rint(points).astype(np.intp)
    xi[:, 0] = np.clip(xi[:, 0], 0, img.shape[1] - 1)
    xi[:, 1] = np.clip(xi[:, 1], 0, img.shape[0] - 1)
    out = np.zeros(len(points))
    for side in np.unique(sides):
        sel = np.flatnonzero(sides == side)
        num, den = (cv2.boxFilter(p, -1, (int(side), int(side)), borderType=cv2.BORDER_REFLECT)
                    for p in (gx * np.abs(gx), gx * gx))
        with np.errstate(divide="ignore", invalid="ignore"):
            out[sel] = num[xi[sel, 1], xi[sel, 0]] / den[xi[sel, 1], xi[sel, 0]]
    return np.nan_to_num(out)


def _polarity_bias(frame: dict, accepted: np.ndarray, neighbours: int = 40,
                   rounds: int = 5) -> tuple[float, float, np.ndarray, np.ndarray,
                                            np.ndarray]:
    """The pair's edge-polarity bias along the row, δ (rectified px), its variance, and
    each window's polarity (:func:`_edge_polarity`; 0 where not accepted).

    The two cameras render an edge differently (blur, tone curve): LSM's linear
    radiometry then places a rising edge δ one way and a falling one δ the other, the
    same for the whole pair.  Estimated from the accepted matches at their
    least-variance points: each one's disparity against the least-squares plane of its
    ``neighbours`` nearest accepted windows that share none of its pixels (a surface is
    locally planar over a few windows; rectified disparity is exactly affine in the
    image over a plane), regressed on the polarity: d_i - plane_i = δ (s_i - plane of
    the s_j) (the neighbours carry the bias too), MAD-trimmed at 3.29 robust spreads.
    """

    n = len(accepted)
    s = np.zeros(n)
    k = np.flatnonzero(accepted & np.isfinite(frame["affine_cov_fin"][:, 0, 0])
                       & (frame["sides"] > 0))
    ratio = np.full(n, np.nan)
    near = np.full((n, neighbours), -1, np.intp)
    if len(k) < neighbours + 1:
        return 0.0, 0.0, s, ratio, near
    half = frame["sides"][k] // 2
    pstar, var = _least_variance_point(frame["affine_cov_fin"][k], half)
    inside = np.isfinite(var)
    pstar[~inside] = frame["frac"][k][~inside]
    a, fo = frame["affine_fin"][k], frame["frac"][k]
    xr = frame["position"][k, 0] + a[:, 1] * (pstar[:, 0] - fo[:, 0]) + a[:, 2] * (
        pstar[:, 1] - fo[:, 1])
    xl = frame["centre"][k] + pstar
    disp = xl[:, 0] - xr
    s_k = _edge_polarity(frame["fprep"].raw, frame["centre"][k], frame["sides"][k])
    s[k] = s_k
    tree = cKDTree(xl)
    m = min(len(k), 4 * neighbours)
    dist, nb = tree.query(xl, k=m)
    far = dist >= frame["sides"][k][:, None].astype(np.float64)  # shares no pixel
    order = np.argsort(~far, axis=1, kind="stable")[:, :neighbours]
    nb = np.take_along_axis(nb, order, axis=1)
    usable = np.take_along_axis(far, order, axis=1).all(axis=1)
    design = np.concatenate([np.ones((len(k), neighbours, 1)), xl[nb] - xl[:, None, :]],
                            axis=2)  # plane about the window's own point
    pinv = np.linalg.pinv(design)  # (K, 3, neighbours)
    own_d = np.einsum("kj,kj->k", pinv[:, 0, :], disp[nb])
    own_s = np.einsum("kj,kj->k", pinv[:, 0, :], s_k[nb])
    e, t = disp - own_d, s_k - own_s
    keep = usable & np.isfinite(e) & np.isfinite(t)
    delta, var_delta = 0.0, 0.0
    for _ in range(rounds):
        if keep.sum() < neighbours or np.sum(t[keep] ** 2) <= 0:
            return 0.0, 0.0, s, ratio, near
        delta = float(np.sum(e[keep] * t[keep]) / np.sum(t[keep] ** 2))
        r = e - delta * t
        spread = 1.4826 * float(np.median(np.abs(r[keep] - np.median(r[keep]))))
        keep_new = usable & (np.abs(r) <= 3.29 * spread)
        var_delta = spread**2 / float(np.sum(t[keep_new] ** 2))
        if np.array_equal(keep_new, keep):
            break
        keep = keep_new
    # each window's departure from its neighbours' plane over its own σ along the row
    var_own = np.where(inside, var, frame["affine_cov_fin"][k][:, 0, 0]) * frame["k2"][k]
    ratio[k] = np.where(usable, (e - delta * t) / np.sqrt(var_own), np.nan)
    near = np.full((n, neighbours), -1, np.intp)
    near[k] = k[nb]
    return delta, var_delta, s, ratio, near


def _correct_polarity(frame: dict, accepted: np.ndarray) -> tuple[np.ndarray, np.ndarray,
                                                                  np.ndarray]:
    """The pair's edge-polarity bias (:func:`_polarity_bias`) removed from the matches
    ``accepted``, and what one-signed edges leave.

    Sets ``frame["polarity_shift"]`` (N,), the shift of each right position along the line
    in the original right image (px).  Returns the variance the bias estimate leaves along
    the line there (px²), each match's variance factor for its edges' own errors, and the
    matches off the surface.  A window whose gradients along the row mostly share one sign
    holds one edge, whose rendering error it does not average with other edges': per
    quartile of |polarity| over the matches, the departures from the neighbours' plane
    over σ, against those of the most balanced quartile (all see the same surface), give
    the factor (never below 1).  Off the surface: a departure, in its class's units,
    beyond 3.29 robust spreads (1.4826 MAD) of its neighbours'.
    """
    delta, var_delta, pol, ratio, near = _polarity_bias(frame, accepted)
    step = np.sqrt(np.nan_to_num(frame["stretch"], nan=1.0))  # right px per rectified px
    frame["polarity_shift"] = np.where(accepted, delta * pol * step, 0.0)
    factor = np.ones(len(accepted))
    known = np.isfinite(ratio)
    outlier = np.zeros(len(accepted), bool)
    if known.sum() >= 4 * 30:
        # classes: the quartiles of |polarity| over the matches (the first, the most
        # balanced windows, the reference)
        edges = np.quantile(np.abs(pol[known]), [0.25, 0.5, 0.75])
        cls = np.searchsorted(edges, np.abs(pol), side="right")
        spread2 = np.array([np.median(ratio[known & (cls == c)] ** 2) for c in range(4)])
        spread2 = spread2 / CHI2_1_MEDIAN
        factor = np.where(accepted, np.maximum(1.0, spread2[cls] / spread2[0]), 1.0)
        # beyond the 99.9 % bound of the departures of its neighbours (in units of their
        # classes' spreads; a rougher surface, a wider bound): off the surface
        z = np.nan_to_num(ratio / np.sqrt(spread2[cls]), nan=np.inf)
        zn = np.where(near >= 0, np.abs(z[np.maximum(near, 0)]), np.inf)
        local = 1.4826 * np.median(zn, axis=1)
        outlier = accepted & known & (np.abs(z) > OUTLIER_Z * local)
    return np.where(accepted, var_delta * pol**2 * step**2, 0.0), factor, outlier


def _shape_dominated(frame: dict, rect, rig, which: np.ndarray, x_left: np.ndarray,
                     max_inflation: float = MAX_INFLATION) -> np.ndarray:
    """(N,) bool: the epipolar-pass matches ``which`` whose variance along the row at their
    reported left point ``x_left`` exceeds ``max_inflation`` x σ0² / Σ f_x² (the shape
    unknowns take the shift's information there: a one-edge window reported off its edge
    is extrapolated through its scale; :func:`_epipolar_refine`'s ``aperture`` test, made
    at the point reported instead of at the window's least-variance point)."""
    from matching.rectify import left_to_rectified

    k = np.flatnonzero(which & np.isfinite(frame["unit"]))
    out = np.zeros(len(which), bool)
    if len(k) == 0:
        return out
    fn = left_to_rectified(rect, rig.left, x_left[k]) - frame["centre"][k]
    g = np.column_stack([np.ones(len(k)), fn])
    var = np.einsum("ni,nij,nj->n", g, frame["affine_cov_fin"][k][:, :3, :3], g)
    out[k] = ~(var * frame["unit"][k] <= max_inflation)
    return out


def _information_centres(frame: dict, rect, rig, accepted: np.ndarray, x_left: np.ndarray,
                         taken: np.ndarray, width: int, scale_cov: bool = True):
    """Report each accepted epipolar-pass match at its window's best-determined pixel.

    The constrained warp along the row, x' = a0 + a1 x + a2 y (+ the fixed second-order
    terms), gives the match of every template pixel; its variance gᵀ C g (g = (1, x, y),
    C the covariance of a0 a1 a2) is smallest at p* = -C₁₁⁻¹ c₁₀, the window's
    information centre (Förstner's optimal point of a window): where its gradients are.
    Anywhere else the match is extrapolated from there through the shape a1, a2, and
    the shape carries what the window model does not (the two cameras' different blur
    and resampling at an edge or a corner), multiplied by the lever arm |p - p*|
    (measured on the chessboard rig: docs/decisions/stereo-information-centre.md).

    Each accepted window (``accepted``, over the frame's candidates) is moved to the
    left image's pixel nearest its p* (of the 3 x 3 around the nearest pixel) that is no
    other candidate's (``taken``: (M,) int64 keys y * ``width`` + x of every candidate's
    pixel) when that pixel lies inside the window; two windows aiming at one pixel: the
    first moves.  Its right position and its variance along the row are those of the warp
    there.
    Returns (moved indices into the frame's candidates, their new left pixels (K, 2),
    right positions (K, 2), covariances (K, 2, 2) in the original right image, unit
    line directions (K, 2)).
    """
    from matching.rectify import left_to_rectified, rectified_to_original, right_to_rectified

    empty = (np.zeros(0, np.intp), np.zeros((0, 2)), np.zeros((0, 2)), np.zeros((0, 2, 2)),
             np.zeros((0, 2)))
    cov_all = frame["affine_cov_fin"]
    k = np.flatnonzero(accepted & np.isfinite(cov_all[:, 0, 0]) & (frame["sides"] > 0))
    if len(k) == 0:
        return empty
    centre = frame["centre"][k]
    half = (frame["sides"][k] // 2).astype(np.float64)
    pstar, _ = _least_variance_point(cov_all[k], half)
    fine = np.isfinite(pstar).all(axis=1)
    k, pstar, centre, half = k[fine], pstar[fine], centre[fine], half[fine]
    if len(k) == 0:
        return empty
    target = rectified_to_original(rect, rig.left, centre + pstar, which="left")
    own = (np.rint(x_left[k, 1]) * width + np.rint(x_left[k, 0])).astype(np.int64)
    # the pixel nearest p* that is no other candidate's (of the 3 x 3 around the nearest)
    steps = np.array([(i, j) for j in (-1, 0, 1) for i in (-1, 0, 1)], np.float64)
    near = np.rint(target)[:, None, :] + steps[None]  # (K, 9, 2)
    dist = np.linalg.norm(near - target[:, None, :], axis=2)
    keys9 = (near[..., 1] * width + near[..., 0]).astype(np.int64)
    free = ~np.isin(keys9, taken) | (keys9 == own[:, None])
    pick = np.argmin(np.where(free, dist, np.inf), axis=1)
    rows = np.arange(len(k))
    q = near[rows, pick]
    key = keys9[rows, pick]
    frac_new = left_to_rectified(rect, rig.left, q) - centre
    move = (free[rows, pick] & (key != own)
            & (np.abs(frac_new) <= half[:, None]).all(axis=1))
    # two windows to one pixel: the first keeps it, the other stays where it was
    first = np.zeros(len(k), bool)
    _, at = np.unique(np.where(move, key, -1 - np.arange(len(k))), return_index=True)
    first[at] = True
    move &= first
    k, q, frac_new = k[move], q[move], frac_new[move]
    if len(k) == 0:
        return empty
    a, quad, fo = frame["affine_fin"][k], frame["quad"][k], frame["frac"][k]
    fn = frac_new
    dx, dy = fn[:, 0] - fo[:, 0], fn[:, 1] - fo[:, 1]
    xr = (frame["position"][k, 0] + a[:, 1] * dx + a[:, 2] * dy
          + quad[:, 0] * (fn[:, 0] ** 2 - fo[:, 0] ** 2)
          + quad[:, 1] * (fn[:, 0] * fn[:, 1] - fo[:, 0] * fo[:, 1])
          + quad[:, 2] * (fn[:, 1] ** 2 - fo[:, 1] ** 2))
    yr = frame["position"][k, 1] + a[:, 4] * dx + a[:, 5] * dy
    g = np.column_stack([np.ones(len(k)), fn])
    var = np.einsum("ni,nij,nj->n", g, frame["affine_cov_fin"][k][:, :3, :3], g)
    if scale_cov:
        var = var * frame["k2"][k]
    right = rectified_to_original(rect, rig.right, np.column_stack([xr, yr]))
    jinv = np.linalg.inv(_jacobians(lambda p: right_to_rectified(rect, rig.right, p), right))
    d = jinv[:, :, 0]  # right-image step of one rectified column
    cov = var[:, None, None] * d[:, :, None] * d[:, None, :]
    dirs = d / np.linalg.norm(d, axis=1)[:, None]
    return k, q, right, cov, dirs


def _loop_closes_rectified(frame: dict, which) -> np.ndarray:
    """(N,) bool: the backward (right-to-left) constrained LSM from each epipolar-pass
    solution in ``which`` returns to its left point within the loop's 99.9 % bound along
    the row; True where not checked or where the backward match itself failed.

    The template is the right rectified image on its pixel grid at the solution (the
    solution eccentric by its fraction of a pixel), started in the left image at the
    inverse of the solution's warp along the row (x_l = (x_r - a0 - a2 dy) / a1) and
    radiometry; the loop's bound is the forward and backward σ along the row combined,
    times the loops' own variance factor (their median |loop| / 0.6745 σ, at least 1).
    """
    n = len(which)
    out = np.ones(n, bool)
    ok = frame["index"]
    local = np.flatnonzero(np.asarray(which, bool)[ok]
                           & np.isfinite(frame["position"]).all(1))
    if not len(local):
        return out
    aff = frame["affine"][local]
    rad = frame["radiometric"][local]
    a1 = aff[:, 1]
    usable = (np.abs(a1) > TOL.zero) & (np.abs(rad[:, 1]) > TOL.zero)
    out[ok[local[~usable]]] = False
    local, aff, rad, a1 = local[usable], aff[usable], rad[usable], a1[usable]
    pos = frame["position"][local]
    centre = np.rint(pos)
    frac = pos - centre
    # the left point of the template centre: x_l = c_l + (x_r - a0 - a2 dy) / a1, dy the
    # row offset (0 here: rows map to rows)
    xl_c = frame["centre"][local]
    init = np.zeros((len(local), 8))
    init[:, 0] = xl_c[:, 0] + (centre[:, 0] - aff[:, 0]) / a1
    init[:, 1], init[:, 2] = 1.0 / a1, -aff[:, 2] / a1
    init[:, 3], init[:, 5] = centre[:, 1], 1.0
    init[:, 6], init[:, 7] = -rad[:, 0] / rad[:, 1], 1.0 / rad[:, 1]
    opts = dict(frame["opts"])
    back_x = np.full(len(local), np.nan)
    back_var = np.full(len(local), np.nan)
    converged = np.zeros(len(local), bool)
    sides = frame["sides"][local]
    for side in np.unique(sides):
        sel = np.flatnonzero(sides == side)
        opts["patch"] = int(side)
        r = lsm_match(frame["gprep"], frame["fprep"], centre[sel], init[sel][:, [0, 3]],
                      initial=init[sel], direction=(1.0, 0.0), rigid_across=True,
                      offset=frac[sel], **opts)
        back_x[sel], back_var[sel] = r.position[:, 0], r.cov[:, 0, 0]
        converged[sel] = r.status == Status.OK
    loop = back_x - frame["xl"][local, 0]
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.abs(loop) / np.sqrt(frame["cov"][local, 0, 0] + back_var)
    k = float(frame.get("loop_k", 1.0))  # an earlier, larger population's
    if converged.sum() >= 30:
        k = max(1.0, float(np.median(ratio[converged])) / 0.6745)
        frame["loop_k"] = k
    # 99.9 % of a normal loop of standard deviation σ k within 3.29 σ k
    out[ok[local]] = ~converged | (ratio <= 3.29 * k)
    return out


def density_deficit(cells: np.ndarray, shape: tuple[int, int], tried: np.ndarray,
                    matched: np.ndarray, delivered: np.ndarray,
                    radius: int) -> tuple[np.ndarray, np.ndarray]:
    r"""Where the first candidate lattice falls short of its own density on the matched surface.

    The lattice asks for one point per cell (``spacing`` x ``spacing`` px).  On the
    cell grid let :math:`T` be the cells whose candidate was tried (LSM ran from an
    approximation: the object as far as the pair can see it), :math:`A \subseteq T`
    those LSM accepted (evidence that the surface is matched there) and
    :math:`P \subseteq A` those that give the pair a point (``delivered``: not a
    window straddling a silhouette).  The *matched surface* is

    .. math:: M = (A \bullet B_r) \cap T,

    the morphological closing of :math:`A` by the disk :math:`B_r` of radius ``radius``
    cells, kept to tried cells: a rejected cell with accepted matches around it within
    :math:`r` cells (a gap up to about :math:`2r` cells wide) lies inside the matched
    surface, while the band beyond the outermost accepted matches (windows reaching
    over a silhouette into the background, occlusions) is its edge, not a hole.  The
    deficit is :math:`D = M \setminus P`: the cells of the matched surface that the
    lattice requested and did not deliver, :math:`|M| - |P|` of them (the closing
    contains :math:`A`).  Its size per connected component of :math:`M` (8-neighbours)
    is that region's shortfall; it is zero where every candidate of the matched
    surface gave a point.

    Parameters
    ----------
    cells : (N, 2) int64
        Cell (column, row) of each first-lattice candidate.
    shape : (int, int)
        Cell grid (rows, columns); ``cells`` lie inside it.
    tried, matched, delivered : (N,) bool
        Per candidate: :math:`T`, :math:`A`, :math:`P` (each implies the one before).
    radius : int
        Closing radius r, cells (>= 1).

    Returns
    -------
    deficit : (rows, columns) bool
        :math:`D`.
    labels : (rows, columns) int32
        Connected component of :math:`M` per cell (0: not in :math:`M`).
    """
    import cv2

    maps = np.zeros((3, *shape), np.uint8)  # T, A, P
    for m, flags in enumerate((tried, tried & matched, tried & matched & delivered)):
        maps[m, cells[:, 1], cells[:, 0]] = flags
    disk = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
    # cv2's default border leaves the closing unchanged at the grid's edge
    surface = cv2.morphologyEx(maps[1], cv2.MORPH_CLOSE, disk) & maps[0]
    _, labels = cv2.connectedComponents(surface, connectivity=8, ltype=cv2.CV_32S)
    return (surface > 0) & (maps[2] == 0), labels


def _fill_deficit(corner_cells: np.ndarray, texture: np.ndarray, deficit: np.ndarray,
                  labels: np.ndarray) -> np.ndarray:
    """Which second-lattice candidates make up the deficit: per component k of the
    matched surface, the :math:`|D_k|` nearest to a deficit cell (distance from the
    mean of the four neighbour cells' distances; ties: stronger texture, then order).

    ``corner_cells`` (M, 4, 2) int64: the four first-lattice cells (column, row) around
    each candidate.  Returns (M,) bool.

    The distances are scipy's exact float64 ones, the same bits on every run: OpenCV's
    precise transform (float32) differs run to run in the last bit at some cells (the
    same input), which reorders candidates at equal distances and so changes which are
    matched -- the multi-view cloud then differed from run to run.
    """
    counts = np.bincount(labels[deficit], minlength=int(labels.max()) + 1)
    # distance (cells) of every cell to the nearest deficit cell (zeros of the source)
    far = ndimage.distance_transform_edt(~deficit)
    dist = far[corner_cells[..., 1], corner_cells[..., 0]].mean(axis=1)
    label = labels[corner_cells[:, 0, 1], corner_cells[:, 0, 0]]
    order = np.lexsort((np.arange(len(label)), -texture, dist, label))
    sorted_label = label[order]
    first = np.searchsorted(sorted_label, sorted_label, side="left")
    rank = np.arange(len(order)) - first  # place within its component
    take = np.zeros(len(label), bool)
    take[order] = rank < counts[sorted_label]
    return take


def _densify(left, fprep, gprep, cand: Candidates, status, edge, offset, out: dict,
             res: LSMResult, spacing: int, patch: int, mask, valid, quad, max_sigma_mad_k,
             factor: float, options: dict, auto: bool = False):
    """A second candidate lattice between accepted matches (rectified pair; region growing).

    The first lattice takes the best-textured pixel of every ``spacing`` cell; the
    second does the same on the cells shifted by ``ceil(spacing / 2)`` px in x and y,
    each of which lies between four first-lattice cells.  A second-lattice candidate is
    matched only where those four candidates were accepted with centred windows (the
    interior of the matched surface: no rim, silhouette or occlusion edge within about
    a window, whose transfers the further-view check would have to catch) and its own
    window holds no untextured or unmatched pixel (:func:`matching.seeds.window_offsets`
    without moving).  Its start is the median of the four neighbours' affine
    predictions (Otto & Chau's growing, :mod:`matching.grow`), its own row for the
    rectified pair, with their median shape, radiometry and second-order terms, so
    one LSM pass at the first lattice's precision suffices; the σ0 and precision tests
    take the first lattice's accepted matches as population.  Doubles the candidates
    where the surface is matched, at the LSM cost of those alone: the candidates of
    the first lattice that fail (background, occlusions, wide-baseline perspective)
    are not tried twice, as a finer first lattice would.

    ``auto``: only the candidates that make up the first lattice's shortfall on the
    matched surface (:func:`density_deficit` with r = ceil(patch / spacing) cells, one
    window: a defect up to a window across in either image -- a specular spot, a
    small occlusion -- rejects every window that overlaps it, a hole up to two windows
    wide, which a closing by r encloses): in each connected region of the matched
    surface with :math:`|D_k|` requested cells not delivered, the :math:`|D_k|`
    eligible candidates nearest to those cells (all eligible ones when fewer).  The
    pair then delivers about one point per cell of its matched surface where the
    interior allows it -- it cannot exceed that, as True can -- and nothing is added
    where the first lattice is complete.

    Returns ``(candidates, status, edge, offset, out, deficit)``: the matched
    second-lattice candidates appended (the inputs unchanged when there are none) and
    :math:`|D|`, the matched-surface cells whose candidate gave no point.
    """
    h, w = left.shape
    s, half = int(spacing), (int(spacing) + 1) // 2
    x0 = cand.points.astype(np.int64)
    good = (status == Status.OK) & ~edge & ~np.any(offset != 0.0, axis=1)
    ny, nx = h // s, w // s
    grid = np.full((ny + 1, nx + 1), -1, np.int64)  # first-lattice candidate per cell
    cell = x0 // s
    grid[cell[good, 1], cell[good, 0]] = np.flatnonzero(good)
    tried = ~np.isin(status, (Status.TEXTURELESS, NO_APPROXIMATION, Status.OUTSIDE_IMAGE))
    deficit, labels = density_deficit(cell, (ny + 1, nx + 1), tried, status == Status.OK,
                                      ~edge, radius=-(-patch // s))
    n_deficit = int(deficit.sum())
    unchanged = (cand, status, edge, offset, out, n_deficit)
    if auto and not n_deficit:
        return unchanged
    occupied = np.zeros((h, w), bool)
    occupied[x0[:, 1], x0[:, 0]] = True
    shifted = select_points(left[half:, half:], spacing=s, patch=patch,
                            min_texture_snr=options.get("min_texture_snr", 2.0),
                            noise=cand.noise, mask=None if mask is None else mask[half:, half:])
    q = shifted.points + half
    qi = q.astype(np.int64)
    d = (qi - half) // s  # the shifted cell: between first-lattice cells d and d + 1
    nb = np.stack([grid[d[:, 1] + dy, d[:, 0] + dx] for dy in (0, 1) for dx in (0, 1)], 1)
    keep = shifted.textured & np.all(nb >= 0, axis=1) & ~occupied[qi[:, 1], qi[:, 0]]
    if not keep.any():
        return unchanged
    q, nb = q[keep], nb[keep]
    dense = Candidates(points=q, texture=shifted.texture[keep],
                       textured=np.ones(len(q), bool), threshold=shifted.threshold,
                       noise=shifted.noise)
    _, straddle = window_offsets(dense, left, patch, s, mask, valid, move=False)
    if auto:  # the shortfall, from the candidates that would be matched
        free = np.flatnonzero(~straddle)
        straddle = straddle.copy()
        straddle[free[~_fill_deficit(cell[nb[free]], dense.texture[free], deficit,
                                     labels)]] = True
    q, nb, dense = q[~straddle], nb[~straddle], replace(
        dense, points=q[~straddle], texture=dense.texture[~straddle],
        textured=dense.textured[~straddle])
    if not len(q):
        return unchanged
    aff = out["affine"][nb]  # (M, 4, 6)
    step = q[:, None, :] - cand.points[nb]  # (M, 4, 2)
    pu = aff[..., 0] + aff[..., 1] * step[..., 0] + aff[..., 2] * step[..., 1]
    start = np.column_stack([np.median(pu, axis=1), q[:, 1]])  # rectified: its own row
    init = np.zeros((len(q), 8))
    init[:, [0, 3]] = start
    init[:, [1, 2, 4, 5]] = np.median(aff[..., [1, 2, 4, 5]], axis=1)
    init[:, 6:] = np.median(out["radiometric"][nb], axis=1)
    lsm = dict(options)
    lsm.pop("offset", None)
    # the new windows are centred in the matched surface's interior (no edge): robust
    # only where every window is
    lsm["robust"] = bool(np.all(lsm.pop("robust", False)))
    lsm["direction"] = np.array([1.0, 0.0])
    acc = res.accepted
    lsm["sigma0_population"] = res.sigma0[acc]
    if res.grad_power is not None:
        lsm["population_grad_power"] = res.grad_power[acc]
    if res.step_score is not None:
        lsm["population_step_score"] = res.step_score[acc]
    if quad is not None:
        lsm["quadratic"] = np.nan_to_num(np.nanmedian(quad[nb], axis=1))
    found = lsm_match(fprep, gprep, q, start, initial=init, **lsm)
    st = found.status.astype(status.dtype)
    if max_sigma_mad_k is not None and acc.sum() >= 30:
        sigma = found.window_sigma
        limit = robust_upper_limit(res.window_sigma[acc & np.isfinite(res.window_sigma)],
                                   max_sigma_mad_k, patch * patch - 8)
        st[found.accepted & np.isfinite(sigma) & (sigma > limit)] = IMPRECISE
    m = len(q)
    add = {"x_right": found.position, "approx": start, "cov": found.cov * factor,
           "sigma": found.sigma * np.sqrt(factor), "sigma0": found.sigma0,
           "correlation": found.correlation, "iterations": found.iterations,
           "affine": found.affine, "radiometric": found.radiometric,
           "patch": np.full(m, patch, np.int32)}
    out = {k: np.concatenate([v, add[k].astype(v.dtype)]) for k, v in out.items()}
    merged = Candidates(points=np.vstack([cand.points, q]),
                        texture=np.concatenate([cand.texture, dense.texture]),
                        textured=np.concatenate([cand.textured, dense.textured]),
                        threshold=cand.threshold, noise=cand.noise)
    return (merged, np.concatenate([status, st]), np.concatenate([edge, np.zeros(m, bool)]),
            np.vstack([offset, np.zeros((m, 2))]), out, n_deficit)


def _fill_directions(points: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """Epipolar directions with the missing ones (no approximation) from the nearest
    point that has one (a rectified pair's are all (1, 0)); (1, 0) when none has."""
    direction = np.array(direction, dtype=np.float64)
    good = np.isfinite(direction).all(1)
    if good.all():
        return direction
    if not good.any():
        direction[:] = (1.0, 0.0)
        return direction

    _, nearest = cKDTree(points[good]).query(points[~good])
    direction[~good] = direction[good][nearest]
    return direction


def default_max_patch(patch: int) -> int:
    """Largest odd side with at most twice the pixels of ``patch`` (15 -> 21)."""
    side = int(np.floor(np.sqrt(2.0) * patch))
    side -= 1 - side % 2
    while side * side > 2 * patch * patch:
        side -= 2
    return max(side, int(patch))


def adaptive_sides(image, points, sigma, accepted, patch: int = 15,
                   max_patch: int | None = None, noise: float | None = None) -> np.ndarray:
    """Patch side per point that brings its predicted σ to the image's median (Gruen).

    Target: τ = the median σ of the accepted first-pass matches (``patch`` sides).  A
    point with σ > τ gets the smallest odd side s in ``patch + 2, ..., max_patch``
    with σ (p_s / p_patch) <= τ, p the structure-tensor prediction of
    :func:`matching.seeds.shift_precision` (the ratio carries the texture the larger
    window adds; σ carries the measured σ0 and the affine unknowns); ``max_patch``
    when none reaches τ.  Others, and points not accepted, keep ``patch``.

    Parameters
    ----------
    image : (H, W) array_like
        Template image, grey levels.
    points : (N, 2) array_like
        Integer template centres, px.
    sigma : (N,) array_like
        First-pass σ, px.
    accepted : (N,) bool
        First-pass acceptance.
    patch : int
        First-pass side, px.
    max_patch : int, optional
        Largest side (default :func:`default_max_patch`).
    noise : float, optional
        Template noise σ, grey levels (default: Immerkaer's estimate).

    Returns
    -------
    (N,) int32, px
    """
    points = check_shape(points, "(N, 2)", "points", dtype=np.float64)
    sigma = np.asarray(sigma, dtype=np.float64)
    accepted = np.asarray(accepted, dtype=bool)
    top = default_max_patch(patch) if max_patch is None else int(max_patch)
    if top < patch or top % 2 == 0:
        raise ValueError(f"max_patch must be an odd integer >= patch ({patch}), got {max_patch!r}")
    sides = np.full(len(points), patch, np.int32)
    ladder = list(range(patch, top + 1, 2))
    good = accepted & np.isfinite(sigma)
    if len(ladder) < 2 or not good.any():
        return sides
    tau = float(np.median(sigma[good]))
    worse = np.flatnonzero(good & (sigma > tau))
    pred = shift_precision(image, points[worse], ladder, noise=noise)  # (S, M)
    with np.errstate(invalid="ignore", divide="ignore"):
        est = sigma[worse] * pred / pred[0]
    reach = est <= tau  # NaN (window outside the image) and inf never reach
    first = np.where(reach.any(0), reach.argmax(0), len(ladder) - 1)
    # a side whose window leaves the image is not used: fall back to the largest inside
    inside = np.isfinite(pred)
    last_inside = np.where(inside.any(0), len(ladder) - 1 - np.argmax(inside[::-1], axis=0), 0)
    first = np.where(np.isfinite(pred[0]), np.minimum(first, last_inside), 0)
    sides[worse] = np.asarray(ladder, np.int32)[first]
    return sides


def _rematch_ici(fprep, gprep, points, start, first: LSMResult, quad, ladder, options,
                 shifted, edge) -> tuple[LSMResult, np.ndarray]:
    """The second pass at every side of ``ladder``, each point keeping the side ICI
    chooses (eccentric windows keep the smallest: a grown one would reach over the edge
    it was moved off).  The intervals' σ carry each side's variance factor per window
    class (``edge``: :func:`matching.precision.class_variance_factors`, as the pair's
    final σ do)."""
    from matching.ici import ici_choice, interval_sigmas, select_results

    n = len(points)
    classes = np.asarray(edge, dtype=np.int64)
    results, sigmas = [], []
    for side in ladder:
        result = _rematch(fprep, gprep, points, start, first, quad,
                          np.full(n, side, np.int32), options)
        results.append(result)
        per_window = class_variance_factors(points, result.affine, result.affine_cov,
                                            result.accepted, classes, patch=side)[0]
        sigmas.append(interval_sigmas(result, points, side, per_window)[0])
    accepted = np.stack([r.accepted for r in results])
    accepted[1:, np.asarray(shifted, bool)] = False
    choice = ici_choice(np.stack([r.position for r in results]), np.stack(sigmas), accepted)
    sides = np.asarray(ladder, np.int32)[np.maximum(choice, 0)]
    return select_results(results, choice), sides


def _clear_at_sides(cand, left, patch, spacing, mask, valid, idx, above):
    """{side: (len(idx),) bool} for the sides of ``ici_ladder(patch)`` above ``above``: the
    centred window of that side holds no pixel off the textured surface
    (:func:`matching.seeds.window_offsets`' test at that side)."""
    from matching.ici import ici_ladder

    out = {}
    for side in ici_ladder(patch)[1:]:
        if side > above:
            out[side] = ~window_offsets(cand, left, side, spacing, mask, valid,
                                        move=False)[1][idx]
    return out


def _grow_population(fprep, gprep, points, start, first: LSMResult, quad,
                     second: LSMResult, sides, patch: int, options, shifted, edge,
                     clear_at: dict):
    """The sides of ``ici_ladder(patch)`` above Gruen's (``second``, ``sides``), each
    window class grown to the largest one the population rule allows
    (:func:`matching.ici.population_sides`), each point to the largest side up to its
    class's where it is accepted and its window clear of edges (``clear_at``; eccentric
    windows stay).  The nested statistics use the image's variance factor -- the
    windows clear of an edge, at Gruen's sides -- for every class: the edge windows' own
    factor holds their model error, which is what the rule must see.  Returns the
    result, the sides and whether any point grew."""
    from matching.ici import ici_ladder, population_choice, population_sides, select_results

    up = [s for s in ici_ladder(patch)[1:] if s > int(sides.max())]
    ok = second.status == Status.OK
    classes = np.asarray(edge, dtype=np.int64)
    if not up or ok.sum() < 30:
        return second, sides, False
    factors = class_variance_factors(points, second.affine, second.affine_cov, ok,
                                     classes, patch=sides)[1]
    k2 = float(factors[0]) if len(factors) else 1.0
    n = len(points)
    results = [second] + [_rematch(fprep, gprep, points, start, first, quad,
                                   np.full(n, side, np.int32), options) for side in up]
    accepted = np.stack([ok] + [r.status == Status.OK for r in results[1:]])
    accepted[1:, np.asarray(shifted, bool)] = False
    for j, side in enumerate(up, start=1):
        accepted[j] &= clear_at[side]
    cap = population_sides(np.stack([r.position for r in results]),
                           np.stack([r.cov for r in results]), accepted, k2, classes,
                           np.stack([r.sigma0 for r in results]))
    choice = population_choice(accepted, cap[classes])
    if not (choice > 0).any():
        return second, sides, False
    chosen = select_results(results, choice)
    ladder = np.asarray([0] + up, np.int32)
    return chosen, np.where(choice > 0, ladder[choice], sides).astype(np.int32), True


def _rematch(fprep, gprep, points, start, first: LSMResult, quad, sides, options,
             only=None, into: LSMResult | None = None) -> LSMResult:
    """Second LSM pass from the first pass's solution, one call per patch side.

    ``only`` (N,) bool: re-match just these points, the others copied from ``into``.
    """
    n = len(points)
    init = np.column_stack([first.affine, first.radiometric])
    fresh = ~np.isfinite(init).all(1)
    init[fresh] = 0.0
    init[fresh, 0], init[fresh, 3] = start[fresh, 0], start[fresh, 1]
    init[fresh, 1] = init[fresh, 5] = init[fresh, 7] = 1.0
    quad = np.zeros((n, 6)) if quad is None else quad
    direction = options.get("direction")
    arrays = {"position": np.full((n, 2), np.nan), "affine": np.full((n, 6), np.nan),
              "radiometric": np.full((n, 2), np.nan), "converged": np.zeros(n, bool),
              "iterations": np.zeros(n, np.int32), "sigma0": np.full(n, np.nan),
              "cov": np.full((n, 2, 2), np.nan), "correlation": np.full(n, np.nan),
              "status": np.zeros(n, np.uint8), "window_cov": np.full((n, 2, 2), np.nan),
              "affine_cov": np.full((n, 6, 6), np.nan)}
    offset = options.get("offset")
    if offset is None:
        del arrays["window_cov"]
    if into is not None:
        arrays = {name: np.array(getattr(into, name)) for name in arrays}
    reference = first.noise_sigma0 if into is None else into.noise_sigma0
    todo = np.ones(n, bool) if only is None else np.asarray(only, bool)
    for side in np.unique(sides[todo]):  # a few sides: one batched call each
        sel = np.flatnonzero((sides == side) & todo)
        opts = {**options, "patch": int(side)}
        if direction is not None:
            opts["direction"] = np.broadcast_to(direction, (n, 2))[sel]
        if offset is not None:
            opts["offset"] = offset[sel]
        if "robust" in options:
            opts["robust"] = np.broadcast_to(options["robust"], (n,))[sel]
        res = lsm_match(fprep, gprep, points[sel], start[sel], initial=init[sel],
                        quadratic=quad[sel], **opts)
        for name in arrays:
            arrays[name][sel] = getattr(res, name)
        if side == options["patch"] and only is None:
            reference = res.noise_sigma0
    return LSMResult(noise_sigma0=reference, **arrays)


def _keep_first(second: LSMResult, first: LSMResult, lost: np.ndarray) -> LSMResult:
    """``second`` with the points ``lost`` (N,) bool taken from ``first`` (every array
    field both carry)."""
    arrays = {}
    for f in fields(second):
        mine, theirs = getattr(second, f.name), getattr(first, f.name)
        if f.name == "noise_sigma0" or mine is None or theirs is None:
            continue
        value = np.array(mine)
        value[lost] = theirs[lost]
        arrays[f.name] = value
    return replace(second, **arrays)


def _imprecise(res: LSMResult, k: float, patch: int, sides=None) -> np.ndarray:
    """(N,) bool: accepted with σ > median + k s over the accepted σ (>= 30 of them).

    s is the larger of 1.4826 MAD(σ) and the spread σ0's own estimation error gives σ,
    median / sqrt(2 (patch² - 8)) (as the σ0 test of :func:`matching.lsm.lsm_match`), so
    that a uniformly textured image, whose σ differ only by that, loses nothing.
    ``sides`` (N,): each side's windows against their own (ICI's sides differ 2x and their
    σ with them: a window kept small beside an edge is not imprecise for being small;
    a side with fewer than 30 accepted is not tested).
    """
    sigma = res.window_sigma  # the window's own precision (eccentric ones: before the
    ok = res.accepted & np.isfinite(sigma)  # transfer, whose growth is geometry, not texture)
    if sides is None:
        return _above_limit(sigma, ok, k, patch)
    out = np.zeros(len(ok), bool)
    for side in np.unique(sides[ok]):
        out |= _above_limit(sigma, ok & (sides == side), k, int(side))
    return out


def _above_limit(sigma: np.ndarray, ok: np.ndarray, k: float, patch: int) -> np.ndarray:
    if ok.sum() < 30:
        return np.zeros(len(ok), bool)
    return ok & (sigma > robust_upper_limit(sigma[ok], k, patch * patch - 8))


@dataclass(frozen=True)
class PairReconstruction:
    """3D points of the accepted matches of a pair (arrays over the M points).

    Attributes
    ----------
    points : (M, 3) float64, scene units
    colours : (M, 3) uint8
        RGB sampled from the left image at ``x_left``.
    sigma : (M,) float64, scene units
        σ along the worst-determined direction (triangulation covariance).
    cov : (M, 3, 3) float64, scene units²
    x_left, x_right : (M, 2) float64, px
    cov_2d : (M, 2, 2) float64, px²
        LSM covariance of the match.
    sigma_px, sigma0, correlation : (M,) float64
    iterations : (M,) int32
    reprojection_error : (M,) float64, px
    matches : PairMatches
        All candidates, their status updated with ``triangulation`` rejections.
    index : (M,) int64
        Index of each point among ``matches``.
    """

    points: np.ndarray
    colours: np.ndarray
    sigma: np.ndarray
    cov: np.ndarray
    x_left: np.ndarray
    x_right: np.ndarray
    cov_2d: np.ndarray
    sigma_px: np.ndarray
    sigma0: np.ndarray
    correlation: np.ndarray
    iterations: np.ndarray
    reprojection_error: np.ndarray
    matches: PairMatches
    index: np.ndarray

    def __len__(self) -> int:
        return len(self.points)

    def per_point(self) -> dict[str, np.ndarray]:
        """Every per-point array (for ``np.savez``)."""
        return {f.name: getattr(self, f.name) for f in fields(self)
                if f.name != "matches"}


def _colours(image, x_left) -> np.ndarray:
    img = np.asarray(image)
    xi = np.rint(x_left).astype(np.intp)
    if img.ndim == 2:
        grey = np.clip(np.rint(img[xi[:, 1], xi[:, 0]]), 0, 255).astype(np.uint8)
        return np.repeat(grey[:, None], 3, axis=1)
    bgr = img[xi[:, 1], xi[:, 0], :3]
    return np.clip(np.rint(bgr[:, ::-1].astype(np.float64)), 0, 255).astype(np.uint8)


def reconstruct_pair(left_img, right_img, rig, *, colour_image=None,
                     max_reprojection_px: float | None = None, **match_options
                     ) -> PairReconstruction:
    """Match a calibrated pair (:func:`match_pair`) and triangulate the accepted matches.

    Parameters
    ----------
    left_img, right_img : (H, W) or (H, W, 3) array_like
        Images (colour in OpenCV's BGR order).
    rig : matching.cameras.StereoRig
    colour_image : (H, W, 3) array_like, optional
        BGR image for the point colours (default: ``left_img``).
    max_reprojection_px : float, optional
        Also reject points whose RMS reprojection error exceeds this.
    **match_options
        Passed to :func:`match_pair`.

    Returns
    -------
    PairReconstruction

    Notes
    -----
    LSM's covariance is that of the *relative* position (both images' noise is in
    σ0); it is split evenly between the two observations, plus an isotropic floor of
    ``TOL.match_cov_floor_px``² so that the epipolar-constrained (rank 1) covariance
    stays positive definite.
    """
    from matching.triangulate import triangulate_pair

    if rig is None:
        raise ValueError("reconstruct_pair needs a rig (calibrated cameras)")
    matches = match_pair(left_img, right_img, rig, rectified=False, **match_options)
    ok = np.flatnonzero(matches.accepted)
    cov = 0.5 * matches.cov[ok] + TOL.match_cov_floor_px**2 * np.eye(2)
    tri = triangulate_pair(rig.left, rig.right, matches.x_left[ok], matches.x_right[ok],
                           cov_left=cov, cov_right=cov, refine=True,
                           max_reprojection_px=max_reprojection_px)
    status = matches.status.copy()
    status[ok[~tri.valid]] = TRIANGULATION
    matches = PairMatches(**{**{f.name: getattr(matches, f.name) for f in fields(matches)},
                             "status": status})
    keep = ok[tri.valid]
    colours = _colours(left_img if colour_image is None else colour_image,
                       matches.x_left[keep])
    return PairReconstruction(
        points=tri.points[tri.valid], colours=colours, sigma=tri.sigma[tri.valid],
        cov=tri.cov[tri.valid], x_left=matches.x_left[keep], x_right=matches.x_right[keep],
        cov_2d=matches.cov[keep], sigma_px=matches.sigma[keep], sigma0=matches.sigma0[keep],
        correlation=matches.correlation[keep], iterations=matches.iterations[keep],
        reprojection_error=tri.reprojection_error[tri.valid], matches=matches,
        index=keep.astype(np.int64))
