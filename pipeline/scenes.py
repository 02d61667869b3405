r"""Synthetic scenes with exact ground truth: a recipe rendered by ray casting, the truth beside it.

A scene is a recipe (TOML, :mod:`pipeline.scene_recipe`) turned into a closed triangle mesh and a
set of pinhole cameras with Brown–Conrady distortion (:mod:`pipeline.scene_geometry`), and images
rendered by ray casting (open3d, :mod:`pipeline.raycast`) with a solid procedural texture
(:mod:`pipeline.scene_texture`).  The truth that matching and surface fitting are judged against is
written beside the images: the mesh, per-view depth maps and, for a stereo pair, the dense
left→right correspondence.

Image formation:

.. math::  g = \mathrm{round}\big(\gamma_v \cdot 255\,\bar L + o_v + \varepsilon\big),
           \quad \varepsilon \sim N(0, \sigma^2),

where :math:`\bar L` is the mean of the radiance :math:`L` over the pixel's area (supersampling
s×s, then ``cv2.INTER_AREA``) and :math:`\gamma_v, o_v` the view's gain and offset (radiance above
1 saturates at 255).

Depth ``truth/depth_XX.npy`` is :math:`z_c`, the z coordinate in the camera frame of the surface
point seen through the pixel centre (not the range along the ray), refined in float64 on the
triangle the ray hit (Möller & Trumbore [1]_) and stored as float32, NaN off the object.  The names
of the parts are re-exported here.

References
----------
.. [1] T. Möller, B. Trumbore, "Fast, minimum storage ray-triangle
   intersection", Journal of Graphics Tools 2(1), 21–28 (1997).
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from matching.cameras import Camera, StereoRig, write_cameras_yml, write_colmap_text
from pipeline import scene_cache
from pipeline.errors import InputError
from pipeline.raycast import RayCaster
from pipeline.scene_geometry import (
    MIN_RADIAL_FACTOR,
    TOL,
    SceneTolerance,
    fit_distance,
    make_camera,
    make_cameras,
    pixel_rays,
    pose_matrix,
    revolution_mesh,
    shape_mesh,
    undistort_pixels,
)
from pipeline.scene_recipe import DEFAULT_RECIPE, load_recipe, validate_recipe
from pipeline.scene_texture import SinusoidTexture, quiet_numba, shade

__all__ = ["DEFAULT_RECIPE", "MIN_RADIAL_FACTOR", "TOL", "Scene", "SceneTolerance",
           "SinusoidTexture", "build_scene", "correspondence", "load_recipe", "make_camera",
           "make_cameras", "pixel_rays", "pose_matrix", "render_scene", "render_view",
           "revolution_mesh", "shape_mesh", "undistort_pixels", "validate_recipe", "visible_from"]


@dataclass
class Scene:
    """Everything needed to render: mesh, shading normals, cameras, texture, radiometry.

    Attributes
    ----------
    vertices : (V, 3) float64, triangles : (F, 3) int64, corner_normals : (F, 3, 3) float64
    cameras : list of Camera
    texture : SinusoidTexture
    light : (3,) unit vector towards the light.
    gains, offsets : (n_views,) float64, grey levels for offsets.
    recipe : dict, the resolved recipe; derived : dict, values computed from it.
    """

    vertices: np.ndarray
    triangles: np.ndarray
    corner_normals: np.ndarray
    cameras: list[Camera]
    texture: SinusoidTexture
    light: np.ndarray
    gains: np.ndarray
    offsets: np.ndarray
    recipe: dict
    derived: dict = field(default_factory=dict)
    _caster: RayCaster | None = None
    _corner32: np.ndarray | None = None

    @property
    def corner_normals32(self) -> np.ndarray:
        """``corner_normals`` as contiguous float32 (what the shading kernel reads)."""
        if self._corner32 is None:
            self._corner32 = np.ascontiguousarray(self.corner_normals, dtype=np.float32)
        return self._corner32

    @property
    def caster(self) -> RayCaster:
        if self._caster is None:
            self._caster = RayCaster(self.vertices, self.triangles)
        return self._caster


def _seeded(seed: int, stream: int) -> np.random.Generator:
    """Independent reproducible streams: texture 1, gains 2, offsets 3, noise of view v 100+v."""
    return np.random.default_rng([seed, stream])


def _draw_per_view(lighting: dict, key: str, n: int, rng) -> np.ndarray:
    if f"{key}_range" in lighting:
        lo, hi = lighting[f"{key}_range"]
        return rng.uniform(lo, hi, n)
    return np.asarray(lighting[key], dtype=np.float64)


def build_scene(recipe: dict, source: str = "<recipe>") -> Scene:
    """Turn a resolved recipe into a :class:`Scene` (mesh, cameras, texture, radiometry).

    Raises
    ------
    InputError
        When a camera does not see the object (inside its bounding sphere, the
        object outside the image, or covering less than ``TOL.min_coverage``).
    """
    vertices, triangles, corner = shape_mesh(recipe["shape"])
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    centre = 0.5 * (lo + hi)
    bound = 0.5 * float(np.linalg.norm(hi - lo))
    cams = recipe["cameras"]
    key = "distance" if cams["layout"] == "stereo" else "radius"
    if key in cams:
        distance = cams[key]
    else:
        sample = vertices[:: max(1, len(vertices) // 4000)]
        try:
            distance = fit_distance(cams, centre, sample, bound)
        except InputError as exc:
            raise InputError(f"{source}: {exc}") from None
    cameras = make_cameras(cams, centre, distance)
    footprint = float(np.mean([np.linalg.norm(c.center - centre) / c.K[0, 0] for c in cameras]))
    tex = recipe["texture"]
    wavelength = (tex["wavelength_px"][0] * footprint, tex["wavelength_px"][1] * footprint)
    texture = SinusoidTexture.random(tex["components"], wavelength, tex["albedo"],
                                     _seeded(recipe["seed"], 1))
    lighting = recipe["lighting"]
    light = np.asarray(lighting["direction"], dtype=np.float64)
    n = len(cameras)
    gains = _draw_per_view(lighting, "gain", n, _seeded(recipe["seed"], 2))
    offsets = _draw_per_view(lighting, "offset", n, _seeded(recipe["seed"], 3))
    derived = {"centre": centre.tolist(), "bounding_radius": bound, key: distance,
               "pixel_footprint": footprint, "texture_wavelength": list(wavelength),
               "texture_frequencies": texture.frequencies.tolist(),  # cycles / unit
               "texture_phases": texture.phases.tolist(),  # turns
               "gains": gains.tolist(), "offsets": offsets.tolist(),
               "vertices": len(vertices), "triangles": len(triangles)}
    if cams["layout"] == "stereo":
        derived["baseline"] = float(np.linalg.norm(cameras[1].center - cameras[0].center))
        f0, f1 = cameras[0].R[2], cameras[1].R[2]
        derived["convergence_deg"] = math.degrees(math.acos(np.clip(f0 @ f1, -1.0, 1.0)))
    scene = Scene(vertices, triangles, corner, cameras, texture, light / np.linalg.norm(light),
                  gains, offsets, recipe, derived)
    _check_visibility(scene, source, key)
    return scene


def _check_visibility(scene: Scene, source: str, key: str) -> None:
    """Every camera must be outside the object's bounding sphere and see it on a coarse grid."""
    centre = np.asarray(scene.derived["centre"])
    for cam in scene.cameras:
        if np.linalg.norm(cam.center - centre) <= scene.derived["bounding_radius"]:
            raise InputError(f"{source}: field cameras.{key}: {cam.name} lies inside the "
                             f"object's bounding sphere (radius "
                             f"{scene.derived['bounding_radius']:.4g})")
        # a grid spanning the whole image area, corners included (where distortion is worst)
        xs, ys = np.meshgrid(np.linspace(-0.5, cam.width - 0.5, 64),
                             np.linspace(-0.5, cam.height - 0.5, 48))
        pixels = np.stack([xs.ravel(), ys.ravel()], 1)
        try:
            origin, directions = pixel_rays(cam, pixels)
        except InputError as exc:
            raise InputError(f"{source}: {exc}") from None
        coverage = float(np.mean(scene.caster.cast(origin, directions)["ids"] >= 0))
        if coverage < TOL.min_coverage:
            raise InputError(f"{source}: field cameras: {cam.name} does not see the object "
                             f"(it covers {100 * coverage:.2g} % of the image)")


def _pixel_grid(width: int, height: int, supersample: int = 1) -> np.ndarray:
    """Sample positions ``(H*s*W*s, 2)`` in full-resolution pixel coordinates, row-major.

    Sub-pixel ``(I, J)`` of an ``s×`` grid sits at ``((I + ½)/s − ½, (J + ½)/s − ½)``: the
    centres of the s×s cells tiling each pixel, so that ``INTER_AREA`` by s is the pixel's
    box average.
    """
    s = supersample
    xs = (np.arange(width * s) + 0.5) / s - 0.5
    ys = (np.arange(height * s) + 0.5) / s - 0.5
    gx, gy = np.meshgrid(xs, ys)
    return np.stack([gx.ravel(), gy.ravel()], axis=1)


def _radiance(scene: Scene, origin: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Cast rays and shade: radiance L ``(N,) float32`` (the background where a ray misses)."""
    hit = scene.caster.cast(origin, directions)
    lighting, tex = scene.recipe["lighting"], scene.texture
    params = np.array([lighting["ambient"], lighting["diffuse"], lighting["background"] / 255.0,
                       0.5 * (tex.albedo[0] + tex.albedo[1]), 0.5 * (tex.albedo[1] - tex.albedo[0]),
                       1.0 / (2.0 * tex.sigma), lighting.get("specular", 0.0),
                       lighting.get("shininess", 1.0)], dtype=np.float32)
    out = np.empty(len(directions), dtype=np.float32)
    quiet_numba(shade, np.asarray(origin, np.float32), np.asarray(directions, np.float32),
                 hit["t"], hit["ids"], hit["uv"], scene.corner_normals32,
                 scene.light.astype(np.float32), params, tex.frequencies.astype(np.float32),
                 tex.phases.astype(np.float32), out)
    return out


def _box_radiance(scene: Scene, cam: Camera, active: np.ndarray) -> np.ndarray:
    """Mean radiance over the area of each ``active`` pixel (flat indices ``(P,)``).

    s×s rays per pixel at the centres of the cells tiling it (``_pixel_grid``); their mean
    is the box average, i.e. ``cv2.INTER_AREA`` downsampling by the integer factor s.
    """
    s = scene.recipe["render"]["supersample"]
    offsets = (np.arange(s) + 0.5) / s - 0.5
    ox, oy = np.meshgrid(offsets, offsets)
    px = (active % cam.width)[:, None] + ox.ravel()[None, :]  # (P, s*s)
    py = (active // cam.width)[:, None] + oy.ravel()[None, :]
    origin, directions = pixel_rays(cam, np.stack([px.ravel(), py.ravel()], axis=1))
    return _radiance(scene, origin, directions).reshape(len(active), s * s).mean(
        axis=1, dtype=np.float64)


def render_view(scene: Scene, index: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Render view ``index``: 8-bit image, depth map and surface points at pixel centres.

    Returns
    -------
    image : (H, W) uint8
    depth : (H, W) float32, camera-frame z of the point seen through each pixel
        centre, NaN off the object.
    points : (H, W, 3) float64, that surface point (NaN off the object).

    Notes
    -----
    Only pixels within one pixel of a centre ray that hits the object are
    supersampled; the rest are background exactly.  An object part thinner than
    about a pixel that no pixel-centre ray meets may therefore be missed.
    """
    import cv2

    cam = scene.cameras[index]
    W, H = cam.width, cam.height
    # truth: one ray through each pixel centre, refined in float64
    origin, directions = pixel_rays(cam, _pixel_grid(W, H))
    hit = scene.caster.cast(origin, directions)
    on = hit["ids"] >= 0
    depth = np.full(W * H, np.nan)
    depth[on] = scene.caster.refine(origin, directions[on], hit["ids"][on])
    points = np.full((W * H, 3), np.nan)
    points[on] = origin + depth[on, None] * directions[on]
    # image: s×s rays per pixel near the object, box-averaged
    near = cv2.dilate(on.reshape(H, W).astype(np.uint8), np.ones((3, 3), np.uint8)).ravel() > 0
    radiance = np.full(W * H, scene.recipe["lighting"]["background"] / 255.0)
    radiance[near] = _box_radiance(scene, cam, np.flatnonzero(near))
    grey = scene.gains[index] * 255.0 * radiance.reshape(H, W) + scene.offsets[index]
    noise = scene.recipe["noise"]
    blur = noise.get("blur_difference_px", 0.0)
    if blur > 0 and index % 2 == 1:
        grey = cv2.GaussianBlur(grey, (0, 0), blur, borderType=cv2.BORDER_REFLECT)
    sigma = noise["sigma"]
    corr = noise.get("correlation_px", 0.0)
    if sigma > 0 and corr > 0:
        draw = _seeded(scene.recipe["seed"], 100 + index).normal(0.0, 1.0, grey.shape)
        draw = cv2.GaussianBlur(draw, (0, 0), corr, borderType=cv2.BORDER_REFLECT)
        grey = grey + sigma * draw / draw.std()
    elif sigma > 0:
        grey = grey + _seeded(scene.recipe["seed"], 100 + index).normal(0.0, sigma, grey.shape)
    image = np.clip(np.rint(grey), 0, 255).astype(np.uint8)
    return image, depth.reshape(H, W).astype(np.float32), points.reshape(H, W, 3)


def visible_from(scene: Scene, index: int, points: np.ndarray) -> np.ndarray:
    """Whether each of ``points (N, 3)`` (on the surface) is unoccluded from camera ``index``."""
    cam = scene.cameras[index]
    origin = cam.center
    directions = points - origin  # the point sits at ray parameter 1
    hit = scene.caster.cast(origin, directions)
    in_front = (points - origin) @ cam.R[2] > 0
    return in_front & (hit["t"] >= 1.0 - TOL.occlusion_rel)


def correspondence(scene: Scene, points: np.ndarray, target: int = 1) -> np.ndarray:
    """Pixel coordinates in view ``target`` of the surface ``points (H, W, 3)`` of another view.

    Returns ``(H, W, 2) float64`` (x, y) with distortion, NaN where the point is
    off the object, occluded in the target view or outside its image
    (x, y outside [-0.5, W-0.5] × [-0.5, H-0.5]).
    """
    H, W = points.shape[:2]
    flat = points.reshape(-1, 3)
    out = np.full((H * W, 2), np.nan)
    on = np.all(np.isfinite(flat), axis=1)
    on[on] = visible_from(scene, target, flat[on])
    cam = scene.cameras[target]
    xy = cam.project(flat[on])
    inside = ((xy[:, 0] >= -0.5) & (xy[:, 0] <= cam.width - 0.5)
              & (xy[:, 1] >= -0.5) & (xy[:, 1] <= cam.height - 0.5))
    xy[~inside] = np.nan
    out[on] = xy
    return out.reshape(H, W, 2)


def _scene_json(scene: Scene, source: str) -> str:
    info = {
        "recipe": scene.recipe,
        "derived": scene.derived,
        "source": Path(source).name,
        "conventions": {
            "camera": "world->camera x_c = R X + t (OpenCV); pixel centres at integer "
                      "coordinates; distortion k1 k2 p1 p2 k3 (Brown-Conrady, OpenCV order)",
            "depth": "truth/depth_XX.npy float32 (H, W): camera-frame z of the surface point "
                     "seen through each pixel centre; NaN off the object",
            "correspondence": "truth/correspondence.npy float64 (H, W, 2): (x, y) in view_01 "
                              "of the point seen through each view_00 pixel centre; NaN off "
                              "the object, occluded in view_01 or outside its image",
            "image": "grey = gain * 255 * mean over the pixel of albedo * (ambient + diffuse * "
                     "max(0, n.l)) + offset + N(0, sigma^2), rounded and clipped to 0..255",
            "colmap": "sparse/: principal point + 0.5 (COLMAP's pixel-corner origin)",
        },
    }
    return json.dumps(info, indent=2, sort_keys=True) + "\n"


def render_scene(recipe_or_path: dict | str | os.PathLike, outdir: str | os.PathLike,
                 progress: bool = True, source: str | None = None) -> Path:
    """Render a scene and write its folder atomically; return ``outdir``.

    Parameters
    ----------
    recipe_or_path : dict or path-like
        A recipe file, or a recipe dict (validated again here).
    outdir : path-like
        The output folder (replaced as a whole on success, untouched on error):
        ``images/view_XX.png``, ``cameras.yml``, ``sparse/{cameras,images,points3D}.txt``,
        ``truth/mesh.ply``, ``truth/depth_XX.npy``, ``truth/correspondence.npy``
        (stereo), ``scene.json``.
    progress : bool
        Per-view progress bar on stderr when it is a terminal.
    source : str, optional
        Name used in error messages and ``scene.json`` for a recipe given as a dict.
    """

    from pipeline.atomic import atomic_dir
    from pipeline.guards import write_image
    from pipeline.mesh_io import write_mesh

    if isinstance(recipe_or_path, Mapping):
        source = source or "<recipe>"
        recipe = validate_recipe(recipe_or_path, source)
    else:
        source = str(recipe_or_path)
        recipe = load_recipe(recipe_or_path)
    key = scene_cache.cache_key(recipe, Path(source).name)
    outdir = Path(outdir)
    with atomic_dir(outdir, kind="synth") as tmp:  # never deletes files it did not write
        # the same recipe, code and libraries render the same bytes (pipeline.scene_cache)
        if scene_cache.fetch(key, tmp):
            return outdir
        scene = build_scene(recipe, source)
        (tmp / "images").mkdir()
        (tmp / "truth").mkdir()
        first_points = None
        for index in _views(scene, progress):
            image, depth, points = render_view(scene, index)
            name = scene.cameras[index].name
            write_image(tmp / "images" / name, image)
            np.save(tmp / "truth" / f"depth_{index:02d}.npy", depth)
            if index == 0:
                first_points = points
        stereo = recipe["cameras"]["layout"] == "stereo"
        if stereo:
            np.save(tmp / "truth" / "correspondence.npy", correspondence(scene, first_points, 1))
        write_mesh(tmp / "truth" / "mesh.ply", scene.vertices, scene.triangles)
        rig = StereoRig(*scene.cameras) if stereo else None
        write_cameras_yml(tmp / "cameras.yml", scene.cameras, rig=rig)
        write_colmap_text(tmp / "sparse", scene.cameras)
        (tmp / "scene.json").write_text(_scene_json(scene, source))
        scene_cache.store(key, tmp)
    return outdir


def _views(scene: Scene, progress: bool):
    indices = range(len(scene.cameras))
    if not progress:
        return indices
    from pipeline.progress import track

    return track(indices, desc="synth", unit="view")
