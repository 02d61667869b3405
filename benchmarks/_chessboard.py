"""Stereo on a real calibrated chessboard rig: is every point on the board, with an honest σ?

The board is planar, so every point matched inside its inner-corner outline must lie on
one plane.  The yardstick is the board's own corners (``cv2.findChessboardCorners`` +
``cornerSubPix`` in both views, triangulated with the same rig): their RMS distance from
their best plane is what this rig's calibration and the print's flatness allow.  For the
points of a matcher inside the outline (the convex hull of the left view's corners):

* the **robust plane**: RANSAC with the inlier band 5x the corners' RMS, refitted by least
  squares to its inliers;
* **blunders**: points farther from it than 5x the corners' RMS (a one-period slip on a
  chessboard is tens of squares in depth, far beyond any band);
* **inlier RMS / corners' RMS**;
* **residual / σ**: RMS over the inliers of the residual divided by the point's σ along the
  plane normal (sqrt(nᵀ C n) of its triangulation covariance) -- 1 for an honest σ;
* **points on the board**;
* **beyond one square** of the corners' own plane: the one-period slips (a slip is tens
  of squares in depth);

each also for the same run without the epipolar pass (``epipolar_pass=False``: the 2-D LSM
matches, uniqueness-tested).

SGBM (OpenCV 3-way, uniqueness ratio 12, on the pair rectified by ``matching.rectify``)
is sampled at the same left candidates and triangulated with the same rig; it reports no
σ.  Everything here is plain measurement; ``benchmarks/matching.py --part chessboard``
prints it.
"""

from __future__ import annotations

import time
from pathlib import Path

import cv2
import numpy as np

from matching.cameras import read_rig
from matching.image_file import imread
from matching.pair import reconstruct_pair
from matching.rectify import left_to_rectified, rectified_to_original, rectify, rectify_images
from matching.seeds import disparity_range, sample_disparity, sgbm_disparity
from matching.triangulate import triangulate_pair

PATTERN = (9, 6)
#: blunder band, in units of the corners' RMS flatness (the issue's definition)
BLUNDER_K = 5.0
SGBM_UNIQUENESS = 12


def board_corners(grey: np.ndarray) -> np.ndarray | None:
    """(54, 2) float64 sub-pixel inner corners of the 9x6 board, or None."""
    img = np.clip(grey, 0, 255).astype(np.uint8)
    found, corners = cv2.findChessboardCorners(img, PATTERN)
    if not found:
        return None
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-3)
    corners = cv2.cornerSubPix(img, corners, (11, 11), (-1, -1), crit)
    return corners.reshape(-1, 2).astype(np.float64)


def fit_plane(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares plane (centroid, unit normal) of (N, 3) points."""
    centroid = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - centroid, full_matrices=False)
    return centroid, vt[2]


def robust_plane(points: np.ndarray, band: float, rng: np.random.Generator,
                 trials: int = 500) -> tuple[np.ndarray, np.ndarray]:
    """RANSAC plane with inlier band ``band``, refitted (twice) to its inliers."""
    n = len(points)
    best, best_count = None, -1
    triples = rng.integers(0, n, size=(trials, 3))
    a, b, c = points[triples[:, 0]], points[triples[:, 1]], points[triples[:, 2]]
    normals = np.cross(b - a, c - a)
    norm = np.linalg.norm(normals, axis=1)
    good = norm > 0
    normals = normals[good] / norm[good, None]
    a = a[good]
    # counts of every hypothesis in blocks (trials x N distances)
    for start in range(0, len(normals), 50):
        diff = points[None, :, :] - a[start:start + 50, None, :]  # (t, N, 3)
        d = np.abs(np.einsum("tnk,tk->tn", diff, normals[start:start + 50]))
        counts = (d <= band).sum(axis=1)
        k = int(np.argmax(counts))
        if counts[k] > best_count:
            best_count, best = int(counts[k]), (a[start + k], normals[start + k])
    centroid, normal = best
    for _ in range(2):
        inl = np.abs((points - centroid) @ normal) <= band
        if inl.sum() < 3:
            break
        centroid, normal = fit_plane(points[inl])
    return centroid, normal


def inside_outline(corners: np.ndarray, x: np.ndarray) -> np.ndarray:
    """(N,) bool: left pixels inside the convex hull of the board's inner corners."""
    hull = cv2.convexHull(corners.astype(np.float32))
    if len(x) == 0:
        return np.zeros(0, bool)
    return np.array([cv2.pointPolygonTest(hull, (float(p[0]), float(p[1])), False) >= 0
                     for p in x])


def plane_measures(points, cov, band_unit, rng) -> dict:
    """The board measures of (N, 3) points (covariances (N, 3, 3) or None)."""
    n = len(points)
    row = {"points": int(n)}
    if n < 10:
        return {**row, "blunders": float("nan"), "inlier_rms": float("nan"),
                "inlier_rms_over_corners": float("nan"), "residual_over_sigma": float("nan")}
    band = BLUNDER_K * band_unit
    centroid, normal = robust_plane(points, band, rng)
    res = (points - centroid) @ normal
    inl = np.abs(res) <= band
    rms = float(np.sqrt(np.mean(res[inl] ** 2))) if inl.any() else float("nan")
    row.update(blunders=float(1.0 - inl.mean()), inlier_rms=rms,
               inlier_rms_over_corners=rms / band_unit,
               median_abs_blunder=float(np.median(np.abs(res[~inl]))) if (~inl).any() else 0.0)
    if cov is not None:
        s_n = np.sqrt(np.einsum("i,nij,j->n", normal, cov, normal))
        row["residual_over_sigma"] = float(np.sqrt(np.mean((res[inl] / s_n[inl]) ** 2)))
        row["median_sigma_normal"] = float(np.median(s_n[inl]))
        # the blunders' own σ: a lie when it is as small as the inliers'
        row["blunders_beyond_5_sigma"] = float(np.mean(np.abs(res) > 5 * s_n) if n else 0)
    return row


def sgbm_points(rig, rect, left, right, x_left):
    """SGBM (uniqueness ratio 12) at left pixels (N, 2), triangulated with the rig."""
    lr, rr = rectify_images(rect, left, right)
    dmin, count = disparity_range(lr, rr)
    disp = sgbm_disparity(lr, rr, int(dmin), int(count), uniqueness=SGBM_UNIQUENESS)
    xl_rect = left_to_rectified(rect, rig.left, x_left)
    d = sample_disparity(disp, xl_rect)
    ok = np.isfinite(d)
    xr = rectified_to_original(rect, rig.right,
                               np.column_stack([xl_rect[ok, 0] - d[ok], xl_rect[ok, 1]]))
    tri = triangulate_pair(rig.left, rig.right, x_left[ok], xr, refine=True, reject_p=None)
    return tri.points[tri.valid], int(ok.sum())


def _beyond(points, centroid, normal, limit: float = 1.0) -> float:
    """Share of points farther than ``limit`` squares from the plane."""
    if len(points) == 0:
        return float("nan")
    return float(np.mean(np.abs((points - centroid) @ normal) > limit))


def pair_figures(left_path: Path, right_path: Path, rig, match_options: dict | None = None,
                 seed: int = 0) -> dict:
    """Every measure of one chessboard pair: corners, LSM (``reconstruct_pair``), SGBM."""
    rng = np.random.default_rng(seed)
    left = imread(str(left_path), cv2.IMREAD_GRAYSCALE).astype(np.float64)
    right = imread(str(right_path), cv2.IMREAD_GRAYSCALE).astype(np.float64)
    cl, cr = board_corners(left), board_corners(right)
    if cl is None or cr is None:
        return {"pair": left_path.stem, "error": "board not found"}
    ctri = triangulate_pair(rig.left, rig.right, cl, cr, refine=True, reject_p=None)
    centroid, normal = fit_plane(ctri.points)
    corners_rms = float(np.sqrt(np.mean(((ctri.points - centroid) @ normal) ** 2)))
    match_options = dict(match_options or {})
    compare_2d = match_options.pop("compare_2d", True)
    t0, c0 = time.perf_counter(), time.process_time()
    match_options = {"epipolar_pass": True, **match_options}  # photosurf stereo's
    rec = reconstruct_pair(left, right, rig, **match_options)
    seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
    on = inside_outline(cl, rec.x_left)
    lsm = plane_measures(rec.points[on], rec.cov[on], corners_rms, rng)
    # one period or more off: farther than one square from the corners' own plane (a
    # slip of one period is tens of squares in depth)
    lsm["beyond_1_square"] = _beyond(rec.points[on], centroid, normal)
    if compare_2d and match_options.get("epipolar_pass", True):
        # the same run without the epipolar pass: the 2-D LSM matches, uniqueness-tested
        old = reconstruct_pair(left, right, rig, **{**match_options, "epipolar_pass": False})
        old_on = inside_outline(cl, old.x_left)
        lsm["without_epipolar_pass"] = {
            "points": int(old_on.sum()),
            "beyond_1_square": _beyond(old.points[old_on], centroid, normal),
            **{k: v for k, v in plane_measures(old.points[old_on], old.cov[old_on],
                                               corners_rms, rng).items()
               if k in ("blunders", "inlier_rms_over_corners", "residual_over_sigma")}}
    lsm["seconds"] = seconds
    lsm["cpu_seconds"] = cpu  # this process's CPU (numba threads included)
    lsm["status"] = rec.matches.status_counts()
    cand_on = inside_outline(cl, rec.matches.x_left)
    lsm["candidates_on_board"] = int(cand_on.sum())
    sg, _ = sgbm_points(rig, rectify(rig), left, right, rec.matches.x_left[cand_on])
    sgbm = plane_measures(sg, None, corners_rms, rng)
    sgbm["beyond_1_square"] = _beyond(sg, centroid, normal)
    return {"pair": left_path.stem.replace("left", ""), "corners_rms": corners_rms,
            "lsm": lsm, "sgbm": sgbm}


def calibrate_rig(folder: Path):
    """The rig from every pair in ``folder`` (``matching.calibrate.stereo_calibrate``,
    what ``photosurf calibrate --pattern 9x6 --square 1`` runs)."""
    from matching.calibrate import stereo_calibrate

    lefts = sorted(folder.glob("left*.jpg"))
    rights = [folder / p.name.replace("left", "right") for p in lefts]
    imgs_l = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in lefts]
    imgs_r = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in rights]
    return stereo_calibrate(imgs_l, imgs_r, PATTERN, 1.0)


def chessboard_figures(folder: Path, rig_path: Path | None = None, pairs=None,
                       match_options: dict | None = None) -> tuple[list[dict], dict]:
    """:func:`pair_figures` of every ``leftNN.jpg``/``rightNN.jpg`` pair in ``folder``,
    and the calibration's figures (rig from ``rig_path``, else calibrated here)."""
    if rig_path is not None:
        rig, calib = read_rig(rig_path), {"rig": str(rig_path)}
    else:
        result = calibrate_rig(folder)
        rig = result.rig
        calib = {"rms_px": float(result.rms_px), "baseline": float(rig.baseline),
                 "pairs": len(result.used)}
    rows = []
    for lp in sorted(folder.glob("left*.jpg")):
        tag = lp.stem.replace("left", "")
        if pairs is not None and tag not in pairs:
            continue
        rp = folder / f"right{tag}.jpg"
        if rp.exists():
            rows.append(pair_figures(lp, rp, rig, match_options))
    return rows, calib
