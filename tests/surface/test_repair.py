"""Local repair of a control mesh whose smooth surface crosses itself (surface.repair,
pipeline.bezier_surface.smooth_mesh's ``repair``).

A flat disk with an interior vertex folded over its neighbours: the membrane of its
border (Tutte's barycentric embedding) unfolds it, inside the border, border untouched.
A capped prism whose top-centre vertex lies near the rim (a cap's fan folded over the
rim, as the stitch's cap fans do): the surface through its vertices crosses itself; the
repair relaxes the faces around the crossing and gives a valid solid of the same genus,
every control vertex away from the region untouched.
"""

from __future__ import annotations

import numpy as np

from pipeline.bezier_surface import smooth_mesh
from surface.fitting import interpolating_control_mesh
from surface.repair import crossing_faces, grow_faces, membrane
from surface.validity import check_solid, self_intersections


def _disk(rings: int = 4):
    """Hexagonal disk: vertex 0 the centre, ``rings`` rings of 6 k vertices."""
    v = [[0.0, 0.0, 0.0]]
    for k in range(1, rings + 1):
        for side in range(6):
            a0, a1 = np.pi / 3 * side, np.pi / 3 * (side + 1)
            p0 = k * np.array([np.cos(a0), np.sin(a0), 0.0])
            p1 = k * np.array([np.cos(a1), np.sin(a1), 0.0])
            v += [p0 + (p1 - p0) * j / k for j in range(k)]
    v = np.array(v)
    from scipy.spatial import Delaunay

    t = Delaunay(v[:, :2]).simplices.astype(np.int64)
    e1, e2 = v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]]
    flip = np.cross(e1, e2)[:, 2] < 0
    t[flip] = t[flip][:, [0, 2, 1]]
    return v, t


def test_membrane_unfolds_a_flat_disk_within_its_border():
    v, t = _disk()
    border = np.linalg.norm(v[:, :2], axis=1) > 3.4   # the outer ring (inradius 3.46)
    folded = v.copy()
    folded[0] = [2.6, 0.4, 0.0]          # the centre pushed over the second ring
    assert len(self_intersections(folded, t)) > 0
    moved_v, moved = membrane(folded, t, np.ones(len(t), dtype=bool))
    assert len(self_intersections(moved_v, t)) == 0
    assert set(moved.tolist()) == set(np.flatnonzero(~border).tolist())
    assert np.array_equal(moved_v[border], folded[border])   # the border stays, exactly
    # within the border's hull (the hexagon of side 4: its inradius 4 cos 30 deg)
    assert np.linalg.norm(moved_v[:, :2], axis=1).max() <= 4.0 + 1e-12
    assert np.abs(moved_v[:, 2]).max() <= 1e-12
    normals = np.cross(moved_v[t[:, 1]] - moved_v[t[:, 0]], moved_v[t[:, 2]] - moved_v[t[:, 0]])
    assert (normals[:, 2] > 0).all()                          # no face turned over


def test_region_growth_and_crossing_faces():
    v, t = _disk()
    region = crossing_faces(v, t, v[[0]] + 1e-3)
    assert region.sum() == 6                                  # the centre's fan
    assert grow_faces(region, t, 1).sum() == 24               # and the first ring's
    _, moved = membrane(v, t, grow_faces(region, t, 1))
    assert moved.tolist() == list(range(7))       # the centre and the first ring


def _capped_prism(n: int = 24, rings: int = 8):
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    v, t = [], []
    for k in range(rings):
        off = 0.5 * (k % 2) * 2 * np.pi / n
        v += [[np.cos(x + off), np.sin(x + off), k / (rings - 1)] for x in a]
    for k in range(rings - 1):
        for j in range(n):
            p, q = k * n + j, k * n + (j + 1) % n
            r, s = (k + 1) * n + j, (k + 1) * n + (j + 1) % n
            t += [[p, q, r], [q, s, r]] if k % 2 == 0 else [[p, q, s], [p, s, r]]
    bottom, top = len(v), len(v) + 1
    v += [[0.0, 0.0, 0.0], [0.0, 0.0, 1.0]]
    last = (rings - 1) * n
    for j in range(n):
        t += [[bottom, (j + 1) % n, j], [top, last + j, last + (j + 1) % n]]
    return np.array(v), np.array(t, dtype=np.int64), top


def test_smooth_mesh_repairs_a_crossing_surface_locally():
    v, t, top = _capped_prism()
    v[top] = [0.95, 0.3, 1.0]            # the cap's fan folded over the rim
    control = interpolating_control_mesh(v, t)
    plain = smooth_mesh(control, t, 2, check=False)
    before = len(check_solid(plain.vertices, plain.triangles).intersecting_pairs)
    assert before > 0                     # the case is one: the surface crosses itself
    repaired = smooth_mesh(control, t, 2)
    solid = repaired.solid
    assert solid["valid"] and solid["self_intersecting_pairs"] == 0
    assert solid["genus"] == 0 and solid["components"] == 1
    assert solid["repair"]["pairs_before"] == before
    # local: the faces relaxed are the top cap's fan and its rings, not the whole mesh
    assert 0 < solid["repair"]["faces"] <= len(t) // 3
    assert solid["repair"]["vertices_moved"] < len(v) // 4
    unrepaired = smooth_mesh(control, t, 2, repair=False)
    assert unrepaired.solid["self_intersecting_pairs"] == before
    assert "repair" not in unrepaired.solid


def test_thin_plate_fill_keeps_a_curved_cap_curved():
    """A cap of a unit sphere (the faces within 40 degrees of a pole), its interior vertices
    pulled in to the pole's tangent plane's depth: the membrane fills it flat (as deep as
    the cap's sagitta, 1 - cos 40 deg = 0.234), the thin-plate fill continues the
    surrounding slope and stays within a quarter of that of the sphere."""
    import open3d as o3d

    mesh = o3d.geometry.TriangleMesh.create_sphere(1.0, 24)
    v = np.asarray(mesh.vertices).copy()
    t = np.asarray(mesh.triangles).astype(np.int64)
    region = (v[t][:, :, 2].min(axis=1) > np.cos(np.radians(40)))
    flat, moved = membrane(v, t, region)
    thin, moved_thin = membrane(v, t, region, "biharmonic")
    assert len(moved) > 20 and np.array_equal(moved, moved_thin)
    sagitta = 1 - np.cos(np.radians(40))
    off_flat = np.abs(np.linalg.norm(flat[moved], axis=1) - 1).max()
    off_thin = np.abs(np.linalg.norm(thin[moved], axis=1) - 1).max()
    assert off_flat > 0.5 * sagitta
    assert off_thin < 0.25 * sagitta
