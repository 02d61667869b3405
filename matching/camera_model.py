r"""Pinhole cameras with lens distortion and stereo rigs: the camera model.

A camera maps a world point :math:`X` to a pixel :math:`x` by

.. math::

    x_c = R X + t, \qquad
    (x', y') = (x_c / z_c,\; y_c / z_c), \qquad
    (x'', y'') = \mathrm{distort}(x', y'; k_1, k_2, p_1, p_2[, k_3, \ldots]), \qquad
    x = K\,(x'', y'', 1)^T,

the OpenCV model (Brown-Conrady radial + tangential distortion), with pixel
centres at integer coordinates.  Without distortion the projection matrix is
:math:`P = K [R \mid t]` (Hartley & Zisserman [1]_ §6.1).  A stereo rig maps
left-camera coordinates to right-camera coordinates, :math:`x_r = R\,x_l + T`
(the convention of ``cv2.stereoCalibrate``).  Also here: the camera of a turned
image, and rotations to and from unit quaternions (COLMAP's ``QW QX QY QZ``).

The file formats are in :mod:`matching.camera_files`; :mod:`matching.cameras`
offers both under one name.

References
----------
.. [1] R. Hartley and A. Zisserman, "Multiple View Geometry in Computer
   Vision", 2nd ed., Cambridge University Press (2004).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from matching.validate import TOL, check_shape

__all__ = [
    "Camera",
    "StereoRig",
    "rotation_to_quaternion",
    "quaternion_to_rotation",
    "turn_camera",
]


#: cv2.undistortPoints stops after 5 iterations by default (errors of ~1e-3 px
#: under strong distortion); OpenCV's eps is the reprojection error in px,
#: so these criteria stop at ~1e-12 px.
_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
_VALID_DIST_LENGTHS = (0, 4, 5, 8, 12, 14)


# --------------------------------------------------------------------------- camera
def _frozen(array: np.ndarray) -> np.ndarray:
    array = np.array(array, dtype=np.float64, copy=True)
    array.flags.writeable = False
    return array


@dataclass(frozen=True, eq=False)
class Camera:
    """A calibrated pinhole camera with OpenCV lens distortion.

    Parameters
    ----------
    K : (3, 3) float64
        Intrinsic matrix ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]``, pixels;
        fx, fy > 0, pixel centres at integer coordinates.
    dist : (k,) float64
        Distortion coefficients in OpenCV order ``k1 k2 p1 p2 [k3 [k4 k5 k6
        [s1 s2 s3 s4 [tx ty]]]]``, k in {0, 4, 5, 8, 12, 14}; empty = none.
    R : (3, 3) float64
        World-to-camera rotation (orthonormal, det +1).
    t : (3,) float64
        World-to-camera translation, scene units: ``x_c = R X + t``.
    width, height : int
        Image size in pixels.
    name : str
        Image file name (or any label).

    Notes
    -----
    Arrays are copied and made read-only.  Equality is identity; compare two
    cameras with :meth:`allclose`.
    """

    K: np.ndarray
    dist: np.ndarray
    R: np.ndarray
    t: np.ndarray
    width: int
    height: int
    name: str = field(default="")

    def __post_init__(self) -> None:
        K = _frozen(check_shape(self.K, "(3, 3)", "K", dtype=np.float64))
        dist = _frozen(np.asarray(self.dist, dtype=np.float64).reshape(-1))
        R = _frozen(check_shape(self.R, "(3, 3)", "R", dtype=np.float64))
        t = _frozen(np.asarray(self.t, dtype=np.float64).reshape(-1))
        for value, label in ((K, "K"), (dist, "dist"), (R, "R"), (t, "t")):
            if not np.all(np.isfinite(value)):
                raise ValueError(f"{label} must be finite, got {value.tolist()}")
        if t.shape != (3,):
            raise ValueError(f"t must have shape (3,), got {np.shape(self.t)}")
        if dist.size not in _VALID_DIST_LENGTHS:
            raise ValueError(
                f"dist must have 0, 4, 5, 8, 12 or 14 coefficients, got {dist.size}")
        if not (K[0, 0] > 0 and K[1, 1] > 0):
            raise ValueError(f"K must have positive focal lengths, got fx={K[0, 0]}, fy={K[1, 1]}")
        if not np.allclose(K[2], [0.0, 0.0, 1.0], atol=TOL.zero) or abs(K[1, 0]) > TOL.zero:
            raise ValueError(f"K must be upper triangular with K[2] = [0, 0, 1], got {K.tolist()}")
        if abs(np.linalg.det(K)) < TOL.zero:
            raise ValueError(f"K is singular: {K.tolist()}")
        orth = np.abs(R.T @ R - np.eye(3)).max()
        det_err = abs(np.linalg.det(R) - 1.0)
        if orth > TOL.rotation_orthonormal or det_err > TOL.rotation_orthonormal:
            raise ValueError(
                f"R must be a rotation (R^T R = I within {TOL.rotation_orthonormal}, det +1), "
                f"got max|R^T R - I| = {orth:.3g}, det = {np.linalg.det(R):.6g}")
        width, height = int(self.width), int(self.height)
        if width <= 0 or height <= 0 or width != self.width or height != self.height:
            raise ValueError(
                f"width, height must be positive integers, got {self.width}x{self.height}")
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "dist", dist)
        object.__setattr__(self, "R", R)
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "width", width)
        object.__setattr__(self, "height", height)
        object.__setattr__(self, "name", str(self.name))

    # ------------------------------------------------------------ geometry
    @property
    def center(self) -> np.ndarray:
        """(3,) camera centre in world coordinates, ``C = -R^T t``."""
        return -self.R.T @ self.t

    @property
    def P(self) -> np.ndarray:
        """(3, 4) projection matrix ``K [R | t]`` (distortion not included)."""
        return self.K @ np.hstack([self.R, self.t[:, None]])

    @property
    def size(self) -> tuple[int, int]:
        """``(width, height)`` in pixels, the order OpenCV expects."""
        return (self.width, self.height)

    @property
    def has_distortion(self) -> bool:
        """True if any distortion coefficient is non-zero."""
        return bool(np.any(self.dist != 0.0))

    @property
    def rvec(self) -> np.ndarray:
        """(3,) Rodrigues vector of ``R``."""
        return cv2.Rodrigues(self.R)[0].reshape(3)

    def _dist_or_none(self) -> np.ndarray | None:
        return self.dist if self.dist.size else None

    def depth(self, X) -> np.ndarray:
        """Depth (z in the camera frame) of world points.

        Parameters
        ----------
        X : (N, 3) float64, scene units

        Returns
        -------
        (N,) float64, scene units; negative behind the camera.
        """
        X = check_shape(X, "(N, 3)", "X", dtype=np.float64)
        return X @ self.R[2] + self.t[2]

    def to_camera(self, X) -> np.ndarray:
        """World points (N, 3) -> camera-frame points (N, 3), ``R X + t``."""
        X = check_shape(X, "(N, 3)", "X", dtype=np.float64)
        return X @ self.R.T + self.t

    def project(self, X, with_jacobian: bool = False):
        """Project world points to distorted pixel coordinates.

        Parameters
        ----------
        X : (N, 3) float64, scene units
        with_jacobian : bool
            Also return the derivative of the pixel with respect to ``X``.

        Returns
        -------
        x : (N, 2) float64, pixels
            Points behind the camera are projected too (check :meth:`depth`).
        J : (N, 2, 3) float64, pixels per scene unit (only if ``with_jacobian``)
        """
        X = check_shape(X, "(N, 3)", "X", dtype=np.float64)
        if len(X) == 0:
            empty = np.zeros((0, 2))
            return (empty, np.zeros((0, 2, 3))) if with_jacobian else empty
        # rotate here, not through cv2's rvec: cv2.Rodrigues(R) loses ~1e-8 rad for
        # rotations near pi (1e-5 px at f = 800), R X + t is exact to rounding
        x, jac = cv2.projectPoints(self.to_camera(X).reshape(-1, 1, 3), np.zeros(3), np.zeros(3),
                                   self.K, self._dist_or_none())
        x = x.reshape(-1, 2)
        if not with_jacobian:
            return x
        # columns 3:6 are d(pixel)/d(t) = d(pixel)/d(x_c); d(x_c)/dX = R.
        dx_dt = jac[:, 3:6].reshape(-1, 2, 3)
        return x, dx_dt @ self.R

    def undistort_points(self, x) -> np.ndarray:
        """Remove lens distortion from pixel coordinates.

        Parameters
        ----------
        x : (N, 2) float64, distorted pixels

        Returns
        -------
        (N, 2) float64, pixels of the ideal pinhole camera with the same ``K``.
        """
        x = check_shape(x, "(N, 2)", "x", dtype=np.float64)
        if not self.has_distortion or len(x) == 0:
            return x.copy()
        out = cv2.undistortPoints(x.reshape(-1, 1, 2), self.K, self.dist, P=self.K,
                                  criteria=_UNDISTORT_CRITERIA)
        return out.reshape(-1, 2)

    def normalized(self, x) -> np.ndarray:
        """Distorted pixels (N, 2) -> normalised image coordinates (N, 2), ``z = 1``."""
        ideal = self.undistort_points(x)
        homog = np.column_stack([ideal, np.ones(len(ideal))])
        return np.linalg.solve(self.K, homog.T).T[:, :2]

    def ray(self, x) -> tuple[np.ndarray, np.ndarray]:
        """Viewing rays through pixels.

        Parameters
        ----------
        x : (N, 2) float64, distorted pixels

        Returns
        -------
        origin : (N, 3) float64
            The camera centre, repeated.
        direction : (N, 3) float64
            Unit direction in world coordinates, pointing forward (z_c > 0).
        """
        n = self.normalized(x)
        d_cam = np.column_stack([n, np.ones(len(n))])
        d = d_cam @ self.R  # R^T d_cam, row-wise
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        return np.broadcast_to(self.center, d.shape).copy(), d

    def allclose(self, other: Camera, rtol: float = 1e-9, atol: float = 1e-9) -> bool:
        """True if both cameras have the same size and (numerically) the same parameters."""
        n = max(self.dist.size, other.dist.size)
        d1 = np.pad(self.dist, (0, n - self.dist.size))
        d2 = np.pad(other.dist, (0, n - other.dist.size))
        return (self.size == other.size
                and np.allclose(self.K, other.K, rtol=rtol, atol=atol)
                and np.allclose(d1, d2, rtol=rtol, atol=atol)
                and np.allclose(self.R, other.R, rtol=rtol, atol=atol)
                and np.allclose(self.t, other.t, rtol=rtol, atol=atol))

    @classmethod
    def from_projection(cls, P, width: int, height: int, name: str = "") -> Camera:
        """Camera from a (3, 4) projection matrix (RQ decomposition, no distortion)."""
        P = check_shape(P, "(3, 4)", "P", dtype=np.float64)
        K, R, c_h = cv2.decomposeProjectionMatrix(P)[:3]
        if abs(c_h[3, 0]) < TOL.zero:
            raise ValueError("P has its centre at infinity (affine camera)")
        C = (c_h[:3, 0] / c_h[3, 0])
        # decomposeProjectionMatrix may return negative diagonals; make them positive.
        S = np.diag(np.sign(np.diag(K)))
        K, R = K @ S, S @ R
        if np.linalg.det(R) < 0:
            R = -R  # P was given up to a negative scale
        K = K / K[2, 2]
        return cls(K=K, dist=np.zeros(0), R=R, t=-R @ C, width=width, height=height, name=name)


# ----------------------------------------------------------------------- stereo rig
@dataclass(frozen=True, eq=False)
class StereoRig:
    """Two cameras seeing the same scene.

    Parameters
    ----------
    left, right : Camera

    Notes
    -----
    ``R`` and ``T`` map left-camera to right-camera coordinates,
    ``x_r = R x_l + T`` (``cv2.stereoCalibrate``'s convention), whatever the
    world frame of the two cameras is.
    """

    left: Camera
    right: Camera

    def __post_init__(self) -> None:
        for label in ("left", "right"):
            if not isinstance(getattr(self, label), Camera):
                raise ValueError(f"{label} must be a Camera, got {type(getattr(self, label))}")

    @property
    def R(self) -> np.ndarray:
        """(3, 3) rotation left camera -> right camera."""
        return self.right.R @ self.left.R.T

    @property
    def T(self) -> np.ndarray:
        """(3,) translation left camera -> right camera, scene units."""
        return self.right.t - self.R @ self.left.t

    @property
    def baseline(self) -> float:
        """Distance between the two camera centres, scene units."""
        return float(np.linalg.norm(self.T))

    @classmethod
    def from_calibration(cls, K1, D1, K2, D2, R, T, width: int, height: int,
                         names: tuple[str, str] = ("left", "right")) -> StereoRig:
        """Rig from OpenCV stereo calibration output; the left camera is the world frame."""
        left = Camera(K1, D1, np.eye(3), np.zeros(3), width, height, names[0])
        right = Camera(K2, D2, R, np.asarray(T, dtype=np.float64).reshape(3), width, height,
                       names[1])
        return cls(left, right)


# ------------------------------------------------------------------ turned images
#: np.rot90 turns the camera about its optical axis by -90 degrees (x_c' = y_c, y_c' = -x_c)
_QUARTER_TURN = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


def turn_camera(camera: Camera, quarter_turns: int) -> Camera:
    """The camera of ``np.rot90(image, quarter_turns)`` (counter-clockwise quarter turns).

    ``np.rot90`` maps pixel (x, y) of a W-wide image to (y, W - 1 - x) (``cv2.rotate``
    with ROTATE_90_COUNTERCLOCKWISE does the same).  The turned image is exactly the
    view of the same camera rolled about its optical axis: K becomes ``[[fy, -s, cy],
    [0, fx, W - 1 - cx], [0, 0, 1]]`` (skew s = 0 required), R and t are premultiplied by
    ``R_z = [[0, 1, 0], [-1, 0, 0], [0, 0, 1]]``, width and height swap.  Radial
    distortion (k1 k2 [k3 ...]) is symmetric about the principal point and is kept;
    tangential or thin-prism terms would turn with the image and are refused.

    Parameters
    ----------
    camera : Camera
    quarter_turns : int
        Any integer; taken modulo 4.

    Returns
    -------
    Camera
        Projects every world point to the turned image's pixel of the original's.

    Raises
    ------
    ValueError
        A camera with skew, or with non-radial distortion terms.
    """
    if abs(camera.K[0, 1]) > TOL.zero:
        raise ValueError(f"camera {camera.name!r}: cannot turn a camera with skew "
                         f"{camera.K[0, 1]}")
    radial = {0: (), 4: (0, 1), 5: (0, 1, 4), 8: (0, 1, 4, 5, 6, 7)}.get(camera.dist.size)
    other = np.delete(camera.dist, radial) if radial is not None else camera.dist
    if radial is None or np.any(other != 0):
        raise ValueError(f"camera {camera.name!r}: only radial distortion turns with the "
                         f"image (got coefficients {camera.dist.tolist()})")
    K, R, t = camera.K, camera.R, camera.t
    width, height = camera.width, camera.height
    for _ in range(int(quarter_turns) % 4):
        K = np.array([[K[1, 1], 0.0, K[1, 2]], [0.0, K[0, 0], width - 1 - K[0, 2]],
                      [0.0, 0.0, 1.0]])
        R, t = _QUARTER_TURN @ R, _QUARTER_TURN @ t
        width, height = height, width
    return Camera(K, camera.dist, R, t, width, height, camera.name)


# ------------------------------------------------------------------ quaternions
def rotation_to_quaternion(R) -> np.ndarray:
    """Rotation matrices (..., 3, 3) -> unit quaternions (..., 4) ``(w, x, y, z)``, w >= 0.

    Shepperd's method (the numerically stable branch per matrix), vectorised.
    """
    R = np.asarray(R, dtype=np.float64)
    m = R.reshape(-1, 3, 3)
    tr = np.trace(m, axis1=1, axis2=2)
    diag = np.diagonal(m, axis1=1, axis2=2)
    # four candidate (unnormalised) quaternions, pick the one with largest norm
    cand = np.stack([
        np.stack([1 + tr, m[:, 2, 1] - m[:, 1, 2], m[:, 0, 2] - m[:, 2, 0],
                  m[:, 1, 0] - m[:, 0, 1]], -1),
        np.stack([m[:, 2, 1] - m[:, 1, 2], 1 + 2 * diag[:, 0] - tr, m[:, 0, 1] + m[:, 1, 0],
                  m[:, 0, 2] + m[:, 2, 0]], -1),
        np.stack([m[:, 0, 2] - m[:, 2, 0], m[:, 0, 1] + m[:, 1, 0], 1 + 2 * diag[:, 1] - tr,
                  m[:, 1, 2] + m[:, 2, 1]], -1),
        np.stack([m[:, 1, 0] - m[:, 0, 1], m[:, 0, 2] + m[:, 2, 0], m[:, 1, 2] + m[:, 2, 1],
                  1 + 2 * diag[:, 2] - tr], -1),
    ], 1)  # (M, 4 candidates, 4)
    best = np.argmax(np.stack([tr, diag[:, 0], diag[:, 1], diag[:, 2]], -1), axis=1)
    q = cand[np.arange(len(m)), best]
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q *= np.where(q[:, :1] < 0, -1.0, 1.0)
    return q.reshape(R.shape[:-2] + (4,))


def quaternion_to_rotation(q) -> np.ndarray:
    """Quaternions (..., 4) ``(w, x, y, z)`` (normalised here) -> rotations (..., 3, 3)."""
    q = np.asarray(q, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], -2)
