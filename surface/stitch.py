r"""Delaunay-stitched triangle mesh from closed section rings.

Between two adjacent sections, odd points :math:`o_k` at
:math:`\theta = 2\pi k/N` and even points :math:`e_j` at
:math:`\theta = \pi j/N`, the *direction criterion* of the paper builds

.. math::

    (o_k, e_{2k}, e_{2k+1}),\quad (o_k, e_{2k+1}, o_{k+1}),\quad
    (o_{k+1}, e_{2k+1}, e_{2k+2}),\qquad k = 0, \dots, N-1.

Generalised to any two ring sizes it is a merge by angle: walking both rings
counter-clockwise, the next triangle advances the ring whose next point comes
first (on a tie the coarser ring first, which reproduces the three triangles
above for N↔2N and a regular diagonal for N↔N).  Each ring of :math:`n_a` and
:math:`n_b` points gives exactly :math:`n_a + n_b` triangles.

The strip is then improved by Lawson's flips [1]_ (the local Delaunay criterion
:math:`\angle acb + \angle adb > \pi`), never across a section contour, never to an
existing edge, never turning a face normal by more than ``max_normal_change``; in
sweeps, one numba kernel (:func:`_lawson`).  End caps are an ear-clipping
triangulation (mapbox ``earcut``) of the end contours followed by the same flips: the
constrained Delaunay triangulation of the contour.

All faces are counter-clockwise seen from outside: the side normal
:math:`(a_{i+1} - a_i) \times (b_j - a_i)` points away from the axis when the
rings run counter-clockwise about the axis and ``b`` lies above ``a``; the
bottom cap faces :math:`-\mathbf{axis}`, the top cap :math:`+\mathbf{axis}`.

Support rings (``stitch_rings(..., support_sigma=σ̂)``, the default of
:func:`surface.reconstruct.surface_from_points` and of the pipeline): Loop's G1 surface
passes a corner of the control polygon with turn α and legs h at
:math:`|P_{-1} + P_1 - 2P_0|/6 = h\sin(\alpha/2)/3` from it.  Where the section profile
turns by more than ``SHARP_TURN`` and that rounding exceeds the points' noise σ̂, a
support ring is added on each leg at :math:`d = 3\hat\sigma/\sin(\alpha/2)`
(:func:`support_distance`), so the rounding falls to σ̂; inside a cap's support ring
come a guard ring (:data:`CAP_GUARD_RINGS`) and a quality triangulation of the plane,
so the patches there read only cap-plane vertices and are exactly flat.  The supports
lie on the stitched polyhedron: only the smooth surface changes.  Why supports and not
an exact crease rule (Hoppe et al. 1994 [3]_; DeRose et al. 1998 [4]_), with the
figures: ``docs/method/stitching.md``, "Support rings".

References
----------
.. [1] C. L. Lawson, "Software for C1 surface interpolation", in Mathematical
   Software III, Academic Press (1977), 161-194.
.. [2] The paper's section-to-section direction criterion (DESIGN.md,
   "Stitching").
.. [3] H. Hoppe, T. DeRose, T. Duchamp, M. Halstead, H. Jin, J. McDonald,
   J. Schweitzer, W. Stuetzle, "Piecewise smooth surface reconstruction",
   SIGGRAPH 1994, 295-302.
.. [4] T. DeRose, M. Kass, T. Truong, "Subdivision surfaces in character
   animation", SIGGRAPH 1998, 85-94.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numba
import numpy as np
from scipy.spatial import cKDTree

from surface._blas import one_blas_thread
from surface.loop_graph import LoopGraph, loop_graph, nesting
from surface.metrics import delaunay_fraction, edge_table, mesh_topology
from surface.polygon import INSIDE_PAIRS
from surface.polygon import inside_polygon as _inside
from surface.validate import TOL, check_finite, check_shape

__all__ = ["StitchResult", "stitch_rings", "zip_rings", "cap_triangles", "delaunay_flips",
           "axis_frame", "support_distance"]

#: Default largest turn of a face normal a flip may cause (radians).  A flip on
#: a smooth patch re-triangulates it and turns normals by about the local
#: dihedral angle; 45° is far above that and far below a fold-over (90°+).
MAX_NORMAL_CHANGE = np.pi / 4


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


# --------------------------------------------------------------------------- frames and parameters
def axis_frame(axis: np.ndarray) -> np.ndarray:
    """Right-handed orthonormal frame ``(3, 3)``, rows ``e1, e2, axis/|axis|``."""
    a = check_shape(axis, "(3,)", "axis", dtype=np.float64)
    check_finite(a, "axis")
    norm = float(np.linalg.norm(a))
    if norm <= TOL.zero:
        raise ValueError(f"axis must have non-zero length, got {a.tolist()}")
    a = a / norm
    helper = np.eye(3)[int(np.argmin(np.abs(a)))]
    e1 = np.cross(helper, a)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(a, e1)
    return np.stack([e1, e2, a])


def _ring_order_and_parameter(ring2d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Counter-clockwise order and absolute merge parameter of one planar ring.

    Parameters
    ----------
    ring2d : (n, 2) float64
        Ring points in the section plane's (e1, e2) coordinates.

    Returns
    -------
    order : (n,) int64
        Index permutation making the ring counter-clockwise, ``order[0] == 0``.
    param : (n,) float64
        Increasing parameter of ``ring2d[order]``, in turns: the polar angle
        about the ring centroid over 2π when the ring is star-shaped about it,
        otherwise the normalised arc length, both offset by the angle of the
        first point so that rings are aligned by direction.
    """
    n = len(ring2d)
    x, y = ring2d[:, 0], ring2d[:, 1]
    twice_area = float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))
    order = np.arange(n)
    if twice_area < 0:
        order = np.concatenate([[0], np.arange(n - 1, 0, -1)])
    pts = ring2d[order]
    centre = pts.mean(axis=0)
    theta = np.arctan2(pts[:, 1] - centre[1], pts[:, 0] - centre[0])
    step = np.mod(np.diff(theta), 2 * np.pi)
    star = bool(np.all(step > TOL.angle)) and float(step.sum()) < 2 * np.pi
    if star:
        relative = np.concatenate([[0.0], np.cumsum(step)]) / (2 * np.pi)
    else:
        chord = np.linalg.norm(np.diff(np.vstack([pts, pts[:1]]), axis=0), axis=1)
        relative = np.concatenate([[0.0], np.cumsum(chord[:-1])]) / chord.sum()
    return order, theta[0] / (2 * np.pi) + relative


# --------------------------------------------------------------------------- side strips
def zip_rings(param_lower: np.ndarray, param_upper: np.ndarray) -> np.ndarray:
    """Triangulate the strip between two closed rings by merging their parameters.

    Parameters
    ----------
    param_lower : (n_a,) float64
        Increasing angular parameter (in turns) of the lower ring, counter-
        clockwise about the axis; its span is less than one turn.
    param_upper : (n_b,) float64
        The same for the upper ring, in the same angular frame.

    Returns
    -------
    (n_a + n_b, 3) int64
        Faces over local indices: lower ring ``0 .. n_a - 1``, upper ring
        ``n_a .. n_a + n_b - 1``; outward (away from the axis) when the rings
        run counter-clockwise and the upper ring lies further along the axis.

    Notes
    -----
    The upper ring is started at its point closest in angle to the lower
    ring's first point; every later step adds the triangle that advances the
    ring whose next point comes first.  Ties (within ``TOL.angle``) advance the
    coarser ring first: for ``n_b = 2 n_a`` this is exactly the paper's
    (o_k, e_2k, e_2k+1), (o_k, e_2k+1, o_k+1), (o_k+1, e_2k+1, e_2k+2).
    """
    n_a, n_b = len(param_lower), len(param_upper)
    u_a = param_lower - param_lower[0]
    rel_b = np.mod(param_upper - param_lower[0], 1.0)
    start = int(np.argmin(np.minimum(rel_b, 1.0 - rel_b)))
    index_b = np.roll(np.arange(n_b), -start)
    u_b = np.mod(param_upper[index_b] - param_lower[0], 1.0)
    u_b = u_b[0] - 1.0 * (u_b[0] > 0.5) + np.concatenate(
        [[0.0], np.cumsum(np.mod(np.diff(u_b), 1.0))])
    # Events: each ring's points 1..n and its closing step back to point 0.
    ev_a = np.append(u_a[1:], 1.0)
    ev_b = np.append(u_b[1:], u_b[0] + 1.0)
    tie = TOL.angle / (2 * np.pi)
    bias_a = tie if n_a <= n_b else 0.0  # the coarser (or the lower, if equal) goes first
    bias_b = 0.0 if n_a <= n_b else tie
    keys = np.concatenate([ev_a - bias_a, ev_b - bias_b])
    is_a = np.concatenate([np.ones(n_a, bool), np.zeros(n_b, bool)])
    order = np.argsort(keys, kind="stable")
    is_a = is_a[order]
    i_a = np.cumsum(is_a) - is_a        # lower-ring position before each event
    i_b = np.cumsum(~is_a) - ~is_a      # upper-ring position before each event
    a0 = i_a % n_a
    a1 = (i_a + 1) % n_a
    b0 = n_a + index_b[i_b % n_b]
    b1 = n_a + index_b[(i_b + 1) % n_b]
    return np.where(is_a[:, None],
                    np.stack([a0, a1, b0], axis=1),
                    np.stack([a0, b1, b0], axis=1)).astype(np.int64)


def _nested_angles(lower: np.ndarray, upper: np.ndarray) -> tuple | None:
    """Both counter-clockwise rings' angles (in turns) about the inner one's centroid,
    when one lies inside the other and both are star-shaped about that point; else None.

    A branch's loop inside its bridged sub-loop (a horn in a head's outline) is tiled by
    these angles (:func:`zip_rings`): the shortest-span tiling between a small dense loop
    and a large sparse one fans the small loop to one far point and the large one to a
    few points behind it, and the fans cross (the noisy cow's horn: 68 pairs).
    """
    def area(ring):
        return float(np.sum(ring[:, 0] * np.roll(ring[:, 1], -1)
                            - np.roll(ring[:, 0], -1) * ring[:, 1]))
    inner, outer = (lower, upper) if area(lower) < area(upper) else (upper, lower)
    if not _inside(inner, outer).all():
        return None
    centre = inner.mean(axis=0)
    params = []
    for ring in (lower, upper):
        theta = np.arctan2(ring[:, 1] - centre[1], ring[:, 0] - centre[0])
        step = np.mod(np.diff(theta), 2 * np.pi)
        if not (np.all(step > TOL.angle) and float(step.sum()) < 2 * np.pi):
            return None
        params.append(theta[0] / (2 * np.pi)
                      + np.concatenate([[0.0], np.cumsum(step)]) / (2 * np.pi))
    return params[0], params[1]


def _star_shaped(ring2d: np.ndarray) -> bool:
    """Whether a counter-clockwise ring's polar angle about its centroid increases.

    The test :func:`_ring_order_and_parameter` makes before taking the angle as
    the ring's parameter (otherwise it falls back to the arc length).
    """
    theta = np.arctan2(ring2d[:, 1] - ring2d[:, 1].mean(), ring2d[:, 0] - ring2d[:, 0].mean())
    step = np.mod(np.diff(theta), 2 * np.pi)
    return bool(np.all(step > TOL.angle)) and float(step.sum()) < 2 * np.pi


MIN_SPAN_STARTS = 4
"""Start pairs :func:`tile_min_span` tries, spread evenly round the lower ring."""
MIN_SPAN_TIE = 1e-9
"""Relative shortening another start's tiling needs to replace the closest pair's: the
same tiling from another start sums its spans in another order (rounding)."""


@numba.njit(cache=True, nogil=True)
def _min_span_moves(a: np.ndarray, b: np.ndarray, a2: np.ndarray, b2: np.ndarray,
                    side_a: np.ndarray, side_b: np.ndarray,
                    penalty: float) -> np.ndarray:  # pragma: no cover - numba
    """Moves of the shortest monotone path through the span lengths ``|a_i - b_j|``.

    ``D[i, j] = |a_(i mod n) - b_(j mod m)| + min(D[i-1, j] + p_a, D[i, j-1] + p_b)`` from
    ``(0, 0)`` to ``(n, m)``; returns ``n + m`` moves, 1 advancing ``a``, 0 ``b``.  The
    move's triangle pays ``penalty`` where, in the plan ``a2``, ``b2``, its third vertex
    lies on the wrong side of its ring edge (``side_a[i]``, ``side_b[j]``: the sign the
    cross product of edge ``i -> i+1`` and the other ring's vertex should have; 0: any).
    """
    n, m = a.shape[0], b.shape[0]
    cost = np.full((n + 1, m + 1), np.inf)
    came_a = np.zeros((n + 1, m + 1), np.bool_)
    cost[0, 0] = 0.0
    for i in range(n + 1):
        for j in range(m + 1):
            if i == 0 and j == 0:
                continue
            d = 0.0
            for k in range(3):
                d += (a[i % n, k] - b[j % m, k]) ** 2
            d = np.sqrt(d)
            from_a = np.inf
            if i > 0:
                from_a = cost[i - 1, j]
                p, q, r = a2[(i - 1) % n], a2[i % n], b2[j % m]
                o = (q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0])
                if o * side_a[(i - 1) % n] < 0.0:
                    from_a += penalty
            from_b = np.inf
            if j > 0:
                from_b = cost[i, j - 1]
                p, q, r = b2[(j - 1) % m], b2[j % m], a2[i % n]
                o = (q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0])
                if o * side_b[(j - 1) % m] < 0.0:
                    from_b += penalty
            came_a[i, j] = from_a <= from_b
            cost[i, j] = d + min(from_a, from_b)
    moves = np.empty(n + m, np.bool_)
    i, j = n, m
    for step in range(n + m - 1, -1, -1):
        moves[step] = came_a[i, j]
        if came_a[i, j]:
            i -= 1
        else:
            j -= 1
    return moves


def _edge_sides(ring2d: np.ndarray, other2d: np.ndarray) -> np.ndarray:
    """``(n,)`` the sign the plan cross product of ``ring2d``'s edge ``i -> i+1`` and a
    vertex of ``other2d`` tiled to it should have: towards the side where the other ring
    lies near that edge (its nearest point to the edge's midpoint inside or outside
    ``ring2d``), so that the strip's faces cover the plan between the rings once; 0 for
    a degenerate ring."""
    area2 = float(np.sum(ring2d[:, 0] * np.roll(ring2d[:, 1], -1)
                         - np.roll(ring2d[:, 0], -1) * ring2d[:, 1]))
    if len(ring2d) < 3 or len(other2d) < 3 or area2 == 0.0:
        return np.zeros(len(ring2d))
    mid = 0.5 * (ring2d + np.roll(ring2d, -1, axis=0))
    near = other2d[cKDTree(other2d).query(mid)[1]]
    inside = _inside(near, ring2d)
    return np.where(inside, 1.0, -1.0) * np.sign(area2)


def tile_min_span(lower: np.ndarray, upper: np.ndarray,
                  axis: np.ndarray | None = None) -> np.ndarray:
    """Triangulate the strip between two closed rings by the shortest total span.

    The optimal tiling of Fuchs, Kedem and Uselton (1977) [5]_ as a shortest
    path in the toroidal graph of spans (edges from a lower to an upper ring
    point), here with the sum of the spans' lengths as the cost (the
    "shortest diagonal" criterion of Christiansen and Sederberg 1978, made
    global by dynamic programming): O(n_a n_b), started at the closest pair of
    points.  Used where a ring is not star-shaped about its centroid (a
    branch's bump on a wall): there the angle is no parameter, and the arc
    length fraction of two rings whose bumps differ in size drifts, twisting
    the strip across the wall (the mug's and amphora's handle joins).

    With the ``axis``, a face whose third vertex lies, in the plan, on the side of its
    ring edge away from the other ring (there: :func:`_edge_sides`) costs more than any
    tiling without one: the strip then covers the plan between the rings once where it
    can.  A ring with a narrow spike the other lacks was fanned from one point over both
    sides of the spike, the far side's faces folded over the near side's (the temple
    ring's top: 179 crossing pairs).

    Parameters
    ----------
    lower, upper : (n_a, 3), (n_b, 3) float64
        The rings, both counter-clockwise about the axis, ``upper`` further
        along it.
    axis : (3,) float64, optional
        The section normal (the plan is the plane across it).  Without it, span
        lengths alone.

    Returns
    -------
    (n_a + n_b, 3) int64
        Faces over local indices as :func:`zip_rings`'s (lower ``0 .. n_a - 1``,
        upper ``n_a ..``), oriented the same way.

    References
    ----------
    .. [5] H. Fuchs, Z. M. Kedem, S. P. Uselton, "Optimal surface
       reconstruction from planar contours", Communications of the ACM 20
       (1977), 693-702.
    """
    lower = np.asarray(lower, np.float64)
    upper = np.asarray(upper, np.float64)
    n_a = len(lower)
    gap, nearest = cKDTree(upper).query(lower)
    i0 = int(np.argmin(gap))
    # The path is forced through its start pair.  The closest pair can sit at a pinch
    # (a spur's or a stick's root, where one ring enters the spur as the other leaves
    # it): through it, one ring's whole spur fans to one point of the other and the two
    # fans overlap.  So the path is also started at the nearest pairs a quarter, a half
    # and three quarters round the lower ring, and the shortest of the four is kept (the
    # closest pair's unless another is shorter beyond rounding).
    plan_a, plan_b = np.zeros((n_a, 2)), np.zeros((len(upper), 2))
    side_a, side_b, penalty = np.zeros(n_a), np.zeros(len(upper)), 0.0
    if axis is not None:
        frame = axis_frame(np.asarray(axis, np.float64))
        plan_a, plan_b = lower @ frame[:2].T, upper @ frame[:2].T
    # only between rings that do not cross in the plan: one lies wholly inside the
    # other, the side is the same along each ring (where they cross, the sides change
    # along the rings, and the nearest point's side misjudged a hook's: 58 new pairs)
    if axis is not None and not loops_cross([plan_a, plan_b]):
        side_a, side_b = _edge_sides(plan_a, plan_b), _edge_sides(plan_b, plan_a)
        both = np.vstack([lower, upper])
        # more than any tiling's whole span: fewer wrong-sided faces always win
        penalty = float((len(both) + 1) * np.linalg.norm(np.ptp(both, axis=0)))
    plan = (plan_a, plan_b, side_a, side_b, penalty)
    best = None
    for k in range(MIN_SPAN_STARTS):
        i_s = (i0 + (k * n_a) // MIN_SPAN_STARTS) % n_a
        if k and i_s == best[0]:
            continue
        tiling = _min_span_from(lower, upper, i_s, int(nearest[i_s]), plan)
        if best is None or tiling[1] < best[2] * (1.0 - MIN_SPAN_TIE):
            best = (i_s, *tiling)
    return best[1]


def _min_span_from(lower: np.ndarray, upper: np.ndarray, i0: int, j0: int,
                   plan: tuple) -> tuple:
    """:func:`tile_min_span`'s faces for the path started at the pair ``(i0, j0)``, and
    the path's total span length plus its wrong-sided faces' penalties (``plan``: the
    rings in the plan, their edges' sides and the penalty)."""
    n_a, n_b = len(lower), len(upper)
    ia = (i0 + np.arange(n_a + 1)) % n_a
    jb = (j0 + np.arange(n_b + 1)) % n_b
    plan_a, plan_b, side_a, side_b, penalty = plan
    moves = _min_span_moves(lower[ia[:-1]], upper[jb[:-1]], plan_a[ia[:-1]], plan_b[jb[:-1]],
                            side_a[ia[:-1]], side_b[jb[:-1]], penalty)
    pos_a = np.concatenate([[0], np.cumsum(moves)])[:-1]      # before each move
    pos_b = np.concatenate([[0], np.cumsum(~moves)])[:-1]
    # (a position may reach n_a once a's moves are done: its "next" is then unused)
    a0, a1 = ia[np.minimum(pos_a, n_a)], ia[np.minimum(pos_a + 1, n_a)]
    b0, b1 = jb[np.minimum(pos_b, n_b)], jb[np.minimum(pos_b + 1, n_b)]
    # every span of the path once: the one each move ends on
    span = np.linalg.norm(lower[np.where(moves, a1, a0)] - upper[np.where(moves, b0, b1)],
                          axis=1).sum()
    faces = np.where(moves[:, None], np.stack([a0, a1, n_a + b0], axis=1),
                     np.stack([a0, n_a + b1, n_a + b0], axis=1)).astype(np.int64)
    if penalty > 0.0:
        p = np.where(moves[:, None, None], np.stack([plan_a[a0], plan_a[a1], plan_b[b0]], axis=1),
                     np.stack([plan_b[b0], plan_b[b1], plan_a[a0]], axis=1))
        o = ((p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1])
             - (p[:, 1, 1] - p[:, 0, 1]) * (p[:, 2, 0] - p[:, 0, 0]))
        span += penalty * np.count_nonzero(o * np.where(moves, side_a[a0], side_b[b0]) < 0.0)
    return faces, float(span)


# --------------------------------------------------------------------------- caps
def cap_triangles(ring2d: np.ndarray, outward_up: bool,
                  holes: Sequence[np.ndarray] = ()) -> np.ndarray:
    """Ear-clipping triangulation of a closed planar contour, with holes.

    Parameters
    ----------
    ring2d : (n, 2) float64
        Contour in the section plane's (e1, e2) coordinates (either winding).
    outward_up : bool
        Orient faces counter-clockwise in (e1, e2) (normal ``+axis``) if True,
        clockwise (normal ``-axis``) otherwise.
    holes : sequence of (n_h, 2) float64
        Contours inside ``ring2d`` bounding holes of the cap (an annulus for a
        rim between a wall's outer and inner loop).

    Returns
    -------
    (m, 3) int64
        Faces over ``0 .. n-1`` then each hole's points in turn;
        ``m == n + Σ n_h - 2 + 2 h`` for a simple polygon with h holes (fewer
        when earcut meets a self-intersecting contour).
    """
    import mapbox_earcut

    rings = [np.asarray(ring2d, np.float64)] + [np.asarray(h, np.float64) for h in holes]
    centre = rings[0].mean(axis=0)
    pts = np.ascontiguousarray(np.vstack(rings) - centre, dtype=np.float64)
    ends = np.cumsum([len(r) for r in rings]).astype(np.uint32)
    flat = mapbox_earcut.triangulate_float64(pts, ends)
    tri = np.asarray(flat, dtype=np.int64).reshape(-1, 3)
    if len(tri) == 0:
        return tri
    p = pts[tri]
    twice = ((p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1])
             - (p[:, 1, 1] - p[:, 0, 1]) * (p[:, 2, 0] - p[:, 0, 0]))
    flip = (twice < 0) if outward_up else (twice > 0)
    tri[flip] = tri[flip][:, ::-1]
    return tri


# --------------------------------------------------------------------------- Lawson flips
def _edge_keys(pairs: np.ndarray, n_vertices: int) -> np.ndarray:
    lo = np.minimum(pairs[:, 0], pairs[:, 1])
    hi = np.maximum(pairs[:, 0], pairs[:, 1])
    return lo * n_vertices + hi


#: Share of the flips' edge table (open addressing, linear probing) its keys may fill
#: before it is rebuilt larger (:func:`_lawson`).
EDGE_TABLE_LOAD = 0.5


@numba.njit(cache=True, nogil=True)
def _slot(table: np.ndarray, key: int) -> int:  # pragma: no cover - numba
    """Slot of ``key`` in the open-addressing table ``table`` (keys, -1 empty; a power
    of two long): where it is, or the empty slot where it goes (linear probing)."""
    mask = np.uint64(len(table) - 1)
    h = np.uint64(key) * np.uint64(0x9E3779B97F4A7C15)
    i = (h ^ (h >> np.uint64(29))) & mask
    while table[i] != key and table[i] != -1:
        i = (i + np.uint64(1)) & mask
    return np.int64(i)


@numba.njit(cache=True, nogil=True)
def _empty_table(size: int) -> tuple:  # pragma: no cover - numba
    """Keys (-1: empty) and counts of an edge table of at least ``2·size`` slots."""
    n = 16
    while n < 2 * size:
        n *= 2
    return np.full(n, -1, np.int64), np.zeros(n, np.int64)


@numba.njit(cache=True, nogil=True)
def _grown(table: np.ndarray, count: np.ndarray) -> tuple:  # pragma: no cover - numba
    """The table's edges of positive count in one of at least four slots a key:
    ``(keys, counts, keys held)``."""
    live = int(np.count_nonzero(count > 0))
    new_table, new_count = _empty_table(2 * live)
    for j in range(len(table)):
        if count[j] > 0:
            i = _slot(new_table, table[j])
            new_table[i], new_count[i] = table[j], count[j]
    return new_table, new_count, live


@numba.njit(cache=True, nogil=True)
def _half_edges(tri: np.ndarray, n_v: int) -> tuple:  # pragma: no cover - numba
    """The edge table of ``tri`` (each edge's key ``lo·V + hi`` with its count of faces)
    and ``opp``: half-edge ``3f + c`` (corner c to c + 1) -> the other half of its edge
    when the edge has exactly two faces, else -1."""
    n_h = 3 * tri.shape[0]
    table, count = _empty_table(n_h // 2 + 1)  # ~one edge per two half-edges
    first = np.empty(len(table), np.int64)
    opp = np.full(n_h, -1, np.int64)
    for h in range(n_h):
        a, b = tri[h // 3, h % 3], tri[h // 3, (h % 3 + 1) % 3]
        i = _slot(table, min(a, b) * n_v + max(a, b))
        if table[i] == -1:
            table[i], first[i] = min(a, b) * n_v + max(a, b), h
        count[i] += 1
        if count[i] == 2:
            opp[first[i]], opp[h] = h, first[i]
        elif count[i] == 3:
            opp[opp[first[i]]] = -1
            opp[first[i]] = -1
    return table, count, opp


@numba.njit(cache=True, nogil=True)
def _angle_at(v: np.ndarray, apex: int, a: int, b: int) -> float:  # pragma: no cover - numba
    """The angle at ``apex`` of the triangle ``(apex, a, b)``: ``atan2(|u x w|, u . w)``
    for ``u = a - apex``, ``w = b - apex`` (the operations, in their order, of the array
    form's ``np.cross``, ``np.linalg.norm`` and ``einsum``: the reference in
    ``tests/surface/test_stitch_flips.py`` gives the same flips bit for bit)."""
    u0, u1, u2 = v[a, 0] - v[apex, 0], v[a, 1] - v[apex, 1], v[a, 2] - v[apex, 2]
    w0, w1, w2 = v[b, 0] - v[apex, 0], v[b, 1] - v[apex, 1], v[b, 2] - v[apex, 2]
    c0, c1, c2 = u1 * w2 - u2 * w1, u2 * w0 - u0 * w2, u0 * w1 - u1 * w0
    return np.arctan2(np.sqrt(c0 * c0 + c1 * c1 + c2 * c2), u0 * w0 + u1 * w1 + u2 * w2)


@numba.njit(cache=True, nogil=True)
def _normal_of(v: np.ndarray, i: int, j: int, k: int) -> tuple:  # pragma: no cover - numba
    """``metrics.face_normals(..., unit=False)`` of the face ``(i, j, k)``."""
    a0, a1, a2 = v[j, 0] - v[i, 0], v[j, 1] - v[i, 1], v[j, 2] - v[i, 2]
    b0, b1, b2 = v[k, 0] - v[i, 0], v[k, 1] - v[i, 1], v[k, 2] - v[i, 2]
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@numba.njit(cache=True, nogil=True)
def _folds(v: np.ndarray, tri: np.ndarray, f1: int, f2: int, c: int, a: int, d: int, b: int,
           cos_limit: float, zero: float) -> bool:  # pragma: no cover - numba
    """Whether a new face ``(c, a, d)`` or ``(d, b, c)`` turns its unit normal beyond
    ``cos_limit`` from the area-weighted normal of the faces ``f1``, ``f2`` it replaces
    (the array form's operations: ``metrics.face_normals``)."""
    p0, p1, p2 = _normal_of(v, tri[f1, 0], tri[f1, 1], tri[f1, 2])
    q0, q1, q2 = _normal_of(v, tri[f2, 0], tri[f2, 1], tri[f2, 2])
    o0, o1, o2 = p0 + q0, p1 + q1, p2 + q2
    norm = max(np.sqrt(o0 * o0 + o1 * o1 + o2 * o2), zero)
    o0, o1, o2 = o0 / norm, o1 / norm, o2 / norm
    for i0, i1, i2 in ((c, a, d), (d, b, c)):
        n0, n1, n2 = _normal_of(v, i0, i1, i2)
        length = np.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
        if length > zero:
            n0, n1, n2 = n0 / length, n1 / length, n2 / length
        else:
            n0, n1, n2 = 0.0, 0.0, 0.0
        if not n0 * o0 + n1 * o1 + n2 * o2 > cos_limit:
            return True
    return False


@numba.njit(cache=True, nogil=True)
def _turns_over(v: np.ndarray, tri: np.ndarray, f1: int, f2: int, c: int, a: int, d: int,
                b: int, axis: np.ndarray) -> bool:  # pragma: no cover - numba
    """Whether a new face ``(c, a, d)`` or ``(d, b, c)`` faces the other way along
    ``axis`` than the faces ``f1``, ``f2`` it replaces, which face one way: seen along
    the axis the quad is not convex and the flip folds a height field over itself."""
    p0, p1, p2 = _normal_of(v, tri[f1, 0], tri[f1, 1], tri[f1, 2])
    q0, q1, q2 = _normal_of(v, tri[f2, 0], tri[f2, 1], tri[f2, 2])
    up_1 = p0 * axis[0] + p1 * axis[1] + p2 * axis[2]
    up_2 = q0 * axis[0] + q1 * axis[1] + q2 * axis[2]
    if not up_1 * up_2 > 0.0:
        return False      # the pair is not a height field over the plane (a wall)
    for i0, i1, i2 in ((c, a, d), (d, b, c)):
        n0, n1, n2 = _normal_of(v, i0, i1, i2)
        if not (n0 * axis[0] + n1 * axis[1] + n2 * axis[2]) * up_1 > 0.0:
            return True
    return False


@numba.njit(cache=True, nogil=True)
def _lawson(v: np.ndarray, tri: np.ndarray, region: np.ndarray, fixed: np.ndarray,
            plane: np.ndarray, axis: np.ndarray, cos_limit: float, angle_tol: float,
            zero: float, max_sweeps: int, max_load: float) -> tuple:  # pragma: no cover - numba
    """:func:`delaunay_flips`' sweeps on ``tri`` in place: ``(flips, converged)``.

    Each sweep (i) finds the interior edges (exactly two faces) of the active faces
    whose faces share a region, run opposite ways and are not ``fixed`` (sorted keys),
    whose opposite angles sum above ``π + angle_tol``, whose new edge does not exist yet
    nor, in a region ``>= 0``, joins two vertices of one ``plane`` label ``>= 0``, nor,
    in a region ``< 0`` with a non-zero ``axis``, turns a face of a pair facing one way
    along it the other way (:func:`_turns_over`), and whose new faces keep their normals
    within ``cos_limit`` of the pair's area-weighted normal, and orders them by their
    keys ``lo·V + hi``; (ii) takes a maximal set of them no two of which share a face,
    by rounds of "each face keeps its largest-excess candidate" (ranks by a stable sort
    of the excesses, so ties go by key), then the first flip of each new edge; (iii)
    applies it.  The next sweep examines the faces of every candidate; when none is left
    after a partial sweep a full one confirms.  The half-edge partners ``opp`` and the
    edges' face counts (an open-addressing table, rebuilt when its keys, removed edges
    included, fill ``max_load`` of it) are kept across flips.
    """
    n_f, n_v = tri.shape[0], v.shape[0]
    check_axis = axis[0] != 0.0 or axis[1] != 0.0 or axis[2] != 0.0
    table, count, opp = _half_edges(tri, n_v)
    filled = int(np.count_nonzero(table != -1))  # a removed edge keeps its slot, count 0
    active = np.arange(n_f)
    is_active = np.ones(n_f, np.bool_)
    full = True
    total = 0
    best = np.full(n_f, -1, np.int64)
    taken = np.zeros(n_f, np.bool_)
    for _ in range(max_sweeps):
        # (i) candidates: each edge of an active face once
        m = 3 * len(active)
        f1s = np.empty(m, np.int64)
        f2s = np.empty(m, np.int64)
        new = np.empty((m, 4), np.int64)   # c, a, d, b: (c, a, d) and (d, b, c)
        excess = np.empty(m)
        new_keys = np.empty(m, np.int64)
        keys = np.empty(m, np.int64)
        n_c = 0
        for f in active:
            for corner in range(3):
                h = 3 * f + corner
                o = opp[h]
                if o < 0 or (is_active[o // 3] and o < h):
                    continue   # no partner, or the edge is met from its first half
                h, o = min(h, o), max(h, o)
                f1, k1, f2, k2 = h // 3, h % 3, o // 3, o % 3
                a, b = tri[f1, k1], tri[f1, (k1 + 1) % 3]
                if region[f1] != region[f2] or tri[f2, k2] != b or tri[f2, (k2 + 1) % 3] != a:
                    continue
                key = min(a, b) * n_v + max(a, b)
                pos = np.searchsorted(fixed, key)
                if pos < len(fixed) and fixed[pos] == key:
                    continue
                c, d = tri[f1, (k1 + 2) % 3], tri[f2, (k2 + 2) % 3]
                ex = _angle_at(v, c, a, b) + _angle_at(v, d, b, a) - np.pi
                if not ex > angle_tol or c == d:
                    continue
                if region[f1] >= 0 and plane[c] >= 0 and plane[c] == plane[d]:
                    continue   # a chord of one section: a flat face in its plane
                new_key = min(c, d) * n_v + max(c, d)
                if count[_slot(table, new_key)] > 0 or _folds(v, tri, f1, f2, c, a, d, b,
                                                              cos_limit, zero):
                    continue
                if region[f1] < 0 and check_axis and _turns_over(v, tri, f1, f2, c, a, d,
                                                                 b, axis):
                    continue   # a cap is a height field over the plane: no fold in it
                f1s[n_c], f2s[n_c], excess[n_c] = f1, f2, ex
                new[n_c, 0], new[n_c, 1], new[n_c, 2], new[n_c, 3] = c, a, d, b
                new_keys[n_c], keys[n_c] = new_key, key
                n_c += 1
        for f in active:
            is_active[f] = False
        if n_c == 0:
            if full:
                return total, True
            active, full = np.arange(n_f), True  # confirm with a full sweep
            is_active[:] = True
            continue
        by_key = np.argsort(keys[:n_c])  # distinct keys: any sort is the one order
        f1s, f2s, new = f1s[by_key], f2s[by_key], new[by_key]
        excess, new_keys = excess[by_key], new_keys[by_key]
        # (ii) a maximal set no two of which share a face, then one flip per new edge
        rank = np.empty(n_c, np.int64)
        rank[np.argsort(excess, kind="mergesort")] = np.arange(n_c)
        alive = np.ones(n_c, np.bool_)
        chosen = np.empty(n_c, np.int64)
        n_chosen = 0
        n_alive = n_c
        while n_alive > 0:
            for t in range(n_c):
                if alive[t]:
                    best[f1s[t]] = max(best[f1s[t]], rank[t])
                    best[f2s[t]] = max(best[f2s[t]], rank[t])
            start = n_chosen
            for t in range(n_c):
                if alive[t] and best[f1s[t]] == rank[t] and best[f2s[t]] == rank[t]:
                    chosen[n_chosen] = t
                    n_chosen += 1
            for t in range(start, n_chosen):
                taken[f1s[chosen[t]]] = True
                taken[f2s[chosen[t]]] = True
            n_alive = 0
            for t in range(n_c):
                best[f1s[t]] = -1
                best[f2s[t]] = -1
                if alive[t] and (taken[f1s[t]] or taken[f2s[t]]):
                    alive[t] = False
                n_alive += alive[t]
        for t in chosen[:n_chosen]:
            # (iii) (a, b, c), (b, a, d) -> (c, a, d), (d, b, c), the outer halves'
            # partners re-pointed; a second flip to the same new edge is dropped
            i = _slot(table, new_keys[t])
            if count[i] > 0:
                continue
            f1, f2 = f1s[t], f2s[t]
            c, a, d, b = new[t, 0], new[t, 1], new[t, 2], new[t, 3]
            k1 = 0 if tri[f1, 0] == a else (1 if tri[f1, 1] == a else 2)
            k2 = 0 if tri[f2, 0] == b else (1 if tri[f2, 1] == b else 2)
            o_bc, o_ca = opp[3 * f1 + (k1 + 1) % 3], opp[3 * f1 + (k1 + 2) % 3]
            o_ad, o_db = opp[3 * f2 + (k2 + 1) % 3], opp[3 * f2 + (k2 + 2) % 3]
            tri[f1, 0], tri[f1, 1], tri[f1, 2] = c, a, d
            tri[f2, 0], tri[f2, 1], tri[f2, 2] = d, b, c
            for h, o in ((3 * f1, o_ca), (3 * f1 + 1, o_ad), (3 * f2, o_db), (3 * f2 + 1, o_bc)):
                opp[h] = o
                if o >= 0:
                    opp[o] = h
            opp[3 * f1 + 2], opp[3 * f2 + 2] = 3 * f2 + 2, 3 * f1 + 2
            count[_slot(table, min(a, b) * n_v + max(a, b))] = 0
            if table[i] == -1:
                if filled + 1 > max_load * len(table):
                    table, count, filled = _grown(table, count)
                    i = _slot(table, new_keys[t])
                table[i] = new_keys[t]
                filled += 1
            count[i] = 2
            total += 1
        for t in range(n_chosen):
            taken[f1s[chosen[t]]] = False
            taken[f2s[chosen[t]]] = False
        # the faces of every candidate are examined again
        for t in range(n_c):
            is_active[f1s[t]] = True
            is_active[f2s[t]] = True
        active, full = np.flatnonzero(is_active), False
    return total, False


def delaunay_flips(vertices: np.ndarray, triangles: np.ndarray, region: np.ndarray | None = None,
                   fixed_edges: np.ndarray | None = None,
                   max_normal_change: float = MAX_NORMAL_CHANGE,
                   max_sweeps: int = 1000,
                   plane: np.ndarray | None = None,
                   axis: np.ndarray | None = None) -> tuple[np.ndarray, int, bool]:
    """Lawson flips until every flippable interior edge is locally Delaunay.

    Parameters
    ----------
    vertices : (V, 3) float64
    triangles : (F, 3) int64
        Consistently oriented, edge-manifold faces.
    region : (F,) int, optional
        Only edges whose two faces share a region label may flip (a flip keeps
        both faces in that region).  Default: one region.
    fixed_edges : (C, 2) int, optional
        Constraint edges that never flip (section contours).
    max_normal_change : float
        Largest angle (radians) between a new face normal and the old pair's
        area-weighted normal; larger flips are refused as fold-overs.
    max_sweeps : int
        Upper bound on sweeps.  Every sweep flips, at once, a set of
        non-Delaunay edges no two of which share a face (for each face the
        candidate with the largest angle excess, repeated until the set is
        maximal).  After the first sweep only
        edges of faces changed by the previous sweep are examined (a flip can
        only spoil the four edges of its own quad); a last full sweep
        confirms the fixed point.

    plane : (V,) int, optional
        Each vertex's section (``-1``: none).  In a region ``>= 0`` (a strip between
        two rings) no flip makes an edge between two vertices of one section: that
        face would lie flat in the section's plane, and where the strips on both sides
        of a thin loop (a finger, a spike) both take such faces they overlap.
    axis : (3,) float64, optional
        The section normal.  In a region ``< 0`` (a cap: a height field over the section
        plane, flat or a dome) no flip turns a face of a pair that faces one way along
        the axis the other way: the quad is then not convex seen along the axis, and in
        3-D the flip is still within ``max_normal_change`` on a steep dome (the noisy
        teapot's lid: 43 of 14 044 cap faces turned over, crossing their neighbours).

    Returns
    -------
    triangles : (F, 3) int64
        The flipped faces (same count, same regions, same orientation).
    flips : int
        Number of flips applied.
    converged : bool
        False if ``max_sweeps`` was reached with flips still pending.
    """
    v = np.ascontiguousarray(vertices, dtype=np.float64)
    tri = np.array(triangles, dtype=np.int64, copy=True, order="C")
    reg = np.zeros(len(tri), np.int64) if region is None else \
        np.ascontiguousarray(region, dtype=np.int64)
    fixed = (np.zeros(0, np.int64) if fixed_edges is None or len(fixed_edges) == 0
             else np.unique(_edge_keys(np.asarray(fixed_edges, np.int64), len(v))))
    labels = (np.full(len(v), -1, np.int64) if plane is None
              else np.ascontiguousarray(plane, dtype=np.int64))
    up = np.zeros(3) if axis is None else np.asarray(axis, np.float64).reshape(3)
    total, converged = _lawson(v, tri, reg, fixed, labels, up,
                               float(np.cos(max_normal_change)), TOL.angle, TOL.zero,
                               max_sweeps, EDGE_TABLE_LOAD)
    return tri, int(total), bool(converged)


def _flippable_edges(triangles: np.ndarray, region: np.ndarray, fixed: np.ndarray,
                     n_vertices: int) -> np.ndarray:
    """``(E,)`` bool over ``edge_table(triangles).edges``: one region on both sides, no contour."""
    table = edge_table(triangles)
    slots = table.face_edge.ravel()
    face_region = np.repeat(region, 3)
    lo = np.full(len(table.edges), np.iinfo(np.int64).max)
    hi = np.full(len(table.edges), np.iinfo(np.int64).min)
    np.minimum.at(lo, slots, face_region)
    np.maximum.at(hi, slots, face_region)
    fixed_keys = np.unique(_edge_keys(fixed, n_vertices))
    return (lo == hi) & ~np.isin(_edge_keys(table.edges, n_vertices), fixed_keys)


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


# --------------------------------------------------------------------------- branch points
def _best_window(label: np.ndarray) -> tuple[int, int]:
    """The cyclic arc ``[i0, i1)`` (``i1`` may exceed n: it wraps) best matching ``label``.

    Minimises the disagreements ``#(not label in the arc) + #(label outside it)``:
    with ``g(i) = i - 2 S(i)`` (``S`` the prefix count of ``label``) a window
    ``[i0, i1)`` costs ``T + g(i1) - g(i0)``, minimised in one pass by a running
    maximum of ``g``; a wrapping arc is the complement of a window of ``~label``.
    """
    n = len(label)
    best = None
    for flip in (False, True):
        lab = ~label if flip else label
        g = np.arange(n + 1) - 2 * np.concatenate([[0], np.cumsum(lab)])
        run_max = np.maximum.accumulate(g)
        i0_of = np.maximum.accumulate(np.where(g == run_max, np.arange(n + 1), 0))
        cost = int(lab.sum()) + g[1:] - run_max[:-1]
        i1 = int(np.argmin(cost)) + 1
        i0 = int(i0_of[i1 - 1])
        if best is None or cost[i1 - 1] < best[0]:
            best = (cost[i1 - 1], (i1, i0 + n) if flip else (i0, i1))
    return best[1]


#: Twice a bridged sub-loop's area, as a share of its length squared, at or below which
#: it encloses nothing (:func:`_bridge_split`): far above rounding (~1e-15), far below any
#: real loop (a circle 0.16, a 100:1 sliver 0.005).
SLIVER = 1e-9


def _bridge_split(ring_idx: np.ndarray, ring_flat: np.ndarray, children: list,
                  base: int) -> tuple[list, np.ndarray, list]:
    """Split one loop into one sub-loop per child loop along straight bridges.

    :func:`_bridge_split_in` peeling the children in its own order (the child nearest
    to the fewest points first); where that split fails or a sub-loop of it crosses
    itself and the loop does not (a straight bridge of a merge of many loops, a head
    with its ears and horns, cuts through the loop's own bends), the other orders are
    tried in lexicographic order, and the first whose sub-loops are all simple is taken
    (at most :data:`BRIDGE_ORDERS`); when none is, the split is its own order's (or its
    error).  Parameters, returns and raises as :func:`_bridge_split_in`'s.
    """
    ring_flat = np.asarray(ring_flat)
    try:
        first, failure = _bridge_split_in(ring_idx, ring_flat, children, base, None), None
    except ValueError as exc:
        first, failure = None, exc
    if self_intersects(ring_flat):
        if failure is not None:
            raise failure
        return first

    def simple(split) -> bool:
        flat = np.vstack([ring_flat, split[1]])
        local = np.full(base + len(split[1]), -1, np.int64)
        local[np.asarray(ring_idx)] = np.arange(len(ring_idx))
        local[base:] = len(ring_idx) + np.arange(len(split[1]))
        return not any(self_intersects(flat[local[sub]]) for sub in split[0])
    if first is not None and simple(first):
        return first
    k = len(children)
    for order in itertools.islice(itertools.permutations(range(k), k - 1), BRIDGE_ORDERS):
        try:
            split = _bridge_split_in(ring_idx, ring_flat, children, base, order)
        except ValueError:
            continue
        if simple(split):
            return split
    if failure is not None:
        raise failure
    return first


#: Peeling orders :func:`_bridge_split` tries at most (5! = 120: a merge of six loops).
BRIDGE_ORDERS = 120


def _bridge_split_in(ring_idx: np.ndarray, ring_flat: np.ndarray, children: list,
                     base: int, order: tuple | None) -> tuple[list, np.ndarray, list]:
    """Split one loop into one sub-loop per child loop along straight bridges, peeling
    the children in ``order`` (None: the child nearest to the fewest points first).

    The loop's points are labelled by their nearest child loop (in the plane);
    the child taken first owns the cyclic arc that best matches its labels
    (:func:`_best_window`), and the loop is cut along the chord between the
    arc's two ends, sampled at the loop's point spacing: the sub-loop is the
    arc closed by the chord, the remainder the rest of the loop closed by the
    same chord the other way, which is split again among the other children.
    Every chord edge thus borders two sub-loops traversed in opposite
    directions, so the strips to the children meet along it in a manifold
    saddle (the bridge construction of contour tiling).

    Parameters
    ----------
    ring_idx : (n,) int64
        Global vertex indices of the loop, counter-clockwise.
    ring_flat : (n, 2) float64
        Its points in the section plane.
    children : list of (m_k, 2) float64
        The child loops of the adjacent section, in the plane.
    base : int
        Global index of the first new (bridge) vertex.

    Returns
    -------
    subs : list of (n_k,) int64
        Global indices of each child's sub-loop, counter-clockwise.
    new_flat : (B, 2) float64
        The bridge points added (global indices ``base ..``).
    bridge : list of (b, 2) int64
        The bridge edges (contour constraints).
    dip : (B,) float64
        ``4 t (1 - t)`` at each bridge point's position t along its chord: the
        caller lowers the chord by ``dip`` × half the gap to the children's
        section (the saddle lies between the two sections, at half the gap
        on average, and the surface under a chord dips towards it as a
        parabola to second order).

    Raises
    ------
    ValueError
        A child owns fewer than two points of the loop.
    """
    spacing = float(np.median(np.linalg.norm(np.roll(ring_flat, -1, axis=0) - ring_flat,
                                             axis=1)))
    trees = [cKDTree(c) for c in children]
    new_flat: list[np.ndarray] = []
    bridges = []
    subs, sub_flats, dips = [], [], []
    idx, flat = np.asarray(ring_idx), np.asarray(ring_flat)
    left = list(range(len(children)))
    peel = order
    order = []
    for step in range(len(children) - 1):
        # Peel the child nearest to the fewest points first: a small branch (a handle)
        # owns one arc of the loop, while the loop's main body may own several.
        dist = np.stack([trees[m].query(flat)[0] for m in left])
        owner = np.argmin(dist, axis=0)
        pick = (int(np.argmin(np.bincount(owner, minlength=len(left)))) if peel is None
                else left.index(peel[step]))
        k = left.pop(pick)
        order.append(k)
        label = owner == pick
        n = len(idx)
        i0, i1 = _best_window(label)
        if i1 - i0 < 2 or n - (i1 - i0) < 2:
            raise ValueError(f"child loop {k} is nearest to {int(label.sum())} of the {n} points")
        arc = np.arange(i0, i1 + 1) % n          # includes the far end v = arc[-1]
        rest = np.arange(i1, i0 + n + 1) % n      # from v round to u = arc[0]
        u, v = flat[arc[0]], flat[arc[-1]]
        m = max(int(round(float(np.linalg.norm(v - u)) / max(spacing, TOL.zero))) - 1, 0)
        t = np.arange(1, m + 1) / (m + 1)
        pts = v + t[:, None] * (u - v)            # from v towards u
        new_idx = base + sum(len(x) for x in new_flat) + np.arange(m)
        new_flat.append(pts)
        dips.append(4 * t * (1 - t))
        path = np.concatenate([[idx[arc[-1]]], new_idx, [idx[arc[0]]]])   # v -> u
        bridges.append(np.stack([path[:-1], path[1:]], axis=1))
        subs.append(np.concatenate([idx[arc], new_idx]))
        sub_flats.append(np.vstack([flat[arc], pts]))
        idx = np.concatenate([idx[rest], new_idx[::-1]])
        flat = np.vstack([flat[rest], pts[::-1]])
    subs.append(idx)
    sub_flats.append(flat)
    for sub_flat in sub_flats:   # each sub-loop must stay counter-clockwise and simple
        # about its centroid (no cancellation against the plane's origin), and by a margin:
        # a child owning three collinear points of the loop (a straight side of a real
        # loop) closes a sub-loop of no area, whose sign is rounding noise -- on the real
        # temple ring rings differing by 3e-14 split one way on one machine, refused on
        # another; such a sliver carries no strip to its child either way
        x, y = (sub_flat - sub_flat.mean(axis=0)).T
        twice = float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))
        length = float(np.linalg.norm(np.roll(sub_flat, -1, axis=0) - sub_flat, axis=1).sum())
        if twice <= SLIVER * length * length:
            raise ValueError("a bridge crosses its loop (a sub-loop runs clockwise or "
                             "encloses no area)")
    order.append(left[0])
    by_child = [subs[order.index(k)] for k in range(len(children))]
    added = np.vstack(new_flat) if new_flat else np.zeros((0, 2))
    return by_child, added, bridges, np.concatenate(dips) if dips else np.zeros(0)


#: Cap points a bridge point's height is fitted to (a plane through them: 3 unknowns,
#: four times as many points).
BRIDGE_NEIGHBOURS = 12


def _bridge_heights(flat: np.ndarray, default: np.ndarray, height: float, other: float,
                    cap_points: np.ndarray | None, frame: np.ndarray) -> np.ndarray:
    """Heights ``(B,)`` of a split's bridge points from the cloud between the sections.

    The bridge runs over the saddle where the loops part; there the surface
    faces along the axis, so its points are cap points (``reconstruct``'s
    ``MIN_WALL_SINE``).  Each bridge point takes the height at its plane
    position of the least-squares plane through the :data:`BRIDGE_NEIGHBOURS`
    nearest (in the plane) cap points strictly between the two sections, when
    they lie within a quarter of the bridge's length; otherwise, or with no cap
    points, ``default`` (the ``4 t (1 - t)`` dip of :func:`_bridge_split`).
    Heights are kept between the sections.
    """
    lo, hi = min(height, other), max(height, other)
    out = np.clip(np.asarray(default, np.float64), lo, hi)
    if cap_points is None or len(cap_points) < BRIDGE_NEIGHBOURS or len(flat) == 0:
        return out
    pts = np.asarray(cap_points, np.float64)
    h = pts @ frame[2]
    between = (h > lo) & (h < hi)
    if np.count_nonzero(between) < BRIDGE_NEIGHBOURS:
        return out
    plane = pts[between] @ frame[:2].T
    h = h[between]
    reach = 0.25 * (float(np.linalg.norm(flat[-1] - flat[0])) +
                    2 * float(np.median(np.linalg.norm(np.diff(flat, axis=0), axis=1)))
                    if len(flat) > 1 else 0.0)
    dist, near = cKDTree(plane).query(flat, k=BRIDGE_NEIGHBOURS)       # (B, k)
    uv = plane[near] - flat[:, None, :]
    design = np.concatenate([np.ones(near.shape + (1,)), uv], axis=2)  # (B, k, 3)
    normal = np.einsum("bki,bkj->bij", design, design) + 1e-12 * np.eye(3)
    fit = np.linalg.solve(normal, np.einsum("bki,bk->bi", design, h[near])[..., None])[:, 0, 0]
    ok = dist[:, -1] <= reach
    out[ok] = np.clip(fit[ok], lo, hi)
    return out


#: Fewest cap points inside a loop that place its cap (a plane fit needs 3; the
#: median of a dozen is robust to a few wall points leaking in).
CAP_MIN_POINTS = 12
#: Cap points count for a loop's cap when inside its contour shrunk by this factor
#: about its centroid, and outside its holes grown by the inverse (keeps walls out).
CAP_SHRINK = 0.9


def _scaled(ring2d: np.ndarray, factor: float) -> np.ndarray:
    centre = ring2d.mean(axis=0)
    return centre + factor * (ring2d - centre)


def _cap_step(outer2d, holes2d, height, up, cap_points, frame, base_heights) -> float:
    """Axial offset from a loop's plane to the median height of the cap points over it.

    Looks between ``height`` and the next section plane in the cap's direction
    (``up``: above), at the points inside ``outer2d`` (shrunk by
    :data:`CAP_SHRINK`) and outside every hole (grown by its inverse); 0 when
    fewer than :data:`CAP_MIN_POINTS` are there.
    """
    pts = np.asarray(cap_points, np.float64)
    if len(pts) == 0:
        return 0.0
    h = pts @ frame[2]
    beyond = base_heights[base_heights > height + TOL.zero] if up else \
        base_heights[base_heights < height - TOL.zero]
    if len(beyond):
        limit = float(beyond.min() if up else beyond.max())
    else:
        limit = height + (1 if up else -1) * 2 * float(np.median(np.abs(np.diff(base_heights))))
    lo, hi = (height, limit) if up else (limit, height)
    near = np.flatnonzero((h > lo) & (h < hi))
    if len(near) < CAP_MIN_POINTS:
        return 0.0
    flat = pts[near] @ frame[:2].T
    keep = _inside(flat, _scaled(outer2d, CAP_SHRINK))
    for hole in holes2d:
        keep &= ~_inside(flat, _scaled(hole, 1 / CAP_SHRINK))
    if np.count_nonzero(keep) < CAP_MIN_POINTS:
        return 0.0
    return float(np.median(h[near[keep]])) - height


# --------------------------------------------------------------------------- support rings
#: A ring where the section profile turns by more than this (radians) is a crease
#: candidate.  Rings placed as far apart along the profile as around it
#: (``surface.reconstruct.ring_count``) sample a smooth surface with turns of Δκ per ring, far
#: below 30° wherever the sampling resolves the surface; a turn this large at one
#: ring is an edge the sampling did not resolve (a rim, a shoulder).
SHARP_TURN = np.pi / 6
#: Support rings are at least this share of the ring's point spacing from their ring
#: (noise-free data would put them at d = 0): strip triangles of aspect ratio <= 10
#: keep the Bezier patches well conditioned (normals of ~1° slivers lose digits:
#: measured 1.2e-9 rad across an exactly G1 edge).
SUPPORT_MIN_SHARE = 0.1


def _read_at(ring: np.ndarray, other: np.ndarray) -> np.ndarray:
    """The closest point of the closed polygon ``other`` to each point of ``ring``: ``(n, 3)``.

    The neighbour ring seen from a ring point along the section profile (rings
    need not start at the same angle: their starts differ by up to a spacing).
    The closest vertex (k-d tree), then the closest point on its two edges.
    """
    m = len(other)
    nearest = cKDTree(other).query(ring)[1]
    best = other[nearest]
    best_d = np.linalg.norm(ring - best, axis=1)
    for step in (-1, 1):
        a, b = other[nearest], other[(nearest + step) % m]
        ab = b - a
        t = np.einsum("ij,ij->i", ring - a, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab),
                                                               TOL.zero)
        foot = a + np.clip(t, 0.0, 1.0)[:, None] * ab
        d = np.linalg.norm(ring - foot, axis=1)
        closer = d < best_d
        best[closer], best_d[closer] = foot[closer], d[closer]
    return best


def _nearest_loop(loop: np.ndarray, loops: list, frame: np.ndarray) -> np.ndarray:
    """The loop of ``loops`` most like ``loop`` in the section plane.

    Nearest by centroid distance plus the difference of the mean radii about the
    centroids, so that of a wall's concentric outer and inner loops the one of
    the same size is taken.
    """
    def centre_radius(lp):
        flat = lp @ frame[:2].T
        c = flat.mean(axis=0)
        return c, float(np.mean(np.linalg.norm(flat - c, axis=1)))

    c0, r0 = centre_radius(loop)
    cost = [float(np.linalg.norm(c - c0)) + abs(r - r0) for c, r in map(centre_radius, loops)]
    return loops[int(np.argmin(cost))]


def support_distance(legs_a: np.ndarray, legs_b: np.ndarray, sigma: float,
                     ring_spacing: float = 0.0) -> float:
    r"""Distance of the support rings at a ring whose profile legs are ``legs_a``, ``legs_b``.

    A G1 spline surface over a control polygon with a corner of turn α and
    legs of length ``h`` passes the corner at :math:`h \sin(\alpha/2)/3` from it
    (cubic B-spline limit :math:`(P_{-1} + 4P_0 + P_1)/6`; Loop's limit mask
    agrees at valence 6).  Support (holding) rings at distance ``d`` on both
    legs shrink that to :math:`d \sin(\alpha/2)/3`; ``d`` is chosen so that it
    is ``sigma``, the noise of the points the ring was fitted to, which the
    data cannot resolve anyway: :math:`d = 3\sigma/\sin(\alpha/2)`, at most half
    the shorter leg (so the support lies between the rings) and at least
    :data:`SUPPORT_MIN_SHARE` of the ring's point spacing.  At a 90° rim the limit surface then
    passes :math:`d/6 = \sigma/\sqrt{2}` from each face.

    Parameters
    ----------
    legs_a, legs_b : (n, 3) float64
        From each ring point to its neighbour along the profile on either side
        (for an end ring, one leg runs into the cap).
    sigma : float
        Noise σ̂ of the section points, scene units (≥ 0).
    ring_spacing : float
        Median distance between consecutive points of the ring, scene units.

    Returns
    -------
    float
        ``d`` in scene units, or 0 where no support is needed: a median turn
        below :data:`SHARP_TURN`, or a rounding ``h sin(α/2)/3`` already within
        ``sigma`` (``h`` the median shorter leg).
    """
    la, lb = np.linalg.norm(legs_a, axis=1), np.linalg.norm(legs_b, axis=1)
    cos = np.einsum("ij,ij->i", legs_a, legs_b) / np.maximum(la * lb, TOL.zero)
    turn = float(np.median(np.pi - np.arccos(np.clip(cos, -1.0, 1.0))))
    h = float(np.median(np.minimum(la, lb)))
    rounding = h * np.sin(turn / 2) / 3
    if turn < SHARP_TURN or rounding <= sigma:
        return 0.0
    return float(min(max(3.0 * sigma / np.sin(turn / 2), SUPPORT_MIN_SHARE * ring_spacing),
                     h / 2))


def _support(sections: list, frame: np.ndarray, sigma: float,
             close_ends: bool) -> tuple[list, dict, list[str]]:
    """Support rings where the profile turns sharply (:func:`support_distance`).

    At an inner ring (sections with one loop each on both sides) two rings are
    added, at ``d`` towards each neighbour ring.  At a capped end ring one is
    added on the wall, at ``d`` towards the next ring, and the cap gets an inner
    ring at ``d`` from the rim (returned as ``cap_inset[(end, loop)] = d`` for
    :func:`stitch_rings` to build, the cap being in the rim's plane).

    Returns
    -------
    sections : list of list of (n, 3)
        With the wall supports inserted (heights stay monotone: each point moves
        at most half its own leg, a third where the strip's other ring is supported
        too: :func:`_support_ring`).
    cap_inset : dict
        ``(0 | -1, loop) -> d`` for the bottom / top caps.
    notes : list of str
    """
    count = len(sections)
    before: dict[int, list] = {}
    after: dict[int, list] = {}
    cap_inset: dict = {}
    notes = []
    for s in range(count):
        end = 0 if s == 0 else (-1 if s == count - 1 else None)
        if end is None and not (len(sections[s - 1]) == len(sections[s]) == len(sections[s + 1])
                                == 1):
            continue
        nested = np.zeros(len(sections[s]), bool)
        if len(sections[s]) > 1:  # a wall's loops (a rim): no disk cap, no support
            depth, parent = nesting([ring @ frame[:2].T for ring in sections[s]])
            nested = depth > 0
            nested[parent[parent >= 0]] = True
        for lp, ring in enumerate(sections[s]):
            if nested[lp]:
                continue
            if end is None:
                legs_a = _read_at(ring, sections[s - 1][0]) - ring
            elif _closes(close_ends, end):
                legs_a = ring.mean(axis=0) - ring     # into the cap, towards its centre
            else:
                continue
            other = sections[s + 1] if end in (None, 0) else sections[s - 1]
            legs_b = _read_at(ring, _nearest_loop(ring, other, frame)) - ring
            spacing = float(np.median(np.linalg.norm(np.diff(ring, axis=0), axis=1)))
            d = support_distance(legs_a, legs_b, sigma, spacing)
            if d <= 0:
                continue
            wall = (ring, legs_b, d)
            if end is None:
                before.setdefault(s, []).append((ring, legs_a, d))
                after.setdefault(s, []).append(wall)
            else:
                (after if end == 0 else before).setdefault(s, []).append(wall)
                cap_inset[(end, lp)] = d
            notes.append(f"section {s} loop {lp}: support rings at {d:.3g} (profile turn "
                         "sharper than a G1 surface over the ring spacing can follow)")
    whole = {s for s in range(count) if len(before.get(s, ())) == len(sections[s])}
    whole_after = {s for s in range(count) if len(after.get(s, ())) == len(sections[s])}
    out = []
    for s in range(count):
        if s in whole:
            out.append([_support_ring(*r, facing=s - 1 in whole_after) for r in before[s]])
        out.append(sections[s])
        if s in whole_after:
            out.append([_support_ring(*r, facing=s + 1 in whole) for r in after[s]])
    return out, cap_inset, notes


#: Share of its own leg a support point may move along: a half where the strip's other
#: ring has no support, a third where both rings of a strip get one towards the other.
#: ``d`` (:func:`support_distance`) is bounded by half the *median* leg; a point whose own
#: leg is shorter (where the neighbour ring lacks a spike or a ledge of this one, its
#: nearest point is sideways and the leg short) would pass the strip's middle, and two
#: facing supports would pass each other: their strip turned upside down and crossed both
#: neighbouring strips (the temple ring's top: 697 crossing pairs).
SUPPORT_SHARE, FACING_SUPPORT_SHARE = 0.5, 1.0 / 3.0


def _support_ring(ring: np.ndarray, legs: np.ndarray, d: float, facing: bool) -> np.ndarray:
    """``ring`` moved ``d`` along each point's leg, at most :data:`SUPPORT_SHARE` (or,
    ``facing`` another support across the strip, :data:`FACING_SUPPORT_SHARE`) of it."""
    length = np.linalg.norm(legs, axis=1)
    share = FACING_SUPPORT_SHARE if facing else SUPPORT_SHARE
    unit = legs / np.maximum(length, TOL.zero)[:, None]
    return ring + np.minimum(d, share * length)[:, None] * unit


#: Rings added inside a flat cap beyond its support ring, each a further support distance
#: in (:func:`stitch_rings`).  Loop's patch over a triangle reads the control mesh up to
#: two rings of edges around it (one refinement step, then the refined corners' 1-rings),
#: so with the support ring alone every cap triangle with a corner on it reads the wall's
#: support ring too and bends out of the cap plane (measured on the 10^5-point vase's
#: sized surface: the cap 0.00033 from its plane on average, the stitched cap 0.00002);
#: one guard ring keeps every triangle inside it two rings from the wall: planar.
CAP_GUARD_RINGS = 1


#: Bits below the contour's size at which :func:`_quality_cap` snaps its points: 2^-26
#: of the size (~1.5e-8), far below any modelling scale and 10⁸ times the last-bit noise
#: of the rings (~1e-16 relative).  At 2^-32 the 10⁴-point torus moved by 1e-12 still
#: crossed grid lines often enough to change a cap in 3 of 8 runs
#: (``benchmarks/last_bits.py``); at 2^-26, in none.
SNAP_BITS = 26


def _snapped(points: np.ndarray) -> np.ndarray:
    """``points`` rounded to a grid of 2^-SNAP_BITS of their extent (a power of two).

    Triangle's quality refinement (``q``) decides where to add points by exact
    in-circle tests, and a ring sampled evenly round a rounded end is nearly cocircular:
    the last bits of its coordinates (another BLAS, another CPU, a solver changed
    elsewhere) chose other Steiner points and another number of cap triangles (the
    10⁴-point torus's dense mesh: 12 106-12 168 triangles under perturbations of 1e-13
    of the coordinates, 2026-12-06).  Snapped, perturbations that small give the same
    input and so the same triangulation, unless a coordinate sits within them of a
    rounding boundary (a chance of about their size / 1.5e-8 each).
    """
    scale = float(np.abs(points).max(initial=0.0))
    if not scale > 0 or not np.isfinite(scale):
        return points
    grid = 2.0 ** (math.floor(math.log2(scale)) - SNAP_BITS)
    return np.round(points / grid) * grid


#: Smallest angle (degrees) of the triangles inside a cap with support rings
#: (Shewchuk's Triangle, ``q``): the ear-clipped cap of a ring of n points has
#: slivers of ~180°/n whose Bezier patches have near-singular Jacobians, where
#: normals lose digits (measured 1.7e-8 rad across an edge that is G1 exactly).
CAP_MIN_ANGLE = 25.0


def _quality_cap(ring2d: np.ndarray, outward_up: bool,
                 max_area: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Constrained quality Delaunay triangulation of a closed planar contour.

    The contour's points and edges are kept as they are (no point added on
    them); points are added inside until every angle is at least
    :data:`CAP_MIN_ANGLE` (Triangle grades them: triangles the contour's edge
    length at the contour, larger inside, so a flat cap costs O(n) triangles).

    Parameters
    ----------
    ring2d : (n, 2) float64
        The contour, counter-clockwise, in the section plane's coordinates.
    outward_up : bool
        As in :func:`cap_triangles`.
    max_area : float, optional
        Largest triangle area (Triangle's ``a`` switch): a dome's height field is
        sampled as finely inside as along its contour.

    Returns
    -------
    added : (k, 2) float64
        The points added inside, plane coordinates.
    triangles : (m, 3) int64
        Over the contour's ``0 .. n-1`` then the added ``n .. n+k-1``.

    Raises
    ------
    ValueError
        The contour is not simple (self-intersecting, or repeated points): the
        triangles do not cover its shoelace area exactly once, or a contour
        point is not a corner.
    """
    import triangle

    n = len(ring2d)
    centre = ring2d.mean(axis=0)
    pts = _snapped(ring2d - centre)
    edge = float(np.mean(np.linalg.norm(np.roll(pts, -1, axis=0) - pts, axis=1)))
    segments = np.stack([np.arange(n), (np.arange(n) + 1) % n], axis=1)
    switches = f"pYq{CAP_MIN_ANGLE:g}" + (f"a{max_area:.15f}" if max_area else "")  # no exponent
    out = triangle.triangulate({"vertices": pts, "segments": segments}, switches)
    verts = np.asarray(out.get("vertices", np.zeros((0, 2))), np.float64)
    tri = np.asarray(out.get("triangles", np.zeros((0, 3))), np.int64).reshape(-1, 3)
    if (len(verts) < n or not np.allclose(verts[:n], pts, rtol=0, atol=TOL.zero * (1 + edge))
            or len(np.unique(tri[tri < n])) < n):
        raise ValueError("the contour's points are not all corners of the triangulation")
    p = verts[tri]
    twice = ((p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1])
             - (p[:, 1, 1] - p[:, 0, 1]) * (p[:, 2, 0] - p[:, 0, 0]))
    x, y = pts[:, 0], pts[:, 1]
    polygon = 0.5 * abs(float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)))
    if abs(0.5 * float(np.abs(twice).sum()) - polygon) > TOL.planar_rel * (1.0 + polygon) * n:
        raise ValueError("contour is not simple (triangles do not cover its area once)")
    flip = (twice < 0) if outward_up else (twice > 0)
    tri[flip] = tri[flip][:, ::-1]
    return verts[n:] + centre, tri


#: Cap points each dome height is fitted to (a local quadratic: the standard error of
#: its value at the centre of a disk of k uniform points is about 1.6 σ/√k, σ/4 here).
DOME_NEIGHBOURS = 48
#: A cap is a dome when the cap points' robust spread about their best plane exceeds
#: this many times their spread about local quadratics (the noise): a flat cap's ratio
#: is ~1 (measured 1.0-1.2 on the benchmark clouds' flat ends).
DOME_RATIO = 2.0


#: Cap points the dome test fits its local quadratics at, at most (evenly spaced through
#: the cap points when there are more): the test compares two robust spreads, whose medians
#: 20 000 points fix to about 1 % (DOME_RATIO is 2 against the flat caps' 1.0-1.2), while
#: the cap points grow with the cloud (10^6-point vase: 2 x ~10^5 a candidate surface).
DOME_TEST_POINTS = 20_000
#: Query points of one batch of :func:`_local_quadratic` (bounds its memory: the
#: ``(Q, k, 6)`` design and its neighbours take ~3 kB a query point with k = 48).
QUADRATIC_BATCH = 8192


@numba.njit(cache=True, nogil=True)
def _quadratic_heights(flat: np.ndarray, h: np.ndarray, query: np.ndarray,
                       near: np.ndarray) -> tuple:  # pragma: no cover - numba
    """Value at each query point of the least-squares quadratic through its neighbours
    ``near[q]`` (see :func:`_local_quadratic`), and its variance over σ² (``(NᵀN)⁻¹``'s
    first diagonal element): normal equations accumulated per query, solved by Gaussian
    elimination with partial pivoting for the heights and for the unit vector."""
    out = np.empty(len(query))
    var = np.empty(len(query))
    normal = np.empty((6, 6))
    rhs = np.empty((6, 2))
    row = np.empty(6)
    for q in range(len(query)):
        qx, qy = query[q, 0], query[q, 1]
        scale = 0.0
        for j in range(near.shape[1]):
            p = near[q, j]
            scale = max(scale, abs(flat[p, 0] - qx), abs(flat[p, 1] - qy))
        scale = max(scale, 1e-12)
        normal[:] = 0.0
        rhs[:] = 0.0
        rhs[0, 1] = 1.0
        for j in range(near.shape[1]):
            p = near[q, j]
            u = (flat[p, 0] - qx) / scale
            v = (flat[p, 1] - qy) / scale
            row[0], row[1], row[2], row[3], row[4], row[5] = 1.0, u, v, u * u, u * v, v * v
            for a in range(6):
                rhs[a, 0] += row[a] * h[p]
                for b in range(a, 6):
                    normal[a, b] += row[a] * row[b]
        for a in range(6):
            normal[a, a] += 1e-9
            for b in range(a):
                normal[a, b] = normal[b, a]
        for c in range(6):                       # elimination, partial pivoting
            piv = c
            for r in range(c + 1, 6):
                if abs(normal[r, c]) > abs(normal[piv, c]):
                    piv = r
            if piv != c:
                for b in range(6):
                    normal[c, b], normal[piv, b] = normal[piv, b], normal[c, b]
                for b in range(2):
                    rhs[c, b], rhs[piv, b] = rhs[piv, b], rhs[c, b]
            for r in range(c + 1, 6):
                f = normal[r, c] / normal[c, c]
                for b in range(c, 6):
                    normal[r, b] -= f * normal[c, b]
                for b in range(2):
                    rhs[r, b] -= f * rhs[c, b]
        for c in range(5, -1, -1):
            for e in range(2):
                acc = rhs[c, e]
                for b in range(c + 1, 6):
                    acc -= normal[c, b] * rhs[b, e]
                rhs[c, e] = acc / normal[c, c]
        out[q] = rhs[0, 0]
        var[q] = rhs[0, 1]
    return out, var


def _local_quadratic(flat: np.ndarray, h: np.ndarray, query: np.ndarray,
                     k: int, variance: bool = False):
    """Heights ``(Q,)`` at ``query`` of least-squares quadratics through k nearest points.

    ``h ≈ c0 + c1 u + c2 v + c3 u² + c4 uv + c5 v²`` in the offsets (u, v) from
    each query point (scaled by their largest); ``c0`` is the height there.  The k-d
    tree of ``flat`` is built once; the queries go in batches of
    :data:`QUADRATIC_BATCH` neighbours' worth (memory), each point's fit its own
    (:func:`_quadratic_heights`, numba: the batched numpy normal equations spent 90 %
    of their time building ``(Q, k, 6)`` designs).  With ``variance`` also each height's
    variance over σ² ``(Q,)``.
    """
    flat = np.ascontiguousarray(flat, dtype=np.float64)
    h = np.ascontiguousarray(h, dtype=np.float64)
    query = np.ascontiguousarray(query, dtype=np.float64).reshape(-1, 2)
    k = min(k, len(flat))
    tree = cKDTree(flat)
    heights, factors = np.empty(len(query)), np.empty(len(query))
    size = max(256, QUADRATIC_BATCH * DOME_NEIGHBOURS // max(k, 1))   # memory ~ size x k
    for s in range(0, len(query), size):
        batch = query[s:s + size]
        _, near = tree.query(batch, k=k)                          # (Q, k)
        heights[s:s + len(batch)], factors[s:s + len(batch)] = _quadratic_heights(
            flat, h, batch, np.asarray(near, np.int64).reshape(len(batch), k))
    return (heights, factors) if variance else heights


#: Share of a contour's inside the cap points may leave uncovered for it to be capped by
#: their height field (:func:`_dome`); more is a hole in the data (:func:`uncovered_share`).
HOLE_SHARE = 0.05
#: A point of a contour's inside is covered when a cap point lies within this many of
#: their median nearest-neighbour distances ν: for points spread at random with density
#: ρ, ν ≈ 0.47 / √ρ, and an empty disc of radius 4ν holds no point with probability
#: exp(-π ρ (4ν)²) ≈ 1.5e-5, so a covered cap is never taken for a hole.
COVER_RADIUS = 4.0


def uncovered_share(ring2d: np.ndarray, holes2d: list, flat: np.ndarray) -> float:
    """Share of the region inside ``ring2d`` and outside each of ``holes2d`` (``(n, 2)``
    contours) farther than :data:`COVER_RADIUS` ν from every point of ``flat`` ``(P, 2)``.

    Measured on a grid of cell 2ν (ν the points' median nearest-neighbour distance);
    1.0 with fewer than 3 points, 0.0 when the region holds no grid point.
    """
    inside = flat[_inside(flat, ring2d)] if len(flat) else flat
    for hole in holes2d:
        inside = inside[~_inside(inside, hole)]
    if len(inside) < 3:
        return 1.0
    tree = cKDTree(inside)
    nu = float(np.median(tree.query(inside, k=2)[0][:, 1]))
    lo, hi = ring2d.min(axis=0), ring2d.max(axis=0)
    cell = 2.0 * max(nu, TOL.zero * float(np.ptp(ring2d, axis=0).max()))
    steps = np.ceil((hi - lo) / cell).astype(np.int64) + 1
    if steps.prod() > INSIDE_PAIRS // 4:     # a coarser grid past ~500 000 cells
        cell *= float(np.sqrt(steps.prod() / (INSIDE_PAIRS // 4)))
        steps = np.ceil((hi - lo) / cell).astype(np.int64) + 1
    gx, gy = np.meshgrid(lo[0] + cell * np.arange(steps[0]), lo[1] + cell * np.arange(steps[1]))
    grid = np.column_stack([gx.ravel(), gy.ravel()])
    grid = grid[_inside(grid, ring2d)]
    for hole in holes2d:
        grid = grid[~_inside(grid, hole)]
    if len(grid) == 0:
        return 0.0
    far = tree.query(grid, distance_upper_bound=COVER_RADIUS * nu)[0] == np.inf
    return float(far.mean())


def _closes(close_ends, end: int) -> bool:
    """Whether end ``end`` (0 the first section, -1 the last) is capped: ``close_ends``
    is one bool for both or a pair."""
    if np.ndim(close_ends) == 0:
        return bool(close_ends)
    return bool(close_ends[0 if end == 0 else 1])


def _dome(ring2d: np.ndarray, lo: float, hi: float, cap_points: np.ndarray | None,
          frame: np.ndarray, field_ring: np.ndarray | None = None,
          rim: tuple[float, bool] | None = None, reach: float | None = None):
    """The cap points' height field over an end contour, or None for a flat cap.

    The section planes stop where the surface turns within 60° of them
    (``reconstruct.MIN_WALL_SINE``); beyond the last contour a rounded end (a
    capsule's hemisphere, a torus' crown) is a height field over the plane,
    sampled by the cap points; so is a branch's rounded end between two
    sections (a handle's lowest point).  Those inside the contour (shrunk by
    :data:`CAP_SHRINK`) with heights in ``(lo, hi)`` (an end cap: from two
    spacings back on; an inner cap: up to the next section plane) are taken;
    the cap is a dome when their robust spread (1.4826 × median
    absolute deviation) about their least-squares plane exceeds
    :data:`DOME_RATIO` times that about local quadratics of
    :data:`DOME_NEIGHBOURS` points (the noise), the latter measured at no more
    than :data:`DOME_TEST_POINTS` of them, and they cover the contour: where more than
    :data:`HOLE_SHARE` of its inside lies farther from every one of them than
    :data:`COVER_RADIUS` spacings (:func:`uncovered_share`: the scanner never saw the
    middle of an animal's base, a bust's cut, a dome's pole), the quadratics would run
    on from the hole's rim into a dome far from every point, so the heights are held
    within those of the points over the contour (a plateau over the hole at the height
    its rim allows).  The height field is fitted to the points
    over ``field_ring`` (default ``ring2d``: a ringed cap decides on its innermost ring
    and fits over its rim), each height to as many of them as the dome's shape allows
    (:func:`_dome_neighbours`).  With ``rim = (height, up)`` the heights are held on the
    cap's side of the contour's plane (``up``: at or above ``height``): the strips the
    contour ends lie on the other side, and a dome dipping back through the plane would
    cross them (the quadratics near the rim also take the wall's last points below it).
    With ``reach`` as well they are held short of that height (``up``: at or below it):
    where a loop vanishes under one section and another appears over the next, both
    inside the slab between them, their two domes are fitted to the same points and
    cross wherever the contours overlap; each is held to its half of the slab.

    Returns
    -------
    callable or None
        ``(Q, 2)`` plane points -> ``(Q,)`` heights along the axis (local
        quadratics, :func:`_local_quadratic`).
    """
    if cap_points is None or len(cap_points) < 2 * DOME_NEIGHBOURS:
        return None
    pts = np.asarray(cap_points, np.float64)
    h = pts @ frame[2]
    side = (h > lo) & (h < hi)
    window, h_window = pts[side] @ frame[:2].T, h[side]
    within = _inside(window, ring2d)
    every, h_every = window[within], h_window[within]
    inside = _inside(every, _scaled(ring2d, CAP_SHRINK))
    flat, h = every[inside], h_every[inside]
    if len(flat) < 2 * DOME_NEIGHBOURS:
        return None
    hole = uncovered_share(_scaled(ring2d, CAP_SHRINK), [], flat) > HOLE_SHARE
    design = np.column_stack([np.ones(len(flat)), flat])
    plane = h - design @ np.linalg.lstsq(design, h, rcond=None)[0]
    test = np.unique(np.linspace(0, len(flat) - 1, min(len(flat), DOME_TEST_POINTS)).astype(
        np.int64))                                                # every point when few
    local = h[test] - _local_quadratic(flat, h, flat[test], DOME_NEIGHBOURS)

    def spread(r):
        return 1.4826 * float(np.median(np.abs(r - np.median(r))))
    if spread(plane) <= DOME_RATIO * max(spread(local), TOL.zero):
        return None
    # The height field is fitted to every point over the contour: near the rim the
    # dome meets the wall's last points, which hold it there (no extrapolation).
    if field_ring is not None:
        within = _inside(window, field_ring)
        every, h_every = window[within], h_window[within]
    test = np.unique(np.linspace(0, len(flat) - 1, min(len(flat), DOME_WIDTH_TEST_POINTS))
                     .astype(np.int64))
    noise, chosen = spread(local), []

    def field(query) -> np.ndarray:
        # the neighbour count on the first call: a caller that only asks "a dome?"
        # (reconstruct.extend_to_caps) does not pay for it
        if not chosen:
            chosen.append(_dome_neighbours(every, h_every, flat[test], noise))
        heights = _local_quadratic(every, h_every, np.asarray(query, np.float64), chosen[0])
        # over a hole the quadratics run on from its rim: held within the points' heights
        if hole:
            heights = np.clip(heights, h_every.min(), h_every.max())
        if rim is not None:   # never back through the contour's plane, into the strips
            heights = np.maximum(heights, rim[0]) if rim[1] else np.minimum(heights, rim[0])
            if reach is not None:     # nor past the half-slab of a facing cap
                heights = np.minimum(heights, reach) if rim[1] else np.maximum(heights, reach)
        return heights
    return field


def end_window(height: float, up: bool, spacing: float) -> tuple[float, float]:
    """Heights of the cap points an end's dome test takes: beyond its last contour, which
    may lie up to two section spacings inside the data (``up``: the end faces +axis)."""
    return (height - 2 * spacing, np.inf) if up else (-np.inf, height + 2 * spacing)


#: Most cap points one dome height is fitted to (the doubling of :func:`_dome_neighbours`
#: stops there: SE 0.08 σ; 384 points spread over ~π (0.17 r)² of a unit dome's plane at
#: 10⁵ points, and the cost grows with it: ~Q k for Q heights).
DOME_MAX_NEIGHBOURS = 384
#: Median of the χ² distribution with one degree of freedom (a robust mean square).
CHI2_1_MEDIAN = 0.454936
#: Points the neighbour count is chosen at (evenly through the cap points).
DOME_WIDTH_TEST_POINTS = 512


def _dome_neighbours(flat: np.ndarray, h: np.ndarray, test: np.ndarray, noise: float) -> int:
    """Cap points per dome height: as many as the dome's shape allows (Lepski's rule).

    A local quadratic's height of k points has a standard error of about 1.6 σ/√k: at
    :data:`DOME_NEIGHBOURS` a dome's vertices were 2-3× noisier than the wall's rings
    beside them (10⁵-point capsule: 0.00054 against 0.0002-0.0003), and the smooth
    surface interpolates them.  k is doubled while the wider fit differs from the
    narrower one by no more than their noise explains: for nested least-squares fits the
    difference's variance is the narrower's less the wider's (each ``σ² (NᵀN)⁻¹₀₀`` of its
    own neighbours, so one-sided fits near the rim count as what they are); the median
    of the squared standardised differences at up to :data:`DOME_WIDTH_TEST_POINTS` cap
    points (``noise``: the cap points' scatter about the narrowest fits) must stay within
    twice χ²₁'s, i.e. the wider fit's bias from the dome's curvature change stays below
    its noise.  Never beyond :data:`DOME_MAX_NEIGHBOURS` nor a quarter of the points.
    """
    k = DOME_NEIGHBOURS
    if not noise > 0:
        return k
    fit, var = _local_quadratic(flat, h, test, k, variance=True)
    while 2 * k <= min(DOME_MAX_NEIGHBOURS, len(flat) // 4):
        wider, var_wider = _local_quadratic(flat, h, test, 2 * k, variance=True)
        # nested fits: the difference's variance is the narrower's less the wider's
        z2 = (wider - fit) ** 2 / (noise ** 2 * np.maximum(var - var_wider, TOL.zero))
        if float(np.median(z2)) / CHI2_1_MEDIAN > 2.0:
            break
        k, fit, var = 2 * k, wider, var_wider
    return k


def self_intersects(uv: np.ndarray) -> bool:
    """Whether the closed polygon ``uv`` ``(n, 2)`` crosses itself (:func:`_edges_cross`
    over its non-adjacent edges; edges that only touch or overlap along a line do not
    count)."""
    return len(uv) >= 4 and _edges_cross([uv], between_loops=False)


def loops_cross(uvs: list) -> bool:
    """Whether two of the closed polygons ``uvs`` (each ``(n, 2)``: one section's loops)
    cross each other (:func:`_edges_cross` over pairs of edges from different loops;
    loops that only touch do not count)."""
    loops = [uv for uv in uvs if len(uv) >= 3]
    return len(loops) >= 2 and _edges_cross(loops, between_loops=True)


def _edges_cross(loops: list, between_loops: bool) -> bool:
    """Whether two edges of the closed polygons ``loops`` cross: pairs from different
    loops (``between_loops``) or non-adjacent pairs of one loop.  Two edges that cross
    have midpoints closer than the longest edge: candidate pairs come from a k-d tree of
    the midpoints (``cKDTree.query_pairs``), each tested exactly by the signs of its four
    orientations."""
    loops = [np.asarray(uv, dtype=np.float64) for uv in loops]
    a = np.concatenate(loops)
    b = np.concatenate([np.roll(uv, -1, axis=0) for uv in loops])
    sizes = np.array([len(uv) for uv in loops])
    owner = np.repeat(np.arange(len(loops)), sizes)
    longest = float(np.linalg.norm(b - a, axis=1).max())
    pairs = cKDTree(0.5 * (a + b)).query_pairs(longest, output_type="ndarray")
    i, j = pairs[:, 0], pairs[:, 1]
    if between_loops:
        keep = owner[i] != owner[j]
    else:                                   # one loop: not sharing a vertex
        step = np.abs(i - j)
        keep = (owner[i] == owner[j]) & (step != 1) & (step != sizes[owner[i]] - 1)
    i, j = i[keep], j[keep]

    def orientation(p, q, r):
        return np.sign((q[:, 0] - p[:, 0]) * (r[:, 1] - p[:, 1])
                       - (q[:, 1] - p[:, 1]) * (r[:, 0] - p[:, 0]))

    crosses = ((orientation(a[i], b[i], a[j]) * orientation(a[i], b[i], b[j]) < 0)
               & (orientation(a[j], b[j], a[i]) * orientation(a[j], b[j], b[i]) < 0))
    return bool(crosses.any())


def _inset_ring(ring: np.ndarray, d: float) -> np.ndarray:
    """``ring`` moved ``d`` towards its centroid (in its plane): the cap's support ring."""
    to_centre = ring.mean(axis=0) - ring
    length = np.maximum(np.linalg.norm(to_centre, axis=1), TOL.zero)[:, None]
    return ring + np.minimum(d, 0.5 * length) * to_centre / length


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

    # Vertices: every loop in counter-clockwise order about the axis.
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
    vertices = np.vstack(vertices)
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
        for low_idx, low_param, up_idx, up_param in pieces:
            if (event.kind == "one-to-one" and _star_shaped(planar_of(low_idx))
                    and _star_shaped(planar_of(up_idx))):
                local = zip_rings(low_param, up_param)
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
        plane[ring_vertices:ring_vertices + sum(len(x) for x in extra_vertices)] = -1
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
