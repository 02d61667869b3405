"""Holes in the data: an end the scanner never saw is closed by the flattest fill within
the data (``surface.stitch.uncovered_share``, ``surface.reconstruct.classify_ends``), never a
dome beyond them, or left as a border with ``open_holes``."""

from __future__ import annotations

import numpy as np
import pytest

from surface import metrics as M
from surface import reconstruct as rc
from surface.open_surface import boundary_loops
from surface.stitch import HOLE_SHARE, uncovered_share


def _capsule(count: int, hole_radius: float, seed: int = 0) -> np.ndarray:
    """Area-uniform points on a capsule (cylinder r = 1, z in [0, 2], a hemisphere on top,
    a flat base) without the points of the dome within ``hole_radius`` of the axis."""
    rng = np.random.default_rng(seed)
    areas = np.array([4 * np.pi, 2 * np.pi, np.pi])
    part = rng.choice(3, count, p=areas / areas.sum())
    t = rng.uniform(0, 2 * np.pi, count)
    pts = np.empty((count, 3))
    wall, dome, base = part == 0, part == 1, part == 2
    pts[wall] = np.column_stack([np.cos(t[wall]), np.sin(t[wall]),
                                 rng.uniform(0, 2, wall.sum())])
    polar = np.arccos(rng.uniform(0, 1, dome.sum()))     # z = cos(polar) uniform: by area
    pts[dome] = np.column_stack([np.sin(polar) * np.cos(t[dome]),
                                 np.sin(polar) * np.sin(t[dome]), 2 + np.cos(polar)])
    r = np.sqrt(rng.uniform(0, 1, base.sum()))
    pts[base] = np.column_stack([r * np.cos(t[base]), r * np.sin(t[base]), np.zeros(base.sum())])
    return pts[~((pts[:, 2] > 2) & (np.hypot(pts[:, 0], pts[:, 1]) < hole_radius))]


def test_uncovered_share_of_a_covered_disc_and_of_an_annulus():
    """Random points filling a unit disc cover it (share 0: an empty disc of 4 median
    nearest-neighbour distances is a 1.5e-5 event); points on the annulus 0.7 < r < 1
    leave the middle uncovered: share ~ (0.7 - 4ν)² / 0.95² of the shrunk disc."""
    rng = np.random.default_rng(1)
    ring = np.column_stack([np.cos(np.linspace(0, 2 * np.pi, 200, endpoint=False)),
                            np.sin(np.linspace(0, 2 * np.pi, 200, endpoint=False))])
    r, t = np.sqrt(rng.uniform(0, 1, 5000)), rng.uniform(0, 2 * np.pi, 5000)
    disc = np.column_stack([r * np.cos(t), r * np.sin(t)])
    assert uncovered_share(0.95 * ring, [], disc) == 0.0
    annulus = disc[r > 0.7]
    share = uncovered_share(0.95 * ring, [], annulus)
    assert 0.3 < share < 0.55
    assert uncovered_share(0.95 * ring, [0.75 * ring], annulus) <= HOLE_SHARE


@pytest.mark.parametrize("hole_radius", [0.0, 0.3])
def test_a_dome_with_a_hole_at_its_pole_stays_within_the_data(hole_radius):
    """The capsule, 20 000 points: with its dome whole the end is a dome to its pole
    (top within 0.01 of 3); with the points within 0.3 of the axis gone (the pole never
    seen, 4.5 % of the dome's area) the surface stays closed and its top is no higher
    than the highest point (before, the height field's quadratics ran on over the hole),
    and within 0.05 of it (the plateau the hole's rim allows)."""
    pts = _capsule(20_000, hole_radius)
    mesh = rc.surface_from_points(pts, axis="z")
    assert mesh.closed
    top = float(mesh.vertices[:, 2].max())
    if hole_radius == 0.0:
        assert top == pytest.approx(3.0, abs=0.01)
        assert not any("hole" in m for m in mesh.messages)
    else:
        assert pts[:, 2].max() - 0.05 < top <= pts[:, 2].max() + 1e-9
        assert any(m.startswith("top: a hole in the data") for m in mesh.messages)


def test_an_unseen_end_is_filled_flat_or_left_open():
    """The capsule with its dome's points within 0.6 of the axis gone (the top seen only
    as a ring): by default one closed surface whose top lies within the data's heights
    (to a quarter point spacing);
    with ``open_holes`` an open surface with one border loop at the top (the base, seen,
    is capped), one component, edge-manifold."""
    pts = _capsule(20_000, 0.6)
    closed = rc.surface_from_points(pts, axis="z")
    # the end is placed at the wall points' 95 % quantile / 0.95 (reconstruct.extend_to_caps):
    # within a quarter point spacing (sqrt(area / N) = 0.033) of the highest point
    assert closed.closed and float(closed.vertices[:, 2].max()) <= pts[:, 2].max() + 0.008
    opened = rc.surface_from_points(pts, axis="z", open_holes=True)
    topo = M.mesh_topology(opened.vertices, opened.triangles)
    assert not opened.closed and topo["components"] == 1 and topo["edge_manifold"]
    borders = boundary_loops(opened.triangles)
    assert len(borders) == 1
    assert opened.vertices[borders[0], 2].min() > 2.5     # the border is at the top
    assert any("left open" in m for m in opened.messages)
