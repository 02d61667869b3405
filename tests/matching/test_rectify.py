"""matching.rectify: rows are epipolar lines whatever the two views' relative pose.

Geometry (no images): random pairs with vertical and diagonal baselines, views rolled by
any angle against each other and different image sizes; a rendered ring whose views are
turned by quarter turns and padded to other sizes (exactly the upright cameras, turned)
gives the upright ring's cloud; the real temple ring rectifies to the epipolar distances
the given cameras predict.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from matching.cameras import Camera, StereoRig, read_cameras, turn_camera
from matching.multiview import reconstruct_multiview, select_pairs
from matching.rectify import (
    left_to_rectified,
    rectified_to_original,
    rectify,
    rectifying_rotation,
    row_residuals,
)


def _rotation(rng) -> np.ndarray:
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _roll(angle_deg: float) -> np.ndarray:
    a = np.radians(angle_deg)
    return np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0, 0, 1.0]])


def _look_at(centre, target, roll_deg=0.0, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    f = np.asarray(target, float) - centre
    f /= np.linalg.norm(f)
    r = np.cross(f, up)
    r /= np.linalg.norm(r)
    return _roll(roll_deg) @ np.stack([r, np.cross(f, r), f])


def _camera(centre, target, roll_deg, size, focal, dist=()) -> Camera:
    w, h = size
    K = np.array([[focal, 0, (w - 1) / 2], [0, 1.02 * focal, (h - 1) / 2], [0, 0, 1.0]])
    R = _look_at(np.asarray(centre, float), target, roll_deg)
    return Camera(K, list(dist), R, -R @ np.asarray(centre, float), w, h)


def _pairs(rng, n=12):
    """Random convergent pairs: any baseline direction, any roll, sizes, distortion."""
    out = []
    for _ in range(n):
        target = rng.normal(0, 0.2, 3)
        d1 = rng.normal(size=3)
        d1 /= np.linalg.norm(d1)
        # the second view 10-30 degrees away along a random direction
        tangent = np.cross(d1, rng.normal(size=3))
        tangent /= np.linalg.norm(tangent)
        ang = np.radians(rng.uniform(10, 30))
        d2 = np.cos(ang) * d1 + np.sin(ang) * tangent
        sizes = [(640, 480), (480, 640), (320, 240), (800, 600)]
        s1, s2 = sizes[rng.integers(4)], sizes[rng.integers(4)]
        dist = [rng.uniform(-0.1, 0.1), 0.0, 0.0, 0.0, 0.0]
        out.append((_camera(target + 5 * d1, target, rng.uniform(0, 360), s1, 1.3 * max(s1),
                            dist),
                    _camera(target + 5 * d2, target, rng.uniform(0, 360), s2, 1.3 * max(s2)),
                    target))
    return out


def test_rectified_rows_are_epipolar_lines_for_any_relative_pose():
    rng = np.random.default_rng(3)
    for left, right, target in _pairs(rng):
        rect = rectify(StereoRig(left, right))
        # points around the target, seen by both: the same row in both rectified images
        X = target + rng.normal(0, 0.3, (200, 3))
        xl, xr = left.project(X), right.project(X)
        yl = left_to_rectified(rect, left, xl)
        res = row_residuals(rect, StereoRig(left, right), xl, xr)
        assert np.abs(res).max() < 1e-6
        # both views look forward in the rectified frame
        for cam, R in ((left, rect.R1), (right, rect.R2)):
            assert np.all((R @ cam.to_camera(X).T)[2] > 0)
        back = rectified_to_original(rect, left, yl, which="left")
        np.testing.assert_allclose(back, xl, atol=1e-6)
        assert rect.size[0] <= 4 * max(left.size + right.size)
        assert rect.size[1] <= 4 * max(left.size + right.size)


def test_disparity_is_f_b_over_depth_plus_the_principal_point_offset():
    rng = np.random.default_rng(5)
    left, right, target = _pairs(rng, 1)[0]
    rig = StereoRig(left, right)
    rect = rectify(rig)
    X = target + rng.normal(0, 0.3, (50, 3))
    xl = left_to_rectified(rect, left, left.project(X))
    R = rectifying_rotation(left, right)
    xr = cv2.undistortPoints(right.project(X).reshape(-1, 1, 2), right.K,
                             right.dist if right.dist.size else None, R=rect.R2,
                             P=rect.P2).reshape(-1, 2)
    Z = (X - left.center) @ R[2]
    f, baseline = rect.P1[0, 0], np.linalg.norm(right.center - left.center)
    expected = f * baseline / Z + rect.P1[0, 2] - rect.P2[0, 2]
    np.testing.assert_allclose(xl[:, 0] - xr[:, 0], expected, atol=1e-6)
    # Q maps (x, y, d, 1) to the rectified left camera's frame
    h = np.column_stack([xl, xl[:, 0] - xr[:, 0], np.ones(len(xl))]) @ rect.Q.T
    np.testing.assert_allclose(h[:, 2] / h[:, 3], Z, rtol=1e-9)


def test_a_pair_looking_along_its_baseline_cannot_be_rectified():
    a = _camera([5.0, 0.0, 0.0], [0.0, 0.0, 0.0], 0.0, (320, 240), 400.0)
    b = _camera([4.0, 0.0, 0.0], [0.0, 0.0, 0.0], 0.0, (320, 240), 400.0)
    with pytest.raises(ValueError, match="along the viewing direction"):
        rectify(StereoRig(a, b))
    with pytest.raises(ValueError, match="zero baseline"):
        rectify(StereoRig(a, a))


def test_select_pairs_returns_each_pair_once_whatever_the_rolls():
    cams = [_camera(7.0 * np.array([np.cos(t), np.sin(t), 0.3]), [0, 0, 0], roll, (320, 240),
                    400.0)
            for t, roll in zip(np.radians(np.arange(0, 360, 15)), [0, 180, 90, 270] * 6,
                               strict=True)]
    pairs = select_pairs(cams)
    unordered = {frozenset(p) for p in pairs}
    assert len(unordered) == len(pairs) == 24


# ------------------------------------------------------------------ rendered ring, turned
def _turn(image: np.ndarray, camera: Camera, quarter_turns: int, pad: tuple[int, int],
          background: float):
    """The image turned by ``quarter_turns`` x 90 degrees (np.rot90) and padded, with its
    camera (:func:`matching.cameras.turn_camera`: exact, the turned camera sees the same
    pixels)."""
    image = np.ascontiguousarray(np.rot90(image, quarter_turns))
    turned = turn_camera(camera, quarter_turns)
    px, py = pad
    image = cv2.copyMakeBorder(image, py, py, px, px, cv2.BORDER_CONSTANT,
                               value=[background] * 3)
    K = turned.K.copy()
    K[0, 2] += px
    K[1, 2] += py
    return image, Camera(K, turned.dist, turned.R, turned.t, image.shape[1], image.shape[0],
                         camera.name)


@pytest.fixture(scope="module")
def arc(tmp_path_factory, fixtures_dir):
    """Nine neighbouring views of the rendered 24-view vase ring (320x240)."""
    from pipeline.scenes import render_scene

    out = tmp_path_factory.mktemp("arc") / "scene"
    render_scene(fixtures_dir / "scenes" / "vase_ring_small.toml", out, progress=False)
    cameras = read_cameras(out / "cameras.yml")[:9]
    images = [cv2.imread(str(out / "images" / c.name), cv2.IMREAD_UNCHANGED) for c in cameras]
    return cameras, images


def test_turned_and_resized_views_give_the_upright_cloud(arc):
    from scipy.spatial import cKDTree

    cameras, images = arc
    turns = [0, 1, 2, 3, 2, 1, 0, 3, 2]
    pads = [(0, 0), (10, 0), (0, 0), (0, 16), (24, 8), (0, 0), (6, 6), (0, 0), (12, 0)]
    turned = [_turn(img, cam, q, p, 20.0) for img, cam, q, p in zip(images, cameras, turns,
                                                                      pads, strict=True)]
    t_images, t_cameras = [t[0] for t in turned], [t[1] for t in turned]
    assert {c.size for c in t_cameras} >= {(320, 240), (240, 320)}
    pairs = [(k, k + 1) for k in range(8)]
    upright = reconstruct_multiview(images, cameras, pairs=pairs, workers=1)
    rolled = reconstruct_multiview(t_images, t_cameras, pairs=pairs, workers=1)
    assert len(upright) > 2000
    # measured: 10 542 upright, 10 565 turned points; nearest-neighbour distance between
    # the clouds median 0.24, 99th percentile 2.2 point spacings; radial error against
    # r(z) = 1 + 0.3 sin 2z 0.00150 and 0.00148 RMS (the same matching noise)
    assert abs(len(rolled) - len(upright)) < 0.03 * len(upright)
    spacing = np.median(cKDTree(upright.points).query(upright.points, k=2)[0][:, 1])
    d = cKDTree(upright.points).query(rolled.points)[0]
    assert np.median(d) < 0.5 * spacing
    assert np.quantile(d, 0.99) < 3.5 * spacing
    assert np.median(rolled.sigma) == pytest.approx(np.median(upright.sigma), rel=0.1)

    def radial_rms(points):
        r = np.hypot(points[:, 0], points[:, 1])
        return np.sqrt(np.mean((r - (1.0 + 0.3 * np.sin(2.0 * points[:, 2]))) ** 2))

    assert radial_rms(rolled.points) == pytest.approx(radial_rms(upright.points), rel=0.1)


# ------------------------------------------------------------------ the real temple ring
def test_temple_pairs_rectify_to_the_cameras_epipolar_lines(real_data_dir):
    folder = real_data_dir / "temple_sparse_ring"
    cameras = read_cameras(folder / "templeSR_par.txt")
    pairs = select_pairs(cameras)
    assert len({frozenset(p) for p in pairs}) == len(pairs) >= 16
    sift = cv2.SIFT_create()
    medians = []
    for a, b in pairs:
        rig = StereoRig(cameras[a], cameras[b])
        rect = rectify(rig)
        feats = [sift.detectAndCompute(cv2.imread(str(folder / cameras[v].name), 0), None)
                 for v in (a, b)]
        knn = cv2.BFMatcher().knnMatch(feats[0][1], feats[1][1], k=2)
        good = [m[0] for m in knn if len(m) == 2 and m[0].distance < 0.7 * m[1].distance]
        xa = np.array([feats[0][0][m.queryIdx].pt for m in good])
        xb = np.array([feats[1][0][m.trainIdx].pt for m in good])
        res = row_residuals(rect, rig, xa, xb)
        inlier = np.abs(res) < 3.0
        assert inlier.sum() >= 20
        medians.append(np.median(np.abs(res[inlier])))
    # measured: median row residual 0.08-0.28 px per pair (SIFT's own localisation on
    # these photographs: identical to the distances from the epipolar lines the given
    # cameras predict), 0.16 px over the pairs
    assert np.median(medians) < 0.2
    assert max(medians) < 0.4


def test_a_failed_pair_is_skipped_with_its_reason(arc):
    cameras, images = arc
    # a tenth view straight in front of view 0 (on its axis): the pair (0, 9) has its
    # baseline along the viewing direction and cannot be rectified
    c0 = cameras[0]
    ahead = Camera(c0.K, c0.dist, c0.R, c0.t - np.array([0.0, 0.0, 1.0]), *c0.size, "ahead")
    cams, imgs = [*cameras[:3], ahead], [*images[:3], images[0]]
    cloud = reconstruct_multiview(imgs, cams, pairs=[(0, 1), (1, 2), (0, 3)], workers=1)
    assert cloud.pairs == [(0, 1), (1, 2)]
    assert cloud.stats["pairs_skipped"] == 1
    (skip,) = cloud.stats["skipped"]
    assert skip["pair"] == [0, 3] and skip["views"] == [c0.name, "ahead"]
    assert "viewing direction" in skip["reason"] and "\n" not in skip["reason"]
    assert len(cloud) > 500
    # too few views left in a reconstructed pair: one clear line
    with pytest.raises(ValueError, match=r"only 0 of 2 views .* most often: .*viewing dir"):
        reconstruct_multiview(imgs, cams, pairs=[(0, 3)], workers=1)


def test_resampling_keeps_a_clipped_background_clipped():
    # a black background clipped at 0 beside a textured object with noise sigma = 2: the
    # cubic kernel's overshoot at the step made the rectified black ripple below 0, the
    # clipped pixels were no longer the image's minimum, and the noise estimate read the
    # ripple-free black (0.00-0.04 grey levels on the rectified temple views); kept
    # within the source's range, the estimate sees the object's noise again
    from matching.lsm import estimate_noise
    from matching.rectify import resample

    rng = np.random.default_rng(0)
    h, w = 240, 320
    yy, xx = np.mgrid[0:h, 0:w]
    texture = 120 + 60 * np.sin(xx / 5.0) * np.cos(yy / 7.0) + rng.normal(0, 2.0, (h, w))
    image = np.where(xx > w // 3, np.clip(texture, 1, 254), 0.0).astype(np.float32)
    K = np.array([[300.0, 0, w / 2], [0, 300.0, h / 2], [0, 0, 1]])
    R = cv2.Rodrigues(np.array([0.0, 0.0, 0.05]))[0]                 # a small roll
    maps = cv2.initUndistortRectifyMap(K, None, R, K, (w, h), cv2.CV_32FC1)
    raw = cv2.remap(image, maps[0], maps[1], cv2.INTER_CUBIC,
                    borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    kept = resample(image, maps)
    assert raw.min() < -1.0                                            # the overshoot
    assert kept.min() >= 0.0 and kept.max() <= image.max()
    inside = (kept > 0)
    np.testing.assert_array_equal(kept[inside & (raw > 0) & (raw <= image.max())],
                                  raw[inside & (raw > 0) & (raw <= image.max())])
    assert estimate_noise(raw) < 0.2                                   # the black's
    assert 0.5 < estimate_noise(kept) < 2.0   # the object's (0.86: the cubic kernel smooths it)
