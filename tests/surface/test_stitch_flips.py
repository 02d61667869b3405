"""stitch._interior_edge_faces is metrics.edge_table(...).edge_faces() in one sort."""

from __future__ import annotations

import numpy as np
import pytest

from surface import stitch
from surface.metrics import edge_table
from tests.surface.test_bezier import band_mesh, icosphere


@pytest.mark.parametrize("mesh", [icosphere, band_mesh])
def test_interior_edge_faces_equal_the_edge_table(mesh):
    _, tris = mesh()
    tris = tris[np.random.default_rng(0).permutation(len(tris))]  # any face order
    n_vertices = int(tris.max()) + 1
    table = edge_table(tris)
    want_ids, want_faces, want_corners = table.edge_faces()
    ids, faces, corners, keys = stitch._interior_edge_faces(tris, n_vertices)
    assert np.array_equal(ids, want_ids)
    assert np.array_equal(faces, want_faces)
    assert np.array_equal(corners, want_corners)
    assert np.array_equal(keys, stitch._edge_keys(table.edges, n_vertices))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_flips_with_kept_incidence_are_the_flips_of_full_scans(monkeypatch, seed):
    """delaunay_flips' late sweeps take the faces around the changed ones from the
    incidence it keeps across flips (a superset, rebuilt when it grows): the flips, the
    count and the faces are those of the scan of every face each sweep."""
    from tests.surface.test_stitch import Z_AXIS, vase_rings

    rng = np.random.default_rng(seed)
    rings = vase_rings(41, 48, a=1.5, b=0.8, twist=0.15)
    rings = [r + rng.normal(0, 0.01, r.shape) for r in rings]   # many cascading flips
    raw = stitch.stitch_rings(rings, Z_AXIS, flip=False)
    region = rng.integers(0, 2, len(raw.triangles)) if seed == 2 else None
    kept = stitch.delaunay_flips(raw.vertices, raw.triangles, region)
    sweeps = []
    original = stitch._flip_candidates

    def full_scan(vertices, triangles, region, fixed, cos_limit, active, around=None):
        sweeps.append(around is not None)
        return original(vertices, triangles, region, fixed, cos_limit, active)

    monkeypatch.setattr(stitch, "_flip_candidates", full_scan)
    scanned = stitch.delaunay_flips(raw.vertices, raw.triangles, region)
    assert sum(sweeps) >= 3               # the incidence was used in late sweeps
    assert kept[1] == scanned[1] > 100
    assert np.array_equal(kept[0], scanned[0])
    assert kept[2] and scanned[2]


def test_kept_incidence_holds_every_face_around_the_vertices(monkeypatch):
    """Each late sweep's faces hold every face now on one of the asked vertices (what
    the flips' candidates and the existence test of their new edges need)."""
    from tests.surface.test_stitch import Z_AXIS, vase_rings

    rng = np.random.default_rng(3)
    rings = [r + rng.normal(0, 0.01, r.shape) for r in vase_rings(41, 48, twist=0.15)]
    raw = stitch.stitch_rings(rings, Z_AXIS, flip=False)
    seen = {"mesh": None, "checked": 0, "added": 0}
    add, around = stitch._Incidence.add, stitch._Incidence.around

    def checked_add(self, vertices, faces, triangles):
        seen["mesh"] = triangles
        seen["added"] += len(vertices)
        return add(self, vertices, faces, triangles)

    def checked_around(self, vertices):
        faces = around(self, vertices)
        exact = np.flatnonzero(np.isin(seen["mesh"], vertices).any(axis=1))
        assert np.isin(exact, faces).all()
        assert np.all(np.diff(faces) > 0)
        seen["checked"] += 1
        return faces

    monkeypatch.setattr(stitch._Incidence, "REBUILD_SHARE", 0.2)  # rebuilt on the way too
    monkeypatch.setattr(stitch._Incidence, "add", checked_add)
    monkeypatch.setattr(stitch._Incidence, "around", checked_around)
    stitch.delaunay_flips(raw.vertices, raw.triangles)
    assert seen["checked"] >= 5 and seen["added"] > 0.4 * len(raw.triangles)
