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
4. **triangulate** (:func:`matching.triangulate.triangulate_pair`): σ from LSM's covariance.

Precision control (second pass).  LSM's shift σ is noise-limited,
:math:`\sigma \approx \sigma_0 / \sqrt{2 w}` with Förstner's weight
:math:`w = \det N / \operatorname{tr} N` of the template's structure tensor N
(Förstner & Gülch 1987).  Two rules act on the first pass's validated σ: the
**adaptive patch** (Gruen's "adaptive": a point whose σ is worse than the median σ τ
of the accepted matches is re-matched with the smallest odd side up to ``max_patch``
whose predicted σ reaches τ, :func:`adaptive_sides`; a first-pass match the second
pass loses keeps its first-pass result) and the **precision test** (σ beyond the
median by more than ``max_sigma_mad_k`` robust spreads: ``imprecise``).

Epipolar pass (calibrated pairs, ``epipolar_pass``): windows re-matched in the rectified
images with the y-shift fixed by the rig (Gruen & Baltsavias 1988), the two images' blur
balanced by region (``equalise_blur``), rejected where ill-conditioned along the line
(``aperture``, tested at the window's least-variance point), reported at the pixel nearest
it, the edge-polarity bias removed.
Every candidate keeps a status code (:data:`PAIR_STATUS_NAMES`, :mod:`matching.pair_status`).
:func:`match_pair` runs named passes (:mod:`matching.pair_second_pass`, ``pair_epipolar``,
``pair_verify``, ``pair_centres``, ``pair_densify``); each rule and what decided it:
``docs/method/acquire.md``, ``docs/decisions/stereo-*.md``.

References
----------
.. [1] A. W. Gruen, "Adaptive least squares correlation", S. Afr. J. Photogramm. 14(3) (1985).
.. [2] W. Förstner, E. Gülch, "A fast operator for detection and precise location of distinct
   points, corners and centres of circular features", ISPRS Intercomm. Conf., 281-305 (1987).
"""


from __future__ import annotations

from dataclasses import dataclass, fields, replace
from types import SimpleNamespace

import numpy as np
from scipy.spatial import cKDTree

from matching import uniqueness
from matching.grow import grow_matches
from matching.ici import ici_ladder
from matching.lsm import (
    DEFAULT_FOOTPRINT_VAR,
    DEFAULT_INTERPOLATION,
    PreparedImage,
    Status,
    lsm_match,
    prepare_image,
)
from matching.pair_centres import _report_epipolar
from matching.pair_densify import _densify, density_deficit
from matching.pair_epipolar import _epipolar_refine
from matching.pair_second_pass import (
    _above_limit,
    _clear_at_sides,
    _grow_population,
    _imprecise,
    _keep_first,
    _rematch,
    _rematch_ici,
    adaptive_sides,
    default_max_patch,
)
from matching.pair_status import (
    AMBIGUOUS,
    APERTURE,
    BACKWARD,
    BLANK,
    IMPRECISE,
    NO_APPROXIMATION,
    OFF_SURFACE,
    PAIR_STATUS_NAMES,
    TRIANGULATION,
)
from matching.pair_verify import (
    _grow_from_volume,
    _grow_verified,
    _loop_closes,
    _loop_closes_rectified,
    _verify_unique,
    _verify_unique_rectified,
)
from matching.precision import class_variance_factors
from matching.rectify import left_to_rectified, rectified_to_original
from matching.second_order import second_order_terms
from matching.seeds import (
    DEFAULT_SPACING,
    approximate_calibrated,
    approximate_rectified,
    disparity_valid_left,
    rectify,
    select_points,
    window_offsets,
)
from matching.triangulate import triangulate_pair
from matching.validate import TOL

#: the names other modules and the tests take from here (status codes, the second pass's
#: public helpers, the density deficit)
__all__ = ["AMBIGUOUS", "APERTURE", "BACKWARD", "BLANK", "IMPRECISE", "NO_APPROXIMATION",
           "OFF_SURFACE", "PAIR_STATUS_NAMES", "TRIANGULATION", "PairMatches", "PairOptions",
           "PairReconstruction", "adaptive_sides", "default_max_patch", "density_deficit",
           "match_pair", "reconstruct_pair"]


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
        Second-lattice candidates matched (:func:`matching.pair_densify._densify`); they
        are the last ``densified`` entries of the arrays.
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



@dataclass(frozen=True)
class PairOptions:
    """How :func:`match_pair` matches a pair: each field may also be given to it as a keyword.

    Attributes
    ----------
    rectified : bool
        The images are rectified: corresponding points share a row (no rig needed).
    spacing, patch : int
        One candidate per ``spacing`` x ``spacing`` cell, px; LSM patch side, px (odd).
    interpolation : {"bilinear", "bicubic", "spline"}
        LSM resampler.
    epipolar : bool, optional
        Constrain the LSM shift to the epipolar direction (default: rectified pairs only).
    min_texture_snr : float
        Texture threshold factor (:func:`matching.seeds.select_points`).
    sgbm_block : int
        SGBM block side, px.
    second_order : bool
        A second pass with fixed second-order warp terms from the neighbours' affine
        parameters (:func:`matching.second_order.second_order_terms`).
    adaptive_patch : bool, "ici", "population" or tuple of int
        Second pass with a grown patch where the σ is worse than the median
        (:func:`adaptive_sides`, default); "ici" / "population": :mod:`matching.ici`'s rules;
        a tuple: those sides (odd, increasing).
    max_patch : int, optional
        Largest grown side, px (default: at most twice the pixels of ``patch``).
    max_sigma_mad_k : float or None
        Reject (``imprecise``) matches whose σ exceeds the median by more than k robust
        spreads (default 4); None: no precision test.
    eccentric : bool
        Windows moved off textureless cells, the point transferred through the warp
        (:func:`matching.seeds.window_offsets`); default off (no further view confirms them).
    densify : {False, True, "auto"}
        Rectified pairs: a second candidate lattice shifted by half a cell
        (:func:`matching.pair_densify._densify`); "auto": only where the density falls short.
    grow : bool
        Region growing from accepted neighbours (:func:`matching.grow.grow_matches`).
    sigma_factor : bool
        Covariances scaled by the variance factor of independent neighbouring windows, per
        window class (:func:`matching.precision.class_variance_factors`; never below 1).
    search_range : (int, int), optional
        SGBM's (min_disparity, num_disparities) of a rectified pair (default: SIFT matches).
    footprint_var : float or None
        ``lsm_match``'s template smoothing where the right view is foreshortened (default
        ``matching.lsm.DEFAULT_FOOTPRINT_VAR``); None: off.
    robust : {False, True, "edge"}
        Robust LSM (Tukey IRLS) for every window, the ``edge`` windows only, or none (default).
    unique : bool
        Uniqueness along the epipolar line (:func:`matching.uniqueness.verify_matches`,
        :func:`matching.uniqueness.anchored`) and a closed backward loop
        (:mod:`matching.pair_verify`); docs/decisions/stereo-uniqueness.md.
    epipolar_pass : bool
        Calibrated pairs: every window matched again in the rectified images with the rig's
        y-shift (:func:`matching.pair_epipolar._epipolar_refine`), ``aperture`` where
        ill-conditioned along the line; default off here, on in ``photosurf stereo`` and
        ``photosurf match --rig`` (docs/decisions/stereo-epipolar.md).
    regrow_ambiguous : bool
        Epipolar pass: grow the ambiguous windows again from verified neighbours too
        (:func:`matching.pair_verify._grow_verified`; docs/decisions/stereo-edges.md).
    centre_points : bool
        Epipolar pass: report each match at the pixel nearest its window's information
        centre (:func:`matching.pair_centres._information_centres`).
    aperture_k : float or None
        The ``aperture`` test's bound on the rig's row error through the edge slope, in
        units of the match's σ along the line (default 1); None: that part off.
    equalise_blur : bool
        Epipolar pass: the rectified images' blur along the rows made equal, measured from
        the matched windows, in place of ``footprint_var`` (default on;
        :func:`matching.pair_epipolar._blur_balance`; docs/decisions/stereo-blur.md).
    far_growth : int
        Epipolar pass: rounds (at most; 0: off) starting the windows still unmatched where
        their verified neighbours' disparity plane (or the scene range) leaves one unique
        peak (:func:`matching.pair_verify._grow_from_volume`; stereo-far-growth.md).
    """

    rectified: bool = False
    spacing: int = DEFAULT_SPACING
    patch: int = 15
    interpolation: str = DEFAULT_INTERPOLATION
    epipolar: bool | None = None
    min_texture_snr: float = 2.0
    sgbm_block: int = 5
    second_order: bool = True
    adaptive_patch: bool | str | tuple = True
    max_patch: int | None = None
    max_sigma_mad_k: float | None = 4.0
    eccentric: bool = False
    grow: bool = True
    sigma_factor: bool = True
    search_range: tuple[int, int] | None = None
    footprint_var: float | None = DEFAULT_FOOTPRINT_VAR
    densify: bool | str = False
    robust: bool | str = False
    unique: bool = True
    epipolar_pass: bool = False
    regrow_ambiguous: bool = True
    centre_points: bool = True
    aperture_k: float | None = 1.0
    equalise_blur: bool = True
    far_growth: int = 4


_PAIR_OPTION_KEYS = frozenset(f.name for f in fields(PairOptions))


def match_pair(left_img, right_img, rig=None, *, mask=None, options: PairOptions | None = None,
               **keywords) -> PairMatches:
    """Match a stereo pair densely by LSM.

    The steps and the rules' measurements are in docs/method/acquire.md and the
    ``docs/decisions/stereo-*.md`` pages each option names.

    Parameters
    ----------
    left_img, right_img : (H, W) or (H, W, 3) array_like, or matching.lsm.PreparedImage
        The images (colour to grey, OpenCV's BGR order); a prepared image is not refiltered.
    rig : matching.cameras.StereoRig, optional
        Calibration; required unless ``rectified`` (corresponding points share a row).
    mask : (H, W) bool, optional
        Only left pixels where true are candidates.
    options : PairOptions, optional
        How the pair is matched (default: :class:`PairOptions`' defaults); any of its fields
        may be given as a keyword instead (``spacing=2``), which overrides it.
    **keywords
        :class:`PairOptions` fields, and options passed to :func:`matching.lsm.lsm_match`
        (``max_iter``, ``sigma0_factor``...).
    Returns
    -------
    PairMatches

    Raises
    ------
    ValueError
        Images of different sizes or not matching the rig, no rig and not rectified,
        no overlap between the views.
    """
    chosen = {k: v for k, v in keywords.items() if k in _PAIR_OPTION_KEYS}
    lsm_options = {k: v for k, v in keywords.items() if k not in _PAIR_OPTION_KEYS}
    opts = replace(options or PairOptions(), **chosen)
    cfg = SimpleNamespace(**{f.name: getattr(opts, f.name) for f in fields(PairOptions)
                             if f.name != "epipolar"}, mask=mask, rig=rig)
    cfg.rectified = rectified = bool(opts.rectified)
    spacing, patch, interpolation = opts.spacing, opts.patch, opts.interpolation
    cfg.ladder, cfg.population = _check_options(cfg, lsm_options)
    preps, left, right = _read_images(left_img, right_img, rig, rectified, interpolation)
    cfg.epipolar = rectified if opts.epipolar is None else bool(opts.epipolar)
    cand = select_points(left, spacing=spacing, patch=patch, min_texture_snr=opts.min_texture_snr,
                         mask=mask, noise=None if preps[0] is None else preps[0].noise)
    n = len(cand.points)
    st = SimpleNamespace(cand=cand, offset=np.zeros((n, 2)), edge=np.zeros(n, bool),
                         status=np.full(n, Status.TEXTURELESS, np.uint8), out=_empty_out(n),
                         factor=1.0, factor_edge=1.0, deficit=0, densified=0,
                         x_left_out=None)  # None: the candidates' pixels
    if len(np.flatnonzero(cand.textured)) and _first_pass(cfg, st, left, right, preps,
                                                          lsm_options):
        _second_pass(cfg, st, left)
        _verify(cfg, st, left, right)
        _finish(cfg, st)
        if (opts.densify and rectified and spacing >= 2 and st.res.accepted.sum() >= 30):
            _densify_pass(cfg, st, left)
    return PairMatches(x_left=st.cand.points if st.x_left_out is None else st.x_left_out,
                       texture=st.cand.texture, status=st.status,
                       rectified=bool(rectified), image_size=(left.shape[1], left.shape[0]),
                       offset=st.offset, edge=st.edge, sigma_factor=float(st.factor),
                       sigma_factor_edge=float(st.factor_edge),
                       density_deficit=int(st.deficit), densified=int(st.densified), **st.out)


def _check_options(cfg, lsm_options: dict):
    """``match_pair``'s option errors; returns the ICI ladder (None: Gruen's sides) and
    whether the population rule is on."""
    patch, spacing, adaptive_patch = cfg.patch, cfg.spacing, cfg.adaptive_patch
    if not (isinstance(patch, int | np.integer) and patch >= 5 and patch % 2 == 1):
        raise ValueError(f"patch must be an odd integer >= 5, got {patch!r}")
    if not (isinstance(spacing, int | np.integer) and spacing >= 1):
        raise ValueError(f"spacing must be a positive integer, got {spacing!r}")
    ladder = None
    population = isinstance(adaptive_patch, str) and adaptive_patch == "population"
    if isinstance(adaptive_patch, str) and adaptive_patch == "ici":
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
    max_patch, max_sigma_mad_k = cfg.max_patch, cfg.max_sigma_mad_k
    if max_patch is not None and not (isinstance(max_patch, int | np.integer)
                                      and max_patch >= patch and max_patch % 2 == 1):
        raise ValueError(f"max_patch must be an odd integer >= patch ({patch}), "
                         f"got {max_patch!r}")
    if max_sigma_mad_k is not None and not (np.isfinite(max_sigma_mad_k)
                                            and max_sigma_mad_k > 0):
        raise ValueError(f"max_sigma_mad_k must be positive or None, got {max_sigma_mad_k!r}")
    if not (isinstance(cfg.robust, bool | np.bool_) or cfg.robust == "edge"):
        raise ValueError(f"robust must be True, False or 'edge', got {cfg.robust!r}")
    if not (isinstance(cfg.densify, bool | np.bool_) or cfg.densify == "auto"):
        raise ValueError(f"densify must be True, False or 'auto', got {cfg.densify!r}")
    corr = lsm_options.get("min_correlation", 0.7)
    if not (np.isfinite(corr) and -1.0 <= corr <= 1.0):
        raise ValueError(f"min_correlation must be in [-1, 1], got {corr!r}")
    return ladder, population


def _read_images(left_img, right_img, rig, rectified: bool, interpolation: str):
    """The pair as grey float64 images (and any PreparedImage inputs of ``interpolation``,
    used as they are, not refiltered), checked against each other and the rig."""
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
    return preps, left, right


def _empty_out(n: int) -> dict:
    """The per-candidate output arrays of :class:`PairMatches`, nothing matched yet."""
    return {
        "x_right": np.full((n, 2), np.nan), "approx": np.full((n, 2), np.nan),
        "cov": np.full((n, 2, 2), np.nan), "sigma": np.full(n, np.nan),
        "sigma0": np.full(n, np.nan), "correlation": np.full(n, np.nan),
        "iterations": np.zeros(n, np.int32), "affine": np.full((n, 6), np.nan),
        "radiometric": np.full((n, 2), np.nan), "patch": np.zeros(n, np.int32),
    }


def _approximations(cfg, st, left, right) -> tuple[np.ndarray, np.ndarray]:
    """SGBM approximations of the textured candidates (``st.approx``, ``st.rect``,
    ``st.valid``), their windows moved off untextured or unmatched pixels (eccentric) or
    flagged (``st.offset``, ``st.edge``).  Returns the right positions and directions."""
    cand, rectified, patch = st.cand, cfg.rectified, cfg.patch
    textured = np.flatnonzero(cand.textured)
    st.rect = rect = None if rectified else rectify(cfg.rig)

    def approximate(pts, reuse=None):
        if rectified:
            return approximate_rectified(left, right, pts, block=cfg.sgbm_block, patch=patch,
                                         reuse=reuse, search_range=cfg.search_range)
        return approximate_calibrated(cfg.rig, left, right, pts, rect=rect,
                                      block=cfg.sgbm_block, patch=patch, reuse=reuse)

    st.approx = approx = approximate(cand.points[textured])
    x_right, direction_all = approx.x_right.copy(), approx.direction.copy()
    # windows reaching into an untextured region or pixels SGBM left unmatched
    # (background, occlusions): moved off them and approximated at their new centres
    # (eccentric), else only flagged (``edge``)
    # (the SGBM map of a calibrated pair is taken back to the left image only when
    # windows are moved: its full-grid undistortion costs ~1 s at 1024x768)
    st.valid = (disparity_valid_left(approx, left.shape, None if rectified else cfg.rig, rect)
                if rectified or cfg.eccentric else None)
    st.offset, st.edge = window_offsets(cand, left, patch, cfg.spacing, cfg.mask, st.valid,
                                        move=cfg.eccentric)
    if cfg.eccentric:
        moved = np.flatnonzero(np.any(st.offset[textured] != 0.0, axis=1))
        if len(moved):
            again = approximate(cand.points[textured[moved]] + st.offset[textured[moved]],
                                reuse=approx)
            x_right[moved], direction_all[moved] = again.x_right, again.direction
    return x_right, direction_all


def _first_pass(cfg, st, left, right, preps, lsm_options: dict) -> bool:
    """Approximations, the first LSM pass and the region growing (:mod:`matching.grow`).
    Sets the state the later passes use; False when no candidate is left to match."""
    cand, patch, grow = st.cand, cfg.patch, cfg.grow
    textured = np.flatnonzero(cand.textured)
    x_right, direction_all = _approximations(cfg, st, left, right)
    centres = cand.points + st.offset  # window centres
    has = np.isfinite(x_right).all(1) & np.isfinite(direction_all).all(1)
    x_right[~has] = np.nan
    if grow:
        idx = textured
    else:
        st.status[textured[~has]] = NO_APPROXIMATION
        idx = textured[has]
    st.out["approx"][textured] = x_right
    if not len(idx):
        return False
    st.idx = idx
    st.fprep = fprep = (preps[0] if preps[0] is not None
                        else prepare_image(left, cfg.interpolation))
    st.gprep = gprep = (preps[1] if preps[1] is not None
                        else prepare_image(right, cfg.interpolation))
    sub = has if not grow else np.ones(len(textured), bool)
    points, start = centres[idx], x_right[sub]
    st.points = points
    st.shifted = shifted = np.any(st.offset[idx] != 0.0, axis=1)
    direction = _fill_directions(points, direction_all[sub]) if cfg.epipolar else None
    # a rectified pair maps rows to rows: the window's shape across them is
    # geometry, not an unknown (lsm_match's rigid_across)
    lsm_options.setdefault("rigid_across", bool(cfg.rectified and cfg.epipolar))
    st.options = options = dict(patch=patch, interpolation=cfg.interpolation,
                                direction=direction, min_texture_snr=cfg.min_texture_snr,
                                footprint_var=cfg.footprint_var, **lsm_options)
    if shifted.any():
        options["offset"] = -st.offset[idx]
    # "edge": the edge windows left where they are (an eccentric window was
    # moved off its edge)
    st.robust_flags = (st.edge[idx] & ~shifted if cfg.robust == "edge" else
                       np.full(len(idx), bool(cfg.robust)))
    res = lsm_match(fprep, gprep, points, start, robust=st.robust_flags, **options)
    if grow and res.accepted.any():
        # approximations from accepted neighbours (their affine warps) for the
        # candidates SGBM gave none, or whose SGBM start failed
        growth = grow_matches(
            fprep, gprep, points, res, start,
            candidates=res.status != Status.TEXTURELESS, same_row=bool(cfg.rectified),
            **options)
        res, start = growth.result, growth.approx
        st.out["approx"][idx] = start
    if grow:
        st.unapproximated = ~np.isfinite(start).all(1)
    st.res, st.start = res, start
    return True


def _second_pass(cfg, st, left) -> None:
    """Second-order terms and grown windows (Gruen's adaptive patch, the ICI ladder or the
    population rule: :mod:`matching.pair_second_pass`) -- not for a calibrated pair's
    epipolar pass, which re-matches every window with its own."""
    patch, res, points, start = cfg.patch, st.res, st.points, st.start
    fprep, gprep, options, idx = st.fprep, st.gprep, st.options, st.idx
    st.sides = sides = np.full(len(points), patch, np.int32)
    st.population_grown = False
    st.quad = quad = None
    # a calibrated pair's epipolar pass re-matches every window with its own
    # second-order terms and grown sides: the 2-D second pass would be redone
    epipolar_next = cfg.epipolar_pass and not cfg.rectified
    if not ((cfg.second_order or cfg.adaptive_patch) and res.accepted.sum() >= 8
            and not epipolar_next):
        return
    st.quad = quad = (second_order_terms(points, res.affine, res.accepted,
                                         radius_px=max(20.0, 5.0 * cfg.spacing))
                      if cfg.second_order else None)
    if cfg.adaptive_patch and cfg.ladder is None:
        sides = adaptive_sides(left, points, res.window_sigma, res.accepted,
                               patch, cfg.max_patch, noise=fprep.noise)
        # a grown eccentric window would reach over the edge it was moved off
        sides[st.shifted] = patch
    options["robust"] = st.robust_flags
    if cfg.ladder is not None:
        second, sides = _rematch_ici(fprep, gprep, points, start, res, quad,
                                     cfg.ladder, options, st.shifted, st.edge[idx])
    else:  # every window: re-matching only the accepted ones left the grown points
        # without their second-order terms (acquire-profile decision)
        second = _rematch(fprep, gprep, points, start, res, quad, sides, options)
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
    if cfg.population:
        clear_at = _clear_at_sides(st.cand, left, patch, cfg.spacing, cfg.mask, st.valid,
                                   idx, int(sides.max()))
        second, sides, st.population_grown = _grow_population(
            fprep, gprep, points, start, res, quad, second, sides, patch,
            options, st.shifted, st.edge[idx], clear_at)
    st.res, st.sides = second, sides


def _verify(cfg, st, left, right) -> None:
    """The epipolar pass (calibrated pairs, ``epipolar_pass``), the uniqueness verdicts and
    backward loops (:mod:`matching.pair_verify`), then the epipolar pass's verified growth
    and report (:mod:`matching.pair_centres`)."""
    idx, status = st.idx, st.status
    st.geo_var, st.first_pass, st.rival_var, st.frame = None, None, None, None
    if cfg.epipolar_pass and not cfg.rectified and st.res.accepted.sum() >= 30:
        # Gruen & Baltsavias' geometric constraint: the y-shift is the rig's,
        # only the shift and shape along the epipolar line are solved
        st.first_pass = st.res
        res, st.geo_var, st.epi_dirs, st.sides, st.epi_factor, st.frame = _epipolar_refine(
            left, right, cfg.rig, st.rect, st.points, st.start, st.res, st.sides,
            st.options, cfg.aperture_k, cfg.interpolation, second_order=cfg.second_order,
            spacing=cfg.spacing, classes=st.edge[idx], scale_cov=bool(cfg.sigma_factor),
            at_best_point=cfg.centre_points, equalise_blur=cfg.equalise_blur)
        status_ill = res.accepted & ~np.isfinite(st.geo_var)
        st.res = replace(res, status=np.where(status_ill, APERTURE, res.status)
                         .astype(res.status.dtype))
    res = st.res
    verdict = None
    if cfg.unique and res.accepted.any():
        if st.first_pass is not None:
            verdict, st.rival_var = _verify_unique_rectified(st.frame, st.points, res,
                                                             st.approx.range, cfg.patch)
        else:
            verdict = _verify_unique(left, right, cfg.rig, st.rect, cfg.rectified, st.fprep,
                                     st.gprep, st.points, res, st.approx.range, cfg.patch,
                                     st.options)
    status[idx] = res.status
    if verdict is not None:
        status[idx[verdict == uniqueness.AMBIGUOUS]] = AMBIGUOUS
        status[idx[verdict == uniqueness.BLANK]] = BLANK
        survivors = verdict == uniqueness.UNIQUE
        closes = (_loop_closes_rectified(st.frame, survivors) if st.first_pass is not None
                  else _loop_closes(st.fprep, st.gprep, st.points, res, survivors, cfg.patch,
                                    st.options))
        status[idx[survivors & ~closes]] = BACKWARD
    if cfg.grow:
        status[idx[st.unapproximated]] = NO_APPROXIMATION
    if st.rival_var is not None:
        # what the rivals along the line leave (rectified px² -> right px²); a
        # match whose uncertainty they dominate -- more than the texture and the
        # rig leave -- is not unique at any precision it could claim
        st.rival_stretch = np.ones(len(idx))
        st.rival_stretch[st.frame["index"]] = np.nan_to_num(st.frame["stretch"], nan=1.0)
        own = np.einsum("ni,nij,nj->n", st.epi_dirs, res.cov, st.epi_dirs)
        dominated = st.rival_var * st.rival_stretch > own + np.nan_to_num(st.geo_var)
        status[idx[(status[idx] == Status.OK) & dominated]] = AMBIGUOUS
    if st.first_pass is not None:
        _grow_and_report(cfg, st, left, right)


def _grow_and_report(cfg, st, left, right) -> None:
    """The epipolar pass's region growing from verified matches (with ``unique`` and
    ``grow``) and where its matches are reported
    (:func:`matching.pair_centres._report_epipolar`)."""
    idx, status = st.idx, st.status
    if cfg.unique and cfg.grow:
        def refine(start_, sub, sides_):
            return _epipolar_refine(
                left, right, cfg.rig, st.rect, st.points, start_, sub, sides_, st.options,
                cfg.aperture_k, cfg.interpolation, second_order=cfg.second_order,
                spacing=cfg.spacing, classes=st.edge[idx], scale_cov=bool(cfg.sigma_factor),
                fixed=st.frame, at_best_point=cfg.centre_points,
                equalise_blur=cfg.equalise_blur)

        local = status[idx].copy()
        reach = max(cfg.patch / 2.0, 1.5 * cfg.spacing)
        st.res, grown_mask = _grow_verified(local, st.points, st.res, st.frame, st.geo_var,
                                            st.epi_dirs, st.sides, refine, cfg.patch,
                                            reach=reach, ambiguous=cfg.regrow_ambiguous)
        # pinned by their verified neighbours within the pull-in range: the
        # rivals a period away are excluded
        st.rival_var[grown_mask] = 0.0
        tried = np.zeros(len(idx), bool)
        far_all = np.zeros(len(idx), bool)
        before = local.copy()
        for _ in range(cfg.far_growth):
            # where SGBM is blind or a period off: the verified neighbours' disparity
            # plane (or the scene range) with the uniqueness test deciding, then
            # the verified growth again from what that found; rounds while it finds
            st.res, far, far_var = _grow_from_volume(
                local, st.points, st.res, st.frame, st.geo_var, st.epi_dirs, st.sides,
                refine, cfg.patch, st.approx.range,
                lambda p: left_to_rectified(st.rect, cfg.rig.left, p),
                lambda q: rectified_to_original(st.rect, cfg.rig.right, q), tried)
            st.rival_var[far] = far_var[far]
            far_all |= far
            if not far.any():
                break
            st.res, again = _grow_verified(local, st.points, st.res, st.frame,
                                           st.geo_var, st.epi_dirs, st.sides, refine,
                                           cfg.patch, reach=reach,
                                           ambiguous=cfg.regrow_ambiguous)
            st.rival_var[again] = 0.0
        if far_all.any():
            # a match geometry from afar resolved stands only where the verified growth
            # joined it: two other matches within the growth's reach (a lone window is
            # one piece of evidence, and its neighbours' plane was extrapolated)
            ok_now = np.flatnonzero(local == Status.OK)
            joined = cKDTree(st.points[ok_now]).query_ball_point(
                st.points[far_all], r=reach, return_length=True) - 1
            lone = np.flatnonzero(far_all)[joined < 2]
            local[lone] = before[lone]
        status[idx] = local
    local = status[idx].copy()
    st.res, st.epi_dirs, st.offset, st.x_left_out, st.polarity_var = _report_epipolar(
        st.frame, st.rect, cfg.rig, st.res, st.epi_dirs, local, st.cand.points, idx,
        st.points, st.offset, st.x_left_out, left.shape[1], cfg.centre_points,
        bool(cfg.sigma_factor))
    status[idx] = local


def _finish(cfg, st) -> None:
    """The precision test, the variance factors and the output arrays of the matched
    candidates (with the epipolar pass: what the rig, the rivals and the edges leave
    along the line, and the precision test again on that σ)."""
    idx, status, res, out, patch = st.idx, st.status, st.res, st.out, cfg.patch
    out["patch"][idx] = st.sides
    if cfg.max_sigma_mad_k is not None:
        status[idx[_imprecise(res, cfg.max_sigma_mad_k, patch,
                              None if cfg.ladder is None and not st.population_grown
                              else st.sides)]] = IMPRECISE
    per_window = np.ones(len(idx))
    if cfg.sigma_factor:
        ok_final = status[idx] == Status.OK
        # σ0²N⁻¹ is the white-noise precision, a lower bound: what real images
        # add only grows it (an estimate below 1 is the estimator's own scatter,
        # ~10 % for a few thousand matches); windows clear of and reaching over
        # an edge are two populations (class_variance_factors)
        if st.first_pass is None:
            per_window, factors = class_variance_factors(
                st.points, res.affine, res.affine_cov, ok_final,
                st.edge[idx].astype(np.int64), patch=st.sides)
        else:  # the epipolar pass's covariances carry their own factors
            per_window, factors = np.ones(len(idx)), np.array(st.epi_factor)
        st.factor = float(factors[0]) if len(factors) else 1.0
        st.factor_edge = float(factors[1]) if len(factors) > 1 else st.factor
    out["x_right"][idx] = res.position
    out["cov"][idx] = res.cov * per_window[:, None, None]
    if st.geo_var is not None:
        # what the rig's epipolar error leaves along the line (_epipolar_refine)
        along = np.nan_to_num(st.geo_var) + st.polarity_var
        if st.rival_var is not None:
            # what the rivals along the line leave (rectified px² -> right px²);
            # a match whose uncertainty they dominate -- more than the texture and
            # the rig leave -- is not unique at any precision it could claim
            along = along + st.rival_var * st.rival_stretch
        out["cov"][idx] += (along[:, None, None]
                            * st.epi_dirs[:, :, None] * st.epi_dirs[:, None, :])
    out["sigma"][idx] = np.sqrt(np.trace(out["cov"][idx], axis1=1, axis2=2) / 2.0)
    if st.geo_var is not None and cfg.max_sigma_mad_k is not None:
        # the precision test again on the σ reported, with what the rig, the
        # rivals and the edges leave along the line
        status[idx[_above_limit(out["sigma"][idx], status[idx] == Status.OK,
                                cfg.max_sigma_mad_k, patch)]] = IMPRECISE
    out["sigma0"][idx] = res.sigma0
    out["correlation"][idx] = res.correlation
    out["iterations"][idx] = res.iterations
    out["affine"][idx] = res.affine
    out["radiometric"][idx] = res.radiometric


def _densify_pass(cfg, st, left) -> None:
    """A rectified pair's second candidate lattice
    (:func:`matching.pair_densify._densify`), appended."""
    quad_all = None
    n = len(st.status)
    if cfg.second_order and st.quad is not None:
        quad_all = np.full((n, 6), np.nan)
        quad_all[st.idx] = st.quad
    dense = _densify(left, st.fprep, st.gprep, st.cand, st.status, st.edge, st.offset,
                     st.out, st.res, cfg.spacing, cfg.patch, cfg.mask, st.valid, quad_all,
                     cfg.max_sigma_mad_k, st.factor, st.options,
                     auto=cfg.densify == "auto")
    st.cand, st.status, st.edge, st.offset, st.out, st.deficit = dense
    st.densified = len(st.status) - n


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
