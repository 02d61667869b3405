""":func:`stitch_rings`: the rings of all sections -> the closed stitched mesh
(:class:`StitchResult`): strips, splits and merges, caps, flips, checks."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from surface._blas import one_blas_thread
from surface.loop_graph import LoopGraph, loop_graph
from surface.metrics import delaunay_fraction, mesh_topology
from surface.polygon import inside_polygon as _inside
from surface.stitch.bridges import _bridge_heights, _bridge_split
from surface.stitch.caps import (
    CAP_GUARD_RINGS,
    _cap_step,
    _closes,
    _dome,
    _inset_ring,
    _quality_cap,
    cap_triangles,
    end_window,
)
from surface.stitch.checks import self_intersects
from surface.stitch.flips import MAX_NORMAL_CHANGE, _flippable_edges, delaunay_flips
from surface.stitch.support import _nearest_loop, _read_at, _support
from surface.stitch.tiling import (
    _common_angles,
    _nested_angles,
    _ring_order_and_parameter,
    axis_frame,
    tile_min_span,
    zip_rings,
)
from surface.validate import TOL, check_finite, check_shape

__all__ = ['StitchResult', 'stitch_rings']

@dataclass(frozen=True)
class StitchResult:
    """A stitched mesh and how it was made.

    Attributes
    ----------
    vertices : (V, 3) float64
        All ring points, section after section, loop after loop.
    triangles : (F, 3) int64
        Counter-clockwise seen from outside.
    closed : bool
        Every edge has exactly two faces.
    messages : tuple of str
        Human-readable notes: open interfaces (loops splitting or merging),
        incomplete caps, flips that did not converge.
    region : (F,) int64
        ``2 * s`` for the strip between sections ``s`` and ``s + 1``,
        ``-1`` bottom cap, ``-2`` top cap (``-3`` any other cap).
    section_of_vertex : (V,) int64
        Section index of each vertex, counted from the lowest section along
        the axis (the input order, or its reverse if the input runs down).
    loop_of_vertex : (V,) int64
        Loop index (within its section) of each vertex.
    open_interfaces : tuple of int
        Sections ``s`` whose interface to ``s + 1`` was left (partly) open.
    flips : int
        Number of Lawson flips applied.
    delaunay_fraction : float
        Share of flippable edges (not a contour, both faces in one region)
        meeting the local Delaunay criterion after the flips.
    notes : tuple of str
        Informational lines that are not problems: the support rings added
        (``support_sigma``), the branch points tiled.
    graph : LoopGraph or None
        How the loops of adjacent sections correspond (``surface.loop_graph``),
        over the sections as stitched (support rings included).
    problems : tuple of str
        The messages that say why the mesh is not one closed edge-manifold
        surface (interfaces left open, incomplete caps, non-manifold edges,
        inconsistent orientation); :meth:`problem_line` summarises them.
    """

    vertices: np.ndarray
    triangles: np.ndarray
    closed: bool
    messages: tuple[str, ...] = ()
    region: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    section_of_vertex: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    loop_of_vertex: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    open_interfaces: tuple[int, ...] = ()
    flips: int = 0
    delaunay_fraction: float = 1.0
    notes: tuple[str, ...] = ()
    graph: LoopGraph | None = None
    problems: tuple[str, ...] = ()

    def problem_line(self) -> str:
        """The first problem and a count of the others, in one short line.

        For a refusal: ``"sections 15 and 16: ...; and 3 more problems (-v lists
        them)"``; the whole list is in ``problems`` (and in ``messages``).
        """
        if not self.problems:
            return "open ends" if not self.closed else "no problem"
        more = len(self.problems) - 1
        return self.problems[0] + (f"; and {more} more problem{'s' * (more > 1)} "
                                   "(-v lists them)" if more else "")


# --------------------------------------------------------------------------- loops and overlap
def _as_sections(rings) -> list[list[np.ndarray]]:
    if not isinstance(rings, Sequence) or isinstance(rings, np.ndarray) and rings.ndim == 2:
        raise ValueError("rings must be a list of (n, 3) arrays (or of lists of them), "
                         f"got {type(rings).__name__}")
    sections = []
    for s, item in enumerate(rings):
        loops = [item] if isinstance(item, np.ndarray) and item.ndim == 2 else list(item)
        if not loops:
            raise ValueError(f"rings[{s}] has no loop")
        checked = []
        for lp, loop in enumerate(loops):
            arr = check_shape(loop, "(n, 3)", f"rings[{s}][{lp}]", dtype=np.float64)
            check_finite(arr, f"rings[{s}][{lp}]")
            if len(arr) < 3:
                raise ValueError(f"rings[{s}][{lp}] has {len(arr)} points; "
                                 "a closed ring needs >= 3")
            checked.append(arr)
        sections.append(checked)
    return sections


# --------------------------------------------------------------------------- the public entry
@one_blas_thread
def stitch_rings(rings, axis, close_ends: bool = True, flip: bool = True,
                 constrain_contours: bool = True,
                 max_normal_change: float = MAX_NORMAL_CHANGE,
                 support_sigma: float | None = None,
                 cap_points: np.ndarray | None = None,
                 diagnostics: bool = True) -> StitchResult:
    """Stitch closed section rings into an oriented triangle mesh.

    Parameters
    ----------
    rings : list of (n_k, 3) float64, or list of lists of them
        One closed ring per section (or several loops per section), sections
        ordered along the axis (either direction); points in scene units,
        each ring's points in order around it (either winding; point 0 is the
        ring's start, e.g. θ = 0 from ``catmull_rom.predict_sections``).
    axis : (3,) float64
        Direction of the section normals (need not be unit length).
    close_ends : bool or (2,) of bool
        Cap the first and last sections' loops (a pair: the first's, the last's; an end
        left open is a border, e.g. a hole in the data, :func:`uncovered_share`).
    flip : bool
        Apply Lawson flips (inside each strip and each cap).
    constrain_contours : bool
        Keep every section contour edge (the chords of the section curves)
        fixed, so each strip is flipped on its own and the mesh passes
        through the section polygons.  With False only the capped end
        contours are fixed and flips may cross interior sections (the
        unconstrained Delaunay criterion on the whole side surface).
    max_normal_change : float
        Fold-over limit for a flip, radians (see :func:`delaunay_flips`).
    support_sigma : float, optional
        Noise σ̂ of the points the rings were fitted to (scene units).  Given,
        support (holding) rings are added where the section profile turns
        sharply (:func:`support_distance`): at a capped end one ring on the wall
        and one inside the cap, at an inner ring one on each side, at
        ``d = 3σ̂/sin(α/2)`` from the ring, so that a G1 surface over the mesh
        (Loop's, ``surface.bezier``) rounds the edge by about σ̂ instead of a
        third of the ring spacing.  They lie on the stitched polyhedron (on
        the strip's legs and in the cap plane), so the mesh's shape is kept.
        Given, a flat end cap is also built as nested rings for the G1 surface:
        inside the cap's support ring :data:`CAP_GUARD_RINGS` more at ``d`` steps
        (without a support, rings one wall leg apart from the rim), then a
        quality triangulation, so the patches inside are exactly planar.
        None: no support rings, ear-clipped caps (the paper's mesh).
    cap_points : (C, 3) float64, optional
        Points of the surfaces facing along the axis (``reconstruct.slice_cloud``'s
        cap cloud).  A loop that appears or vanishes between two sections (a
        mug's floor under its inner wall, a branch's end) is capped at the median
        height of the cap points inside it between its section and the next
        (at least ``CAP_MIN_POINTS`` of them), its wall carried on straight to
        that height; without them, or too few, the cap lies in the loop's plane.
    diagnostics : bool
        Measure ``delaunay_fraction`` (False: NaN, for the sizing's candidate meshes,
        which only need the mesh).

    Returns
    -------
    StitchResult

    Raises
    ------
    ValueError
        Fewer than two sections, a ring with fewer than 3 points, NaN/inf, a
        zero axis, or sections not ordered along the axis.

    Notes
    -----
    Adjacent sections with one loop each are always stitched.  With several
    loops, loops are paired by overlap of their projections on the section
    plane; a loop overlapping exactly one loop of the next section (and that
    one only it) is stitched, every other loop (splits, merges, loops that
    appear or vanish) is left open on that side and reported in ``messages``.
    """
    frame, sections, heights, close_ends = _ordered_sections(rings, axis, close_ends)
    cap_inset: dict = {}
    messages: list[str] = []
    notes: list[str] = []
    base_heights = heights.copy()     # the sections' own planes (support rings come between)
    spacing = float(np.median(np.abs(np.diff(base_heights))))

    def dome_window(height: float, up: bool, inner: bool) -> tuple[float, float]:
        if not inner:
            return end_window(height, up, spacing)
        beyond = base_heights[base_heights > height + TOL.zero] if up else \
            base_heights[base_heights < height - TOL.zero]
        limit = (beyond.min() if up else beyond.max()) if len(beyond) else \
            height + (spacing if up else -spacing)
        return (height, float(limit)) if up else (float(limit), height)

    def dome_area(ring2d: np.ndarray) -> float:
        # A quarter of the strips' triangles (half their edges): Loop's patches round a
        # quality triangulation's irregular vertices follow a curved dome less closely
        # than the strips' regular ones (noise-free 10⁵-point capsule, a step-6 / n = 29
        # thinning: the domes' mean error 0.00057 / 0.00032 at the strips' size, 0.00014 /
        # 0.00006 at a quarter, the walls' 0.0002-0.0005; +33 % patches).
        edge = float(np.mean(np.linalg.norm(np.roll(ring2d, -1, axis=0) - ring2d, axis=1)))
        return 0.125 * edge * spacing
    problems: list[str] = []

    def problem(text: str) -> None:  # a reason the surface is not one closed manifold
        messages.append(text)
        problems.append(text)
    if support_sigma is not None:
        if not (np.isfinite(support_sigma) and support_sigma >= 0):
            raise ValueError(f"support_sigma must be a finite number >= 0, got {support_sigma!r}")
        sections, cap_inset, notes = _support(sections, frame, float(support_sigma), close_ends)

    vertices, sec_of, loop_of, params, offsets, planar = _ring_vertices(sections, frame)
    count = len(vertices)
    faces, region, fixed, open_ifaces = [], [], [], []

    indices = [[offsets[s][lp] + np.arange(len(flat)) for lp, flat in enumerate(loops)]
               for s, loops in enumerate(planar)]
    heights_all = np.array([np.mean(np.concatenate([lp @ frame[2] for lp in loops]))
                            for loops in sections])
    graph = loop_graph(planar, spacing=float(np.median(np.diff(heights_all))))
    dropped = set(graph.spurious)
    for s, i in sorted(dropped):
        notes.append(f"section {s} loop {i}: dropped (a loop related to no loop of either "
                     "neighbour section: thinner than the section spacing, noise or a "
                     "flat body of no volume)")
    cap_requests: dict[tuple[int, bool], list[int]] = {}
    extra_vertices: list[np.ndarray] = []
    flip_label: list[int] = []

    def vertex_of(idx: np.ndarray) -> np.ndarray:  # bridge points are not in vertices yet
        if not extra_vertices or idx.max() < len(vertices):
            return vertices[idx]
        return np.vstack([vertices] + extra_vertices)[idx]

    def planar_of(idx: np.ndarray) -> np.ndarray:
        return vertex_of(idx) @ frame[:2].T

    def add_faces(tri: np.ndarray, label: int, flip_as: int | None = None) -> None:
        faces.append(tri)
        region.append(np.full(len(tri), label))
        flip_label.append(label if flip_as is None else flip_as)

    for event in graph.events:
        s = event.section
        if event.kind in ("appear", "vanish"):
            where, up = (s + 1, False) if event.kind == "appear" else (s, True)
            loop = event.upper[0] if event.kind == "appear" else event.lower[0]
            cap_requests.setdefault((where, up), []).append(loop)
            continue
        if event.kind == "complex":
            open_ifaces.append(s)
            problem(
                f"sections {s} and {s + 1}: loops {list(event.lower)} and {list(event.upper)} "
                "correspond many-to-many; the surface is left open there")
            continue
        if event.kind == "one-to-one":
            pieces = [(indices[s][event.lower[0]], params[s][event.lower[0]],
                       indices[s + 1][event.upper[0]], params[s + 1][event.upper[0]])]
        else:
            single_s, single = (s, event.lower[0]) if event.kind == "split" else (
                s + 1, event.upper[0])
            many_s = s + 1 if event.kind == "split" else s
            many = event.upper if event.kind == "split" else event.lower
            base = count + sum(len(x) for x in extra_vertices)
            try:
                subs, new_flat, bridge, dip = _bridge_split(
                    indices[single_s][single], planar[single_s][single],
                    [planar[many_s][k] for k in many], base)
            except ValueError as exc:
                open_ifaces.append(s)
                problem(f"sections {s} and {s + 1}: the {event.kind} of loops "
                                f"{list(event.lower)} into {list(event.upper)} could not be "
                                f"tiled ({exc}); the surface is left open there")
                continue
            height = float(np.mean(vertices[indices[single_s][single]] @ frame[2]))
            other = float(np.mean(np.concatenate([vertices[indices[many_s][k]] @ frame[2]
                                                  for k in many])))
            if len(new_flat):
                lift = _bridge_heights(new_flat, height + 0.5 * (other - height) * dip,
                                       height, other, cap_points, frame)
                extra_vertices.append(new_flat @ frame[:2] + lift[:, None] * frame[2])
                sec_of.append(np.full(len(new_flat), single_s))
                loop_of.append(np.full(len(new_flat), single))
            all_flat = np.vstack([vertices @ frame[:2].T] + [x @ frame[:2].T
                                                              for x in extra_vertices])
            fixed.extend(bridge)
            pieces = []
            for k, sub in zip(many, subs, strict=True):
                sub_param = _ring_order_and_parameter(all_flat[sub])[1]
                mine = (indices[many_s][k], params[many_s][k])
                pieces.append((sub, sub_param, *mine) if event.kind == "split"
                              else (*mine, sub, sub_param))
            notes.append(f"sections {s} and {s + 1}: {event.kind} of loop(s) "
                         f"{list(event.lower)} into {list(event.upper)}, tiled with "
                         f"{len(bridge)} bridge edge(s)")
        for low_idx, low_param, up_idx, _up_param in pieces:
            if event.kind == "one-to-one" and (
                    about := _common_angles(planar_of(low_idx), planar_of(up_idx))):
                local = zip_rings(*about)   # one angle for the strip (one centre)
            elif event.kind != "one-to-one" and (
                    about := _nested_angles(planar_of(low_idx), planar_of(up_idx))):
                local = zip_rings(*about)   # a branch inside its sub-loop, seen from it
            else:  # a bump on a wall, a branch's sub-loop: no common angle (tile_min_span)
                local = tile_min_span(vertex_of(low_idx), vertex_of(up_idx), frame[2])
            n_a = len(low_param)
            glob = np.where(local < n_a, low_idx[np.minimum(local, n_a - 1)],
                            up_idx[np.maximum(local - n_a, 0)])
            if event.depth % 2:
                glob = glob[:, ::-1]        # a hole: outward is towards its centre
            add_faces(glob, 2 * s)
    for s, loops in enumerate(planar):
        if not constrain_contours and 0 < s < len(planar) - 1:
            continue
        for lp, flat in enumerate(loops):
            n = len(flat)
            idx = offsets[s][lp] + np.arange(n)
            fixed.append(np.stack([idx, np.roll(idx, -1)], axis=1))
    ring_vertices = count     # the sections' own points; bridge points follow
    if extra_vertices:
        vertices = np.vstack([vertices] + extra_vertices)
        count = len(vertices)

    def ringed_cap(s, lp, end, up, face_up, label, d, support) -> bool:
        """An end cap as nested rings (rim -> inset rings -> quality triangulation inside):
        the support ring at ``d`` (when given) and :data:`CAP_GUARD_RINGS` more, each a
        further ``d`` in; without ``d`` (no support) they are one wall leg apart (the
        distance from the rim to the next ring), so the cap's first strips are as wide as
        the wall's.  Adds the vertices and faces and returns True, or False (nothing
        added) when the rings do not fit inside the contour or the inner contour is not
        simple (a message says so for a support ring)."""
        nonlocal vertices
        start, rim = offsets[s][lp], planar[s][lp]
        ring = vertices[start:start + len(rim)]
        rings_in = [ring]
        if d is None:
            other = sections[1] if end == 0 else sections[-2]
            d = float(np.median(np.linalg.norm(
                _read_at(ring, _nearest_loop(ring, other, frame)) - ring, axis=1)))
            reach = float(np.min(np.linalg.norm(rim - rim.mean(axis=0), axis=1)))
            if not (d > 0 and (CAP_GUARD_RINGS + 1) * d < 0.5 * reach):
                return False
        for _ in range(CAP_GUARD_RINGS + 1):
            rings_in.append(_inset_ring(rings_in[-1], d))
            # moved towards the centroid, the two sides of a waist narrower than 2d
            # (a contour like a peanut's) cross: such rings would fold the cap
            outer_flat, inset_flat = rings_in[-2] @ frame[:2].T, rings_in[-1] @ frame[:2].T
            if self_intersects(inset_flat) or not _inside(inset_flat, outer_flat).all():
                if support:
                    messages.append(f"cap of section {s} loop {lp}: no support ring inside "
                                    "the cap (the inset contour would cross itself or "
                                    "the rim)")
                return False
        inner_flat = rings_in[-1] @ frame[:2].T
        height = float(np.mean(rings_in[-1] @ frame[2]))
        dome = _dome(inner_flat, *dome_window(height, up, None), cap_points, frame,
                     field_ring=rim, rim=(height, up)) if support else None
        try:
            added, cap = _quality_cap(inner_flat, outward_up=face_up,
                                      max_area=dome_area(inner_flat) if dome else None)
        except ValueError as exc:  # the inset contour is not simple
            if support:
                messages.append(f"cap of section {s} loop {lp}: no support ring inside "
                                f"the cap ({exc})")
            return False
        if dome is not None:
            # A rounded end: the inset rings lie on the dome too (flat at the rim's
            # height they cut under it, by the dome's sag over the inset); its height
            # field takes every point over the rim, not only the innermost ring's.
            for k in range(1, len(rings_in)):
                flat_k = rings_in[k] @ frame[:2].T
                rings_in[k] = flat_k @ frame[:2] + dome(flat_k)[:, None] * frame[2]
        ring_starts = [start]
        for inner in rings_in[1:]:
            inner_start = len(vertices)
            vertices = np.vstack([vertices, inner])
            sec_of.append(np.full(len(inner), s))
            loop_of.append(np.full(len(inner), lp))
            outer_param = _ring_order_and_parameter(
                vertices[ring_starts[-1]:ring_starts[-1] + len(inner)] @ frame[:2].T)[1]
            inner_param = _ring_order_and_parameter(inner @ frame[:2].T)[1]
            lower, upper = ((inner_param, outer_param) if end == 0
                            else (outer_param, inner_param))
            local = zip_rings(lower, upper)
            lo_start, up_start = ((inner_start, ring_starts[-1]) if end == 0
                                  else (ring_starts[-1], inner_start))
            add_faces(np.where(local < len(lower), local + lo_start,
                               local - len(lower) + up_start), label)
            idx = inner_start + np.arange(len(inner))
            fixed.append(np.stack([idx, np.roll(idx, -1)], axis=1))
            ring_starts.append(inner_start)
        added_start = len(vertices)
        lift = dome(added) if dome and len(added) else np.full(len(added), height)
        vertices = np.vstack([vertices, added @ frame[:2] + lift[:, None] * frame[2]])
        sec_of.append(np.full(len(added), s))
        loop_of.append(np.full(len(added), lp))
        add_faces(np.where(cap < len(inner_flat), cap + ring_starts[-1],
                           cap - len(inner_flat) + added_start), label)
        return True

    last = len(sections) - 1
    other_caps = 0

    def facing_half(s: int, lp: int, up: bool) -> float | None:
        """The height halfway to the next section when a cap over loop ``lp`` of ``s``
        faces one across that slab (a loop vanishing under it, ``up``, and one appearing
        over it, or the reverse) and their contours overlap; None otherwise."""
        t = s + 1 if up else s - 1
        mine = planar[s][lp]
        for k in cap_requests.get((t, not up), []):
            other = planar[t][k]
            if _inside(mine, other).any() or _inside(other, mine).any():
                return 0.5 * float(heights_all[s] + heights_all[t])
        return None
    for (s, up), loops_here in sorted(cap_requests.items()):
        end = 0 if (s == 0 and not up) else (-1 if (s == last and up) else None)
        if end is not None and not _closes(close_ends, end):
            continue
        requested = set(loops_here)
        parents = graph.parent[s]
        for lp in sorted(requested):
            if parents[lp] in requested:
                continue  # a hole of a cap: triangulated with it
            holes = [k for k in sorted(requested) if parents[k] == lp]
            face_up = up != bool(graph.depth[s][lp] % 2)
            label = -1 if end == 0 else (-2 if end == -1 else -3)
            flip_as = label if end is not None else -10 - other_caps
            other_caps += end is None
            flat = planar[s][lp]
            if end is not None and not holes and (end, lp) in cap_inset:
                if ringed_cap(s, lp, end, up, face_up, label, cap_inset[(end, lp)], True):
                    continue
            dome = None if holes else _dome(flat, *dome_window(float(heights_all[s]), up,
                                                                end is None), cap_points, frame,
                                            rim=(float(heights_all[s]), up),
                                            reach=facing_half(s, lp, up) if end is None
                                            else None)
            if dome is not None:
                try:
                    added, cap = _quality_cap(flat, outward_up=face_up, max_area=dome_area(flat))
                except ValueError:   # the contour is not simple: the flat cap below
                    pass
                else:
                    new_idx = len(vertices) + np.arange(len(added))
                    vertices = np.vstack([vertices, added @ frame[:2] + dome(added)[:, None]
                                          * frame[2]] if len(added) else [vertices])
                    sec_of.append(np.full(len(added), s))
                    loop_of.append(np.full(len(added), lp))
                    add_faces(np.concatenate([indices[s][lp], new_idx])[cap], label, flip_as)
                    notes.append(f"cap of section {s} loop {lp}: a dome of {len(added)} points "
                                 "on the cap points' height field")
                    continue
            if (end is not None and not holes and dome is None and support_sigma is not None
                    and ringed_cap(s, lp, end, up, face_up, label, None, False)):
                continue
            rings_here = [indices[s][lp]] + [indices[s][k] for k in holes]
            step = (_cap_step(planar[s][lp], [planar[s][k] for k in holes],
                              float(heights_all[s]), up, cap_points, frame, base_heights)
                    if end is None and cap_points is not None else 0.0)
            if step != 0.0:  # carry the walls on to the cap height, cap there
                moved = []
                for k, ring_idx in zip([lp] + holes, rings_here, strict=True):
                    new_idx = len(vertices) + np.arange(len(ring_idx))
                    vertices = np.vstack([vertices, vertices[ring_idx] + step * frame[2]])
                    sec_of.append(np.full(len(ring_idx), s))
                    loop_of.append(np.full(len(ring_idx), k))
                    lower, upper = (ring_idx, new_idx) if step > 0 else (new_idx, ring_idx)
                    local = zip_rings(params[s][k], params[s][k])
                    n_k = len(ring_idx)
                    glob = np.where(local < n_k, lower[np.minimum(local, n_k - 1)],
                                    upper[np.maximum(local - n_k, 0)])
                    add_faces(glob[:, ::-1] if graph.depth[s][k] % 2 else glob, -3,
                              -10 - other_caps)
                    fixed.append(np.stack([new_idx, np.roll(new_idx, -1)], axis=1))
                    moved.append(new_idx)
                other_caps += 1
                rings_here = moved
                notes.append(f"cap of section {s} loop {lp} moved {step:.4g} along the axis to "
                             "the median height of the cap points inside it")
            cap = cap_triangles(flat, outward_up=face_up,
                                holes=[planar[s][k] for k in holes])
            expected = sum(len(r) for r in rings_here) - 2 + 2 * len(holes)
            if len(cap) != expected:
                problem(f"cap of section {s} loop {lp}: {len(cap)} triangles for "
                                f"{expected} expected (contour not simple); cap incomplete")
            add_faces(np.concatenate(rings_here)[cap], label, flip_as)

    return _finished(vertices, faces, region, flip_label, fixed, sec_of, loop_of,
                     bridge_points=(ring_vertices, sum(len(x) for x in extra_vertices)),
                     frame=frame, flip=flip, constrain_contours=constrain_contours,
                     max_normal_change=max_normal_change, diagnostics=diagnostics,
                     messages=messages, problems=problems, notes=notes,
                     open_ifaces=open_ifaces, graph=graph)


def _ordered_sections(rings, axis, close_ends) -> tuple:
    """:func:`stitch_rings`'s first step: ``(frame, sections, heights, close_ends)``, the
    rings as sections of loops ordered up the axis (reversed, with ``close_ends``, when
    given down it); ``ValueError`` when fewer than two or not monotone."""
    frame = axis_frame(axis)
    sections = _as_sections(rings)
    if len(sections) < 2:
        raise ValueError(f"rings must hold at least 2 sections, got {len(sections)}")
    heights = np.array([np.mean(np.concatenate([lp @ frame[2] for lp in loops]))
                        for loops in sections])
    steps = np.diff(heights)
    if np.all(steps < 0):
        sections, heights = sections[::-1], heights[::-1]
        if np.ndim(close_ends):
            close_ends = tuple(close_ends)[::-1]
    elif not np.all(steps > 0):
        raise ValueError("rings must be ordered along the axis (heights strictly monotone), "
                         f"got heights {np.round(heights, 6).tolist()}")
    return frame, sections, heights, close_ends


def _ring_vertices(sections: list, frame: np.ndarray) -> tuple:
    """The mesh's vertices: every loop's points in counter-clockwise order about the axis.
    ``(vertices (V, 3), sec_of, loop_of, params, offsets, planar)``: per loop its
    section and loop labels, angle-like parameters, first vertex, plan coordinates."""
    vertices, sec_of, loop_of, params, offsets, planar = [], [], [], [], [], []
    count = 0
    for s, loops in enumerate(sections):
        offsets.append([])
        params.append([])
        planar.append([])
        for lp, pts in enumerate(loops):
            flat = pts @ frame[:2].T                                # (n, 2)
            order, param = _ring_order_and_parameter(flat)
            vertices.append(pts[order])
            planar[s].append(flat[order])
            params[s].append(param)
            offsets[s].append(count)
            sec_of.append(np.full(len(pts), s))
            loop_of.append(np.full(len(pts), lp))
            count += len(pts)
    return np.vstack(vertices), sec_of, loop_of, params, offsets, planar


def _finished(vertices, faces, region, flip_label, fixed, sec_of, loop_of, *, bridge_points,
              frame, flip, constrain_contours, max_normal_change, diagnostics, messages,
              problems, notes, open_ifaces, graph) -> StitchResult:
    """:func:`stitch_rings`'s last step: the faces joined, Lawson flips within their
    regions (``bridge_points``: the first bridge point and their count, in no section's
    plane), the topology checked (a problem each), unused vertices dropped."""

    def problem(text: str) -> None:
        messages.append(text)
        problems.append(text)
    ring_vertices, bridge_count = bridge_points
    triangles = np.vstack(faces).astype(np.int64) if faces else np.zeros((0, 3), np.int64)
    region = np.concatenate(region).astype(np.int64) if region else np.zeros(0, np.int64)
    fixed = np.vstack(fixed)
    flips = 0
    flip_region = (np.concatenate([np.full(len(f), lab) for f, lab in zip(faces, flip_label,
                                                                        strict=True)])
                   if faces else region)
    if not constrain_contours:
        flip_region = np.where(flip_region >= 0, 0, flip_region)
    if flip and len(triangles):
        plane = np.concatenate(sec_of).astype(np.int64)
        plane[ring_vertices:ring_vertices + bridge_count] = -1
        triangles, flips, converged = delaunay_flips(vertices, triangles, flip_region, fixed,
                                                     max_normal_change=max_normal_change,
                                                     plane=plane, axis=frame[2])
        if not converged:
            messages.append(f"Lawson flips stopped after the sweep limit ({flips} flips)")
    topo = mesh_topology(vertices, triangles)
    if topo["nonmanifold_edges"]:
        problem(f"{topo['nonmanifold_edges']} non-manifold edges")
    if not topo["oriented"]:
        problem("faces are not consistently oriented")
    mask = _flippable_edges(triangles, flip_region, fixed, len(vertices)) if diagnostics \
        else None
    sec_of = np.concatenate(sec_of).astype(np.int64)
    loop_of = np.concatenate(loop_of).astype(np.int64)
    used = np.zeros(len(vertices), bool)
    used[triangles.ravel()] = True
    if not used.all():  # a loop dropped as noise: its points are in no face
        renumber = np.cumsum(used) - 1
        vertices, sec_of, loop_of = vertices[used], sec_of[used], loop_of[used]
        triangles = renumber[triangles]
    return StitchResult(
        vertices=vertices,
        triangles=triangles,
        closed=bool(topo["closed"]),
        messages=tuple(messages),
        region=region,
        section_of_vertex=sec_of,
        loop_of_vertex=loop_of,
        open_interfaces=tuple(open_ifaces),
        flips=int(flips),
        delaunay_fraction=delaunay_fraction(vertices, triangles, edge_mask=mask)
        if diagnostics else float("nan"),
        notes=tuple(notes),
        graph=graph,
        problems=tuple(problems),
    )
