"""Camera files without image sizes: each view takes its own image's size."""

from __future__ import annotations

import numpy as np

from matching.cameras import read_projection_txt
from pipeline.inputs import load_folder
from testkit.temple import turned_temple, write_par  # noqa: F401  (write_par: imported from here)

#: Tight bounding box of the temple (metres), from the data set's SOURCE.md.
BOX = np.array([[-0.073568, 0.021728, -0.012445], [0.028855, 0.181892, 0.062736]])


def _rot90_pixel(xy: np.ndarray, width: int, height: int, turns: int) -> np.ndarray:
    """Where pixel ``xy`` of a ``width`` x ``height`` image lands under ``np.rot90(., turns)``:
    (x, y) -> (y, W - 1 - x) per counter-clockwise quarter turn."""
    for _ in range(turns % 4):
        xy = np.stack([xy[:, 1], width - 1 - xy[:, 0]], axis=1)
        width, height = height, width
    return xy


def test_par_file_views_take_their_own_image_size(real_data_dir, tmp_path):
    """Temple ring, every image turned by a seeded random quarter turn, par file turned
    with it (portrait views 480x640 among 640x480 ones): no view is left out (all 6
    portrait views were: "image is 640x480 px but its camera in templeSR_par.txt is
    480x640 px"), each camera has its image's size, and it projects points of the
    object's box exactly where the upright camera's projection lands in the turned image
    (1e-9 px: the turned K, R, t are exact in the written digits)."""
    source = real_data_dir / "temple_sparse_ring"
    turns = turned_temple(source, tmp_path / "turned")
    assert sum(k % 2 for k in turns.values()) >= 2  # portrait views among landscape ones
    loaded = load_folder(tmp_path / "turned", cameras=tmp_path / "turned" / "templeSR_par.txt")
    assert loaded["skipped_views"] == [] and len(loaded["names"]) == 16
    upright = {cam.name: cam for cam in read_projection_txt(source / "templeSR_par.txt")}
    points = BOX[0] + np.random.default_rng(1).random((500, 3)) * (BOX[1] - BOX[0])
    for cam, shape in zip(loaded["cameras"], loaded["images"].shapes, strict=True):
        assert cam.size == (shape[1], shape[0])
        before = upright[cam.name]
        expected = _rot90_pixel(before.project(points), before.width, before.height,
                                turns[cam.name])
        assert np.abs(cam.project(points) - expected).max() < 1e-9


def test_par_file_sizes_by_name(tmp_path):
    """``sizes`` gives each camera its own image's size; cameras without one take
    ``width``/``height``."""
    from matching.cameras import Camera

    K = np.array([[500.0, 0, 300], [0, 500, 200], [0, 0, 1]])
    cams = [Camera(K, np.zeros(0), np.eye(3), np.array([0.0, 0, 1]), 640, 480, n)
            for n in ("a.png", "b.png", "c.png")]
    write_par(tmp_path / "p_par.txt", cams)
    read = read_projection_txt(tmp_path / "p_par.txt", 640, 480,
                               sizes={"a.png": (480, 640), "b.png": (700, 500)})
    assert [c.size for c in read] == [(480, 640), (700, 500), (640, 480)]
