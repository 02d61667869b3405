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
