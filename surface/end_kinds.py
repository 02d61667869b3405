r"""What each end of the sections is: a cap the data cover, a hole, or a vessel's mouth.

:func:`classify_ends` gives one :class:`EndKind` per end, used by every path (the
stitched mesh from points, the pipeline's stitch stage, the sized surface): ``none`` (a
cap the data cover), ``hole`` (the data do not cover the end's inside: filled flat, or
left open with ``open_holes``) or ``mouth`` (a cavity's opening: the rim annulus capped
and the inside open where the wall's two faces are parted; the outer surface only, open,
where the wall is too thin to part, :data:`THIN_RIM`).  The rules and their measurements:
``docs/decisions/ends-and-mouths.md``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from checks.robust import mad_sigma
from surface.loop_graph import nesting
from surface.polygon import inside_polygon, polygon_area
from surface.sections import point_spacing
from surface.stitch import (
    CAP_SHRINK,
    HOLE_SHARE,
    _scaled,
    end_window,
    uncovered_share,
)

__all__ = ["EndKind", "MOUTH_COLUMNS", "MOUTH_COLUMN_RADIUS", "MOUTH_MARGIN", "MOUTH_SHEET_GAP",
           "THIN_RIM", "classify_ends", "outer_loops"]


@dataclass(frozen=True)
class EndKind:
    """What one end of the sections is (:func:`classify_ends`), with the evidence.

    ``kind`` is ``"none"`` (a cap the data cover: closed at the cap points), ``"hole"``
    (the data do not cover the end's inside: closed by the flattest fill, or left as a
    border with ``open_holes``) or ``"mouth"`` (the opening of a cavity: ``parted``, the
    end holds both faces of the wall as nested loops and the annulus between them is the
    rim, capped, the inside open through the inner loop; else the wall is too thin for
    the sections to part and the end is left open, the outer surface only; ``thin``: so
    is a parted rim narrower than :data:`THIN_RIM` over a deep cavity).  ``uncovered``:
    the share of the end's inside beyond reach of every cap point; ``even_columns``: the
    share of axis columns from inside a hole end that meet an even number of the cloud's
    sheets (counted only for a hole with one loop); ``wall``: the wall's thickness at the
    end in point spacings (a parted rim's mean width, or 1.35 robust σ of a single band's
    points about its ring); ``sigma``: that robust σ, scene units."""

    end: str
    kind: str
    uncovered: float
    parted: bool = False
    thin: bool = False
    even_columns: float | None = None
    wall: float | None = None
    sigma: float | None = None
    note: str | None = None

    def closed(self, open_holes: bool = False) -> bool:
        """Whether the stitch caps this end (a parted mouth's rim annulus is capped)."""
        if self.kind == "mouth":
            return self.parted and not self.thin
        return not (self.kind == "hole" and open_holes)

    @property
    def outer_only(self) -> bool:
        """The sections' inner loops are to be dropped (:func:`outer_loops`): a parted rim
        too thin to part everywhere."""
        return self.kind == "mouth" and self.parted and self.thin

    def record(self) -> dict:
        """The classification and its evidence as JSON-ready values (the note left out)."""
        return {"kind": self.kind, "uncovered": round(self.uncovered, 4),
                "parted": self.parted, "thin": self.thin or not self.closed(),
                **({"even_columns": round(self.even_columns, 4)}
                   if self.even_columns is not None else {}),
                **({"wall_spacings": round(self.wall, 3)} if self.wall is not None else {}),
                **({"band_sigma": self.sigma} if self.sigma is not None else {})}


def classify_ends(rings: list, frame: np.ndarray, cap_points: np.ndarray, spacing: float,
                  points: np.ndarray | None = None,
                  open_holes: bool = False) -> tuple[EndKind, EndKind]:
    """The one classification of the first and the last section's end, used by every path
    (``surface_from_points``, the pipeline's stitch stage, the sized surface).

    An end is a **hole** when, for one of its outermost loops, more than
    ``stitch.HOLE_SHARE`` of the region inside it (shrunk by ``stitch.CAP_SHRINK``, the
    wall's own points kept out) and outside its inner loops is farther than
    ``stitch.COVER_RADIUS`` point spacings from every cap point of the end's window
    (``stitch.end_window``: beyond the end, from two section spacings inside):
    ``stitch.uncovered_share``.  A cap seen by the scanner, flat or domed, covers its
    contour; a bust cut at the chest, an animal's unseen base or the mouth of a wall too
    thin to part do not.  A hole end with one loop is a **mouth** on a wall too thin to
    part when most axis columns from inside it meet an even number of the cloud's sheets
    (:func:`_even_columns`: the cavity's floor, then the base; an unseen base meets an
    odd number).  An end whose outer loop holds inner loops and whose annulus is covered
    is a parted **mouth** (the rim of a wall seen from both sides; the can's rim above
    its recessed lid too).  Judged on the sections' own end loops: an extended end ring
    may drift off the data.

    Parameters
    ----------
    rings : list
        One entry per section (an ``(n, 3)`` array or a list of them), along the axis.
    frame : (3, 3) float64
        Section frame (rows e1, e2, axis).
    cap_points : (C, 3) float64
        The cloud's cap points (``SlicedCloud.cap_cloud``).
    spacing : float
        Section spacing.
    points : (P, 3) float64, optional
        The whole cloud: without it no sheet is counted (a hole stays a hole) and no wall
        is measured.
    open_holes : bool
        Only the hole notes' wording: the hole is left open, or capped flat.

    Returns
    -------
    (EndKind, EndKind)
        The bottom and the top end.
    """
    cap_points = np.asarray(cap_points, np.float64).reshape(-1, 3)
    heights = cap_points @ frame[2]
    flat_all = cap_points @ frame[:2].T
    cloud = None if points is None else np.asarray(points, np.float64).reshape(-1, 3)
    nu = [None]

    def point_gap() -> float:    # the cloud's point spacing, once
        if nu[0] is None:
            nu[0] = point_spacing(cloud)
        return nu[0]

    kinds = []
    for end, up in ((0, False), (-1, True)):
        name = "bottom" if end == 0 else "top"
        loops = [rings[end]] if isinstance(rings[end], np.ndarray) else list(rings[end])
        flats = [lp @ frame[:2].T for lp in loops]
        height = float(np.mean(np.concatenate([lp @ frame[2] for lp in loops])))
        lo, hi = end_window(height, up, spacing)
        flat = flat_all[(heights > lo) & (heights < hi)]
        depth, parent = nesting(flats)
        share, parted, rim, cavity = 0.0, False, [], 0.0
        for k in np.flatnonzero(depth == 0):
            children = np.flatnonzero(parent == k)
            parted |= len(children) > 0
            inner = [_scaled(flats[j], 1.0 / CAP_SHRINK) for j in children]
            outer = _scaled(flats[k], CAP_SHRINK)
            for j in children:   # the inside of an inner face: a cavity deeper than the window
                cavity = max(cavity, uncovered_share(_scaled(flats[j], CAP_SHRINK), [], flat))
            if len(children):   # the rim's mean width: area between the faces / mean length
                length = _perimeter(flats[k]) + sum(_perimeter(flats[j]) for j in children)
                rim.append(2.0 * (polygon_area(flats[k]) - sum(
                    polygon_area(flats[j]) for j in children)) / max(length, 1e-300))
            if polygon_area(outer) <= sum(polygon_area(ring) for ring in inner):
                continue    # a rim narrower than the margins: no inside to be a hole
            share = max(share, uncovered_share(outer, inner, flat))
        if share > HOLE_SHARE:
            kinds.append(_hole_or_thin_mouth(name, share, loops, frame, height, up, spacing,
                                             cloud, point_gap, open_holes))
        elif parted:
            wall = float(np.median(rim)) / point_gap() if cloud is not None else None
            thin = wall is not None and wall < THIN_RIM and cavity > HOLE_SHARE
            kinds.append(EndKind(
                name, "mouth", share, parted=True, thin=thin, wall=wall,
                note=f"{name}: an open mouth on a wall too thin for the data to resolve "
                     f"(~{wall:.1f} point spacings thick, under the {THIN_RIM:g} a wall's "
                     "faces need to be parted in every section): left open, the outer "
                     "surface only" if thin else None))
        else:
            kinds.append(EndKind(name, "none", share))
    return kinds[0], kinds[1]


#: Narrowest rim, in point spacings (``EndKind.wall`` of a parted end), of a wall whose
#: faces are built both: the faces of a pot's wall (``testkit/cup.py``, 60 000 points,
#: noise 0.1 s) are parted in every section at 2 s, with and without a handle, but not at
#: 1 s where a handle joins the wall (sections there dropped as joined nested contours:
#: 3 pieces, 27 % of the mesh over the mouth).  Midway between the rims measured there:
#: 0.95-0.98 s at 1 s, 1.80-1.82 s at 2 s (the fitted rings run a little inside the faces).
#: Below it, over a cavity deeper than the cap window, the end is a thin mouth: the outer
#: surface only.  A can's rim over its recessed lid (cap points inside) is never one.
THIN_RIM = 1.4


def outer_loops(rings: list, frame: np.ndarray) -> list:
    """``rings`` (one entry per section: an ``(n, 3)`` ring or a list of them) with every
    loop that lies inside another of its section dropped: the outer surface of a wall too
    thin to build both faces of (``EndKind.outer_only``)."""
    kept = []
    for entry in rings:
        if isinstance(entry, np.ndarray) or len(entry) < 2:
            kept.append(entry)
            continue
        depth, _ = nesting([lp @ frame[:2].T for lp in entry])
        outer = [lp for lp, d in zip(entry, depth, strict=True) if d == 0]
        kept.append(outer[0] if len(outer) == 1 else outer)
    return kept


def _perimeter(ring: np.ndarray) -> float:
    return float(np.linalg.norm(ring - np.roll(ring, -1, axis=0), axis=1).sum())


def _hole_or_thin_mouth(name, share, loops, frame, height, up, spacing, cloud, point_gap,
                        open_holes) -> EndKind:
    """A hole end (:func:`classify_ends`): a mouth on a wall too thin to part when it has
    one loop and most columns from inside it meet an even number of sheets (more than half
    by :data:`MOUTH_MARGIN` binomial standard errors of a fair share, 0.5/√columns); its
    note."""
    if cloud is not None and len(loops) == 1:
        even, columns = _even_columns(loops[0], frame, cloud, height, up, spacing,
                                      point_gap())
        if even is not None and even > 0.5 + MOUTH_MARGIN * 0.5 / np.sqrt(columns):
            sigma = _band_sigma(loops[0], frame, cloud, height, spacing)
            wall = 1.35 * sigma / point_gap()
            return EndKind(name, "mouth", share, even_columns=even, wall=wall, sigma=sigma,
                           note=f"{name}: an open mouth on a wall too thin for the data to "
                                f"resolve (~{wall:.1f} point spacings thick, its two faces one "
                                "band of points): left open, the outer surface only")
    else:
        even = None
    return EndKind(name, "hole", share, even_columns=even,
                   note=f"{name}: a hole in the data ({100 * share:.0f} % of the end out of "
                        "reach of every point): "
                        + ("left open, a border where the data end" if open_holes else
                           "closed by the flattest fill within the data's heights (open = "
                           "true leaves it open)"))


#: Columns along the axis inside an end's contour that :func:`_even_columns` counts the
#: cloud's sheets in (a grid over the contour shrunk by ``CAP_SHRINK``, at most this many).
MOUTH_COLUMNS = 64


#: Radius of a column, in point spacings: ~12 points of a sheet crossing it.
MOUTH_COLUMN_RADIUS = 2.0


#: Gap between consecutive heights in a column, in section spacings, that parts two
#: sheets: within one sheet crossing at up to ~80° from the plane the heights of the
#: ~12 points step by ~2 point spacings (1 section spacing); a floor and a base, or a
#: head's top and its chin, lie farther apart than the 3 sections a cap needs anyway.
MOUTH_SHEET_GAP = 3.0


#: Binomial standard errors by which the even columns' share must exceed one half for a
#: mouth: a share a fair coin gives as often is no evidence.  A pot's mouth at 0.25-0.5
#: point spacings (``testkit/cup.py``, 20 000 points, with and without a handle) gives
#: 0.85-1.0 of 46-64 columns (3.4-4 errors above); the temple ring's unseen base, whose
#: columns meet the plinth's top and then the entablature's, 0.51 (0.1 errors).
MOUTH_MARGIN = 3.0


def _even_columns(ring: np.ndarray, frame: np.ndarray, points: np.ndarray, h_end: float,
                  up: bool, spacing: float, nu: float) -> tuple[float | None, int]:
    """Share of the columns inside an end's single loop that meet an even number of the
    cloud's sheets below it (``up``: the top end) or above it, and the number of columns
    that meet one; (None, 0) when none does.

    From a point just inside a mouth the axis runs through the cavity, meets its floor
    and then the object's base: an even number of sheets, the point is outside the
    solid.  From an unseen base (a bust cut at the chest) it runs through the solid to
    the surface beyond: an odd number.  Up to :data:`MOUTH_COLUMNS` columns of radius
    :data:`MOUTH_COLUMN_RADIUS` point spacings ``nu`` on a grid inside the loop shrunk by
    ``CAP_SHRINK``; heights parted at gaps of :data:`MOUTH_SHEET_GAP` section spacings.
    """
    contour = _scaled(np.asarray(ring) @ frame[:2].T, CAP_SHRINK)
    lo, hi = contour.min(axis=0), contour.max(axis=0)
    step = float(np.sqrt(np.prod(hi - lo) / MOUTH_COLUMNS))
    if not step > 0:
        return None, 0
    gx, gy = np.meshgrid(np.arange(lo[0], hi[0], step), np.arange(lo[1], hi[1], step))
    grid = np.column_stack([gx.ravel(), gy.ravel()])
    grid = grid[inside_polygon(grid, contour)]
    if len(grid) == 0:
        return None, 0
    heights = points @ frame[2]
    tree = cKDTree(points @ frame[:2].T)
    parity = []
    for column in tree.query_ball_point(grid, MOUTH_COLUMN_RADIUS * nu):
        h = heights[column]
        h = np.sort(h[h < h_end] if up else h[h > h_end])
        if len(h):
            parity.append(1 + int(np.count_nonzero(np.diff(h) > MOUTH_SHEET_GAP * spacing)))
    if not parity:
        return None, 0
    return float(np.mean(np.array(parity) % 2 == 0)), len(parity)


def _band_sigma(ring: np.ndarray, frame: np.ndarray, points: np.ndarray, h_end: float,
                spacing: float) -> float:
    """Robust σ (1.4826 MAD) of the cloud's points within a section spacing of an end's
    height about the end's ring, across it in the plane: a wall's two faces ±a about
    their midline give 1.48 a, so 2a ≈ 1.35 σ̂ (the noise adds to it: an upper bound)."""
    flat_ring = np.asarray(ring) @ frame[:2].T
    near = points[np.abs(points @ frame[2] - h_end) < spacing] @ frame[:2].T
    if len(near) < 3 or len(flat_ring) < 3:
        return 0.0
    tangent = np.roll(flat_ring, -1, axis=0) - np.roll(flat_ring, 1, axis=0)
    normal = np.column_stack([tangent[:, 1], -tangent[:, 0]])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
    distance, nearest = cKDTree(flat_ring).query(near)
    mine = distance < 2.0 * spacing   # the end's own wall, not another part at its height
    offset = np.einsum("ij,ij->i", near[mine] - flat_ring[nearest[mine]],
                       normal[nearest[mine]])
    if len(offset) < 3:
        return 0.0
    return float(mad_sigma(offset))
