"""Support (holding) rings of surface.stitch: G1 surfaces that keep sharp rims.

Analytic cylinders (r = 1, flat caps) and a cylinder-cone kink, whose exact
distance functions are known, plus a noisy cylinder cloud end to end.
"""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from surface import bezier
from surface import metrics as M
from surface.reconstruct import surface_from_points
from surface.stitch import SUPPORT_MIN_SHARE, stitch_rings, support_distance

Z_AXIS = np.array([0.0, 0.0, 1.0])
HEIGHT = 2.0


def ring(z: float, n: int, r: float = 1.0) -> np.ndarray:
    t = 2 * np.pi * np.arange(n) / n
    return np.stack([r * np.cos(t), r * np.sin(t), np.full(n, z)], axis=1)


def cylinder_rings(sections: int = 11, n: int = 192) -> list:
    """Rings of the cylinder r = 1, z in [0, HEIGHT]: n points, 2n on every other."""
    return [ring(z, n if k % 2 == 0 else 2 * n)
            for k, z in enumerate(np.linspace(0.0, HEIGHT, sections))]


def cylinder_distance(points: np.ndarray) -> np.ndarray:
    """Exact distance of points to the surface of the solid cylinder r <= 1, 0 <= z <= HEIGHT."""
    rad = np.hypot(points[:, 0], points[:, 1])
    z = points[:, 2]
    inside = (rad <= 1) & (z >= 0) & (z <= HEIGHT)
    d_in = np.minimum.reduce([1 - rad, z, HEIGHT - z])
    d_out = np.hypot(np.maximum(rad - 1, 0), np.maximum.reduce([-z, z - HEIGHT, 0 * z]))
    return np.where(inside, d_in, d_out)


def smooth(result, level: int = 3):
    surface = bezier.control_net(result.vertices, result.triangles)
    v, t, _ = bezier.tessellate(surface, level=level)
    return surface, v, t


# --------------------------------------------------------------------------- the rule
def legs(turn_deg: float, h: float, n: int = 5):
    """Profile legs of length h on either side of a ring turning by turn_deg."""
    a = np.tile([0.0, 0.0, -h], (n, 1))
    phi = np.radians(180.0 - turn_deg)  # angle between the two legs
    b = np.tile([h * np.sin(phi), 0.0, -h * np.cos(phi)], (n, 1))
    return a, b


def test_support_distance_rule():
    h, sigma = 0.2, 0.002
    # 90° rim: d = 3 sigma / sin 45°, so the B-spline corner deviation d sin 45°/3 = sigma
    assert support_distance(*legs(90, h), sigma) == pytest.approx(3 * sigma / np.sin(np.pi / 4))
    # rounding h sin(45°)/3 = 0.047 already within the noise: no support
    assert support_distance(*legs(90, h), 0.05) == 0.0
    # a gentle turn (below 30°) is a smooth profile, not an edge
    assert support_distance(*legs(20, h), sigma) == 0.0
    # noise-free rings: the floor SUPPORT_MIN_SHARE x the ring's point spacing
    assert support_distance(*legs(90, h), 0.0, 0.05) == pytest.approx(SUPPORT_MIN_SHARE * 0.05)
    assert support_distance(*legs(90, h), sigma, 0.05) == pytest.approx(
        3 * sigma / np.sin(np.pi / 4))  # the noise rule wins over the floor 0.005
    # never beyond half the leg (the support stays between the rings)
    assert support_distance(*legs(90, h), 0.04) == pytest.approx(h / 2)


# --------------------------------------------------------------------------- exact rings
@pytest.mark.parametrize("sigma", [0.002, 0.005])
def test_cylinder_rim_is_kept_to_the_noise(sigma):
    """Rings h = 0.2 apart: without supports Loop's surface rounds the 90° rim by about
    h sin(45°)/3 = 0.047 (the cubic B-spline corner bound); with supports at
    d = 3 sigma/sin 45° the rim vertex is regular (valence 6) and its limit point
    (v/2 + sum/12) lies d/6 = sigma/sqrt(2) inside each face; the N = 192 rings add
    Loop's shrinkage (2 pi/N)^2/12 = 9e-5 < 0.29 sigma.  So: distance <= sigma."""
    supported = stitch_rings(cylinder_rings(), Z_AXIS, support_sigma=sigma)
    plain = stitch_rings(cylinder_rings(), Z_AXIS)
    topo = M.mesh_topology(supported.vertices, supported.triangles)
    assert topo["closed"] and topo["oriented"] and topo["components"] == 1
    assert len(supported.vertices) > len(plain.vertices)
    assert sum("support rings" in m for m in supported.notes) == 2  # the two rims only
    surface, v, t = smooth(supported)
    assert cylinder_distance(v).max() <= sigma
    _, v0, _ = smooth(plain)
    assert cylinder_distance(v0).max() >= np.sin(np.pi / 4) * 0.2 / 3  # the test can fail
    gap, angle = bezier.edge_continuity(surface.control_points, surface.domain_mesh[1])
    assert angle <= 1e-9 and gap <= 1e-12 * 2.0
    # the caps inside the supports are planar control meshes: exactly flat
    centre = np.hypot(v[:, 0], v[:, 1]) < 0.9
    cap_z = v[centre, 2]
    assert np.abs(np.minimum(np.abs(cap_z), np.abs(cap_z - HEIGHT))).max() <= 1e-12


def test_supported_stitched_mesh_keeps_its_shape():
    """The supports lie on the stitched polyhedron up to the ring chords' sagitta: the cap
    support is in the cap plane, the wall support on the legs from the rim points, and
    its chords are at most the sagitta 1 - cos(pi/N) off the strip's triangles, so
    |dV| <= 2 rims x perimeter 2 pi x d x (1 - cos(pi/N)) (d = 3 sigma/sin 45°)."""
    sigma, n = 0.002, 192
    supported = stitch_rings(cylinder_rings(n=n), Z_AXIS, support_sigma=sigma)
    plain = stitch_rings(cylinder_rings(n=n), Z_AXIS)
    d = 3 * sigma / np.sin(np.pi / 4)
    bound = 2 * 2 * np.pi * d * (1 - np.cos(np.pi / n))
    assert abs(M.signed_volume(supported.vertices, supported.triangles)
               - M.signed_volume(plain.vertices, plain.triangles)) <= bound


def test_a_kink_between_sections_gets_supports_on_both_sides():
    """Cylinder r = 1 for z <= 1 then a 45° cone (r = 2 - z) to z = 1.5: the ring at z = 1
    turns by 45° over legs h = 0.1 (rounding h sin 22.5°/3 = 0.013 > sigma = 0.002) and
    gets one support ring on each side, at d = 3 sigma/sin 22.5°; no other inner ring
    turns.  The smooth surface then passes within the corner deviation
    d sin(22.5°)/3 = sigma of the kink circle plus Loop's shrinkage of the 96-gon rings
    (limit v/2 + sum/12 of a regular vertex: (1 - cos(2 pi/96))/3 = phi^2/6 radially),
    against >= h sin(22.5°)/3 / 2 without."""
    z = np.round(np.arange(0.0, 1.5001, 0.1), 12)
    rad = np.where(z <= 1.0, 1.0, 2.0 - z)
    rings = [ring(zz, 96, rr) for zz, rr in zip(z, rad, strict=True)]
    sigma = 0.002
    supported = stitch_rings(rings, Z_AXIS, support_sigma=sigma)
    inner = [m for m in supported.notes if "support rings" in m and "section 10 " in m]
    assert len(inner) == 1
    assert len(np.unique(supported.section_of_vertex)) == len(rings) + 2 + 2  # kink + both rims
    _, v, _ = smooth(supported, level=2)
    _, v0, _ = smooth(stitch_rings(rings, Z_AXIS), level=2)

    def kink_distance(points):  # distance from the kink circle (r = 1, z = 1)
        return np.hypot(np.hypot(points[:, 0], points[:, 1]) - 1.0, points[:, 2] - 1.0)

    s = np.sin(np.radians(22.5))
    assert kink_distance(v).min() <= 1.05 * (sigma + (2 * np.pi / 96) ** 2 / 6)
    assert kink_distance(v0).min() >= 0.1 * s / 3 / 2


def test_facing_supports_across_a_ledge_stay_in_order():
    """A ledge (r 1 -> 0.4 between z 0.2 and 0.25) with a one-point spike of the upper ring
    reaching back to r 0.99: both rings of the strip get supports towards each other, and
    at the spike each point's own leg (~0.05) is shorter than twice ``d`` (~0.044, from the
    median leg).  Moved the whole ``d``, the two supports passed each other in height
    (0.243 over 0.207) and the stitched mesh crossed itself at 8 pairs; each point now
    moves at most a third of its own leg when both rings of its strip are supported."""
    from surface.stitch import _support, axis_frame
    from surface.validity import check_solid

    n = 120
    upper = np.full(n, 0.4)
    upper[0], upper[[1, -1]] = 0.99, 0.7
    t = 2 * np.pi * np.arange(n) / n
    ledge = np.stack([upper * np.cos(t), upper * np.sin(t), np.full(n, 0.25)], axis=1)
    sections = [ring(0.0, n), ring(0.2, n), ledge, ring(0.5, n, 0.4)]
    out, _, notes = _support([[s] for s in sections], axis_frame(Z_AXIS), 0.01, True)
    assert len(notes) == 4 and len(out) == 10             # both ends one, both inner two
    z = [rings[0][:, 2] for rings in out]
    for k in range(len(z) - 1):
        assert z[k].max() < z[k + 1].min(), k             # heights in order ring by ring
    result = stitch_rings(sections, Z_AXIS, support_sigma=0.01)
    report = check_solid(result.vertices, result.triangles)
    assert report.valid and report.genus == 0


def test_smooth_profiles_get_no_supports():
    """A vase-like profile sampled finely turns by a few degrees per ring: nothing added
    (open ends: no rims)."""
    z = np.linspace(0.0, 3.0, 31)
    rings = [ring(zz, 64, 1.0 + 0.3 * np.sin(2 * zz)) for zz in z]
    supported = stitch_rings(rings, Z_AXIS, close_ends=False, support_sigma=0.0)
    plain = stitch_rings(rings, Z_AXIS, close_ends=False)
    assert len(supported.vertices) == len(plain.vertices)
    np.testing.assert_array_equal(supported.triangles, plain.triangles)


def test_support_sigma_is_checked():
    with pytest.raises(ValueError, match="support_sigma"):
        stitch_rings(cylinder_rings(), Z_AXIS, support_sigma=-1.0)
    with pytest.raises(ValueError, match="support_sigma"):
        stitch_rings(cylinder_rings(), Z_AXIS, support_sigma=float("nan"))


# --------------------------------------------------------------------------- noisy cloud
def test_noisy_cylinder_cloud_keeps_its_rims():
    """Cylinder cloud, sigma = 0.002 (the section-point noise the loops estimate).  At the
    rim band (truth points within one section spacing of a rim, on either face) the
    smooth surface built with supports is on average within sigma of the truth; without
    them Loop's surface rounds the rim by about Delta sin 45°/3 (Delta the section
    spacing) and the band's mean distance is several times larger."""
    from surface.reconstruct import slice_cloud
    from testkit.vase import noisy_cloud

    truth_rings = [ring(z, 256) for z in np.linspace(0.0, HEIGHT, 65)]
    truth = stitch_rings(truth_rings, Z_AXIS, flip=False)
    sigma = 0.002
    cloud = noisy_cloud(truth.vertices, truth.triangles, 20_000, seed=3, sigma=sigma)
    samples = M.sample_mesh(truth.vertices, truth.triangles, count=20_000, seed=4)
    rad = np.hypot(samples[:, 0], samples[:, 1])
    means = {}
    delta = slice_cloud(cloud, axis="z").spacing
    for support in (True, False):
        result = surface_from_points(cloud, axis="z", support=support)
        topo = M.mesh_topology(result.vertices, result.triangles)
        assert topo["closed"] and topo["components"] == 1
        band = (np.minimum(samples[:, 2], HEIGHT - samples[:, 2]) < delta) & (rad > 1 - delta)
        _, v, t = smooth(result, level=2)
        means[support] = float(M.point_mesh_distance(samples[band], v, t).mean())
    print(f"rim band mean distance: {means[True]:.5f} with supports, {means[False]:.5f} without")
    assert means[True] <= sigma
    assert means[False] >= 2 * means[True]


@settings(max_examples=15, deadline=None)
@given(counts=st.lists(st.integers(6, 40), min_size=2, max_size=6),
       radii=st.lists(st.floats(0.3, 1.5), min_size=6, max_size=6),
       sigma=st.floats(0.0, 0.05))
def test_supports_keep_any_ring_stack_closed_and_oriented(counts, radii, sigma):
    """Whatever the ring counts, radii (sharp profile turns included) and sigma, the
    supported mesh is closed, oriented, one component, with positive volume."""
    z = np.arange(len(counts)) * 0.3
    rings = [ring(zz, n, radii[k]) for k, (zz, n) in enumerate(zip(z, counts, strict=True))]
    result = stitch_rings(rings, Z_AXIS, support_sigma=sigma)
    topo = M.mesh_topology(result.vertices, result.triangles)
    assert topo["closed"] and topo["oriented"] and topo["components"] == 1
    assert M.signed_volume(result.vertices, result.triangles) > 0


def test_quality_cap_refuses_a_self_intersecting_contour():
    from surface.stitch import _quality_cap

    t = np.linspace(0, 2 * np.pi, 40, endpoint=False)
    added, tri = _quality_cap(np.stack([np.cos(t), np.sin(t)], 1), outward_up=True)
    # a convex 40-gon: Euler for a disc, V - E + F = 1, all triangles counter-clockwise
    assert len(tri) == 40 + 2 * len(added) - 2
    crossing = t + np.pi / 40   # a figure eight, no point on its crossing
    with pytest.raises(ValueError, match="not simple"):
        _quality_cap(np.stack([np.sin(2 * crossing), np.sin(crossing)], 1), outward_up=True)
    with pytest.raises(ValueError, match="not all corners"):   # a point repeated
        _quality_cap(np.stack([np.sin(2 * t), np.sin(t)], 1), outward_up=True)


def test_quality_cap_does_not_read_the_last_bits():
    """An evenly sampled circle is cocircular: Triangle's quality refinement chose its
    Steiner points by in-circle tests that the last bits decided.  The contour is snapped
    to 2^-26 of its size (``stitch.SNAP_BITS``), so perturbations of 1e-13 give the same
    triangulation."""
    from surface.stitch import _quality_cap

    t = np.linspace(0, 2 * np.pi, 96, endpoint=False)
    ring = np.stack([0.7 * np.cos(t) + 3.0, 0.7 * np.sin(t) - 1.0], 1)
    area = 0.5 * (2 * np.pi * 0.7 / 96) ** 2
    added, tri = _quality_cap(ring, outward_up=True, max_area=area)
    assert len(added) > 50
    rng = np.random.default_rng(0)
    for _ in range(6):
        moved = ring * (1 + 1e-13 * rng.standard_normal(ring.shape))
        again, tri_again = _quality_cap(moved, outward_up=True, max_area=area)
        assert np.array_equal(tri_again, tri)
        assert np.abs(again - added).max() < 1e-9


@pytest.mark.parametrize("seed", [0, 1])
def test_open_cylinder_ends_where_the_wall_points_end(seed):
    """No cap points (the cameras never saw the ends): each end is put where the wall
    points run out, the 95th percentile of their offsets past the last section / 0.95.
    Wall points spread evenly over z in [0, 2], noise σ = 0.002 in every direction: the
    ends land within 2σ of z = 0 and z = 2 (measured 5e-4 and 8e-4)."""
    rng = np.random.default_rng(seed)
    z = rng.uniform(0.0, 2.0, 40000)
    t = rng.uniform(0.0, 2 * np.pi, len(z))
    pts = np.column_stack([np.cos(t), np.sin(t), z]) + rng.normal(0.0, 0.002, (len(z), 3))
    result = surface_from_points(pts, axis="z")
    notes = [m for m in result.messages if "no cap points" in m]
    assert len(notes) == 2, result.messages
    assert abs(result.vertices[:, 2].max() - 2.0) < 0.004
    assert abs(result.vertices[:, 2].min()) < 0.004


@pytest.mark.parametrize("seed", [0, 1])
def test_open_cylinder_ends_where_thinning_wall_points_end(seed):
    """Wall points that thin towards the ends (as a ring of cameras measures a rim it
    sees edge-on: windows there are moved or rejected): density falling linearly to
    15 % over the last 0.08 of z in [0, 2], σ = 0.002.  The thin tail is cut from the
    slicing (sparse tail), so the end planes sit ~1.5 spacings inside the ends; the end
    placement must still see those points (before: ends 0.016 inside, measured; now
    within 0.003 over three seeds)."""
    rng = np.random.default_rng(seed)
    z = rng.uniform(0.0, 2.0, 120_000)
    keep = rng.uniform(0.0, 1.0, len(z)) < np.clip(0.15 + 0.85 * np.minimum(z, 2.0 - z) / 0.08,
                                                   0.0, 1.0)
    z = z[keep][:40_000]
    t = rng.uniform(0.0, 2 * np.pi, len(z))
    pts = np.column_stack([np.cos(t), np.sin(t), z]) + rng.normal(0.0, 0.002, (len(z), 3))
    result = surface_from_points(pts, axis="z")
    assert sum("no cap points" in m for m in result.messages) == 2, result.messages
    assert abs(result.vertices[:, 2].min()) < 0.006          # 3 σ; before 0.016
    assert abs(result.vertices[:, 2].max() - 2.0) < 0.006


@pytest.mark.parametrize("sigma", [0.002, 0.05])
def test_flat_cap_of_a_coarse_control_mesh_stays_in_its_plane(sigma):
    """Coarse rings (24 / 48 points, sections h = 0.2 apart: a sized control mesh) under the
    interpolating surface the smooth stage builds.  sigma = 0.002: support rings at d (0.026
    here) and the guard ring at 2 d; sigma = 0.05: the rim's rounding h sin(45°)/3 = 0.047
    is within the noise, no support, and the cap gets rings one wall leg (0.2) apart.
    Loop's patch reads two rings of the control mesh about its triangle, so every patch
    inside the guard ring reads only cap-plane vertices: the surface there is the plane
    to rounding (affine invariance).  The ear-clipped cap of the same rings (no
    ``support_sigma``) has no inner vertex, and its patches bend by > 0.01 across it."""
    from surface.sizing import interpolating_control

    def cap_heights(result, inside):
        surface = bezier.control_net(interpolating_control(result.vertices, result.triangles),
                                     result.triangles)
        v, _, _ = bezier.tessellate(surface, level=3)
        centre = np.hypot(v[:, 0], v[:, 1]) < inside
        assert centre.sum() > 100
        return np.minimum(np.abs(v[centre, 2]), np.abs(v[centre, 2] - HEIGHT))

    rings = cylinder_rings(n=24)
    inside = 0.9 if sigma < 0.01 else 1.0 - 2 * 0.2 - 1e-6
    assert cap_heights(stitch_rings(rings, Z_AXIS, support_sigma=sigma), inside).max() <= 1e-12
    assert cap_heights(stitch_rings(rings, Z_AXIS), inside).max() > 0.01  # the test can fail
