"""A triangle mesh -> Loop's G1 sextic Bézier surface, tessellated, with its G1 report.

One smoothing path for ``photosurf smooth``, ``photosurf sections --smooth`` and the
smooth stage of ``photosurf run``: :func:`smooth_mesh` builds the surface over the mesh
as its control mesh (:func:`surface.bezier.control_net`: C. Loop, "Smooth spline
surfaces over irregular meshes", SIGGRAPH 1994; the mesh refined once, ``P = 4 F``
sextic triangular patches), tessellates it at level L (each patch edge cut
into ``2**L`` segments, :func:`surface.bezier.tessellate`) and measures G1 continuity
across every interior patch edge (:func:`surface.bezier.edge_continuity`: the largest
position gap and normal angle at :data:`EDGE_SAMPLES` points per edge);
:func:`smooth_to_files` writes the tessellation and its control net
(:func:`pipeline.export.export_surface`).

Level: the refinement halves the control mesh's edge h₀ and level L cuts a patch edge
into 2^L, so the flat triangles have edges h = h₀/2^(L+1) and deviate from the exact
surface by about the sagitta κh²/8 — 4× less per level.  ``"auto"`` picks the coarsest
level whose chord error is within a tolerance
(:func:`surface.bezier.tessellation_level`, at most 3).

Solid check: the tessellation is checked as a solid (:func:`surface.validity.check_solid`:
manifold, oriented, closed, self-intersections); :func:`solid_report` logs one warning
line naming every defect (a border only when the control mesh was closed) and returns
the figures for the manifest, so a defect is never written silently.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pipeline.errors import InputError

log = logging.getLogger("photosurf")

#: G1 is checked at this many points per interior patch edge (ends included).
EDGE_SAMPLES = 9
#: Largest level ``"auto"`` chooses (4^3 = 64 triangles per patch).
MAX_AUTO_LEVEL = 3
#: Repair of a self-crossing surface (:func:`_untangled`): per round, the rings of control
#: faces grown around the crossing ones (and the previous rounds' region) and the move
#: (:func:`surface.repair.membrane`: Jacobi steps, the thin-plate fill, the membrane
#: itself) -- the smallest move and the one keeping the shape first; and
#: the largest share of the control faces relaxed after the first round (beyond it the
#: tangle is not local: reported).
REPAIR_SCHEDULE = ((1, 3), (1, "biharmonic"), (1, None), (1, "biharmonic"), (1, None),
                   (2, None))
REPAIR_SHARE = 0.1
#: Once a region's move untangles the surface: the shares of that move tried, least first
#: (the first that leaves no crossing is kept; the whole move otherwise).
REPAIR_SHARES = (0.25, 0.5)


@dataclass
class Smoothed:
    """A smoothed mesh.

    Attributes
    ----------
    surface : surface.bezier.BezierSurface
        The exact surface (``control_points`` (P, 28, 3), ``source_face``,
        ``domain_mesh``).
    vertices : (V, 3) float64
    triangles : (T, 3) int64
    normals : (V, 3) float64
        The exact unit normals of the tessellation.
    level : int or "adaptive"
    gap : float
        Largest position gap across patch edges, scene units.
    g1_angle : float
        Largest normal angle across patch edges, radians.
    solid : dict or None
        :func:`solid_report` of the tessellation (``None`` when not checked).

    ``gap`` and ``g1_angle`` (:func:`surface.bezier.edge_continuity`) are computed when
    first asked for: the candidates a smooth path builds and drops (a fit that crosses
    itself, the repair's rounds) never pay for them.
    """

    surface: object
    vertices: np.ndarray
    triangles: np.ndarray
    normals: np.ndarray
    level: int
    solid: dict | None = None
    _continuity: tuple[float, float] | None = field(default=None, repr=False, compare=False)

    def _g1(self) -> tuple[float, float]:
        if self._continuity is None:
            from surface import bezier

            gap, angle = bezier.edge_continuity(self.surface.control_points,
                                                self.surface.domain_mesh[1],
                                                samples=EDGE_SAMPLES)
            self._continuity = (float(gap), float(angle))
        return self._continuity

    @property
    def gap(self) -> float:
        return self._g1()[0]

    @property
    def g1_angle(self) -> float:
        return self._g1()[1]

    def info(self) -> dict:
        """Counts, the G1 figures and the solid check (for the manifest and the
        command's summary)."""
        return {"patches": len(self.surface.control_points), "level": self.level,
                "vertices": len(self.vertices), "triangles": len(self.triangles),
                "g1_angle": self.g1_angle, "gap": self.gap,
                **({"solid": self.solid} if self.solid is not None else {})}


def solid_report(stage: str, vertices: np.ndarray, triangles: np.ndarray,
                 expect_closed: bool = True, report=None, seconds: float | None = None,
                 note: str = "") -> dict:
    """Check a mesh as a solid, log one warning line if it is not one, return the figures.

    Parameters
    ----------
    stage : str
        Prefix of the log line (``"stitch"``, ``"smooth"``).
    vertices : (V, 3) float64
    triangles : (F, 3) int64
    expect_closed : bool
        ``False`` for a surface open by design (one-sided data, ``--open``): its border
        is not a defect and is not logged (it is still counted).
    report, seconds : optional
        The check already made (:func:`surface.validity.check_solid`) and its time.
    note : str
        Appended to the warning line (e.g. what a repair left).

    Returns
    -------
    dict
        :meth:`surface.validity.SolidReport.to_json` plus ``seconds`` (the check's time).
    """
    import time

    from surface.validity import check_solid

    if report is None:
        start = time.perf_counter()
        report = check_solid(vertices, triangles)
        seconds = round(time.perf_counter() - start, 3)
    problems = [p for p in report.problems()
                if expect_closed or not p.startswith("is open")]
    if problems:
        log.warning("%s: the mesh %s%s", stage, "; ".join(problems), note)
    return {**report.to_json(), "expect_closed": bool(expect_closed),
            "seconds": seconds}


#: Level of the stand-alone commands (``photosurf smooth``, ``sections --smooth``) when the
#: pipeline's ``smooth.level`` is a word: they have no error estimate to make a chord
#: tolerance from.
COMMAND_LEVEL = 1


def default_level() -> int:
    """The pipeline's ``smooth.level`` (pipeline/defaults.toml) if it is an integer level,
    else :data:`COMMAND_LEVEL`."""
    from pipeline.config import defaults

    level = defaults()["smooth"]["level"]
    return COMMAND_LEVEL if isinstance(level, str) else int(level)


def spacing_cuts(control_points: np.ndarray, spacing: float) -> np.ndarray:
    """Most cuts per patch edge that keep the facets about ``spacing`` wide, ``(P,) int64``:
    the smallest power of two ``m >= ℓ_p / spacing`` (at least 1), ``ℓ_p`` the longest side
    of patch ``p``'s corner triangle, so that the facets' sides lie between half the spacing
    and the spacing (or the patch's own, where it is smaller).

    The data resolve no shape finer than their point spacing: a facet smaller than it
    shows the surface's interpolation between samples, not a measurement.  Capping the
    adaptive cuts there floors the chord tolerance at what a facet of half a spacing to
    one spacing can hold on each patch's own curvature (``κ s² / 32 .. κ s² / 8``), and
    bounds the tessellation -- and the solid check, linear in its triangles -- before
    either runs: at most ``Σ_p m_p²`` (times ~1.5 for the transitions between
    patches).  Noise-free data give a tolerance from their error estimate near zero
    (a noise-free can: 6.9·10⁻⁷, 5.7 M triangles certified); the cap is what bounds
    them.
    """
    from surface.bezier import control_index

    cp = np.asarray(control_points, dtype=np.float64)
    corners = cp[:, [control_index(6, 0, 0), control_index(0, 6, 0), control_index(0, 0, 6)]]
    longest = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2).max(axis=1)
    ratio = np.maximum(longest / float(spacing), 1.0)
    return (2 ** np.ceil(np.log2(ratio) - 1e-9)).astype(np.int64)


def smooth_mesh(vertices: np.ndarray, triangles: np.ndarray, level: int | str,
                tolerance: float | None = None, surface=None,
                check: bool = True, spacing: float | None = None,
                repair: bool = True) -> Smoothed:
    """Build, tessellate and check the Bézier surface over a control mesh.

    Parameters
    ----------
    vertices : (V, 3) float64
    triangles : (F, 3) int64
        Oriented 2-manifold control mesh (closed gives a watertight surface).
    level : int, "auto" or "adaptive"
        Tessellation level; ``"auto"`` (one level, the coarsest within ``tolerance``) and
        ``"adaptive"`` (:func:`surface.bezier.tessellate_adaptive` with
        :func:`surface.bezier.certified_segments`: cuts per patch) need ``tolerance``.
    tolerance : float, optional
        Chord tolerance of ``"auto"`` and ``"adaptive"``, scene units.
    surface : surface.bezier.BezierSurface, optional
        ``surface.bezier.control_net(vertices, triangles)`` when it was built already
        (the sizing builds the chosen control mesh's surface to judge it).
    check : bool
        Check the tessellation as a solid (:func:`solid_report`, logged as ``smooth``;
        a border counts as a defect only when the control mesh has none).
    spacing : float, optional
        The data's point spacing, scene units: ``"adaptive"`` cuts no patch finer than
        it (:func:`spacing_cuts`).
    repair : bool
        With ``check``: where the surface crosses itself, relax the control mesh there
        and rebuild (:func:`_untangled`, :mod:`surface.repair`); the figures go to
        ``solid["repair"]``.

    Raises
    ------
    ValueError
        A control mesh :func:`surface.bezier.control_net` rejects.
    """
    from pipeline import limits
    from surface import bezier

    # Loop's refinement makes 4 patches per control triangle, level L 4^L triangles each:
    # refused before the control net is built ("auto" is bounded by MAX_AUTO_LEVEL; the
    # adaptive cuts are known once the net is, and checked before tessellating)
    if level != "adaptive":
        finest = MAX_AUTO_LEVEL if level == "auto" else int(level)
        limits.check("smooth.triangles", 4 * len(triangles) * 4 ** finest,
                     where=f"level {finest} on {len(triangles)} control triangles")
    if surface is None:
        if len(triangles):  # a vertex's ring patches cost ~valence^2 (limits: smooth.valence)
            valence = int(np.bincount(np.asarray(triangles).ravel()).max())
            limits.check("smooth.valence", valence,
                         where=f"a control mesh vertex in {valence} triangles")
        surface = bezier.control_net(vertices, triangles)
    if level == "adaptive":  # a chord tolerance per patch, crack-free across patch edges
        if tolerance is None or not tolerance > 0:
            raise ValueError(f"level 'adaptive' needs a positive chord tolerance, got {tolerance}")
        cuts = bezier.certified_segments(surface.control_points, tolerance)
        if spacing is not None and spacing > 0:   # no facet finer than the data's spacing
            cuts = np.minimum(cuts, spacing_cuts(surface.control_points, spacing))
        limits.check("smooth.triangles", int((cuts ** 2).sum()),
                     where=f"adaptive cuts (tolerance {tolerance:.3g}) on "
                           f"{len(cuts)} patches")
        v, t, n = bezier.tessellate_adaptive(surface, tolerance, segments=cuts)
    else:
        if level == "auto":  # finest detail the data can vouch for: chord error <= tolerance
            level = bezier.tessellation_level(surface.control_points, tolerance,
                                              max_level=MAX_AUTO_LEVEL)
        level = int(level)
        v, t, n = bezier.tessellate(surface, level=level)
    solid = None
    smoothed = Smoothed(surface, v, t, n, level, None)
    if check:
        from surface.metrics import edge_table

        closed_control = not np.any(edge_table(triangles).counts == 1)
        report, seconds = _checked(v, t)
        if repair and report.self_intersecting:
            smoothed, report, seconds, solid = _untangled(
                smoothed, report, seconds, vertices, triangles, level, tolerance, spacing)
        smoothed.solid = {**solid_report("smooth", smoothed.vertices, smoothed.triangles,
                                         expect_closed=closed_control, report=report,
                                         seconds=seconds, note=_repair_note(solid)),
                          **({"repair": solid} if solid else {})}
    return smoothed


def smooth_general(vertices: np.ndarray, triangles: np.ndarray, level: int | str,
                   tolerance: float | None = None, points: np.ndarray | None = None,
                   spacing: float | None = None) -> Smoothed:
    """Loop's surface over a general control mesh (``surface.general_mesh``), the first
    valid solid of:

    0. with ``points`` (the cloud): the control mesh fitted to the points
       (``surface.fitting.fitted_control_mesh``); where it crosses itself, the control
       vertices around the crossings back at the mesh's own (:data:`FIT_HOLD_ROUNDS`),
       then repaired as :func:`smooth_mesh` does (``spacing``: the points' spacing);
    1. through its vertices with the interpolating correction in full
       (``surface.fitting.interpolating_control_mesh``, sharp and flat vertices kept);
    2. where that crosses itself, the correction held back where the surface folds
       (``surface.interpolation.interpolating_control`` at the candidates' fold level);
    3. where that crosses too (the interpolation overshoots across a thin gap of a
       decimated iso-surface: the cow's 10^4 points, 136 pairs), over the mesh itself (the
       approximating surface: 0 pairs there), checked and repaired as :func:`smooth_mesh`.

    The first step skips the fold search (its cost: ``docs/decisions/complex-shapes.md``).
    ``solid["general_control"]`` says which step carries the surface.
    """
    from surface.fitting import (
        fitted_control_mesh,
        flat_vertices,
        interpolating_control_mesh,
        sharp_vertices,
    )
    from surface.interpolation import JUDGE_FOLD_LEVEL, interpolating_control

    try:
        keep = sharp_vertices(vertices, triangles, rings=0) | flat_vertices(vertices, triangles)
    except ValueError:   # the construction below refuses the mesh and says why
        keep = None
    start = None
    if points is not None:
        try:
            start = interpolating_control_mesh(vertices, triangles, keep=keep)
            control, fit = fitted_control_mesh(vertices, triangles, points, start=start)
            smoothed = smooth_mesh(control, triangles, level, tolerance, check=False,
                                   spacing=spacing)
            report, seconds = _checked(smoothed.vertices, smoothed.triangles)
            held = np.zeros(len(vertices), dtype=bool)
            for rings in range(1, FIT_HOLD_ROUNDS + 1):
                if not len(report.intersecting_pairs):
                    break
                # where the fitted surface crosses itself (a thin gap, noise followed too
                # closely), the control vertices there go back to the mesh's own (the
                # approximating surface, which keeps to the iso-surface's side of a gap)
                held |= _crossing_vertices(smoothed, report, control, triangles, rings)
                control = np.where(held[:, None], vertices, control)
                smoothed = smooth_mesh(control, triangles, level, tolerance, check=False,
                                       spacing=spacing)
                report, seconds = _checked(smoothed.vertices, smoothed.triangles)
            fit["held_vertices"] = int(held.sum())
            repair = None
            if len(report.intersecting_pairs):
                smoothed, report, seconds, repair = _untangled(
                    smoothed, report, seconds, control, triangles, level, tolerance, spacing)
        except ValueError as exc:
            log.info("smooth: no fitted general surface (%s)", exc)
        else:
            if len(report.intersecting_pairs) == 0:
                smoothed.solid = {**solid_report("smooth", smoothed.vertices, smoothed.triangles,
                                                 report=report, seconds=seconds),
                                  **({"repair": repair} if repair else {}),
                                  "general_control": "fitted", "fit_weight": fit["weight"],
                                  "fit_bend": fit["bend"],
                                  "fit_held_vertices": fit["held_vertices"]}
                return smoothed
            log.info("smooth: the fitted general surface self-intersects at %d pairs",
                     len(report.intersecting_pairs))
    for step in ("interpolating", "unfolded"):
        try:
            if step == "interpolating":
                control = (start if start is not None
                           else interpolating_control_mesh(vertices, triangles, keep=keep))
            else:
                control = interpolating_control(vertices, triangles,
                                                fold_level=JUDGE_FOLD_LEVEL)
            smoothed = smooth_mesh(control, triangles, level, tolerance, check=False)
        except ValueError:   # a control net the construction refuses: the next step
            continue
        solid, seconds = _checked(smoothed.vertices, smoothed.triangles)
        if len(solid.intersecting_pairs) == 0:
            smoothed.solid = {**solid_report("smooth", smoothed.vertices, smoothed.triangles,
                                             report=solid, seconds=seconds),
                              "general_control": step}
            return smoothed
        log.info("smooth: the %s general surface self-intersects at %d pairs", step,
                 len(solid.intersecting_pairs))
    smoothed = smooth_mesh(vertices, triangles, level, tolerance)
    smoothed.solid = {**(smoothed.solid or {}), "general_control": "approximating"}
    return smoothed


#: Rounds in which the fitted general surface's control vertices around its crossings go
#: back to the mesh's own (one more ring of faces each round).
FIT_HOLD_ROUNDS = 3


def _crossing_vertices(smoothed: Smoothed, report, control, triangles, rings: int) -> np.ndarray:
    """Control vertices ``(V,) bool`` of the faces under a surface's crossing facets, grown
    by ``rings`` rings (:mod:`surface.repair`)."""
    from surface.repair import crossing_faces, grow_faces

    pairs = np.asarray(report.intersecting_pairs, dtype=np.int64).reshape(-1)
    corners = smoothed.vertices[smoothed.triangles[pairs]].reshape(-1, 3)
    region = grow_faces(crossing_faces(control, triangles, corners), triangles, rings)
    out = np.zeros(len(control), dtype=bool)
    out[np.asarray(triangles)[region].ravel()] = True
    return out


def _checked(v, t):
    import time

    from surface.validity import check_solid

    start = time.perf_counter()
    report = check_solid(v, t)
    return report, round(time.perf_counter() - start, 3)


def _repair_note(repair: dict | None) -> str:
    if not repair:
        return ""
    return (f" (left after relaxing {repair['faces']} control faces around the "
            f"{repair['pairs_before']} crossing pairs found first, {repair['rounds']} rounds)")


def _untangled(smoothed: Smoothed, report, seconds, control, triangles, level, tolerance,
               spacing):
    """The surface rebuilt over its control mesh relaxed where it crosses itself
    (:mod:`surface.repair`): the control faces under the crossing facets, grown by
    rings, their interior vertices moved towards the membrane of the region's border (a
    few Jacobi steps first, then the membrane itself); again with the new crossings added,
    by :data:`REPAIR_SCHEDULE`, until none is left or the region passes
    :data:`REPAIR_SHARE` of the faces.  Returns the surface with the fewest crossing
    pairs (the first on a tie), its report and the repair's figures (``None`` when
    nothing better was found: the surface is reported as it is)."""
    from surface.repair import crossing_faces, grow_faces, membrane

    x = np.asarray(control, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    before = len(report.intersecting_pairs)
    best = (smoothed, report, seconds, None)
    region = np.zeros(len(t), dtype=bool)
    current = smoothed, report

    def rebuilt(moved_control):
        """The surface over the moved control mesh, None where the Bézier construction
        refuses it (a face collapsed to zero area)."""
        try:
            return smooth_mesh(moved_control, t, level, tolerance, check=False,
                               spacing=spacing, repair=False)
        except ValueError:
            return None

    for round_, (rings, steps) in enumerate(REPAIR_SCHEDULE, start=1):
        tv, tt = current[0].vertices, current[0].triangles
        corners = tv[tt[np.unique(current[1].intersecting_pairs.ravel())].ravel()]
        region = grow_faces(region | crossing_faces(x, t, corners), t, rings)
        if round_ > 1 and region.mean() > REPAIR_SHARE:
            break
        moved_x, moved = membrane(x, t, region, steps)
        if len(moved) == 0:
            break
        candidate = rebuilt(moved_x)
        if candidate is None:   # the membrane collapsed faces to zero area: half of the move
            moved_x = x + 0.5 * (moved_x - x)
            candidate = rebuilt(moved_x)
            if candidate is None:
                continue
        rep, sec = _checked(candidate.vertices, candidate.triangles)
        shift = float(np.linalg.norm(moved_x[moved] - x[moved], axis=1).max())
        figures = {"pairs_before": int(before), "rounds": round_,
                   "faces": int(region.sum()), "vertices_moved": int(len(moved)),
                   "steps": steps, "share": 1.0,
                   "largest_move": shift,
                   "largest_move_spacings": (shift / spacing if spacing else None)}
        current = candidate, rep
        if len(rep.intersecting_pairs) < len(best[1].intersecting_pairs):
            best = (candidate, rep, sec, figures)
        if not rep.self_intersecting:   # the least share of the move that still untangles
            for share in REPAIR_SHARES:
                candidate = rebuilt(x + share * (moved_x - x))
                if candidate is None:
                    continue
                rep, sec = _checked(candidate.vertices, candidate.triangles)
                if not rep.self_intersecting:
                    best = (candidate, rep, sec,
                            {**figures, "share": share, "largest_move": share * shift,
                             "largest_move_spacings": (share * shift / spacing
                                                       if spacing else None)})
                    break
            break
    smoothed, report, seconds, figures = best
    if figures is not None:
        log.info("smooth: the surface crossed itself at %d triangle pairs: %d control faces "
                 "around them relaxed (%d vertices moved, at most %.3g): %d pairs left",
                 before, figures["faces"], figures["vertices_moved"], figures["largest_move"],
                 len(report.intersecting_pairs))
    else:
        figures = {"pairs_before": int(before), "rounds": 0, "faces": 0, "vertices_moved": 0,
                   "largest_move": 0.0, "largest_move_spacings": 0.0}
    return smoothed, report, seconds, figures


def smooth_to_files(vertices, triangles, out, level: int | str | None = None,
                    source: str = "control mesh", tolerance: float | None = None,
                    spacing: float | None = None) -> dict:
    """:func:`smooth_mesh`, then write ``out`` and ``out.npz`` (the control net).

    Parameters
    ----------
    vertices : (V, 3) float64
    triangles : (F, 3) int64
    out : path-like
        Mesh file (suffix one of ``pipeline.export.EXPORT_SUFFIXES``); the
        control net goes to ``out`` with suffix ``.npz``.  Both appear
        together or not at all.
    level : int, "auto" or "adaptive", optional
        Tessellation level (default: the pipeline's ``smooth.level`` when an integer);
        ``"auto"`` and ``"adaptive"`` need ``tolerance`` (:func:`smooth_mesh`).
    source : str
        Name of the input used in error messages (e.g. its path).
    tolerance : float, optional
        Chord tolerance of ``"auto"`` / ``"adaptive"``, scene units.
    spacing : float, optional
        The data's point spacing (:func:`smooth_mesh`).

    Returns
    -------
    dict
        :meth:`Smoothed.info` plus the ``mesh`` and ``control_net`` paths.

    Raises
    ------
    InputError
        Bad output name or level, or a control mesh the construction rejects
        (non-manifold, unoriented, bordered, degenerate).
    """
    from pipeline.export import EXPORT_SUFFIXES, export_surface
    from surface import bezier

    out = Path(out)
    level = default_level() if level is None else level
    if out.suffix.lower() not in EXPORT_SUFFIXES:
        raise InputError(f"{out}: cannot write mesh format {out.suffix!r} "
                         f"(choose one of {', '.join(EXPORT_SUFFIXES)})")
    if level in ("auto", "adaptive"):
        if tolerance is None or not tolerance > 0:
            raise InputError(f"level {level!r} needs a chord tolerance > 0")
    elif not 0 <= int(level) <= 8:
        raise InputError(f"--level must be in 0..8, got {level}")
    else:
        level = int(level)
    from pipeline.limits import LimitError

    try:
        smoothed = smooth_mesh(vertices, triangles, level, tolerance, spacing=spacing)
    except LimitError:
        raise  # the request, not the mesh
    except ValueError as exc:
        raise InputError(f"{source}: cannot build the Bezier surface: {exc}") from exc
    surface = smoothed.surface
    mesh_out, net_out = export_surface(out, smoothed.vertices, smoothed.triangles,
                                       smoothed.normals, surface.control_points,
                                       bezier.index_table(), surface.source_face,
                                       surface.domain_mesh)
    return {**smoothed.info(), "mesh": mesh_out, "control_net": net_out}
