"""``photosurf synth``: a small render end to end, and every bad recipe refused cleanly.

A bad recipe gives exit status 2, one line on stderr naming the recipe file and
the field, and leaves OUTDIR exactly as it was (absent, or untouched).
"""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.cli import main

GOOD = """
seed = 3
[shape]
kind = "revolution"
profile = [[0.0, 1.0], [1.5, 1.2], [3.0, 1.0]]
triangles = 2000
[cameras]
layout = "stereo"
width = 96
height = 72
[noise]
sigma = 2.0
"""


def _synth(tmp_path, text, capsys, *extra):
    recipe = tmp_path / "recipe.toml"
    recipe.write_text(text)
    out = tmp_path / "out"
    status = main(["synth", str(recipe), "--out", str(out), *extra])
    return status, capsys.readouterr(), recipe, out


def test_synth_writes_the_scene_folder(tmp_path, capsys):
    status, captured, _, out = _synth(tmp_path, GOOD, capsys, "-q", "--set", "seed=4")
    assert status == 0
    assert captured.err == "" and captured.out == ""
    for name in ["images/view_00.png", "images/view_01.png", "cameras.yml", "scene.json",
                 "sparse/cameras.txt", "sparse/images.txt", "sparse/points3D.txt",
                 "truth/mesh.ply", "truth/depth_00.npy", "truth/depth_01.npy",
                 "truth/correspondence.npy"]:
        assert (out / name).is_file(), name
    assert np.load(out / "truth" / "correspondence.npy").shape == (72, 96, 2)
    assert '"seed": 4' in (out / "scene.json").read_text()
    # nothing but the recipe and the folder beside it (no temporary left behind)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out", "recipe.toml"]


BAD = {
    "unknown field": (GOOD.replace('kind = "revolution"', 'kind = "revolution"\ncolour = 1'),
                      "field shape.colour: unknown field"),
    "missing field": (GOOD.replace("width = 96\n", ""), "field cameras.width: missing"),
    "missing table": (GOOD.replace('[cameras]\nlayout = "stereo"\nwidth = 96\nheight = 72\n',
                                   ""), "field cameras: missing"),
    "non-positive radius": (GOOD.replace("[1.5, 1.2]", "[1.5, -0.2]"),
                            "field shape.profile: radius must be positive"),
    "spline dips below zero": (
        GOOD.replace("[[0.0, 1.0], [1.5, 1.2], [3.0, 1.0]]",
                     "[[0.0, 0.05], [0.2, 1.5], [0.4, 0.05], [3.0, 0.05]]"),
        "field shape.profile: the interpolated radius becomes non-positive"),
    "wrong type": (GOOD.replace("width = 96", 'width = "wide"'),
                   "field cameras.width: expected an integer"),
    "unknown choice": (GOOD.replace('layout = "stereo"', 'layout = "orbit"'),
                       "field cameras.layout: 'orbit' is not one of"),
    "mesh path missing": (GOOD.replace(
        'kind = "revolution"\nprofile = [[0.0, 1.0], [1.5, 1.2], [3.0, 1.0]]\n'
        'triangles = 2000', 'kind = "mesh"\npath = "nowhere.ply"'),
        "field shape.path: no such mesh file"),
    "camera inside the object": (GOOD.replace("height = 72", "height = 72\ndistance = 0.5"),
                                 "field cameras.distance: view_00.png lies inside"),
    "object outside the image": (
        GOOD.replace("height = 72", "height = 72\nprincipal_point = [2000.0, 2000.0]"),
        "field cameras: view_00.png does not see the object"),
    "gain per view": (GOOD + "[lighting]\ngain = [1.0, 1.1, 1.2]\n",
                      "field lighting.gain: has 3 values for 2 views"),
    "invalid TOML": (GOOD + "[noise\n", "invalid TOML"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_recipe_exit_2_one_line_nothing_written(tmp_path, capsys, case):
    text, expected = BAD[case]
    status, captured, recipe, out = _synth(tmp_path, text, capsys)
    assert status == 2
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1, captured.err
    assert str(recipe) in lines[0] and expected in lines[0], lines[0]
    assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["recipe.toml"]


def test_bad_recipe_leaves_an_existing_outdir_untouched(tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    (out / "keep.txt").write_text("previous result")
    status, captured, _, _ = _synth(tmp_path, GOOD.replace("width = 96", "width = 0"), capsys)
    assert status == 2 and "field cameras.width: must be positive" in captured.err
    assert [p.name for p in out.iterdir()] == ["keep.txt"]
    assert (out / "keep.txt").read_text() == "previous result"


def test_missing_recipe_file_exit_2(tmp_path, capsys):
    status = main(["synth", str(tmp_path / "none.toml"), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert status == 2 and "none.toml" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists()


def test_bad_override_names_the_field(tmp_path, capsys):
    status, captured, _, out = _synth(tmp_path, GOOD, capsys, "--set", "cameras.zoom=2")
    assert status == 2 and "field cameras.zoom: unknown field" in captured.err
    assert not out.exists()
