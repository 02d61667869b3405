r"""Open surfaces from one-sided sections: open Catmull-Rom arcs stitched into a bordered mesh.

When the sections are open arcs over most of the object (one stereo pair, a relief,
a facade: :func:`one_sided`, the rule of ``surface.reconstruct.bridged_share``), each
section's ordered points become an *open* uniform Catmull-Rom curve (the paper's eq.
3,5 without closing): control points ``P_0 … P_n``, the curve runs through
``P_1 … P_{n−1}`` and segment ``j`` (between ``P_j`` and ``P_{j+1}``) is::

    Q_j(t) = ½ · [t³ t² t 1] · M_CR · [P_{j−1} P_j P_{j+1} P_{j+2}]ᵀ,   t ∈ [0, 1]

The end control points are the linear extrapolations ``P_0 = 2P_1 − P_2`` and
``P_n = 2P_{n−1} − P_{n−2}`` (reflection of the neighbour through the end), so the
end tangent is the end chord and the curve is linear in the interpolated points
``P_1 … P_{n−1}``: fitted by the least squares of ``surface.catmull_rom`` (its basis,
its third-difference fairness weight, its arc-length data parameters and its GCV
choice of the smoothing level), without the cyclic wrap.  The curve starts and ends
at the arc's first and last data points (their parameters are 0 and n − 2): it ends
where the data end.

Arcs are put on one common parameter ``u`` (:func:`align_arcs`): each arc is linked to
the one below by the affine function of its own arc length that best matches, in least
squares, the arc length of its points' nearest points on that arc (pairs whose nearest
point is an end of it are left out: there the arcs do not overlap); the surface is the
run of linked arcs with the most length, ``u`` the arc length of its longest arc carried
along the links.  On a surface of revolution seen from one side ``u`` is proportional to
the angle θ.  Odd sections are resampled every ``h`` in
``u``, even ones every ``h/2`` on the same grid (N and 2N per unit of ``u``; ``h`` is
the section spacing on the widest arc, as the closed rings' ``N = P_max/Δ``), at the
grid points within the arc's range, plus the arc's end itself where it lies more than
a quarter step past its last grid point: a ring never reaches past its data, and stops
short of them by less than a quarter of its spacing.

Strips (:func:`zip_arcs`): between two adjacent arcs, over the range of ``u`` both
cover (widened by a quarter step, so a strip's corner passes the other arc's end by at
most that), the direction criterion as a merge by ``u`` (each step advances the arc whose
next point comes first, the coarser on a tie: for N↔2N on the common grid exactly
the paper's ``(o_k, e_2k, e_2k+1), (o_k, e_2k+1, o_k+1), (o_k+1, e_2k+1, e_2k+2)``),
then Lawson flips (``surface.stitch.delaunay_flips``, never across a section contour).
The result is an oriented, manifold mesh with borders where the data end (a vertex
where two strips meet at a point only is split); faces are counter-clockwise seen from
outside each loop's centroid (the loops' counter-clockwise order), or facing
``viewpoint`` when given (the cameras': they saw the surface's outside).  A section
with several loops gives one arc of the pieces that continue one another
(:func:`chain_arcs`).

References
----------
.. [1] E. Catmull and R. Rom, "A class of local interpolating splines", Computer
   Aided Geometric Design, Academic Press (1974), 317–326.
.. [2] C. L. Lawson, "Software for C1 surface interpolation", in Mathematical
   Software III, Academic Press (1977), 161–194.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import sparse
from scipy.sparse import csgraph
from scipy.spatial import cKDTree

from surface._blas import one_blas_thread
from surface.catmull_rom import _FAIRNESS, M_CR, _basis
from surface.polygon import polygon_area
from surface.validate import TOL, check_finite, check_shape

__all__ = ["OpenCurve", "OpenSurface", "loop_arc", "fit_open", "one_sided", "align_arcs",
           "resample_arcs", "zip_arcs", "stitch_arcs", "boundary_loops",
           "open_surface_from_loops", "organise_arcs", "main_piece", "bridge_open_gaps",
           "open_arcs", "chain_arcs", "height_field_arc",
           "smooth_border", "open_share", "window_footprint", "smooth_across", "LINE_BAND",
           "QUARTER_STEP", "BORDER_SLOPE", "BORDER_PASSES", "BORDER_REACH"]

#: Share of a grid step an arc end may lie past its last grid point and still get an
#: end point there (the most the resampled arc reaches beyond its data is this share of
#: the ring spacing).
QUARTER_STEP = 0.25
#: How far along ``u`` (in grid steps) a strip's fan may join two neighbouring arcs'
#: ends: one step a section spacing is a border crossing the sections at 45° on the
#: widest arc, and the fan's triangles then span at most one ring step along ``u``, no
#: longer than the strips' own triangles (their chords' sagitta h²κ/8).  Where the
#: border runs closer to along the sections the ends differ more and the strip keeps
#: its step there: the border follows the data.
BORDER_SLOPE = 1.0
#: Passes of the (1, 2, 1)/4 filter over the sections in :func:`smooth_border`: a
#: Gaussian of σ = √(passes / 2) = 2 section spacings (where the matcher stops is noise
#: from section to section; the object's own border changes over many sections).
BORDER_PASSES = 8
#: How far past the overlap of two arcs (in grid steps) their strip reaches: the
#: trimmed ends of neighbours differ by at most :data:`BORDER_SLOPE` steps, and the
#: strip joins them (a fan from the shorter arc's end) instead of stopping at the
#: shorter one (a step in the border).
BORDER_REACH = BORDER_SLOPE + QUARTER_STEP
#: Most the length scale of ``u`` may change from one arc to the next (a factor): arcs
#: one section spacing apart whose lengths per unit of ``u`` differ more are not one
#: surface seen across them (a cluttered scene's unrelated arcs): the surface stops there
#: (:func:`align_arcs`).
MAX_SCALE_CHANGE = 2.0
#: Least share of the sections the run of overlapping arcs must hold (:func:`align_arcs`):
#: below it the arcs are not one surface seen from one side but pieces (a cluttered scene,
#: a facade's layers and windows: on the Sceaux facade at a quarter size the longest run
#: held 2 of 80 sections and Loop's patches over its one strip folded), and an open surface
#: of a few of them would be a wrong one.
MIN_RUN_SHARE = 0.5
#: Most resampled points per data point: the rings are one section spacing apart, about
#: two data spacings (surface.sections), so a sound alignment gives well under one.
MAX_RING_POINTS_PER_POINT = 4.0
#: Dense samples per curve segment for arc length and nearest points (chord error
#: ~ (h/16)² κ / 8: below 1e-4 of the spacing for a segment turning 30°).
_DENSE = 16


# --------------------------------------------------------------------------- curve
@dataclass(frozen=True)
class OpenCurve:
    """An open uniform Catmull-Rom curve (module notes).

    Attributes
    ----------
    control_points : (n + 1, 3) float64
        ``P_0 … P_n``; the curve interpolates ``P_1 … P_{n−1}`` (n ≥ 3).
    smoothing : float
        Data points per control point of the fit (1: interpolating).
    """

    control_points: np.ndarray
    smoothing: float = 1.0

    @property
    def segments(self) -> int:
        """Number of segments, ``n − 2``; the parameter runs over ``[0, segments]``."""
        return len(self.control_points) - 3

    def _split(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        t = np.clip(np.asarray(t, dtype=np.float64), 0.0, self.segments)
        seg = np.minimum(np.floor(t).astype(np.int64), self.segments - 1)
        return seg, t - seg

    def __call__(self, t: np.ndarray) -> np.ndarray:
        """Points ``(M, 3)`` at parameters ``t`` ``(M,)`` in ``[0, segments]`` (clipped)."""
        seg, local = self._split(t)
        cols = seg[:, None] + np.arange(4)                          # P_{j-1} .. P_{j+2}
        return np.einsum("mk,mkd->md", _basis(local), self.control_points[cols])

    def derivative(self, t: np.ndarray) -> np.ndarray:
        """``dQ/dt`` ``(M, 3)`` at ``t``."""
        seg, local = self._split(t)
        powers = np.stack([3 * local**2, 2 * local, np.ones_like(local),
                           np.zeros_like(local)], axis=1)
        cols = seg[:, None] + np.arange(4)
        return np.einsum("mk,mkd->md", 0.5 * powers @ M_CR, self.control_points[cols])

    def dense(self, per_segment: int = _DENSE) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Parameters ``(K,)``, points ``(K, 3)`` and cumulative chord length ``(K,)``."""
        t = np.linspace(0.0, self.segments, self.segments * per_segment + 1)
        pts = self(t)
        length = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0),
                                                                 axis=1))])
        return t, pts, length


def _extension(m: int) -> np.ndarray:
    """``(m + 2, m)`` map from the interpolated points to ``P_0 … P_n`` (reflected ends)."""
    ext = np.zeros((m + 2, m))
    ext[1:-1] = np.eye(m)
    ext[0, 0], ext[0, 1] = 2.0, -1.0
    ext[-1, -1], ext[-1, -2] = 2.0, -1.0
    return ext


def _moving_average(points: np.ndarray, window: int) -> np.ndarray:
    """``(M, 3)`` means of ``window`` consecutive points about each (shrinking at the ends)."""
    m = len(points)
    window = int(min(max(window, 1), max(1, m // 2)))
    csum = np.concatenate([np.zeros((1, 3)), np.cumsum(points, axis=0)])
    idx = np.arange(m)
    lo = np.clip(idx - window // 2, 0, m)
    hi = np.clip(idx - window // 2 + window, 0, m)
    lo = np.maximum(0, np.minimum(lo, hi - 1))
    return (csum[hi] - csum[lo]) / (hi - lo)[:, None]


def _open_parameters(points: np.ndarray, window: int, segments: int) -> np.ndarray:
    """Parameters ``(M,)`` in ``[0, segments]`` proportional to arc length along the arc.

    As ``catmull_rom._arc_parameters`` without the wrap: the arc length of a moving
    average of ``window`` points (shrinking at the ends), each point placed at its own
    foot on it; the ends map to 0 and ``segments``.
    """
    smooth = _moving_average(points, window)
    step = np.linalg.norm(np.diff(smooth, axis=0), axis=1)
    cum = np.concatenate([[0.0], np.cumsum(step)])
    total = float(cum[-1])
    if total <= TOL.zero:
        raise ValueError("points all coincide: cannot fit a curve")
    tangent = np.gradient(smooth, axis=0)
    tangent /= np.maximum(np.linalg.norm(tangent, axis=1), TOL.zero)[:, None]
    arc = cum + np.einsum("mi,mi->m", points - smooth, tangent)
    # the ends are the data's ends: rescale so the first and last points sit at 0, L
    arc = (arc - arc[0]) / max(arc[-1] - arc[0], TOL.zero) * total
    return np.clip(segments * arc / total, 0.0, segments)


def _least_squares(points: np.ndarray, m: int, smoothing: float, correlation: float = 0.0
                   ) -> tuple[np.ndarray, np.ndarray, float]:
    """Interpolated points ``(m, 3)`` of the open curve minimising
    ``Σ|Q(t_j) − x_j|² + λ Σ|Δ³P_i|²`` and the data parameters ``t`` ``(M,)``.

    λ is ``catmull_rom``'s fairness weight (1 % of the mean diagonal of ``AᵀA``);
    the system is ``m × m`` and dense (m is a few hundred at most).  The third value is
    ``tr(H R)``, H the fit's hat matrix and ``R_ij = max(0, 1 − |s_i − s_j|/ℓ)`` the
    correlation of errors shared over ``ℓ = correlation`` of arc length (a box window's
    overlap); ``tr(H)`` when ``correlation`` is 0.
    """
    window = max(int(round(smoothing)), int(np.ceil(np.sqrt(len(points)))))
    t = _open_parameters(points, window, m - 1)
    seg = np.minimum(np.floor(t).astype(np.int64), m - 2)
    weights = _basis(t - seg)                                      # (M, 4)
    ext = _extension(m)
    full = np.zeros((len(points), m + 2))                         # weights of P_0 .. P_n
    np.put_along_axis(full, seg[:, None] + np.arange(4), weights, axis=1)
    design = full @ ext                                            # (M, m)
    normal = design.T @ design
    third = np.diff(np.eye(m + 2), n=3, axis=0) @ ext              # (m - 1, m)
    system = normal + _FAIRNESS * float(np.diagonal(normal).mean()) * (third.T @ third)
    ctrl = np.linalg.solve(system, design.T @ points)
    if correlation <= 0:
        return ctrl, t, float(m)
    inverse = np.linalg.inv(system)
    df = float(np.einsum("ij,jk,ik->", design, inverse, design))          # tr(H)
    # + 2 Σ_{i<j} R_ij H_ij over the pairs closer than ℓ
    pos = t / max(m - 1, 1) * _length(_moving_average(points, window))
    pairs = cKDTree(pos[:, None]).query_pairs(correlation, output_type="ndarray")
    if len(pairs):
        i, j = pairs[:, 0], pairs[:, 1]
        h_ij = np.einsum("pk,kl,pl->p", design[i], inverse, design[j])
        df += 2.0 * float(np.sum((1.0 - np.abs(pos[i] - pos[j]) / correlation) * h_ij))
    return ctrl, t, df


def _normal_rss(points: np.ndarray, curve: OpenCurve, t: np.ndarray, frame: np.ndarray) -> float:
    """Sum of squared residuals normal to the curve, in the section plane."""
    resid = (points - curve(t)) @ frame[:2].T
    tangent = curve.derivative(t) @ frame[:2].T
    normal = np.stack([-tangent[:, 1], tangent[:, 0]], axis=1)
    normal /= np.maximum(np.linalg.norm(normal, axis=1), TOL.zero)[:, None]
    return float(np.sum(np.einsum("mi,mi->m", resid, normal) ** 2))


def fit_open(points: np.ndarray, smoothing: float | str = "auto",
             frame: np.ndarray | None = None, correlation: float = 0.0,
             least: float = 4.0) -> OpenCurve:
    """Fit an open Catmull-Rom curve to the ordered points of an arc.

    Parameters
    ----------
    points : (M, 3) float64, M ≥ 4
        The arc's points in order from one end to the other.
    smoothing : float or "auto"
        Data points per control point: ``≤ 1`` interpolates every point (the
        curve passes through them, ``P_{j+1} = x_j``); ``s > 1`` fits
        ``max(3, round(M/s))`` interpolated points by least squares.  ``"auto"``:
        generalised cross-validation over s = 4, 8, 16, … (as
        ``surface.catmull_rom.choose_smoothing``, never below 4), ``M·RSS/(M − m)²``
        with residuals normal to the curve in the section plane.
    frame : (3, 3) float64, optional
        Section frame (rows e1, e2, normal) for the GCV residuals; default the
        points' best-fit plane.
    correlation : float
        Length ℓ (scene units) over which the points' errors are shared: the matcher's
        window on the surface (:func:`window_footprint`).  GCV then scores
        ``(RSS/M) / (1 − tr(H R)/M)²``, the fit's degrees of freedom counted over the
        shared errors (``R_ij = max(0, 1 − |s_i − s_j|/ℓ)`` along the arc: about one
        independent point per ℓ, so ``tr(H R) ≈ m·M/(L/ℓ)``), over s = 4, 4√2, 8, …
        down to 3 control points (the fewest when every level has as many degrees of
        freedom as data).  0: the points are independent (the plain GCV above).
    least : float
        The ladder's first level (data points per control point; 4 above).

    Returns
    -------
    OpenCurve
    """
    pts = check_shape(points, "(M, 3)", "points", dtype=np.float64)
    check_finite(pts, "points")
    if len(pts) < 4:
        raise ValueError(f"points: an open curve needs at least 4 points, got {len(pts)}")
    if isinstance(smoothing, str) and smoothing != "auto":
        raise ValueError(f"smoothing must be a number >= 0 or 'auto', got {smoothing!r}")
    m_data = len(pts)
    if smoothing != "auto" and smoothing <= 1:
        return OpenCurve(np.ascontiguousarray(_extension(m_data) @ pts), 1.0)
    if frame is None:
        centred = pts - pts.mean(axis=0)
        frame = np.linalg.svd(centred, full_matrices=False)[2]
    # with shared errors a finer ladder (√2): the penalty grows fast as m nears M_eff
    fewest, ratio = (8, 2.0) if correlation <= 0 else (3, 2.0**0.5)
    candidates = [float(smoothing)] if smoothing != "auto" else \
        [least * ratio**k for k in range(64) if m_data / (least * ratio**k) >= fewest] \
        or [least]
    best = None
    for s in candidates:
        m = max(3, min(m_data, int(round(m_data / s))))
        ctrl, t, df = _least_squares(pts, m, s, correlation)
        curve = OpenCurve(np.ascontiguousarray(_extension(m) @ ctrl), s)
        rss = _normal_rss(pts, curve, t, frame)
        if correlation <= 0:
            score = m_data * rss / max(m_data - m, 1) ** 2
        else:  # as many degrees of freedom as data over the shared errors: fits them
            score = rss / m_data / (1.0 - df / m_data) ** 2 if df < m_data else math.inf
        if best is None or score < best[0] or (score == best[0] == math.inf):
            best = (score, curve)  # (all infinite: the last, the fewest control points)
    return best[1]


def window_footprint(points: np.ndarray, centres: np.ndarray, focals: np.ndarray,
                     patch: float) -> float:
    """Length (scene units) the matcher's ``patch``-pixel window covers at ``points``:
    ``patch × d / f`` (median over the points), ``d`` each point's distance to its nearest
    camera centre ``centres`` ``(K, 3)``, ``f`` that camera's focal length ``focals``
    ``(K,)`` px.  Two points whose windows overlap share image pixels, so their errors
    are shared; for a box window the correlation falls as 1 − h/W and integrates to W:
    one independent point per W along a line (:func:`fit_open`'s ``correlation``).  On a
    surface seen obliquely the footprint is longer (a lower bound)."""
    centres = np.asarray(centres, np.float64).reshape(-1, 3)
    dist, which = cKDTree(centres).query(np.asarray(points, np.float64))
    return float(patch * np.median(dist / np.asarray(focals, np.float64)[which]))


# --------------------------------------------------------------------------- arcs
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
    from surface.catmull_rom import bridge_gaps

    return bridge_gaps(arc, link, closed=False)


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
    from surface.reconstruct import MAX_BRIDGED_SHARE

    return open_share(list(loops)) > MAX_BRIDGED_SHARE


@dataclass(frozen=True)
class _Placed:
    """A curve's dense samples on the common parameter: ``u = offset + scale · s``."""

    t: np.ndarray
    points: np.ndarray
    length: np.ndarray
    offset: float
    scale: float

    @property
    def u(self) -> np.ndarray:
        return self.offset + self.scale * self.length


def _match(placed: _Placed, t, pts, length) -> tuple[float, float, int] | None:
    """Affine ``u = a + c·s`` of an arc from nearest points on a placed neighbour."""
    _, nearest = cKDTree(placed.points).query(pts)
    inside = (nearest > 1) & (nearest < len(placed.points) - 2)   # not past its ends
    if np.count_nonzero(inside) < 8:
        return None
    s, u = length[inside], placed.u[nearest[inside]]
    keep = np.ones(len(s), bool)
    for _ in range(2):  # one pass of a 3-MAD cut against pairs across a fold
        c, a = np.polyfit(s[keep], u[keep], 1)
        resid = u - (a + c * s)
        mad = 1.4826 * np.median(np.abs(resid[keep] - np.median(resid[keep])))
        keep = np.abs(resid) <= 3 * mad + TOL.zero * (1 + abs(u).max())
        if np.count_nonzero(keep) < 8:
            return None
    c, a = np.polyfit(s[keep], u[keep], 1)
    return float(a), float(c), int(np.count_nonzero(keep))


def align_arcs(curves: list[OpenCurve]
               ) -> tuple[list[OpenCurve], list[_Placed], list[str], range]:
    """Put the arcs on one parameter ``u`` (module notes), reversing arcs that run
    against their neighbours.

    Each arc is linked to the one below by the affine map of :func:`_match` (its arc
    length onto the lower arc's); a link fails where the arcs do not overlap or the map's
    scale is off by more than :data:`MAX_SCALE_CHANGE`.  The surface is the run of
    linked arcs with the most length; ``u`` is the arc length of its longest arc, carried
    along the links.

    Returns
    -------
    curves : list of OpenCurve
        Some reversed.
    placed : list
        The run's arcs' dense samples and their ``u`` map (None outside the run).
    notes : list of str
    run : range
        Indices of the arcs in the run.
    """
    curves = list(curves)
    dense = [c.dense() for c in curves]
    links: list = [None] * len(curves)     # links[k]: s_{k-1} = a + c * s_k
    for k in range(1, len(curves)):
        below = _Placed(*dense[k - 1], 0.0, 1.0)
        fit = _match(below, *dense[k])
        if fit is not None and fit[1] < 0:  # runs the other way: reverse the arc
            curves[k] = OpenCurve(curves[k].control_points[::-1].copy(), curves[k].smoothing)
            dense[k] = curves[k].dense()
            fit = _match(below, *dense[k])
        if fit is not None and MAX_SCALE_CHANGE ** -1 <= fit[1] <= MAX_SCALE_CHANGE:
            links[k] = fit
    runs, lo = [], 0
    for k in range(1, len(curves) + 1):
        if k == len(curves) or links[k] is None:
            runs.append(range(lo, k))
            lo = k
    run = max(runs, key=lambda r: sum(dense[k][2][-1] for k in r))
    notes = []
    if len(run) < len(curves):
        notes.append(f"{len(curves) - len(run)} of {len(curves)} arcs left out: they do not "
                     f"overlap the run of arcs {run.start}..{run.stop - 1} (the surface's) "
                     "section to section")
    ref = max(run, key=lambda k: dense[k][2][-1])
    placed: list = [None] * len(curves)
    placed[ref] = _Placed(*dense[ref], 0.0, 1.0)
    for k in range(ref + 1, run.stop):   # U_k(s) = U_{k-1}(a + c s)
        a, c, _ = links[k]
        prev = placed[k - 1]
        placed[k] = _Placed(*dense[k], prev.offset + prev.scale * a, prev.scale * c)
    for k in range(ref - 1, run.start - 1, -1):   # U_k(s) = U_{k+1}((s - a) / c)
        a, c, _ = links[k + 1]
        nxt = placed[k + 1]
        placed[k] = _Placed(*dense[k], nxt.offset - nxt.scale * a / c, nxt.scale / c)
    return curves, placed, notes, run


def place_across(curves: list[OpenCurve], across: np.ndarray
                 ) -> tuple[list[OpenCurve], list[_Placed], list[str], range]:
    """:func:`align_arcs` for height-field arcs (:func:`height_field_arc`): ``u`` is the
    position along ``across`` itself, the same for every section, so nothing is carried
    from arc to arc (on the Sceaux facade the carried scale drifted tenfold over 244
    sections: arcs of depth steps and noise are longer than their neighbours by a few
    per cent each).  Along each arc ``u`` is made non-decreasing (its running maximum: a
    depth step parallel to the view is crossed at one ``u``).  Every arc is kept (what
    the cameras see: the object and the scene about it); neighbours whose ranges of
    ``u`` do not overlap get no strip between them (:func:`stitch_arcs`)."""
    placed = []
    for curve in curves:
        t, pts, _ = curve.dense()
        placed.append(_Placed(t, pts, np.maximum.accumulate(pts @ across), 0.0, 1.0))
    apart = sum(1 for k in range(1, len(curves))
                if min(placed[k].u[-1], placed[k - 1].u[-1]) <= max(placed[k].u[0],
                                                                     placed[k - 1].u[0]))
    notes = [f"{apart} of {len(curves) - 1} pairs of neighbouring arcs do not overlap "
             "across the view: the surface has a border between them"] if apart else []
    return curves, placed, notes, range(len(curves))


def smooth_border(ends: np.ndarray, step: float) -> np.ndarray:
    """Where each arc's ring ends on the border's side of larger ``u``: a smooth curve
    over the sections that never passes an arc's own end.

    Where LSM stops changes from section to section by the matcher's luck (a texture
    patch, a window that failed): on the default stereo recipe neighbouring arcs end
    0.5 (median) to 2 (90th percentile) grid steps apart.  Strips that stop where the
    shorter of their two arcs ends make a staircase of that size.  The border is instead
    a smooth curve ``b`` under the arcs' ends (``b_k ≤ e_k``: nothing past the data):
    :data:`BORDER_PASSES` passes of the (1, 2, 1)/4 filter over the sections, each
    clipped to the ends again (an obstacle problem: it rests on the shortest arcs and
    spans the others; a straight run of ends is kept as it is).  No bound on its slope:
    where an object's border runs nearly along the sections (a board's edge, the last
    sections of a run) the ends move many steps a section, and a slope bound carried
    along would trim every arc to the shortest one's reach (on the chessboard pair 03 it
    kept 28 % of the stitched area; without it 93 %).

    Parameters
    ----------
    ends : (K,) float64
        The arcs' ends in ``u``, in section order.
    step : float
        The odd arcs' grid step in ``u``.

    Returns
    -------
    (K,) float64, ``≤ ends``.
    """
    e = np.asarray(ends, np.float64)
    if len(e) < 3:
        return e.copy()
    b = e.copy()
    for _ in range(BORDER_PASSES):
        padded = np.concatenate([b[:1], b, b[-1:]])
        b = np.minimum(e, 0.25 * padded[:-2] + 0.5 * padded[1:-1] + 0.25 * padded[2:])
    return b


def resample_arcs(curves: list[OpenCurve], placed: list[_Placed], step: float,
                  smooth: bool = True) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Resample every arc on the common grid of ``u``: section ``k`` every ``step``
    (``k`` even: the paper's odd sections, N points) or ``step/2`` (2N).

    Returns the rings ``(n_k, 3)`` and their ``u`` ``(n_k,)`` (increasing).  With
    ``smooth`` each ring runs between the border curves of :func:`smooth_border` (both
    sides), which lie within the arc's data: its grid points more than a quarter of its
    step inside them, and a point on each border curve itself.  Without, between the
    arc's own ends: the grid points inside its range, and an end lying past its last grid
    point by more than :data:`QUARTER_STEP` of the step gets an extra point at the end.
    """
    origin = min(float(p.u.min()) for p in placed)
    lo = np.array([float(p.u[0]) for p in placed])
    hi = np.array([float(p.u[-1]) for p in placed])
    if smooth:
        b_lo, b_hi = -smooth_border(-lo, step), smooth_border(hi, step)
        # an arc the border curves would cut to less than a step keeps its own ends
        short = b_hi - b_lo < step
        b_lo, b_hi = np.where(short, lo, b_lo), np.where(short, hi, b_hi)
    rings, params = [], []
    for k, (curve, where) in enumerate(zip(curves, placed, strict=True)):
        h = step if k % 2 == 0 else step / 2
        if smooth:
            u_lo, u_hi = float(b_lo[k]), float(b_hi[k])
            first = math.ceil((u_lo - origin) / h + QUARTER_STEP)
            last = math.floor((u_hi - origin) / h - QUARTER_STEP)
            u = np.concatenate([[u_lo], origin + h * np.arange(first, last + 1), [u_hi]])
        else:
            u_lo, u_hi = lo[k], hi[k]
            first = math.ceil((u_lo - origin) / h - TOL.angle)
            last = math.floor((u_hi - origin) / h + TOL.angle)
            u = origin + h * np.arange(first, last + 1)
            if len(u) == 0 or u[0] - u_lo > QUARTER_STEP * h:
                u = np.concatenate([[u_lo], u])
            if u_hi - u[-1] > QUARTER_STEP * h:
                u = np.append(u, u_hi)
        s = (u - where.offset) / where.scale
        t = np.interp(s, where.length, where.t)
        rings.append(curve(t))
        params.append(u)
    return rings, params


#: First level of a column's GCV ladder (points per control point): a column's points are
#: one section spacing apart, an arc's about half of one (``surface.sections``), so the
#: arcs' 4 would be 4 sections here, twice theirs; √2 is the ladder's first step above
#: interpolation (the stereo vase at half size: rings 0.00085 from the truth with 4, 0.00053
#: with √2, 0.00058 without smoothing across).
_COLUMN_LEAST = 2.0**0.5


def _foot_on_polyline(line: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Each point's nearest point ``(P, 3)`` on the polyline ``line`` ``(K, 3)``: its foot
    on the segments either side of its nearest vertex (not the vertex: a dense sample
    lies up to half its spacing along the curve from the foot)."""
    _, near = cKDTree(line).query(points)
    best, dist = line[near], np.linalg.norm(points - line[near], axis=1)
    for a in (np.maximum(near - 1, 0), near):
        b = np.minimum(a + 1, len(line) - 1)
        seg = line[b] - line[a]
        t = np.einsum("pi,pi->p", points - line[a], seg) / np.maximum(
            np.einsum("pi,pi->p", seg, seg), TOL.zero)
        foot = line[a] + np.clip(t, 0.0, 1.0)[:, None] * seg
        d = np.linalg.norm(points - foot, axis=1)
        best = np.where((d < dist)[:, None], foot, best)
        dist = np.minimum(d, dist)
    return best


def smooth_across(rings: list[np.ndarray], params: list[np.ndarray], step: float,
                  origin: float, axis: np.ndarray, correlation: float) -> list[np.ndarray]:
    """The rings smoothed across the sections: each column of grid points at one ``u``
    (every ``step``: on every ring) through consecutive sections, 4 or more of them, is
    fitted by :func:`fit_open` with the errors shared over ``correlation`` (the matcher's
    window), and each point moved to its nearest point on that curve, within its own
    section plane (normal to ``axis``); the even rings' half-step points and the border
    points move as their ring's nearest column points (the mean of the two about them).
    ``origin``: the grid's origin in ``u`` (:func:`resample_arcs`'s, the least ``u``).

    Each arc is fitted alone (:func:`open_arcs`): errors shared over a window make whole
    arcs lie off their neighbours, a ripple from section to section that no fit along
    them removes (the chessboard pairs' rings, where LSM sees texture only at the
    squares' edges, and each section crosses other edges).
    """
    axis = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    counts = np.array([len(r) for r in rings])
    ring = np.repeat(np.arange(len(rings)), counts)
    points = np.concatenate(rings)
    half = np.concatenate(params) - origin
    half = half / (step / 2)
    grid = np.rint(half).astype(np.int64)
    on_grid = np.abs(half - grid) < 1e-6
    column = on_grid & (grid % 2 == 0)
    move = np.zeros_like(points)
    # columns: (u, ring) sorted; a run of consecutive rings at one u
    idx = np.flatnonzero(column)
    idx = idx[np.lexsort((ring[idx], grid[idx]))]
    breaks = np.flatnonzero((np.diff(grid[idx]) != 0) | (np.diff(ring[idx]) != 1)) + 1
    for run in np.split(idx, breaks):
        if len(run) < 4:
            continue
        curve = fit_open(points[run], "auto", correlation=correlation, least=_COLUMN_LEAST)
        move[run] = _foot_on_polyline(curve.dense()[1], points[run]) - points[run]
    # the other points: the mean move of their ring's column points about them
    key = ring.astype(np.int64) * (int(grid.max()) + 4) + grid
    col_keys, col_idx = key[column], np.flatnonzero(column)
    order = np.argsort(col_keys)
    col_keys, col_idx = col_keys[order], col_idx[order]
    rest = np.flatnonzero(~column)
    below = np.floor(half[rest] / 2).astype(np.int64) * 2
    total, weight = np.zeros((len(rest), 3)), np.zeros(len(rest))
    for side in (below, below + 2):
        want = ring[rest].astype(np.int64) * (int(grid.max()) + 4) + side
        at = np.clip(np.searchsorted(col_keys, want), 0, max(len(col_keys) - 1, 0))
        found = (col_keys[at] == want) if len(col_keys) else np.zeros(len(rest), bool)
        total[found] += move[col_idx[at[found]]]
        weight[found] += 1.0
    move[rest] = total / np.maximum(weight, 1.0)[:, None]
    move -= np.outer(move @ axis, axis)            # stay in the section's plane
    return np.split(points + move, np.cumsum(counts)[:-1])


def zip_arcs(u_lower: np.ndarray, u_upper: np.ndarray) -> np.ndarray:
    """Triangulate the strip between two open arcs by merging their parameters.

    Parameters
    ----------
    u_lower : (n_a,) float64
        Increasing common parameter of the lower arc's points (n_a ≥ 1).
    u_upper : (n_b,) float64
        The same for the upper arc.

    Returns
    -------
    (n_a + n_b − 2, 3) int64
        Faces over local indices (lower ``0 .. n_a − 1``, upper from ``n_a``), in
        the orientation of ``surface.stitch.zip_rings``: the next triangle advances
        the arc whose next point comes first, the coarser on a tie.
    """
    n_a, n_b = len(u_lower), len(u_upper)
    tie = TOL.angle * max(1.0, float(np.abs(np.concatenate([u_lower, u_upper])).max()))
    bias_a = tie if n_a <= n_b else 0.0
    bias_b = 0.0 if n_a <= n_b else tie
    keys = np.concatenate([u_lower[1:] - bias_a, u_upper[1:] - bias_b])
    is_a = np.concatenate([np.ones(n_a - 1, bool), np.zeros(n_b - 1, bool)])
    is_a = is_a[np.argsort(keys, kind="stable")]
    i_a = np.cumsum(is_a) - is_a
    i_b = np.cumsum(~is_a) - ~is_a
    b0, b1 = n_a + i_b, n_a + i_b + 1
    return np.where(is_a[:, None], np.stack([i_a, i_a + 1, b0], axis=1),
                    np.stack([i_a, b1, b0], axis=1)).astype(np.int64)


def _overlap(u_a: np.ndarray, u_b: np.ndarray, tol: float) -> tuple[np.ndarray, np.ndarray]:
    """Indices of each arc's points within the range of ``u`` both arcs cover."""
    lo, hi = max(u_a[0], u_b[0]) - tol, min(u_a[-1], u_b[-1]) + tol
    return (np.flatnonzero((u_a >= lo) & (u_a <= hi)),
            np.flatnonzero((u_b >= lo) & (u_b <= hi)))


# --------------------------------------------------------------------------- mesh
@dataclass
class OpenSurface:
    """A stitched open mesh (:func:`stitch_arcs`).

    Attributes
    ----------
    vertices : (V, 3) float64
    triangles : (F, 3) int64
        Oriented faces (module notes); vertices used by no face are dropped.
    boundary : list of (B_i,) int64
        Each border loop's vertex ids, in order.
    boundary_length : float
        Total length of the border loops, scene units.
    flips : int
    delaunay_fraction : float
        Share of flippable interior edges meeting the local Delaunay criterion.
    notes : list of str
    """

    vertices: np.ndarray
    triangles: np.ndarray
    boundary: list
    boundary_length: float
    flips: int
    delaunay_fraction: float
    notes: list = field(default_factory=list)

    def info(self) -> dict:
        """The manifest's figures."""
        return {"open": True, "boundary_loops": len(self.boundary),
                "boundary_length": float(self.boundary_length), "flips": int(self.flips),
                "delaunay_fraction": float(self.delaunay_fraction)}


@one_blas_thread
def stitch_arcs(rings: Sequence[np.ndarray], params: Sequence[np.ndarray], step: float,
                flip: bool = True, viewpoint: np.ndarray | None = None,
                reach: float = QUARTER_STEP) -> OpenSurface:
    """Stitch consecutive resampled arcs into an open mesh.

    Parameters
    ----------
    rings : sequence of (n_k, 3) float64
        Resampled arcs in section order, running counter-clockwise about the axis
        (as :func:`resample_arcs` gives them).
    params : sequence of (n_k,) float64
        Their common parameter ``u``.
    step : float
        The odd sections' grid step in ``u``.
    reach : float
        Points within ``reach`` steps beyond the overlap of two arcs still join their
        strip (a fan from the shorter arc's end): :data:`BORDER_REACH` for rings
        resampled between :func:`smooth_border` curves (the border then runs from arc
        end to arc end), a quarter step for rings that end where their own data end.
    flip : bool
        Lawson flips after stitching.
    viewpoint : (3,) or (K, 3) float64, optional
        Points the surface was seen from; the faces are turned to face them (by the
        area-weighted majority).  Default: keep the arcs' counter-clockwise order
        (normals away from their centres of curvature on a convex object).

    Returns
    -------
    OpenSurface
    """
    from surface.metrics import delaunay_fraction
    from surface.stitch import delaunay_flips

    offsets = np.concatenate([[0], np.cumsum([len(r) for r in rings])]).astype(np.int64)
    vertices = np.concatenate([np.asarray(r, np.float64) for r in rings])
    faces, region, fixed, notes = [], [], [], []
    tol = reach * step
    for k in range(len(rings) - 1):
        ia, ib = _overlap(params[k], params[k + 1], tol)
        if len(ia) < 1 or len(ib) < 1 or len(ia) + len(ib) < 3:
            notes.append(f"arcs {k} and {k + 1} do not overlap: no strip between them")
            continue
        local = zip_arcs(params[k][ia], params[k + 1][ib])
        glob = np.concatenate([offsets[k] + ia, offsets[k + 1] + ib])
        faces.append(glob[local])
        region.append(np.full(len(local), k))
        for ids, off in ((ia, offsets[k]), (ib, offsets[k + 1])):
            fixed.append(np.stack([off + ids[:-1], off + ids[1:]], axis=1))
    if not faces:
        raise ValueError("no two neighbouring arcs overlap: no open surface")
    tri = np.concatenate(faces)
    reg = np.concatenate(region)
    fixed_edges = np.concatenate(fixed)
    tri, reg = _drop_degenerate(vertices, tri, reg)
    flips = 0
    if flip:
        tri, flips, _ = delaunay_flips(vertices, tri, region=reg, fixed_edges=fixed_edges)
    if viewpoint is not None and _faces_away(vertices, tri, viewpoint):
        tri = tri[:, ::-1].copy()
    vertices, tri, pinches = _split_pinches(vertices, tri)
    if pinches:
        notes.append(f"{pinches} vertex(es) where two strips met at a point only were "
                     "split (the border touches itself there)")
    used = np.unique(tri)
    remap = np.full(len(vertices), -1, np.int64)
    remap[used] = np.arange(len(used))
    vertices, tri = vertices[used], remap[tri]
    fraction = delaunay_fraction(vertices, tri)
    loops = boundary_loops(tri)
    length = float(sum(np.linalg.norm(vertices[lp] - vertices[np.roll(lp, -1)], axis=1).sum()
                       for lp in loops))
    return OpenSurface(vertices, tri, loops, length, int(flips), fraction, notes)


def _split_pinches(vertices: np.ndarray, tri: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """Give every extra fan of a pinched vertex its own copy of the vertex.

    Where the strips below and above an arc cover ranges of it that share one point only
    (arcs drifting sideways), that point's faces form two fans joined at it alone: a
    non-manifold vertex, which the Bézier construction refuses.  Such a vertex has more
    than two border edges; its fans are the faces connected through edges at it.
    """
    directed = np.stack([tri, np.roll(tri, -1, axis=1)], axis=2).reshape(-1, 2)
    n = len(vertices)
    keys = directed[:, 0] * n + directed[:, 1]
    border = directed[~np.isin(directed[:, 1] * n + directed[:, 0], keys)]
    degree = np.bincount(border.ravel(), minlength=n)
    candidates = np.flatnonzero(degree > 2)
    if len(candidates) == 0:
        return vertices, tri, 0
    tri = tri.copy()
    extra = []
    for v in candidates.tolist():  # a few vertices at most, not one per point
        faces = np.flatnonzero((tri == v).any(axis=1))
        # fans: faces joined through an edge (v, w), i.e. sharing a vertex w other than v
        others = tri[faces][tri[faces] != v].reshape(-1, 2)
        ws, w_index = np.unique(others, return_inverse=True)
        f, m = len(faces), len(ws)
        graph = sparse.coo_matrix((np.ones(2 * f), (np.repeat(np.arange(f), 2),
                                                     f + w_index.ravel())), shape=(f + m, f + m))
        label = csgraph.connected_components(graph, directed=False)[1][:f]
        for group in np.unique(label)[1:]:
            extra.append(vertices[v])
            fan = tri[faces[label == group]]
            fan[fan == v] = n + len(extra) - 1
            tri[faces[label == group]] = fan
    return np.concatenate([vertices, np.array(extra)]), tri, len(extra)


def _drop_degenerate(vertices, tri, reg):
    """Faces of zero area (two arcs' end points at one place) are left out."""
    from surface.metrics import triangle_areas

    scale = float(np.ptp(vertices, axis=0).max()) if len(vertices) else 1.0
    keep = triangle_areas(vertices, tri) > TOL.zero * max(scale, 1.0) ** 2
    return tri[keep], reg[keep]


def _faces_away(vertices: np.ndarray, tri: np.ndarray, viewpoint) -> bool:
    """Whether most of the area faces away from the viewpoint(s)."""
    from surface.metrics import face_normals

    eyes = np.atleast_2d(np.asarray(viewpoint, np.float64))
    normals = face_normals(vertices, tri, unit=False)          # length 2·area
    centres = vertices[tri].mean(axis=1)
    towards = eyes.mean(axis=0) - centres
    return float(np.einsum("fi,fi->f", normals, towards).sum()) < 0


def boundary_loops(triangles: np.ndarray) -> list[np.ndarray]:
    """The border loops of an oriented edge-manifold mesh, each as its vertex ids in order.

    A border edge is a directed face edge whose reverse is no face's; each border
    vertex of a vertex-manifold mesh starts exactly one, so following them closes
    the loops.
    """
    tri = np.asarray(triangles, np.int64)
    directed = np.stack([tri, np.roll(tri, -1, axis=1)], axis=2).reshape(-1, 2)
    n = int(tri.max()) + 1 if tri.size else 1
    keys = directed[:, 0] * n + directed[:, 1]
    reverse = directed[:, 1] * n + directed[:, 0]
    border = directed[~np.isin(reverse, keys)]
    nxt = dict(zip(border[:, 0].tolist(), border[:, 1].tolist(), strict=False))
    loops, seen = [], set()
    for start in border[:, 0].tolist():
        if start in seen:
            continue
        loop, v = [], start
        while v not in seen and v in nxt:
            seen.add(v)
            loop.append(v)
            v = nxt[v]
        loops.append(np.array(loop, np.int64))
    return loops


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
    from dataclasses import replace

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
    import warnings

    from surface.reconstruct import _drop_one_section_splits
    from surface.topology import SectionSkippedWarning, organise

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


@one_blas_thread
def open_arcs(loops: Sequence, spacing: float, n: int | None = None,
              smoothing: float | str = "auto", border: bool = True,
              view: np.ndarray | None = None,
              window: tuple[np.ndarray, np.ndarray, float] | None = None):
    """Sections' loops → open arcs → open curves → arcs resampled on the common grid.

    Parameters
    ----------
    loops : sequence of sequence of surface.topology.Loop
        Per section in height order (:func:`organise_arcs`); a section with several
        loops gives one arc of those that continue one another (:func:`chain_arcs`).
    spacing : float
        Distance between the sections, scene units: the odd arcs' ring spacing on the
        widest arc (the closed rings' rule ``N = P_max / Δ``) unless ``n`` is given.
    n : int, optional
        Points on the widest odd arc instead.
    smoothing : float or "auto"
        :func:`fit_open`.
    border : bool
        The rings end on the smooth border curves (:func:`smooth_border`; stitch them
        with ``reach=BORDER_REACH``); False: where each arc's data end (the former rule,
        a staircase border; for comparison).
    view : (3,) float64, optional
        The mean of the cameras' unit viewing directions: each section's loops become one
        height field across it (:func:`height_field_arc`: the nearest piece at each
        position across the view) on the parameter ``u`` across it
        (:func:`place_across`); without it, when it is shorter than 1/2 (the cameras do
        not share a view) or when the sections face it within 45° (depth slabs), the
        pieces that continue one another (:func:`chain_arcs`) on :func:`align_arcs`.
    window : (centres (K, 3), focals (K,), patch), optional
        The cameras' centres and focal lengths (px) and the matcher's window (px): each
        arc's GCV counts one independent point per the window's footprint on it
        (:func:`window_footprint`, :func:`fit_open`'s ``correlation``); without it every
        point is independent.

    Returns
    -------
    curves : list of OpenCurve
    rings, params : list of (n_k, 3) and (n_k,) float64
        The resampled arcs and their common parameter ``u``.
    step : float
        The odd arcs' grid step in ``u``.
    notes : list of str
    run : range
        The sections (indices into ``loops``) the arcs come from: the run of arcs that
        overlap section to section (:func:`align_arcs`).
    """
    if not spacing > 0:
        raise ValueError(f"spacing must be > 0, got {spacing}")
    notes, curves, data, partial = [], [], 0, 0
    across = None
    if view is not None and np.linalg.norm(view) >= 0.5 and loops and loops[0]:
        # (a mean of the cameras' unit view directions shorter than 1/2: they do not
        # share one view)
        axis = np.asarray(loops[0][0].frame, np.float64)[2]
        across = np.cross(axis, np.asarray(view, np.float64) / np.linalg.norm(view))
        # sections within 45° of facing the view cut it into depth slabs: no height field
        across = across / np.linalg.norm(across) if np.linalg.norm(across) > 0.5**0.5 \
            else None
    for section_loops in loops:
        best = max(section_loops, key=len)
        pieces = [loop_arc(lp) for lp in section_loops]
        if across is not None:  # a loop's runs between its gaps may lie at other depths
            pieces = [run for piece, lp in zip(pieces, section_loops, strict=True)
                      for run in _runs_between_gaps(piece, getattr(lp, "bridge", math.inf))]
        arc, used = (chain_arcs(pieces) if across is None else
                     height_field_arc(pieces, across, view))
        data += len(arc)
        if used < len(section_loops):
            partial += 1
            if partial <= 3:
                notes.append(f"section at height {best.height:.6g}: {len(section_loops)} "
                             f"loops, {used} piece(s) kept as one arc ({len(arc)} points)"
                             + (" (the pieces that continue one another)" if across is None
                                else " (one depth across the view)"))
        arc = bridge_open_gaps(arc, getattr(best, "bridge", math.inf))
        correlation = window_footprint(arc, *window) if window is not None else 0.0
        curves.append(fit_open(arc, smoothing, frame=best.frame, correlation=correlation))
    if partial > 3:
        notes.append(f"... and {partial - 3} more sections with pieces left out")
    curves, placed, align_notes, run = (align_arcs(curves) if across is None else
                                        place_across(curves, across))
    notes += align_notes
    if len(run) < MIN_RUN_SHARE * len(curves) or len(run) < 2:
        raise ValueError(f"the arcs do not line up as one surface: the longest run of arcs "
                         f"that overlap section to section holds {len(run)} of "
                         f"{len(curves)} sections")
    curves, placed = [curves[k] for k in run], [placed[k] for k in run]
    loops = [loops[k] for k in run]
    if n is None:
        # the widest arc (smallest scale: most length per unit of u) gets ring points
        # one section spacing apart
        step = spacing * min(p.scale for p in placed)
    else:
        widest = max(placed, key=lambda p: float(p.u[-1] - p.u[0]))
        step = float(widest.u[-1] - widest.u[0]) / max(int(n) - 1, 1)
    counts = [float(p.u[-1] - p.u[0]) / (step if k % 2 == 0 else step / 2) + 2
              for k, p in enumerate(placed)]
    if sum(counts) > MAX_RING_POINTS_PER_POINT * data:
        raise ValueError(f"the arcs do not line up as one surface: resampling them would "
                         f"take {sum(counts):.3g} ring points for {data} data points")
    rings, params = resample_arcs(curves, placed, step, smooth=border)
    if window is not None:  # errors shared over the window: whole arcs off, across too
        axis = np.asarray(loops[0][0].frame, np.float64)[2]
        sample = np.concatenate(rings)[:: max(1, sum(map(len, rings)) // 4096)]
        origin = min(float(p.u.min()) for p in placed)
        rings = smooth_across(rings, params, step, origin, axis,
                              window_footprint(sample, *window))
    return curves, rings, params, float(step), notes, run


def open_surface_from_loops(loops: Sequence, spacing: float, n: int | None = None,
                            smoothing: float | str = "auto", flip: bool = True,
                            viewpoint: np.ndarray | None = None
                            ) -> tuple[OpenSurface, list[np.ndarray], list[np.ndarray]]:
    """:func:`open_arcs` then :func:`stitch_arcs`: the open mesh of one-sided sections.

    Returns
    -------
    surface : OpenSurface
    rings, params : list of (n_k, 3) and (n_k,) float64
        The resampled arcs and their common parameter (for the workspace).
    """
    _, rings, params, step, notes, _ = open_arcs(loops, spacing, n, smoothing)
    result = stitch_arcs(rings, params, step, flip=flip, viewpoint=viewpoint,
                         reach=BORDER_REACH)
    result.notes = notes + result.notes
    return result, rings, params
