"""The one-sided rule: whether sections' loops are open arcs over much of their length.

:func:`open_share` is the share of the loops' length that goes round nothing: the length
across their gaps (the closed rings' ``surface.reconstruct.bridged_share``) plus every
loop that is a thin line traced there and back (its path more than :data:`DOUBLED_PATH`
times its points' spine, the longest path of their minimum spanning tree, and thinner
than :data:`LINE_BAND` σ of its noise).  :func:`one_sided`: above the closed rings'
``MAX_BRIDGED_SHARE`` the surface is open (``surface.open_surface``).  :func:`loop_arc`
cuts a loop into the arc it is: at its longest step (the unseen side), or along its
spine when it is such a line.  The rule's figures: ``docs/decisions/open-surfaces.md``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy import sparse
from scipy.sparse import csgraph
from scipy.spatial import cKDTree

from surface.polygon import polygon_area
from surface.reconstruct import MAX_BRIDGED_SHARE
from surface.validate import TOL

__all__ = ["DOUBLED_PATH", "LINE_BAND", "loop_arc", "open_share", "one_sided"]


#: A loop whose path is longer than this many times its points' spine went along them
#: and back: a thin, noisy line (a flat board seen edge-on in a section, a facade's wall)
#: is traced as a closed loop round it.  Once along an arc the path is about the spine's
#: length (noise adds a little); there and back, twice it: halfway between.
DOUBLED_PATH = 1.5


#: Neighbours per point in the graph whose minimum spanning tree gives the spine.
_SPINE_NEIGHBOURS = 12


def _spine_order(points: np.ndarray) -> tuple[np.ndarray, float]:
    """The points' order along their spine and its length: the geodesic distance, in the
    minimum spanning tree of their neighbour graph (k nearest plus the loop's own steps,
    which keep it connected), from one end of the tree's longest path."""
    m = len(points)
    k = min(_SPINE_NEIGHBOURS, m - 1)
    dist, near = cKDTree(points).query(points, k=k + 1)
    rows = np.concatenate([np.repeat(np.arange(m), k), np.arange(m)])
    cols = np.concatenate([near[:, 1:].ravel(), np.roll(np.arange(m), -1)])
    weight = np.concatenate([dist[:, 1:].ravel(),
                             np.linalg.norm(np.roll(points, -1, axis=0) - points, axis=1)])
    weight = np.maximum(weight, TOL.zero)   # coincident points: an edge, not a missing one
    graph = sparse.coo_matrix((weight, (rows, cols)), shape=(m, m)).tocsr()
    tree = csgraph.minimum_spanning_tree(graph)
    end = int(np.argmax(csgraph.dijkstra(tree, directed=False, indices=0)))
    along = csgraph.dijkstra(tree, directed=False, indices=end)
    return np.argsort(along, kind="stable"), float(along.max())


def loop_arc(loop) -> np.ndarray:
    """The ordered points ``(M, 3)`` of a ``surface.topology.Loop`` as an open arc.

    The loop's cyclic order is cut at its longest step (the unseen side) and the arc
    runs from the point after it to the point before it, keeping the loop's
    counter-clockwise direction.  A loop that went along its points and back (its path
    more than :data:`DOUBLED_PATH` times its spine: a thin noisy line) is instead
    ordered along its spine (:func:`_spine_order`), in the direction of its cut order.
    """
    pts = np.asarray(loop.points, dtype=np.float64)
    step = np.linalg.norm(np.roll(pts, -1, axis=0) - pts, axis=1)
    arc = np.roll(pts, -(int(np.argmax(step)) + 1), axis=0)
    if len(arc) < 4:
        return arc
    path = float(np.sort(step)[:-1].sum())     # the loop without its cut step
    order, spine = _spine_order(arc)
    if path <= DOUBLED_PATH * spine:
        return arc
    if order[0] > order[-1]:                    # keep the cut order's direction
        order = order[::-1]
    return arc[order]


#: Thickness (enclosed area over spine length) below which a loop traced along its
#: points and back is a line, in units of the loop's own noise ``Loop.noise``: a noisy
#: line's points scatter over a band of ±2σ across it, so a loop round them encloses at
#: most about 4σ of thickness; a thin closed object seen all round (two sides) is thicker
#: than its noise band, or its two sides could not be told apart.
LINE_BAND = 4.0


def _is_line(loop) -> bool:
    """Whether a closed-looking loop is a thin line traced there and back: its path more
    than :data:`DOUBLED_PATH` times its spine, and thinner than :data:`LINE_BAND` σ."""
    pts = np.asarray(loop.points, np.float64)
    if len(pts) < 4:
        return False
    step = np.linalg.norm(np.roll(pts, -1, axis=0) - pts, axis=1)
    spine = _spine_order(pts)[1]
    if not float(step.sum() - step.max()) > DOUBLED_PATH * spine:
        return False
    area = polygon_area((pts - pts.mean(axis=0)) @ np.asarray(loop.frame)[:2].T)
    return area / max(spine, TOL.zero) < LINE_BAND * float(getattr(loop, "noise", 0.0))


def open_share(loops: Sequence) -> float:
    """Share of the loops' length that does not go round anything: across their gaps
    (``surface.reconstruct.bridged_share``'s steps longer than ``Loop.bridge``) or along
    a loop that is a line traced there and back (:func:`_is_line`; a flat board, a wall
    or a relief cut by a section is a noisy line, which the loop tracer closes by going
    along it and back).  0 for sections that go round the object."""
    across = total = 0.0
    for section_loops in loops:
        for loop in section_loops:
            pts = np.asarray(loop.points, np.float64)
            step = np.linalg.norm(np.roll(pts, -1, axis=0) - pts, axis=1)
            length = float(step.sum())
            gaps = float(step[step > loop.bridge].sum())
            total += length
            across += length if _is_line(loop) else gaps
    return across / total if total > 0 else 0.0


def one_sided(loops: Sequence) -> bool:
    """True when the loops are open over much of their length: :func:`open_share`
    exceeds ``surface.reconstruct.MAX_BRIDGED_SHARE`` (the share of gaps at which the
    closed rings are refused).  One rule from the sections alone, whatever the cameras:
    a stereo pair, a ring of views over a relief, a one-sided folder (a facade)."""

    return open_share(list(loops)) > MAX_BRIDGED_SHARE
