"""Cameras and their file formats: validation, projection, round trips, pycolmap agreement."""

from __future__ import annotations

import cv2
import numpy as np
import pycolmap
import pytest

from matching.cameras import (
    Camera,
    StereoRig,
    quaternion_to_rotation,
    read_cameras,
    read_cameras_yml,
    read_colmap_text,
    read_projection_txt,
    read_rig,
    read_stereo_calibration,
    rotation_to_quaternion,
    turn_camera,
    write_cameras_yml,
    write_colmap_text,
    write_rig,
)

K0 = np.array([[520.0, 0.0, 319.5], [0.0, 515.0, 239.5], [0.0, 0.0, 1.0]])
DISTS = [np.zeros(0), np.array([0.1, -0.05, 0.001, 0.002]),
         np.array([-0.2, 0.08, -0.001, 0.0015, -0.01])]


def random_camera(rng, dist=(), name="img.png") -> Camera:
    R = cv2.Rodrigues(rng.normal(size=3) * 0.6)[0]
    return Camera(K0, np.asarray(dist, float), R, rng.normal(size=3), 640, 480, name)


@pytest.fixture
def cameras():
    rng = np.random.default_rng(1)
    return [random_camera(rng, d, f"view_{i}.png") for i, d in enumerate(DISTS)]


def points_in_front(cam: Camera, rng, n=50, depth=4.0) -> np.ndarray:
    """World points inside the camera's field of view at depths around ``depth``."""
    pix = rng.uniform([40, 40], [600, 440], size=(n, 2))
    _, d = cam.ray(pix)
    return cam.center + d * rng.uniform(0.7 * depth, 1.3 * depth, size=(n, 1))


# ------------------------------------------------------------------ turned images
@pytest.mark.parametrize("dist", [(), (-0.2, 0.08, 0.0, 0.0, -0.01)])
@pytest.mark.parametrize("quarter_turns", [1, 2, 3, -1])
def test_turned_camera_sees_the_turned_pixels(dist, quarter_turns):
    # np.rot90 maps pixel (x, y) of a W-wide image to (y, W - 1 - x): the turned camera
    # projects every point to that pixel of the original's projection (radial
    # distortion included), to rounding
    rng = np.random.default_rng(4)
    cam = random_camera(rng, dist)
    X = points_in_front(cam, rng)
    x = cam.project(X)
    expect = x.copy()
    width = cam.width
    for _ in range(quarter_turns % 4):
        expect = np.c_[expect[:, 1], width - 1 - expect[:, 0]]
        width = cam.height if width == cam.width else cam.width
    turned = turn_camera(cam, quarter_turns)
    assert np.abs(turned.project(X) - expect).max() < 1e-9
    assert (turned.width, turned.height) == ((cam.height, cam.width) if quarter_turns % 2
                                             else (cam.width, cam.height))
    assert np.allclose(turned.center, cam.center, atol=1e-12)
    assert turn_camera(turned, -quarter_turns).allclose(cam, atol=1e-12)


def test_turning_refuses_tangential_distortion():
    cam = random_camera(np.random.default_rng(5), DISTS[1])
    with pytest.raises(ValueError, match="only radial distortion"):
        turn_camera(cam, 1)


# ------------------------------------------------------------------ validation
@pytest.mark.parametrize("field, value, message", [
    ("K", np.eye(2), "K must have shape"),
    ("K", np.diag([0.0, 500.0, 1.0]), "focal"),
    ("K", np.diag([500.0, 500.0, 1.0]) * np.nan, "K must be finite"),
    ("R", np.diag([1.0, 1.0, -1.0]), "R must be a rotation"),
    ("R", np.eye(3) * 1.01, "R must be a rotation"),
    ("t", np.zeros(2), "t must have shape"),
    ("dist", np.zeros(3), "dist must have"),
    ("width", 0, "width, height"),
])
def test_camera_rejects_bad_fields(field, value, message):
    kwargs = dict(K=K0, dist=np.zeros(0), R=np.eye(3), t=np.zeros(3), width=640, height=480)
    kwargs[field] = value
    with pytest.raises(ValueError, match=message):
        Camera(**kwargs)


def test_camera_arrays_are_read_only(cameras):
    with pytest.raises(ValueError):
        cameras[0].K[0, 0] = 1.0


# ------------------------------------------------------------------ geometry
def test_projection_matches_P_without_distortion(cameras):
    cam = cameras[0]
    X = points_in_front(cam, np.random.default_rng(2))
    xh = np.column_stack([X, np.ones(len(X))]) @ cam.P.T
    np.testing.assert_allclose(cam.project(X), xh[:, :2] / xh[:, 2:], atol=1e-9)
    np.testing.assert_allclose(cam.depth(X), xh[:, 2], rtol=1e-12)
    np.testing.assert_allclose(cam.P @ np.append(cam.center, 1.0), 0.0, atol=1e-9)


def test_projection_exact_for_rotations_near_pi():
    # cv2.Rodrigues(R) -> rvec loses ~1e-8 rad for angles near pi (~1e-5 px here); the
    # projection must not go through it: K (R X + t) to rounding (~1e-12 px)
    axis = np.array([1.0, 2.0, 2.0]) / 3.0
    R = cv2.Rodrigues(axis * (np.pi - 1e-7))[0]
    cam = Camera(K0, np.zeros(0), R, np.array([0.1, -0.2, 0.3]), 640, 480, "pi.png")
    X = points_in_front(cam, np.random.default_rng(5))
    xh = (X @ R.T + cam.t) @ K0.T
    np.testing.assert_allclose(cam.project(X), xh[:, :2] / xh[:, 2:], rtol=0, atol=1e-9)


@pytest.mark.parametrize("index", [0, 1, 2])
def test_undistort_inverts_projection(cameras, index):
    """Undistorted pixels are the pinhole projection K (x/z, y/z) to ~1e-9 px."""
    cam = cameras[index]
    X = points_in_front(cam, np.random.default_rng(3))
    xc = cam.to_camera(X)
    ideal = (xc[:, :2] / xc[:, 2:]) @ cam.K[:2, :2].T + cam.K[:2, 2]
    np.testing.assert_allclose(cam.undistort_points(cam.project(X)), ideal, atol=1e-8)


@pytest.mark.parametrize("index", [0, 2])
def test_ray_passes_through_point(cameras, index):
    cam = cameras[index]
    X = points_in_front(cam, np.random.default_rng(4))
    origin, d = cam.ray(cam.project(X))
    v = X - origin
    np.testing.assert_allclose(np.linalg.norm(np.cross(v, d), axis=1) / np.linalg.norm(v, axis=1),
                               0.0, atol=1e-10)
    assert np.all(np.einsum("ij,ij->i", v, d) > 0)


def test_projection_jacobian_matches_finite_differences(cameras):
    cam = cameras[2]
    X = points_in_front(cam, np.random.default_rng(5), n=5)
    _, J = cam.project(X, with_jacobian=True)
    h = 1e-6
    for k in range(3):
        step = np.zeros(3)
        step[k] = h
        numeric = (cam.project(X + step) - cam.project(X - step)) / (2 * h)
        np.testing.assert_allclose(J[:, :, k], numeric, rtol=1e-5, atol=1e-4)


def test_stereo_rig_relative_pose(cameras):
    rig = StereoRig(cameras[0], cameras[1])
    X = points_in_front(cameras[0], np.random.default_rng(6))
    xl, xr = cameras[0].to_camera(X), cameras[1].to_camera(X)
    np.testing.assert_allclose(xl @ rig.R.T + rig.T, xr, atol=1e-10)
    assert rig.baseline == pytest.approx(np.linalg.norm(cameras[0].center - cameras[1].center))


def test_from_projection_recovers_camera(cameras):
    cam = cameras[0]
    back = Camera.from_projection(-3.0 * cam.P, cam.width, cam.height)
    assert back.allclose(cam, atol=1e-8)


def test_quaternion_round_trip():
    rng = np.random.default_rng(7)
    R = np.stack([cv2.Rodrigues(v)[0] for v in rng.normal(size=(200, 3)) * 2.0])
    R[0] = np.diag([1.0, -1.0, -1.0])  # 180° turn: the w = 0 branch
    q = rotation_to_quaternion(R)
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(quaternion_to_rotation(q), R, atol=1e-12)


# ------------------------------------------------------------------ formats
@pytest.mark.parametrize("suffix", [".yml", ".xml"])
def test_cameras_yml_round_trip(tmp_path, cameras, suffix):
    path = tmp_path / f"cameras{suffix}"
    write_cameras_yml(path, cameras)
    back = read_cameras_yml(path)
    assert [c.name for c in back] == [c.name for c in cameras]
    for a, b in zip(cameras, back, strict=True):
        assert a.allclose(b, rtol=0, atol=1e-14)
    assert all(a.allclose(b) for a, b in zip(cameras, read_cameras(path), strict=True))


def test_rig_round_trip(tmp_path, cameras):
    rig = StereoRig(cameras[1], cameras[2])
    write_rig(tmp_path / "rig.yml", rig, extra={"rms_px": 0.25})
    back = read_rig(tmp_path / "rig.yml")
    assert back.left.allclose(rig.left) and back.right.allclose(rig.right)
    # a three-view cameras.yml with a rig names its pair
    write_cameras_yml(tmp_path / "three.yml", cameras, rig=rig)
    back = read_rig(tmp_path / "three.yml")
    np.testing.assert_allclose(back.T, rig.T, atol=1e-12)
    # a plain two-view cameras.yml is a rig too
    write_cameras_yml(tmp_path / "two.yml", cameras[:2])
    assert read_rig(tmp_path / "two.yml").right.allclose(cameras[1])


def test_read_rig_three_views_without_rig_is_an_error(tmp_path, cameras):
    write_cameras_yml(tmp_path / "three.yml", cameras)
    with pytest.raises(ValueError, match="which two"):
        read_rig(tmp_path / "three.yml")


OPENCV_INTRINSICS = """%YAML:1.0
M1: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 530., 0., 320., 0., 530., 240., 0., 0., 1. ]
D1: !!opencv-matrix
   rows: 1
   cols: 5
   dt: d
   data: [ -0.27, 0.1, 0.001, -0.0002, 0. ]
M2: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 532., 0., 325., 0., 532., 245., 0., 0., 1. ]
D2: !!opencv-matrix
   rows: 1
   cols: 5
   dt: d
   data: [ -0.26, 0.09, 0.0, 0.0, 0. ]
"""

OPENCV_EXTRINSICS = """%YAML:1.0
R: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 1., 0., 0., 0., 1., 0., 0., 0., 1. ]
T: !!opencv-matrix
   rows: 3
   cols: 1
   dt: d
   data: [ -3.33, 0.04, -0.01 ]
R1: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 1., 0., 0., 0., 1., 0., 0., 0., 1. ]
"""


def test_opencv_sample_files(tmp_path):
    (tmp_path / "intrinsics.yml").write_text(OPENCV_INTRINSICS)
    (tmp_path / "extrinsics.yml").write_text(OPENCV_EXTRINSICS)
    rig = read_rig(tmp_path / "intrinsics.yml", width=640, height=480)
    assert rig.baseline == pytest.approx(np.linalg.norm([3.33, 0.04, 0.01]))
    assert rig.left.K[0, 0] == 530.0 and rig.right.dist[0] == -0.26
    same = read_rig(tmp_path / "extrinsics.yml", width=640, height=480)
    np.testing.assert_allclose(same.T, rig.T)
    cv2.imwrite(str(tmp_path / "left.png"), np.zeros((480, 640), np.uint8))
    sized = read_stereo_calibration(tmp_path / "intrinsics.yml", tmp_path / "extrinsics.yml",
                                    image=tmp_path / "left.png")
    assert sized.left.size == (640, 480)
    with pytest.raises(ValueError, match="image size"):
        read_rig(tmp_path / "intrinsics.yml")


def test_missing_matrix_and_singular_k_are_named(tmp_path):
    (tmp_path / "intrinsics.yml").write_text(OPENCV_INTRINSICS.split("M2:")[0])
    (tmp_path / "extrinsics.yml").write_text(OPENCV_EXTRINSICS)
    with pytest.raises(ValueError, match=r"intrinsics.yml: missing field M2"):
        read_rig(tmp_path / "intrinsics.yml", width=640, height=480)
    (tmp_path / "intrinsics.yml").write_text(OPENCV_INTRINSICS.replace("530., 0., 320.",
                                                                       "0., 0., 320."))
    with pytest.raises(ValueError, match=r"intrinsics.yml.*focal"):
        read_rig(tmp_path / "intrinsics.yml", width=640, height=480)


def test_bad_files(tmp_path, cameras):
    with pytest.raises(FileNotFoundError, match="nothing.yml"):
        read_cameras_yml(tmp_path / "nothing.yml")
    (tmp_path / "junk.yml").write_text("this: [is not, opencv\n")
    with pytest.raises(ValueError, match="junk.yml"):
        read_cameras_yml(tmp_path / "junk.yml")
    write_cameras_yml(tmp_path / "c.yml", cameras)
    text = (tmp_path / "c.yml").read_text().replace("n_views: 3", "n_views: 4")
    (tmp_path / "c.yml").write_text(text)
    with pytest.raises(ValueError, match="c.yml: missing field view_03"):
        read_cameras_yml(tmp_path / "c.yml")
    (tmp_path / "r.yml").write_text("%YAML:1.0\nfoo: 1\n")
    with pytest.raises(ValueError, match="not a rig file"):
        read_rig(tmp_path / "r.yml")


def test_colmap_text_round_trip_and_pycolmap(tmp_path, cameras):
    write_colmap_text(tmp_path / "model", cameras)
    back = read_colmap_text(tmp_path / "model")
    for a, b in zip(cameras, back, strict=True):
        assert a.allclose(b, atol=1e-12), (a.name, b.name)
    assert all(a.allclose(b) for a, b in zip(cameras, read_cameras(tmp_path / "model"),
                                             strict=True))
    # pycolmap reads the same model and projects every point to the same pixel,
    # shifted by COLMAP's half-pixel origin.
    rec = pycolmap.Reconstruction(str(tmp_path / "model"))
    assert rec.num_reg_images() == len(cameras) if hasattr(rec, "num_reg_images") else True
    rng = np.random.default_rng(8)
    by_name = {im.name: im for im in rec.images.values()}
    for cam in cameras:
        image = by_name[cam.name]
        colmap_cam = rec.cameras[image.camera_id]
        X = points_in_front(cam, rng, n=10)
        pose = image.cam_from_world()
        pix = np.array([colmap_cam.img_from_cam(pose * x) for x in X])
        np.testing.assert_allclose(pix - 0.5, cam.project(X), atol=1e-9)


def test_colmap_reader_models(tmp_path):
    (tmp_path / "cameras.txt").write_text(
        "# comment\n1 SIMPLE_RADIAL 640 480 500 320.5 240.5 0.01\n"
        "2 RADIAL 640 480 500 320.5 240.5 0.01 -0.002\n")
    (tmp_path / "images.txt").write_text(
        "# comment\n1 1 0 0 0 0 0 0 1 a.png\n\n2 0.7071067811865476 0 0.7071067811865476 0 "
        "1 2 3 2 b.png\n10 20 -1\n")
    a, b = read_colmap_text(tmp_path)
    np.testing.assert_allclose(a.dist, [0.01, 0, 0, 0])
    np.testing.assert_allclose(b.dist, [0.01, -0.002, 0, 0])
    assert a.K[0, 2] == 320.0
    np.testing.assert_allclose(b.R, [[0, 0, 1], [0, 1, 0], [-1, 0, 0]], atol=1e-12)
    (tmp_path / "cameras.txt").write_text("1 FISHEYE 640 480 500 320 240 0.1\n")
    with pytest.raises(ValueError, match="cameras.txt:1: camera model FISHEYE"):
        read_colmap_text(tmp_path)


def test_projection_txt(tmp_path, cameras):
    lines = [str(len(cameras))]
    for cam in cameras:
        values = np.concatenate([cam.K.ravel(), np.round(cam.R, 9).ravel(), cam.t])
        lines.append(cam.name + " " + " ".join(f"{v:.12g}" for v in values))
    (tmp_path / "ring_par.txt").write_text("\n".join(lines) + "\n")
    cv2.imwrite(str(tmp_path / cameras[0].name), np.zeros((480, 640, 3), np.uint8))
    back = read_projection_txt(tmp_path / "ring_par.txt")
    for a, b in zip(cameras, back, strict=True):
        assert b.size == (640, 480)
        np.testing.assert_allclose(b.R, a.R, atol=1e-8)
        np.testing.assert_allclose(b.t, a.t, atol=1e-10)
    assert len(read_cameras(tmp_path / "ring_par.txt")) == 3
    (tmp_path / "bad_par.txt").write_text("a.png 1 2 3\n")
    with pytest.raises(ValueError, match="bad_par.txt:1"):
        read_projection_txt(tmp_path / "bad_par.txt", 640, 480)


def test_colmap_binary_through_pycolmap(tmp_path, cameras):
    write_colmap_text(tmp_path / "text", cameras)
    (tmp_path / "bin").mkdir()
    pycolmap.Reconstruction(str(tmp_path / "text")).write_binary(str(tmp_path / "bin"))
    assert (tmp_path / "bin" / "cameras.bin").exists()
    back = {cam.name: cam for cam in read_cameras(tmp_path / "bin")}
    for cam in cameras:
        assert back[cam.name].allclose(cam, atol=1e-12)
