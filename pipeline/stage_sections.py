"""The sections stage of ``photosurf run``: the acquired cloud sliced into parallel planar
sections (:func:`surface.reconstruct.slice_cloud`), along an axis that is given, or read
from the data (the cameras' ring normal, else the cloud's principal axis across the
cameras' view).
"""

from __future__ import annotations

import json
import logging
import warnings
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from pipeline import artifacts
from pipeline.errors import InputError
from pipeline.stage_cameras import view_cameras

if TYPE_CHECKING:
    from pipeline.engine import StageContext

log = logging.getLogger("photosurf")


def sections(ctx: StageContext) -> dict:
    """``surface.reconstruct.slice_cloud``: slice and move the slab points to their planes."""
    from pipeline.guards import (
        MIN_EXTENT,
        check_cloud_shape,
        check_section_cost,
        drop_far_outliers,
    )
    from surface import reconstruct as rc
    from surface import sections as sections_mod

    p = ctx.params["sections"]
    cloud = artifacts.read_cloud(ctx.stage_path("acquire"))
    # far stray points would set the sections' extent: dropped, with a warning line
    points, cap_sigma, outliers = drop_far_outliers(cloud["points"], "sections",
                                                    cloud["sigma"])
    axis, axis_source = _section_axis(p["axis"], ctx.stage_path("acquire", artifacts.RING_FILE))
    if isinstance(p["axis"], str) and p["axis"] == "data" and axis_source.startswith("z "):
        axis, axis_source = _across_the_view(points, view_cameras(ctx), axis, axis_source)
    elif isinstance(p["axis"], str) and p["axis"] == "data" and axis == "auto":
        # SfM frame, no ring: cameras on one side (a facade) get sections along their view
        axis, axis_source = _across_the_view(points, view_cameras(ctx), axis, axis_source,
                                             one_side=True)
    check_cloud_shape(points, "acquire: the cloud", axis=axis)  # a line or plane: no surface
    extent = float(np.ptp(points, axis=0).max()) if len(points) else 0.0
    if 0 < extent < MIN_EXTENT:  # the stages' lengths are in scene units: not rescaled here
        raise InputError(f"sections: the cloud spans {extent:.3g} scene units, below "
                         f"{MIN_EXTENT:g}, where the surface code's absolute tolerances change "
                         "the result; give the cloud in a smaller unit (or use photosurf "
                         "sections, which rescales it)")
    check_section_cost(points, axis, "sections", sections=p["count"] or None,
                       spacing=p["spacing"] or None)  # before anything is allocated
    if outliers:
        log.warning("%s", outliers)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", sections_mod.SectionSkippedWarning)
        sliced = rc.slice_cloud(
            points, axis=axis, sections=p["count"] or None, spacing=p["spacing"] or None,
            thickness=p["thickness"] or None, projection=p["projection"])
    kept = [s for s in sliced.sections if len(s) > 0]
    if len(kept) < 2:
        raise InputError(f"sections: only {len(kept)} non-empty sections; need at least 2 "
                         "(set sections.count or sections.spacing)")
    artifacts.write_sections(ctx.out, kept, sliced.cap_cloud, sliced.spacing,
                             cap_sigma[sliced.cap_index])
    warned = [str(w.message) for w in caught]
    for message in warned:
        log.warning("sections: %s", message)
    for message in sliced.notes:  # axis = "auto": the axis chosen and why
        log.info("sections: %s", message)
    used = kept[0].frame[2]
    return {"sections": len(kept), "empty": len(sliced.sections) - len(kept),
            "spacing": sliced.spacing, "cap_points": len(sliced.cap_cloud),
            "axis": [round(float(a), 6) for a in used], "axis_source": axis_source,
            "warnings": warned, "notes": list(sliced.notes),
            **({"outliers": outliers.split(": ", 1)[1]} if outliers else {})}


def _section_axis(axis, ring_file: Path):
    """The slicing axis and what it is: ``"data"`` is the cameras' ring normal when they
    form a ring (:func:`matching.ring.fit_ring`), else the cloud's principal axis in an
    SfM frame (whose z means nothing) and z in the user's own frame."""
    if not (isinstance(axis, str) and axis == "data"):
        return axis, "given" if not isinstance(axis, str) else f"sections.axis = {axis}"
    ring = json.loads(ring_file.read_text()) if ring_file.is_file() else {}
    if ring.get("is_ring"):
        return ring["axis"], "ring normal of the cameras"
    if ring.get("frame") == "sfm":
        return "auto", "principal axis (SfM frame; cameras not a ring)"
    return "z", "z (no camera ring)"


#: Largest angle (degrees) between the z axis and the cameras' mean viewing direction at
#: which ``sections.axis = "data"`` moves off z: closer than 45° the section planes face
#: the cameras more than they contain their rays, and a surface seen face-on is cut into
#: depth slabs (a real stereo pair's rig frame has z along the left optical axis: on the
#: chessboard pair 255 sections of blobs and a non-manifold stitched mesh).
AXIS_VIEW_DEGREES = 45.0


def _across_the_view(points, cameras, axis, source, one_side: bool = False):
    """The cloud's principal direction across the cameras' mean viewing direction ``d``
    (the largest eigenvector of ``(I - d dᵀ) Σ (I - d dᵀ)``), when z lies within
    :data:`AXIS_VIEW_DEGREES` of ``d``, or with ``one_side`` when every camera centre lies
    within 90° of their mean direction from the cloud's median (they see one side: each
    section then holds the view, a depth profile of what they see); else ``axis,
    source`` unchanged."""
    if not cameras:
        return axis, source
    view = np.mean([camera.R[2] for camera in cameras], axis=0)   # optical axes in world
    view /= np.linalg.norm(view)
    if one_side:
        sides = np.array([c.center for c in cameras]) - np.median(points, axis=0)
        sides /= np.linalg.norm(sides, axis=1)[:, None]
        mean = sides.sum(axis=0)
        if not (np.linalg.norm(mean) > 0 and np.min(sides @ mean) > 0):
            return axis, source
    elif abs(view[2]) < np.cos(np.radians(AXIS_VIEW_DEGREES)):
        return axis, source
    across = np.eye(3) - np.outer(view, view)
    centred = np.asarray(points, np.float64) - np.median(points, axis=0)
    scatter = across @ (centred.T @ centred) @ across
    principal = np.linalg.eigh(scatter)[1][:, -1]
    return ([round(float(a), 9) for a in principal],
            "principal axis across the cameras' view (" + (
                "they see the cloud from one side)" if one_side else
                f"z is within {AXIS_VIEW_DEGREES:g} degrees of their viewing direction)"))
