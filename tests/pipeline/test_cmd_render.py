"""``photosurf render``: PNG written at the asked size; error colouring; bad input."""

import re

import cv2
import numpy as np
import open3d as o3d
import pytest

from pipeline.cli import main
from pipeline.mesh_io import write_mesh
from pipeline.render import coolwarm


def _sphere(radius, resolution=30):
    mesh = o3d.geometry.TriangleMesh.create_sphere(radius, resolution)
    return np.asarray(mesh.vertices), np.asarray(mesh.triangles)


@pytest.fixture(scope="module")
def meshes(tmp_path_factory):
    folder = tmp_path_factory.mktemp("meshes")
    write_mesh(folder / "sphere.ply", *_sphere(1.0))
    write_mesh(folder / "big.ply", *_sphere(1.05))
    return folder


def test_render_writes_the_sheet(tmp_path, meshes, capsys):
    out = tmp_path / "r.png"
    assert main(["render", str(meshes / "sphere.ply"), "--out", str(out),
                 "--size", "300x200"]) == 0
    assert "6 views, 300x200" in capsys.readouterr().out
    image = cv2.imread(str(out))
    assert image.shape == (200, 300, 3)
    for row in range(2):
        for col in range(3):  # a sphere in every tile of the 3x2 sheet
            tile = image[row * 100:(row + 1) * 100, col * 100:(col + 1) * 100]
            assert 0.4 < np.any(tile != 255, axis=2).mean() < 0.75
    assert [p.name for p in tmp_path.iterdir()] == ["r.png"]


def test_render_with_truth_colours_by_distance(tmp_path, meshes):
    # sphere of radius 1.05 against the unit sphere: +0.05 everywhere; with
    # --range 0.1 that is 3/4 of the cool-warm map (a warm orange).
    out = tmp_path / "e.png"
    assert main(["render", str(meshes / "big.ply"), "--out", str(out), "--truth",
                 str(meshes / "sphere.ply"), "--views", "1", "--size", "200x260",
                 "--range", "0.1"]) == 0
    image = cv2.imread(str(out))[:, :, ::-1]
    centre = image[95:105, 95:105].reshape(-1, 3).astype(float)
    want = coolwarm(np.array([0.75]))[0] * 255
    # lit at the centre by ambient + key·cos: same hue, red channel dominant
    ratio = centre.mean(axis=0) / want
    assert np.all(np.abs(ratio / ratio.mean() - 1) < 0.08), (centre.mean(axis=0), want)


@pytest.mark.parametrize("argv_tail, message", [
    (["missing.ply", "--out", "{out}/r.png"], r"missing\.ply: no such mesh file"),
    (["{meshes}/sphere.ply", "--out", "{out}/r.jpg"], r"r\.jpg: renders are written as \.png"),
    (["{meshes}/sphere.ply", "--out", "{out}/r.png", "--range", "0.1"], r"--range needs --truth"),
    (["{meshes}/garbage.ply", "--out", "{out}/r.png"], r"garbage\.ply: no triangles"),
    (["{meshes}/sphere.ply", "--out", "{out}/r.png", "--truth", "{meshes}/nope.stl"],
     r"nope\.stl: no such mesh file"),
])
def test_bad_input_one_line_exit_2(tmp_path, meshes, capfd, argv_tail, message):
    (meshes / "garbage.ply").write_text("ply\nformat nonsense\n")
    outdir = tmp_path / "out"
    argv = ["render"] + [a.format(out=outdir, meshes=meshes) for a in argv_tail]
    capfd.readouterr()
    assert main(argv) == 2
    err = capfd.readouterr().err
    assert len(err.strip().splitlines()) == 1 and re.search(message, err), err
    assert not outdir.exists() or list(outdir.iterdir()) == []
