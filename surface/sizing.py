r"""A control mesh sized by the data: as few rings and sections as the smooth surface needs.

The stitched mesh of :mod:`surface.stitch` follows the point density; Loop's surface over
it (4 patches a triangle) inherits every vertex.  Here the dense rings are *thinned*: every
``step``-th section kept (graded towards both ends, :func:`kept_sections`; along the profile
length instead of the height when both ends are rounded, :func:`rounded_ends`), each kept
ring resampled to ``n`` (odd positions) / ``2n`` (even) points at common polar angles
(:func:`resample_at_angles`), and the result stitched again with the same rules.  One target
edge ``h`` sets ``step = floor(h / Δ)`` and ``n = ceil(P / h)`` (Δ the dense section spacing,
P the largest ring perimeter).  The smooth surface is built over the *interpolating* control
mesh (:func:`interpolating_control`), so it passes through the thinned vertices instead of
shrinking by ``h² (κ1 + κ2) / 8`` as an approximating surface would [1, 2].

*Regression across sections.*  A kept ring is the local quadratic regression in height (or
profile length) of the dense rings within ``w`` sections of it, each loop along its own chain
through the loop graph (:func:`section_weights`, :func:`loop_chains`; Savitzky-Golay [4]).

*Level search* (:func:`size_control_mesh`).  ``h`` shrinks by √2 from 12 points round the
largest ring; the coarsest level whose estimated error is within the goal is taken (or the
level half way to the previous, ``h·2^¼``, if it passes too): bisection over the levels of
step ≥ 2, then the step-1 levels, then a walk outwards from the closest estimate.  When none
passes, the candidate estimated closest is kept if it beats the rings' sill, else the dense
mesh.  A step-1 candidate is judged against the goal the last coarser candidate measured.

*The rings' errors* (:func:`section_variogram`): ``γ(k) = ½ E|ε_{i+k} − ε_i|²`` across
sections, from 6th differences at lags 1..12, fitted by a nugget + exponential model.

*A candidate's error* (:func:`risk_estimate`): with ``S`` its smoothing across sections
(:func:`smoothing_matrix`), ``E|Sx − truth|² = E|Sx − x|² − 2 Σ_j S_ij γ(|i − j|) + sill``
(Stein's unbiased risk estimate [3] for correlated errors), ``|Sx − x|`` the distances from a
fixed sample of dense vertices (:func:`reference_vertices`) to the candidate's surface.

*The goal* (:func:`stitched_surface_error`): the stitched mesh's own error over its faces,
``sill + E d_q² − E d_v²`` (points on the dense faces against the dense vertices): a
candidate is never farther from the truth than the stitched mesh, as an RMS over the surface.  Scene
units throughout; the rules' history and the figures that decided them:
``docs/decisions/sizing.md``.

References
----------
.. [1] C. Loop, "Smooth subdivision surfaces based on triangles", M.S. thesis, Utah (1987).
.. [2] H. Hoppe et al., "Piecewise smooth surface reconstruction", SIGGRAPH 1994.
.. [3] C. M. Stein, Annals of Statistics 9 (1981) 1135-1151; C. L. Mallows, "Some comments
   on Cp", Technometrics 15 (1973) 661-675.
.. [4] A. Savitzky, M. J. E. Golay, Analytical Chemistry 36 (1964) 1627-1639.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from surface._blas import one_blas_thread

#: Tessellation chord tolerance as a share of the sized surface's estimated error
#: (:meth:`SizedMesh.chord_tolerance`).
CHORD_FRACTION = 1.0

__all__ = ["SectionLayout", "SizedMesh", "Variogram", "coarsen_rings", "error_estimate",
           "influence", "interpolating_control", "kept_sections", "profile_length",
           "reference_vertices", "resample_ring", "rounded_ends",
           "ring_noise", "ring_precision", "risk_estimate", "section_layout",
           "section_scatter",
           "section_variogram", "section_weights", "size_control_mesh", "sized_from_points",
           "crease_band", "crease_vertices", "mesh_creases", "smooth_deviation",
           "smoothing_matrix", "stitched_error", "stitched_surface_error", "thinning",
           "unshared_noise"]

#: Points round the largest ring of the coarsest candidate.
MIN_RING_POINTS = 12
#: Each candidate's edge length is the previous one's / this.
H_RATIO = float(np.sqrt(2.0))
#: Dense-mesh vertices the deviation of a candidate is measured at (a fixed sample).
REFERENCE_POINTS = 10_000
#: A candidate whose estimate to its level-1 tessellation is within this many times the
#: goal (measured to the tessellation too: :func:`stitched_surface_error`, never below
#: :func:`stitched_error`) is measured again to its exact surface (the tessellation's chord error,
#: κh²/128, is 5e-5 on the demo's candidates: half their error; far-off candidates are
#: refused on the cheap measure).
EXACT_WITHIN = 2.0
#: Shortest step kept along the profile (:func:`size_control_mesh`, ``along_profile``).
ALONG_PROFILE_STEP = 4
#: Find the coarsest passing candidate by bisection over the candidate levels (step >= 2)
#: instead of trying each from the coarsest (:func:`size_control_mesh`).
SEARCH_BISECT = True
#: When the bisection finds none: the step-1 levels, then coarser levels outwards from the
#: closest estimate only while they stay within its standard error, instead of every level
#: (:func:`size_control_mesh`; 2026-12-06).
WALK_WHEN_NONE_PASS = True
#: Interpolate the object's convex creases away from its ends (:func:`crease_vertices`,
#: :func:`interpolating_control`; 2026-12-06): False keeps every sharp vertex as it is,
#: the rule before.
INTERPOLATE_CREASES = True


def ring_precision(fits: Sequence) -> float:
    """The dense rings' precision σ_ring: the median of the rings' own σ (module notes).

    Parameters
    ----------
    fits : sequence
        ``surface.catmull_rom.RingFit`` records, or lists of them (one per section, as
        ``predict_sections(..., fits=True)`` returns them).

    Returns
    -------
    float
        Scene units; 0 when no ring has a noise estimate (noise-free points give 0 too).
    """
    values = [float(f.precision) for item in fits
              for f in ([item] if hasattr(item, "precision") else list(item))]
    values = [v for v in values if np.isfinite(v)]
    return float(np.median(values)) if values else 0.0


def ring_noise(rings: Sequence, axis, precision: float = 0.0, points_noise: float = 0.0
               ) -> float:
    """σ of the dense rings' errors: their scatter between sections (:func:`section_scatter`),
    else the fits' own precision σ_ring (:func:`ring_precision`), else the points' σ̂;
    scene units (0 if none is known)."""
    for value in (section_scatter(rings, axis), precision, points_noise):
        if value is not None and np.isfinite(value) and value > 0:
            return float(value)
    return 0.0


def resample_ring(ring: np.ndarray, count: int) -> np.ndarray:
    """Closed ring resampled to ``count`` points on the periodic cubic through its points.

    Parameters
    ----------
    ring : (M, 3) float64
        Ring points at a regular parameter (equal θ or equal arc length), first
        point not repeated.
    count : int
        Points wanted, >= 3.

    Returns
    -------
    (count, 3) float64
        Point ``j`` at parameter ``j / count`` of the ring's ``0 .. 1``: the
        first point stays where it was.
    """
    ring = np.asarray(ring, dtype=np.float64)
    if ring.ndim != 2 or ring.shape[1] != 3 or len(ring) < 3:
        raise ValueError(f"ring must have shape (M >= 3, 3), got {ring.shape}")
    if count < 3:
        raise ValueError(f"count must be >= 3, got {count}")
    return periodic_cubic([ring], (np.arange(count) / count)[None])[0]


def resample_at_angles(ring: np.ndarray, count: int, centre: np.ndarray,
                       frame: np.ndarray) -> np.ndarray | None:
    """Ring resampled at the polar angles ``2πj/count`` about ``centre`` in the plane
    ``frame[:2]``, on the periodic cubic through its points (:func:`resample_ring`'s
    curve), so that rings of different sections line up point by point whatever their
    first points; ``None`` when the ring is not star-shaped about ``centre``.

    Parameters
    ----------
    ring : (M, 3) float64
    count : int
    centre : (3,) float64
    frame : (3, 3) float64
        Rows e1, e2 (the plane), axis.

    Returns
    -------
    (count, 3) float64 or None
    """

    out = resample_rings_at_angles([ring], count, centre, frame)
    return None if out is None else out[0]


def resample_rings_at_angles(rings: Sequence, count: int, centre: np.ndarray,
                             frame: np.ndarray) -> np.ndarray | None:
    """:func:`resample_at_angles` of several rings about one centre, ``(R, count, 3)``
    (None if one is not star-shaped), all at once: the rings' periodic cubics by
    :func:`periodic_cubic` (one FFT solve per point count, one evaluation of every ring),
    instead of a ``scipy`` spline per ring (the sizing resamples thousands of rings of
    all sizes; on the real temple ring 1 745 splines of ~0.5 ms, mostly the spline's
    set-up, 0.97 s of its 3.3 s).
    """
    prepared = []
    for ring in rings:
        ring = np.asarray(ring, dtype=np.float64)
        flat = (ring - centre) @ frame[:2].T
        angle = np.unwrap(np.arctan2(flat[:, 1], flat[:, 0]))
        if angle[-1] < angle[0]:                       # clockwise: the same ring reversed
            ring, angle = ring[::-1], angle[::-1]
        period = np.append(angle, angle[0] + 2 * np.pi)
        if np.any(np.diff(period) <= 0):               # not star-shaped about the centre
            return None
        prepared.append((ring, angle, period))
    steps = 2 * np.pi * np.arange(count) / count
    params = np.stack([np.interp(angle[0] + np.mod(steps - angle[0], 2 * np.pi), period,
                                 np.arange(len(ring) + 1) / len(ring))
                       for ring, angle, period in prepared]) if prepared else \
        np.empty((0, count))
    return periodic_cubic([ring for ring, _, _ in prepared], params)


def periodic_cubic(rings: Sequence, params: np.ndarray) -> np.ndarray:
    """The periodic C2 cubic interpolants of closed rings, at uniform parameters.

    Ring ``r``'s point ``j`` (of ``M_r``) sits at parameter ``j / M_r`` of ``0 .. 1``; the
    interpolant is the one ``scipy.interpolate.CubicSpline(..., bc_type="periodic")``
    makes (the periodic cubic spline through given points is unique).  With uniform
    knots its second derivatives ``c`` solve a circulant system,
    ``c[j-1] + 4 c[j] + c[j+1] = 6 (y[j+1] - 2 y[j] + y[j-1])`` (in index units), so one
    FFT over all the rings of one point count solves it (the eigenvalues
    ``4 + 2 cos(2πk/M)`` are at least 2: well conditioned), and every ring is evaluated
    in one vectorised pass (de Boor, *A Practical Guide to Splines*, ch. IV; the
    circulant solve as in ``scipy.linalg.solve_circulant``).  ``scipy``'s spline costs
    ~0.5 ms a ring in its set-up, which the sizing paid thousands of times.

    Parameters
    ----------
    rings : sequence of (M_r, D) float64, M_r >= 3
    params : (R, K) float64
        Parameters (taken modulo 1) at which to evaluate each ring.

    Returns
    -------
    (R, K, D) float64
    """
    params = np.asarray(params, dtype=np.float64)
    if not len(rings):
        return np.empty((0, params.shape[1] if params.ndim == 2 else 0, 3))
    dim = np.asarray(rings[0]).shape[1]
    out = np.empty(params.shape + (dim,))
    groups: dict[int, list[int]] = {}
    for i, ring in enumerate(rings):
        groups.setdefault(len(ring), []).append(i)
    for m, idx in groups.items():
        y = np.stack([np.asarray(rings[i], dtype=np.float64) for i in idx])   # (G, m, D)
        rhs = 6.0 * (np.concatenate([y[:, 1:], y[:, :1]], axis=1) - 2.0 * y
                     + np.concatenate([y[:, -1:], y[:, :-1]], axis=1))
        eigen = 4.0 + 2.0 * np.cos(2.0 * np.pi * np.arange(m // 2 + 1) / m)
        c = np.fft.irfft(np.fft.rfft(rhs, axis=1) / eigen[None, :, None], n=m, axis=1)
        x = np.mod(params[idx], 1.0) * m                                     # (G, K)
        i0 = np.minimum(np.floor(x).astype(np.int64), m - 1)
        b = (x - i0)[..., None]
        a = 1.0 - b
        i1 = (i0 + 1) % m
        g = np.arange(len(idx))[:, None]
        out[idx] = (a * y[g, i0] + b * y[g, i1]
                    + ((a ** 3 - a) * c[g, i0] + (b ** 3 - b) * c[g, i1]) / 6.0)
    return out


def kept_sections(count: int, step: int, length: np.ndarray | None = None) -> list[int]:
    """Indices of the sections kept: every ``step``-th, graded towards both ends.

    From each end the gaps grow 1, 2, 4, ... up to ``step``: an end section is
    usually a rim (a sharp turn of the profile, held by support rings one noise
    width away, ``surface.stitch.support_distance``), and a G1 surface
    interpolating a rim ring, its support ring and a wall ring ``step`` sections
    further overshoots the edge (measured on the demo, step 7 without grading:
    0.015 outward at the bottom rim).  A rounded end gains from it too (below).

    With the profile's ``length`` the sections between the graded ends are kept
    ``step`` apart *along the profile*, not by their count: the dense sections are
    equally spaced in height, but where the profile leans (a dome, a flaring neck)
    they lie farther apart on the surface, and an interpolating surface over kept
    rings unevenly spaced along it undulates.  Measured on exact rings of a capsule
    (``r = 1`` hemispheres on a cylinder, rings 0.2 apart, 25 / 50 points, the
    interpolating Loop surface, one-off script): mean distance 0.000905 with the rings
    equally spaced in height, 0.000463 along the profile (0.1 apart, 50 / 100 points:
    0.000158 against 0.000073); the error sat where the dome leans (0.0033 against
    0.0016 at 44-58° latitude).  With the ends graded (gaps ¼, ½, then 1 of the step):
    0.000413 in height (the rule before), 0.000259 along the profile; rings 0.4 apart,
    12 / 24 points: 0.00184 against 0.00135 -- the grading holds the junction of the
    last ring with the dome's own triangulation (there, 44-58° latitude, 0.00055 / 0.0016
    graded, 0.0016 / 0.0085 not).

    Parameters
    ----------
    count : int
        Sections, >= 2.
    step : int
        Gap in the middle, >= 1 (sections, or profile length in dense section spacings).
    length : (count,) float64, optional
        Each section's position along the profile in units of the dense section spacing
        (:func:`profile_length` / spacing), increasing; default the section index.

    Returns
    -------
    list of int
        Increasing, first 0 and last ``count - 1``.
    """
    step = max(1, int(step))
    head, gap, at = [0], 1, 0
    while at + gap < count // 2 and gap < step:
        at += gap
        head.append(at)
        gap *= 2
    tail = [count - 1 - i for i in head]
    if length is None:
        middle = list(range(head[-1], tail[-1] + 1, step))
    else:
        middle = _along_profile(np.asarray(length, dtype=np.float64), head[-1], tail[-1],
                                step)
    keep = sorted(set(head) | set(middle) | set(tail))
    return keep


def rounded_ends(rings: Sequence, dense: tuple[np.ndarray, np.ndarray], axis,
                 sharp: np.ndarray | None = None) -> tuple[bool, bool]:
    """Whether the dense stitched mesh's first / last end is rounded: no sharp edge
    (dihedral angle over 30°, ``surface.fitting.sharp_vertices``) at as many as a quarter
    of its end section's ring points among the vertices nearest that section.  A rim (a
    flat cap's edge) has a sharp edge all round.  Measured on the σ = 0.002 clouds of
    ``benchmarks/surface.py`` (10⁴ and 10⁵ points, one-off script): 0 sharp vertices at both
    ends of the capsule; at each end of the flat-capped vase, cylinder, amphora and ellipse
    every point of the end ring (67-478).  ``sharp``: the dense mesh's sharp vertices
    (:func:`_sharp`), if known."""
    vertices, triangles = (np.asarray(a) for a in dense)
    axis = np.asarray(axis, dtype=np.float64)
    heights = _heights(rings, axis)
    sharp = _sharp(vertices, triangles) if sharp is None else sharp
    if sharp is None:
        return False, False
    near = _nearest_section(vertices @ axis, heights, np.argsort(heights))
    out = []
    for end in (0, len(rings) - 1):
        points = sum(len(loop) for loop in _loops(rings[end]))
        out.append(bool(sharp[near == end].sum() < 0.25 * points))
    return out[0], out[1]


def _along_profile(length: np.ndarray, lo: int, hi: int, step: int) -> list[int]:
    """Sections ``lo .. hi`` kept about ``step`` apart along the profile, from both ends
    towards the middle: each next one the section whose distance from the last is nearest
    ``step`` (ties: the farther), so a straight profile keeps every ``step``-th and the
    sections next to both graded ends are spaced alike.  What is left in the middle (up
    to 2½ steps) is cut into ``round(left / step)`` equal gaps, none of one section when
    the step is longer (such a gap leaves its rings unregressed, :func:`section_weights`).
    """
    low, high = [lo], [hi]
    shortest = 2 if step >= 2 else 1

    def next_from(at: int, toward: int) -> int:
        span = np.arange(at + 1, toward + 1) if toward > at else np.arange(at - 1, toward - 1, -1)
        miss = np.abs(np.abs(length[span] - length[at]) - step)
        return int(span[len(miss) - 1 - int(np.argmin(miss[::-1]))])

    while True:
        a, b = low[-1], high[-1]
        left = float(length[b] - length[a])
        if left <= 2.5 * step or b - a <= 2 * shortest:
            pieces = max(1, min(int(round(left / step)), (b - a) // shortest))
            inner = np.arange(a + 1, b)
            for i in range(1, pieces):
                low.append(int(inner[np.argmin(np.abs(length[inner] - length[a]
                                                      - left * i / pieces))]))
            break
        low.append(next_from(a, b - 1))
        if length[high[-1]] - length[low[-1]] > 2.5 * step and high[-1] - low[-1] > 2 * shortest:
            high.append(next_from(high[-1], low[-1] + 1))
    return sorted(set(low) | set(high))


def profile_length(rings: Sequence, axis=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Each section's position along the profile: the cumulative mean distance between
    the rings of consecutive sections at common polar angles (:func:`resample_at_angles`
    about the mean of their area centroids, :func:`_area_centroid`, which the N / 2N
    rings' sampling does not move: a radius or centre that moves between sections
    counts), ``(K,)`` from 0.  Between sections where one has several loops or a ring is
    not star-shaped, the height difference.
    """
    frame = _plane_frame(axis)
    heights = _heights(rings, frame[2])
    step = np.abs(np.diff(heights))
    single = [_single(entry) for entry in rings]
    for k in range(len(rings) - 1):
        a, b = single[k], single[k + 1]
        if a is None or b is None:
            continue
        count = min(len(a), len(b))
        centre = 0.5 * (_area_centroid(a, frame) + _area_centroid(b, frame))
        pair = resample_rings_at_angles([a, b], count, centre, frame)
        if pair is not None:
            step[k] = max(step[k], float(np.linalg.norm(pair[1] - pair[0], axis=1).mean()))
    return np.concatenate([[0.0], np.cumsum(step)])


def _heights(rings: Sequence, axis: np.ndarray) -> np.ndarray:
    return np.array([float(np.mean(np.concatenate([loop @ axis for loop in _loops(entry)])))
                     for entry in rings])


def _single(entry) -> np.ndarray | None:
    loops = _loops(entry)
    return loops[0] if len(loops) == 1 else None


def _plane_frame(axis) -> np.ndarray:
    """Rows e1, e2, axis: an orthonormal frame with the unit axis last."""
    axis = np.asarray(axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis)
    helper = np.eye(3)[int(np.argmin(np.abs(axis)))]
    e1 = np.cross(axis, helper)
    e1 /= np.linalg.norm(e1)
    return np.stack([e1, np.cross(axis, e1), axis])


def _aligned(rings: Sequence, sections: np.ndarray, count: int, frame: np.ndarray):
    """The single-loop rings of ``sections`` resampled at common polar angles about their
    mean centroid, ``(len(sections), count, 3)``; None if one is missing or not
    star-shaped.  ``rings`` may be one chain's loops (:func:`loop_chains`)."""
    loops = [_single(rings[j]) for j in sections]
    if any(loop is None for loop in loops):
        return None
    centre = np.mean([loop.mean(axis=0) for loop in loops], axis=0)
    return resample_rings_at_angles(loops, count, centre, frame)


#: Consecutive sections of one 4th difference, and its noise gain Σ c² = 1+16+36+16+1.
_D4 = np.array([1.0, -4.0, 6.0, -4.0, 1.0])


def section_scatter(rings: Sequence, axis=(0.0, 0.0, 1.0)) -> float:
    """The dense rings' error measured from their scatter between neighbouring sections.

    The rings are resampled to one count at the same polar angles about the window's
    mean centroid (:func:`resample_at_angles`: the rings' own first points are not
    aligned from section to section), and at each point of five consecutive sections,
    equally spaced, of one loop followed from section to section (:func:`loop_chains`:
    a stack of single loops, or a branch's loops related one to one), the 4th
    difference across the sections ``x_{k-2} - 4x_{k-1} + 6x_k - 4x_{k+1} + x_{k+2}``
    is taken along the middle ring's in-plane radial direction: the profile's shape up
    to a cubic cancels and the rings' independent errors add up to 70 σ², so
    ``σ = 1.4826 · median|d4| / √70`` (robust to the rims and to branch events).
    Each ring is fitted to its own section's points, so their errors are independent
    from section to section, whatever their correlation along the ring.

    Only single-loop sections were read before: on the real temple ring (plinth, four
    columns, entablature) that left one window of five sections, whose L-shaped loops
    were 45 % bridged gaps, and the estimate moved 4x with how the gaps were filled; its
    columns' chains give ~200 windows.

    Parameters
    ----------
    rings : sequence
        One entry per section, ``(M, 3)`` or a list of loops.
    axis : (3,) float64
        The sections' common normal.

    Returns
    -------
    float
        Scene units; ``nan`` when no loop runs through five consecutive sections.
    """
    frame = _plane_frame(axis)
    axis = frame[2]
    heights = _heights(rings, frame[2])
    values = []
    for sections, chain in loop_chains(rings, frame):
        if len(chain) < 5:
            continue
        count = min(len(loop) for loop in chain)
        for k in range(2, len(chain) - 2):
            gaps = np.diff(heights[sections[k - 2:k + 3]])
            if np.ptp(gaps) > 0.25 * abs(float(np.median(gaps))):
                continue
            window = _aligned(chain, np.arange(k - 2, k + 3), count, frame)
            if window is None:
                continue
            d4 = np.tensordot(_D4, window, axes=1)                      # (count, 3)
            radial = window[2] - window[2].mean(axis=0)
            radial -= np.outer(radial @ axis, axis)
            radial /= np.maximum(np.linalg.norm(radial, axis=1), 1e-300)[:, None]
            values.append(np.einsum("ij,ij->i", d4, radial))
    if not values:
        return float("nan")
    return float(1.4826 * np.median(np.abs(np.concatenate(values))) / np.sqrt(_D4 @ _D4))


def loop_chains(rings: Sequence, frame: np.ndarray) -> list[tuple[np.ndarray, list]]:
    """Each loop followed from section to section while it continues one to one.

    Returns
    -------
    list of (sections (L,) int64, loops list of L (M, 3) arrays)
        A stack of single loops is one chain; with several loops a section, the
        one-to-one events of the loop graph (``surface.loop_graph``: loops related by
        their overlap) link them, and a split, merge, appearance or end starts a new
        chain.
    """
    loops = [_loops(entry) for entry in rings]
    if all(len(found) == 1 for found in loops):
        return [(np.arange(len(loops)), [found[0] for found in loops])]
    from surface.loop_graph import loop_graph

    graph = loop_graph([[loop @ frame[:2].T for loop in found] for found in loops])
    after = {(e.section, e.lower[0]): e.upper[0] for e in graph.events
             if e.kind == "one-to-one" and 0 <= e.section < len(loops) - 1}
    continued = {(s + 1, j) for (s, _), j in after.items()}
    chains = []
    for s, found in enumerate(loops):
        for i in range(len(found)):
            if (s, i) in continued:
                continue
            sections, members = [s], [found[i]]
            while (sections[-1], i) in after:
                i = after[(sections[-1], i)]
                sections.append(sections[-1] + 1)
                members.append(loops[sections[-1]][i])
            chains.append((np.array(sections), members))
    return chains


@dataclass(frozen=True)
class SectionLayout:
    """How the dense rings can be regressed across sections (:func:`section_layout`).

    Attributes
    ----------
    chains : list of (sections (L,) int64, loops list of L (M, 3) arrays)
        :func:`loop_chains`.
    where : dict
        ``(section, loop) -> (chain, position)``.
    reach : (K,) int64
        Per section, the widest half-window ``w`` over which every loop of it continues
        one to one: its regression across ``2w + 1`` sections can follow each loop
        (:func:`section_weights`).
    """

    chains: list
    where: dict
    reach: np.ndarray


def section_layout(rings: Sequence, frame: np.ndarray) -> SectionLayout:
    """The dense rings' chains of loops (:func:`loop_chains`) and each section's reach
    along them.

    A stack of single loops is one chain and each section reaches as far as the nearer
    end (the regression rule before 2026-12-06, which read only single-loop sections).
    Several loops a section -- a temple's columns, a torus's two sides -- are regressed
    along their own chains; the sections where loops split, merge, appear or end reach
    no farther than the event.
    """
    chains = loop_chains(rings, frame)
    where, reach = {}, np.zeros(len(rings), dtype=np.int64)
    seen = np.zeros(len(rings), dtype=bool)
    for c, (sections, members) in enumerate(chains):
        for p, (section, member) in enumerate(zip(sections, members, strict=True)):
            i = next(i for i, loop in enumerate(_loops(rings[section])) if loop is member)
            where[(int(section), i)] = (c, p)
            span = min(p, len(sections) - 1 - p)
            reach[section] = span if not seen[section] else min(reach[section], span)
            seen[section] = True
    return SectionLayout(chains, where, reach)


#: 6th difference across seven sections (cancels the profile up to a quintic) and its
#: noise gain Σ c².
_D6 = np.array([1.0, -6.0, 15.0, -20.0, 15.0, -6.0, 1.0])
#: Largest lag (in sections) of the measured variogram.
MAX_LAG = 12
#: Fewest windows (of seven sections) a lag of the variogram is measured on.
MIN_WINDOWS = 5
#: The 6th differences' mean squares of the :class:`Variogram` model are concave in the
#: lag L (``504 p L/r − 56 p (L/r)³ + …`` from the nugget's level, then saturating at
#: ``924 sill``), so they grow no faster than L; a profile that the 6th differences do not
#: cancel grows as L¹² (a rounded end's last sections, where the profile's 6th derivative
#: is large).  :func:`section_variogram` stops at the first lag whose mean square exceeds
#: the previous one's times ``L / L_prev`` by more than this share (a margin for the
#: medians' sampling scatter, ~5 %).  The profile of a shape of revolution is taken out
#: before (the spread about each window's mean over the ring: on a 10⁵-point capsule,
#: σ 0.002, the mean squares had run 3.8e-4 flat to lag 5 and 5.5e-4 .. 1.0e-3 beyond, a
#: fitted sill of 1.9e-3); this stop guards against a profile that varies with the angle.
PROFILE_MARGIN = 0.25


@dataclass
class Variogram:
    """The dense rings' errors across sections: ``γ(k) = ½ E|ε_{i+k} − ε_i|²``.

    Modelled as a nugget (errors independent between sections) plus an exponential
    part (errors shared by neighbouring sections, e.g. one camera pair's bias seen in
    several sections): ``γ(k) = nugget + partial (1 − exp(−k / range))`` for ``k >= 1``,
    ``γ(0) = 0``; variances in scene units².  Only differences of the rings' errors are
    measurable, so an error common to all sections (a scale or offset of the whole
    cloud) is not in it -- and needs not be: it moves every candidate and the dense mesh
    alike.  ``lags`` / ``measured``: the measurements it was fitted to.
    """

    nugget: float
    partial: float = 0.0
    range: float = 1.0
    lags: tuple = ()
    measured: tuple = ()

    @classmethod
    def white(cls, sigma: float) -> Variogram:
        """Independent errors of σ (``γ(k) = σ²`` for ``k >= 1``)."""
        return cls(float(sigma) ** 2)

    @property
    def sill(self) -> float:
        """``γ(∞)``: the variance of one ring's error about the sections' common error."""
        return self.nugget + self.partial

    def __call__(self, k) -> np.ndarray:
        k = np.abs(np.asarray(k, dtype=np.float64))
        value = self.nugget + self.partial * (1.0 - np.exp(-k / max(self.range, 1e-12)))
        return np.where(k == 0, 0.0, value)

    def to_json(self) -> dict:
        return {"nugget": self.nugget, "partial": self.partial, "range": self.range,
                "lags": list(self.lags), "measured": list(self.measured)}


def _area_centroid(loop: np.ndarray, frame: np.ndarray) -> np.ndarray:
    """Centroid of the area a closed ring encloses (its plane ``frame[:2]``), at the ring's
    mean height: unlike the mean of its points it does not depend on how the ring is
    sampled (the N / 2N rings of alternate sections would shift by their spacing's
    unevenness)."""
    flat = loop @ frame[:2].T
    x, y = flat[:, 0], flat[:, 1]
    xn, yn = np.roll(x, -1), np.roll(y, -1)
    cross = x * yn - xn * y
    area = 0.5 * cross.sum()
    if abs(area) < 1e-300:
        return loop.mean(axis=0)
    cx = ((x + xn) * cross).sum() / (6.0 * area)
    cy = ((y + yn) * cross).sum() / (6.0 * area)
    return cx * frame[0] + cy * frame[1] + float(np.mean(loop @ frame[2])) * frame[2]


def _radial_profiles(rings: Sequence, axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each single-loop ring's distance from its own centroid at the common polar angles
    ``2πj/M`` (M the smallest ring), ``(K, M)`` with NaN rows for sections with several
    loops or not star-shaped; and the sections' heights.

    A ring's own area centroid as its centre (:func:`_area_centroid`): the centroids'
    drift along the axis is a smooth function of the height, which the 6th differences
    cancel like the profile itself.
    """
    frame = _plane_frame(axis)
    single = [_single(entry) for entry in rings]
    count = min(len(loop) for loop in single if loop is not None)
    out = np.full((len(rings), count), np.nan)
    for k, loop in enumerate(single):
        if loop is None:
            continue
        centre = _area_centroid(loop, frame)
        aligned = resample_at_angles(loop, count, centre, frame)
        if aligned is not None:
            flat = (aligned - centre) @ frame[:2].T
            out[k] = np.hypot(flat[:, 0], flat[:, 1])
    return out, _heights(rings, frame[2])


def section_variogram(rings: Sequence, axis=(0.0, 0.0, 1.0), max_lag: int = MAX_LAG
                      ) -> Variogram | None:
    """The dense rings' variogram across sections, measured from the data.

    At each lag ``L`` the 6th difference over every ``L``-th section,
    ``Σ c_m r_{i+mL}(θ)`` with ``c = (1, −6, 15, −20, 15, −6, 1)``, of the rings' radii at
    common polar angles (:func:`_radial_profiles`) cancels the profile up to a quintic;
    its mean square is ``−Σ_{m≠m'} c_m c_m' γ(|m − m'| L)`` (``924 γ`` for independent
    errors).  Per lag, the median over the windows (seven equally spaced single-loop
    sections, spanning at most half the sections) of each window's mean square over
    the ring: a mean square within the window, because the errors are heavier-tailed
    than a Gaussian and the sizing compares mean squares (on the demo's rings a median
    of the single values under-stated γ by 15 % against the truth); a median across
    windows, because one odd ring spoils every window that holds it (the densified
    demo's cloud: one ring made 3 % of the lag-1 windows 12× the rest, and a mean
    square with the largest 1 % clipped gave 2.6× the truth's sill).  The lags
    ``1 .. max_lag`` are fitted by the model of :class:`Variogram` (log least squares).
    Fitted against the truth (``benchmarks/demo_truth.py W``), √γ at k = 1, 4, 8: 9.1,
    11.8, 12.7e-5 against 8.9, 11.7, 12.6e-5 (2026-12-03 demo cloud), 8.9, 11.6, 12.5e-5
    against 8.7, 11.5, 12.5e-5 (merged main's).

    Returns
    -------
    Variogram or None
        None when fewer than seven consecutive single-loop sections exist.
    """
    from scipy.optimize import least_squares

    axis = np.asarray(axis, dtype=np.float64)
    if len(rings) < len(_D6) or sum(_single(e) is not None for e in rings) < len(_D6):
        return None
    radii, heights = _radial_profiles(rings, axis)
    pairs = [np.sum(_D6[:-d] * _D6[d:]) for d in range(1, len(_D6))]
    lags, measured = [], []
    for lag in range(1, max(1, int(max_lag)) + 1):
        span = (len(_D6) - 1) * lag
        if span >= len(rings) or (lag > 1 and span > len(rings) // 2):
            break
        starts = np.arange(len(rings) - span)
        index = starts[:, None] + lag * np.arange(len(_D6))[None, :]       # (W, 7)
        gaps = np.diff(heights[index], axis=1)
        median_gap = np.median(gaps, axis=1)
        even = np.ptp(gaps, axis=1) <= 0.25 * np.abs(median_gap)
        values = np.tensordot(radii[index[even]], _D6, axes=([1], [0]))     # (W', M)
        values = values[np.isfinite(values).all(axis=1)]
        if len(values) < MIN_WINDOWS:
            break
        # About the window's mean over the ring: a shape of revolution's profile term is
        # the same at every angle, so what the 6th differences leave of it near a rounded
        # end goes; the rings' errors lose their mean over the ring (mode 0), put back
        # below from lag 1, where the profile term is smallest.
        spread = float(np.median(np.var(values, axis=1)))
        if not lags:
            mode0 = float(np.median(np.mean(values ** 2, axis=1))) / max(spread, 1e-300)
        mean_square = spread * mode0
        if lags and mean_square > (1.0 + PROFILE_MARGIN) * measured[-1] * lag / lags[-1]:
            break   # growing faster than any variogram of the model can: the profile
        lags.append(lag)
        measured.append(mean_square)
    if not lags:
        return None
    lags_a, measured_a = np.array(lags, dtype=np.float64), np.array(measured)

    def model(params):
        g = Variogram(*np.exp(params))
        return np.array([-2.0 * sum(pairs[d - 1] * g(d * lag) for d in range(1, len(_D6)))
                         for lag in lags_a])

    white = float(measured_a[0] / (_D6 @ _D6))
    if len(lags) < 3:
        return Variogram(white, 0.0, 1.0, tuple(lags), tuple(measured))
    start = np.log([white, white, 2.0])
    fit = least_squares(lambda p: np.log(model(p) / measured_a), start,
                        bounds=(np.log([white * 1e-4, white * 1e-6, 0.1]),
                                np.log([white * 10, white * 1e3, 4.0 * lags_a[-1]])))
    nugget, partial, rng = (float(x) for x in np.exp(fit.x))
    return Variogram(nugget, partial, rng, tuple(lags), tuple(measured))


def section_weights(heights: np.ndarray, keep: Sequence[int], reach: Sequence[int],
                    least: int = 1) -> list[tuple[np.ndarray, np.ndarray]]:
    """Each kept section's local quadratic regression across its neighbour sections.

    Kept section ``k`` is replaced by the value at its own height of the least-squares
    quadratic (in height) through the sections ``j`` with ``|j - k| <= w``, ``w`` the
    smaller gap to the neighbouring kept sections (Savitzky-Golay; 5 sections: weight
    0.49 on its own, noise σ·0.70; 9 sections: 0.26, σ·0.51), so the thinning averages
    the dense rings' independent errors across sections instead of interpolating them;
    a quadratic's weights reproduce the profile up to its curvature.  The window is
    narrowed to the section's ``reach`` (as far as its loops continue one to one,
    :func:`section_layout`); where that leaves ``w < 2`` the section is kept as it is.
    (Before 2026-12-06 a window reaching a section with several loops kept it as it was:
    a temple's columns or a torus's two sides were never regressed.)

    ``heights`` may be any coordinate along the profile: with the sections' positions
    along it (:func:`profile_length`) the quadratic follows a rounded end, whose radius
    is no quadratic of the height near its pole (a unit sphere at 57° latitude, five
    sections 0.17 apart along it: the radius' bias 0.0046 in height, 0.00006 along the
    profile); ``least`` then widens windows narrower than that many sections (where the
    kept sections lie closer than 2 apart, on a dome's leaning part, their rings would
    otherwise be kept unregressed), within the sections there are.

    Parameters
    ----------
    heights : (K,) float64
        The dense sections' heights along the axis.
    keep : sequence of int
        Kept section indices, increasing.
    reach : sequence of int
        Per dense section, the widest half-window its loops allow
        (:attr:`SectionLayout.reach`).

    Returns
    -------
    list of (indices, weights)
        Per kept section, the dense sections and their weights (summing to 1).
    """
    out = []
    keep = list(keep)
    for position, k in enumerate(keep):
        gaps = [k - keep[position - 1] if position > 0 else 0,
                keep[position + 1] - k if position + 1 < len(keep) else 0]
        w = min(gaps)
        if 0 < w < least:   # widened within the sections there are (not at an end)
            w = min(least, k, len(heights) - 1 - k)
        w = min(w, int(reach[k]))
        if w < 2:
            out.append((np.array([k]), np.array([1.0])))
            continue
        index = np.arange(k - w, k + w + 1)
        t = heights[index] - heights[k]
        scale = max(float(np.max(np.abs(t))), 1e-300)
        design = np.vander(t / scale, 3, increasing=True)              # (2w+1, 3)
        weights = design @ np.linalg.solve(design.T @ design, np.eye(3)[0])
        out.append((index, weights))
    return out


def smoothing_matrix(heights: np.ndarray, keep: Sequence[int],
                     weights: Sequence[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """The linear map dense rings -> thinned surface along the profile, ``(K, K)``.

    Row ``i``: the weights of the dense sections in the thinned surface at section
    ``i``'s height -- the kept sections' regressions (:func:`section_weights`) then the
    interpolation between the kept heights, modelled by the not-a-knot cubic spline
    through them (the interpolating Loop surface is a G1 interpolant of the kept rings).
    Rows sum to 1 (constants are reproduced).
    """
    from scipy.interpolate import CubicSpline

    count, keep = len(heights), np.asarray(keep)
    smooth = np.zeros((len(keep), count))
    for row, (index, w) in enumerate(weights):
        smooth[row, index] = w
    if len(keep) >= 4:
        interp = CubicSpline(heights[keep], np.eye(len(keep)), axis=0)(heights)   # (K, kept)
    else:
        interp = np.stack([np.interp(heights, heights[keep], col)
                           for col in np.eye(len(keep))], axis=1)
    return interp @ smooth


def influence(heights: np.ndarray, keep: Sequence[int],
              weights: Sequence[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """The weight of each dense section's own ring in the thinned surface at its height:
    the diagonal of :func:`smoothing_matrix`, the trace term of Stein's unbiased risk
    estimate (:func:`error_estimate`).

    Returns
    -------
    (K,) float64
    """
    return np.diag(smoothing_matrix(heights, keep, weights)).copy()


def unshared_noise(matrix: np.ndarray, variogram: Variogram) -> np.ndarray:
    """Per dense section ``i``, ``Σ_j S_ij γ(|i − j|)``: how much of the dense rings' error
    the thinned surface does *not* share with the ring at ``i`` (``E⟨(I − S)ε, ε⟩_i``
    for rows of ``S`` summing to 1), the correlated-noise form of ``σ² (1 − S_ii)``."""
    lag = np.abs(np.arange(len(matrix))[:, None] - np.arange(len(matrix))[None, :])
    return np.einsum("ij,ij->i", matrix, variogram(lag))


def risk_estimate(distances: np.ndarray, variogram: Variogram, unshared: float) -> float:
    """RMS error to the truth of a thinned surface, from its distances to the dense
    vertices, for errors correlated across sections.

    With ``x = truth + ε`` the dense vertices and ``S x`` the thinned surface at them,
    ``E|Sx − truth|² = E|Sx − x|² − 2 E⟨(I − S)ε, ε⟩ + E|ε|²``; with rows of ``S``
    summing to 1, ``E⟨(I − S)ε, ε⟩ = Σ_j S_ij γ(|i − j|)`` (``unshared``, the mean of
    :func:`unshared_noise` over the reference vertices' sections) and ``E|ε|²`` is the
    variogram's sill (an error common to all sections is left out: it is in every
    surface alike).  For independent errors (``γ = σ²``) it is Stein's estimate,
    :func:`error_estimate`.

    Returns
    -------
    float
        Scene units (0 if the estimate is negative).
    """
    mean_square = float(np.mean(np.square(distances)))
    return float(np.sqrt(max(mean_square - 2.0 * unshared + variogram.sill, 0.0)))


def stitched_error(variogram: Variogram) -> float:
    """RMS error to the truth of the dense stitched mesh over its surface (not at its
    vertices): a point of a triangle with barycentrics ``b`` errs by ``Σ b_i ε_i``, whose
    mean square over the triangle is ``sill − Σ_{i<j} E[b_i b_j] 2γ_ij = sill −
    (γ_a + 2 γ(1)) / 6`` (``E[b_i b_j] = 1/12``; two vertices on one ring, ``γ_a`` their
    variogram along the ring, one on the next section); ``γ_a`` is taken as ``γ(1)``,
    which under-states the stitched mesh's error (the demo's rings: ``γ_a`` = 3.5e-5² by
    the truth) and so makes the sizing stricter.  This, not the error at the vertices,
    is what a mean distance to the truth (Chamfer) sees: for independent errors
    ``σ/√2``, the 0.56 σ mean distance of a polyhedron through noisy vertices against a
    smooth surface's √(2/π) of its RMS error.
    """
    return float(np.sqrt(max(variogram.sill - 0.5 * float(variogram(1)), 0.0)))


def stitched_surface_error(distances: np.ndarray, face_distances: np.ndarray | None,
                           variogram: Variogram) -> float:
    """RMS error to the truth of the dense stitched mesh over its surface, measured against
    a candidate's smooth surface.

    Points ``q`` spread over the dense mesh's faces err by their vertices' errors
    interpolated (``Σ b_i ε_i``, smaller than at the vertices: :func:`stitched_error`)
    plus the flat triangles' chord error (``κ h² / 8`` at an edge's middle: on a coarse
    dense mesh -- few points a section -- as large as the noise).  Both show in their
    distances to any fixed smooth surface as against the vertices' distances:
    ``E d_q² − E d_v² ≈ R_q − R_v`` for a surface whose own error is not correlated with
    the chords, so ``R_q = sill + E d_q² − E d_v²`` (``sill`` = ``R_v``, the vertices'
    error, :class:`Variogram`), and at least :func:`stitched_error` (the interpolated
    noise without chords: a coarse candidate, whose own error follows the chords,
    measures less).  Measured to the exact surface: its tessellation lies
    inside it by its own chords, which cancel part of the dense faces' (by
    ``2 c_dense c_tess``): on the 10⁵-point vase the tessellation's goal was 7 % low and
    took a candidate 1.6× finer.  Without face points (a mesh all rims), the model value
    :func:`stitched_error`.

    Parameters
    ----------
    distances : (N,) float64
        From the reference vertices to the candidate's surface.
    face_distances : (N',) float64 or None
        From points on the dense faces (``_points_on_faces``) to it, measured the same
        way (the far candidates' first check uses the tessellation for both).
    variogram : Variogram

    Returns
    -------
    float
        Scene units.
    """
    if face_distances is None:
        return stitched_error(variogram)
    shift = float(np.mean(np.square(face_distances)) - np.mean(np.square(distances)))
    # never below the interpolated noise alone (chords only add to it): a candidate far
    # from the data, whose own error follows the chords, would measure less
    return max(float(np.sqrt(max(variogram.sill + shift, 0.0))), stitched_error(variogram))


def error_estimate(distances: np.ndarray, noise: float, influence_mean: float) -> float:
    """RMS error to the truth of a surface fitted to noisy points, from its distances to them.

    Stein's unbiased risk estimate (Mallows' Cp): for points ``x = truth + ε``,
    ``ε ~ N(0, σ²)`` independent, and a fit ``S x`` linear in them, the mean squared
    error to the truth is ``E|Sx - x|² - σ² + 2σ²·tr(S)/N``; ``tr(S)/N`` is the mean
    influence of a point on the fit at itself (:func:`influence`).  A fit that copies the
    points (influence 1) gets σ, one that ignores them (0) ``sqrt(mean d² - σ²)``.

    Parameters
    ----------
    distances : (N,) float64
        From the dense vertices to the thinned surface, scene units.
    noise : float
        σ of the dense vertices (:func:`section_scatter`).
    influence_mean : float
        Mean influence over the same vertices.

    Returns
    -------
    float
        Scene units (0 if the estimate is negative).
    """
    mean_square = float(np.mean(np.square(distances)))
    return float(np.sqrt(max(mean_square - noise ** 2 * (1.0 - 2.0 * influence_mean), 0.0)))


def thinning(heights: np.ndarray, layout: SectionLayout, step: int,
             length: np.ndarray | None = None, smooth: bool = True
             ) -> tuple[list[int], list[tuple[np.ndarray, np.ndarray]]]:
    """The sections a thinning keeps (:func:`kept_sections`) and each kept ring's weights
    on the dense rings (:func:`section_weights` within the layout's reach; with ``length``,
    in profile length and windows of at least 2 sections; without ``smooth``, its own
    ring) -- what :func:`coarsen_rings` builds and :func:`size_control_mesh` models."""
    keep = kept_sections(len(heights), step, length)
    if not smooth:
        return keep, [(np.array([k]), np.array([1.0])) for k in keep]
    return keep, section_weights(heights if length is None else length, keep, layout.reach,
                                 least=1 if length is None else 2)


def coarsen_rings(rings: Sequence, planes: Sequence, step: int, n: int,
                  smooth: bool = False, axis=(0.0, 0.0, 1.0), length: np.ndarray | None = None,
                  layout: SectionLayout | None = None) -> tuple[list, list]:
    """Every ``step``-th section (the first and last always), rings resampled to n / 2n.

    Parameters
    ----------
    rings : sequence
        One entry per section: an ``(M, 3)`` ring or a list of them (several loops).
    planes : sequence
        The sections' planes, one per entry (passed through for the kept ones).
    step : int
        Keep every ``step``-th section, graded towards the ends (:func:`kept_sections`).
    n : int
        Points on the kept rings at even positions of the result; odd ones get 2n
        (the stitch's N / 2N pattern, ``surface.catmull_rom.ring_size``).
    smooth : bool
        Each kept ring the local quadratic regression of the resampled dense rings
        around it (:func:`section_weights`) instead of its own dense ring.
    axis : (3,) float64
        The sections' normal (for their heights when ``smooth``).
    length : (K,) float64, optional
        As :func:`kept_sections` (the sections kept ``step`` apart along the profile), and
        the regressions along it (:func:`section_weights` in that coordinate, windows of at
        least 2 sections).
    layout : SectionLayout, optional
        :func:`section_layout` of the rings (computed if not given).

    Returns
    -------
    (rings, planes) : lists
    """
    from surface.catmull_rom import branch_ring_size, perimeter, ring_size

    frame = _plane_frame(axis)
    layout = section_layout(rings, frame) if layout is None else layout
    keep, weights = thinning(_heights(rings, frame[2]), layout, step, length, smooth)
    out, largest = [], _largest_perimeter(rings)
    for position, index in enumerate(keep):
        count = ring_size(position, int(n))
        entry = rings[index]
        loops = _loops(entry)
        window, w = weights[position]
        several = len(loops) > 1  # a lone loop in a list keeps N, as an array does
        new, regressed = [], False
        for i, loop in enumerate(loops):
            size = ring_size(position, branch_ring_size(int(n), perimeter(loop), largest)) \
                if several else count
            aligned = None
            if len(window) > 1:   # the loop regressed along its chain (section_layout)
                chain, at = layout.where[(index, i)]
                members = layout.chains[chain][1][at - (index - window[0]):
                                                  at + (window[-1] - index) + 1]
                aligned = _aligned(members, np.arange(len(members)), size, frame)
            new.append(resample_ring(loop, size) if aligned is None
                       else np.tensordot(w, aligned, axes=1))
            regressed = aligned is not None
        # an array stays an array; a lone loop in a list, regressed, too (as before)
        single = (isinstance(entry, np.ndarray) and entry.ndim == 2) or (
            regressed and not several)
        out.append(new[0] if single else new)
    return out, [planes[i] for i in keep]


def untangled(rings: Sequence, planes: Sequence) -> tuple[list, list]:
    """Thinned ``rings, planes`` without the sections whose loops knot the loop graph or
    cross themselves (``reconstruct.untangle``, as the curves stage does for the dense).

    Thinning a branching stack moves its splits and merges: sections that related one
    to one now relate many to many, or a split's single loop cannot be bridged into its
    branches, and the candidate stitched open.  On the real temple ring posed by SfM
    (``photosurf run`` without cameras) six of seven candidates did, and the sizing kept
    the dense mesh: 424 776 patches for 54 393 points.  The risk model's smoothing
    matrix still counts the dropped sections (a few, at the branch events).
    """
    from surface import reconstruct as rc

    planes, _, rings, _ = rc.untangle(list(planes), [_loops(e) for e in rings], list(rings))
    return rings, planes


def _loops(entry) -> list:
    return [entry] if isinstance(entry, np.ndarray) and entry.ndim == 2 else list(entry)


def _largest_perimeter(rings: Sequence) -> float:
    from surface.catmull_rom import perimeter

    return max((perimeter(loop) for entry in rings for loop in _loops(entry)), default=0.0)


#: Most solves of :func:`interpolating_control`'s unfolding (each keeps the vertices of the
#: faces the last one folded; the mustard bottle needed 4).
UNFOLD_ROUNDS = 8
#: The shares of its interpolating correction a folding vertex is moved by, round after
#: round (:func:`interpolating_control`): halved each time its faces fold, then none.
UNFOLD_SHARES = (0.5, 0.25)
#: Tessellation level the surface's folds are looked for at (:func:`surface.fitting.surface_folds`).
FOLD_LEVEL = 2
#: The level the sizing's candidates are unfolded at while they are judged; the chosen
#: one's surface is built again at :data:`FOLD_LEVEL` (level 2 doubled the sizing's CPU
#: seconds on the shapes table's 10⁴-point rows; what it finds beyond level 1 is a few
#: pairs on a rim, which move no candidate's estimate).
JUDGE_FOLD_LEVEL = 1
#: Keep only the vertices of the folded control faces the surface itself folds over
#: (:func:`surface.fitting.surface_folds`); False: of every folded control face.
SURFACE_FOLDS = True


@one_blas_thread
def interpolating_control(vertices: np.ndarray, triangles: np.ndarray,
                          creases: np.ndarray | None = None,
                          fold_level: int | None = None) -> np.ndarray:
    """Control vertices of the surface through the mesh's vertices, sharp edges kept (but
    ``creases``).

    :func:`surface.fitting.interpolating_control_mesh` with the vertices on an edge
    sharper than 30° (the stitch's support-ring threshold) kept as they are
    (:func:`surface.fitting.sharp_vertices`, ``rings=0``): interpolating a rim ring
    and its support ring one noise width away overshoots the edge (measured on the
    demo's step-7 thinning, 2026-12-01: Hausdorff distance to the truth 0.015
    interpolating everything, 0.0018 with the sharp vertices and their one-rings
    kept).  With the caps' guard rings (``surface.stitch.CAP_GUARD_RINGS``) keeping
    the rim vertices alone is enough and rounds the rims less: 10⁵-point vase sized
    Chamfer 0.000222 -> 0.000206 (rim band 0.00120 -> 0.00085), Hausdorff 0.021 ->
    0.015; demo Hausdorff 0.0072 -> 0.0054, Chamfer unchanged; 5·10⁴ points 0.000319
    -> 0.000311.  Open: at 5·10⁴ points (step 5, n = 34) the bottom rim still
    overshoots outward, about in the cap plane, to 0.024 from the truth (the stitched
    mesh's Hausdorff distance 0.0053); keeping two rings (``rings=2``) gave 0.0101 and
    Chamfer 0.000268 (stitched 0.000288) but a candidate twice as fine (18 248 patches),
    and without the guard ring the overshoot is 0.035 (``rings=0``) / 0.013 (``rings=1``,
    at the top rim).  A mesh with borders gets its own vertices back.

    ``creases`` (2026-12-06): vertices on the object's convex creases inside its end
    sections (:func:`crease_vertices`), which are interpolated too.  Kept, a crease's
    vertices round it inwards: the real temple's smooth surface lay 0.0027 IoU below its
    stitched mesh's silhouettes on average over the 16 views (its unsized dense surface
    alike, -0.0028).  Measured (one-off scripts; the temple against its silhouettes, the
    shapes against their truth, seeds 0 / 1 of 30 000 points): the rule as it is, temple
    +0.0051 above the stitched mesh (min / median IoU 0.807 / 0.856 against 0.796 / 0.851;
    63 840 patches against 75 624: the sizing passes step 2 at n = 81 now); at spacing 5
    (18 998 points) -0.0152 against -0.0125 before, at 16 480 patches against 27 816;
    torus +3 / -3 %, pants -5 / -8 %, mug +1 / -3 %, amphora -7 / -8 %, the vase with an
    opening and the five shapes of revolution unchanged bit for bit.  The variants tried:
    every sharp vertex interpolated, temple +0.0039 but the mug +46-56 % and the vase with
    an opening +28-30 % (their lips' and floors' creases); the valleys kept, the mug still
    +21-25 % (its lip: two ridges 0.25 apart at the top end, kept now as an end's); a
    candidate's own sharp vertices, without the dense mesh's, the 10⁴-point elliptic
    cylinder 1.9x (its sections' tips, 24-34 ring points, are "sharp" at 30° by their
    sampling alone).

    Folds (2026-12-07): where the correction turns a control face over or makes control
    faces cross that the mesh does not (:func:`surface.fitting.folded_faces`: signs, no
    tolerance), that face's vertices are kept too and the system solved again, until no
    such face is left (at most :data:`UNFOLD_ROUNDS` solves); a ``creases`` vertex only where
    the face has no other vertex to keep (the stepped column of ``tests/surface/test_creases.py``:
    keeping every folded face's vertices kept all 110 crease vertices, Chamfer 0.00444 ->
    0.00392; sparing them, all 110 still interpolated, 3 164 crossing pairs -> 0, Chamfer
    0.00389).  The mustard bottle (40 000 points, noise-free, stitched mesh 54 414 faces):
    3 691 control faces turned over and
    10 382 crossing pairs in the caps' fans and rims, the smooth surface 16 705 crossing
    pairs; after three rounds (5 838 of 27 209 vertices kept) 0 pairs and Chamfer
    3.53e-5 -> 3.37e-5 (``docs/decisions/smooth-folds.md``).

    Part way, where the surface folds (2026-12-07, the rule now): of the folded control
    faces only those whose patches cross or turn over (:func:`surface.fitting.surface_folds`)
    count, and their vertices move by half, then a quarter of their correction
    (:data:`UNFOLD_SHARES`), then none.  Keeping every folded face's vertices had held ~20 %
    of a coarse candidate's vertices off the data and sent the sizing to the dense mesh
    (the 10⁴-point cylinder: 25 160 patches); now 6 512, 0 crossing pairs, and the
    capsule's 339 pairs -> 0 at Chamfer 0.000787 (keeping: 0.001075 on the same mesh).
    ``fold_level``: the tessellation level the folds are looked for at (default
    :data:`FOLD_LEVEL`; the sizing judges its candidates at :data:`JUDGE_FOLD_LEVEL`).
    """
    from surface.fitting import (
        flat_vertices,
        folded_faces,
        interpolating_control_mesh,
        sharp_vertices,
        surface_folds,
    )
    from surface.validity import check_solid

    try:
        keep = sharp_vertices(vertices, triangles, rings=0) | flat_vertices(vertices, triangles)
        if creases is not None:   # the object's convex creases are interpolated
            keep &= ~np.asarray(creases, dtype=bool)
        triangles = np.asarray(triangles, dtype=np.int64)
        crossing = check_solid(vertices, triangles).intersecting_pairs  # the mesh's own
        crease = None if creases is None else np.asarray(creases, dtype=bool)
        # each vertex's share of its interpolating correction: 1 free, 0 kept as it is
        share = np.where(keep, 0.0, 1.0)
        full = control = interpolating_control_mesh(vertices, triangles, keep=keep)
        for _ in range(UNFOLD_ROUNDS):
            folded = folded_faces(vertices, control, triangles, target_pairs=crossing)
            if folded.any() and SURFACE_FOLDS:   # those the surface itself folds over
                folded = surface_folds(vertices, control, triangles, folded, crossing,
                                       level=FOLD_LEVEL if fold_level is None
                                       else fold_level)
            flag = np.zeros(len(share), dtype=bool)
            flag[triangles[folded].ravel()] = True
            flag &= share > 0.0
            if crease is not None:   # a crease's vertices only where nothing else unfolds it
                others = (flag & ~crease)[triangles].any(axis=1)
                spared = np.zeros_like(flag)
                spared[triangles[folded & others].ravel()] = True
                flag &= ~(crease & spared)
            if not flag.any():   # no fold left the correction made
                break
            share[flag] = np.where(share[flag] > UNFOLD_SHARES[-1], share[flag] / 2.0, 0.0)
            held = share < 1.0
            control = interpolating_control_mesh(
                vertices, triangles, keep=held,
                at=vertices + share[:, None] * (full - np.asarray(vertices, np.float64)))
        return control
    except ValueError:  # borders: no limit-point system
        return np.asarray(vertices, dtype=np.float64)


def reference_vertices(vertices: np.ndarray, triangles: np.ndarray,
                       rng: np.random.Generator, off_rims: np.ndarray | None = None
                       ) -> np.ndarray:
    """Indices (sorted) of at most ``REFERENCE_POINTS`` vertices of the dense mesh that its
    smooth surface passes through: those on or next to a sharp edge are left out.

    There :func:`interpolating_control` keeps the vertices as control points, so every
    surface -- the dense one too -- rounds the rim off by about the support-ring width
    instead of passing through them: a deviation common to all candidates that says
    nothing about the thinning (measured on the 50 000-point vase: it raised the mean
    deviation of the step-2 candidate from 0.00024 to 0.00029, 20 % of the tolerance).
    A coarser candidate's wider rounding still shows at the dense vertices next to
    that band.  A mesh with no other vertices keeps them all.  ``off_rims``: the mask of
    the vertices off the sharp edges, if known (:func:`_off_rims`).
    """
    candidates = np.arange(len(vertices))
    smooth = np.flatnonzero(_off_rims(vertices, triangles) if off_rims is None else off_rims)
    if len(smooth):
        candidates = smooth
    area = _vertex_areas(vertices, triangles)[candidates]
    weights = area / area.sum() if area.sum() > 0 else None
    pick = rng.choice(candidates, size=min(REFERENCE_POINTS, np.count_nonzero(area) if
                                           weights is not None else len(candidates)),
                      replace=False, p=weights)
    return np.sort(pick)


def _vertex_areas(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """A third of the area of each vertex's faces: the reference vertices are drawn by it,
    so that their mean squares weigh the surface as the points spread over its faces do
    (:func:`stitched_surface_error` compares the two)."""
    from surface.metrics import triangle_areas

    tri = np.asarray(triangles, dtype=np.int64)
    area = triangle_areas(np.asarray(vertices, dtype=np.float64), tri)
    return np.bincount(tri.ravel(), weights=np.repeat(area / 3.0, 3), minlength=len(vertices))


def crease_band(heights: np.ndarray) -> tuple[float, float]:
    """The heights between which :func:`crease_vertices` looks: the second and the
    last-but-one of the sections' ``heights``, half their median spacing beyond -- no
    vertex of a ring sits on a bound (a ring's height is its points' mean: a bound at it
    would split them by rounding).  Empty (``(inf, -inf)``) with fewer than four."""
    ordered = np.sort(np.asarray(heights, dtype=np.float64))
    if len(ordered) < 4:
        return np.inf, -np.inf
    half = 0.5 * float(np.median(np.diff(ordered)))
    return float(ordered[1]) - half, float(ordered[-2]) + half


def mesh_creases(vertices: np.ndarray, triangles: np.ndarray, rings: Sequence,
                 axis) -> np.ndarray | None:
    """:func:`crease_vertices` of a stitched mesh itself (no candidate to match against),
    its ``rings`` giving the sections' heights: what the smooth stage interpolates when
    the sizing is off (``smooth.size = false``) or keeps the dense mesh."""
    axis = np.asarray(axis, dtype=np.float64)
    return crease_vertices(vertices, triangles, axis, crease_band(_heights(rings, axis)))


def crease_vertices(vertices: np.ndarray, triangles: np.ndarray, axis, inner: tuple,
                    dense: np.ndarray | None = None, reach: float = 0.0) -> np.ndarray | None:
    """The vertices on the object's convex creases, ``(V,) bool`` (None without any):
    :func:`surface.fitting.convex_creases` between the heights ``inner = (lo, hi)``
    along ``axis`` (:func:`size_control_mesh`: the second and the last but one section,
    half a spacing beyond) -- the ends' rims, held by support rings a noise width away,
    stay as they are -- and, with ``dense`` crease points (a candidate judged against its dense
    mesh), within ``reach`` of one of them: a crease the dense mesh has too, not the
    coarse sampling of a smooth bend (an elliptic section's tips at 24-34 ring points
    are "sharp" at 30°; at the dense mesh's resolution they are not).

    Why (2026-12-06): the kept creases round the real temple's edges inwards; the
    figures are :func:`interpolating_control`'s.
    """
    from surface.fitting import convex_creases

    if not INTERPOLATE_CREASES:
        return None
    vertices = np.asarray(vertices, dtype=np.float64)
    height = vertices @ np.asarray(axis, dtype=np.float64)
    mask = convex_creases(vertices, triangles) & (height > inner[0]) & (height < inner[1])
    if dense is not None:
        if len(dense) == 0:
            return None
        from scipy.spatial import cKDTree

        near = np.zeros(len(vertices), dtype=bool)
        if mask.any():
            near[mask] = cKDTree(dense).query(vertices[mask], distance_upper_bound=reach)[0] \
                <= reach
        mask = near
    return mask if mask.any() else None


def _smooth_surface(vertices: np.ndarray, triangles: np.ndarray,
                    creases: np.ndarray | None = None):
    """Loop's surface interpolating the mesh (``creases``: :func:`interpolating_control`)
    and the distance function of its level-1 tessellation (``surface.metrics.MeshDistance``:
    one raycasting scene for several point sets, and the start of
    :func:`surface.bezier.closest_points`)."""
    from surface import bezier
    from surface.metrics import MeshDistance

    control = interpolating_control(vertices, triangles, creases, JUDGE_FOLD_LEVEL)
    surface = bezier.control_net(control, triangles)
    v, t, _ = bezier.tessellate(surface, 1)
    return surface, MeshDistance(v, t)


def smooth_deviation(vertices: np.ndarray, triangles: np.ndarray, reference: np.ndarray):
    """Loop's surface interpolating ``(vertices, triangles)`` and its mean distance to
    ``reference``.

    Returns ``(surface, mean distance)``; the distance is measured to the level-1
    tessellation (16 triangles per control triangle: edges a quarter of the control
    mesh's, chord error ~ κ h² / 128 for control edge h: 5e-5 on the demo's candidates,
    which is why :func:`size_control_mesh` measures the candidates near its goal to the
    exact surface).  A mesh with borders gets the approximating surface (no
    interpolating solve exists there).
    """
    surface, measure = _smooth_surface(vertices, triangles)
    return surface, float(measure(reference).mean())


@dataclass
class SizedMesh:
    """The thinned control mesh and how it was chosen.

    Attributes
    ----------
    vertices : (V, 3) float64
    triangles : (F, 3) int64
        The thinned stitched mesh (vertices on the dense curves, or on their
        regression across sections).
    step, n : int
        Sections kept every ``step``; ring points n / 2n (``step = 1, n = 0``: the
        dense mesh itself was kept).
    deviation : float
        Mean distance from the dense mesh's reference vertices to the smooth surface
        over this mesh (scene units).
    tolerance : float
        Largest error estimate accepted (scene units).
    tried : list of dict
        Every candidate: ``step``, ``n``, ``triangles``, ``deviation``, ``error``.
    error : float
        The chosen candidate's estimated RMS error to the truth
        (:func:`risk_estimate`; 0 for the dense mesh).
    noise : float
        σ of the dense rings' errors between neighbouring sections: ``√γ(1)`` of the
        variogram, or the white-noise σ taken where it could not be measured.
    variogram : Variogram
        The dense rings' errors across sections the estimates used.
    surface : surface.bezier.BezierSurface or None
        Loop's surface interpolating this mesh (:func:`interpolating_control`, then
        ``surface.bezier.control_net``), as built to judge a thinned candidate (passed
        or the closest of those that failed); None for the dense mesh.
    creases : (V,) bool or None
        The vertices on the object's convex creases (:func:`crease_vertices`), which the
        surface interpolates: ``interpolating_control(vertices, triangles, creases)``.
    spacing : float
        The cloud's point spacing (``surface.sections.point_spacing``; 0 when not known):
        no facet of the tessellation need be finer
        (``pipeline.smoothing.spacing_cuts``).
    """

    vertices: np.ndarray
    triangles: np.ndarray
    step: int
    n: int
    deviation: float
    tolerance: float
    tried: list = field(default_factory=list)
    error: float = 0.0
    noise: float = 0.0
    variogram: Variogram | None = None
    surface: object = field(default=None, repr=False)
    creases: np.ndarray | None = field(default=None, repr=False)
    spacing: float = 0.0

    def chord_tolerance(self) -> float:
        """Chord tolerance of the surface's tessellation: ``CHORD_FRACTION`` of its
        estimated error to the truth (of the dense rings' noise when the dense mesh was
        kept), 0 when neither is known.

        The flat triangles then lie within what the data leave open anyway.  Measured
        (one run each, 2026-12-03): on the 5*10^4-point σ = 0.002 vase (9 304 patches,
        estimated error 0.00041) the smooth surface's Chamfer distance to the truth is
        0.000249 tessellated at level 3 (595 456 triangles), 0.000247 at half the error
        (160 516), 0.000261 at the error (74 920) and 0.000322 at the former fixed
        level 1 (37 216), the dense stitched mesh's 0.000287; on the demo (108 376
        patches, error 6.3e-5) half the error gives 884 166 triangles and Chamfer
        0.000331, level 1 433 504 and 0.000334, the error itself at least 381 052.
        Half the error doubles the demo's files for 1 % of its Chamfer distance.
        """
        scale = self.error if self.error > 0 else self.noise
        return CHORD_FRACTION * scale if np.isfinite(scale) and scale > 0 else 0.0


@one_blas_thread
def size_control_mesh(rings: Sequence, planes: Sequence, spacing: float,
                      build: Callable, dense: tuple[np.ndarray, np.ndarray],
                      tolerance: float | None = None, seed: int = 0,
                      noise: float | None = None, smooth: bool = True,
                      variogram: Variogram | None = None,
                      along_profile: bool = True) -> SizedMesh:
    """The coarsest thinning of the rings whose smooth surface is estimated no farther
    from the truth than the dense stitched mesh (or within ``tolerance`` of it).

    Each candidate's kept rings are regressions across their neighbour sections
    (``smooth``, :func:`section_weights`); its RMS error to the truth is estimated from
    its exact distances to the dense mesh's reference vertices (:func:`risk_estimate`:
    the dense rings' variogram across sections, :func:`section_variogram`, and the
    candidate's weights on them, :func:`smoothing_matrix`).  By default a candidate
    passes when that estimate is within the dense stitched mesh's own error over its
    surface (:func:`stitched_error`), the goal's currency: a mean distance to the truth
    sees a surface, not its vertices.  After the first candidate that passes, one
    between it and the previous (its edge length × 2^¼) is tried too.

    Parameters
    ----------
    rings : sequence
        The dense rings, one entry per section (``(M, 3)`` or a list of loops),
        before any end extension.
    planes : sequence
        Their section planes (``surface.sections.Section``).
    spacing : float
        Distance between the dense sections, scene units (> 0).
    build : callable ``(rings, planes) -> (vertices, triangles)``
        Stitches thinned rings with the dense mesh's rules (end rings, caps,
        supports), e.g. ``surface.reconstruct.extend_to_caps`` then
        ``surface.stitch.stitch_rings``.
    dense : ((V, 3) float64, (F, 3) int64)
        The dense stitched mesh, the reference.
    tolerance : float, optional
        Largest estimated RMS error to the truth, scene units (> 0); default the dense
        stitched mesh's estimated error, :func:`stitched_error`.
    seed : int
        Seed of the reference sample (fixed: the same input gives the same choice).
    noise : float, optional
        σ of the dense rings' errors, taken as independent between sections where their
        variogram cannot be measured (fewer than seven single-loop sections); default
        :func:`section_scatter` (0 when it cannot be measured either: the estimate is
        then the RMS distance).
    smooth : bool
        Regress the kept rings across sections (else they are the dense rings).
    variogram : Variogram, optional
        Default :func:`section_variogram` of the rings, else white noise of ``noise``.
    along_profile : bool
        Keep the sections ``step`` apart along the profile (:func:`profile_length`) when
        both ends are rounded (:func:`rounded_ends`; module docstring, *Along the
        profile*); False: every ``step``-th section (the rule before 2026-12-06).

    Returns
    -------
    SizedMesh
        If no coarser candidate passes: the one estimated closest to the truth (the
        fewest patches within one standard error of the closest estimate) when that
        estimate is below the rings' sill (what the dense mesh's own smooth surface can
        reach; its ``error`` then exceeds its ``tolerance``), else the dense mesh itself
        (``step = 1, n = 0``).

    Raises
    ------
    ValueError
        A non-positive spacing or tolerance, or fewer than two sections.
    """
    if not (np.isfinite(spacing) and spacing > 0):
        raise ValueError(f"spacing must be a positive distance, got {spacing}")
    if tolerance is not None and not (np.isfinite(tolerance) and tolerance > 0):
        raise ValueError(f"tolerance must be a positive distance, got {tolerance}")
    if len(rings) < 2 or len(planes) != len(rings):
        raise ValueError(f"need at least two sections with one plane each, got {len(rings)} "
                         f"rings and {len(planes)} planes")
    axis = np.asarray(planes[0].frame[2], dtype=np.float64)
    if variogram is None:
        variogram = section_variogram(rings, axis)
    if variogram is None:   # fewer than seven single-loop sections: independent errors
        if noise is None:
            noise = section_scatter(rings, axis)
        noise = float(noise) if np.isfinite(noise) else 0.0
        variogram = Variogram.white(noise)
    else:
        noise = float(np.sqrt(variogram(1)))
    if tolerance is None and not variogram.sill > 0:
        raise ValueError("no noise estimate of the dense rings: give a tolerance")
    dense_vertices, dense_triangles = (np.asarray(a) for a in dense)
    heights = _heights(rings, axis)
    order = np.argsort(heights)
    rng = np.random.default_rng(seed)
    sharp = _sharp(dense_vertices, dense_triangles)
    # the object's convex creases inside its end sections (crease_vertices), interpolated by
    # every candidate; like the rims they stay out of the reference sample (counted in it,
    # the real temple's thinnings were estimated 3-6x their goal and its dense mesh kept:
    # 308 744 patches, its silhouettes 0.0032 IoU above the stitched mesh's; 2026-12-06)
    between = crease_band(heights)
    dense_creases = crease_vertices(dense_vertices, dense_triangles, axis, between)
    crease_points = dense_vertices[dense_creases] if dense_creases is not None else None
    off_rims = _off_rims(dense_vertices, dense_triangles, sharp)
    reference = reference_vertices(dense_vertices, dense_triangles, rng, off_rims)
    nearest = _nearest_section(dense_vertices[reference] @ axis, heights, order)
    inner = (nearest > 0) & (nearest < len(rings) - 1)   # the end planes' caps: not rings
    if inner.sum() >= min(100, len(inner)):
        reference, nearest = reference[inner], nearest[inner]
    reference = dense_vertices[reference]
    on_faces = _points_on_faces(dense_vertices, dense_triangles, off_rims, len(reference),
                                axis, heights, order, seed)
    layout = section_layout(rings, _plane_frame(axis))
    # kept step apart along the profile where both ends are rounded (kept_sections)
    length = profile_length(rings, axis) / spacing if along_profile and all(
        rounded_ends(rings, (dense_vertices, dense_triangles), axis, sharp)) else None
    perimeter = _largest_perimeter(rings)
    dense_n = min(len(loop) for entry in rings[::2] for loop in _loops(entry))
    tried: list[dict] = []
    seen = set()
    failed: list = []            # (SizedMesh, standard error) of each candidate that failed
    shared_goal = [None, np.inf]  # the goal measured by the finest candidate not at step 1
                                  # (and its h)
    floor = float(np.sqrt(variogram.sill))   # a step-1 candidate's estimate is never below

    def level_key(h):
        """``(step, n)`` of the level of edge length ``h``."""
        return max(1, int(np.floor(h / spacing))), _ring_points(perimeter, h)

    def judge(h):
        """The candidate of edge length ``h``: a SizedMesh if it passes, else None."""
        step, n = level_key(h)
        if (step, n) in seen or (step == 1 and n >= dense_n):
            return None
        seen.add((step, n))
        if step == 1 and tolerance is None and shared_goal[0] is not None \
                and floor > shared_goal[0]:
            # keeps every dense ring as it is (section_weights: w < 2), so its error
            # estimate is at least the rings' sill: it cannot pass (module docstring)
            tried.append({"step": step, "n": n, "skipped": "step 1 cannot reach the goal",
                          "floor": floor, "tolerance": float(shared_goal[0])})
            return None
        started = time.perf_counter()
        along = length if step >= ALONG_PROFILE_STEP else None
        thin_rings, thin_planes = untangled(*coarsen_rings(rings, planes, step, n,
                                                           smooth=smooth, axis=axis,
                                                           length=along, layout=layout))
        keep, weights = thinning(heights, layout, step, along, smooth)
        matrix = smoothing_matrix(heights if along is None else along, keep, weights)
        mean_influence = float(np.diag(matrix)[nearest].mean())
        unshared = float(unshared_noise(matrix, variogram)[nearest].mean())
        try:
            vertices, triangles = build(thin_rings, thin_planes)
            creases = None if crease_points is None else crease_vertices(
                vertices, triangles, axis, between, crease_points, h)
            surface, measure = _smooth_surface(vertices, triangles, creases)
            distances = measure(reference)
            error = risk_estimate(distances, variogram, unshared)
            goal = tolerance if tolerance is not None else stitched_surface_error(
                distances, None if on_faces is None else measure(on_faces), variogram)
            if error <= EXACT_WITHIN * goal:   # near: exact distances to the candidate
                from surface.bezier import closest_points
                faces = tolerance is None and on_faces is not None
                exact = closest_points(surface, np.vstack([reference, on_faces]) if faces
                                       else reference, tessellated=measure)[0]
                distances = exact[:len(reference)]
                error = risk_estimate(distances, variogram, unshared)
                if faces:
                    goal = stitched_surface_error(distances, exact[len(reference):],
                                                  variogram)
        except ValueError as exc:  # a thinning the stitch or the surface refuses
            tried.append({"step": step, "n": n, "error": str(exc)})
            return None
        if tolerance is None:
            if step > 1:
                if h < shared_goal[1]:
                    shared_goal[0], shared_goal[1] = goal, h
            elif shared_goal[0] is not None:
                # a step-1 candidate copies the dense rings' errors: its own measure of the
                # goal holds them twice (module docstring); the finest coarser one's holds
                goal = shared_goal[0]
        se = _risk_se(distances, error)
        tried.append({"step": step, "n": n, "triangles": int(len(triangles)),
                      "deviation": float(distances.mean()), "error": error,
                      "tolerance": float(goal), "influence": mean_influence,
                      "unshared": unshared, "error_se": se,
                      "seconds": round(time.perf_counter() - started, 3)})
        # the surface built to judge it is the smooth stage's, should it be chosen (the
        # closest of the failed ones may be)
        sized = SizedMesh(np.asarray(vertices), np.asarray(triangles, np.int64), step, n,
                          float(distances.mean()), float(goal), tried, error, noise, variogram,
                          surface, creases)
        if error > goal:
            failed.append((sized, se))
            return None
        return sized

    levels, h = [], perimeter / MIN_RING_POINTS
    while level_key(h)[0] > 1 or level_key(h)[1] < dense_n:
        levels.append(h)
        h /= H_RATIO

    def walk():
        """After a bisection that found none (WALK_WHEN_NONE_PASS): the step-1 levels in
        order, then, from the level estimated closest, coarser levels outwards while
        their estimates stay within one standard error of it (each coarser one beyond is
        farther still, as the bisection assumes): what trying every level finds -- the
        coarsest pass, or :func:`_closest_failed`'s choice -- without building the coarse
        levels the estimate rules out (the real temple: four of seven candidates)."""
        for h in levels:
            if int(np.floor(h / spacing)) < 2:
                passed = judge(h)
                if passed is not None:
                    return h, passed
        if not failed:
            return None
        best, se = min(failed, key=lambda pair: pair[0].error)
        at = next((i for i, h in enumerate(levels) if level_key(h) == (best.step, best.n)), 0)
        passes = []
        for h in levels[at - 1::-1] if at > 0 else []:
            passed = judge(h)
            if passed is not None:
                passes.append((h, passed))
                continue
            error = next((c["error"] for c in tried if (c["step"], c["n"]) == level_key(h)
                          and isinstance(c.get("error"), float)), None)
            if error is not None and error > best.error + se:
                break
        return passes[-1] if passes else None

    # the coarsest level that passes, by bisection over the levels of step >= 2 (the
    # estimate falls as h does: SEARCH_BISECT)
    coarse = [h for h in levels if int(np.floor(h / spacing)) >= 2]
    found = None
    lo, hi = 0, len(coarse) if SEARCH_BISECT else 0
    while lo < hi:
        mid = (lo + hi) // 2
        passed = judge(coarse[mid])
        if passed is not None:
            hi, found = mid, (coarse[mid], passed)
        else:
            lo = mid + 1
    if found is None and SEARCH_BISECT and WALK_WHEN_NONE_PASS:
        found = walk()
    # none found: every level in order (those judged already are skipped; the step-1 ones
    # against the finest coarser level's goal, module docstring), as without the bisection
    # -- a level it stepped over may pass, and the closest estimate, kept when none does,
    # is chosen among all of them
    for h in ([] if found is not None or (SEARCH_BISECT and WALK_WHEN_NONE_PASS)
              else levels):
        passed = judge(h)
        if passed is not None:
            found = (h, passed)
            break
    if found is not None:
        between = judge(found[0] * np.sqrt(H_RATIO))   # half way (in log h) to the previous
        return _refolded(between if between is not None else found[1])
    best = _closest_failed(failed)
    if best is not None and best.error < floor:
        # none passed, but one is estimated closer to the truth than the dense mesh's own
        # smooth surface can be (at least the sill): the fewest patches among the closest
        return _refolded(best)
    return SizedMesh(dense_vertices, dense_triangles.astype(np.int64), 1, 0, 0.0,
                     tolerance if tolerance is not None else stitched_error(variogram),
                     tried, 0.0, noise, variogram, creases=dense_creases)


def _refolded(sized: SizedMesh) -> SizedMesh:
    """The chosen candidate with its surface built again over the control mesh unfolded at
    :data:`FOLD_LEVEL` (it was judged at :data:`JUDGE_FOLD_LEVEL`): the surface the smooth
    stage writes."""
    if sized.surface is None or FOLD_LEVEL == JUDGE_FOLD_LEVEL:
        return sized
    from surface import bezier

    control = interpolating_control(sized.vertices, sized.triangles, sized.creases)
    sized.surface = bezier.control_net(control, sized.triangles)
    return sized


def _risk_se(distances: np.ndarray, error: float) -> float:
    """Standard error of :func:`risk_estimate` from its reference sample (the mean square's
    sampling error, ``√(var d² / N)``, through the square root); 0 where it cannot be
    told (no credit for noise)."""
    square = np.square(np.asarray(distances, dtype=np.float64))
    if error <= 0 or len(square) < 2:
        return 0.0
    return float(np.sqrt(square.var(ddof=1) / len(square)) / (2.0 * error))


def _ring_points(perimeter: float, h: float) -> int:
    """Ring points ``n = ceil(P / h)`` of a candidate level, at least 3.

    The levels are ``h = P / 12 / √2^k``, so for even k ``P / h`` is an integer
    (12, 24, 48, 96, ...) up to rounding, and a plain ceiling read the rounding: on the
    real temple ring the cloud moved by 1e-13 of its coordinates gave 96 or 97 ring points
    (75 624 or 76 336 patches).  The quotient is taken 1e-9 below itself: the integer.
    """
    return max(3, int(np.ceil(perimeter / h * (1.0 - 1e-9))))


def _closest_failed(failed: list) -> SizedMesh | None:
    """Of the candidates that did not pass (``(SizedMesh, standard error)`` each), the one
    with the fewest triangles among those whose estimate is within one standard error of
    the smallest (the estimates of neighbouring candidates differ by less than their
    sampling noise: the coarser one is as close as the data can tell)."""
    if not failed:
        return None
    best, se = min(failed, key=lambda pair: pair[0].error)
    return min((c for c, _ in failed if c.error <= best.error + se),
               key=lambda c: len(c.triangles))


def _sharp(vertices, triangles) -> np.ndarray | None:
    """Vertices on a sharp edge (``surface.fitting.sharp_vertices``), None when the mesh
    has borders."""
    from surface.fitting import sharp_vertices

    try:
        return sharp_vertices(vertices, triangles, rings=0)
    except ValueError:
        return None


def _off_rims(vertices, triangles, sharp: np.ndarray | None = None) -> np.ndarray:
    """Vertices neither on nor next to a sharp edge (all of them if the mesh has borders);
    ``sharp``: :func:`_sharp` of the mesh, if known."""
    from surface.fitting import grow_vertices

    sharp = _sharp(vertices, triangles) if sharp is None else sharp
    if sharp is None:
        return np.ones(len(vertices), dtype=bool)
    return ~grow_vertices(sharp, triangles, 1)


def _points_on_faces(vertices, triangles, off_rims, count, axis, heights, order, seed):
    """``count`` points spread by area over the dense mesh's faces whose vertices are all
    off the sharp rims and off the end planes (as the reference vertices); None if there
    are none."""
    from surface.metrics import sample_mesh

    eligible = off_rims.copy()
    section = _nearest_section(vertices @ axis, heights, order)
    eligible &= (section > 0) & (section < len(heights) - 1)
    faces = triangles[eligible[triangles].all(axis=1)]
    if len(faces) == 0:
        return None
    return sample_mesh(vertices, faces, count=count, seed=seed + 1)


def _nearest_section(values: np.ndarray, heights: np.ndarray, order: np.ndarray) -> np.ndarray:
    """Index of the section whose height is nearest each value."""
    sorted_heights = heights[order]
    at = np.clip(np.searchsorted(sorted_heights, values), 1, len(heights) - 1)
    left = np.abs(values - sorted_heights[at - 1]) <= np.abs(sorted_heights[at] - values)
    return order[np.where(left, at - 1, at)]


@one_blas_thread
def sized_from_points(points: np.ndarray, axis="z", tolerance: float | None = None,
                      smoothing: float | str = "auto", support: bool = True,
                      sections: int | None = None, n: int | None = None,
                      sigma: np.ndarray | None = None):
    """Cloud -> dense stitched mesh -> sized control mesh, the steps of
    ``surface.reconstruct.surface_from_points`` with its defaults, then
    :func:`size_control_mesh` (what ``photosurf run``'s smooth stage does).

    Parameters
    ----------
    points : (P, 3) float64
    axis : as ``surface_from_points``
    tolerance : float, optional
        Largest estimated error to the truth; default :func:`ring_noise` of the dense
        rings (the thinned surface no farther from the truth than they are).
    smoothing, support, sections, n, sigma
        As ``surface_from_points`` (``sigma``: the points' precision, which places the
        ends by inverse-variance weights).

    Returns
    -------
    (SizedMesh, StitchResult)
        The sized control mesh and the dense stitched mesh.
    """
    from surface import reconstruct as rc
    from surface.stitch import stitch_rings

    sliced = rc.slice_cloud(points, axis=axis, sections=sections)
    kept, loops, _ = rc.organise_sections(sliced.sections,
                                          min_points=rc.min_loop_points(smoothing))
    rings, fits = rc.section_rings(kept, loops, n, smoothing=smoothing, fits=True)
    fit_of = {id(section): fit for section, fit in zip(kept, fits, strict=True)}
    kept, loops, rings, _ = rc.untangle(kept, loops, rings)
    noise = rc.section_noise(loops)
    precision = ring_precision([fit_of[id(section)] for section in kept])
    cap = sliced.cap_cloud
    cap_sigma = None if sigma is None else np.asarray(sigma, np.float64)[sliced.cap_index]

    def build(ring_list, planes):
        extended, _ = rc.extend_to_caps(ring_list, planes, cap, np.arange(len(cap)),
                                        sliced.spacing, sigma=cap_sigma)
        result = stitch_rings(extended, kept[0].frame[2], close_ends=True,
                              support_sigma=noise if support else None, cap_points=cap)
        if not result.closed:
            raise ValueError("the thinned rings stitch to an open mesh")
        return result

    dense = build(rings, kept)
    ring_sigma = ring_noise(rings, kept[0].frame[2], precision, noise)
    sized = size_control_mesh(rings, kept, sliced.spacing,
                              lambda r, p: (lambda s: (s.vertices, s.triangles))(build(r, p)),
                              (dense.vertices, dense.triangles),
                              float(tolerance) if tolerance else None, noise=ring_sigma)
    from surface.sections import point_spacing

    sized.spacing = float(point_spacing(np.asarray(points, dtype=np.float64)))
    return sized, dense
