"""Topological organisation of a planar section: loops, order, outliers (step c).

For the points ``x_j`` of one loop in the section plane (coordinates ``(u, v)``
along the common frame ``e1, e2``) the method takes the centroid and the
cylindrical coordinates about it::

    C = (1/M) Σ_j x_j,    (u_j, v_j) = x_j − C,
    R_j = sqrt(u_j² + v_j²),    θ_j = atan2(v_j, u_j) ∈ [0, 2π)

and numbers the points counter-clockwise (seen from +axis) from θ_min.  The
neighbours of a point are its nearest points (the minimum-distance criterion,
the method's (2,1)).  Where the θ order and the nearest-neighbour order
disagree the loop is not star-shaped about C and the nearest-neighbour chain
wins.

Each part robust and vectorised (the derivations: ``docs/method/sections.md``,
"Loops, outliers, order"):

* **Loops**: the section's Euclidean minimum spanning tree cut at edges longer than
  the link distance ``ℓ = 2·(ln M + 6)·g``, ``g = median(MST edge)/ln 2`` the mean gap
  along a curve; components under ``min_points`` points are outliers.
* **Outliers**: a quadratic fitted to each point's ``k`` nearest neighbours (batched);
  an outlier when ``|r| > max(threshold·σ̂, g/2)``, σ̂ the MAD scale; two passes.
* **Order**: grid-cell centres (``h = max(3 g, 6 σ̂, D/128)``) joined by a closed tour
  improved by 2-opt; θ order where the loop is star-shaped about C, else the arc
  length of each point's foot on the tour (the nearest-neighbour chain).
* **Degenerate sections**: a section thinner than ``TOL.planar_rel`` times its
  diameter across its principal direction encloses no area and is skipped.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, replace

import numba
import numpy as np
from scipy.spatial import Delaunay, QhullError, cKDTree

from surface.sections import Section, SectionSkippedWarning
from surface.validate import TOL, check_finite

__all__ = ["Loop", "SectionSkippedWarning", "organise", "organise_all"]

#: 1.4826 · MAD = σ for Gaussian residuals.
_MAD_TO_SIGMA = 1.4826
#: ln(1/p) for a false split probability p ≈ 0.25 % of a loop by the link distance.
_SPLIT_LOG_ODDS = 6.0
#: Density variation along a loop that the link distance tolerates.
_DENSITY_RATIO = 2.0
#: Longest MST edges tried as bridges between two closed loops.
_SPLIT_TRIES = 2
#: Angular sectors a closed loop must fill about its centroid (bridge test).
_SECTORS = 16
#: Largest bend, in degrees, between a point's nearest-neighbour edge and its
#: half-neighbour edge (prolonged) for a curve to run on through it, and between a
#: loose end's direction and the gap it is joined across (:func:`_curve_graph`).
#: Along a noise-free curve sampled at gap g the bend is ~g/R rad; across a wall
#: from a gap's end it is 45-90°.
_CRUST_BEND = 30.0
#: Longest half-neighbour edge, in mean gaps g, kept whatever its bend (a wall 2 point
#: spacings thick is ~4 g across at a slab 2 spacings thick, 2 g at a half slab).
_BRIDGE_GAPS = 2.0
#: The tracings :func:`_wall_splits` tries, in turn (``_curve_graph``'s chord,
#: neighbours, mutual): lines from neighbours g/2 away among 8 fit noise-free faces
#: (the can's rim parted in 10 of 10 samplings, 7 of 10 with the second alone); with
#: noise (σ ≈ 0.3 g) such short chords tilt, and lines from neighbours a gap away
#: among 12, loose ends joined only as each other's choice, part the σ = 0.002
#: bowl's faces in every section but its last half slab (3 sections left joined
#: with the first alone).
_TRACINGS = ((0.5, 8, False), (1.0, 12, True))
#: Nearest points a loose end may be joined to (:func:`_curve_graph`).
_JOIN_CANDIDATES = 16
#: A piece of a traced cluster holding more than ``1 - _WALL_SHARE`` of its points is
#: taken for a loop by :func:`_wall_splits` (a wall's faces hold ~half each).
_WALL_SHARE = 0.9


@dataclass(frozen=True, eq=False)
class Loop:
    """One closed loop of a section, its points ordered counter-clockwise.

    Attributes
    ----------
    centroid : (3,) float64
        Mean of the loop's points, world coordinates (on the section plane).
    points : (M, 3) float64
        The points ordered counter-clockwise seen from ``+frame[2]``, the
        first at θ_min.
    theta : (M,) float64
        Angle in [0, 2π) of each point about the centroid, measured in the
        section frame (``atan2(e2·(x−C), e1·(x−C))``).
    radius : (M,) float64
        Distance of each point from the centroid, scene units.
    star_shaped : bool
        True when the θ order and the nearest-neighbour order agree; then
        ``theta`` is increasing along ``points``.
    outliers : (k,) int64
        Indices into ``Section.points`` removed from this loop.
    indices : (M,) int64
        Index into ``Section.points`` of each ordered point.
    frame : (3, 3) float64
        The section frame (rows e1, e2, axis), common to all sections.
    height : float
        The section's height along the axis.
    section_id : int
        The section's id.
    closed : bool
        False when the ordered loop has a gap longer than the link distance
        (an open arc, e.g. missing data).
    noise : float
        Robust scale σ̂ of the points about their local curve, scene units.
    bridge : float
        A step between consecutive ordered points longer than this is missing
        data, which the curve bridges by a straight chord
        (``catmull_rom.bridge_gaps``): the link distance ℓ's rule,
        ``2·(ln M + 6)·h``, with the loop's own median step h (a column's loop
        is denser than its section's mean gap says), and at most ℓ; inf when
        unknown.
    """

    centroid: np.ndarray
    points: np.ndarray
    theta: np.ndarray
    radius: np.ndarray
    star_shaped: bool
    outliers: np.ndarray
    indices: np.ndarray
    frame: np.ndarray
    height: float
    section_id: int
    closed: bool = True
    noise: float = 0.0
    bridge: float = math.inf

    def __len__(self) -> int:
        return int(self.points.shape[0])


def organise(
    section: Section,
    *,
    link_distance: float | None = None,
    outlier_threshold: float = 4.0,
    neighbours: int = 12,
    min_points: int = 4,
) -> list[Loop]:
    """Find the loops of a section, reject outliers and order each loop.

    Parameters
    ----------
    section : Section
    link_distance : float, optional
        Points farther apart than this (scene units) along the minimum
        spanning tree belong to different loops.  Default ``2·(ln M + 6)·g``
        (module notes).
    outlier_threshold : float
        Outlier cut in robust standard deviations of the distance from the
        local curve fit (default 4: one false rejection in ~16 000 Gaussian
        points).
    neighbours : int
        Neighbours k of the local quadratic fit (≥ 3).
    min_points : int
        Smallest loop (≥ 4: a closed cubic curve needs 4 control points).

    Returns
    -------
    list of Loop
        Largest loop first.  Empty, with a :class:`SectionSkippedWarning`, when
        the section has fewer than ``min_points`` points.

    Raises
    ------
    ValueError
        NaN/inf points, or bad parameters.
    """
    if min_points < 4:
        raise ValueError(f"min_points must be >= 4, got {min_points}")
    if neighbours < 3:
        raise ValueError(f"neighbours must be >= 3, got {neighbours}")
    if not (np.isfinite(outlier_threshold) and outlier_threshold > 0):
        raise ValueError(f"outlier_threshold must be > 0, got {outlier_threshold!r}")
    if link_distance is not None and not (np.isfinite(link_distance) and link_distance > 0):
        raise ValueError(f"link_distance must be a positive number, got {link_distance!r}")
    pts = np.asarray(section.points, dtype=np.float64)
    check_finite(pts, f"section {section.section_id} points")
    if len(pts) < min_points:
        _skip(section, f"{len(pts)} points (< {min_points})")
        return []
    uv = section.to_plane(pts)
    scale = float(np.ptp(uv, axis=0).max())
    if scale <= TOL.zero:
        _skip(section, "all points coincide")
        return []
    if _is_collinear(uv):
        _skip(section, f"all {len(pts)} points lie on one line (no closed curve: a flat cloud "
                       "cut across its plane)")
        return []
    labels, gap, link, whole = _clusters(uv, link_distance, scale)
    loops_members = _face_members(section, uv, labels, whole, gap, link, outlier_threshold,
                                  neighbours, min_points)
    stray = np.concatenate([m for m, _ in loops_members if len(m) < min_points]
                           + [np.empty(0, int)])
    loops = []
    for members, built in loops_members:
        if len(members) < min_points:
            continue
        if built is None:
            built = _organise_loop(
                section, uv, members, gap, link, outlier_threshold, neighbours, min_points
            )
        if built is not None:
            loops.append(built)
    if not loops:
        _skip(section, "no loop kept at least min_points points")
        return []
    return _attach_stray(loops, uv, stray)


def organise_all(sections, **kwargs) -> list[list[Loop]]:
    """:func:`organise` every section; a list of loops per section (possibly empty)."""
    return [organise(section, **kwargs) for section in sections]


def _is_collinear(uv: np.ndarray) -> bool:
    """True when ``(M, 2)`` points lie on one line: width ≤ ``TOL.planar_rel``·diameter.

    The width is the extent along the minor principal direction (module notes);
    the diameter the largest coordinate extent.  Coincident points count as
    collinear.
    """
    centred = uv - uv.mean(axis=0)
    _, vecs = np.linalg.eigh(centred.T @ centred)  # ascending eigenvalues
    width = float(np.ptp(centred @ vecs[:, 0]))
    diameter = float(np.ptp(uv, axis=0).max())
    return width <= TOL.planar_rel * max(diameter, TOL.zero)


def _skip(section: Section, why: str) -> None:
    warnings.warn(
        f"section {section.section_id} at height {section.height:.6g} skipped: {why}",
        SectionSkippedWarning,
        stacklevel=3,
    )


# ----------------------------------------------------------------------------- clusters
def _graph_edges(uv: np.ndarray) -> np.ndarray:
    """Candidate edges ``(E, 2)``, each once, containing the Euclidean MST.

    The Delaunay edges contain it; qhull leaves duplicate points out of every
    triangle (``coplanar``), so each of those is joined to its nearest
    triangulated vertex.  Collinear or too few points: the 8-nearest-neighbour
    graph.
    """
    n = len(uv)
    edges = _triangle_edges(uv)
    if edges is not None:
        return edges
    try:
        tri = Delaunay(uv)
    except (QhullError, ValueError):  # collinear or too few points
        k = min(8, n - 1)
        _, nbr = cKDTree(uv).query(uv, k=k + 1)
        edges = np.sort(np.stack([np.repeat(np.arange(n), k), nbr[:, 1:].ravel()], axis=1), axis=1)
        edges = edges[edges[:, 0] != edges[:, 1]]
        key = np.unique(edges[:, 0].astype(np.int64) * n + edges[:, 1])
        return np.stack([key // n, key % n], axis=1)
    indptr, neighbours = tri.vertex_neighbor_vertices  # CSR adjacency, both directions
    rows = np.repeat(np.arange(n), np.diff(indptr))
    once = rows < neighbours
    edges = np.stack([rows[once], neighbours[once]], axis=1)
    if len(tri.coplanar):
        edges = np.concatenate([edges, tri.coplanar[:, [0, 2]]])
    return edges


def _triangle_edges(uv: np.ndarray) -> np.ndarray | None:
    """Delaunay edges ``(E, 2)`` (lo, hi), ascending, by Shewchuk's Triangle; None if unfit.

    About 6x faster than qhull on a section.  Any Delaunay triangulation holds the
    Euclidean MST (its edges have an empty closed diametral disk, so they are in
    every one), so the tree is qhull's.  Where Triangle leaves a point out (a
    duplicate) or finds no triangle (collinear points), the caller falls back to
    qhull, which joins duplicates to their nearest vertex.
    """
    import triangle

    try:
        out = triangle.triangulate({"vertices": uv}, "Q")
    except (RuntimeError, ValueError):  # pragma: no cover - Triangle's own failure
        return None
    tris = out.get("triangles")
    if tris is None or len(tris) == 0 or not np.array_equal(out["vertices"], uv):
        return None
    n = len(uv)
    used = np.zeros(n, bool)
    used[tris] = True
    if not used.all():
        return None
    start, end = tris.ravel().astype(np.int64), np.roll(tris, -1, axis=1).ravel()
    key = np.unique(np.minimum(start, end) * n + np.maximum(start, end))
    return np.stack([key // n, key % n], axis=1)


@dataclass(frozen=True)
class _Tree:
    """A spanning tree's edges ``row[e] – col[e]`` and lengths ``data[e]``, in (row, col)
    order (the order of scipy's ``minimum_spanning_tree(...).tocoo()``)."""

    row: np.ndarray
    col: np.ndarray
    data: np.ndarray


def _spanning_tree(n: int, row: np.ndarray, col: np.ndarray, weight: np.ndarray) -> _Tree:
    """Kruskal's minimum spanning tree (forest) of the graph ``row[e] – col[e]``.

    The edges are put in (row, col) order and ranked by a stable sort of their
    weights, as ``scipy.sparse.csgraph.minimum_spanning_tree`` does with a CSR matrix
    (:func:`_kruskal`), so the tree is scipy's edge for edge, ties included (a test
    compares them); without the sparse matrices' set-up, which was most of the cost of
    the ~300 small trees of the real temple's sections.  Weights must be positive (scipy
    drops zeros).
    """
    row, col = np.asarray(row, np.int64), np.asarray(col, np.int64)
    order = np.argsort(row * n + col, kind="stable")
    row, col, weight = row[order], col[order], np.asarray(weight, np.float64)[order]
    kept = _kruskal(n, row, col, weight)
    return _Tree(row=row[kept], col=col[kept], data=weight[kept])


@numba.njit(cache=True, nogil=True)
def _root(parent: np.ndarray, x: int) -> int:  # pragma: no cover - numba
    """Union-find root of ``x``, halving the path on the way."""
    while parent[x] != x:
        parent[x] = parent[parent[x]]
        x = parent[x]
    return x


@numba.njit(cache=True, nogil=True)
def _kruskal(n: int, row: np.ndarray, col: np.ndarray,
             weight: np.ndarray) -> np.ndarray:  # pragma: no cover - numba
    """Edges ``(E,) bool`` of the minimum spanning forest: through the edges by a stable
    sort of their weights, each kept when it joins two components (union-find)."""
    kept = np.zeros(len(weight), np.bool_)
    parent = np.arange(n)
    joined = 0
    for e in np.argsort(weight, kind="mergesort"):
        if joined == n - 1:
            break
        a, b = _root(parent, row[e]), _root(parent, col[e])
        if a != b:
            parent[max(a, b)] = min(a, b)
            kept[e] = True
            joined += 1
    return kept


@numba.njit(cache=True, nogil=True)
def _components(n: int, row: np.ndarray, col: np.ndarray) -> np.ndarray:  # pragma: no cover
    """Connected-component labels ``(n,)`` of the graph ``row[e] – col[e]``, numbered in
    the order of each component's smallest node (scipy's ``connected_components``)."""
    parent = np.arange(n)
    for e in range(len(row)):
        a, b = _root(parent, row[e]), _root(parent, col[e])
        if a != b:
            parent[max(a, b)] = min(a, b)
    label = np.full(n, -1, np.int64)
    out = np.empty(n, np.int64)
    count = 0
    for v in range(n):
        r = _root(parent, v)
        if label[r] < 0:
            label[r] = count
            count += 1
        out[v] = label[r]
    return out


@numba.njit(cache=True, nogil=True)
def _tree_walk(n: int, row: np.ndarray, col: np.ndarray,
               start: int) -> np.ndarray:  # pragma: no cover - numba
    """Depth-first order of the nodes reached from ``start`` over the undirected edges
    ``row[e] – col[e]`` (in (row, col) order): scipy's ``depth_first_order(...,
    directed=False)`` on their CSR matrix, which from each node takes the first unvisited
    node among its row's columns, ascending, else among its column's rows, ascending."""
    out_start = np.zeros(n + 1, np.int64)
    in_start = np.zeros(n + 1, np.int64)
    for e in range(len(row)):
        out_start[row[e] + 1] += 1
        in_start[col[e] + 1] += 1
    for v in range(n):
        out_start[v + 1] += out_start[v]
        in_start[v + 1] += in_start[v]
    out_next = out_start[:-1].copy()
    in_next = in_start[:-1].copy()
    outs = np.empty(len(row), np.int64)
    ins = np.empty(len(row), np.int64)
    for e in range(len(row)):   # rows ascending: each column's rows come out ascending
        outs[out_next[row[e]]] = col[e]
        out_next[row[e]] += 1
        ins[in_next[col[e]]] = row[e]
        in_next[col[e]] += 1
    walk = np.empty(n, np.int64)
    stack = np.empty(n, np.int64)
    seen = np.zeros(n, np.bool_)
    walk[0], stack[0], seen[start] = start, start, True
    top, length = 0, 1
    while top >= 0 and length < n:
        node = stack[top]
        child = -1
        for i in range(out_start[node], out_start[node + 1]):
            if not seen[outs[i]]:
                child = outs[i]
                break
        if child < 0:
            for i in range(in_start[node], in_start[node + 1]):
                if not seen[ins[i]]:
                    child = ins[i]
                    break
        if child < 0:
            top -= 1
        else:
            top += 1
            stack[top], walk[length], seen[child] = child, child, True
            length += 1
    return walk[:length]


def _mst(uv: np.ndarray, scale: float) -> _Tree:
    """MST of the points (:class:`_Tree`: its edges and their lengths)."""
    edges = _graph_edges(uv)
    length = np.linalg.norm(uv[edges[:, 0]] - uv[edges[:, 1]], axis=1)
    # csgraph drops explicit zeros: duplicates get a length of TOL.zero·scale
    weight = np.maximum(length, TOL.zero * scale)
    return _spanning_tree(len(uv), edges[:, 0], edges[:, 1], weight)


def _clusters(uv: np.ndarray, link_distance, scale):
    """Labels ``(M,)`` of the loops, the mean gap g, the link distance ℓ, and the labels
    of the tree cut at ℓ alone (before the bridge and wall tests part its clusters)."""
    tree = _mst(uv, scale)
    lengths = tree.data
    gap = float(np.median(lengths)) / math.log(2.0) if lengths.size else scale
    gap = max(gap, TOL.zero * scale)
    n = len(uv)
    if link_distance is not None:
        link = float(link_distance)
    else:
        link = _DENSITY_RATIO * gap * (math.log(n) + _SPLIT_LOG_ODDS)
    keep = lengths <= link
    whole = _components(n, tree.row[keep], tree.col[keep])
    if link_distance is None:
        keep &= ~_closed_splits(uv, tree, keep, gap, link)
    labels = _components(n, tree.row[keep], tree.col[keep])
    if link_distance is None:
        labels = _wall_splits(uv, labels, gap, link)
    return labels, gap, float(link), whole


def _face_members(section, uv, labels, whole, gap, link, threshold, k, min_points):
    """Members of each loop, largest first, each with its loop when already built
    (else None): a cluster of the tree cut at ℓ (``whole``)
    whose points are both faces of a thin wall (:func:`_face_split` of it ordered as one
    loop) gives the two faces; any other gives the loops the bridge and wall tests
    (``labels``) part it into.  The offsets decide first: where the wall is thinner
    than the gaps along its faces the crust tracing can join half of one face to half
    of the other (a pot's wall 2 spacings thick at 20 000 points: 2 of 26 sections)."""
    members = []
    for c in range(int(whole.max()) + 1 if len(whole) else 0):
        mine = np.flatnonzero(whole == c)
        walls = built = None
        if len(mine) >= 2 * min_points:
            built = _organise_loop(section, uv, mine, gap, link, threshold, k, min_points)
            walls = None if built is None else _face_split(uv, built, gap)
        for faces in walls or []:
            parted = [_organise_loop(section, uv, face, gap, link, threshold, k, min_points)
                      for face in faces]
            if all(lp is not None and lp.closed for lp in parted):
                members += [(face, lp) for face, lp in zip(faces, parted, strict=True)]
                mine = np.setdiff1d(mine, np.concatenate(faces))
                built = None
        if len(mine) == 0:
            continue
        sub = labels[mine]
        values = np.unique(sub)
        if built is not None and len(values) == 1:
            # one loop, the cluster itself: the loop already built (not built twice)
            members.append((mine, built))
            continue
        members += [(mine[sub == value], None) for value in values]
    return sorted(members, key=lambda pair: len(pair[0]), reverse=True)


def _wall_splits(uv: np.ndarray, labels: np.ndarray, gap: float, link: float) -> np.ndarray:
    """Labels ``(M,)`` with a cluster that holds both faces of a thin wall parted.

    Where a wall is thinner than the largest gaps along its loops (gaps along a loop
    are exponential with mean g, the largest of M about ``g (ln M + 0.58)``, ~7 g: a
    rim 3-4 point spacings thick) the MST crosses the wall more than once and
    :func:`_closed_splits` finds no single bridge.  Here each cluster is traced as
    curves instead (:func:`_curve_graph`); the pieces holding at least
    ``1 - _WALL_SHARE`` of its points (and :data:`_SECTORS`) take the rest, each
    smaller piece (and then each big one that is not closed, smallest first) joining
    the one at the nearest median distance from the centroid, and the cluster is
    parted when there are two or more and each is a closed loop
    (:func:`_is_closed_loop`), by the first of :data:`_TRACINGS` that gives them;
    otherwise it is left as it was.
    """
    sizes = np.bincount(labels)
    out = labels.copy()
    for c in np.flatnonzero(sizes >= 2 * _SECTORS):
        members = np.flatnonzero(labels == c)
        pts = uv[members]
        if float(np.ptp(pts, axis=0).max()) <= 2 * link:
            continue
        owner, big = None, []
        for tracing in _TRACINGS:  # the first that parts the cluster into closed loops
            owner, big = _faces(pts, gap, link, *tracing)
            if len(big) >= 2:
                break
        if len(big) < 2:
            continue
        fresh = out.max() + 1
        for j, b in enumerate(big[1:]):
            out[members[owner == b]] = fresh + j
    return out


#: Points along the loop's order within which a face's curve nodes are not bridged
#: (:func:`_face_curves_labels`: half of it): both faces of a wall 2 spacings thick
#: are ~4 g apart, and 32 points are ~16 g of arc, 16 per face.
_FACE_WINDOW = 32
#: Separation of a wall's two faces, in pooled standard deviations of either face's
#: offsets about its own mean, below which a disc is one band (:func:`_disc_walls`):
#: one noisy face split at its midline gives 2.65 whatever its noise (half-normal
#: means ±0.80σ, within-half σ 0.60σ), two faces ±a apart give 2a/σ' (σ' the in-section
#: noise), so 4 takes a disc for a wall when a > 2σ'; a single face (2.65 ± ~0.3 over
#: the ~32 points of its disc) passes none, and a disc is a wall only when most of
#: its points' discs are.
_FACE_SEPARATION = 4.0
#: Fewest points of a loop, over 4, that :func:`_face_split` tries to part.
_FACE_RUN = 64
#: Radius, in mean gaps g, of the disc about each point whose centroid and principal
#: parabola are the wall's midline (:func:`_disc_walls`): a wall up to ~4 spacings
#: (8 g at a slab 2 spacings thick) has both faces in it, each ~32 points long.  A
#: line would put the sag of a curve of radius R, ~(16 g)²/(2R), into the offsets.
_FACE_DISC = 16.0
#: Mean points per disc, in units of its radius in gaps, beyond which a cluster is
#: an area of points rather than faces along curves (two faces hold ~4 per unit; 16
#: allows the twofold density variation along a loop and a wider noise band), and
#: :func:`_disc_walls` does not try it (its pairs would grow as M·disc area).
_FACE_DISC_LOAD = 16.0
#: Least length, in disc diameters, of the chord along which each face of a wall
#: crosses a disc (:func:`_disc_walls`; a chord of length 2fr sampled evenly has x
#: spread f/sqrt(3) radii). The far face of the thickest wall the disc tests (4
#: spacings, 8 g = r/2 from the near face) crosses along sqrt(1 - 1/4) = 0.87 of a
#: diameter; a loop of diameter D < r lying in the disc (a handle's section beside the
#: wall) spans at most D/2r < 1/2. 0.7 lies between them.
_FACE_SPAN = 0.7


def _face_split(uv: np.ndarray, loop: Loop, gap: float
                ) -> list[tuple[np.ndarray, np.ndarray]] | None:
    """The two faces of a wall that the clustering left as one band, or None.

    A wall thinner than the largest gaps along its faces (under ~3.5 point spacings,
    :func:`_wall_splits`) is ordered as one loop, zig-zagging across it or running
    along one face and back along the other. Each point's disc (radius
    :data:`_FACE_DISC` g) holds both faces of such a wall, whatever the order does
    between them; their offsets from the disc's centroid across its principal line
    are two groups ±a (:func:`_disc_walls`). A point's disc is a wall when both signs
    hold at least 15 % of it and the groups' means are :data:`_FACE_SEPARATION`
    pooled σ apart and at least a mean gap g (a noise-free single face scatters by
    less than g about its line), and each crosses the disc (:data:`_FACE_SPAN`; a
    handle's section lying inside the disc is no wall). When at least half the points
    are walls, those whose disc holds no other point are parted by the sign of their
    own offset (the discs'
    normals oriented alike along a tree where they agree, :func:`_tree_signs`);
    the rest (a handle or spout joins the wall there) take the face whose curve
    through the parted points, bridged across them, is nearer
    (:func:`_face_curves_labels`).

    Returns the two faces' indices into ``uv`` (outer first is not implied) of each
    wall, or None.
    """
    m = len(loop.indices)
    if m < 4 * _FACE_RUN:
        return None
    # the outliers too: where the faces interleave, the local curve fit of one loop
    # rejects stretches of a face (the 3-spacing bowl: 140-210 points of ~1 900)
    index = np.concatenate([loop.indices, loop.outliers])
    pts = uv[index]
    tree = cKDTree(pts)
    held = tree.query_ball_point(pts, _FACE_DISC * gap, return_length=True)
    if held.mean() > _FACE_DISC_LOAD * _FACE_DISC:   # an area of points, not a band
        return None
    # loops of one cluster farther apart than a disc (a handle's section beside the
    # wall, within the link distance ℓ of it) are tried each on its own
    pairs = tree.query_pairs(_FACE_DISC * gap, output_type="ndarray")
    part = _components(len(pts), pairs[:, 0], pairs[:, 1])
    faces = []
    for c in np.flatnonzero(np.bincount(part) >= 4 * _FACE_RUN):
        mine = np.flatnonzero(part == c)
        labels = _disc_walls(pts[mine], int(np.count_nonzero(mine < m)), gap)
        if labels is not None:
            faces.append((np.sort(index[mine[labels == 1]]), np.sort(index[mine[labels == 0]])))
    return faces or None


def _disc_walls(pts: np.ndarray, ordered: int, gap: float) -> np.ndarray | None:
    """Face labels ``(M,)`` (1: positive offset) by the disc test of :func:`_face_split`,
    or None; the first ``ordered`` points are in the loop's order."""
    m = len(pts)
    pairs = cKDTree(pts).query_pairs(_FACE_DISC * gap, output_type="ndarray")
    row = np.concatenate([pairs[:, 0], pairs[:, 1], np.arange(m)])
    col = np.concatenate([pairs[:, 1], pairs[:, 0], np.arange(m)])
    count = np.bincount(row, minlength=m).astype(np.float64)
    centre = np.column_stack([np.bincount(row, pts[col, k], m) for k in (0, 1)]) / count[:, None]
    d = pts[col] - centre[row]
    sxx = np.bincount(row, d[:, 0] * d[:, 0], m)
    sxy = np.bincount(row, d[:, 0] * d[:, 1], m)
    syy = np.bincount(row, d[:, 1] * d[:, 1], m)
    angle = 0.5 * np.arctan2(2 * sxy, sxx - syy)          # the principal direction
    normal = np.column_stack([-np.sin(angle), np.cos(angle)])
    normal *= _tree_signs(pts, normal, _FACE_DISC * gap)[:, None]
    # offsets from the parabola y = c0 + c1 x + c2 x² fitted to each disc in its
    # principal frame, x in units of the radius (the 1e-9 ridge: a disc of one point)
    x = np.einsum("ij,ij->i", d, normal[row][:, ::-1] * np.array([1.0, -1.0]))
    y = np.einsum("ij,ij->i", d, normal[row])
    scale = _FACE_DISC * gap
    x = x / scale
    moments = np.stack([np.bincount(row, x ** k, m) for k in range(5)], axis=1)
    normal_eq = moments[:, [[0, 1, 2], [1, 2, 3], [2, 3, 4]]]
    normal_eq += 1e-9 * np.eye(3)
    rhs = np.stack([np.bincount(row, y * x ** k, m) for k in range(3)], axis=1)
    coef = np.linalg.solve(normal_eq, rhs[:, :, None])[:, :, 0]
    o = y - (coef[row, 0] + coef[row, 1] * x + coef[row, 2] * x * x)
    up = o > 0
    n_up = np.bincount(row, up, m)
    n_down = count - n_up
    share = n_up / count
    mean_up = np.bincount(row, np.where(up, o, 0.0), m) / np.maximum(n_up, 1)
    mean_down = np.bincount(row, np.where(up, 0.0, o), m) / np.maximum(n_down, 1)
    resid = o - np.where(up, mean_up[row], mean_down[row])
    pooled = np.sqrt(np.bincount(row, resid * resid, m) / np.maximum(count - 2, 1))
    separation = mean_up - mean_down
    # each face crosses the disc: the spread of its points along the disc's line (x in
    # radii) is that of a chord nearly a diameter long, not of a loop smaller than the
    # disc lying inside it (a handle's section beside the wall)
    x_sq = x * x
    spread = np.minimum(*(np.sqrt(np.maximum(
        np.bincount(row, np.where(side, x_sq, 0.0), m) / np.maximum(n, 1)
        - (np.bincount(row, np.where(side, x, 0.0), m) / np.maximum(n, 1)) ** 2, 0.0))
        for side, n in ((up, n_up), (~up, n_down))))
    wall = ((share >= 0.15) & (share <= 0.85) & (separation >= gap)
            & (separation >= _FACE_SEPARATION * pooled)
            & (spread >= _FACE_SPAN / np.sqrt(3.0)))
    # each disc's test scatters (~64 points); a disc is a wall when most of it is
    wall = 2 * np.bincount(row, wall[col], m) >= count
    if 2 * wall.sum() < m:
        return None
    own = o[2 * len(pairs):]       # each point's offset in its own disc
    trusted = wall & (np.bincount(row, ~wall[col], m) == 0)
    labels = np.where(trusted, (own > 0).astype(np.int64), -1)
    if not trusted.all():
        labels = _face_curves_labels(pts[:ordered], labels[:ordered], gap,
                                     float(np.median(separation[wall])), query=pts)
    return labels


def _tree_signs(pts: np.ndarray, normal: np.ndarray, reach: float) -> np.ndarray:
    """Signs ``(M,)`` that orient the unsigned ``normal`` consistently: each agrees with
    its parent's along a spanning tree (rooted at point 0), the parity of the flips to
    the root found by pointer jumping (log2 M vectorised rounds).

    The tree is Hoppe et al.'s [2]_: the minimum spanning tree of the Delaunay edges no
    longer than ``reach`` weighted by 1 - |n_i·n_j| (and a thousandth of their length
    over ``reach``, so a straight wall's ties go to the nearer point), so the
    orientation is carried where the normals agree and not across a stretch where they
    turn (a handle's root, whose discs hold the handle's sides: a tree of lengths
    alone crossed it and swapped the faces' labels beyond it).

    .. [2] H. Hoppe, T. DeRose, T. Duchamp, J. McDonald, W. Stuetzle, "Surface
       reconstruction from unorganized points", SIGGRAPH 1992, section 3.3.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import breadth_first_order, minimum_spanning_tree

    m = len(pts)
    edges = _graph_edges(pts)
    length = np.linalg.norm(pts[edges[:, 0]] - pts[edges[:, 1]], axis=1)
    edges, length = edges[length <= reach], length[length <= reach]
    turn = 1.0 - np.abs(np.einsum("ij,ij->i", normal[edges[:, 0]], normal[edges[:, 1]]))
    # csgraph drops explicit zeros: every weight is at least TOL.zero
    weight = np.maximum(turn, 0.0) + 1e-3 * length / reach + TOL.zero
    tree = minimum_spanning_tree(coo_matrix((weight, (edges[:, 0], edges[:, 1])), shape=(m, m)))
    _, parent = breadth_first_order(tree, 0, directed=False)
    root = parent < 0            # point 0, and any point the tree does not reach
    parent = np.where(root, np.arange(m), parent)
    parity = (np.einsum("ij,ij->i", normal, normal[parent]) < 0).astype(np.int8)
    for _ in range(int(np.ceil(np.log2(max(m, 2)))) + 1):
        parity ^= parity[parent]
        parent = parent[parent]
    return np.where(parity == 1, -1.0, 1.0)


#: Face points averaged into one node of the face curve that the points outside the
#: wall runs are compared with (:func:`_face_curves_labels`).
_FACE_BLOCK = 8


def _face_curves_labels(pts: np.ndarray, labels: np.ndarray, gap: float,
                        separation: float, query: np.ndarray | None = None
                        ) -> np.ndarray | None:
    """Labels ``(Q,)`` of the ``query`` points (default ``pts``, ordered along the loop)
    : each on the face whose curve is nearer (None: a face's
    curve would lose more than a quarter of its nodes to the peeling below, and the band
    is not parted).

    Each face's curve: the means of runs of :data:`_FACE_BLOCK` consecutive points of
    that face along the order (never across a stretch of half a :data:`_FACE_WINDOW`
    without one), spikes peeled (the node farthest from the line through its two
    neighbours goes while that is more than half the wall's ``separation``, at most a
    quarter of them, the nodes taken by θ about the face's mean when that tour is
    shorter than the loop's order: a handle's neck is a thin wall too, and its sides
    took both labels), joined by a periodic cubic spline over their chord lengths,
    which bridges the stretches left smoothly (a handle's root bulges the outer face
    there; the inner face runs on), sampled every g/2. A face no tour of whose nodes is
    shorter than their θ order about its least-squares circle centre is joined as its
    radius over θ instead, which keeps its curvature across a long stretch.
    """
    from scipy.interpolate import CubicSpline

    curves = []
    for face in (0, 1):
        mine = np.flatnonzero(labels == face)     # the faces interleave along the order
        breaks = np.flatnonzero(np.diff(mine) > _FACE_WINDOW // 2) + 1
        nodes = []
        for run in np.split(mine, breaks):
            blocks = max(1, len(run) // _FACE_BLOCK)
            nodes += [pts[b].mean(axis=0) for b in np.array_split(run, blocks)]
        nodes = np.array(nodes)
        # a bulge's nodes come back along the loop's order; in θ order they are spikes
        rel = nodes - pts[mine].mean(axis=0)
        by_theta = nodes[np.argsort(np.arctan2(rel[:, 1], rel[:, 0]), kind="stable")]
        theta_tour = _tour_length(by_theta, np.arange(len(nodes)))
        order_tour = _tour_length(nodes, np.arange(len(nodes)))
        if theta_tour < order_tour:
            nodes = by_theta
        star = theta_tour <= order_tour * (1 + 1e-9)   # no shorter tour than by θ
        kept = len(nodes)
        while len(nodes) > max(5, kept - kept // 4):
            before, after = np.roll(nodes, 1, axis=0), np.roll(nodes, -1, axis=0)
            chord, rel = after - before, nodes - before
            span = np.linalg.norm(chord, axis=1)
            across = np.abs(chord[:, 0] * rel[:, 1] - chord[:, 1] * rel[:, 0]) / np.maximum(
                span, TOL.zero)
            # a spike turns by more than ~50° (across > span/4); a node at the end of
            # a stretch bridged (a face's gap at a handle's root) lies off the chord
            # over the gap by its sag, span²/(8R), under span/4 where span < 2R
            across = np.where(across > 0.25 * span, across, 0.0)
            worst = int(np.argmax(across))
            if across[worst] <= 0.5 * separation:
                break
            nodes = np.delete(nodes, worst, axis=0)
        else:   # a quarter of the nodes peeled: no smooth face to follow
            return None
        closed = np.vstack([nodes, nodes[:1]])
        chord = np.linalg.norm(np.diff(closed, axis=0), axis=1)
        if np.any(chord <= 0):
            return None
        samples = int(np.ceil(2 * chord.sum() / gap)) + 1
        if star:
            # a face star-shaped about its least-squares circle centre (not its mean,
            # which moves away from a long stretch without points) is bridged as its
            # radius over θ: across a stretch without nodes (a handle's root, 60-70°
            # of a 2-spacing wall at 20 000 points) it keeps the face's curvature,
            # where the spline over chord lengths cut inside by more than half the wall
            face_pts = pts[mine]
            fit = np.linalg.lstsq(np.column_stack([2 * face_pts, np.ones(len(mine))]),
                                  (face_pts ** 2).sum(axis=1), rcond=None)[0][:2]
            rel = nodes - fit
            theta = np.arctan2(rel[:, 1], rel[:, 0])
            order = np.argsort(theta, kind="stable")
            theta, rel = theta[order], rel[order]
            if np.all(np.diff(theta) > 0) and _tour_length(nodes[order], np.arange(len(nodes))) \
                    <= _tour_length(nodes, np.arange(len(nodes))) * (1 + 1e-9):
                theta = np.append(theta, theta[0] + 2 * np.pi)
                radius = np.append(np.hypot(rel[:, 0], rel[:, 1]), np.hypot(*rel[0]))
                at = np.linspace(theta[0], theta[-1], samples)
                r = CubicSpline(theta, radius, bc_type="periodic")(at)
                curves.append(fit + r[:, None] * np.column_stack([np.cos(at), np.sin(at)]))
                continue
        t = np.concatenate([[0.0], np.cumsum(chord)])
        spline = CubicSpline(t, closed, bc_type="periodic")
        curves.append(spline(np.linspace(0.0, t[-1], samples)))
    query = pts if query is None else query
    dist = np.column_stack([cKDTree(c).query(query)[0] for c in curves])
    return np.argmin(dist, axis=1)


def _faces(pts: np.ndarray, gap: float, link: float, chord: float, neighbours: int,
           mutual: bool) -> tuple[np.ndarray | None, list]:
    """The loop ``(m,)`` of each point of a traced cluster and the loops' labels (fewer
    than two: no parting); see :func:`_wall_splits`."""
    row, col = _curve_graph(pts, gap, link, chord, neighbours, mutual)
    parts = _components(len(pts), row, col)
    part_sizes = np.bincount(parts)
    big = np.flatnonzero(part_sizes >= max(_SECTORS, (1 - _WALL_SHARE) * len(pts)))
    if len(big) == 0:  # only small pieces (a facade's broken section): no parting
        return None, []
    # the smaller pieces go to the big one at the nearest distance from the
    # cluster's centroid (a wall's faces: the inner and the outer radius; nearest
    # points would hand a piece of one face across a gap to the other)
    radius = np.linalg.norm(pts - pts.mean(axis=0), axis=1)
    level = np.array([np.median(radius[parts == b]) for b in big])
    piece_level = np.array([np.median(radius[parts == c]) if part_sizes[c] else 0.0
                            for c in range(len(part_sizes))])
    owner = big[np.argmin(np.abs(piece_level[:, None] - level[None, :]), axis=1)][parts]
    owner[np.isin(parts, big)] = parts[np.isin(parts, big)]
    # a big piece that is an arc of a face, not closed, joins the nearest level too
    big = list(big)
    while len(big) >= 2:
        open_ = [b for b in big if not _is_closed_loop(pts[owner == b], link)]
        if not open_:
            break
        b = min(open_, key=lambda c: np.count_nonzero(owner == c))
        big.remove(b)
        lv = np.array([np.median(radius[owner == c]) for c in big])
        owner[owner == b] = big[int(np.argmin(np.abs(lv - np.median(radius[owner == b]))))]
    return owner, big


def _curve_graph(pts: np.ndarray, gap: float, link: float, chord: float = 0.5,
                 neighbours: int = 8, mutual: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Edges ``(row, col)`` tracing points sampled along curves: NN-crust [1]_, pruned.

    Each point joins its nearest neighbour q and its nearest neighbour r on the other
    side (``(q - p)·(r - p) < 0``, the *half neighbour*).  Along a curve q and r lie
    on either side, nearly opposite; the curve's line at p is the chord between
    its nearest neighbours on either side at least ``chord`` g away (of its
    ``neighbours`` nearest), where the bend there is below :data:`_CRUST_BEND`.
    Where a face of a wall has a gap wider than the wall a neighbour lies across it:
    an edge longer than :data:`_BRIDGE_GAPS` g (a short one bends with the noise,
    not across a wall) more than :data:`_CRUST_BEND` off the line at either of its
    ends (or at p, for a half-neighbour edge, where p has no line) is dropped.
    Each loose end of the arcs left is then joined across its gap to the nearest
    point of another arc within ℓ that lies ahead of it (within :data:`_CRUST_BEND`
    of its direction, and of that point's line -- or, a loose end itself, facing
    back within the same angle; with ``mutual``, only as each other's choice).

    .. [1] T. K. Dey, P. Kumar, "A simple provable algorithm for curve
       reconstruction", Proc. SODA (1999).
    """
    m = len(pts)
    k = min(neighbours, m - 1)
    tree = cKDTree(pts)
    dist, nbr = tree.query(pts, k=k + 1)
    dist, nbr = dist[:, 1:], nbr[:, 1:]
    rel = pts[nbr] - pts[:, None, :]  # (m, k, 2)
    rows = np.arange(m)

    def opposite(first, usable):
        # the nearest usable neighbour on the other side of ``first``: (index, has one)
        other = usable & ((rel * first[:, None, :]).sum(axis=2) < 0)  # (m, k)
        return np.argmax(other, axis=1), other.any(axis=1)

    first = rel[:, 0]
    pick, has = opposite(first, np.ones_like(dist, bool))
    # The line through p: the chord between its nearest neighbours on either side at
    # least half a gap away (nearer ones point wherever the points' scatter across the
    # curve -- sliding, noise -- puts them).
    far = dist >= chord * gap
    near_far = np.where(far.any(axis=1), np.argmax(far, axis=1), k - 1)
    ahead = rel[rows, near_far]
    pick_far, has_far = opposite(ahead, far)
    behind = rel[rows, pick_far]
    cos = -(ahead * behind).sum(axis=1) / np.maximum(
        np.linalg.norm(ahead, axis=1) * np.linalg.norm(behind, axis=1), TOL.zero)
    cos_bend = np.cos(np.radians(_CRUST_BEND))
    straight = has_far & (cos >= cos_bend)  # the curve runs straight on through p
    tangent = np.where(straight[:, None], ahead - behind, 0.0)
    tangent /= np.maximum(np.linalg.norm(tangent, axis=1), TOL.zero)[:, None]
    # a half-neighbour edge longer than the noise's bends must run along p's line
    second = rel[rows, pick]
    along = np.abs((second * tangent).sum(axis=1)) >= cos_bend * np.linalg.norm(second, axis=1)
    half = has & ((straight & along) | (np.linalg.norm(second, axis=1) <= _BRIDGE_GAPS * gap))
    row = np.r_[np.arange(m), np.flatnonzero(half)]
    col = np.r_[nbr[:, 0], nbr[half, pick[half]]]
    pairs = np.unique(np.sort(np.stack([row, col], axis=1), axis=1), axis=0)
    # an edge longer than the noise's bends must run along the line at each end that
    # has one: across a wall it leaves the other face's line at 45-90°
    d = pts[pairs[:, 1]] - pts[pairs[:, 0]]
    length = np.linalg.norm(d, axis=1)
    d /= np.maximum(length, TOL.zero)[:, None]
    off = np.zeros(len(pairs), bool)
    for end in (0, 1):
        at = pairs[:, end]
        off |= straight[at] & (np.abs((d * tangent[at]).sum(axis=1)) < cos_bend)
    pairs = pairs[~(off & (length > _BRIDGE_GAPS * gap))]
    degree = np.bincount(pairs.ravel(), minlength=m)
    ends = np.flatnonzero(degree == 1)
    if len(ends) >= 2:
        # each loose end's direction: out from the mean of its arc's points among its
        # nearest neighbours (one neighbour alone, a fraction of g away, points anywhere)
        arc = _components(m, pairs[:, 0], pairs[:, 1])
        mine = (arc[nbr[ends]] == arc[ends][:, None]).astype(np.float64)  # (e, k)
        back = (pts[nbr[ends]] * mine[:, :, None]).sum(axis=1) / np.maximum(
            mine.sum(axis=1), 1.0)[:, None]
        out_dir = np.where(mine.any(axis=1)[:, None], pts[ends] - back, 0.0)
        out_dir /= np.maximum(np.linalg.norm(out_dir, axis=1), TOL.zero)[:, None]
        dist, idx = tree.query(pts[ends], k=min(m, _JOIN_CANDIDATES),
                               distance_upper_bound=link)
        end_of = np.full(m, -1)
        end_of[ends] = np.arange(len(ends))
        best = np.full(len(ends), -1)
        for j in range(1, idx.shape[1]):  # candidates nearest first
            ok = (best < 0) & np.isfinite(dist[:, j])
            cand = np.where(ok, idx[:, j], 0)
            step = pts[cand] - pts[ends]
            step /= np.maximum(np.linalg.norm(step, axis=1), TOL.zero)[:, None]
            facing = (end_of[cand] >= 0) & (
                (-step * out_dir[np.maximum(end_of[cand], 0)]).sum(axis=1) >= cos_bend)
            along = facing | (straight[cand] & (
                np.abs((step * tangent[cand]).sum(axis=1)) >= cos_bend))
            ahead = ok & along & (arc[cand] != arc[ends]) & (
                (step * out_dir).sum(axis=1) >= cos_bend)
            best[ahead] = cand[ahead]
        # two loose ends join only as each other's choice
        to_end = end_of[np.maximum(best, 0)]
        joined = (best >= 0) & ((to_end < 0) | (best[np.maximum(to_end, 0)] == ends) | (not mutual))
        pairs = np.concatenate([pairs, np.stack([ends[joined], best[joined]], axis=1)])
    return pairs[:, 0], pairs[:, 1]


def _closed_splits(uv, tree, keep, gap, link) -> np.ndarray:
    """MST edges ``(E,) bool`` that join two closed loops (e.g. nested rings).

    Gap statistics cannot part two loops a few gaps apart (a cup's inner and
    outer wall): the bridge is only slightly longer than the largest gaps
    along one loop.  So the few longest kept edges beyond the expected largest
    gap ``g·(ln M + 0.58)`` are tried: an edge is cut when both sides are
    wider than ℓ and each surrounds its own centroid (points in all 16
    angular sectors about it).  Cutting a loop's own gap instead leaves two
    open arcs, and the shorter one cannot surround its centroid.  (Nested
    loops that are not star-shaped, or closer than the largest gap along
    them, stay merged.)
    """
    n = len(uv)
    lengths = tree.data
    bridges = np.zeros(len(lengths), bool)
    expected_max = gap * (math.log(n) + 0.58)
    candidates = np.flatnonzero(keep & (lengths > expected_max))
    candidates = candidates[np.argsort(-lengths[candidates])][:_SPLIT_TRIES]
    for edge in candidates:
        trial = keep & ~bridges
        trial[edge] = False
        labels = _components(n, tree.row[trial], tree.col[trial])
        sides = [uv[labels == labels[tree.row[edge]]], uv[labels == labels[tree.col[edge]]]]
        if all(_is_closed_loop(side, link) for side in sides):
            bridges[edge] = True
    return bridges


def _is_closed_loop(uv: np.ndarray, link: float) -> bool:
    """A side wider than ℓ that surrounds its centroid: every one of 16 sectors holds a point."""
    if len(uv) < _SECTORS or float(np.ptp(uv, axis=0).max()) <= link:
        return False
    rel = uv - uv.mean(axis=0)
    sector = (
        np.mod(np.arctan2(rel[:, 1], rel[:, 0]), 2 * np.pi) * (_SECTORS / (2 * np.pi))
    ).astype(np.int64)
    return bool(np.all(np.bincount(np.minimum(sector, _SECTORS - 1), minlength=_SECTORS) > 0))


def _attach_stray(loops: list[Loop], uv: np.ndarray, stray: np.ndarray) -> list[Loop]:
    """Give the points of too-small clusters to the loop of their nearest kept point."""
    if stray.size == 0:
        return loops
    owner = np.concatenate([np.full(len(lp), i) for i, lp in enumerate(loops)])
    kept = np.concatenate([lp.indices for lp in loops])
    _, nearest = cKDTree(uv[kept]).query(uv[stray])
    out = []
    for i, lp in enumerate(loops):
        mine = stray[owner[nearest] == i]
        if mine.size:
            lp = replace(lp, outliers=np.sort(np.concatenate([lp.outliers, mine])))
        out.append(lp)
    return out


# ----------------------------------------------------------------------------- outliers
def _local_residuals(uv: np.ndarray, reference: np.ndarray, k: int) -> np.ndarray:
    """Distance ``(M,)`` of each point from a quadratic fitted to its k nearest references.

    ``reference`` ``(R,)`` indexes the points the fits may use; a point never
    uses itself.  The 3×3 normal equations of ``y = a + b x + c x²`` are built
    from power sums of the neighbours' local coordinates and solved point by point in
    a numba kernel (:func:`_quadratic_residuals`; the array form's temporaries and
    per-loop overhead were 0.4 s of the real temple's 263 loops).
    """
    k = min(k, len(reference) - 1)
    _, nbr = cKDTree(uv[reference]).query(uv, k=k + 1)
    nbr = np.ascontiguousarray(reference[nbr])  # (M, k + 1) point indices, self among them
    return _quadratic_residuals(np.ascontiguousarray(uv, dtype=np.float64), nbr,
                                float(TOL.ridge_rel), float(TOL.zero))


@numba.njit(cache=True, nogil=True)
def _quadratic_residuals(uv, nbr, ridge, tiny):  # pragma: no cover - compiled
    """Per point: its k neighbours (``nbr[i]``, its k + 1 nearest references, less itself
    or, where it is not a reference, less the farthest) about their mean, rotated to their
    principal direction (half the angle of the second moments), x scaled by its RMS;
    ``y = a + b x + c x²`` by least squares (power sums, ridge ``ridge`` times the
    trace on the diagonal, solved by Cholesky: the system is symmetric positive
    definite); the point's distance from it across the direction."""
    m, k = nbr.shape[0], nbr.shape[1] - 1
    out = np.empty(m)
    x = np.empty(k)
    y = np.empty(k)
    near = np.empty((1, k), np.int64)
    for i in range(m):
        drop = k
        for j in range(k + 1):
            if nbr[i, j] == i:
                drop = j
                break
        at = 0
        for j in range(k + 1):
            if j != drop:
                near[0, at] = nbr[i, j]
                at += 1
        mu = 0.0
        mv = 0.0
        for j in range(k):
            mu += uv[near[0, j], 0]
            mv += uv[near[0, j], 1]
        mu /= k
        mv /= k
        suv = 0.0
        sdiff = 0.0
        for j in range(k):
            du = uv[near[0, j], 0] - mu
            dv = uv[near[0, j], 1] - mv
            suv += du * dv
            sdiff += du * du - dv * dv
        angle = 0.5 * np.arctan2(2.0 * suv, sdiff)
        c = np.cos(angle)
        s = np.sin(angle)
        sq = 0.0
        for j in range(k):
            du = uv[near[0, j], 0] - mu
            dv = uv[near[0, j], 1] - mv
            x[j] = du * c + dv * s
            y[j] = dv * c - du * s
            sq += x[j] * x[j]
        spread = max(np.sqrt(sq / k), tiny)
        s1 = 0.0
        s2 = 0.0
        s3 = 0.0
        s4 = 0.0
        t0 = 0.0
        t1 = 0.0
        t2 = 0.0
        for j in range(k):
            xs = x[j] / spread
            x2 = xs * xs
            s1 += xs
            s2 += x2
            s3 += x2 * xs
            s4 += x2 * x2
            t0 += y[j]
            t1 += xs * y[j]
            t2 += x2 * y[j]
        # the normal equations (power sums, the ridge on the diagonal) are symmetric
        # positive definite: Cholesky, then the two triangular solves
        s0 = float(k)
        lift = ridge * (s0 + s2 + s4)
        l00 = np.sqrt(s0 + lift)
        l10 = s1 / l00
        l20 = s2 / l00
        l11 = np.sqrt(max(s2 + lift - l10 * l10, tiny))
        l21 = (s3 - l20 * l10) / l11
        l22 = np.sqrt(max(s4 + lift - l20 * l20 - l21 * l21, tiny))
        y0 = t0 / l00
        y1 = (t1 - l10 * y0) / l11
        y2 = (t2 - l20 * y0 - l21 * y1) / l22
        cc = y2 / l22
        bb = (y1 - l21 * cc) / l11
        aa = (y0 - l10 * bb - l20 * cc) / l00
        ou = uv[i, 0] - mu
        ov = uv[i, 1] - mv
        x0 = (ou * c + ov * s) / spread
        y0 = ov * c - ou * s
        out[i] = abs(y0 - (aa + bb * x0 + cc * x0 * x0))
    return out


def _reject(uv: np.ndarray, gap: float, threshold: float, k: int) -> tuple[np.ndarray, float]:
    """Mask ``(M,)`` of kept points and the robust noise σ̂ (two passes, module notes)."""
    keep = np.ones(len(uv), bool)
    sigma = 0.0
    for _ in range(2):
        reference = np.flatnonzero(keep)
        if len(reference) <= 4:
            break
        resid = _local_residuals(uv, reference, k)
        sigma = _MAD_TO_SIGMA * float(np.median(resid[reference]))
        new_keep = resid <= max(threshold * sigma, 0.5 * gap)
        if np.array_equal(new_keep, keep):
            break
        keep = new_keep
    return keep, sigma


# ----------------------------------------------------------------------------- order
def _grid_centres(uv: np.ndarray, cell: float) -> np.ndarray:
    """Mean ``(C, 2)`` of the points in each occupied grid cell."""
    key = np.floor((uv - uv.min(axis=0)) / cell).astype(np.int64)  # (M, 2), >= 0
    # one int64 per cell, in the lexicographic order of (row, column): the same cells,
    # numbered as np.unique(key, axis=0) numbers them, without its structured sort
    flat = key[:, 0] * (int(key[:, 1].max()) + 1) + key[:, 1]
    _, inverse = np.unique(flat, return_inverse=True)
    count = np.bincount(inverse)
    sums = np.stack([np.bincount(inverse, uv[:, d]) for d in range(2)], axis=1)
    return sums / count[:, None]


def _tour_length(points: np.ndarray, tour: np.ndarray) -> float:
    ring = points[tour]
    return float(np.linalg.norm(np.roll(ring, -1, axis=0) - ring, axis=1).sum())


#: Candidate moves :func:`_two_opt` evaluates at most, in all (~15 s on this machine at load 4:
#: 2e8 took 66 s on a 3 000-point disk; a loop of thousands of points needs far fewer).
TWO_OPT_WORK = 50_000_000


def _two_opt(points: np.ndarray, tour: np.ndarray) -> np.ndarray:
    """Best-improvement 2-opt of a closed tour through ``points`` ``(n, 2)``.

    A move replaces edges (a, b), (c, d) by (a, c), (b, d); it can only
    shorten the tour when ``|ac| < |ab| + |cd| ≤ 2·(longest edge)``, so the
    candidate moves are the vertex pairs closer than that (a k-d tree query,
    renewed when the longest edge outgrows it), and every move takes the
    candidate of the largest gain (:func:`_two_opt_moves`, a numba kernel since
    2026-12-06: the array form spent 0.5 s of the real temple's 3 s of curves in
    per-move array calls; the same moves, the same tours).

    The work is bounded: at most ``10 n`` moves and :data:`TWO_OPT_WORK` candidate
    evaluations in all, after which the tour is returned as it stands (still a
    permutation, only less short).  A loop is a curve and its candidates are few; a
    filled disk of points (a cap taken for a section) has a long edge, so every pair is a
    candidate at every move: on the first 10⁷-point vase two such sections of 197 433 and
    368 516 points kept this loop busy for over 20 minutes (2026-12-03).
    """
    n = len(tour)
    if n < 5:
        return tour
    points = np.ascontiguousarray(points, dtype=np.float64)
    tree = cKDTree(points)
    tol = TOL.zero * float(np.ptp(points, axis=0).max())
    tour = np.array(tour, dtype=np.int64)
    moves, work = 0, 0
    while True:
        ring = points[tour]
        longest = float(np.linalg.norm(np.roll(ring, -1, axis=0) - ring, axis=1).max())
        radius = 2.0 * longest * (1.0 + 1e-9)
        pairs = np.ascontiguousarray(tree.query_pairs(radius, output_type="ndarray"),
                                     dtype=np.int64)
        if len(pairs) == 0:
            return tour
        moves, work, more = _two_opt_moves(points, tour, pairs, radius, tol, moves, 10 * n,
                                           work, TWO_OPT_WORK)
        if not more:
            return tour


@numba.njit(cache=True, nogil=True)
def _two_opt_moves(points, tour, pairs, radius, tol, moves, max_moves, work, max_work):
    """Best-improvement 2-opt moves on ``tour`` (in place) among the candidate ``pairs``
    found within ``radius``, until none shortens the tour by more than ``tol``, the
    move or work budget is spent, or the longest edge outgrows the candidates
    (``2·longest > radius``: returns ``more = True`` for new pairs).  Returns
    ``(moves, work, more)``.  The arithmetic of the array form before it (edge lengths
    ``sqrt(dx² + dy²)``, gains ``|ac| + |bd| − |ab| − |cd|`` in that order, the first
    of equal gains in pair order), so the same moves."""
    n = len(tour)
    edge = np.empty(n)
    pos = np.empty(n, np.int64)
    while moves < max_moves:
        if work > max_work:
            return moves, work, False
        longest = 0.0
        for k in range(n):
            a, b = tour[k], tour[(k + 1) % n]
            dx, dy = points[b, 0] - points[a, 0], points[b, 1] - points[a, 1]
            edge[k] = math.sqrt(dx * dx + dy * dy)
            longest = max(longest, edge[k])
        if 2.0 * longest > radius:
            return moves, work, True
        for k in range(n):
            pos[tour[k]] = k
        best, best_i, best_j, found = np.inf, -1, -1, False
        for p in range(len(pairs)):
            i, j = pos[pairs[p, 0]], pos[pairs[p, 1]]
            if i > j:
                i, j = j, i
            if j - i < 2 or (i == 0 and j == n - 1):
                continue
            found = True
            a, b, c, d = tour[i], tour[(i + 1) % n], tour[j], tour[(j + 1) % n]
            dx, dy = points[a, 0] - points[c, 0], points[a, 1] - points[c, 1]
            ex, ey = points[b, 0] - points[d, 0], points[b, 1] - points[d, 1]
            gain = math.sqrt(dx * dx + dy * dy) + math.sqrt(ex * ex + ey * ey) - edge[i] \
                - edge[j]
            if gain < best:
                best, best_i, best_j = gain, i, j
        if not found:
            return moves, work, False
        work += len(pairs)
        if best >= -tol:
            return moves, work, False
        tour[best_i + 1:best_j + 1] = tour[best_i + 1:best_j + 1][::-1].copy()
        moves += 1
    return moves, work, False


def _centre_tour(centres: np.ndarray, theta_order: np.ndarray, cell: float) -> np.ndarray:
    """A short closed tour through the centres (θ order or MST walk, then 2-opt)."""
    n = len(centres)
    tour = theta_order
    ring = centres[tour]
    if np.linalg.norm(np.roll(ring, -1, axis=0) - ring, axis=1).max() > 3.0 * cell:
        # θ order jumps (a fold): try a depth-first walk of the minimum spanning tree
        tree = _centre_mst(centres)
        walk = _tree_walk(n, tree.row, tree.col, int(theta_order[0]))
        if len(walk) == n and _tour_length(centres, walk) < _tour_length(centres, tour):
            tour = walk
    return _two_opt(centres, np.asarray(tour))


def _centre_mst(centres: np.ndarray):
    """Minimum spanning tree of the complete graph on the centres (sparse, edges i < j).

    The Euclidean MST lies in the Delaunay graph (an MST edge has no other point
    in its closed diametral disk), so the tree is taken over the Delaunay edges,
    ``O(n log n)`` instead of sorting all ``n²`` pairs.  The edges keep the
    complete graph's weights, orientation (row < column) and row-major order,
    so Kruskal's stable tie-breaking, and hence the tree and any walk of it,
    are the complete graph's.  Near-coincident or collinear centres take the
    complete graph, its upper triangle (each lower twin would come after its upper
    one in Kruskal's order and close a cycle).  Until 2026-12-06 that fallback went
    through scipy's dense-matrix input, which drops weights within 1e-8 of zero
    (absolute), so coincident centres lost their edge at any scene scale; here every
    pair keeps its floored length.
    """
    n = len(centres)
    tree = None
    try:
        tri = Delaunay(centres)
    except (QhullError, ValueError):  # collinear or too few centres
        tri = None
    if tri is not None and len(tri.coplanar) == 0:
        indptr, neighbours = tri.vertex_neighbor_vertices
        rows = np.repeat(np.arange(n), np.diff(indptr))
        once = rows < neighbours
        a, b = rows[once], neighbours[once]
        length = np.linalg.norm(centres[a] - centres[b], axis=1)
        # the complete graph floors lengths at TOL.zero x its diameter (<= the box diagonal)
        floor = TOL.zero * max(float(np.linalg.norm(np.ptp(centres, axis=0))), TOL.zero)
        if length.min() > floor:
            tree = _spanning_tree(n, a, b, length)
    if tree is None:   # the complete graph's upper triangle: scipy's tree of the full matrix
        dist = np.linalg.norm(centres[:, None, :] - centres[None, :, :], axis=2)
        a, b = np.triu_indices(n, 1)
        tree = _spanning_tree(n, a, b, np.maximum(dist, TOL.zero * max(dist.max(), TOL.zero))[a, b])
    return tree


def _is_star(ring_rel: np.ndarray, cell: float) -> bool:
    """θ increases along the counter-clockwise tour, up to folds below two cells.

    The winding number about the centroid must be one, and θ may never fall
    back from its running maximum by more than the angle ``2·cell/R`` that two
    grid cells subtend at radius R (grid jitter, not a fold of the curve).
    """
    phi = np.arctan2(ring_rel[:, 1], ring_rel[:, 0])
    dphi = np.mod(np.diff(np.append(phi, phi[0])) + np.pi, 2 * np.pi) - np.pi
    if round(dphi.sum() / (2 * np.pi)) != 1:
        return False
    unwrapped = np.concatenate([[0.0], np.cumsum(dphi)[:-1]])
    # start the running maximum at the tour's smallest unwrapped θ; the vertices
    # before it in the tour come after it, one turn later
    start = int(np.argmin(unwrapped))
    unwrapped = np.roll(unwrapped, -start)
    unwrapped[len(unwrapped) - start :] += 2 * np.pi
    radius = np.maximum(np.roll(np.hypot(ring_rel[:, 0], ring_rel[:, 1]), -start), TOL.zero)
    fall = np.maximum.accumulate(unwrapped) - unwrapped
    return bool(np.all(fall <= 2.0 * cell / radius))


#: θ orders two points a gap g apart along a curve crossing the rays from the centroid
#: at angle α when their angular step g sin α / R exceeds this many times their angular
#: noise σ cos α / R (:func:`_theta_resolves`).
THETA_NOISE_RATIO = 3.0
#: Consecutive tour centres where θ does not resolve the order that make a loop
#: ordered along its tour instead (one or two are grid jitter).
THETA_RUN = 3


def _theta_resolves(ring_rel: np.ndarray, sigma: float, gap: float) -> bool:
    """Whether θ orders the points of a star-shaped tour despite their noise.

    Where the curve runs nearly along the rays from the centroid (the sides of
    a long thin lobe: a handle's section merging with a wall), consecutive
    points differ in θ by ``g sin α / R`` while noise σ across the curve moves
    them by ``σ cos α / R``: θ scrambles their order when
    ``tan α < THETA_NOISE_RATIO σ / g`` (measured: the amphora's handle lobe,
    α ≈ 5°, ordered by θ zig-zagged along its sides and shrank its ring by half
    its width).  α is taken at every centre from the chord of its two tour
    neighbours; a run of :data:`THETA_RUN` failing centres decides.
    """
    if sigma <= 0 or gap <= 0 or len(ring_rel) < 2 * THETA_RUN:
        return True
    chord = np.roll(ring_rel, -1, axis=0) - np.roll(ring_rel, 1, axis=0)       # (n, 2)
    cross = np.abs(chord[:, 0] * ring_rel[:, 1] - chord[:, 1] * ring_rel[:, 0])
    dot = np.abs(np.einsum("ij,ij->i", chord, ring_rel))
    fails = cross * gap < THETA_NOISE_RATIO * sigma * dot
    if not fails.any():
        return True
    if fails.all():
        return False
    run = np.roll(fails, -int(np.argmin(fails)))       # start at a centre that passes
    edges = np.diff(np.concatenate([[0], run.astype(np.int8), [0]]))
    return int((np.flatnonzero(edges == -1) - np.flatnonzero(edges == 1)).max()) < THETA_RUN


def _order_loop(uv: np.ndarray, cell: float, link: float, sigma: float = 0.0,
                gap: float = 0.0):
    """Ordering ``(M,)`` of a loop's points, star-shaped flag and closed flag.

    ``sigma`` and ``gap`` (the noise σ̂ and the mean gap g) let
    :func:`_theta_resolves` veto the θ order where the noise scrambles it.
    """
    centre = uv.mean(axis=0)
    rel = uv - centre
    theta = np.mod(np.arctan2(rel[:, 1], rel[:, 0]), 2 * np.pi)
    centres = _grid_centres(uv, cell)
    if len(centres) < 4:
        return _from_theta_min(np.argsort(theta, kind="stable"), theta), True, True
    c_rel = centres - centre
    c_theta = np.mod(np.arctan2(c_rel[:, 1], c_rel[:, 0]), 2 * np.pi)
    tour = _centre_tour(centres, np.argsort(c_theta, kind="stable"), cell)
    ring = centres[tour]
    x, y = ring[:, 0], ring[:, 1]
    if np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y) < 0:
        tour, ring = tour[::-1], ring[::-1]
    edge = np.linalg.norm(np.roll(ring, -1, axis=0) - ring, axis=1)
    closed = bool(edge.max() <= link)
    star = _is_star(ring - centre, cell) and _theta_resolves(ring - centre, sigma, gap)
    if star:
        order = np.argsort(theta, kind="stable")
    else:
        order = np.argsort(_polyline_parameter(uv, ring, edge), kind="stable")
    return _from_theta_min(order, theta), star, closed


def _polyline_parameter(uv: np.ndarray, ring: np.ndarray, edge: np.ndarray) -> np.ndarray:
    """Arc length ``(M,)`` of each point's foot on the closed polyline ``ring``."""
    n = len(ring)
    cum = np.concatenate([[0.0], np.cumsum(edge)[:-1]])
    _, nearest = cKDTree(ring).query(uv)
    best_s = np.zeros(len(uv))
    best_d = np.full(len(uv), np.inf)
    for seg in ((nearest - 1) % n, nearest):  # the two edges at the nearest vertex
        a, b = ring[seg], ring[(seg + 1) % n]
        ab = b - a
        t = np.clip(np.einsum("mi,mi->m", uv - a, ab) / np.maximum(edge[seg] ** 2, TOL.zero), 0, 1)
        d = np.linalg.norm(a + t[:, None] * ab - uv, axis=1)
        better = d < best_d
        best_d = np.where(better, d, best_d)
        best_s = np.where(better, cum[seg] + t * edge[seg], best_s)
    return best_s


def _from_theta_min(order: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """Rotate a cyclic order so it starts at the point of smallest θ."""
    start = int(np.argmin(theta[order]))
    return np.roll(order, -start)


def _organise_loop(section, uv_all, members, gap, link, threshold, k, min_points):
    uv = uv_all[members]
    keep, sigma = _reject(uv, gap, threshold, k)
    kept, removed = members[keep], members[~keep]
    if len(kept) < min_points:
        return None
    uv_kept = uv_all[kept]
    if _is_collinear(uv_kept):
        return None
    diameter = float(np.ptp(uv_kept, axis=0).max())
    cell = max(3.0 * gap, 6.0 * sigma, diameter / 128.0, TOL.zero)
    order, star, closed = _order_loop(uv_kept, cell, link, sigma, gap)
    ordered = kept[order]
    centre_uv = uv_all[ordered].mean(axis=0)
    rel = uv_all[ordered] - centre_uv
    return Loop(
        centroid=section.to_world(centre_uv[None])[0],
        points=section.points[ordered],
        theta=np.mod(np.arctan2(rel[:, 1], rel[:, 0]), 2 * np.pi),
        radius=np.hypot(rel[:, 0], rel[:, 1]),
        star_shaped=star,
        outliers=np.sort(removed).astype(np.int64),
        indices=ordered.astype(np.int64),
        frame=section.frame,
        height=section.height,
        section_id=section.section_id,
        closed=closed,
        noise=sigma,
        bridge=_bridge_length(section.points[ordered], link),
    )


def _bridge_length(points: np.ndarray, link: float) -> float:
    """``Loop.bridge`` of the ordered loop ``points``: ``min(ℓ, 2·(ln M + 6)·h)``."""
    step = np.linalg.norm(np.roll(points, -1, axis=0) - points, axis=1)
    local = _DENSITY_RATIO * float(np.median(step)) * (math.log(len(points)) + _SPLIT_LOG_ODDS)
    return float(min(link, local))
