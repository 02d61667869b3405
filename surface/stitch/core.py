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

    The loops of adjacent sections are related by overlap in the section plane
    (``surface.loop_graph``): a loop with one partner is stitched to it, a split or a
    merge is bridged, a loop appearing or vanishing is capped, many-to-many is left
    open (a problem says so).  The rules: ``docs/method/stitching.md``.

    Parameters
    ----------
    rings : list of (n_k, 3) float64, or list of lists of them
        One closed ring per section (or several loops per section), sections
        ordered along the axis (either direction); points in scene units,
        each ring's points in order around it (either winding).
    axis : (3,) float64
        Direction of the section normals (need not be unit length).
    close_ends : bool or (2,) of bool
        Cap the first and last sections' loops (a pair: the first's, the last's; an end
        left open is a border, e.g. a hole in the data, :func:`uncovered_share`).
    flip : bool
        Apply Lawson flips (inside each strip and each cap).
    constrain_contours : bool
        Keep every section contour edge fixed, so each strip is flipped on its own
        and the mesh passes through the section polygons (False: only the capped end
        contours, flips may cross interior sections).
    max_normal_change : float
        Fold-over limit for a flip, radians (see :func:`delaunay_flips`).
    support_sigma : float, optional
        Noise σ̂ of the points the rings were fitted to (scene units).  Given, support
        rings are added where the section profile turns sharply, at
        ``d = 3σ̂/sin(α/2)`` from the ring (:func:`support_distance`), and a flat end
        cap is built as nested rings and a quality triangulation; None: no support
        rings, ear-clipped caps (the paper's mesh).
    cap_points : (C, 3) float64, optional
        Points of the surfaces facing along the axis (``reconstruct.slice_cloud``'s cap
        cloud): a loop that appears or vanishes is capped at the median height of the
        cap points inside it (at least ``CAP_MIN_POINTS``), or on their dome; without
        them the cap lies in the loop's plane.
    diagnostics : bool
        Measure ``delaunay_fraction`` (False: NaN, for the sizing's candidate meshes).

    Returns
    -------
    StitchResult

    Raises
    ------
    ValueError
        Fewer than two sections, a ring with fewer than 3 points, NaN/inf, a
        zero axis, or sections not ordered along the axis.
    """
    build = _started(rings, axis, close_ends, support_sigma, cap_points)
    for event in build.graph.events:
        _tile_event(build, event)
    for s, loops in enumerate(build.planar):
        if not constrain_contours and 0 < s < len(build.planar) - 1:
            continue
        for lp, flat in enumerate(loops):
            idx = build.offsets[s][lp] + np.arange(len(flat))
            build.fixed.append(np.stack([idx, np.roll(idx, -1)], axis=1))
    ring_vertices = len(build.vertices)     # the sections' own points; bridge points follow
    if build.extra_vertices:
        build.vertices = np.vstack([build.vertices] + build.extra_vertices)
    for (s, up), loops_here in sorted(build.cap_requests.items()):
        _caps_at(build, s, up, loops_here)
    return _finished(build, ring_vertices, flip=flip, constrain_contours=constrain_contours,
                     max_normal_change=max_normal_change, diagnostics=diagnostics)


# --------------------------------------------------------------------------- the mesh being built
@dataclass
class _Build:
    """What :func:`stitch_rings`' steps share: the sections in the axis frame, the loop
    graph, the mesh built so far and the lines said about it."""

    frame: np.ndarray             # (3, 3): e1, e2, axis
    sections: list                # per section its loops, (n, 3), supports included
    planar: list                  # the loops in the plan, counter-clockwise
    params: list                  # the loops' angle-like parameters
    offsets: list                 # each loop's first vertex
    indices: list                 # each loop's vertices
    base_heights: np.ndarray      # the sections' own planes (support rings come between)
    heights: np.ndarray           # every section's mean height, supports included
    spacing: float                # median distance of the sections' own planes
    graph: LoopGraph
    vertices: np.ndarray          # the ring points, then (after the strips) everything
    sec_of: list                  # per block of vertices its section ...
    loop_of: list                 # ... and loop
    cap_inset: dict               # (end, loop) -> the cap's support distance
    support: bool                 # support rings asked for
    cap_points: np.ndarray | None
    close_ends: object
    notes: list
    messages: list = field(default_factory=list)
    problems: list = field(default_factory=list)
    faces: list = field(default_factory=list)
    region: list = field(default_factory=list)
    flip_label: list = field(default_factory=list)
    fixed: list = field(default_factory=list)            # edges no flip may remove
    open_ifaces: list = field(default_factory=list)
    extra_vertices: list = field(default_factory=list)   # bridge points, until the caps
    cap_requests: dict = field(default_factory=dict)     # (section, up) -> loops
    other_caps: int = 0

    def problem(self, text: str) -> None:   # a reason the surface is not one closed manifold
        self.messages.append(text)
        self.problems.append(text)

    def add_faces(self, tri: np.ndarray, label: int, flip_as: int | None = None) -> None:
        self.faces.append(tri)
        self.region.append(np.full(len(tri), label))
        self.flip_label.append(label if flip_as is None else flip_as)

    def add_vertices(self, points: np.ndarray, s: int, lp: int) -> None:
        self.vertices = np.vstack([self.vertices, points])
        self.sec_of.append(np.full(len(points), s))
        self.loop_of.append(np.full(len(points), lp))

    def vertex_of(self, idx: np.ndarray) -> np.ndarray:  # bridge points not in vertices yet
        if not self.extra_vertices or idx.max() < len(self.vertices):
            return self.vertices[idx]
        return np.vstack([self.vertices] + self.extra_vertices)[idx]

    def planar_of(self, idx: np.ndarray) -> np.ndarray:
        return self.vertex_of(idx) @ self.frame[:2].T

    def dome_window(self, height: float, up: bool, inner: bool) -> tuple[float, float]:
        if not inner:
            return end_window(height, up, self.spacing)
        beyond = self.base_heights[self.base_heights > height + TOL.zero] if up else \
            self.base_heights[self.base_heights < height - TOL.zero]
        limit = (beyond.min() if up else beyond.max()) if len(beyond) else \
            height + (self.spacing if up else -self.spacing)
        return (height, float(limit)) if up else (float(limit), height)

    def dome_area(self, ring2d: np.ndarray) -> float:
        # A quarter of the strips' triangles (half their edges): Loop's patches round a
        # quality triangulation's irregular vertices follow a curved dome less closely
        # than the strips' regular ones (noise-free 10⁵-point capsule, a step-6 / n = 29
        # thinning: the domes' mean error 0.00057 / 0.00032 at the strips' size, 0.00014 /
        # 0.00006 at a quarter, the walls' 0.0002-0.0005; +33 % patches).
        edge = float(np.mean(np.linalg.norm(np.roll(ring2d, -1, axis=0) - ring2d, axis=1)))
        return 0.125 * edge * self.spacing


def _started(rings, axis, close_ends, support_sigma, cap_points) -> _Build:
    """The sections ordered up the axis, with their support rings, as vertices, and the
    loop graph between them (a note for each loop dropped as spurious)."""
    frame, sections, heights, close_ends = _ordered_sections(rings, axis, close_ends)
    base_heights = heights.copy()
    spacing = float(np.median(np.abs(np.diff(base_heights))))
    cap_inset: dict = {}
    notes: list[str] = []
    if support_sigma is not None:
        if not (np.isfinite(support_sigma) and support_sigma >= 0):
            raise ValueError(f"support_sigma must be a finite number >= 0, got {support_sigma!r}")
        sections, cap_inset, notes = _support(sections, frame, float(support_sigma), close_ends)
    vertices, sec_of, loop_of, params, offsets, planar = _ring_vertices(sections, frame)
    indices = [[offsets[s][lp] + np.arange(len(flat)) for lp, flat in enumerate(loops)]
               for s, loops in enumerate(planar)]
    heights_all = np.array([np.mean(np.concatenate([lp @ frame[2] for lp in loops]))
                            for loops in sections])
    graph = loop_graph(planar, spacing=float(np.median(np.diff(heights_all))))
    for s, i in sorted(set(graph.spurious)):
        notes.append(f"section {s} loop {i}: dropped (a loop related to no loop of either "
                     "neighbour section: thinner than the section spacing, noise or a "
                     "flat body of no volume)")
    return _Build(frame=frame, sections=sections, planar=planar, params=params,
                  offsets=offsets, indices=indices, base_heights=base_heights,
                  heights=heights_all, spacing=spacing, graph=graph, vertices=vertices,
                  sec_of=sec_of, loop_of=loop_of, cap_inset=cap_inset,
                  support=support_sigma is not None, cap_points=cap_points,
                  close_ends=close_ends, notes=notes)


# --------------------------------------------------------------------------- strips
def _tile_event(build: _Build, event) -> None:
    """One event of the loop graph between sections ``s`` and ``s + 1``: a loop appearing
    or vanishing asks for a cap, one-to-one gets its strip, a split or merge its bridged
    strips, many-to-many stays open (a problem says so)."""
    s = event.section
    if event.kind in ("appear", "vanish"):
        where, up = (s + 1, False) if event.kind == "appear" else (s, True)
        loop = event.upper[0] if event.kind == "appear" else event.lower[0]
        build.cap_requests.setdefault((where, up), []).append(loop)
        return
    if event.kind == "complex":
        build.open_ifaces.append(s)
        build.problem(
            f"sections {s} and {s + 1}: loops {list(event.lower)} and {list(event.upper)} "
            "correspond many-to-many; the surface is left open there")
        return
    if event.kind == "one-to-one":
        pieces = [(build.indices[s][event.lower[0]], build.indices[s + 1][event.upper[0]])]
    elif (pieces := _bridged_pieces(build, event)) is None:
        return
    for low_idx, up_idx in pieces:
        if event.kind == "one-to-one" and (
                about := _common_angles(build.planar_of(low_idx), build.planar_of(up_idx))):
            local = zip_rings(*about)   # one angle for the strip (one centre)
        elif event.kind != "one-to-one" and (
                about := _nested_angles(build.planar_of(low_idx), build.planar_of(up_idx))):
            local = zip_rings(*about)   # a branch inside its sub-loop, seen from it
        else:  # a bump on a wall, a branch's sub-loop: no common angle (tile_min_span)
            local = tile_min_span(build.vertex_of(low_idx), build.vertex_of(up_idx),
                                  build.frame[2])
        n_a = len(low_idx)
        glob = np.where(local < n_a, low_idx[np.minimum(local, n_a - 1)],
                        up_idx[np.maximum(local - n_a, 0)])
        if event.depth % 2:
            glob = glob[:, ::-1]        # a hole: outward is towards its centre
        build.add_faces(glob, 2 * s)


def _bridged_pieces(build: _Build, event) -> list | None:
    """A split or merge: the single loop cut by bridges into one sub-loop per loop of the
    other section (``_bridge_split``; the bridge points lifted between the sections).
    Returns the ``(lower, upper)`` vertex indices of each strip, or None (left open, a
    problem says why)."""
    s = event.section
    single_s, single = (s, event.lower[0]) if event.kind == "split" else (
        s + 1, event.upper[0])
    many_s = s + 1 if event.kind == "split" else s
    many = event.upper if event.kind == "split" else event.lower
    base = len(build.vertices) + sum(len(x) for x in build.extra_vertices)
    try:
        subs, new_flat, bridge, dip = _bridge_split(
            build.indices[single_s][single], build.planar[single_s][single],
            [build.planar[many_s][k] for k in many], base)
    except ValueError as exc:
        build.open_ifaces.append(s)
        build.problem(f"sections {s} and {s + 1}: the {event.kind} of loops "
                      f"{list(event.lower)} into {list(event.upper)} could not be "
                      f"tiled ({exc}); the surface is left open there")
        return None
    frame = build.frame
    height = float(np.mean(build.vertices[build.indices[single_s][single]] @ frame[2]))
    other = float(np.mean(np.concatenate([build.vertices[build.indices[many_s][k]] @ frame[2]
                                          for k in many])))
    if len(new_flat):
        lift = _bridge_heights(new_flat, height + 0.5 * (other - height) * dip,
                               height, other, build.cap_points, frame)
        build.extra_vertices.append(new_flat @ frame[:2] + lift[:, None] * frame[2])
        build.sec_of.append(np.full(len(new_flat), single_s))
        build.loop_of.append(np.full(len(new_flat), single))
    build.fixed.extend(bridge)
    build.notes.append(f"sections {s} and {s + 1}: {event.kind} of loop(s) "
                       f"{list(event.lower)} into {list(event.upper)}, tiled with "
                       f"{len(bridge)} bridge edge(s)")
    return [(sub, build.indices[many_s][k]) if event.kind == "split"
            else (build.indices[many_s][k], sub) for k, sub in zip(many, subs, strict=True)]


# --------------------------------------------------------------------------- caps
def _caps_at(build: _Build, s: int, up: bool, loops_here: list) -> None:
    """The caps asked for over (``up``) or under section ``s``: each loop with the loops
    nested in it as its holes (an end left open by ``close_ends`` gets none)."""
    last = len(build.sections) - 1
    end = 0 if (s == 0 and not up) else (-1 if (s == last and up) else None)
    if end is not None and not _closes(build.close_ends, end):
        return
    requested = set(loops_here)
    parents = build.graph.parent[s]
    for lp in sorted(requested):
        if parents[lp] in requested:
            continue  # a hole of a cap: triangulated with it
        _cap(build, s, lp, up, end, [k for k in sorted(requested) if parents[k] == lp])


def _cap(build: _Build, s: int, lp: int, up: bool, end: int | None, holes: list) -> None:
    """One cap over loop ``lp`` of section ``s``: at an end with a support distance, nested
    rings (:func:`_ringed_cap`); else a dome where the cap points are domed; else nested
    rings one wall leg apart (support rings asked for); else the contour's ear-clipped
    triangulation, moved to the cap points' height inside the body (:func:`_flat_cap`)."""
    face_up = up != bool(build.graph.depth[s][lp] % 2)
    label = -1 if end == 0 else (-2 if end == -1 else -3)
    flip_as = label if end is not None else -10 - build.other_caps
    build.other_caps += end is None
    flat = build.planar[s][lp]
    if end is not None and not holes and (end, lp) in build.cap_inset:
        if _ringed_cap(build, s, lp, end, up, face_up, label, build.cap_inset[(end, lp)], True):
            return
    height = float(build.heights[s])
    dome = None if holes else _dome(flat, *build.dome_window(height, up, end is None),
                                    build.cap_points, build.frame, rim=(height, up),
                                    reach=_facing_half(build, s, lp, up) if end is None
                                    else None)
    if dome is not None:
        try:
            added, cap = _quality_cap(flat, outward_up=face_up, max_area=build.dome_area(flat))
        except ValueError:   # the contour is not simple: the flat cap below
            pass
        else:
            new_idx = len(build.vertices) + np.arange(len(added))
            if len(added):
                build.vertices = np.vstack([build.vertices, added @ build.frame[:2]
                                            + dome(added)[:, None] * build.frame[2]])
            build.sec_of.append(np.full(len(added), s))
            build.loop_of.append(np.full(len(added), lp))
            build.add_faces(np.concatenate([build.indices[s][lp], new_idx])[cap], label,
                            flip_as)
            build.notes.append(f"cap of section {s} loop {lp}: a dome of {len(added)} "
                               "points on the cap points' height field")
            return
    if (end is not None and not holes and dome is None and build.support
            and _ringed_cap(build, s, lp, end, up, face_up, label, None, False)):
        return
    _flat_cap(build, s, lp, up, end, holes, face_up, label, flip_as)


def _flat_cap(build: _Build, s, lp, up, end, holes, face_up, label, flip_as) -> None:
    """The contour's ear-clipped triangulation with its holes; inside the body (not an
    end) with cap points, the walls first carried on to their median height."""
    frame, planar = build.frame, build.planar
    rings_here = [build.indices[s][lp]] + [build.indices[s][k] for k in holes]
    step = (_cap_step(planar[s][lp], [planar[s][k] for k in holes], float(build.heights[s]),
                      up, build.cap_points, frame, build.base_heights)
            if end is None and build.cap_points is not None else 0.0)
    if step != 0.0:  # carry the walls on to the cap height, cap there
        moved = []
        for k, ring_idx in zip([lp] + holes, rings_here, strict=True):
            new_idx = len(build.vertices) + np.arange(len(ring_idx))
            build.add_vertices(build.vertices[ring_idx] + step * frame[2], s, k)
            lower, upper = (ring_idx, new_idx) if step > 0 else (new_idx, ring_idx)
            local = zip_rings(build.params[s][k], build.params[s][k])
            n_k = len(ring_idx)
            glob = np.where(local < n_k, lower[np.minimum(local, n_k - 1)],
                            upper[np.maximum(local - n_k, 0)])
            build.add_faces(glob[:, ::-1] if build.graph.depth[s][k] % 2 else glob, -3,
                            -10 - build.other_caps)
            build.fixed.append(np.stack([new_idx, np.roll(new_idx, -1)], axis=1))
            moved.append(new_idx)
        build.other_caps += 1
        rings_here = moved
        build.notes.append(f"cap of section {s} loop {lp} moved {step:.4g} along the axis to "
                           "the median height of the cap points inside it")
    cap = cap_triangles(planar[s][lp], outward_up=face_up,
                        holes=[planar[s][k] for k in holes])
    expected = sum(len(r) for r in rings_here) - 2 + 2 * len(holes)
    if len(cap) != expected:
        build.problem(f"cap of section {s} loop {lp}: {len(cap)} triangles for "
                      f"{expected} expected (contour not simple); cap incomplete")
    build.add_faces(np.concatenate(rings_here)[cap], label, flip_as)


def _facing_half(build: _Build, s: int, lp: int, up: bool) -> float | None:
    """The height halfway to the next section when a cap over loop ``lp`` of ``s`` faces
    one across that slab (a loop vanishing under it, ``up``, and one appearing over it,
    or the reverse) and their contours overlap; None otherwise."""
    t = s + 1 if up else s - 1
    mine = build.planar[s][lp]
    for k in build.cap_requests.get((t, not up), []):
        other = build.planar[t][k]
        if _inside(mine, other).any() or _inside(other, mine).any():
            return 0.5 * float(build.heights[s] + build.heights[t])
    return None


def _ringed_cap(build: _Build, s, lp, end, up, face_up, label, d, support) -> bool:
    """An end cap as nested rings (rim -> inset rings -> quality triangulation inside):
    the support ring at ``d`` (when given) and :data:`CAP_GUARD_RINGS` more, each a
    further ``d`` in; without ``d`` (no support) they are one wall leg apart (the
    distance from the rim to the next ring), so the cap's first strips are as wide as
    the wall's.  Adds the vertices and faces and returns True, or False (nothing
    added) when the rings do not fit inside the contour or the inner contour is not
    simple (a message says so for a support ring)."""
    frame = build.frame
    start, rim = build.offsets[s][lp], build.planar[s][lp]
    ring = build.vertices[start:start + len(rim)]
    rings_in = [ring]
    if d is None:
        other = build.sections[1] if end == 0 else build.sections[-2]
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
                build.messages.append(f"cap of section {s} loop {lp}: no support ring "
                                      "inside the cap (the inset contour would cross itself "
                                      "or the rim)")
            return False
    inner_flat = rings_in[-1] @ frame[:2].T
    height = float(np.mean(rings_in[-1] @ frame[2]))
    dome = _dome(inner_flat, *build.dome_window(height, up, None), build.cap_points, frame,
                 field_ring=rim, rim=(height, up)) if support else None
    try:
        added, cap = _quality_cap(inner_flat, outward_up=face_up,
                                  max_area=build.dome_area(inner_flat) if dome else None)
    except ValueError as exc:  # the inset contour is not simple
        if support:
            build.messages.append(f"cap of section {s} loop {lp}: no support ring inside "
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
        inner_start = len(build.vertices)
        build.add_vertices(inner, s, lp)
        outer_param = _ring_order_and_parameter(
            build.vertices[ring_starts[-1]:ring_starts[-1] + len(inner)] @ frame[:2].T)[1]
        inner_param = _ring_order_and_parameter(inner @ frame[:2].T)[1]
        lower, upper = ((inner_param, outer_param) if end == 0
                        else (outer_param, inner_param))
        local = zip_rings(lower, upper)
        lo_start, up_start = ((inner_start, ring_starts[-1]) if end == 0
                              else (ring_starts[-1], inner_start))
        build.add_faces(np.where(local < len(lower), local + lo_start,
                                 local - len(lower) + up_start), label)
        idx = inner_start + np.arange(len(inner))
        build.fixed.append(np.stack([idx, np.roll(idx, -1)], axis=1))
        ring_starts.append(inner_start)
    added_start = len(build.vertices)
    lift = dome(added) if dome and len(added) else np.full(len(added), height)
    build.add_vertices(added @ frame[:2] + lift[:, None] * frame[2], s, lp)
    build.add_faces(np.where(cap < len(inner_flat), cap + ring_starts[-1],
                             cap - len(inner_flat) + added_start), label)
    return True


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


def _finished(build: _Build, ring_vertices: int, *, flip, constrain_contours,
              max_normal_change, diagnostics) -> StitchResult:
    """:func:`stitch_rings`'s last step: the faces joined, Lawson flips within their
    regions (the bridge points, from ``ring_vertices`` on, in no section's plane), the
    topology checked (a problem each), unused vertices dropped."""
    vertices, faces, flip_label = build.vertices, build.faces, build.flip_label
    region, fixed, sec_of, loop_of = build.region, build.fixed, build.sec_of, build.loop_of
    frame, messages, problem = build.frame, build.messages, build.problem
    bridge_count = sum(len(x) for x in build.extra_vertices)
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
        open_interfaces=tuple(build.open_ifaces),
        flips=int(flips),
        delaunay_fraction=delaunay_fraction(vertices, triangles, edge_mask=mask)
        if diagnostics else float("nan"),
        notes=tuple(build.notes),
        graph=build.graph,
        problems=tuple(build.problems),
    )
