r"""Point selection and approximate correspondences for least-squares matching.

Texture.  A template is worth matching when its smallest structure-tensor eigenvalue is
well above what image noise alone produces (Shi & Tomasi 1994):

.. math::

    S = \frac{1}{n}\sum_{patch} \nabla f \nabla f^\mathsf{T}, \qquad
    \lambda_{min}(S) \ge k \, \sigma_n^2 / 2 ,

with central-difference gradients (the noise of one has variance :math:`\sigma_n^2/2`),
:math:`\sigma_n` Immerkaer's noise estimate and :math:`k` = ``min_texture_snr`` -- the test
and units of :func:`matching.lsm.lsm_match`, so a selected point is never rejected there as
textureless.  The best point of every ``spacing`` x ``spacing`` cell is kept.

Precision.  :func:`shift_precision` predicts the σ of a match per unit σ0 from the same
tensor summed over a patch, less its noise part (Förstner's error ellipse, 1/√(2w),
w = det N / tr N, Förstner & Gülch 1987), for any set of patch sides at once (integral
images); :func:`forstner` gives w and the roundness q.  Selecting by w or q only buys
precision by dropping points (on the vase, q >= 0.75 keeps 81 % of the points for 0.0371 ->
0.0364 px RMS); :mod:`matching.pair` uses the prediction to grow the patch instead.

Approximations.  A calibrated pair is rectified (:mod:`matching.rectify`, Fusiello, Trucco
and Verri 2000) and ``cv2.StereoSGBM`` (Hirschmüller 2008) computes a coarse disparity map,
its range from SIFT matches between the rectified images (ratio test, rows within 2 px:
1st-99th percentile plus a margin).  A selected left pixel is mapped into the rectified
left image exactly, shifted by the SGBM disparity, and mapped back into the *original*
right image exactly (rectified ray -> R2ᵀ -> ``cv2.projectPoints`` with the right camera's
distortion).  LSM then refines in the original images: the template is never resampled
(its noise stays white, as σ0²(AᵀA)⁻¹ assumes); the local epipolar direction is given.

References: J. Shi, C. Tomasi, "Good features to track", CVPR (1994); H. Hirschmüller,
"Stereo processing by semiglobal matching and mutual information", IEEE TPAMI 30(2)
(2008); J.-Y. Bouguet, Camera Calibration Toolbox for Matlab; W. Förstner, E. Gülch, "A
fast operator for detection and precise location of distinct points, corners and centres
of circular features", ISPRS Interlaken, 281-305 (1987); A. F. Bobick, S. S. Intille,
"Large occlusion stereo", IJCV 33(3) (1999); A. Fusiello, V. Roberto, E. Trucco,
"Efficient stereo with multiple windowing", CVPR (1997).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from matching.lsm import estimate_noise
from matching.rectify import (  # noqa: F401 - rectification lives in matching.rectify
    Rectification,
    left_to_rectified,
    rectified_to_original,
    rectify,
    rectify_images,
)
from matching.validate import TOL, check_shape

#: Candidate spacing, px: one candidate per 3 x 3 cell.  Chosen for the density the
#: multi-view issue asks for (>= 20x the points of a SIFT structure-from-motion model:
#: 21.9x on the 24-view ring, 12.9x at 4 px) at a cost the 2-core budget still takes;
#: neighbouring points then share most of their 15 px windows, so their errors are
#: correlated (each σ is right; the independent samples are fewer than the points).
DEFAULT_SPACING = 3


@dataclass(frozen=True)
class Candidates:
    """Grid of candidate template centres.

    Attributes
    ----------
    points : (N, 2) float64
        Integer pixel positions (x, y) in the image, px.
    texture : (N,) float64
        λ_min of the mean structure tensor over the patch, grey levels²/px².
    textured : (N,) bool
        ``texture >= threshold``.
    threshold : float
        ``min_texture_snr * noise**2 / 2``.
    noise : float
        Image noise σ used, grey levels.
    """

    points: np.ndarray
    texture: np.ndarray
    textured: np.ndarray
    threshold: float
    noise: float


def texture_map(image, patch: int = 15) -> np.ndarray:
    """λ_min of the mean structure tensor over a ``patch`` x ``patch`` window at every pixel.

    Parameters
    ----------
    image : (H, W) array_like
        Grey image.
    patch : int
        Window side, px.

    Returns
    -------
    (H, W) float64, grey levels² / px²; the border (patch/2 + 1 px) is 0.
    """
    img = np.asarray(image, dtype=np.float64)
    gx = np.zeros_like(img)
    gy = np.zeros_like(img)
    gx[:, 1:-1] = 0.5 * (img[:, 2:] - img[:, :-2])
    gy[1:-1, :] = 0.5 * (img[2:, :] - img[:-2, :])
    box = lambda a: cv2.boxFilter(a, cv2.CV_64F, (patch, patch), normalize=True,  # noqa: E731
                                  borderType=cv2.BORDER_REPLICATE)
    sxx, syy, sxy = box(gx * gx), box(gy * gy), box(gx * gy)
    lam = 0.5 * (sxx + syy) - np.sqrt(0.25 * (sxx - syy) ** 2 + sxy**2)
    border = patch // 2 + 1
    out = np.zeros_like(lam)
    out[border:-border, border:-border] = lam[border:-border, border:-border]
    return out


def select_points(image, spacing: int = DEFAULT_SPACING, patch: int = 15,
                  min_texture_snr: float = 2.0,
                  noise: float | None = None, margin: int | None = None,
                  mask=None) -> Candidates:
    """The best-textured pixel of every ``spacing`` x ``spacing`` cell.

    Parameters
    ----------
    image : (H, W) array_like
        Grey template (left) image.
    spacing : int
        Cell side, px (1 = every pixel).
    patch : int
        LSM patch side, px.
    min_texture_snr : float
        Threshold factor k of the module docstring (same as ``lsm_match``'s).
    noise : float, optional
        Image noise σ, grey levels (default: Immerkaer's estimate).
    margin : int, optional
        Cells closer than this to the border are skipped (default patch/2 + 2).
    mask : (H, W) bool, optional
        Only pixels where ``mask`` is true may be chosen.

    Returns
    -------
    Candidates
    """
    img = np.asarray(image, dtype=np.float64)
    if img.ndim != 2:
        raise ValueError(f"image must be a 2-D grey image, got shape {img.shape}")
    if not (int(spacing) == spacing and spacing >= 1):
        raise ValueError(f"spacing must be a positive integer, got {spacing!r}")
    spacing = int(spacing)
    sigma = estimate_noise(img) if noise is None else float(noise)
    lam = texture_map(img, patch)
    margin = patch // 2 + 2 if margin is None else int(margin)
    h, w = img.shape
    score = np.full_like(lam, -1.0)
    score[margin:h - margin, margin:w - margin] = lam[margin:h - margin, margin:w - margin]
    if mask is not None:
        mask = check_shape(mask, "(H, W)", "mask", dtype=bool)
        if mask.shape != img.shape:
            raise ValueError(f"mask must have the image's shape {img.shape}, got {mask.shape}")
        score[~mask] = -1.0
    ny, nx = h // spacing, w // spacing
    cells = score[:ny * spacing, :nx * spacing].reshape(ny, spacing, nx, spacing)
    cells = cells.transpose(0, 2, 1, 3).reshape(ny, nx, spacing * spacing)
    best = cells.argmax(axis=2)
    best_score = np.take_along_axis(cells, best[..., None], axis=2)[..., 0]
    cy, cx = np.mgrid[0:ny, 0:nx]
    ys = cy * spacing + best // spacing
    xs = cx * spacing + best % spacing
    keep = best_score >= 0.0
    points = np.column_stack([xs[keep], ys[keep]]).astype(np.float64)
    texture = best_score[keep]
    threshold = max(min_texture_snr * 0.5 * sigma**2, TOL.zero)
    return Candidates(points=points, texture=texture, textured=texture > threshold,
                      threshold=float(threshold), noise=sigma)


#: Window side of the fine texture test that locates the edge of an untextured region
#: (:func:`window_offsets`), px: the smallest window whose structure tensor still
#: tells 2-D texture from noise (25 gradients); the edge is found to half of it.
EDGE_SCALE_PX = 5


def window_offsets(candidates: Candidates, image, patch: int = 15,
                   spacing: int = DEFAULT_SPACING, mask=None,
                   valid=None, move: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Eccentric windows: move each template window off textureless cells (shiftable windows).

    A candidate's window that reaches into an untextured region (uniform background
    beyond a silhouette or a rim, an untextured part of the object) straddles an
    edge: the pixels beyond it do not move with the surface, and the match slides
    along the edge.  The region is located at two scales: the ``spacing`` cells of
    the candidates that failed the texture test (``patch`` window) mark it, and the
    pixels that fail the same test over an ``EDGE_SCALE_PX`` window and are connected
    to such a cell trace its boundary to a couple of pixels; grown by half that
    window (the test's own reach), they are the pixels *off* the textured surface.
    A window holding such a pixel, a pixel without an approximation (``valid``) or a
    masked one is moved by the smallest integer offset ``o`` (Euclidean length;
    ``|o| <= patch // 2`` per axis, so the point stays in its window) that clears
    them all and keeps the window inside the image (LSM's margin); LSM then matches
    that window and transfers the point through the estimated warp (``lsm_match``'s
    ``offset = -o``).  A candidate itself off the surface gets no eccentric window
    (the transfer would extrapolate the surface beyond its edge).  Weakly textured
    parts of the object that no failed cell touches are not affected.  The idea of
    the shiftable / multiple windows of area-based stereo near depth
    discontinuities (Bobick & Intille 1999; Fusiello, Roberto & Trucco 1997).

    Parameters
    ----------
    candidates : Candidates
        :func:`select_points`'s grid (same ``spacing`` and ``patch``).
    image : (H, W) array_like
        The grey template image.
    patch : int
        Window side, px (odd).
    spacing : int
        Candidate cell side, px.
    mask : (H, W) bool, optional
        Pixels a window may cover (default all).
    valid : (H, W) bool, optional
        Pixels where the approximations have a disparity
        (:func:`disparity_valid_left`): windows avoid the others as well, and a
        candidate on such a pixel (beyond the object) gets no eccentric window.
    move : bool
        False: no window is moved; ``edge`` then flags every textured candidate whose
        centred window is blocked (the windows a caller should not trust).

    Returns
    -------
    offset : (N, 2) float64
        Window centre minus candidate, px (0 where the centred window is clear, or
        where no offset clears it).
    edge : (N,) bool
        A textured candidate no window within the patch clears: its window straddles
        the edge.
    """
    img = np.asarray(image, dtype=np.float64)
    if img.ndim != 2:
        raise ValueError(f"image must be a 2-D grey image, got shape {img.shape}")
    h, w = img.shape
    half = patch // 2
    pts = np.asarray(candidates.points, dtype=np.intp).reshape(-1, 2)
    n = len(pts)
    bad, valid = _excluded_pixels((h, w), mask, valid)
    off_surface = _off_surface(img, candidates, pts, spacing)
    bad[off_surface] = 1.0
    count = cv2.boxFilter(bad, -1, (patch, patch), normalize=False,
                          borderType=cv2.BORDER_CONSTANT)
    clear = count < 0.5
    # LSM's inside test for the template window: cx - half >= 1, cx + half < w - 2
    inside = np.zeros((h, w), bool)
    inside[half + 1:max(h - half - 2, half + 1), half + 1:max(w - half - 2, half + 1)] = True
    clear &= inside
    offset = np.zeros((n, 2))
    edge = np.zeros(n, bool)
    if n == 0:
        return offset, edge
    blocked = ~clear[pts[:, 1], pts[:, 0]]
    textured = np.asarray(candidates.textured, bool)
    off_object = off_surface[pts[:, 1], pts[:, 0]]
    if valid is not None:
        off_object |= ~valid[pts[:, 1], pts[:, 0]]
    if not move:
        return offset, blocked & textured
    todo = np.flatnonzero(blocked & textured & ~off_object)
    if len(todo):
        found, offs = _nearest_clear_offsets(pts[todo], clear, half)
        offset[todo[found]] = offs[found]
        edge[todo[~found]] = True
    edge |= blocked & textured & off_object
    return offset, edge


def _excluded_pixels(shape, mask, valid):
    """:func:`window_offsets`' pixels a window must not cover (float32 1.0): outside
    ``mask`` or without an approximation (``valid``); returns them and ``valid`` checked."""
    h, w = shape
    bad = np.zeros((h, w), np.float32)
    if mask is not None:
        mask = check_shape(mask, "(H, W)", "mask", dtype=bool)
        if mask.shape != (h, w):
            raise ValueError(f"mask must have the image's shape {(h, w)}, got {mask.shape}")
        bad[~mask] = 1.0
    if valid is not None:
        valid = check_shape(valid, "(H, W)", "valid", dtype=bool)
        if valid.shape != (h, w):
            raise ValueError(f"valid must have the image's shape {(h, w)}, got {valid.shape}")
        bad[~valid] = 1.0
    return bad, valid


def _off_surface(img: np.ndarray, candidates: Candidates, pts: np.ndarray,
                 spacing: int) -> np.ndarray:
    """:func:`window_offsets`' pixels off the textured surface, (H, W) bool: the failed
    candidates' cells and the connected pixels failing the texture test over an
    ``EDGE_SCALE_PX`` window, grown by that test's reach."""
    h, w = img.shape
    off_surface = np.zeros((h, w), bool)
    # The region a window must not reach is judged against the *upper* noise bound, the
    # whole-image Immerkaer estimate (texture counted as noise), not the flat-block σ the
    # texture test uses: the two errors cost differently -- a background cell called
    # textured lets a straddling window follow the silhouette and put its point beyond
    # the object, one called flat only moves a window.  (1024x768 24-view ring, 377 k
    # points: with the flat-block σ here 222 points lay beyond the rims, cloud RMS 0.00057;
    # with the upper bound 3 points, RMS 0.00025.)
    upper = max(float(candidates.noise), estimate_noise(img, flat_blocks=False))
    scale = (upper / candidates.noise) ** 2 if candidates.noise > 0 else 1.0
    edge_threshold = candidates.threshold * scale
    flat = pts[~(np.asarray(candidates.texture, np.float64) > edge_threshold)]
    if len(flat):
        cells = np.zeros((-(-h // spacing), -(-w // spacing)), np.uint8)
        cells[flat[:, 1] // spacing, flat[:, 0] // spacing] = 1
        up = np.repeat(np.repeat(cells, spacing, axis=0), spacing, axis=1)[:h, :w] > 0
        fine = texture_map(img, EDGE_SCALE_PX) < edge_threshold
        rim = EDGE_SCALE_PX // 2 + 1  # texture_map's border is unknown, not flat
        fine[:rim] = fine[-rim:] = False
        fine[:, :rim] = fine[:, -rim:] = False
        _, labels = cv2.connectedComponents(fine.astype(np.uint8), connectivity=8)
        touched = np.unique(labels[up & fine])
        region = np.isin(labels, touched[touched > 0]) | up
        # grown by the test's reach: a 5 px window of central differences reads pixels
        # up to 5 // 2 + 1 = 3 px from its centre (a 5 px kernel, reach 2, left a 1 px
        # gap at a rim where a candidate could sit off the surface unflagged)
        reach = 2 * (EDGE_SCALE_PX // 2 + 1) + 1
        off_surface = cv2.dilate(region.astype(np.uint8), np.ones((reach, reach), np.uint8)) > 0
    return off_surface


def _nearest_clear_offsets(pts: np.ndarray, clear: np.ndarray, half: int):
    """For each point (M, 2) the smallest integer offset (Euclidean length, then angle;
    at most ``half`` per axis) whose window centre is ``clear``: (found (M,), the
    offsets (M, 2), meaningful where found)."""
    h, w = clear.shape
    oy, ox = np.mgrid[-half:half + 1, -half:half + 1]
    order = np.lexsort((np.arctan2(oy.ravel(), ox.ravel()), ox.ravel()**2 + oy.ravel()**2))
    offs = np.column_stack([ox.ravel(), oy.ravel()])[order]  # (S, 2), nearest first
    xs = pts[:, 0][:, None] + offs[None, :, 0]
    ys = pts[:, 1][:, None] + offs[None, :, 1]
    valid = (xs >= 0) & (xs < w) & (ys >= 0) & (ys < h)
    ok = np.zeros(xs.shape, bool)
    ok[valid] = clear[ys[valid], xs[valid]]
    found = ok.any(axis=1)
    first = ok.argmax(axis=1)
    return found, offs[first]


def structure_tensors(image, points, sides) -> np.ndarray:
    """Sums of the gradient products over square windows of several sides at each point.

    Parameters
    ----------
    image : (H, W) array_like
        Grey image, grey levels.
    points : (N, 2) array_like
        Integer window centres (x, y), px.
    sides : sequence of int
        Odd window sides, px.

    Returns
    -------
    (S, N, 3) float64
        ``(sum fx², sum fy², sum fx fy)`` over each window (central-difference
        gradients, grey levels²/px²); NaN where a window comes closer than 1 px to the
        image border.

    Notes
    -----
    One integral image per product (``cv2.integral``), so any number of sides costs one
    pass over the image plus four look-ups per point and side.
    """
    img = np.asarray(image, dtype=np.float64)
    points = check_shape(points, "(N, 2)", "points", dtype=np.float64)
    gx = np.zeros_like(img)
    gy = np.zeros_like(img)
    gx[:, 1:-1] = 0.5 * (img[:, 2:] - img[:, :-2])
    gy[1:-1, :] = 0.5 * (img[2:, :] - img[:-2, :])
    sums = [cv2.integral(prod, sdepth=cv2.CV_64F) for prod in (gx * gx, gy * gy, gx * gy)]
    h, w = img.shape
    xi = np.rint(points[:, 0]).astype(np.intp)
    yi = np.rint(points[:, 1]).astype(np.intp)
    out = np.full((len(sides), len(points), 3), np.nan)
    for k, side in enumerate(sides):
        half = int(side) // 2
        x0, y0, x1, y1 = xi - half, yi - half, xi + half + 1, yi + half + 1
        # one pixel to spare: the window's central differences need their neighbours
        inside = (x0 >= 1) & (y0 >= 1) & (x1 <= w - 1) & (y1 <= h - 1)
        x0, y0, x1, y1 = (c[inside] for c in (x0, y0, x1, y1))
        for c, table in enumerate(sums):
            out[k, inside, c] = table[y1, x1] - table[y0, x1] - table[y1, x0] + table[y0, x0]
    return out


def shift_precision(image, points, sides, noise: float | None = None) -> np.ndarray:
    r"""Predicted σ of the matched shift per unit σ0, for several patch sides (Förstner).

    The shift part of the LSM normal matrix is the structure tensor of the template,
    :math:`N = \sum \nabla f \nabla f^\mathsf{T}`, less its expected noise part
    :math:`n \sigma_n^2/2 \, I` (n pixels, central differences); its inverse is
    Förstner's error ellipse of the point, and
    :math:`\sqrt{\operatorname{tr} N^{-1} / 2} = 1/\sqrt{2 w}`,
    :math:`w = \det N / \operatorname{tr} N` the interest operator's weight [4]_.
    Times the residual σ0 of a match, it predicts the σ that :func:`matching.lsm.lsm_match`
    reports before the affine unknowns are added (they raise it by a factor that barely
    depends on the side, so ratios between sides carry over).

    Parameters
    ----------
    image : (H, W) array_like
        Grey template image, grey levels.
    points : (N, 2) array_like
        Integer template centres, px.
    sides : sequence of int
        Odd patch sides, px.
    noise : float, optional
        Image noise σ_n, grey levels (default: Immerkaer's estimate).

    Returns
    -------
    (S, N) float64
        px per grey level of σ0; ``inf`` where the noise-free tensor is not positive
        definite, NaN where the patch leaves the image.
    """
    sigma = estimate_noise(np.asarray(image, dtype=np.float64)) if noise is None else noise
    st = structure_tensors(image, points, sides)
    area = np.asarray([int(s) ** 2 for s in sides], dtype=np.float64)[:, None]
    sxx = st[..., 0] - area * 0.5 * sigma**2
    syy = st[..., 1] - area * 0.5 * sigma**2
    sxy = st[..., 2]
    det = sxx * syy - sxy**2
    trace = sxx + syy
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.where((det > TOL.zero) & (sxx > 0), np.sqrt(0.5 * trace / det), np.inf)
    out[~np.isfinite(st).all(-1)] = np.nan
    return out


def forstner(image, points, patch: int = 15) -> tuple[np.ndarray, np.ndarray]:
    """Förstner's interest operator at ``points``: weight w and roundness q [4]_.

    ``w = det N / tr N`` (grey levels²/px², the size of the inverse error ellipse) and
    ``q = 4 det N / tr² N`` in [0, 1] (1: circular ellipse), N the structure tensor
    summed over the ``patch`` x ``patch`` window.

    Returns
    -------
    w, q : (N,) float64
    """
    st = structure_tensors(image, points, [patch])[0]
    det = st[:, 0] * st[:, 1] - st[:, 2] ** 2
    trace = st[:, 0] + st[:, 1]
    with np.errstate(invalid="ignore", divide="ignore"):
        return det / trace, 4.0 * det / trace**2


# --------------------------------------------------------------------------------------
# rectification
# --------------------------------------------------------------------------------------


# --------------------------------------------------------------------------------------
# coarse dense matching
# --------------------------------------------------------------------------------------


def _to_uint8(img) -> np.ndarray:
    return np.clip(np.asarray(img, dtype=np.float64) + 0.5, 0, 255).astype(np.uint8)


#: Rectified images wider than this find their SIFT disparity range at half resolution.
_SIFT_FULL_RES_PX = 640


def disparity_range(left_rect, right_rect, min_matches: int = 8) -> tuple[int, int]:
    """Disparity search range (min, count) of a rectified pair from SIFT matches.

    Parameters
    ----------
    left_rect, right_rect : (H, W) array_like
        Rectified grey images.
    min_matches : int
        Fewer row-consistent matches than this means the views do not overlap.

    Returns
    -------
    (min_disparity, num_disparities) : (int, int)
        ``num_disparities`` a multiple of 16 (SGBM's requirement); the range covers the
        2nd-98th percentile of the disparities of mutual SIFT matches (Lowe's ratio test
        0.75 both ways, rows within 2 px) widened by 25 % and 8 px, clipped to the width;
        features are detected at half resolution in images wider than 640 px.

    Raises
    ------
    ValueError
        ``"no overlap ..."`` when too few matches are found.
    """
    sift = cv2.SIFT_create(nfeatures=4000)
    # the range is padded by 8 px + 25 %: features found at 1/scale of the resolution
    # (scale 2 above _SIFT_FULL_RES_PX columns, SIFT's cost falls ~4x) locate it to
    # ~scale/2 px, well inside the pad
    scale = 2 if np.shape(left_rect)[1] > _SIFT_FULL_RES_PX else 1
    small = [_to_uint8(img) for img in (left_rect, right_rect)]
    if scale > 1:
        small = [cv2.resize(img, None, fx=1.0 / scale, fy=1.0 / scale,
                            interpolation=cv2.INTER_AREA) for img in small]
    kl, dl = sift.detectAndCompute(small[0], None)
    kr, dr = sift.detectAndCompute(small[1], None)
    disp = np.zeros(0)
    if dl is not None and dr is not None and len(kl) >= 2 and len(kr) >= 2:
        matcher = cv2.BFMatcher(cv2.NORM_L2)
        fwd = _ratio_matches(matcher.knnMatch(dl, dr, k=2))
        bwd = _ratio_matches(matcher.knnMatch(dr, dl, k=2))
        mutual = [(q, t) for q, t in fwd.items() if bwd.get(t) == q]
        if mutual:
            # INTER_AREA pixel centres: x_full = scale (x_small + 1/2) - 1/2
            pl = scale * (np.array([kl[q].pt for q, _ in mutual]) + 0.5) - 0.5
            pr = scale * (np.array([kr[t].pt for _, t in mutual]) + 0.5) - 0.5
            rows = np.abs(pl[:, 1] - pr[:, 1]) < 2.0
            disp = (pl[:, 0] - pr[:, 0])[rows]
    if len(disp) < min_matches:
        raise ValueError(f"no overlap between the two images: {len(disp)} row-consistent "
                         f"feature matches after rectification (need {min_matches})")
    lo, hi = np.percentile(disp, [2, 98])
    pad = 0.25 * (hi - lo) + 8.0
    width = np.shape(left_rect)[1]
    # SGBM needs x - d inside the image for some x: keep the range within the width
    dmin = int(max(np.floor(lo - pad), -(width - 32)))
    dmax = min(hi + pad, width - 32)
    count = int(np.ceil((dmax - dmin) / 16.0)) * 16
    return dmin, int(np.clip(count, 16, max(16, (width - 16) // 16 * 16)))


def _ratio_matches(pairs, ratio: float = 0.75) -> dict[int, int]:
    """query -> train index of Lowe's ratio-test survivors."""
    return {p[0].queryIdx: p[0].trainIdx for p in pairs
            if len(p) == 2 and p[0].distance < ratio * p[1].distance}


def sgbm_disparity(left_rect, right_rect, min_disparity: int, num_disparities: int,
                   block: int = 5, uniqueness: int = 10) -> np.ndarray:
    """Coarse disparity of a rectified pair by ``cv2.StereoSGBM`` (3-way mode).

    Parameters
    ----------
    left_rect, right_rect : (H, W) array_like
        Rectified grey images.
    min_disparity, num_disparities : int
        Search range (``num_disparities`` a multiple of 16), px.
    block : int
        Matching block side, px; P1 = 8 block², P2 = 32 block² (OpenCV's recommendation
        for one channel).
    uniqueness : int
        SGBM's uniqueness ratio, % (the best cost must beat the second by this margin).

    Returns
    -------
    (H, W) float32
        Disparity x_left - x_right, px; NaN where SGBM found none.
    """
    sgbm = cv2.StereoSGBM_create(minDisparity=int(min_disparity),
                                 numDisparities=int(num_disparities), blockSize=block,
                                 P1=8 * block * block, P2=32 * block * block,
                                 disp12MaxDiff=1, uniquenessRatio=int(uniqueness),
                                 speckleWindowSize=100,
                                 speckleRange=2, mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)
    raw = sgbm.compute(_to_uint8(left_rect), _to_uint8(right_rect)).astype(np.float32) / 16.0
    raw[raw < min_disparity] = np.nan
    return raw


def sample_disparity(disparity, points) -> np.ndarray:
    """Disparity at rectified positions (N, 2): nearest pixel, NaN outside or invalid."""
    points = check_shape(points, "(N, 2)", "points", dtype=np.float64)
    h, w = disparity.shape
    xi = np.rint(points[:, 0])
    yi = np.rint(points[:, 1])
    inside = np.isfinite(xi) & np.isfinite(yi) & (xi >= 0) & (yi >= 0) & (xi < w) & (yi < h)
    out = np.full(len(points), np.nan)
    out[inside] = disparity[yi[inside].astype(np.intp), xi[inside].astype(np.intp)]
    return out


@dataclass(frozen=True)
class Approximations:
    """Approximate right-image positions of left points.

    Attributes
    ----------
    x_right : (N, 2) float64
        Approximate position in the original right image, px (NaN: none).
    direction : (N, 2) float64
        Unit tangent of the epipolar curve in the right image at ``x_right``.
    x_left_rect : (N, 2) float64
        Left points in the rectified frame, px.
    disparity : (H, W) float32
        The coarse SGBM disparity map (rectified frame), NaN where none.
    range : (int, int)
        (min_disparity, num_disparities) used.
    """

    x_right: np.ndarray
    direction: np.ndarray
    x_left_rect: np.ndarray
    disparity: np.ndarray
    range: tuple[int, int]


def _patch_probes(points, patch: int) -> np.ndarray:
    """(N, 9, 2): the centre, corners and edge midpoints of each patch."""
    half = patch // 2
    offsets = np.array([(dx, dy) for dy in (-half, 0, half) for dx in (-half, 0, half)],
                       dtype=np.float64)
    return points[:, None, :] + offsets[None, :, :]


def _disparity_over_patch(disp, probes_rect) -> np.ndarray:
    """Disparity at the centre probe; NaN when any probe of the patch has none.

    LSM assumes one smooth surface under the patch: a patch reaching into a region
    SGBM left unmatched (background, an occlusion, a silhouette) breaks that.
    """
    n = probes_rect.shape[0]
    d = sample_disparity(disp, probes_rect.reshape(-1, 2)).reshape(n, 9)
    centre = d[:, 4].copy()
    centre[~np.isfinite(d).all(axis=1)] = np.nan
    return centre


def disparity_valid_left(approx: Approximations, shape: tuple[int, int], rig=None,
                         rect: Rectification | None = None) -> np.ndarray:
    """(H, W) bool: the left image's pixels where SGBM found a disparity.

    For a rectified pair the map itself; for a calibrated one each original left pixel
    is taken to the rectified frame (:func:`left_to_rectified`, the exact inverse of
    the rectification maps) and looked up there (nearest pixel).
    """
    valid = np.isfinite(approx.disparity)
    h, w = int(shape[0]), int(shape[1])
    if rig is None:  # SGBM ran on the left image itself
        if valid.shape != (h, w):
            raise ValueError(f"the disparity map is {valid.shape}, the left image {(h, w)}")
        return valid
    rect = rectify(rig) if rect is None else rect
    ys, xs = np.mgrid[0:h, 0:w]
    grid = np.column_stack([xs.ravel(), ys.ravel()]).astype(np.float64)
    r = left_to_rectified(rect, rig.left, grid).reshape(h, w, 2).astype(np.float32)
    return cv2.remap(valid.astype(np.uint8), r[..., 0], r[..., 1], cv2.INTER_NEAREST,
                     borderMode=cv2.BORDER_CONSTANT, borderValue=0) > 0


def approximate_rectified(left_rect, right_rect, points, block: int = 5,
                          patch: int = 15, reuse: Approximations | None = None,
                          search_range: tuple[int, int] | None = None) -> Approximations:
    """Approximations for left points of an already rectified pair (rows correspond).

    ``patch``: LSM patch side; a point gets no approximation when SGBM has no disparity
    at any of its patch's corners, edge midpoints or centre.  ``reuse``: an earlier
    result for the same pair, whose disparity map is sampled instead of running SGBM
    again.  ``search_range``: SGBM's (min_disparity, num_disparities) when the geometry
    gives it (:func:`matching.search_range.pair_disparity_range`); default: from SIFT
    matches (:func:`disparity_range`).
    """
    points = check_shape(points, "(N, 2)", "points", dtype=np.float64)
    if reuse is not None:
        disp, (dmin, count) = reuse.disparity, reuse.range
    else:
        dmin, count = (disparity_range(left_rect, right_rect) if search_range is None
                       else (int(search_range[0]), int(search_range[1])))
        disp = sgbm_disparity(left_rect, right_rect, dmin, count, block)
    d = _disparity_over_patch(disp, _patch_probes(points, patch))
    x_right = np.column_stack([points[:, 0] - d, points[:, 1]])
    direction = np.broadcast_to([1.0, 0.0], points.shape).copy()
    return Approximations(x_right=x_right, direction=direction, x_left_rect=points.copy(),
                          disparity=disp, range=(dmin, count))


def approximate_calibrated(rig, left, right, points, rect: Rectification | None = None,
                           block: int = 5, patch: int = 15,
                           reuse: Approximations | None = None) -> Approximations:
    """Approximations for left points of a calibrated pair through rectification + SGBM.

    Parameters
    ----------
    rig : StereoRig
    left, right : (H, W) array_like
        Original grey images.
    points : (N, 2) array_like
        Left-image pixels, px.
    rect : Rectification, optional
        Precomputed :func:`rectify` of ``rig``.
    block : int
        SGBM block side, px.
    patch : int
        LSM patch side, px: no approximation where SGBM has no disparity at any of the
        patch's corners, edge midpoints or centre.
    reuse : Approximations, optional
        An earlier result for the same pair and ``rect``: its disparity map is sampled
        instead of rectifying and running SGBM again.

    Returns
    -------
    Approximations
        ``x_right`` in the original right image (exact mapping through the rectification).
    """
    points = check_shape(points, "(N, 2)", "points", dtype=np.float64)
    rect = rectify(rig) if rect is None else rect
    if reuse is not None:
        disp, (dmin, count) = reuse.disparity, reuse.range
    else:
        left_r, right_r = rectify_images(rect, left, right)
        dmin, count = disparity_range(left_r, right_r)
        disp = sgbm_disparity(left_r, right_r, dmin, count, block)
    probes = left_to_rectified(rect, rig.left, _patch_probes(points, patch).reshape(-1, 2))
    probes = probes.reshape(len(points), 9, 2)
    xl_rect = probes[:, 4]
    d = _disparity_over_patch(disp, probes)
    xr_rect = np.column_stack([xl_rect[:, 0] - d, xl_rect[:, 1]])
    x_right = rectified_to_original(rect, rig.right, xr_rect)
    # local epipolar tangent: image of a 1 px step along the rectified row
    ahead = rectified_to_original(rect, rig.right, xr_rect + [1.0, 0.0])
    direction = ahead - x_right
    norm = np.linalg.norm(direction, axis=1, keepdims=True)
    direction = np.where(norm > TOL.zero, direction / np.where(norm > 0, norm, 1.0), np.nan)
    return Approximations(x_right=x_right, direction=direction, x_left_rect=xl_rect,
                          disparity=disp, range=(dmin, count))
