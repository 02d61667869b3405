"""Working resolution: scaled cameras see the resized image's pixels; the scale rule."""

import numpy as np
import pytest

from matching.cameras import Camera
from matching.resolution import object_extent_px, scale_camera, scaled_size, working_scale


def _camera(width=4000, height=3000, f=3200.0, name="v"):
    K = np.array([[f, 0.0, width / 2 - 0.5 + 7.0], [0.0, f, height / 2 - 0.5 - 3.0], [0, 0, 1]])
    return Camera(K=K, dist=np.array([-0.05, 0.01, 0.0, 0.0]), R=np.eye(3),
                  t=np.array([0.0, 0.0, 5.0]), width=width, height=height, name=name)


def test_scaled_camera_maps_pixel_centres_as_resize_does():
    cam = _camera()
    rng = np.random.default_rng(1)
    X = np.c_[rng.uniform(-1, 1, (50, 2)), rng.uniform(-0.5, 0.5, 50)]
    small = scale_camera(cam, 0.37)
    assert small.size == scaled_size(cam.size, 0.37) == (1480, 1110)
    sx, sy = small.width / cam.width, small.height / cam.height
    uv, uv_small = cam.project(X), small.project(X)
    # cv2.resize's pixel-centre mapping x' = s (x + 1/2) - 1/2, distortion included
    np.testing.assert_allclose(uv_small[:, 0], sx * (uv[:, 0] + 0.5) - 0.5, atol=1e-9)
    np.testing.assert_allclose(uv_small[:, 1], sy * (uv[:, 1] + 0.5) - 0.5, atol=1e-9)
    assert scale_camera(cam, 1.0) is cam


def test_working_scale_rule():
    assert working_scale(1000.0, 3, 500) == 1.0  # 1 500 px of cells: full size
    assert working_scale(3000.0, 3, 500) == pytest.approx(0.5)
    assert working_scale(3000.0, 3, 0) == 1.0  # 0: full resolution
    with pytest.raises(ValueError, match="points_across"):
        working_scale(3000.0, 3, -1)


def test_object_extent_from_points_and_without():
    cam = _camera()
    rng = np.random.default_rng(2)
    # a 1 x 1 square at depth 5, f 3200: 640 px across; 5 % stray points far off
    square = np.c_[rng.uniform(-0.5, 0.5, (400, 2)), np.zeros(400)]
    stray = np.c_[rng.uniform(-2.0, 2.0, (10, 2)), np.zeros(10)]
    extent = object_extent_px([cam, cam], np.r_[square, stray])
    assert 540 < extent < 700
    assert object_extent_px([cam]) == 4000.0  # no points: the image fills it


def test_object_extent_from_the_foreground_without_points():
    """No sparse points (given cameras): a uniform background's foreground gives the
    extent; without one the image fills it."""
    rng = np.random.default_rng(3)
    image = np.full((1200, 1600), 20, np.uint8)
    image[500:700, 600:900] = rng.integers(60, 250, (200, 300))  # 300 x 200 px object
    from matching.resolution import foreground_extent_px

    # the central 90 % of the object's columns: 270 px, and the foreground's blurred edge
    # (a few px of the 1000 px copy it is found on, x 1.6)
    assert 270.0 <= foreground_extent_px(image) <= 300.0
    cam = _camera(1600, 1200)
    assert 270.0 <= object_extent_px([cam] * 3, images=[image] * 3) <= 300.0
    noise = rng.integers(0, 255, (1200, 1600)).astype(np.uint8)
    assert foreground_extent_px(noise) is None
    assert object_extent_px([cam], images=[noise]) == 1600.0
    # the object's own points win over the images
    square = np.c_[rng.uniform(-0.5, 0.5, (400, 2)), np.zeros(400)]
    assert 540 < object_extent_px([cam], square, images=[image]) < 700
