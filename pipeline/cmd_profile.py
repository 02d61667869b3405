"""``photosurf profile``: the profile drawing, volume, area and capacity of an object.

Input: a control net ``.npz`` (the exact Bézier surface: :mod:`pipeline.export`'s format
or a workspace's ``smooth/control_net.npz``), a workspace folder (its smooth stage's
control net, else its stitched mesh; the sections' axis and the cloud's σ come with it),
or a closed triangle mesh (.ply .obj .stl .gltf .off).

The surface is tessellated (a control net: level 1-3, at most ~0.5 M triangles; the chord
bound is stated) and cut by the half-plane through the axis at ``--azimuth`` (default: the
major principal direction of the section at mid height, the widest profile), and at the
opposite azimuth for the diameters (:mod:`surface.profile`).  The axis passes through the
centroid of the section at mid height.  Volume and area are exact integrals over the
patches (:mod:`surface.measure`; the signed tetrahedra for a mesh); a vessel's capacity is
its cavity up to the rim (or ``--fill`` above the base).  The uncertainty ``u`` of a
measure is the larger of the points' σ (``--sigma``, or the workspace cloud's median) and
the tessellation's chord bound: diameters ± 2u, heights and thickness ± √2 u, volume
± u × area and capacity ± u × wet area (first order: a shift of the whole wall by u
along its normal).

Output: ``--out`` a drawing, ``.svg`` or ``.dxf`` (:mod:`pipeline.profile_drawing`), written
atomically; the figures on stdout, or as one JSON object with ``--json``.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np

from pipeline.errors import InputError

HELP = "profile drawing (SVG/DXF), volume, area and capacity of an object with an axis"

DRAWING_SUFFIXES = (".svg", ".dxf")
#: Triangles of the tessellation a control net is cut at, at most (~100 MB of arrays with
#: the ray-casting scene and the profile's work arrays).
MAX_TRIANGLES = 2 ** 19


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("surface", metavar="SURFACE|WORKSPACE",
                        help="control net .npz, workspace folder, or closed mesh "
                             "(.ply .obj .stl .gltf .off)")
    parser.add_argument("--out", default=None, metavar="DRAWING",
                        help="profile drawing: .svg or .dxf")
    parser.add_argument("--axis", default=None, metavar="z|x|y|X,Y,Z",
                        help="the object's axis, base to mouth (default: the workspace's "
                             "sections axis, else z)")
    parser.add_argument("--azimuth", type=float, default=None, metavar="DEG",
                        help="azimuth of the profile plane about the axis (default: the "
                             "widest section)")
    parser.add_argument("--units", default=None, choices=sorted(("mm", "cm", "m", "in")),
                        help="unit of the coordinates (capacity in litres, drawing to scale)")
    parser.add_argument("--scale", default=None, metavar="1:N",
                        help="drawing scale (default: the 1-2-5 step that fits 180 mm)")
    parser.add_argument("--thickness-at", default=None, metavar="Z1,Z2,...",
                        help="heights above the base for the wall thickness (default: a "
                             "quarter, half and three quarters of the height)")
    parser.add_argument("--fill", type=float, default=None, metavar="H",
                        help="capacity up to this height above the base (default: the rim)")
    parser.add_argument("--sigma", type=float, default=None, metavar="S",
                        help="the surface's 1-sigma along its normal, in its unit (default: "
                             "the workspace cloud's median sigma, else the chord bound only)")
    parser.add_argument("--json", action="store_true", help="print the figures as JSON")


def _scale(text: str | None) -> int | None:
    if text is None:
        return None
    parts = text.replace(" ", "").split(":")
    try:
        if len(parts) == 2 and float(parts[0]) == 1:
            n = float(parts[1])
            if n >= 1 and n == int(n):
                return int(n)
    except ValueError:
        pass
    raise InputError(f"--scale must be 1:N with a whole N >= 1, got {text!r}")


def _heights(text: str | None) -> list[float] | None:
    if text is None:
        return None
    try:
        values = [float(p) for p in text.split(",") if p.strip()]
    except ValueError:
        values = []
    if not values or not all(math.isfinite(v) and v >= 0 for v in values):
        raise InputError(f"--thickness-at must be heights >= 0 separated by commas, "
                         f"got {text!r}")
    return values


# --------------------------------------------------------------------------- reading
def _net_surface(cp: np.ndarray, domain: np.ndarray | None, where: str) -> dict:
    """Tessellation of a control net (level from the patch count) with its chord bound."""
    from surface import bezier
    from surface.measure import chord_bound

    if domain is None:
        raise InputError(f"{where}: the control net has no domain triangles: it cannot be "
                         "tessellated without cracks")
    level = int(np.clip(math.floor(math.log(MAX_TRIANGLES / len(cp), 4)), 1, 3))
    vertices, triangles, normals = bezier.tessellate(cp, level, triangles=domain)
    return {"vertices": vertices, "triangles": triangles, "normals": normals,
            "control_points": cp, "chord": chord_bound(cp, level), "level": level}


def _read_npz(path: Path) -> dict:
    from pipeline.export import read_control_net
    from pipeline.guards import regular_file

    regular_file(path, "control-net file")
    try:
        with open(path, "rb") as fh, np.load(fh, allow_pickle=False) as npz:
            names = set(npz.files)
            raw = {k: npz[k] for k in ("control_points", "domain_triangles") if k in names}
    except (OSError, ValueError, EOFError) as exc:
        raise InputError(f"{path}: not a readable .npz ({exc or type(exc).__name__})") from exc
    if "format" in names:
        net = read_control_net(path)
        return _net_surface(net.control_points, net.domain_triangles, str(path))
    cp = raw.get("control_points")
    if cp is None or cp.ndim != 3 or cp.shape[1:] != (28, 3) or len(cp) == 0:
        raise InputError(f"{path}: no control_points (P, 28, 3) in this .npz")
    if not np.all(np.isfinite(cp)):
        raise InputError(f"{path}: control_points holds non-finite values")
    return _net_surface(cp.astype(np.float64), raw.get("domain_triangles"), str(path))


def _read_mesh(path: Path) -> dict:
    from pipeline.mesh_io import MESH_SUFFIXES, read_mesh, weld_vertices

    if path.suffix.lower() not in MESH_SUFFIXES:
        raise InputError(f"{path}: not a control net (.npz), workspace or mesh "
                         f"({' '.join(MESH_SUFFIXES)})")
    vertices, triangles = read_mesh(path)
    return mesh_surface(*weld_vertices(vertices, triangles))


def mesh_surface(vertices: np.ndarray, triangles: np.ndarray) -> dict:
    """A closed triangle mesh ``(V, 3)``, ``(F, 3)`` as :func:`read_surface` returns it."""
    from pipeline.export import vertex_normals

    return {"vertices": vertices, "triangles": triangles,
            "normals": vertex_normals(vertices, triangles), "control_points": None,
            "chord": 0.0, "level": None}


def _read_workspace(folder: Path) -> dict:
    net = folder / "smooth" / "control_net.npz"
    mesh = folder / "stitch" / "mesh.ply"
    if net.is_file():
        surface = _read_npz(net)
    elif mesh.is_file():
        surface = _read_mesh(mesh)
    else:
        raise InputError(f"{folder}: a folder without smooth/control_net.npz or "
                         "stitch/mesh.ply: not a photosurf workspace that reached a surface")
    curves, cloud = folder / "curves" / "curves.npz", folder / "acquire" / "cloud.npz"
    if curves.is_file():
        with np.load(curves) as npz:
            if "axis" in npz.files:
                surface["axis"] = np.asarray(npz["axis"], np.float64)
    if cloud.is_file():
        with np.load(cloud) as npz:
            sigma = np.asarray(npz["sigma"], np.float64) if "sigma" in npz.files else None
        if sigma is not None and np.any(np.isfinite(sigma) & (sigma > 0)):
            surface["sigma"] = float(np.median(sigma[np.isfinite(sigma) & (sigma > 0)]))
    return surface


def read_surface(path: str | Path) -> dict:
    """``vertices, triangles, normals`` of the tessellation, ``control_points`` (None for a
    mesh), ``chord`` bound, and from a workspace ``axis`` and ``sigma`` when known."""
    path = Path(path)
    if path.is_dir():
        return _read_workspace(path)
    if path.suffix.lower() == ".npz":
        return _read_npz(path)
    return _read_mesh(path)


# --------------------------------------------------------------------------- figures
def _principal(surface: dict, axis: np.ndarray) -> tuple:
    from surface.profile import principal_azimuths

    v = surface["vertices"]
    centre = 0.5 * (v.min(axis=0) + v.max(axis=0))
    return principal_azimuths(v, surface["triangles"], axis, centre)


def profile_figures(surface: dict, axis, azimuth: float | None = None,
                    heights: list[float] | None = None, fill: float | None = None,
                    sigma: float | None = None) -> dict:
    """Every figure of the command (scene units) and the profiles to draw.

    ``surface`` as :func:`read_surface` returns it; ``azimuth`` in degrees; ``heights`` and
    ``fill`` above the base.  Returns a dict of plain numbers (JSON-ready) with the
    profiles under the private key ``_profiles``.
    """
    from surface import measure
    from surface.profile import frame, half_profile, measure_profile, silhouette

    v, f, n = surface["vertices"], surface["triangles"], surface["normals"]
    a = frame(axis)[2]
    major, minor, widths, origin = _principal(surface, a)
    u = max(sigma or 0.0, surface["chord"])
    if u == 0.0:
        # a mesh with no sigma: its own resolution, the sagitta of a mean edge on the
        # mid-height section's circle (radius ~ its half width)
        edges = np.linalg.norm(v[f[:, 1]] - v[f[:, 0]], axis=1)
        u = float(np.mean(edges)) ** 2 / (4.0 * max(widths[0], 1e-300))
    phi = major if azimuth is None else math.radians(azimuth)
    z = (v - origin) @ a
    height = float(np.ptp(z))
    heights = [0.25 * height, 0.5 * height, 0.75 * height] if heights is None else heights
    profiles = []
    # non-circular: the principal widths differ by more than 4 u (both ends' uncertainty,
    # twice): both principal profiles are drawn and measured
    circular = widths[0] - widths[1] <= 4.0 * u
    azimuths = [phi] if circular or azimuth is not None else [major, minor]
    for az in azimuths:
        hp = half_profile(v, f, a, origin, az)
        op = half_profile(v, f, a, origin, az + math.pi)
        profiles.append((hp, measure_profile(hp, op, heights, tolerance=u)))
    # the object's height is its extent along the axis (the silhouette's): the cut's own
    # height (profiles[].height) misses a top or foot off the profile plane
    out = {"axis": a.tolist(), "origin": origin.tolist(), "height": height,
           "uncertainty": u,
           "chord_bound": surface["chord"], "sigma": sigma,
           "principal_widths": widths.tolist(), "circular": bool(circular),
           "profiles": [{"azimuth_deg": math.degrees(hp.azimuth) % 360.0, **m,
                         "has_inner_wall": hp.inner is not None} for hp, m in profiles]}
    if surface["control_points"] is not None:
        integrals = measure.surface_integrals(surface["control_points"])
        out.update(volume=integrals["volume"], area=integrals["area"],
                   area_quadrature_error=integrals["area_error"], integrals="exact patches")
    else:
        out.update(volume=measure.mesh_volume(v, f), area=measure.mesh_area(v, f),
                   integrals="mesh")
    out["volume_sigma"] = u * out["area"]
    base = float(profiles[0][1]["base_z"])
    out["capacity"] = None
    if profiles[0][0].inner is not None:
        cap = measure.capacity(v, f, n, a, origin,
                               height=None if fill is None else base + fill)
        if cap.volume > 0:
            out["capacity"] = {"volume": cap.volume, "sigma": u * cap.wet_area,
                               "fill_height": cap.height - base,
                               "rim_height": cap.rim_height - base,
                               "wet_area": cap.wet_area}
    out["_profiles"] = [hp for hp, _ in profiles]
    out["_silhouette"] = silhouette(v, f, a, origin)
    return out


def _with_units(figures: dict, units: str | None) -> None:
    if units is None:
        return
    from pipeline.profile_drawing import UNIT_MM

    litres = (UNIT_MM[units] / 100.0) ** 3  # (unit in dm)^3
    figures["units"] = units
    figures["volume_litres"] = figures["volume"] * litres
    if figures["capacity"] is not None:
        figures["capacity"]["litres"] = figures["capacity"]["volume"] * litres
        figures["capacity"]["sigma_litres"] = figures["capacity"]["sigma"] * litres


def summary_lines(figures: dict) -> list[str]:
    """The measures as text lines (the drawing's and stdout's)."""
    unit = figures.get("units") or "units"
    u = figures["uncertainty"]
    lines = [f"height {figures['height']:.4g} +- {math.sqrt(2) * u:.2g} {unit}"]
    for p in figures["profiles"]:
        lines.append(f"profile at {p['azimuth_deg']:.1f} deg: section height "
                     f"{p['height']:.4g} {unit}")
        lines.append(f"  rim diameter {p['rim_diameter']:.4g}, base diameter "
                     f"{p['base_diameter']:.4g}, max diameter {p['max_diameter']:.4g} at "
                     f"{p['max_diameter_height']:.4g} (+- {2 * u:.2g} {unit})")
        if p["thickness"]:
            wall = ", ".join(f"{t:.3g} at {h:.4g}" for h, t in p["thickness"].items())
            lines.append(f"  wall thickness {wall} (+- {math.sqrt(2) * u:.2g} {unit})")
    lines.append(f"volume {figures['volume']:.6g} +- {figures['volume_sigma']:.2g} {unit}^3, "
                 f"area {figures['area']:.6g} {unit}^2")
    if "volume_litres" in figures:
        lines[-1] += f" ({figures['volume_litres']:.4g} l)"
    cap = figures["capacity"]
    if cap is not None:
        text = (f"capacity {cap['volume']:.6g} +- {cap['sigma']:.2g} {unit}^3 to "
                f"{cap['fill_height']:.4g} above the base (rim {cap['rim_height']:.4g})")
        if "litres" in cap:
            text += f" = {cap['litres']:.4g} +- {cap['sigma_litres']:.2g} l"
        lines.append(text)
    return lines


def _drawing(figures: dict, units: str | None, scale: int | None, title: str):
    from pipeline.profile_drawing import Drawing

    hp = figures["_profiles"][0]
    p = figures["profiles"][0]
    return Drawing(section=hp.section, silhouette=figures["_silhouette"],
                   rim_z=float(hp.outer[:, 1].max()), base_z=p["base_z"],
                   lines=summary_lines(figures), others=hp.others, units=units,
                   scale=scale, title=title)


def run(args: argparse.Namespace) -> int:
    from pipeline.guards import check_output

    out = Path(args.out) if args.out is not None else None
    if out is not None and out.suffix.lower() not in DRAWING_SUFFIXES:
        raise InputError(f"{out}: cannot write a drawing as {out.suffix!r} (choose "
                         f"{' or '.join(DRAWING_SUFFIXES)})")
    if out is not None:
        check_output(out, [args.surface])
    scale = _scale(args.scale)
    heights = _heights(args.thickness_at)
    if args.sigma is not None and not (math.isfinite(args.sigma) and args.sigma >= 0):
        raise InputError(f"--sigma must be a number >= 0, got {args.sigma}")
    if args.fill is not None and not (math.isfinite(args.fill) and args.fill > 0):
        raise InputError(f"--fill must be a height > 0 above the base, got {args.fill}")
    if args.azimuth is not None and not math.isfinite(args.azimuth):
        raise InputError(f"--azimuth must be a finite angle in degrees, got {args.azimuth}")
    axis_arg = None
    if args.axis is not None:
        from pipeline.cmd_sections import parse_axis

        axis_arg = parse_axis(args.axis)
        if isinstance(axis_arg, str) and axis_arg == "auto":
            raise InputError("--axis auto is not known here: give z, x, y or X,Y,Z")
    surface = read_surface(args.surface)
    names = {"x": [1.0, 0, 0], "y": [0, 1.0, 0], "z": [0, 0, 1.0]}
    axis = (names[axis_arg] if isinstance(axis_arg, str) else axis_arg) if axis_arg is not None \
        else surface.get("axis", names["z"])
    sigma = args.sigma if args.sigma is not None else surface.get("sigma")
    try:
        figures = profile_figures(surface, np.asarray(axis, np.float64), args.azimuth,
                                  heights, args.fill, sigma)
    except ValueError as exc:
        raise InputError(f"{args.surface}: {exc}") from exc
    _with_units(figures, args.units)
    if out is not None:
        from pipeline.profile_drawing import write_dxf, write_svg

        drawing = _drawing(figures, args.units, scale, Path(args.surface).name)
        (write_svg if out.suffix.lower() == ".svg" else write_dxf)(out, drawing)
        figures["drawing"] = str(out)
    public = {k: v for k, v in figures.items() if not k.startswith("_")}
    if args.json:
        print(json.dumps(public, indent=1))
    elif not args.quiet:
        print(f"photosurf profile: {args.surface}")
        for line in summary_lines(figures):
            print("  " + line)
        if out is not None:
            print(f"  drawing -> {out}")
    return 0
