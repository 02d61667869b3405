"""Creases the smooth surface interpolates (2026-12-06): ``surface.fitting.convex_creases``,
``surface.interpolation.crease_vertices`` and ``interpolating_control(..., creases)``."""

from __future__ import annotations

import numpy as np
import open3d as o3d

from surface import interpolation, sizing
from surface.fitting import convex_creases, limit_positions


def _arrays(mesh):
    return np.asarray(mesh.vertices).copy(), np.asarray(mesh.triangles).astype(np.int64)


def _stepped(rows: int = 9, n_theta: int = 48):
    """Closed mesh of a stepped column about z: r = 1 for z in [0, 1], a flat ledge at z =
    1 in to r = 0.6, r = 0.6 up to z = 2, flat caps -- one convex crease (the ledge's
    outer edge), one valley (its inner corner), two rims at the ends."""
    theta = 2 * np.pi * np.arange(n_theta) / n_theta
    profile = [(1.0, z) for z in np.linspace(0.0, 1.0, rows)] + \
              [(r, 1.0) for r in (0.9, 0.8, 0.7)] + \
              [(0.6, z) for z in np.linspace(1.0, 2.0, rows)]
    v = np.array([[r * np.cos(a), r * np.sin(a), z] for r, z in profile for a in theta])
    faces = []
    for i in range(len(profile) - 1):
        for j in range(n_theta):
            a, b = i * n_theta + j, i * n_theta + (j + 1) % n_theta
            faces += [[a, b, b + n_theta], [a, b + n_theta, a + n_theta]]
    bottom, top = len(v), len(v) + 1
    v = np.vstack([v, [[0, 0, 0.0], [0, 0, 2.0]]])
    last = (len(profile) - 1) * n_theta
    for j in range(n_theta):
        k = (j + 1) % n_theta
        faces += [[bottom, k, j], [top, last + j, last + k]]
    return v, np.array(faces, dtype=np.int64), profile, n_theta


def test_a_cube_is_all_ridges_and_an_l_prism_has_one_valley():
    v, t = _arrays(o3d.geometry.TriangleMesh.create_box().subdivide_midpoint(1))
    crease = convex_creases(v, t)
    corner = np.isin(v, (0.0, 1.0)).sum(axis=1) >= 2     # on an edge of the box
    assert np.array_equal(crease, corner)               # face centres are not on a crease
    # the stepped column: the ledge's outer edge (r = 1, z = 1) is a ridge, its inner
    # corner (r = 0.6, z = 1) a valley, the rims at z = 0 and 2 ridges
    v, t, profile, n = _stepped()
    crease = convex_creases(v, t)
    r, z = np.hypot(v[:, 0], v[:, 1]), v[:, 2]
    assert crease[(np.abs(r - 1.0) < 1e-9) & (np.abs(z - 1.0) < 1e-9)].all()
    assert not crease[(np.abs(r - 0.6) < 1e-9) & (np.abs(z - 1.0) < 1e-9)].any()
    assert crease[(np.abs(r - 1.0) < 1e-9) & (z < 1e-9)].all()
    assert not crease[(z > 0.1) & (z < 0.9)].any()       # the walls, 7.5° a step round


def test_crease_vertices_leave_the_ends_and_need_a_dense_crease_nearby():
    v, t, profile, n = _stepped()
    axis = (0.0, 0.0, 1.0)
    inner = (0.125, 1.875)                             # inside the second rows from each end
    mask = sizing.crease_vertices(v, t, axis, inner)
    r, z = np.hypot(v[:, 0], v[:, 1]), v[:, 2]
    ledge = (np.abs(r - 1.0) < 1e-9) & (np.abs(z - 1.0) < 1e-9)
    assert np.array_equal(mask, ledge)                  # not the rims at z = 0, 2
    # a candidate's crease counts only within reach of one of the dense mesh's
    far = np.array([[5.0, 5.0, 1.0]])
    assert sizing.crease_vertices(v, t, axis, inner, far, 0.1) is None
    near = v[ledge][::4] + 0.01
    assert np.array_equal(sizing.crease_vertices(v, t, axis, inner, near, 0.3), ledge)
    sizing_flag = interpolation.INTERPOLATE_CREASES
    try:
        interpolation.INTERPOLATE_CREASES = False
        assert sizing.crease_vertices(v, t, axis, inner) is None
    finally:
        interpolation.INTERPOLATE_CREASES = sizing_flag


def test_interpolated_creases_pass_through_the_ledge_kept_ones_round_it_off():
    # The Loop limit of the control mesh at the ledge's outer edge: kept as they are, the
    # vertices round the edge inwards (their limit points pulled into the solid by ~0.03
    # here); interpolated, the limit points are the vertices (the sparse solve, ~1e-10).
    v, t, profile, n = _stepped()
    r, z = np.hypot(v[:, 0], v[:, 1]), v[:, 2]
    ledge = (np.abs(r - 1.0) < 1e-9) & (np.abs(z - 1.0) < 1e-9)
    kept = sizing.interpolating_control(v, t)
    moved = sizing.interpolating_control(v, t, ledge)
    off_kept = np.linalg.norm(limit_positions(kept, t)[ledge] - v[ledge], axis=1)
    off_moved = np.linalg.norm(limit_positions(moved, t)[ledge] - v[ledge], axis=1)
    assert off_kept.min() > 0.01
    assert off_moved.max() < 1e-9
    # everything else as before: the walls interpolated either way, the rims kept
    wall = (z > 0.1) & (z < 0.9)
    rim = (np.abs(r - 1.0) < 1e-9) & (z < 1e-9)
    for control in (kept, moved):
        np.testing.assert_allclose(limit_positions(control, t)[wall], v[wall], atol=1e-9)
    np.testing.assert_array_equal(moved[rim], v[rim])
    np.testing.assert_array_equal(kept[rim], v[rim])


def test_the_sizing_interpolates_a_stepped_columns_ledge_and_not_its_rims():
    # A noisy cloud of the stepped column (σ = 0.002, 20 000 points): the sized control
    # mesh carries its creases to the smooth stage -- on the ledge's outer edge (r = 1,
    # z = 1), none at the rims of the ends (z = 0, 2) nor on the ledge's inner corner
    # (a valley) -- and the surface built to judge the candidate interpolates them: its
    # limit points there are the control mesh's vertices.
    from pipeline.section_surface import sized_surface
    from testkit.vase import noisy_cloud

    v, t, _, _ = _stepped(rows=41, n_theta=256)
    points = noisy_cloud(v, t, 20_000, seed=3)
    sized = sized_surface(points, axis="z").sized
    assert sized.creases is not None and sized.creases.any()
    at = sized.vertices[sized.creases]
    r, z = np.hypot(at[:, 0], at[:, 1]), at[:, 2]
    assert np.all(np.abs(z - 1.0) < 0.06), z          # the ledge, within a section or so
    assert np.all(r > 0.85), r                         # its outer edge, not the valley
    control = sizing.interpolating_control(sized.vertices, sized.triangles, sized.creases)
    limit = limit_positions(control, sized.triangles)
    np.testing.assert_allclose(limit[sized.creases], at, rtol=0, atol=1e-9)
    sizing_flag = interpolation.INTERPOLATE_CREASES
    try:
        interpolation.INTERPOLATE_CREASES = False
        assert sized_surface(points, axis="z").sized.creases is None
    finally:
        interpolation.INTERPOLATE_CREASES = sizing_flag


def test_mesh_creases_of_a_stitched_mesh_take_the_band_from_its_rings():
    # What the smooth stage interpolates without the sizing: the band runs from the
    # second ring to the last but one, half a spacing beyond (sizing.crease_band), so
    # the ledge's ridge is in and the rims at the ends are out.
    v, t, profile, n = _stepped()
    rings = [v[i * n:(i + 1) * n] for i in range(len(profile))]
    heights = np.array([z for _, z in profile])
    lo, hi = sizing.crease_band(heights)
    assert lo == 0.125 - 0.0625 and hi == 1.875 + 0.0625    # spacing 0.125: the median gap
    mask = interpolation.mesh_creases(v, t, rings, (0.0, 0.0, 1.0))
    r, z = np.hypot(v[:, 0], v[:, 1]), v[:, 2]
    assert np.array_equal(mask, (np.abs(r - 1.0) < 1e-9) & (np.abs(z - 1.0) < 1e-9))
    assert sizing.crease_band(heights[:3]) == (np.inf, -np.inf)
