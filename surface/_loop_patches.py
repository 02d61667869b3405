"""Mesh topology, Loop subdivision and the patch construction behind ``bezier.control_net``.

Private helpers of :mod:`surface.bezier` (see its module docstring for the
construction, after C. Loop, "Smooth spline surfaces over irregular meshes",
SIGGRAPH 1994).  Half-edge ``h = 3 f + c`` runs from ``tri[f, c]`` to
``tri[f, (c + 1) % 3]``; ``twin[h]`` is the opposite half-edge; rotating an
outgoing half-edge counter-clockwise about its origin is
``twin[prev(h)]``.  Every kernel is vectorised over faces or vertices; the
only Python loops run over ring positions (<= max valence) and valence classes.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from dataclasses import dataclass
from functools import cache, cached_property
from pathlib import Path

import numba
import numpy as np
import scipy.linalg

from surface.bezier_patch import _blossom_matrix, _empty_pages, bernstein_matrix, elevate
from surface.loop_weights import limit_weight, loop_beta
from surface.validate import TOL

DEGREE = 6


# ----------------------------------------------------------------------------- topology
@dataclass(frozen=True)
class HalfEdges:
    """Half-edge view of an oriented 2-manifold triangle mesh (``twin = -1`` on borders)."""

    triangles: np.ndarray  # (F, 3) int64
    twin: np.ndarray  # (3F,) int64, -1 for a border half-edge
    valence: np.ndarray  # (V,) int64: triangles around the vertex (0 if unused)
    first_out: np.ndarray  # (V,) one outgoing half-edge (the border one on a border), -1 if unused
    on_border: np.ndarray  # (V,) bool

    @property
    def origin(self) -> np.ndarray:
        return self.triangles.ravel()

    @cached_property
    def dest(self) -> np.ndarray:
        # computed once (read-only): the patch construction reads it a dozen times
        dest = self.triangles[:, [1, 2, 0]].ravel()
        dest.flags.writeable = False
        return dest


def prev_half_edge(h: np.ndarray) -> np.ndarray:
    return 3 * (h // 3) + (h + 2) % 3


def next_half_edge(h: np.ndarray) -> np.ndarray:
    return 3 * (h // 3) + (h + 1) % 3


def build_half_edges(n_vertices: int, triangles: np.ndarray,
                     allow_border: bool = False) -> HalfEdges:
    """Half-edges of an oriented manifold mesh, or ``ValueError`` naming the defect."""
    tris = triangles
    if tris.size and (tris.min() < 0 or tris.max() >= n_vertices):
        raise ValueError(f"triangles index vertices outside 0..{n_vertices - 1} "
                         f"(found {tris.min()}..{tris.max()})")
    repeated = (tris[:, 0] == tris[:, 1]) | (tris[:, 1] == tris[:, 2]) | (tris[:, 2] == tris[:, 0])
    if np.any(repeated):
        raise ValueError(f"triangles has {int(repeated.sum())} degenerate triangles with a "
                         f"repeated vertex (first: face {int(np.argmax(repeated))})")
    origin = tris.ravel()
    dest = tris[:, [1, 2, 0]].ravel()
    key = origin * n_vertices + dest
    order = np.argsort(key, kind="stable")
    sorted_key = key[order]
    dup = sorted_key[1:] == sorted_key[:-1]
    if np.any(dup):
        undirected = np.minimum(origin, dest) * n_vertices + np.maximum(origin, dest)
        _, counts = np.unique(undirected, return_counts=True)
        if np.any(counts > 2):
            raise ValueError(f"triangles is non-manifold: {int((counts > 2).sum())} edges are "
                             "shared by more than two triangles")
        a = int(sorted_key[1:][dup][0] // n_vertices)
        b = int(sorted_key[1:][dup][0] % n_vertices)
        raise ValueError(f"triangles is not consistently oriented: edge ({a}, {b}) is "
                         "traversed twice in the same direction")
    twin_key = dest * n_vertices + origin
    pos = np.minimum(np.searchsorted(sorted_key, twin_key), len(key) - 1)
    found = sorted_key[pos] == twin_key
    if not allow_border and not np.all(found):
        raise ValueError(f"triangles has {int((~found).sum())} border edges; this step needs "
                         "a closed mesh")
    twin = np.where(found, order[pos], -1)
    mesh = _with_vertex_tables(n_vertices, tris, twin)
    _check_vertex_manifold(mesh)
    return mesh


def _with_vertex_tables(n_vertices: int, tris: np.ndarray, twin: np.ndarray) -> HalfEdges:
    """The per-vertex tables of :class:`HalfEdges` from faces and twins (border check)."""
    origin = tris.ravel()
    border = twin < 0
    out_count = np.bincount(origin[border], minlength=n_vertices)
    in_count = np.bincount(tris[:, [1, 2, 0]].ravel()[border], minlength=n_vertices)
    if np.any(out_count > 1) or np.any(in_count > 1):
        bad = np.flatnonzero((out_count > 1) | (in_count > 1))
        raise ValueError(f"triangles is non-manifold at {len(bad)} border vertices "
                         f"(first: vertex {int(bad[0])} lies on the border twice)")
    valence = np.bincount(origin, minlength=n_vertices)
    first_out = np.full(n_vertices, -1, dtype=np.int64)
    first_out[origin[::-1]] = np.arange(len(origin))[::-1]
    first_out[origin[border]] = np.flatnonzero(border)
    return HalfEdges(tris, twin, valence, first_out, out_count > 0)


def refined_half_edges(coarse: HalfEdges, n_vertices: int, children: np.ndarray) -> HalfEdges:
    """Half-edges of :func:`loop_subdivide`'s refined mesh, read off the coarse ones.

    Equal to ``build_half_edges(n_vertices, children, allow_border=True)`` without its
    sort: coarse half-edge ``3f + c`` is split into ``3 (4f + c) + c`` (from its origin)
    and ``3 (4f + c + 1) + c`` (to its end), so the halves of a coarse twin pair are
    twins crosswise; the three inner edges of face f pair the corner children with the
    centre child ``4f + 3``.  The refinement of a manifold mesh is manifold, so the
    fan check is not repeated.
    """
    n_faces = len(coarse.triangles)
    face = np.arange(n_faces)[:, None]
    corner = np.arange(3)[None, :]
    first = 3 * (4 * face + corner) + corner  # (F, 3)
    second = 3 * (4 * face + (corner + 1) % 3) + corner
    coarse_twin = coarse.twin.reshape(n_faces, 3)
    other, other_corner = coarse_twin // 3, coarse_twin % 3
    border = coarse_twin < 0
    twin = np.empty(12 * n_faces, dtype=np.int64)
    twin[first] = np.where(border, -1, 3 * (4 * other + (other_corner + 1) % 3) + other_corner)
    twin[second] = np.where(border, -1, 3 * (4 * other + other_corner) + other_corner)
    base = 12 * face.ravel()
    for child, local in ((0, 1), (1, 2), (2, 0)):  # inner edge <-> centre child, same slot
        twin[base + 3 * child + local] = base + 9 + local
        twin[base + 9 + local] = base + 3 * child + local
    return _with_vertex_tables(n_vertices, children, twin)


def rotate_ccw(mesh: HalfEdges, h: np.ndarray) -> np.ndarray:
    """Next outgoing half-edge counter-clockwise about the same origin."""
    return mesh.twin[prev_half_edge(h)]


def ring_half_edges(mesh: HalfEdges, start: np.ndarray, steps: int) -> np.ndarray:
    """``(len(start), steps)`` outgoing half-edges, counter-clockwise from ``start``."""
    out = np.empty((len(start), steps), dtype=np.int64)
    h = np.asarray(start, dtype=np.int64)
    for k in range(steps):
        out[:, k] = h
        h = rotate_ccw(mesh, h)
    return out


def _check_vertex_manifold(mesh: HalfEdges) -> None:
    """Each vertex's triangles must form one fan (no bow-ties).

    Walks counter-clockwise from ``first_out``: around an interior vertex
    until it comes back, from a border vertex's border half-edge until the
    walk leaves the mesh; either way it must meet every triangle at the vertex.
    """
    used = np.flatnonzero(mesh.valence > 0)
    h = mesh.first_out[used]
    start = h.copy()
    steps = np.zeros(len(used), dtype=np.int64)
    open_ = np.ones(len(used), dtype=bool)
    for _ in range(int(mesh.valence.max(initial=0))):
        step = rotate_ccw(mesh, np.maximum(h, 0))
        h = np.where(open_, step, h)
        steps += open_
        open_ &= (h != start) & (h >= 0)
    bad = steps != mesh.valence[used]
    if np.any(bad):
        raise ValueError(f"triangles is non-manifold at {int(bad.sum())} vertices "
                         f"(first: vertex {int(used[bad][0])} joins several fans)")


# ----------------------------------------------------------------------------- Loop subdivision
def limit_positions(mesh: HalfEdges, points: np.ndarray) -> np.ndarray:
    """Loop limit positions ``(1 - n chi) v + chi sum(w)``, ``chi = 1 / (3 / (8 beta) + n)``.

    ``points`` may have any trailing width (``(V, D)``).
    """
    n = np.maximum(mesh.valence, 1)
    chi = limit_weight(n)
    ring_sum = _ring_sum(mesh, points)
    return (1.0 - n * chi)[:, None] * points + chi[:, None] * ring_sum


def _ring_sum(mesh: HalfEdges, points: np.ndarray) -> np.ndarray:
    """``(V, D)`` sum of each vertex's neighbours over its outgoing half-edges.

    One ``bincount`` per column adds in half-edge order, as ``np.add.at`` would
    (the same sums bit for bit), without its per-element overhead.
    """
    origin, dest = mesh.origin, mesh.dest
    n_vertices = len(points)
    out = np.empty(points.shape)
    for d in range(points.shape[1]):
        out[:, d] = np.bincount(origin, weights=points[dest, d], minlength=n_vertices)
    return out


def loop_subdivide(mesh: HalfEdges, points: np.ndarray):
    """One step of Loop subdivision (with Loop's boundary rules on borders).

    Interior: edge points ``3/8 (a + b) + 1/8 (c + d)``, vertex points
    ``(1 - n beta) v + beta sum(w)``.  Border: edge points ``(a + b) / 2`` and
    vertex points ``3/4 v + 1/8 (p + q)`` (the cubic B-spline of the border
    polygon).  Returns ``(points (V + E, D), triangles (4F, 3))``; new vertex
    ``V + e`` sits on undirected edge ``e``; children ``4f .. 4f + 3`` of face
    f are its corner triangles at ``tri[0], tri[1], tri[2]`` and the centre
    ``(m12, m20, m01)``.
    """
    tris = mesh.triangles
    n_vertices = len(points)
    h = np.arange(3 * len(tris))
    primary = (h < mesh.twin) | (mesh.twin < 0)
    edge_of = np.empty(len(h), dtype=np.int64)
    edge_of[primary] = np.arange(int(primary.sum()))
    paired = primary & (mesh.twin >= 0)
    edge_of[mesh.twin[paired]] = edge_of[paired]
    hp = h[primary]
    inner = mesh.twin[hp] >= 0
    opposite = tris.ravel()[prev_half_edge(hp)]
    opposite_twin = tris.ravel()[prev_half_edge(np.maximum(mesh.twin[hp], 0))]
    ends = points[mesh.origin[hp]] + points[mesh.dest[hp]]
    edge_points = np.where(inner[:, None],
                           (3.0 / 8.0) * ends + (1.0 / 8.0) * (points[opposite]
                                                               + points[opposite_twin]),
                           0.5 * ends)
    n = np.maximum(mesh.valence, 1)
    beta = loop_beta(n)
    ring_sum = _ring_sum(mesh, points)
    vertex_points = (1.0 - n * beta)[:, None] * points + beta[:, None] * ring_sum
    border = np.flatnonzero(mesh.twin < 0)
    if len(border):
        start, end = mesh.origin[border], mesh.dest[border]
        vertex_points[start] = 0.75 * points[start] + 0.125 * points[end]
        np.add.at(vertex_points, end, 0.125 * points[start])
    mid = n_vertices + edge_of.reshape(-1, 3)  # (F, 3): m01, m12, m20
    a, b, c = tris.T
    m01, m12, m20 = mid.T
    children = np.stack([
        np.stack([a, m01, m20], 1), np.stack([m01, b, m12], 1),
        np.stack([m20, m12, c], 1), np.stack([m12, m20, m01], 1)], axis=1).reshape(-1, 3)
    return np.concatenate([vertex_points, edge_points]), children


def add_ghost_layer(mesh: HalfEdges, points: np.ndarray):
    """Close every border vertex's fan with one ring of ghost triangles.

    The rule continues the regular grid (all weights affine):

    * border half-edge ``a -> b`` with opposite vertex c gets the ghost
      ``g = a + b - c`` (c reflected through the edge midpoint) and the
      triangle ``(b, a, g)``;
    * a border vertex a with k triangles, between the ghosts ``g_in`` of its
      incoming and ``g_out`` of its outgoing border edge, gets ``(a, g_in,
      g_out)`` if k >= 3; if k = 2 (neighbours b, c, p counter-clockwise) the
      extra ghost ``2a - c`` splits that triangle in two; if k = 1 the extra
      ghosts ``2a - b`` and ``2a - p`` split it in three -- on the regular
      grid these are exactly the missing grid neighbours, and a border vertex
      with k <= 3 ends up with valence 6.

    Returns the extended ``(points, triangles)``; the input faces keep their
    indices, the new border runs through the ghosts.
    """
    tris = mesh.triangles
    border = np.flatnonzero(mesh.twin < 0)
    a, b = mesh.origin[border], mesh.dest[border]
    c = tris.ravel()[prev_half_edge(border)]
    ghost = len(points) + np.arange(len(border))
    new_points = [points, points[a] + points[b] - points[c]]
    ghost_of_out = np.full(len(points), -1)
    ghost_of_in = np.full(len(points), -1)
    ghost_of_out[a] = ghost
    ghost_of_in[b] = ghost
    new_tris = [tris, np.stack([b, a, ghost], axis=1)]
    corner = a  # one per border vertex (each has one outgoing border half-edge)
    k = mesh.valence[corner]
    g_in, g_out = ghost_of_in[corner], ghost_of_out[corner]
    wide = k >= 3
    new_tris.append(np.stack([corner[wide], g_in[wide], g_out[wide]], axis=1))
    first = len(points) + len(border)
    two = np.flatnonzero(k == 2)
    middle = mesh.dest[rotate_ccw(mesh, mesh.first_out[corner[two]])]
    extra = first + np.arange(len(two))
    new_points.append(2.0 * points[corner[two]] - points[middle])
    new_tris += [np.stack([corner[two], g_in[two], extra], axis=1),
                 np.stack([corner[two], extra, g_out[two]], axis=1)]
    one = np.flatnonzero(k == 1)
    first += len(two)
    h_b = first + np.arange(len(one))
    h_p = first + len(one) + np.arange(len(one))
    out_edge = mesh.first_out[corner[one]]
    far_b, far_p = mesh.dest[out_edge], tris.ravel()[prev_half_edge(out_edge)]
    new_points += [2.0 * points[corner[one]] - points[far_b],
                   2.0 * points[corner[one]] - points[far_p]]
    new_tris += [np.stack([corner[one], g_in[one], h_b], axis=1),
                 np.stack([corner[one], h_b, h_p], axis=1),
                 np.stack([corner[one], h_p, g_out[one]], axis=1)]
    return np.concatenate(new_points), np.concatenate(new_tris)


#: Barycentric corners of the children of the midpoint split (Loop's order).
CHILD_CORNERS = np.array([
    [[1, 0, 0], [0.5, 0.5, 0], [0.5, 0, 0.5]],
    [[0.5, 0.5, 0], [0, 1, 0], [0, 0.5, 0.5]],
    [[0.5, 0, 0.5], [0, 0.5, 0.5], [0, 0, 1]],
    [[0, 0.5, 0.5], [0.5, 0, 0.5], [0.5, 0.5, 0]],
])


def subdivide_tracked(points: np.ndarray, triangles: np.ndarray, steps: int,
                      allow_border: bool = False):
    """``steps`` Loop steps, tracking where each new face lies in its root face.

    Returns ``(points, triangles, root_face (F',), corner_bary (F', 3, 3))``:
    corner ``c`` of face ``f'`` sits at barycentric ``corner_bary[f', c]`` of
    root face ``root_face[f']`` (of the input mesh).
    """
    root = np.arange(len(triangles))
    bary = np.broadcast_to(np.eye(3), (len(triangles), 3, 3)).copy()
    for _ in range(steps):
        mesh = build_half_edges(len(points), triangles, allow_border=allow_border)
        points, triangles = loop_subdivide(mesh, points)
        bary = np.einsum("cij,fjd->fcid", CHILD_CORNERS, bary).reshape(-1, 3, 3)
        root = np.repeat(root, 4)
    return points, triangles, root, bary


# ----------------------------------------------------------------------------- Bézier helpers
def _index_table(degree: int) -> np.ndarray:
    return np.array([(i, j, degree - i - j) for i in range(degree, -1, -1)
                     for j in range(degree - i, -1, -1)], dtype=np.int64)


def _control_index(multi: np.ndarray) -> np.ndarray:
    m = multi[..., 1] + multi[..., 2]
    return m * (m + 1) // 2 + multi[..., 2]


@cache
def corner_rotation(corner: int, degree: int = DEGREE) -> np.ndarray:
    """Index array ``q`` with ``net_rotated = net[..., q, :]``.

    ``net_rotated`` is the same patch with its corners relabelled to start at
    ``corner``: ``(tri[c], tri[c+1], tri[c+2])``.
    """
    rot = _index_table(degree)  # exponents on (t_c, t_c+1, t_c+2)
    face = np.empty_like(rot)
    for axis in range(3):
        face[:, (corner + axis) % 3] = rot[:, axis]
    return _control_index(face)


@cache
def bernstein_interpolation_inverse(degree: int) -> np.ndarray:
    """Inverse of the Bernstein matrix at the uniform grid ``(i, j, k) / degree``."""

    return np.linalg.inv(bernstein_matrix(_index_table(degree) / degree, degree))


# ----------------------------------------------------------------------------- box spline
def box_spline_stencil(mesh: HalfEdges, faces: np.ndarray) -> np.ndarray:
    """The 12 control vertices of each regular face, ``(len(faces), 12)``.

    Order: ``a, b, c``, then a's ring slots 2..5, b's ring slots 3..5, c's ring
    slots 3..4, each ring counter-clockwise starting at the next corner.
    """
    h = 3 * np.asarray(faces)[:, None] + np.arange(3)[None, :]  # a->b, b->c, c->a
    dest = mesh.dest
    rings = [dest[ring_half_edges(mesh, h[:, c], 6)] for c in range(3)]  # (n, 6) each
    tri = mesh.triangles[faces]
    cols = [tri[:, 0], tri[:, 1], tri[:, 2]]
    cols += [rings[0][:, s] for s in (2, 3, 4, 5)]
    cols += [rings[1][:, s] for s in (3, 4, 5)]
    cols += [rings[2][:, s] for s in (3, 4)]
    return np.stack(cols, axis=1)


#: Quartic Bézier net of the three-direction box spline over a regular triangle
#: (a, b, c), times 24, from its 12-point stencil in :func:`box_spline_stencil`
#: order (rows in quartic index order).  Re-derived from Loop subdivision by
#: :func:`derive_box_spline_quartic` (a test checks they agree).
BOX_SPLINE_QUARTIC = np.array([
    [12, 2, 2, 2, 2, 2, 2, 0, 0, 0, 0, 0],
    [12, 4, 3, 1, 0, 1, 3, 0, 0, 0, 0, 0],
    [12, 3, 4, 3, 1, 0, 1, 0, 0, 0, 0, 0],
    [8, 8, 4, 0, 0, 0, 4, 0, 0, 0, 0, 0],
    [10, 6, 6, 1, 0, 0, 1, 0, 0, 0, 0, 0],
    [8, 4, 8, 4, 0, 0, 0, 0, 0, 0, 0, 0],
    [4, 12, 3, 0, 0, 0, 3, 1, 0, 1, 0, 0],
    [6, 10, 6, 0, 0, 0, 1, 0, 0, 1, 0, 0],
    [6, 6, 10, 1, 0, 0, 0, 0, 0, 1, 0, 0],
    [4, 3, 12, 3, 0, 0, 0, 0, 0, 1, 0, 1],
    [2, 12, 2, 0, 0, 0, 2, 2, 2, 2, 0, 0],
    [3, 12, 4, 0, 0, 0, 1, 0, 1, 3, 0, 0],
    [4, 8, 8, 0, 0, 0, 0, 0, 0, 4, 0, 0],
    [3, 4, 12, 1, 0, 0, 0, 0, 0, 3, 1, 0],
    [2, 2, 12, 2, 0, 0, 0, 0, 0, 2, 2, 2],
]) / 24.0


def derive_box_spline_quartic() -> np.ndarray:
    """``(15, 12)`` map from a regular stencil to the quartic Bézier net.

    Derived, not typed in: on a periodic regular grid (a torus, every valence
    6) whose vertex "positions" are the unit vectors, two Loop steps followed
    by Loop's limit mask give the limit surface at the 15 points
    ``(i, j, k) / 4`` of one triangle; inverting the quartic Bernstein
    interpolation there yields the Bézier net as weights of the grid vertices.
    The weights outside the 12-point stencil vanish (checked), which is the
    locality of the quartic box spline.
    """
    size = 8
    ij = np.arange(size * size).reshape(size, size)
    q, r = np.meshgrid(np.arange(size), np.arange(size), indexing="ij")
    v00, v10 = ij[q, r], ij[(q + 1) % size, r]
    v01, v11 = ij[q, (r + 1) % size], ij[(q + 1) % size, (r + 1) % size]
    tris = np.concatenate([np.stack([v00, v10, v01], -1).reshape(-1, 3),
                           np.stack([v10, v11, v01], -1).reshape(-1, 3)])
    n_vertices = size * size
    face = 0  # (0,0), (1,0), (0,1)
    mesh = build_half_edges(n_vertices, tris)
    stencil = box_spline_stencil(mesh, np.array([face]))[0]
    points, sub_tris, root, bary = subdivide_tracked(np.eye(n_vertices), tris, 2)
    sub_mesh = build_half_edges(len(points), sub_tris)
    limit = limit_positions(sub_mesh, points)
    target = _index_table(4) / 4.0
    mine = np.flatnonzero(root == face)
    corner_b = bary[mine].reshape(-1, 3)
    corner_v = sub_tris[mine].reshape(-1)
    match = np.all(np.abs(corner_b[None, :, :] - target[:, None, :]) < 1e-12, axis=2)
    values = limit[corner_v[np.argmax(match, axis=1)]]  # (15, V)
    net = bernstein_interpolation_inverse(4) @ values
    outside = np.delete(net, stencil, axis=1)
    if np.abs(outside).max() > 1e-12:
        raise RuntimeError("box-spline stencil derivation is not local")
    matrix = net[:, stencil]
    matrix.flags.writeable = False
    return matrix


# ----------------------------------------------------------------------------- irregular vertices
#: Barycentric coordinates, in the neighbour's frame (w_{i+1}, w_i, x_i), of the
#: ring triangle's corners (v, w_i, w_{i+1}); x_i = w_i + w_{i+1} - v on the grid.
_NEIGHBOUR_TO_RING = np.array([[1.0, 1.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])


def _spoke_g1_rows(n: int, i: int) -> np.ndarray:
    """Rows of ``D_l + D_r - lambda D_e == 0`` (degree-6 Bernstein coefficients in t).

    Spoke i runs from v (t = 0) to w_i (t = 1); it is edge (corner 0 -> 1) of
    ring patch i = (v, w_i, w_{i+1}) and edge (corner 0 -> 2) of patch i - 1 =
    (v, w_{i-1}, w_i).  Columns index all ``28 n`` ring control points.
    """
    lam0, lam1 = 2.0 * np.cos(2.0 * np.pi / n), 1.0
    left, right = 28 * i, 28 * ((i - 1) % n)

    def col(base, i_, j_, k_):
        return base + int(_control_index(np.array([i_, j_, k_])))

    def vec(entries):
        row = np.zeros(28 * n)
        for c, w in entries:
            row[c] += w
        return row

    e = [vec([(col(left, 5 - m, m + 1, 0), 6.0), (col(left, 6 - m, m, 0), -6.0)]) for m in range(6)]
    d = [vec([(col(left, 5 - m, m, 1), 6.0), (col(left, 6 - m, m, 0), -6.0),
              (col(right, 5 - m, 1, m), 6.0), (col(right, 6 - m, 0, m), -6.0)]) for m in range(6)]
    zero = np.zeros(28 * n)
    rows = []
    for m in range(7):
        d_m, d_prev = (d[m] if m < 6 else zero), (d[m - 1] if m > 0 else zero)
        e_m, e_prev = (e[m] if m < 6 else zero), (e[m - 1] if m > 0 else zero)
        rows.append((6 - m) / 6 * d_m + m / 6 * d_prev
                    - lam0 * (6 - m) / 6 * e_m - lam1 * m / 6 * e_prev)
    return np.array(rows)


def _spoke_share_rows(n: int, i: int) -> np.ndarray:
    """Rows equating spoke i's inner points (v-exponent 2..5) seen from both patches."""
    left, right = 28 * i, 28 * ((i - 1) % n)
    rows = []
    for a in range(2, 6):
        row = np.zeros(28 * n)
        row[left + int(_control_index(np.array([a, 6 - a, 0])))] = 1.0
        row[right + int(_control_index(np.array([a, 0, 6 - a])))] = -1.0
        rows.append(row)
    return np.array(rows)


# ----------------------------------------------------------------------------- Loop-limit reference
def _ring_template(n: int) -> tuple[int, np.ndarray]:
    """Valence-n vertex with its two rings, the local control mesh of its ring patches.

    Vertices: ``v = 0``, ``w_j = 1 + j``, ``x_j = 1 + n + j`` (apex of the
    regular neighbour ``N_j = (w_{j+1}, w_j, x_j)``), ``y_j = 1 + 2n + j``
    (between ``x_{j-1}`` and ``x_j`` around ``w_j``).  Ring faces come first.
    Each ring patch's Loop limit depends on these ``3n + 1`` points only
    (its ``n + 6``-point control mesh).
    """
    j = np.arange(n)
    w, x, y = 1 + j, 1 + n + j, 1 + 2 * n + j
    w_next, x_prev = np.roll(w, -1), np.roll(x, 1)
    tris = np.concatenate([np.stack([np.zeros(n, dtype=np.int64), w, w_next], 1),
                           np.stack([w_next, w, x], 1),
                           np.stack([w, x_prev, y], 1),
                           np.stack([w, y, x], 1)])
    return 3 * n + 1, tris


@cache
def _limit_samples(n: int, steps: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Barycentric samples ``(S, 3)`` of ring patch 0 and Loop's limit there ``(S, 3n+1)``.

    Exact limit points (Loop's limit mask after ``steps`` subdivisions of the
    template with unit-vector "positions"), as weights of the local vertices.
    """
    n_local, tris = _ring_template(n)
    points, sub, root, bary = subdivide_tracked(np.eye(n_local), tris, steps, allow_border=True)
    limit = limit_positions(build_half_edges(len(points), sub, allow_border=True), points)
    mine = root == 0
    vertex, where = np.unique(sub[mine].ravel(), return_index=True)
    return bary[mine].reshape(-1, 3)[where], limit[vertex]


def _rotate_local(n: int, shift: int) -> np.ndarray:
    """Column permutation taking patch 0's local weights to patch ``shift``'s."""
    j = np.arange(n)
    perm = np.empty(3 * n + 1, dtype=np.int64)
    perm[0] = 0
    for block in range(3):
        perm[1 + block * n + j] = 1 + block * n + (j + shift) % n
    return perm


def _ring_problem(n: int):
    """Pieces of the valence-n fit: per-patch start nets, weights and spoke rows.

    Data columns: ``[p_v | N_0 .. N_{n-1} quartic nets (15 each) | 3n + 1
    local vertices]``.  Returns ``start (n, 28, D)`` -- each patch's net with
    its fixed rows exact and its free rows the unconstrained least-squares
    fit to Loop's limit --, ``free (28,)``, ``weight (14, 14) = G_u^T G_u``,
    and the spoke-0 rows ``left``, ``right`` (11, 28).
    """

    v_exp = _index_table(DEGREE)[:, 0]
    free = (v_exp >= 2) & (v_exp <= 5)
    n_local = 3 * n + 1
    n_data = 1 + 15 * n + n_local
    continuation = _blossom_matrix(_NEIGHBOUR_TO_RING) @ elevate(np.eye(15), DEGREE)  # (28, 15)
    bary, limit0 = _limit_samples(n)
    basis = bernstein_matrix(bary)  # (S, 28)
    fit_u, fit_f = basis[:, free], basis[:, ~free]
    weight = fit_u.T @ fit_u
    fit = np.linalg.solve(weight, fit_u.T)  # (14, S): unconstrained least squares
    outer = v_exp <= 1
    fixed_start = np.zeros((28, 16))  # fixed rows as functions of [p_v, N_i (15)]
    fixed_start[v_exp == 6, 0] = 1.0
    fixed_start[outer, 1:] = continuation[outer]
    free_from_fixed = -fit @ fit_f @ fixed_start[~free]  # (14, 16)
    free_from_local = fit @ limit0  # (14, 3n + 1)
    start = np.zeros((n, 28, n_data))
    for i in range(n):  # patch i: its own neighbour block, its rotation of the local data
        cols = np.concatenate([[0], 1 + 15 * i + np.arange(15)])
        start[i][:, cols] = fixed_start
        start[i][np.ix_(free, cols)] = free_from_fixed
        start[i][np.ix_(free, 1 + 15 * n + _rotate_local(n, i))] = free_from_local
    rows = np.concatenate([_spoke_share_rows(n, 0), _spoke_g1_rows(n, 0)])  # (11, 28 n)
    return start, free, weight, rows[:, :28], rows[:, 28 * (n - 1):]


#: Where :func:`ring_operator` keeps the operators it built (beside numba's cache).
OPERATOR_CACHE = Path(__file__).resolve().parent / "__pycache__"


@cache
def _operator_cache_key() -> str:
    """What the ring operators depend on: the source of this module and of the modules it
    builds them with (the patch algebra, Loop's weights) and numpy's version (a stale file
    is never read)."""
    digest = hashlib.sha256(np.__version__.encode())
    for name in ("_loop_patches.py", "bezier_patch.py", "loop_weights.py", "validate.py"):
        digest.update((Path(__file__).parent / name).read_bytes())
    return digest.hexdigest()[:16]


@cache
def ring_operator(n: int) -> np.ndarray:
    """:func:`ring_operator_fft` of valence ``n``, kept on disk beside numba's kernels
    (``surface/__pycache__``, keyed by :func:`_operator_cache_key`): each valence costs
    20-30 ms to build, and a real mesh has many (the temple's sized meshes 24: 0.5 s a
    run); where the folder cannot be written it is built every time."""

    folder = OPERATOR_CACHE
    path = folder / f"ring_operator.{_operator_cache_key()}.{int(n)}.npy"
    try:
        operator = np.load(path, allow_pickle=False)
        if operator.shape == (28 * n, 1 + 15 * n + 3 * n + 1):
            operator.flags.writeable = False
            return operator
    except (OSError, ValueError):
        pass
    operator = ring_operator_fft(n)
    try:
        folder.mkdir(exist_ok=True)
        for stale in folder.glob("ring_operator.*.npy"):   # an older code's (~0.4 MB each)
            if f".{_operator_cache_key()}." not in stale.name:
                stale.unlink(missing_ok=True)
        handle, tmp = tempfile.mkstemp(dir=folder, suffix=".npy.tmp")
        with os.fdopen(handle, "wb") as fh:
            np.save(fh, operator, allow_pickle=False)
        os.replace(tmp, path)   # atomic: a concurrent process reads the old or the new
    except OSError:
        pass
    return operator


def ring_operator_fft(n: int) -> np.ndarray:
    """Linear map from the data of a valence-n vertex to its n sextic ring patches.

    Data (columns): ``[p_v, N_0 .. N_{n-1}, local]`` -- Loop's limit point of
    v, the quartic nets of the regular neighbours across the outer edges (each
    in the frame (w_{i+1}, w_i, x_i)), and the 3n + 1 local control vertices of
    :func:`_ring_template`.  Output (rows): the n nets of the ring patches
    ``(v, w_i, w_{i+1})``, ``28 i + index``.

    Fixed: ``b_600 = p_v``; the two rows nearest the outer edge are the C1
    continuation of N_i.  Free: the rows with v-exponent 2..5, the
    least-squares fit to Loop's limit surface at 45 points of each patch,
    subject to spoke sharing and Loop's G1 condition on every spoke.

    The constraints are block-circulant (spoke j couples patches j and j - 1
    identically) and the fit weight ``W`` is the same for every patch, so a
    discrete Fourier transform over the ring splits the weighted minimum-norm
    correction into n independent 11 x 14 problems (Parseval).
    """
    start, free, weight, left, right = _ring_problem(n)
    a0, a1 = left[:, free], right[:, free]
    values, vectors = np.linalg.eigh(weight)
    w_inv_half = (vectors / np.sqrt(values)) @ vectors.T
    omega = np.exp(-2j * np.pi * np.arange(n) / n)  # omega^{-k}
    symbols = (a0[None] + a1[None] * omega[:, None, None]) @ w_inv_half  # (n, 11, 14)
    solve = w_inv_half @ np.linalg.pinv(symbols, rcond=1e-10)  # (n, 14, 11)
    residual = -(np.einsum("ab,ibd->iad", left, start)
                 + np.einsum("ab,ibd->iad", right, np.roll(start, 1, axis=0)))  # (n, 11, D)
    spectrum = np.einsum("kab,kbd->kad", solve, np.fft.fft(residual, axis=0))
    operator = start.copy()
    operator[:, free] += np.fft.ifft(spectrum, axis=0).real
    operator = operator.reshape(28 * n, -1)
    operator.flags.writeable = False
    return operator


def ring_operator_dense(n: int) -> np.ndarray:
    """The same fit by a dense null-space solve (a reference for the tests)."""
    start, free, weight, _, _ = _ring_problem(n)
    constraints = np.concatenate([np.concatenate([_spoke_share_rows(n, i), _spoke_g1_rows(n, i)])
                                  for i in range(n)])
    mask = np.tile(free, n)
    a_free = constraints[:, mask]
    keep = np.abs(a_free).sum(axis=1) > 0  # drop the rows on data only
    a_free = a_free[keep]
    flat = start.reshape(28 * n, -1)
    rhs = -(constraints[keep] @ flat)  # correction must satisfy a_free @ dz = rhs
    particular = np.linalg.pinv(a_free, rcond=1e-10) @ rhs
    null = scipy.linalg.null_space(a_free, rcond=1e-10)
    metric = np.kron(np.eye(n), weight)
    reduced = null.T @ metric @ null
    y = -np.linalg.solve(reduced, null.T @ metric @ particular)
    out = flat.copy()
    out[mask] += particular + null @ y
    return out


# ----------------------------------------------------------------------------- the surface
def _compact(vertices: np.ndarray, triangles: np.ndarray):
    """Drop vertices no triangle uses (they carry no patch)."""
    used = np.zeros(len(vertices), dtype=bool)
    used[triangles.ravel()] = True
    remap = np.cumsum(used) - 1
    return vertices[used], remap[triangles]


def _check_areas(vertices: np.ndarray, triangles: np.ndarray) -> None:
    corner = vertices[triangles]
    doubled = np.linalg.norm(np.cross(corner[:, 1] - corner[:, 0], corner[:, 2] - corner[:, 0]),
                             axis=1)
    scale = np.linalg.norm(vertices.max(axis=0) - vertices.min(axis=0))
    bad = doubled <= TOL.zero * max(scale, TOL.zero) ** 2
    if np.any(bad):
        raise ValueError(f"triangles has {int(bad.sum())} degenerate (zero-area) triangles "
                         f"(first: face {int(np.argmax(bad))})")


@cache
def _coordinate_operator(matrix_key: str) -> np.ndarray:
    """``kron(M, I_3).T``: applies an ``(N, K)`` net map to patch-major ``(P, K * 3)`` rows.

    ``(P, K, 3) -> (P, N, 3)`` then is one GEMM ``(P, 3K) x (3K, 3N)`` with no
    transposed copies (the zero blocks cost flops, not memory traffic).
    """

    matrix = BOX_SPLINE_QUARTIC if matrix_key == "quartic" else elevate(BOX_SPLINE_QUARTIC, DEGREE)
    operator = np.kron(matrix, np.eye(3)).T
    operator.flags.writeable = False
    return operator


def regular_patches(mesh: HalfEdges, points: np.ndarray, faces: np.ndarray):
    """Nets of regular faces: the box-spline quartic ``(R, 15, 3)`` and its sextic elevation.

    The sextic comes straight from the stencil through the elevated box-spline
    matrix (the same linear map as elevating the quartic, up to rounding).
    """
    stencil = box_spline_stencil(mesh, faces)
    gathered = points[stencil].reshape(len(faces), -1)  # (R, 36) patch-major
    quartic = (gathered @ _coordinate_operator("quartic")).reshape(len(faces), 15, 3)
    sextic = (gathered @ _coordinate_operator("sextic")).reshape(len(faces), N_SEXTIC, 3)
    return quartic, sextic


N_SEXTIC = 28
#: Patches per batch of the patch GEMMs: ~20 MB work arrays, below glibc's largest mmap
#: threshold (32 MB), so batches reuse their memory; fresh pages (first touch) cost
#: more than the arithmetic on the dense meshes this is for.
_CHUNK_FACES = 2 ** 15


@numba.njit(cache=True, nogil=True)
def _gather_neighbour_nets(quartic, quartic_row, across, rotation, out):  # pragma: no cover
    """``out[15 i + p, v] = quartic[row of across[v, i]'s face, rotation[corner, p]]``.

    ``out`` ``(15 n, Vn, 3)``: the quartic neighbour nets of a valence class in the
    data-major layout of the ring operator's GEMM, each relabelled to start at the
    corner where the half-edge ``across`` leaves.
    """
    n_vertices, n = across.shape
    for v in range(n_vertices):
        for i in range(n):
            h = across[v, i]
            row = quartic_row[h // 3]
            corner = h % 3
            for p in range(15):
                src = rotation[corner, p]
                for d in range(3):
                    out[15 * i + p, v, d] = quartic[row, src, d]


@numba.njit(cache=True, nogil=True)
def _scatter_ring_nets(rings, spokes, rotation, control_points):  # pragma: no cover
    """``control_points[face of spoke, rotation[corner, p]] = rings[i, p, v]``.

    ``rings`` ``(n, 28, Vn, 3)`` is the GEMM's output; spoke ``v -> w_i`` is half-edge
    ``3 f + c`` of its patch, whose net is stored from corner 0, not from v.
    """
    n_vertices, n = spokes.shape
    for v in range(n_vertices):
        for i in range(n):
            h = spokes[v, i]
            face = h // 3
            corner = h % 3
            for p in range(N_SEXTIC):
                dst = rotation[corner, p]
                for d in range(3):
                    control_points[face, dst, d] = rings[i, p, v, d]


def _irregular_patches(mesh: HalfEdges, points: np.ndarray, limit: np.ndarray,
                       quartic: np.ndarray, quartic_row: np.ndarray,
                       control_points: np.ndarray, centres_wanted: np.ndarray) -> None:
    """Fill the ring patches of the wanted irregular vertices, one batch per valence.

    ``quartic`` ``(R, 15, 3)`` holds the box-spline quartic nets of the regular
    faces, ``quartic_row`` ``(F,)`` each face's row there (-1: not regular); the
    ring patches are written into ``control_points`` ``(F, 28, 3)``.
    """
    dest = mesh.dest
    rotation4 = np.stack([corner_rotation(c, 4) for c in range(3)])
    rotation6 = np.stack([corner_rotation(c) for c in range(3)])
    for n in np.unique(mesh.valence[centres_wanted]):
        n = int(n)
        centres = centres_wanted[mesh.valence[centres_wanted] == n]
        spokes = ring_half_edges(mesh, mesh.first_out[centres], n)  # (Vn, n): v -> w_i
        across = mesh.twin[next_half_edge(spokes)]  # w_{i+1} -> w_i in N_i
        if np.any(across < 0) or np.any(quartic_row[across // 3] < 0):
            raise RuntimeError("an irregular vertex's neighbour patch is not regular")
        to_apex = next_half_edge(across)  # w_i -> x_i
        local = np.concatenate([centres[:, None], dest[spokes], dest[to_apex],
                                dest[next_half_edge(mesh.twin[to_apex])]], axis=1)  # v, w, x, y
        operator = ring_operator(n)
        n_data = operator.shape[1]
        batch = max(1, _CHUNK_FACES // n)  # about _CHUNK_FACES ring patches per GEMM
        for start in range(0, len(centres), batch):
            part = slice(start, start + batch)
            count = len(centres[part])
            flat = np.empty((n_data, count, 3))  # data-major for one GEMM
            flat[0] = limit[centres[part]]
            _gather_neighbour_nets(quartic, quartic_row, across[part], rotation4,
                                   flat[1:1 + 15 * n])
            flat[1 + 15 * n:] = points[local[part].T]
            # (28n, D) x (D, 3 count): a batch of vertices of this valence at once
            rings = operator @ flat.reshape(n_data, -1)
            _scatter_ring_nets(rings.reshape(n, N_SEXTIC, count, 3), spokes[part], rotation6,
                               control_points)


def build_surface(vertices: np.ndarray, triangles: np.ndarray):
    """Control nets over the once-refined mesh; see ``bezier.control_net``.

    Returns ``(control_points (4F, 28, 3), source_face (4F,), refined vertices,
    refined triangles (4F, 3))``.  A mesh with borders is first extended by two
    ghost layers (:func:`add_ghost_layer`) so that every input vertex is
    interior; only the patches of the input faces are returned.
    """

    if len(triangles) == 0:
        raise ValueError("triangles is empty")
    checked = build_half_edges(len(vertices), triangles, allow_border=True)  # index/orientation
    n_given = len(vertices)
    vertices, triangles = _compact(vertices, triangles)
    _check_areas(vertices, triangles)
    n_faces, n_vertices = len(triangles), len(vertices)
    # nothing dropped: the mesh just checked is the compacted one
    mesh0 = checked if n_vertices == n_given else build_half_edges(n_vertices, triangles,
                                                                     allow_border=True)
    points, tris = vertices, triangles
    if mesh0.on_border.any():
        for _ in range(2):
            points, tris = add_ghost_layer(mesh0, points)
            mesh0 = build_half_edges(len(points), tris, allow_border=True)
    points, tris = loop_subdivide(mesh0, points)
    mesh = refined_half_edges(mesh0, len(points), tris)
    # every patch the input faces keep is written below (regular or ring patch);
    # ghost-layer patches far from the input may stay unset and are dropped
    control_points = _empty_pages((len(tris), N_SEXTIC, 3))
    inner6 = (mesh.valence == 6) & ~mesh.on_border
    regular = np.flatnonzero(np.all(inner6[tris], axis=1))
    quartic = _empty_pages((len(regular), 15, 3))
    for start in range(0, len(regular), _CHUNK_FACES):
        faces = regular[start:start + _CHUNK_FACES]
        quartic[start:start + len(faces)], control_points[faces] = regular_patches(
            mesh, points, faces)
    quartic_row = np.full(len(tris), -1, dtype=np.int64)
    quartic_row[regular] = np.arange(len(regular))
    limit = limit_positions(mesh, points)
    centres = np.flatnonzero(~inner6[:n_vertices])  # input vertices are interior here
    _irregular_patches(mesh, points, limit, quartic, quartic_row, control_points, centres)
    kept = 4 * n_faces  # children of the input faces come first
    used = np.zeros(len(points), dtype=bool)
    used[tris[:kept].ravel()] = True
    remap = np.cumsum(used) - 1
    source = np.repeat(np.arange(n_faces), 4)
    return control_points[:kept], source, points[used], remap[tris[:kept]]
