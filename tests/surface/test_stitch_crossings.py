"""The stitched mesh does not cross itself where its pieces meet: an end's dome and the
strips below its contour, a section whose loop is two nested contours joined through a
neck.  Each case is small synthetic data that crossed before the rule it tests."""

from __future__ import annotations

import numpy as np

from surface.stitch import stitch_rings
from surface.validity import check_solid

AXIS = np.array([0.0, 0.0, 1.0])


def _circle(radius: float, z: float, n: int = 64, centre=(0.0, 0.0)) -> np.ndarray:
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return np.column_stack([centre[0] + radius * np.cos(t), centre[1] + radius * np.sin(t),
                            np.full(n, z)])


def _tilted_dome_points(count: int, top: float, tilt: float, seed: int) -> np.ndarray:
    """Cap points over the unit disk on a dome tilted so that its low side lies ``tilt``
    below ``top`` at the rim: the quadratics fitted there run back through the top
    contour's plane."""
    rng = np.random.default_rng(seed)
    r, t = np.sqrt(rng.uniform(0, 0.98, count)), rng.uniform(0, 2 * np.pi, count)
    x, y = r * np.cos(t), r * np.sin(t)
    return np.column_stack([x, y, top + 0.3 * (1 - r ** 2) + tilt * x])


def test_an_end_dome_stays_beyond_its_contour_plane():
    """A cone widening upwards (radius 0.5 + 0.5 z, 11 rings 0.1 apart: the strip under
    the top ring lies under the top contour), its top points on a dome whose low side
    falls 0.25 (2.5 ring spacings) below the top ring's plane.  Before the dome's heights
    were held on the cap's side of that plane the cap crossed the strips below it (189
    pairs with the support rings, 160 without); now the mesh is a valid solid, and the
    dome still rises to the points' height at the centre (0.3 above the rim, within
    0.01)."""
    rings = [_circle(0.5 + 0.5 * z, z) for z in np.linspace(0.0, 1.0, 11)]
    cap = _tilted_dome_points(4000, 1.0, 0.25, seed=0)
    for support in (0.002, None):
        result = stitch_rings(rings, AXIS, cap_points=cap, support_sigma=support)
        report = check_solid(result.vertices, result.triangles)
        assert result.closed and report.valid, (support, report.problems())
        top = result.vertices[np.unique(result.triangles[result.region == -2])]
        assert top[:, 2].min() >= 1.0 - 1e-12
        centre = top[np.argmin(np.linalg.norm(top[:, :2], axis=1))]
        assert abs(centre[2] - 1.3) < 0.01
