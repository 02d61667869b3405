r"""Unorganised points to a stitched mesh: slice, organise, fit, predict, stitch.

The orchestration of the section method from a cloud (DESIGN.md): the steps
are public so that a pipeline can store what is between them, and run in this
order with the same parameters they give :func:`surface_from_points`'s mesh.

1. :func:`slice_cloud` (``surface.section_slicing``: ``surface.sections.slice_sections``,
   then :func:`slide_to_planes`; ``axis="auto"``: :func:`choose_axis`);
2. :func:`organise_sections` (``surface.section_loops``: ``surface.topology.organise`` per
   section);
3. :func:`section_rings` (``surface.section_loops``: ``surface.catmull_rom.predict_sections``);
4. :func:`classify_ends` (``surface.end_kinds``) and :func:`extend_to_caps`
   (``surface.end_caps``);
5. ``surface.stitch.stitch_rings``.

From points (:func:`surface_from_points`): slice, then move every slab
point to its plane along the local surface rather than along the axis
(:func:`slide_to_planes`: on a wall of slope r' an axial projection adds
noise of size r'·(slab half-width); sliding on the tangent plane leaves
O(κδ²)), organise, fit and predict the rings, move the end sections to the
median height of the cap points beyond them (:func:`extend_to_caps`: the
section planes stop half a spacing inside the data), stitch.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from surface._blas import one_blas_thread

# the steps, each in its module, public here as before
from surface.end_caps import (
    extend_to_caps,
    rim_line,
)
from surface.end_kinds import (
    THIN_RIM,
    EndKind,
    classify_ends,
    outer_loops,
)
from surface.section_loops import (
    MAX_BRIDGED_SHARE,
    OneSidedError,
    _drop_one_section_splits,  # noqa: F401  (the open pieces import it from here)
    bridged_share,
    keyhole,
    largest_perimeter,
    min_loop_points,
    organise_sections,
    ring_count,
    section_noise,
    section_rings,
    untangle,
)
from surface.section_slicing import (
    SlicedCloud,
    choose_axis,
    slice_cloud,
    slide_to_planes,
)
from surface.stitch import (
    StitchResult,
    self_intersects,
    stitch_rings,
)

__all__ = ["OneSidedError", "surface_from_points", "slide_to_planes", "extend_to_caps",
           "largest_perimeter",
           "SlicedCloud", "slice_cloud", "organise_sections", "ring_count", "section_rings",
           "min_loop_points", "section_noise", "untangle", "choose_axis", "rim_line",
           "bridged_share", "MAX_BRIDGED_SHARE", "self_intersects", "keyhole", "EndKind",
           "classify_ends", "outer_loops", "THIN_RIM"]


@one_blas_thread
def surface_from_points(points: np.ndarray, axis="z", sections: int | None = None,
                        spacing: float | None = None, thickness: float | None = None,
                        n: int | None = None, smoothing: float | str = "auto",
                        projection: str = "surface", extend_ends: bool = True,
                        close_ends: bool = True, flip: bool = True,
                        support: bool = True, sigma: np.ndarray | None = None,
                        open_holes: bool = False, ends: dict | None = None) -> StitchResult:
    """Unorganised points to a stitched mesh: slice → organise → fit/predict → stitch.

    The steps are public (:func:`slice_cloud`, :func:`organise_sections`,
    :func:`section_rings`, :func:`extend_to_caps`, :func:`stitch_rings`) so
    that a pipeline can store what is between them; run in this order with
    the same parameters they give this function's mesh exactly.

    Parameters
    ----------
    points : (P, 3) float64
        The cloud, scene units.
    axis : {"z", "x", "y", "auto"} or (3,) array_like
        Slicing axis (:func:`surface.sections.slice_sections`); ``"auto"`` is the
        principal axis with the fewest branch events (:func:`choose_axis`, its
        reason the first message).
    sections : int, optional
        Number of sections K (default from the point spacing, see
        ``sections.slice_sections``).
    spacing : float, optional
        Distance between sections instead of ``sections``.
    thickness : float, optional
        Half-width of the slab of points assigned to a section.  Default:
        ``sections.slice_sections``'s with ``projection="axis"``, and half the
        section spacing (every point used once) with ``projection="surface"``.
    n : int, optional
        N, ring points on the odd sections (2N on the even ones); default
        ``ceil(P_max / Δ)`` (largest loop perimeter over the section spacing).
    smoothing : float or "auto"
        Data points per Catmull-Rom control point (``catmull_rom.fit``); ``"auto"``:
        per loop by generalised cross-validation (``catmull_rom.choose_smoothing``), from
        the loop's own residuals and density (the vase cloud, σ = 0.002: 16-32 points per
        control point, stitched Chamfer 0.00042 with a fixed 8 → 0.00029).
    projection : {"surface", "axis"}
        How a slab point reaches its plane: along the local surface (PCA tangent plane;
        surfaces within 30° of the plane left out) or along the axis.
    extend_ends : bool
        Move the end caps from the first and last section planes to the cap points beyond
        them (:func:`extend_to_caps`).
    close_ends : bool
        Cap the first and last sections.
    flip : bool
        Lawson flips.
    support : bool
        Support rings where the profile turns sharply (``stitch_rings``'s
        ``support_sigma`` = :func:`section_noise` of the loops): rims sharp to the noise.
    sigma : (N,) float64, optional
        The points' precision (scene units): the ends are placed with inverse-variance
        weights (:func:`extend_to_caps`); without it (or with any σ unknown) every point
        weighs the same.
    open_holes : bool
        Leave an end the data do not cover (:func:`classify_ends`: unseen, an open mouth)
        as a border instead of capping it flat.
    ends : dict, optional
        Filled with each end's placement and its standard error (:func:`extend_to_caps`)
        and its kind with the evidence (:func:`classify_ends`, ``EndKind.record``).

    Returns
    -------
    StitchResult
        With skipped sections and end extensions reported in ``messages``.

    Raises
    ------
    ValueError
        Bad cloud or parameters (from the steps), an unknown projection, or
        fewer than two sections with a loop.
    """
    # |x| > 1e50 overflows the geometry's 4th-6th powers; at ~1e300 Shewchuk's Triangle
    # (section_trees._triangle_edges) crashed the process (pipeline.guards.MAX_COORDINATE)
    extreme = np.abs(np.asarray(points, dtype=np.float64))
    if extreme.size and not extreme.max() <= 1e50:
        raise ValueError(f"points: |coordinates| up to {extreme.max():.3g} (NaN/inf or beyond "
                         "1e50, where products of coordinates overflow float64)")
    sliced = slice_cloud(points, axis=axis, sections=sections, spacing=spacing,
                         thickness=thickness, projection=projection)
    kept, loops, messages = organise_sections(sliced.sections, organised=sliced.organised,
                                              min_points=min_loop_points(smoothing))
    messages = list(sliced.notes) + messages
    rings = section_rings(kept, loops, n, smoothing=smoothing)
    kept, loops, rings, notes = untangle(kept, loops, rings)
    messages += notes
    rings, notes, ends_closed = _placed_ends(rings, kept, sliced, points, sigma, close_ends,
                                             extend_ends, open_holes, ends)
    messages += notes
    result = stitch_rings(rings, kept[0].frame[2], close_ends=ends_closed, flip=flip,
                          support_sigma=section_noise(loops) if support else None,
                          cap_points=sliced.cap_cloud)
    if len(result.triangles) == 0:
        raise ValueError(f"no surface from {len(kept)} section(s) with loops: "
                         f"{result.problem_line()} (too few points or sections?)")
    if messages:
        result = replace(result, messages=tuple(messages) + result.messages)
    return result


def _placed_ends(rings, kept, sliced, points, sigma, close_ends, extend_ends, open_holes,
                 ends) -> tuple[list, list[str], tuple | bool]:
    """``(rings, notes, closed)`` with the ends classified (:func:`classify_ends`; a too
    thin mouth keeps the outer loops only) and placed (:func:`extend_to_caps`), each end's
    kind and placement recorded in ``ends``; ``closed`` the stitch's ``close_ends``."""
    messages, kinds = [], None
    if close_ends:   # on the sections' own end loops: an extended ring may drift off the data
        kinds = classify_ends(rings, kept[0].frame, sliced.cap_cloud, sliced.spacing,
                              points, open_holes)
        messages += [k.note for k in kinds if k.note]
        if any(k.outer_only for k in kinds):
            rings = outer_loops(rings, kept[0].frame)
    if extend_ends and close_ends:
        cap = sliced.cap_cloud
        cap_sigma = None if sigma is None else np.asarray(sigma, np.float64)[sliced.cap_index]
        rings, notes = extend_to_caps(rings, kept, cap, np.arange(len(cap)), sliced.spacing,
                                      sigma=cap_sigma, ends=ends)
        messages += notes
    if kinds is not None and ends is not None:   # the placement and the kind, per end
        for kind in kinds:
            ends.setdefault(kind.end, {}).update(kind.record())
    ends_closed = tuple(k.closed(open_holes) for k in kinds) if kinds else close_ends
    return rings, messages, ends_closed
