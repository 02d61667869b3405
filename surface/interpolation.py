r"""The control mesh whose Loop surface passes through a mesh's vertices: rims kept, creases too.

Loop's limit surface over a control mesh lies inside it, by about ``h² (κ1 + κ2) / 8`` for edge
``h`` [1, 2]; the control points whose limit points are the mesh's vertices
(``surface.fitting.interpolating_control_mesh``) give a surface through them instead
(:func:`interpolating_control`).  The vertices on a sharp edge (:func:`rim_vertices`: the ends'
rims, held by support rings one noise width away) are kept as they are; the object's convex creases
between its end sections (:func:`crease_vertices`) are interpolated; where the correction folds the
surface, the folding vertices move by a half, then a quarter of it, then not at all
(:data:`UNFOLD_SHARES`).  Vertices ``(V, 3) float64`` in scene units, triangles ``(F, 3) int64``.
Why each rule, with the figures that decided it: ``docs/decisions/sizing.md``,
``docs/decisions/smooth-folds.md``.

References
----------
.. [1] C. Loop, "Smooth subdivision surfaces based on triangles", M.S. thesis, Utah (1987).
.. [2] H. Hoppe et al., "Piecewise smooth surface reconstruction", SIGGRAPH 1994.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.spatial import cKDTree

from surface._blas import one_blas_thread
from surface.fitting import (
    convex_creases,
    flat_vertices,
    folded_faces,
    grow_vertices,
    interpolating_control_mesh,
    sharp_vertices,
    surface_folds,
)
from surface.section_chains import section_heights
from surface.validity import check_solid

__all__ = ["FOLD_LEVEL", "INTERPOLATE_CREASES", "JUDGE_FOLD_LEVEL", "crease_band",
           "crease_vertices", "interpolating_control", "mesh_creases", "off_rim_vertices",
           "rim_vertices"]


#: Interpolate the object's convex creases away from its ends (:func:`crease_vertices`,
#: :func:`interpolating_control`); False keeps every sharp vertex as it is (the benchmark
#: ``benchmarks/creases.py`` compares the two).
INTERPOLATE_CREASES = True


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


@one_blas_thread
def interpolating_control(vertices: np.ndarray, triangles: np.ndarray,
                          creases: np.ndarray | None = None,
                          fold_level: int | None = None) -> np.ndarray:
    """Control vertices of the surface through the mesh's vertices, sharp edges kept (but
    ``creases``).

    :func:`surface.fitting.interpolating_control_mesh` with the vertices on an edge
    sharper than 30° (the stitch's support-ring threshold) kept as they are
    (:func:`surface.fitting.sharp_vertices`, ``rings=0``): interpolating a rim ring and its
    support ring one noise width away overshoots the edge; with the caps' guard rings
    (``surface.stitch.CAP_GUARD_RINGS``) keeping the rim vertices alone is enough.  A mesh
    with borders gets its own vertices back.  ``creases``: vertices on the object's convex
    creases inside its end sections (:func:`crease_vertices`), interpolated too (kept, a
    crease's vertices round it inwards).

    Folds: where the correction turns a control face over or makes control faces cross
    that the mesh does not (:func:`surface.fitting.folded_faces`: signs, no tolerance), and
    the surface's patches there cross or turn over (:func:`surface.fitting.surface_folds`),
    that face's vertices move by half, then a quarter of their correction
    (:data:`UNFOLD_SHARES`), then none, the system solved again each round (at most
    :data:`UNFOLD_ROUNDS` solves); a ``creases`` vertex only where the face has no other
    vertex to keep.  The figures behind each rule: ``docs/decisions/sizing.md``,
    *Interpolating control and creases*, and ``docs/decisions/smooth-folds.md``.
    ``fold_level``: the tessellation level the folds are looked for at (default
    :data:`FOLD_LEVEL`; the sizing judges its candidates at :data:`JUDGE_FOLD_LEVEL`).
    """

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
            if folded.any():   # of the folded control faces, those the surface folds over
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
    return crease_vertices(vertices, triangles, axis, crease_band(section_heights(rings, axis)))


def crease_vertices(vertices: np.ndarray, triangles: np.ndarray, axis, inner: tuple,
                    dense: np.ndarray | None = None, reach: float = 0.0) -> np.ndarray | None:
    """The vertices on the object's convex creases, ``(V,) bool`` (None without any):
    :func:`surface.fitting.convex_creases` between the heights ``inner = (lo, hi)``
    along ``axis`` (``surface.sizing.size_control_mesh``: the second and the last but one section,
    half a spacing beyond) -- the ends' rims, held by support rings a noise width away,
    stay as they are -- and, with ``dense`` crease points (a candidate judged against its dense
    mesh), within ``reach`` of one of them: a crease the dense mesh has too, not the
    coarse sampling of a smooth bend (an elliptic section's tips at 24-34 ring points
    are "sharp" at 30°; at the dense mesh's resolution they are not).

    Why: kept, the creases round the object's edges inwards
    (``docs/decisions/sizing.md``, *Interpolating control and creases*).
    """
    if not INTERPOLATE_CREASES:
        return None
    vertices = np.asarray(vertices, dtype=np.float64)
    height = vertices @ np.asarray(axis, dtype=np.float64)
    mask = convex_creases(vertices, triangles) & (height > inner[0]) & (height < inner[1])
    if dense is not None:
        if len(dense) == 0:
            return None

        near = np.zeros(len(vertices), dtype=bool)
        if mask.any():
            near[mask] = cKDTree(dense).query(vertices[mask], distance_upper_bound=reach)[0] \
                <= reach
        mask = near
    return mask if mask.any() else None


def rim_vertices(vertices, triangles) -> np.ndarray | None:
    """Vertices on a sharp edge (``surface.fitting.sharp_vertices``), None when the mesh
    has borders."""
    try:
        return sharp_vertices(vertices, triangles, rings=0)
    except ValueError:
        return None


def off_rim_vertices(vertices, triangles, sharp: np.ndarray | None = None) -> np.ndarray:
    """Vertices neither on nor next to a sharp edge (all of them if the mesh has borders);
    ``sharp``: :func:`rim_vertices` of the mesh, if known."""
    sharp = rim_vertices(vertices, triangles) if sharp is None else sharp
    if sharp is None:
        return np.ones(len(vertices), dtype=bool)
    return ~grow_vertices(sharp, triangles, 1)
