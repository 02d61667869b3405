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

* **Loops** (here, over :mod:`surface.section_trees`): the section's Euclidean minimum
  spanning tree cut at edges longer than the link distance ``ℓ = 2·(ln M + 6)·g``,
  ``g = median(MST edge)/ln 2`` the mean gap along a curve; components under
  ``min_points`` points are outliers; both faces of a thin wall parted
  (:mod:`surface.wall_faces`).
* **Outliers** (:mod:`surface.loop_outliers`): a quadratic fitted to each point's ``k``
  nearest neighbours (batched); an outlier when ``|r| > max(threshold·σ̂, g/2)``, σ̂ the
  MAD scale; two passes.
* **Order** (:mod:`surface.loop_order`): grid-cell centres (``h = max(3 g, 6 σ̂,
  D/128)``) joined by a closed tour improved by 2-opt; θ order where the loop is
  star-shaped about C, else the arc length of each point's foot on the tour (the
  nearest-neighbour chain).
* **Degenerate sections**: a section thinner than ``TOL.planar_rel`` times its
  diameter across its principal direction encloses no area and is skipped.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial import cKDTree

from surface.loop_order import _order_loop
from surface.loop_outliers import _reject
from surface.section_trees import _components, _is_closed_loop, _mst
from surface.sections import Section, SectionSkippedWarning
from surface.validate import TOL, check_finite
from surface.wall_faces import _face_split, _wall_splits

__all__ = ["Loop", "SectionSkippedWarning", "organise", "organise_all"]

#: ln(1/p) for a false split probability p ≈ 0.25 % of a loop by the link distance.
_SPLIT_LOG_ODDS = 6.0

#: Density variation along a loop that the link distance tolerates.
_DENSITY_RATIO = 2.0

#: Longest MST edges tried as bridges between two closed loops.
_SPLIT_TRIES = 2


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
