r"""Synthetic scenes with exact ground truth: shape, procedural texture, ray-cast rendering.

A scene is a recipe (TOML, validated here) turned into a closed triangle mesh, a
set of pinhole cameras with Brown–Conrady distortion, and images rendered by
ray casting.  The truth that matching and surface fitting are judged against is
written beside the images: the mesh, per-view depth maps and, for a stereo pair,
the dense left→right correspondence.

Shape.  A surface of revolution about the z axis with an elliptic cross-section,

.. math::  P(\theta, z) = \big(r(z)\,s_x(z)\cos\theta,\; r(z)\,s_y(z)\sin\theta,\; z\big),

with :math:`r` a C2 cubic spline through the recipe's profile points (and
:math:`s_x, s_y` constants or C2 splines), closed by flat caps; or any mesh
file.  Then a rigid pose :math:`X \mapsto R_o X + t_o`.

Texture.  A solid (3D) band-limited texture, the same function of the surface
point from every view:

.. math::  T(X) = \sum_{k=1}^{K} \sin 2\pi(\mathbf f_k \cdot X + \varphi_k),
           \qquad a(X) = \bar a + \Delta a \tanh\!\big(T(X) / 2\sigma_T\big),

with :math:`|\mathbf f_k|` log-uniform between 1/λ_max and 1/λ_min, directions
uniform on the sphere, :math:`\sigma_T = \sqrt{K/2}` and the albedo
:math:`a \in [\bar a - \Delta a, \bar a + \Delta a]`.

Shading (Lambert with ambient light, no cast shadows) and image formation:

.. math::  L = a(X)\,\big(k_a + k_d \max(0, \mathbf n \cdot \mathbf l)\big)
           + k_s \max(0, \mathbf n \cdot \mathbf h)^{p},\qquad
           g = \mathrm{round}\big(\gamma_v \cdot 255\,\bar L + o_v + \varepsilon\big),
           \quad \varepsilon \sim N(0, \sigma^2),

where :math:`\bar L` is the mean of :math:`L` over the pixel's area
(supersampling s×s, then ``cv2.INTER_AREA``), :math:`\gamma_v, o_v` the view's
gain and offset, and **n** the barycentric interpolation of the corner normals
(analytic for surfaces of revolution).  The specular term (Blinn-Phong [4]_,
``lighting.specular`` :math:`k_s` and ``lighting.shininess`` :math:`p`, off unless
given) uses the half vector :math:`\mathbf h` of the light and the direction back to
the camera, and only where :math:`\mathbf n \cdot \mathbf l > 0`: a highlight that
does not move with the texture but with the viewpoint, so that it differs between the
views as on a glossy surface (radiance above 1 saturates at 255).

Cameras (OpenCV convention, Hartley & Zisserman §6.1): world→camera
:math:`x_c = R X + t`, normalised :math:`(x, y) = (x_c/z_c, y_c/z_c)`, Brown–Conrady
distortion :math:`x_d = x(1 + k_1 r^2 + k_2 r^4 + k_3 r^6) + 2p_1xy + p_2(r^2 + 2x^2)`
(and symmetrically for y), pixel :math:`u = f_x x_d + c_x`.  Pixel centres are at
integer coordinates.  Each ray is cast through the *undistorted* direction of
its distorted pixel position, so distortion is exact, not resampled.

Depth ``truth/depth_XX.npy`` is :math:`z_c`, the z coordinate in the camera frame
of the surface point seen through the pixel centre (not the range along the
ray), refined in float64 on the triangle the ray hit (Möller & Trumbore) and
stored as float32, NaN off the object.

References
----------
.. [1] D. C. Brown, "Decentering distortion of lenses", Photogrammetric
   Engineering 32(3), 444–462 (1966).
.. [2] T. Möller, B. Trumbore, "Fast, minimum storage ray-triangle
   intersection", Journal of Graphics Tools 2(1), 21–28 (1997).
.. [3] R. Hartley, A. Zisserman, "Multiple View Geometry in Computer Vision",
   2nd ed., Cambridge University Press (2004), §6.1 and §9.
.. [4] J. F. Blinn, "Models of light reflection for computer synthesized pictures",
   Computer Graphics (SIGGRAPH '77) 11(2), 192–198 (1977).
"""

from __future__ import annotations

import json
import math
import os
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numba
import numpy as np

from matching.cameras import Camera, StereoRig, write_cameras_yml, write_colmap_text
from pipeline import limits, scene_cache
from pipeline.errors import InputError
from pipeline.raycast import RayCaster, look_at
from pipeline.raycast import direction as view_direction

#: Default recipe shipped with the project.
DEFAULT_RECIPE = Path(__file__).resolve().parents[1] / "fixtures" / "scenes" / "vase.toml"


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

_REQUIRED = object()


# --------------------------------------------------------------------------- recipe


class _Table:
    """One TOML table being validated: typed lookups, then a check for unknown keys."""

    def __init__(self, source: str, name: str, table: object):
        self.source, self.name = source, name
        if not isinstance(table, Mapping):
            raise InputError(f"{source}: field {name}: expected a table, got {table!r}")
        self.table = dict(table)
        self.used: set[str] = set()

    def error(self, key: str, problem: str) -> InputError:
        dotted = f"{self.name}.{key}" if self.name else key
        return InputError(f"{self.source}: field {dotted}: {problem}")

    def has(self, key: str) -> bool:
        return key in self.table

    def take(self, key: str, kind: str, default=_REQUIRED, choices=None, positive=False,
             nonneg=False, length=None):
        """Value of ``key`` as ``kind`` (float, int, bool, str, vector, matrix), range-checked."""
        self.used.add(key)
        if key not in self.table:
            if default is _REQUIRED:
                raise self.error(key, "missing")
            return default
        value = self.table[key]
        try:
            value = _convert(value, kind, length)
        except (TypeError, ValueError) as exc:
            raise self.error(key, f"{exc} (got {value!r})") from None
        if choices is not None and value not in choices:
            raise self.error(key, f"{value!r} is not one of {', '.join(map(repr, choices))}")
        values = np.atleast_1d(np.asarray(value, dtype=float)) if kind != "str" else None
        if positive and not np.all(values > 0):
            raise self.error(key, f"must be positive, got {value!r}")
        if nonneg and not np.all(values >= 0):
            raise self.error(key, f"must be non-negative, got {value!r}")
        return value

    def sub(self, key: str, required: bool = False) -> _Table | None:
        self.used.add(key)
        if key not in self.table:
            if required:
                raise self.error(key, "missing")
            return None
        return _Table(self.source, f"{self.name}.{key}" if self.name else key, self.table[key])

    def done(self) -> None:
        unknown = sorted(set(self.table) - self.used)
        if unknown:
            allowed = ", ".join(sorted(self.used))
            raise self.error(unknown[0], f"unknown field (allowed here: {allowed})")


def _convert(value, kind: str, length: int | None):
    """Convert a TOML value to the named kind; raise TypeError/ValueError with a short reason."""
    def number(x):
        if isinstance(x, bool) or not isinstance(x, int | float):
            raise TypeError("expected a number")
        if not math.isfinite(x):
            raise ValueError("must be finite")
        return float(x)

    if kind == "float":
        return number(value)
    if kind == "int":
        if isinstance(value, bool) or not isinstance(value, int):
            raise TypeError("expected an integer")
        return int(value)
    if kind == "bool":
        if not isinstance(value, bool):
            raise TypeError("expected true or false")
        return value
    if kind == "str":
        if not isinstance(value, str):
            raise TypeError("expected a string")
        return value
    if kind == "vector":
        if not isinstance(value, list | tuple):
            raise TypeError(f"expected a list of {length or 'some'} numbers")
        out = [number(x) for x in value]
        if length is not None and len(out) != length:
            raise ValueError(f"expected {length} numbers, got {len(out)}")
        return out
    if kind == "matrix":  # list of rows of `length` numbers
        if not isinstance(value, list | tuple) or not value:
            raise TypeError(f"expected a non-empty list of [{length} numbers] rows")
        rows = []
        for row in value:
            if not isinstance(row, list | tuple) or len(row) != length:
                raise ValueError(f"every row must hold {length} numbers")
            rows.append([number(x) for x in row])
        return rows
    raise AssertionError(kind)


def load_recipe(path: str | os.PathLike = DEFAULT_RECIPE, overrides: Mapping | None = None) -> dict:
    """Read, override and validate a scene recipe; return it with every default filled.

    Parameters
    ----------
    path : path-like
        A TOML recipe (format in :func:`validate_recipe` and the README).
    overrides : mapping, optional
        Nested or dotted values applied before validation, e.g.
        ``{"cameras.width": 160, "cameras": {"height": 120}}``.

    Returns
    -------
    dict
        The resolved recipe: every field present, mesh paths absolute.

    Raises
    ------
    FileNotFoundError
        No such recipe file.
    InputError
        ``"FILE: field shape.profile: ..."`` for invalid TOML, an unknown or
        missing field, a value of the wrong type or range.
    """
    from pipeline.config import deep_update
    from pipeline.guards import load_toml

    path = Path(path)
    raw = load_toml(path, "recipe file")  # regular file, bounded size and nesting
    if overrides:
        deep_update(raw, overrides, dotted=True)
    return validate_recipe(raw, source=str(path), base_dir=path.parent)


def validate_recipe(raw: Mapping, source: str = "<recipe>",
                    base_dir: str | os.PathLike | None = None) -> dict:
    """Validate a recipe given as a dict and fill its defaults (see :func:`load_recipe`).

    Top-level fields: ``seed`` (int, default 0) and the tables ``shape``,
    ``texture``, ``lighting``, ``cameras``, ``noise``, ``render``.  Errors
    name ``source`` and the dotted field.
    """
    limits.check_recipe(raw, source)  # the sizes as written, before anything is built
    top = _Table(source, "", raw)
    recipe = {"seed": top.take("seed", "int", 0, nonneg=True)}
    recipe["shape"] = _validate_shape(top.sub("shape", required=True),
                                      Path(base_dir) if base_dir is not None else Path.cwd())
    recipe["texture"] = _validate_texture(top.sub("texture") or _Table(source, "texture", {}))
    recipe["cameras"] = _validate_cameras(top.sub("cameras", required=True))
    recipe["lighting"] = _validate_lighting(top.sub("lighting") or _Table(source, "lighting", {}),
                                            _view_count(recipe["cameras"]))
    noise = top.sub("noise") or _Table(source, "noise", {})
    recipe["noise"] = {"sigma": noise.take("sigma", "float", 2.0, nonneg=True)}
    # less kind than white noise on equally sharp views, only when asked for
    # (the recipes without them stay byte-identical): noise low-passed by a Gaussian of
    # correlation_px (as demosaicing correlates it; renormalised to sigma), and the odd
    # views blurred by a Gaussian of blur_difference_px before the noise
    for key in ("correlation_px", "blur_difference_px"):
        if noise.has(key):
            recipe["noise"][key] = noise.take(key, "float", nonneg=True)
    noise.done()
    render = top.sub("render") or _Table(source, "render", {})
    recipe["render"] = {"supersample": render.take("supersample", "int", 3, positive=True)}
    render.done()
    top.done()
    limits.check_recipe(recipe, source)  # every size of the recipe, before anything is built
    return recipe


def _validate_pose(table: _Table | None) -> dict:
    if table is None:
        return {"rotation_axis": [0.0, 0.0, 1.0], "rotation_deg": 0.0,
                "translation": [0.0, 0.0, 0.0]}
    if table.has("euler_xyz_deg") and (table.has("rotation_axis") or table.has("rotation_deg")):
        raise table.error("euler_xyz_deg", "give either euler_xyz_deg or rotation_axis + "
                          "rotation_deg, not both")
    pose = {}
    if table.has("euler_xyz_deg"):
        pose["euler_xyz_deg"] = table.take("euler_xyz_deg", "vector", length=3)
    else:
        axis = table.take("rotation_axis", "vector", [0.0, 0.0, 1.0], length=3)
        if np.linalg.norm(axis) == 0:
            raise table.error("rotation_axis", "has zero length")
        pose["rotation_axis"] = axis
        pose["rotation_deg"] = table.take("rotation_deg", "float", 0.0)
    pose["translation"] = table.take("translation", "vector", [0.0, 0.0, 0.0], length=3)
    table.done()
    return pose


def _validate_shape(table: _Table, base_dir: Path) -> dict:
    kind = table.take("kind", "str", choices=("revolution", "mesh"))
    shape: dict = {"kind": kind}
    if kind == "revolution":
        profile = table.take("profile", "matrix", length=2)
        z = np.array([p[0] for p in profile])
        r = np.array([p[1] for p in profile])
        if len(profile) < 2:
            raise table.error("profile", f"needs at least 2 [z, r] points, got {len(profile)}")
        if np.any(np.diff(z) <= 0):
            raise table.error("profile", f"z must be strictly increasing, got {z.tolist()}")
        if np.any(r <= 0):
            raise table.error("profile", f"radius must be positive, got r = {r.min():g} at "
                              f"z = {z[np.argmin(r)]:g}")
        shape["profile"] = profile
        if table.has("section_scale") and (table.has("scale_x") or table.has("scale_y")):
            raise table.error("section_scale", "give either section_scale or scale_x/scale_y")
        if table.has("section_scale"):
            rows = table.take("section_scale", "matrix", length=3)
            zs = np.array([row[0] for row in rows])
            if np.any(np.diff(zs) <= 0):
                raise table.error("section_scale", "z must be strictly increasing")
            if zs[0] > z[0] or zs[-1] < z[-1]:
                raise table.error("section_scale", f"must span the profile's z range "
                                  f"[{z[0]:g}, {z[-1]:g}], got [{zs[0]:g}, {zs[-1]:g}]")
            if np.any(np.array([row[1:] for row in rows]) <= 0):
                raise table.error("section_scale", "scales must be positive")
            shape["section_scale"] = rows
        else:
            shape["scale_x"] = table.take("scale_x", "float", 1.0, positive=True)
            shape["scale_y"] = table.take("scale_y", "float", 1.0, positive=True)
        shape["triangles"] = table.take("triangles", "int", 100_000)
        if shape["triangles"] < 64:
            raise table.error("triangles", f"must be at least 64, got {shape['triangles']}")
        # the spline may overshoot between positive points: check the interpolated radius
        _, radius_x, radius_y = _revolution_functions(shape)
        zz = np.linspace(z[0], z[-1], 4001)
        rmin = np.minimum(radius_x(zz), radius_y(zz))
        if np.any(rmin <= 0):
            raise table.error("profile", f"the interpolated radius becomes non-positive "
                              f"near z = {zz[np.argmin(rmin)]:g}")
    else:
        path = Path(table.take("path", "str"))
        if not path.is_absolute():
            path = (base_dir / path).resolve()
        if not path.is_file():
            raise table.error("path", f"no such mesh file: {path}")
        shape["path"] = str(path)
        shape["scale"] = table.take("scale", "float", 1.0, positive=True)
        axis = table.take("axis", "vector", [0.0, 0.0, 1.0], length=3)
        if np.linalg.norm(axis) == 0:
            raise table.error("axis", "has zero length")
        shape["axis"] = axis
    shape["pose"] = _validate_pose(table.sub("pose"))
    table.done()
    return shape


def _validate_texture(table: _Table) -> dict:
    texture = {"kind": table.take("kind", "str", "sinusoids", choices=("sinusoids",))}
    texture["components"] = table.take("components", "int", 48, positive=True)
    wavelength = table.take("wavelength_px", "vector", [6.0, 24.0], length=2, positive=True)
    if wavelength[0] > wavelength[1]:
        raise table.error("wavelength_px", f"expected [min, max], got {wavelength}")
    if wavelength[0] < 2.0:
        raise table.error("wavelength_px", f"below 2 px the texture aliases (Nyquist), got "
                          f"{wavelength[0]:g}")
    texture["wavelength_px"] = wavelength
    albedo = table.take("albedo", "vector", [0.15, 0.85], length=2)
    if not 0 <= albedo[0] < albedo[1] <= 1:
        raise table.error("albedo", f"expected 0 <= min < max <= 1, got {albedo}")
    texture["albedo"] = albedo
    table.done()
    return texture


def _per_view(table: _Table, key: str, n_views: int, default: float, positive: bool = False):
    """A per-view list from ``key`` (number or list) or ``key_range`` (uniform, seeded later)."""
    range_key = f"{key}_range"
    if table.has(key) and table.has(range_key):
        raise table.error(range_key, f"give either {key} or {range_key}, not both")
    if table.has(range_key):
        lo, hi = table.take(range_key, "vector", length=2, positive=positive)
        if lo > hi:
            raise table.error(range_key, f"expected [min, max], got {[lo, hi]}")
        return {range_key: [lo, hi]}
    raw = table.table.get(key, default)
    if isinstance(raw, list | tuple):
        values = table.take(key, "vector", positive=positive)
        if len(values) != n_views:
            raise table.error(key, f"has {len(values)} values for {n_views} views")
    else:
        values = [table.take(key, "float", default, positive=positive)] * n_views
    return {key: values}


def _validate_lighting(table: _Table, n_views: int) -> dict:
    direction = table.take("direction", "vector", [1.0, -0.5, 1.0], length=3)
    if np.linalg.norm(direction) == 0:
        raise table.error("direction", "has zero length")
    lighting = {"direction": direction,
                "ambient": table.take("ambient", "float", 0.3, nonneg=True),
                "diffuse": table.take("diffuse", "float", 0.7, nonneg=True),
                "background": table.take("background", "float", 20.0, nonneg=True)}
    if lighting["ambient"] + lighting["diffuse"] > 1.0 + TOL.recipe_slack:
        raise table.error("diffuse", "ambient + diffuse must not exceed 1")
    if lighting["background"] > 255:
        raise table.error("background", f"is a grey level in 0..255, got "
                          f"{lighting['background']:g}")
    # a Blinn-Phong highlight (less kind than Lambert), only when asked for
    # (the recipes without it stay byte-identical)
    if table.has("specular") or table.has("shininess"):
        lighting["specular"] = table.take("specular", "float", 0.0, nonneg=True)
        lighting["shininess"] = table.take("shininess", "float", 40.0, positive=True)
    lighting.update(_per_view(table, "gain", n_views, 1.0, positive=True))
    lighting.update(_per_view(table, "offset", n_views, 0.0))
    table.done()
    return lighting


def _view_count(cameras: dict) -> int:
    if cameras["layout"] == "stereo":
        return 2
    return cameras["n"] + cameras.get("second_ring", {}).get("n", 0)


def _validate_cameras(table: _Table) -> dict:
    layout = table.take("layout", "str", choices=("stereo", "ring"))
    cams: dict = {"layout": layout,
                  "width": table.take("width", "int", positive=True),
                  "height": table.take("height", "int", positive=True)}
    if cams["width"] < 8 or cams["height"] < 8:
        raise table.error("width", f"image must be at least 8x8, got {cams['width']}x"
                          f"{cams['height']}")
    cams["focal_px"] = table.take("focal_px", "float", 1.3 * cams["width"], positive=True)
    centre = [(cams["width"] - 1) / 2.0, (cams["height"] - 1) / 2.0]
    cams["principal_point"] = table.take("principal_point", "vector", centre, length=2)
    distortion = table.take("distortion", "vector", [0.0] * 5, length=5)
    cams["distortion"] = distortion
    if any(distortion):  # invertible and a lens's over the image, before any scene is built
        K, dist = _intrinsics(cams)
        border = np.array([[u, v] for u in (-0.5, (cams["width"] - 1) / 2, cams["width"] - 0.5)
                           for v in (-0.5, (cams["height"] - 1) / 2, cams["height"] - 0.5)])
        try:
            undistort_pixels(border, Camera(K, dist, np.eye(3), np.zeros(3), cams["width"],
                                            cams["height"], "each view"))
        except InputError as exc:
            raise table.error("distortion", str(exc).removeprefix(
                "field cameras.distortion: ")) from None
    cams["fill"] = table.take("fill", "float", 0.85, positive=True)
    if cams["fill"] > 1:  # a share of the image: beyond 1 the object overflows every view
        raise table.error("fill", f"{cams['fill']:g} is the share of the image the object "
                          "fills, at most 1")
    cams["azimuth_deg"] = table.take("azimuth_deg", "float", 0.0)
    elevation = table.take("elevation_deg", "float", 0.0 if layout == "stereo" else 15.0)
    if abs(elevation) >= 89.0:
        raise table.error("elevation_deg", f"must lie in (-89, 89), got {elevation:g}")
    cams["elevation_deg"] = elevation
    if layout == "stereo":
        if table.has("distance"):
            cams["distance"] = table.take("distance", "float", positive=True)
        if table.has("baseline"):
            cams["baseline"] = table.take("baseline", "float", positive=True)
        if table.has("convergence_deg"):
            conv = table.take("convergence_deg", "float")
            if abs(conv) >= 180:
                raise table.error("convergence_deg", f"must lie in (-180, 180), got {conv:g}")
            cams["convergence_deg"] = conv
    else:
        cams["n"] = table.take("n", "int", 8)
        if cams["n"] < 1:
            raise table.error("n", f"must be at least 1, got {cams['n']}")
        if table.has("radius"):
            cams["radius"] = table.take("radius", "float", positive=True)
        ring2 = table.sub("second_ring")
        if ring2 is not None:
            second = {"n": ring2.take("n", "int")}
            if second["n"] < 1:
                raise ring2.error("n", f"must be at least 1, got {second['n']}")
            second["elevation_deg"] = ring2.take("elevation_deg", "float")
            if abs(second["elevation_deg"]) >= 89.0:
                raise ring2.error("elevation_deg", "must lie in (-89, 89)")
            second["azimuth_offset_deg"] = ring2.take("azimuth_offset_deg", "float",
                                                      180.0 / cams["n"])
            ring2.done()
            cams["second_ring"] = second
    table.done()
    return cams


# --------------------------------------------------------------------------- geometry


def _revolution_functions(shape: dict):
    """C2 splines ``r(z)``, ``rx(z) = r sx``, ``ry(z) = r sy`` of a revolution shape."""
    from scipy.interpolate import CubicSpline

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
    _, radius_x, radius_y = _revolution_functions(shape)
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


def _rotation_about(axis, angle_deg: float) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    axis = np.asarray(axis, dtype=np.float64)
    return Rotation.from_rotvec(axis / np.linalg.norm(axis) * math.radians(angle_deg)).as_matrix()


def pose_matrix(pose: dict) -> tuple[np.ndarray, np.ndarray]:
    """Rotation ``(3, 3)`` and translation ``(3,)`` of a validated ``shape.pose`` table."""
    from scipy.spatial.transform import Rotation

    if "euler_xyz_deg" in pose:
        rotation = Rotation.from_euler("xyz", pose["euler_xyz_deg"], degrees=True).as_matrix()
    else:
        rotation = _rotation_about(pose["rotation_axis"], pose["rotation_deg"])
    return rotation, np.asarray(pose["translation"], dtype=np.float64)


def shape_mesh(shape: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The posed mesh of a validated ``shape`` table: ``vertices, triangles, corner_normals``."""
    if shape["kind"] == "revolution":
        vertices, triangles, corner = revolution_mesh(shape)
    else:
        from scipy.spatial.transform import Rotation

        from pipeline.mesh_io import read_mesh

        vertices, triangles = read_mesh(shape["path"])
        vertices = vertices * shape["scale"]
        align, _ = Rotation.align_vectors([[0.0, 0.0, 1.0]], [shape["axis"]])
        vertices = vertices @ align.as_matrix().T
        corner = _corner_normals_from_mesh(vertices, triangles)
    rotation, translation = pose_matrix(shape["pose"])
    return vertices @ rotation.T + translation, triangles, corner @ rotation.T


# --------------------------------------------------------------------------- texture


#: The texture kernels' floating-point flags: only "no signed zeros".  Reassociation
#: (fastmath's "reassoc") lets LLVM vectorise the 48-term float32 sum with the host's
#: vector width (8 lanes with AVX2, 16 with AVX-512), and contraction ("contract") fuses
#: multiply-adds where the host has FMA: the rendered grey levels then differ in the
#: last float32 bits between CPUs, a few pixels round to another 8-bit level, and every
#: test on a rendered scene sees other data on another machine (the
#: 24-view ring's lowest point moved 1.6 px on an AMD EPYC).  Without them the
#: arithmetic is IEEE's on any x86-64 (texture evaluation ~1.8x slower: ~+1 s of the
#: 24-view 320x240 ring's render).
_EXACT = {"nsz"}


@numba.njit(inline="always", fastmath=_EXACT, cache=True)
def _sin_turns(u):  # pragma: no cover - compiled
    # sin 2πu: reduce to [-1/4, 1/4] turn, degree-9 Taylor polynomial (error < 4e-6, far
    # below a grey level); ~7x faster than libm's sin, which numba cannot vectorise here
    # (no SVML).
    u = u - np.floor(u + np.float32(0.5))
    a = abs(u)
    if a > np.float32(0.25):
        a = np.float32(0.5) - a
    w = a * np.float32(2.0 * np.pi)
    w2 = w * w
    sine = w * (np.float32(1.0) + w2 * (np.float32(-1.0 / 6.0) + w2 * (
        np.float32(1.0 / 120.0) + w2 * (np.float32(-1.0 / 5040.0)
                                       + w2 * np.float32(1.0 / 362880.0)))))
    return sine if u >= 0 else -sine


@numba.njit(inline="always", fastmath=_EXACT, cache=True)
def _texture_sum(x, y, z, freq, phase):  # pragma: no cover - compiled
    total = np.float32(0.0)
    for k in range(freq.shape[0]):
        total += _sin_turns(freq[k, 0] * x + freq[k, 1] * y + freq[k, 2] * z + phase[k])
    return total


@numba.njit(parallel=True, fastmath=_EXACT, cache=True)
def _sinusoid_sum(points, freq, phase, out):  # pragma: no cover - compiled
    for i in numba.prange(points.shape[0]):
        out[i] = _texture_sum(points[i, 0], points[i, 1], points[i, 2], freq, phase)


@numba.njit(parallel=True, fastmath=_EXACT, cache=True)
def _shade(origin, directions, t, ids, uv, corner, light, params, freq, phase,
           out):  # pragma: no cover - compiled
    """Radiance per ray; params = ambient, diffuse, background, albedo mid, half-range,
    1/(2 σ_T), specular, shininess.  Corner normals interpolated barycentrically,
    texture at the hit point; the Blinn-Phong term only where specular > 0."""
    for i in numba.prange(t.shape[0]):
        tri = ids[i]
        if tri < 0:
            out[i] = params[2]
            continue
        u, v = uv[i, 0], uv[i, 1]
        w = np.float32(1.0) - u - v
        nx = w * corner[tri, 0, 0] + u * corner[tri, 1, 0] + v * corner[tri, 2, 0]
        ny = w * corner[tri, 0, 1] + u * corner[tri, 1, 1] + v * corner[tri, 2, 1]
        nz = w * corner[tri, 0, 2] + u * corner[tri, 1, 2] + v * corner[tri, 2, 2]
        dx, dy, dz = directions[i, 0], directions[i, 1], directions[i, 2]
        if nx * dx + ny * dy + nz * dz > 0:  # seen from behind: shade the side seen
            nx, ny, nz = -nx, -ny, -nz
        norm = np.sqrt(nx * nx + ny * ny + nz * nz)
        lambert = max((nx * light[0] + ny * light[1] + nz * light[2]) / norm, np.float32(0.0))
        x = origin[0] + t[i] * dx
        y = origin[1] + t[i] * dy
        z = origin[2] + t[i] * dz
        albedo = params[3] + params[4] * np.tanh(_texture_sum(x, y, z, freq, phase) * params[5])
        out[i] = albedo * (params[0] + params[1] * lambert)
        if params[6] > 0 and lambert > 0:
            # half vector of the light and the direction back to the camera (-d)
            dn = np.sqrt(dx * dx + dy * dy + dz * dz)
            hx = light[0] - dx / dn
            hy = light[1] - dy / dn
            hz = light[2] - dz / dn
            hn = np.sqrt(hx * hx + hy * hy + hz * hz)
            cos_h = (nx * hx + ny * hy + nz * hz) / (norm * hn)
            if cos_h > 0:
                out[i] += params[6] * cos_h ** params[7]


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


def _quiet_numba(function, *args):
    """Call a parallel kernel with numba's one-time TBB-version warning silenced."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", numba.NumbaWarning)
        return function(*args)


@dataclass(frozen=True)
class SinusoidTexture:
    """Solid band-limited texture: albedo of a 3D point (see the module equations).

    Attributes
    ----------
    frequencies : (K, 3) float64, cycles per scene unit.
    phases : (K,) float64, turns.
    albedo : (2,) albedo range [min, max].
    """

    frequencies: np.ndarray
    phases: np.ndarray
    albedo: tuple[float, float]

    @classmethod
    def random(cls, components: int, wavelength: tuple[float, float], albedo, rng):
        """Draw K components: |f| log-uniform in [1/λmax, 1/λmin], isotropic directions."""
        direction = rng.standard_normal((components, 3))
        direction /= np.linalg.norm(direction, axis=1, keepdims=True)
        lo, hi = np.log(1.0 / wavelength[1]), np.log(1.0 / wavelength[0])
        magnitude = np.exp(rng.uniform(lo, hi, components))
        return cls(direction * magnitude[:, None], rng.uniform(0.0, 1.0, components),
                   (float(albedo[0]), float(albedo[1])))

    def raw(self, points: np.ndarray) -> np.ndarray:
        """The sum T(X) of the K sinusoids at ``points (N, 3)``; returns ``(N,) float32``."""
        points = np.ascontiguousarray(points, dtype=np.float32)
        out = np.empty(len(points), dtype=np.float32)
        if len(points):
            _quiet_numba(_sinusoid_sum, points, self.frequencies.astype(np.float32),
                         self.phases.astype(np.float32), out)
        return out

    @property
    def sigma(self) -> float:
        """Standard deviation of T over space, sqrt(K / 2)."""
        return math.sqrt(len(self.phases) / 2.0)

    def __call__(self, points: np.ndarray) -> np.ndarray:
        """Albedo at ``points (N, 3)`` scene units; returns ``(N,) float32`` in the albedo range."""
        mid = 0.5 * (self.albedo[0] + self.albedo[1])
        half = 0.5 * (self.albedo[1] - self.albedo[0])
        return (mid + half * np.tanh(self.raw(points) / np.float32(2.0 * self.sigma))).astype(
            np.float32)


# --------------------------------------------------------------------------- cameras


def _intrinsics(cams: dict) -> tuple[np.ndarray, np.ndarray]:
    f = cams["focal_px"]
    cx, cy = cams["principal_point"]
    return np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]]), np.asarray(
        cams["distortion"], dtype=np.float64)


def _make_camera(index: int, position, rotation, K, dist, cams) -> Camera:
    """Camera number ``index`` (named after its image, ``view_XX.png``) at ``position``."""
    return Camera(K, dist, rotation, -rotation @ position, cams["width"], cams["height"],
                  f"view_{index:02d}.png")


def _stereo_cameras(cams: dict, centre: np.ndarray, distance: float) -> list[Camera]:
    """Left and right camera: midpoint at ``distance`` from the centre, toed in symmetrically."""
    K, dist = _intrinsics(cams)
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
        turn = _rotation_about(mid_rotation[1], -side * 0.5 * convergence)
        rotation = mid_rotation @ turn.T
        out.append(_make_camera(index, position, rotation, K, dist, cams))
    return out


def _ring_cameras(cams: dict, centre: np.ndarray, radius: float) -> list[Camera]:
    K, dist = _intrinsics(cams)
    rings = [(cams["n"], cams["elevation_deg"], cams["azimuth_deg"])]
    if "second_ring" in cams:
        second = cams["second_ring"]
        rings.append((second["n"], second["elevation_deg"],
                      cams["azimuth_deg"] + second["azimuth_offset_deg"]))
    out = []
    for n, elevation, azimuth0 in rings:
        for k in range(n):
            position = centre + radius * view_direction(azimuth0 + 360.0 * k / n, elevation)
            out.append(_make_camera(len(out), position, look_at(position, centre), K, dist,
                                    cams))
    return out


def make_cameras(cams: dict, centre: np.ndarray, distance: float) -> list[Camera]:
    """Cameras of a validated ``cameras`` table at ``distance`` (ring radius) from ``centre``."""
    if cams["layout"] == "stereo":
        return _stereo_cameras(cams, centre, distance)
    return _ring_cameras(cams, centre, distance)


def _fit_distance(cams: dict, centre: np.ndarray, corners: np.ndarray, bound: float) -> float:
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


# --------------------------------------------------------------------------- rays


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
    _quiet_numba(_undistort_newton, target, np.asarray(camera.dist[:5], np.float64), xy)
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


# --------------------------------------------------------------------------- scene


@dataclass
class Scene:
    """Everything needed to render: mesh, shading normals, cameras, texture, radiometry.

    Attributes
    ----------
    vertices : (V, 3) float64, triangles : (F, 3) int64, corner_normals : (F, 3, 3) float64
    cameras : list of Camera
    texture : SinusoidTexture
    light : (3,) unit vector towards the light.
    gains, offsets : (n_views,) float64, grey levels for offsets.
    recipe : dict, the resolved recipe; derived : dict, values computed from it.
    """

    vertices: np.ndarray
    triangles: np.ndarray
    corner_normals: np.ndarray
    cameras: list[Camera]
    texture: SinusoidTexture
    light: np.ndarray
    gains: np.ndarray
    offsets: np.ndarray
    recipe: dict
    derived: dict = field(default_factory=dict)
    _caster: RayCaster | None = None
    _corner32: np.ndarray | None = None

    @property
    def corner_normals32(self) -> np.ndarray:
        """``corner_normals`` as contiguous float32 (what the shading kernel reads)."""
        if self._corner32 is None:
            self._corner32 = np.ascontiguousarray(self.corner_normals, dtype=np.float32)
        return self._corner32

    @property
    def caster(self) -> RayCaster:
        if self._caster is None:
            self._caster = RayCaster(self.vertices, self.triangles)
        return self._caster


def _seeded(seed: int, stream: int) -> np.random.Generator:
    """Independent reproducible streams: texture 1, gains 2, offsets 3, noise of view v 100+v."""
    return np.random.default_rng([seed, stream])


def _draw_per_view(lighting: dict, key: str, n: int, rng) -> np.ndarray:
    if f"{key}_range" in lighting:
        lo, hi = lighting[f"{key}_range"]
        return rng.uniform(lo, hi, n)
    return np.asarray(lighting[key], dtype=np.float64)


def build_scene(recipe: dict, source: str = "<recipe>") -> Scene:
    """Turn a resolved recipe into a :class:`Scene` (mesh, cameras, texture, radiometry).

    Raises
    ------
    InputError
        When a camera does not see the object (inside its bounding sphere, the
        object outside the image, or covering less than ``TOL.min_coverage``).
    """
    vertices, triangles, corner = shape_mesh(recipe["shape"])
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    centre = 0.5 * (lo + hi)
    bound = 0.5 * float(np.linalg.norm(hi - lo))
    cams = recipe["cameras"]
    key = "distance" if cams["layout"] == "stereo" else "radius"
    if key in cams:
        distance = cams[key]
    else:
        sample = vertices[:: max(1, len(vertices) // 4000)]
        try:
            distance = _fit_distance(cams, centre, sample, bound)
        except InputError as exc:
            raise InputError(f"{source}: {exc}") from None
    cameras = make_cameras(cams, centre, distance)
    footprint = float(np.mean([np.linalg.norm(c.center - centre) / c.K[0, 0] for c in cameras]))
    tex = recipe["texture"]
    wavelength = (tex["wavelength_px"][0] * footprint, tex["wavelength_px"][1] * footprint)
    texture = SinusoidTexture.random(tex["components"], wavelength, tex["albedo"],
                                     _seeded(recipe["seed"], 1))
    lighting = recipe["lighting"]
    light = np.asarray(lighting["direction"], dtype=np.float64)
    n = len(cameras)
    gains = _draw_per_view(lighting, "gain", n, _seeded(recipe["seed"], 2))
    offsets = _draw_per_view(lighting, "offset", n, _seeded(recipe["seed"], 3))
    derived = {"centre": centre.tolist(), "bounding_radius": bound, key: distance,
               "pixel_footprint": footprint, "texture_wavelength": list(wavelength),
               "texture_frequencies": texture.frequencies.tolist(),  # cycles / unit
               "texture_phases": texture.phases.tolist(),  # turns
               "gains": gains.tolist(), "offsets": offsets.tolist(),
               "vertices": len(vertices), "triangles": len(triangles)}
    if cams["layout"] == "stereo":
        derived["baseline"] = float(np.linalg.norm(cameras[1].center - cameras[0].center))
        f0, f1 = cameras[0].R[2], cameras[1].R[2]
        derived["convergence_deg"] = math.degrees(math.acos(np.clip(f0 @ f1, -1.0, 1.0)))
    scene = Scene(vertices, triangles, corner, cameras, texture, light / np.linalg.norm(light),
                  gains, offsets, recipe, derived)
    _check_visibility(scene, source, key)
    return scene


def _check_visibility(scene: Scene, source: str, key: str) -> None:
    """Every camera must be outside the object's bounding sphere and see it on a coarse grid."""
    centre = np.asarray(scene.derived["centre"])
    for cam in scene.cameras:
        if np.linalg.norm(cam.center - centre) <= scene.derived["bounding_radius"]:
            raise InputError(f"{source}: field cameras.{key}: {cam.name} lies inside the "
                             f"object's bounding sphere (radius "
                             f"{scene.derived['bounding_radius']:.4g})")
        # a grid spanning the whole image area, corners included (where distortion is worst)
        xs, ys = np.meshgrid(np.linspace(-0.5, cam.width - 0.5, 64),
                             np.linspace(-0.5, cam.height - 0.5, 48))
        pixels = np.stack([xs.ravel(), ys.ravel()], 1)
        try:
            origin, directions = pixel_rays(cam, pixels)
        except InputError as exc:
            raise InputError(f"{source}: {exc}") from None
        coverage = float(np.mean(scene.caster.cast(origin, directions)["ids"] >= 0))
        if coverage < TOL.min_coverage:
            raise InputError(f"{source}: field cameras: {cam.name} does not see the object "
                             f"(it covers {100 * coverage:.2g} % of the image)")


# --------------------------------------------------------------------------- rendering


def _pixel_grid(width: int, height: int, supersample: int = 1) -> np.ndarray:
    """Sample positions ``(H*s*W*s, 2)`` in full-resolution pixel coordinates, row-major.

    Sub-pixel ``(I, J)`` of an ``s×`` grid sits at ``((I + ½)/s − ½, (J + ½)/s − ½)``: the
    centres of the s×s cells tiling each pixel, so that ``INTER_AREA`` by s is the pixel's
    box average.
    """
    s = supersample
    xs = (np.arange(width * s) + 0.5) / s - 0.5
    ys = (np.arange(height * s) + 0.5) / s - 0.5
    gx, gy = np.meshgrid(xs, ys)
    return np.stack([gx.ravel(), gy.ravel()], axis=1)


def _radiance(scene: Scene, origin: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Cast rays and shade: radiance L ``(N,) float32`` (the background where a ray misses)."""
    hit = scene.caster.cast(origin, directions)
    lighting, tex = scene.recipe["lighting"], scene.texture
    params = np.array([lighting["ambient"], lighting["diffuse"], lighting["background"] / 255.0,
                       0.5 * (tex.albedo[0] + tex.albedo[1]), 0.5 * (tex.albedo[1] - tex.albedo[0]),
                       1.0 / (2.0 * tex.sigma), lighting.get("specular", 0.0),
                       lighting.get("shininess", 1.0)], dtype=np.float32)
    out = np.empty(len(directions), dtype=np.float32)
    _quiet_numba(_shade, np.asarray(origin, np.float32), np.asarray(directions, np.float32),
                 hit["t"], hit["ids"], hit["uv"], scene.corner_normals32,
                 scene.light.astype(np.float32), params, tex.frequencies.astype(np.float32),
                 tex.phases.astype(np.float32), out)
    return out


def _box_radiance(scene: Scene, cam: Camera, active: np.ndarray) -> np.ndarray:
    """Mean radiance over the area of each ``active`` pixel (flat indices ``(P,)``).

    s×s rays per pixel at the centres of the cells tiling it (``_pixel_grid``); their mean
    is the box average, i.e. ``cv2.INTER_AREA`` downsampling by the integer factor s.
    """
    s = scene.recipe["render"]["supersample"]
    offsets = (np.arange(s) + 0.5) / s - 0.5
    ox, oy = np.meshgrid(offsets, offsets)
    px = (active % cam.width)[:, None] + ox.ravel()[None, :]  # (P, s*s)
    py = (active // cam.width)[:, None] + oy.ravel()[None, :]
    origin, directions = pixel_rays(cam, np.stack([px.ravel(), py.ravel()], axis=1))
    return _radiance(scene, origin, directions).reshape(len(active), s * s).mean(
        axis=1, dtype=np.float64)


def render_view(scene: Scene, index: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Render view ``index``: 8-bit image, depth map and surface points at pixel centres.

    Returns
    -------
    image : (H, W) uint8
    depth : (H, W) float32, camera-frame z of the point seen through each pixel
        centre, NaN off the object.
    points : (H, W, 3) float64, that surface point (NaN off the object).

    Notes
    -----
    Only pixels within one pixel of a centre ray that hits the object are
    supersampled; the rest are background exactly.  An object part thinner than
    about a pixel that no pixel-centre ray meets may therefore be missed.
    """
    import cv2

    cam = scene.cameras[index]
    W, H = cam.width, cam.height
    # truth: one ray through each pixel centre, refined in float64
    origin, directions = pixel_rays(cam, _pixel_grid(W, H))
    hit = scene.caster.cast(origin, directions)
    on = hit["ids"] >= 0
    depth = np.full(W * H, np.nan)
    depth[on] = scene.caster.refine(origin, directions[on], hit["ids"][on])
    points = np.full((W * H, 3), np.nan)
    points[on] = origin + depth[on, None] * directions[on]
    # image: s×s rays per pixel near the object, box-averaged
    near = cv2.dilate(on.reshape(H, W).astype(np.uint8), np.ones((3, 3), np.uint8)).ravel() > 0
    radiance = np.full(W * H, scene.recipe["lighting"]["background"] / 255.0)
    radiance[near] = _box_radiance(scene, cam, np.flatnonzero(near))
    grey = scene.gains[index] * 255.0 * radiance.reshape(H, W) + scene.offsets[index]
    noise = scene.recipe["noise"]
    blur = noise.get("blur_difference_px", 0.0)
    if blur > 0 and index % 2 == 1:
        grey = cv2.GaussianBlur(grey, (0, 0), blur, borderType=cv2.BORDER_REFLECT)
    sigma = noise["sigma"]
    corr = noise.get("correlation_px", 0.0)
    if sigma > 0 and corr > 0:
        draw = _seeded(scene.recipe["seed"], 100 + index).normal(0.0, 1.0, grey.shape)
        draw = cv2.GaussianBlur(draw, (0, 0), corr, borderType=cv2.BORDER_REFLECT)
        grey = grey + sigma * draw / draw.std()
    elif sigma > 0:
        grey = grey + _seeded(scene.recipe["seed"], 100 + index).normal(0.0, sigma, grey.shape)
    image = np.clip(np.rint(grey), 0, 255).astype(np.uint8)
    return image, depth.reshape(H, W).astype(np.float32), points.reshape(H, W, 3)


def visible_from(scene: Scene, index: int, points: np.ndarray) -> np.ndarray:
    """Whether each of ``points (N, 3)`` (on the surface) is unoccluded from camera ``index``."""
    cam = scene.cameras[index]
    origin = cam.center
    directions = points - origin  # the point sits at ray parameter 1
    hit = scene.caster.cast(origin, directions)
    in_front = (points - origin) @ cam.R[2] > 0
    return in_front & (hit["t"] >= 1.0 - TOL.occlusion_rel)


def correspondence(scene: Scene, points: np.ndarray, target: int = 1) -> np.ndarray:
    """Pixel coordinates in view ``target`` of the surface ``points (H, W, 3)`` of another view.

    Returns ``(H, W, 2) float64`` (x, y) with distortion, NaN where the point is
    off the object, occluded in the target view or outside its image
    (x, y outside [-0.5, W-0.5] × [-0.5, H-0.5]).
    """
    H, W = points.shape[:2]
    flat = points.reshape(-1, 3)
    out = np.full((H * W, 2), np.nan)
    on = np.all(np.isfinite(flat), axis=1)
    on[on] = visible_from(scene, target, flat[on])
    cam = scene.cameras[target]
    xy = cam.project(flat[on])
    inside = ((xy[:, 0] >= -0.5) & (xy[:, 0] <= cam.width - 0.5)
              & (xy[:, 1] >= -0.5) & (xy[:, 1] <= cam.height - 0.5))
    xy[~inside] = np.nan
    out[on] = xy
    return out.reshape(H, W, 2)


# --------------------------------------------------------------------------- files


def _scene_json(scene: Scene, source: str) -> str:
    info = {
        "recipe": scene.recipe,
        "derived": scene.derived,
        "source": Path(source).name,
        "conventions": {
            "camera": "world->camera x_c = R X + t (OpenCV); pixel centres at integer "
                      "coordinates; distortion k1 k2 p1 p2 k3 (Brown-Conrady, OpenCV order)",
            "depth": "truth/depth_XX.npy float32 (H, W): camera-frame z of the surface point "
                     "seen through each pixel centre; NaN off the object",
            "correspondence": "truth/correspondence.npy float64 (H, W, 2): (x, y) in view_01 "
                              "of the point seen through each view_00 pixel centre; NaN off "
                              "the object, occluded in view_01 or outside its image",
            "image": "grey = gain * 255 * mean over the pixel of albedo * (ambient + diffuse * "
                     "max(0, n.l)) + offset + N(0, sigma^2), rounded and clipped to 0..255",
            "colmap": "sparse/: principal point + 0.5 (COLMAP's pixel-corner origin)",
        },
    }
    return json.dumps(info, indent=2, sort_keys=True) + "\n"


def render_scene(recipe_or_path: dict | str | os.PathLike, outdir: str | os.PathLike,
                 progress: bool = True, source: str | None = None) -> Path:
    """Render a scene and write its folder atomically; return ``outdir``.

    Parameters
    ----------
    recipe_or_path : dict or path-like
        A recipe file, or a recipe dict (validated again here).
    outdir : path-like
        The output folder (replaced as a whole on success, untouched on error):
        ``images/view_XX.png``, ``cameras.yml``, ``sparse/{cameras,images,points3D}.txt``,
        ``truth/mesh.ply``, ``truth/depth_XX.npy``, ``truth/correspondence.npy``
        (stereo), ``scene.json``.
    progress : bool
        Per-view progress bar on stderr when it is a terminal.
    source : str, optional
        Name used in error messages and ``scene.json`` for a recipe given as a dict.
    """

    from pipeline.atomic import atomic_dir
    from pipeline.guards import write_image
    from pipeline.mesh_io import write_mesh

    if isinstance(recipe_or_path, Mapping):
        source = source or "<recipe>"
        recipe = validate_recipe(recipe_or_path, source)
    else:
        source = str(recipe_or_path)
        recipe = load_recipe(recipe_or_path)
    key = scene_cache.cache_key(recipe, Path(source).name)
    outdir = Path(outdir)
    with atomic_dir(outdir, kind="synth") as tmp:  # never deletes files it did not write
        # the same recipe, code and libraries render the same bytes (pipeline.scene_cache)
        if scene_cache.fetch(key, tmp):
            return outdir
        scene = build_scene(recipe, source)
        (tmp / "images").mkdir()
        (tmp / "truth").mkdir()
        first_points = None
        for index in _views(scene, progress):
            image, depth, points = render_view(scene, index)
            name = scene.cameras[index].name
            write_image(tmp / "images" / name, image)
            np.save(tmp / "truth" / f"depth_{index:02d}.npy", depth)
            if index == 0:
                first_points = points
        stereo = recipe["cameras"]["layout"] == "stereo"
        if stereo:
            np.save(tmp / "truth" / "correspondence.npy", correspondence(scene, first_points, 1))
        write_mesh(tmp / "truth" / "mesh.ply", scene.vertices, scene.triangles)
        rig = StereoRig(*scene.cameras) if stereo else None
        write_cameras_yml(tmp / "cameras.yml", scene.cameras, rig=rig)
        write_colmap_text(tmp / "sparse", scene.cameras)
        (tmp / "scene.json").write_text(_scene_json(scene, source))
        scene_cache.store(key, tmp)
    return outdir


def _views(scene: Scene, progress: bool):
    indices = range(len(scene.cameras))
    if not progress:
        return indices
    from pipeline.progress import track

    return track(indices, desc="synth", unit="view")
