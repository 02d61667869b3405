"""matching.masks and matching.search_range: object masks, visual hull, geometric search ranges."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from matching.cameras import Camera, read_cameras
from matching.masks import (
    foreground_mask,
    inside_masks,
    mask_path,
    near_foreground,
    read_mask,
    signed_distance,
)
from matching.multiview import rectify_pair
from matching.search_range import pair_disparity_range, scene_volume


def _object_image(background: float, rng, size=(240, 320)) -> tuple[np.ndarray, np.ndarray]:
    """A textured ellipse on a uniform noisy background, and its true silhouette."""
    h, w = size
    yy, xx = np.mgrid[0:h, 0:w]
    inside = ((xx - 170) / 90.0) ** 2 + ((yy - 120) / 70.0) ** 2 <= 1.0
    texture = 128 + 60 * np.sin(xx / 3.0) * np.cos(yy / 4.0)
    img = np.where(inside, texture, background) + rng.normal(0, 2.0, (h, w))
    return np.clip(img, 0, 255).astype(np.uint8), inside


@pytest.mark.parametrize("background", [8.0, 240.0])
def test_foreground_of_a_uniform_dark_or_light_background(background):
    rng = np.random.default_rng(0)
    img, truth = _object_image(background, rng)
    mask = foreground_mask(img, margin_px=3)
    assert mask is not None
    # every object pixel is in the mask (the texture never reaches the background grey
    # within the noise), and the mask reaches beyond it by at most the dilation plus
    # the blur's reach (4 σ = 6 px: the blurred edge crosses a threshold near the
    # background's own level there); measured 8.0 and 8.4 px
    assert mask[truth].all()
    beyond = cv2.distanceTransform((~truth).astype(np.uint8), cv2.DIST_L2, 5)
    assert beyond[mask].max() <= 3 + 6


def test_no_automatic_mask_on_a_textured_background():
    rng = np.random.default_rng(1)
    img = rng.uniform(0, 255, (240, 320)).astype(np.uint8)
    img = cv2.GaussianBlur(img, (0, 0), 2.0)
    img = cv2.normalize(img, None, 0, 255, cv2.NORM_MINMAX)
    assert foreground_mask(img) is None


def test_mask_files_as_colmap_names_them(tmp_path):
    (tmp_path / "masks").mkdir()
    m = np.zeros((20, 30), np.uint8)
    m[5:10, 5:20] = 255
    cv2.imwrite(str(tmp_path / "masks" / "a.jpg.png"), m)
    cv2.imwrite(str(tmp_path / "masks" / "b.png"), m)
    assert mask_path(tmp_path, "a.jpg").name == "a.jpg.png"
    assert mask_path(tmp_path, "b.jpg").name == "b.png"  # the stem's mask, as well
    assert mask_path(tmp_path, "c.png") is None
    mask = read_mask(tmp_path / "masks" / "a.jpg.png", (30, 20))
    assert mask.sum() == 75 and mask[5, 5] and not mask[0, 0]
    with pytest.raises(ValueError, match="mask is 30x20 px but its image is 40x20"):
        read_mask(tmp_path / "masks" / "a.jpg.png", (40, 20))


def _ring(n=12, radius=6.0, size=(320, 240), f=400.0, elevation=0.3):
    cams = []
    for k in range(n):
        a = 2 * np.pi * k / n
        c = np.array([radius * np.cos(a), radius * np.sin(a), elevation * radius])
        fwd = -c / np.linalg.norm(c)
        r = np.cross(fwd, [0, 0, 1.0])
        r /= np.linalg.norm(r)
        R = np.stack([r, np.cross(fwd, r), fwd])
        w, h = size
        K = np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1.0]])
        cams.append(Camera(K, [], R, -R @ c, w, h, f"v{k}"))
    return cams


def _sphere_masks(cams, radius):
    """Silhouettes of a sphere of ``radius`` at the origin (ray-sphere test per pixel)."""
    masks = []
    for cam in cams:
        w, h = cam.size
        ys, xs = np.mgrid[0:h, 0:w]
        _, d = cam.ray(np.column_stack([xs.ravel(), ys.ravel()]).astype(float))
        c = cam.center
        # distance of the origin from the ray
        t = -(d @ c)
        dist = np.linalg.norm(c + t[:, None] * d, axis=1)
        masks.append((dist <= radius).reshape(h, w))
    return masks


def test_volume_holds_the_object_and_the_hull_is_tighter():
    cams = _ring()
    rng = np.random.default_rng(2)
    u = rng.normal(size=(2000, 3))
    sphere = 1.0 * u / np.linalg.norm(u, axis=1, keepdims=True)  # surface, radius 1
    frusta = scene_volume(cams)
    hull = scene_volume(cams, masks=_sphere_masks(cams, 1.0))
    assert frusta.source == "frusta" and hull.source == "visual hull"
    for vol in (frusta, hull):
        lo, hi = vol.bounds
        assert np.all(sphere >= lo) and np.all(sphere <= hi)
    assert np.prod(np.ptp(hull.points, 0)) < 0.7 * np.prod(np.ptp(frusta.points, 0))
    # the hull of 12 views about a unit sphere lies within ~1.1 (polygonal cones) plus
    # a cell
    assert np.linalg.norm(hull.points, axis=1).max() < 1.15 + np.sqrt(3) * hull.cell


def test_pair_range_covers_the_object_disparities():
    cams = _ring()
    masks = _sphere_masks(cams, 1.0)
    rng = np.random.default_rng(3)
    u = rng.normal(size=(5000, 3))
    sphere = u / np.linalg.norm(u, axis=1, keepdims=True)
    for vol in (scene_volume(cams), scene_volume(cams, masks=masks)):
        _, cam_l, cam_r = rectify_pair(cams[0], cams[1])
        dmin, count = pair_disparity_range(vol, cam_l, cam_r)
        assert count % 16 == 0
        # disparities of the sphere points both views see (front half towards them)
        front = (sphere @ (cams[0].center + cams[1].center)) > 0
        X = sphere[front]
        d = cam_l.project(X)[:, 0] - cam_r.project(X)[:, 0]
        assert dmin <= d.min() and d.max() <= dmin + count
    # the hull's range is the narrower
    _, cam_l, cam_r = rectify_pair(cams[0], cams[1])
    assert (pair_disparity_range(scene_volume(cams, masks=masks), cam_l, cam_r)[1]
            <= pair_disparity_range(scene_volume(cams), cam_l, cam_r)[1])


def test_cameras_sharing_no_volume_raise():
    cams = _ring(4)
    away = [Camera(c.K, [], c.R, c.R @ c.center, *c.size, c.name) for c in cams]  # turned out
    with pytest.raises(ValueError, match="share no viewing volume"):
        scene_volume(away)


def test_visual_hull_keeps_points_on_every_mask():
    cams = _ring(6)
    masks = _sphere_masks(cams, 1.0)
    pts = np.array([[0.0, 0.0, 0.0], [0.5, 0.5, 0.0], [3.0, 0.0, 0.0], [0.0, 0.0, 1.5]])
    np.testing.assert_array_equal(inside_masks(pts, cams, masks), [True, True, False, False])
    np.testing.assert_array_equal(inside_masks(pts, cams, [None] * 6), [True] * 4)


def test_temple_masks_hold_the_object(real_data_dir):
    folder = real_data_dir / "temple_sparse_ring"
    cameras = read_cameras(folder / "templeSR_par.txt")
    for cam in cameras:
        img = cv2.imread(str(folder / cam.name))
        mask = foreground_mask(img)
        assert mask is not None, cam.name
        bright = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY) > 0.19 * 255
        # measured: >= 99.8 % of the pixels above the data set's threshold in every view
        assert mask[bright].mean() > 0.995, cam.name
        assert mask.mean() < 0.6  # the black cloth is mostly left out


def test_signed_distance_puts_the_boundary_halfway_between_pixel_centres():
    mask = np.zeros((20, 30), bool)
    mask[:, :10] = True  # object: columns 0-9, boundary at x = 9.5
    d = signed_distance(mask)
    np.testing.assert_allclose(d[5, [7, 8, 9, 10, 11, 14]], [-2.5, -1.5, -0.5, 0.5, 1.5, 4.5])
    assert signed_distance(np.ones((4, 4), bool)).max() < 0
    assert signed_distance(np.zeros((4, 4), bool)).min() > 0


def _sphere_points(n, seed):
    u = np.random.default_rng(seed).normal(size=(n, 3))
    return u / np.linalg.norm(u, axis=1, keepdims=True)


def _rim_offset_px(cams, points, radius=1.0):
    """Largest distance (px) by which points project outside a sphere's silhouette,
    over the views: the ray-sphere geometry, exact."""
    worst = np.zeros(len(points))
    for cam in cams:
        c = cam.center
        dist = np.linalg.norm(c)
        # angle of the point's ray from the centre direction vs the rim's angle
        rays = points - c
        cos_a = (rays @ -c) / (np.linalg.norm(rays, axis=1) * dist)
        alpha = np.arccos(np.clip(cos_a, -1, 1))
        rim = np.arcsin(radius / dist)
        f = cam.K[0, 0]
        # px along the image's radial direction, valid near the optical axis (the
        # sphere sits on it): f (tan alpha - tan rim)
        worst = np.maximum(worst, f * (np.tan(alpha) - np.tan(rim)))
    return worst


def test_silhouette_consistency_with_exact_silhouettes():
    """Exact silhouettes of a unit sphere: every surface point is kept, points planted
    1.5-3 px past the rim in some view are dropped unless their own σ covers that."""
    cams = _ring(8)
    dist = [signed_distance(m) for m in _sphere_masks(cams, 1.0)]
    surface = _sphere_points(4000, 4)
    q = 3.29
    sigma = np.full(len(surface), 1e-4)  # 0.007 px at 6 units, f = 400
    assert near_foreground(surface, sigma, cams, dist, q).all()
    assert near_foreground(0.5 * surface, sigma, cams, dist, q).all()  # inside the object
    off = 1.06 * surface
    px = _rim_offset_px(cams, off)
    planted = off[(px > 1.5) & (px < 3.0)]
    assert len(planted) > 100
    assert not near_foreground(planted, np.full(len(planted), 1e-4), cams, dist, q).any()
    # the same points with a σ of 1.4-1.9 px (0.025 units at f = 400, depth 5.2-7.3) are
    # within their tolerance, >= 0.71 + 3.29 * 1.37 = 5.2 px (the raster adds <= 0.71 px
    # to their 3 px)
    assert near_foreground(planted, np.full(len(planted), 0.025), cams, dist, q).all()
    # no foreground in any view: nothing changes
    assert near_foreground(planted, np.full(len(planted), 1e-4), cams, [None] * 8, q).all()


def _render_sphere(cam, background, rng, supersample=3):
    """A textured unit sphere at the origin seen by ``cam`` on a uniform background
    (or ``background="textured"``), ray-cast at ``supersample``² samples per pixel and
    area-averaged, grey noise σ = 2; uint8."""
    w, h = cam.size
    s = supersample
    ys, xs = np.mgrid[0:h * s, 0:w * s]
    px = np.column_stack([(xs.ravel() + 0.5) / s - 0.5, (ys.ravel() + 0.5) / s - 0.5])
    _, d = cam.ray(px)
    origin = cam.center
    b = d @ origin
    disc = b * b - (origin @ origin - 1.0)
    hit = disc >= 0
    t = -b - np.sqrt(np.where(hit, disc, 0.0))
    X = origin + t[:, None] * d
    tex = 150 + 60 * np.sin(9 * X[:, 0]) * np.cos(7 * X[:, 1] + 3 * X[:, 2])
    if isinstance(background, str):
        back = 128 + 100 * np.sin(px[:, 0] / 2.3) * np.cos(px[:, 1] / 3.1)
    else:
        back = np.full(len(px), float(background))
    img = np.where(hit, tex, back).reshape(h * s, w * s)
    img = cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)
    return np.clip(img + rng.normal(0, 2.0, img.shape), 0, 255).astype(np.uint8)


def test_silhouette_consistency_with_the_automatic_foreground():
    """Rendered ring, uniform dark background: the automatic foreground (no dilation)
    keeps every point of the surface and drops points planted well past the rim; on a
    textured background there is no foreground and nothing changes."""
    from matching.multiview import _foreground_distances

    cams = _ring(8)
    rng = np.random.default_rng(5)
    images = [_render_sphere(c, 8.0, rng) for c in cams]
    dist = _foreground_distances(len(cams), lambda v: images[v])
    assert all(d is not None for d in dist)
    surface = _sphere_points(4000, 6)
    sigma = np.full(len(surface), 1e-4)
    assert near_foreground(surface, sigma, cams, dist, 3.29).all()
    off = 1.3 * surface
    px = _rim_offset_px(cams, off)
    # the blurred threshold reaches past a bright edge (test above: up to ~6 px), so
    # only points farther out than that are the automatic foreground's to reject
    # (measured here: kept up to 5.3 px past the rim, dropped from 4.0 px)
    planted = off[px > 8.0]
    assert len(planted) > 100
    assert not near_foreground(planted, np.full(len(planted), 1e-4), cams, dist, 3.29).any()
    textured = [_render_sphere(c, "textured", rng) for c in cams[:2]]
    assert _foreground_distances(2, lambda v: textured[v]) == [None, None]


def test_bilinear_samples_any_count_in_pieces(monkeypatch):
    """masks.bilinear against the exact bilinear value, across several remap calls."""
    from matching import masks

    rng = np.random.default_rng(3)
    image = rng.normal(0, 1, (40, 50))
    x = rng.uniform([0, 0], [49, 39], (5000, 3, 2))
    monkeypatch.setattr(masks, "REMAP_MAX_ROWS", 2)               # 5 x 3 000 -> 8 calls
    got = masks.bilinear(image, x)
    x0, y0 = np.floor(x[..., 0]).astype(int), np.floor(x[..., 1]).astype(int)
    x1, y1 = np.minimum(x0 + 1, 49), np.minimum(y0 + 1, 39)
    fx, fy = x[..., 0] - x0, x[..., 1] - y0
    exact = ((1 - fx) * (1 - fy) * image[y0, x0] + fx * (1 - fy) * image[y0, x1]
             + (1 - fx) * fy * image[y1, x0] + fx * fy * image[y1, x1])
    assert got.shape == (5000, 3)
    assert np.max(np.abs(got - exact)) < 1e-3
    assert masks.bilinear(image, np.zeros((0, 2))).shape == (0,)
