"""stitch.delaunay_flips (the numba kernel ``_lawson``) makes the flips of its array form.

The array form below is the implementation the kernel replaced (2026-12-01 / 2026-12-06), kept
here as the reference: each sweep lists the candidate flips among the edges of the
active faces in the order of their keys, takes a maximal independent set by rounds of
"each face keeps its largest-excess candidate", drops a second flip to the same new
edge and applies the rest at once.  The kernel must give the same faces bit for bit.
"""

from __future__ import annotations

import numpy as np
import pytest

from surface import stitch
from surface.metrics import edge_table, face_normals
from surface.validate import TOL
from tests.surface.test_bezier import band_mesh, icosphere


def _angle(vertices, apex, a, b):
    u = vertices[a] - vertices[apex]
    w = vertices[b] - vertices[apex]
    return np.arctan2(np.linalg.norm(np.cross(u, w), axis=1), np.einsum("ij,ij->i", u, w))


def _member(sorted_keys, query):
    if sorted_keys.size == 0:
        return np.zeros(query.shape, bool)
    pos = np.minimum(np.searchsorted(sorted_keys, query), sorted_keys.size - 1)
    return sorted_keys[pos] == query


def _candidates(vertices, triangles, region, fixed_keys, cos_limit, active):
    """One sweep's flips ``(f1, f2, new1, new2, excess, new keys)``, in edge-key order."""
    n_v = len(vertices)
    table = edge_table(triangles)
    edge_ids, faces, corners = table.edge_faces()
    edge_keys = stitch._edge_keys(table.edges, n_v)
    f1, f2 = faces[:, 0], faces[:, 1]
    k1, k2 = corners[:, 0], corners[:, 1]
    a = triangles[f1, k1]
    b = triangles[f1, (k1 + 1) % 3]
    keep = ((active[f1] | active[f2]) & (region[f1] == region[f2])
            & (triangles[f2, k2] == b) & (triangles[f2, (k2 + 1) % 3] == a)
            & ~_member(fixed_keys, edge_keys[edge_ids]))
    sel = np.flatnonzero(keep)
    f1, f2, k1, k2, a, b = f1[sel], f2[sel], k1[sel], k2[sel], a[sel], b[sel]
    c = triangles[f1, (k1 + 2) % 3]
    d = triangles[f2, (k2 + 2) % 3]
    excess = _angle(vertices, c, a, b) + _angle(vertices, d, b, a) - np.pi
    new_keys = stitch._edge_keys(np.stack([c, d], axis=1), n_v)
    sel = np.flatnonzero((excess > TOL.angle) & (c != d) & ~_member(edge_keys, new_keys))
    f1, f2, a, b, c, d = f1[sel], f2[sel], a[sel], b[sel], c[sel], d[sel]
    excess, new_keys = excess[sel], new_keys[sel]
    new1, new2 = np.stack([c, a, d], axis=1), np.stack([d, b, c], axis=1)
    old = face_normals(vertices, triangles[f1], unit=False) + face_normals(
        vertices, triangles[f2], unit=False)
    old /= np.maximum(np.linalg.norm(old, axis=1, keepdims=True), TOL.zero)
    ok = np.einsum("ij,ij->i", face_normals(vertices, new1), old) > cos_limit
    ok &= np.einsum("ij,ij->i", face_normals(vertices, new2), old) > cos_limit
    sel = np.flatnonzero(ok)
    return f1[sel], f2[sel], new1[sel], new2[sel], excess[sel], new_keys[sel]


def _independent(f1, f2, excess, new_keys, n_faces):
    rank = np.empty(len(f1), np.int64)
    rank[np.argsort(excess, kind="stable")] = np.arange(len(f1))
    taken = np.zeros(n_faces, bool)
    alive = np.ones(len(f1), bool)
    chosen = []
    while alive.any():
        live = np.flatnonzero(alive)
        best = np.full(n_faces, -1, np.int64)
        np.maximum.at(best, f1[live], rank[live])
        np.maximum.at(best, f2[live], rank[live])
        win = live[(best[f1[live]] == rank[live]) & (best[f2[live]] == rank[live])]
        chosen.append(win)
        taken[f1[win]] = True
        taken[f2[win]] = True
        alive &= ~(taken[f1] | taken[f2])
    chosen = np.concatenate(chosen)
    _, first = np.unique(new_keys[chosen], return_index=True)
    return chosen[first]


def reference_flips(vertices, triangles, region=None, fixed_edges=None,
                    max_normal_change=stitch.MAX_NORMAL_CHANGE, max_sweeps=1000):
    v = np.asarray(vertices, dtype=np.float64)
    tri = np.array(triangles, dtype=np.int64, copy=True)
    reg = np.zeros(len(tri), np.int64) if region is None else np.asarray(region, np.int64)
    fixed = (np.zeros(0, np.int64) if fixed_edges is None or len(fixed_edges) == 0
             else np.unique(stitch._edge_keys(np.asarray(fixed_edges, np.int64), len(v))))
    cos_limit = float(np.cos(max_normal_change))
    everything = np.ones(len(tri), bool)
    active, total = everything, 0
    for _ in range(max_sweeps):
        f1, f2, new1, new2, excess, new_keys = _candidates(v, tri, reg, fixed, cos_limit,
                                                           active)
        if len(f1) == 0:
            if active is everything:
                return tri, total, True
            active = everything
            continue
        chosen = _independent(f1, f2, excess, new_keys, len(tri))
        tri[f1[chosen]] = new1[chosen]
        tri[f2[chosen]] = new2[chosen]
        total += len(chosen)
        active = np.zeros(len(tri), bool)
        active[f1] = True
        active[f2] = True
    return tri, total, False


def _noisy_vase(seed: int, twist: float = 0.15):
    from tests.surface.test_stitch import Z_AXIS, vase_rings

    rng = np.random.default_rng(seed)
    rings = [r + rng.normal(0, 0.01, r.shape)
             for r in vase_rings(41, 48, a=1.5, b=0.8, twist=twist)]  # many cascading flips
    return stitch.stitch_rings(rings, Z_AXIS, flip=False), rng


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_flips_are_the_array_forms_bit_for_bit(seed):
    """Regions (seeds 1, 3) and fixed edges (seeds 2, 3) included; hundreds of flips."""
    raw, rng = _noisy_vase(seed)
    region = rng.integers(0, 2, len(raw.triangles)) if seed % 2 else None
    fixed = raw.triangles[rng.choice(len(raw.triangles), 60), :2] if seed >= 2 else None
    got = stitch.delaunay_flips(raw.vertices, raw.triangles, region, fixed)
    want = reference_flips(raw.vertices, raw.triangles, region, fixed)
    assert got[1] == want[1] > 300
    assert np.array_equal(got[0], want[0])
    assert got[2] and want[2]


def test_flips_stopped_by_max_sweeps_are_the_array_forms():
    raw, _ = _noisy_vase(4)
    for sweeps in (1, 2, 3):
        got = stitch.delaunay_flips(raw.vertices, raw.triangles, max_sweeps=sweeps)
        want = reference_flips(raw.vertices, raw.triangles, max_sweeps=sweeps)
        assert got[1] == want[1] > 0 and not got[2] and not want[2]
        assert np.array_equal(got[0], want[0])


def test_the_edge_table_rebuilt_on_the_way_changes_nothing():
    """A low load limit rebuilds the edge table many times during the flips."""
    raw, _ = _noisy_vase(5)
    v = np.ascontiguousarray(raw.vertices)
    args = (np.zeros(len(raw.triangles), np.int64), np.zeros(0, np.int64),
            np.full(len(v), -1, np.int64), np.zeros(3), float(np.cos(stitch.MAX_NORMAL_CHANGE)),
            TOL.angle, TOL.zero, 1000)
    tight = np.array(raw.triangles, np.int64)
    loose = tight.copy()
    flips_tight, _ = stitch._lawson(v, tight, *args, 0.26)
    flips_loose, _ = stitch._lawson(v, loose, *args, stitch.EDGE_TABLE_LOAD)
    assert flips_tight == flips_loose > 300
    assert np.array_equal(tight, loose)


@pytest.mark.parametrize("mesh", [icosphere, band_mesh])
def test_half_edge_partners_and_counts_are_the_edge_tables(mesh):
    _, tris = mesh()
    tris = np.ascontiguousarray(tris[np.random.default_rng(0).permutation(len(tris))])
    tris = np.vstack([tris, tris[:1]])      # one face twice: its edges lose their partners
    n_v = int(tris.max()) + 1
    table = edge_table(tris)
    keys, counts, opp = stitch._half_edges(tris, n_v)
    held = keys != -1
    want = dict(zip(stitch._edge_keys(table.edges, n_v).tolist(),
                    np.bincount(table.face_edge.ravel()).tolist(), strict=True))
    assert dict(zip(keys[held].tolist(), counts[held].tolist(), strict=True)) == want
    ids, faces, corners = table.edge_faces()
    partner = np.full(3 * len(tris), -1)
    two = np.bincount(table.face_edge.ravel())[ids] == 2
    first, second = 3 * faces[two, 0] + corners[two, 0], 3 * faces[two, 1] + corners[two, 1]
    partner[first], partner[second] = second, first
    assert np.array_equal(opp, partner)
    assert (opp == -1).sum() >= 6 and (opp >= 0).sum() > len(opp) // 2


def test_flips_of_messy_meshes_are_the_array_forms():
    """Random faces over few vertices (repeated corners, edges of three faces and more,
    both orientations, flat and not, two regions): the kernel flips as the array form."""
    flipped = 0
    for seed in range(60):
        rng = np.random.default_rng(seed)
        n_v = int(rng.integers(4, 30))
        vertices = rng.normal(size=(n_v, 3)) * [1.0, 1.0, 0.1 * (seed % 3)]
        faces = rng.integers(0, n_v, (int(rng.integers(2, 60)), 3))
        region = rng.integers(0, 2, len(faces)) if seed % 5 == 0 else None
        got = stitch.delaunay_flips(vertices, faces, region, max_sweeps=50)
        want = reference_flips(vertices, faces, region, max_sweeps=50)
        assert got[1:] == want[1:] and np.array_equal(got[0], want[0])
        flipped += got[1] > 0
    assert flipped >= 10
