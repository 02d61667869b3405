"""Working resolution: scaled cameras see the resized image's pixels; the scale rule."""

import numpy as np
import pytest

from matching.cameras import Camera
from matching.resolution import (
    SIGMA_LSM_PX,
    object_depths,
    object_extent_px,
    requested_scale,
    scale_camera,
    scaled_size,
    working_scale,
)


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


def _ring(n=8, radius=5.0, f=3200.0):
    """``n`` views of 4000 x 3000 on a circle of ``radius`` round the origin, looking at it."""
    cams = []
    for k in range(n):
        a = 2 * np.pi * k / n
        centre = radius * np.array([np.cos(a), np.sin(a), 0.0])
        z = -centre / radius
        x = np.cross([0.0, 0.0, 1.0], z)
        x /= np.linalg.norm(x)
        R = np.stack([x, np.cross(z, x), z])
        K = np.array([[f, 0, 1999.5], [0, f, 1499.5], [0, 0, 1.0]])
        cams.append(Camera(K=K, dist=np.zeros(4), R=R, t=-R @ centre, width=4000,
                           height=3000, name=f"v{k}"))
    return cams


def test_the_scale_the_request_needs():
    cams = _ring()
    # precision: the object must span SIGMA_LSM_PX / precision px -> 0.1 / (2e-4 * 2000)
    s, why = requested_scale(cams, 2000.0, 3, precision=2e-4)
    assert s == pytest.approx(SIGMA_LSM_PX / (2e-4 * 2000.0)) and "precision" in why
    # 100 sections: 200 points across 2000 px at 3 px -> 0.3
    assert requested_scale(cams, 2000.0, 3, section_count=100)[0] == pytest.approx(0.3)
    # sections 0.02 apart: points 0.01 apart, f 0.01 / 5 = 6.4 px at full size -> 3 / 6.4;
    # no points: the depth is the axes' meeting point's (the ring's centre, 5 away)
    np.testing.assert_allclose(object_depths(cams), 5.0, rtol=1e-9)
    s, why = requested_scale(cams, 2000.0, 3, section_spacing=0.02)
    assert s == pytest.approx(3 / 6.4) and "section spacing" in why
    # points at depth 4 in every view (a sphere of radius 1 about the centre, near side)
    rng = np.random.default_rng(3)
    pts = rng.normal(size=(4000, 3))
    pts /= np.linalg.norm(pts, axis=1, keepdims=True)
    depths = object_depths(cams, pts)
    assert np.all((depths > 4.5) & (depths < 5.5))  # the sphere's median depth about 5
    # the finest need wins; never above full size; nothing asked: full size
    both = requested_scale(cams, 2000.0, 3, precision=2e-4, section_count=100)[0]
    assert both == pytest.approx(0.3)
    assert requested_scale(cams, 2000.0, 3, section_count=1000)[0] == 1.0
    assert requested_scale(cams, 2000.0, 3) == (1.0, requested_scale(cams, 100.0, 3)[1])
    with pytest.raises(ValueError, match="precision"):
        requested_scale(cams, 2000.0, 3, precision=-1.0)
