r"""Loop's tangent-plane-continuous sextic triangular Bézier surface.

Each triangle of the (once Loop-refined) control mesh carries one sextic patch

.. math::

    P(r, s, t) = \sum_{i+j+k=6} b_{ijk} \, B_{ijk}(r, s, t), \qquad
    B_{ijk} = \frac{6!}{i!\,j!\,k!} r^i s^j t^k, \quad r + s + t = 1,

after C. Loop, SIGGRAPH 1994 [1]_; ``(r, s, t)`` weight the domain corners ``tri[0..2]``
(counter-clockwise from outside).  The 28 control points ``(P, 28, 3)`` are stored
descending in i, then in j: ``index(i, j, k) = m (m + 1) / 2 + k``, ``m = 6 - i``
(:func:`index_table`, :func:`control_index`; the same rule for every degree here).

Construction (:func:`control_net`): (1) one Loop subdivision step [2]_, after which a
triangle has at most one vertex of valence != 6; (2) regular patches are the quartic box
spline of Loop subdivision, degree-elevated to 6 (C2 between them: the limit surface
itself); (3) around an irregular vertex of valence n the patches meet Loop's limit point,
join their regular neighbours C1, and satisfy the scalar G1 condition across each spoke

.. math::  D_l(t) + D_r(t) = \lambda(t)\, D_e(t), \qquad
           \lambda(t) = 2\cos(2\pi/n)\,(1 - t) + t;

the free points are the constrained least-squares fit to Loop's limit surface at 45 points
a patch (a fixed linear map per valence, split by a DFT into n small problems), instead of
Loop's explicit formulas: close to, not equal to, the limit surface there (at most 0.6 % of
the control edge on a subdivided cube).  Borders are closed by two layers of reflected
ghost triangles (``g = a + b - c``); only the input faces' patches are returned, G1 across
every interior edge.  Bad meshes (non-manifold, misoriented, NaN, zero area) raise
``ValueError``.  The construction in full: ``docs/method/bezier.md``.

References
----------
.. [1] C. Loop, "Smooth spline surfaces over irregular meshes",
   Proc. SIGGRAPH 94, pp. 303-310 (1994).
.. [2] C. Loop, "Smooth subdivision surfaces based on triangles", MSc thesis,
   University of Utah (1987).
.. [3] G. Farin, "Triangular Bernstein-Bézier patches", CAGD 3 (1986) 83-127.
"""

from __future__ import annotations

import mmap
from dataclasses import dataclass
from functools import cache
from math import factorial

import numba
import numpy as np

from surface._blas import one_blas_thread
from surface.validate import TOL, check_finite, check_shape

# as in matching.lsm: OpenMP first (the TBB layer here is too old and warns on stderr:
# an export-only process, which never imports matching.lsm, printed numba's TBB
# warning beside its own error line)
numba.config.THREADING_LAYER_PRIORITY = ["omp", "workqueue", "tbb"]

DEGREE = 6
N_CONTROL = (DEGREE + 1) * (DEGREE + 2) // 2  # 28
#: Samples x patches evaluated at once in tessellate: ~5 MB work arrays, far below glibc's
#: largest mmap threshold (32 MB), so the chunks reuse their memory instead of faulting
#: fresh pages in each time.
_CHUNK_ROWS = 2 ** 16

__all__ = [
    "DEGREE",
    "N_CONTROL",
    "BezierSurface",
    "bernstein_matrix",
    "chord_error_bound",
    "control_index",
    "control_net",
    "control_point_ids",
    "corner_normals",
    "edge_continuity",
    "elevate",
    "evaluate",
    "index_table",
    "normals",
    "share_boundaries",
    "subdivide",
    "tensor_product_nets",
    "adaptive_segments",
    "certified_segments",
    "closest_points",
    "tessellate",
    "tessellate_adaptive",
    "tessellation_level",
]


# ----------------------------------------------------------------------------- index order
@cache
def _index_table(degree: int) -> np.ndarray:
    rows = [(i, j, degree - i - j) for i in range(degree, -1, -1)
            for j in range(degree - i, -1, -1)]
    table = np.array(rows, dtype=np.int64).reshape(-1, 3)
    table.flags.writeable = False
    return table


def index_table(degree: int = DEGREE) -> np.ndarray:
    """Multi-indices ``(i, j, k)`` of a triangular net, in storage order.

    Parameters
    ----------
    degree : int
        Polynomial degree (6 for the surface's patches).

    Returns
    -------
    (N, 3) int64, N = (degree + 1)(degree + 2) / 2
        Row ``p`` holds the exponents of ``r, s, t`` of control point ``p``;
        descending i, then descending j.
    """
    return _index_table(int(degree))


def control_index(i, j, k, degree: int = DEGREE):
    """Storage position of control point ``b_ijk`` (vectorised over arrays).

    ``index = m (m + 1) / 2 + k`` with ``m = degree - i = j + k``.

    Raises
    ------
    ValueError
        If ``i + j + k != degree`` or an index is negative.
    """
    i, j, k = (np.asarray(a, dtype=np.int64) for a in (i, j, k))
    if np.any(i + j + k != degree) or np.any((i < 0) | (j < 0) | (k < 0)):
        raise ValueError(f"control_index needs non-negative i + j + k == {degree}")
    m = degree - i
    out = m * (m + 1) // 2 + k
    return int(out) if out.ndim == 0 else out


# ----------------------------------------------------------------------------- Bernstein basis
def _multinomials(degree: int) -> np.ndarray:
    idx = index_table(degree)
    return np.array([factorial(degree) / (factorial(i) * factorial(j) * factorial(k))
                     for i, j, k in idx])


def _bernstein(bary: np.ndarray, degree: int) -> np.ndarray:
    idx = index_table(degree)
    # the degree + 1 powers of each coordinate once, by repeated products (no pow(): 1.8x
    # faster, and correctly rounded products are the same on every CPU), then gathered
    powers = np.empty(bary.shape + (degree + 1,))                      # (S, 3, degree + 1)
    powers[..., 0] = 1.0
    for k in range(1, degree + 1):
        np.multiply(powers[..., k - 1], bary, out=powers[..., k])
    return _multinomials(degree)[None, :] * (powers[:, 0, idx[:, 0]] * powers[:, 1, idx[:, 1]]
                                             * powers[:, 2, idx[:, 2]])


def bernstein_matrix(bary, degree: int = DEGREE) -> np.ndarray:
    """Bernstein basis ``B_ijk(r, s, t)`` at sample points.

    Parameters
    ----------
    bary : (S, 3) array_like
        Barycentric coordinates ``(r, s, t)``; rows should sum to 1.
    degree : int

    Returns
    -------
    (S, N) float64
        ``points = B @ control_points`` evaluates a patch at every sample.
    """
    bary = check_shape(bary, "(S, 3)", "bary", dtype=np.float64)
    check_finite(bary, "bary")
    return _bernstein(bary, degree)


def _derivative_nets(control_points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Nets of the derivatives along corner 0 -> 1 and corner 0 -> 2.

    ``d/du P = deg * sum_{|a| = deg-1} B_a (b_{a+e2} - b_{a+e1})`` and the same
    with ``e3`` for ``d/dv``; returns two ``(..., N', 3)`` arrays of degree - 1.
    """
    n = control_points.shape[-2]
    degree = int(round((np.sqrt(8 * n + 1) - 3) / 2))
    low = index_table(degree - 1)
    i0 = control_index(low[:, 0] + 1, low[:, 1], low[:, 2], degree)
    i1 = control_index(low[:, 0], low[:, 1] + 1, low[:, 2], degree)
    i2 = control_index(low[:, 0], low[:, 1], low[:, 2] + 1, degree)
    du = degree * (control_points[..., i1, :] - control_points[..., i0, :])
    dv = degree * (control_points[..., i2, :] - control_points[..., i0, :])
    return du, dv


def _check_control_points(control_points) -> np.ndarray:
    cp = check_shape(control_points, f"(P, {N_CONTROL}, 3)", "control_points", dtype=np.float64)
    return check_finite(cp, "control_points")


def evaluate(control_points, bary) -> np.ndarray:
    """Points of every patch at the same barycentric samples.

    Parameters
    ----------
    control_points : (P, 28, 3) array_like
        Sextic nets in the module's index order.
    bary : (S, 3) array_like
        Barycentric sample coordinates ``(r, s, t)``.

    Returns
    -------
    (P, S, 3) float64
        ``points[p, s] = sum_ijk B_ijk(bary[s]) b_ijk[p]``: one ``(S, 28)``
        Bernstein matrix times the control array.
    """
    cp = _check_control_points(control_points)
    return _apply(bernstein_matrix(bary, DEGREE), cp).transpose(1, 0, 2)


def _unit(vectors: np.ndarray) -> np.ndarray:
    length = np.sqrt(np.einsum("...d,...d->...", vectors, vectors))[..., None]
    return vectors / np.maximum(length, TOL.zero)


@cache
def _derivative_operators(degree: int = DEGREE) -> tuple[np.ndarray, np.ndarray]:
    """``(N', N)`` matrices mapping a net to its two derivative nets (see _derivative_nets)."""
    du, dv = _derivative_nets(np.eye(len(index_table(degree)))[:, :, None].transpose(2, 0, 1))
    return du[0], dv[0]


def _clipped_trial(bary: np.ndarray, step: np.ndarray) -> np.ndarray:
    """Barycentrics ``bary`` moved by ``step`` (in s, t), kept within ``_EXTEND`` of the
    patch (:func:`closest_points`)."""
    st = bary[:, 1:] + step
    return np.clip(np.column_stack([1.0 - st.sum(axis=1), st]), -_EXTEND,
                   1.0 + 2.0 * _EXTEND)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1]
    out[..., 1] = a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2]
    out[..., 2] = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    return out


def _apply(basis: np.ndarray, cp: np.ndarray) -> np.ndarray:
    """``(S, N) x (P, N, 3) -> (S, P, 3)`` (sample-major) as one GEMM, not P small ones."""
    flat = cp.transpose(1, 0, 2).reshape(cp.shape[1], -1)  # (N, 3P)
    return (basis @ flat).reshape(len(basis), cp.shape[0], 3)


def _points_and_derivatives_basis(bary: np.ndarray) -> np.ndarray:
    """``(3S, 28)``: rows giving the points, ``P_u`` and ``P_v`` at the samples."""
    du, dv = _derivative_operators()
    low = _bernstein(bary, DEGREE - 1)
    return np.concatenate([_bernstein(bary, DEGREE), low @ du, low @ dv])


def _points_and_normals_sp(cp: np.ndarray, bary: np.ndarray):
    """Points and unit normals, ``(S, P, 3)`` each, from one stacked GEMM."""
    out = _apply(_points_and_derivatives_basis(bary), cp)
    n = len(bary)
    return out[:n], _unit(_cross(out[n:2 * n], out[2 * n:]))


def _normals(cp: np.ndarray, bary: np.ndarray) -> np.ndarray:
    return _points_and_normals_sp(cp, bary)[1].transpose(1, 0, 2)


def normals(control_points, bary) -> np.ndarray:
    """Exact unit normals of every patch at the barycentric samples.

    Parameters
    ----------
    control_points : (P, 28, 3) array_like
    bary : (S, 3) array_like

    Returns
    -------
    (P, S, 3) float64
        ``normalise(P_u x P_v)`` with ``P_u``, ``P_v`` the derivatives along
        corner 0 -> 1 and corner 0 -> 2, evaluated from the quintic derivative
        nets; outward for a counter-clockwise domain triangle.  A vanishing
        cross product (a degenerate patch) gives a zero vector, never NaN.
    """
    cp = _check_control_points(control_points)
    bary = check_shape(bary, "(S, 3)", "bary", dtype=np.float64)
    check_finite(bary, "bary")
    return _normals(cp, bary)


# ----------------------------------------------------------------------------- de Casteljau
def _casteljau_step(degree: int, weights: np.ndarray) -> np.ndarray:
    """Matrix of one de Casteljau step from degree ``degree`` to ``degree - 1``."""
    low = index_table(degree - 1)
    step = np.zeros((len(low), len(index_table(degree))))
    rows = np.arange(len(low))
    for axis in range(3):
        shifted = low.copy()
        shifted[:, axis] += 1
        cols = control_index(shifted[:, 0], shifted[:, 1], shifted[:, 2], degree)
        step[rows, cols] += weights[axis]
    return step


def _blossom_matrix(corners: np.ndarray, degree: int = DEGREE) -> np.ndarray:
    """Reparametrisation of a net onto the sub-triangle with barycentric ``corners``.

    The new point ``b'_ijk`` is the blossom ``b[q0^i, q1^j, q2^k]`` evaluated
    by ``degree`` de Casteljau steps (Farin [3]_ §4); returns ``(N, N)``.
    """
    idx = index_table(degree)
    out = np.zeros((len(idx), len(idx)))
    for row, multi in enumerate(idx):
        args = np.repeat(corners, multi, axis=0)  # (degree, 3)
        mat = np.eye(1)
        for level, u in zip(range(1, degree + 1), args[::-1], strict=True):
            mat = mat @ _casteljau_step(level, u)
        out[row] = mat[0]
    return out


#: Barycentric corners of the four children of the midpoint split, the same
#: order as Loop subdivision's children: three corner triangles, then the centre.
_CHILD_CORNERS = np.array([
    [[1, 0, 0], [0.5, 0.5, 0], [0.5, 0, 0.5]],
    [[0.5, 0.5, 0], [0, 1, 0], [0, 0.5, 0.5]],
    [[0.5, 0, 0.5], [0, 0.5, 0.5], [0, 0, 1]],
    [[0, 0.5, 0.5], [0.5, 0, 0.5], [0.5, 0.5, 0]],
])


@cache
def _subdivision_matrices() -> np.ndarray:
    mats = np.stack([_blossom_matrix(c) for c in _CHILD_CORNERS])
    mats.flags.writeable = False
    return mats


def subdivide(control_points) -> np.ndarray:
    """Split every patch at its edge midpoints into 4 sub-patches (de Casteljau).

    Parameters
    ----------
    control_points : (P, 28, 3) array_like

    Returns
    -------
    (4P, 28, 3) float64
        Children ``4p .. 4p+3`` of patch ``p``: the corner triangles at
        ``tri[0]``, ``tri[1]``, ``tri[2]``, then the centre triangle
        ``(m12, m20, m01)``; each exactly reparametrises its part of the parent.
    """
    cp = _check_control_points(control_points)
    return _subdivide(cp)


@cache
def _subdivision_operator() -> np.ndarray:
    """``(84, 336)``: a patch's 28 x 3 coordinates (row-major) to its four children's.

    ``kron(S, I_3)ᵀ`` with ``S`` the stacked ``(112, 28)`` subdivision matrices: one GEMM
    then writes the children patch-major, as they are stored.  Mapping sample-major
    (:func:`_apply`) and transposing cost 19-26x more on 3.4-13.7·10⁴ patches (the
    transpose's copy of the 4x larger output, not the flops, which this triples).
    """
    stacked = _subdivision_matrices().reshape(4 * N_CONTROL, N_CONTROL)
    operator = np.ascontiguousarray(np.kron(stacked, np.eye(3)).T)
    operator.flags.writeable = False
    return operator


def _subdivide(cp: np.ndarray) -> np.ndarray:
    # into plain pages (:func:`_empty_pages`): numpy's own allocation of the 4x larger
    # output cost 1.6-3.6 s of first-touch compaction on the demo's 2.6-4.6·10⁴ patches
    # certified_segments splits, the mapping 0.3 s
    children = _empty_pages((len(cp), 12 * N_CONTROL))
    np.matmul(cp.reshape(len(cp), 3 * N_CONTROL), _subdivision_operator(), out=children)
    return children.reshape(-1, N_CONTROL, 3)


@cache
def _elevation_matrix(degree: int) -> np.ndarray:
    """``(N_{d+1}, N_d)`` degree elevation: ``b'_a = sum_e (a_e / (d+1)) b_{a - e}``."""
    high, low = index_table(degree + 1), index_table(degree)
    mat = np.zeros((len(high), len(low)))
    for row, multi in enumerate(high):
        for axis in range(3):
            if multi[axis] > 0:
                src = multi.copy()
                src[axis] -= 1
                mat[row, control_index(*src, degree=degree)] += multi[axis] / (degree + 1)
    mat.flags.writeable = False
    return mat


def elevate(control_points, to_degree: int = DEGREE) -> np.ndarray:
    """Degree-elevate triangular nets ``(..., N_d, D)`` to degree ``to_degree``."""
    net = np.asarray(control_points, dtype=np.float64)
    degree = int(round((np.sqrt(8 * net.shape[-2] + 1) - 3) / 2))
    if (degree + 1) * (degree + 2) // 2 != net.shape[-2] or to_degree < degree:
        raise ValueError(f"control_points has {net.shape[-2]} points per net: not a "
                         f"triangular net of degree <= {to_degree}")
    for d in range(degree, to_degree):
        net = np.matmul(_elevation_matrix(d), net)
    return net


# ----------------------------------------------------------------------------- tessellation
#: Arrays at least this large are mapped by :func:`_empty_pages` (bytes).
_PAGES_MIN_BYTES = 2 ** 26


def _empty_pages(shape, dtype=np.float64) -> np.ndarray:
    """``np.empty`` for the large outputs (control nets, tessellations), in plain pages.

    numpy advises the kernel to back large arrays with transparent huge pages;
    where the kernel then compacts memory on the first touch (``defrag=madvise``,
    as on this project's machines) that first write costs 2-4x a plain anonymous
    mapping's (measured: 2.4 GB in 2.9-5.8 s against 1.2-2.0 s).  The arrays here
    are written once and streamed, so huge pages buy nothing back.  The mapping is
    freed with the last array that uses it.  The mapping is private (copy-on-write
    after a fork, like any numpy array): a shared one faulted in faster here
    (0.9-1.4 s of kernel time against 1.7-2.0 s in the s3 tessellation) but would
    let a forked child write into its parent's surface.
    """
    dtype = np.dtype(dtype)
    nbytes = int(np.prod(shape)) * dtype.itemsize
    if nbytes < _PAGES_MIN_BYTES or not hasattr(mmap, "MAP_PRIVATE"):  # (not on Windows)
        return np.empty(shape, dtype)
    pages = mmap.mmap(-1, nbytes, flags=mmap.MAP_PRIVATE | mmap.MAP_ANONYMOUS)
    return np.frombuffer(pages, dtype).reshape(shape)


@cache
def _grid(segments: int):
    """Sample grid of a patch: bary (S, 3), local triangles, and sample kinds."""
    idx = index_table(segments)  # (S, 3) as (a, b, c), a + b + c = segments
    bary = idx / segments
    b, c = np.meshgrid(np.arange(segments), np.arange(segments), indexing="ij")
    b, c = b.ravel(), c.ravel()
    up = b + c <= segments - 1
    down = b + c <= segments - 2

    def at(bb, cc):
        return control_index(segments - bb - cc, bb, cc, segments)

    tris_up = np.stack([at(b[up], c[up]), at(b[up] + 1, c[up]), at(b[up], c[up] + 1)], axis=1)
    tris_down = np.stack([at(b[down] + 1, c[down]), at(b[down] + 1, c[down] + 1),
                          at(b[down], c[down] + 1)], axis=1)
    local_tris = np.concatenate([tris_up, tris_down]).astype(np.int64)
    return bary, local_tris, idx


def _edge_ids(triangles: np.ndarray):
    """Undirected edge id of every half-edge ``3f + c`` (corner c -> c + 1)."""
    start = triangles.ravel()
    end = triangles[:, [1, 2, 0]].ravel()
    keys = np.minimum(start, end) * (int(triangles.max()) + 1) + np.maximum(start, end)
    unique, edge_id = np.unique(keys, return_inverse=True)
    return edge_id.reshape(-1, 3), len(unique), start.reshape(-1, 3) < end.reshape(-1, 3)



def _patches_and_domain(control_points, triangles, caller: str, why: str = ""):
    """``(cp (P, 28, 3), triangles (P, 3) int64)`` of a :class:`BezierSurface` or of
    control points plus their domain triangles, checked (the tessellators' entrance)."""
    if isinstance(control_points, BezierSurface):
        triangles = control_points.domain_mesh[1] if triangles is None else triangles
        control_points = control_points.control_points
    cp = _check_control_points(control_points)
    if triangles is None:
        raise ValueError(f"{caller} needs the domain triangles (P, 3) {why}".rstrip())
    tris = check_shape(triangles, "(P, 3)", "triangles", dtype=np.int64)
    if len(tris) != len(cp):
        raise ValueError(f"triangles has {len(tris)} rows but control_points {len(cp)} patches")
    return cp, tris

@one_blas_thread
def tessellate(control_points, level: int, triangles=None):
    """Uniform, welded triangulation of all patches.

    Parameters
    ----------
    control_points : (P, 28, 3) array_like or BezierSurface
        Patches; a :class:`BezierSurface` brings its own domain triangles.
    level : int
        Each patch edge is cut into ``2**level`` segments; a patch gives
        ``4**level`` triangles (level 0: one flat triangle per patch).
    triangles : (P, 3) int array_like, optional
        Domain triangles of the patches (vertex ids), required with a plain
        array: shared vertices along patch edges get one index through the
        shared edge's parametrisation (exact index sharing, no distance
        tolerance), so a closed domain mesh gives a watertight result.

    Returns
    -------
    vertices : (V, 3) float64
        Points on the patches (each evaluated exactly on one patch).
    triangles : (F, 3) int64
        Counter-clockwise as the domain triangles; ``F = P 4**level``.
    normals : (V, 3) float64
        Exact unit surface normals from the derivative nets.
    """
    cp, tris = _patches_and_domain(control_points, triangles, "tessellate",
                                   "to weld patch edges")
    level = int(level)
    if not 0 <= level <= 10:
        raise ValueError(f"level must be in 0..10, got {level}")
    segments = 2 ** level
    bary, local_tris, grid_idx = _grid(segments)
    layout = _SampleLayout.of(tris, segments, grid_idx)
    used = np.ones(layout.n_ids, dtype=bool)
    used[:layout.n_domain] = False
    used[tris] = True
    n_vertices = int(used.sum())
    # domain vertices no patch uses leave gaps in the ids: close them
    remap = np.cumsum(used) - 1 if n_vertices < len(used) else None
    vertices = _empty_pages((n_vertices, 3))
    out_normals = _empty_pages((n_vertices, 3))
    faces = _empty_pages((len(tris), local_tris.size), np.int64)  # (P, 4**level * 3)
    stacked = _points_and_derivatives_basis(bary)
    chunk = max(1, _CHUNK_ROWS // len(bary))  # bounds the (3S, chunk, 3) work arrays
    for start in range(0, len(cp), chunk):
        part = slice(start, start + chunk)
        gid = _global_sample_ids(tris[part], segments, grid_idx, layout, part)  # (chunk, S)
        if remap is not None:
            gid = remap[gid]
        _store_points_and_normals(_apply(stacked, cp[part]), gid, TOL.zero, vertices,
                                  out_normals)
        np.take(gid, local_tris.ravel(), axis=1, out=faces[part])
    return vertices, faces.reshape(-1, 3), out_normals


@numba.njit(cache=True, nogil=True)
def _store_points_and_normals(out, gid, zero, vertices, normals):  # pragma: no cover
    """Write points and unit normals of a chunk to their welded vertex ids.

    ``out`` ``(3S, P, 3)``: points, ``P_u`` and ``P_v`` at S samples of P patches
    (:func:`_points_and_derivatives_basis`); ``gid`` ``(P, S)``.  Samples are written
    sample-major (s outer, then p), so where patches share a vertex the last of them in
    that order gives it, as a sample-major fancy assignment would.  The normal is
    ``normalise(P_u x P_v)`` with the length floored at ``zero`` (see :func:`_unit`).
    """
    n_samples = out.shape[0] // 3
    for s in range(n_samples):
        for p in range(out.shape[1]):
            g = gid[p, s]
            ux, uy, uz = (out[n_samples + s, p, 0], out[n_samples + s, p, 1],
                          out[n_samples + s, p, 2])
            vx, vy, vz = (out[2 * n_samples + s, p, 0], out[2 * n_samples + s, p, 1],
                          out[2 * n_samples + s, p, 2])
            nx = uy * vz - uz * vy
            ny = uz * vx - ux * vz
            nz = ux * vy - uy * vx
            length = max(np.sqrt(nx * nx + ny * ny + nz * nz), zero)
            for d in range(3):
                vertices[g, d] = out[s, p, d]
            normals[g, 0] = nx / length
            normals[g, 1] = ny / length
            normals[g, 2] = nz / length


@dataclass(frozen=True)
class _SampleLayout:
    """Numbering of the welded tessellation vertices (see :func:`_global_sample_ids`)."""

    n_domain: int  # domain vertex ids 0 .. n_domain - 1 (the corners)
    edge_id: np.ndarray  # (P, 3) undirected edge of each patch edge
    forward: np.ndarray  # (P, 3) patch edge runs from the lower vertex id
    n_edges: int
    n_inner: int  # interior samples per patch
    n_ids: int  # ids in all: corners, then edge samples, then interior samples

    @classmethod
    def of(cls, tris: np.ndarray, segments: int, grid_idx: np.ndarray) -> _SampleLayout:
        edge_id, n_edges, forward = _edge_ids(tris)
        n_domain = int(tris.max()) + 1
        n_inner = int(np.all(grid_idx > 0, axis=1).sum())
        n_ids = n_domain + n_edges * max(segments - 1, 0) + len(tris) * n_inner
        return cls(n_domain, edge_id, forward, n_edges, n_inner, n_ids)


def _global_sample_ids(tris: np.ndarray, segments: int, grid_idx: np.ndarray,
                       layout: _SampleLayout | None = None,
                       rows: slice = slice(None)) -> np.ndarray:
    """Global vertex id of every (patch, sample): corners by domain vertex,
    edge samples by (undirected edge, position from the lower vertex id),
    interior samples per patch.

    ``tris`` are the patches ``rows`` of the mesh whose ``layout`` is given
    (default: the whole mesh), so that the ids can be made a chunk at a time.
    """
    if layout is None:
        layout = _SampleLayout.of(tris, segments, grid_idx)
    n_patches = len(tris)
    first = rows.start or 0
    edge_id, forward = layout.edge_id[rows], layout.forward[rows]
    a, b, c = grid_idx.T
    m = segments
    gid = np.empty((n_patches, len(grid_idx)), dtype=np.int64)
    # corners
    for corner, mask in enumerate([a == m, b == m, c == m]):
        gid[:, mask] = tris[:, corner:corner + 1]
    # edge-interior samples: edge 0 (c == 0, position b from corner 0), edge 1
    # (a == 0, position c from corner 1), edge 2 (b == 0, position a from corner 2)
    base = layout.n_domain
    for edge, (mask, pos) in enumerate([((c == 0) & (a > 0) & (b > 0), b),
                                         ((a == 0) & (b > 0) & (c > 0), c),
                                         ((b == 0) & (c > 0) & (a > 0), a)]):
        pos = pos[mask][None, :]
        along = np.where(forward[:, edge:edge + 1], pos, m - pos)
        gid[:, mask] = base + edge_id[:, edge:edge + 1] * (m - 1) + along - 1
    inner = (a > 0) & (b > 0) & (c > 0)
    n_inner = layout.n_inner
    start = base + layout.n_edges * max(m - 1, 0)
    patch = first + np.arange(n_patches)
    gid[:, inner] = start + patch[:, None] * n_inner + np.arange(n_inner)[None, :]
    return gid


# ----------------------------------------------------------------------------- a-priori level
def chord_error_bound(control_points) -> np.ndarray:
    """Upper bound of the distance between each patch and its flat triangle (level 0).

    With ``L`` the linear interpolant of the three corners, linear precision
    of the Bernstein basis (``sum_a B_a(u) a / n = u``) gives
    ``P(u) - L(u) = sum_a B_a(u) (b_a - L(a / n))``, a convex combination, so
    ``|P - L| <= max_a |b_a - L(a / n)|``: the largest distance of a control
    point from the flat triangle's point at the same Greville abscissa.

    Parameters
    ----------
    control_points : (P, 28, 3) array_like

    Returns
    -------
    (P,) float64, scene units
    """
    cp = _check_control_points(control_points)
    return _net_deviation(cp)


@cache
def _deviation_operator() -> np.ndarray:
    """``(28, 28)``: net minus the flat triangle of its corners at the Greville abscissae."""
    greville = index_table() / DEGREE  # (28, 3)
    pick = np.zeros((3, N_CONTROL))
    pick[[0, 1, 2], [0, 21, 27]] = 1.0  # corners b600, b060, b006
    operator = np.eye(N_CONTROL) - greville @ pick
    operator.flags.writeable = False
    return operator


def _net_deviation(cp: np.ndarray) -> np.ndarray:
    return _net_deviation_sp(cp.transpose(1, 0, 2))


def _net_deviation_sp(nets: np.ndarray) -> np.ndarray:
    """Chord bound of sample-major nets ``(28, P, 3)`` -> ``(P,)``."""
    diff = (_deviation_operator() @ nets.reshape(N_CONTROL, -1)).reshape(nets.shape)
    return np.sqrt(np.einsum("npd,npd->np", diff, diff)).max(axis=0)


def _second_difference_bound(cp: np.ndarray) -> np.ndarray:
    """``n (n - 1) M2 / 2`` per patch: bounds the chord error and shrinks by 4 per level.

    Taylor's formula about ``x = sum_i l_i v_i`` gives ``P(x) - L(x) =
    -sum_i l_i int_0^1 (1 - s) D^2_{v_i - x} P ds``; along ``v_i - x =
    sum_j l_j (v_i - v_j)`` the second derivative is at most ``n (n - 1) M2``
    with ``M2`` the largest (mixed) second difference of the net.
    """
    low = index_table(DEGREE - 2)
    worst = np.zeros(len(cp))
    eye = np.eye(3, dtype=np.int64)
    for i in range(3):
        for j in range(3):
            for k in range(j, 3):
                terms = [(eye[j] + eye[k], 1.0), (eye[i] + eye[k], -1.0),
                         (eye[i] + eye[j], -1.0), (2 * eye[i], 1.0)]
                diff = sum(w * cp[:, control_index(*(low + step).T)] for step, w in terms)
                worst = np.maximum(worst, np.linalg.norm(diff, axis=-1).max(axis=1))
    return 0.5 * DEGREE * (DEGREE - 1) * worst


def plane_deviation(control_points) -> np.ndarray:
    """Largest distance of each patch's control points from the plane of its corners.

    By the convex-hull property the patch lies within this distance of that plane, so
    it bounds the patch's distance *across* its flat triangle (level 0), not counting
    the parametrisation's motion along the surface that :func:`chord_error_bound`
    also counts.

    Parameters
    ----------
    control_points : (P, 28, 3) array_like

    Returns
    -------
    (P,) float64, scene units (``inf`` for a patch whose corners are collinear)
    """
    cp = np.ascontiguousarray(_check_control_points(control_points))
    return _plane_deviation(cp)


@numba.njit(cache=True, nogil=True)
def _plane_deviation(cp):  # pragma: no cover
    out = np.empty(cp.shape[0])
    for p in range(cp.shape[0]):
        ax, ay, az = cp[p, 0, 0], cp[p, 0, 1], cp[p, 0, 2]
        ux, uy, uz = cp[p, 21, 0] - ax, cp[p, 21, 1] - ay, cp[p, 21, 2] - az
        vx, vy, vz = cp[p, 27, 0] - ax, cp[p, 27, 1] - ay, cp[p, 27, 2] - az
        nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
        length = np.sqrt(nx * nx + ny * ny + nz * nz)
        if length == 0.0:
            out[p] = np.inf
            continue
        worst = 0.0
        for m in range(cp.shape[1]):
            h = ((cp[p, m, 0] - ax) * nx + (cp[p, m, 1] - ay) * ny
                 + (cp[p, m, 2] - az) * nz) / length
            worst = max(worst, abs(h))
        out[p] = worst
    return out


#: Largest number of sub-patches tessellation_level subdivides while searching.
_LEVEL_BUDGET = 2 ** 17


def tessellation_level(control_points, tolerance: float, max_level: int = 8) -> int:
    """Smallest tessellation level whose chord error is guaranteed <= ``tolerance``.

    Decided from the control nets before tessellating: patches whose
    :func:`chord_error_bound` exceeds the tolerance are split by de Casteljau
    and checked again, level by level (only the offending ones).  If that
    would exceed ``_LEVEL_BUDGET`` sub-patches, the remaining levels come from
    the second-difference bound ``n (n - 1) M2 / 2 / 4^L`` of the offending
    nets instead (also rigorous, more conservative).

    Parameters
    ----------
    control_points : (P, 28, 3) array_like
    tolerance : float
        Largest allowed distance between the tessellation and the surface,
        scene units (e.g. a fraction of the section spacing or the point noise).
    max_level : int
        Cap (a level-8 tessellation has 65536 triangles per patch).

    Returns
    -------
    int
        Level in ``0..max_level``.
    """
    cp = _check_control_points(control_points)
    if not np.isfinite(tolerance) or tolerance <= 0:
        raise ValueError(f"tolerance must be a positive number, got {tolerance}")
    nets = cp.transpose(1, 0, 2)  # (28, P, 3): sample-major, one GEMM per level
    split = _subdivision_matrices().reshape(4 * N_CONTROL, N_CONTROL)
    level = 0
    while level < max_level:
        bad = _net_deviation_sp(nets) > tolerance
        if not bad.any():
            return level
        offending = nets[:, bad]  # (28, B, 3)
        if 4 * len(offending[0]) > _LEVEL_BUDGET:
            bound = float(_second_difference_bound(offending.transpose(1, 0, 2)).max())
            more = np.ceil(np.log(max(bound / tolerance, 1.0)) / np.log(4.0))
            return int(min(max_level, level + more))
        children = (split @ offending.reshape(N_CONTROL, -1)).reshape(4, N_CONTROL, -1, 3)
        nets = children.transpose(1, 0, 2, 3).reshape(N_CONTROL, -1, 3)
        level += 1
    return max_level


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


# ----------------------------------------------------------------------------- the surface
@dataclass(frozen=True)
class BezierSurface:
    """Sextic triangular Bézier patches over a triangle mesh.

    Attributes
    ----------
    control_points : (P, 28, 3) float64
        One net per domain triangle, index order of :func:`index_table`.
    source_face : (P,) int64
        Control-mesh face each patch lies in (refinement splits a face in 4).
    domain_mesh : tuple of (V', 3) float64 and (P, 3) int64
        The mesh the patches are built over (the once-refined control mesh);
        patch p's corners ``b_600, b_060, b_006`` belong to
        ``domain_mesh[1][p]``'s three vertices.
    """

    control_points: np.ndarray
    source_face: np.ndarray
    domain_mesh: tuple[np.ndarray, np.ndarray]


@one_blas_thread
def control_net(vertices, triangles) -> BezierSurface:
    """Loop's G1 sextic Bézier surface over a triangle mesh (closed or bordered).

    Parameters
    ----------
    vertices : (V, 3) array_like, scene units
    triangles : (F, 3) int array_like
        Counter-clockwise seen from outside, 2-manifold (closed or with
        borders).

    Returns
    -------
    BezierSurface
        ``4F`` patches over the once Loop-refined mesh (see the module notes).

    Raises
    ------
    ValueError
        Non-finite vertices, out-of-range indices, non-manifold edges or
        vertices, inconsistent orientation, degenerate (zero-area) triangles.

    Notes
    -----
    Borders are allowed and handled by the ghost-layer rule of the module
    notes; vertices used by no triangle are dropped before refinement.
    """
    from surface._loop_patches import build_surface

    verts = check_shape(vertices, "(V, 3)", "vertices", dtype=np.float64)
    check_finite(verts, "vertices")
    tris = check_shape(triangles, "(F, 3)", "triangles")
    if not np.issubdtype(tris.dtype, np.integer):
        raise ValueError(f"triangles must hold integer vertex ids, got dtype {tris.dtype}")
    tris = tris.astype(np.int64)
    cp, source, refined_vertices, refined_tris = build_surface(verts, tris)
    share_boundaries(cp, refined_tris)
    return BezierSurface(cp, source, (refined_vertices, refined_tris))


def control_point_ids(triangles) -> tuple[np.ndarray, int]:
    """Topological id of every control point: shared boundary points get one id.

    Control point ``(i, j, k)`` of patch ``p`` is numbered as a sample of a
    degree-6 grid over the domain triangle (:func:`_global_sample_ids` with 6
    segments): a corner by its domain vertex, a point on an edge (one index 0)
    by the undirected domain edge and its position counted from the edge's lower
    vertex id, an interior point (no index 0) per patch.  Neighbouring patches
    therefore give their common boundary points the same id.

    Parameters
    ----------
    triangles : (P, 3) int array_like
        Domain triangles of the patches (``BezierSurface.domain_mesh[1]``),
        every vertex id in ``0 .. max`` used.

    Returns
    -------
    ids : (P, 28) int64
        Id of control point ``m`` of patch ``p``, in the module's index order.
    count : int
        ``V + 5 E + 10 P`` distinct ids (V domain vertices, E domain edges).
    """
    tris = check_shape(triangles, "(P, 3)", "triangles", dtype=np.int64)
    layout = _SampleLayout.of(tris, DEGREE, index_table())
    return _global_sample_ids(tris, DEGREE, index_table(), layout), layout.n_ids


def gather_shared(control_points: np.ndarray, ids: np.ndarray, count: int
                  ) -> tuple[np.ndarray, np.ndarray] | None:
    """The distinct points of a net numbered by ``ids``, or ``None`` where copies differ.

    Parameters
    ----------
    control_points : (P, N, 3) float64
    ids : (P, N) int64
        Id of every control point in ``0 .. count - 1`` (e.g. :func:`control_point_ids`).
    count : int

    Returns
    -------
    points : (count, 3) float64
        ``points[ids] == control_points`` (ids no point has are left zero).
    used : (count,) bool
        The ids some point has.
    Or ``None`` when two points of one id differ (``!=``).
    """
    cp = np.ascontiguousarray(control_points, dtype=np.float64)
    points = np.zeros((int(count), 3))
    used = np.zeros(int(count), dtype=np.bool_)
    ok = _gather_shared(cp, np.ascontiguousarray(ids, dtype=np.int64), points, used)
    return (points, used) if ok else None


@numba.njit(cache=True, nogil=True)
def _gather_shared(cp, ids, points, seen):  # pragma: no cover
    """One pass: the first copy of an id is stored, every later one compared (``!=``, as
    ``numpy.array_equal``; the nets are finite)."""
    for p in range(ids.shape[0]):
        for m in range(ids.shape[1]):
            g = ids[p, m]
            if not seen[g]:
                seen[g] = True
                for d in range(3):
                    points[g, d] = cp[p, m, d]
            else:
                for d in range(3):
                    if points[g, d] != cp[p, m, d]:
                        return False
    return True


def share_boundaries(control_points: np.ndarray, triangles: np.ndarray) -> float:
    """Make the boundary control points that neighbouring patches share bit-identical, in place.

    The construction computes a shared boundary point on both sides of an edge
    from different stencils (a box-spline GEMM per patch, or a ring operator),
    so the two copies agree only to rounding (measured on the demo's control
    mesh: a few units in the last place).  Each id of :func:`control_point_ids`
    takes the value one of its patches gave, so the surface is exactly
    watertight and its control net can be stored once per id
    (``pipeline.export`` format version 2).

    Parameters
    ----------
    control_points : (P, 28, 3) float64, changed in place
    triangles : (P, 3) int64
        Domain triangles, as for :func:`control_point_ids`.

    Returns
    -------
    float
        The largest change made (scene units).
    """
    ids, count = control_point_ids(triangles)
    if not control_points.flags.c_contiguous:
        raise ValueError("share_boundaries changes control_points in place: give a "
                         "C-contiguous array")
    return float(_share_rows(control_points.reshape(-1, 3), ids.ravel(), np.empty((count, 3))))


@numba.njit(cache=True, nogil=True)
def _share_rows(flat, ids, shared):  # pragma: no cover
    """``flat[r] = shared[ids[r]]`` with each id's value its last row's (rows in order, as
    a numpy fancy assignment leaves it); returns the largest coordinate change."""
    for r in range(len(ids)):
        for d in range(3):
            shared[ids[r], d] = flat[r, d]
    change = 0.0
    for r in range(len(ids)):
        for d in range(3):
            value = shared[ids[r], d]
            change = max(change, abs(value - flat[r, d]))
            flat[r, d] = value
    return change


# ----------------------------------------------------------------------------- tensor-product form
@cache
def _quad_matrix(corner: int) -> np.ndarray:
    """See :func:`_corner_quad_matrix`; the other corners by relabelling the net."""
    if corner == 0:
        return _corner_quad_matrix()
    # corner c of the net is corner 0 of the net relabelled (c, c + 1, c + 2) -> (0, 1, 2):
    # its point (i', j', k') is the original point whose exponent at corner c is i', ...
    multi = index_table()
    original = np.roll(multi, corner, axis=1)  # (i', j', k') -> exponents at (0, 1, 2)
    columns = control_index(original[:, 0], original[:, 1], original[:, 2])
    out = np.empty_like(_corner_quad_matrix())
    out[:, columns] = _corner_quad_matrix()
    out.flags.writeable = False
    return out


@cache
def _corner_quad_matrix() -> np.ndarray:
    """``(49, 28)`` map from a sextic triangular net to the degree (6, 6) tensor-product
    net of its quadrilateral at ``corner`` (corner, edge midpoint, centroid, edge midpoint).

    The quadrilateral is the image of the unit square under the bilinear map
    ``x(u, v) = (1-u)(1-v) e_c + u(1-v) m_{c,c+1} + u v g + (1-u) v m_{c,c+2}``
    (barycentric), so ``P(x(u, v))`` is a polynomial of degree 6 in u and in v,
    i.e. exactly a tensor-product Bézier patch.  Its net is found by
    interpolation at the 7 x 7 grid ``(a/6, b/6)`` in exact rational arithmetic
    (``fractions.Fraction``), so the matrix is exact to the last bit of each
    entry and its zeros are zeros (a quadrilateral's boundary row on the
    triangle's edge depends on that edge's 7 control points only).
    Row ``7 k + l`` is the pole of u-index k and v-index l.
    """
    from fractions import Fraction

    def bernstein1(k, x):
        return Fraction(factorial(DEGREE), factorial(k) * factorial(DEGREE - k)) \
            * x ** k * (1 - x) ** (DEGREE - k)

    eye = [[Fraction(int(a == b)) for b in range(3)] for a in range(3)]
    half = Fraction(1, 2)
    e_c, e_next, e_prev = eye[0], eye[1], eye[2]
    m_next = [half * (a + b) for a, b in zip(e_c, e_next, strict=True)]
    m_prev = [half * (a + b) for a, b in zip(e_c, e_prev, strict=True)]
    centroid = [Fraction(1, 3)] * 3
    nodes = [Fraction(a, DEGREE) for a in range(DEGREE + 1)]
    multi = index_table()
    weights = [Fraction(factorial(DEGREE), factorial(i) * factorial(j) * factorial(k))
               for i, j, k in multi.tolist()]
    values = []  # (49, 28): the triangle's Bernstein basis at the grid's images
    for u in nodes:
        for v in nodes:
            bary = [(1 - u) * (1 - v) * a + u * (1 - v) * b + u * v * c + (1 - u) * v * d
                    for a, b, c, d in zip(e_c, m_next, centroid, m_prev, strict=True)]
            values.append([w * bary[0] ** i * bary[1] ** j * bary[2] ** k
                           for w, (i, j, k) in zip(weights, multi.tolist(), strict=True)])
    # 1-D Bernstein collocation matrix and its inverse (Gauss-Jordan on fractions)
    n = DEGREE + 1
    aug = [[bernstein1(k, x) for k in range(n)] + [Fraction(int(r == c)) for c in range(n)]
           for r, x in enumerate(nodes)]
    for col in range(n):
        pivot = next(r for r in range(col, n) if aug[r][col] != 0)
        aug[col], aug[pivot] = aug[pivot], aug[col]
        scale = aug[col][col]
        aug[col] = [x / scale for x in aug[col]]
        for r in range(n):
            if r != col and aug[r][col] != 0:
                factor = aug[r][col]
                aug[r] = [x - factor * y for x, y in zip(aug[r], aug[col], strict=True)]
    inverse = [row[n:] for row in aug]
    out = np.zeros((n, n, N_CONTROL))
    for m in range(N_CONTROL):  # C = V^-1 X V^-T for each basis function's grid values X
        half_way = [[sum(inverse[k][a] * values[n * a + b][m] for a in range(n))
                     for b in range(n)] for k in range(n)]
        for k in range(n):
            for l in range(n):
                out[k, l, m] = float(sum(half_way[k][b] * inverse[l][b] for b in range(n)))
    out = out.reshape(n * n, N_CONTROL)
    out.flags.writeable = False
    return out


def tensor_product_nets(control_points) -> np.ndarray:
    """Each sextic triangular patch as three degree (6, 6) tensor-product Bézier patches.

    The triangle is split at its centroid and edge midpoints into three
    quadrilaterals, one per corner; each is exactly a non-degenerate
    tensor-product patch (:func:`_quad_matrix`), the form CAD kernels and STEP
    store (``B_SPLINE_SURFACE_WITH_KNOTS`` of degree 6 x 6 with Bézier knots).

    Parameters
    ----------
    control_points : (P, 28, 3) array_like

    Returns
    -------
    (P, 3, 7, 7, 3) float64
        ``out[p, c, k, l]`` is the pole ``(k, l)`` of the quadrilateral at corner
        ``c`` of patch ``p``: u runs from the corner to the midpoint of edge
        ``c -> c + 1``, v to the midpoint of edge ``c -> c + 2``, so
        ``dS/du x dS/dv`` points the way the triangle's normal does (outward for
        a counter-clockwise domain triangle); ``(6, 6)`` is the centroid.
    """
    cp = _check_control_points(control_points)
    stacked = np.concatenate([_quad_matrix(c) for c in range(3)])  # (147, 28)
    out = _apply(stacked, cp)  # (147, P, 3)
    return out.reshape(3, 7, 7, len(cp), 3).transpose(3, 0, 1, 2, 4)


# ------------------------------------------------------------------------ adaptive tessellation
@cache
def _adaptive_template(m: int, e0: int, e1: int, e2: int):
    """Samples and triangles of a patch cut ``m`` times inside and ``e_j`` times along edge j.

    Samples: the corners, ``e_j - 1`` points along edge ``j`` (corner j -> j + 1, equal
    steps) and the interior points of the uniform degree-m grid; triangles: the uniform
    grid's when every ``e_j == m``, else the Delaunay triangulation of the samples in the
    equilateral plane (``scipy.spatial.Delaunay``), so a patch meets finer neighbours
    without cracks.  Returns ``bary (S, 3)``, ``kind (S,)`` (0 corner, 1 edge, 2 interior),
    ``slot (S,)`` (corner or edge number), ``pos (S,)`` (step along the edge, or interior
    index), ``triangles (T, 3)`` counter-clockwise, and the largest triangle edge in units
    of the patch's edge (``diameter``).
    """
    from scipy.spatial import Delaunay

    eye = np.eye(3)
    bary, kind, slot, pos = [eye], [np.zeros(3, int)], [np.arange(3)], [np.zeros(3, int)]
    for j, e in enumerate((e0, e1, e2)):
        t = np.arange(1, e) / e
        bary.append((1 - t)[:, None] * eye[j] + t[:, None] * eye[(j + 1) % 3])
        kind.append(np.ones(e - 1, int))
        slot.append(np.full(e - 1, j))
        pos.append(np.arange(1, e))
    grid = index_table(m)
    inner = np.all(grid > 0, axis=1)
    bary.append(grid[inner] / m)
    kind.append(np.full(int(inner.sum()), 2))
    slot.append(np.zeros(int(inner.sum()), int))
    pos.append(np.arange(int(inner.sum())))
    bary, kind, slot, pos = (np.concatenate(a) for a in (bary, kind, slot, pos))
    xy = np.column_stack([bary[:, 1] + 0.5 * bary[:, 2], bary[:, 2] * np.sqrt(3.0) / 2])
    if e0 == e1 == e2 == m:  # the uniform grid's triangles, renumbered to this order
        grid_bary, local, _ = _grid(m)
        lookup = {tuple(np.round(b * m).astype(int)): i for i, b in enumerate(bary)}
        order = np.array([lookup[tuple(np.round(b * m).astype(int))] for b in grid_bary])
        tris = order[local]
    else:
        tris = Delaunay(xy).simplices.astype(np.int64)
    a, b, c = (xy[tris[:, i]] for i in range(3))
    signed = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    tris[signed < 0] = tris[signed < 0][:, [0, 2, 1]]
    area = np.abs(signed).sum() / 2
    if abs(area - np.sqrt(3.0) / 4) > 1e-9 or np.any(np.abs(signed) < 1e-14):
        raise RuntimeError(f"adaptive template ({m}, {e0}, {e1}, {e2}) is not a triangulation")
    edges = np.concatenate([b - a, c - b, a - c])
    diameter = float(np.sqrt((edges ** 2).sum(axis=1)).max())
    return bary, kind, slot, pos, tris, diameter


#: Sub-patches :func:`certified_segments` holds at once (28 x 3 float64 each: 2^20 ~ 700 MB).
_SPLIT_BUDGET = 2 ** 20


def certified_segments(control_points, tolerance: float, max_segments: int = 32) -> np.ndarray:
    """Per-patch cuts ``2^L``: the smallest level whose pieces all lie within ``tolerance``
    of the planes of their own corners.

    What a tessellation gets wrong is the surface's distance from its flat triangles
    *across* them: a patch lies within ``h = max_a |n . (b_a - b_600)|`` of the plane of
    its corners (:func:`plane_deviation`, convex-hull property).  A patch with ``h >
    tolerance`` is split at its edge midpoints (de Casteljau, :func:`subdivide`: the exact
    nets of the uniform grid's triangles) until every piece is within the tolerance;
    level ``L`` gives the patch ``2^L`` cuts.  The parametric bounds
    (:func:`adaptive_segments`, :func:`chord_error_bound`) also count the
    parametrisation's motion *along* the surface, which moves no point off it: on the
    demo's patches they are 40-2000x ``h``, and on the 5*10^4-point vase the parametric
    rule gives 4.15 M triangles where this one gives 160 516 for the same tolerance
    (measured once, 2026-12-03).  A patch still outside the tolerance after
    ``max_segments`` cuts keeps them; past ``_SPLIT_BUDGET`` pieces the remaining levels
    come from ``h ~ 1 / m^2``.

    Parameters
    ----------
    control_points : (P, 28, 3) array_like
    tolerance : float
        Chord tolerance, scene units (> 0).
    max_segments : int
        Cap of the cuts per patch edge.

    Returns
    -------
    (P,) int64, powers of two in ``1 .. max_segments``
    """
    cp = _check_control_points(control_points)
    if not np.isfinite(tolerance) or tolerance <= 0:
        raise ValueError(f"tolerance must be a positive number, got {tolerance}")
    cuts = np.ones(len(cp), dtype=np.int64)
    owner = np.arange(len(cp))
    nets = np.ascontiguousarray(cp)
    while len(nets):
        bad = np.unique(owner[plane_deviation(nets) > tolerance])
        bad = bad[2 * cuts[bad] <= max_segments]
        if not len(bad):
            break
        cuts[bad] *= 2
        keep = np.isin(owner, bad)
        if 4 * np.count_nonzero(keep) > _SPLIT_BUDGET:  # the rest from h ~ 1/m^2
            h = plane_deviation(nets[keep])
            worst = np.zeros(len(cp))
            np.maximum.at(worst, owner[keep], h)
            more = np.ceil(np.sqrt(worst[bad] / tolerance))
            cuts[bad] = np.minimum(max_segments, cuts[bad] * np.maximum(more, 1)).astype(np.int64)
            break
        nets = subdivide(nets[keep])
        owner = np.repeat(owner[keep], 4)
    return cuts


def adaptive_segments(control_points, tolerance: float, max_segments: int = 32) -> np.ndarray:
    """Per-patch segment count m with the chord error guaranteed within ``tolerance``.

    The second-difference bound ``B = n (n - 1) M2 / 2`` (:func:`_second_difference_bound`)
    bounds the distance between the patch and the flat triangle of its corners; a
    triangle whose edges are at most ``d`` (patch edge = 1) deviates by at most
    ``B d^2``, so the uniform grid with ``m = ceil(sqrt(B / tolerance))`` cuts is within
    the tolerance.

    Returns
    -------
    (P,) int64 in ``1 .. max_segments``
    """
    cp = _check_control_points(control_points)
    if not np.isfinite(tolerance) or tolerance <= 0:
        raise ValueError(f"tolerance must be a positive number, got {tolerance}")
    bound = _second_difference_bound(cp)
    return np.clip(np.ceil(np.sqrt(bound / tolerance)), 1, max_segments).astype(np.int64)


@one_blas_thread
def tessellate_adaptive(control_points, tolerance: float, triangles=None,
                        max_segments: int = 32, segments: np.ndarray | None = None):
    """Welded triangulation with a chord tolerance per patch, crack-free across patch edges.

    Each patch gets ``m_p`` cuts inside (:func:`certified_segments`); each domain edge
    is cut ``max(m_p, m_q)`` times (the finer of its two patches), and a patch whose edge
    is cut more finely than its inside meets it through a Delaunay transition
    (:func:`_adaptive_template`).  Samples on an edge are numbered by the undirected edge
    and their step from its lower vertex, so both patches use the same vertices: a closed
    domain gives a closed, manifold mesh.  Every piece of the uniform grid is within
    ``tolerance`` of its corners' plane (:func:`certified_segments`); a transition
    triangle is smaller than the grid's (its patch's edge is cut more finely), so no
    farther (measured in the tests).

    Parameters
    ----------
    control_points : (P, 28, 3) array_like or BezierSurface
    tolerance : float
        Chord tolerance, scene units (e.g. the points' sigma).
    triangles : (P, 3) int array_like, optional
        Domain triangles (a :class:`BezierSurface` brings its own).
    max_segments : int
        Cap of the cuts per patch edge.
    segments : (P,) int, optional
        The cuts per patch, when decided otherwise (e.g. for a screen:
        ``pipeline.render.screen_tessellation``); default :func:`certified_segments`
        (:func:`adaptive_segments` gives the parametric bound's cuts).

    Returns
    -------
    vertices (V, 3), triangles (F, 3), normals (V, 3)
        As :func:`tessellate`.
    """
    cp, tris = _patches_and_domain(control_points, triangles, "tessellate_adaptive")
    if segments is None:
        segments = certified_segments(cp, tolerance, max_segments)
    else:
        segments = np.asarray(segments, dtype=np.int64).reshape(-1)
        if len(segments) != len(cp) or segments.min(initial=1) < 1:
            raise ValueError(f"segments must be {len(cp)} positive cut counts")
    edge_id, n_edges, forward = _edge_ids(tris)
    edge_cuts = np.zeros(n_edges, dtype=np.int64)
    np.maximum.at(edge_cuts, edge_id.ravel(), np.repeat(segments, 3))
    n_domain = int(tris.max()) + 1
    edge_start = n_domain + np.concatenate([[0], np.cumsum(edge_cuts - 1)[:-1]])
    n_inner = (segments - 1) * (segments - 2) // 2
    inner_start = n_domain + int((edge_cuts - 1).sum()) + np.concatenate(
        [[0], np.cumsum(n_inner)[:-1]])
    n_vertices = int(inner_start[-1] + n_inner[-1]) if len(cp) else n_domain
    vertices = np.zeros((n_vertices, 3))
    out_normals = np.zeros((n_vertices, 3))
    keys = np.column_stack([segments, edge_cuts[edge_id]])  # (P, 4)
    base = int(keys.max(initial=0)) + 1  # one integer per key: a 1-D unique, not a row sort
    code = ((keys[:, 0] * base + keys[:, 1]) * base + keys[:, 2]) * base + keys[:, 3]
    _, first, group = np.unique(code, return_index=True, return_inverse=True)
    unique = keys[first]
    faces = []
    for g, key in enumerate(unique):  # one batch per template (few distinct ones)
        patches = np.flatnonzero(group.ravel() == g)
        bary, kind, slot, pos, local, _ = _adaptive_template(*(int(k) for k in key))
        gid = np.empty((len(patches), len(bary)), dtype=np.int64)
        corner = kind == 0
        gid[:, corner] = tris[patches][:, slot[corner]]
        for j in range(3):
            on = (kind == 1) & (slot == j)
            e = edge_id[patches, j][:, None]
            along = np.where(forward[patches, j][:, None], pos[on][None, :],
                             edge_cuts[e] - pos[on][None, :])
            gid[:, on] = edge_start[e] + along - 1
        inside = kind == 2
        gid[:, inside] = inner_start[patches][:, None] + pos[inside][None, :]
        _store_points_and_normals(_apply(_points_and_derivatives_basis(bary), cp[patches]),
                                  gid, TOL.zero, vertices, out_normals)
        faces.append(gid[:, local].reshape(-1, 3))
    return vertices, np.concatenate(faces), out_normals


# ----------------------------------------------------------------------------- closest points
#: How far past its patch's edges (in barycentrics) a foot point may lie (closest_points).
_EXTEND = 0.5


def closest_points(control_points, points, triangles=None, level: int = 1,
                   iterations: int = 4, tessellated=None):
    """Nearest points of the smooth surface itself (not of a tessellation) to ``points``.

    A flat tessellation lies inside a convex surface by its chord error, ``κ e² / 8``
    for edges ``e``: at the level-1 tessellation of a control mesh of edge ``h``
    (``e = h / 4``) that is ``κ h² / 128`` -- on the demo's sized candidates (h ≈ 0.08,
    κ ≈ 1) 5e-5, as large as the noise the sizing compares distances with, and growing
    as h², so that it, not the surface, decided how coarse a candidate could be.
    Here each point's nearest triangle of the level-``level`` tessellation (open3d's
    ``RaycastingScene.compute_closest_points``) gives its patch and a starting
    parameter, and Gauss-Newton on that patch's sextic ``P(r, s, t)`` (normal
    equations of the 2×2 tangent system, the parameter kept in the domain triangle)
    finds the foot of the perpendicular.  Vectorised over the points.

    A foot point past its start patch's edge (the start triangle belonged to the
    neighbour's side) is taken on the patch's polynomial continued past the edge
    (barycentrics down to ``-_EXTEND``): patches join C2 (box-spline regions) or G1,
    so the continuation leaves the neighbour by the jump of a higher derivative times
    the overshoot's cube -- measured on a unit sphere's surface (open3d resolution 8, points
    up to 0.01 off it), about 1e-6 at most (at the valence-8 poles) where a foot point kept
    inside its start patch erred by up to 7.5e-4 and the level-1 tessellation by 0.0024.
    A foot point that does not settle (no step below 1e-6 of the patch) or settles more
    than ``_EXTEND / 2`` past the edges keeps its start, a point of the surface.

    Parameters
    ----------
    control_points : (P, 28, 3) array_like or BezierSurface
    points : (N, 3) array_like
    triangles : (P, 3) int array_like, optional
        Domain triangles, required with a plain array (as :func:`tessellate`).
    level : int
        Tessellation level of the start (1: edges a quarter of the control mesh's).
    iterations : int
        Gauss-Newton steps (quadratic convergence from the tessellation's foot point;
        4 reach float64 round-off on the demo's patches).
    tessellated : surface.metrics.MeshDistance, optional
        The distance function of this surface's level-``level`` tessellation
        (:func:`tessellate`'s triangles in its order), if the caller has one: its
        raycasting scene is used instead of building another.

    Returns
    -------
    distance : (N,) float64
    patch : (N,) int64
        Patch of each foot point.
    bary : (N, 3) float64
        Its barycentric parameter on that patch.
    """
    import open3d as o3d

    cp, tris = _patches_and_domain(control_points, triangles, "closest_points",
                                   "to weld patch edges")
    p = check_shape(points, "(N, 3)", "points", dtype=np.float64)
    check_finite(p, "points")
    level = int(level)
    if tessellated is None:
        vertices, faces, _ = tessellate(cp, level, tris)
        centre = vertices.mean(axis=0)
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(o3d.core.Tensor((vertices - centre).astype(np.float32)),
                            o3d.core.Tensor(faces.astype(np.uint32)))
    else:
        scene, centre = tessellated.scene, tessellated.centre
    found = scene.compute_closest_points(o3d.core.Tensor((p - centre).astype(np.float32)))
    primitive = found["primitive_ids"].numpy().astype(np.int64)
    uv = found["primitive_uvs"].numpy().astype(np.float64)
    per_patch = 4 ** level
    patch = primitive // per_patch
    grid_bary, local_tris, _ = _grid(2 ** level)
    corners = grid_bary[local_tris[primitive % per_patch]]            # (N, 3 corners, 3)
    weights = np.stack([1.0 - uv[:, 0] - uv[:, 1], uv[:, 0], uv[:, 1]], axis=1)
    bary = np.einsum("nc,ncb->nb", weights, corners)
    du, dv = _derivative_operators()
    nets = cp[patch]                                                    # (N, 28, 3)
    start = bary
    moved = np.zeros(len(p))

    def at(b, rows=None):   # a batched matrix product: several times einsum's speed here
        return np.matmul(_bernstein(b, DEGREE)[:, None, :],
                         nets if rows is None else nets[rows])[:, 0]

    here = at(bary)
    for _ in range(max(0, int(iterations))):
        low = _bernstein(bary, DEGREE - 1)
        pu = np.matmul((low @ du)[:, None, :], nets)[:, 0]
        pv = np.matmul((low @ dv)[:, None, :], nets)[:, 0]
        r = p - here
        a, b, c = (np.einsum("nd,nd->n", pu, pu), np.einsum("nd,nd->n", pu, pv),
                   np.einsum("nd,nd->n", pv, pv))
        gu, gv = np.einsum("nd,nd->n", pu, r), np.einsum("nd,nd->n", pv, r)
        det = a * c - b * b
        ok = det > TOL.zero * np.maximum(a * c, TOL.zero)
        safe = np.where(ok, det, 1.0)
        step = np.stack([np.where(ok, (c * gu - b * gv) / safe, 0.0),
                         np.where(ok, (a * gv - b * gu) / safe, 0.0)], axis=1)
        # Gauss-Newton, its step halved (up to 3 times) where it would move away
        # (the halvings evaluate only the points that moved away)
        old = np.einsum("nd,nd->n", r, r)

        trial = _clipped_trial(bary, step)
        there = at(trial)
        worse = np.einsum("nd,nd->n", p - there, p - there) > old
        for _halving in range(3):
            redo = np.flatnonzero(worse)
            if not len(redo):
                break
            step[redo] *= 0.5
            trial[redo] = _clipped_trial(bary[redo], step[redo])
            there[redo] = at(trial[redo], redo)
            gap = p[redo] - there[redo]
            worse[redo] = np.einsum("nd,nd->n", gap, gap) > old[redo]
        keep = worse[:, None]
        bary = np.where(keep, bary, trial)
        here = np.where(keep, here, there)
        moved = np.where(worse, 0.0, np.hypot(step[:, 0], step[:, 1]))
    # a foot point that did not settle, or settled far past the patch's edges, is not on
    # the surface: such points keep the tessellation's start (a point of the surface)
    trusted = (moved < 1e-6) & (bary.min(axis=1) > -_EXTEND / 2)
    bary = np.where(trusted[:, None], bary, start)
    foot = np.where(trusted[:, None], here, at(start))
    return np.linalg.norm(p - foot, axis=1), patch, bary
