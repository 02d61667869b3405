r"""Local repair of a control mesh whose smooth surface crosses itself.

Loop's patches lie near their control triangles, so where the G1 surface over a control
mesh crosses itself the control mesh is tangled there: a fan of slivers around one vertex
(two rings of a stitched strip parametrised differently), a cap's flat fan folded over
itself, two sheets of a thin part pushed through each other by the interpolating
correction.  The repair touches only that neighbourhood:

1. :func:`crossing_faces` -- the control faces under the crossing facets: each facet
   vertex of a crossing pair is given its nearest control vertex (the surface passes
   through or near the control vertices, within a ring of its own patch), and the faces
   around those vertices are the region;
2. :func:`grow_faces` -- the region grown by whole rings of faces, so that it has an
   interior to move;
3. :func:`membrane` -- the region's interior vertices placed at the discrete harmonic
   (uniform-Laplacian) membrane spanned by its fixed border: each interior vertex the mean
   of its neighbours, one sparse solve.  With uniform weights this is Tutte's barycentric
   embedding: on a region that is a disk with a convex border (a flat cap) no face is
   folded, and on any region every moved vertex is a convex combination of the border's,
   so the fill stays within the border's convex hull (the flattest fill the border allows,
   never a dome away from it).  The connectivity is unchanged: components, genus,
   manifoldness and orientation are kept.

The caller (``pipeline.bezier_surface.smooth_mesh``) rebuilds the surface over the repaired
control mesh, checks it again, grows the region by one ring and repeats a few rounds,
keeping the surface with the fewest crossings, and reports what is left in one line.

Boundary: vertices ``(V, 3) float64``, triangles ``(F, 3) int64``; masks ``(F,) bool``.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.sparse.linalg import spsolve
from scipy.spatial import cKDTree

from surface.validate import check_shape

__all__ = ["crossing_faces", "grow_faces", "membrane"]


def _mesh(vertices, triangles) -> tuple[np.ndarray, np.ndarray]:
    v = check_shape(vertices, "(V, 3)", "vertices", np.float64)
    t = check_shape(triangles, "(F, 3)", "triangles", np.int64)
    if len(t) and (t.min() < 0 or t.max() >= len(v)):
        raise ValueError("triangles index vertices out of range")
    return v, t


def crossing_faces(control, triangles, points) -> np.ndarray:
    """Control faces around the control vertices nearest to ``points``, ``(F,) bool``.

    ``points`` ``(K, 3)``: the corners of the surface's crossing facets.
    """
    x, t = _mesh(control, triangles)
    faces = np.zeros(len(t), dtype=bool)
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(p) == 0 or len(t) == 0:
        return faces
    _, nearest = cKDTree(x).query(p)
    near = np.zeros(len(x), dtype=bool)
    near[nearest] = True
    return near[t].any(axis=1)


def grow_faces(faces, triangles, rings: int = 1) -> np.ndarray:
    """``faces`` and ``rings`` rings of their neighbours (faces sharing a vertex)."""
    t = np.asarray(triangles, dtype=np.int64)
    region = np.asarray(faces, dtype=bool).copy()
    count = int(t.max()) + 1 if len(t) else 0
    for _ in range(int(rings)):
        near = np.zeros(count, dtype=bool)
        near[t[region].ravel()] = True
        region = near[t].any(axis=1)
    return region


def membrane(vertices, triangles, region, steps: int | str | None = None
             ) -> tuple[np.ndarray, np.ndarray]:
    """The region's interior vertices moved to the uniform-Laplacian membrane of its border.

    Parameters
    ----------
    vertices : (V, 3) float64
    triangles : (F, 3) int64
    region : (F,) bool
        Faces to relax.  Its interior vertices (every face around them in the region, not
        on a border of the mesh) move; the vertices on its border, and every other vertex,
        stay.  An interior part with no
        border (a whole closed component) stays as it is.
    steps : int or "biharmonic", optional
        Jacobi steps towards the membrane (each interior vertex to its neighbours' mean,
        all at once) instead of the membrane itself: a smaller move, each step spreading
        one ring farther from the tangle.  ``"biharmonic"``: the thin-plate fill instead
        (the squared uniform Laplacian zero at the moving vertices, every other vertex
        fixed): it continues the surrounding surface's slope into the region, so a curved
        region (an object's tip) is filled curved rather than flattened; no fold-free
        guarantee.

    Returns
    -------
    (V, 3) float64, (M,) int64
        The new vertices and the indices of those that moved.
    """
    v, t = _mesh(vertices, triangles)
    region = np.asarray(region, dtype=bool)
    if region.shape != (len(t),):
        raise ValueError(f"region must be ({len(t)},) bool, got {region.shape}")
    outside = np.zeros(len(v), dtype=bool)
    outside[t[~region].ravel()] = True
    inside = np.zeros(len(v), dtype=bool)
    inside[t[region].ravel()] = True
    edges = np.sort(np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]]), axis=1)
    unique, counts = np.unique(edges, axis=0, return_counts=True)
    outside[unique[counts == 1].ravel()] = True     # the mesh's own border stays too
    interior = inside & ~outside
    out = v.copy()
    if not interior.any():
        return out, np.zeros(0, dtype=np.int64)
    edges = unique       # every edge once: the thin-plate fill needs the neighbours' rows
    n = len(v)
    adjacency = sp.coo_matrix((np.ones(2 * len(edges)), (np.r_[edges[:, 0], edges[:, 1]],
                                                       np.r_[edges[:, 1], edges[:, 0]])),
                              shape=(n, n)).tocsr()
    adjacency.data[:] = 1.0
    moving = np.flatnonzero(interior)
    # interior parts that touch no fixed vertex have no membrane: they stay
    inner = adjacency[moving][:, moving]
    _, labels = connected_components(inner, directed=False)
    anchored = np.asarray(adjacency[moving][:, ~interior].sum(axis=1)).ravel() > 0
    has_anchor = np.zeros(labels.max() + 1, dtype=bool)
    has_anchor[labels[anchored]] = True
    moving = moving[has_anchor[labels]]
    if len(moving) == 0:
        return out, moving
    fixed = np.ones(n, dtype=bool)
    fixed[moving] = False
    a_mm = adjacency[moving][:, moving]
    degree = np.asarray(adjacency[moving].sum(axis=1)).ravel()
    rhs = adjacency[moving][:, np.flatnonzero(fixed)] @ v[fixed]
    if steps is None:
        laplacian = (sp.diags(degree) - a_mm).tocsc()
        solution = np.asarray(spsolve(laplacian, rhs)).reshape(len(moving), 3)
    elif steps == "biharmonic":
        # L = D - A over the rows that reach a moving vertex (theirs and their neighbours')
        full = (sp.diags(np.asarray(adjacency.sum(axis=1)).ravel()) - adjacency).tocsr()
        square = (full[moving] @ full).tocsc()
        rhs2 = -(square[:, np.flatnonzero(fixed)] @ v[fixed])
        solution = np.asarray(spsolve(square[:, moving].tocsc(), rhs2)).reshape(len(moving), 3)
    else:
        solution = v[moving].copy()
        for _ in range(int(steps)):
            solution = (a_mm @ solution + rhs) / degree[:, None]
    if not np.all(np.isfinite(solution)):
        return v.copy(), np.zeros(0, dtype=np.int64)
    out[moving] = solution
    return out, moving
