r"""All-round multi-view acquisition: view pairs, multi-image consistency, one merged cloud.

A ring of calibrated views becomes one cloud in four steps (:func:`reconstruct_multiview`,
its options :class:`MultiViewOptions`); tasks run through :mod:`matching.scheduler`.

1. **View pairs** (:mod:`matching.view_pairs`): a pair is usable when its baseline-to-depth
   ratio lies in ``[min_ratio, max_ratio]`` and its optical axes are within
   ``max_angle_deg``; each view keeps the ``partners`` closest to ``target_ratio`` (1:4).
2. **Pair reconstruction** (here): rectified with the baseline as the x axis
   (:mod:`matching.rectify`, Fusiello, Trucco and Verri 2000), matched by
   :func:`matching.pair.match_pair`, re-matched with second-order warp terms
   (:mod:`matching.second_order`), eccentric windows at rims
   (:func:`matching.seeds.window_offsets`), a second half-cell lattice where the first left
   holes (``densify``), triangulated (:func:`matching.triangulate.triangulate_pair`).
3. **Multi-image consistency** (MPGC in spirit, Gruen & Baltsavias 1988 [1]_;
   :mod:`matching.further_views`, :mod:`matching.visibility`): each point is LSM-matched into the
   ``check_views`` nearest further views where it is visible (in front, inside, facing
   within ``max_incidence_deg``, not occluded in a z-buffer of every pair's points), started
   from its reprojection and the local-plane mapping; consistent when the Mahalanobis
   distance from :math:`\pi_k(X)` with covariance :math:`J_k \Sigma_X J_k^T + \Sigma_{LSM}`
   passes :math:`\chi^2_2` at ``reject_p``; confirmed points are triangulated from all their
   consistent views (:func:`matching.triangulate.triangulate_multiview`).
4. **Merge** (:mod:`matching.fusion`): points of different pairs closer than half the point
   spacing fused by 1/σ² weights; a statistical outlier removal (after Rusu et al. 2008
   [2]_) by neighbour distance and distance to the neighbours' PCA plane.

**Silhouettes** (:func:`matching.masks.near_foreground`): where a view's background is
uniform, a point must project within :math:`\sqrt2/2 + q\,\sigma f/z` px of its foreground.

Per-point reasons: :data:`REASON_NAMES`; 2-6 are rejected (2 only with
``require_confirmation``), 1 (``pair_only``) unless ``keep_unchecked``.  ``views (N, V)``
bool: the views that saw each point; ``pair (N,)``: the pair it came from (-1 fused from
several, -1 - v an outline point of view v).  Every rule: ``docs/method/acquire.md``.

References
----------
.. [1] A. Gruen, E. Baltsavias, "Geometrically constrained multiphoto matching", PE&RS 54(5) (1988).
.. [2] R. B. Rusu et al., "Towards 3D point cloud based object maps for household
   environments", Robotics and Autonomous Systems 56(11), 927-941 (2008).
"""

from __future__ import annotations

import os
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, fields, replace

import cv2
import numpy as np
from scipy.stats import norm

from matching.cameras import Camera, StereoRig
from matching.contours import OutlinePoints, outline_points
from matching.further_views import (  # noqa: F401 - the reason codes, re-exported
    INCONSISTENT,
    LSM_KEYS,
    MULTIVIEW,
    NO_FURTHER_MATCH,
    OUTLIER,
    OUTSIDE,
    PAIR_ONLY,
    REASON_NAMES,
    SECOND_ORDER_MODES,
    TRIANGULATION,
    Consistency,
    check_consistency,
    variance_factor,
)
from matching.fusion import merge_clouds, point_colours
from matching.lsm import DEFAULT_INTERPOLATION, PreparedImage, prepare_image
from matching.masks import foreground_mask, grey, inside_masks, near_foreground, signed_distance
from matching.pair import match_pair
from matching.rectify import Rectification, rectify, rectify_images, resample
from matching.scheduler import ViewRef, check_stop, default_workers, load_image, thread_map
from matching.search_range import SceneVolume, pair_disparity_range, scene_volume
from matching.seeds import DEFAULT_SPACING, disparity_range
from matching.triangulate import triangulate_pair
from matching.validate import TOL, check_shape
from matching.view_pairs import further_views, scene_centre, select_pairs
from matching.visibility import zbuffer

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
    "variance_factor",
    "merge_clouds",
    "zbuffer",
    "reconstruct_multiview",
    "MultiViewOptions",
]

#: Where SGBM's disparity range comes from (:func:`reconstruct_multiview`).
SEARCH_MODES = ("geometry", "features")


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
        Index into ``pairs`` of the pair the point came from; -1 when fused from several,
        -1 - v for an outline point of view v (:func:`_with_outline`).
    pairs : list of (int, int)
    reason_counts : dict
        Pair points per :data:`REASON_NAMES` name (before merging; ``outlier`` after).
    stats : dict
        Counts and timings (``pair_seconds``, ``consistency_seconds``, ``merge_seconds``,
        ``fused``, ``median_sigma_pair``, ``median_sigma_multiview`` ...);
        ``further_view_offsets``: one ``{"pair", "view", "offset_px"}`` per pair and
        further view whose matches were systematically off (an orientation error:
        :func:`matching.further_views._systematic_offset`).
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


def _pair_options(match_options: dict) -> dict:
    """``match_pair``'s options for a pair of a ring (:func:`reconstruct_view_pair`): the
    caller's, with this module's defaults where it gives none (each with its reason)."""
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
    # a second candidate lattice, half a cell off, matched between accepted centred
    # windows, "auto": only as many candidates as the first lattice left cells of the
    # matched surface unaccepted (match_pair's density_deficit: the density ``spacing``
    # asks for, where a share of the candidates was rejected).  Everywhere (True) it
    # costs the demo's rendered ring, whose matched surface is accepted nearly
    # completely, 51 % more acquisition time and 53 % more patches (381 k -> 551 k
    # points, Hausdorff 0.0016 -> 0.0031, the same Chamfer; README); the temple ring,
    # spacing 3, is where it pays: 33 910 -> 49 768 points with True
    options.setdefault("densify", "auto")
    # the pair's own variance factor (match_pair's default) is left to the further-view
    # check (matching.further_views), which estimates it from a third view's matches of the
    # same points and scales the pair's covariances by it: applying both would count
    # what real images add twice
    options.setdefault("sigma_factor", False)
    # no pair-level uniqueness test here (match_pair's default is on): every point of a
    # ring is re-matched in further views (matching.further_views), which rejects a one-period
    # slip by geometry that does not depend on the pair's texture; the pair test on top
    # cost the rendered test rings 15-30 % of their points (densify and portrait tests:
    # 3 862 of > 5 000) and ~4x the pair's matching time
    options.setdefault("unique", False)
    return options


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
    grey_l, grey_r = rectify_images(rect, grey(left_image), grey(right_image))
    source = np.ones(left.size[::-1], np.float32) if mask is None else \
        np.asarray(mask, dtype=np.float32)
    valid = cv2.remap(source, *rect.maps_left, cv2.INTER_NEAREST,
                      borderMode=cv2.BORDER_CONSTANT, borderValue=0) > 0
    search = _search_range(volume, cam_l, cam_r, grey_l, grey_r)
    options = _pair_options(match_options)
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
                                    "density_deficit": matches.density_deficit,
                                    "densified": matches.densified,
                                    "silhouette": int(np.count_nonzero(matches.accepted
                                                                       & near_edge)),
                                    "eccentric": int(np.count_nonzero(
                                        np.any(offset != 0, axis=1)))},
                     seconds=time.perf_counter() - start, offset=offset)


def _densify_stats(clouds: Sequence[PairCloud]) -> dict:
    """How much of the second lattice the pairs matched (``stats["densify"]``).

    ``pairs``: pairs that matched any; ``candidates``: second-lattice candidates matched;
    ``first_lattice``: the pairs' first-lattice candidates (one per cell on the masks);
    ``share``: candidates / first_lattice; ``deficit``: matched-surface cells whose
    first-lattice candidate gave no point (:func:`matching.pair.density_deficit`).
    """
    extra = ("density_deficit", "densified", "silhouette", "eccentric")
    counts = [c.status_counts for c in clouds]
    dense = sum(int(c.get("densified", 0)) for c in counts)
    first = sum(int(v) for c in counts for k, v in c.items() if k not in extra) - dense
    return {"pairs": sum(int(c.get("densified", 0)) > 0 for c in counts),
            "candidates": dense, "first_lattice": first,
            "share": dense / first if first > 0 else 0.0,
            "deficit": sum(int(c.get("density_deficit", 0)) for c in counts)}


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
    return prepare_image(resample(grey(left_image, np.float32), rect.maps_left), interpolation)


# --------------------------------------------------------------------------- consistency
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


def _outline_points(cameras: Sequence[Camera], masks, roi, points: np.ndarray,
                    sigma: np.ndarray, image, map_func: Callable = map) -> OutlinePoints:
    """Outline points (:mod:`matching.contours`) of every view with a mask (given, or
    the automatic foreground of a uniform background), on the object and in ``roi``;
    each image read once, one in memory at a time."""
    extra = outline_points(_Lazy(image, len(cameras)), cameras, masks, points, sigma,
                           auto_masks=True, map_func=map_func)
    if len(extra) and (masks is not None or roi is not None):
        extra = extra.take(_inside_object(extra.points, cameras, masks, roi))
    return extra


class _Lazy:
    """``images[v]`` read by ``image(v)`` on access."""

    def __init__(self, image, n: int):
        self._image, self._n = image, n

    def __len__(self) -> int:
        return self._n

    def __getitem__(self, v: int):
        return self._image(v)


def _foreground_distances(n: int, image, map_func: Callable = map) -> list:
    """Per view, the signed distance (px) from its automatic foreground's boundary
    (:func:`matching.masks.foreground_mask` without dilation,
    :func:`matching.masks.signed_distance`), or None where the background is not
    uniform; each image read once, one per ``map_func`` worker in memory at a time."""
    def one(v: int):
        fg = foreground_mask(image(v), margin_px=0)
        return None if fg is None else signed_distance(fg)

    return list(map_func(one, range(n)))


def _near_foreground(points, sigma, cameras, distances, quantile, map_func: Callable,
                     parts: int) -> np.ndarray:
    """:func:`matching.masks.near_foreground` over ``parts`` runs of the points on
    ``map_func``'s threads (a per-point test: the same answer; its projections and
    remaps release the GIL; on one core it was 5 % of the demo's acquisition)."""
    chunks = np.array_split(np.arange(len(points)), max(1, min(parts, len(points) // 10_000)))
    keep = map_func(lambda i: near_foreground(points[i], sigma[i], cameras, distances,
                                              quantile), chunks)
    return np.concatenate(keep) if keep else np.ones(0, bool)


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
# --------------------------------------------------------------------------- driver
@dataclass(frozen=True)
class SkippedPair:
    """A view pair that could not be reconstructed, and why (one line)."""

    pair: tuple[int, int]
    reason: str


@dataclass(frozen=True, eq=False)
class StoredPair:
    """A :class:`PairCloud` kept on disk until its consistency check: in memory only
    what the steps before it read (the pair, its points for the further views'
    z-buffers, σ, the status counts); :meth:`load` reads the rest back and removes the
    file.  Held per pair instead of the cloud, 32 bytes a point instead of ~190."""

    pair: tuple[int, int]
    points: np.ndarray
    sigma: np.ndarray
    cameras: tuple[Camera, Camera]
    status_counts: dict
    seconds: float
    path: str

    def __len__(self) -> int:
        return len(self.points)

    def load(self) -> PairCloud:
        with np.load(self.path, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
        os.remove(self.path)
        return PairCloud(pair=self.pair, points=self.points, sigma=self.sigma,
                         cameras=self.cameras, status_counts=self.status_counts,
                         seconds=self.seconds, offset=arrays.pop("offset", None), **arrays)


def _stored(cloud: PairCloud, folder: str) -> StoredPair:
    """``cloud`` written to ``folder`` (:class:`StoredPair`), its arrays bit for bit."""
    path = os.path.join(folder, f"pair_{cloud.pair[0]}_{cloud.pair[1]}.npz")
    extra = {} if cloud.offset is None else {"offset": cloud.offset}
    tmp = path[:-len(".npz")] + ".part.npz"  # np.savez keeps a name ending in .npz
    np.savez(tmp, cov=cloud.cov, x_template=cloud.x_template, x_right=cloud.x_right,
             cov_2d=cloud.cov_2d, **extra)
    os.replace(tmp, path)
    return StoredPair(pair=cloud.pair, points=cloud.points, sigma=cloud.sigma,
                      cameras=cloud.cameras, status_counts=cloud.status_counts,
                      seconds=cloud.seconds, path=path)


def _pair_task(item: dict) -> PairCloud | SkippedPair:
    """One pair's cloud, or a :class:`SkippedPair` when its data do not allow one.

    A ``ValueError`` is the data's verdict (no overlap, no usable rectification, too few
    matches): the pair is skipped and the run goes on; any other error is a fault.
    """
    check_stop()  # a task picked up as the map was interrupted does nothing
    try:
        cloud = reconstruct_view_pair(load_image(item["left_image"]),
                                      load_image(item["right_image"]),
                                      item["left"], item["right"], item["pair"],
                                      volume=item.get("volume"), mask=item.get("mask"),
                                      **item["options"])
        return _stored(cloud, item["store"]) if item.get("store") else cloud
    except ValueError as exc:
        return SkippedPair(tuple(item["pair"]), str(exc).splitlines()[0] if str(exc)
                           else type(exc).__name__)


def _consistency_task(item: dict) -> Consistency:
    check_stop()
    cloud = item["cloud"]
    if isinstance(cloud, StoredPair):
        cloud = cloud.load()
    i, j = cloud.pair
    template = rectified_template(load_image(item["template_image"]), item["cameras"][i],
                                  item["cameras"][j], item["options"]["interpolation"])
    res = check_consistency(cloud, item["cameras"], item["images"], item["zbuffers"],
                            template, **item["options"])
    # what the merge needs, compactly: no covariances, the view flags packed in bits
    return Consistency(points=res.points, cov=np.zeros((0, 3, 3)), sigma=res.sigma,
                       reason=res.reason, views=np.packbits(res.views, axis=1),
                       checked=res.checked, seconds=res.seconds,
                       variance_factor=res.variance_factor, offsets=res.offsets)


def _view_task(item: dict) -> tuple[PreparedImage, np.ndarray]:
    """A further view's grey image prepared for LSM and its z-buffer of all pair points."""
    prepared = prepare_image(grey(load_image(item["image"])), item["interpolation"])
    return prepared, zbuffer(item["camera"], item["points"], item["window"])


_MATCH_KEYS = ("spacing", "patch", "interpolation", "min_texture_snr", "sgbm_block",
               "max_iter", "shift_stop_px", "sigma0_factor", "min_correlation",
               "adaptive_patch", "max_patch", "max_sigma_mad_k", "eccentric", "densify")


def _image_shape(images: Sequence, v: int) -> tuple:
    shapes = getattr(images, "shapes", None)
    return tuple(shapes[v]) if shapes is not None else np.shape(images[v])


@dataclass(frozen=True)
class MultiViewOptions:
    """How :func:`reconstruct_multiview` pairs, checks and merges the views.

    Attributes
    ----------
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
    search : {"geometry", "features"}
        Where SGBM's disparity range comes from: ``"geometry"`` (default) the common
        volume of the frusta, the visual hull with masks, cut to ``roi``
        (:func:`matching.search_range.scene_volume`); ``"features"`` SIFT matches per
        pair (:func:`matching.seeds.disparity_range`).
    outline : bool
        Add outline points (:mod:`matching.contours`): each view's object edge measured
        to sub-pixel where it is a rim (not a grazing contour), its depth from the
        matched surface beside it, so the cloud reaches a rim that area matching stops a
        pixel short of; in views with a mask, or the automatic foreground of a uniform
        background (default True; ``stats["outline_points"]`` counts them).
    silhouettes : bool
        Reject points farther outside a view's automatic foreground (uniform
        background) than their σ allows (the module docstring's silhouette consistency;
        ``outside``; ``stats["silhouette_rejected"]`` counts the matched and outline
        points it removed, ``stats["silhouette_views"]`` the views that had a
        foreground).  Default True; views without a uniform background do not take part.
    """

    chunk_pairs: int = 8
    check_views: int = 2
    max_incidence_deg: float = 60.0
    reject_p: float = 0.999
    require_confirmation: bool = True
    second_order: str = "geometric"
    keep_unchecked: bool | None = None
    sor_neighbours: int = 16
    sor_std: float = 3.0
    pair_options: dict | None = None
    min_covered: float = 0.5
    search: str = "geometry"
    outline: bool = True
    silhouettes: bool = True


_OPTION_KEYS = tuple(f.name for f in fields(MultiViewOptions))


def reconstruct_multiview(images: Sequence, cameras: Sequence[Camera], *,
                          pairs: Sequence[tuple[int, int]] | None = None,
                          map_func: Callable | None = None, workers: int | None = None,
                          masks: Sequence | None = None, roi=None,
                          options: MultiViewOptions | None = None,
                          pair_store: str | None = None,
                          **keywords) -> MultiViewCloud:
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
    masks : sequence of V (H, W) bool or None, optional
        Object masks (:mod:`matching.masks`; None entries: no mask for that view):
        candidates only on the mask, the search volume is the visual hull, and points
        off a mask where they project into its image are dropped (``outside``).
    roi : (2, 3) array_like, optional
        Region of interest, lower and upper world corner: the search volume is cut to it
        and points outside are dropped (``outside``).
    options : MultiViewOptions, optional
        How the views are paired, checked and merged; any of its fields may be given as
        a keyword instead (``check_views=3``), which overrides it.
    pair_store : str, optional
        A folder the pair tasks can write to (this machine's disk): each pair's cloud
        waits there for its consistency check (:class:`StoredPair`), so the memory the
        finished pairs hold is their points and σ, not their covariances and matches.
        Default: a temporary folder when the tasks run on this process's threads
        (``map_func`` not given), else in memory (a remote worker's disk is not ours).
    **keywords
        :class:`MultiViewOptions` fields, and the matching options ``spacing``,
        ``patch``, ``interpolation``, ``min_correlation``, ``sigma0_factor``,
        ``max_iter``, ``shift_stop_px``, ``min_texture_snr``, ``sgbm_block``,
        ``adaptive_patch`` (default False: see :func:`reconstruct_view_pair`),
        ``max_patch``, ``max_sigma_mad_k``, ``eccentric`` (default True here: see
        :func:`reconstruct_view_pair`) (:func:`matching.pair.match_pair`).

    Returns
    -------
    MultiViewCloud
        Identical whatever ``map_func``, ``workers`` and ``chunk_pairs`` (every task is
        deterministic and independent of the others).
    """
    opts = replace(options or MultiViewOptions(),
                   **{k: v for k, v in keywords.items() if k in _OPTION_KEYS})
    match_options = {k: v for k, v in keywords.items() if k not in _OPTION_KEYS}
    cameras = list(cameras)
    workers = default_workers() if workers is None else int(workers)
    masks, roi = _checked_inputs(images, cameras, opts, workers, masks, roi, match_options)
    local_map = thread_map(workers)
    map_func = local_map if map_func is None else map_func
    lazy = bool(getattr(images, "lazy", False))

    def ref(v: int):
        return ViewRef(images, v) if lazy else images[v]

    pairs = select_pairs(cameras, **(opts.pair_options or {})) if pairs is None else [
        (int(a), int(b)) for a, b in pairs]
    if not pairs:
        raise ValueError("cameras: no view pair has a usable baseline-to-depth ratio and "
                         "viewing angle")
    own_store = tempfile.TemporaryDirectory(prefix="photosurf-pairs-") if (
        pair_store is None and map_func is local_map) else None
    store = own_store.name if own_store is not None else pair_store
    try:
        return _reconstruct(cameras, pairs, map_func, local_map, ref, workers, masks, roi,
                            opts, match_options, store)
    finally:
        if own_store is not None:
            own_store.cleanup()


def _reconstruct(cameras: list, pairs: list, map_func: Callable, local_map: Callable,
                 ref: Callable, workers: int, masks, roi, opts: MultiViewOptions,
                 match_options: dict, store: str | None) -> MultiViewCloud:
    """:func:`reconstruct_multiview` after its inputs are checked (steps 1-4)."""
    t0 = time.perf_counter()
    volume = (_search_volume(cameras, masks, roi) if opts.search == "geometry" else None)
    results = map_func(_pair_task, [_pair_item(ref, cameras, masks, volume, match_options, a, b,
                                               store) for a, b in pairs])
    skipped = [r for r in results if isinstance(r, SkippedPair)]
    clouds = [r for r in results if not isinstance(r, SkippedPair)]
    _check_coverage(cameras, [c.pair for c in clouds], skipped, opts.min_covered)
    pairs = [c.pair for c in clouds]
    densify = _densify_stats(clouds)
    t1 = time.perf_counter()
    all_points = np.concatenate([c.points for c in clouds]) if clouds else np.zeros((0, 3))
    median_sigma_pair = (float(np.median(np.concatenate([c.sigma for c in clouds])))
                         if len(all_points) else float("nan"))
    checks, prepared_views = _consistency_checks(clouds, pairs, cameras, all_points, ref,
                                                 local_map, map_func, opts, match_options)
    del all_points
    t2 = time.perf_counter()
    reasons, keep, distances, quantile, n_silhouette = _kept(
        checks, cameras, masks, roi, opts, lambda v: load_image(ref(v)), local_map, workers)
    points, sigma, views, source, factors, offsets = _assembled(checks, keep, pairs,
                                                                len(cameras))
    del checks
    matched_sigma = sigma
    points, sigma, views, source, n_outline, n_outside = _with_outline(
        points, sigma, views, source, cameras, masks, roi, opts.outline, distances, quantile,
        lambda v: load_image(ref(v)), local_map)
    n_silhouette += n_outside
    colours = point_colours(points, views, cameras, lambda v: load_image(ref(v)))
    merged = merge_clouds(points, sigma, views, source, colours,
                          sor_neighbours=opts.sor_neighbours, sor_std=opts.sor_std)
    t3 = time.perf_counter()
    counts, stats = _summary(cameras, pairs, skipped, volume, reasons, keep, factors, offsets,
                             merged, n_outline=n_outline, densify=densify,
                             n_silhouette=n_silhouette, distances=distances,
                             median_sigma_pair=median_sigma_pair, matched_sigma=matched_sigma,
                             prepared_views=prepared_views, workers=workers,
                             times=(t0, t1, t2, t3))
    return MultiViewCloud(points=merged["points"], colours=merged["colours"],
                          sigma=merged["sigma"], views=merged["views"], pair=merged["pair"],
                          pairs=list(pairs), reason_counts=counts, stats=stats)


def _summary(cameras: list, pairs: list, skipped: list, volume, reasons: np.ndarray,
             keep: np.ndarray, factors: list, offsets: list, merged: dict, *, n_outline: int,
             densify: dict, n_silhouette: int, distances: list, median_sigma_pair: float,
             matched_sigma: np.ndarray, prepared_views: int, workers: int,
             times: tuple) -> tuple[dict, dict]:
    """:func:`reconstruct_multiview`'s reason counts and ``stats``."""
    t0, t1, t2, t3 = times
    counts = {REASON_NAMES[c]: int(np.count_nonzero(reasons == c)) for c in REASON_NAMES}
    counts[REASON_NAMES[OUTLIER]] = merged["outliers"]
    is_multi = reasons[keep] == MULTIVIEW
    stats = {
        "views": len(cameras), "pairs": len(pairs), "pairs_skipped": len(skipped),
        "search": "features" if volume is None else volume.source,
        "variance_factor_median": float(np.median(factors)) if factors else 1.0,
        "variance_factor_max": float(np.max(factors)) if factors else 1.0,
        "outside": int(np.count_nonzero(reasons == OUTSIDE)),
        "further_view_offsets": offsets,
        "skipped": [{"pair": list(sp.pair), "views": [cameras[v].name for v in sp.pair],
                     "reason": sp.reason} for sp in skipped],
        "pair_points": int(len(reasons)), "kept_points": int(keep.sum()),
        "outline_points": n_outline, "densify": densify,
        "silhouette_rejected": n_silhouette,
        "silhouette_views": sum(d is not None for d in distances),
        "fused": merged["fused"], "fusion_radius": merged["radius"],
        "points": int(len(merged["points"])),
        "median_sigma_pair": median_sigma_pair,
        "median_sigma_multiview": float(np.median(matched_sigma[is_multi])) if is_multi.any()
        else float("nan"),
        "prepared_views": prepared_views, "workers": workers,
        "pair_seconds": t1 - t0, "consistency_seconds": t2 - t1, "merge_seconds": t3 - t2,
        "seconds_per_pair": (t2 - t0) / len(pairs), "seconds": t3 - t0,
    }
    return counts, stats


def _pair_item(ref: Callable, cameras: list, masks, volume, match_options: dict, a: int,
               b: int, store: str | None = None) -> dict:
    """The task of view pair ``(a, b)`` (:func:`_pair_task`; ``store``: the folder its
    cloud waits in for its check, None: returned whole)."""
    return {"left_image": ref(a), "right_image": ref(b), "left": cameras[a],
            "right": cameras[b], "pair": (a, b), "volume": volume,
            "mask": None if masks is None else masks[a], "options": match_options,
            "store": store}


def _assembled(checks: list, keep: np.ndarray, pairs: list, n_views: int):
    """The kept points of every pair's check in one cloud: ``(points, sigma, views (N, V)
    bool, source pair, variance factors, further views' offsets)``."""
    points = np.concatenate([c.points for c in checks])[keep]
    sigma = np.concatenate([c.sigma for c in checks])[keep]
    views = np.unpackbits(np.concatenate([c.views for c in checks])[keep], axis=1,
                          count=n_views).astype(bool)
    source = np.concatenate([np.full(len(c.reason), p, np.int64)
                             for p, c in enumerate(checks)])[keep]
    factors = [c.variance_factor for c in checks]
    offsets = [{"pair": list(pr), "view": int(k), "offset_px": [float(v) for v in b]}
               for pr, c in zip(pairs, checks, strict=True) for k, b in c.offsets.items()]
    return points, sigma, views, source, factors, offsets


def _kept(checks: list, cameras: list, masks, roi, opts: MultiViewOptions, image: Callable,
          local_map: Callable, workers: int):
    """Which checked points are kept: confirmed in a further view (or unchecked, with
    ``keep_unchecked``), inside the masks and the ``roi``, and not outside a view's
    automatic foreground by more than their σ allows.  Returns ``(reasons, keep,
    foreground distances per view, the σ quantile, points left out by the silhouettes)``."""
    reasons = np.concatenate([c.reason for c in checks]) if checks else np.zeros(0, np.int8)
    keep_unchecked = len(cameras) < 3 if opts.keep_unchecked is None else opts.keep_unchecked
    keep = np.isin(reasons, (MULTIVIEW, PAIR_ONLY) if keep_unchecked else (MULTIVIEW,))
    if masks is not None or roi is not None:
        all_pts = np.concatenate([c.points for c in checks])
        out = np.zeros(len(keep), bool)
        out[keep] = ~_inside_object(all_pts[keep], cameras, masks, roi)
        reasons = np.where(out, OUTSIDE, reasons).astype(reasons.dtype)
        keep &= ~out
        del all_pts
    # per view on the worker threads (OpenCV's distance transform and PNG decoding
    # release the GIL): this tail ran on one core
    distances = (_foreground_distances(len(cameras), image, local_map)
                 if opts.silhouettes else [None] * len(cameras))
    quantile = float(norm.ppf(0.5 + 0.5 * opts.reject_p))
    n_silhouette = 0
    if any(d is not None for d in distances):
        idx = np.flatnonzero(keep)
        off = ~_near_foreground(np.concatenate([c.points for c in checks])[idx],
                                np.concatenate([c.sigma for c in checks])[idx], cameras,
                                distances, quantile, local_map, workers)
        reasons[idx[off]] = OUTSIDE
        keep[idx[off]] = False
        n_silhouette = int(off.sum())
    return reasons, keep, distances, quantile, n_silhouette


def _checked_inputs(images: Sequence, cameras: list, opts: MultiViewOptions, workers: int,
                    masks, roi, match_options: dict):
    """:func:`reconstruct_multiview`'s inputs checked (a ValueError naming the first
    problem); returns ``(masks, roi)`` as lists / arrays."""
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
    if int(opts.check_views) < 1:
        raise ValueError(f"check_views must be >= 1, got {opts.check_views}")
    if opts.second_order not in SECOND_ORDER_MODES:
        raise ValueError(f"second_order must be one of {SECOND_ORDER_MODES}, "
                         f"got {opts.second_order!r}")
    if not 0.0 < opts.max_incidence_deg < 90.0:
        raise ValueError(f"max_incidence_deg must lie in (0, 90), got "
                         f"{opts.max_incidence_deg}")
    if not 0.0 < opts.reject_p < 1.0:
        raise ValueError(f"reject_p must lie in (0, 1), got {opts.reject_p}")
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    if not 0.0 <= opts.min_covered <= 1.0:
        raise ValueError(f"min_covered must lie in [0, 1], got {opts.min_covered}")
    if int(opts.chunk_pairs) < 1:
        raise ValueError(f"chunk_pairs must be >= 1, got {opts.chunk_pairs}")
    if opts.search not in SEARCH_MODES:
        raise ValueError(f"search must be one of {SEARCH_MODES}, got {opts.search!r}")
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
    return masks, roi


def _consistency_checks(clouds: list, pairs: list, cameras: list, all_points: np.ndarray,
                        ref: Callable, local_map: Callable, map_func: Callable,
                        opts: MultiViewOptions, match_options: dict) -> tuple[list, int]:
    """Every pair's points checked in its further views (:func:`check_consistency`),
    ``chunk_pairs`` pairs at a time, each chunk's views prepared once (grey image and
    z-buffer of ``all_points``) and dropped when no later chunk needs them; the pairs'
    clouds are released as they are checked.  Returns ``(checks, prepared views)``."""
    patch = int(match_options.get("patch", 15))
    spacing = int(match_options.get("spacing", DEFAULT_SPACING))
    window = 2 * spacing + 1
    interpolation = match_options.get("interpolation", DEFAULT_INTERPOLATION)
    options = {"check_views": opts.check_views, "patch": patch, "spacing": spacing,
               "interpolation": interpolation,
               "max_incidence_deg": opts.max_incidence_deg, "reject_p": opts.reject_p,
               "require_confirmation": opts.require_confirmation,
               "second_order": opts.second_order,
               **{k: v for k, v in match_options.items() if k in LSM_KEYS}}
    near = [further_views(cameras, pr, 2 * opts.check_views + 2, opts.max_incidence_deg)
            for pr in pairs]
    chunks = [range(s, min(s + int(opts.chunk_pairs), len(pairs)))
              for s in range(0, len(pairs), int(opts.chunk_pairs))]
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
    return checks, prepared_views


def _with_outline(points: np.ndarray, sigma: np.ndarray, views: np.ndarray,
                  source: np.ndarray, cameras: list, masks, roi, outline: bool,
                  distances: list, quantile: float, image: Callable, local_map: Callable):
    """The matched points with the outline points added (:func:`_outline_points`; those
    outside a view's foreground by more than their σ allows left out): ``(points, sigma,
    views, source, outline points added, outline points left out)``."""
    n_outline, n_outside = 0, 0
    if outline and len(points):
        extra = _outline_points(cameras, masks, roi, points, sigma, image, local_map)
        if len(extra) and any(d is not None for d in distances):
            near = near_foreground(extra.points, extra.sigma, cameras, distances, quantile)
            n_outside = int(np.count_nonzero(~near))
            extra = extra.take(near)
        n_outline = len(extra)
        if n_outline:
            points = np.vstack([points, extra.points])
            sigma = np.concatenate([sigma, extra.sigma])
            seen = views[extra.neighbour].copy()  # the surface beside it, and its view
            seen[np.arange(n_outline), extra.view] = True
            views = np.vstack([views, seen])
            source = np.concatenate([source, -1 - extra.view])  # fused across views
    return points, sigma, views, source, n_outline, n_outside
