r"""Multi-image consistency: a pair's points confirmed in further views by LSM (MPGC spirit).

In the spirit of MPGC (Gruen & Baltsavias 1988 [1]_).  Every pair point :math:`X` is
projected into the further views :math:`k`.  It is *visible* in :math:`k` when it lies in
front of the camera, inside the image by the LSM half-patch plus 3 px, the surface
normal faces :math:`k` within ``max_incidence_deg``, and it passes the depth test
against every pair's points (:func:`matching.visibility.zbuffer`).  The template of the
pair's left view is then LSM-matched into the ``check_views`` visible views nearest to
it, starting from the reprojection :math:`\pi_k(X)` and the local-plane mapping
(:func:`matching.visibility.plane_affine`), with fixed second-order warp terms fitted to
the neighbours' local-plane mappings.  A shift :math:`b_k` common to the pair's matches
in view k (the median of :math:`x_k - \pi_k(X)`, taken when it exceeds twice their
scatter: an orientation error of view k or of the pair, :func:`_systematic_offset`) is
estimated from the accepted matches, LSM restarted from :math:`\pi_k(X) + b_k` until
it settles, and removed from the matches.  Windows the free 2-D LSM loses (pulled
away or not converged: one-dimensional texture) are matched again with the shift held
to the epipolar line of the template ray in view k (the geometric constraint of [1]_,
:func:`_match_along_epipolar`).  A match is *consistent* when the Mahalanobis
distance of :math:`x_k - b_k` from :math:`\pi_k(X)`, with covariance
:math:`s^2 (J_k \Sigma_X J_k^T + \Sigma_{LSM})`, passes the :math:`\chi^2_2` test at
``reject_p``; :math:`s^2` is the pair's a-posteriori variance factor
(:func:`matching.precision.variance_factor`, Förstner 1979 [2]_: on real photographs
LSM's σ is several times optimistic).  Points with at least one consistent further view
are triangulated from all their views (:func:`matching.triangulate.triangulate_multiview`).

References
----------
.. [1] A. Gruen, E. Baltsavias, "Geometrically constrained multiphoto matching",
   Photogrammetric Engineering and Remote Sensing 54(5), 633-641 (1988).
.. [2] W. Förstner, "Ein Verfahren zur Schätzung von Varianz- und Kovarianzkomponenten",
   Allgemeine Vermessungs-Nachrichten 86, 446-453 (1979).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from scipy.stats import chi2

from checks.robust import MAD_TO_SIGMA
from matching.cameras import Camera
from matching.lsm import DEFAULT_INTERPOLATION, PreparedImage, Status, lsm_match, prepare_image
from matching.precision import variance_factor
from matching.scheduler import check_stop
from matching.second_order import second_order_terms
from matching.seeds import DEFAULT_SPACING
from matching.triangulate import triangulate_multiview
from matching.validate import TOL
from matching.view_pairs import further_views
from matching.visibility import normals as _normals
from matching.visibility import plane_affine as _plane_affine
from matching.visibility import project as _project

if TYPE_CHECKING:
    from matching.multiview import PairCloud

__all__ = ["REASON_NAMES", "SECOND_ORDER_MODES", "Consistency", "check_consistency",
           "variance_factor"]

MULTIVIEW, PAIR_ONLY, NO_FURTHER_MATCH, INCONSISTENT, TRIANGULATION, OUTLIER, OUTSIDE = \
    range(7)
#: Reason code -> name (:mod:`matching.multiview`'s docstring).
REASON_NAMES = {MULTIVIEW: "multiview", PAIR_ONLY: "pair_only",
                NO_FURTHER_MATCH: "no_further_match", INCONSISTENT: "inconsistent",
                TRIANGULATION: "triangulation", OUTLIER: "outlier", OUTSIDE: "outside"}
#: Where a further view's second-order warp terms come from (:func:`check_consistency`).
SECOND_ORDER_MODES = ("geometric", "matched")
#: Image margin beyond the LSM half-patch for a further view, px (interpolation support).
_BORDER_PX = 3
#: Options passed on to :func:`matching.lsm.lsm_match`.
#: Further-view matches needed to estimate a systematic offset (:func:`_systematic_offset`).
_OFFSET_MIN_COUNT = 30
#: A systematic offset is taken when larger than this many scatters of one offset.
_OFFSET_SCATTERS = 2.0
#: LSM passes per further view at most while the systematic offset moves, and the
#: change below which it has settled, px.
_OFFSET_PASSES = 3
_OFFSET_STOP_PX = 0.1
#: LSM outcomes matched again along the epipolar line (:func:`_match_along_epipolar`).
_LOST = (Status.PULL_IN, Status.NO_CONVERGENCE)
LSM_KEYS = ("max_iter", "shift_stop_px", "sigma0_factor", "min_correlation",
            "min_texture_snr")


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
    lsm = {k: options[k] for k in LSM_KEYS if k in options}
    res = lsm_match(template, search, points[idx], approx, patch=int(options.get("patch", 15)),
                    interpolation=options.get("interpolation", DEFAULT_INTERPOLATION),
                    direction=direction, initial=init, quadratic=quad[idx],
                    offset=None if offset is None else offset[idx], **lsm)
    return res.accepted, res.position, res.cov

def _initial(approx: np.ndarray, affine: np.ndarray) -> np.ndarray:
    """(M, 8) LSM start ``a0 a1 a2 b0 b1 b2 r0 r1``: ``approx`` (M, 2), the local-plane
    ``affine`` (M, 2, 2), no radiometric change."""
    init = np.zeros((len(approx), 8))
    init[:, [0, 3]] = approx
    init[:, [1, 2]] = affine[:, 0]
    init[:, [4, 5]] = affine[:, 1]
    init[:, 7] = 1.0
    return init


def _match_further(template, search, centres, approx, affine, offset, quad, second_order,
                   patch, interpolation, lsm_options):
    """LSM of the template windows into a further view from ``approx`` and the
    local-plane affine: ``(accepted (M,) bool, position (M, 2), cov (M, 2, 2),
    LSMResult)``."""
    res = lsm_match(template, search, centres, approx, patch=patch,
                    interpolation=interpolation, initial=_initial(approx, affine),
                    offset=offset, quadratic=quad, **lsm_options)
    ok, position, lsm_cov = res.accepted, res.position, res.cov
    if second_order == "matched":  # a second pass with the matched field's terms
        refined = _second_order_pass(
            template, search, centres, res.affine, res.radiometric, ok,
            res.affine[ok][:, [0, 3]], None,
            {"patch": patch, "interpolation": interpolation, **lsm_options}, offset=offset)
        if refined is not None:
            good, pos2, cov2 = refined
            sub = np.flatnonzero(ok)
            ok = np.zeros_like(ok)
            ok[sub[good]] = True
            position, lsm_cov = position.copy(), lsm_cov.copy()
            position[sub[good]], lsm_cov[sub[good]] = pos2[good], cov2[good]
    return ok, position, lsm_cov, res


def _match_along_epipolar(template, search, centres, approx, affine, offset, quad,
                          direction, patch, interpolation, lsm_options, first):
    """The windows a free LSM lost (pulled away, not converged), matched again with the
    shift held to the epipolar line of the template ray in view k (MPGC's geometric
    constraint [1]_): ``(accepted, position, cov)`` as :func:`_match_further`.

    A window on one-dimensional texture (a column's flutes, a moulding) leaves a free
    2-D shift undetermined along the texture, and LSM slides away from a good start
    (temple ring: the lost windows' correlation at the start is a median 0.7-0.87 in
    the views whose cameras agree).  Along the epipolar line the point's depth is the
    one unknown.  The σ0 tests take the first pass's accepted matches as population
    (``first``: its LSMResult), so a small batch is judged like the whole view.
    """
    good = first.accepted
    res = lsm_match(template, search, centres, approx, patch=patch,
                    interpolation=interpolation, initial=_initial(approx, affine),
                    offset=offset,
                    quadratic=quad, direction=direction,
                    sigma0_population=first.sigma0[good],
                    population_grad_power=first.grad_power[good], **lsm_options)
    return res.accepted, res.position, res.cov


def _systematic_offset(d: np.ndarray) -> np.ndarray:
    """(2,) systematic part of a further view's match offsets ``d`` (M, 2), px.

    The component-wise median of the matched positions minus the reprojections, when
    at least ``_OFFSET_MIN_COUNT`` matches give it and it exceeds ``_OFFSET_SCATTERS``
    times the robust scatter of one offset (1.4826 MAD per axis, summed in quadrature);
    zero otherwise.  A shift common to all of a pair's points in view k is an
    orientation error of view k or of the pair (the temple ring's given cameras: a
    view of one latitude (views 0-10, 11-15) checking a pair of the other sits ~1.2 px
    off, a short-baseline pair's points 2.4-3.5 px in its further views), not a
    matching error; larger than the matching scatter it
    decides the χ² test and the pull-in range instead of the matching.  Two scatters:
    ~98 % of the matches (Φ(2) for a normal scatter) are displaced the same way, a
    common cause; on the temple ring the camera offsets measure 2-5 scatters, while the
    largest median on the rendered 24-view 320x240 ring (exact cameras,
    ``benchmarks/multiview.py --quick``) is 1.1 scatters (cause not measured: a bias of
    those pair points, not of a camera, which the test must keep seeing).  Such a median is
    significant by far (its standard error is 1.25 scatters / sqrt(M)).
    """
    if len(d) < _OFFSET_MIN_COUNT:
        return np.zeros(2)
    median = np.median(d, axis=0)
    scatter = MAD_TO_SIGMA * np.median(np.abs(d - median), axis=0)
    if float(median @ median) <= _OFFSET_SCATTERS**2 * float(scatter @ scatter):
        return np.zeros(2)
    return median


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
    offsets : dict int -> (2,) float64
        The systematic offset, px, of each further view where one was found
        (:func:`_systematic_offset`; views without one are absent).
    """

    points: np.ndarray
    cov: np.ndarray
    sigma: np.ndarray
    reason: np.ndarray
    views: np.ndarray
    checked: np.ndarray
    seconds: float = 0.0
    variance_factor: float = 1.0
    offsets: dict = field(default_factory=dict)


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


def _match_view(cloud: PairCloud, camera: Camera, image: PreparedImage,
                template: PreparedImage, idx: np.ndarray, x_pred: np.ndarray,
                normals: np.ndarray, centres: np.ndarray, offset: np.ndarray, eccentric: bool,
                second_order: str, patch: int, interpolation: str, epipolar: bool,
                lsm_options: dict):
    """The points ``idx`` of a pair matched by LSM in one further view (``camera``,
    ``image``) and tested against their reprojections ``x_pred`` (:func:`check_consistency`).

    Returns ``(idx, ok, position, lsm_cov, d2, bias)``: the points with a finite
    local-plane mapping, which of them LSM matched, their positions in the view (the
    view's systematic offset ``bias`` taken off) and LSM covariances, and the squared
    Mahalanobis distances of the matches from the reprojections.
    """
    cam_t = cloud.cameras[0]
    affine = _plane_affine(cam_t, camera, cloud.x_template[idx], cloud.points[idx],
                           normals[idx])
    good_aff = np.all(np.isfinite(affine), axis=(1, 2))
    idx, affine = idx[good_aff], affine[good_aff]
    # the window centre's approximation: the point's, moved along the tangent plane
    approx = x_pred[idx] + np.einsum("mij,mj->mi", affine, offset[idx])
    off = -offset[idx] if eccentric else None
    quad = None
    if second_order == "geometric":  # the terms of the local-plane mappings' field
        aff6 = np.zeros((len(idx), 6))
        aff6[:, [1, 2]], aff6[:, [4, 5]] = affine[:, 0], affine[:, 1]
        quad = second_order_terms(centres[idx], aff6, radius_px=1.5 * patch)
    _, jac = _project(camera, cloud.points[idx], with_jacobian=True)
    s_pred = jac @ cloud.cov[idx] @ np.swapaxes(jac, 1, 2)
    s_pred += TOL.match_cov_floor_px**2 * np.eye(2)
    # the view's systematic offset (an orientation error of view k or of the pair,
    # _systematic_offset): LSM is started from the reprojection moved by it, and
    # matched again while the estimate moves (at most _OFFSET_PASSES passes)
    start_bias = np.zeros(2)
    for _ in range(_OFFSET_PASSES):
        check_stop()  # an interrupted run ends between LSM passes
        ok, position, lsm_cov, first = _match_further(
            template, image, centres[idx], approx + start_bias, affine, off, quad,
            second_order, patch, interpolation, lsm_options)
        bias = _systematic_offset(position[ok] - x_pred[idx][ok])
        if np.all(np.abs(bias - start_bias) <= _OFFSET_STOP_PX):
            break
        start_bias = bias
    lost = np.flatnonzero(np.isin(first.status, _LOST))
    if epipolar and len(lost):
        # the template ray's image in k: its direction at the point, J_k d (none
        # where view k's centre lies on the ray)
        _, ray = cam_t.ray(centres[idx[lost]])
        direction = np.einsum("mij,mj->mi", jac[lost], ray)
        along = np.linalg.norm(direction, axis=1) > TOL.zero
        lost, direction = lost[along], direction[along]
    if epipolar and len(lost):
        q = None if quad is None else quad[lost]
        ok2, pos2, cov2 = _match_along_epipolar(
            template, image, centres[idx[lost]], approx[lost] + bias,
            affine[lost], None if off is None else off[lost], q, direction, patch,
            interpolation, lsm_options, first)
        ok, position, lsm_cov = ok.copy(), position.copy(), lsm_cov.copy()
        ok[lost], position[lost], lsm_cov[lost] = ok2, pos2, cov2
    s_pred = s_pred + lsm_cov
    d = position - x_pred[idx] - bias
    with np.errstate(invalid="ignore"):
        d2 = np.einsum("mi,mij,mj->m", d, np.linalg.inv(np.where(
            np.isfinite(s_pred), s_pred, np.eye(2))), d)
    return idx, ok, position - bias, lsm_cov, d2, bias


def _further_views(cameras: Sequence[Camera], images: dict, pair: tuple[int, int],
                   max_incidence_deg: float) -> list[int]:
    """The views a pair's points may be checked in, nearest the template view first:
    ``view_pairs.further_views`` (not facing away from the template view) of those with
    an image."""
    return [k for k in further_views(cameras, pair, len(cameras), max_incidence_deg)
            if k in images]


def _pair_variance_factor(tests: list) -> float:
    """The a-posteriori variance factor of the pair's matches (Förstner 1979), from the
    further views' tests of :func:`check_consistency`.

    On real images LSM's σ is several times optimistic (correlated noise, blur, shading),
    and the χ² tests would then reject correct matches.  The median Mahalanobis distance of
    each further view's matches estimates it robustly; the smallest over the views is
    taken: a view whose camera disagrees with the pair's (temple ring: views 5 and 14 sit a
    systematic ~1.4 px off every other pair's points) must not widen the test for itself.
    Never below 1 (rendered scenes: the σ are right).
    """
    return min([variance_factor(t[5][t[2]]) for t in tests if t[2].sum() >= 30],
               default=1.0)


def _retriangulated(cloud: PairCloud, cameras: Sequence[Camera], others: list[int],
                    tests: list, factor: float, bound: float, views: np.ndarray,
                    reason: np.ndarray, tried: np.ndarray, matched: np.ndarray,
                    reject_p: float):
    """The further views' matches within ``bound · factor`` of their reprojections taken as
    observations (``views``, ``reason`` filled in place), and the points they confirm
    triangulated again from all their views: ``(points, cov, sigma)``
    (:func:`check_consistency`)."""
    i, j = cloud.pair
    m = len(cloud)
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
    confirmed = np.zeros(m, np.int64)
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
    return points, pcov, sigma


def check_consistency(cloud: PairCloud, cameras: Sequence[Camera], images: dict,
                      zbuffers: dict, template: PreparedImage, *, check_views: int = 2,
                      patch: int = 15,
                      spacing: int = DEFAULT_SPACING,
                      interpolation: str = DEFAULT_INTERPOLATION,
                      max_incidence_deg: float = 60.0, reject_p: float = 0.999,
                      require_confirmation: bool = True, second_order: str = "geometric",
                      epipolar: bool = True, **lsm_options) -> Consistency:
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
        parameters of a first, affine-only LSM pass and matches again (the figures:
        ``docs/decisions/multiview-acquisition.md``).
    epipolar : bool
        Match the windows a free LSM lost (``pull_in``, ``no_convergence``) again along
        the epipolar line (:func:`_match_along_epipolar`; default True).
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
    views = np.zeros((m, n_views), bool)
    views[:, [i, j]] = True
    reason = np.full(m, PAIR_ONLY, np.int8)
    if m == 0:
        return Consistency(cloud.points, cloud.cov, cloud.sigma, reason, views,
                           np.zeros(0, np.int64), time.perf_counter() - start)
    normals = _normals(cloud.points, cameras[i].center)
    window = 2 * spacing + 1
    others = _further_views(cameras, images, (i, j), max_incidence_deg)
    tried = np.zeros(m, np.int64)
    matched = np.zeros(m, bool)
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
    offsets = {}  # per further view with a systematic offset: that offset, px
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
        idx, ok, position, lsm_cov, d2, bias = _match_view(
            cloud, cameras[k], images[k], template, idx, x_pred, normals, centres, offset,
            eccentric, second_order, patch, interpolation, epipolar, lsm_options)
        if np.any(bias):
            offsets[k] = bias
        matched[idx[ok]] = True
        tests.append((k, idx, ok, position, lsm_cov, d2))
    factor = _pair_variance_factor(tests)
    points, pcov, sigma = _retriangulated(cloud, cameras, others, tests, factor, bound, views,
                                          reason, tried, matched, reject_p)
    if not require_confirmation:
        reason[reason == NO_FURTHER_MATCH] = PAIR_ONLY
    return Consistency(points, pcov, sigma, reason, views, tried,
                       time.perf_counter() - start, factor, offsets)

