r"""The synthetic scenes' geometry: shapes of revolution, poses, cameras with lens distortion, rays.

Shape.  A surface of revolution about the z axis with an elliptic cross-section,

.. math::  P(\theta, z) = \big(r(z)\,s_x(z)\cos\theta,\; r(z)\,s_y(z)\sin\theta,\; z\big),

with :math:`r` a C2 cubic spline through the recipe's profile points (and :math:`s_x, s_y`
constants or C2 splines), closed by flat caps; or any mesh file.  Then a rigid pose
:math:`X \mapsto R_o X + t_o` (:func:`shape_mesh`).

Cameras (OpenCV convention, Hartley & Zisserman §6.1 [2]_): world→camera :math:`x_c = R X + t`,
normalised :math:`(x, y) = (x_c/z_c, y_c/z_c)`, Brown–Conrady distortion [1]_
:math:`x_d = x(1 + k_1 r^2 + k_2 r^4 + k_3 r^6) + 2p_1xy + p_2(r^2 + 2x^2)` (and symmetrically for
y), pixel :math:`u = f_x x_d + c_x`.  Pixel centres are at integer coordinates.  Each ray is cast
through the *undistorted* direction of its distorted pixel position (:func:`undistort_pixels`,
:func:`pixel_rays`), so distortion is exact, not resampled.  Scene units; pixels for image
coordinates.

References
----------
.. [1] D. C. Brown, "Decentering distortion of lenses", Photogrammetric
   Engineering 32(3), 444–462 (1966).
.. [2] R. Hartley, A. Zisserman, "Multiple View Geometry in Computer Vision",
   2nd ed., Cambridge University Press (2004), §6.1 and §9.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np
from scipy.interpolate import CubicSpline
from scipy.spatial.transform import Rotation

from matching.cameras import Camera
from pipeline.errors import InputError
from pipeline.mesh_io import read_mesh
from pipeline.raycast import direction as view_direction
from pipeline.raycast import look_at
from pipeline.scene_texture import quiet_numba

__all__ = ["MIN_RADIAL_FACTOR", "TOL", "SceneTolerance", "fit_distance", "intrinsics",
           "make_camera", "make_cameras", "pixel_rays", "pose_matrix", "revolution_functions",
           "revolution_mesh", "rotation_about", "shape_mesh", "undistort_pixels"]


@dataclass(frozen=True)
class SceneTolerance:
    """Every epsilon of the scene generator, in the unit named."""

    #: A surface point counts as visible from a camera when the first hit along the
    #: ray towards it lies no closer than this fraction of its distance (float32
    #: ray casting is good to ~1e-6 relative; 1e-4 of 6 units ≈ 0.1 px here).
    occlusion_rel: float = 1e-4
    #: Largest reprojection error (px) tolerated when inverting the lens distortion.
    undistort_px: float = 1e-6
    #: Share of the image the object must cover for a camera to "see" it.
    min_coverage: float = 0.01
    #: Denominator guard of normalisations.
    zero: float = 1e-300
    #: Rounding slack on recipe sums that must not exceed 1 (ambient + diffuse).
    recipe_slack: float = 1e-12


TOL = SceneTolerance()


def revolution_functions(shape: dict):
    """C2 splines ``r(z)``, ``rx(z) = r sx``, ``ry(z) = r sy`` of a revolution shape."""
    profile = np.asarray(shape["profile"], dtype=np.float64)
    radius = CubicSpline(profile[:, 0], profile[:, 1])  # not-a-knot: C2, exact for cubics
    if "section_scale" in shape:
        rows = np.asarray(shape["section_scale"], dtype=np.float64)
        sx, sy = CubicSpline(rows[:, 0], rows[:, 1]), CubicSpline(rows[:, 0], rows[:, 2])
    else:
        sx0, sy0 = shape.get("scale_x", 1.0), shape.get("scale_y", 1.0)
        sx = lambda z, nu=0: np.full_like(z, sx0 if nu == 0 else 0.0, dtype=np.float64)
        sy = lambda z, nu=0: np.full_like(z, sy0 if nu == 0 else 0.0, dtype=np.float64)

    def radius_x(z, nu=0):
        return radius(z) * sx(z) if nu == 0 else radius(z, 1) * sx(z) + radius(z) * sx(z, 1)

    def radius_y(z, nu=0):
        return radius(z) * sy(z) if nu == 0 else radius(z, 1) * sy(z) + radius(z) * sy(z, 1)

    return radius, radius_x, radius_y


def revolution_mesh(shape: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Tessellate a surface of revolution (elliptic sections allowed) closed by flat caps.

    Parameters
    ----------
    shape : dict
        A validated ``shape`` table with ``kind = "revolution"``.

    Returns
    -------
    vertices : (V, 3) float64
    triangles : (F, 3) int64
        Counter-clockwise seen from outside; closed 2-manifold (shared vertices).
    corner_normals : (F, 3, 3) float64
        Unit normal at each triangle corner: the analytic normal
        :math:`P_\\theta \\times P_z` on the side, ∓z on the caps (so the rim
        stays a crease).

    Notes
    -----
    The side is an ``n_z × n_θ`` grid, rows equally spaced in profile arc length
    and columns in θ, with ``n_θ / n_z`` the ratio of mean circumference to
    profile length so that cells are near square; ``2 n_θ (n_z - 1) + 2 n_θ ≈``
    ``shape["triangles"]``.
    """
    _, radius_x, radius_y = revolution_functions(shape)
    profile = np.asarray(shape["profile"], dtype=np.float64)
    z0, z1 = profile[0, 0], profile[-1, 0]
    zz = np.linspace(z0, z1, 4001)
    rmean = 0.5 * (radius_x(zz) + radius_y(zz))
    slope = np.hypot(0.5 * (radius_x(zz, 1) + radius_y(zz, 1)), 1.0)
    arc = np.concatenate([[0.0], np.cumsum(0.5 * (slope[1:] + slope[:-1]) * np.diff(zz))])
    circumference = 2 * np.pi * rmean.mean()
    budget = shape["triangles"]
    n_theta = max(8, int(round(math.sqrt(budget / 2 * circumference / arc[-1]))))
    n_z = max(2, int(round(budget / (2 * n_theta))))
    z = np.interp(np.linspace(0.0, arc[-1], n_z), arc, zz)
    z[0], z[-1] = z0, z1
    theta = 2 * np.pi * np.arange(n_theta) / n_theta
    c, s = np.cos(theta)[None, :], np.sin(theta)[None, :]
    rx, ry = radius_x(z)[:, None], radius_y(z)[:, None]
    drx, dry = radius_x(z, 1)[:, None], radius_y(z, 1)[:, None]
    side = np.stack([rx * c, ry * s, np.broadcast_to(z[:, None], (n_z, n_theta))], axis=-1)
    # P_theta x P_z = (ry cos, rx sin, -(rx ry' sin^2 + ry rx' cos^2)): outward
    normal = np.stack([ry * c, rx * s, -(rx * dry * s**2 + ry * drx * c**2)], axis=-1)
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    vertices = np.concatenate([side.reshape(-1, 3), [[0.0, 0.0, z0], [0.0, 0.0, z1]]])
    vnormal = normal.reshape(-1, 3)
    bottom, top = n_z * n_theta, n_z * n_theta + 1

    i, j = np.meshgrid(np.arange(n_z - 1), np.arange(n_theta), indexing="ij")
    a = i * n_theta + j
    b = i * n_theta + (j + 1) % n_theta
    quad_c, quad_d = b + n_theta, a + n_theta
    side_tri = np.concatenate([np.stack([a, b, quad_c], -1).reshape(-1, 3),
                               np.stack([a, quad_c, quad_d], -1).reshape(-1, 3)])
    ring = np.arange(n_theta)
    nxt = (ring + 1) % n_theta
    top_ring = (n_z - 1) * n_theta
    cap_bottom = np.stack([np.full(n_theta, bottom), nxt, ring], -1)
    cap_top = np.stack([np.full(n_theta, top), top_ring + ring, top_ring + nxt], -1)
    triangles = np.concatenate([side_tri, cap_bottom, cap_top]).astype(np.int64)
    corner = np.empty((len(triangles), 3, 3))
    corner[: len(side_tri)] = vnormal[side_tri]
    corner[len(side_tri): len(side_tri) + n_theta] = [0.0, 0.0, -1.0]
    corner[len(side_tri) + n_theta:] = [0.0, 0.0, 1.0]
    return vertices, triangles, corner


def _corner_normals_from_mesh(vertices: np.ndarray, triangles: np.ndarray,
                              crease_deg: float = 60.0) -> np.ndarray:
    """Area-weighted vertex normals per corner, face normal where the corner is a crease.

    Returns
    -------
    (F, 3, 3) float64 unit normals.
    """
    tri = vertices[triangles]  # (F, 3, 3)
    face = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # length = 2 * area
    vnormal = np.zeros_like(vertices)
    for k in range(3):
        np.add.at(vnormal, triangles[:, k], face)
    vnormal /= np.maximum(np.linalg.norm(vnormal, axis=1, keepdims=True), TOL.zero)
    unit_face = face / np.maximum(np.linalg.norm(face, axis=1, keepdims=True), TOL.zero)
    corner = vnormal[triangles]  # (F, 3, 3)
    crease = np.einsum("fkc,fc->fk", corner, unit_face) < math.cos(math.radians(crease_deg))
    corner[crease] = np.broadcast_to(unit_face[:, None, :], corner.shape)[crease]
    return corner


def rotation_about(axis, angle_deg: float) -> np.ndarray:
    axis = np.asarray(axis, dtype=np.float64)
    return Rotation.from_rotvec(axis / np.linalg.norm(axis) * math.radians(angle_deg)).as_matrix()


def pose_matrix(pose: dict) -> tuple[np.ndarray, np.ndarray]:
    """Rotation ``(3, 3)`` and translation ``(3,)`` of a validated ``shape.pose`` table."""
    if "euler_xyz_deg" in pose:
        rotation = Rotation.from_euler("xyz", pose["euler_xyz_deg"], degrees=True).as_matrix()
    else:
        rotation = rotation_about(pose["rotation_axis"], pose["rotation_deg"])
    return rotation, np.asarray(pose["translation"], dtype=np.float64)


def shape_mesh(shape: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The posed mesh of a validated ``shape`` table: ``vertices, triangles, corner_normals``."""
    if shape["kind"] == "revolution":
        vertices, triangles, corner = revolution_mesh(shape)
    else:
        vertices, triangles = read_mesh(shape["path"])
        vertices = vertices * shape["scale"]
        align, _ = Rotation.align_vectors([[0.0, 0.0, 1.0]], [shape["axis"]])
        vertices = vertices @ align.as_matrix().T
        corner = _corner_normals_from_mesh(vertices, triangles)
    rotation, translation = pose_matrix(shape["pose"])
    return vertices @ rotation.T + translation, triangles, corner @ rotation.T


@numba.njit(parallel=True, cache=True)
def _undistort_newton(target, dist, out):  # pragma: no cover - compiled
    """Per point Newton on the Brown–Conrady model (see :func:`_distort`), from the target."""
    k1, k2, p1, p2, k3 = dist[0], dist[1], dist[2], dist[3], dist[4]
    for i in numba.prange(target.shape[0]):
        tx, ty = target[i, 0], target[i, 1]
        x, y = tx, ty
        for _ in range(50):
            r2 = x * x + y * y
            radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
            ex = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x) - tx
            ey = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y - ty
            if abs(ex) <= 1e-15 and abs(ey) <= 1e-15:  # normalised: ~1e-12 px
                break
            slope = 2.0 * (k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2))
            a = radial + x * x * slope + 2.0 * p1 * y + 6.0 * p2 * x
            b = x * y * slope + 2.0 * p1 * x + 2.0 * p2 * y
            d = radial + y * y * slope + 6.0 * p1 * y + 2.0 * p2 * x
            det = a * d - b * b
            if det == 0.0:
                break
            x -= (d * ex - b * ey) / det
            y -= (a * ey - b * ex) / det
        out[i, 0] = x
        out[i, 1] = y


def intrinsics(cams: dict) -> tuple[np.ndarray, np.ndarray]:
    f = cams["focal_px"]
    cx, cy = cams["principal_point"]
    return np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]]), np.asarray(
        cams["distortion"], dtype=np.float64)


def make_camera(index: int, position, rotation, K, dist, cams) -> Camera:
    """Camera number ``index`` (named after its image, ``view_XX.png``) at ``position``."""
    return Camera(K, dist, rotation, -rotation @ position, cams["width"], cams["height"],
                  f"view_{index:02d}.png")


def _stereo_cameras(cams: dict, centre: np.ndarray, distance: float) -> list[Camera]:
    """Left and right camera: midpoint at ``distance`` from the centre, toed in symmetrically."""
    K, dist = intrinsics(cams)
    view = view_direction(cams["azimuth_deg"], cams["elevation_deg"])
    middle = centre + distance * view
    mid_rotation = look_at(middle, centre)
    right_axis = mid_rotation[0]
    baseline = cams.get("baseline", 0.25 * distance)  # base/distance 1:4 by default
    convergence = cams.get("convergence_deg",
                           math.degrees(2.0 * math.atan2(0.5 * baseline, distance)))
    out = []
    for index, side in ((0, -1.0), (1, 1.0)):
        position = middle + side * 0.5 * baseline * right_axis
        # toe-in: turn about the image's down axis by ±convergence/2 from the parallel pose
        turn = rotation_about(mid_rotation[1], -side * 0.5 * convergence)
        rotation = mid_rotation @ turn.T
        out.append(make_camera(index, position, rotation, K, dist, cams))
    return out


def _ring_cameras(cams: dict, centre: np.ndarray, radius: float) -> list[Camera]:
    K, dist = intrinsics(cams)
    rings = [(cams["n"], cams["elevation_deg"], cams["azimuth_deg"])]
    if "second_ring" in cams:
        second = cams["second_ring"]
        rings.append((second["n"], second["elevation_deg"],
                      cams["azimuth_deg"] + second["azimuth_offset_deg"]))
    out = []
    for n, elevation, azimuth0 in rings:
        for k in range(n):
            position = centre + radius * view_direction(azimuth0 + 360.0 * k / n, elevation)
            out.append(make_camera(len(out), position, look_at(position, centre), K, dist,
                                    cams))
    return out


def make_cameras(cams: dict, centre: np.ndarray, distance: float) -> list[Camera]:
    """Cameras of a validated ``cameras`` table at ``distance`` (ring radius) from ``centre``."""
    if cams["layout"] == "stereo":
        return _stereo_cameras(cams, centre, distance)
    return _ring_cameras(cams, centre, distance)


def fit_distance(cams: dict, centre: np.ndarray, corners: np.ndarray, bound: float) -> float:
    """Smallest distance at which the object fills ``fill`` of every image (pinhole model).

    ``corners (N, 3)`` are points of the object (a sample of its vertices); ``bound`` the
    radius of a sphere about ``centre`` holding them.  Bisection on the distance (the
    projected extent shrinks monotonically once the cameras are outside that sphere).
    """
    def too_big(distance):
        for cam in make_cameras(cams, centre, distance):
            xc = corners @ cam.R.T + cam.t
            if np.any(xc[:, 2] <= 0):
                return True
            x = cam.K[0, 0] * xc[:, 0] / xc[:, 2]
            y = cam.K[1, 1] * xc[:, 1] / xc[:, 2]
            if (np.abs(x).max() > 0.5 * cams["fill"] * cam.width
                    or np.abs(y).max() > 0.5 * cams["fill"] * cam.height):
                return True
        return False

    lo, hi = 1.001 * bound, 1.001 * bound
    while too_big(hi):
        hi *= 2.0
        if hi > 1e6 * bound:
            raise InputError("field cameras.fill: no camera distance fits the object")
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if too_big(mid) else (lo, mid)
    return hi


def _distort(xy: np.ndarray, dist: np.ndarray, jacobian: bool = False):
    """Brown–Conrady distortion of normalised coordinates ``(N, 2)`` (OpenCV's model [1]).

    With ``jacobian`` also return the 2×2 derivative as four ``(N,)`` arrays
    ``(dxd/dx, dxd/dy, dyd/dx, dyd/dy)``.
    """
    k1, k2, p1, p2, k3 = (float(c) for c in dist)
    x, y = xy[:, 0], xy[:, 1]
    r2 = x * x + y * y
    radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    distorted = np.stack([x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x),
                          y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y], axis=1)
    if not jacobian:
        return distorted
    slope = 2 * (k1 + r2 * (2 * k2 + 3 * k3 * r2))  # d(radial)/d(r2) * 2
    cross = x * y * slope + 2 * p1 * x + 2 * p2 * y
    return distorted, (radial + x * x * slope + 2 * p1 * y + 6 * p2 * x, cross, cross,
                       radial + y * y * slope + 6 * p1 * y + 2 * p2 * x)


#: Smallest radial factor ``1 + k1 r² + k2 r⁴ + k3 r⁶`` over an image (and the inverse
#: largest) accepted as a lens distortion (:func:`undistort_pixels`).
MIN_RADIAL_FACTOR = 0.5


def undistort_pixels(pixels: np.ndarray, camera: Camera) -> np.ndarray:
    """Normalised undistorted coordinates ``(N, 2)`` of distorted ``pixels (N, 2)``.

    Newton's method on the exact forward model with its analytic Jacobian,
    started at the distorted coordinates, per point until the model reproduces
    it to ~1e-12 px (quadratic convergence: 3–5 steps), then checked against
    ``TOL.undistort_px``.

    Raises
    ------
    InputError
        When the distortion cannot be inverted over the image: Newton does not
        converge, or the model folds over (Jacobian determinant ≤ 0) or flips
        through the centre (radial factor ≤ 0).
    """
    K = camera.K
    pixels = np.asarray(pixels, dtype=np.float64)
    target = np.stack([(pixels[:, 0] - K[0, 2]) / K[0, 0], (pixels[:, 1] - K[1, 2]) / K[1, 1]], 1)
    if not np.any(camera.dist) or len(target) == 0:
        return target
    xy = np.empty_like(target)
    quiet_numba(_undistort_newton, target, np.asarray(camera.dist[:5], np.float64), xy)
    distorted, (a, b, c, d) = _distort(xy, camera.dist, jacobian=True)
    error_px = np.abs(distorted - target).max() * K[0, 0]
    k1, k2, _, _, k3 = camera.dist[:5]
    r2 = (xy**2).sum(axis=1)
    radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    # a genuine inverse keeps both principal stretches positive: radial factor > 0 (no
    # flip through the centre) and det J > 0 (no fold)
    if not (error_px <= TOL.undistort_px and np.all(radial > 0) and np.all(a * d - b * c > 0)):
        raise InputError(f"field cameras.distortion: {camera.dist.tolist()} cannot be inverted "
                         f"over the image of {camera.name} (residual {error_px:.2g} px)")
    # the 5-coefficient model is a lens's correction of the pinhole: a radial factor past
    # [1/2, 2] moves image points by as much as their own distance from the centre (k1 =
    # 1e6 shrinks the view to a pinhole's 1/100): no lens this model describes (a wide
    # angle's barrel stays near 0.7 at the corners; fisheyes need another model)
    if radial.min() < MIN_RADIAL_FACTOR or radial.max() > 1 / MIN_RADIAL_FACTOR:
        raise InputError(f"field cameras.distortion: {camera.dist.tolist()} scales the image "
                         f"of {camera.name} by {radial.min():.3g}..{radial.max():.3g} from its "
                         f"centre: a lens distortion stays within {MIN_RADIAL_FACTOR:g}.."
                         f"{1 / MIN_RADIAL_FACTOR:g}")
    return xy


def pixel_rays(camera: Camera, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rays through distorted ``pixels (N, 2)``: origin ``(3,)`` and directions ``(N, 3)``.

    Each direction has camera-frame z component exactly 1, so the ray parameter
    of a hit is its depth ``z_c``.
    """
    xy = undistort_pixels(pixels, camera)
    R = camera.R  # directions Rᵀ (x, y, 1), written out: (N, 3) @ (3, 3) is slow in BLAS
    directions = xy[:, 0:1] * R[0] + xy[:, 1:2] * R[1] + R[2]
    return camera.center, directions
