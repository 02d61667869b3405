"""Documented limits on every size a user can set, checked before anything is allocated.

A request past a limit is refused in one line naming the key, the value and
its estimated cost::

    photosurf sections: error: --sections: sections.count = 1000000000 is past the
    limit 100000 (estimated 8e+02 GB, 2.8e+04 h); ... (--allow-large or
    PHOTOSURF_ALLOW_LARGE=1 lifts the limits)

``photosurf --allow-large COMMAND ...`` (or the environment variable
``PHOTOSURF_ALLOW_LARGE=1``, inherited by Dask workers) lifts every limit for
a machine that can afford the request.  The estimates are linear cost models,
cost = value x (bytes, seconds) per unit, with per-unit figures of this
code's own arrays (the memory of the arrays the step allocates per unit, the
time per unit of the step on one 2020s core); they are orders of magnitude,
meant to say *why* a request is refused.

Each limit is chosen so that a request at the limit still fits a 24 GB
machine; the defaults and the shipped fixtures are far below every one
(``tests/pipeline/test_hostile.py`` checks that the demo recipe and the
defaults pass).  The limits, their values and per-unit costs are :data:`LIMITS`
(built from the table ``_TABLE`` below, each row with where its cost comes from);
what each key counts, for a user, is the table of ``docs/cli.md`` (*Hostile and
extreme input*): ``image.pixels``, ``synth.views`` / ``pixels`` / ``rays`` /
``triangles``, ``texture.components``, ``render.supersample`` / ``pixels``,
``sections.count``, ``ring.points``, ``mesh.triangles``, ``smooth.triangles``,
``smooth.valence`` (a control vertex's valence n, cost ~n²), ``iterations``, ``workers``,
``file.elements`` (what a mesh or cloud file claims, before it is read),
``calibrate.corners`` and ``cad.patches``.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass

from pipeline.errors import InputError, escape

#: Environment variable that lifts every limit (``photosurf --allow-large`` sets it).
ALLOW_ENV = "PHOTOSURF_ALLOW_LARGE"


@dataclass(frozen=True)
class Limit:
    """One documented limit: the largest value, and the cost of one unit.

    Attributes
    ----------
    key : str
    maximum : float
    bytes_each : float
        Memory per unit, bytes (the arrays the step allocates per unit).
    seconds_each : float
        Time per unit on one core, seconds.
    unit : str
        What one unit is, for the message.
    power : int
        The cost grows as ``value ** power`` (1: linear).
    """

    key: str
    maximum: float
    bytes_each: float
    seconds_each: float
    unit: str
    power: int = 1


_TABLE = (
    # decoded image (3 B), grey float64 (8), gradients/pyramids/LSM maps (~60)
    Limit("image.pixels", 1e8, 72, 2e-6, "pixel"),
    # each view: an image, a depth map (float32) and its truth at the default 640x480 x 9
    Limit("synth.views", 1000, 640 * 480 * 9 * 100, 640 * 480 * 9 * 1e-6, "view"),
    # one ray: origin/direction float32 (24 B), hit t/ids/uv/normal (40 B), float64 shading (~90)
    Limit("synth.pixels", 1e8, 150, 1e-6, "ray"),
    Limit("synth.rays", 1e10, 0, 1e-6, "ray"),
    # vertices, corner normals (72 B), open3d's BVH (~150 B)
    Limit("synth.triangles", 2e7, 250, 2e-6, "triangle"),
    # per ray per component: one sinusoid (~10 ns), float64 sums
    Limit("texture.components", 4096, 640 * 480 * 9 * 8, 640 * 480 * 9 * 1e-8, "component"),
    Limit("render.supersample", 16, 640 * 480 * 150, 640 * 480 * 1e-6, "supersample^2"),
    # float64 RGB, depth, normals of each sample
    Limit("render.pixels", 1e8, 80, 2e-7, "pixel"),
    # per section: a slab of points, a loop graph, a curve fit (~1 ms)
    Limit("sections.count", 1e5, 8e5, 1e-3, "section"),
    Limit("ring.points", 1e5, 1e5, 1e-4, "ring point"),
    # vertices (24 B / 2 per triangle), faces (24 B), flips/edge tables (~50 B)
    Limit("mesh.triangles", 5e7, 90, 1e-6, "triangle"),
    # vertices, normals (48 B / 2), faces (24 B), welding ids (~40 B)
    Limit("smooth.triangles", 5e7, 90, 3e-7, "triangle"),
    # Loop's ring patches of a vertex of valence n: a (28n, 18n + 2) operator from a
    # subdivided (~33n, 3n + 1) template; measured peak memory over the valence-50 run
    # (photosurf smooth on a bipyramid, valence 200 / 300 / 400: 0.74 / 1.72 / 3.07 GB,
    # 12 / 40 / 79 s): 19 kB and 0.5 ms per n^2, so 1000 needs ~19 GB, 2000 ~77 GB
    Limit("smooth.valence", 1000, 1.92e4, 5e-4, "valence^2", power=2),
    # one Gauss-Newton iteration over every candidate of a 1024x768 pair at spacing 3
    Limit("iterations", 1000, 0, 0.05, "iteration"),
    # one Dask worker process (interpreter, numpy, open3d, numba)
    Limit("workers", 64, 3e8, 2.0, "worker"),
    # a vertex or face: float64 x 3 or int64 x 3 plus open3d's copy
    Limit("file.elements", 1e8, 48, 2e-7, "element"),
    # OpenCV's chessboard search grows with the corners and the image
    Limit("calibrate.corners", 1e4, 1e4, 1e-3, "corner"),
    # OpenCascade's STEP model of a patch (~43 entities) and its text: measured on the demo's
    # 34 216 patches, 0.8 GB of peak memory and 9.3 s (2026-12-06); a dense real surface
    # (the temple posed by SfM: 424 832 patches) would take ~10 GB and a 1.7 GB file
    Limit("cad.patches", 5e5, 2.4e4, 2.7e-4, "patch"),
)

#: Every limit by key.
LIMITS = {limit.key: limit for limit in _TABLE}


class LimitError(InputError):
    """A request past a documented limit (one line: key, value, estimated cost)."""


#: Values of ``PHOTOSURF_ALLOW_LARGE`` that lift the limits, and those that keep them;
#: anything else (``banana``, ``2``) is an error naming the variable, never a lifted limit.
ALLOW_YES = ("1", "yes", "true", "on", "y")
ALLOW_NO = ("", "0", "no", "false", "off", "n")


def allowed() -> bool:
    """True when ``PHOTOSURF_ALLOW_LARGE`` is an explicit yes (:data:`ALLOW_YES`).

    Raises
    ------
    InputError
        The variable holds something that is neither a yes nor a no.
    """
    raw = os.environ.get(ALLOW_ENV, "")
    value = raw.strip().lower()
    if value in ALLOW_YES:
        return True
    if value in ALLOW_NO:
        return False
    raise InputError(f"{ALLOW_ENV}={escape(raw)!s} is neither yes ({', '.join(ALLOW_YES)}) "
                     f"nor no ({', '.join(v for v in ALLOW_NO if v)}, or unset)")


def _amount(value: float, unit: str) -> str:
    for size, name in ((1e12, "T"), (1e9, "G"), (1e6, "M"), (1e3, "k")):
        if value >= size:
            return f"{value / size:.3g} {name}{unit}"
    return f"{value:.3g} {unit}"


def _duration(seconds: float) -> str:
    if seconds >= 86400:
        return f"{seconds / 86400:.3g} days"
    if seconds >= 3600:
        return f"{seconds / 3600:.3g} h"
    if seconds >= 60:
        return f"{seconds / 60:.3g} min"
    return f"{seconds:.3g} s"


def estimate(key: str, value: float) -> str:
    """The estimated cost of ``value`` units of ``key``: ``"8 GB, 3 h"``."""
    limit = LIMITS[key]
    units = float(value) ** limit.power
    parts = []
    if limit.bytes_each:
        parts.append(_amount(units * limit.bytes_each, "B"))
    if limit.seconds_each:
        parts.append(_duration(units * limit.seconds_each))
    return ", ".join(parts) or "unbounded"


def check(key: str, value: float, where: str | None = None) -> None:
    """Refuse ``value`` of ``key`` past its limit (unless :func:`allowed`).

    Parameters
    ----------
    key : str
        A key of :data:`LIMITS`.
    value : int or float
        The requested amount (already multiplied out: pixels, triangles ...).
    where : str, optional
        The file or option the value came from, leading the message.

    Raises
    ------
    LimitError
        ``"WHERE: KEY = VALUE is past the limit MAX (estimated COST); ..."``.
    """
    limit = LIMITS[key]
    if value <= limit.maximum or allowed():
        return
    shown = f"{int(value)}" if float(value).is_integer() else f"{value:.6g}"
    prefix = f"{where}: " if where else ""
    raise LimitError(f"{prefix}{key} = {shown} is past the limit {limit.maximum:g} "
                     f"(estimated {estimate(key, value)}); --allow-large or "
                     f"{ALLOW_ENV}=1 lifts the limits")


def check_positive(option: str, value: int, key: str, minimum: int = 1) -> None:
    """``value`` at least ``minimum`` and within ``key``'s limit (option-named errors)."""
    if value < minimum:
        raise InputError(f"{option} must be at least {minimum}, got {value}")
    check(key, value, where=option)


#: The defaults of the recipe fields the sizes depend on (``pipeline.scenes``'
#: ``validate_recipe`` fills the same; ``tests/pipeline/test_hostile.py`` checks they agree),
#: so that a raw recipe is costed as the validated one will be.
RECIPE_DEFAULTS = {"render.supersample": 3, "cameras.n": 8}


def _whole(table, key: str, default: int | None = None) -> int | None:
    """``table[key]`` when it is a whole number, ``default`` when absent, else ``None``
    (a value of the wrong type is the validation's to report, not a size)."""
    if not isinstance(table, Mapping) or key not in table:
        return default
    value = table[key]
    return value if isinstance(value, int) and not isinstance(value, bool) else None


def check_recipe(recipe: Mapping, source: str) -> None:
    """The sizes of a scene recipe -- views, pixels, rays, triangles, texture components,
    supersampling -- before any array is made.

    ``recipe`` may be the raw TOML (``photosurf synth`` costs it before the scene code
    is even imported) or the validated one (``pipeline.scenes.validate_recipe``):
    fields that are absent take :data:`RECIPE_DEFAULTS`, fields that are not whole
    numbers are left to the validation.
    """
    cams = recipe.get("cameras")
    render = recipe.get("render")
    supersample = _whole(render, "supersample", RECIPE_DEFAULTS["render.supersample"])
    if supersample is not None:
        check("render.supersample", supersample, where=f"{source}: render.supersample")
    if isinstance(cams, Mapping):
        ring2 = cams.get("second_ring")
        views = 2 if cams.get("layout") == "stereo" else _whole(
            cams, "n", RECIPE_DEFAULTS["cameras.n"])
        extra = _whole(ring2, "n", 0) if cams.get("layout") != "stereo" else 0
        if views is not None and extra is not None:
            views += extra
            check("synth.views", views, where=f"{source}: cameras.n (+ second_ring.n)")
        width, height = _whole(cams, "width"), _whole(cams, "height")
        if width is not None and height is not None and supersample is not None:
            pixels = width * height * supersample ** 2
            check("synth.pixels", pixels,
                  where=f"{source}: cameras.width x cameras.height x render.supersample^2")
            if views is not None and extra is not None:
                check("synth.rays", pixels * views, where=f"{source}: views x pixels per view")
    triangles = _whole(recipe.get("shape"), "triangles")
    if triangles is not None:
        check("synth.triangles", triangles, where=f"{source}: shape.triangles")
    components = _whole(recipe.get("texture"), "components")
    if components is not None:
        check("texture.components", components, where=f"{source}: texture.components")
