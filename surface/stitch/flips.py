"""Lawson's Delaunay flips over a stitched mesh (numba): the edge hash table, the flip
rules (folds, caps turned over as seen along the axis), :func:`delaunay_flips`."""

from __future__ import annotations

import numba
import numpy as np

from surface.metrics import edge_table
from surface.validate import TOL

__all__ = ['delaunay_flips']

#: Default largest turn of a face normal a flip may cause (radians).  A flip on
#: a smooth patch re-triangulates it and turns normals by about the local
#: dihedral angle; 45° is far above that and far below a fold-over (90°+).
MAX_NORMAL_CHANGE = np.pi / 4


# --------------------------------------------------------------------------- Lawson flips
def _edge_keys(pairs: np.ndarray, n_vertices: int) -> np.ndarray:
    lo = np.minimum(pairs[:, 0], pairs[:, 1])
    hi = np.maximum(pairs[:, 0], pairs[:, 1])
    return lo * n_vertices + hi


#: Share of the flips' edge table (open addressing, linear probing) its keys may fill
#: before it is rebuilt larger (:func:`_lawson`).
EDGE_TABLE_LOAD = 0.5


@numba.njit(cache=True, nogil=True)
def _slot(table: np.ndarray, key: int) -> int:  # pragma: no cover - numba
    """Slot of ``key`` in the open-addressing table ``table`` (keys, -1 empty; a power
    of two long): where it is, or the empty slot where it goes (linear probing)."""
    mask = np.uint64(len(table) - 1)
    h = np.uint64(key) * np.uint64(0x9E3779B97F4A7C15)
    i = (h ^ (h >> np.uint64(29))) & mask
    while table[i] != key and table[i] != -1:
        i = (i + np.uint64(1)) & mask
    return np.int64(i)


@numba.njit(cache=True, nogil=True)
def _empty_table(size: int) -> tuple:  # pragma: no cover - numba
    """Keys (-1: empty) and counts of an edge table of at least ``2·size`` slots."""
    n = 16
    while n < 2 * size:
        n *= 2
    return np.full(n, -1, np.int64), np.zeros(n, np.int64)


@numba.njit(cache=True, nogil=True)
def _grown(table: np.ndarray, count: np.ndarray) -> tuple:  # pragma: no cover - numba
    """The table's edges of positive count in one of at least four slots a key:
    ``(keys, counts, keys held)``."""
    live = int(np.count_nonzero(count > 0))
    new_table, new_count = _empty_table(2 * live)
    for j in range(len(table)):
        if count[j] > 0:
            i = _slot(new_table, table[j])
            new_table[i], new_count[i] = table[j], count[j]
    return new_table, new_count, live


@numba.njit(cache=True, nogil=True)
def _half_edges(tri: np.ndarray, n_v: int) -> tuple:  # pragma: no cover - numba
    """The edge table of ``tri`` (each edge's key ``lo·V + hi`` with its count of faces)
    and ``opp``: half-edge ``3f + c`` (corner c to c + 1) -> the other half of its edge
    when the edge has exactly two faces, else -1."""
    n_h = 3 * tri.shape[0]
    table, count = _empty_table(n_h // 2 + 1)  # ~one edge per two half-edges
    first = np.empty(len(table), np.int64)
    opp = np.full(n_h, -1, np.int64)
    for h in range(n_h):
        a, b = tri[h // 3, h % 3], tri[h // 3, (h % 3 + 1) % 3]
        i = _slot(table, min(a, b) * n_v + max(a, b))
        if table[i] == -1:
            table[i], first[i] = min(a, b) * n_v + max(a, b), h
        count[i] += 1
        if count[i] == 2:
            opp[first[i]], opp[h] = h, first[i]
        elif count[i] == 3:
            opp[opp[first[i]]] = -1
            opp[first[i]] = -1
    return table, count, opp


@numba.njit(cache=True, nogil=True)
def _angle_at(v: np.ndarray, apex: int, a: int, b: int) -> float:  # pragma: no cover - numba
    """The angle at ``apex`` of the triangle ``(apex, a, b)``: ``atan2(|u x w|, u . w)``
    for ``u = a - apex``, ``w = b - apex`` (the operations, in their order, of the array
    form's ``np.cross``, ``np.linalg.norm`` and ``einsum``: the reference in
    ``tests/surface/test_stitch_flips.py`` gives the same flips bit for bit)."""
    u0, u1, u2 = v[a, 0] - v[apex, 0], v[a, 1] - v[apex, 1], v[a, 2] - v[apex, 2]
    w0, w1, w2 = v[b, 0] - v[apex, 0], v[b, 1] - v[apex, 1], v[b, 2] - v[apex, 2]
    c0, c1, c2 = u1 * w2 - u2 * w1, u2 * w0 - u0 * w2, u0 * w1 - u1 * w0
    return np.arctan2(np.sqrt(c0 * c0 + c1 * c1 + c2 * c2), u0 * w0 + u1 * w1 + u2 * w2)


@numba.njit(cache=True, nogil=True)
def _normal_of(v: np.ndarray, i: int, j: int, k: int) -> tuple:  # pragma: no cover - numba
    """``metrics.face_normals(..., unit=False)`` of the face ``(i, j, k)``."""
    a0, a1, a2 = v[j, 0] - v[i, 0], v[j, 1] - v[i, 1], v[j, 2] - v[i, 2]
    b0, b1, b2 = v[k, 0] - v[i, 0], v[k, 1] - v[i, 1], v[k, 2] - v[i, 2]
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@numba.njit(cache=True, nogil=True)
def _folds(v: np.ndarray, tri: np.ndarray, f1: int, f2: int, c: int, a: int, d: int, b: int,
           cos_limit: float, zero: float) -> bool:  # pragma: no cover - numba
    """Whether a new face ``(c, a, d)`` or ``(d, b, c)`` turns its unit normal beyond
    ``cos_limit`` from the area-weighted normal of the faces ``f1``, ``f2`` it replaces
    (the array form's operations: ``metrics.face_normals``)."""
    p0, p1, p2 = _normal_of(v, tri[f1, 0], tri[f1, 1], tri[f1, 2])
    q0, q1, q2 = _normal_of(v, tri[f2, 0], tri[f2, 1], tri[f2, 2])
    o0, o1, o2 = p0 + q0, p1 + q1, p2 + q2
    norm = max(np.sqrt(o0 * o0 + o1 * o1 + o2 * o2), zero)
    o0, o1, o2 = o0 / norm, o1 / norm, o2 / norm
    for i0, i1, i2 in ((c, a, d), (d, b, c)):
        n0, n1, n2 = _normal_of(v, i0, i1, i2)
        length = np.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
        if length > zero:
            n0, n1, n2 = n0 / length, n1 / length, n2 / length
        else:
            n0, n1, n2 = 0.0, 0.0, 0.0
        if not n0 * o0 + n1 * o1 + n2 * o2 > cos_limit:
            return True
    return False


@numba.njit(cache=True, nogil=True)
def _turns_over(v: np.ndarray, tri: np.ndarray, f1: int, f2: int, c: int, a: int, d: int,
                b: int, axis: np.ndarray) -> bool:  # pragma: no cover - numba
    """Whether a new face ``(c, a, d)`` or ``(d, b, c)`` faces the other way along
    ``axis`` than the faces ``f1``, ``f2`` it replaces, which face one way: seen along
    the axis the quad is not convex and the flip folds a height field over itself."""
    p0, p1, p2 = _normal_of(v, tri[f1, 0], tri[f1, 1], tri[f1, 2])
    q0, q1, q2 = _normal_of(v, tri[f2, 0], tri[f2, 1], tri[f2, 2])
    up_1 = p0 * axis[0] + p1 * axis[1] + p2 * axis[2]
    up_2 = q0 * axis[0] + q1 * axis[1] + q2 * axis[2]
    if not up_1 * up_2 > 0.0:
        return False      # the pair is not a height field over the plane (a wall)
    for i0, i1, i2 in ((c, a, d), (d, b, c)):
        n0, n1, n2 = _normal_of(v, i0, i1, i2)
        if not (n0 * axis[0] + n1 * axis[1] + n2 * axis[2]) * up_1 > 0.0:
            return True
    return False


@numba.njit(cache=True, nogil=True)
def _lawson(v: np.ndarray, tri: np.ndarray, region: np.ndarray, fixed: np.ndarray,
            plane: np.ndarray, axis: np.ndarray, cos_limit: float, angle_tol: float,
            zero: float, max_sweeps: int, max_load: float) -> tuple:  # pragma: no cover - numba
    """:func:`delaunay_flips`' sweeps on ``tri`` in place: ``(flips, converged)``.

    Each sweep (i) finds the interior edges (exactly two faces) of the active faces
    whose faces share a region, run opposite ways and are not ``fixed`` (sorted keys),
    whose opposite angles sum above ``π + angle_tol``, whose new edge does not exist yet
    nor, in a region ``>= 0``, joins two vertices of one ``plane`` label ``>= 0``, nor,
    in a region ``< 0`` with a non-zero ``axis``, turns a face of a pair facing one way
    along it the other way (:func:`_turns_over`), and whose new faces keep their normals
    within ``cos_limit`` of the pair's area-weighted normal, and orders them by their
    keys ``lo·V + hi``; (ii) takes a maximal set of them no two of which share a face,
    by rounds of "each face keeps its largest-excess candidate" (ranks by a stable sort
    of the excesses, so ties go by key), then the first flip of each new edge; (iii)
    applies it.  The next sweep examines the faces of every candidate; when none is left
    after a partial sweep a full one confirms.  The half-edge partners ``opp`` and the
    edges' face counts (an open-addressing table, rebuilt when its keys, removed edges
    included, fill ``max_load`` of it) are kept across flips.
    """
    n_f, n_v = tri.shape[0], v.shape[0]
    check_axis = axis[0] != 0.0 or axis[1] != 0.0 or axis[2] != 0.0
    table, count, opp = _half_edges(tri, n_v)
    filled = int(np.count_nonzero(table != -1))  # a removed edge keeps its slot, count 0
    active = np.arange(n_f)
    is_active = np.ones(n_f, np.bool_)
    full = True
    total = 0
    best = np.full(n_f, -1, np.int64)
    taken = np.zeros(n_f, np.bool_)
    for _ in range(max_sweeps):
        # (i) candidates: each edge of an active face once
        m = 3 * len(active)
        f1s = np.empty(m, np.int64)
        f2s = np.empty(m, np.int64)
        new = np.empty((m, 4), np.int64)   # c, a, d, b: (c, a, d) and (d, b, c)
        excess = np.empty(m)
        new_keys = np.empty(m, np.int64)
        keys = np.empty(m, np.int64)
        n_c = 0
        for f in active:
            for corner in range(3):
                h = 3 * f + corner
                o = opp[h]
                if o < 0 or (is_active[o // 3] and o < h):
                    continue   # no partner, or the edge is met from its first half
                h, o = min(h, o), max(h, o)
                f1, k1, f2, k2 = h // 3, h % 3, o // 3, o % 3
                a, b = tri[f1, k1], tri[f1, (k1 + 1) % 3]
                if region[f1] != region[f2] or tri[f2, k2] != b or tri[f2, (k2 + 1) % 3] != a:
                    continue
                key = min(a, b) * n_v + max(a, b)
                pos = np.searchsorted(fixed, key)
                if pos < len(fixed) and fixed[pos] == key:
                    continue
                c, d = tri[f1, (k1 + 2) % 3], tri[f2, (k2 + 2) % 3]
                ex = _angle_at(v, c, a, b) + _angle_at(v, d, b, a) - np.pi
                if not ex > angle_tol or c == d:
                    continue
                if region[f1] >= 0 and plane[c] >= 0 and plane[c] == plane[d]:
                    continue   # a chord of one section: a flat face in its plane
                new_key = min(c, d) * n_v + max(c, d)
                if count[_slot(table, new_key)] > 0 or _folds(v, tri, f1, f2, c, a, d, b,
                                                              cos_limit, zero):
                    continue
                if region[f1] < 0 and check_axis and _turns_over(v, tri, f1, f2, c, a, d,
                                                                 b, axis):
                    continue   # a cap is a height field over the plane: no fold in it
                f1s[n_c], f2s[n_c], excess[n_c] = f1, f2, ex
                new[n_c, 0], new[n_c, 1], new[n_c, 2], new[n_c, 3] = c, a, d, b
                new_keys[n_c], keys[n_c] = new_key, key
                n_c += 1
        for f in active:
            is_active[f] = False
        if n_c == 0:
            if full:
                return total, True
            active, full = np.arange(n_f), True  # confirm with a full sweep
            is_active[:] = True
            continue
        by_key = np.argsort(keys[:n_c])  # distinct keys: any sort is the one order
        f1s, f2s, new = f1s[by_key], f2s[by_key], new[by_key]
        excess, new_keys = excess[by_key], new_keys[by_key]
        # (ii) a maximal set no two of which share a face, then one flip per new edge
        rank = np.empty(n_c, np.int64)
        rank[np.argsort(excess, kind="mergesort")] = np.arange(n_c)
        alive = np.ones(n_c, np.bool_)
        chosen = np.empty(n_c, np.int64)
        n_chosen = 0
        n_alive = n_c
        while n_alive > 0:
            for t in range(n_c):
                if alive[t]:
                    best[f1s[t]] = max(best[f1s[t]], rank[t])
                    best[f2s[t]] = max(best[f2s[t]], rank[t])
            start = n_chosen
            for t in range(n_c):
                if alive[t] and best[f1s[t]] == rank[t] and best[f2s[t]] == rank[t]:
                    chosen[n_chosen] = t
                    n_chosen += 1
            for t in range(start, n_chosen):
                taken[f1s[chosen[t]]] = True
                taken[f2s[chosen[t]]] = True
            n_alive = 0
            for t in range(n_c):
                best[f1s[t]] = -1
                best[f2s[t]] = -1
                if alive[t] and (taken[f1s[t]] or taken[f2s[t]]):
                    alive[t] = False
                n_alive += alive[t]
        for t in chosen[:n_chosen]:
            # (iii) (a, b, c), (b, a, d) -> (c, a, d), (d, b, c), the outer halves'
            # partners re-pointed; a second flip to the same new edge is dropped
            i = _slot(table, new_keys[t])
            if count[i] > 0:
                continue
            f1, f2 = f1s[t], f2s[t]
            c, a, d, b = new[t, 0], new[t, 1], new[t, 2], new[t, 3]
            k1 = 0 if tri[f1, 0] == a else (1 if tri[f1, 1] == a else 2)
            k2 = 0 if tri[f2, 0] == b else (1 if tri[f2, 1] == b else 2)
            o_bc, o_ca = opp[3 * f1 + (k1 + 1) % 3], opp[3 * f1 + (k1 + 2) % 3]
            o_ad, o_db = opp[3 * f2 + (k2 + 1) % 3], opp[3 * f2 + (k2 + 2) % 3]
            tri[f1, 0], tri[f1, 1], tri[f1, 2] = c, a, d
            tri[f2, 0], tri[f2, 1], tri[f2, 2] = d, b, c
            for h, o in ((3 * f1, o_ca), (3 * f1 + 1, o_ad), (3 * f2, o_db), (3 * f2 + 1, o_bc)):
                opp[h] = o
                if o >= 0:
                    opp[o] = h
            opp[3 * f1 + 2], opp[3 * f2 + 2] = 3 * f2 + 2, 3 * f1 + 2
            count[_slot(table, min(a, b) * n_v + max(a, b))] = 0
            if table[i] == -1:
                if filled + 1 > max_load * len(table):
                    table, count, filled = _grown(table, count)
                    i = _slot(table, new_keys[t])
                table[i] = new_keys[t]
                filled += 1
            count[i] = 2
            total += 1
        for t in range(n_chosen):
            taken[f1s[chosen[t]]] = False
            taken[f2s[chosen[t]]] = False
        # the faces of every candidate are examined again
        for t in range(n_c):
            is_active[f1s[t]] = True
            is_active[f2s[t]] = True
        active, full = np.flatnonzero(is_active), False
    return total, False


def delaunay_flips(vertices: np.ndarray, triangles: np.ndarray, region: np.ndarray | None = None,
                   fixed_edges: np.ndarray | None = None,
                   max_normal_change: float = MAX_NORMAL_CHANGE,
                   max_sweeps: int = 1000,
                   plane: np.ndarray | None = None,
                   axis: np.ndarray | None = None) -> tuple[np.ndarray, int, bool]:
    """Lawson flips until every flippable interior edge is locally Delaunay.

    Parameters
    ----------
    vertices : (V, 3) float64
    triangles : (F, 3) int64
        Consistently oriented, edge-manifold faces.
    region : (F,) int, optional
        Only edges whose two faces share a region label may flip (a flip keeps
        both faces in that region).  Default: one region.
    fixed_edges : (C, 2) int, optional
        Constraint edges that never flip (section contours).
    max_normal_change : float
        Largest angle (radians) between a new face normal and the old pair's
        area-weighted normal; larger flips are refused as fold-overs.
    max_sweeps : int
        Upper bound on sweeps.  Every sweep flips, at once, a set of
        non-Delaunay edges no two of which share a face (for each face the
        candidate with the largest angle excess, repeated until the set is
        maximal).  After the first sweep only
        edges of faces changed by the previous sweep are examined (a flip can
        only spoil the four edges of its own quad); a last full sweep
        confirms the fixed point.

    plane : (V,) int, optional
        Each vertex's section (``-1``: none).  In a region ``>= 0`` (a strip between
        two rings) no flip makes an edge between two vertices of one section: that
        face would lie flat in the section's plane, and where the strips on both sides
        of a thin loop (a finger, a spike) both take such faces they overlap.
    axis : (3,) float64, optional
        The section normal.  In a region ``< 0`` (a cap: a height field over the section
        plane, flat or a dome) no flip turns a face of a pair that faces one way along
        the axis the other way: the quad is then not convex seen along the axis, and in
        3-D the flip is still within ``max_normal_change`` on a steep dome (the noisy
        teapot's lid: 43 of 14 044 cap faces turned over, crossing their neighbours).

    Returns
    -------
    triangles : (F, 3) int64
        The flipped faces (same count, same regions, same orientation).
    flips : int
        Number of flips applied.
    converged : bool
        False if ``max_sweeps`` was reached with flips still pending.
    """
    v = np.ascontiguousarray(vertices, dtype=np.float64)
    tri = np.array(triangles, dtype=np.int64, copy=True, order="C")
    reg = np.zeros(len(tri), np.int64) if region is None else \
        np.ascontiguousarray(region, dtype=np.int64)
    fixed = (np.zeros(0, np.int64) if fixed_edges is None or len(fixed_edges) == 0
             else np.unique(_edge_keys(np.asarray(fixed_edges, np.int64), len(v))))
    labels = (np.full(len(v), -1, np.int64) if plane is None
              else np.ascontiguousarray(plane, dtype=np.int64))
    up = np.zeros(3) if axis is None else np.asarray(axis, np.float64).reshape(3)
    total, converged = _lawson(v, tri, reg, fixed, labels, up,
                               float(np.cos(max_normal_change)), TOL.angle, TOL.zero,
                               max_sweeps, EDGE_TABLE_LOAD)
    return tri, int(total), bool(converged)


def _flippable_edges(triangles: np.ndarray, region: np.ndarray, fixed: np.ndarray,
                     n_vertices: int) -> np.ndarray:
    """``(E,)`` bool over ``edge_table(triangles).edges``: one region on both sides, no contour."""
    table = edge_table(triangles)
    slots = table.face_edge.ravel()
    face_region = np.repeat(region, 3)
    lo = np.full(len(table.edges), np.iinfo(np.int64).max)
    hi = np.full(len(table.edges), np.iinfo(np.int64).min)
    np.minimum.at(lo, slots, face_region)
    np.maximum.at(hi, slots, face_region)
    fixed_keys = np.unique(_edge_keys(fixed, n_vertices))
    return (lo == hi) & ~np.isin(_edge_keys(table.edges, n_vertices), fixed_keys)
