"""Camera files naming one image twice, and a COLMAP images.txt without its points lines."""

from __future__ import annotations

import numpy as np
import pytest

from matching.cameras import (
    Camera,
    read_cameras,
    read_cameras_yml,
    read_colmap_text,
    write_cameras_yml,
    write_colmap_text,
)
from tests.pipeline.test_inputs_turned import write_par

K = np.array([[500.0, 0, 319.5], [0, 500, 239.5], [0, 0, 1]])


def _cameras(names=("a.png", "b.png", "c.png")) -> list[Camera]:
    return [Camera(K, np.zeros(0), np.eye(3), np.array([0.1 * k, 0, 2]), 640, 480, name)
            for k, name in enumerate(names)]


def test_yml_duplicate_view_with_another_pose_is_refused(tmp_path):
    cams = _cameras(("a.png", "b.png", "a.png"))
    write_cameras_yml(tmp_path / "cameras.yml", cams)
    with pytest.raises(ValueError) as info:
        read_cameras_yml(tmp_path / "cameras.yml")
    message = str(info.value)
    assert "image a.png has two different cameras: view_00 and view_02" in message
    assert message.count(str(tmp_path / "cameras.yml")) == 1 and "\n" not in message


def test_par_duplicate_line_with_another_pose_is_refused_and_a_repeat_is_one(tmp_path):
    cams = _cameras(("a.png", "b.png", "a.png"))
    write_par(tmp_path / "x_par.txt", cams)
    with pytest.raises(ValueError, match=r"image a.png has two different cameras: line 2 and "
                                         r"line 4"):
        read_cameras(tmp_path / "x_par.txt", 640, 480)
    same = _cameras()
    write_par(tmp_path / "y_par.txt", [*same, same[1]])   # the very entry twice: one view
    assert [c.name for c in read_cameras(tmp_path / "y_par.txt", 640, 480)] == \
        ["a.png", "b.png", "c.png"]


def test_colmap_duplicate_image_with_another_pose_is_refused(tmp_path):
    write_colmap_text(tmp_path, _cameras())
    text = (tmp_path / "images.txt").read_text().replace(" c.png", " a.png")
    (tmp_path / "images.txt").write_text(text)
    with pytest.raises(ValueError, match=r"images.txt: image a.png has two different cameras: "
                                         r"image entry 1 \(IMAGE_ID 1\) and image entry 3 "
                                         r"\(IMAGE_ID 3\)"):
        read_colmap_text(tmp_path)


def test_colmap_images_without_points_lines_is_malformed_once(tmp_path):
    """Six images, one line each (the POINTS2D lines left out): one error saying the file
    is malformed, where every second image was read as a points line (and its view left
    out with a line of its own)."""
    write_colmap_text(tmp_path, _cameras([f"v{k}.png" for k in range(6)]))
    lines = (tmp_path / "images.txt").read_text().splitlines()
    (tmp_path / "images.txt").write_text("\n".join(ln for ln in lines if ln.strip()) + "\n")
    with pytest.raises(ValueError, match=r"images.txt:6: malformed images.txt: expected the "
                                         r"POINTS2D line"):
        read_colmap_text(tmp_path)
    write_colmap_text(tmp_path, _cameras([f"v{k}.png" for k in range(6)]))
    text = (tmp_path / "images.txt").read_text().splitlines()
    text[5] = "10.5 20.25 -1 30.0 40.0 7"   # a points line with two observations: fine
    (tmp_path / "images.txt").write_text("\n".join(text) + "\n")
    assert len(read_colmap_text(tmp_path)) == 6
