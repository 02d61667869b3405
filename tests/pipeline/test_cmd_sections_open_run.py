"""``photosurf run --open`` (``sections.open = true``): an end the data do not cover is left
as a border by the stitch stage and the smooth surface stays open there."""

import json

import numpy as np

from pipeline.cli import main
from pipeline.mesh_io import read_mesh
from surface import metrics as M
from surface.open_surface import boundary_loops
from tests.surface.test_holes import _capsule


def test_run_open_leaves_the_unseen_top_of_a_capsule_open(tmp_path):
    """The capsule of ``tests/surface/test_holes.py`` (r = 1, wall z in [0, 2], dome to
    z = 3) without its dome's points within 0.6 of the axis, 20 000 points.  With --open:
    the top is a hole, the bottom is not; the stitched and the smooth surfaces are one
    edge-manifold piece with one border loop, above z = 2.5 (the hole's rim is at
    z = 2 + sqrt(1 - 0.36) = 2.8).  Rerun without --open in the same workspace: the stitch
    stage runs again (sections.open is one of its parameters) and closes the mesh."""
    path = tmp_path / "capsule.npz"
    np.savez(path, points=_capsule(20_000, 0.6))
    out = tmp_path / "run"
    assert main(["run", str(path), "--out", str(out), "--open", "--to", "smooth",
                 "--quiet"]) == 0
    notes = json.loads((out / "stitch" / "stitch.json").read_text())
    assert notes["open"] is True and notes["holes"] == [False, True]
    assert any("hole in the data" in m and "left open" in m for m in notes["messages"])
    for mesh in (out / "stitch" / "mesh.ply", out / "smooth" / "surface.ply"):
        vertices, triangles = read_mesh(mesh)
        topo = M.mesh_topology(vertices, triangles)
        assert topo["components"] == 1 and topo["edge_manifold"] and not topo["closed"]
        borders = boundary_loops(triangles)
        assert len(borders) == 1 and vertices[borders[0], 2].min() > 2.5, mesh
        # the border follows the hole's rim (radius 0.6 at z = 2.8), within 0.15
        radius = np.hypot(*vertices[borders[0], :2].T)
        assert abs(np.median(radius) - 0.6) < 0.15, (mesh, np.median(radius))
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["stages"]["smooth"]["info"]["boundary_loops"] == 1
    # the ends' placements in the stitch stage's record: the flat base (z = 0) from its
    # cap points, noise-free, within a quarter point spacing (s = sqrt(area / N) ~ 0.033);
    # the hole's end from the wall points past the last section
    ends = manifest["stages"]["stitch"]["info"]["ends"]
    spacing = np.sqrt(7 * np.pi / 20_000)
    assert ends["bottom"]["how"] == "cap" and abs(ends["bottom"]["height"]) < 0.25 * spacing
    assert 0 <= ends["bottom"]["standard_error"] < 0.25 * spacing
    assert ends["top"]["how"] == "wall end" and 2.5 < ends["top"]["height"] < 3.0

    assert main(["run", str(path), "--out", str(out), "--to", "stitch", "--quiet"]) == 0
    notes = json.loads((out / "stitch" / "stitch.json").read_text())
    assert "open" not in notes and notes["closed"]
    assert M.mesh_topology(*read_mesh(out / "stitch" / "mesh.ply"))["closed"]
