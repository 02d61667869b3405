"""The synthetic scenes' truth is true: depth, correspondence, photometry, camera files.

Every check is independent of the renderer's own code path where it can be: the
cameras are read back from the written files (``matching.cameras``), rays are
built by ``Camera.ray``, and intersections are brute-forced in float64 over
every triangle of ``truth/mesh.ply``.  Images are 160x120 so the file runs in
seconds.
"""

from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest

from matching.cameras import read_cameras_yml, read_colmap_text
from pipeline import scene_geometry, scenes
from pipeline.errors import InputError
from pipeline.mesh_io import read_mesh
from pipeline.raycast import look_at

SMALL = {"cameras.width": 160, "cameras.height": 120, "cameras.focal_px": 208.0}


def _render(tmp_path_factory, name, overrides, recipe=scenes.DEFAULT_RECIPE):
    recipe = scenes.load_recipe(recipe, overrides={**SMALL, **overrides})
    out = tmp_path_factory.mktemp(name) / "scene"
    scenes.render_scene(recipe, out, progress=False)
    return out, recipe


@pytest.fixture(scope="module")
def vase(tmp_path_factory):
    """Pinhole stereo vase, 3000 triangles (small enough to brute-force every ray)."""
    return _render(tmp_path_factory, "vase", {"shape.triangles": 3000})[0]


@pytest.fixture(scope="module")
def ellipse(tmp_path_factory, fixtures_dir):
    """Tilted elliptic cylinder seen through Brown-Conrady distortion."""
    return _render(tmp_path_factory, "ellipse", {"shape.triangles": 3000},
                   fixtures_dir / "scenes" / "ellipse.toml")[0]


def _first_hit(vertices, triangles, origin, direction):
    """Float64 Moller-Trumbore of rays ``origin (3,) + t direction (P, 3)`` against every
    triangle; the nearest t > 0 (inf on a miss)."""
    tri = vertices[triangles]
    v0, e1, e2 = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    s = origin - v0  # (F, 3)
    q = np.cross(s, e1)  # (F, 3)
    t_all = np.full(len(direction), np.inf)
    for start in range(0, len(direction), 64):
        d = direction[start:start + 64, None, :]  # (P, 1, 3)
        p = np.cross(d, e2)  # (P, F, 3)
        det = np.einsum("fc,pfc->pf", e1, p)
        u = np.einsum("fc,pfc->pf", s, p) / det
        v = np.einsum("pc,fc->pf", d[:, 0], q) / det
        t = np.einsum("fc,fc->f", e2, q)[None, :] / det
        ok = (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
        t_all[start:start + 64] = np.where(ok, t, np.inf).min(axis=1)
    return t_all


def _brute_force_depth(vertices, triangles, camera, pixels):
    """Camera-frame z of the first float64 hit through each pixel (rays from the camera file)."""
    origin, direction = camera.ray(pixels)  # unit directions
    t = _first_hit(vertices, triangles, origin[0], direction)
    return np.where(np.isfinite(t), t * (direction @ camera.R[2]), np.nan)


def _silhouette(mask):
    """Pixels whose 3x3 neighbourhood mixes object and background."""
    m = mask.astype(np.uint8)
    return cv2.dilate(m, np.ones((3, 3), np.uint8)) != cv2.erode(m, np.ones((3, 3), np.uint8))


# ------------------------------------------------------------------ geometry


def test_vase_profile_is_the_analytic_vase(fixtures_dir):
    recipe = scenes.load_recipe(fixtures_dir / "scenes" / "vase.toml")
    radius, _, _ = scene_geometry.revolution_functions(recipe["shape"])
    z = np.linspace(0.0, 3.0, 20001)
    # 61 knots, h = 0.05: the not-a-knot end intervals dominate; measured 3.2e-7
    assert np.abs(radius(z) - (1 + 0.3 * np.sin(2 * z))).max() < 4e-7


@pytest.mark.parametrize("name", ["vase", "cylinder", "amphora", "ellipse"])
def test_shipped_mesh_is_closed_outward_and_has_the_analytic_volume(fixtures_dir, name):
    recipe = scenes.load_recipe(fixtures_dir / "scenes" / f"{name}.toml",
                                overrides={"shape.triangles": 20000})
    vertices, triangles, corner = scenes.shape_mesh(recipe["shape"])
    # closed 2-manifold, consistently oriented: every directed edge once, its reverse once
    edges = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    directed = {tuple(e) for e in edges.tolist()}
    assert len(directed) == len(edges)
    assert all((b, a) in directed for a, b in directed)
    tri = vertices[triangles]
    volume = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6
    _, rx, ry = scene_geometry.revolution_functions(recipe["shape"])
    profile = np.asarray(recipe["shape"]["profile"])
    z = np.linspace(profile[0, 0], profile[-1, 0], 200001)
    exact = np.pi * np.trapezoid(rx(z) * ry(z), z)
    # inscribed polygons lose ~ (2 pi / n_theta)^2 / 6 of the area: < 0.1 % at 20k triangles
    assert volume > 0
    assert abs(volume - exact) / exact < 1e-3
    # shading normals are unit and point outward (same side as the face normal)
    assert np.allclose(np.linalg.norm(corner, axis=2), 1.0)
    face = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    assert np.all(np.einsum("fkc,fc->fk", corner, face) > 0)


def test_pose_rotates_the_axis(fixtures_dir):
    recipe = scenes.load_recipe(fixtures_dir / "scenes" / "ellipse.toml",
                                overrides={"shape.triangles": 4000})
    vertices, _, _ = scenes.shape_mesh(recipe["shape"])
    centred = vertices - vertices.mean(axis=0)
    axis = np.linalg.svd(centred, full_matrices=False)[2][0]  # longest extent: the axis
    rotation, _ = scenes.pose_matrix(recipe["shape"]["pose"])
    # the elliptic cylinder's long axis is the rotated z axis (up to sign and the
    # discretisation of a 3 x 2.24 x 1.34 box)
    assert abs(axis @ rotation[:, 2]) > 0.99
    tilt = math.degrees(math.acos(abs(rotation[2, 2])))
    assert tilt == pytest.approx(20.0, abs=1e-9)


# ------------------------------------------------------------------ depth


@pytest.mark.parametrize("scene_name", ["vase", "ellipse"])
def test_depth_equals_independent_float64_ray_cast(scene_name, request):
    out = request.getfixturevalue(scene_name)
    vertices, triangles = read_mesh(out / "truth" / "mesh.ply")
    cameras = read_cameras_yml(out / "cameras.yml")
    rng = np.random.default_rng(0)
    for index, cam in enumerate(cameras):
        depth = np.load(out / "truth" / f"depth_{index:02d}.npy")
        assert depth.dtype == np.float32 and depth.shape == (cam.height, cam.width)
        hit = np.isfinite(depth)
        assert 0.05 < hit.mean() < 0.95
        rows, cols = np.nonzero(~_silhouette(hit))
        pick = rng.choice(len(rows), 600, replace=False)
        pixels = np.stack([cols[pick], rows[pick]], axis=1).astype(np.float64)
        truth = _brute_force_depth(vertices, triangles, cam, pixels)
        stored = depth[rows[pick], cols[pick]].astype(np.float64)
        assert np.array_equal(np.isnan(truth), np.isnan(stored))
        on = np.isfinite(truth)
        # float32 storage: half an ulp of rounding, plus float64 noise of ~1e-15 relative
        ulp = np.spacing(stored[on].astype(np.float32)).astype(np.float64)
        assert np.all(np.abs(truth[on] - stored[on]) <= 0.5 * ulp + 1e-12 * stored[on])


def test_depth_points_reproject_to_their_pixel_centres_through_distortion(ellipse):
    cam = read_cameras_yml(ellipse / "cameras.yml")[0]
    assert cam.has_distortion
    depth = np.load(ellipse / "truth" / "depth_00.npy").astype(np.float64)
    rows, cols = np.nonzero(np.isfinite(depth))
    pixels = np.stack([cols, rows], axis=1).astype(np.float64)
    origin, direction = cam.ray(pixels)
    z = depth[rows, cols]
    points = origin + direction * (z / (direction @ cam.R[2]))[:, None]
    assert np.abs(cam.project(points) - pixels).max() < 1e-6


# ------------------------------------------------------------------ correspondence


def _skew(v):
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


def test_correspondence_lies_on_the_epipolar_line(vase):
    left, right = read_cameras_yml(vase / "cameras.yml")
    corr = np.load(vase / "truth" / "correspondence.npy")
    assert corr.shape == (left.height, left.width, 2)
    rows, cols = np.nonzero(np.isfinite(corr[..., 0]))
    assert len(rows) > 0.1 * left.width * left.height
    R = right.R @ left.R.T
    T = right.t - R @ left.t
    F = np.linalg.inv(right.K).T @ _skew(T) @ R @ np.linalg.inv(left.K)
    xl = np.stack([cols, rows, np.ones_like(rows)], axis=1).astype(np.float64)
    xr = np.concatenate([corr[rows, cols], np.ones((len(rows), 1))], axis=1)
    lines = xl @ F.T  # epipolar lines in the right image
    distance = np.abs(np.einsum("ij,ij->i", xr, lines)) / np.hypot(lines[:, 0], lines[:, 1])
    assert distance.max() < 1e-6


def test_correspondence_is_the_projection_of_the_left_depth(vase):
    left, right = read_cameras_yml(vase / "cameras.yml")
    depth = np.load(vase / "truth" / "depth_00.npy").astype(np.float64)
    corr = np.load(vase / "truth" / "correspondence.npy")
    assert np.all(np.isnan(corr[~np.isfinite(depth)]))  # off the object -> NaN
    rows, cols = np.nonzero(np.isfinite(corr[..., 0]))
    origin, direction = left.ray(np.stack([cols, rows], 1).astype(np.float64))
    z = depth[rows, cols]
    points = origin + direction * (z / (direction @ left.R[2]))[:, None]
    projected = right.project(points)
    # the stored depth is float32: a relative error 2^-24 moves the right point by at most
    # f * (B/Z) * 2^-24 ~ 208 * 0.3 * 6e-8 < 1e-5 px
    assert np.abs(projected - corr[rows, cols]).max() < 1e-5


@pytest.fixture(scope="module")
def wide_vase(tmp_path_factory):
    """A wide-baseline pair (base/distance ~ 0.6): a broad band seen only from the left."""
    return _render(tmp_path_factory, "wide", {"shape.triangles": 3000, "cameras.distance": 8.0,
                                              "cameras.baseline": 5.0})[0]


def test_correspondence_nan_exactly_where_occluded(wide_vase):
    """A float64 ray from the right camera meets the mesh before a NaN point, never before a
    point with a correspondence."""
    out = wide_vase
    vertices, triangles = read_mesh(out / "truth" / "mesh.ply")
    left, right = read_cameras_yml(out / "cameras.yml")
    depth = np.load(out / "truth" / "depth_00.npy").astype(np.float64)
    corr = np.load(out / "truth" / "correspondence.npy")
    rows, cols = np.nonzero(np.isfinite(depth))
    origin, direction = left.ray(np.stack([cols, rows], 1).astype(np.float64))
    points = origin + direction * (depth[rows, cols] / (direction @ left.R[2]))[:, None]
    visible = np.isfinite(corr[rows, cols, 0])
    assert 0.05 < (~visible).mean() < 0.6
    rng = np.random.default_rng(2)
    pick = np.concatenate([rng.choice(np.flatnonzero(visible), 300, replace=False),
                           rng.choice(np.flatnonzero(~visible), 300, replace=False)])
    towards = points[pick] - right.center
    distance = np.linalg.norm(towards, axis=1)
    first = _first_hit(vertices, triangles, right.center, towards / distance[:, None])
    # the renderer's tolerance is 1e-4 of the distance; a point within it of the
    # occluder is ambiguous, and a random sample of 600 meets none such
    blocked = first < distance * (1 - 1e-4)
    assert np.array_equal(blocked, ~visible[pick])


# ------------------------------------------------------------------ photometry


@pytest.fixture(scope="module")
def photometric_pair(tmp_path_factory):
    """The vase with a coarser texture (so bicubic interpolation is exact to ~1 grey),
    with and without noise."""
    common = {"texture.wavelength_px": [10.0, 30.0], "shape.triangles": 20000}
    clean, _ = _render(tmp_path_factory, "clean", {**common, "noise.sigma": 0.0})
    noisy, recipe = _render(tmp_path_factory, "noisy", common)
    return clean, noisy, recipe


def _photometric_residual(out, recipe):
    """(I_l - o_l)/g_l - (I_r(q) - o_r)/g_r at interior corresponding pixels, grey levels."""
    derived = json.loads((out / "scene.json").read_text())["derived"]
    gains, offsets = derived["gains"], derived["offsets"]
    assert gains == recipe["lighting"]["gain"] and offsets == recipe["lighting"]["offset"]
    left = cv2.imread(str(out / "images" / "view_00.png"), cv2.IMREAD_UNCHANGED).astype(np.float32)
    right = cv2.imread(str(out / "images" / "view_01.png"), cv2.IMREAD_UNCHANGED).astype(
        np.float32)
    corr = np.load(out / "truth" / "correspondence.npy").astype(np.float32)
    depth_r = np.load(out / "truth" / "depth_01.npy")
    # interior: 5x5 neighbourhoods fully on the object in both views and all visible
    kernel = np.ones((5, 5), np.uint8)
    ok_l = cv2.erode(np.isfinite(corr[..., 0]).astype(np.uint8), kernel) > 0
    ok_r = cv2.erode(np.isfinite(depth_r).astype(np.uint8), kernel) > 0
    sampled_ok = cv2.remap(ok_r.astype(np.float32), np.nan_to_num(corr[..., 0], nan=-10),
                           np.nan_to_num(corr[..., 1], nan=-10), cv2.INTER_NEAREST) > 0
    mask = ok_l & sampled_ok
    warped = cv2.remap(right, np.nan_to_num(corr[..., 0], nan=-10),
                       np.nan_to_num(corr[..., 1], nan=-10), cv2.INTER_CUBIC)
    residual = (left - offsets[0]) / gains[0] - (warped - offsets[1]) / gains[1]
    return residual[mask]


def test_corresponding_pixels_agree_photometrically(photometric_pair):
    clean, noisy, recipe = photometric_pair
    model = _photometric_residual(clean, recipe)
    assert len(model) > 1500
    # noise-free: Lambertian radiance is view-independent; what remains is rounding
    # (1/sqrt(6) grey for two roundings), bicubic interpolation and the different pixel
    # footprints of the two views: measured 0.55 grey RMS
    assert abs(model.mean()) < 0.15
    rms_model = float(np.sqrt(np.mean(model**2)))
    assert rms_model < 1.0
    # with noise sigma in both images the variance grows by sigma^2 (1/g_l^2 + k/g_r^2),
    # k <= 1 the noise gain of bicubic interpolation
    sigma = recipe["noise"]["sigma"]
    g_l, g_r = recipe["lighting"]["gain"]
    residual = _photometric_residual(noisy, recipe)
    assert abs(residual.mean()) < 0.2
    rms = float(np.sqrt(np.mean(residual**2)))
    assert rms**2 > rms_model**2 + 0.5 * sigma**2 / g_l**2
    assert rms**2 < 1.2 * (rms_model**2 + sigma**2 * (1 / g_l**2 + 1 / g_r**2))


def test_texture_is_band_limited_and_in_the_albedo_range():
    rng = np.random.default_rng(5)
    texture = scenes.SinusoidTexture.random(48, (0.02, 0.08), (0.15, 0.85), rng)
    freq = np.linalg.norm(texture.frequencies, axis=1)
    assert np.all((freq >= 1 / 0.08) & (freq <= 1 / 0.02))
    points = rng.uniform(-2, 2, (20000, 3))
    albedo = texture(points)
    assert albedo.min() >= 0.15 and albedo.max() <= 0.85
    assert albedo.std() > 0.1  # contrast for matching
    # the polynomial sine in the kernel equals the sum of sines to float32 precision
    exact = np.sin(2 * np.pi * (points @ texture.frequencies.T + texture.phases)).sum(axis=1)
    assert np.abs(texture.raw(points) - exact).max() < 2e-3  # 48 terms, float32 phases


def test_texture_has_gradient_energy_for_area_based_matching():
    """Shift precision of a 15x15 patch, sigma / sqrt(sum g^2) (the LSM covariance of a pure
    shift, Gruen 1985), is a few hundredths of a pixel on the default texture."""
    recipe = scenes.load_recipe(overrides={**SMALL, "noise.sigma": 0.0,
                                           "shape.triangles": 20000})
    image, depth, _ = scenes.render_view(scenes.build_scene(recipe), 0)
    grey = image.astype(np.float64)
    gx = cv2.Sobel(grey, cv2.CV_64F, 1, 0, ksize=1) / 2  # central differences
    gy = cv2.Sobel(grey, cv2.CV_64F, 0, 1, ksize=1) / 2
    interior = cv2.erode(np.isfinite(depth).astype(np.uint8), np.ones((15, 15), np.uint8)) > 0
    energy = np.minimum(cv2.boxFilter(gx**2, -1, (15, 15), normalize=False),
                        cv2.boxFilter(gy**2, -1, (15, 15), normalize=False))[interior]
    sigma_shift = 2.0 / np.sqrt(energy)  # at the default 2 grey levels of noise
    # measured: median 0.016 px, 95 % 0.028 px (0.018 / 0.033 at 1024x768)
    assert np.median(sigma_shift) < 0.03
    assert np.percentile(sigma_shift, 95) < 0.05


# ------------------------------------------------------------------ camera files


def test_camera_files_round_trip_through_opencv_and_pycolmap(ellipse):
    import pycolmap

    fs = cv2.FileStorage(str(ellipse / "cameras.yml"), cv2.FILE_STORAGE_READ)
    try:
        assert int(fs.getNode("n_views").real()) == 2
        K = fs.getNode("view_00").getNode("K").mat()
        dist = fs.getNode("view_00").getNode("dist").mat().ravel()
        rig_R, rig_T = fs.getNode("rig_R").mat(), fs.getNode("rig_T").mat().ravel()
    finally:
        fs.release()
    recipe = json.loads((ellipse / "scene.json").read_text())["recipe"]
    assert K[0, 0] == recipe["cameras"]["focal_px"]
    assert K[0, 2] == pytest.approx((recipe["cameras"]["width"] - 1) / 2, abs=0)
    assert dist.tolist() == recipe["cameras"]["distortion"]
    left, right = read_cameras_yml(ellipse / "cameras.yml")
    assert np.allclose(rig_R, right.R @ left.R.T, atol=1e-15)
    assert np.allclose(rig_T, right.t - rig_R @ left.t, atol=1e-14)
    assert all(a.allclose(b, rtol=0, atol=1e-14)
               for a, b in zip(read_colmap_text(ellipse / "sparse"), [left, right], strict=True))
    reconstruction = pycolmap.Reconstruction(str(ellipse / "sparse"))
    assert len(reconstruction.images) == 2
    for image in reconstruction.images.values():
        cam = left if image.name == left.name else right
        pose = image.cam_from_world().matrix()
        assert np.allclose(pose[:, :3], cam.R, atol=1e-12) and np.allclose(pose[:, 3], cam.t)
        colmap_cam = reconstruction.cameras[image.camera_id]
        # COLMAP's pixel origin is the corner of the first pixel: +0.5
        assert colmap_cam.principal_point_x == pytest.approx(cam.K[0, 2] + 0.5, abs=1e-12)
        assert np.allclose(colmap_cam.params[4:8], cam.dist[:4])


# ------------------------------------------------------------------ determinism, layouts


def test_same_recipe_gives_byte_identical_files(tmp_path):
    recipe = scenes.load_recipe(overrides={**SMALL, "shape.triangles": 2000})
    first = scenes.render_scene(recipe, tmp_path / "a", progress=False)
    second = scenes.render_scene(recipe, tmp_path / "b", progress=False)
    files = sorted(p.relative_to(first) for p in first.rglob("*") if p.is_file())
    assert len(files) == 12  # 11 outputs and the marker listing them (pipeline.atomic.MARKER)
    for name in files:
        assert (first / name).read_bytes() == (second / name).read_bytes(), name
    # the resolved recipe in scene.json renders the same scene again
    again = json.loads((first / "scene.json").read_text())["recipe"]
    third = scenes.render_scene(again, tmp_path / "c", progress=False)
    assert (third / "images/view_01.png").read_bytes() == (
        first / "images/view_01.png").read_bytes()
    # and another seed does not
    other = scenes.render_scene({**recipe, "seed": recipe["seed"] + 1}, tmp_path / "d",
                                progress=False)
    assert (other / "images/view_00.png").read_bytes() != (
        first / "images/view_00.png").read_bytes()


def test_ring_cameras_look_at_the_centre_from_the_radius(fixtures_dir):
    recipe = scenes.load_recipe(fixtures_dir / "scenes" / "amphora.toml",
                                overrides={**SMALL, "shape.triangles": 2000,
                                           "cameras.radius": 9.0})
    scene = scenes.build_scene(recipe)
    assert len(scene.cameras) == 12
    centre = np.asarray(scene.derived["centre"])
    for cam in scene.cameras:
        assert np.linalg.norm(cam.center - centre) == pytest.approx(9.0, rel=1e-12)
        assert np.allclose(cam.project(centre[None]), cam.K[:2, 2], atol=1e-9)
    gains = np.asarray(scene.derived["gains"])
    assert np.all((gains >= 0.9) & (gains <= 1.1)) and np.ptp(gains) > 0


def test_stereo_auto_geometry_fills_the_image(fixtures_dir):
    scene = scenes.build_scene(scenes.load_recipe(
        overrides={**SMALL, "shape.triangles": 2000}))
    left, right = scene.cameras
    for cam in scene.cameras:
        xy = cam.project(scene.vertices)
        extent = np.maximum(np.abs(xy - cam.K[:2, 2]).max(axis=0) / (0.5 * np.array(
            [cam.width, cam.height])), 0)
        assert extent.max() == pytest.approx(0.9, abs=0.01)  # fill = 0.9 of the tighter side
    baseline = np.linalg.norm(right.center - left.center)
    assert baseline == pytest.approx(0.25 * scene.derived["distance"], rel=1e-12)


def test_mesh_shape_with_ring(tmp_path):
    import open3d as o3d

    sphere = o3d.geometry.TriangleMesh.create_sphere(radius=2.0, resolution=20)
    o3d.io.write_triangle_mesh(str(tmp_path / "ball.ply"), sphere)
    (tmp_path / "ball.toml").write_text(
        '[shape]\nkind = "mesh"\npath = "ball.ply"\nscale = 0.5\naxis = [0, 1, 0]\n'
        '[shape.pose]\ntranslation = [1.0, 2.0, 3.0]\n'
        '[cameras]\nlayout = "ring"\nwidth = 96\nheight = 72\nn = 3\n')
    out = scenes.render_scene(tmp_path / "ball.toml", tmp_path / "out", progress=False)
    cam = read_cameras_yml(out / "cameras.yml")[2]
    depth = np.load(out / "truth" / "depth_02.npy").astype(np.float64)
    rows, cols = np.nonzero(np.isfinite(depth))
    origin, direction = cam.ray(np.stack([cols, rows], 1).astype(np.float64))
    points = origin + direction * (depth[rows, cols] / (direction @ cam.R[2]))[:, None]
    distance = np.linalg.norm(points - [1.0, 2.0, 3.0], axis=1)
    # on the scaled polyhedral sphere: between its inradius and its circumradius 1
    assert distance.max() <= 1.0 + 1e-6 and distance.min() > 0.97


def test_undistort_inverts_the_distortion_model():
    cam = scenes.make_camera(0, np.array([0.0, -5.0, 0.0]),
                              look_at(np.array([0.0, -5.0, 0.0]), np.zeros(3)),
                              np.array([[300.0, 0, 159.5], [0, 300.0, 119.5], [0, 0, 1]]),
                              np.array([-0.25, 0.08, 0.001, -0.002, -0.01]),
                              {"width": 320, "height": 240})
    pixels = np.random.default_rng(1).uniform([-0.5, -0.5], [319.5, 239.5], (5000, 2))
    xy = scenes.undistort_pixels(pixels, cam)
    back = cv2.projectPoints(np.column_stack([xy, np.ones(len(xy))]), np.zeros(3), np.zeros(3),
                             cam.K, cam.dist)[0].reshape(-1, 2)
    assert np.abs(back - pixels).max() < 1e-9


def test_non_invertible_distortion_is_an_input_error():
    cam = scenes.make_camera(0, np.array([0.0, -5.0, 0.0]),
                              look_at(np.array([0.0, -5.0, 0.0]), np.zeros(3)),
                              np.array([[100.0, 0, 159.5], [0, 100.0, 119.5], [0, 0, 1]]),
                              np.array([-0.9, 0.0, 0.0, 0.0, 0.0]),
                              {"width": 320, "height": 240})
    with pytest.raises(InputError, match="cameras.distortion"):
        scenes.undistort_pixels(np.array([[0.0, 0.0], [319.0, 239.0]]), cam)


# ------------------------------------------------------------------ less kind scenes
def _views(overrides, index):
    recipe = scenes.load_recipe(overrides={**SMALL, "shape.triangles": 4000, **overrides})
    scene = scenes.build_scene(recipe)
    return scenes.render_view(scene, index)


def test_correlated_noise_option():
    """noise.correlation_px = c low-passes the noise by a Gaussian of c px and keeps its σ:
    its lag-1 autocorrelation is exp(-1/(4 c²)) = 0.78 at c = 1 (white: 0); quantisation
    to 8 bits adds 1/12 grey level² of white noise, the object's edges a little more."""
    clean, depth, _ = _views({"noise.sigma": 0.0}, 0)
    noisy, _, _ = _views({"noise.sigma": 4.0, "noise.correlation_px": 1.0}, 0)
    diff = noisy.astype(np.float64) - clean
    inner = cv2.erode(np.isfinite(depth).astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    both = inner[:, 1:] & inner[:, :-1]
    lag1 = np.mean((diff[:, 1:] * diff[:, :-1])[both]) / np.mean(diff[inner] ** 2)
    assert lag1 == pytest.approx(np.exp(-0.25), abs=0.06)
    assert np.std(diff[inner]) == pytest.approx(4.0, rel=0.1)


def test_blur_difference_option_blurs_the_odd_views_only():
    """noise.blur_difference_px blurs views 1, 3, ... before the noise: their gradient
    energy falls, view 0 is untouched (byte-identical without the option)."""
    plain0, _, _ = _views({"noise.sigma": 0.0}, 0)
    blurred0, _, _ = _views({"noise.sigma": 0.0, "noise.blur_difference_px": 1.0}, 0)
    plain1, _, _ = _views({"noise.sigma": 0.0}, 1)
    blurred1, _, _ = _views({"noise.sigma": 0.0, "noise.blur_difference_px": 1.0}, 1)
    assert np.array_equal(plain0, blurred0)
    energy = [np.mean(np.diff(im.astype(np.float64), axis=1) ** 2) for im in (plain1, blurred1)]
    assert energy[1] < 0.6 * energy[0]


def test_specular_option_adds_a_highlight_that_moves_between_views():
    """lighting.specular adds a Blinn-Phong highlight k_s max(0, n·h)^p: it only brightens
    (never darkens, up to the 8-bit rounding), leaves the image byte-identical when absent,
    and sits on another part of the surface in each view (the half vector follows the
    camera): the surface points under the two views' brightest highlight pixels lie
    apart by more than a tenth of the vase's radius (measured 0.18 of 1; the highlight
    adds up to 102 / 112 grey levels at k_s 0.4, p 30)."""
    plain, _, _ = _views({"noise.sigma": 0.0}, 0)
    again, _, _ = _views({"noise.sigma": 0.0, "lighting.specular": 0.0}, 0)
    assert np.array_equal(plain, again)
    peaks = []
    for view in (0, 1):
        base, _, _ = _views({"noise.sigma": 0.0}, view)
        shiny, _, points = _views({"noise.sigma": 0.0, "lighting.specular": 0.4,
                                   "lighting.shininess": 30.0}, view)
        gain = shiny.astype(np.float64) - base
        assert gain.min() >= -1.0 and gain.max() > 40.0
        smooth = cv2.GaussianBlur(gain, (0, 0), 2.0)
        y, x = np.unravel_index(np.argmax(smooth), smooth.shape)
        peaks.append(points[y, x])
    assert np.linalg.norm(peaks[0] - peaks[1]) > 0.1
