r"""Unorganised points to a stitched mesh: slice, organise, fit, predict, stitch.

The orchestration of the section method from a cloud (DESIGN.md): the steps
are public so that a pipeline can store what is between them, and run in this
order with the same parameters they give :func:`surface_from_points`'s mesh.

1. :func:`slice_cloud` (``surface.sections.slice_sections``, then
   :func:`slide_to_planes`);
2. :func:`organise_sections` (``surface.topology.organise`` per section);
3. :func:`section_rings` (``surface.catmull_rom.predict_sections``);
4. :func:`extend_to_caps`;
5. ``surface.stitch.stitch_rings``.

From points (:func:`surface_from_points`): slice, then move every slab
point to its plane along the local surface rather than along the axis
(:func:`slide_to_planes`: on a wall of slope r' an axial projection adds
noise of size r'·(slab half-width); sliding on the tangent plane leaves
O(κδ²)), organise, fit and predict the rings, move the end sections to the
median height of the cap points beyond them (:func:`extend_to_caps`: the
section planes stop half a spacing inside the data), stitch.
"""

from __future__ import annotations

import inspect
import warnings
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from surface._blas import one_blas_thread
from surface.loop_graph import nesting
from surface.polygon import inside_polygon, polygon_area
from surface.stitch import (
    CAP_SHRINK,
    HOLE_SHARE,
    StitchResult,
    _dome,
    _nearest_loop,
    _scaled,
    end_window,
    loops_cross,
    self_intersects,
    stitch_rings,
    uncovered_share,
)
from surface.topology import SectionSkippedWarning, organise
from surface.validate import TOL

__all__ = ["OneSidedError", "surface_from_points", "slide_to_planes", "extend_to_caps",
           "largest_perimeter",
           "SlicedCloud", "slice_cloud", "organise_sections", "ring_count", "section_rings",
           "min_loop_points", "section_noise", "untangle", "choose_axis", "rim_line",
           "bridged_share", "MAX_BRIDGED_SHARE", "self_intersects", "keyhole", "EndKind",
           "classify_ends", "outer_loops", "THIN_RIM"]

#: Neighbours of the PCA normal estimate (a plane fit needs >= 3; 12 averages noise).
NORMAL_NEIGHBOURS = 12
#: Smallest sin(angle between surface normal and axis) for a point to join a
#: section contour: below it the surface is within 30° of the section plane
#: (an end cap, a pole) and sliding the point to its plane would move it more
#: than twice its height offset.
MIN_WALL_SINE = 0.5
#: Cap points count for the cap height when inside the end contour shrunk by
#: this factor about its centroid (keeps the wall's own points out).
CAP_INSET = 0.9


#: Points the PCA normals are estimated on, at most (a fixed random subset beyond, each
#: point taking its nearest subset point's normal).  With k neighbours the plane fit spans
#: ~sqrt(k/π) point spacings, and once the spacing falls below the noise σ the fit sees the
#: noise, not the surface: on the 10^7-point vase (σ = 0.002, spacing 0.0016) the flat
#: end's slabs passed as walls and its end sections came out as filled disks (organise's
#: 2-opt then ran for tens of minutes).  10^6 points is the densest vase cloud measured
#: sound; at or below it the normals are those of the whole cloud, unchanged.
NORMAL_POINTS = 1_000_000


#: Largest median tilt a cloud's PCA normals may have, estimated as ``ρ / √k`` (ρ the
#: median of ``sqrt(λ3 / λ2)`` over k neighbours): about 0.1 rad (6°), at which a point
#: slid half a section spacing along its tangent (:func:`slide_to_planes`) lands within
#: 5 % of the spacing of its place, and the 60° wall / cap cone is never in doubt.
NORMAL_TILT = 0.1
#: Most neighbours :func:`normal_neighbours` takes (each doubling costs one more pass).
MAX_NORMAL_NEIGHBOURS = 192
#: Points the flatness ρ is measured at (a seeded sample).
NORMAL_SAMPLE = 20_000


def normal_neighbours(cloud: np.ndarray) -> int:
    """Neighbours for the cloud's PCA normals: :data:`NORMAL_NEIGHBOURS`, doubled until the
    normals' estimated tilt is within :data:`NORMAL_TILT`.

    A plane fitted to k neighbours within radius r of a surface with noise σ tilts by
    about ``σ / (√k · r/2)``; ``ρ = sqrt(λ3 / λ2)`` of their covariance is ``≈ σ / (r/2)``,
    so ``ρ / √k`` estimates the tilt from the data.  Where the noise is below the point
    spacing 12 neighbours are plenty; where it is not (a dense cloud: 10⁷ points of the
    σ = 0.002 vase have a spacing of 0.0016) 12 neighbours are a noise blob, the normals
    point anywhere and cap points pass as walls: measured on the 10⁵-point vase at
    σ = 0.02 (spacing 0.016), ρ/√k = 0.199 / 0.141 / 0.084 and the walls' median tilt
    0.61 / 0.29 / 0.13 rad for k = 12 / 24 / 48; at σ = 0.002 0.042 and 0.051 rad at
    k = 12.  With k = 48 that cloud's surface came out closed with its ends 0.0017 from
    the truth instead of 0.0152 (Chamfer 0.0087 -> 0.0026).
    """
    from scipy.spatial import cKDTree

    cloud = np.asarray(cloud, dtype=np.float64)
    k = NORMAL_NEIGHBOURS
    if len(cloud) <= 2 * k:
        return k
    tree = cKDTree(cloud)
    rng = np.random.default_rng(0)
    sample = cloud[rng.choice(len(cloud), min(NORMAL_SAMPLE, len(cloud)), replace=False)]
    while True:
        _, index = tree.query(sample, k=min(k, len(cloud)))
        local = cloud[index] - cloud[index].mean(axis=1, keepdims=True)
        values = np.linalg.eigvalsh(np.einsum("nki,nkj->nij", local, local) / k)
        flatness = np.sqrt(np.maximum(values[:, 0], 0.0) / np.maximum(values[:, 1], TOL.zero))
        if (float(np.median(flatness)) / np.sqrt(k) <= NORMAL_TILT
                or 2 * k > min(MAX_NORMAL_NEIGHBOURS, len(cloud) // 2)):
            return k
        k *= 2


def _pca_normals(cloud: np.ndarray, query: np.ndarray, k: int | None = None) -> np.ndarray:
    """Unit normals ``(Q, 3)`` at ``cloud[query]``: least-variance axis of k nearest points.

    open3d's ``estimate_normals`` (the same PCA, multithreaded C++) on the
    whole cloud, or on :data:`NORMAL_POINTS` of it (seeded) when it is larger;
    the sign is arbitrary (only ``(a·n)²`` and ``(a·n) n`` are used).  ``k`` defaults
    to :func:`normal_neighbours` of the cloud the normals are estimated on.
    """
    import open3d as o3d

    if len(cloud) > NORMAL_POINTS:
        from scipy.spatial import cKDTree

        subset = np.sort(np.random.default_rng(0).choice(len(cloud), NORMAL_POINTS,
                                                         replace=False))
        normals = _pca_normals(cloud[subset], np.arange(NORMAL_POINTS), k)
        _, nearest = cKDTree(cloud[subset]).query(cloud[query])
        return normals[nearest]
    if k is None:
        k = normal_neighbours(cloud)
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(cloud))
    pcd.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(knn=min(k, len(cloud))))
    return np.asarray(pcd.normals)[query]


def slide_to_planes(points: np.ndarray, slices: list) -> tuple[list, np.ndarray]:
    """Move each section's points to its plane along the surface, not along the axis.

    A point at height offset ``δ = a·x − h`` on a wall of normal ``n`` lies on
    the tangent plane; the tangent direction of steepest ascent is
    ``t = a − (a·n) n`` with ``t·a = 1 − (a·n)²``, so ``x' = x − δ t/(t·a)``
    is on both the tangent plane and the section plane (error O(κ δ²)
    instead of the axis projection's O(|r'| δ), which on a sloped wall is
    noise of size slope × slab half-width; where the wall leans near the limit
    below, along its neighbours' chord slope instead, :func:`pooled_slopes`).
    Points where the surface is nearly parallel to the plane
    (``sqrt(t·a) < MIN_WALL_SINE``) are left out of the contour and returned as
    *cap points*.

    A section whose slab holds more cap points than wall points lies in a
    cap (a shelf) and is emptied; at the ends the test looks at the inner
    half-slab only, and sections outside the outermost walled ones (end
    planes inside a noisy end face) are emptied too.  The first and last
    sections keep only their wall points on the inner side of their planes.

    Parameters
    ----------
    points : (P, 3) float64
        The whole cloud (normals are estimated from it).
    slices : list of Section
        From :func:`surface.sections.slice_sections` on ``points`` (their
        ``source_index`` rows into ``points`` are used).

    Returns
    -------
    sections : list of Section
        The same sections with slid points (``source_index`` kept).
    cap_points : (C,) int64
        Indices into ``points`` of the section points left out.
    """
    from dataclasses import replace

    members = [s.source_index for s in slices if len(s)]
    if not members:
        return slices, np.zeros(0, np.int64)
    index = np.concatenate(members)
    normals = _pca_normals(points, index)
    # Pass 1: which slab points lie on walls, and which sections lie in a cap.
    walls, deltas, start = [], [], 0
    for section in slices:
        n = normals[start:start + len(section)]
        start += len(section)
        walls.append(1.0 - (n @ section.frame[2]) ** 2 >= MIN_WALL_SINE**2)
        deltas.append(points[section.source_index] @ section.frame[2] - section.height)

    def walled(k: int, side: np.ndarray) -> bool:
        # Mostly wall points among those considered: a contour, not a cap.
        return bool(side.any()) and float(walls[k][side].mean()) >= 0.5

    nonempty = [k for k, section in enumerate(slices) if len(section)]
    # End sections: the outermost whose inner half-slab is mostly wall (when the end
    # planes fall inside a noisy end face, the sections there are caps, not contours).
    first = next((k for k in nonempty if walled(k, deltas[k] >= 0)), None)
    last = next((k for k in reversed(nonempty) if walled(k, deltas[k] <= 0)), None)
    if first is None or last is None or first > last:
        return slices, np.concatenate(members).astype(np.int64)
    for k in nonempty:
        # Outside the ends, and any slab mostly of cap points (a shelf): no contour.
        whole = np.ones(len(slices[k]), bool)
        if k < first or k > last or (first < k < last and not walled(k, whole)):
            walls[k] = np.zeros(len(slices[k]), bool)
    # Pass 2: slide the wall points.
    out, capped, start = [], [], 0
    for k, section in enumerate(slices):
        m = len(section)
        n = normals[start:start + m]
        start += m
        if m == 0:
            out.append(section)
            continue
        x = points[section.source_index]
        axis = section.frame[2]
        an = n @ axis
        tangent = axis - an[:, None] * n                           # (m, 3)
        ta = 1.0 - an**2
        wall = walls[k].copy()
        delta = deltas[k]
        # The end sections keep only the inner half of their slab: beyond the end
        # planes the neighbourhoods straddle the rim and the cap, so normals and
        # slides are wrong there; those points go to the cap-height estimate.
        side = _kept_side(delta, k, first, last)
        wall &= side
        own = tangent / np.maximum(ta, TOL.zero)[:, None]    # slide per unit offset
        if wall.any() and float(np.median(ta[wall])) < (MIN_WALL_SINE + 2 * NORMAL_TILT) ** 2:
            # leaning near the wall limit: the wall test selected on the normals' noise
            slope = pooled_slopes(x, own, delta, wall, _loose_walls(an) & side)
        else:
            slope = own[wall]
        slid = x[wall] - delta[wall][:, None] * slope
        slid -= (slid @ axis - section.height)[:, None] * axis     # exactly on the plane
        capped.append(section.source_index[~wall])
        out.append(replace(section, points=slid, source_index=section.source_index[wall]))
    return out, np.concatenate(capped).astype(np.int64)


#: Wall sine down to which a slab point's normal still counts in its neighbours' slide
#: slopes (:func:`pooled_slopes`), though the point itself is no wall point.
LOOSE_WALL_SINE = 0.25
#: Slab points whose slopes :func:`pooled_slopes` fits for each wall point.
SLOPE_NEIGHBOURS = 16


def _loose_walls(an: np.ndarray) -> np.ndarray:
    """Slab points whose normals (``an = n·a``) are at least LOOSE_WALL_SINE off the axis."""
    return 1.0 - an ** 2 >= LOOSE_WALL_SINE ** 2


def _kept_side(delta: np.ndarray, k: int, first: int, last: int) -> np.ndarray:
    """The slab points on the side section ``k`` keeps (the inner half at the ends)."""
    if k == first:
        return delta >= 0
    if k == last:
        return delta <= 0
    return np.ones(len(delta), dtype=bool)


def pooled_slopes(points: np.ndarray, slopes: np.ndarray, delta: np.ndarray,
                  wall: np.ndarray, pool: np.ndarray) -> np.ndarray:
    """Each wall point's slide per unit height offset from its slab neighbours, ``(W, 3)``.

    For a section whose wall points lean within two normal-tilt widths of the wall limit
    (median wall sine below ``MIN_WALL_SINE + 2 NORMAL_TILT``: a dome's last contours),
    :func:`slide_to_planes` slides each wall point along the least-squares line of its
    :data:`SLOPE_NEIGHBOURS` nearest ``pool`` points' ``slopes`` (``t / (t·a)``) in their
    height offsets ``delta``, read at half its own offset: the chord slope between the
    point and its plane, so the profile's curvature cancels to second order.

    Why: near the limit the wall test selects on the normals' noise (tilt ~0.1 rad,
    :data:`NORMAL_TILT`) -- a point passes when its normal came out steeper, and its own
    tangent then slides it short of the surface; the end sections slide from one side
    only, so all outward.  The pool takes normals down to :data:`LOOSE_WALL_SINE`, past
    the selection.  Measured (one-off scripts): on a 10⁵-point capsule (σ = 0.002) the
    last sections' rings +0.0005 / +0.0003 off the sphere, 0.001 / 0.00067 RMS, against
    +0.00013 / -0.00005 and 0.00065 / 0.0005; on a 10⁴-point one +0.0011 / +0.0012 against
    +0.0006 / +0.0004.  Steeper walls keep their own slopes: next to a flat cap's rim the
    neighbours' normals straddle the rim (used everywhere, the 10⁴-point cylinder's end
    ring went from -0.0023 to -0.0041 off the truth).

    Parameters
    ----------
    points : (m, 3) float64
        The slab's points.
    slopes : (m, 3) float64
        Each point's own slide per unit height offset.
    delta : (m,) float64
        Their height offsets from the section plane.
    wall, pool : (m,) bool
        The points to slide; the points whose slopes are pooled.

    Returns
    -------
    (W, 3) float64
        One slope per wall point (their own when the pool has fewer than 3 points).
    """
    from scipy.spatial import cKDTree

    index = np.flatnonzero(pool)
    if len(index) < 3:
        return slopes[wall]
    near = min(SLOPE_NEIGHBOURS, len(index))
    _, nb = cKDTree(points[index]).query(points[wall], k=near)
    nb = index[np.asarray(nb).reshape(int(wall.sum()), near)]
    s, d = slopes[nb], delta[nb]                                  # (W, k, 3), (W, k)
    d_mean, s_mean = d.mean(axis=1), s.mean(axis=1)
    dd = d - d_mean[:, None]
    spread = np.einsum("wk,wk->w", dd, dd)
    gain = np.einsum("wk,wkc->wc", dd, s - s_mean[:, None, :]) / \
        np.maximum(spread, TOL.zero)[:, None]                     # d(slope)/d(offset)
    return s_mean + gain * (0.5 * delta[wall] - d_mean)[:, None]


@dataclass(frozen=True)
class SlicedCloud:
    """Sections of a cloud ready for organising (:func:`slice_cloud`).

    Attributes
    ----------
    sections : list of Section
        Every section plane in height order (some may be empty), their points
        on the plane (slid along the surface with ``projection="surface"``).
    cap_cloud : (C, 3) float64
        The points an end cap may be moved to (:func:`extend_to_caps`): the
        slab points left out as cap points, or the whole cloud when there are
        none (``projection="axis"``).
    spacing : float
        Distance Δ between the section planes, scene units (0 for one section).
    cap_index : (C,) int64
        Row of each cap point in the input cloud (to carry per-point data along, e.g.
        its precision σ for :func:`extend_to_caps`).
    """

    sections: list
    cap_cloud: np.ndarray
    spacing: float
    notes: tuple[str, ...] = ()
    cap_index: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    #: What :func:`organise_sections` found on these sections already (the axis trial of
    #: ``axis="auto"`` organised them): ``id(section) -> (options, section, loops,
    #: warnings)``; passed back as ``organise_sections(..., organised=)`` so that they are
    #: not organised twice.
    organised: dict = field(default_factory=dict, compare=False, repr=False)


@one_blas_thread
def slice_cloud(points: np.ndarray, axis="z", sections: int | None = None,
                spacing: float | None = None, thickness: float | None = None,
                projection: str = "surface") -> SlicedCloud:
    """Step 1 of :func:`surface_from_points`: slice, then move points to their planes.

    Parameters are those of :func:`surface_from_points`.

    Returns
    -------
    SlicedCloud
    """
    from surface.sections import slice_sections

    if projection not in ("surface", "axis"):
        raise ValueError(f"projection must be 'surface' or 'axis', got {projection!r}")
    notes: tuple[str, ...] = ()
    if isinstance(axis, str) and axis.strip().lower() == "auto":
        trials: dict = {}
        axis, why = choose_axis(points, sections=sections, spacing=spacing, trials=trials)
        notes = (why,)
        if thickness is None and projection == "surface" and trials.get("whole"):
            # the axis trial sliced (and organised) this very cloud along this axis with
            # these options: its sections, not a second slicing
            return replace(trials[id(axis)], notes=notes)
    slices = slice_sections(points, axis=axis, count=sections, spacing=spacing,
                            thickness=thickness)
    pts = np.asarray(points, dtype=np.float64)
    delta = abs(slices[1].height - slices[0].height) if len(slices) > 1 else 0.0
    cap_points = np.zeros(0, np.int64)
    if projection == "surface" and len(slices) > 1:
        if thickness is None:
            # Slabs widened to tile the cloud (every point used once), over the extent of
            # its dense part: sparse tails (stray points beyond the ends) would otherwise
            # place the end planes outside the surface.
            axis_vector = slices[0].frame[2]
            in_dense = _dense_extent(pts @ axis_vector, delta)
            dense = np.flatnonzero(in_dense)
            heights = pts[dense] @ axis_vector
            count = None if spacing is not None else len(slices)
            step = spacing if spacing is not None else (
                float(heights.max() - heights.min()) / count)  # slice_sections' Δ
            slices = slice_sections(pts[dense], axis=axis_vector, count=count,
                                    spacing=spacing, thickness=step / 2)
            slices = [replace(s, source_index=dense[s.source_index]) for s in slices]
            delta = abs(slices[1].height - slices[0].height) if len(slices) > 1 else delta
        slices, cap_points = slide_to_planes(pts, slices)
        if thickness is None:
            # the sparse tails are where a thinning wall ends (points thin towards a rim
            # the cameras see edge-on): the end placement needs them
            cap_points = np.union1d(cap_points, np.flatnonzero(~in_dense)).astype(np.int64)
    cap_index = cap_points if len(cap_points) else np.arange(len(pts), dtype=np.int64)
    cap_cloud = pts[cap_points] if len(cap_points) else pts  # (no copy of a whole cloud)
    return SlicedCloud(list(slices), cap_cloud, float(delta), notes, cap_index.astype(np.int64))


#: Points of the cloud the axis trials of :func:`choose_axis` slice (a random subset:
#: the loops' count and correspondence need the sections' shape, not their detail).
AXIS_TRIAL_POINTS = 60_000
#: Candidate axes closer than this (degrees) to one already tried are not tried again.
AXIS_SAME_DEGREES = 5.0
#: Candidates whose share of cap points exceeds the smallest share by more than this
#: are not chosen for their Euler characteristic (:func:`choose_axis`).
CAP_SHARE_SLACK = 0.10


def choose_axis(points: np.ndarray, sections: int | None = None,
                spacing: float | None = None, trials: dict | None = None
                ) -> tuple[np.ndarray, str]:
    r"""``axis="auto"``: the candidate axis that resolves the shape's topology best.

    The section method rebuilds surfaces that run along the axis (walls) from
    their contours, and surfaces facing along it (caps) only as flat fills
    between contours; and it sees a handle only if the sections resolve it.
    Candidates: the direction most perpendicular to the surface normals (the
    least eigenvector of :math:`\sum n n^T`, PCA normals of 12 neighbours: the
    axis of a surface of revolution or an extrusion), then the cloud's three
    principal axes (PCA) unless within :data:`AXIS_SAME_DEGREES` of it.  Each is
    tried:

    1. sliced (:func:`slice_cloud`, on at most :data:`AXIS_TRIAL_POINTS`
       points), organised and related by the loop graph, which gives the
       Euler characteristic of the surface the sections describe,
       :math:`\chi = \sum_{caps} (1 - h) - \sum (k - 1)` over its caps with h holes
       (``LoopGraph.euler``) and its splits and merges into k loops; an
       unresolved handle only raises χ, so the smallest χ found is the shape's;
    2. among the axes reaching that χ, the one with the smallest share of cap
       points (PCA normals within 60° of the axis, ``MIN_WALL_SINE``) wins.

    χ is compared only among the axes whose cap share is within
    :data:`CAP_SHARE_SLACK` of the smallest: an axis cutting most walls
    obliquely gives ragged loops whose spurious splits lower χ (a sparse
    cylinder cut across).  The other axes are not sliced (their χ decides nothing).

    A mug: along its height χ = 0 with its floor and rims as caps (~20 % of
    its area); across, the handle is resolved too but a third of the walls
    face the axis; along the handle's axis the handle hole is missed (χ = 2).

    Parameters
    ----------
    points : (P, 3) float64
    sections, spacing
        As for :func:`slice_cloud`.
    trials : dict, optional
        Filled with each candidate's :class:`SlicedCloud` (keyed by ``id`` of the
        candidate axis returned) and ``"whole"``: whether the trials sliced every point
        (then :func:`slice_cloud` returns the chosen one's, organised, as its own).

    Returns
    -------
    axis : (3,) float64
        Unit axis, signed as ``sections.principal_axis`` signs it.
    reason : str
        One line: the axis chosen and every candidate's χ (or "not sliced") and cap
        share.
    """
    from surface.loop_graph import loop_graph
    from surface.sections import _orient

    pts = np.asarray(points, dtype=np.float64)
    centred = pts - pts.mean(axis=0)
    _, vecs = np.linalg.eigh(centred.T @ centred)
    rng = np.random.default_rng(0)
    trial = pts if len(pts) <= AXIS_TRIAL_POINTS else pts[
        np.sort(rng.choice(len(pts), AXIS_TRIAL_POINTS, replace=False))]
    normals = _pca_normals(trial, np.arange(len(trial)))
    # The direction most perpendicular to the normals (least eigenvector of Σ n nᵀ)
    # is a surface of revolution's or an extrusion's axis even where a handle or a
    # spout tilts the points' principal axes; it is tried first, then those.
    candidates = [_orient(np.linalg.eigh(normals.T @ normals)[1][:, 0])]
    for k in (2, 1, 0):
        if all(abs(float(vecs[:, k] @ c)) < np.cos(np.radians(AXIS_SAME_DEGREES))
               for c in candidates):
            candidates.append(_orient(vecs[:, k]))
    shares = [float(np.mean(1.0 - (normals @ axis) ** 2 < MIN_WALL_SINE**2))
              for axis in candidates]
    # χ decides only among axes with about as few cap points as the fewest: an axis
    # cutting most walls obliquely makes ragged loops whose spurious splits lower χ.
    # The others are not sliced at all (their χ would decide nothing).
    close = [k for k in range(len(candidates)) if shares[k] <= min(shares) + CAP_SHARE_SLACK]
    chis = []
    for k, axis in enumerate(candidates):
        if k not in close:
            chis.append(None)
            continue
        try:
            sliced = slice_cloud(trial, axis=axis, sections=sections, spacing=spacing)
            if trials is not None:
                trials[id(axis)] = sliced
            _, loops, _ = organise_sections(sliced.sections, organised=sliced.organised,
                                            min_points=4)
            graph = loop_graph([[lp.points @ lp.frame[:2].T for lp in found] for found in loops],
                               spacing=sliced.spacing)
            chis.append(graph.euler())
        except ValueError:
            chis.append(float("inf"))
    finite = [chis[k] for k in close if np.isfinite(chis[k])]
    best_chi = min(finite) if finite else float("inf")
    pool = [k for k in close if chis[k] == best_chi] or close
    best = min(pool, key=lambda k: (shares[k], k))
    listed = "; ".join(f"{np.round(a, 3).tolist()}: "
                       f"{'not sliced' if c is None else f'chi {c:g}'}, caps {100 * f:.0f} %"
                       for a, c, f in zip(candidates, chis, shares, strict=True))
    reason = (f"axis auto: {np.round(candidates[best], 4).tolist()}, of the candidate axes "
              f"resolving the most topology (smallest Euler characteristic chi of the "
              f"sections' loop graph) the one with the fewest points on caps ({listed})")
    if trials is not None:
        trials["whole"] = trial is pts and id(candidates[best]) in trials
    return candidates[best], reason


#: A tail bin (half a section spacing wide) holding less than this share of the median
#: bin's points lies beyond the surface's end: stray points, not a slab of wall.  A wall
#: ending inside a bin still fills its share of it; a flat end face is a dense spike.
SPARSE_TAIL = 0.25


def _dense_extent(heights: np.ndarray, delta: float) -> np.ndarray:
    """Mask ``(P,)`` of the points between the sparse tails of the height histogram.

    Bins of width Δ/2; from each end, the run of bins with fewer than
    ``SPARSE_TAIL`` × the median non-empty bin's count is cut off.
    """
    lo, hi = float(heights.min()), float(heights.max())
    if delta <= 0 or hi - lo <= delta:
        return np.ones(len(heights), bool)
    # the edges np.arange(lo, hi + Δ/2, Δ/2) gave, their count taken 1e-9 below its
    # ceiling: Δ is the extent over the section count, so (hi - lo) / (Δ/2) is an integer
    # up to rounding, and the plain ceiling added a last bin beyond hi on one build and
    # not on another -- its single point cut off as a sparse tail moved every section
    # (the 10⁴-point torus of tests/_shapes.py: the cloud moved by 1e-13 shifted its
    # sections by up to 3e-4)
    count = int(np.ceil((hi - lo) / (delta / 2) + 1.0 - 1e-9))
    edges = lo + (delta / 2) * np.arange(count)
    edges[-1] = max(edges[-1], hi)
    counts, edges = np.histogram(heights, bins=edges)
    full = counts >= SPARSE_TAIL * np.median(counts[counts > 0])
    if not full.any():
        return np.ones(len(heights), bool)
    first = int(np.argmax(full))
    last = len(full) - 1 - int(np.argmax(full[::-1]))
    return (heights >= edges[first]) & (heights <= edges[last + 1])


def organise_sections(sections: Iterable, organised: dict | None = None,
                      **organise_options) -> tuple[list, list, list[str]]:
    """Step 2 of :func:`surface_from_points`: the loops of every section.

    Parameters
    ----------
    sections : iterable of Section
        In height order (empty ones are skipped); iterated once (a progress
        bar may wrap it).
    organised : dict, optional
        ``SlicedCloud.organised`` of these sections: a section organised before with the
        same options takes its loops and warnings from it (and a new one is added).
    **organise_options
        Passed to :func:`surface.topology.organise` (``outlier_threshold``,
        ``min_points`` ...; :func:`surface_from_points` gives
        ``min_points=min_loop_points(smoothing)``).

    Notes
    -----
    An inner section whose number of loops differs from both its neighbours'
    (which agree) is dropped with a message (:func:`_drop_one_section_splits`).

    Returns
    -------
    kept : list of Section
        The sections with at least one loop (less one-section splits).
    loops : list of list of Loop
        Their loops.
    messages : list of str
        One per skipped section (``SectionSkippedWarning``), and a count.

    Raises
    ------
    ValueError
        Fewer than two sections with a loop.
    """
    messages, kept, loops, total, caught = [], [], [], 0, []
    options = _organise_key(organise_options)
    for section in sections:
        total += 1
        if not len(section):
            continue
        done = None if organised is None else organised.get(id(section))
        if done is None or done[0] != options or done[1] is not section:
            done = (options, section, *_organise_one(section, organise_options))
            if organised is not None:
                organised[id(section)] = done
        found, said = list(done[2]), done[3]
        caught += said
        if found:
            kept.append(section)
            loops.append(found)
    for w in caught:  # skipped sections become messages; anything else is passed on
        if issubclass(w.category, SectionSkippedWarning):
            messages.append(str(w.message))
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    kept, loops, notes = _drop_one_section_splits(kept, loops)
    messages += notes
    kept, loops, notes = untangle(kept, loops)
    messages += notes
    if total - len(kept):
        messages.append(f"{total - len(kept)} of {total} sections had no loop "
                        "and were skipped")
    if len(kept) < 2:
        raise ValueError(f"points gave {len(kept)} section(s) with a closed loop; "
                         "stitching needs at least 2 (too few points or sections?)")
    _refuse_open_arcs(loops)
    return kept, loops, messages


def _organise_key(options: dict) -> tuple:
    """``surface.topology.organise``'s keyword options with its defaults filled in."""
    defaults = {name: p.default for name, p in inspect.signature(organise).parameters.items()
                if p.kind is inspect.Parameter.KEYWORD_ONLY}
    return tuple(sorted({**defaults, **options}.items()))


def _organise_one(section, options: dict) -> tuple[list, list]:
    """``surface.topology.organise`` of one section: its loops and the warnings it gave."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", SectionSkippedWarning)
        found = organise(section, **options)
    return found, list(caught)


#: Share of the loops' length lying across gaps (wider than ``Loop.bridge``) above
#: which the points are taken not to go round the object.  A circle's chord across an
#: unseen arc of φ is ``2 sin(φ/2) / (2 sin(φ/2) + 2π − φ)`` of the bridged loop: 0.23
#: for a quarter of it unseen, 0.39 for half (what one stereo pair sees).
MAX_BRIDGED_SHARE = 0.25


def bridged_share(loops: list) -> float:
    """Share of the loops' length that lies across their gaps (0: every loop closed).

    A gap is a step between consecutive ordered points longer than ``Loop.bridge``
    (the loop's expected largest step); the curve bridges it by its chord
    (``catmull_rom.bridge_gaps``).  Lengths are of the closed polylines of the
    ordered points, summed over every loop of every section.
    """
    bridged = total = 0.0
    for section_loops in loops:
        for loop in section_loops:
            step = np.linalg.norm(np.roll(loop.points, -1, axis=0) - loop.points, axis=1)
            bridged += float(step[step > loop.bridge].sum())
            total += float(step.sum())
    return bridged / total if total > 0 else 0.0


class OneSidedError(ValueError):
    """The sections are open arcs over much of their length (:func:`_refuse_open_arcs`):
    the points do not go round the object.  The pipeline's curves stage takes the open
    path on it (``curves.open = "auto"``)."""


def _refuse_open_arcs(loops: list) -> None:
    """Raise when the sections are open arcs, not closed contours, over much of their length.

    ``Loop.closed`` is False when the ordered points have a gap longer than
    the link distance (surface/topology.py): the data covers only part of the
    section.  Gaps here and there are data the curve bridges by a chord (a real
    ring leaves the odd side unseen: the real temple ring's sections along its
    height are open in 57 of 102 sections but across 14 % of their length), but
    when the gaps are much of the contours' length the points do not go round the
    object (one stereo pair sees one side: 36-41 % on the vase) and closing every
    arc would make a surface that is silently wrong.  The rule is the share of the
    length bridged, :data:`MAX_BRIDGED_SHARE`.
    """
    share = bridged_share(loops)
    if share > MAX_BRIDGED_SHARE:
        open_count = sum(not loop.closed for section_loops in loops for loop in section_loops)
        total = sum(len(section_loops) for section_loops in loops)
        raise OneSidedError(
            f"{open_count} of {total} section loops are open arcs, not closed contours, "
            f"and {100 * share:.0f} % of their length lies across their gaps (more than "
            f"{100 * MAX_BRIDGED_SHARE:.0f} %): parts of the object unseen -- one stereo "
            "pair sees one side -- or too sparse on thin parts; the section method needs "
            "contours that go round the object")


def _drop_one_section_splits(kept: list, loops: list) -> tuple[list, list, list[str]]:
    """Drop inner sections whose number of loops differs from both neighbours' (equal).

    A loop that splits (or two that merge) for one section only, between
    neighbours that agree, is below what the section spacing resolves: a
    feature that thin cannot be stitched anyway, and in measured clouds it is
    nearly always a gap in the data (a ring broken into arcs where the
    acquisition missed a patch).  Keeping it leaves the surface open on both
    sides; dropping it stitches the neighbours to each other.

    An end section whose number of loops differs from the two next to it (which
    agree) is dropped too: the end sections hold only their inner half-slab,
    and a thin wall's inner loop is the first to go missing there, which would
    seal a hollow's rim into a closed cavity (a second component).  An end section
    whose extra loops are holes (inside another loop, where the neighbours have fewer
    holes) is kept: a rim standing above a recessed lid or base, its inner face seen
    at the end only (a can's rim 3.3 point spacings tall at 20 000 points was dropped
    and the top put on the lid, 3.3 spacings low, on 5 samplings of 6).
    """
    counts = [len(found) for found in loops]
    drop = {k for k in range(1, len(kept) - 1)
            if counts[k - 1] == counts[k + 1] != counts[k]}
    last = len(kept) - 1
    ends = set()
    if len(kept) >= 8:  # a long enough stack that two ends and their pairs are a few
        ends = {k for k, a, b in ((0, 1, 2), (last, last - 1, last - 2))
                if counts[a] == counts[b] != counts[k] and a not in drop and b not in drop
                and not (counts[k] > counts[a] and _holes(kept[k], loops[k])
                         - _holes(kept[a], loops[a]) >= counts[k] - counts[a])}
    notes = [f"section {kept[k].section_id} at height {kept[k].height:.6g} skipped: "
             f"{counts[k]} loop(s) between sections of {counts[k - 1]} (a one-section split "
             "or merge: a gap in the data at this section spacing)" for k in sorted(drop)]
    notes += [f"end section {kept[k].section_id} at height {kept[k].height:.6g} skipped: "
              f"{counts[k]} loop(s) beyond two sections of {counts[1 if k == 0 else last - 1]} "
              "(a loop missing from the end's half slab)" for k in sorted(ends)]
    drop |= ends
    keep = [k for k in range(len(kept)) if k not in drop]
    return [kept[k] for k in keep], [loops[k] for k in keep], notes


def _holes(section, section_loops: list) -> int:
    """How many of a section's loops are holes: inside an odd number of its other loops."""
    from surface.loop_graph import nesting

    if len(section_loops) < 2:
        return 0
    depth, _ = nesting([loop.points @ section.frame[:2].T for loop in section_loops])
    return int(np.count_nonzero(depth % 2))


def _tangle(planar: list, rasters: dict | None = None) -> int | None:
    """The first section to drop so that the loop graph has no knot, or None.

    A knot is a ``complex`` event (loops of two sections relating many-to-many)
    or a split or merge whose loop cannot be cut along bridges into one
    counter-clockwise sub-loop per branch (``stitch._bridge_split``).  Both
    happen where a branch meets a body at a grazing angle and its loop flickers
    between separate and merged from one section to the next: a loop missing
    from one section.  The section dropped is the one of the single loop of a
    split or merge, the upper one of a many-to-many (the lower at the end).
    """
    from surface.loop_graph import loop_graph
    from surface.stitch import _bridge_split

    graph = loop_graph(planar, rasters=rasters)
    last = len(planar) - 1
    for event in graph.events:
        s = event.section
        if event.kind == "complex":
            return s + 1 if s + 1 < last else s
        if event.kind in ("split", "merge"):
            single_s = s if event.kind == "split" else s + 1
            single = event.lower[0] if event.kind == "split" else event.upper[0]
            many_s, many = (s + 1, event.upper) if event.kind == "split" else (s, event.lower)
            ring = planar[single_s][single]
            try:
                _bridge_split(np.arange(len(ring)), ring, [planar[many_s][k] for k in many],
                              len(ring))
            except ValueError:
                return single_s
    return None


def untangle(kept: list, loops: list, rings: list | None = None):
    """Drop sections whose loops knot the loop graph (:func:`_tangle`), one at a time.

    Tested on the loops' ordered points, or on ``rings`` (``section_rings``
    output, dropped alongside) when given.  Returns ``kept, loops, notes`` or,
    with rings, ``kept, loops, rings, notes``.
    """
    notes = []
    kept, loops = list(kept), list(loops)
    rings = None if rings is None else list(rings)
    if rings is not None:  # a ring that crosses itself can be neither walled nor capped
        frame = kept[0].frame
        crossing = [k for k, item in enumerate(rings)
                    if any(self_intersects(r @ frame[:2].T) for r in
                           ([item] if isinstance(item, np.ndarray) else item))]
        crossing = sorted(set(crossing) | {
            k for k, item in enumerate(rings) if k not in crossing and
            any(keyhole(r @ frame[:2].T) for r in
                ([item] if isinstance(item, np.ndarray) else item))})
        # two loops of one section that cross each other: no strip can wall both
        tangled = [k for k, item in enumerate(rings) if k not in crossing and
                   not isinstance(item, np.ndarray) and len(item) > 1 and
                   loops_cross([r @ frame[:2].T for r in item])]
        crossing = sorted(set(crossing) | set(tangled))
        if len(kept) - len(crossing) >= 2:
            for k in crossing[::-1]:
                notes.append(f"section {kept[k].section_id} at height {kept[k].height:.6g} "
                             + ("skipped: two of its loops cross each other (points of two "
                                "parts closer than the sections resolve, each taken into the "
                                "other's contour)" if k in tangled else
                                "skipped: its ring crosses itself or is two nested contours "
                                "joined through a neck (points of a face across the section "
                                "plane, a sliver of noise, or a gap narrower than the sections "
                                "resolve, taken for one contour)"))
                del kept[k], loops[k], rings[k]
    if any(len(found) > 1 for found in loops):
        frame = kept[0].frame
        if rings is None:
            planar = [[lp.points @ frame[:2].T for lp in found] for found in loops]
        else:
            planar = [[r @ frame[:2].T for r in ([item] if isinstance(item, np.ndarray)
                                                 else item)] for item in rings]
        rasters: dict = {}     # each loop scan-converted once while the grid holds
        for _ in range(len(kept)):
            if len(kept) <= 2:
                break
            k = _tangle(planar, rasters)
            if k is None:
                break
            del planar[k]
            notes.append(f"section {kept[k].section_id} at height {kept[k].height:.6g} "
                         f"skipped: its {len(loops[k])} loop(s) do not correspond to its "
                         "neighbours' as splits, merges or continuations (a branch flickering "
                         "between separate and merged at this section spacing)")
            del kept[k], loops[k]
            if rings is not None:
                del rings[k]
    return (kept, loops, notes) if rings is None else (kept, loops, rings, notes)


#: A ring passing within this many of its own median point spacings of itself, away
#: from its neighbours along it, has a neck narrower than the sections resolve (the
#: rings are spaced about as the sections are).
NECK_SPACINGS = 2.0
#: Shortest way round the ring (median point spacings) between the two sides of a neck:
#: a U-turn of width w runs πw/2, so 4 necks' width keeps tight bends out.
NECK_ARC = 4 * NECK_SPACINGS
#: Share of one side's points inside the other's polygon for the sides to be nested.
NESTED_SHARE = 0.9
#: Necks tested per ring (the narrowest first).
NECK_CANDIDATES = 8


def keyhole(uv: np.ndarray) -> bool:
    """Whether the closed ring ``uv`` ``(n, 2)`` is two nested contours joined through a neck.

    A ring that runs round an outer contour, in through a channel narrower than
    :data:`NECK_SPACINGS` of its point spacings, round an inner contour and back out
    (a teapot's body and its lid at the rim's height, taken for one loop) is a keyhole:
    cut at the neck, one side lies inside the other (:data:`NESTED_SHARE` of its
    points).  Neither neighbour section has the channel, so the strips on both sides
    fold across it.  Side-by-side lobes joined at a waist, and a thin finger, are not
    nested and pass.
    """
    from scipy.spatial import cKDTree

    a = np.asarray(uv, dtype=np.float64)
    n = len(a)
    if n < 8:
        return False
    edge = np.linalg.norm(np.roll(a, -1, axis=0) - a, axis=1)
    step = float(np.median(edge))
    if not step > 0:
        return False
    along = np.concatenate([[0.0], np.cumsum(edge)])
    length = along[-1]
    pairs = cKDTree(a).query_pairs(NECK_SPACINGS * step, output_type="ndarray")
    if not len(pairs):
        return False
    i, j = pairs.min(axis=1), pairs.max(axis=1)
    arc = along[j] - along[i]
    far = np.minimum(arc, length - arc) > NECK_ARC * step
    i, j = i[far], j[far]
    order = np.argsort(np.linalg.norm(a[i] - a[j], axis=1), kind="stable")
    tried: list[tuple[int, int]] = []
    for k in order:
        if len(tried) == NECK_CANDIDATES:
            break
        if any(abs(int(i[k]) - p) + abs(int(j[k]) - q) < NECK_ARC for p, q in tried):
            continue      # the same neck, a point along
        tried.append((int(i[k]), int(j[k])))
        one, other = a[i[k]:j[k] + 1], np.vstack([a[j[k]:], a[:i[k] + 1]])
        if (np.mean(inside_polygon(one, other)) >= NESTED_SHARE
                or np.mean(inside_polygon(other, one)) >= NESTED_SHARE):
            return True
    return False


def min_loop_points(smoothing: float | str) -> int:
    """Fewest points a loop needs: more than one smoothing window, and at least 4.

    A loop with no more points than ``smoothing`` holds less than one control
    point's worth of data: its curve would be the minimal 4-point closed cubic
    fitted to noise (typically a few stray points beyond an end of the cloud).
    ``"auto"`` (chosen per loop) needs only the 4 a closed cubic needs.
    """
    if isinstance(smoothing, str):
        return 4
    return max(4, int(np.floor(smoothing)) + 1)


def ring_count(kept: Sequence, loops: Sequence) -> int:
    """Default N: ``ceil(P_max / Δ)``, ring points as far apart as the sections.

    ``P_max`` is the largest loop perimeter (:func:`largest_perimeter`) and Δ
    the smallest gap between the sections ``kept`` (at least 4).
    """
    gaps = np.abs(np.diff([section.height for section in kept]))
    return max(4, int(np.ceil(largest_perimeter(loops) / float(gaps.min()))))


@one_blas_thread
def section_rings(kept: Sequence, loops: Sequence, n: int | None = None,
                  smoothing: float | str = 8.0, parametrisation: str = "uniform",
                  fits: bool = False):
    """Step 3 of :func:`surface_from_points`: fit and predict the rings.

    Parameters
    ----------
    kept, loops
        From :func:`organise_sections`.
    n : int, optional
        Ring points on odd sections (default :func:`ring_count`).
    smoothing, parametrisation, fits
        Passed to :func:`surface.catmull_rom.predict_sections` (``fits``: also return
        each ring's ``RingFit``, its smoothing and precision, mirroring the rings).

    Returns
    -------
    list, or (list, list) with ``fits``
        One entry per section: an ``(n_k, 3)`` array, or a list of them for
        several loops.  Step 4 is :func:`extend_to_caps`, step 5
        :func:`stitch_rings`.
    """
    from surface.catmull_rom import predict_sections

    if n is None:
        n = ring_count(kept, loops)
    # A lone loop is passed as itself, so its ring comes back as one (n_k, 3) array.
    return predict_sections([lp[0] if len(lp) == 1 else lp for lp in loops], n,
                            smoothing=smoothing, parametrisation=parametrisation, fits=fits)


def section_noise(loops: Sequence) -> float:
    """Noise σ̂ of the section points: the median of the loops' ``Loop.noise``.

    ``Loop.noise`` is 1.4826 × the median residual of a loop's points about a
    local quadratic (``surface.topology``), a robust σ of the points across
    the curve; the median over loops ignores the odd ragged section.

    Parameters
    ----------
    loops : sequence of sequence of Loop
        From :func:`organise_sections`.

    Returns
    -------
    float
        Scene units (0 for noise-free points).
    """
    noise = [float(lp.noise) for section in loops for lp in section]
    return float(np.median(noise)) if noise else 0.0


@one_blas_thread
def surface_from_points(points: np.ndarray, axis="z", sections: int | None = None,
                        spacing: float | None = None, thickness: float | None = None,
                        n: int | None = None, smoothing: float | str = "auto",
                        projection: str = "surface", extend_ends: bool = True,
                        close_ends: bool = True, flip: bool = True,
                        support: bool = True, sigma: np.ndarray | None = None,
                        open_holes: bool = False, ends: dict | None = None) -> StitchResult:
    """Unorganised points to a stitched mesh: slice → organise → fit/predict → stitch.

    The steps are public (:func:`slice_cloud`, :func:`organise_sections`,
    :func:`section_rings`, :func:`extend_to_caps`, :func:`stitch_rings`) so
    that a pipeline can store what is between them; run in this order with
    the same parameters they give this function's mesh exactly.

    Parameters
    ----------
    points : (P, 3) float64
        The cloud, scene units.
    axis : {"z", "x", "y", "auto"} or (3,) array_like
        Slicing axis (:func:`surface.sections.slice_sections`); ``"auto"`` is the
        principal axis with the fewest branch events (:func:`choose_axis`, its
        reason the first message).
    sections : int, optional
        Number of sections K (default from the point spacing, see
        ``sections.slice_sections``).
    spacing : float, optional
        Distance between sections instead of ``sections``.
    thickness : float, optional
        Half-width of the slab of points assigned to a section.  Default:
        ``sections.slice_sections``'s with ``projection="axis"``, and half the
        section spacing (every point used once) with ``projection="surface"``.
    n : int, optional
        N, ring points on the odd sections (2N on the even ones).  Default
        ``ceil(P_max / Δ)`` with ``P_max`` the largest loop perimeter (convex
        hull) and Δ the section spacing, so that triangles are about as wide
        along the rings as they are tall across them.
    smoothing : float or "auto"
        Data points per Catmull-Rom control point (``catmull_rom.fit``).
        Default ``"auto"``: chosen per loop by generalised cross-validation
        (``catmull_rom.choose_smoothing``), i.e. from the loop's own residuals
        (its noise) and number of points (its density) instead of a constant
        tuned to one cloud; on the vase cloud (σ = 0.002) it picks 16-32
        points per control point, lowering the stitched Chamfer from 0.00042
        (fixed 8) to 0.00029 and the Bezier surface's from 0.00039 to 0.00032.
    projection : {"surface", "axis"}
        How a slab point reaches its plane: along the local surface (tangent
        plane from a PCA normal of its 12 nearest neighbours; points on
        surfaces within 30° of the plane are left out) or straight along the
        axis (``sections.slice_sections`` as is).
    extend_ends : bool
        Move the end caps from the first and last section planes to the
        median height of the cloud's cap points beyond them (if at least
        ``NORMAL_NEIGHBOURS`` such points lie inside the end contour); the end
        ring is extrapolated linearly from the last two rings.
    close_ends : bool
        Cap the first and last sections.
    flip : bool
        Lawson flips.
    support : bool
        Support rings where the profile turns sharply (``stitch_rings``'s
        ``support_sigma`` = :func:`section_noise` of the loops), so that the
        G1 surface built over the mesh keeps rims sharp to the noise level.
    sigma : (N,) float64, optional
        The points' precision (scene units): the ends are placed with inverse-variance
        weights (:func:`extend_to_caps`); without it (or with any σ unknown) every point
        weighs the same.
    open_holes : bool
        Leave an end the data do not cover (:func:`classify_ends`: a hole where the scanner
        never looked, an open mouth) as a border instead of capping it flat: an open
        surface of what was seen.
    ends : dict, optional
        Filled with each end's placement and its standard error (:func:`extend_to_caps`)
        and its kind with the evidence (:func:`classify_ends`, ``EndKind.record``).

    Returns
    -------
    StitchResult
        With skipped sections and end extensions reported in ``messages``.

    Raises
    ------
    ValueError
        Bad cloud or parameters (from the steps), an unknown projection, or
        fewer than two sections with a loop.
    """
    # |x| > 1e50 overflows the geometry's 4th-6th powers; at ~1e300 Shewchuk's Triangle
    # (topology._triangle_edges) crashed the process (pipeline.guards.MAX_COORDINATE)
    extreme = np.abs(np.asarray(points, dtype=np.float64))
    if extreme.size and not extreme.max() <= 1e50:
        raise ValueError(f"points: |coordinates| up to {extreme.max():.3g} (NaN/inf or beyond "
                         "1e50, where products of coordinates overflow float64)")
    sliced = slice_cloud(points, axis=axis, sections=sections, spacing=spacing,
                         thickness=thickness, projection=projection)
    kept, loops, messages = organise_sections(sliced.sections,
                                              min_points=min_loop_points(smoothing))
    messages = list(sliced.notes) + messages
    rings = section_rings(kept, loops, n, smoothing=smoothing)
    kept, loops, rings, notes = untangle(kept, loops, rings)
    messages += notes
    kinds = None
    if close_ends:   # on the sections' own end loops: an extended ring may drift off the data
        kinds = classify_ends(rings, kept[0].frame, sliced.cap_cloud, sliced.spacing,
                              points, open_holes)
        messages += [k.note for k in kinds if k.note]
        if any(k.outer_only for k in kinds):
            rings = outer_loops(rings, kept[0].frame)
    if extend_ends and close_ends:
        cap = sliced.cap_cloud
        cap_sigma = None if sigma is None else np.asarray(sigma, np.float64)[sliced.cap_index]
        rings, notes = extend_to_caps(rings, kept, cap, np.arange(len(cap)), sliced.spacing,
                                      sigma=cap_sigma, ends=ends)
        messages += notes
    if kinds is not None and ends is not None:   # the placement and the kind, per end
        for kind in kinds:
            ends.setdefault(kind.end, {}).update(kind.record())
    ends_closed = tuple(k.closed(open_holes) for k in kinds) if kinds else close_ends
    result = stitch_rings(rings, kept[0].frame[2], close_ends=ends_closed, flip=flip,
                          support_sigma=section_noise(loops) if support else None,
                          cap_points=sliced.cap_cloud)
    if len(result.triangles) == 0:
        raise ValueError(f"no surface from {len(kept)} section(s) with loops: "
                         f"{result.problem_line()} (too few points or sections?)")
    if messages:
        from dataclasses import replace

        result = replace(result, messages=tuple(messages) + result.messages)
    return result



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
            from surface.sections import point_spacing

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
    from scipy.spatial import cKDTree

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
    from scipy.spatial import cKDTree

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
    return float(1.4826 * np.median(np.abs(offset - np.median(offset))))


#: Quantile of the wall points' offsets past the last section that, divided by itself,
#: places an end without cap points (:func:`extend_to_caps`).
#: Rings inwards of an end ring through which its line is extrapolated to the end
#: (:func:`_extrapolate_ring`).
EXTRAPOLATION_RINGS = 2
_END_QUANTILE = 0.95


def extend_to_caps(rings: list, kept: list, points: np.ndarray, cap_points: np.ndarray,
                 delta: float, sigma: np.ndarray | None = None,
                 ends: dict | None = None) -> tuple[list, list[str]]:
    """Add an end section at each end's cap height (see ``surface_from_points``).

    Every loop of an end section is moved to the median height of the cap
    points inside it and extrapolated from the nearest loop of the section
    before; an end is left as it is when one of its loops has fewer than
    ``NORMAL_NEIGHBOURS`` cap points inside.

    Parameters
    ----------
    rings : list
        ``catmull_rom.predict_sections`` output, one entry per kept section
        (an ``(n_k, 3)`` array or a list of them).
    kept : list of Section
        The sections the rings come from (heights and frame).
    points : (P, 3) float64
        The cloud.
    cap_points : (C,) int64
        Candidate cap points (``slide_to_planes``); empty means every point.
    delta : float
        Section spacing: cap points are looked for within ``2 delta`` beyond
        each end plane.
    sigma : (P,) float64, optional
        Precision of each point (scene units): the median height of the cap points and
        the offsets' quantile are then weighted by ``1 / σ²``, so that a few imprecise
        points (the last, grazing pixels of a rim seen edge-on, an outline point on a
        dark rim) move an end less than the precise ones do.  Measured on the demo
        (24-view ring, no cap seen): bottom end 0.0016 -> 0.0013 below the rim, top
        0.0008 -> 0.0007 above it, smooth-surface Chamfer 0.000334 -> 0.000284 (the report's,
        one run, 2026-12-03).  ``None`` or any non-finite / non-positive σ: equal weights.
    ends : dict, optional
        Filled with each end's placement, ``ends["bottom"]`` and ``ends["top"]``:
        ``{"how": "cap" | "wall end" | "rim line" | "dome" | "last section", "height": h,
        "standard_error": u}`` -- ``h`` the end ring's mean height along the axis, ``u``
        the placement's own standard error (the largest of its loops'; ``None`` where the
        end stays at its last section: a dome, or too few points beyond it).

    Returns
    -------
    rings : list
        With one section added at each end that has cap points.
    notes : list of str
        One line per moved end.
    """
    rings = list(rings)
    section_heights = [float(section.height) for section in kept]
    notes = []
    frame = kept[0].frame
    axis = frame[2]
    candidates = cap_points if len(cap_points) else np.arange(len(points))
    heights = points[candidates] @ axis
    candidates_flat = points[candidates] @ frame[:2].T
    for end, (this, sign) in enumerate(((0, -1.0), (-1, 1.0))):
        dropped = _drop_sections_past_cap(rings, section_heights, this, sign, heights,
                                          candidates_flat, frame, delta,
                                          None if sigma is None else sigma[candidates])
        if dropped:
            notes.append(f"{'bottom' if end == 0 else 'top'}: {dropped[0]} end section(s) "
                         f"beyond the cap dropped (cap points' height {dropped[1]:.6g}, "
                         f"inside the last section plane: those sections were the cap's "
                         f"noise)")
        end_loops = [rings[this]] if isinstance(rings[this], np.ndarray) else list(rings[this])
        h_end = section_heights[this]
        offset = sign * (heights - h_end)
        # Within two spacings: a section emptied as a cap may lie in between.
        beyond = candidates[(offset > 0) & (offset <= 2 * delta)]
        beyond_flat = points[beyond] @ frame[:2].T
        # No cap seen (an open end, or a cap the cameras missed): the wall points beyond
        # the end plane -- its outer half-slab and the sparse tail cut from the slicing
        # (slice_cloud), where a wall thinning towards a rim ends -- run on to the end of
        # the data (only the half-slab was looked at before, so a thinned end stopped up
        # to a spacing short: demo ring bottom 0.008 high).  For points spread evenly
        # over [0, e] beyond the plane the p-quantile of the offsets is p e.  p = 0.95:
        # the median (p = 1/2) undershoots where the points are not spread evenly up to
        # the edge (24-view ring: caps 0.005 inside the rims at spacing 4, 0.001 at 3;
        # with p = 0.95 0.003 and 0.0006), and the top 5 % keeps strays past the edge out.
        near = (offset > 0) & (offset <= 2 * delta)
        outer = offset[near]
        weights = None if sigma is None else _precision_weights(sigma[candidates][near])
        end_step = (_weighted_quantile(outer, weights, _END_QUANTILE) / _END_QUANTILE
                    if len(outer) >= NORMAL_NEIGHBOURS else None)
        # Standard error of that end: for M offsets spread evenly over [0, e] the
        # p-quantile's is e sqrt(p (1 - p) / M), divided by p with the end.
        end_error = (None if end_step is None else end_step * float(
            np.sqrt(_END_QUANTILE * (1 - _END_QUANTILE) / len(outer))) / _END_QUANTILE)
        rim = None
        if end_step is not None and sigma is not None:
            rim = rim_line(outer, sigma[candidates][near], end_step)
        if rim is not None:
            end_step = rim
        if end_step is not None:
            end_step *= sign
        new_rings, counts, dome, errors = [], [], False, []
        for ring in end_loops:
            flat = ring @ frame[:2].T
            flat = flat.mean(axis=0) + CAP_INSET * (flat - flat.mean(axis=0))
            inside = beyond[inside_polygon(beyond_flat, flat)]
            counts.append(len(inside))
            found = None if len(inside) < NORMAL_NEIGHBOURS else _cap_height(
                heights, candidates_flat, ring @ frame[:2].T, h_end, sign, delta,
                None if sigma is None else sigma[candidates], spread=True)
            cap = None if found is None else found[0]
            if cap is None and _dome(ring @ frame[:2].T, *end_window(h_end, sign > 0, delta),
                                     points[candidates], frame) is not None:
                # A rounded end (no flat cap across the plane, a dome past it): the
                # median height of its points is no contour of it; the end stays at
                # the last section and the stitch's dome covers the rest.  Asked
                # whatever ``inside`` holds: with sections closer than the dome's sag
                # over the ring's inset (10⁶-point capsule, spacing 0.0102) no dome
                # point within 2 spacings lies inside it, and the end was extended
                # straight along the wall instead, 0.021 past the contour and 0.0014
                # outside the sphere (the capsule's 10⁶ Chamfer 0.000118 -> 0.000105).
                dome = True
                break
            # a median's standard error: sqrt(π/2) s / sqrt(m), s the MAD scale
            if cap is not None:
                step = cap - h_end
                errors.append(_MEDIAN_ERROR * found[1] / np.sqrt(found[2]))
            elif len(inside) >= NORMAL_NEIGHBOURS:
                cap_weights = None if sigma is None else _precision_weights(sigma[inside])
                inside_h = points[inside] @ axis
                step = _weighted_quantile(inside_h, cap_weights, 0.5) - h_end
                errors.append(_MEDIAN_ERROR * 1.4826 * float(np.median(np.abs(
                    inside_h - h_end - step))) / np.sqrt(len(inside)))
            elif end_step is not None:
                step = end_step
                errors.append(end_error)
            else:
                break
            chain, last = [], ring
            for k in range(1, EXTRAPOLATION_RINGS + 1):
                idx = k if end == 0 else len(rings) - 1 - k
                if not 0 <= idx < len(rings):
                    break
                loops = [rings[idx]] if isinstance(rings[idx], np.ndarray) else list(rings[idx])
                last = _nearest_loop(last, loops, frame)
                chain.append(last)
            new_rings.append(_extrapolate_ring(ring, chain, step, axis))
        name = "bottom" if end == 0 else "top"
        if dome or len(new_rings) < len(end_loops):
            if ends is not None:
                ends[name] = {"how": "dome" if dome else "last section",
                              "height": float(np.mean([float(np.mean(lp @ axis))
                                                       for lp in end_loops])),
                              "standard_error": None}
            if dome:
                notes.append(f"{name}: a dome past the last section "
                             f"(its height field closes the end)")
            continue
        rings.insert(0 if end == 0 else len(rings),
                     new_rings[0] if len(new_rings) == 1 else new_rings)
        moved = np.mean([abs(float((r - e).mean(axis=0) @ axis))
                         for r, e in zip(new_rings, end_loops, strict=True)])
        error = f" (± {max(errors):.2g}, its standard error)" if errors else ""
        if ends is not None:
            ends[name] = {"how": "cap" if min(counts) >= NORMAL_NEIGHBOURS else
                          "rim line" if rim is not None else "wall end",
                          "height": float(np.mean([float(np.mean(r @ axis)) for r in new_rings])),
                          "standard_error": float(max(errors)) if errors else None}
        if min(counts) >= NORMAL_NEIGHBOURS:
            notes.append(f"{'bottom' if end == 0 else 'top'} cap moved {moved:.4g} to the "
                         f"median height of {sum(counts)} cap points{error}")
        else:
            notes.append(f"{'bottom' if end == 0 else 'top'} end extended {moved:.4g} to the "
                         + (f"rim line the points beyond the end plane bunch at (no cap points; "
                            f"{len(outer)} points beyond the plane)" if rim is not None else
                            f"end of the wall points (no cap points: the 95th percentile offset "
                            f"of {len(outer)} points beyond the end plane, / 0.95)") + error)
    return rings, notes


def _cap_height(heights: np.ndarray, flat: np.ndarray, ring_flat: np.ndarray, h_end: float,
                sign: float, delta: float, sigma: np.ndarray | None,
                spread: bool = False) -> float | tuple[float, float, int] | None:
    """Height of a flat cap from its points on *both* sides of the end plane.

    The cap points inside the end ring (inset by ``CAP_INSET``) within ``2 delta``
    outwards and ``2 delta`` inwards of the end plane give a first (1/σ²-weighted)
    median; then, three times, the median of those within ``max(3 s, delta / 2)`` of it
    (``s`` their MAD scale).  Where the section spacing is below the cap's noise
    (10⁷ points at σ = 0.002: spacing 0.0033, ±3σ = ±0.006) the end plane lies inside
    the cap's band, and the points past it alone are a truncated sample whose median
    sits about σ outwards -- the 10⁷-point vase's ends were 0.0020 / 0.0026 out, walls
    0.000044 (benchmarks/README.md).  ``None`` with fewer than ``NORMAL_NEIGHBOURS``
    points, or when the points inwards of the plane do not belong to a flat cap (a
    dome's top has none there: the median of the outer ones is kept).  With
    ``spread``: ``(height, s, m)``, ``s`` the MAD scale of the ``m`` points kept about it.
    """
    offset = sign * (heights - h_end)
    near = np.flatnonzero((offset > -2 * delta) & (offset <= 2 * delta))
    if len(near) < NORMAL_NEIGHBOURS:
        return None
    mean = ring_flat.mean(axis=0)
    near = near[inside_polygon(flat[near], mean + CAP_INSET * (ring_flat - mean))]
    if len(near) < NORMAL_NEIGHBOURS or not np.any(offset[near] <= 0):
        return None
    values = heights[near]
    weights = None if sigma is None else _precision_weights(sigma[near])
    centre = _weighted_quantile(values, weights, 0.5)
    for _ in range(3):
        scale = 1.4826 * float(np.median(np.abs(values - centre)))
        keep = np.abs(values - centre) <= max(3.0 * scale, 0.5 * delta)
        if keep.sum() < NORMAL_NEIGHBOURS:
            break
        centre = _weighted_quantile(values[keep], None if weights is None else weights[keep],
                                    0.5)
    if spread:
        kept = values[np.abs(values - centre) <= max(3.0 * scale, 0.5 * delta)]
        return float(centre), 1.4826 * float(np.median(np.abs(kept - centre))), len(kept)
    return float(centre)


def _drop_sections_past_cap(rings: list, section_heights: list, this: int, sign: float,
                            heights: np.ndarray, flat: np.ndarray, frame: np.ndarray,
                            delta: float, sigma: np.ndarray | None):
    """Remove the end sections that lie beyond their cap's height (in place).

    With the cap's noise wider than the section spacing the slicing's dense extent
    reaches into the noise and the last sections' planes lie past the cap itself
    (10⁵ points at σ = 0.02: end planes 0.033 / 0.024 beyond the truth's caps, the
    caps then placed 0.017 / 0.018 out); their rings are rim points scattered by the
    noise.  Single-loop ends only, and at least three sections kept.  Returns
    ``(count, cap height)`` when sections were dropped, else None.
    """
    count, cap = 0, None
    while len(rings) > 3:
        entry = rings[this]
        ring = entry if isinstance(entry, np.ndarray) else (entry[0] if len(entry) == 1
                                                           else None)
        if ring is None:
            break
        found = _cap_height(heights, flat, ring @ frame[:2].T, section_heights[this], sign,
                            delta, sigma, spread=True)
        if found is None:
            break
        h, scale, _ = found
        # Only a plane within the cap's noise band (3 MAD scales, or half a spacing, the
        # slab's own half-width, when the cap is sharper) is the cap's noise; one farther
        # out holds wall points past the cap -- a rim standing above a recessed lid (a
        # can's top: its rim sections had been dropped and the end put on the lid, 4.7
        # point spacings below the rim top).
        past = sign * (section_heights[this] - h)
        if past <= 0 or past > max(3.0 * scale, 0.5 * delta):
            break
        cap = h
        rings.pop(this)
        section_heights.pop(this)
        count += 1
    return (count, cap) if count else None


#: Significance (in standard errors) a bunch of points at the end of a wall must reach to
#: be taken for its rim line (:func:`rim_line`).  Of 1 200 simulated ends with no rim line
#: (100-2 000 points uniform over the end's extent, blurred by their σ; a one-off
#: simulation, ``tests/surface/test_stitch.py`` checks 180) none reached 5 (the largest
#: 4.5); the demo's rims, seen edge-on by the ring, reach 7.2-8.4.
RIM_LINE_Z = 5.0


def rim_line(offsets: np.ndarray, sigma: np.ndarray, end: float) -> float | None:
    """The rim line the points beyond an end plane bunch at, if they do.

    A ring of cameras sees a rim edge-on: its outline is measured many times over
    (``matching/contours.py``) while the wall just inside it runs out at a grazing
    angle.  The points beyond the last section plane are then not spread evenly up
    to the rim, as the 95 %-quantile rule of :func:`extend_to_caps` assumes, but
    bunch at the rim, centred on it with their own σ of spread, and the quantile
    lands on the bunch's outer flank (demo ring: top end 0.0009, bottom 0.0017
    beyond the truth's rim).  This finds the bunch and returns its centre.

    The offsets' density is estimated with a Gaussian kernel of the points' median
    σ (the measurement blur, from the data) within ``[end - 4σ, end + σ]`` (a rim
    line lies at the end of the data, which ``end`` -- the quantile rule's
    answer -- overshoots by at most its spread); its maximum ``p`` is a rim line
    when the points within ±σ of it exceed what the wall just inside (``[p - 8σ,
    p - 3σ]``) predicts by :data:`RIM_LINE_Z` standard errors of the difference
    (both counts Poisson); the line's centre is then the window's mean with the
    wall's shoulder taken out (below).  Measured on four demo workspaces (24-view
    ring; ``benchmarks/demo_truth.py W``, the stitched mesh's ends against the
    truth's): bottom -0.00009..+0.00014, top -0.00006..-0.00040, where the quantile
    rule said +0.0016..+0.0018 and +0.0009.

    Parameters
    ----------
    offsets : (M,) float64
        Offsets of the points beyond the end plane (positive, outwards).
    sigma : (M,) float64
        Their precisions (same units); the median of the finite, positive ones is
        the kernel's width.
    end : float
        The quantile rule's end offset.

    Returns
    -------
    float or None
        The rim line's offset, or ``None`` where no bunch stands out (the quantile
        rule's end stays).
    """
    offsets = np.asarray(offsets, dtype=np.float64)
    sigma = np.asarray(sigma, dtype=np.float64)
    good = np.isfinite(sigma) & (sigma > 0)
    if not good.any() or len(offsets) < NORMAL_NEIGHBOURS:
        return None
    blur = float(np.median(sigma[good]))
    grid = np.linspace(max(end - 4.0 * blur, 0.0), end + blur, 201)
    # Kernel sums over a fixed grid, in chunks of points (a few hundred points here).
    density = np.zeros(len(grid))
    for start in range(0, len(offsets), 4096):
        chunk = offsets[start:start + 4096]
        density += np.exp(-0.5 * ((grid[:, None] - chunk[None, :]) / blur) ** 2).sum(axis=1)
    peak = float(grid[int(np.argmax(density))])
    lo, hi = max(peak - 8.0 * blur, 0.0), peak - 3.0 * blur
    if hi - lo < 2.0 * blur:
        return None
    wall = np.count_nonzero((offsets > lo) & (offsets <= hi))
    ratio = 2.0 * blur / (hi - lo)
    expected = ratio * wall
    observed = np.count_nonzero(np.abs(offsets - peak) <= blur)
    z = (observed - expected) / np.sqrt(max(expected + ratio * ratio * wall, 1.0))
    if z < RIM_LINE_Z:
        return None
    # The wall's shoulder: its points within ±σ of an edge at e number ρσ and average
    # e - φ(1)σ (∫ t Φ(-t) dt over [-1, 1] = -φ(1)); taken out of the window's count and
    # sum, what is left is the line's.  Halves the maximum's inward bias (simulated 250
    # wall + 100 line points, σ 0.0006: -0.00032 -> -0.00015 on average; on the demo's
    # full clouds, one-off, top rims -0.00024..-0.00042 -> -0.00006..-0.00028).
    density_wall = wall / (hi - lo)
    shoulder = density_wall * blur
    line = peak
    for _ in range(3):
        window = np.abs(offsets - line) <= blur
        count = np.count_nonzero(window)
        if count - shoulder < 1.0:
            return peak
        line = (offsets[window].sum() - shoulder * (line - _PHI_1 * blur)) / (count - shoulder)
    return float(line)


#: Standard error of a median over that of a mean, for Gaussian values: sqrt(π / 2).
_MEDIAN_ERROR = float(np.sqrt(np.pi / 2.0))
#: φ(1), the standard normal density at 1.
_PHI_1 = float(np.exp(-0.5) / np.sqrt(2.0 * np.pi))


def _precision_weights(sigma: np.ndarray) -> np.ndarray | None:
    """Inverse-variance weights ``1 / σ²``; ``None`` (equal weights) unless every σ is
    finite and positive."""
    sigma = np.asarray(sigma, dtype=np.float64)
    if not len(sigma) or not np.all(np.isfinite(sigma) & (sigma > 0)):
        return None
    return 1.0 / sigma ** 2


def _weighted_quantile(values: np.ndarray, weights: np.ndarray | None, q: float) -> float:
    """The q-quantile of ``values`` with ``weights`` (``None``: ``np.quantile``'s)."""
    if weights is None:
        return float(np.quantile(values, q))
    order = np.argsort(values, kind="stable")
    cumulative = np.cumsum(weights[order])
    # midpoint rule: each value stands at the middle of its weight
    position = (cumulative - 0.5 * weights[order]) / cumulative[-1]
    return float(np.interp(q, position, values[order]))


def _extrapolate_ring(ring: np.ndarray, befores: list, step: float,
                      axis: np.ndarray) -> np.ndarray:
    """``ring`` moved ``step`` along the axis, extrapolated from the rings before it.

    ``befores``: the next rings inwards, nearest first (the caller passes
    :data:`EXTRAPOLATION_RINGS`).  Each ring point is followed inwards through them at
    its own polar angle (:func:`_same_angle`: rings numbered from their own θ_min do
    not start at the same angle, and pairing them by index slid the points sideways),
    and a straight line fitted per point to those positions against their heights is
    read at the new height.  A line through the last two rings alone, read two
    spacings out, multiplies their noise by ~3 (demo ring, end ring moved 0.0165: with
    index pairing it bulged 0.011 at two opposite sides, with angle pairing 0.0034, the
    line through three rings 0.0018); three rings, not more: a torus' crown bends
    within them (Chamfer over seeds 3-5 0.00077-0.00109 with two rings, 0.00083-0.00114
    with three, 0.00092-0.00117 with four; the closest-point pairing of
    :func:`surface.stitch._read_at` left its crown caps not simple).  Falls back to a
    straight move when the extrapolation would shrink or stretch the ring more than
    2x (near a pole, where the wall turns into the cap).
    """
    track = [ring]
    for other in befores:
        track.append(_same_angle(track[-1], other, axis))
    if len(track) < 2:
        return ring + step * axis
    pos = np.stack(track)  # (k, n, 3)
    h = pos @ axis  # (k, n): heights along the axis
    h0 = h[0]
    dh = h - h0  # relative heights
    mean_h = dh.mean(axis=0)
    mean_p = pos.mean(axis=0)
    var = ((dh - mean_h) ** 2).sum(axis=0)
    cov = np.einsum("kn,knc->nc", dh - mean_h, pos - mean_p)
    slope = cov / np.maximum(var, TOL.zero)[:, None]  # d(position)/d(height)
    target = step  # the new ring's height above ring's own (per point)
    new = mean_p + (target - mean_h)[:, None] * slope
    # exactly at the ring's height + step along the axis
    new += (h0 + step - new @ axis)[:, None] * axis
    stretch = np.linalg.norm(new - new.mean(axis=0), axis=1) / np.maximum(
        np.linalg.norm(ring - ring.mean(axis=0), axis=1), TOL.zero)
    if not np.all((stretch > 0.5) & (stretch < 2.0)):
        new = ring + step * axis
    return new


def _same_angle(ring: np.ndarray, before: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """(n, 3): ``before`` read at the polar angles of ``ring``'s points about the axis.

    Angles about each ring's own centre; ``before`` interpolated linearly along its
    closed loop.  Where its angles do not run monotonically round the loop (not
    star-shaped about its centre), it is read at the fractional index
    ``j n_before / n`` instead.
    """
    n_this, n_prev = len(ring), len(before)
    e1 = np.cross(axis, [1.0, 0.0, 0.0])
    if np.linalg.norm(e1) < 0.5:
        e1 = np.cross(axis, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)

    def angles(pts):
        d = pts - pts.mean(axis=0)
        return np.arctan2(d @ e2, d @ e1)

    tb = np.unwrap(angles(before))
    steps = np.diff(np.r_[tb, tb[0] + np.sign(tb[-1] - tb[0]) * 2 * np.pi])
    if n_prev >= 3 and (np.all(steps > 0) or np.all(steps < 0)) and \
            abs(tb[-1] - tb[0]) < 2 * np.pi:
        if steps[0] < 0:  # clockwise: reversed
            tb, before = tb[::-1], before[::-1]
        ext_t = np.r_[tb - 2 * np.pi, tb, tb + 2 * np.pi]
        ext_p = np.vstack([before, before, before])
        t = tb[0] + np.mod(angles(ring) - tb[0], 2 * np.pi)
        return np.column_stack([np.interp(t, ext_t, ext_p[:, a]) for a in range(3)])
    u = np.arange(n_this) * (n_prev / n_this)
    i0 = np.floor(u).astype(np.int64)
    w = (u - i0)[:, None]
    return (1 - w) * before[i0 % n_prev] + w * before[(i0 + 1) % n_prev]


def largest_perimeter(loops_per_section) -> float:
    """Largest convex-hull perimeter over all loops (a noise-robust length), scene units."""
    from scipy.spatial import ConvexHull

    best = 0.0
    for loops in loops_per_section:
        for loop in loops:
            flat = loop.points @ loop.frame[:2].T
            try:
                best = max(best, float(ConvexHull(flat).area))  # 2-D "area" is the perimeter
            except Exception:  # noqa: BLE001 - degenerate (collinear) loop: skip its length
                continue
    return best


#: Former private name, used by ``pipeline.stages`` (kept as an alias).
