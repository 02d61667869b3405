"""The smooth stage of ``photosurf run``: the stitched mesh sized to a control mesh
(:mod:`surface.sizing`), its vertices interpolated, and Loop's G1 Bezier patches over it
(:func:`pipeline.bezier_surface.smooth_mesh`); beside it, where the sections give cause, the
general control mesh that knows no axis (:mod:`surface.general_mesh`); over an open
stitched mesh, the patches with the border rule.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Mapping
from typing import TYPE_CHECKING

import numpy as np

from pipeline import artifacts
from pipeline.errors import InputError, StageSkipped
from pipeline.stage_stitch import stitcher

if TYPE_CHECKING:
    from pipeline.engine import StageContext

log = logging.getLogger("photosurf")


def _sized_control_mesh(ctx: StageContext, vertices, triangles):
    """``surface.sizing.size_control_mesh`` of the curves' rings (``smooth.size``): the
    thinned stitched mesh (kept rings regressed across their neighbour sections) whose
    interpolating surface is estimated within ``smooth.size_tolerance`` of the truth (0:
    no farther than the dense stitched mesh, ``surface.sizing.stitched_error`` of the
    rings' variogram across sections, ``surface.sizing.section_variogram``; where it
    cannot be measured, their independent scatter ``surface.section_errors.ring_noise``, else
    their fits' precision stored by the curves stage, else the points' noise σ̂);
    ``None`` when not asked or not possible (no noise estimate, an open mesh), with the
    reason logged."""
    if not ctx.params["smooth"]["size"] or not ctx.has_output("curves") \
            or not ctx.has_output("sections"):
        return None
    rings, planes, noise = artifacts.read_curves(ctx.stage_path("curves"))
    fits = artifacts.read_curve_fits(ctx.stage_path("curves"))
    _, cap_cloud, spacing = artifacts.read_sections(ctx.stage_path("sections"))
    return sized_rings(ctx.params, rings, planes, noise,
                       fits["ring_precision"] if fits is not None else 0.0, cap_cloud, spacing,
                       artifacts.read_cap_sigma(ctx.stage_path("sections")),
                       (vertices, triangles))


def sized_rings(params: Mapping, rings: list, planes: list, noise: float | None,
                precision: float, cap_cloud, spacing: float, cap_sigma, dense: tuple):
    """The smooth stage's sizing of the curves' rings (``rings`` a list of loops per
    section, ``planes`` their sections, as ``pipeline.artifacts.read_curves`` gives them;
    ``precision`` the fits' ring precision; the sections' cap cloud, spacing and cap σ;
    ``dense`` the stitched ``(vertices, triangles)``) with the stitch stage's rules
    (``params``: the run's parameters): a ``surface.sizing.SizedMesh``, or ``None`` with
    the reason logged (:func:`_sized_control_mesh`)."""
    from surface import section_errors, sizing

    p = params["smooth"]
    variogram = sizing.section_variogram(rings, planes[0].frame[2])
    ring_sigma = section_errors.ring_noise(rings, planes[0].frame[2], precision, noise or 0.0) \
        if variogram is None else float(np.sqrt(variogram(1)))
    tolerance = float(p["size_tolerance"]) or None
    if (tolerance is None and variogram is None and ring_sigma <= 0) or spacing <= 0:
        log.info("smooth: no sizing (no noise estimate or section spacing); the stitched "
                 "mesh is the control mesh")
        return None
    build = stitcher(params["stitch"], planes, noise, cap_cloud, spacing, cap_sigma)

    def mesh(thin_rings, thin_planes):
        result, _ = build(thin_rings, thin_planes, diagnostics=False)
        if not result.closed:
            raise ValueError("the thinned rings stitch to an open mesh")
        return result.vertices, result.triangles

    return sizing.size_control_mesh(rings, planes, spacing, mesh, dense,
                                    tolerance, noise=ring_sigma, variogram=variogram)


def smooth(ctx: StageContext) -> dict:
    """``pipeline.bezier_surface.smooth_mesh`` over the control mesh (the one smoothing path,
    with its G1 report: ``g1_angle`` radians, ``gap`` scene units).  The control mesh is
    the stitched mesh thinned by ``surface.sizing`` (``smooth.size``), its vertices
    interpolated except at sharp rims (``smooth.interpolate``:
    ``surface.sizing.interpolating_control``)."""
    from pipeline.bezier_surface import smooth_mesh
    from pipeline.mesh_io import read_mesh
    from surface.sizing import interpolating_control

    vertices, triangles = read_mesh(ctx.stage_path("stitch", artifacts.MESH))
    level = ctx.params["smooth"]["level"]
    info: dict = {}
    if _stitched_open(ctx):
        return _smooth_open(ctx, vertices, triangles, level)
    try:
        sized = _sized_control_mesh(ctx, vertices, triangles)
        if sized is not None:
            _log_sizing(sized, len(triangles))
            vertices, triangles = sized.vertices, sized.triangles
            info = {"size_step": sized.step, "size_n": sized.n,
                    "size_deviation": sized.deviation, "size_tolerance": sized.tolerance,
                    "size_error": sized.error, "size_noise": sized.noise,
                    "size_within_goal": bool(sized.error <= sized.tolerance),
                    "size_variogram": sized.variogram.to_json() if sized.variogram else None,
                    "size_tried": sized.tried,
                    "control_triangles": len(triangles)}
        control, built = vertices, None
        if ctx.params["smooth"]["interpolate"]:  # borders: the mesh's own vertices back
            if sized is not None and sized.surface is not None:
                built = sized.surface   # the sizing built it so, to judge it
            else:   # the object's ridges interpolated too (sizing.crease_vertices)
                creases = sized.creases if sized is not None else _mesh_creases(
                    ctx, vertices, triangles)
                control = interpolating_control(vertices, triangles, creases)
        tolerance = _smooth_tolerance(ctx, sized) if level in ("auto", "adaptive") else None
        if tolerance is not None:
            info["chord_tolerance"] = tolerance
        smoothed = smooth_mesh(control, triangles, level, tolerance, surface=built)
    except ValueError as exc:
        from surface.metrics import mesh_topology

        border = mesh_topology(vertices, triangles)["boundary_edges"]
        if border:  # an open stitched mesh (e.g. one stereo pair sees one side only)
            raise StageSkipped(f"the stitched mesh is open ({border} border edges) and the "
                               f"Bezier construction refused it: {exc}") from exc
        general = _general_surface(ctx, level, tolerance, None, reason=str(exc))
        if general is None:
            raise
        smoothed, chosen = general
        info.update(chosen)
    else:
        general = _general_surface(ctx, level, tolerance, smoothed)
        if general is not None:
            smoothed, chosen = general
            info.update(chosen)
    artifacts.write_smooth(ctx.out, smoothed.vertices, smoothed.triangles, smoothed.normals,
                           smoothed.surface)
    return {**smoothed.info(), **info}


def _general_surface(ctx: StageContext, level, tolerance, section, reason: str = "",
                     noise: float | None = None):
    """``smooth.general``: where one family of parallel sections cannot organise the
    points, the control mesh that knows no axis (``surface.general_mesh``).  ``"auto"``
    builds it beside the section surface and keeps the valid solid, then the one of the
    genus the data support, then the one nearer the cloud
    (``surface.general_mesh.prefer_general``, ``evidence_genus``, ``cloud_fidelity``);
    ``"always"`` takes it; ``"never"`` does not build it.  Returns ``(Smoothed, info)`` when
    the stage's surface changes or was measured, ``None`` when not asked or possible (no
    cloud, too few points).  With ``section`` None (the section surface was refused) the
    general surface stands in when asked.  ``"auto"`` builds it only where the section
    surface gives cause (``surface.general_mesh.needs_general``: not a valid solid, or its
    C beyond what the points' noise about their curves (the curves stage's estimate, else
    ``noise``) and the sizing's goal explain)."""
    from surface import general_mesh
    from surface.sections import point_spacing

    mode = ctx.params["smooth"]["general"]
    if mode not in ("auto", "always", "never"):
        raise InputError(f"smooth.general must be one of auto, always, never, got {mode!r}")
    if mode == "never" or not ctx.has_output("acquire") or not ctx.has_output("sections"):
        return None
    points = artifacts.read_cloud(ctx.stage_path("acquire"))["points"]
    heights = artifacts.section_heights(ctx.stage_path("sections"))
    if len(points) < 4 * general_mesh.NORMAL_NEIGHBOURS or len(heights) < 2:
        return None
    spacing = float(np.median(np.diff(np.sort(heights))))
    own = None
    if ctx.has_output("curves"):  # the points' noise about their sections' curves
        noise = artifacts.read_curves(ctx.stage_path("curves"))[2]
    if section is not None and mode == "auto":
        own = general_mesh.cloud_fidelity(section.vertices, section.triangles, points)
        valid = bool((section.solid or {}).get("valid", True))
        if not general_mesh.needs_general(own, valid, noise):
            return section, {"general_mode": mode, "sections_fidelity": own.to_json(),
                             "control": "sections"}
    try:  # triangles of the section spacing: as fine as the section mesh it stands in for
        vertices, triangles = general_mesh.poisson_control_mesh(points, spacing,
                                                                point_spacing(points))
        if tolerance is None and level in ("auto", "adaptive"):
            tolerance = _smooth_tolerance(ctx)
        general = _general_smooth(vertices, triangles, level, tolerance, points)
    except ValueError as exc:
        log.info("smooth: no general control mesh (%s): the section surface stays", exc)
        return None
    fidelity = general_mesh.cloud_fidelity(general.vertices, general.triangles, points)
    info = {"general_mode": mode, "general_fidelity": fidelity.to_json(),
            "general_control_triangles": len(triangles)}
    if section is None:
        log.warning("smooth: the section surface was refused (%s): the general control mesh "
                    "stands in", reason)
        return general, {**info, "control": "general", "control_triangles": len(triangles)}
    if own is None:
        own = general_mesh.cloud_fidelity(section.vertices, section.triangles, points)
    info["sections_fidelity"] = own.to_json()
    valid = [bool((smoothed.solid or {}).get("valid", True)) for smoothed in (section, general)]
    genera = [(smoothed.solid or {}).get("genus") for smoothed in (section, general)]
    evidence = None
    if mode == "auto" and None not in genera and genera[0] != genera[1]:
        evidence = general_mesh.evidence_genus(
            section.vertices, section.triangles, points,
            general_mesh.support_reach(point_spacing(points), noise))
        info["evidence_genus"] = evidence
    if mode == "always" or general_mesh.prefer_general(
            own, fidelity, section_valid=valid[0], general_valid=valid[1],
            section_genus=genera[0], general_genus=genera[1], evidence_genus=evidence):
        log.info("smooth: the general control mesh carries the surface (valid %s, genus %s, "
                 "A %.3g / C %.3g against the sections' %s, %s, %.3g / %.3g; the data's "
                 "genus %s)", valid[1], genera[1], fidelity.a90, fidelity.c50, valid[0],
                 genera[0], own.a90, own.c50, evidence)
        return general, {**info, "control": "general", "control_triangles": len(triangles)}
    return section, {**info, "control": "sections"}


def _general_smooth(vertices, triangles, level, tolerance, points=None):
    """Loop's patches over the general control mesh: ``pipeline.bezier_surface.smooth_general``
    (fitted to ``points`` where that is a valid solid, else through its vertices, else with
    the folds held back, else over the mesh itself)."""
    from pipeline.bezier_surface import smooth_general
    from surface.sections import point_spacing

    return smooth_general(vertices, triangles, level, tolerance, points=points,
                          spacing=None if points is None else point_spacing(points))


def _stitched_open(ctx: StageContext) -> bool:
    """Whether the stitch stage made an open surface from one-sided data."""
    notes_path = ctx.stage_path("stitch", artifacts.STITCH_NOTES)
    return notes_path.is_file() and bool(json.loads(notes_path.read_text()).get("open"))


def _smooth_open(ctx: StageContext, vertices, triangles, level) -> dict:
    """The smooth stage over an open stitched mesh: the stitched mesh is the control mesh
    (the sizing and the interpolating control points need a closed mesh), Loop's patches
    with the border rule of ``surface.bezier`` (ghost triangles past the border: the
    surface is G1 inside and ends at the border edges without interpolating them)."""
    from pipeline.bezier_surface import smooth_mesh
    from surface.open_surface import boundary_loops

    tolerance = _smooth_tolerance(ctx) if level in ("auto", "adaptive") else None
    try:
        smoothed = smooth_mesh(vertices, triangles, level, tolerance)
    except ValueError as exc:  # e.g. two strips meeting at one vertex only (a pinch)
        raise StageSkipped(f"the open stitched mesh was refused by the Bezier construction: "
                           f"{exc}") from exc
    artifacts.write_smooth(ctx.out, smoothed.vertices, smoothed.triangles, smoothed.normals,
                           smoothed.surface)
    border = boundary_loops(smoothed.triangles)
    length = sum(float(np.linalg.norm(smoothed.vertices[b] - smoothed.vertices[np.roll(b, -1)],
                                      axis=1).sum()) for b in border)
    return {**smoothed.info(), "open": True, "boundary_loops": len(border),
            "boundary_length": length, "control_triangles": len(triangles),
            **({"chord_tolerance": tolerance} if tolerance is not None else {}),
            "border_rule": "surface.bezier ghost layers (the border is approximated, "
                           "not interpolated)"}


def _mesh_creases(ctx: StageContext, vertices, triangles):
    """``surface.interpolation.mesh_creases`` of the stitched mesh, the sections' heights from the
    curves stage; None without curves (a mesh given as input)."""
    from surface import interpolation

    if not ctx.has_output("curves"):
        return None
    rings, planes, _ = artifacts.read_curves(ctx.stage_path("curves"))
    try:
        return interpolation.mesh_creases(vertices, triangles, rings, planes[0].frame[2])
    except ValueError:   # borders or a degenerate mesh: the sharp vertices kept as before
        return None


def _log_sizing(sized, dense_triangles: int) -> None:
    """One line on the sizing's choice; a warning when it kept the dense stitched mesh
    (no thinned candidate within its goal), with the closest candidate and the way to
    accept a coarser surface."""
    if sized.step > 1 or sized.n > 0:
        log.info("smooth: control mesh thinned to sections %d apart, %d ring points: %d of "
                 "%d triangles, estimated error %.3g against its goal %.3g", sized.step,
                 sized.n, len(sized.triangles), dense_triangles, sized.error, sized.tolerance)
        return
    judged = [c for c in sized.tried if isinstance(c.get("error"), float)]
    closest = min(judged, key=lambda c: c["error"] / c["tolerance"], default=None)
    told = "" if closest is None else (
        f"; the closest, sections {closest['step']} apart with {closest['n']} ring points, "
        f"was estimated {closest['error']:.3g} against {closest['tolerance']:.3g}")
    log.warning("smooth: no thinned control mesh was within its goal%s: the dense stitched "
                "mesh is the control mesh (%d triangles, 4 patches each); set "
                "smooth.size_tolerance to the error to accept for a coarser surface", told,
                dense_triangles)


def _smooth_tolerance(ctx: StageContext, sized=None) -> float:
    """Chord tolerance of ``smooth.level = "adaptive"`` / ``"auto"`` (scene units): given,
    else the sized surface's estimated error to the truth
    (``surface.sizing.SizedMesh.chord_tolerance``), else the cloud's median sigma, else
    5 % of the section spacing (the surface between two sections is only known to the
    scale of their spacing, finer facets would show no more)."""
    given = float(ctx.params["smooth"]["tolerance"])
    if given > 0:
        return given
    from_size = sized.chord_tolerance() if sized is not None else 0.0
    if from_size > 0:
        return from_size
    sigma = artifacts.read_cloud(ctx.stage_path("acquire"))["sigma"]
    sigma = sigma[np.isfinite(sigma) & (sigma > 0)]
    if sigma.size:
        return float(np.median(sigma))
    return 0.05 * float(np.median(np.diff(artifacts.section_heights(ctx.stage_path("sections")))))
