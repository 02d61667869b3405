r"""All-round multi-view acquisition: view pairs, multi-image consistency, one merged cloud.

A ring of calibrated views is turned into one cloud in four steps.

1. **View pairs.**  For views :math:`i, j` with centres :math:`C_i, C_j` and the
   scene centre :math:`S` (least-squares intersection of the optical axes), the
   baseline-to-depth ratio :math:`b/d = \lVert C_i - C_j\rVert / \tfrac12(\lVert
   C_i - S\rVert + \lVert C_j - S\rVert)` and the angle between the optical axes
   decide: a pair is usable when ``min_ratio <= b/d <= max_ratio`` and the angle is
   at most ``max_angle_deg``; each view keeps its ``partners`` usable partners whose
   ratio is closest to ``target_ratio`` (1:4, the stereo recipe's base/distance).
2. **Pair reconstruction.**  Each pair is rectified with the baseline as the rectified
   x axis (:mod:`matching.rectify`, Fusiello, Trucco and Verri 2000: rows are epipolar
   lines whatever the views' relative roll, baseline direction or image sizes),
   *without* the zero-disparity constraint, so that a convergent pair keeps the object
   in both rectified frames, and matched by
   :func:`matching.pair.match_pair` (SGBM approximations, horizontal epipolar LSM),
   then re-matched with second-order warp terms estimated from the neighbours' affine
   parameters (:func:`matching.second_order.second_order_terms`: an affine fit of a curved
   mapping is biased).  A template window reaching into an untextured region
   (background beyond a rim or a silhouette) is moved onto the surface and the point
   transferred through the estimated warp (*eccentric windows*,
   :func:`matching.seeds.window_offsets`), so the points reach a rim to about a
   pixel instead of stopping half a window short; a window that cannot be moved
   clear straddles a silhouette and is dropped (``silhouette`` in the pair's
   counts).  The accepted matches are triangulated in the rectified cameras
   (:func:`matching.triangulate.triangulate_pair`).
3. **Multi-image consistency** (in the spirit of MPGC, Gruen & Baltsavias 1988 [1]_).
   Every pair point :math:`X` is projected into the further views :math:`k`.  It is
   *visible* in :math:`k` when it lies in front of the camera, inside the image by the
   LSM half-patch plus 3 px, the surface normal (PCA of the 12 nearest pair points)
   faces :math:`k` within ``max_incidence_deg``, and it passes a **depth test against
   every pair's points**: all points are splatted into a z-buffer of view :math:`k`,
   minimum-filtered over a window of ``2 spacing + 1`` px (the splat spacing), and
   :math:`X` is occluded if its depth exceeds the buffer by more than
   :math:`w\,(z/f)\tan\theta_{max} + 3\sigma_X` (the depth change of a surface at the
   largest accepted incidence across the window, plus the point's own 3 σ).  The
   template of view :math:`i` is then LSM-matched into the ``check_views`` visible
   views nearest to :math:`i` (all points of a view in one batch; at most
   ``2 check_views + 2`` further views are considered per pair; views closer than half
   the pair's baseline to either pair view add little parallax and are tried last):
   the approximation
   is the reprojection :math:`\pi_k(X)` (an eccentric window's centre: moved by the
   local-plane mapping), the initial affine the local-plane mapping
   :math:`i \to k` (rays of the template's unit pixel steps cut the tangent plane and
   are projected into :math:`k`), and the fixed second-order warp terms are fitted to
   the neighbouring points' local-plane mappings (one LSM pass; a first affine-only
   pass would be biased by the curvature, ``second_order``).  A match is *consistent*
   when the Mahalanobis distance of the matched position from :math:`\pi_k(X)`, with covariance
   :math:`J_k \Sigma_X J_k^T + \Sigma_{LSM}`, passes the :math:`\chi^2_2` test at
   ``reject_p``.  Points with at least one consistent further view are triangulated
   from all their consistent views (:func:`matching.triangulate.triangulate_multiview`)
   and get its smaller σ.
4. **Merge.**  The pairs' clouds are concatenated; points of *different* pairs closer
   than half the point spacing (median nearest-neighbour distance within a pair; a
   ``scipy.spatial.cKDTree`` radius search) are one surface sample and are fused by
   σ-weighted averaging (weights :math:`1/\sigma^2`, :math:`\sigma = (\sum
   \sigma_i^{-2})^{-1/2}`, views OR-ed, colours averaged); finally a statistical outlier
   removal (a local form of Rusu et al. 2008 [2]_) drops points whose mean distance to
   their ``sor_neighbours`` nearest neighbours exceeds ``sor_std`` times the median of
   their neighbours' mean distances, and points farther from their neighbours' PCA
   plane than ``2 sor_std`` robust standard deviations of that distance (silhouette
   mismatches lie off the surface without being isolated).

**Execution and memory.**  View pairs, and then the consistency checks, are
independent tasks: in this process they run on one thread per core (the numba LSM
kernels release the GIL and run single-threaded in each), or on any ``map_func`` (a
Dask executor's).  No task keeps an image: a pair task reads its two images (from a
lazily loading sequence, see :func:`reconstruct_multiview`), a check re-rectifies its
template image, and the further views' prepared grey images and z-buffers exist only
for the chunk of ``chunk_pairs`` pairs that checks in them.  The results do not depend
on the number of threads or on where tasks run.

Per-point reasons (:data:`REASON_NAMES`), for every triangulated pair point:

====  ======================  ===================================================
0     ``multiview``           confirmed in >= 1 further view, multi-view triangulated
1     ``pair_only``           no further view sees it (kept with the pair's σ only
                              with ``keep_unchecked``)
2     ``no_further_match``    visible in further views, every LSM there failed
3     ``inconsistent``        LSM matched in a further view, but off the reprojection
4     ``triangulation``       rejected by the multi-view triangulation
5     ``outlier``             removed by the statistical outlier filter (merge)
6     ``outside``             off a view's object mask where it projects into that
                              image (visual hull), or outside the region of interest
====  ======================  ===================================================

Codes 2-6 are rejected (2 only when ``require_confirmation``), 1 unless
``keep_unchecked``.

Views that saw a point are stored as a dense ``(N, V)`` bool matrix (``views``; V
the number of cameras, column order of ``cameras``); the pair a point came from is
``pair (N,)`` (index into ``pairs``), ``-1`` for points fused from several pairs.

References
----------
.. [1] A. Gruen, E. Baltsavias, "Geometrically constrained multiphoto matching",
   Photogrammetric Engineering and Remote Sensing 54(5), 633-641 (1988).
.. [2] R. B. Rusu, Z. C. Marton, N. Blodow, M. Dolha, M. Beetz, "Towards 3D point
   cloud based object maps for household environments", Robotics and Autonomous
   Systems 56(11), 927-941 (2008).
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import cv2
import numba
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree
from scipy.stats import chi2

from matching.cameras import Camera, StereoRig
from matching.lsm import DEFAULT_INTERPOLATION, PreparedImage, lsm_match, prepare_image
from matching.masks import inside_masks
from matching.pair import match_pair
from matching.rectify import Rectification, rectify, rectify_images
from matching.search_range import SceneVolume, pair_disparity_range, scene_volume
from matching.second_order import second_order_terms
from matching.seeds import DEFAULT_SPACING, disparity_range
from matching.triangulate import triangulate_multiview, triangulate_pair
from matching.validate import TOL, check_shape

__all__ = [
    "REASON_NAMES",
    "PairCloud",
    "MultiViewCloud",
    "SkippedPair",
    "scene_centre",
    "select_pairs",
    "rectify_pair",
    "reconstruct_view_pair",
    "check_consistency",
    "merge_clouds",
    "reconstruct_multiview",
]

MULTIVIEW, PAIR_ONLY, NO_FURTHER_MATCH, INCONSISTENT, TRIANGULATION, OUTLIER, OUTSIDE = \
    range(7)
#: Reason code -> name (module docstring).
REASON_NAMES = {MULTIVIEW: "multiview", PAIR_ONLY: "pair_only",
                NO_FURTHER_MATCH: "no_further_match", INCONSISTENT: "inconsistent",
                TRIANGULATION: "triangulation", OUTLIER: "outlier", OUTSIDE: "outside"}
#: Where SGBM's disparity range comes from (:func:`reconstruct_multiview`).
SEARCH_MODES = ("geometry", "features")
#: Where a further view's second-order warp terms come from (:func:`check_consistency`).
SECOND_ORDER_MODES = ("geometric", "matched")
#: Nearest pair points for the PCA normal (12: a 3x3 grid ring plus slack).
_NORMAL_NEIGHBOURS = 12
#: Image margin beyond the LSM half-patch for a further view, px (interpolation support).
_BORDER_PX = 3
#: Rows per block of the outlier filter's neighbourhood arrays (bounded working memory).
_SOR_BLOCK = 65536


# --------------------------------------------------------------------------- data
@dataclass(frozen=True, eq=False)
class PairCloud:
    """Triangulated points of one view pair (arrays over its M points).

    Attributes
    ----------
    pair : (int, int)
        View indices (left, right) into the camera list.
    points : (M, 3) float64, scene units
    cov : (M, 3, 3) float64, scene units²
    sigma : (M,) float64, scene units (worst direction)
    x_template : (M, 2) float64, px
        The matched points in the rectified left image (integer pixels).
    x_right : (M, 2) float64, px
        Matches in the rectified right image.
    cov_2d : (M, 2, 2) float64, px²
        Observation covariance used for both rectified observations.
    cameras : (Camera, Camera)
        The rectified left and right cameras (pinhole, no distortion).
    status_counts : dict
        Candidates per :data:`matching.pair.PAIR_STATUS_NAMES` name.
    seconds : float
        Wall time of the pair.
    offset : (M, 2) float64, px, or None
        LSM window centre minus ``x_template`` (eccentric windows moved off textureless
        cells, :func:`matching.seeds.window_offsets`); None: all windows centred.

    Notes
    -----
    No image is kept (memory stays bounded by the points, not by the views): the
    consistency step re-rectifies the left image (:func:`rectified_template`).
    """

    pair: tuple[int, int]
    points: np.ndarray
    cov: np.ndarray
    sigma: np.ndarray
    x_template: np.ndarray
    x_right: np.ndarray
    cov_2d: np.ndarray
    cameras: tuple[Camera, Camera]
    status_counts: dict = field(default_factory=dict)
    seconds: float = 0.0
    offset: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.points)


@dataclass(frozen=True, eq=False)
class MultiViewCloud:
    """The merged all-round cloud.

    Attributes
    ----------
    points : (N, 3) float64, scene units
    colours : (N, 3) uint8, RGB
    sigma : (N,) float64, scene units
    views : (N, V) bool
        Which cameras saw (matched) each point.
    pair : (N,) int64
        Index into ``pairs`` of the pair the point came from; -1 when fused from several.
    pairs : list of (int, int)
    reason_counts : dict
        Pair points per :data:`REASON_NAMES` name (before merging; ``outlier`` after).
    stats : dict
        Counts and timings (``pair_seconds``, ``consistency_seconds``, ``merge_seconds``,
        ``fused``, ``median_sigma_pair``, ``median_sigma_multiview`` ...).
    """

    points: np.ndarray
    colours: np.ndarray
    sigma: np.ndarray
    views: np.ndarray
    pair: np.ndarray
    pairs: list
    reason_counts: dict
    stats: dict

    def __len__(self) -> int:
        return len(self.points)

    @property
    def colors(self) -> np.ndarray:
        """Alias of ``colours`` (open3d's spelling, what ``pipeline.stages`` reads)."""
        return self.colours


# --------------------------------------------------------------------------- pairs
def scene_centre(cameras: Sequence[Camera]) -> np.ndarray:
    """(3,) least-squares intersection of the optical axes.

    Minimises :math:`\\sum_v \\lVert (I - a_v a_v^T)(S - C_v)\\rVert^2` over S, with
    :math:`a_v` the unit optical axis (third row of R) and :math:`C_v` the centre.

    Raises
    ------
    ValueError
        Fewer than 2 cameras, or (nearly) parallel axes (no convergence point).
    """
    if len(cameras) < 2:
        raise ValueError(f"cameras: need at least 2, got {len(cameras)}")
    axes = np.stack([cam.R[2] for cam in cameras])  # (V, 3)
    centres = np.stack([cam.center for cam in cameras])
    proj = np.eye(3) - axes[:, :, None] * axes[:, None, :]  # (V, 3, 3)
    A = proj.sum(axis=0)
    b = np.einsum("vij,vj->i", proj, centres)
    w = np.linalg.eigvalsh(A)
    if w[0] < TOL.axes_min_eig * len(cameras):
        raise ValueError("cameras: optical axes are (nearly) parallel; no scene centre "
                         "(give pairs explicitly)")
    return np.linalg.solve(A, b)


def select_pairs(cameras: Sequence[Camera], *, min_ratio: float = 0.1,
                 max_ratio: float = 0.6, target_ratio: float = 0.25,
                 max_angle_deg: float = 40.0, partners: int = 2) -> list[tuple[int, int]]:
    """View pairs by baseline-to-depth ratio and viewing angle (module docstring, step 1).

    Parameters
    ----------
    cameras : sequence of V Camera
    min_ratio, max_ratio : float
        Usable baseline/depth range (below: depth too poorly determined; above: the
        views differ too much for area matching).
    target_ratio : float
        Preferred ratio.
    max_angle_deg : float
        Largest angle between the optical axes, degrees.
    partners : int
        Partners kept per view (2: both ring neighbours).

    Returns
    -------
    list of (left, right)
        Each unordered pair once, sorted; oriented so that the lower-numbered view
        sees the other on its +x side where it does (any order rectifies:
        :mod:`matching.rectify` takes the baseline as the x axis).
    """
    if not 0 < min_ratio <= target_ratio <= max_ratio:
        raise ValueError(f"need 0 < min_ratio <= target_ratio <= max_ratio, got {min_ratio}, "
                         f"{target_ratio}, {max_ratio}")
    if partners < 1:
        raise ValueError(f"partners must be >= 1, got {partners}")
    centre = scene_centre(cameras)
    centres = np.stack([cam.center for cam in cameras])
    axes = np.stack([cam.R[2] for cam in cameras])
    depth = np.linalg.norm(centres - centre, axis=1)
    base = np.linalg.norm(centres[:, None] - centres[None], axis=2)  # (V, V)
    ratio = base / (0.5 * (depth[:, None] + depth[None]))
    angle = np.degrees(np.arccos(np.clip(axes @ axes.T, -1.0, 1.0)))
    usable = (ratio >= min_ratio) & (ratio <= max_ratio) & (angle <= max_angle_deg)
    np.fill_diagonal(usable, False)
    chosen = set()
    for i in range(len(cameras)):
        cand = np.flatnonzero(usable[i])
        best = cand[np.argsort(np.abs(ratio[i, cand] - target_ratio), kind="stable")]
        chosen.update((min(i, int(j)), max(i, int(j))) for j in best[:partners])
    pairs = []
    for a, b in chosen:  # each pair once, oriented by its lower-numbered view
        x_in_a = cameras[a].to_camera(centres[b][None])[0, 0]
        pairs.append((a, b) if x_in_a > 0 else (b, a))
    return sorted(pairs)


def rectify_pair(left: Camera, right: Camera) -> tuple[Rectification, Camera, Camera]:
    """Rectify a pair whatever its relative pose (:func:`matching.rectify.rectify`).

    The baseline is the rectified x axis (Fusiello, Trucco and Verri 2000), each view
    keeps its own principal-point column (no zero-disparity constraint) and every
    column it reaches, so a convergent pair keeps its overlap in view; vertical
    baselines, views turned against each other and different image sizes are all
    rectified to rows.

    Returns
    -------
    rect : matching.rectify.Rectification
    left_rect, right_rect : Camera
        The rectified pinhole cameras in the world frame (``P1``/``P2`` composed with
        the left camera's pose), no distortion, of the rectified size.
    """
    rect = rectify(StereoRig(left, right))
    pose = np.eye(4)
    pose[:3, :3] = rect.R1 @ left.R
    pose[:3, 3] = rect.R1 @ left.t
    w, h = rect.size
    cam_l = Camera.from_projection(rect.P1 @ pose, w, h, name=left.name)
    cam_r = Camera.from_projection(rect.P2 @ pose, w, h, name=right.name)
    return rect, cam_l, cam_r


def _grey(image) -> np.ndarray:
    img = np.asarray(image)
    if img.ndim == 3:
        img = img[..., :3].astype(np.float64) @ np.array([0.114, 0.587, 0.299])  # BGR
    return np.asarray(img, dtype=np.float64)


def reconstruct_view_pair(left_image, right_image, left: Camera, right: Camera,
                          pair: tuple[int, int] = (0, 1), *, volume: SceneVolume | None = None,
                          mask=None, **match_options) -> PairCloud:
    """Rectify, match (:func:`matching.pair.match_pair`) and triangulate one view pair.

    Parameters
    ----------
    left_image, right_image : (H, W) or (H, W, 3) array_like
        Original images (colour in BGR order), of the cameras' sizes.
    left, right : Camera
    pair : (int, int)
        Their indices (stored in the result).
    volume : matching.search_range.SceneVolume, optional
        Where the object can be (frusta, visual hull, sparse points): SGBM's disparity
        range comes from it (:func:`matching.search_range.pair_disparity_range`), not
        from SIFT matches.
    mask : (H, W) bool, optional
        The left view's object mask: candidates only where true.
    **match_options
        Passed to :func:`matching.pair.match_pair` (``spacing``, ``patch``,
        ``interpolation``, ``min_correlation`` ...); ``adaptive_patch`` defaults to
        False here (not match_pair's True) and ``eccentric`` to True (not match_pair's
        False), ``max_sigma_mad_k`` keeps match_pair's 4.

    Returns
    -------
    PairCloud
    """
    start = time.perf_counter()
    for name, img, cam in (("left_image", left_image, left), ("right_image", right_image, right)):
        shape = np.shape(img)
        if len(shape) < 2 or (shape[1], shape[0]) != cam.size:
            got = f"{shape[1]}x{shape[0]}" if len(shape) >= 2 else str(shape)
            raise ValueError(f"{name} ({cam.name}) is {got} px but its camera is "
                             f"{cam.size[0]}x{cam.size[1]} px")
    rect, cam_l, cam_r = rectify_pair(left, right)
    grey_l, grey_r = rectify_images(rect, _grey(left_image), _grey(right_image))
    source = np.ones(left.size[::-1], np.float32) if mask is None else \
        np.asarray(mask, dtype=np.float32)
    valid = cv2.remap(source, *rect.maps_left, cv2.INTER_NEAREST,
                      borderMode=cv2.BORDER_CONSTANT, borderValue=0) > 0
    search = _search_range(volume, cam_l, cam_r, grey_l, grey_r)
    options = {k: v for k, v in match_options.items() if k != "epipolar"}
    # fixed patches here (match_pair's adaptive default grows imprecise patches): the
    # further-view check re-matches every point at the fixed patch, so a larger pair
    # patch is paid and then overridden (small test ring: adaptive 14 064 points,
    # RMS 0.00105 vs fixed 14 348, 0.00111); the 'imprecise' σ test stays
    options.setdefault("adaptive_patch", False)
    # eccentric windows near untextured regions (match_pair's default is off): a point
    # near a rim is matched with its window moved onto the surface instead of being
    # dropped as a silhouette straddler -- 24-view ring: the cloud reaches the rims to
    # within ~1 px (was ~4 px short) and the surface Chamfer falls from 0.156 % to
    # 0.042 % of the height; transfer errors at occluding contours are caught by the
    # further-view check (cloud RMS 0.000229 -> 0.000228)
    options.setdefault("eccentric", True)
    # both rectified images are prepared (spline prefilter, noise) once for all LSM passes
    interpolation = options.get("interpolation", DEFAULT_INTERPOLATION)
    prep_l, prep_r = prepare_image(grey_l, interpolation), prepare_image(grey_r, interpolation)
    matches = match_pair(prep_l, prep_r, rectified=True, mask=valid, search_range=search,
                         **options)
    # a window match_pair could not move off every textureless cell straddles a
    # silhouette (object against a uniform background, or an occluding contour): its
    # match follows the contour, which slides from view to view and survives the
    # multi-view check while lying beyond the object
    near_edge = matches.edge
    # match_pair's second pass already carries the second-order terms of its first pass's
    # affine field; a third pass (terms re-estimated from the second) moved the matches by
    # a median 0.002 px, 0.15 of their sigma, on the 1024x768 ring: not worth its cost
    ok = np.flatnonzero(matches.accepted & ~near_edge)
    x_right, cov_lsm = matches.x_right[ok], matches.cov[ok]
    cov2 = 0.5 * cov_lsm + TOL.match_cov_floor_px**2 * np.eye(2)
    tri = triangulate_pair(cam_l, cam_r, matches.x_left[ok], x_right,
                           cov_left=cov2, cov_right=cov2, refine=True)
    keep = tri.valid
    offset = matches.offset[ok][keep]
    return PairCloud(pair=(int(pair[0]), int(pair[1])), points=tri.points[keep],
                     cov=tri.cov[keep], sigma=tri.sigma[keep],
                     x_template=matches.x_left[ok][keep], x_right=x_right[keep],
                     cov_2d=cov2[keep], cameras=(cam_l, cam_r),
                     status_counts={**matches.status_counts(),
                                    "silhouette": int(np.count_nonzero(matches.accepted
                                                                       & near_edge)),
                                    "eccentric": int(np.count_nonzero(
                                        np.any(offset != 0, axis=1)))},
                     seconds=time.perf_counter() - start, offset=offset)


def _search_range(volume: SceneVolume | None, cam_l: Camera, cam_r: Camera, grey_l,
                  grey_r) -> tuple[int, int] | None:
    """SGBM's range of a rectified pair: from the geometry, SIFT matches only as an aid.

    The volume's range (:func:`matching.search_range.pair_disparity_range`) is used as
    it is when it spans at most half the rectified width (a ring's frusta, a visual
    hull); a wider one (two views bound little: their frusta meet in a long wedge) is
    narrowed to the SIFT matches' range (:func:`matching.seeds.disparity_range`) where
    those are found and agree with it, and kept otherwise.  None (no volume): SIFT only.
    """
    if volume is None:
        return None
    geometric = pair_disparity_range(volume, cam_l, cam_r)
    if geometric is None:
        raise ValueError("the object's volume falls in neither rectified image: "
                         "the views do not overlap")
    width = cam_l.size[0]
    if geometric[1] <= width // 2:
        return geometric
    try:
        lo, count = disparity_range(grey_l, grey_r)
    except ValueError:
        return geometric
    g_lo, g_hi = geometric[0], geometric[0] + geometric[1]
    lo, hi = max(lo, g_lo), min(lo + count, g_hi)
    if hi - lo < 16:
        return geometric
    return int(lo), int(np.ceil((hi - lo) / 16.0)) * 16


def rectified_template(left_image, left: Camera, right: Camera,
                       interpolation: str = DEFAULT_INTERPOLATION) -> PreparedImage:
    """The rectified left grey image of a pair, prepared for LSM (consistency templates).

    The same rectification and resampling as :func:`reconstruct_view_pair` (so the same
    pixels); recomputed where needed (~30 ms at 1024x768) instead of kept per pair.
    """
    rect, _, _ = rectify_pair(left, right)
    grey = cv2.remap(np.asarray(_grey(left_image), dtype=np.float32), *rect.maps_left,
                     cv2.INTER_CUBIC, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return prepare_image(grey, interpolation)


def _second_order_pass(template, search, points, affine, radiometric, accepted, approx,
                       direction, options: dict, offset=None):
    """Re-match accepted points with second-order warp terms from their neighbours.

    An affine patch fit of a curved mapping is biased by ~``<x²>(u_xx + u_yy)``
    (``matching.second_order.second_order_terms``); on the 320x240 test ring this is 0.08 px of
    disparity for a 15 px patch and falls to 0.003 px after this pass.  Returns
    ``(kept (K,) bool, position (K, 2), cov (K, 2, 2))`` over the K accepted points,
    or None when the terms are not available.  ``points`` are the window centres;
    ``offset`` (N, 2), as ``lsm_match``'s, names the pixel reported.
    """
    if not np.any(accepted):
        return None
    idx = np.flatnonzero(accepted)
    radius = 1.5 * int(options.get("patch", 15))  # neighbours within ~a patch and a half
    quad = second_order_terms(points, affine, valid=accepted, radius_px=radius)
    init = np.column_stack([affine, radiometric])[idx]
    lsm = {k: options[k] for k in _LSM_KEYS if k in options}
    res = lsm_match(template, search, points[idx], approx, patch=int(options.get("patch", 15)),
                    interpolation=options.get("interpolation", DEFAULT_INTERPOLATION),
                    direction=direction, initial=init, quadratic=quad[idx],
                    offset=None if offset is None else offset[idx], **lsm)
    return res.accepted, res.position, res.cov


# --------------------------------------------------------------------------- consistency
def _project(camera: Camera, X: np.ndarray, with_jacobian: bool = False):
    """:meth:`Camera.project` for a camera without distortion, in one numba pass.

    ``x = (P [X 1])_{1,2} / (P [X 1])_3`` with ``P = K [R | t]``; the Jacobian is
    ``(K_{1,2} - x K_3) R / (K X_c)_3``.  Agrees with ``cv2.projectPoints`` to rounding
    (~1e-12 px); the consistency step projects every pair point ~50 times per pair
    (cv2: ~3x the cost, numpy's two skinny matmuls ~7 CPU s of a spacing-3 ring).
    Cameras with distortion go through :meth:`Camera.project`.

    Parameters
    ----------
    camera : Camera
    X : (N, 3) float64, scene units
    with_jacobian : bool

    Returns
    -------
    x : (N, 2) float64, px
    J : (N, 2, 3) float64, px per scene unit (only if ``with_jacobian``)
    """
    if camera.has_distortion:
        return camera.project(X, with_jacobian=with_jacobian)
    X = np.ascontiguousarray(X, dtype=np.float64)
    h = np.empty((len(X), 3))
    _homogeneous(X, np.ascontiguousarray(camera.P), h)  # (N, 3) homogeneous pixels
    x = h[:, :2] / h[:, 2:3]
    if not with_jacobian:
        return x
    K = camera.K
    jac = (K[None, :2, :] - x[:, :, None] * K[None, 2:3, :]) / h[:, 2, None, None]  # (N, 2, 3)
    return x, jac @ camera.R


@numba.njit(cache=True, nogil=True, fastmath=False, error_model="numpy")
def _homogeneous(X, P, out):
    """out = [X 1] Pᵀ for (N, 3) X and a 3x4 projection P."""
    for i in range(X.shape[0]):
        x, y, z = X[i, 0], X[i, 1], X[i, 2]
        for r in range(3):
            out[i, r] = P[r, 0] * x + P[r, 1] * y + P[r, 2] * z + P[r, 3]


@numba.njit(cache=True, nogil=True, fastmath=False, error_model="numpy")
def _splat_nearest(X, P, w, h, buf):
    """buf[y w + x] = min(depth) of the points projecting to pixel (x, y) in front."""
    for i in range(X.shape[0]):
        x, y, z = X[i, 0], X[i, 1], X[i, 2]
        hz = P[2, 0] * x + P[2, 1] * y + P[2, 2] * z + P[2, 3]
        if not hz > 0.0:
            continue
        u = np.rint((P[0, 0] * x + P[0, 1] * y + P[0, 2] * z + P[0, 3]) / hz)
        v = np.rint((P[1, 0] * x + P[1, 1] * y + P[1, 2] * z + P[1, 3]) / hz)
        if u >= 0 and u < w and v >= 0 and v < h:
            k = int(v) * w + int(u)
            if hz < buf[k]:
                buf[k] = hz


def _normals(points: np.ndarray, towards: np.ndarray) -> np.ndarray:
    """(M, 3) unit PCA normals of the nearest pair points, oriented towards ``towards``."""
    k = min(_NORMAL_NEIGHBOURS, len(points))
    if k < 3:
        return np.full_like(points, np.nan)
    _, idx = cKDTree(points).query(points, k=k)
    nb = points[idx] - points[idx].mean(axis=1, keepdims=True)  # (M, k, 3)
    _, vec = np.linalg.eigh(np.einsum("mki,mkj->mij", nb, nb))
    n = vec[:, :, 0]
    flip = np.einsum("mi,mi->m", n, towards - points) < 0
    n[flip] *= -1
    return n


def zbuffer(camera: Camera, points: np.ndarray, window: int) -> np.ndarray:
    """(H, W) nearest depth of ``points`` splatted into ``camera``, min-filtered.

    Parameters
    ----------
    camera : Camera
    points : (N, 3) float64
    window : int
        Side of the minimum filter, px (the splat spacing, so that the samples'
        gaps are closed).

    Returns
    -------
    (H, W) float64, scene units; +inf where no point falls.
    """
    w, h = camera.size
    buf = np.full(h * w, np.inf)
    if camera.has_distortion:
        depth = camera.depth(points)
        front = depth > 0
        x = np.rint(_project(camera, points[front])).astype(np.int64)
        inside = (x[:, 0] >= 0) & (x[:, 0] < w) & (x[:, 1] >= 0) & (x[:, 1] < h)
        np.minimum.at(buf, x[inside, 1] * w + x[inside, 0], depth[front][inside])
    else:  # one pass: project, keep the nearest depth per pixel (K's last row is 0 0 1)
        _splat_nearest(np.ascontiguousarray(points, dtype=np.float64),
                       np.ascontiguousarray(camera.P), int(w), int(h), buf)
    # a square minimum filter is a grey erosion (OpenCV's is ~4x faster than ndimage's;
    # BORDER_REPLICATE is ndimage's mode="nearest", the result is identical)
    return cv2.erode(buf.reshape(h, w), np.ones((int(window), int(window)), np.uint8),
                     borderType=cv2.BORDER_REPLICATE)


def _plane_affine(cam_t: Camera, cam_k: Camera, x_t: np.ndarray, X: np.ndarray,
                  normal: np.ndarray) -> np.ndarray:
    """(M, 2, 2) Jacobian of the template-pixel -> view-k mapping through the tangent plane."""
    out = np.empty((len(X), 2, 2))
    base = _project(cam_k, X)
    for col, step in enumerate(([1.0, 0.0], [0.0, 1.0])):
        origin, d = cam_t.ray(x_t + step)
        denom = np.einsum("mi,mi->m", d, normal)
        s = np.einsum("mi,mi->m", X - origin, normal) / np.where(np.abs(denom) > TOL.zero,
                                                                 denom, np.nan)
        out[:, :, col] = _project(cam_k, origin + s[:, None] * d) - base
    return out


@dataclass(frozen=True, eq=False)
class Consistency:
    """Outcome of the consistency check of one pair (arrays over its M points).

    Attributes
    ----------
    points, cov, sigma : (M, 3), (M, 3, 3), (M,) float64
        Multi-view result where ``reason == MULTIVIEW``, the pair's otherwise.
    reason : (M,) int8, codes of :data:`REASON_NAMES`.
    views : (M, V) bool
    checked : (M,) int64, further views LSM was tried in.
    seconds : float
    variance_factor : float
        The a-posteriori variance factor applied to the pair's match covariances
        (:func:`variance_factor`; 1: they were right).
    """

    points: np.ndarray
    cov: np.ndarray
    sigma: np.ndarray
    reason: np.ndarray
    views: np.ndarray
    checked: np.ndarray
    seconds: float = 0.0
    variance_factor: float = 1.0


def _visible(cloud: PairCloud, cam_k: Camera, zbuf: np.ndarray, normals: np.ndarray,
             patch: int, window: int, max_incidence_deg: float) -> tuple[np.ndarray, ...]:
    """Visibility of the pair's points in view k: (mask, projections, incidence cosine)."""
    X = cloud.points
    depth = cam_k.depth(X)
    x = _project(cam_k, X)
    w, h = cam_k.size
    border = patch // 2 + _BORDER_PX
    inside = ((depth > 0) & (x[:, 0] >= border) & (x[:, 0] <= w - 1 - border)
              & (x[:, 1] >= border) & (x[:, 1] <= h - 1 - border))
    to_cam = cam_k.center - X
    cos_inc = np.einsum("mi,mi->m", normals, to_cam) / np.linalg.norm(to_cam, axis=1)
    ok = inside & (cos_inc >= np.cos(np.radians(max_incidence_deg)))
    xi = np.rint(np.where(ok[:, None], x, 0)).astype(np.int64)
    front = zbuf[xi[:, 1], xi[:, 0]]
    slope = np.tan(np.radians(max_incidence_deg))
    margin = window * depth / cam_k.K[0, 0] * slope + 3.0 * cloud.sigma
    ok &= depth <= front + margin
    return ok, x, cos_inc


def check_consistency(cloud: PairCloud, cameras: Sequence[Camera], images: dict,
                      zbuffers: dict, template: PreparedImage, *, check_views: int = 2,
                      patch: int = 15,
                      spacing: int = DEFAULT_SPACING,
                      interpolation: str = DEFAULT_INTERPOLATION,
                      max_incidence_deg: float = 60.0, reject_p: float = 0.999,
                      require_confirmation: bool = True, second_order: str = "geometric",
                      **lsm_options) -> Consistency:
    """Confirm a pair's points in further views by LSM and re-triangulate them (step 3).

    Parameters
    ----------
    cloud : PairCloud
    cameras : sequence of V Camera
        All cameras (original, with distortion).
    images : dict int -> matching.lsm.PreparedImage
        Grey images of (at least) the views that may be checked, prepared for
        ``interpolation`` (:func:`matching.lsm.prepare_image`, once per view).
    zbuffers : dict int -> (H, W) float
        :func:`zbuffer` of every pair's points for those views.
    template : matching.lsm.PreparedImage
        The pair's rectified left image (:func:`rectified_template`).
    check_views : int
        Further views tried per point (visible ones nearest to the template view).
    patch, spacing, interpolation : as :func:`matching.pair.match_pair`.
    max_incidence_deg : float
        Largest angle between the surface normal and the direction to view k.
    reject_p : float
        Probability of the χ² tests (consistency and triangulation).
    require_confirmation : bool
        Reject points visible in further views that no LSM confirmed.
    second_order : {"geometric", "matched"}
        Where the second-order warp terms of a further view come from: ``"geometric"``
        (default) fits them (:func:`matching.second_order.second_order_terms`) to the
        local-plane mappings i -> k of the neighbouring pair points, known before any
        matching, so one LSM pass suffices; ``"matched"`` fits them to the affine
        parameters of a first, affine-only LSM pass and matches again.  Measured on the
        24-view 1024x768 ring at spacing 3 (eccentric windows on): geometric 315 524
        points, RMS 0.000228, acquisition 45.6 s / 85.7 CPU s; matched 311 988 points,
        RMS 0.000226, 53.2 s / 100.8 CPU s (the consistency step 19.3 s against 28.7 s);
        with no second-order terms at all the RMS doubles (0.000446).
    **lsm_options
        Passed to :func:`matching.lsm.lsm_match` (``min_correlation`` ...).

    Returns
    -------
    Consistency
    """
    if second_order not in SECOND_ORDER_MODES:
        raise ValueError(f"second_order must be one of {SECOND_ORDER_MODES}, "
                         f"got {second_order!r}")
    start = time.perf_counter()
    i, j = cloud.pair
    n_views = len(cameras)
    m = len(cloud)
    cam_t = cloud.cameras[0]
    views = np.zeros((m, n_views), bool)
    views[:, [i, j]] = True
    reason = np.full(m, PAIR_ONLY, np.int8)
    if m == 0:
        return Consistency(cloud.points, cloud.cov, cloud.sigma, reason, views,
                           np.zeros(0, np.int64), time.perf_counter() - start)
    normals = _normals(cloud.points, cameras[i].center)
    window = 2 * spacing + 1
    # views facing away from the template view (axes > 2 max_incidence apart) cannot see
    # a point that view i sees within max_incidence
    axis_i = cameras[i].R[2]
    facing = np.cos(np.radians(min(2.0 * max_incidence_deg, 180.0)))
    others = _check_order(cameras, (i, j), [
        k for k in range(n_views) if k not in (i, j) and k in images
        and float(cameras[k].R[2] @ axis_i) >= facing])
    # observations only in the views that can take part (the pair and its further views,
    # in camera order): (M, len(cols), ...) instead of (M, V, ...) keeps a task's memory
    # independent of the number of views
    cols = sorted({i, j, *others})
    col = {v: c for c, v in enumerate(cols)}
    obs = np.full((m, len(cols), 2), np.nan)
    cov = np.full((m, len(cols), 2, 2), np.nan)
    obs[:, col[i]] = cloud.x_template  # the rectified cameras stand in for views i and j
    obs[:, col[j]] = cloud.x_right
    cov[:, col[i]] = cloud.cov_2d
    cov[:, col[j]] = cloud.cov_2d
    tried = np.zeros(m, np.int64)
    matched = np.zeros(m, bool)
    confirmed = np.zeros(m, np.int64)
    # eccentric windows (moved off a textureless cell in the pair): the same window is
    # matched in view k and the point transferred through the warp, as in the pair
    offset = (np.zeros((m, 2)) if cloud.offset is None
              else np.asarray(cloud.offset, dtype=np.float64))
    eccentric = bool(np.any(offset != 0.0))
    centres = cloud.x_template + offset
    if template.interpolation != interpolation:
        template = prepare_image(template.raw, interpolation)
    bound = chi2.ppf(reject_p, 2)
    tests = []  # per further view: (k, idx, matched, position, LSM cov, Mahalanobis d²)
    for k in others:
        need = tried < check_views
        if not need.any():
            break
        vis, x_pred, _ = _visible(cloud, cameras[k], zbuffers[k], normals, patch, window,
                                  max_incidence_deg)
        idx = np.flatnonzero(need & vis)
        if len(idx) == 0:
            continue
        tried[idx] += 1
        affine = _plane_affine(cam_t, cameras[k], cloud.x_template[idx], cloud.points[idx],
                               normals[idx])
        good_aff = np.all(np.isfinite(affine), axis=(1, 2))
        idx, affine = idx[good_aff], affine[good_aff]
        # the window centre's approximation: the point's, moved along the tangent plane
        approx = x_pred[idx] + np.einsum("mij,mj->mi", affine, offset[idx])
        off = -offset[idx] if eccentric else None
        init = np.zeros((len(idx), 8))
        init[:, [0, 3]] = approx
        init[:, [1, 2]] = affine[:, 0]
        init[:, [4, 5]] = affine[:, 1]
        init[:, 7] = 1.0
        quad = None
        if second_order == "geometric":  # the terms of the local-plane mappings' field
            aff6 = np.zeros((len(idx), 6))
            aff6[:, [1, 2]], aff6[:, [4, 5]] = affine[:, 0], affine[:, 1]
            quad = second_order_terms(centres[idx], aff6, radius_px=1.5 * patch)
        res = lsm_match(template, images[k], centres[idx], approx, patch=patch,
                        interpolation=interpolation, initial=init, offset=off,
                        quadratic=quad, **lsm_options)
        refined = None if quad is not None else _second_order_pass(
            template, images[k], centres[idx], res.affine, res.radiometric, res.accepted,
            res.affine[res.accepted][:, [0, 3]], None,
            {"patch": patch, "interpolation": interpolation, **lsm_options}, offset=off)
        ok, position, lsm_cov = res.accepted, res.position, res.cov
        if refined is not None:
            good, pos2, cov2 = refined
            sub = np.flatnonzero(ok)
            ok = np.zeros_like(ok)
            ok[sub[good]] = True
            position, lsm_cov = position.copy(), lsm_cov.copy()
            position[sub[good]], lsm_cov[sub[good]] = pos2[good], cov2[good]
        matched[idx[ok]] = True
        _, jac = _project(cameras[k], cloud.points[idx], with_jacobian=True)
        s_pred = jac @ cloud.cov[idx] @ np.swapaxes(jac, 1, 2) + lsm_cov
        s_pred += TOL.match_cov_floor_px**2 * np.eye(2)
        d = position - x_pred[idx]
        with np.errstate(invalid="ignore"):
            d2 = np.einsum("mi,mij,mj->m", d, np.linalg.inv(np.where(
                np.isfinite(s_pred), s_pred, np.eye(2))), d)
        tests.append((k, idx, ok, position, lsm_cov, d2))
    # the a-posteriori variance factor of the pair's matches (Förstner 1979): on real
    # images LSM's σ is several times optimistic (correlated noise, blur, shading), and
    # the χ² tests would then reject correct matches.  The median Mahalanobis distance of
    # each further view's matches estimates it robustly; the smallest over the views is
    # taken: a view whose camera disagrees with the pair's (temple ring: views 5 and 14
    # sit a systematic ~1.4 px off every other pair's points) must not widen the test
    # for itself.  Never below 1 (rendered scenes: the σ are right)
    factor = min([variance_factor(t[5][t[2]]) for t in tests if t[2].sum() >= 30],
                 default=1.0)
    cov[:, col[i]] *= factor
    cov[:, col[j]] *= factor
    for k, idx, ok, position, lsm_cov, d2 in tests:
        agree = ok & (d2 <= bound * factor)
        hit = idx[agree]
        obs[hit, col[k]] = position[agree]
        cov[hit, col[k]] = factor * (0.5 * lsm_cov[agree]
                                     + TOL.match_cov_floor_px**2 * np.eye(2))
        views[hit, k] = True
        confirmed[hit] += 1
    reason[(tried > 0) & ~matched] = NO_FURTHER_MATCH
    reason[matched & (confirmed == 0)] = INCONSISTENT
    multi = confirmed > 0
    points, pcov, sigma = cloud.points.copy(), cloud.cov.copy(), cloud.sigma.copy()
    if multi.any():
        cams = [cameras[v] for v in cols]
        cams[col[i]], cams[col[j]] = cloud.cameras
        tri = triangulate_multiview(cams, obs[multi], np.where(
            np.isfinite(cov[multi]), cov[multi], np.eye(2)), reject_p=reject_p)
        idx = np.flatnonzero(multi)
        reason[idx] = np.where(tri.valid, MULTIVIEW, TRIANGULATION)
        good = idx[tri.valid]
        points[good] = tri.points[tri.valid]
        pcov[good] = tri.cov[tri.valid]
        sigma[good] = tri.sigma[tri.valid]
    if not require_confirmation:
        reason[reason == NO_FURTHER_MATCH] = PAIR_ONLY
    return Consistency(points, pcov, sigma, reason, views, tried,
                       time.perf_counter() - start, factor)


def variance_factor(d2: np.ndarray, dof: int = 2, min_count: int = 30) -> float:
    """Robust a-posteriori variance factor of χ²-distributed squared distances, >= 1.

    ``median(d2) / median(χ²_dof)`` (the median of χ²_2 is 2 ln 2 = 1.386), 1 when fewer
    than ``min_count`` values or when the data are no worse than their covariances say.
    """
    d2 = np.asarray(d2, dtype=np.float64)
    d2 = d2[np.isfinite(d2)]
    if len(d2) < min_count:
        return 1.0
    return float(max(1.0, np.median(d2) / chi2.ppf(0.5, dof)))


def _search_volume(cameras: Sequence[Camera], masks, roi) -> SceneVolume | None:
    """The object's possible region for the pairs' search ranges (None: use features)."""
    try:
        volume = scene_volume(cameras, masks)
    except ValueError:
        return None
    if roi is not None:
        inside = np.all((volume.points >= roi[0]) & (volume.points <= roi[1]), axis=1)
        if not inside.any():
            return None
        volume = SceneVolume(points=volume.points[inside], cell=volume.cell,
                             source=volume.source + " in the region of interest")
    return volume


def _inside_object(points: np.ndarray, cameras: Sequence[Camera], masks, roi) -> np.ndarray:
    """(N,) bool: on every mask (where it projects into the image) and inside ``roi``."""
    keep = np.ones(len(points), bool)
    if masks is not None:
        keep &= inside_masks(points, cameras, masks)
    if roi is not None:
        keep &= np.all((points >= roi[0]) & (points <= roi[1]), axis=1)
    return keep


def _check_coverage(cameras: Sequence[Camera], done: Sequence[tuple[int, int]],
                    skipped: Sequence[SkippedPair], min_covered: float) -> None:
    """Raise (one line) when too few views remain in a reconstructed pair."""
    covered = {v for pr in done for v in pr}
    asked = {v for pr in [*done, *(sp.pair for sp in skipped)] for v in pr}
    need = max(2, int(np.ceil(min_covered * len(asked))))
    if len(covered) >= need:
        return
    reasons: dict[str, int] = {}
    for sp in skipped:
        reasons[sp.reason] = reasons.get(sp.reason, 0) + 1
    worst = max(reasons, key=reasons.get) if reasons else "no pair"
    raise ValueError(f"only {len(covered)} of {len(asked)} views are in a reconstructed "
                     f"pair (need {need}); {len(skipped)} of {len(skipped) + len(done)} pairs "
                     f"failed, most often: {worst}")


# --------------------------------------------------------------------------- merge
def _colours(points: np.ndarray, views: np.ndarray, cameras: Sequence[Camera],
             colour_image: Callable) -> np.ndarray:
    """(N, 3) uint8 RGB from the first view that saw each point (``colour_image(v)``)."""
    out = np.zeros((len(points), 3), np.uint8)
    first = np.argmax(views, axis=1)
    for v in np.unique(first):
        sel = np.flatnonzero(first == v)
        img = np.asarray(colour_image(int(v)))
        x = np.rint(_project(cameras[v], points[sel])).astype(np.int64)
        x[:, 0] = np.clip(x[:, 0], 0, img.shape[1] - 1)
        x[:, 1] = np.clip(x[:, 1], 0, img.shape[0] - 1)
        px = img[x[:, 1], x[:, 0]]
        if img.ndim == 2:
            px = np.repeat(px[:, None], 3, axis=1)
        else:
            px = px[:, :3][:, ::-1]  # BGR -> RGB
        out[sel] = np.clip(px, 0, 255).astype(np.uint8)
    return out


def merge_clouds(points: np.ndarray, sigma: np.ndarray, views: np.ndarray,
                 source: np.ndarray, colours: np.ndarray, *, radius: float | None = None,
                 sor_neighbours: int = 16, sor_std: float = 3.0) -> dict:
    """Fuse duplicates from different pairs and remove statistical outliers (step 4).

    Parameters
    ----------
    points : (N, 3) float64
    sigma : (N,) float64
    views : (N, V) bool
    source : (N,) int64
        Pair index of each point.
    colours : (N, 3) uint8
    radius : float, optional
        Fusion radius, scene units (default: half the median nearest-neighbour
        distance among points of one pair).
    sor_neighbours : int
        Neighbours of the statistical outlier removal (0 disables it).
    sor_std : float
        Isolation factor (mean neighbour distance against the neighbours'), and half
        the off-surface threshold in robust standard deviations.

    Returns
    -------
    dict
        ``points, sigma, views, pair, colours`` (merged), ``fused`` (points absorbed),
        ``outliers`` (removed), ``radius``.
    """
    points = check_shape(points, "(N, 3)", "points", dtype=np.float64)
    n = len(points)
    sigma = check_shape(sigma, "(N,)", "sigma", dtype=np.float64)
    views = check_shape(views, "(N, V)", "views", dtype=bool)
    source = check_shape(source, "(N,)", "source", dtype=np.int64)
    colours = check_shape(colours, "(N, 3)", "colours")
    for name, arr in (("sigma", sigma), ("views", views), ("source", source),
                      ("colours", colours)):
        if len(arr) != n:
            raise ValueError(f"{name} has {len(arr)} rows for {n} points")
    if n and not np.all(np.isfinite(points)):
        raise ValueError("points contains NaN/inf values")
    if n and not np.all(sigma > 0):
        raise ValueError(f"sigma must be positive, got min {float(np.min(sigma)):g}")
    if n == 0:
        return {"points": points, "sigma": sigma, "views": views, "pair": source,
                "colours": colours, "fused": 0, "outliers": 0, "radius": 0.0}
    tree = cKDTree(points)
    if radius is None:
        d, nb = tree.query(points, k=min(8, n))
        same = source[nb] == source[:, None]
        same[:, 0] = False
        nearest = np.where(same, d, np.inf).min(axis=1)
        finite = nearest[np.isfinite(nearest)]
        radius = 0.5 * float(np.median(finite)) if finite.size else 0.0
    labels = np.arange(n)
    if radius > 0:
        links = tree.query_pairs(radius, output_type="ndarray")
        links = links[source[links[:, 0]] != source[links[:, 1]]]
        graph = coo_matrix((np.ones(len(links)), (links[:, 0], links[:, 1])), shape=(n, n))
        _, labels = connected_components(graph, directed=False)
    n_groups = int(labels.max()) + 1
    weight = 1.0 / np.maximum(sigma, TOL.zero) ** 2
    wsum = np.bincount(labels, weight, n_groups)
    merged = np.stack([np.bincount(labels, weight * points[:, a], n_groups)
                       for a in range(3)], axis=1) / wsum[:, None]
    size = np.bincount(labels, minlength=n_groups)
    col = np.stack([np.bincount(labels, colours[:, a].astype(np.float64), n_groups)
                    for a in range(3)], axis=1) / size[:, None]
    mviews = np.zeros((n_groups, views.shape[1]), bool)
    np.logical_or.at(mviews, labels, views)
    pair = np.full(n_groups, -1, np.int64)
    pair[labels] = source  # any member; reset where groups mix pairs below
    first = np.full(n_groups, -1, np.int64)
    first[labels[::-1]] = source[::-1]
    mixed = np.bincount(labels, (source != first[labels]).astype(np.float64), n_groups) > 0
    pair[mixed] = -1
    out = {"points": merged, "sigma": 1.0 / np.sqrt(wsum), "views": mviews, "pair": pair,
           "colours": np.clip(np.rint(col), 0, 255).astype(np.uint8),
           "fused": int(n - n_groups), "radius": float(radius)}
    keep = _statistical_inliers(merged, sor_neighbours, sor_std)
    out = {k: (v[keep] if isinstance(v, np.ndarray) else v) for k, v in out.items()}
    out["outliers"] = int(np.count_nonzero(~keep))
    return out


def _statistical_inliers(points: np.ndarray, k: int, n_std: float) -> np.ndarray:
    """(N,) bool: inliers of two statistical tests over the k nearest neighbours.

    1. Rusu's test, made local: the mean distance to the k neighbours at most ``n_std``
       times the median of the neighbours' own mean distances (the global mean + n std
       form of [2]_ removes a cloud's boundary rows, whose mean distance is ~1.3x the
       interior's; an isolated point is far from neighbours that are close to theirs).
    2. Off-surface test: distance to the neighbours' PCA plane within ``2 n_std``
       robust standard deviations (1.4826 MAD) of all such distances.  A mismatch at a
       silhouette lies off the surface but not in a sparse region, which test 1 misses;
       the plane residual of a true point is noise plus the sagitta of the neighbourhood.
    """
    if k <= 0 or len(points) <= k:
        return np.ones(len(points), bool)
    tree = cKDTree(points)
    mean_d = np.empty(len(points))
    resid = np.empty(len(points))
    nbs = []
    # in blocks of rows: the (block, k, 3) neighbourhoods, not (N, k, 3) at once (~1 KB a
    # point), so the working memory does not grow with the cloud; rows are independent
    for lo in range(0, len(points), _SOR_BLOCK):
        rows = slice(lo, lo + _SOR_BLOCK)
        d, nb = tree.query(points[rows], k=k + 1)
        mean_d[rows] = d[:, 1:].mean(axis=1)
        nbs.append(nb[:, 1:].astype(np.int32))
        nbp = points[nb[:, 1:]]  # (B, k, 3)
        mean_nb = nbp.mean(axis=1)
        centred = nbp - mean_nb[:, None]
        _, vec = np.linalg.eigh(np.einsum("nki,nkj->nij", centred, centred))
        resid[rows] = np.abs(np.einsum("ni,ni->n", points[rows] - mean_nb, vec[:, :, 0]))
    keep = mean_d <= n_std * np.median(mean_d[np.concatenate(nbs)], axis=1)
    scale = 1.4826 * np.median(np.abs(resid - np.median(resid)))
    return keep & (resid <= np.median(resid) + 2.0 * n_std * max(scale, TOL.zero))


# --------------------------------------------------------------------------- driver
def _further_views(cameras: Sequence[Camera], pair: tuple[int, int], count: int,
                   max_incidence_deg: float) -> list[int]:
    """The ``count`` views nearest to the pair's left view that may see its points.

    Bounds what a consistency task carries (images and z-buffers travel to Dask workers):
    the check tries the nearest views first and stops after ``check_views`` per point, so
    ``2 check_views + 2`` leaves room for the views a point is hidden from.
    """
    i, j = pair
    axis_i = cameras[i].R[2]
    facing = np.cos(np.radians(min(2.0 * max_incidence_deg, 180.0)))
    return _check_order(cameras, pair, [k for k in range(len(cameras)) if k not in (i, j)
                                        and float(cameras[k].R[2] @ axis_i) >= facing])[:count]


def _check_order(cameras: Sequence[Camera], pair: tuple[int, int],
                 candidates: list[int]) -> list[int]:
    """Further views in the order the consistency check tries them.

    Nearest to the template view first, but views closer than half the pair's baseline
    to either pair view go last: such a view adds less parallax than the pair itself, so
    a wrong depth reprojects almost where it should (a weak check) and the multi-view
    triangulation gains little.  On a dense ring (72 views, pairs 3 views apart) the
    nearest views lie *inside* the pair's baseline; on the 24-view ring every
    neighbour qualifies and the order is the plain nearest-first one.
    """
    i, j = pair
    ci, cj = cameras[i].center, cameras[j].center
    half_base = 0.5 * float(np.linalg.norm(ci - cj))

    def key(k):
        ck = cameras[k].center
        weak = min(np.linalg.norm(ck - ci), np.linalg.norm(ck - cj)) < half_base
        return (bool(weak), float(np.linalg.norm(ck - ci)))

    return sorted(candidates, key=key)


@dataclass(frozen=True)
class _View:
    """One view's image, read on use from a lazily loading image sequence.

    Tasks carry this (the sequence names files; it pickles small) instead of the pixels,
    so that an image is in memory only while a task uses it.
    """

    images: Sequence
    index: int

    def load(self) -> np.ndarray:
        return np.asarray(self.images[self.index])


def _image(ref) -> np.ndarray:
    return ref.load() if isinstance(ref, _View) else ref


@dataclass(frozen=True)
class SkippedPair:
    """A view pair that could not be reconstructed, and why (one line)."""

    pair: tuple[int, int]
    reason: str


def _pair_task(item: dict) -> PairCloud | SkippedPair:
    """One pair's cloud, or a :class:`SkippedPair` when its data do not allow one.

    A ``ValueError`` is the data's verdict (no overlap, no usable rectification, too few
    matches): the pair is skipped and the run goes on; any other error is a fault.
    """
    try:
        return reconstruct_view_pair(_image(item["left_image"]), _image(item["right_image"]),
                                     item["left"], item["right"], item["pair"],
                                     volume=item.get("volume"), mask=item.get("mask"),
                                     **item["options"])
    except ValueError as exc:
        return SkippedPair(tuple(item["pair"]), str(exc).splitlines()[0] if str(exc)
                           else type(exc).__name__)


def _consistency_task(item: dict) -> Consistency:
    cloud = item["cloud"]
    i, j = cloud.pair
    template = rectified_template(_image(item["template_image"]), item["cameras"][i],
                                  item["cameras"][j], item["options"]["interpolation"])
    res = check_consistency(cloud, item["cameras"], item["images"], item["zbuffers"],
                            template, **item["options"])
    # what the merge needs, compactly: no covariances, the view flags packed in bits
    return Consistency(points=res.points, cov=np.zeros((0, 3, 3)), sigma=res.sigma,
                       reason=res.reason, views=np.packbits(res.views, axis=1),
                       checked=res.checked, seconds=res.seconds,
                       variance_factor=res.variance_factor)


def _view_task(item: dict) -> tuple[PreparedImage, np.ndarray]:
    """A further view's grey image prepared for LSM and its z-buffer of all pair points."""
    grey = prepare_image(_grey(_image(item["image"])), item["interpolation"])
    return grey, zbuffer(item["camera"], item["points"], item["window"])


def _kernels_release_gil() -> bool:
    """True when the LSM and second-order numba kernels are compiled with ``nogil=True``."""
    from matching import lsm, second_order

    kernels = [getattr(lsm, "_lsm_batch", None),
               getattr(second_order, "_second_order_kernel", None)]
    return all(getattr(k, "targetoptions", {}).get("nogil", False) for k in kernels)


def _thread_map(workers: int) -> Callable:
    """``map(func, items)`` on ``workers`` threads of this process, results in order.

    View pairs are independent and much of a pair's time is serial (SIFT, SGBM,
    rectification, numpy), so two pairs at once keep two cores busy where one pair's
    numba ``prange`` kernels alone leave them half idle.  When the kernels release the
    GIL each thread runs them on one numba thread (``numba.set_num_threads`` is
    per thread), else they keep numba's default and the other threads overlap them with
    GIL-free OpenCV/numpy work.  Results do not depend on the thread count (every
    kernel works per point).
    """
    def run(func, items):
        items = list(items)
        if workers <= 1 or len(items) < 2:
            return [func(item) for item in items]
        single = _kernels_release_gil()

        def call(item):
            if single:
                import numba

                numba.set_num_threads(1)
            return func(item)

        with ThreadPoolExecutor(min(workers, len(items))) as pool:
            return list(pool.map(call, items))
    return run


def _default_workers() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


_MATCH_KEYS = ("spacing", "patch", "interpolation", "min_texture_snr", "sgbm_block",
               "max_iter", "shift_stop_px", "sigma0_factor", "min_correlation",
               "adaptive_patch", "max_patch", "max_sigma_mad_k", "eccentric")
_LSM_KEYS = ("max_iter", "shift_stop_px", "sigma0_factor", "min_correlation",
             "min_texture_snr")


def _image_shape(images: Sequence, v: int) -> tuple:
    shapes = getattr(images, "shapes", None)
    return tuple(shapes[v]) if shapes is not None else np.shape(images[v])


def reconstruct_multiview(images: Sequence, cameras: Sequence[Camera], *,
                          pairs: Sequence[tuple[int, int]] | None = None,
                          map_func: Callable | None = None, workers: int | None = None,
                          chunk_pairs: int = 8, check_views: int = 2,
                          max_incidence_deg: float = 60.0, reject_p: float = 0.999,
                          require_confirmation: bool = True, second_order: str = "geometric",
                          keep_unchecked: bool | None = None, sor_neighbours: int = 16,
                          sor_std: float = 3.0, pair_options: dict | None = None,
                          min_covered: float = 0.5, masks: Sequence | None = None,
                          roi=None, search: str = "geometry",
                          **match_options) -> MultiViewCloud:
    """Images of calibrated views all round an object -> one merged cloud (steps 1-4).

    Parameters
    ----------
    images : sequence of V (H, W) or (H, W, 3) array_like
        Images in camera order (colour in BGR order).  A sequence with a true ``lazy``
        attribute (and ``shapes``, the V image shapes) reads an image on item access,
        e.g. :class:`pipeline.inputs.FolderImages`: tasks then carry the sequence
        and a view index, and an image is in memory only while a task uses it.
    cameras : sequence of V Camera
    pairs : sequence of (int, int), optional
        View pairs (default :func:`select_pairs` with ``pair_options``).
    map_func : callable, optional
        ``map_func(func, items) -> list``, e.g. ``executor.map`` of
        :mod:`pipeline.executor` (default: ``workers`` threads of this process).
    workers : int, optional
        Threads for the view pairs and consistency checks when ``map_func`` is not
        given, and for the per-view preparation always (default: the usable cores).
    chunk_pairs : int
        Consistency checks are mapped ``chunk_pairs`` pairs at a time (pairs in the
        given order: neighbours on a ring); only the views those pairs check in are
        prepared (grey image + z-buffer) and held, so memory is bounded by a chunk's
        views, not by all V.
    check_views, max_incidence_deg, reject_p, require_confirmation, second_order :
        As :func:`check_consistency`.
    keep_unchecked : bool, optional
        Keep ``pair_only`` points (no further view sees them).  Default: only when
        there are fewer than 3 views (nothing to check against); on a ring every
        surface point a pair sees is seen by a neighbour too, and the unchecked ones
        are mostly silhouette mismatches.
    sor_neighbours, sor_std :
        As :func:`merge_clouds`.
    pair_options : dict, optional
        Keyword arguments of :func:`select_pairs`.
    min_covered : float
        A pair whose data allow no reconstruction (no overlap, no rectification...) is
        skipped (``stats["skipped"]``: pair, view names, one-line reason); the run fails
        only when fewer than this share of the views in the pairs (and fewer than 2)
        remain in a reconstructed pair.
    masks : sequence of V (H, W) bool or None, optional
        Object masks (:mod:`matching.masks`; None entries: no mask for that view):
        candidates only on the mask, the search volume is the visual hull, and points
        off a mask where they project into its image are dropped (``outside``).
    roi : (2, 3) array_like, optional
        Region of interest, lower and upper world corner: the search volume is cut to it
        and points outside are dropped (``outside``).
    search : {"geometry", "features"}
        Where SGBM's disparity range comes from: ``"geometry"`` (default) the common
        volume of the frusta, the visual hull with masks, cut to ``roi``
        (:func:`matching.search_range.scene_volume`); ``"features"`` SIFT matches per
        pair (:func:`matching.seeds.disparity_range`).
    **match_options
        ``spacing``, ``patch``, ``interpolation``, ``min_correlation``,
        ``sigma0_factor``, ``max_iter``, ``shift_stop_px``, ``min_texture_snr``,
        ``sgbm_block``, ``adaptive_patch`` (default False: see
        :func:`reconstruct_view_pair`), ``max_patch``, ``max_sigma_mad_k``,
        ``eccentric`` (default True here: see :func:`reconstruct_view_pair`)
        (:func:`matching.pair.match_pair`).

    Returns
    -------
    MultiViewCloud
        Identical whatever ``map_func``, ``workers`` and ``chunk_pairs`` (every task is
        deterministic and independent of the others).
    """
    cameras = list(cameras)
    if len(images) != len(cameras):
        raise ValueError(f"images: got {len(images)} images for {len(cameras)} cameras")
    if len(cameras) < 2:
        raise ValueError(f"cameras: need at least 2 views, got {len(cameras)}")
    for v, cam in enumerate(cameras):
        shape = _image_shape(images, v)
        if len(shape) < 2 or (shape[1], shape[0]) != cam.size:
            got = f"{shape[1]}x{shape[0]}" if len(shape) >= 2 else str(shape)
            raise ValueError(f"images[{v}] ({cam.name or v}) is {got} px but its camera is "
                             f"{cam.size[0]}x{cam.size[1]} px")
    if int(check_views) < 1:
        raise ValueError(f"check_views must be >= 1, got {check_views}")
    if second_order not in SECOND_ORDER_MODES:
        raise ValueError(f"second_order must be one of {SECOND_ORDER_MODES}, "
                         f"got {second_order!r}")
    if not 0.0 < max_incidence_deg < 90.0:
        raise ValueError(f"max_incidence_deg must lie in (0, 90), got {max_incidence_deg}")
    if not 0.0 < reject_p < 1.0:
        raise ValueError(f"reject_p must lie in (0, 1), got {reject_p}")
    workers = _default_workers() if workers is None else int(workers)
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    if not 0.0 <= min_covered <= 1.0:
        raise ValueError(f"min_covered must lie in [0, 1], got {min_covered}")
    if int(chunk_pairs) < 1:
        raise ValueError(f"chunk_pairs must be >= 1, got {chunk_pairs}")
    if search not in SEARCH_MODES:
        raise ValueError(f"search must be one of {SEARCH_MODES}, got {search!r}")
    if masks is not None:
        masks = list(masks)
        if len(masks) != len(cameras):
            raise ValueError(f"masks: got {len(masks)} for {len(cameras)} cameras")
        for v, (m, cam) in enumerate(zip(masks, cameras, strict=True)):
            if m is not None and np.shape(m) != (cam.height, cam.width):
                raise ValueError(f"masks[{v}] ({cam.name or v}) is {np.shape(m)[::-1]} px "
                                 f"but its camera is {cam.size[0]}x{cam.size[1]} px")
    if roi is not None:
        roi = check_shape(roi, "(2, 3)", "roi", dtype=np.float64)
        if not np.all(roi[1] > roi[0]):
            raise ValueError(f"roi: the upper corner must exceed the lower, got {roi.tolist()}")
    unknown = set(match_options) - set(_MATCH_KEYS)
    if unknown:
        raise ValueError(f"unknown matching option(s) {sorted(unknown)}; choose from "
                         f"{', '.join(_MATCH_KEYS)}")
    local_map = _thread_map(workers)
    map_func = local_map if map_func is None else map_func
    lazy = bool(getattr(images, "lazy", False))

    def ref(v: int):
        return _View(images, v) if lazy else images[v]

    pairs = select_pairs(cameras, **(pair_options or {})) if pairs is None else [
        (int(a), int(b)) for a, b in pairs]
    if not pairs:
        raise ValueError("cameras: no view pair has a usable baseline-to-depth ratio and "
                         "viewing angle")
    t0 = time.perf_counter()
    volume = (_search_volume(cameras, masks, roi) if search == "geometry" else None)
    results = map_func(_pair_task, [
        {"left_image": ref(a), "right_image": ref(b), "left": cameras[a],
         "right": cameras[b], "pair": (a, b), "volume": volume,
         "mask": None if masks is None else masks[a], "options": match_options}
        for a, b in pairs])
    skipped = [r for r in results if isinstance(r, SkippedPair)]
    clouds = [r for r in results if not isinstance(r, SkippedPair)]
    _check_coverage(cameras, [c.pair for c in clouds], skipped, min_covered)
    pairs = [c.pair for c in clouds]
    t1 = time.perf_counter()
    patch = int(match_options.get("patch", 15))
    spacing = int(match_options.get("spacing", DEFAULT_SPACING))
    all_points = np.concatenate([c.points for c in clouds]) if clouds else np.zeros((0, 3))
    median_sigma_pair = (float(np.median(np.concatenate([c.sigma for c in clouds])))
                         if len(all_points) else float("nan"))
    window = 2 * spacing + 1
    interpolation = match_options.get("interpolation", DEFAULT_INTERPOLATION)
    options = {"check_views": check_views, "patch": patch, "spacing": spacing,
               "interpolation": interpolation,
               "max_incidence_deg": max_incidence_deg, "reject_p": reject_p,
               "require_confirmation": require_confirmation, "second_order": second_order,
               **{k: v for k, v in match_options.items() if k in _LSM_KEYS}}
    near = [_further_views(cameras, pr, 2 * check_views + 2, max_incidence_deg)
            for pr in pairs]
    chunks = [range(s, min(s + int(chunk_pairs), len(pairs)))
              for s in range(0, len(pairs), int(chunk_pairs))]
    view_data: dict = {}
    checks: list = []
    prepared_views = 0
    for c, chunk in enumerate(chunks):
        need = sorted({k for p in chunk for k in near[p]})
        missing = [k for k in need if k not in view_data]
        prepared_views += len(missing)
        view_data.update(zip(missing, local_map(_view_task, [
            {"image": ref(k), "camera": cameras[k], "points": all_points,
             "window": window, "interpolation": interpolation} for k in missing]),
            strict=True))
        checks += map_func(_consistency_task, [
            {"cloud": clouds[p], "cameras": cameras, "template_image": ref(pairs[p][0]),
             "images": {k: view_data[k][0] for k in near[p]},
             "zbuffers": {k: view_data[k][1] for k in near[p]}, "options": options}
            for p in chunk])
        for p in chunk:
            clouds[p] = None  # the pair's points live on in its check
        later = {k for p in chunks[c + 1] for k in near[p]} if c + 1 < len(chunks) else set()
        view_data = {k: d for k, d in view_data.items() if k in later}
    del view_data, all_points
    t2 = time.perf_counter()
    reasons = np.concatenate([c.reason for c in checks]) if checks else np.zeros(0, np.int8)
    if keep_unchecked is None:
        keep_unchecked = len(cameras) < 3
    keep = np.isin(reasons, (MULTIVIEW, PAIR_ONLY) if keep_unchecked else (MULTIVIEW,))
    if masks is not None or roi is not None:
        all_pts = np.concatenate([c.points for c in checks])
        out = np.zeros(len(keep), bool)
        out[keep] = ~_inside_object(all_pts[keep], cameras, masks, roi)
        reasons = np.where(out, OUTSIDE, reasons).astype(reasons.dtype)
        keep &= ~out
        del all_pts
    points = np.concatenate([c.points for c in checks])[keep]
    sigma = np.concatenate([c.sigma for c in checks])[keep]
    views = np.unpackbits(np.concatenate([c.views for c in checks])[keep], axis=1,
                          count=len(cameras)).astype(bool)
    source = np.concatenate([np.full(len(c.reason), p, np.int64)
                             for p, c in enumerate(checks)])[keep]
    factors = [c.variance_factor for c in checks]
    del checks
    colours = _colours(points, views, cameras, lambda v: _image(ref(v)))
    merged = merge_clouds(points, sigma, views, source, colours,
                          sor_neighbours=sor_neighbours, sor_std=sor_std)
    t3 = time.perf_counter()
    counts = {REASON_NAMES[c]: int(np.count_nonzero(reasons == c)) for c in REASON_NAMES}
    counts[REASON_NAMES[OUTLIER]] = merged["outliers"]
    is_multi = reasons[keep] == MULTIVIEW
    stats = {
        "views": len(cameras), "pairs": len(pairs), "pairs_skipped": len(skipped),
        "search": "features" if volume is None else volume.source,
        "variance_factor_median": float(np.median(factors)) if factors else 1.0,
        "variance_factor_max": float(np.max(factors)) if factors else 1.0,
        "outside": int(np.count_nonzero(reasons == OUTSIDE)),
        "skipped": [{"pair": list(sp.pair), "views": [cameras[v].name for v in sp.pair],
                     "reason": sp.reason} for sp in skipped],
        "pair_points": int(len(reasons)), "kept_points": int(keep.sum()),
        "fused": merged["fused"], "fusion_radius": merged["radius"],
        "points": int(len(merged["points"])),
        "median_sigma_pair": median_sigma_pair,
        "median_sigma_multiview": float(np.median(sigma[is_multi])) if is_multi.any()
        else float("nan"),
        "prepared_views": prepared_views, "workers": workers,
        "pair_seconds": t1 - t0, "consistency_seconds": t2 - t1, "merge_seconds": t3 - t2,
        "seconds_per_pair": (t2 - t0) / len(pairs), "seconds": t3 - t0,
    }
    return MultiViewCloud(points=merged["points"], colours=merged["colours"],
                          sigma=merged["sigma"], views=merged["views"], pair=merged["pair"],
                          pairs=list(pairs), reason_counts=counts, stats=stats)
