"""``photosurf sections --open``: an end the data do not cover is left as a border."""

import numpy as np

from pipeline.cli import main
from pipeline.mesh_io import read_mesh
from surface import metrics as M
from surface.open_surface import boundary_loops
from tests.surface.test_holes import _capsule


def test_open_leaves_the_unseen_top_of_a_capsule_open(tmp_path, capsys):
    """The capsule of ``tests/surface/test_holes.py`` without its dome's points within 0.6
    of the axis (20 000 points): with --open the written mesh has one border loop, at the
    top, and is one edge-manifold piece; without it the same cloud gives a closed mesh."""
    path = tmp_path / "capsule.npz"
    np.savez(path, points=_capsule(20_000, 0.6))
    out = tmp_path / "open.ply"
    assert main(["sections", str(path), "--out", str(out), "--open"]) == 0
    assert ", open," in capsys.readouterr().out
    vertices, triangles = read_mesh(out)
    topo = M.mesh_topology(vertices, triangles)
    assert topo["components"] == 1 and topo["edge_manifold"] and not topo["closed"]
    borders = boundary_loops(triangles)
    assert len(borders) == 1 and vertices[borders[0], 2].min() > 2.5
    closed = tmp_path / "closed.ply"
    assert main(["sections", str(path), "--out", str(closed)]) == 0
    assert M.mesh_topology(*read_mesh(closed))["closed"]
