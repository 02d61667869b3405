r"""One sextic triangular Bézier patch: index order, Bernstein basis, evaluation, subdivision.

.. math::

    P(r, s, t) = \sum_{i+j+k=6} b_{ijk} \, B_{ijk}(r, s, t), \qquad
    B_{ijk} = \frac{6!}{i!\,j!\,k!} r^i s^j t^k, \quad r + s + t = 1,

``(r, s, t)`` weighting the domain corners ``tri[0..2]`` (counter-clockwise from outside).
The 28 control points ``(P, 28, 3)`` are stored descending in i, then in j:
``index(i, j, k) = m (m + 1) / 2 + k``, ``m = 6 - i`` (:func:`index_table`,
:func:`control_index`; the same rule for every degree here).  Evaluation and normals by
the Bernstein basis, subdivision into four by de Casteljau's blossoms, degree elevation
(Farin [1]_); also the surface's data type, :class:`BezierSurface`, and the allocator of
the large outputs (:func:`_empty_pages`).  The surface built from these patches is
:mod:`surface.bezier`.

References
----------
.. [1] G. Farin, "Triangular Bernstein-Bézier patches", CAGD 3 (1986) 83-127.
"""

from __future__ import annotations

import mmap
from dataclasses import dataclass
from functools import cache
from math import factorial

import numba
import numpy as np

from surface.validate import TOL, check_finite, check_shape

# as in matching.lsm: OpenMP first (the TBB layer here is too old and warns on stderr:
# an export-only process, which never imports matching.lsm, printed numba's TBB
# warning beside its own error line)
numba.config.THREADING_LAYER_PRIORITY = ["omp", "workqueue", "tbb"]

DEGREE = 6
N_CONTROL = (DEGREE + 1) * (DEGREE + 2) // 2  # 28


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


# ----------------------------------------------------------------------------- extension
#: How far past its patch's edges (in barycentrics) a foot point may lie (closest_points).
_EXTEND = 0.5


# ----------------------------------------------------------------------------- large outputs
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
