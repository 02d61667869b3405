r"""Metric scale of an SfM frame: a known distance between two marked points, or markers.

Structure from motion fixes the scene up to a similarity; one known length :math:`L`
measured as :math:`\ell` in the frame gives the factor :math:`s = L / \ell` applied to
points, σ and camera translations (:func:`matching.sfm.transform_cameras`).

**Two marked points** (``A_X,A_Y B_X,B_Y@IMAGE=DIST``): each pixel's 3D point is where
its ray meets the plane fitted (least squares) to the cloud points that project nearest
to it in that view (the ``k`` nearest within the visible depth layer: depths within
3 MAD of their median).  Its variance is the plane fit's, :math:`\sigma_p^2 =
\text{rms}^2 / k`, plus the marking error (0.5 px) across the ray,
:math:`(0.5\,Z/f)^2`; the factor's relative σ is :math:`\sqrt{\sigma_A^2 +
\sigma_B^2} / \ell`.

**Markers** (ArUco, OpenCV's ``aruco`` [1]_): each marker seen in two or more views has
its four corners triangulated (:func:`matching.triangulate.triangulate_multiview`); its
four sides are four measurements of the known side.  The factor is the median of
:math:`L / \ell_j` over all sides and its σ their standard deviation over
:math:`\sqrt{n}` (with fewer than 2 sides: none).

References
----------
.. [1] S. Garrido-Jurado, R. Muñoz-Salinas, F. J. Madrid-Cuevas and M. J. Marín-Jiménez,
   "Automatic generation and detection of highly reliable fiducial markers under
   occlusion", Pattern Recognition 47(6), 2280-2292 (2014).
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from checks.robust import mad_sigma
from matching.validate import check_shape

__all__ = ["ScaleResult", "parse_scale", "scale_from_points", "detect_markers",
           "scale_from_markers", "MARKER_DICTIONARIES"]

#: ArUco dictionaries tried, in this order (the one with the most markers wins).
MARKER_DICTIONARIES = ("DICT_4X4_50", "DICT_5X5_100", "DICT_6X6_250", "DICT_ARUCO_ORIGINAL",
                       "DICT_APRILTAG_36h11")
#: Standard deviation of a hand-marked pixel (px).
MARK_SIGMA_PX = 0.5

_SPEC = re.compile(r"^\s*([-+0-9.eE]+)\s*,\s*([-+0-9.eE]+)\s+([-+0-9.eE]+)\s*,\s*"
                   r"([-+0-9.eE]+)\s*@\s*(.+?)\s*=\s*([-+0-9.eE]+)\s*$")


@dataclass(frozen=True)
class ScaleResult:
    """A scale factor, its standard deviation and where it came from."""

    factor: float
    sigma: float
    source: str
    detail: dict = field(default_factory=dict)

    def report(self) -> dict:
        return {"scale_source": self.source, "scale_factor": float(self.factor),
                "scale_sigma": float(self.sigma),
                "scale_relative_sigma": float(self.sigma / self.factor), **self.detail}


def parse_scale(text: str) -> tuple[np.ndarray, np.ndarray, str, float]:
    """``"A_X,A_Y B_X,B_Y@IMAGE=DIST"`` -> ``(a (2,), b (2,), image, dist)``.

    Raises ``ValueError`` naming the form when it does not parse, the distance is not
    positive or the two points coincide.
    """
    match = _SPEC.match(str(text))
    if match is None:
        raise ValueError(f"scale {text!r}: give A_X,A_Y B_X,B_Y@IMAGE=DIST (two pixels of "
                         "one image and their distance)")
    ax, ay, bx, by, image, dist = match.groups()
    try:
        a, b, dist = np.array([float(ax), float(ay)]), np.array([float(bx), float(by)]), \
            float(dist)
    except ValueError:
        raise ValueError(f"scale {text!r}: the coordinates and the distance must be "
                         "numbers") from None
    if not (np.isfinite(dist) and dist > 0):
        raise ValueError(f"scale {text!r}: the distance must be positive, got {dist:g}")
    if not np.all(np.isfinite(np.r_[a, b])) or np.allclose(a, b):
        raise ValueError(f"scale {text!r}: the two points must be two different pixels")
    return a, b, image, dist


def _point_at_pixel(pixel: np.ndarray, camera, points: np.ndarray, k: int) -> tuple:
    """The 3D point of ``pixel`` on the plane of its nearest cloud points, its σ, depth."""
    depth = camera.depth(points)
    front = np.flatnonzero(depth > 0)
    uv = camera.project(points[front])
    distance = np.linalg.norm(uv - pixel, axis=1)
    near = front[np.argsort(distance)[: 4 * k]]
    z = depth[near]
    mad = mad_sigma(z) + 1e-300
    layer = near[np.abs(z - np.median(z)) <= 3 * mad][:k]  # the visible depth layer
    if len(layer) < 3:
        raise ValueError("too few cloud points around it")
    if np.linalg.norm(camera.project(points[layer[:1]])[0] - pixel) > 50.0:
        raise ValueError("no cloud point within 50 px of it")
    centre = points[layer].mean(axis=0)
    _, singular, vt = np.linalg.svd(points[layer] - centre)
    normal = vt[2]
    rms = singular[2] / np.sqrt(len(layer))
    if camera.has_distortion:
        import cv2

        xy = cv2.undistortPoints(pixel.reshape(1, 1, 2), camera.K, camera.dist).reshape(2)
        ray = np.r_[xy, 1.0]
    else:
        ray = np.linalg.solve(camera.K, np.r_[pixel, 1.0])
    direction = camera.R.T @ (ray / np.linalg.norm(ray))
    origin = np.asarray(camera.center, dtype=np.float64)
    denominator = direction @ normal
    if abs(denominator) < 1e-6:
        raise ValueError("its ray grazes the surface")
    X = origin + direction * ((centre - origin) @ normal) / denominator
    Z = float(camera.depth(X[None])[0])
    sigma = float(np.sqrt(rms**2 / len(layer) + (MARK_SIGMA_PX * Z / camera.K[0, 0]) ** 2))
    return X, sigma, Z


def scale_from_points(a, b, image: str, distance: float, cameras: Sequence, points,
                      k: int = 20) -> ScaleResult:
    """The factor that makes the two marked pixels' points ``distance`` apart.

    Parameters
    ----------
    a, b : (2,) float64
        Pixels of ``image`` in the camera's pixel frame (centres at integers).
    image : str
        The view's name (a camera's ``name``).
    distance : float
        The known distance, in the unit wanted.
    cameras : sequence of Camera
    points : (N, 3) float64
        The cloud, in the cameras' frame.
    k : int
        Cloud points per plane fit.
    """
    points = check_shape(points, "(N, 3)", "points", dtype=np.float64)
    by_name = {cam.name: cam for cam in cameras}
    if image not in by_name:
        raise ValueError(f"scale: no view {image!r} (views: "
                         f"{', '.join(sorted(by_name)[:5])}{' ...' if len(by_name) > 5 else ''})")
    cam = by_name[image]
    ends = []
    for label, pixel in (("A", np.asarray(a, float)), ("B", np.asarray(b, float))):
        if not (0 <= pixel[0] < cam.width and 0 <= pixel[1] < cam.height):
            raise ValueError(f"scale: point {label} {pixel.tolist()} lies outside {image} "
                             f"({cam.width}x{cam.height} px)")
        try:
            ends.append(_point_at_pixel(pixel, cam, points, k))
        except ValueError as exc:
            raise ValueError(f"scale: point {label} {pixel.tolist()} of {image}: {exc}") from None
    length = float(np.linalg.norm(ends[0][0] - ends[1][0]))
    if length <= 0:
        raise ValueError(f"scale: points A and B of {image} fall on one cloud point")
    factor = distance / length
    sigma = factor * float(np.hypot(ends[0][1], ends[1][1])) / length
    return ScaleResult(factor, sigma, f"two marked points in {image} {distance:g} apart",
                       {"scale_length_model": length})


def detect_markers(image, dictionary: str | None = None) -> tuple[str, dict]:
    """ArUco markers of an image: the dictionary used and ``{id: (4, 2) corners}``.

    ``dictionary`` None tries :data:`MARKER_DICTIONARIES` and keeps the one with the
    most markers.  Corners are refined to sub-pixel (``CORNER_REFINE_SUBPIX``).
    """
    import cv2

    grey = image if image.ndim == 2 else cv2.cvtColor(image[..., :3], cv2.COLOR_BGR2GRAY)
    parameters = cv2.aruco.DetectorParameters()
    parameters.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    best = (dictionary or MARKER_DICTIONARIES[0], {})
    for name in ((dictionary,) if dictionary else MARKER_DICTIONARIES):
        detector = cv2.aruco.ArucoDetector(
            cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name)), parameters)
        corners, ids, _ = detector.detectMarkers(grey)
        found = {} if ids is None else {int(i): np.asarray(c, np.float64).reshape(4, 2)
                                         for i, c in zip(ids.ravel(), corners, strict=True)}
        if len(found) > len(best[1]):
            best = (name, found)
    return best


def scale_from_markers(detections: Sequence[dict], cameras: Sequence,
                       side: float, dictionary: str = "") -> ScaleResult:
    """The factor from markers of side ``side`` seen in two or more views.

    Parameters
    ----------
    detections : sequence of V dict
        Each view's ``{id: (4, 2) corners}`` (:func:`detect_markers`), in the cameras'
        pixel frame.
    cameras : sequence of V Camera
    side : float
        The markers' printed side (black square), in the unit wanted.

    Raises
    ------
    ValueError
        No marker seen in two views.
    """
    from matching.triangulate import triangulate_multiview

    if not side > 0:
        raise ValueError(f"markers: the side must be positive, got {side}")
    ids = sorted({i for found in detections for i in found})
    seen = [i for i in ids if sum(i in found for found in detections) >= 2]
    if not seen:
        raise ValueError(f"markers: no marker seen in two views ({len(ids)} marker(s) "
                         "found in all)")
    obs = np.full((4 * len(seen), len(cameras), 2), np.nan)
    for v, found in enumerate(detections):
        for m, i in enumerate(seen):
            if i in found:
                obs[4 * m: 4 * m + 4, v] = found[i]
    tri = triangulate_multiview(list(cameras), obs, reject_p=None)
    corners = tri.points.reshape(len(seen), 4, 3)
    sides = np.linalg.norm(corners - np.roll(corners, -1, axis=1), axis=2).ravel()
    sides = sides[np.isfinite(sides) & (sides > 0)]
    if not len(sides):
        raise ValueError("markers: their corners could not be triangulated")
    factors = side / sides
    factor = float(np.median(factors))
    sigma = float(np.std(factors, ddof=1) / np.sqrt(len(factors))) if len(factors) > 1 \
        else float("nan")
    return ScaleResult(factor, sigma, f"{len(seen)} ArUco marker(s) ({dictionary or 'ArUco'}) "
                       f"of side {side:g}", {"scale_markers": len(seen),
                                             "scale_sides": int(len(sides))})
