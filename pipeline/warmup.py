"""Compile photosurf's numba kernels once, at set-up, into numba's on-disk cache.

``python -m pipeline.warmup`` renders 4 views of the small vase ring
(``vase_ring_small.toml``) and runs the multi-view acquisition and a stereo match over it, and
the surface back end over a small noisy vase cloud, so every ``cache=True``
kernel (matching, the scene renderer, the curve fits, Loop's patches, the
tessellation) is compiled and written to ``__pycache__``.  Two reasons:

* the first real run does not pay the compilation;
* every later process — this one, threads, Dask workers — then loads the same
  machine code.  Measured in a fresh clone: a process that compiled the kernels
  itself and Dask workers that loaded them from the cache it wrote gave clouds
  that differed in the last bits (same points; ``test_executor``'s 1024×768
  identity test failed), while with a warm cache they are bit-identical.  The
  cause inside numba was not found; warming the cache at set-up removes it.

``make setup`` (and so ``make demo`` / ``make test``) runs it after installing and
whenever the kernels' sources change; it prints one line.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def warm_up() -> float:
    """Compile and cache the kernels; returns the seconds it took."""
    from matching.multiview import reconstruct_multiview, select_pairs
    from pipeline.scenes import build_scene, load_recipe, render_view

    start = time.perf_counter()
    recipe = load_recipe(ROOT / "fixtures" / "scenes" / "vase_ring_small.toml")
    scene = build_scene(recipe)
    views = range(4)
    images = [render_view(scene, k)[0] for k in views]
    cameras = [scene.cameras[k] for k in views]
    pairs = select_pairs(cameras)[:2]
    reconstruct_multiview(images, cameras, pairs=pairs)
    # the stereo path's adaptive patch (multi-view matches at the fixed patch)
    reconstruct_multiview(images, cameras, pairs=pairs[:1], adaptive_patch=True)
    # the surface kernels (curve fits, Loop's patches, tessellation) on a noisy vase cloud
    from surface import bezier
    from surface.reconstruct import surface_from_points

    rng = np.random.default_rng(0)
    z = rng.uniform(0.0, 3.0, 4000)
    theta = rng.uniform(0.0, 2 * np.pi, 4000)
    r = 1.0 + 0.3 * np.sin(2.0 * z)
    cloud = np.column_stack([r * np.cos(theta), r * np.sin(theta), z])
    stitched = surface_from_points(cloud + rng.normal(0.0, 0.002, cloud.shape), axis="z")
    bezier.tessellate(bezier.control_net(stitched.vertices, stitched.triangles), 1)
    from surface.validity import check_solid  # the solid check's candidate prefilter

    check_solid(stitched.vertices, stitched.triangles)
    # a kernel on a path the vase does not take: the tree walk of a loop whose θ folds
    from surface import section_trees

    section_trees._tree_walk(3, np.array([0, 1]), np.array([1, 2]), 0)
    return time.perf_counter() - start


def main() -> int:
    seconds = warm_up()
    print(f"photosurf setup: numba kernels compiled and cached ({seconds:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
