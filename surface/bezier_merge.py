r"""Fewer, larger faces for CAD: the four patches of a control triangle as one face.

Loop's surface (``surface.bezier``) refines its control mesh once, so each control
triangle ``(A, B, C)`` carries four sextic patches: one at each corner and one in the
middle.  Here each control triangle becomes one degree (6, 6) tensor-product face over
``[0, 2]^2``, degenerate at ``A`` through the collapsed-square map (Duffy's)

    (lambda_A, lambda_B, lambda_C) = (1 - u/2, u/2 (1 - v/2), u/2 v/2),

with its real sides the control edges ``A -> B`` (``v = 0``), ``B -> C`` (``u = 2``) and
``A -> C`` (``v = 2``).  Two forms (``spans``):

- ``spans=2``: a B-spline with a knot of multiplicity 6 at 1 in both directions (13 x 13
  poles, four Bézier blocks joined C0 in the parameters).  Along a side the map is linear
  in each patch's own barycentric coordinates, so a side's 13 poles are its two patch
  edges' 7 + 7 control points, exactly: the edges are the patch edges.
- ``spans=1``: one Bézier net of 7 x 7 poles.  Each control edge is one sextic curve,
  the least-squares fit to its two patch edges with its end points and end tangents
  kept (the curve's first and last pole legs are twice the patch edges': the same
  derivative at the vertex), made once per edge and shared by both faces.

Either way the inner poles are the least-squares fit to the patches at 19 x 19 parameter
samples and to the patches' derivative across each side at 19 points a side (weight
:data:`DERIVATIVE_WEIGHT`), one fixed matrix for every face; matching the cross
derivative keeps the tangent plane along the sides, which the neighbour matches too.
:func:`merged_faces` reports each face's largest offset from the patches at the same
parameters on a finer 33 x 33 grid, split into its component along the patches' normal
(``deviation``: the distance between the surfaces, to first order) and along the surface
(``slide``: the two parametrisations differ, the shape does not; it adds at most
``slide^2 kappa / 2`` to the distance at curvature ``kappa``), and the largest angle
between the face's normal and the patches' along its sides (twice that bounds the kink
between neighbouring faces).
"""

from __future__ import annotations

from functools import cache
from math import comb

import numpy as np

from surface.bezier_patch import (
    _apply,
    _normals,
    _points_and_normals_sp,
    bernstein_matrix,
    control_index,
)

__all__ = ["DERIVATIVE_WEIGHT", "control_triangles", "face_points", "merged_faces"]

_FIT_SAMPLES = 19  # a side: 9 intervals a block
_CHECK_SAMPLES = 33
_CHUNK = 512  # faces a chunk: (512, 33 * 33, 3) doubles ~ 13 MB
#: Step (in the face's parameters) of the one-sided differences giving the patches'
#: derivative across a side: second order, so its error (~h^2 times the third
#: derivative) is far below the fit's.
_STEP = 1e-3
#: Weight of the cross-derivative rows against the point rows (parameters span 2, so a
#: derivative is about half a side long): the tangent plane along the sides, which
#: neighbouring faces share, is held first (weight 0: kinks up to 1.8 degrees on the
#: demo's surface; 10: 0.002 degrees, normal offset 2.7e-6 of a 3-unit vase).
DERIVATIVE_WEIGHT = 10.0


def control_triangles(triangles: np.ndarray, source_face: np.ndarray) -> dict | None:
    """The control triangles behind the patches, or None where the patches are not
    four per control triangle in the order ``bezier.control_net`` makes them.

    Returns
    -------
    dict or None
        ``corners (F, 3)`` domain vertex ids ``A, B, C`` (counter-clockwise as the
        patches), ``mids (F, 3)`` ``m_AB, m_BC, m_CA``, ``patches (F, 4)`` the patch ids
        of the corner patches at A, B, C and of the middle one.
    """
    tris = np.asarray(triangles, dtype=np.int64)
    source = np.asarray(source_face, dtype=np.int64)
    if len(source) != len(tris) or len(tris) % 4 or len(tris) == 0:
        return None
    order = np.argsort(source, kind="stable")
    if not np.array_equal(np.bincount(source[order]), np.full(len(tris) // 4, 4)):
        return None
    group = order.reshape(-1, 4)
    g = tris[group]  # (F, 4, 3)
    # as made: [A, mAB, mCA], [mAB, B, mBC], [mCA, mBC, C], [mBC, mCA, mAB]; turned over
    # (corners 1 and 2 swapped in every patch) the corner patches at B and C trade places
    for slots in ((0, 1, 2, 3), (0, 2, 1, 3)):
        pa, pb, pc, pm = (g[:, s] for s in slots)
        a, m_ab, m_ca = pa[:, 0], pa[:, 1], pa[:, 2]
        b, m_bc, c = pb[:, 1], pb[:, 2], pc[:, 2]
        ok = (np.array_equal(pb[:, 0], m_ab) and np.array_equal(pc[:, 0], m_ca)
              and np.array_equal(pc[:, 1], m_bc)
              and np.array_equal(pm, np.stack([m_bc, m_ca, m_ab], axis=1)))
        if ok:
            return {"corners": np.stack([a, b, c], axis=1),
                    "mids": np.stack([m_ab, m_bc, m_ca], axis=1),
                    "patches": group[:, list(slots)]}
    return None


def _times(basis: np.ndarray, nets: np.ndarray) -> np.ndarray:
    """``(S, K) x (F, K, 3) -> (F, S, 3)``: every face's poles through one basis as a
    single matrix product (numpy's ``einsum`` loops here: 70 % of the fit's time)."""
    flat = nets.transpose(1, 0, 2).reshape(nets.shape[1], -1)
    return (basis @ flat).reshape(len(basis), len(nets), 3).transpose(1, 0, 2)


def _bernstein_1d(t: np.ndarray, derivative: bool) -> np.ndarray:
    k = np.arange(7)
    binom = np.array([comb(6, i) for i in k], dtype=np.float64)
    t = t[:, None]
    if derivative:  # d/dt t^k (1 - t)^(6 - k)
        return binom * (k * t ** np.maximum(k - 1, 0) * (1.0 - t) ** (6 - k)
                        - (6 - k) * t ** k * (1.0 - t) ** np.maximum(5 - k, 0))
    return binom * t ** k * (1.0 - t) ** (6 - k)


def _basis(x: np.ndarray, spans: int, derivative: bool = False) -> np.ndarray:
    """``(S, n)`` the degree-6 basis on ``[0, 2]`` (or its derivative): one span, the
    Bernstein basis of ``x / 2`` (n = 7); two, knots 0^7 1^6 2^7, a Bernstein basis on
    each half sharing pole 6 (n = 13; a derivative at 1 is the upper half's)."""
    x = np.asarray(x, dtype=np.float64)
    if spans == 1:
        return _bernstein_1d(x / 2.0, derivative) * (0.5 if derivative else 1.0)
    out = np.zeros((len(x), 13))
    upper = x >= 1.0 if derivative else x > 1.0
    bern = _bernstein_1d(np.where(upper, x - 1.0, x), derivative)
    rows = np.arange(len(x))
    for i in range(7):
        out[rows, np.where(upper, 6 + i, i)] += bern[:, i]
    return out


def _tensor(u: np.ndarray, v: np.ndarray, spans: int, du: bool = False, dv: bool = False
            ) -> np.ndarray:
    """``(S, n^2)`` the tensor-product basis (or a first derivative) at ``(u, v)``."""
    a, b = _basis(u, spans, du), _basis(v, spans, dv)
    return np.einsum("sm,sl->sml", a, b).reshape(len(u), -1)


def _pieces(u: np.ndarray, v: np.ndarray):
    """Which patch slot (0-2 the corners at A, B, C; 3 the middle) holds each
    parameter sample, and its barycentric coordinates in that patch's own corner order."""
    lam = np.stack([1.0 - u / 2.0, u / 2.0 * (1.0 - v / 2.0), u / 2.0 * (v / 2.0)], axis=1)
    return _lambda_pieces(lam)


def _lambda_pieces(lam: np.ndarray):
    """:func:`_pieces` from barycentric coordinates ``(N, 3)`` in a control triangle's
    stored corner order: each sample's patch slot and its coordinates in that patch."""
    slot = np.full(len(lam), 3)
    for s in (2, 1, 0):  # a sample on a dividing line goes to a corner patch (either is exact)
        slot[lam[:, s] >= 0.5] = s
    mu = np.empty_like(lam)
    for s in range(3):
        sel = slot == s
        mu[sel] = 2.0 * lam[sel]
        mu[sel, s] -= 1.0
    sel = slot == 3
    mu[sel] = 1.0 - 2.0 * lam[sel]
    return slot, np.clip(mu, 0.0, 1.0)


@cache
def _samples(count: int):
    """A ``count x count`` parameter grid: ``(u, v)``, and per patch slot the sample
    indices and their Bernstein matrix."""
    x = np.linspace(0.0, 2.0, count)
    u, v = (a.ravel() for a in np.meshgrid(x, x, indexing="ij"))
    return u, v, _slotted(u, v)


def _slotted(u: np.ndarray, v: np.ndarray) -> list:
    slot, mu = _pieces(u, v)
    return [(np.flatnonzero(slot == s), mu[slot == s], bernstein_matrix(mu[slot == s]))
            for s in range(4)]


def _exact(cp: np.ndarray, patches: np.ndarray, pieces: list, normals: bool = False
           ) -> np.ndarray:
    """``(F, S, 3)`` the patches (or their unit normals) at the samples, each sample in
    its own slot's patch."""
    count = sum(len(sel) for sel, _, _ in pieces)
    out = np.empty((len(patches), count, 3))
    for s, (sel, mu, matrix) in enumerate(pieces):
        if sel.size:
            out[:, sel] = _normals(cp[patches[:, s]], mu) if normals else \
                _apply(matrix, cp[patches[:, s]]).transpose(1, 0, 2)
    return out


def _exact_with_normals(cp: np.ndarray, patches: np.ndarray, pieces: list
                        ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_exact`'s points and unit normals from one product a slot."""
    count = sum(len(sel) for sel, _, _ in pieces)
    points, normals = np.empty((2, len(patches), count, 3))
    for s, (sel, mu, _) in enumerate(pieces):
        if sel.size:
            at, unit = _points_and_normals_sp(cp[patches[:, s]], mu)
            points[:, sel], normals[:, sel] = at.transpose(1, 0, 2), unit.transpose(1, 0, 2)
    return points, normals


@cache
def _sides():
    """Points along the three real sides where the cross derivative is matched: ``(u, v)``,
    whether the derivative is along u, the inward sign, and the one-sided difference
    stencil's three sample sets."""
    x = np.linspace(0.0, 2.0, _FIT_SAMPLES)[1:]  # the apex (u = 0) has no cross direction
    y = np.linspace(0.0, 2.0, _FIT_SAMPLES)
    u = np.concatenate([x, np.full_like(y, 2.0), x])
    v = np.concatenate([np.zeros_like(x), y, np.full_like(x, 2.0)])
    across_u = np.concatenate([np.zeros_like(x), np.ones_like(y), np.zeros_like(x)]) > 0
    inward = np.concatenate([np.ones_like(x), -np.ones_like(y), -np.ones_like(x)])
    stencil = [_slotted(u + np.where(across_u, inward * k * _STEP, 0.0),
                        v + np.where(across_u, 0.0, inward * k * _STEP)) for k in range(3)]
    return u, v, across_u, inward, stencil


def _cross_derivatives(cp: np.ndarray, patches: np.ndarray) -> np.ndarray:
    """``(F, D, 3)`` the patches' derivative across each side point: inward one-sided
    second-order differences ``(-3 S0 + 4 S1 - S2) / 2h``, signed back to +u or +v."""
    *_, inward, stencil = _sides()
    s0, s1, s2 = (_exact(cp, patches, pieces) for pieces in stencil)
    return (-3.0 * s0 + 4.0 * s1 - s2) / (2.0 * _STEP) * inward[None, :, None]


@cache
def _fixed(spans: int) -> np.ndarray:
    """``(n, n)`` True where a pole is fixed by the face's boundary (row 0: the apex A;
    column 0, the last row and the last column: the sides)."""
    n = 6 * spans + 1
    out = np.zeros((n, n), dtype=bool)
    out[0, :] = out[-1, :] = out[:, 0] = out[:, -1] = True
    return out


@cache
def _operators(spans: int):
    """The point basis, the side-derivative basis and the ``(inner, S + D)``
    least-squares map from the residuals (the patches minus the fixed poles' share, at
    the point samples and of the cross derivatives) to the inner poles."""
    u, v, _ = _samples(_FIT_SAMPLES)
    points = _tensor(u, v, spans)
    su, sv, across_u, *_ = _sides()
    slopes = np.where(across_u[:, None], _tensor(su, sv, spans, du=True),
                      _tensor(su, sv, spans, dv=True))
    rows = np.concatenate([points, DERIVATIVE_WEIGHT * slopes])
    return points, slopes, np.linalg.pinv(rows[:, ~_fixed(spans).ravel()])


_K = np.arange(7)
_EDGE01 = control_index(6 - _K, _K, 0 * _K)  # a net's edge corner 0 -> 1
_EDGE12 = control_index(0 * _K, 6 - _K, _K)  # corner 1 -> 2
_EDGE02 = control_index(6 - _K, 0 * _K, _K)  # corner 0 -> 2


def _chains(cp: np.ndarray, patches: np.ndarray) -> np.ndarray:
    """``(F, 3, 13, 3)`` each face's sides 0 (A -> B), 1 (B -> C), 2 (A -> C) as the two
    patch edges' 7 + 7 control points, in increasing u or v."""
    pa, pb, pc = (cp[patches[:, s]] for s in range(3))
    out = np.empty((len(patches), 3, 13, 3))
    out[:, 0, :7], out[:, 0, 6:] = pa[:, _EDGE01], pb[:, _EDGE01]
    out[:, 1, :7], out[:, 1, 6:] = pb[:, _EDGE12], pc[:, _EDGE12]
    out[:, 2, :7], out[:, 2, 6:] = pa[:, _EDGE02], pc[:, _EDGE02]
    return out


@cache
def _curve_fit() -> np.ndarray:
    """``(7, 13)`` map from a chain of two sextic segments (13 poles, each segment half
    the parameter) to one sextic: end points and end derivatives kept, poles 2-4 the
    least-squares fit at 41 parameters."""
    t = np.linspace(0.0, 1.0, 41)
    chain = _basis(2.0 * t, 2)  # (41, 13): the chain at t
    one = _bernstein_1d(t, False)  # (41, 7)
    fixed = np.zeros((7, 13))
    fixed[0, 0] = 1.0
    fixed[1, 0], fixed[1, 1] = -1.0, 2.0  # Q1 = c0 + 2 (c1 - c0): the same derivative
    fixed[5, 12], fixed[5, 11] = -1.0, 2.0
    fixed[6, 12] = 1.0
    free = [2, 3, 4]
    residual = chain - one[:, [0, 1, 5, 6]] @ fixed[[0, 1, 5, 6]]
    fixed[free] = np.linalg.pinv(one[:, free]) @ residual
    return fixed


def _shared_sides(chains: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """``(F, 3, 7, 3)`` each side as one sextic fitted once per control edge (in the
    direction from its lower to its higher vertex id, from the first face naming it) and
    shared by both faces."""
    a, b, c = corners.T
    ends = np.stack([np.stack([a, b], 1), np.stack([b, c], 1), np.stack([a, c], 1)], axis=1)
    forward = ends[..., 0] < ends[..., 1]  # (F, 3) the side runs low -> high
    key = np.minimum(ends[..., 0], ends[..., 1]) * (int(corners.max()) + 1) \
        + np.maximum(ends[..., 0], ends[..., 1])
    _, first, inverse = np.unique(key.ravel(), return_index=True, return_inverse=True)
    flat_chains = chains.reshape(-1, 13, 3)[first]
    flat_forward = forward.ravel()[first]
    canonical = np.where(flat_forward[:, None, None], flat_chains, flat_chains[:, ::-1])
    curves = np.einsum("kj,ejd->ekd", _curve_fit(), canonical)  # (E, 7, 3) low -> high
    out = curves[inverse.reshape(-1, 3)]
    return np.where(forward[..., None, None], out, out[:, :, ::-1])


def _boundary(cp: np.ndarray, topo: dict, spans: int) -> np.ndarray:
    """``(F, n, n, 3)`` with the fixed poles set (the rest zero)."""
    patches = topo["patches"]
    sides = _chains(cp, patches)
    if spans == 1:
        sides = _shared_sides(sides, topo["corners"])
    n = 6 * spans + 1
    out = np.zeros((len(patches), n, n, 3))
    out[:, 0, :] = cp[patches[:, 0], :1]  # the apex A
    out[:, :, 0], out[:, -1, :], out[:, :, -1] = sides[:, 0], sides[:, 1], sides[:, 2]
    return out


def face_points(poles: np.ndarray, u, v, du: bool = False, dv: bool = False) -> np.ndarray:
    """``(F, S, 3)`` faces ``(F, n, n, 3)`` (n = 7 or 13) at parameters ``(u, v)`` in
    ``[0, 2]`` (or a first derivative)."""
    spans = (poles.shape[1] - 1) // 6
    basis = _tensor(np.asarray(u, float), np.asarray(v, float), spans, du, dv)
    return _times(basis, poles.reshape(len(poles), -1, 3))


@cache
def _angle_samples():
    x = np.linspace(0.0, 2.0, 17)[1:-1]
    u = np.concatenate([x, np.full_like(x, 2.0), x])
    v = np.concatenate([np.zeros_like(x), x, np.full_like(x, 2.0)])
    return u, v, _slotted(u, v)


def _side_angles(poles: np.ndarray, cp: np.ndarray, patches: np.ndarray) -> np.ndarray:
    """Largest angle (radians) a face's normal makes with the patches' along its three
    sides (15 points a side, the apex left out)."""
    u, v, pieces = _angle_samples()
    n_face = np.cross(face_points(poles, u, v, du=True), face_points(poles, u, v, dv=True))
    n_true = _exact(cp, patches, pieces, normals=True)
    cos = np.einsum("fsd,fsd->fs", n_face, n_true) / np.maximum(
        np.linalg.norm(n_face, axis=2) * np.linalg.norm(n_true, axis=2), 1e-300)
    return np.arccos(np.clip(cos, -1.0, 1.0)).max(axis=1)


#: Weight of a sample's whole offset (against 1 for its offset along the normal) in the
#: one-span fit: it keeps the parametrisation from folding; the shape is fitted along
#: the normal too, where the patches' parametrisation kinks cannot pull it.  On the
#: demo's 8 554 faces: 0.1, 1 352 faces fold (a normal turned over near the apex);
#: 0.3, 249; 1, 27; 3, 9, with the median kink 0.15 -> 0.22 degrees.
PARAMETER_WEIGHT = 1.0
_GEOMETRIC_SAMPLES = 13


@cache
def _geometric_operators():
    u, v, pieces = _samples(_GEOMETRIC_SAMPLES)
    points = _tensor(u, v, 1)
    su, sv, across_u, *_ = _sides()
    slopes = np.where(across_u[:, None], _tensor(su, sv, 1, du=True),
                      _tensor(su, sv, 1, dv=True))
    return points, slopes, pieces


def _geometric_fit(cp: np.ndarray, patches: np.ndarray, net: np.ndarray,
                   fixed: np.ndarray) -> np.ndarray:
    """``(F, 25, 3)`` inner poles of one-span faces: least squares of the offset from the
    patches along their normal at 13 x 13 samples (weight 1), of the face's derivative
    across each side along the patches' normal there (weight :data:`DERIVATIVE_WEIGHT`:
    the face's tangent plane the patches', so neighbours meet G1 to the accuracy of
    their shared edge's tangent) and of the whole offset (weight
    :data:`PARAMETER_WEIGHT`).  Linear in the poles, one 75 x 75 system a face."""
    points, slopes, pieces = _geometric_operators()
    target, normal = _exact_with_normals(cp, patches, pieces)
    side_normal = _exact(cp, patches, _sides()[4][0], normals=True)
    free = ~fixed
    known = _times(points[:, fixed], net[:, fixed])
    known_slope = _times(slopes[:, fixed], net[:, fixed])
    # rows over the unknowns (pole k, coordinate d), flattened k * 3 + d
    rows_n = np.einsum("sk,fsd->fskd", points[:, free], normal).reshape(len(patches), -1, 75)
    rhs_n = np.einsum("fsd,fsd->fs", target - known, normal)
    rows_t = np.einsum("sk,fsd->fskd", slopes[:, free], side_normal).reshape(
        len(patches), -1, 75) * DERIVATIVE_WEIGHT
    rhs_t = -np.einsum("fsd,fsd->fs", known_slope, side_normal) * DERIVATIVE_WEIGHT
    gram = np.einsum("fsa,fsb->fab", rows_n, rows_n) + np.einsum("fsa,fsb->fab", rows_t, rows_t)
    rhs = np.einsum("fsa,fs->fa", rows_n, rhs_n) + np.einsum("fsa,fs->fa", rows_t, rhs_t)
    b = points[:, free]
    gram += PARAMETER_WEIGHT ** 2 * np.kron(b.T @ b, np.eye(3))[None]
    rhs += PARAMETER_WEIGHT ** 2 * _times(b.T, target - known).reshape(len(patches), 75)
    return np.linalg.solve(gram, rhs[..., None])[..., 0].reshape(len(patches), 25, 3)


def merged_faces(control_points: np.ndarray, triangles: np.ndarray,
                 source_face: np.ndarray, spans: int = 1) -> dict | None:
    """One face per control triangle, fitted to its four patches.

    Parameters
    ----------
    control_points : (P, 28, 3) float64
    triangles : (P, 3) int64
        The patches' domain triangles (the once-refined control mesh).
    source_face : (P,) int64
        Each patch's control triangle (``BezierSurface.source_face``).
    spans : {1, 2}
        1: 7 x 7 Bézier faces with fitted edges; 2: 13 x 13 faces whose edges are the
        patch edges.

    Returns
    -------
    dict or None
        None where the patches are not four per control triangle; else
        :func:`control_triangles`' arrays and ``poles (F, n, n, 3)`` (u index first,
        ``u = 0`` collapsed to A), ``deviation (F,)`` each face's largest offset from
        the patches along their normal and ``slide (F,)`` along the surface (33 x 33
        grid, same parameters), ``angle (F,)`` the largest angle (radians) between its
        normal and the patches' along its sides.
    """
    if spans not in (1, 2):
        raise ValueError(f"spans must be 1 or 2, got {spans}")
    topo = control_triangles(triangles, source_face)
    if topo is None:
        return None
    cp = np.asarray(control_points, dtype=np.float64)
    patches = topo["patches"]
    points, slopes, operator = _operators(spans)
    _, _, fit_pieces = _samples(_FIT_SAMPLES)
    check_u, check_v, check_pieces = _samples(_CHECK_SAMPLES)
    check_basis = _tensor(check_u, check_v, spans)
    fixed = _fixed(spans).ravel()
    n = 6 * spans + 1
    boundary = _boundary(cp, topo, spans).reshape(len(patches), n * n, 3)
    poles = np.empty((len(patches), n, n, 3))
    deviation, slide, angle = (np.empty(len(patches)) for _ in range(3))
    for start in range(0, len(patches), _CHUNK):
        part = slice(start, start + _CHUNK)
        net, chunk = boundary[part], patches[part]
        if spans == 1:
            net[:, ~fixed] = _geometric_fit(cp, chunk, net, fixed)
        else:
            residual = _exact(cp, chunk, fit_pieces) - _times(points[:, fixed], net[:, fixed])
            slope = _cross_derivatives(cp, chunk) - _times(slopes[:, fixed], net[:, fixed])
            residual = np.concatenate([residual, DERIVATIVE_WEIGHT * slope], axis=1)
            net[:, ~fixed] = _times(operator, residual)
        poles[part] = net.reshape(-1, n, n, 3)
        exact, normal = _exact_with_normals(cp, chunk, check_pieces)
        offset = _times(check_basis, net) - exact
        along = np.einsum("fsd,fsd->fs", offset, normal)
        deviation[part] = np.abs(along).max(axis=1)
        slide[part] = np.sqrt(np.maximum(np.einsum("fsd,fsd->fs", offset, offset) - along ** 2,
                                         0.0)).max(axis=1)
        angle[part] = _side_angles(poles[part], cp, chunk)
    return {**topo, "poles": poles, "deviation": deviation, "slide": slide, "angle": angle}
