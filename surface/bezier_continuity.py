"""The G1 report of a Bézier surface: normal angles across the patches' shared edges.

:func:`edge_continuity` samples every interior edge from both sides and reports the
largest angle between the two patches' normals (0 for tangent-plane continuity up to
rounding) and the largest gap between their positions; :func:`corner_normals` gives each
patch's normals at its three corners.  The patch algebra is :mod:`surface.bezier_patch`.
"""

from __future__ import annotations

import numba
import numpy as np

from surface.bezier_patch import (
    DEGREE,
    _bernstein,
    _check_control_points,
    _normals,
    _points_and_derivatives_basis,
)
from surface.bezier_tessellation import _edge_ids
from surface.validate import TOL, check_shape


# ----------------------------------------------------------------------------- continuity report
def _edge_pairs(tris: np.ndarray):
    """Pairs of half-edges ``(3f + c, 3g + c')`` sharing an undirected edge."""
    edge_id, n_edges, _ = _edge_ids(tris)
    flat = edge_id.ravel()
    order = np.argsort(flat, kind="stable")
    counts = np.bincount(flat, minlength=n_edges)
    if np.any(counts > 2):
        raise ValueError("triangles has non-manifold edges (shared by more than 2 triangles)")
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    interior = counts == 2
    return order[starts[interior]], order[starts[interior] + 1]


def edge_continuity(control_points, triangles, samples: int = 9):
    """Largest position gap and normal angle across every interior patch edge.

    Parameters
    ----------
    control_points : (P, 28, 3) array_like
    triangles : (P, 3) int array_like
        Domain triangles of the patches.
    samples : int
        Points per edge, uniformly in ``t = 0 .. 1`` (ends included).

    Returns
    -------
    gap : float
        Largest ``|P_f(t) - P_g(t)|`` over all shared edges and samples
        (scene units).
    angle : float
        Largest ``atan2(|n_f x n_g|, n_f . n_g)`` (radians).

    Notes
    -----
    On the edge from corner ``c`` to ``c + 1`` a patch's point is the degree-6 curve of
    its 7 boundary control points and its derivatives ``P_u``, ``P_v`` involve only the
    boundary row and the row next to it (13 points), so one numba kernel evaluates every
    edge sample from those columns of the Bernstein rows (no ``(P, 28, 3)`` gathers).
    """
    cp = _check_control_points(control_points)
    tris = check_shape(triangles, "(P, 3)", "triangles", dtype=np.int64)
    h1, h2 = _edge_pairs(tris)
    if len(h1) == 0:
        return 0.0, 0.0
    t = np.linspace(0.0, 1.0, int(samples))
    cols, vals = _edge_bases(t)
    gap, angle = _edge_continuity_kernel(cp, h1, h2, cols, vals, TOL.zero)
    return float(gap.max()), float(angle.max())


def _edge_bases(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sparse Bernstein rows of the edge samples: ``cols, vals (2, 3, 3S, 13)``.

    ``[side, c]`` is the half-edge from corner ``c`` at parameter ``t`` (side 0) or
    ``1 - t`` (side 1, the twin runs the other way); rows ``0..S-1`` give the points,
    ``S..2S-1`` ``P_u``, ``2S..3S-1`` ``P_v`` (:func:`_points_and_derivatives_basis`),
    each as at most 13 (column, weight) pairs (unused slots: column 0, weight 0).
    """
    n = len(t)
    cols = np.zeros((2, 3, 3 * n, 13), dtype=np.int64)
    vals = np.zeros((2, 3, 3 * n, 13))
    for side, along in enumerate((t, 1.0 - t)):
        for c in range(3):
            bary = np.zeros((n, 3))
            bary[:, c] = 1.0 - along
            bary[:, (c + 1) % 3] = along
            basis = _points_and_derivatives_basis(bary)  # (3S, 28)
            # the columns a sample on this edge can use: the boundary row and the next
            # row (exact zeros elsewhere, since the third barycentric is 0)
            for row in range(3 * n):
                used = np.flatnonzero(basis[row])
                if len(used) > 13:
                    raise AssertionError("an edge sample uses more than two rows of the net")
                cols[side, c, row, :len(used)] = used
                vals[side, c, row, :len(used)] = basis[row, used]
    return cols, vals


@numba.njit(parallel=True, nogil=True, cache=True)
def _edge_continuity_kernel(cp, h1, h2, cols, vals, zero):  # pragma: no cover
    """Per interior edge, the largest gap and normal angle over its samples, ``(E,)`` each.

    ``cp (P, 28, 3)``; ``h1, h2 (E,)`` the two half-edges ``3f + c`` of each edge;
    ``cols, vals`` from :func:`_edge_bases`.  Normals are ``P_u x P_v`` with the length
    floored at ``zero`` (:func:`_unit`).
    """
    n_edges = len(h1)
    n = cols.shape[2] // 3
    width = cols.shape[3]
    gap = np.zeros(n_edges)
    angle = np.zeros(n_edges)
    for e in numba.prange(n_edges):
        f1, c1 = h1[e] // 3, h1[e] % 3
        f2, c2 = h2[e] // 3, h2[e] % 3
        worst_gap = 0.0
        worst_angle = 0.0
        out = np.empty((2, 3, 3))  # side, (point, P_u, P_v), xyz
        normal = np.empty((2, 3))
        for s in range(n):
            out[:] = 0.0
            for side in range(2):
                f = f1 if side == 0 else f2
                c = c1 if side == 0 else c2
                for kind in range(3):
                    row = kind * n + s
                    for k in range(width):
                        w = vals[side, c, row, k]
                        if w != 0.0:
                            col = cols[side, c, row, k]
                            for d in range(3):
                                out[side, kind, d] += w * cp[f, col, d]
            dx = out[0, 0, 0] - out[1, 0, 0]
            dy = out[0, 0, 1] - out[1, 0, 1]
            dz = out[0, 0, 2] - out[1, 0, 2]
            worst_gap = max(worst_gap, np.sqrt(dx * dx + dy * dy + dz * dz))
            for side in range(2):
                ux, uy, uz = out[side, 1, 0], out[side, 1, 1], out[side, 1, 2]
                vx, vy, vz = out[side, 2, 0], out[side, 2, 1], out[side, 2, 2]
                nx = uy * vz - uz * vy
                ny = uz * vx - ux * vz
                nz = ux * vy - uy * vx
                length = max(np.sqrt(nx * nx + ny * ny + nz * nz), zero)
                normal[side, 0] = nx / length
                normal[side, 1] = ny / length
                normal[side, 2] = nz / length
            ax, ay, az = normal[0, 0], normal[0, 1], normal[0, 2]
            bx, by, bz = normal[1, 0], normal[1, 1], normal[1, 2]
            cx = ay * bz - az * by
            cy = az * bx - ax * bz
            cz = ax * by - ay * bx
            dot = ax * bx + ay * by + az * bz
            worst_angle = max(worst_angle, np.arctan2(np.sqrt(cx * cx + cy * cy + cz * cz),
                                                      dot))
        gap[e] = worst_gap
        angle[e] = worst_angle
    return gap, angle


def _edge_samples(cp: np.ndarray, half_edges: np.ndarray, t: np.ndarray):
    """Points and normals on half-edge ``3f + c`` at parameter t from corner c
    (the dense reference of :func:`_edge_continuity_kernel`, for small inputs)."""
    face, corner = half_edges // 3, half_edges % 3
    pts = np.empty((len(face), len(t), 3))
    nrm = np.empty_like(pts)
    for c in range(3):  # three corner cases, vectorised over edges
        sel = corner == c
        bary = np.zeros((len(t), 3))
        bary[:, c] = 1.0 - t
        bary[:, (c + 1) % 3] = t
        pts[sel] = np.einsum("sn,pnd->psd", _bernstein(bary, DEGREE), cp[face[sel]])
        nrm[sel] = _normals(cp[face[sel]], bary)
    return pts, nrm


def corner_normals(control_points) -> np.ndarray:
    """Unit normals of every patch at its three corners, ``(P, 3, 3)``."""
    cp = _check_control_points(control_points)
    return _normals(cp, np.eye(3))
