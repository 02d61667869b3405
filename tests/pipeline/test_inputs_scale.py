"""--scale on a photo folder read at a working scale: the marked pixels are the full-size
image's, the cloud, sigma and cameras come out in real units."""

import numpy as np
import pytest

from matching.multiview import MultiViewCloud
from matching.resolution import scale_camera
from matching.sfm import transform_cameras
from pipeline.acquisition import _metric_scale
from pipeline.errors import InputError
from tests.matching.test_roi import _look_at

SHRINK = 0.37


def _loaded_and_cloud(working=0.5):
    rng = np.random.default_rng(5)
    truth = [_look_at(np.array([x, -3.0, 0.4]), (0.0, 0.0, 0.0), f=1800.0, size=(1600, 1200),
                      name=f"v{k}.jpg") for k, x in enumerate((-1.0, 0.0, 1.0))]
    wall = np.c_[rng.uniform(-1, 1, 20000), rng.normal(0, 0.001, 20000),
                 rng.uniform(-1, 1, 20000)]
    frame = transform_cameras(truth, SHRINK, np.eye(3), np.zeros(3))  # an SfM frame
    cams = [scale_camera(c, working) for c in frame]                  # read at half size
    n = len(wall)
    cloud = MultiViewCloud(points=SHRINK * wall, colours=np.zeros((n, 3), np.uint8),
                           sigma=np.full(n, SHRINK * 0.001), views=np.ones((n, 3), bool),
                           pair=np.zeros(n, np.int64), pairs=[(0, 1)], reason_counts={},
                           stats={"cameras": cams})
    loaded = {"cameras": cams, "names": [c.name for c in cams],
              "full_sizes": [c.size for c in truth]}
    return truth, loaded, cloud


def test_marked_pixels_of_the_full_size_image_scale_the_cloud():
    truth, loaded, cloud = _loaded_and_cloud()
    A, B = np.array([-0.6, 0.0, 0.3]), np.array([0.5, 0.0, -0.4])
    a, b = truth[2].project(np.array([A, B]))  # pixels of the full-size image
    spec = f"{a[0]:.3f},{a[1]:.3f} {b[0]:.3f},{b[1]:.3f}@v2.jpg={np.linalg.norm(A - B):.6f}"
    scaled = _metric_scale(cloud, loaded, "folder", spec, 0.0)
    report = scaled.stats["scale"]
    assert report["scale_factor"] == pytest.approx(1 / SHRINK, rel=2e-3)
    assert 0 < report["scale_relative_sigma"] < 0.01
    assert "two marked points in v2.jpg" in report["scale_source"]
    np.testing.assert_allclose(scaled.sigma, report["scale_factor"] * cloud.sigma)
    # the cameras in real units: their centres where the truth's are
    for cam, ref in zip(scaled.stats["cameras"], truth, strict=True):
        np.testing.assert_allclose(cam.center, ref.center, atol=0.01)


def test_a_view_not_in_the_folder_is_a_one_line_error():
    _, loaded, cloud = _loaded_and_cloud()
    with pytest.raises(InputError, match="folder: scale: no view 'x.jpg'"):
        _metric_scale(cloud, loaded, "folder", "1,2 30,40@x.jpg=1", 0.0)
