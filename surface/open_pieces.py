"""A section's loops to one open arc, and the sections' sheet (``surface.open_surface``).

:func:`chain_arcs` chains a section's pieces that continue one another (the gap along
both end tangents within :data:`CONTINUATION_ANGLE`); :func:`height_field_arc` makes one
depth per position across the cameras' view (runs nearest first, what a nearer run hides
dropped); :func:`bridge_open_gaps` puts points along a wide gap's chord;
:func:`main_piece` keeps the sections' largest connected piece (points within
:data:`PIECE_REACH` section spacings linked); :func:`organise_arcs` is the closed path's
organisation of the sections without its closed-ring refusals.  The rules' figures:
``docs/decisions/open-surfaces.md``.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import replace

import numpy as np
from scipy import sparse
from scipy.sparse import csgraph
from scipy.spatial import cKDTree

from surface.catmull_rom import bridge_gaps
from surface.reconstruct import _drop_one_section_splits
from surface.topology import SectionSkippedWarning, organise
from surface.validate import TOL

__all__ = ["CONTINUATION_ANGLE", "PIECE_REACH", "STEP_SIGMAS", "chain_arcs", "height_field_arc",
           "depth_steps", "bridge_open_gaps", "main_piece", "organise_arcs"]


#: Largest angle between an arc's end tangent and the gap to the next piece for the
#: piece to continue the arc (a window, an unmatched patch): the stitch's sharp-turn
#: angle (``surface.stitch.SHARP_TURN``, 30°); a piece off to the side is another surface.
CONTINUATION_ANGLE = np.pi / 6


#: Points at each end of a piece its end tangent is taken over (a chord: noise averaged).
_TANGENT_POINTS = 8


def _end(arc: np.ndarray, last: bool, reach: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """An arc's end point and unit tangent pointing out of it: the chord from the end to
    the point ``reach`` along the arc from it (at least :data:`_TANGENT_POINTS` points
    in, at most the whole arc) -- directions compared at the scale of the gap they
    bridge, so a short noisy piece is judged by its whole chord, not by its last few
    points' noise."""
    ordered = arc[::-1] if last else arc
    along = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(ordered, axis=0),
                                                            axis=1))])
    k = max(min(_TANGENT_POINTS, len(arc) - 1), int(np.searchsorted(along, reach)))
    k = min(k, len(arc) - 1)
    a, b = ordered[k], ordered[0]
    direction = b - a
    return b, direction / max(float(np.linalg.norm(direction)), TOL.zero)


def _length(arc: np.ndarray) -> float:
    return float(np.linalg.norm(np.diff(arc, axis=0), axis=1).sum())


def chain_arcs(arcs: Sequence[np.ndarray]) -> tuple[np.ndarray, int]:
    """One section's arcs chained into one where they continue one another.

    Starting from the longest, a piece joins an end of the chain when the gap to it runs
    along the chain's end tangent and along the piece's own end tangent (both within
    :data:`CONTINUATION_ANGLE`) and is no longer than the longer of the two: a facade's
    wall between windows, an arc broken where the matcher found nothing.  Pieces off to
    the side (another layer, another object) are left out.

    Parameters
    ----------
    arcs : sequence of (M_i, 3) float64
        Ordered points of each piece (:func:`loop_arc`).

    Returns
    -------
    arc : (M, 3) float64
        The chain, in the longest piece's direction.
    used : int
        Pieces in it.
    """
    pieces = sorted((np.asarray(a, np.float64) for a in arcs), key=_length, reverse=True)
    chain, rest = pieces[0], [p for p in pieces[1:] if len(p) >= 2]
    cos_max = np.cos(CONTINUATION_ANGLE)
    used, joined = 1, True
    while rest and joined:
        joined = False
        for i, piece in enumerate(rest):
            for at_end in (True, False):
                tip = chain[-1] if at_end else chain[0]
                for flip in (False, True):
                    cand = piece[::-1] if flip else piece
                    # the piece's end facing the chain: its first point when appended
                    near = cand[0] if at_end else cand[-1]
                    gap = near - tip
                    dist = float(np.linalg.norm(gap))
                    if dist <= TOL.zero or dist > max(_length(chain), _length(cand)):
                        continue
                    out = _end(chain, at_end, dist)[1]
                    into = _end(cand, not at_end, dist)[1]
                    along = gap / dist
                    if along @ out >= cos_max and -along @ into >= cos_max:
                        chain = np.concatenate([chain, cand] if at_end else [cand, chain])
                        del rest[i]
                        used, joined = used + 1, True
                        break
                if joined:
                    break
            if joined:
                break
    return chain, used


def _runs_between_gaps(arc: np.ndarray, link: float) -> list[np.ndarray]:
    """An ordered arc cut at its steps longer than ``link`` (``Loop.bridge``: missing
    data), into the runs of points between them."""
    step = np.linalg.norm(np.diff(arc, axis=0), axis=1)
    return np.split(arc, np.flatnonzero(step > link) + 1)


def height_field_arc(arcs: Sequence[np.ndarray], across: np.ndarray, view: np.ndarray
                     ) -> tuple[np.ndarray, int]:
    """One section's arcs as one height field over the direction ``across`` (in the
    section plane, across the cameras' view ``view``): what cameras on one side see of a
    section is one depth at each position across their view, the nearest.

    The pieces are taken nearest first (their median depth along ``view``), each without
    its points within the range across the view of the pieces already taken (a wall
    behind a board, behind a tree: what they hide is dropped, what shows beside them is
    kept); the runs left are turned to run along ``+across`` and joined in order along
    it; the gaps between them (windows, plain stone where the matcher found nothing) are
    bridged by the fit's chords (:func:`bridge_open_gaps`).

    Returns
    -------
    arc : (M, 3) float64
    used : int
        Runs in it.
    """
    pieces = [np.asarray(a, np.float64) for a in arcs if len(a) >= 2]
    view = np.asarray(view, np.float64) / np.linalg.norm(view)
    taken: list[tuple[float, float]] = []
    runs: list[np.ndarray] = []
    for i in np.argsort([float(np.median(p @ view)) for p in pieces], kind="stable"):
        piece = pieces[i]
        coord = piece @ across
        free = np.ones(len(piece), bool)
        for lo, hi in taken:
            free &= ~((coord >= lo) & (coord <= hi))
        index = np.flatnonzero(free)
        for part in np.split(index, np.flatnonzero(np.diff(index) > 1) + 1):
            if len(part) < 2:
                continue
            c = coord[part]
            runs.append(piece[part] if c[-1] >= c[0] else piece[part][::-1])
            taken.append((float(c.min()), float(c.max())))
    if not runs:
        return pieces[0], 1
    runs.sort(key=lambda r: float(np.mean(r @ across)))
    return np.concatenate(runs), len(runs)


#: A depth step is a jump between neighbours along a section of more than this many σ of
#: their difference (σ√2, σ the points' own): 6 of them is not noise (two-sided p ≈ 2·10⁻⁹
#: a pair; a section has a few hundred pairs).
STEP_SIGMAS = 6.0


def depth_steps(arc: np.ndarray, across: np.ndarray, centres: np.ndarray, noise: np.ndarray
                ) -> np.ndarray:
    """Where an ordered height-field arc steps in depth: indices ``i`` (``(S,)`` int64)
    with points ``i`` and ``i + 1`` an occlusion edge apart.

    The rays from the cameras' ``centres`` ``(K, 3)`` to the arc's median point are
    within β of their mean direction ``v`` (``|mean of the unit rays|`` = cos β, the
    spread of the cameras seen from the object).  A face between two neighbours steeper
    than ``cot β`` (depth along ``v`` over the distance along ``across``) lies within β
    of the rays: the cameras on its far side see its back, so not all of them see it (an
    occlusion edge, or a face no pair matched); the jump must also exceed
    :data:`STEP_SIGMAS` σ√2 (``noise``: each point's σ, ``(M,)``).  One camera, or cameras
    that see the arc along one ray, see no step."""
    arc = np.asarray(arc, np.float64)
    rays = np.median(arc, axis=0) - np.asarray(centres, np.float64).reshape(-1, 3)
    view = np.mean(rays / np.linalg.norm(rays, axis=1)[:, None], axis=0)
    cos_beta = float(np.linalg.norm(view))
    if len(arc) < 2 or cos_beta >= 1.0 - TOL.angle:
        return np.zeros(0, np.int64)
    slope = cos_beta / np.sqrt(1.0 - cos_beta**2)                  # cot β
    step = np.diff(arc, axis=0)
    depth = np.abs(step @ (view / cos_beta))
    side = np.abs(step @ np.asarray(across, np.float64))
    sigma = np.maximum(noise[:-1], noise[1:])
    return np.flatnonzero((depth > STEP_SIGMAS * np.sqrt(2.0) * sigma) & (depth > slope * side))


def bridge_open_gaps(arc: np.ndarray, link: float) -> np.ndarray:
    """An open arc with straight chords across its wide gaps, as the closed rings'
    (``surface.catmull_rom.bridge_gaps``, without the wrap: an open arc's ends are where
    the data end): a step longer than ``link`` (the loop's expected largest step,
    ``topology.Loop.bridge``) and than ``catmull_rom.BRIDGE_SHARE`` of the arc's length
    gets points along its chord every median step before the fit.

    Over a wide gap the fit's fairness continues the arc's bend from both sides: on the
    chessboard pair 03 a board section's curve bulged 1.6 squares off the board across a
    3.5-square gap (white squares and the matcher's holes), where the data lie within
    0.27 of it."""

    return bridge_gaps(arc, link, closed=False)


#: Reach, in section spacings, within which points of the sections are one piece
#: (:func:`main_piece`): a strip joins sections one spacing apart, and along a section
#: the arcs are chained across gaps, so a point within one spacing over and one along
#: belongs to the same sheet; two spacings.
PIECE_REACH = 2.0


def main_piece(sections, spacing: float) -> tuple[list, str | None]:
    """The sections' points in the largest connected piece of all of them (points within
    :data:`PIECE_REACH` section spacings linked), the others left out.

    An open surface is one sheet (:func:`align_arcs` keeps one run of arcs); a stereo
    pair's cloud holds the scene -- on the chessboard rig the board and, apart from it,
    a keyboard, a monitor, the wall -- whose pieces break every section into arcs of
    several objects.  The largest piece is the object the pair was aimed at.

    Returns
    -------
    sections : list of Section
        The same sections with the points of the largest piece (some may be empty).
    note : str or None
        What was left out.
    """

    sizes = [len(s) for s in sections]
    if sum(sizes) == 0:
        return list(sections), None
    points = np.concatenate([np.asarray(s.points, np.float64).reshape(-1, 3)
                             for s in sections])
    tree = cKDTree(points)
    pairs = tree.query_pairs(PIECE_REACH * spacing, output_type="ndarray")
    graph = sparse.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])),
                              shape=(len(points), len(points)))
    count, label = csgraph.connected_components(graph, directed=False)
    if count == 1:
        return list(sections), None
    size = np.bincount(label)
    keep = label == int(np.argmax(size))
    offsets = np.concatenate([[0], np.cumsum(sizes)])
    out = []
    for k, section in enumerate(sections):
        mine = keep[offsets[k]:offsets[k + 1]]
        index = np.asarray(section.source_index)
        out.append(replace(section, points=np.asarray(section.points)[mine],
                           source_index=index[mine] if len(index) == len(mine) else index))
    return out, (f"{int((~keep).sum())} of {len(points)} section points in {count - 1} "
                 f"piece(s) apart from the largest ({int(keep.sum())} points, within "
                 f"{PIECE_REACH:g} section spacings) left out: one sheet is made")


def organise_arcs(sections, drop_splits: bool = True, **organise_options
                  ) -> tuple[list, list, list[str]]:
    """The loops of every non-empty section, open arcs kept (``surface.topology.organise``).

    ``surface.reconstruct.organise_sections`` without its refusal of open arcs and
    without the loop-graph repairs (an open surface follows one arc per section); inner
    sections with more loops than both neighbours (which agree) are dropped, as there.

    Returns
    -------
    kept : list of Section
    loops : list of list of Loop
    messages : list of str
        Skipped sections.
    """


    kept, loops, messages = [], [], []
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", SectionSkippedWarning)
        for section in sections:
            found = organise(section, **organise_options) if len(section) else []
            if found:
                kept.append(section)
                loops.append(found)
    messages += [str(w.message) for w in caught if issubclass(w.category,
                                                              SectionSkippedWarning)]
    # a section broken into more loops than both its neighbours (a gap in the data there)
    # is skipped as the closed path skips it: its largest piece would notch the surface
    # (not for a height field, which takes every piece: ``drop_splits`` False)
    kept, loops, notes = _drop_one_section_splits(kept, loops) if drop_splits else \
        (kept, loops, [])
    return kept, loops, messages + notes
