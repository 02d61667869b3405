"""Rendering speed of the synthetic scenes: seconds per 1024x768 view of a 100k-triangle object.

Goal: <= 2 s per view on 2 cores at the default supersampling (s = 3, i.e. 9 rays
per pixel near the object).  Rows, all in one process on the same vase (r = 1 + 0.3 sin 2z,
99 840 triangles, the default stereo pair):

* ``render_view`` at s = 1, 2, 3, 4 (pinhole) and at s = 3 through Brown-Conrady distortion
  (rays through exactly undistorted directions cost an inverse of the lens model per ray);
* the peers inside one view: open3d's ``RaycastingScene.cast_rays`` alone for the same rays
  (the floor no shading can beat), and the texture evaluated with numpy's ``np.sin`` instead
  of the numba kernel (why the kernel exists);
* the whole ``render_scene`` of the default recipe (2 views, correspondence, files).

Run: ``.venv/bin/python benchmarks/render.py [--quick] [--json PATH]``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pipeline import scenes  # noqa: E402

DISTORTION = [-0.08, 0.02, 0.0005, -0.0003, 0.0]


_CPU: list[float] = []  # CPU seconds (all threads) of the last _median_time call


def _median_time(function, repeats: int) -> float:
    """Median wall seconds; the median CPU seconds go to ``_CPU`` (a figure the load of a
    shared machine inflates less: on 2 idle cores wall >= CPU / 2)."""
    times, cpu = [], []
    for _ in range(repeats):
        start, start_cpu = time.perf_counter(), time.process_time()
        function()
        times.append(time.perf_counter() - start)
        cpu.append(time.process_time() - start_cpu)
    _CPU[:] = [statistics.median(cpu)]
    return statistics.median(times)


def _row(case: str, supersample: int, seconds: float, **extra) -> dict:
    return {"case": case, "supersample": supersample, "seconds_per_view": seconds,
            "cpu_seconds_per_view": _CPU[0], **extra}


def _scene(supersample: int, distortion=None):
    overrides = {"render.supersample": supersample}
    if distortion is not None:
        overrides["cameras.distortion"] = distortion
    return scenes.build_scene(scenes.load_recipe(overrides=overrides))


def _rays_near_object(scene, s: int):
    """The rays render_view casts for the image: s*s per pixel within a pixel of the object."""
    import cv2

    cam = scene.cameras[0]
    origin, directions = scenes.pixel_rays(cam, scenes._pixel_grid(cam.width, cam.height))
    on = (scene.caster.cast(origin, directions)["ids"] >= 0).reshape(cam.height, cam.width)
    near = np.flatnonzero(cv2.dilate(on.astype(np.uint8), np.ones((3, 3), np.uint8)).ravel())
    offsets = (np.arange(s) + 0.5) / s - 0.5
    ox, oy = np.meshgrid(offsets, offsets)
    px = ((near % cam.width)[:, None] + ox.ravel()).ravel()
    py = ((near // cam.width)[:, None] + oy.ravel()).ravel()
    return scenes.pixel_rays(cam, np.stack([px, py], 1))


def run(quick: bool) -> dict:
    repeats = 1 if quick else 3
    rows = []
    base = None
    for s in (1, 2, 3, 4):
        scene = _scene(s)
        base = scene if s == 3 else base
        scenes.render_view(scene, 0)  # warm-up: numba cache, open3d BVH
        seconds = _median_time(lambda scene=scene: scenes.render_view(scene, 0), repeats)
        rows.append(_row(f"render_view, s={s}, pinhole", s, seconds))
    scene = _scene(3, DISTORTION)
    scenes.render_view(scene, 0)
    seconds = _median_time(lambda: scenes.render_view(scene, 0), repeats)
    rows.append(_row("render_view, s=3, distortion", 3, seconds))
    origin, directions = _rays_near_object(base, 3)
    seconds = _median_time(lambda: base.caster.cast(origin, directions), repeats)
    rows.append(_row("peer: open3d cast_rays only, s=3 rays", 3, seconds,
                     rays=len(directions)))
    hit = base.caster.cast(origin, directions)
    on = hit["ids"] >= 0
    points = (origin + hit["t"][on, None] * directions[on]).astype(np.float32)
    tex = base.texture
    seconds = _median_time(lambda: tex.raw(points), repeats)
    rows.append(_row("texture, numba kernel (s=3 hits)", 3, seconds, points=int(on.sum())))
    chunk = points[: len(points) // (8 if quick else 1)]

    def numpy_texture():
        total = np.zeros(len(chunk), np.float32)
        for start in range(0, len(chunk), 200_000):
            block = chunk[start:start + 200_000]
            phase = block @ tex.frequencies.T.astype(np.float32) + tex.phases.astype(np.float32)
            total[start:start + 200_000] = np.sin(np.float32(2 * np.pi) * phase).sum(axis=1)
        return total

    seconds = _median_time(numpy_texture, 1) * len(points) / len(chunk)
    _CPU[0] *= len(points) / len(chunk)
    rows.append(_row("peer: texture with numpy np.sin (s=3 hits)", 3, seconds,
                     points=int(on.sum())))
    with tempfile.TemporaryDirectory() as tmp:
        seconds = _median_time(lambda: scenes.render_scene(scenes.DEFAULT_RECIPE,
                                                           Path(tmp) / "vase",
                                                           progress=False), 1)
    _CPU[0] /= 2
    rows.append(_row("render_scene vase.toml (2 views + truth + files)", 3, seconds / 2,
                     seconds_total=seconds))
    cam = base.cameras[0]
    return {
        "benchmark": "render",
        "image": [cam.width, cam.height],
        "triangles": int(len(base.triangles)),
        "object_pixels_share": float(np.mean(np.isfinite(
            scenes.render_view(base, 0)[1]))),
        "goal_seconds_per_view": 2.0,
        "default_supersample": 3,
        "cpu_count": os.cpu_count(),
        "load_average": list(os.getloadavg()),
        "python": platform.python_version(),
        "quick": quick,
        "rows": rows,
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="one repetition per row")
    parser.add_argument("--json", type=Path,
                        default=Path(__file__).resolve().parent / "results" / "render.json")
    args = parser.parse_args(argv)
    result = run(args.quick)
    print(f"render: {result['image'][0]}x{result['image'][1]} px, {result['triangles']} "
          f"triangles, object on {100 * result['object_pixels_share']:.0f} % of the image, "
          f"{result['cpu_count']} cores, load {result['load_average'][0]:.1f}")
    print(f"{'case':<52} {'s':>2} {'s/view':>8} {'cpu s/view':>10}")
    for row in result["rows"]:
        print(f"{row['case']:<52} {row['supersample']:>2} {row['seconds_per_view']:>8.3f} "
              f"{row['cpu_seconds_per_view']:>10.3f}")
    print(f"goal: <= {result['goal_seconds_per_view']} s per view at s = 3")
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(result, indent=2, sort_keys=True) + "\n")
    print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
