"""The temple benchmark's visibility proxy (``benchmarks/_visibility.py``) on exact
geometry: a textured back wall with a box in front, two cameras side by side."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from matching.cameras import Camera

ROOT = Path(__file__).resolve().parents[2]


def _seen_in_both():
    sys.path.insert(0, str(ROOT / "benchmarks"))
    try:
        from _visibility import seen_in_both
    finally:
        sys.path.remove(str(ROOT / "benchmarks"))
    return seen_in_both


def _grid(x0, x1, y0, y1, z, step):
    x, y = np.meshgrid(np.arange(x0, x1, step), np.arange(y0, y1, step))
    return np.column_stack([x.ravel(), y.ravel(), np.full(x.size, z)])


def test_pixels_behind_an_occluder_in_the_right_view_are_hidden():
    """Wall at z = 2 (points every 2 mm), the front face of a 0.2 x 0.2 box at z = 1.5;
    the right camera 0.3 to the right.  A wall point is hidden from the right camera
    exactly when its ray to it crosses the box's face: x_r(t) at z = 1.5 within the box.
    The proxy agrees with that on every pixel more than 3 px from an edge (14 137 of
    20 000; 243 of them hidden, 5 147 off the cloud: no surface)."""
    seen_in_both = _seen_in_both()
    K = np.array([[800.0, 0, 320], [0, 800.0, 240], [0, 0, 1]])
    left = Camera(K, np.zeros(0), np.eye(3), np.zeros(3), 640, 480)
    right = Camera(K, np.zeros(0), np.eye(3), np.array([-0.3, 0.0, 0.0]), 640, 480)
    wall = _grid(-0.6, 0.6, -0.45, 0.45, 2.0, 0.002)
    box = _grid(-0.1, 0.1, -0.1, 0.1, 1.5, 0.002)
    cloud = np.vstack([wall, box])
    rng = np.random.default_rng(0)
    x_left = np.column_stack([rng.uniform(0, 639, 20_000), rng.uniform(0, 479, 20_000)])
    surface, seen = seen_in_both(cloud, left, right, x_left)

    # exact: the left ray hits the box face (z = 1.5) or else the wall (z = 2)
    ray = np.column_stack([(x_left - K[:2, 2]) / 800.0, np.ones(len(x_left))])
    on_box = (np.abs(ray[:, 0] * 1.5) < 0.1) & (np.abs(ray[:, 1] * 1.5) < 0.1)
    point = ray * np.where(on_box, 1.5, 2.0)[:, None]
    on_cloud = np.where(on_box, True, (np.abs(point[:, 0]) < 0.6) & (np.abs(point[:, 1]) < 0.45))
    # the right camera sits at x = 0.3: its ray to a wall point meets z = 1.5 at
    centre = np.array([0.3, 0.0, 0.0])
    at = centre + (point - centre) * (1.5 / point[:, 2:])
    behind = ~on_box & (np.abs(at[:, 0]) < 0.1) & (np.abs(at[:, 1]) < 0.1)
    right_px = (point - centre) @ K.T
    right_px = right_px[:, :2] / right_px[:, 2:]
    in_right = (right_px >= 0).all(1) & (right_px[:, 0] <= 639) & (right_px[:, 1] <= 479)
    truth = on_cloud & in_right & ~behind
    # clear of the edges by 3 px (the proxy looks 2.5 px round each pixel)
    margin = 3.0 / 800.0 * 2.0
    def away(values, edge):
        return np.abs(np.abs(values) - edge) > margin

    clear = (away(at[:, 0], 0.1) & away(at[:, 1], 0.1) & away(point[:, 0], 0.6)
             & away(point[:, 1], 0.45) & away(ray[:, 0] * 1.5, 0.1) & away(ray[:, 1] * 1.5, 0.1)
             & (np.abs(right_px[:, 0] - 639) > 3) & (right_px[:, 0] > 3))
    assert clear.sum() > 12_000 and behind[clear].sum() > 200 and (~on_cloud[clear]).sum() > 500
    assert np.array_equal(surface[clear], on_cloud[clear])
    assert np.array_equal(seen[clear], truth[clear])
