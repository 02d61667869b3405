"""The stitch stage of ``photosurf run``: the curves' rings joined into a triangle mesh
(:func:`surface.stitch.stitch_rings`, the end rings moved to the cap points and each end
classified first), or, for one-sided data, the open arcs joined into an open surface
facing the cameras (:func:`surface.open_surface.stitch_arcs`).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import TYPE_CHECKING

import numpy as np

from pipeline import artifacts
from pipeline.errors import InputError
from pipeline.stage_cameras import camera_centres

if TYPE_CHECKING:
    from pipeline.engine import StageContext

log = logging.getLogger("photosurf")


def _stitch_open(ctx: StageContext, rings: list, params: list, step: float) -> dict:
    """``surface.open_surface.stitch_arcs`` of the curves stage's open arcs, facing the
    cameras when they are known."""
    from surface.metrics import mesh_topology
    from surface.open_surface import BORDER_REACH, stitch_arcs

    eyes = camera_centres(ctx)
    try:  # the rings end on the smooth border curves: strips join their ends
        result = stitch_arcs([r[0] for r in rings], params, step, viewpoint=eyes,
                             reach=BORDER_REACH)
    except ValueError as exc:  # no two neighbouring arcs overlap
        raise InputError(f"stitch: {exc} (set sections.count or sections.spacing)") from exc
    topology = mesh_topology(result.vertices, result.triangles)
    notes = {**result.info(), "closed": False, "messages": list(result.notes),
             "faces_cameras": eyes is not None, "edge_manifold": topology["edge_manifold"],
             "oriented": topology["oriented"], "components": topology["components"]}
    artifacts.write_stitched(ctx.out, result.vertices, result.triangles, notes)
    for message in result.notes:
        log.warning("stitch: %s", message)
    from pipeline.bezier_surface import solid_report  # open by design: its border no defect

    notes["solid"] = solid_report("stitch", result.vertices, result.triangles,
                                  expect_closed=False)
    return {"vertices": len(result.vertices), "triangles": len(result.triangles), **notes}


def stitcher(params: Mapping, planes: list, noise: float | None, cap_cloud, spacing: float,
              cap_sigma=None, leave_holes: bool = False, points=None):
    """``(rings, planes) -> (StitchResult, notes)`` with the stitch stage's rules: end rings
    moved to the cap points (``stitch.extend_ends``, weighted by their precision
    ``cap_sigma`` where known), caps, support rings at sharp rims (``stitch.support``),
    inner caps at their cap points' height; ``notes`` are the end extension's.  Each end
    is classified on the un-extended end loops (``surface.reconstruct.classify_ends``,
    the cloud ``points`` counting a mouth's sheets): a mouth on a wall too thin to part is
    left as a border, and with ``leave_holes`` (``sections.open``) a hole in the data;
    ``build.holes`` / ``build.mouths`` are then the last build's ``(bottom, top)`` ends
    left open.  ``build.ends``: the last build's end placements, their standard errors
    (``surface.reconstruct.extend_to_caps``) and kinds with the evidence."""
    from surface import reconstruct as rc
    from surface import stitch as st

    support = noise if params["support"] and noise is not None else None

    def build(rings, ring_planes, diagnostics=True):
        # a lone loop as itself, as surface.reconstruct.surface_from_points passes it
        rings = [item[0] if isinstance(item, list) and len(item) == 1 else item
                 for item in rings]
        notes_ends, close, kinds = [], params["caps"], None
        if params["caps"] and spacing > 0 and (leave_holes or points is not None):
            kinds = rc.classify_ends(rings, ring_planes[0].frame, cap_cloud, spacing, points,
                                     open_holes=leave_holes)
            notes_ends = [k.note for k in kinds if k.note]
            close = tuple(k.closed(leave_holes) for k in kinds)
            build.holes = tuple(k.kind == "hole" and leave_holes for k in kinds)
            build.mouths = tuple(k.kind == "mouth" and not k.closed() for k in kinds)
            if any(k.outer_only for k in kinds):   # a wall too thin to build both faces
                rings = rc.outer_loops(rings, ring_planes[0].frame)
        build.ends = {}
        if params["caps"] and params["extend_ends"] and spacing > 0:
            rings, notes_extend = rc.extend_to_caps(rings, ring_planes, cap_cloud,
                                                    np.arange(len(cap_cloud)), spacing,
                                                    sigma=cap_sigma, ends=build.ends)
            notes_ends += notes_extend
        for kind in kinds or ():
            build.ends.setdefault(kind.end, {}).update(kind.record())
        result = st.stitch_rings(rings, planes[0].frame[2], close_ends=close,
                                 support_sigma=support, cap_points=cap_cloud,
                                 diagnostics=diagnostics)
        return result, notes_ends

    build.holes, build.mouths, build.ends = (False, False), (False, False), {}
    return build


def stitch(ctx: StageContext) -> dict:
    """``surface.reconstruct.extend_to_caps`` (end rings to the cap points), then
    ``surface.stitch.stitch_rings`` (with support rings at sharp profile turns when
    ``stitch.support``; inner caps at their cap points' height); stitch.json holds the
    loop graph."""
    p = ctx.params["stitch"]
    rings, planes, noise = artifacts.read_curves(ctx.stage_path("curves"))
    arcs = artifacts.read_arc_parameters(ctx.stage_path("curves"))
    if arcs is not None:  # one-sided data: an open surface with a border
        return _stitch_open(ctx, rings, *arcs)
    _, cap_cloud, spacing = artifacts.read_sections(ctx.stage_path("sections"))
    cap_sigma = artifacts.read_cap_sigma(ctx.stage_path("sections"))
    points = (artifacts.read_cloud(ctx.stage_path("acquire"))["points"]
              if ctx.has_output("acquire") else None)   # a mouth's sheets are counted in it
    build = stitcher(p, planes, noise, cap_cloud, spacing, cap_sigma,
                      leave_holes=bool(ctx.params["sections"]["open"]), points=points)
    result, notes_ends = build(rings, planes)
    messages = notes_ends + list(result.notes) + list(result.messages)
    notes = {"closed": bool(result.closed), "messages": messages,
             # sections.open: a hole in the data left as a border; a mouth on a wall too
             # thin to part left open (either: the smooth stage's open path)
             **({"open": True, "holes": [bool(h) for h in build.holes]}
                if any(build.holes) else {}),
             **({"open": True, "mouths": [bool(m) for m in build.mouths]}
                if any(build.mouths) else {}),
             # each end: where and how it was placed, the placement's own standard error,
             # its kind (none, hole, mouth) and the evidence
             "ends": build.ends,
             "open_interfaces": list(result.open_interfaces), "flips": int(result.flips),
             "delaunay_fraction": float(result.delaunay_fraction),
             "branch_events": result.graph.counts() if result.graph else {}}
    artifacts.write_stitched(ctx.out, result.vertices, result.triangles,
                             {**notes, "loop_graph": result.graph.to_json() if result.graph
                              else None})
    thin = [m for m in notes_ends if "too thin" in m]   # the one line a user must read
    for message in thin + list(result.messages):
        log.warning("stitch: %s", message)
    for message in [m for m in notes_ends if m not in thin] + list(result.notes):
        log.info("stitch: %s", message)
    from pipeline.bezier_surface import solid_report  # one warning line when not a valid solid

    notes["solid"] = solid_report("stitch", result.vertices, result.triangles,
                                  expect_closed=bool(result.closed))
    return {"vertices": len(result.vertices), "triangles": len(result.triangles), **notes}
