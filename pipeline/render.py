"""Headless CPU rendering of a triangle mesh: a shaded contact sheet of views.

Each pixel's ray is cast with open3d's ``RaycastingScene`` (Embree on the CPU, no
display or GPU needed), and shaded in numpy with the Blinn-Phong model [1]_ [2]_

.. math::

    c = \\rho\\,\\Big(k_a + \\sum_l k_l \\max(0, \\mathbf n\\cdot\\mathbf l)\\Big)
        + k_s \\sum_l k_l \\max(0, \\mathbf n\\cdot\\mathbf h_l)^{\\alpha},
    \\qquad \\mathbf h_l = \\frac{\\mathbf l + \\mathbf v}{\\lVert\\mathbf l + \\mathbf v\\rVert},

in linear light, then encoded with the sRGB transfer curve.  The normal :math:`\\mathbf n`
is the barycentric interpolation of the vertex normals at the hit point (Phong
interpolation: a finely tessellated smooth surface looks smooth, not faceted).  Lights are
fixed to the camera (a key light above-left, a fill light right), so every view is lit
alike; surfaces are lit from both sides.  Anti-aliasing is adaptive [4]_: one ray per
pixel centre, then ``supersample²`` rays averaged in linear light wherever a pixel's
colour or hit status differs from a neighbour's (:func:`render_view`).

Cameras follow the OpenCV convention (``x_c = R X + t``, pixel centres at integer
coordinates, y down); the world's +z axis is up in every view.  The camera looks at the
bounding box's centre from azimuth φ and elevation θ, at the distance where the bounding
sphere fills ``fill`` of the smaller tile side.

With a truth mesh, the surface is coloured by each vertex's distance to the truth
(signed, negative inside, with a diverging blue-white-red map [3]_ when the truth is
closed; unsigned with viridis otherwise), interpolated across triangles, with a scale bar;
error colours are shaded without the specular term (a pixel's chromaticity is the map's).

References
----------
.. [1] B. T. Phong, "Illumination for computer generated pictures",
       Communications of the ACM 18(6), pp. 311-317 (1975).
.. [2] J. F. Blinn, "Models of light reflection for computer synthesized
       pictures", Proc. SIGGRAPH '77, pp. 192-198 (1977).
.. [3] K. Moreland, "Diverging color maps for scientific visualization",
       ISVC 2009, LNCS 5876, pp. 92-103 (2009).
.. [4] T. Whitted, "An improved illumination model for shaded display",
       Communications of the ACM 23(6), pp. 343-349 (1980).
"""

from __future__ import annotations

import functools
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipeline.atomic import atomic_file
from pipeline.export import vertex_normals
from pipeline.raycast import RayCaster, look_at_rotation
from pipeline.raycast import direction as view_direction
from surface.validate import TOL, check_finite, check_shape


@dataclass(frozen=True)
class Lighting:
    """Blinn-Phong parameters (linear light, fractions of full white).

    ``albedo · (ambient + key + fill) + specular`` stays below 1 so that no
    lit pixel is ever pure white (the default background).
    """

    albedo: tuple[float, float, float] = (0.62, 0.66, 0.74)  # a light blue-grey
    ambient: float = 0.10
    key: float = 0.72
    fill: float = 0.18
    specular: float = 0.18
    shininess: float = 40.0
    #: Key light direction in the camera frame (x right, y down, z forward),
    #: pointing from the surface towards the light: above-left, behind the eye.
    key_dir: tuple[float, float, float] = (-0.45, -0.6, -1.0)
    fill_dir: tuple[float, float, float] = (0.8, 0.1, -0.6)


#: Field of view of every view (horizontal = vertical, square pixels), degrees.
FOV_DEG = 30.0
#: Share of the tile's smaller side the bounding sphere's image spans.
FILL = 0.92
#: Default elevation of the two rows of the contact sheet, degrees.
ELEVATION_DEG = 25.0

# Moreland's cool-warm diverging map [3]: its end colours (sRGB 8-bit) and the
# Msh magnitude of its white midpoint.
_COOL, _WARM, _MID_M = (59, 76, 192), (180, 4, 38), 88.0
# D65 white in XYZ and the sRGB -> XYZ matrix (IEC 61966-2-1).
_D65 = np.array([0.95047, 1.0, 1.08883])
_SRGB_TO_XYZ = np.array([[0.4124564, 0.3575761, 0.1804375],
                         [0.2126729, 0.7151522, 0.0721750],
                         [0.0193339, 0.1191920, 0.9503041]])


# --------------------------------------------------------------------------- cameras


def default_views(n_views: int = 6, elevation_deg: float = ELEVATION_DEG
                  ) -> list[tuple[float, float]]:
    """Viewpoints ``(azimuth, elevation)`` in degrees around the object.

    Azimuths at ``360/n`` steps; with more than three views the elevation
    alternates ``+elevation`` / ``-elevation`` (six views: 60° steps, the
    top row seen from above, the bottom row from below).
    """
    if n_views < 1:
        raise ValueError(f"views must be at least 1, got {n_views}")
    views = []
    for k in range(n_views):
        el = elevation_deg if n_views <= 3 or k % 2 == 0 else -elevation_deg
        views.append((360.0 * k / n_views, el))
    return views


def _grid(n_views: int) -> tuple[int, int]:
    """(rows, cols) of the sheet: one row up to three views, else two rows."""
    return (1, n_views) if n_views <= 3 else (2, math.ceil(n_views / 2))


def look_at(center: np.ndarray, radius: float, azimuth_deg: float, elevation_deg: float,
            width: int, height: int, fov_deg: float = FOV_DEG, fill: float = FILL
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """An OpenCV pinhole camera looking at a bounding sphere.

    Parameters
    ----------
    center : (3,) float64
        Bounding-sphere centre, scene units.
    radius : float
        Bounding-sphere radius, scene units.
    azimuth_deg, elevation_deg : float
        Direction from the centre to the eye (azimuth about +z from +x).
    width, height : int
        Image size in pixels.
    fov_deg : float
        Field of view across the smaller image side.
    fill : float
        Share of the smaller side the sphere's image spans; the eye distance
        ``d = r / sin(atan(fill · tan(fov/2)))`` follows.

    Returns
    -------
    K : (3, 3) float64
    R : (3, 3) float64
    t : (3,) float64
        ``x_c = R X + t``.
    """
    half = math.radians(fov_deg) / 2.0
    focal = 0.5 * min(width, height) / math.tan(half)
    distance = radius / math.sin(math.atan(fill * math.tan(half)))
    outward = view_direction(azimuth_deg, elevation_deg)
    eye = np.asarray(center, dtype=np.float64) + distance * outward
    az = math.radians(azimuth_deg)  # looking straight up/down: any horizontal right will do
    R = look_at_rotation(-outward, fallback_right=np.array([-math.sin(az), math.cos(az), 0.0]))
    K = np.array([[focal, 0.0, (width - 1) / 2.0], [0.0, focal, (height - 1) / 2.0],
                  [0.0, 0.0, 1.0]])
    return K, R, -R @ eye


def camera_rays(K: np.ndarray, R: np.ndarray, t: np.ndarray, width: int, height: int,
                supersample: int = 1) -> np.ndarray:
    """Rays through pixel centres, ``supersample²`` per pixel.

    Returns
    -------
    rays : (height·s, width·s, 6) float32
        Origin and unit direction per sub-pixel; sub-pixel ``(x', y')`` has
        centre ``((x' + 0.5) / s - 0.5, (y' + 0.5) / s - 0.5)`` in the
        pixel grid, so a box filter over each s×s block recovers pixel ``(x, y)``.
    """
    s = supersample
    xs = (np.arange(width * s) + 0.5) / s - 0.5
    ys = (np.arange(height * s) + 0.5) / s - 0.5
    grid_x, grid_y = np.meshgrid(xs, ys)  # (Hs, Ws)
    return rays_through(K, R, t, grid_x, grid_y)


def rays_through(K: np.ndarray, R: np.ndarray, t: np.ndarray, x: np.ndarray,
                 y: np.ndarray) -> np.ndarray:
    """Rays ``(..., 6) float32`` (origin, unit direction) through image points ``x, y``
    (pixels, any equal shapes)."""
    pixels = np.stack([x, y, np.ones_like(x)], axis=-1)
    dirs = pixels @ (np.linalg.inv(K).T @ R)  # R^T K^-1 x, row-vector form
    dirs /= np.linalg.norm(dirs, axis=-1, keepdims=True)
    eye = -R.T @ t
    origins = np.broadcast_to(eye, dirs.shape)
    return np.concatenate([origins, dirs], axis=-1).astype(np.float32)


def pixel_footprint(radius: float, width: int, height: int, fov_deg: float = FOV_DEG,
                    fill: float = FILL) -> float:
    """Smallest length on the object one pixel spans in a :func:`look_at` view, scene units.

    Every point of the bounding sphere (radius ``r``, eye distance ``d``) is at least
    ``d - r`` from the eye and within the sphere's angular radius ``asin(r / d)`` of the
    optical axis, where a pixel subtends at least ``cos²`` of the ``1 / f`` radians it
    subtends on the axis; so a pixel covers at least ``(d - r) cos²(asin(r/d)) / f``.
    A surface approximated within a fraction of this moves no pixel's content by more
    than that fraction of a pixel.
    """
    half = math.radians(fov_deg) / 2.0
    focal = 0.5 * min(width, height) / math.tan(half)
    distance = radius / math.sin(math.atan(fill * math.tan(half)))
    return (distance - radius) * (1.0 - (radius / distance) ** 2) / focal


def screen_tessellation(control_points: np.ndarray, triangles: np.ndarray, width: int,
                        height: int, supersample: int = 2, radius: float | None = None,
                        max_segments: int = 32
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """A Bézier surface tessellated for :func:`look_at` views of ``width`` × ``height``.

    The chord tolerance is half a sub-pixel, ``δ = pixel_footprint / (2 s)``
    (:func:`pixel_footprint`): no silhouette or shading sample moves by more than half
    the spacing of the rays that draw it, however finely the surface was tessellated
    for export: every patch is cut until its pieces lie within ``δ`` of their own
    corners' planes (:func:`surface.bezier.certified_segments`: what moves a pixel is the
    surface's distance *across* its flat triangles), welded and crack-free across patch
    edges (:func:`surface.bezier.tessellate_adaptive`).

    Parameters
    ----------
    control_points : (P, 28, 3) float64
        Sextic nets (``smooth/control_net.npz``).
    triangles : (P, 3) int
        Their domain triangles (shared vertices: a welded result).
    width, height : int
        Pixels of one view.
    supersample : int
        Rays per pixel side of :func:`render_view`'s anti-aliasing.
    radius : float, optional
        Bounding-sphere radius of the surface as rendered, scene units (default: from
        the patches' corners, which lie on the surface, so no larger than the surface's:
        the footprint, and with it the tolerance, is not overestimated).
    max_segments : int
        Cap of the cuts per patch edge.

    Returns
    -------
    vertices (V, 3), triangles (F, 3), normals (V, 3)
        Points and exact unit normals of the surface; counter-clockwise as the domain.
    tolerance : float
        ``δ``, scene units.
    """
    from surface import bezier

    cp = check_shape(control_points, "(P, 28, 3)", "control_points", dtype=np.float64)
    if radius is None:
        corners = cp[:, [0, 21, 27]].reshape(-1, 3)
        centre = 0.5 * (corners.min(axis=0) + corners.max(axis=0))
        radius = float(np.sqrt(((corners - centre) ** 2).sum(axis=1).max()))
    footprint = pixel_footprint(max(float(radius), TOL.zero), width, height)
    tolerance = footprint / (2.0 * max(int(supersample), 1))
    cuts = bezier.certified_segments(cp, tolerance, max_segments)
    if cuts.max(initial=1) == 1:  # one flat triangle a patch: the uniform level 0, faster
        vertices, faces, normals = bezier.tessellate(cp, 0, triangles)
    else:
        vertices, faces, normals = bezier.tessellate_adaptive(cp, tolerance, triangles,
                                                              segments=cuts.astype(np.int64))
    return vertices, faces, normals, tolerance


# --------------------------------------------------------------------------- shading


def _srgb(linear: np.ndarray) -> np.ndarray:
    """The sRGB transfer curve (IEC 61966-2-1), linear [0, 1] -> encoded [0, 1]."""
    linear = np.clip(linear, 0.0, 1.0)
    return np.where(linear <= 0.0031308, 12.92 * linear,
                    1.055 * np.power(linear, 1 / 2.4) - 0.055)


def _linear(encoded: np.ndarray) -> np.ndarray:
    """Inverse of :func:`_srgb`."""
    encoded = np.clip(encoded, 0.0, 1.0)
    return np.where(encoded <= 0.04045, encoded / 12.92, ((encoded + 0.055) / 1.055) ** 2.4)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), TOL.zero)


def _shade(normals: np.ndarray, view_dirs: np.ndarray, albedo: np.ndarray, R: np.ndarray,
           lighting: Lighting, specular: bool) -> np.ndarray:
    """Blinn-Phong colour in linear light.

    normals, view_dirs : (M, 3) unit, world frame (view_dirs along the rays)
    albedo : (M, 3) or (3,) linear reflectance
    Returns (M, 3) linear colour.
    """
    flip = np.einsum("ij,ij->i", normals, view_dirs) > 0  # lit from both sides
    normals = np.where(flip[:, None], -normals, normals)
    to_eye = -view_dirs
    diffuse = np.full(len(normals), lighting.ambient)
    highlight = np.zeros(len(normals))
    for weight, direction in ((lighting.key, lighting.key_dir), (lighting.fill, lighting.fill_dir)):
        light = _unit(R.T @ np.asarray(direction, dtype=np.float64))  # camera -> world
        diffuse += weight * np.clip(normals @ light, 0.0, None)
        if specular:
            half = _unit(light[None, :] + to_eye)
            highlight += weight * np.clip(np.einsum("ij,ij->i", normals, half), 0.0,
                                          None) ** lighting.shininess
    return albedo * diffuse[:, None] + lighting.specular * highlight[:, None]


#: Adaptive anti-aliasing: a pixel is supersampled when its centre ray's colour differs
#: from an 8-neighbour's by more than this many 8-bit sRGB levels in a channel, or one of
#: the two hits the object and the other does not.
AA_CONTRAST = 4.0


def render_view(scene, vertices: np.ndarray, triangles: np.ndarray, normals: np.ndarray,
                K: np.ndarray, R: np.ndarray, t: np.ndarray, width: int, height: int,
                supersample: int = 2, lighting: Lighting = Lighting(),
                vertex_values: np.ndarray | None = None, colormap=None,
                background=(255, 255, 255), smooth: bool = True) -> np.ndarray:
    """Render one view of a mesh already loaded in ``scene``.

    Anti-aliasing is adaptive (Whitted [4]_): one ray through every pixel centre, then ``s²`` rays
    (sub-pixel centres as :func:`camera_rays`, averaged in linear light: a box filter)
    only for the pixels whose colour differs from a neighbour's by more than
    :data:`AA_CONTRAST` levels or whose neighbour's ray has the other hit status
    (silhouettes, occlusion edges, highlights' rims).  Elsewhere the shading changes by
    less than :data:`AA_CONTRAST` levels per pixel, and the centre sample differs from
    the box filter's mean only by the curvature term, about 1/24 of the second
    difference (< 1 level): the same image as supersampling every pixel, for about
    ``1 + s² e`` rays per pixel instead of ``s²`` (``e`` the share of edge pixels, a few
    percent).  Detail thinner than a pixel that no centre ray hits is not seen.

    Parameters
    ----------
    scene : pipeline.raycast.RayCaster
        Holding exactly the mesh ``(vertices, triangles)``.
    vertices : (V, 3) float64
    triangles : (F, 3) int64
    normals : (V, 3) float64, unit vertex normals
    K, R, t : camera, see :func:`look_at`
    width, height : int, output size in pixels
    supersample : int
        Rays per pixel side at the edges (anti-aliasing); 1 disables it.
    lighting : Lighting
    vertex_values : (V,) float64, optional
        Scalars mapped through ``colormap`` (interpolated per pixel); the
        specular term is then left out.
    colormap : callable, optional
        ``(M,) values -> (M, 3) sRGB in [0, 1]``.
    background : 3 ints, RGB
    smooth : bool
        Interpolated vertex normals (default) or the flat face normals.

    Returns
    -------
    image : (height, width, 3) uint8, RGB
    """
    def shade(rays):
        return _shade_rays(scene, rays, triangles, normals, R, lighting, vertex_values,
                           colormap, background, smooth)

    s = int(supersample)
    ys, xs = np.mgrid[0:height, 0:width].astype(np.float64)
    image, hit = shade(rays_through(K, R, t, xs, ys))  # (H·W, 3) linear, (H·W,)
    image = image.reshape(height, width, 3)
    if s > 1:
        edge = _edges(_srgb(image) * 255.0, hit.reshape(height, width), AA_CONTRAST)
        py, px = np.nonzero(edge)
        if len(py):
            offsets = (np.arange(s) + 0.5) / s - 0.5  # sub-pixel centres, as camera_rays
            sub_y, sub_x = np.broadcast_arrays(py[:, None, None] + offsets[None, :, None],
                                               px[:, None, None] + offsets[None, None, :])
            sub, _ = shade(rays_through(K, R, t, sub_x, sub_y))  # (M·s², 3), row-major
            # sub-pixels are averaged in linear light (a pixel's light is the sum of its
            # parts), then encoded
            image[py, px] = sub.reshape(len(py), s * s, 3).mean(axis=1)
    return np.clip(np.rint(_srgb(image) * 255.0), 0, 255).astype(np.uint8)


def _edges(encoded: np.ndarray, hit: np.ndarray, contrast: float) -> np.ndarray:
    """``(H, W)`` bool: pixels differing from an 8-neighbour by more than ``contrast``
    levels in a channel of ``encoded (H, W, 3)``, or in ``hit (H, W)``."""
    edge = np.zeros(hit.shape, dtype=bool)
    height, width = hit.shape
    for dy, dx in ((0, 1), (1, 0), (1, 1), (1, -1)):
        a = (slice(0, height - dy), slice(max(0, -dx), width - max(0, dx)))
        b = (slice(dy, height), slice(max(0, dx), width - max(0, -dx)))
        gap = np.abs(encoded[a] - encoded[b])
        # the channels' largest by two elementwise maxima (a reduction over the last axis
        # of 3 is ~6x slower; the same values)
        most = np.maximum(np.maximum(gap[..., 0], gap[..., 1]), gap[..., 2])
        differ = (most > contrast) | (hit[a] != hit[b])
        edge[a] |= differ
        edge[b] |= differ
    return edge


def _shade_rays(scene, rays, triangles, normals, R, lighting, vertex_values, colormap,
                background, smooth) -> tuple[np.ndarray, np.ndarray]:
    """Linear colour ``(N, 3)`` (background where a ray misses) and hit mask ``(N,)`` of
    ``rays (..., 6)``."""
    hits = scene.cast_rays(rays)
    hit = np.isfinite(hits["t_hit"])
    face = hits["primitive_ids"][hit].astype(np.int64)
    uv = hits["primitive_uvs"][hit].astype(np.float64)
    bary = np.column_stack([1.0 - uv.sum(axis=1), uv])  # (M, 3): weights of corners 0, 1, 2
    corners = triangles[face]  # (M, 3)
    if smooth:
        normal = _unit(np.einsum("mc,mcx->mx", bary, normals[corners]))
    else:
        normal = hits["primitive_normals"][hit].astype(np.float64)
    view_dirs = rays.reshape(-1, 6)[hit, 3:].astype(np.float64)
    if vertex_values is None:
        albedo = np.asarray(lighting.albedo, dtype=np.float64)
    else:
        value = np.einsum("mc,mc->m", bary, vertex_values[corners])
        albedo = _linear(colormap(value))
    colour = _shade(normal, view_dirs, albedo, R, lighting, specular=vertex_values is None)
    out = np.empty((hit.size, 3))
    out[:] = _linear(np.asarray(background, dtype=np.float64) / 255.0)
    out[hit] = np.clip(colour, 0.0, 1.0)
    return out, hit


# --------------------------------------------------------------------------- error colours


def _lab_f(t):
    return np.where(t > (6 / 29) ** 3, np.cbrt(t), t / (3 * (6 / 29) ** 2) + 4 / 29)


def _lab_finv(f):
    return np.where(f > 6 / 29, f**3, 3 * (6 / 29) ** 2 * (f - 4 / 29))


def _srgb_to_msh(rgb: np.ndarray) -> np.ndarray:
    """sRGB [0, 1] -> CIELAB (D65) -> Moreland's polar (M, s, h) [3]_."""
    f = _lab_f(_linear(rgb) @ _SRGB_TO_XYZ.T / _D65)
    lab = np.stack([116 * f[..., 1] - 16, 500 * (f[..., 0] - f[..., 1]),
                    200 * (f[..., 1] - f[..., 2])], axis=-1)
    m = np.linalg.norm(lab, axis=-1)
    return np.stack([m, np.arccos(lab[..., 0] / m), np.arctan2(lab[..., 2], lab[..., 1])], -1)


def _msh_to_srgb(msh: np.ndarray) -> np.ndarray:
    m, s, h = msh[..., 0], msh[..., 1], msh[..., 2]
    lab_l, lab_a, lab_b = m * np.cos(s), m * np.sin(s) * np.cos(h), m * np.sin(s) * np.sin(h)
    fy = (lab_l + 16) / 116
    xyz = _D65 * np.stack([_lab_finv(fy + lab_a / 500), _lab_finv(fy),
                           _lab_finv(fy - lab_b / 200)], axis=-1)
    return _srgb(xyz @ np.linalg.inv(_SRGB_TO_XYZ).T)


@functools.cache
def _coolwarm_table(size: int = 257) -> np.ndarray:
    """Moreland's diverging interpolation in Msh through a white midpoint [3]_, (size, 3)."""
    cool, warm = (_srgb_to_msh(np.asarray(c, dtype=np.float64) / 255.0) for c in (_COOL, _WARM))
    mid = max(cool[0], warm[0], _MID_M)

    def spin(saturated, m_unsat):
        # hue shift so the unsaturated end bends towards the white point (paper eq. 7)
        m, s, h = saturated
        turn = s * np.sqrt(m_unsat**2 - m**2) / (m * np.sin(s))
        return h + turn if h > -np.pi / 3 else h - turn

    x = np.linspace(0.0, 1.0, size)
    lower, w = x < 0.5, np.where(x < 0.5, 2 * x, 2 * x - 1)[:, None]
    start = np.where(lower[:, None], cool, [mid, 0.0, 0.0])
    end = np.where(lower[:, None], [mid, 0.0, spin(cool, mid)], warm)
    start[~lower, 2] = spin(warm, mid)
    table = _msh_to_srgb((1 - w) * start + w * end)
    table.flags.writeable = False
    return table


def coolwarm(values: np.ndarray) -> np.ndarray:
    """Moreland's cool-warm diverging map [3]_: ``values`` in [0, 1] -> (M, 3) sRGB in [0, 1].

    Blue (59, 76, 192) at 0, white-grey (≈ 221, 221, 221) at 0.5, red
    (180, 4, 38) at 1, interpolated in Moreland's Msh space (perceptually
    even, no Mach bands), tabulated at 257 entries and interpolated linearly.
    """
    table = _coolwarm_table()
    x = np.clip(np.asarray(values, dtype=np.float64), 0.0, 1.0) * (len(table) - 1)
    lo = np.minimum(x.astype(np.int64), len(table) - 2)
    w = (x - lo)[..., None]
    return (1 - w) * table[lo] + w * table[lo + 1]


def viridis(values: np.ndarray) -> np.ndarray:
    """OpenCV's viridis table: ``values`` in [0, 1] -> (M, 3) sRGB in [0, 1]."""
    import cv2

    table = cv2.applyColorMap(np.arange(256, dtype=np.uint8)[:, None], cv2.COLORMAP_VIRIDIS)
    table = table[:, 0, ::-1].astype(np.float64) / 255.0  # BGR -> RGB
    x = np.clip(np.asarray(values, dtype=np.float64), 0.0, 1.0) * 255.0
    lo = np.minimum(x.astype(np.int64), 254)
    w = (x - lo)[..., None]
    return (1 - w) * table[lo] + w * table[lo + 1]


def _nice_ceil(x: float) -> float:
    """Smallest of 1, 1.2, 1.5, 2, 2.5, 3, 4, 5, 6, 8 × 10^k that is ≥ x."""
    if x <= 0 or not math.isfinite(x):
        return 1.0
    exp = math.floor(math.log10(x))
    for step in (1.0, 1.2, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0):
        if step * 10.0**exp >= x * (1 - 1e-12):
            return step * 10.0**exp
    return 10.0 ** (exp + 1)


def _draw_legend(band: np.ndarray, lo: float, hi: float, colormap, caption: str) -> None:
    """Draw a caption, a horizontal colour bar and its end/middle labels into ``band`` (RGB)."""
    import cv2

    h, w = band.shape[:2]
    font, scale = cv2.FONT_HERSHEY_SIMPLEX, max(0.35, h / 130.0)
    x0, x1 = int(0.08 * w), int(0.92 * w)
    bar_top, bar_bottom = int(0.38 * h), int(0.62 * h)
    ramp = np.linspace(0.0, 1.0, x1 - x0)
    band[bar_top:bar_bottom, x0:x1] = np.rint(colormap(ramp) * 255.0).astype(np.uint8)[None]
    cv2.rectangle(band, (x0, bar_top), (x1 - 1, bar_bottom - 1), (0, 0, 0), 1)
    (cw, ch), _ = cv2.getTextSize(caption, font, scale, 1)
    cv2.putText(band, caption, (max(2, (w - cw) // 2), max(ch + 1, bar_top - int(0.08 * h))),
                font, scale, (0, 0, 0), 1, cv2.LINE_AA)
    for frac, value in ((0.0, lo), (0.5, 0.5 * (lo + hi)), (1.0, hi)):
        label = f"{value:+.3g}" if lo < 0 else f"{value:.3g}"
        (tw, th), _ = cv2.getTextSize(label, font, scale, 1)
        x = int(x0 + frac * (x1 - x0) - frac * tw)
        cv2.putText(band, label, (x, min(h - 3, bar_bottom + th + int(0.1 * h))), font, scale,
                    (0, 0, 0), 1, cv2.LINE_AA)


# --------------------------------------------------------------------------- the sheet


def _layout(views) -> tuple[list[tuple[float, float]], list[tuple[int, int]], int, int]:
    """Viewpoints, their (row, col) cells, and the grid's rows and cols.

    A count puts the upper-elevation views (even k) on the top row and the
    lower ones under them; explicit viewpoints fill the grid row by row.
    """
    if isinstance(views, int | np.integer):
        pairs = default_views(int(views))
        rows, cols = _grid(len(pairs))
        cells = [(k % 2, k // 2) if rows == 2 else (0, k) for k in range(len(pairs))]
        return pairs, cells, rows, cols
    pairs = [tuple(float(x) for x in v) for v in views]
    if not pairs or any(len(p) != 2 for p in pairs):
        raise ValueError(f"views must be a count or (azimuth, elevation) pairs, got {views!r}")
    rows, cols = _grid(len(pairs))
    return pairs, [divmod(k, cols) for k in range(len(pairs))], rows, cols


def render_mesh(vertices: np.ndarray, triangles: np.ndarray,
                views: int | Sequence[tuple[float, float]] = 6,
                size: tuple[int, int] = (1200, 800),
                truth: tuple[np.ndarray, np.ndarray] | None = None,
                normals: np.ndarray | None = None,
                error_range: tuple[float, float] | None = None,
                supersample: int = 2, lighting: Lighting = Lighting(),
                background: tuple[int, int, int] = (255, 255, 255),
                smooth: bool = True, caster: RayCaster | None = None,
                distances: np.ndarray | None = None) -> np.ndarray:
    """Render a contact sheet of shaded views of a mesh, headless on the CPU.

    Parameters
    ----------
    vertices : (V, 3) float64, scene units
    triangles : (F, 3) int64
    views : int or sequence of (azimuth_deg, elevation_deg)
        A count (default 6: azimuths at 60° steps, elevations alternating
        ±25°, laid out 3×2) or explicit viewpoints; more than three views
        make two rows.
    size : (width, height) int
        Size of the whole sheet in pixels (including the error scale bar).
    truth : (truth_vertices (T, 3), truth_triangles (G, 3)), optional
        Colour the surface by each vertex's distance to this mesh.
    normals : (V, 3) float64, optional
        Vertex normals (e.g. exact Bézier normals); area-weighted otherwise.
    error_range : (lo, hi) float, optional
        Distances mapped to the ends of the colour map (clipped beyond);
        default ``±m`` (signed) or ``[0, m]`` (unsigned) with ``m`` the
        largest distance rounded up to a 1-1.2-1.5-2-2.5-3-4-5-6-8 step.
    supersample : int
        Anti-aliasing factor (rays per pixel side), ≥ 1.
    lighting : Lighting
    background : RGB
    smooth : bool
        Interpolated vertex normals (default) or flat facets.
    caster : pipeline.raycast.RayCaster, optional
        The ray caster of exactly this mesh, when already built (several sheets of one
        mesh share its BVH).
    distances : (V,) float64, optional
        With ``truth``: the vertices' distances to it, when already measured (signed,
        negative inside, for a watertight truth; as :func:`surface.metrics.point_mesh_distance`).

    Returns
    -------
    image : (height, width, 3) uint8, RGB
    """
    vertices = check_shape(vertices, "(V, 3)", "vertices", dtype=np.float64)
    check_finite(vertices, "vertices")
    triangles = check_shape(triangles, "(F, 3)", "triangles").astype(np.int64)
    if len(triangles) == 0 or triangles.min() < 0 or triangles.max() >= len(vertices):
        raise ValueError(f"triangles must be non-empty and index [0, {len(vertices)})")
    width, height = (int(x) for x in size)
    if width < 8 or height < 8:
        raise ValueError(f"size must be at least 8x8 pixels, got {width}x{height}")
    if supersample < 1:
        raise ValueError(f"supersample must be >= 1, got {supersample}")
    pairs, cells, rows, cols = _layout(views)
    if normals is None:
        normals = vertex_normals(vertices, triangles)
    else:
        normals = _unit(check_shape(normals, "(V, 3)", "normals", dtype=np.float64))
        if len(normals) != len(vertices) or not np.all(np.isfinite(normals)):
            raise ValueError(f"normals must be finite, one per vertex ({len(vertices)}), "
                             f"got {len(normals)}")

    values = colormap = legend = None
    if truth is not None:
        values, colormap, legend = _error_colours(vertices, truth, error_range, distances)
    legend_h = max(48, height // 10) if legend is not None else 0
    tile_w, tile_h = width // cols, (height - legend_h) // rows
    if tile_w < 8 or tile_h < 8:
        raise ValueError(f"size {width}x{height} is too small for {len(pairs)} views")

    scene = RayCaster(vertices, triangles) if caster is None else caster
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    center = 0.5 * (lo + hi)
    radius = max(float(np.linalg.norm(vertices - center, axis=1).max()), TOL.zero)

    sheet = np.empty((height, width, 3), dtype=np.uint8)
    sheet[:] = np.asarray(background, dtype=np.uint8)
    for (az, el), (row, col) in zip(pairs, cells, strict=True):
        K, R, t = look_at(center, radius, az, el, tile_w, tile_h)
        tile = render_view(scene, vertices, triangles, normals, K, R, t, tile_w, tile_h,
                           supersample, lighting, values, colormap, background, smooth)
        sheet[row * tile_h:(row + 1) * tile_h, col * tile_w:(col + 1) * tile_w] = tile
    if legend is not None:
        _draw_legend(sheet[height - legend_h:], *legend)
    return sheet


def _error_colours(vertices, truth, error_range, distance=None):
    """Per-vertex normalised distances, the colour map and the legend's arguments."""
    truth_vertices = check_shape(truth[0], "(T, 3)", "truth vertices", dtype=np.float64)
    truth_triangles = check_shape(truth[1], "(G, 3)", "truth triangles").astype(np.int64)
    from surface.metrics import is_watertight, point_mesh_distance

    signed = is_watertight(truth_triangles)  # signed (- inside) only where inside means something
    if distance is None:
        distance = point_mesh_distance(vertices, truth_vertices, truth_triangles, signed=signed)
    elif np.shape(distance) != (len(vertices),):
        raise ValueError(f"distances must be one per vertex ({len(vertices)}), got "
                         f"{np.shape(distance)}")
    if error_range is None:
        top = _nice_ceil(float(np.abs(distance).max()))
        error_range = (-top, top) if signed else (0.0, top)
    lo, hi = (float(x) for x in error_range)
    if not hi > lo:
        raise ValueError(f"error_range must have hi > lo, got ({lo}, {hi})")
    colormap = coolwarm if signed else viridis
    values = (distance - lo) / (hi - lo)
    kind = "signed distance to truth (- inside)" if signed else "distance to truth"
    caption = f"{kind}, range [{lo:.3g}, {hi:.3g}], clipped"
    return values, colormap, (lo, hi, colormap, caption)


def write_png(path: str | os.PathLike, image: np.ndarray) -> Path:
    """Write an RGB uint8 image as PNG, atomically.

    Parameters
    ----------
    path : path-like, suffix ``.png``
    image : (H, W, 3) uint8, RGB
    """
    from pipeline.guards import write_image

    path = Path(path)
    if path.suffix.lower() != ".png":
        raise ValueError(f"{path}: renders are written as .png")
    image = check_shape(image, "(H, W, 3)", "image")

    with atomic_file(path) as tmp:  # encoded in memory, written and checked by Python
        write_image(tmp, np.ascontiguousarray(image[:, :, ::-1]))
    return path
