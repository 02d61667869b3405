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


def test_views_read_at_the_working_scale_with_their_cameras_and_masks(tmp_path):
    import cv2

    from matching.cameras import write_cameras_yml
    from pipeline.inputs import load_folder

    rng = np.random.default_rng(7)
    cams = [_look_at(np.array([x, -3.0, 0.0]), (0.0, 0.0, 0.0), f=400.0, size=(400, 300),
                     name=f"v{k}.png") for k, x in enumerate((-0.5, 0.5))]
    (tmp_path / "masks").mkdir()
    for cam in cams:
        cv2.imwrite(str(tmp_path / cam.name), rng.integers(0, 255, (300, 400), np.uint8))
        mask = np.zeros((300, 400), np.uint8)
        mask[100:200, 100:300] = 255
        cv2.imwrite(str(tmp_path / "masks" / f"{cam.name}.png"), mask)
    write_cameras_yml(tmp_path / "cameras.yml", cams)
    # no sparse points: the extent is the image's 400 px; 40 points at spacing 3 -> 0.3
    loaded = load_folder(tmp_path, spacing=3, points_across=40)
    assert loaded["working_scale"] == pytest.approx(0.3)
    assert loaded["full_sizes"] == [(400, 300), (400, 300)]
    assert loaded["images"][0].shape == (90, 120) == loaded["images"].shapes[0][:2]
    assert loaded["cameras"][0].size == (120, 90)
    full = load_folder(tmp_path, spacing=3, points_across=0)
    assert full["working_scale"] == 1.0 and full["images"][1].shape == (300, 400)
    # a precision asked: the object must span 0.1 / 1e-3 = 100 px of its 400 -> 0.25;
    # 20 sections asked too: 40 points across at 3 px -> 0.3, the finer need
    asked = load_folder(tmp_path, spacing=3, precision=1e-3)
    assert asked["working_scale"] == pytest.approx(0.25)
    asked = load_folder(tmp_path, spacing=3, precision=1e-3, section_count=20)
    assert asked["working_scale"] == pytest.approx(0.3)
    assert "20 sections" in asked["working_scale_reason"]
    from pipeline.acquisition import folder_masks

    masks, source = folder_masks([tmp_path], loaded["names"], loaded["images"],
                                 loaded["cameras"], "folder", loaded["full_sizes"])
    assert source == "2 from masks/" and masks[0].shape == (90, 120)
    assert masks[0].sum() == pytest.approx(0.09 * 100 * 200, rel=0.05)  # the area, scaled
