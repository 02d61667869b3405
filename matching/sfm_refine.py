r"""Tie-point refinement of an SfM reconstruction by least-squares matching.

SIFT keypoints are located independently in every image, to about 0.2 px on
real photographs (scale-space extrema; the affine shape of a keypoint is not
used for its position).  On a small object seen from far away a rotation
error of a camera trades against a sideways shift of its centre, and only
precise, consistent tie points separate the two.  Each track of the
reconstruction is therefore re-measured by least-squares matching [1]_
(:func:`matching.lsm.lsm_match`: affine + radiometric Gauss-Newton): one
observation of the track is the reference (the one whose viewing ray is
closest to the track's mean ray), its keypoint is rounded to the pixel grid
and its patch matched into every other observation's image, with the affine
start taken from the geometry: the plane through the 3D point
:math:`X` whose normal bisects the two viewing rays,

.. math::  x_j(x) = \pi_j\big(c_r + \lambda(x)\, d_r(x)\big),\qquad
           \lambda(x) = \frac{n^T (X - c_r)}{n^T d_r(x)},

linearised at the reference pixel (``d_r`` the ray of pixel ``x`` of the
reference view, ``c_r`` its centre).  The geometry, not an identity start,
carries views turned 90° or 180° against each other.  Observations LSM rejects
leave the track; the bundle adjustment [2]_ (pycolmap) then runs again on the
re-measured tracks.

References
----------
.. [1] A. W. Gruen, "Adaptive least squares correlation: a powerful image
   matching technique", S. Afr. J. Photogramm. Remote Sens. Cartogr. 14(3),
   175-187 (1985).
.. [2] B. Triggs, P. McLauchlan, R. Hartley, A. Fitzgibbon, "Bundle
   Adjustment -- A Modern Synthesis", Vision Algorithms: Theory and Practice,
   LNCS 1883 (2000).
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np

from matching.cameras import cameras_from_pycolmap
from matching.colmap_log import quiet_colmap
from matching.visibility import plane_affine

__all__ = ["refine_tracks_lsm", "bundle_adjust"]

log = logging.getLogger(__name__)

#: COLMAP's pixel origin is the top-left pixel's corner, OpenCV's its centre.
_COLMAP_SHIFT = 0.5


def _observations(reconstruction):
    """Flat arrays of every track element: point id, image id, point2D index, xy (OpenCV)."""
    pid, iid, p2d, xy = [], [], [], []
    for k, point in reconstruction.points3D.items():
        for element in point.track.elements:
            pid.append(k)
            iid.append(element.image_id)
            p2d.append(element.point2D_idx)
            xy.append(reconstruction.images[element.image_id].points2D[element.point2D_idx].xy)
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2) - _COLMAP_SHIFT
    return (np.asarray(pid, np.int64), np.asarray(iid, np.int64), np.asarray(p2d, np.int64), xy)


def refine_tracks_lsm(reconstruction, image_dir: str | os.PathLike, patch: int = 15,
                      max_shift_px: float | None = None) -> dict:
    """Re-measure every track of a reconstruction by LSM against a reference observation.

    Parameters
    ----------
    reconstruction : pycolmap.Reconstruction
        Modified in place: the observations' xy are replaced by their LSM
        positions; observations LSM rejects are deleted, and points left with
        fewer than two observations.
    image_dir : path
        Folder of the reconstruction's images (by their names).
    patch : int
        Odd LSM patch side, px.
    max_shift_px : float, optional
        Reject an LSM position farther than this from its keypoint (moved with the
        reference's rounding).  Default: 5x the reconstruction's mean reprojection
        error, at least 0.5 px -- a keypoint is that precise, so a match that slid
        farther (along an edge, onto the background) is a different point; along the
        epipolar line such a slide would only move a two-view point in depth, which
        the bundle adjustment's residuals cannot show.

    Returns
    -------
    dict
        ``observations`` (before), ``matched`` (non-reference observations
        accepted), ``share_accepted``, ``median_shift_px`` (accepted positions
        against their keypoints, the reference's rounding included),
        ``points_removed``.
    """
    from matching.lsm import lsm_match

    pid, iid, p2d, xy = _observations(reconstruction)
    if max_shift_px is None:
        max_shift_px = max(0.5, 5.0 * float(reconstruction.compute_mean_reprojection_error()))
    if not len(pid):
        return {"observations": 0, "matched": 0, "share_accepted": 0.0,
                "median_shift_px": float("nan"), "points_removed": 0}
    names = {i: reconstruction.images[i].name for i in np.unique(iid)}
    by_name = {c.name: c for c in cameras_from_pycolmap(reconstruction)}
    cams = {i: by_name[n] for i, n in names.items()}
    X = np.array([reconstruction.points3D[k].xyz for k in pid]).reshape(-1, 3)
    centres = np.stack([cams[i].center for i in iid])
    ray = centres - X
    ray /= np.linalg.norm(ray, axis=1, keepdims=True)

    upid, inv, ref, is_ref = _references(pid, ray)
    p_ref = np.rint(xy[ref])
    groups, approx, init = _affine_starts(cams, iid, ref, is_ref, X, ray, xy, p_ref)
    prepared = _prepare(image_dir, names)
    new = np.full_like(xy, np.nan)
    new[is_ref] = p_ref[is_ref]
    for m in groups:
        i, j = int(iid[ref[m[0]]]), int(iid[m[0]])
        result = lsm_match(prepared[i], prepared[j], p_ref[m], approx[m], patch=patch,
                           initial=init[m], max_shift_px=max_shift_px)
        ok = result.accepted
        new[m[ok]] = result.position[ok]
    matched = np.zeros(len(upid), np.int64)
    np.add.at(matched, inv, np.isfinite(new[:, 0]) & ~is_ref)
    new[is_ref & (matched[inv] == 0)] = np.nan
    good = np.isfinite(new[:, 0])

    images = reconstruction.images
    for k in np.flatnonzero(good):
        images[int(iid[k])].points2D[int(p2d[k])].xy = new[k] + _COLMAP_SHIFT
    before = reconstruction.num_points3D()
    bad = np.flatnonzero(~good)
    _delete(reconstruction, pid[bad], iid[bad], p2d[bad])
    removed = before - reconstruction.num_points3D()
    others = ~is_ref
    report = {"observations": int(len(pid)), "matched": int(np.sum(good & others)),
              "share_accepted": float(np.mean(good[others])) if others.any() else 0.0,
              "median_shift_px": float(np.median(np.linalg.norm(new[good] - xy[good], axis=1)))
              if good.any() else float("nan"),
              "points_removed": removed, "max_shift_px": float(max_shift_px)}
    log.info("LSM tie points: %d of %d observations re-measured (%.1f %%), %d points removed",
             report["matched"], int(others.sum()), 100 * report["share_accepted"], removed)
    return report


def _references(pid: np.ndarray, ray: np.ndarray) -> tuple:
    """The reference of each track: its observation whose ray is closest to the track's
    mean ray.  ``(upid, inv, ref, is_ref)``: the tracks, each observation's track, its
    reference observation, and whether it is one."""
    upid, inv = np.unique(pid, return_inverse=True)
    mean = np.zeros((len(upid), 3))
    np.add.at(mean, inv, ray)
    mean /= np.maximum(np.linalg.norm(mean, axis=1, keepdims=True), 1e-300)
    score = np.sum(ray * mean[inv], axis=1)
    order = np.lexsort((-score, inv))
    first = np.r_[True, inv[order][1:] != inv[order][:-1]]
    ref_of = np.empty(len(upid), np.int64)
    ref_of[inv[order][first]] = order[first]
    ref = ref_of[inv]
    return upid, inv, ref, ref == np.arange(len(pid))


def _affine_starts(cams: dict, iid, ref, is_ref, X, ray, xy, p_ref) -> tuple:
    """LSM's start of each non-reference observation: the affine map of the plane through
    its point whose normal bisects its ray and its reference's, the reference keypoint
    moved to the pixel grid (``p_ref``) and its partner moved with it.  ``(groups, approx,
    init)``: the observations grouped by (reference view, view), their approximate
    positions ``(N, 2)`` and LSM's initial parameters ``(N, 8)``."""
    normal = ray + ray[ref]
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
    pair = iid[ref] * (int(iid.max()) + 1) + iid
    # observations grouped by (reference view, view): one sort instead of a scan per pair
    others = np.flatnonzero(~is_ref)
    codes, inverse = np.unique(pair[others], return_inverse=True)
    groups = np.split(others[np.argsort(inverse, kind="stable")],
                      np.cumsum(np.bincount(inverse, minlength=len(codes)))[:-1])
    A = np.zeros((len(iid), 2, 2))
    for m in groups:
        ci, cj = cams[int(iid[ref[m[0]]])], cams[int(iid[m[0]])]
        # the Jacobian at the point's own projection (a plane's homography is smooth on
        # the sub-pixel scale that separates it from the reference keypoint)
        A[m] = plane_affine(ci, cj, ci.project(X[m]), X[m], normal[m])
    # the reference keypoint moved to the pixel grid: move its partners with the affine map
    approx = xy + np.einsum("nij,nj->ni", A, p_ref - xy[ref])
    init = np.zeros((len(iid), 8))
    init[:, 0], init[:, 3] = approx[:, 0], approx[:, 1]
    init[:, 1], init[:, 2], init[:, 4], init[:, 5] = A[:, 0, 0], A[:, 0, 1], A[:, 1, 0], A[:, 1, 1]
    init[:, 7] = 1.0
    return groups, approx, init


#: Points seen under a smaller angle are dropped after each adjustment: COLMAP's
#: mapper's ``filter_min_tri_angle`` (degrees); their depth is not determined,
#: so a two-view point can slide far out along its rays without a residual.
MIN_TRIANGULATION_ANGLE_DEG = 1.5


def _prepare(image_dir, names: dict) -> dict:
    from matching.image_file import imread, to_uint8
    from matching.lsm import prepare_image
    from matching.masks import grey

    image_dir = Path(image_dir)
    prepared = {}
    for i, name in names.items():
        # upright, as COLMAP read them: run_sfm gives it upright copies of EXIF-turned images
        image = imread(image_dir / name)
        if image is None or image.ndim not in (2, 3):
            raise ValueError(f"{image_dir / name}: not a readable image")
        prepared[i] = prepare_image(grey(to_uint8(image, str(image_dir / name))))
    return prepared


def bundle_adjust(reconstruction, refine_intrinsics: bool = True, rounds: int = 2,
                  reject_k: float = 3.72) -> dict:
    """Global bundle adjustment in place (pycolmap), the principal point held, with outlier rounds.

    After each adjustment the observations whose reprojection error exceeds
    ``reject_k`` σ are deleted and the adjustment repeated; σ is the robust
    per-axis σ of the residuals, median(|v|) / sqrt(2 ln 2) (|v| of a 2-D normal
    error is Rayleigh-distributed), scaled by sqrt(n / (n - u)) (n residuals, u
    unknowns: 3 per point, 6 per image, less the 7 of the gauge) -- a residual is
    smaller than the error it comes from by the redundancy, and two-view points
    keep little of it; k = 3.72 is the 99.9 % quantile of
    sqrt(χ²₂) — a wrong LSM match converged on the wrong texture, not noise.
    Points whose rays meet at less than ``MIN_TRIANGULATION_ANGLE_DEG`` (or
    behind a camera) are deleted too.

    Parameters
    ----------
    reconstruction : pycolmap.Reconstruction
    refine_intrinsics : bool
        Refine focal length and distortion (as COLMAP's mapper does); False
        holds every intrinsic parameter (known camera matrix).
    rounds : int
        Outlier-rejection rounds after the first adjustment.
    reject_k : float

    Returns
    -------
    dict
        ``rejected`` observations, ``sigma_px`` (last round), ``converged``.
    """
    import pycolmap

    options = pycolmap.BundleAdjustmentOptions()
    options.refine_focal_length = refine_intrinsics
    options.refine_extra_params = refine_intrinsics
    options.refine_principal_point = False
    options.print_summary = False
    options.ceres.solver_options.max_num_iterations = 500
    rejected, sigma, converged = 0, float("nan"), False
    for round_ in range(rounds + 1):
        with quiet_colmap():  # COLMAP/Ceres log lines ("Global bundle adjustment") on fd 2
            summary = pycolmap.bundle_adjustment(reconstruction, options)
        converged = _converged(summary)
        pid, iid, p2d, xy = _observations(reconstruction)
        if not len(pid):
            break
        err, angle, behind = _residuals(reconstruction, pid, iid, xy)
        # residuals are smaller than the errors by the redundancy: σ² = Σv²/(n - u)
        n_res = 2 * len(pid)
        unknowns = 3 * len(np.unique(pid)) + 6 * len(np.unique(iid)) - 7
        sigma = float(np.median(err) / np.sqrt(2 * np.log(2))
                      * np.sqrt(n_res / max(n_res - unknowns, 1)))
        weak = np.isin(pid, np.unique(pid[behind | (angle < MIN_TRIANGULATION_ANGLE_DEG)]))
        if round_ == rounds:  # the poses stay; undetermined points are not returned
            reconstruction_points = np.unique(pid[weak])
            for point in reconstruction_points.tolist():
                reconstruction.delete_point3D(point)
            break
        bad = np.flatnonzero((err > reject_k * sigma) | weak)
        if not len(bad):
            break
        rejected += _delete(reconstruction, pid[bad], iid[bad], p2d[bad])
    return {"rejected": rejected, "sigma_px": sigma, "converged": converged}


def _converged(summary) -> bool:
    term = getattr(summary, "termination_type", None)
    return term is None or "NO_CONVERGENCE" not in str(term)


def _residuals(reconstruction, pid, iid, xy):
    """Per observation: reprojection error (px), its track's triangulation angle (deg), behind."""
    by_name = {c.name: c for c in cameras_from_pycolmap(reconstruction)}
    X = np.array([reconstruction.points3D[k].xyz for k in pid]).reshape(-1, 3)
    err, ray, behind = np.empty(len(pid)), np.empty((len(pid), 3)), np.zeros(len(pid), bool)
    for i in np.unique(iid):
        m = iid == i
        cam = by_name[reconstruction.images[int(i)].name]
        err[m] = np.linalg.norm(cam.project(X[m]) - xy[m], axis=1)
        ray[m] = cam.center - X[m]
        behind[m] = cam.depth(X[m]) <= 0
    ray /= np.maximum(np.linalg.norm(ray, axis=1, keepdims=True), 1e-300)
    # largest angle between two rays of a track: observations sorted by point,
    # compared with the k-th next one of the same point for every k
    order = np.argsort(pid, kind="stable")
    sp, sr = pid[order], ray[order]
    best = np.zeros(len(pid))
    for k in range(1, int(np.max(np.bincount(np.unique(pid, return_inverse=True)[1])))):
        same = sp[k:] == sp[:-k]
        cos = np.clip(np.sum(sr[k:] * sr[:-k], axis=1), -1.0, 1.0)
        ang = np.where(same, np.degrees(np.arccos(cos)), 0.0)
        np.maximum.at(best, np.arange(len(ang)), ang)
        np.maximum.at(best, np.arange(k, len(ang) + k), ang)
    uniq, inv = np.unique(sp, return_inverse=True)
    track_best = np.zeros(len(uniq))
    np.maximum.at(track_best, inv, best)
    angle = np.empty(len(pid))
    angle[order] = track_best[inv]
    return err, angle, behind


def _delete(reconstruction, pid, iid, p2d) -> int:
    """Delete observations (points left with one observation go with them); the count."""
    count = 0
    for point, image, index in zip(pid.tolist(), iid.tolist(), p2d.tolist(), strict=True):
        if not reconstruction.exists_point3D(point):
            continue
        if reconstruction.points3D[point].track.length() > 2:
            reconstruction.delete_observation(image, index)
        else:
            reconstruction.delete_point3D(point)
        count += 1
    return count
