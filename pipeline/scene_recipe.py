"""Scene recipes: a TOML file read into a table with defaults, and every field validated.

A recipe names the shape (profile, section scales or a mesh file; pose), the texture, the lighting
and the cameras (a stereo pair or a ring, intrinsics, distortion, per-view gain and offset); the
fields, their units and defaults are in ``docs/formats.md`` and ``fixtures/scenes/*.toml``.  A
recipe that cannot be rendered is an :class:`pipeline.errors.InputError` naming the file and the
field (:func:`load_recipe`, :func:`validate_recipe`).
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from matching.cameras import Camera
from pipeline import limits
from pipeline.errors import InputError
from pipeline.scene_geometry import TOL, intrinsics, revolution_functions, undistort_pixels

__all__ = ["DEFAULT_RECIPE", "load_recipe", "validate_recipe"]


#: Default recipe shipped with the project.
DEFAULT_RECIPE = Path(__file__).resolve().parents[1] / "fixtures" / "scenes" / "vase.toml"


_REQUIRED = object()


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
        _, radius_x, radius_y = revolution_functions(shape)
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
        K, dist = intrinsics(cams)
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
