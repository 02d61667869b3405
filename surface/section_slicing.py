r"""The cloud cut into sections on their planes, and the slicing axis chosen for it.

Step 1 of the section method (``surface.reconstruct``): :func:`slice_cloud` slices the
cloud (``surface.sections.slice_sections``) and moves every slab point to its plane along
the local surface (:func:`slide_to_planes`: tangent planes from PCA normals, with
:func:`normal_neighbours` neighbours; points on surfaces within 30° of the plane are cap
points, left out of the contours); ``axis="auto"`` tries candidate axes
(:func:`choose_axis`) and keeps the one whose sections resolve the most topology.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.spatial import cKDTree

from surface._blas import one_blas_thread
from surface.loop_graph import loop_graph
from surface.section_loops import organise_sections
from surface.sections import _orient, slice_sections
from surface.validate import TOL

__all__ = ["AXIS_SAME_DEGREES", "AXIS_TRIAL_POINTS", "CAP_SHARE_SLACK", "LOOSE_WALL_SINE",
           "MAX_NORMAL_NEIGHBOURS", "MIN_WALL_SINE", "NORMAL_NEIGHBOURS", "NORMAL_POINTS",
           "NORMAL_SAMPLE", "NORMAL_TILT", "SHARE_TIE", "SLOPE_NEIGHBOURS", "SPARSE_TAIL",
           "SlicedCloud", "choose_axis", "normal_neighbours", "pooled_slopes", "slice_cloud",
           "slide_to_planes"]


#: Neighbours of the PCA normal estimate (a plane fit needs >= 3; 12 averages noise).
NORMAL_NEIGHBOURS = 12


#: Smallest sin(angle between surface normal and axis) for a point to join a
#: section contour: below it the surface is within 30° of the section plane
#: (an end cap, a pole) and sliding the point to its plane would move it more
#: than twice its height offset.
MIN_WALL_SINE = 0.5


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
    """Step 1 of ``surface.reconstruct.surface_from_points``: slice, then move points to
    their planes.

    Parameters are those of :func:`surface.reconstruct.surface_from_points`.

    Returns
    -------
    SlicedCloud
    """
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


#: Cap shares within this many standard errors of their difference are tied
#: (:func:`choose_axis`; the one-standard-error rule of model selection).  On the corpus
#: clouds (10⁴-6·10⁴ points) it ties only the mug's two axes (0.25-0.8 standard errors
#: apart at 2·10⁴ points); at 1.96 it would tie two of Igea's at 2·10⁴ (1.3 and 1.9).
SHARE_TIE = 1.0


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
       points (PCA normals within 60° of the axis, ``MIN_WALL_SINE``) wins; shares
       within :data:`SHARE_TIE` standard errors of their difference are tied, and
       of tied axes the one the normals lie most across wins (smallest mean
       :math:`(n·a)^2`: the mug's axis, not its principal axis tilted 5° by the handle).

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
    candidates = _candidate_axes(normals, vecs)
    capped = [1.0 - (normals @ axis) ** 2 < MIN_WALL_SINE**2 for axis in candidates]
    shares = [float(np.mean(c)) for c in capped]
    # χ decides only among axes with about as few cap points as the fewest: an axis
    # cutting most walls obliquely makes ragged loops whose spurious splits lower χ.
    # The others are not sliced at all (their χ would decide nothing).
    close = [k for k in range(len(candidates)) if shares[k] <= min(shares) + CAP_SHARE_SLACK]
    chis = [_trial_chi(trial, axis, sections, spacing, trials) if k in close else None
            for k, axis in enumerate(candidates)]
    finite = [chis[k] for k in close if np.isfinite(chis[k])]
    best_chi = min(finite) if finite else float("inf")
    pool = [k for k in close if chis[k] == best_chi] or close
    fewest = min(pool, key=lambda k: (shares[k], k))
    # Cap shares apart by less than SHARE_TIE standard errors of their difference (the
    # same points counted along both axes: sqrt(discordant share / N), McNemar's) are
    # the same share sampled twice; between such axes the one the normals lie most
    # across (smallest mean (n·a)², the revolution's or extrusion's axis) wins.
    tied = [k for k in pool if shares[k] - shares[fewest] <= SHARE_TIE * np.sqrt(
        np.mean(capped[k] != capped[fewest]) / len(normals))]
    best = min(tied, key=lambda k: (float(np.mean((normals @ candidates[k]) ** 2)), k))
    listed = "; ".join(f"{np.round(a, 3).tolist()}: "
                       f"{'not sliced' if c is None else f'chi {c:g}'}, caps {100 * f:.0f} %"
                       for a, c, f in zip(candidates, chis, shares, strict=True))
    reason = (f"axis auto: {np.round(candidates[best], 4).tolist()}, of the candidate axes "
              f"resolving the most topology (smallest Euler characteristic chi of the "
              f"sections' loop graph) the one with the fewest points on caps ({listed})")
    if trials is not None:
        trials["whole"] = trial is pts and id(candidates[best]) in trials
    return candidates[best], reason


def _candidate_axes(normals: np.ndarray, vecs: np.ndarray) -> list:
    """The axes :func:`choose_axis` tries: the direction most perpendicular to the normals
    (least eigenvector of Σ n nᵀ), then the principal axes ``vecs`` (columns, largest last)
    not within :data:`AXIS_SAME_DEGREES` of one already listed."""
    candidates = [_orient(np.linalg.eigh(normals.T @ normals)[1][:, 0])]
    for k in (2, 1, 0):
        if all(abs(float(vecs[:, k] @ c)) < np.cos(np.radians(AXIS_SAME_DEGREES))
               for c in candidates):
            candidates.append(_orient(vecs[:, k]))
    return candidates


def _trial_chi(trial: np.ndarray, axis: np.ndarray, sections, spacing, trials) -> float:
    """The Euler characteristic of the loop graph of ``trial`` sliced along ``axis``
    (inf when it cannot be sliced); the slicing kept in ``trials`` by ``id(axis)``."""
    try:
        sliced = slice_cloud(trial, axis=axis, sections=sections, spacing=spacing)
        if trials is not None:
            trials[id(axis)] = sliced
        _, loops, _ = organise_sections(sliced.sections, organised=sliced.organised,
                                        min_points=4)
        graph = loop_graph([[lp.points @ lp.frame[:2].T for lp in found] for found in loops],
                           spacing=sliced.spacing)
        return graph.euler()
    except ValueError:
        return float("inf")


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
