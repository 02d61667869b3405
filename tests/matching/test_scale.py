"""Metric scale: two marked points and ArUco markers, on scenes whose true scale is known."""

import cv2
import numpy as np
import pytest

from matching.scale import detect_markers, parse_scale, scale_from_markers, scale_from_points
from matching.sfm import transform_cameras
from tests.matching.test_roi import _look_at

#: The SfM frame is the truth shrunk by this (an arbitrary similarity's scale).
SHRINK = 0.37


def _cameras():
    return [_look_at(np.array([x, -3.0, 0.4]), (0.0, 0.0, 0.0), up=(0, 0, 1), f=900.0,
                     size=(800, 600), name=f"v{k}.png")
            for k, x in enumerate((-1.0, 0.0, 1.0))]


def test_parse_scale():
    a, b, image, dist = parse_scale("10,20.5 300,400@IMG 1.JPG=1.25")
    assert a.tolist() == [10, 20.5] and b.tolist() == [300, 400]
    assert image == "IMG 1.JPG" and dist == 1.25
    for bad in ("10,20 300,400=1", "10,20 300,400@a.png=-1", "1,1 1,1@a.png=2", "x"):
        with pytest.raises(ValueError, match="scale"):
            parse_scale(bad)


def test_two_marked_points_on_a_wall_give_the_true_scale():
    rng = np.random.default_rng(3)
    truth_cams = _cameras()
    # the cloud: a wall y = 0 (x, z in -1..1) with sigma 1 mm, in the shrunk frame
    wall = np.c_[rng.uniform(-1, 1, 20000), rng.normal(0, 0.001, 20000),
                 rng.uniform(-1, 1, 20000)]
    cams = transform_cameras(truth_cams, SHRINK, np.eye(3), np.zeros(3))
    A, B = np.array([-0.6, 0.0, 0.3]), np.array([0.5, 0.0, -0.4])
    a, b = truth_cams[1].project(np.array([A, B]))
    result = scale_from_points(a, b, "v1.png", float(np.linalg.norm(A - B)), cams,
                               SHRINK * wall)
    assert result.factor == pytest.approx(1 / SHRINK, rel=3 * result.sigma * SHRINK + 1e-3)
    assert 0 < result.sigma * SHRINK < 0.01  # a stated uncertainty, under 1 %
    with pytest.raises(ValueError, match="no view"):
        scale_from_points(a, b, "nope.png", 1.0, cams, wall)


def _render_marker(cam, corners3d, marker, size):
    """The marker image warped into a grey view by the plane's homography."""
    side = marker.shape[0]
    src = np.array([[0, 0], [side, 0], [side, side], [0, side]], np.float32) - 0.5
    dst = cam.project(corners3d).astype(np.float32)
    H = cv2.getPerspectiveTransform(src, dst)
    view = np.full((size[1], size[0]), 128, np.uint8)
    warped = cv2.warpPerspective(marker, H, size, flags=cv2.INTER_AREA,
                                 borderMode=cv2.BORDER_CONSTANT, borderValue=255)
    inside = cv2.warpPerspective(np.ones_like(marker), H, size) > 0
    # a white margin round the marker (aruco needs the quiet zone)
    margin = 0.25 * (corners3d - corners3d.mean(axis=0)) + corners3d
    quiet = np.zeros_like(view)
    cv2.fillConvexPoly(quiet, np.round(cam.project(margin)).astype(np.int32), 1)
    view[quiet > 0] = 255
    view[inside] = warped[inside]
    return view


def test_aruco_markers_give_the_true_scale():
    truth_cams = _cameras()
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
    side = 0.3  # metres in the truth frame
    detections = []
    markers = {7: np.array([-0.5, 0.0, 0.0]), 21: np.array([0.4, 0.0, 0.2])}
    views = [np.full((600, 800), 128, np.uint8) for _ in truth_cams]
    for ident, centre in markers.items():
        image = cv2.aruco.generateImageMarker(dictionary, ident, 240)
        corners = centre + side / 2 * np.array([[-1, 0, 1], [1, 0, 1], [1, 0, -1], [-1, 0, -1]])
        for v, cam in enumerate(truth_cams):
            drawn = _render_marker(cam, corners, image, (800, 600))
            views[v] = np.where(drawn != 128, drawn, views[v])
    names = set()
    for view in views:
        name, found = detect_markers(view)
        names.add(name)
        detections.append(found)
    assert names == {"DICT_4X4_50"} and all(set(d) == {7, 21} for d in detections)
    cams = transform_cameras(truth_cams, SHRINK, np.eye(3), np.zeros(3))
    result = scale_from_markers(detections, cams, side, "DICT_4X4_50")
    # corners to ~0.1 px at ~90 px a side: the factor to well under 1 %
    assert result.factor == pytest.approx(1 / SHRINK, rel=0.005)
    assert np.isfinite(result.sigma) and result.sigma * SHRINK < 0.005
    assert abs(result.factor - 1 / SHRINK) < 4 * result.sigma + 1e-3 / SHRINK
    with pytest.raises(ValueError, match="no marker seen in two views"):
        scale_from_markers([detections[0], {}, {}], cams, side)
