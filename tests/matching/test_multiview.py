"""matching.multiview on a rendered 24-view ring of the vase (320x240), checked against the truth.

The ring is ``fixtures/scenes/vase_ring_small.toml``: r(z) = 1 + 0.3 sin 2z, z in [0, 3],
cameras 15 degrees apart at 7.1 units, 2 grey-level noise, per-view gain and offset.
"""

from __future__ import annotations

import cv2
import numpy as np
import open3d as o3d
import pytest

from matching.cameras import Camera, read_cameras
from matching.further_views import _systematic_offset
from matching.multiview import (
    MULTIVIEW,
    REASON_NAMES,
    merge_clouds,
    reconstruct_multiview,
    reconstruct_view_pair,
    scene_centre,
    select_pairs,
)
from pipeline.mesh_io import read_mesh
from testkit.rings import ring_cameras

N_VIEWS = 24


@pytest.fixture(scope="module")
def ring(tmp_path_factory, fixtures_dir):
    from pipeline.scenes import render_scene

    out = tmp_path_factory.mktemp("ring") / "scene"
    render_scene(fixtures_dir / "scenes" / "vase_ring_small.toml", out, progress=False)
    cameras = read_cameras(out / "cameras.yml")
    images = [cv2.imread(str(out / "images" / c.name), cv2.IMREAD_UNCHANGED) for c in cameras]
    vertices, triangles = read_mesh(out / "truth" / "mesh.ply")[:2]
    truth = o3d.t.geometry.RaycastingScene()
    truth.add_triangles(o3d.core.Tensor(vertices.astype(np.float32)),
                        o3d.core.Tensor(triangles.astype(np.uint32)))
    return {"folder": out, "cameras": cameras, "images": images, "truth": truth}


@pytest.fixture(scope="module")
def cloud(ring):
    return reconstruct_multiview(ring["images"], ring["cameras"])


def _distance(truth, points) -> np.ndarray:
    return truth.compute_distance(o3d.core.Tensor(points.astype(np.float32))).numpy()


def _ring_cameras(n=N_VIEWS, radius=7.0, height=1.5):
    return ring_cameras(n, radius, height)


# ------------------------------------------------------------------ view pairs (no images)
def test_scene_centre_is_where_the_ring_looks():
    assert np.allclose(scene_centre(_ring_cameras()), [0.0, 0.0, 1.5], atol=1e-9)


def test_scene_centre_of_parallel_cameras_raises():
    cam = _ring_cameras()[0]
    shifted = Camera(cam.K, [], cam.R, cam.t + [1.0, 0, 0], 320, 240)
    with pytest.raises(ValueError, match="parallel"):
        scene_centre([cam, shifted])


def test_ring_pairs_are_the_neighbours_left_to_right():
    cams = _ring_cameras()
    pairs = select_pairs(cams)
    # 15 deg apart at 7 units: b/d = 2 sin 7.5 = 0.26, the target 0.25; each view keeps both
    # neighbours, which is the 24 pairs (k, k+1) once each
    assert sorted(pairs) == sorted((k, (k + 1) % N_VIEWS) for k in range(N_VIEWS))
    for a, b in pairs:  # the right view's centre is on the left view's +x side
        assert cams[a].to_camera(cams[b].center[None])[0, 0] > 0


def test_pairs_respect_the_ratio_and_angle_limits():
    cams = _ring_cameras()
    # a 30 deg limit drops nothing at 15 deg; max_ratio below the neighbours' 0.26 drops all
    assert len(select_pairs(cams, max_angle_deg=30.0, partners=4)) == 2 * N_VIEWS
    assert select_pairs(cams, min_ratio=0.05, target_ratio=0.1, max_ratio=0.2) == []
    with pytest.raises(ValueError, match="min_ratio"):
        select_pairs(cams, min_ratio=0.5, target_ratio=0.25)


# ------------------------------------------------------------------ merge (no images)
def test_merge_fuses_duplicates_by_sigma_weights():
    rng = np.random.default_rng(0)
    grid = np.stack(np.meshgrid(np.arange(20.0), np.arange(20.0)), -1).reshape(-1, 2)
    base = np.column_stack([grid, np.zeros(len(grid))])  # spacing 1
    offset = rng.normal(0, 0.05, base.shape)
    a, b = base + offset, base - offset
    sa, sb = np.full(len(a), 0.1), np.full(len(a), 0.2)
    views = np.zeros((2 * len(a), 3), bool)
    views[: len(a), 0] = views[len(a):, 1] = True
    out = merge_clouds(np.concatenate([a, b]), np.concatenate([sa, sb]), views,
                       np.repeat([0, 1], len(a)), np.zeros((2 * len(a), 3), np.uint8),
                       sor_neighbours=0)
    assert out["fused"] == len(a) and len(out["points"]) == len(a)
    assert out["radius"] == pytest.approx(0.5, rel=0.1)  # half the within-pair spacing (noisy)
    order = np.lexsort(np.rint(out["points"][:, :2]).T[::-1])
    # weights 1/0.1^2 : 1/0.2^2 = 4 : 1 -> base + (4 - 1)/5 offset
    expected = base + 0.6 * offset
    assert np.allclose(out["points"][order], expected[np.lexsort(np.rint(base[:, :2]).T[::-1])])
    assert np.allclose(out["sigma"], 1 / np.sqrt(1 / 0.1**2 + 1 / 0.2**2))
    assert np.all(out["views"][:, :2]) and not out["views"][:, 2].any()
    assert np.all(out["pair"] == -1)


def test_merge_checks_its_arrays():
    pts = np.zeros((4, 3))
    ok = (np.ones(4), np.ones((4, 2), bool), np.zeros(4, np.int64), np.zeros((4, 3), np.uint8))
    with pytest.raises(ValueError, match=r"points must have shape \(N, 3\)"):
        merge_clouds(np.zeros((4, 2)), *ok)
    with pytest.raises(ValueError, match="sigma has 3 rows for 4 points"):
        merge_clouds(pts, np.ones(3), *ok[1:])
    with pytest.raises(ValueError, match="sigma must be positive"):
        merge_clouds(pts, np.zeros(4), *ok[1:])


def test_merge_keeps_one_pairs_neighbours_apart_and_drops_off_surface_points():
    rng = np.random.default_rng(1)
    # a jittered grid, like matched points (one per spacing x spacing cell)
    grid = np.stack(np.meshgrid(np.arange(60.0), np.arange(50.0)), -1).reshape(-1, 2)
    xy = grid + rng.uniform(-0.3, 0.3, grid.shape)
    pts = np.column_stack([xy, rng.normal(0, 0.01, 3000)])
    pts[:5, 2] = 1.0  # 100 noise sigmas off the plane, not isolated in x, y
    out = merge_clouds(pts, np.full(3000, 0.01), np.ones((3000, 1), bool),
                       np.zeros(3000, np.int64), np.zeros((3000, 3), np.uint8))
    assert out["fused"] == 0  # one pair: nothing is a duplicate
    assert out["outliers"] >= 5
    assert np.abs(out["points"][:, 2]).max() < 0.1
    assert out["outliers"] < 30  # < 1 % of the true points


# ------------------------------------------------------------------ the rendered ring
def test_pair_matching_error_against_the_truth(ring):
    cams, images = ring["cameras"], ring["images"]
    pc = reconstruct_view_pair(images[0], images[1], cams[0], cams[1], (0, 1))
    assert len(pc) > 500
    x_true = _true_right(ring["truth"], pc)
    err = pc.x_right[:, 0] - x_true[:, 0]
    ok = np.isfinite(err)
    assert ok.mean() > 0.99  # every template's ray meets the vase
    centred = ok & np.all(pc.offset == 0, axis=1)
    # measured with the second-order pass: median 0.003 px, RMS 0.035-0.04 px (affine
    # only: median 0.08 px, the curvature bias); bounds at 3x and 2x
    assert abs(np.median(err[centred])) < 0.01
    assert np.sqrt(np.mean(err[centred] ** 2)) < 0.08
    # eccentric windows (moved off the background onto the vase near rims and contours):
    # a minority, transferred through a warp fitted 7 px away, so their errors exceed
    # σ more than the centred ones' (measured: 20 % of the points, error/σ 3.2 against
    # 1.5 at this 320x240 size; 7 %, 1.74 against 1.39 at 1024x768) -- bounded here at
    # 1.5x what was measured; the further-view check rejects what is off
    ecc = ok & ~centred
    assert 0 < ecc.sum() < 0.3 * ok.sum()
    sigma = np.sqrt(2.0 * pc.cov_2d[:, 0, 0])  # cov_2d = cov / 2 + floor
    assert np.sqrt(np.mean((err[ecc] / sigma[ecc]) ** 2)) < 4.8
    assert np.sqrt(np.mean((err[centred] / sigma[centred]) ** 2)) < 2.3


def test_pair_uses_fixed_patches_unless_asked(ring):
    """reconstruct_view_pair matches at the fixed patch by default (the further-view check
    re-matches at that patch anyway); adaptive_patch / max_patch / max_sigma_mad_k reach
    match_pair from reconstruct_multiview, whose option check knows them."""
    cams, images = ring["cameras"], ring["images"]
    default = reconstruct_view_pair(images[0], images[1], cams[0], cams[1], (0, 1))
    fixed = reconstruct_view_pair(images[0], images[1], cams[0], cams[1], (0, 1),
                                  adaptive_patch=False)
    np.testing.assert_array_equal(default.points, fixed.points)
    adaptive = reconstruct_view_pair(images[0], images[1], cams[0], cams[1], (0, 1),
                                     adaptive_patch=True, max_patch=21)
    assert adaptive.status_counts != fixed.status_counts  # the option took effect
    no_test = reconstruct_view_pair(images[0], images[1], cams[0], cams[1], (0, 1),
                                    max_sigma_mad_k=None)
    assert len(no_test) >= len(fixed)  # without the 'imprecise' test nothing more is cut
    with pytest.raises(ValueError, match="max_patch must be an odd integer"):
        reconstruct_multiview(images[:3], cams[:3], pairs=[(0, 1)], max_patch=16)


def _true_right(truth, pc) -> np.ndarray:
    cl, cr = pc.cameras
    origin, direction = cl.ray(pc.x_template)
    hit = truth.cast_rays(o3d.core.Tensor(np.hstack([origin, direction]).astype(np.float32)))
    t = hit["t_hit"].numpy().astype(np.float64)
    t[~np.isfinite(t)] = np.nan
    return cr.project(origin + t[:, None] * direction)


def test_cloud_covers_the_vase_all_round(cloud):
    p = cloud.points
    theta = np.degrees(np.arctan2(p[:, 1], p[:, 0])) % 360.0
    # sections every 0.25 over the band every view sees well (the under-bulge below
    # z = 0.5 is seen at grazing angles); slab half-width 0.1 = 6 px at 320x240
    for z in np.arange(0.5, 2.76, 0.25):
        slab = np.abs(p[:, 2] - z) < 0.1
        counts = np.bincount((theta[slab] // 5).astype(int), minlength=72)
        assert counts.min() >= 1, f"z = {z}: empty 5-degree sectors {np.flatnonzero(counts == 0)}"


def test_cloud_reaches_the_rims_and_not_beyond(ring, cloud):
    """Eccentric windows: points up to the rims z = 0 and z = 3, none past them.

    One pixel on the vase is ``d / f`` (d: camera distance from the axis): 0.019 at
    320x240.  Measured: 101 points above z = 2.95 (2.7 px below the rim) with eccentric
    windows against 9 without (the silhouette rule dropped every window reaching past
    the rim, so the points stopped half a window short); the extreme points lie 0.5 px
    inside the top rim and 0.8 px below the bottom one.
    """
    cam = ring["cameras"][0]
    px = np.hypot(*cam.center[:2]) / cam.K[0, 0]
    z = cloud.points[:, 2]
    assert np.count_nonzero(z > 3.0 - 3.0 * px) >= 50
    assert np.count_nonzero(z < 3.0 * px) >= 50
    assert z.max() < 3.0 + 1.5 * px and z.min() > -1.5 * px


def test_cloud_accuracy_within_the_matching_error_prediction(ring, cloud):
    cams, images = ring["cameras"], ring["images"]
    pc = reconstruct_view_pair(images[0], images[1], cams[0], cams[1], (0, 1))
    err = pc.x_right[:, 0] - _true_right(ring["truth"], pc)[:, 0]
    rms_px = np.sqrt(np.nanmean(err**2))
    # depth error of a pair from a disparity error e: Z^2 / (f b) e (Z: camera distance
    # of the point, b: baseline, f: rectified focal length)
    cl, cr = pc.cameras
    depth = cl.depth(pc.points)
    baseline = np.linalg.norm(cl.center - cr.center)
    predicted = np.sqrt(np.mean((depth**2 / (cl.K[0, 0] * baseline)) ** 2)) * rms_px
    rms = np.sqrt(np.mean(_distance(ring["truth"], cloud.points) ** 2))
    # measured: rms 0.0013, predicted 0.0023 (0.04 px at Z ~ 6, f 381, b 1.85)
    assert rms <= predicted
    assert len(cloud) > 10000


def test_geometric_second_order_terms_match_the_matched_ones(ring):
    """Further views' second-order terms from the local-plane mappings (one LSM pass,
    the default) against those of a first affine-only pass (two passes): as many points
    confirmed, as accurate (measured here on views 0-5, pairs (1, 2), (3, 4): 1 719
    points, RMS 0.00172 geometric against 1 708, 0.00175 matched; 1024x768 ring at
    spacing 3: 0.000228 against 0.000226)."""
    cams, images = ring["cameras"][:6], ring["images"][:6]
    out = {}
    for mode in ("geometric", "matched"):
        c = reconstruct_multiview(images, cams, pairs=[(1, 2), (3, 4)], second_order=mode)
        out[mode] = (len(c), np.sqrt(np.mean(_distance(ring["truth"], c.points) ** 2)))
    assert out["geometric"][0] >= 0.97 * out["matched"][0]
    assert out["geometric"][1] <= 1.15 * out["matched"][1]
    with pytest.raises(ValueError, match="second_order must be"):
        reconstruct_multiview(images, cams, pairs=[(1, 2)], second_order="affine")


def test_systematic_offset_is_the_median_above_two_scatters():
    """matching.further_views._systematic_offset: zero while the common shift is within two
    scatters of one offset (matching noise decides), the median beyond (to its standard
    error 1.25 σ / sqrt(M), bounded at 4x), zero with fewer than 30 matches."""
    rng = np.random.default_rng(0)
    d = rng.normal(0.0, 0.3, (500, 2))  # scatter 0.42 px in quadrature: 2 scatters 0.85
    assert not np.any(_systematic_offset(d + [0.2, -0.3]))  # 0.36 px
    tol = 4 * 1.2533 * 0.3 / np.sqrt(len(d))
    np.testing.assert_allclose(_systematic_offset(d + [1.0, -1.5]), [1.0, -1.5], atol=tol)
    assert not np.any(_systematic_offset((d + [1.0, -1.5])[:29]))


def _tilted(cam: Camera, deg: float) -> Camera:
    """``cam`` turned by ``deg`` about its own x axis (the image moves by ~f tan(deg) in y)."""
    a = np.radians(deg)
    turn = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(a), -np.sin(a)], [0.0, np.sin(a), np.cos(a)]])
    R = turn @ cam.R
    return Camera(cam.K, cam.dist, R, -R @ cam.center, cam.width, cam.height, cam.name)


def test_a_further_views_orientation_error_is_estimated_not_rejected(ring):
    """A further view whose given camera is tilted by 0.25 deg (its image ~1.7 px off the
    others', 30x the matches' σ; the temple ring's given cameras: the views of one
    latitude sit ~1.2 px off those of the other): the common offset of its matches is
    estimated and removed (matching.further_views._systematic_offset), so it confirms as many
    points as with the exact camera, and the cloud stays as accurate.  Measured: 1 771
    points confirmed in view 0 against 1 769, RMS 0.00155 against 0.00151; without the
    estimate 4 points (every match 'inconsistent')."""
    cams, images = list(ring["cameras"][:6]), ring["images"][:6]
    exact = reconstruct_multiview(images, cams, pairs=[(1, 2), (3, 4)])
    cams[0] = _tilted(cams[0], 0.25)
    tilted = reconstruct_multiview(images, cams, pairs=[(1, 2), (3, 4)])
    assert exact.views[:, 0].sum() > 1000  # view 0 checks both pairs' points
    assert tilted.views[:, 0].sum() >= 0.95 * exact.views[:, 0].sum()
    assert len(tilted) >= 0.97 * len(exact)
    rms = {name: np.sqrt(np.mean(_distance(ring["truth"], c.points) ** 2))
           for name, c in (("exact", exact), ("tilted", tilted))}
    assert rms["tilted"] <= 1.1 * rms["exact"]
    # the offset found is the tilt's image shift, f tan(0.25 deg) = 1.815 px along y
    # (measured: (-0.003, 1.841) for pair (1, 2); pair (3, 4) has nearer views to check)
    shift = cams[0].K[1, 1] * np.tan(np.radians(0.25))
    found = [o["offset_px"] for o in tilted.stats["further_view_offsets"] if o["view"] == 0]
    assert found and not exact.stats["further_view_offsets"]
    np.testing.assert_allclose(found, [[0.0, shift]] * len(found), atol=0.1 * shift)


def test_multiview_sigma_is_smaller_and_honest(ring, cloud):
    st = cloud.stats
    # three or more rays instead of two: measured 0.00065 against 0.0019
    assert st["median_sigma_multiview"] < 0.5 * st["median_sigma_pair"]
    d = _distance(ring["truth"], cloud.points)
    # sigma is the worst direction's; the distance to the truth is the normal component.
    # Measured median |d|/sigma = 1.1 (sigma is ~1.6x optimistic); bound 1.5
    assert np.median(d / cloud.sigma) < 1.5


def test_views_say_which_cameras_saw_each_point(ring, cloud):
    assert cloud.views.shape == (len(cloud), N_VIEWS) and cloud.views.dtype == bool
    assert cloud.views.sum(1).min() >= 3  # a pair plus at least one confirming view
    rng = np.random.default_rng(2)
    for n in rng.choice(len(cloud), 50, replace=False):
        for v in np.flatnonzero(cloud.views[n]):
            cam = ring["cameras"][v]
            x = cam.project(cloud.points[n][None])[0]
            assert cam.depth(cloud.points[n][None])[0] > 0
            assert 0 <= x[0] < cam.width and 0 <= x[1] < cam.height
    assert set(cloud.reason_counts) == set(REASON_NAMES.values())
    assert cloud.reason_counts[REASON_NAMES[MULTIVIEW]] > 0.6 * cloud.stats["pair_points"]
    assert cloud.colours.shape == (len(cloud), 3) and cloud.colours.dtype == np.uint8
    assert cloud.colours.std() > 10  # the texture, not a constant


def test_bad_input(ring):
    cams, images = ring["cameras"], ring["images"]
    with pytest.raises(ValueError, match="2 images for 3 cameras"):
        reconstruct_multiview(images[:2], cams[:3])
    with pytest.raises(ValueError, match=r"images\[1\].*320x240"):
        reconstruct_multiview([images[0], images[1][:100]], cams[:2])
    with pytest.raises(ValueError, match="unknown matching option"):
        reconstruct_multiview(images[:3], cams[:3], spacng=4)
    with pytest.raises(ValueError, match="max_incidence_deg must lie in"):
        reconstruct_multiview(images[:3], cams[:3], max_incidence_deg=90.0)
    with pytest.raises(ValueError, match="check_views must be >= 1"):
        reconstruct_multiview(images[:3], cams[:3], check_views=0)


def _downsampled(cam: Camera, factor: int) -> Camera:
    """The camera of the image downsampled ``factor``x (pixel centres at integers:
    x' = (x + ½)/factor − ½)."""
    K = cam.K.copy()
    K[:2] /= factor
    K[:2, 2] += 0.5 / factor - 0.5
    return Camera(K, cam.dist, cam.R, cam.t, cam.width // factor, cam.height // factor,
                  cam.name)


@pytest.mark.slow
def test_pycolmap_poses_give_a_cloud_within_twice_the_error(ring, cloud, tmp_path):
    from matching.sfm import align_to_reference, run_sfm

    # SIFT finds too few features on the 320x240 vase for the mapper to chain all 24 views
    # (6 registered); upsampled 3x (cubic) it registers all 24 in ~30 s (2x: camera centres
    # 0.0175 off after alignment, 3x: 0.0142), and the intrinsics are scaled back.  At
    # 1024x768 the originals register directly (benchmarks/multiview.py: 0.0025).
    up = tmp_path / "up"
    up.mkdir()
    for cam, image in zip(ring["cameras"], ring["images"], strict=True):
        cv2.imwrite(str(up / cam.name), cv2.resize(image, None, fx=3, fy=3,
                                                   interpolation=cv2.INTER_CUBIC))
    # the rendered cameras have no distortion; SIMPLE_RADIAL's k1 trades against the focal
    # length on this narrow (+-11 deg) field (measured: f 957 px with k1 = -0.67 for the
    # true 832), which puts the cloud 0.12 off; a pinhole model has no such freedom
    # one thread: the same model every run (multi-threaded mapping varies run to run:
    # centre-aligned cloud RMS 0.0037-0.0085 over three runs)
    sfm = run_sfm(up, work_dir=tmp_path / "sfm", camera_model="SIMPLE_PINHOLE", num_threads=1)
    assert len(sfm.registered) == N_VIEWS
    aligned, centre_rms = align_to_reference(sfm, ring["cameras"])
    by_name = {c.name: _downsampled(c, 3) for c in aligned.cameras}
    cams = [by_name[c.name] for c in ring["cameras"]]
    result = reconstruct_multiview(ring["images"], cams)
    rms_known = np.sqrt(np.mean(_distance(ring["truth"], cloud.points) ** 2))
    rms_centres = np.sqrt(np.mean(_distance(ring["truth"], result.points) ** 2))
    refined = _umeyama_icp(ring["truth"], result.points)
    rms_sfm = np.sqrt(np.mean(_distance(ring["truth"], refined) ** 2))
    print(f"known {rms_known:.5f}, sfm centre-aligned {rms_centres:.5f}, icp {rms_sfm:.5f}, "
          f"centre rms {centre_rms:.4f}")
    assert rms_sfm <= 2.0 * rms_known, (rms_sfm, rms_centres, rms_known, centre_rms)
    assert len(result) > 0.5 * len(cloud)


def _umeyama_icp(truth, points, iterations: int = 5):
    """Similarity-align points to the truth surface: Umeyama to the closest points, repeated."""
    from matching.sfm import umeyama

    current = points
    for _ in range(iterations):
        closest = truth.compute_closest_points(o3d.core.Tensor(current.astype(np.float32)))
        target = closest["points"].numpy().astype(np.float64)
        s, R, t = umeyama(points, target)
        current = s * points @ R.T + t
    return current


def test_outline_points_put_the_rims_where_they_are(ring):
    """Outline points (matching.contours) from a wall that stops 1.5 px short of each
    rim, as area matching leaves it: the points near a rim lie on it to a fraction of a
    pixel, and on the surface.  The wall: 40 000 points of r(z) = 1 + 0.3 sin 2z between
    the rims less 1.5 px, with 0.1 px of noise; masks: the automatic foreground."""
    from matching.contours import outline_points
    from matching.masks import foreground_mask

    cams, images = ring["cameras"], ring["images"]
    px = np.hypot(*cams[0].center[:2]) / cams[0].K[0, 0]
    rng = np.random.default_rng(3)
    z = rng.uniform(1.5 * px, 3.0 - 1.5 * px, 40000)
    a = rng.uniform(0, 2 * np.pi, len(z))
    r = 1.0 + 0.3 * np.sin(2 * z)
    wall = np.column_stack([r * np.cos(a), r * np.sin(a), z])
    wall += rng.normal(0, 0.1 * px, wall.shape)
    masks = [foreground_mask(img, margin_px=0) for img in images]
    out = outline_points(images, cams, masks, wall, np.full(len(wall), 0.1 * px))
    zo = out.points[:, 2]
    top, bottom = zo > 3.0 - 1.5 * px, zo < 1.5 * px
    # measured (320x240, px = 0.0175): 97 / 34 points; top 90th percentile 0.03 px
    # below the rim (the median 0.66 px: points on the rim's sides, where the outline
    # turns down the wall), bottom 10th percentile 0.16 px below; 90 % of all within
    # 0.09 px of the truth
    assert top.sum() >= 20 and bottom.sum() >= 20
    assert abs(np.quantile(zo[top], 0.9) - 3.0) < 0.3 * px
    assert abs(np.quantile(zo[bottom], 0.1)) < 0.3 * px
    assert zo.max() < 3.0 + 1.0 * px and zo.min() > -1.0 * px
    assert np.quantile(_distance(ring["truth"], out.points), 0.9) < 0.5 * px


def test_pairs_waiting_on_disk_give_the_same_cloud(ring, tmp_path):
    """The pairs' clouds kept in a folder until their checks (what the in-process run
    does) give the cloud bit for bit, and the folder is left empty."""
    from matching.scheduler import thread_map

    views = list(range(4))
    images, cameras = [ring["images"][v] for v in views], [ring["cameras"][v] for v in views]
    pairs = [(v, v + 1) for v in range(3)]
    kept = reconstruct_multiview(images, cameras, pairs=pairs, map_func=thread_map(2))
    stored = reconstruct_multiview(images, cameras, pairs=pairs, map_func=thread_map(2),
                                   pair_store=str(tmp_path))
    assert len(kept) > 1000
    for name in ("points", "sigma", "views", "pair", "colours"):
        np.testing.assert_array_equal(getattr(stored, name), getattr(kept, name))
    assert list(tmp_path.iterdir()) == []
