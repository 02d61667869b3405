r"""A control mesh sized by the data: as few rings and sections as the smooth surface needs.

The stitched mesh of :mod:`surface.stitch` follows the point density; Loop's surface over it (4
patches a triangle) inherits every vertex.  Here the dense rings are *thinned*
(:mod:`surface.section_regression`: every ``step``-th section kept, graded towards both ends, each
kept ring regressed across its neighbours and resampled to ``n`` / ``2n`` points) and stitched again
with the same rules.  One target edge ``h`` sets ``step = floor(h / Δ)`` and ``n = ceil(P / h)`` (Δ
the dense section spacing, P the largest ring perimeter).  The smooth surface is built over the
*interpolating* control mesh (:mod:`surface.interpolation`), so it passes through the thinned
vertices instead of shrinking.

*Level search* (:func:`size_control_mesh`).  ``h`` shrinks by √2 from 12 points round the largest
ring; the coarsest level whose estimated error (:mod:`surface.section_errors`) is within the goal is
taken (or the level half way to the previous, ``h·2^¼``, if it passes too): bisection over the
levels of step ≥ 2, then the step-1 levels, then a walk outwards from the closest estimate.  When
none passes, the candidate estimated closest is kept if it beats the rings' sill, else the dense
mesh.  A step-1 candidate is judged against the goal the last coarser candidate measured.

Scene units throughout.  The names of its parts (:mod:`surface.section_chains`,
:mod:`surface.section_errors`, :mod:`surface.section_regression`, :mod:`surface.interpolation`)
that the sizing's callers use are re-exported here (``__all__``); the others are imported from
their own modules.  The rules' history and the figures that decided them:
``docs/decisions/sizing.md``.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from surface import bezier
from surface._blas import one_blas_thread
from surface.bezier import closest_points
from surface.interpolation import (
    FOLD_LEVEL,
    JUDGE_FOLD_LEVEL,
    crease_band,
    crease_vertices,
    interpolating_control,
    off_rim_vertices,
    rim_vertices,
)
from surface.metrics import MeshDistance, sample_mesh, triangle_areas
from surface.section_chains import (
    SectionLayout,
    largest_perimeter,
    nearest_section,
    plane_frame,
    profile_length,
    section_heights,
    section_layout,
    section_loops,
)
from surface.section_errors import (
    Variogram,
    risk_estimate,
    section_scatter,
    section_variogram,
    stitched_error,
    stitched_surface_error,
    unshared_noise,
)
from surface.section_regression import (
    coarsen_rings,
    kept_sections,
    rounded_ends,
    section_weights,
    smoothing_matrix,
    thinning,
    untangled,
)

__all__ = ["FOLD_LEVEL", "SizedMesh", "Variogram", "coarsen_rings", "crease_band",
           "crease_vertices", "interpolating_control", "kept_sections", "profile_length",
           "reference_vertices", "risk_estimate", "rounded_ends", "section_layout",
           "section_scatter", "section_variogram", "section_weights", "size_control_mesh",
           "smooth_deviation", "smoothing_matrix", "stitched_error", "stitched_surface_error",
           "untangled"]


#: Tessellation chord tolerance as a share of the sized surface's estimated error
#: (:meth:`SizedMesh.chord_tolerance`).
CHORD_FRACTION = 1.0


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
    the vertices off the sharp edges, if known (:func:`off_rim_vertices`).
    """
    candidates = np.arange(len(vertices))
    smooth = np.flatnonzero(off_rim_vertices(vertices, triangles) if off_rims is None else off_rims)
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
    tri = np.asarray(triangles, dtype=np.int64)
    area = triangle_areas(np.asarray(vertices, dtype=np.float64), tri)
    return np.bincount(tri.ravel(), weights=np.repeat(area / 3.0, 3), minlength=len(vertices))


def _smooth_surface(vertices: np.ndarray, triangles: np.ndarray,
                    creases: np.ndarray | None = None):
    """Loop's surface interpolating the mesh (``creases``: :func:`interpolating_control`)
    and the distance function of its level-1 tessellation (``surface.metrics.MeshDistance``:
    one raycasting scene for several point sets, and the start of
    :func:`surface.bezier.closest_points`)."""

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
        (``pipeline.bezier_surface.spacing_cuts``).
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

        The flat triangles then lie within what the data leave open anyway (the figures:
        ``docs/decisions/sizing.md``, *Chord tolerance*).
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
        profile*); False: every ``step``-th section.

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
    axis, variogram, noise = _checked_noise(rings, planes, spacing, tolerance, noise, variogram)
    dense_vertices, dense_triangles = (np.asarray(a) for a in dense)
    search = _level_search(rings, planes, spacing, build, (dense_vertices, dense_triangles),
                           tolerance, seed, smooth, variogram, noise, along_profile, axis)
    found = search.coarsest_passing()
    if found is not None:
        between = search.judge(found[0] * np.sqrt(H_RATIO))   # half way (in log h) to the previous
        return _refolded(between if between is not None else found[1])
    best = _closest_failed(search.failed)
    if best is not None and best.error < search.floor:
        # none passed, but one is estimated closer to the truth than the dense mesh's own
        # smooth surface can be (at least the sill): the fewest patches among the closest
        return _refolded(best)
    return SizedMesh(dense_vertices, dense_triangles.astype(np.int64), 1, 0, 0.0,
                     tolerance if tolerance is not None else stitched_error(variogram),
                     search.tried, 0.0, noise, variogram, creases=search.dense_creases)


def _checked_noise(rings: Sequence, planes: Sequence, spacing: float, tolerance: float | None,
                   noise: float | None, variogram: Variogram | None):
    """:func:`size_control_mesh`'s inputs checked, and the dense rings' errors:
    ``(axis, variogram, noise)`` (the variogram measured, else white noise of ``noise``)."""
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
    return axis, variogram, noise


def _level_search(rings: Sequence, planes: Sequence, spacing: float, build: Callable,
                  dense: tuple[np.ndarray, np.ndarray], tolerance: float | None, seed: int,
                  smooth: bool, variogram: Variogram, noise: float, along_profile: bool,
                  axis: np.ndarray) -> _LevelSearch:
    """The search's fixed parts: the dense mesh's reference sample (off the rims, the creases
    and the end planes), points on its faces, the sections' layout and profile length."""
    dense_vertices, dense_triangles = dense
    heights = section_heights(rings, axis)
    order = np.argsort(heights)
    rng = np.random.default_rng(seed)
    sharp = rim_vertices(dense_vertices, dense_triangles)
    # the object's convex creases inside its end sections (crease_vertices), interpolated by
    # every candidate; like the rims they stay out of the reference sample (counted in it,
    # the real temple's thinnings were estimated 3-6x their goal and its dense mesh kept:
    # 308 744 patches, its silhouettes 0.0032 IoU above the stitched mesh's)
    between = crease_band(heights)
    dense_creases = crease_vertices(dense_vertices, dense_triangles, axis, between)
    crease_points = dense_vertices[dense_creases] if dense_creases is not None else None
    off_rims = off_rim_vertices(dense_vertices, dense_triangles, sharp)
    reference = reference_vertices(dense_vertices, dense_triangles, rng, off_rims)
    nearest = nearest_section(dense_vertices[reference] @ axis, heights, order)
    inner = (nearest > 0) & (nearest < len(rings) - 1)   # the end planes' caps: not rings
    if inner.sum() >= min(100, len(inner)):
        reference, nearest = reference[inner], nearest[inner]
    reference = dense_vertices[reference]
    on_faces = _points_on_faces(dense_vertices, dense_triangles, off_rims, len(reference),
                                axis, heights, order, seed)
    layout = section_layout(rings, plane_frame(axis))
    # kept step apart along the profile where both ends are rounded (kept_sections)
    length = profile_length(rings, axis) / spacing if along_profile and all(
        rounded_ends(rings, (dense_vertices, dense_triangles), axis, sharp)) else None
    return _LevelSearch(
        rings, planes, spacing, build, tolerance, smooth, axis, variogram, noise, heights,
        layout, length, nearest, reference, on_faces, between, crease_points, dense_creases,
        perimeter=largest_perimeter(rings),
        dense_n=min(len(loop) for entry in rings[::2] for loop in section_loops(entry)),
        floor=float(np.sqrt(variogram.sill)))   # a step-1 candidate's estimate is never below


@dataclass
class _LevelSearch:
    """One search of :func:`size_control_mesh`: what every candidate is judged with, and
    what was tried (in order), which failed (``(SizedMesh, standard error)``), and the goal
    measured by the finest candidate not at step 1 with its ``h`` (``shared_goal``)."""

    rings: Sequence
    planes: Sequence
    spacing: float
    build: Callable
    tolerance: float | None
    smooth: bool
    axis: np.ndarray
    variogram: Variogram
    noise: float
    heights: np.ndarray
    layout: SectionLayout
    length: np.ndarray | None
    nearest: np.ndarray
    reference: np.ndarray
    on_faces: np.ndarray | None
    between: tuple
    crease_points: np.ndarray | None
    dense_creases: np.ndarray | None
    perimeter: float = 0.0
    dense_n: int = 0
    floor: float = 0.0
    tried: list = field(default_factory=list)
    seen: set = field(default_factory=set)
    failed: list = field(default_factory=list)
    shared_goal: list = field(default_factory=lambda: [None, np.inf])

    def level_key(self, h):
        """``(step, n)`` of the level of edge length ``h``."""
        return max(1, int(np.floor(h / self.spacing))), _ring_points(self.perimeter, h)

    def levels(self) -> list:
        """The edge lengths from 12 points round the largest ring down, by ``H_RATIO``, while
        coarser than the dense mesh."""
        levels, h = [], self.perimeter / MIN_RING_POINTS
        while self.level_key(h)[0] > 1 or self.level_key(h)[1] < self.dense_n:
            levels.append(h)
            h /= H_RATIO
        return levels

    def judge(self, h):
        """The candidate of edge length ``h``: a SizedMesh if it passes, else None."""
        step, n = self.level_key(h)
        if (step, n) in self.seen or (step == 1 and n >= self.dense_n):
            return None
        self.seen.add((step, n))
        if step == 1 and self.tolerance is None and self.shared_goal[0] is not None \
                and self.floor > self.shared_goal[0]:
            # keeps every dense ring as it is (section_weights: w < 2), so its error
            # estimate is at least the rings' sill: it cannot pass (module docstring)
            self.tried.append({"step": step, "n": n, "skipped": "step 1 cannot reach the goal",
                               "floor": self.floor, "tolerance": float(self.shared_goal[0])})
            return None
        started = time.perf_counter()
        along = self.length if step >= ALONG_PROFILE_STEP else None
        thin_rings, thin_planes = untangled(*coarsen_rings(
            self.rings, self.planes, step, n, smooth=self.smooth, axis=self.axis, length=along,
            layout=self.layout))
        keep, weights = thinning(self.heights, self.layout, step, along, self.smooth)
        matrix = smoothing_matrix(self.heights if along is None else along, keep, weights)
        mean_influence = float(np.diag(matrix)[self.nearest].mean())
        unshared = float(unshared_noise(matrix, self.variogram)[self.nearest].mean())
        try:
            vertices, triangles, creases, surface, distances, error, goal = self.measure(
                h, thin_rings, thin_planes, unshared)
        except ValueError as exc:  # a thinning the stitch or the surface refuses
            self.tried.append({"step": step, "n": n, "error": str(exc)})
            return None
        if self.tolerance is None:
            if step > 1:
                if h < self.shared_goal[1]:
                    self.shared_goal[0], self.shared_goal[1] = goal, h
            elif self.shared_goal[0] is not None:
                # a step-1 candidate copies the dense rings' errors: its own measure of the
                # goal holds them twice (module docstring); the finest coarser one's holds
                goal = self.shared_goal[0]
        se = _risk_se(distances, error)
        self.tried.append({"step": step, "n": n, "triangles": int(len(triangles)),
                           "deviation": float(distances.mean()), "error": error,
                           "tolerance": float(goal), "influence": mean_influence,
                           "unshared": unshared, "error_se": se,
                           "seconds": round(time.perf_counter() - started, 3)})
        # the surface built to judge it is the smooth stage's, should it be chosen (the
        # closest of the failed ones may be)
        sized = SizedMesh(np.asarray(vertices), np.asarray(triangles, np.int64), step, n,
                          float(distances.mean()), float(goal), self.tried, error, self.noise,
                          self.variogram, surface, creases)
        if error > goal:
            self.failed.append((sized, se))
            return None
        return sized

    def measure(self, h, thin_rings, thin_planes, unshared):
        """A thinning stitched, its smooth surface and its distances to the reference sample:
        ``(vertices, triangles, creases, surface, distances, error, goal)`` (exact distances
        when its estimate is near the goal); a ValueError where the stitch or the surface
        refuses it."""
        vertices, triangles = self.build(thin_rings, thin_planes)
        creases = None if self.crease_points is None else crease_vertices(
            vertices, triangles, self.axis, self.between, self.crease_points, h)
        surface, measure = _smooth_surface(vertices, triangles, creases)
        reference, on_faces, variogram = self.reference, self.on_faces, self.variogram
        distances = measure(reference)
        error = risk_estimate(distances, variogram, unshared)
        goal = self.tolerance if self.tolerance is not None else stitched_surface_error(
            distances, None if on_faces is None else measure(on_faces), variogram)
        if error <= EXACT_WITHIN * goal:   # near: exact distances to the candidate
            faces = self.tolerance is None and on_faces is not None
            exact = closest_points(surface, np.vstack([reference, on_faces]) if faces
                                   else reference, tessellated=measure)[0]
            distances = exact[:len(reference)]
            error = risk_estimate(distances, variogram, unshared)
            if faces:
                goal = stitched_surface_error(distances, exact[len(reference):], variogram)
        return vertices, triangles, creases, surface, distances, error, goal

    def walk(self, levels: list):
        """After a bisection that found none: the step-1 levels in
        order, then, from the level estimated closest, coarser levels outwards while
        their estimates stay within one standard error of it (each coarser one beyond is
        farther still, as the bisection assumes): what trying every level finds -- the
        coarsest pass, or :func:`_closest_failed`'s choice -- without building the coarse
        levels the estimate rules out (the real temple: four of seven candidates)."""
        for h in levels:
            if int(np.floor(h / self.spacing)) < 2:
                passed = self.judge(h)
                if passed is not None:
                    return h, passed
        if not self.failed:
            return None
        best, se = min(self.failed, key=lambda pair: pair[0].error)
        at = next((i for i, h in enumerate(levels)
                   if self.level_key(h) == (best.step, best.n)), 0)
        passes = []
        for h in levels[at - 1::-1] if at > 0 else []:
            passed = self.judge(h)
            if passed is not None:
                passes.append((h, passed))
                continue
            error = next((c["error"] for c in self.tried
                          if (c["step"], c["n"]) == self.level_key(h)
                          and isinstance(c.get("error"), float)), None)
            if error is not None and error > best.error + se:
                break
        return passes[-1] if passes else None

    def coarsest_passing(self):
        """``(h, SizedMesh)`` of the coarsest level that passes, or None: bisection over the
        levels of step >= 2 (the estimate falls as h does), then, when it finds none,
        :meth:`walk`."""
        levels = self.levels()
        coarse = [h for h in levels if int(np.floor(h / self.spacing)) >= 2]
        found = None
        lo, hi = 0, len(coarse)
        while lo < hi:
            mid = (lo + hi) // 2
            passed = self.judge(coarse[mid])
            if passed is not None:
                hi, found = mid, (coarse[mid], passed)
            else:
                lo = mid + 1
        return found if found is not None else self.walk(levels)


def _refolded(sized: SizedMesh) -> SizedMesh:
    """The chosen candidate with its surface built again over the control mesh unfolded at
    :data:`FOLD_LEVEL` (it was judged at :data:`JUDGE_FOLD_LEVEL`): the surface the smooth
    stage writes."""
    if sized.surface is None or FOLD_LEVEL == JUDGE_FOLD_LEVEL:
        return sized

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


def _points_on_faces(vertices, triangles, off_rims, count, axis, heights, order, seed):
    """``count`` points spread by area over the dense mesh's faces whose vertices are all
    off the sharp rims and off the end planes (as the reference vertices); None if there
    are none."""
    eligible = off_rims.copy()
    section = nearest_section(vertices @ axis, heights, order)
    eligible &= (section > 0) & (section < len(heights) - 1)
    faces = triangles[eligible[triangles].all(axis=1)]
    if len(faces) == 0:
        return None
    return sample_mesh(vertices, faces, count=count, seed=seed + 1)
