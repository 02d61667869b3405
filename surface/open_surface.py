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
the angle θ.  Odd sections are resampled every ``h`` in ``u``, even ones every ``h/2``
on the same grid (``h``: the section spacing on the widest arc, as the closed rings'
``N = P_max/Δ``), within the arc's range plus its end: never past its data.

Errors shared over the matcher's window: GCV counts the fit's degrees of freedom over
them, and the rings are smoothed across the sections too (:func:`smooth_across`).  The
one-sided rule, a section's pieces to one arc, and the strips and mesh are
``surface.open_rule``, ``surface.open_pieces`` and ``surface.open_strips`` (imported here).

References
----------
.. [1] E. Catmull and R. Rom, "A class of local interpolating splines", Computer
   Aided Geometric Design, Academic Press (1974), 317–326.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from checks.robust import mad_sigma
from surface._blas import one_blas_thread
from surface.catmull_rom import _FAIRNESS, M_CR, _basis
from surface.open_pieces import (
    CONTINUATION_ANGLE,
    PIECE_REACH,
    _length,
    _runs_between_gaps,
    bridge_open_gaps,
    chain_arcs,
    depth_steps,
    height_field_arc,
    main_piece,
    organise_arcs,
)
from surface.open_rule import DOUBLED_PATH, LINE_BAND, loop_arc, one_sided, open_share
from surface.open_strips import QUARTER_STEP, OpenSurface, boundary_loops, stitch_arcs, zip_arcs
from surface.validate import TOL, check_finite, check_shape

__all__ = ["OpenCurve", "OpenSurface", "loop_arc", "fit_open", "one_sided", "align_arcs",
           "resample_arcs", "zip_arcs", "stitch_arcs", "boundary_loops",
           "open_surface_from_loops", "organise_arcs", "main_piece", "bridge_open_gaps",
           "open_arcs", "chain_arcs", "height_field_arc",
           "smooth_border", "open_share", "window_footprint", "smooth_across", "SHARED_BAND",
           "LINE_BAND",
           "QUARTER_STEP", "BORDER_SLOPE", "BORDER_PASSES", "BORDER_REACH", "DOUBLED_PATH",
           "CONTINUATION_ANGLE", "PIECE_REACH"]

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


def _least_squares(points: np.ndarray, m: int, smoothing: float, correlation: float = 0.0,
                   source: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, float]:
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
    gain = design @ np.linalg.inv(system)                  # H = gain · designᵀ
    df = float(np.einsum("ij,ij->", gain, design))                        # tr(H)
    # + 2 Σ_{i<j} R_ij H_ij over the pairs closer than ℓ; design row j is zero outside
    # the min(4, m) columns from its segment − 1 (clipped; the reflected ends folded in)
    pos = t / max(m - 1, 1) * _length(_moving_average(points, window))
    pairs = cKDTree(pos[:, None]).query_pairs(correlation, output_type="ndarray")
    if source is not None:  # errors shared only within one source (one pair's windows)
        pairs = pairs[(source[pairs[:, 0]] == source[pairs[:, 1]]) & (source[pairs[:, 0]] >= 0)]
    if len(pairs):
        i, j = pairs[:, 0], pairs[:, 1]
        width = min(4, m)
        cols = np.clip(seg[j] - 1, 0, m - width)[:, None] + np.arange(width)
        h_ij = np.einsum("pc,pc->p", gain[i[:, None], cols], design[j[:, None], cols])
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
             least: float = 4.0, noise: float = 0.0,
             source: np.ndarray | None = None) -> OpenCurve:
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
    noise : float
        The points' σ (RMS) when known: with ``correlation``, a level whose residuals'
        RMS exceeds :data:`SHARED_BAND` σ is not taken (that shape is relief, not errors
        shared over a window), and when no level is within it the plain GCV is used.
    source : (M,) int, optional
        With ``correlation``: each point's error source, the view pair that matched it
        (−1: fused from several).  Errors are shared only between points of one source
        (``R_ij = 0`` across sources and for −1): a shape two pairs show is not one pair's
        shared error, and it is fitted.  Without it every point is of one source (a
        stereo pair: relief at the window's scale and its shared error are not told apart).

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
    best = _ladder(pts, candidates, frame, correlation, noise, source)
    if best is None:  # every level beyond the points' noise: the shape is the data's
        return fit_open(pts, smoothing, frame, least=least)
    return best[0]


def _ladder(pts, candidates, frame, correlation, noise, source):
    """:func:`fit_open`'s GCV over the ladder ``candidates``: the best curve and its data
    parameters, or None when every level lies beyond :data:`SHARED_BAND` of ``noise``."""
    m_data, best = len(pts), None
    for s in candidates:
        m = max(3, min(m_data, int(round(m_data / s))))
        ctrl, t, df = _least_squares(pts, m, s, correlation, source)
        curve = OpenCurve(np.ascontiguousarray(_extension(m) @ ctrl), s)
        rss = _normal_rss(pts, curve, t, frame)
        if correlation > 0 and noise > 0 and rss > m_data * (SHARED_BAND * noise) ** 2:
            continue
        if correlation <= 0:
            score = m_data * rss / max(m_data - m, 1) ** 2
        else:  # as many degrees of freedom as data over the shared errors: fits them
            score = rss / m_data / (1.0 - df / m_data) ** 2 if df < m_data else math.inf
        if best is None or score < best[0] or (score == best[0] == math.inf):
            best = (score, curve, t)  # (all infinite: the last, the fewest control points)
    return None if best is None else best[1:]


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
        mad = mad_sigma(resid[keep])
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
                  smooth: bool = True, section: np.ndarray | None = None
                  ) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Resample every arc on the common grid of ``u``: section ``k`` every ``step``
    (``k`` even: the paper's odd sections, N points) or ``step/2`` (2N).

    Returns the rings ``(n_k, 3)`` and their ``u`` ``(n_k,)`` (increasing).  With
    ``smooth`` each ring runs between the border curves of :func:`smooth_border` (both
    sides), which lie within the arc's data: its grid points more than a quarter of its
    step inside them, and a point on each border curve itself.  Without, between the
    arc's own ends: the grid points inside its range, and an end lying past its last grid
    point by more than :data:`QUARTER_STEP` of the step gets an extra point at the end.
    ``section``: each arc's section ``(K,)`` (default one arc a section): a section's
    parts (cut at depth steps) share its grid; only its outer ends are on the border
    curves, the ends at the steps are the parts' own.
    """
    origin = min(float(p.u.min()) for p in placed)
    lo = np.array([float(p.u[0]) for p in placed])
    hi = np.array([float(p.u[-1]) for p in placed])
    sec = np.arange(len(placed)) if section is None else np.asarray(section)
    first = np.concatenate([[True], np.diff(sec) != 0])
    last = np.concatenate([np.diff(sec) != 0, [True]])
    if smooth:
        b_lo, b_hi = lo.copy(), hi.copy()
        b_lo[first], b_hi[last] = -smooth_border(-lo[first], step), smooth_border(hi[last], step)
        # an arc the border curves would cut to less than a step keeps its own ends
        short = b_hi - b_lo < step
        b_lo, b_hi = np.where(short, lo, b_lo), np.where(short, hi, b_hi)
    rings, params = [], []
    for k, (curve, where) in enumerate(zip(curves, placed, strict=True)):
        h = step if sec[k] % 2 == 0 else step / 2
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


#: Most a fit under the shared-error model may lie from its points (RMS of the normal
#: residuals, in units of the points' own σ): the chessboard pairs' smoother rings lie
#: within it (pairs 03, 06, 13: the same rings with a bound of 3 or 2); on the Sceaux
#: facade, whose windows and depth steps a curve smooth over the window misses, it keeps
#: some relief (cloud within 3 σ of the stitched surface 0.63 with 3, 0.67 with 2, 0.69
#: with 1.5; 0.81 with the plain GCV): not enough (docs/decisions/open-surfaces.md).
SHARED_BAND = 2.0
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


def _column_runs(runs: list[np.ndarray], points: np.ndarray, axis: np.ndarray,
                 noise: np.ndarray | None, centres: np.ndarray | None) -> list[np.ndarray]:
    """The columns ``runs`` (indices into ``points``, consecutive sections) cut at their
    depth steps (:func:`depth_steps` along ``axis``, the cameras at ``centres``, the
    points' σ ``noise``): an edge of the object across the sections (a window's jamb, a
    tower's corner) is relief that a fit across it would round off, not an arc's error."""
    if noise is None or centres is None:
        return runs
    return [part for run in runs
            for part in np.split(run, depth_steps(points[run], axis, centres, noise[run]) + 1)]


def smooth_across(rings: list[np.ndarray], params: list[np.ndarray], step: float,
                  origin: float, axis: np.ndarray, correlation: float,
                  noise: np.ndarray | None = None, source: np.ndarray | None = None,
                  section: np.ndarray | None = None, centres: np.ndarray | None = None
                  ) -> list[np.ndarray]:
    """The rings smoothed across the sections: each column of grid points at one ``u``
    (every ``step``: on every ring) through consecutive sections, 4 or more of them, is
    fitted by :func:`fit_open` with the errors shared over ``correlation`` (the matcher's
    window), and each point moved to its nearest point on that curve, within its own
    section plane (normal to ``axis``); the even rings' half-step points and the border
    points move as their ring's nearest column points (the mean of the two about them).
    ``origin``: the grid's origin in ``u`` (:func:`resample_arcs`'s, the least ``u``);
    ``noise``, ``source``: each ring point's σ and error source ``(sum n_k,)`` when known
    (:func:`fit_open`'s); ``section``: each ring's section (default one ring a section;
    a section's parts cut at depth steps lie apart in ``u``); ``centres``: the cameras'
    centres ``(K, 3)``, with ``noise``: each column is cut at its depth steps
    (:func:`depth_steps` along ``axis``: a window's jamb, a tower's corner: relief, not
    the arcs' errors) and its parts fitted alone (on the Sceaux facade the cloud within
    3 σ of the stitched surface 0.731 → 0.773; the chessboard pairs and the stereo vase
    have no such step).

    Each arc is fitted alone (:func:`open_arcs`): errors shared over a window make whole
    arcs lie off their neighbours, a ripple from section to section that no fit along
    them removes (the chessboard pairs' rings, where LSM sees texture only at the
    squares' edges, and each section crosses other edges).
    """
    axis = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    counts = np.array([len(r) for r in rings])
    ring = np.repeat(np.arange(len(rings)) if section is None else np.asarray(section), counts)
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
    for run in _column_runs(np.split(idx, breaks), points, axis, noise, centres):
        if len(run) < 4:
            continue
        sigma = 0.0 if noise is None else float(np.sqrt(np.mean(noise[run] ** 2)))
        curve = fit_open(points[run], "auto", correlation=correlation, least=_COLUMN_LEAST,
                         noise=sigma, source=None if source is None else source[run])
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


def _across_view(loops: Sequence, view: np.ndarray | None) -> np.ndarray | None:
    """The unit direction across the cameras' mean view ``view`` in the sections' planes,
    or None: no view, a mean of the cameras' unit view directions shorter than 1/2 (they
    do not share one view), or sections within 45° of facing it (they cut it into depth
    slabs: no height field)."""
    if view is None or np.linalg.norm(view) < 0.5 or not loops or not loops[0]:
        return None
    axis = np.asarray(loops[0][0].frame, np.float64)[2]
    across = np.cross(axis, np.asarray(view, np.float64) / np.linalg.norm(view))
    return across / np.linalg.norm(across) if np.linalg.norm(across) > 0.5**0.5 else None


def _noise_lookup(sigma, window):
    """Points ``(P, 3)`` → the σ ``(P,)`` and the source ``(P,)`` (None without) of their
    nearest section point (``sigma``: (points, σ[, source])), or None without σ or
    without the window's model."""
    if sigma is None or window is None:
        return None
    finite = np.isfinite(sigma[1])
    if not finite.any():
        return None
    tree, known = cKDTree(np.asarray(sigma[0])[finite]), np.asarray(sigma[1])[finite]
    src = np.asarray(sigma[2])[finite] if len(sigma) > 2 and sigma[2] is not None else None

    def lookup(pts):
        near = tree.query(pts)[1]
        return known[near], None if src is None else src[near]
    return lookup


def _section_arc(section_loops, across, view) -> tuple[np.ndarray, int]:
    """A section's loops as one ordered arc and the pieces in it: the pieces that continue
    one another (:func:`chain_arcs`), or across the view one height field of their runs
    between gaps (:func:`height_field_arc`: a loop's runs may lie at other depths)."""
    pieces = [loop_arc(lp) for lp in section_loops]
    if across is None:
        return chain_arcs(pieces)
    pieces = [run for piece, lp in zip(pieces, section_loops, strict=True)
              for run in _runs_between_gaps(piece, getattr(lp, "bridge", math.inf))]
    return height_field_arc(pieces, across, view)


def _fit_parts(arc, best, smoothing, across, window, noise_of) -> list[OpenCurve]:
    """A section's arc cut at its depth steps (:func:`depth_steps`: across the view, with
    the cameras and σ known) into parts of 4 or more points (fewer: dropped; none: the
    arc whole), each with its wide gaps bridged (:func:`bridge_open_gaps`) and fitted
    (:func:`fit_open`, under the window's model when known)."""
    parts = [arc]
    if across is not None and window is not None and noise_of is not None:
        cut = depth_steps(arc, across, window[0], noise_of(arc)[0])
        parts = [p for p in np.split(arc, cut + 1) if len(p) >= 4] or [arc]
    curves = []
    for part in parts:
        part = bridge_open_gaps(part, getattr(best, "bridge", math.inf))
        correlation = window_footprint(part, *window) if window is not None else 0.0
        near, src = (None, None) if noise_of is None else noise_of(part)
        noise = 0.0 if noise_of is None else float(np.sqrt(np.mean(near ** 2)))
        curves.append(fit_open(part, smoothing, frame=best.frame, correlation=correlation,
                               noise=noise, source=src))
    return curves


def _by_section(items: list, sec: np.ndarray) -> list:
    """Items per section: the item itself where a section has one, else their list."""
    groups = np.split(np.arange(len(items)), np.flatnonzero(np.diff(sec)) + 1)
    return [items[g[0]] if len(g) == 1 else [items[i] for i in g] for g in groups]


def _grid_step(placed: list, spacing: float, n: int | None) -> float:
    """The odd arcs' grid step in ``u``: the widest arc (smallest scale: most length per
    unit of u) gets ring points one section ``spacing`` apart, or ``n`` points."""
    if n is None:
        return spacing * min(p.scale for p in placed)
    widest = max(placed, key=lambda p: float(p.u[-1] - p.u[0]))
    return float(widest.u[-1] - widest.u[0]) / max(int(n) - 1, 1)


def _across_window(rings, params, step, placed, loops, window, noise_of, sec):
    """:func:`smooth_across` of the rings under the matcher's ``window`` (its footprint on
    a sample of the rings), their σ and sources from ``noise_of``, the cameras' centres."""
    axis = np.asarray(loops[0][0].frame, np.float64)[2]
    sample = np.concatenate(rings)[:: max(1, sum(map(len, rings)) // 4096)]
    origin = min(float(p.u.min()) for p in placed)
    noise, src = (None, None) if noise_of is None else noise_of(np.concatenate(rings))
    return smooth_across(rings, params, step, origin, axis, window_footprint(sample, *window),
                         noise, src, sec, window[0])


@one_blas_thread
def open_arcs(loops: Sequence, spacing: float, n: int | None = None,
              smoothing: float | str = "auto", border: bool = True,
              view: np.ndarray | None = None,
              window: tuple[np.ndarray, np.ndarray, float] | None = None,
              sigma: tuple[np.ndarray, np.ndarray] | None = None, steps: bool = False):
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
        The rings end on the smooth border curves (:func:`smooth_border`; stitch with
        ``reach=BORDER_REACH``); False: where each arc's data end (a staircase).
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
        (:func:`window_footprint`, :func:`fit_open`'s ``correlation``).
    sigma : (points (N, 3), σ (N,)[, source (N,)]), optional
        The sections' points, their σ and error sources: each arc's and column's points
        take their nearest one's; the fits under the window's model stay within
        :data:`SHARED_BAND` of them (:func:`fit_open`'s ``noise`` and ``source``).
    steps : bool
        With ``view``, ``window`` and ``sigma``: cut each arc at its depth steps into parts
        (:func:`depth_steps`; a section's rings are then a list of parts).

    Returns
    -------
    curves : list of OpenCurve
    rings, params : list of (n_k, 3) and (n_k,) float64
        The resampled arcs (with ``steps``, or a list of parts) and their ``u``.
    step : float
        The odd arcs' grid step in ``u``.
    notes : list of str
    run : range
        The sections (indices into ``loops``) the arcs come from (:func:`align_arcs`).
    """
    if not spacing > 0:
        raise ValueError(f"spacing must be > 0, got {spacing}")
    notes, curves, data, partial = [], [], 0, 0
    across, noise_of = _across_view(loops, view), _noise_lookup(sigma, window)
    section: list[int] = []
    for k, section_loops in enumerate(loops):
        best = max(section_loops, key=len)
        arc, used = _section_arc(section_loops, across, view)
        data += len(arc)
        if used < len(section_loops):
            partial += 1
            if partial <= 3:
                notes.append(f"section at height {best.height:.6g}: {len(section_loops)} "
                             f"loops, {used} piece(s) kept as one arc ({len(arc)} points)"
                             + (" (the pieces that continue one another)" if across is None
                                else " (one depth across the view)"))
        fitted = _fit_parts(arc, best, smoothing, across if steps else None, window, noise_of)
        curves, section = curves + fitted, section + [k] * len(fitted)
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
    # each arc's section in the run (place_across, the only one with parts, keeps all)
    sec = np.asarray(section)[list(run)] - section[run[0]]
    run = run if len(section) == len(loops) else range(len(loops))
    loops = [loops[k] for k in run]
    step = _grid_step(placed, spacing, n)
    counts = [float(p.u[-1] - p.u[0]) / (step if k % 2 == 0 else step / 2) + 2
              for k, p in zip(sec, placed, strict=True)]
    if sum(counts) > MAX_RING_POINTS_PER_POINT * data:
        raise ValueError(f"the arcs do not line up as one surface: resampling them would "
                         f"take {sum(counts):.3g} ring points for {data} data points")
    rings, params = resample_arcs(curves, placed, step, smooth=border, section=sec)
    if window is not None:  # errors shared over the window: whole arcs off, across too
        rings = _across_window(rings, params, step, placed, loops, window, noise_of, sec)
    if len(sec) > len(loops):  # a section's parts as one list of rings, parameters joined
        rings, params = _by_section(rings, sec), _by_section(params, sec)
        params = [u if isinstance(u, np.ndarray) else np.concatenate(u) for u in params]
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
