"""``photosurf run`` classifies each end as ``surface_from_points`` does
(``surface.reconstruct.classify_ends``): the open mouth of a wall too thin to part is left
open with one line, a parted wall keeps its inner wall and floor, and each end's kind and
its evidence go in the stitch stage's record."""

import json

import numpy as np
import pytest

from pipeline.cli import main
from pipeline.mesh_io import read_mesh
from surface import metrics as M
from surface.open_surface import boundary_loops
from testkit import cup as _cup

POINTS = 20_000


def _spacing() -> float:
    """Point spacing s = sqrt(area / N) of the 0.1-wall pot at :data:`POINTS` (0.038)."""
    return float(np.sqrt(_cup.vessel_area(_cup.vessel(0.1, False)) / POINTS))


def _over_the_mouth(vertices, triangles, wall, sigma) -> int:
    """Points sampled on the mesh inside the cavity, more than 5σ (and a spacing) from the
    inner face, above the floor: a flat fill or a dome over the mouth."""
    on_mesh = M.sample_mesh(vertices, triangles, 40_000, seed=1)
    r = np.hypot(on_mesh[:, 0], on_mesh[:, 1])
    return int(np.count_nonzero((on_mesh[:, 2] > _cup.VESSEL_FLOOR + 5 * sigma) & (
        r < _cup.VESSEL_RADIUS - wall - 5 * sigma - _spacing())))


@pytest.mark.slow
def test_run_leaves_the_mouth_of_a_wall_too_thin_to_part_open_with_one_line(tmp_path):
    """The pot (``testkit/cup.py``) with a wall half a point spacing thick, 20 000 points,
    noise 0.1 s, as a cloud input to ``photosurf run --to smooth``: the stitch stage
    records the top as a mouth (not parted, most columns from inside it meeting an even
    number of sheets: the floor, then the base), the bottom as a covered end; exactly one
    message says the wall is too thin; the stitched and the smooth surfaces are one piece
    with one border, at the rim (within 3 s of the top), and nothing of either lies over
    the mouth.  Before, the stage called the hole test alone and capped the mouth flat."""
    spacing = _spacing()
    wall, sigma = 0.5 * spacing, 0.1 * spacing
    path = tmp_path / "pot.npz"
    np.savez(path, points=_cup.vessel_sample(_cup.vessel(wall, False), POINTS, seed=0,
                                             sigma=sigma))
    out = tmp_path / "run"
    assert main(["run", str(path), "--out", str(out), "--to", "smooth", "--quiet",
                 "--set", "sections.axis=\"z\""]) == 0
    notes = json.loads((out / "stitch" / "stitch.json").read_text())
    assert notes["open"] is True and notes["mouths"] == [False, True]
    assert len([m for m in notes["messages"] if "too thin" in m]) == 1, notes["messages"]
    assert not [m for m in notes["messages"] if "a hole in the data" in m]
    ends = json.loads((out / "manifest.json").read_text())["stages"]["stitch"]["info"]["ends"]
    assert ends["top"]["kind"] == "mouth" and not ends["top"]["parted"]
    assert ends["top"]["even_columns"] > 0.5 and 0.3 <= ends["top"]["wall_spacings"] <= 2.0
    assert ends["bottom"]["kind"] == "none"
    for mesh in (out / "stitch" / "mesh.ply", out / "smooth" / "surface.ply"):
        vertices, triangles = read_mesh(mesh)
        assert M.mesh_topology(vertices, triangles)["components"] == 1
        borders = boundary_loops(triangles)
        assert len(borders) == 1, mesh
        assert vertices[borders[0], 2].min() > _cup.VESSEL_HEIGHT - 3 * spacing, mesh
        assert _over_the_mouth(vertices, triangles, wall, sigma) == 0, mesh


@pytest.mark.slow
def test_run_keeps_the_inner_wall_and_floor_of_a_wall_two_spacings_thick(tmp_path):
    """The same pot with a wall 2 s thick through ``photosurf run --to stitch``: the top is
    a parted mouth (nested loops, its rim capped; the rim's mean width recorded, within a
    spacing of 2 s), the mesh one closed piece of genus 0, nothing over the mouth, the
    truth's inner wall (0.5 < z < 1.8) within a quarter spacing of the mesh on average,
    and no line about a thin wall."""
    spacing = _spacing()
    wall, sigma = 2 * spacing, 0.1 * spacing
    f = _cup.vessel(wall, False)
    path = tmp_path / "mug.npz"
    np.savez(path, points=_cup.vessel_sample(f, POINTS, seed=0, sigma=sigma))
    out = tmp_path / "run"
    assert main(["run", str(path), "--out", str(out), "--to", "stitch", "--quiet",
                 "--set", "sections.axis=\"z\""]) == 0
    notes = json.loads((out / "stitch" / "stitch.json").read_text())
    assert "open" not in notes and notes["closed"]
    assert not [m for m in notes["messages"] if "too thin" in m]
    top = notes["ends"]["top"]
    assert top["kind"] == "mouth" and top["parted"]
    assert abs(top["wall_spacings"] - 2.0) < 1.0, top
    vertices, triangles = read_mesh(out / "stitch" / "mesh.ply")
    topo = M.mesh_topology(vertices, triangles)
    assert topo["closed"] and topo["components"] == 1 and topo["euler"] == 2
    assert _over_the_mouth(vertices, triangles, wall, sigma) == 0
    truth = _cup.vessel_sample(f, 20_000, seed=2)
    inner = (truth[:, 2] > 0.5) & (truth[:, 2] < 1.8) & (
        np.hypot(truth[:, 0], truth[:, 1]) < _cup.VESSEL_RADIUS - wall / 2)
    d = M.point_mesh_distance(truth[inner], vertices, triangles)
    assert d.mean() < 0.25 * spacing, d.mean() / spacing


@pytest.mark.slow
def test_sections_smooth_leaves_the_mouth_of_a_wall_too_thin_to_part_open(tmp_path, caplog):
    """``photosurf sections --smooth`` (the stages' own steps) on the pot with a wall half a
    spacing thick: no sizing (the stitched mesh is open at the mouth), the open mesh
    smoothed with its border rule, exit 0, exactly one warning line saying the wall is
    too thin, and the smooth surface one piece with one border at the rim.  Before, it
    stopped with "the stitched mesh is open"."""
    spacing = _spacing()
    wall, sigma = 0.5 * spacing, 0.1 * spacing
    path = tmp_path / "cloud.npz"
    np.savez(path, points=_cup.vessel_sample(_cup.vessel(wall, False), POINTS, seed=0,
                                             sigma=sigma))
    out = tmp_path / "pot.ply"   # its control net beside it as pot.npz
    with caplog.at_level("WARNING", logger="pipeline"):
        assert main(["sections", str(path), "--out", str(out), "--smooth", "--quiet"]) == 0
    lines = [r.getMessage() for r in caplog.records if "too thin" in r.getMessage()]
    assert len(lines) == 1, [r.getMessage() for r in caplog.records]
    vertices, triangles = read_mesh(out)
    assert M.mesh_topology(vertices, triangles)["components"] == 1
    borders = boundary_loops(triangles)
    assert len(borders) == 1
    assert vertices[borders[0], 2].min() > _cup.VESSEL_HEIGHT - 3 * spacing
    assert _over_the_mouth(vertices, triangles, wall, sigma) == 0
