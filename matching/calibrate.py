r"""Chessboard stereo calibration.

Each board view gives the homography-like constraint
:math:`x_{ij} = \pi(K, d, R_i, t_i; X_j)` between the known board corners
:math:`X_j = (c\,s,\; r\,s,\; 0)` (column c, row r, square size s) and their
detected image positions.  Zhang's method [1]_ (``cv2.calibrateCamera``)
estimates each camera's intrinsics and distortion; ``cv2.stereoCalibrate``
then minimises the joint reprojection error of both cameras over all pairs
with the rig constraint :math:`R_{r,i} = R\,R_{l,i}`,
:math:`t_{r,i} = R\,t_{l,i} + T`, refining the intrinsics from the
per-camera start (Bouguet's toolbox [2]_).

Corners are found by the sector-based detector ``cv2.findChessboardCornersSB``
[3]_ (more accurate than corner refinement on saddle points), falling back to
``cv2.findChessboardCorners`` + ``cv2.cornerSubPix``.

References
----------
.. [1] Z. Zhang, "A flexible new technique for camera calibration", IEEE
   TPAMI 22(11) (2000).
.. [2] J.-Y. Bouguet, "Camera Calibration Toolbox for Matlab", Caltech (2004).
.. [3] A. Duda and U. Frese, "Accurate Detection and Localization of
   Checkerboard Corners for Calibration", BMVC (2018).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np

from matching.cameras import StereoRig
from matching.validate import TOL

__all__ = [
    "StereoCalibration",
    "board_points",
    "find_chessboard",
    "stereo_calibrate",
    "parse_pattern",
]

#: Zhang's method needs at least 3 views of a plane for K with 5 unknowns.
MIN_PAIRS = 3


@dataclass(frozen=True, eq=False)
class StereoCalibration:
    """Result of :func:`stereo_calibrate`.

    Attributes
    ----------
    rig : StereoRig
        Left camera at the world origin; units of the square size.
    rms_px : float
        RMS reprojection error of the joint stereo adjustment, px.
    rms_left_px, rms_right_px : float
        RMS errors of the single-camera calibrations, px.
    used : list of int
        Indices of the pairs in which both cameras saw the whole board.
    skipped : dict of int -> str
        Pairs left out and why ("no board in left", ...).
    per_pair_px : (len(used), 2) float64
        RMS error per used pair and camera, px.
    """

    rig: StereoRig
    rms_px: float
    rms_left_px: float
    rms_right_px: float
    used: list[int]
    skipped: dict[int, str] = field(default_factory=dict)
    per_pair_px: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))


def parse_pattern(text: str) -> tuple[int, int]:
    """``"9x6"`` -> (9, 6): inner corners per row and per column."""
    parts = str(text).lower().replace("*", "x").split("x")
    try:
        cols, rows = (int(p) for p in parts)
    except ValueError:
        raise ValueError(f"pattern must look like 9x6 (inner corners), got {text!r}") from None
    if cols < 2 or rows < 2:
        raise ValueError(f"pattern needs at least 2x2 inner corners, got {text!r}")
    return cols, rows


def board_points(pattern: tuple[int, int], square: float) -> np.ndarray:
    """Inner-corner coordinates on the board, in OpenCV's detection order.

    Parameters
    ----------
    pattern : (cols, rows)
        Inner corners per row and per column.
    square : float
        Side of a square, in the unit the rig will have.

    Returns
    -------
    (cols * rows, 3) float32, z = 0, row-major (x fastest).
    """
    cols, rows = pattern
    if not square > 0:
        raise ValueError(f"square must be positive, got {square}")
    grid = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2)  # (x, y) with x fastest
    return np.column_stack([grid * float(square), np.zeros(len(grid))]).astype(np.float32)


def find_chessboard(image: np.ndarray, pattern: tuple[int, int]) -> np.ndarray | None:
    """Detect the inner corners of a chessboard.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) uint8
    pattern : (cols, rows)

    Returns
    -------
    (cols * rows, 2) float64 px in OpenCV's order, or None if the whole board
    is not found.
    """
    gray = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    found, corners = cv2.findChessboardCornersSB(
        gray, pattern, flags=cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_EXHAUSTIVE
        | cv2.CALIB_CB_ACCURACY)
    if not found:
        found, corners = cv2.findChessboardCorners(
            gray, pattern, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
        if not found:
            return None
        criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 50, 1e-3)
        corners = cv2.cornerSubPix(gray, corners, (5, 5), (-1, -1), criteria)
    return corners.reshape(-1, 2).astype(np.float64)


def _same_orientation(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """Reverse the right corners when the detector numbered them from the other end.

    A board seen by both cameras of a rig points the same way in both images,
    so the vector first -> last corner must too; a 180° ambiguity of the
    detector shows up as opposite vectors.
    """
    if np.dot(left[-1] - left[0], right[-1] - right[0]) < 0:
        return right[::-1].copy()
    return right


def stereo_calibrate(left_images: Sequence[np.ndarray], right_images: Sequence[np.ndarray],
                     pattern: tuple[int, int], square: float, fix_k3: bool = True,
                     names: Sequence[str] | None = None) -> StereoCalibration:
    """Calibrate a stereo rig from chessboard image pairs.

    Parameters
    ----------
    left_images, right_images : sequences of (H, W) or (H, W, 3) uint8
        Simultaneous views of the board, pair i = (left_images[i], right_images[i]);
        all images of the same size.
    pattern : (cols, rows)
        Inner corners (9x6 for a board of 10x7 squares).
    square : float
        Square size; the baseline comes out in this unit.
    fix_k3 : bool
        Keep k3 = 0 (k1 k2 p1 p2 estimated): the sixth-order radial term is
        poorly determined by a few views of a planar board unless the lens
        is wide-angle.
    names : sequence of str, optional
        Pair labels for the skip messages (default: the indices).

    Returns
    -------
    StereoCalibration

    Raises
    ------
    ValueError
        Different numbers of left and right images, mixed image sizes, no
        board in any pair, or fewer than ``MIN_PAIRS`` usable pairs.
    """
    pattern = tuple(int(v) for v in pattern)
    if len(left_images) != len(right_images):
        raise ValueError(f"got {len(left_images)} left and {len(right_images)} right images; "
                         "they must pair up")
    if not left_images:
        raise ValueError("no calibration images")
    names = list(names) if names is not None else [str(i) for i in range(len(left_images))]
    sizes = {img.shape[:2] for img in (*left_images, *right_images)}
    if len(sizes) != 1:
        raise ValueError(f"calibration images have different sizes: {sorted(sizes)}")
    height, width = sizes.pop()
    obj = board_points(pattern, square)
    used, skipped, pts_l, pts_r = [], {}, [], []
    for i, (img_l, img_r) in enumerate(zip(left_images, right_images, strict=True)):
        c_l, c_r = find_chessboard(img_l, pattern), find_chessboard(img_r, pattern)
        if c_l is None or c_r is None:
            side = "left and right" if c_l is None and c_r is None else \
                "left" if c_l is None else "right"
            skipped[i] = f"pair {names[i]}: no {pattern[0]}x{pattern[1]} board found in {side}"
            continue
        used.append(i)
        pts_l.append(c_l.astype(np.float32))
        pts_r.append(_same_orientation(c_l, c_r).astype(np.float32))
    if not used:
        raise ValueError(f"no {pattern[0]}x{pattern[1]} chessboard found in any of the "
                         f"{len(left_images)} pairs (check --pattern: inner corners, cols x rows)")
    if len(used) < MIN_PAIRS:
        raise ValueError(f"the board was found in only {len(used)} pair(s); at least "
                         f"{MIN_PAIRS} are needed ({'; '.join(skipped.values())})")
    return _calibrate(obj, pts_l, pts_r, (width, height), fix_k3, used, skipped)


def _calibrate(obj, pts_l, pts_r, size, fix_k3, used, skipped) -> StereoCalibration:
    flags = cv2.CALIB_FIX_K3 if fix_k3 else 0
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, TOL.zero)
    objs = [obj] * len(used)
    rms_l, K1, D1, _, _ = cv2.calibrateCamera(objs, pts_l, size, None, None, flags=flags,
                                              criteria=criteria)
    rms_r, K2, D2, _, _ = cv2.calibrateCamera(objs, pts_r, size, None, None, flags=flags,
                                              criteria=criteria)
    out = cv2.stereoCalibrate(objs, pts_l, pts_r, K1, D1, K2, D2, size, None, None,
                              flags=flags | cv2.CALIB_USE_INTRINSIC_GUESS, criteria=criteria)
    rms, K1, D1, K2, D2, R, T = out[:7]
    per_pair = _per_pair_errors(obj, pts_l, pts_r, K1, D1, K2, D2, R, T)
    rig = StereoRig.from_calibration(K1, D1.reshape(-1), K2, D2.reshape(-1), R, T.reshape(3),
                                     size[0], size[1])
    return StereoCalibration(rig=rig, rms_px=float(rms), rms_left_px=float(rms_l),
                             rms_right_px=float(rms_r), used=used, skipped=skipped,
                             per_pair_px=per_pair)


def _per_pair_errors(obj, pts_l, pts_r, K1, D1, K2, D2, R, T) -> np.ndarray:
    """RMS reprojection error (px) per pair and camera, from the left board pose."""
    errors = np.zeros((len(pts_l), 2))
    for i, (c_l, c_r) in enumerate(zip(pts_l, pts_r, strict=True)):  # loop over pairs
        _, rvec, tvec = cv2.solvePnP(obj, c_l, K1, D1)
        R_l = cv2.Rodrigues(rvec)[0]
        proj_l = cv2.projectPoints(obj, rvec, tvec, K1, D1)[0].reshape(-1, 2)
        R_r, t_r = R @ R_l, R @ tvec.reshape(3) + T.reshape(3)
        proj_r = cv2.projectPoints(obj, cv2.Rodrigues(R_r)[0], t_r, K2, D2)[0].reshape(-1, 2)
        errors[i, 0] = np.sqrt(np.mean(np.sum((proj_l - c_l) ** 2, axis=1)))
        errors[i, 1] = np.sqrt(np.mean(np.sum((proj_r - c_r) ** 2, axis=1)))
    return errors
