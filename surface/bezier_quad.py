r"""Quadrilateral CAD faces: two control triangles, eight patches, one B-spline face.

``surface.bezier_merge`` writes each control triangle as one face collapsed at a corner;
OpenCascade's reading time follows the Bézier spans, and a one-span triangle face folds
beside its collapsed corner.  Here neighbouring control triangles ``(A, B, C)`` and
``(C, B, D)`` (sharing the control edge ``B - C``) are paired and written as one
degree (6, 6) B-spline face over ``[0, 2]^2`` with a knot of multiplicity 6 at 1 in both
directions (13 x 13 poles, four Bézier spans for eight patches: half the spans of two
triangle faces), corners ``A (0, 0)``, ``B (2, 0)``, ``D (2, 2)``, ``C (0, 2)``, no
collapsed corner.  The domain map is affine on each half of the square,

    u + v <= 2:  (lambda_A, lambda_B, lambda_C) = (1 - (u + v)/2, u/2, v/2),
    u + v >= 2:  (lambda_C, lambda_B, lambda_D) = (1 - u/2, 1 - v/2, (u + v)/2 - 1),

so each side is linear in its control triangle's barycentric coordinates and its 13 poles
are the side's two patch edges' 7 + 7 control points, exactly: the edges are the patch
edges, shared with the neighbour bit for bit.  The 121 inner poles are the least-squares
fit to the eight patches at :data:`FIT_SAMPLES` squared parameters, plus rows holding the
face's derivative across each side perpendicular to the patches' normal there (weight
:data:`NORMAL_WEIGHT`, 31 points a side), so the tangent plane along every side is the
patches' to the fit's accuracy and neighbouring faces meet G1.  Only the derivative's
normal component is held: its whole vector (as ``bezier_merge`` holds it) cannot be met
at the corners B and C, where the side from one triangle and the side from the other
ask for different twists (the demo: the median angle to the patches' normal along the
sides 0.14 degrees against 0.007).

Pairing: a matching on the dual graph of the control triangles (each pair shares an
edge), greedy in rounds: a triangle with one unpaired neighbour left is paired with it
first (Karp and Sipser), otherwise the pair closest to a parallelogram,
``|A + D - B - C| / (|A - D| + |B - C|)`` (0 for a parallelogram, where the two halves'
parametrisations agree across the diagonal and one polynomial fits both best).  Triangles
left unpaired stay ``bezier_merge``'s two-span triangle faces.

:func:`quad_faces` reports each face's largest offset from the patches along their normal
(``deviation``) and along the surface (``slide``) on a 33 x 33 grid, the largest angle
between its normal and the patches' along its sides (``angle``) and anywhere inside
(``inner_angle``: over 90 degrees, the face folds).
"""

from __future__ import annotations

from functools import cache

import numpy as np

from surface.bezier_merge import (
    _CHUNK,
    _EDGE01,
    _EDGE02,
    _STEP,
    _chains,
    _exact,
    _exact_with_normals,
    _lambda_pieces,
    _tensor,
    _times,
    control_triangles,
)
from surface.bezier_patch import bernstein_matrix

__all__ = ["FIT_SAMPLES", "pair_triangles", "quad_faces"]

#: Parameter samples a direction of the inner poles' fit (12 intervals a span: the
#: diagonal, where the two halves meet, crosses every span).
FIT_SAMPLES = 25
_CHECK_SAMPLES = 33
#: Largest corner angle of a quad (radians), at the ends of the shared edge: at 180
#: degrees the face's two side tangents there are parallel and its normal undefined.
MAX_ANGLE = np.radians(150.0)
#: Weight of the rows "the face's derivative across a side is perpendicular to the
#: patches' normal there" against the point rows (the demo's 3 081 quads, largest angle
#: to the patches' normal along the sides, median / 99th percentile: 10, 0.019 / 0.13
#: degrees; 30, 0.007 / 0.08; 100, 0.009 / 0.11 with 2 folded).
NORMAL_WEIGHT = 30.0
_SIDE_SAMPLES = 33


def pair_triangles(corners: np.ndarray, xyz: np.ndarray, angles: np.ndarray,
                   max_angle: float) -> np.ndarray:
    """Pairs of control triangles sharing an edge, each triangle in at most one pair.

    Parameters
    ----------
    corners : (F, 3) int64
        Each triangle's vertex ids, all triangles oriented alike.
    xyz : (F, 3, 3) float64
        The surface at each triangle's corners.
    angles : (F, 3) float64
        The surface's angle (radians) at each corner between the triangle's sides.
    max_angle : float
        Largest angle a quad may have at the shared edge's ends (the two triangles'
        angles there summed); pairs over it are not made.

    Returns
    -------
    (Q, 2) int64
        Triangle ids ``(t1, t2)``, ``t1 < t2``.
    """
    corners = np.asarray(corners, dtype=np.int64)
    n_faces = len(corners)
    nxt = np.roll(corners, -1, axis=1)
    lo, hi = np.minimum(corners, nxt).ravel(), np.maximum(corners, nxt).ravel()
    key = lo * (int(corners.max()) + 1) + hi
    order = np.argsort(key, kind="stable")
    k = key[order]
    twin = np.flatnonzero(k[1:] == k[:-1])
    first, second = order[twin], order[twin + 1]  # (face * 3 + side) of each shared edge
    f, g = first // 3, second // 3
    keep = f != g
    first, second, f, g = first[keep], second[keep], f[keep], g[keep]
    # the corners opposite the shared edge (side i runs corner i -> i + 1)
    a = xyz[f, (first % 3 + 2) % 3]
    d = xyz[g, (second % 3 + 2) % 3]
    b, c = xyz[f, first % 3], xyz[f, (first % 3 + 1) % 3]
    cost = np.linalg.norm(a + d - b - c, axis=1) / np.maximum(
        np.linalg.norm(a - d, axis=1) + np.linalg.norm(b - c, axis=1), 1e-300)
    i, j = first % 3, second % 3  # f's side i runs B -> C, g's side j C -> B
    wide = np.maximum(angles[f, i] + angles[g, (j + 1) % 3],
                      angles[f, (i + 1) % 3] + angles[g, j]) > max_angle
    f, g, cost = f[~wide], g[~wide], cost[~wide]
    partner = np.full(n_faces, -1)
    alive = np.ones(len(f), dtype=bool)
    while alive.any():
        idx = np.flatnonzero(alive)
        degree = np.bincount(f[idx], minlength=n_faces) + np.bincount(g[idx], minlength=n_faces)
        forced = np.minimum(degree[f[idx]], degree[g[idx]]) == 1
        rank = np.empty(len(idx), dtype=np.int64)
        rank[np.lexsort((cost[idx], ~forced))] = np.arange(len(idx))
        best = np.full(n_faces, len(idx))
        np.minimum.at(best, f[idx], rank)
        np.minimum.at(best, g[idx], rank)
        mutual = (best[f[idx]] == rank) & (best[g[idx]] == rank)
        pf, pg = f[idx[mutual]], g[idx[mutual]]
        partner[pf], partner[pg] = pg, pf
        alive &= (partner[f] < 0) & (partner[g] < 0)
    one = np.flatnonzero(partner > np.arange(n_faces))
    return np.column_stack([one, partner[one]]).astype(np.int64)


def _quad_pieces(u: np.ndarray, v: np.ndarray, r1: int, r2: int) -> list:
    """Per patch slot of a quad (0-3 the first triangle's, 4-7 the second's) the sample
    indices, their coordinates in that patch and its Bernstein matrix.  ``r1``, ``r2``:
    each triangle's stored corners are ``(A, B, C)`` and ``(C, B, D)`` rolled by them."""
    upper = u + v > 2.0
    lam1 = np.stack([1.0 - (u + v) / 2.0, u / 2.0, v / 2.0], axis=1)
    lam2 = np.stack([1.0 - u / 2.0, 1.0 - v / 2.0, (u + v) / 2.0 - 1.0], axis=1)
    lam = np.where(upper[:, None], lam2[:, (np.arange(3) + r2) % 3],
                   lam1[:, (np.arange(3) + r1) % 3])
    slot, mu = _lambda_pieces(lam)
    slot = slot + 4 * upper
    return [(np.flatnonzero(slot == s), mu[slot == s], bernstein_matrix(mu[slot == s]))
            for s in range(8)]


@cache
def _grid(count: int):
    x = np.linspace(0.0, 2.0, count)
    return tuple(a.ravel() for a in np.meshgrid(x, x, indexing="ij"))


@cache
def _sides():
    """Points inside the four sides (corners left out), whether the derivative there is
    along u, and the inward sign: ``v = 0``, ``u = 2``, ``v = 2``, ``u = 0``."""
    x = np.linspace(0.0, 2.0, _SIDE_SAMPLES)[1:-1]
    zero, two = np.zeros_like(x), np.full_like(x, 2.0)
    u = np.concatenate([x, two, x, zero])
    v = np.concatenate([zero, x, two, x])
    across_u = np.concatenate([zero, zero + 1, zero, zero + 1]) > 0
    inward = np.concatenate([zero + 1, zero - 1, zero - 1, zero + 1])
    return u, v, across_u, inward


@cache
def _pieces_cached(name: str, r1: int, r2: int, k: int = 0) -> list:
    if name == "fit":
        u, v = _grid(FIT_SAMPLES)
    elif name == "check":
        u, v = _grid(_CHECK_SAMPLES)
    else:  # the side stencil's k-th row
        u, v, across_u, inward = _sides()
        u = u + np.where(across_u, inward * k * _STEP, 0.0)
        v = v + np.where(across_u, 0.0, inward * k * _STEP)
    return _quad_pieces(u, v, r1, r2)


@cache
def _fixed() -> np.ndarray:
    out = np.zeros((13, 13), dtype=bool)
    out[0, :] = out[-1, :] = out[:, 0] = out[:, -1] = True
    return out.ravel()


@cache
def _operators():
    """The fit's fixed matrices.  Unknowns: the 40 inner poles next to the sides
    (``ring``) and the 81 inside them (``core``), which no side's cross derivative
    touches.  The core is eliminated (the point rows' least squares given the ring), so
    each face solves one 120 x 120 system: the point rows projected off the core's span
    (the same ``40 x 40`` block for x, y and z) plus its normal-derivative rows."""
    u, v = _grid(FIT_SAMPLES)
    points = _tensor(u, v, 2)
    su, sv, across_u, _ = _sides()
    slopes = np.where(across_u[:, None], _tensor(su, sv, 2, du=True),
                      _tensor(su, sv, 2, dv=True))
    index = np.arange(13)
    edge = (index == 1) | (index == 11)
    inner = (index > 0) & (index < 12)
    ring = (np.outer(inner, inner) & (edge[:, None] | edge[None, :])).ravel()
    core = (np.outer(inner, inner) & ~(edge[:, None] | edge[None, :])).ravel()
    core_map = np.linalg.pinv(points[:, core])  # (81, N)
    project = np.eye(len(u)) - points[:, core] @ core_map  # off the core's span
    to_ring = points[:, ring].T @ project  # (40, N)
    side = slopes[:, ring]  # (D, 40); slopes[:, core] is zero
    outer = np.einsum("ia,ib->iab", side, side).reshape(len(side), -1)
    return {"points": points, "slopes": slopes, "ring": ring, "core": core,
            "core_map": core_map, "to_ring": to_ring, "gram": to_ring @ points[:, ring],
            "side": side, "outer": outer}


def _directed(chains: np.ndarray, mids: np.ndarray, stored: np.ndarray, x: np.ndarray,
              y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(Q, 13, 3)`` the side ``x -> y`` of each triangle (its two patch edges' poles,
    from x), and its midpoint vertex."""
    out = np.empty((len(x), 13, 3))
    mid = np.full(len(x), -1)
    for k, (p, q) in enumerate(((0, 1), (1, 2), (0, 2))):
        fwd = (stored[:, p] == x) & (stored[:, q] == y)
        back = (stored[:, p] == y) & (stored[:, q] == x)
        out[fwd], out[back] = chains[fwd, k], chains[back, k, ::-1]
        mid[fwd | back] = mids[fwd | back, k]  # m_AB, m_BC, m_CA
    if (mid < 0).any():
        raise ValueError("a paired triangle lacks its side")
    return out, mid


def corner_angles(chains: np.ndarray) -> np.ndarray:
    """``(F, 3)`` each control triangle's angle at its corners between its sides' end
    tangents (``bezier_merge._chains``' sides 0 ``A -> B``, 1 ``B -> C``, 2 ``A -> C``)."""
    out = (chains[:, 0, 1] - chains[:, 0, 0], chains[:, 2, 1] - chains[:, 2, 0],
           chains[:, 0, 11] - chains[:, 0, 12], chains[:, 1, 1] - chains[:, 1, 0],
           chains[:, 1, 11] - chains[:, 1, 12], chains[:, 2, 11] - chains[:, 2, 12])
    t = np.stack(out, axis=1).reshape(-1, 3, 2, 3)
    t /= np.maximum(np.linalg.norm(t, axis=3, keepdims=True), 1e-300)
    return np.arccos(np.clip(np.einsum("fkd,fkd->fk", t[:, :, 0], t[:, :, 1]), -1.0, 1.0))


def _corner_xyz(cp: np.ndarray, patches: np.ndarray) -> np.ndarray:
    """``(F, 3, 3)`` the surface at each control triangle's corners A, B, C."""
    return np.stack([cp[patches[:, 0], _EDGE01[0]], cp[patches[:, 1], _EDGE01[6]],
                     cp[patches[:, 2], _EDGE02[6]]], axis=1)


def _quad_layout(topo: dict, pairs: np.ndarray) -> dict:
    """Each pair's quad corners ``A, B, D, C``, the rolls ``r1, r2`` of its triangles'
    stored corners, and the eight patches (the first triangle's, then the second's)."""
    corners = topo["corners"]
    t1, t2 = corners[pairs[:, 0]], corners[pairs[:, 1]]
    in2 = (t1[:, :, None] == t2[:, None, :]).any(axis=2)  # (Q, 3) corner of t1 in t2
    k1 = np.argmin(in2, axis=1)  # A: the corner of t1 not in t2
    in1 = (t2[:, :, None] == t1[:, None, :]).any(axis=2)
    m2 = np.argmin(in1, axis=1)  # D
    rows = np.arange(len(pairs))
    a = t1[rows, k1]
    b = t1[rows, (k1 + 1) % 3]
    c = t1[rows, (k1 + 2) % 3]
    d = t2[rows, m2]
    r1 = (-k1) % 3
    r2 = (2 - m2) % 3
    if not np.array_equal(t2[rows, (0 - r2) % 3], c):
        raise ValueError("paired triangles are not oriented alike")
    patches = np.concatenate([topo["patches"][pairs[:, 0]], topo["patches"][pairs[:, 1]]], 1)
    return {"corners": np.stack([a, b, d, c], axis=1), "r1": r1, "r2": r2, "patches": patches}


def _fit(cp: np.ndarray, patches: np.ndarray, net: np.ndarray, r1: int, r2: int) -> dict:
    """Inner poles of a chunk of quads sharing the rolls ``r1, r2`` (set in ``net``,
    ``(F, 169, 3)``), and their offsets from the patches."""
    op = _operators()
    fixed = _fixed()
    target = _exact(cp, patches, _pieces_cached("fit", r1, r2)) \
        - _times(op["points"][:, fixed], net[:, fixed])
    normal = _exact(cp, patches, _pieces_cached("side", r1, r2, 0), normals=True)
    known = np.einsum("fid,fid->fi", _times(op["slopes"][:, fixed], net[:, fixed]), normal)
    w2 = NORMAL_WEIGHT ** 2
    nn = np.einsum("fid,fie->fide", normal, normal).reshape(len(net), -1, 9)
    gram = w2 * np.einsum("ik,fil->fkl", op["outer"], nn).reshape(-1, 40, 40, 3, 3)
    gram += np.einsum("ab,de->abde", op["gram"], np.eye(3))[None]
    gram = gram.transpose(0, 1, 3, 2, 4).reshape(-1, 120, 120)
    rhs = _times(op["to_ring"], target) \
        - w2 * np.einsum("ia,fi,fid->fad", op["side"], known, normal)
    ring = np.linalg.solve(gram, rhs.reshape(-1, 120, 1)).reshape(-1, 40, 3)
    net[:, op["ring"]] = ring
    net[:, op["core"]] = _times(op["core_map"], target - _times(op["points"][:, op["ring"]],
                                                                    ring))
    return _offsets(cp, patches, net, r1, r2)


def _offsets(cp: np.ndarray, patches: np.ndarray, net: np.ndarray, r1: int, r2: int) -> dict:
    u, v = _grid(_CHECK_SAMPLES)
    exact, normal = _exact_with_normals(cp, patches, _pieces_cached("check", r1, r2))
    offset = _times(_tensor(u, v, 2), net) - exact
    along = np.einsum("fsd,fsd->fs", offset, normal)
    n_face = np.cross(_times(_tensor(u, v, 2, du=True), net),
                      _times(_tensor(u, v, 2, dv=True), net))
    cos = np.einsum("fsd,fsd->fs", n_face, normal) / np.maximum(
        np.linalg.norm(n_face, axis=2), 1e-300)
    angle = np.arccos(np.clip(cos, -1.0, 1.0))
    side = (u == 0) | (u == 2) | (v == 0) | (v == 2)
    return {"deviation": np.abs(along).max(axis=1),
            "slide": np.sqrt(np.maximum((offset ** 2).sum(2) - along ** 2, 0.0)).max(axis=1),
            "angle": angle[:, side].max(axis=1), "inner_angle": angle.max(axis=1)}


def quad_faces(control_points: np.ndarray, triangles: np.ndarray, source_face: np.ndarray,
               max_angle: float = MAX_ANGLE) -> dict | None:
    """Paired control triangles as quadrilateral faces.

    Parameters
    ----------
    control_points : (P, 28, 3) float64
    triangles : (P, 3) int64
        The patches' domain triangles (the once-refined control mesh), oriented alike.
    source_face : (P,) int64
        Each patch's control triangle.

    Returns
    -------
    dict or None
        None where the patches are not four per control triangle; else ``corners
        (Q, 4)`` the quads' vertex ids ``A, B, D, C`` at ``(u, v)`` = (0, 0), (2, 0),
        (2, 2), (0, 2); ``mids (Q, 4)`` the midpoint vertices of the sides ``A -> B``,
        ``B -> D``, ``C -> D``, ``A -> C``; ``poles (Q, 13, 13, 3)`` (u index first);
        ``deviation``, ``slide``, ``angle``, ``inner_angle`` ``(Q,)`` as the module
        says; ``pairs (Q, 2)`` the control triangles paired and ``single (S,)`` those
        left, both indexing ``triangles (F, 3)``, ``bezier_merge.control_triangles``'
        output, which is returned as ``triangles``.
    """
    topo = control_triangles(triangles, source_face)
    if topo is None:
        return None
    cp = np.asarray(control_points, dtype=np.float64)
    chains = _chains(cp, topo["patches"])
    pairs = pair_triangles(topo["corners"], _corner_xyz(cp, topo["patches"]),
                           corner_angles(chains), max_angle)
    lay = _quad_layout(topo, pairs)
    quad = lay["corners"]
    a, b, d, c = quad.T
    first, second = pairs[:, 0], pairs[:, 1]
    mids = np.empty((len(pairs), 4), dtype=np.int64)
    net = np.empty((len(pairs), 13, 13, 3))
    sides = ((first, a, b), (second, b, d), (second, c, d), (first, a, c))
    for s, (owner, x, y) in enumerate(sides):
        chain, mids[:, s] = _directed(chains[owner], topo["mids"][owner],
                                      topo["corners"][owner], x, y)
        if s == 0:
            net[:, :, 0] = chain
        elif s == 1:
            net[:, 12, :] = chain
        elif s == 2:
            net[:, :, 12] = chain
        else:
            net[:, 0, :] = chain
    net = net.reshape(len(pairs), 169, 3)
    stats = {k: np.empty(len(pairs)) for k in ("deviation", "slide", "angle", "inner_angle")}
    for r1 in range(3):
        for r2 in range(3):
            group = np.flatnonzero((lay["r1"] == r1) & (lay["r2"] == r2))
            for start in range(0, len(group), _CHUNK):
                part = group[start:start + _CHUNK]
                sub = net[part]
                got = _fit(cp, lay["patches"][part], sub, r1, r2)
                net[part] = sub
                for k, val in got.items():
                    stats[k][part] = val
    paired = np.zeros(len(topo["corners"]), dtype=bool)
    paired[pairs.ravel()] = True
    return {"corners": quad, "mids": mids, "poles": net.reshape(-1, 13, 13, 3), **stats,
            "pairs": pairs, "single": np.flatnonzero(~paired), "triangles": topo}
