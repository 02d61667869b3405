"""Tests of surface.stitch on analytic rings (vase r(z) = 1 + 0.3 sin 2z)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.integrate import quad
from scipy.spatial import Delaunay

from surface import metrics as M
from surface.stitch import cap_triangles, delaunay_flips, stitch_rings, zip_rings
from testkit.vase import SIGMA, noisy_cloud, radius, vase_truth

Z_AXIS = np.array([0.0, 0.0, 1.0])


def vase_rings(sections, n, double=True, a=1.0, b=1.0, twist=0.0, centre=(0.0, 0.0)):
    """Rings at equal theta: N points on sections 0, 2, ..., 2N on 1, 3, ... (or N on all)."""
    rings = []
    for k, z in enumerate(np.linspace(0.0, 3.0, sections)):
        n_k = 2 * n if double and k % 2 else n
        theta = 2 * np.pi * np.arange(n_k) / n_k + twist * k
        r = radius(z)
        rings.append(np.stack([centre[0] + a * r * np.cos(theta), centre[1] + b * r * np.sin(theta),
                               np.full(n_k, z)], axis=1))
    return rings


VASE_VOLUME = quad(lambda z: np.pi * radius(z) ** 2, 0.0, 3.0)[0]


def volume_bound(sections, n):
    """|V_mesh - V| bound for the inscribed vase mesh.

    Polygon deficit: an inscribed regular n-gon has area pi r^2 sin(2pi/n)/(2pi/n),
    relative deficit <= (2pi/n)^2/6.  Between sections the radius is interpolated
    linearly: |r - r_lin| <= h^2/8 max|r''| (max|r''| = 1.2), so
    |int r^2 - int r_lin^2| <= L h^2/8 * 1.2 * 2 max r (max r = 1.3).
    """
    h = 3.0 / (sections - 1)
    return VASE_VOLUME * (2 * np.pi / n) ** 2 / 6 + np.pi * 3.0 * h**2 / 8 * 1.2 * 2 * 1.3


def assert_closed_oriented(result, components=1):
    topo = M.mesh_topology(result.vertices, result.triangles)
    table = M.edge_table(result.triangles)
    assert np.all(table.counts == 2), "every edge must have exactly 2 faces"
    assert topo["oriented"] and result.closed
    assert topo["components"] == components
    assert topo["euler"] == 2 * components
    assert topo["degenerate_faces"] == 0
    return topo


# ----------------------------------------------------------------------------- direction criterion
def test_zip_rings_reproduces_the_papers_triangles_n_to_2n():
    n = 6
    lower = np.arange(n) / n                # o_k at theta = 2 pi k / N
    upper = np.arange(2 * n) / (2 * n)      # e_j at theta = pi j / N
    tri = zip_rings(lower, upper)
    o = lambda k: k % n
    e = lambda j: n + j % (2 * n)
    paper = set()
    for k in range(n):
        paper |= {frozenset((o(k), e(2 * k), e(2 * k + 1))),
                  frozenset((o(k), e(2 * k + 1), o(k + 1))),
                  frozenset((o(k + 1), e(2 * k + 1), e(2 * k + 2)))}
    assert {frozenset(t) for t in tri.tolist()} == paper
    assert len(tri) == 3 * n


def test_zip_rings_equal_counts_and_offset_start():
    n = 8
    tri = zip_rings(np.arange(n) / n, np.arange(n) / n)
    assert len(tri) == 2 * n
    # Each quad (a_i, a_i+1, b_i+1, b_i) split into two triangles.
    assert {frozenset(t) for t in tri.tolist()} == (
        {frozenset((i, (i + 1) % n, n + i)) for i in range(n)}
        | {frozenset(((i + 1) % n, n + (i + 1) % n, n + i)) for i in range(n)})
    # The upper ring listed from another start gives the same faces (mapped).
    shift = 3
    rolled = zip_rings(np.arange(n) / n, np.roll(np.arange(n) / n, -shift))
    back = np.where(rolled >= n, n + (rolled - n + shift) % n, rolled)
    assert {frozenset(t) for t in back.tolist()} == {frozenset(t) for t in tri.tolist()}


# ----------------------------------------------------------------------------- the vase
@pytest.mark.parametrize("double", [True, False], ids=["N-2N", "N-N"])
def test_vase_closed_oriented_volume(double):
    sections, n = 21, 32
    result = stitch_rings(vase_rings(sections, n, double), Z_AXIS)
    topo = assert_closed_oriented(result)
    assert result.messages == ()
    volume = topo["signed_volume"]
    assert volume > 0
    assert abs(volume - VASE_VOLUME) <= volume_bound(sections, n)
    assert result.delaunay_fraction == 1.0
    counts = [n * (2 if double and k % 2 else 1) for k in range(sections)]
    side = sum(counts[k] + counts[k + 1] for k in range(sections - 1))
    assert len(result.triangles) == side + counts[0] - 2 + counts[-1] - 2


def test_volume_error_is_second_order():
    # Doubling N and the number of intervals divides the error by about 4.
    coarse = stitch_rings(vase_rings(11, 16), Z_AXIS)
    fine = stitch_rings(vase_rings(21, 32), Z_AXIS)
    e1 = abs(M.signed_volume(coarse.vertices, coarse.triangles) - VASE_VOLUME)
    e2 = abs(M.signed_volume(fine.vertices, fine.triangles) - VASE_VOLUME)
    assert 0.15 < e2 / e1 < 0.35


def test_flips_reach_delaunay_on_twisted_elliptic_rings():
    # Elliptic rings twisted by 0.15 rad per section: the merge makes skewed
    # strips and earcut makes fan-like caps; Lawson flips must fix both.
    rings = vase_rings(15, 24, a=1.5, b=0.8, twist=0.15)
    raw = stitch_rings(rings, Z_AXIS, flip=False)
    result = stitch_rings(rings, Z_AXIS)
    assert raw.delaunay_fraction < 1.0
    assert result.flips > 0
    assert result.delaunay_fraction == 1.0
    assert_closed_oriented(result)
    # Flips move no vertex and keep the enclosed volume close (same rings).
    v_raw = M.signed_volume(raw.vertices, raw.triangles)
    v_new = M.signed_volume(result.vertices, result.triangles)
    assert abs(v_new - v_raw) < 0.01 * v_raw


def test_unconstrained_contours_make_the_whole_side_delaunay():
    # Many close sections with few points: contour chords are long and not
    # Delaunay; letting flips cross the sections fixes every side edge.
    rings = vase_rings(61, 12)
    fixed = stitch_rings(rings, Z_AXIS)
    free = stitch_rings(rings, Z_AXIS, constrain_contours=False)
    assert M.delaunay_fraction(fixed.vertices, fixed.triangles) < 1.0
    assert M.delaunay_fraction(free.vertices, free.triangles) == 1.0
    assert_closed_oriented(free)


def test_cap_is_constrained_delaunay_of_a_convex_contour():
    # Points on an ellipse are in convex position and (generically) not co-circular:
    # the Delaunay triangulation is unique and earcut + flips must find it.
    rng = np.random.default_rng(5)
    theta = np.sort(rng.uniform(0, 2 * np.pi, 30))
    flat = np.stack([2.0 * np.cos(theta), 0.7 * np.sin(theta)], axis=1)
    cap = cap_triangles(flat, outward_up=True)
    v = np.column_stack([flat, np.zeros(len(flat))])
    tri, flips, converged = delaunay_flips(v, cap)
    assert converged and flips > 0
    want = {frozenset(t) for t in Delaunay(flat).simplices.tolist()}
    assert {frozenset(t) for t in tri.tolist()} == want
    # Counter-clockwise in the plane: normals +z.
    assert np.all(M.face_normals(v, tri)[:, 2] > 0)


def test_order_and_winding_do_not_matter():
    rings = vase_rings(9, 16)
    reference = M.signed_volume(*_mesh(stitch_rings(rings, Z_AXIS)))
    # Sections top to bottom, rings clockwise, axis pointing down: same solid.
    reversed_rings = [r[::-1] for r in rings[::-1]]
    for axis in (Z_AXIS, -Z_AXIS):
        result = stitch_rings(reversed_rings, axis)
        assert_closed_oriented(result)
        assert M.signed_volume(*_mesh(result)) == pytest.approx(reference, rel=1e-9)


def test_rotated_rings_stitch_the_same_way():
    rings = vase_rings(7, 12)
    base = stitch_rings(rings, Z_AXIS)
    angle = 0.7
    c, s = np.cos(angle), np.sin(angle)
    rot = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    turned = stitch_rings([r @ rot.T for r in rings], Z_AXIS)
    assert np.array_equal(np.sort(np.sort(base.triangles, 1), 0),
                          np.sort(np.sort(turned.triangles, 1), 0))


def _mesh(result):
    return result.vertices, result.triangles


# ----------------------------------------------------------------------------- several loops
def test_two_loops_per_section_give_two_closed_solids():
    left = vase_rings(9, 16, centre=(-3.0, 0.0))
    right = vase_rings(9, 16, centre=(3.0, 0.5))
    result = stitch_rings([[lft, rgt] for lft, rgt in zip(left, right, strict=True)], Z_AXIS)
    topo = assert_closed_oriented(result, components=2)
    one = M.signed_volume(*_mesh(stitch_rings(left, Z_AXIS)))
    assert topo["signed_volume"] == pytest.approx(2 * one, rel=1e-9)
    # Listing the loops in another order in one section changes nothing.
    swapped = [[lft, rgt] if k != 4 else [rgt, lft]
               for k, (lft, rgt) in enumerate(zip(left, right, strict=True))]
    assert_closed_oriented(stitch_rings(swapped, Z_AXIS), components=2)


def test_split_is_tiled_into_one_closed_surface():
    # One loop on sections 0-3, two loops on 4-7 (a trunk splitting into two branches):
    # the trunk's last ring is cut along a bridge into one sub-ring per branch, so the
    # surface is one closed, oriented, edge-manifold sphere (Euler characteristic 2).
    trunk = vase_rings(8, 16, a=2.5)
    left = vase_rings(8, 16, centre=(-1.2, 0.0))
    right = vase_rings(8, 16, centre=(1.2, 0.0))
    rings = trunk[:4] + [[left[k], right[k]] for k in range(4, 8)]
    result = stitch_rings(rings, Z_AXIS)
    topo = assert_closed_oriented(result, components=1)
    assert topo["euler"] == 2
    assert result.open_interfaces == ()
    splits = [e for e in result.graph.events if e.kind == "split"]
    assert [(e.section, e.lower, e.upper) for e in splits] == [(3, (0,), (0, 1))]
    # The bridge is a chord across the trunk ring: the saddle's new points lie between
    # sections 3 and 4 (lowered towards the branches by at most half the gap), between
    # the branches (|x| below the trunk's radius).
    new = result.vertices[sum(len(r) if isinstance(r, np.ndarray) else sum(map(len, r))
                              for r in rings):]
    z3, z4 = trunk[3][0, 2], left[4][0, 2]
    assert len(new) > 0
    assert np.all((new[:, 2] > z3) & (new[:, 2] <= z3 + 0.5 * (z4 - z3) + 1e-12))
    assert np.all(np.hypot(new[:, 0], new[:, 1]) < 2.5 * (1 + 0.3))


# ----------------------------------------------------------------------------- bad input
@pytest.mark.parametrize("rings, axis, match", [
    ([np.zeros((5, 3))], Z_AXIS, "at least 2 sections"),
    ([np.eye(3)[:2], np.eye(3)], Z_AXIS, r"rings\[0\]\[0\] has 2 points"),
    ([np.full((4, 3), np.nan), np.ones((4, 3))], Z_AXIS, "NaN"),
    (None, [0.0, 0.0, 0.0], "non-zero length"),
    (None, Z_AXIS, "ordered along the axis"),
])
def test_bad_input_is_named(rings, axis, match):
    if rings is None:
        rings = vase_rings(4, 8)
        if np.linalg.norm(axis) > 0:
            rings = [rings[1], rings[0], rings[2], rings[3]]
    with pytest.raises(ValueError, match=match):
        stitch_rings(rings, axis)


# ----------------------------------------------------------------------------- properties
@settings(max_examples=40, deadline=None)
@given(counts=st.lists(st.integers(3, 40), min_size=2, max_size=7),
       seed=st.integers(0, 2**31 - 1))
def test_any_ring_counts_close_the_surface(counts, seed):
    rng = np.random.default_rng(seed)
    rings = []
    for k, n_k in enumerate(counts):
        # Jittered angles, random start: every angular gap < 2 pi 1.4 / 3 < pi, so the
        # ring is star-shaped about the axis (a simple polygon, as real sections are).
        theta = 2 * np.pi * (np.arange(n_k) + rng.uniform(0, 0.4, n_k)) / n_k + rng.uniform(0, 6)
        r = radius(0.4 * k) * (1 + 0.1 * rng.uniform(-1, 1, len(theta)))
        rings.append(np.stack([r * np.cos(theta), r * np.sin(theta), np.full(len(theta), 0.4 * k)],
                              axis=1))
    result = stitch_rings(rings, Z_AXIS)
    topo = assert_closed_oriented(result)
    assert topo["signed_volume"] > 0
    sizes = [len(r) for r in rings]
    assert len(result.triangles) == (sum(sizes[k] + sizes[k + 1] for k in range(len(sizes) - 1))
                                     + sizes[0] - 2 + sizes[-1] - 2)
    # The flips stopped at a fixed point: no legal flip is left (none in a strip joins
    # two points of one section, none turns a cap's face over along the axis).
    _, more, converged = delaunay_flips(result.vertices, result.triangles, result.region,
                                        _contours(result), plane=result.section_of_vertex,
                                        axis=Z_AXIS)
    assert converged and more == 0


def _contours(result):
    edges = []
    for s in np.unique(result.section_of_vertex):
        idx = np.flatnonzero(result.section_of_vertex == s)
        edges.append(np.stack([idx, np.roll(idx, -1)], axis=1))
    return np.vstack(edges)


# ----------------------------------------------------------------------------- from points
@pytest.fixture(scope="module")
def vase_cloud():
    v, f = vase_truth()
    return v, f, noisy_cloud(v, f, 6000, seed=11)


def test_surface_from_points_vase(vase_cloud):
    from surface.reconstruct import surface_from_points

    v, f, points = vase_cloud
    result = surface_from_points(points)
    assert_closed_oriented(result)
    # The caps were moved from the end planes to the cap points.
    assert sum("cap moved" in m for m in result.messages) == 2
    scores = M.compare_meshes(result.vertices, result.triangles, v, f, tau=0.005, count=20000)
    # The raw points lie sqrt(2/pi) sigma = 0.8 sigma from the truth on average; the
    # surface, which averages many points per control point, must be closer.
    assert scores["chamfer"] < 0.8 * SIGMA
    # Without the end extension the caps sit half a section spacing inside the truth.
    plain = surface_from_points(points, extend_ends=False, projection="axis")
    assert_closed_oriented(plain)
    worse = M.compare_meshes(plain.vertices, plain.triangles, v, f, tau=0.005, count=20000)
    assert worse["chamfer"] > scores["chamfer"]


def test_surface_from_points_two_solids(vase_cloud):
    from surface.reconstruct import surface_from_points

    _, _, points = vase_cloud
    both = np.vstack([points - [1.8, 0, 0], points + [1.8, 0, 0]])
    result = surface_from_points(both, sections=20)
    topo = assert_closed_oriented(result, components=2)
    one = surface_from_points(points, sections=20)
    assert topo["signed_volume"] == pytest.approx(
        2 * M.signed_volume(one.vertices, one.triangles), rel=0.02)


@pytest.mark.parametrize("points, kwargs, match", [
    (np.zeros((0, 3)), {}, "empty"),
    (np.array([[0, 0, 0], [np.nan, 0, 1.0]]), {}, "NaN"),
    (None, {"axis": [0.0, 0.0, 0.0]}, "non-zero length"),
    (None, {"projection": "sideways"}, "projection"),
    (np.column_stack([np.random.default_rng(0).random((300, 2)), np.zeros(300)]), {},
     "one plane"),
])
def test_surface_from_points_bad_input(vase_cloud, points, kwargs, match):
    from surface.reconstruct import surface_from_points

    points = vase_cloud[2] if points is None else points
    with pytest.raises(ValueError, match=match):
        surface_from_points(points, **kwargs)


def test_flip_guard_refuses_large_normal_changes():
    # A valley along ab: c and d raised 0.3 on either side.  The opposite angles are
    # 108 deg each (sum 216 > 180, not Delaunay); the flip to cd turns the faces'
    # normals by atan(0.3 / 0.5) = 31 deg from the old mean normal (+z).
    v = np.array([[0, 0, 0], [1.0, 0, 0], [0.5, 0.2, 0.3], [0.5, -0.2, 0.3]])
    t = np.array([[0, 1, 2], [1, 0, 3]])
    flipped, flips, _ = delaunay_flips(v, t)
    assert flips == 1 and {frozenset(f) for f in flipped.tolist()} == {
        frozenset((2, 0, 3)), frozenset((3, 1, 2))}
    assert np.all(M.face_normals(v, flipped)[:, 2] > 0)  # still facing +z
    _, flips, _ = delaunay_flips(v, t, max_normal_change=np.radians(25))
    assert flips == 0
    _, flips, _ = delaunay_flips(v, t, max_normal_change=np.radians(35))
    assert flips == 1


def test_surface_from_points_noisy_ends():
    # sigma = 0.012 with 10 000 points: the end planes (half a spacing, 0.035, inside
    # the extremes at about -4 sigma = -0.048) fall inside the noisy end faces.  The
    # mesh must still be one closed solid, closer to the truth than the points
    # (0.8 sigma); the plain axial projection without end handling is not (1.1 sigma).
    from surface.reconstruct import surface_from_points

    v, f = vase_truth()
    sigma = 0.012
    points = noisy_cloud(v, f, 10_000, seed=2, sigma=sigma)
    result = surface_from_points(points)
    assert_closed_oriented(result)
    scores = M.compare_meshes(result.vertices, result.triangles, v, f, tau=0.005, count=20000)
    assert scores["chamfer"] < 0.5 * sigma


def test_surface_from_points_bridges_a_one_section_gap(vase_cloud):
    """Two wedges missing from one section's slab break its ring into two arcs (two
    "loops" between one-loop neighbours): the section is dropped and the surface closed."""
    from surface.reconstruct import slice_cloud, surface_from_points

    v, f, points = vase_cloud
    sliced = slice_cloud(points)
    section = sliced.sections[len(sliced.sections) // 2]
    theta = np.degrees(np.arctan2(points[:, 1], points[:, 0]))
    in_slab = np.abs(points[:, 2] - section.height) < sliced.spacing / 2
    wedge = (np.abs(theta - 40) < 30) | (np.abs(theta + 120) < 30)  # arcs of 60°
    holed = points[~(in_slab & wedge)]
    result = surface_from_points(holed)
    assert any("one-section split" in m for m in result.messages), result.messages
    assert_closed_oriented(result)
    scores = M.compare_meshes(result.vertices, result.triangles, v, f, tau=0.005, count=20000)
    assert scores["chamfer"] < 0.8 * SIGMA  # as the whole cloud (test_surface_from_points_vase)


def test_surface_from_points_open_ends_reach_the_end_of_the_walls():
    """Walls only (a ring of cameras sees no cap) and a few stray points beyond the ends:
    the end planes are placed on the dense part of the cloud, and each end ring is moved
    to where the wall points stop (2 x the median offset of the outer half-slab points)."""
    from surface.reconstruct import surface_from_points
    from surface.sections import slice_sections

    v, f = vase_truth()
    walls = f[:-2 * 256]  # vase_truth's two cap fans (n_theta = 256 faces each) are last
    rng = np.random.default_rng(5)
    points = M.sample_mesh(v, walls, count=6000, seed=5) + rng.normal(0.0, SIGMA, (6000, 3))
    stray = np.column_stack([rng.normal(0.0, 0.5, (8, 2)),
                             np.r_[rng.uniform(-0.1, -0.01, 4), rng.uniform(3.01, 3.1, 4)]])
    points = np.vstack([points, stray])
    delta = abs(np.diff([s.height for s in slice_sections(points)[:2]])[0])
    result = surface_from_points(points)
    assert_closed_oriented(result)
    assert sum("end extended" in m for m in result.messages) == 2, result.messages
    # The end estimate from ~100 points spread over delta/2 has a spread of about
    # (delta/2)/sqrt(100) = delta/20; the planes alone stop delta/2 inside the walls.
    z = result.vertices[:, 2]
    assert abs(z.min() - 0.0) < delta / 4 and abs(z.max() - 3.0) < delta / 4
    scores = M.compare_meshes(result.vertices, result.triangles, v, f, tau=0.005, count=20000)
    plain = surface_from_points(points, projection="axis", extend_ends=False)
    worse = M.compare_meshes(plain.vertices, plain.triangles, v, f, tau=0.005, count=20000)
    assert scores["chamfer"] < 0.5 * worse["chamfer"]


def test_one_sided_cloud_is_refused_not_closed_into_a_wrong_solid():
    """Half the vase (what one stereo pair sees): every section is an open arc."""
    from surface.reconstruct import surface_from_points

    v, f = vase_truth()
    points = noisy_cloud(v, f, 8000, seed=3)
    half = points[points[:, 0] > 0.2]  # a 130-degree-or-so arc of every section
    with pytest.raises(ValueError, match="open arcs"):
        surface_from_points(half, axis="z")
    # the whole cloud, from the same generator, is accepted and closed
    assert surface_from_points(points, axis="z").closed


def _wall_end(rng, wall, line, end, blur):
    """Offsets beyond an end plane: ``wall`` points spread evenly up to ``end`` and
    ``line`` points on the rim line at ``end``, each blurred by ``blur``."""
    offsets = np.r_[rng.uniform(0.0, end, wall), np.full(line, end)]
    offsets = offsets + rng.normal(0.0, blur, len(offsets))
    return offsets[offsets > 0]


def test_rim_line_finds_the_bunch_at_a_rim_seen_edge_on():
    """A rim seen edge-on by a ring of cameras: the points beyond the end plane bunch at
    the rim.  The quantile rule lands on the bunch's outer flank (about +1.5 sigma at
    these counts); the rim line is found within 0.75 sigma (the wall's shoulder, taken
    out to first order, leaves an inward bias of ~0.2 sigma at 150 line to 250 wall
    points; simulated: mean -0.00011, largest 0.00043 at sigma 0.0006)."""
    from surface.reconstruct import rim_line

    rng = np.random.default_rng(11)
    blur, end = 0.0006, 0.0056
    errors, quantile_errors = [], []
    for _ in range(40):
        offsets = _wall_end(rng, 250, 150, end, blur)
        q = np.quantile(offsets, 0.95) / 0.95
        found = rim_line(offsets, np.full(len(offsets), blur), q)
        assert found is not None
        errors.append(found - end)
        quantile_errors.append(q - end)
    errors = np.array(errors)
    assert np.abs(errors).max() < 0.75 * blur, errors
    assert np.mean(quantile_errors) > 2.0 * np.abs(errors.mean())


def test_rim_line_leaves_a_plain_wall_end_alone():
    """No rim line (the wall points just stop, blurred): no bunch stands out at 5
    standard errors, so the quantile rule's end stays (None), at any count."""
    from surface.reconstruct import rim_line

    rng = np.random.default_rng(12)
    found = 0
    for wall, end, blur in ((100, 0.01, 0.001), (350, 0.0056, 0.0006), (2000, 0.01, 0.0005)):
        for _ in range(60):
            offsets = _wall_end(rng, wall, 0, end, blur)
            q = np.quantile(offsets, 0.95) / 0.95
            found += rim_line(offsets, np.full(len(offsets), blur), q) is not None
    assert found == 0
    # Without a finite, positive sigma there is no kernel width: no rim line is claimed.
    offsets = _wall_end(rng, 250, 100, 0.0056, 0.0006)
    assert rim_line(offsets, np.full(len(offsets), np.nan), 0.006) is None


def test_open_ends_with_rim_lines_end_at_the_rims():
    """Walls only plus a rim line at each end (outline points of rims seen edge-on, as
    the demo ring measures them): with the points' sigma the end rings go to the rim
    lines, without it to the quantile rule's end beyond them."""
    from surface.reconstruct import surface_from_points

    v, f = vase_truth()
    walls = f[:-2 * 256]
    rng = np.random.default_rng(7)
    points = M.sample_mesh(v, walls, count=12000, seed=7)
    theta = rng.uniform(0.0, 2.0 * np.pi, 1200)
    rims = np.where(np.arange(1200) < 600, 0.0, 3.0)
    rim_points = np.column_stack([radius(rims) * np.cos(theta), radius(rims) * np.sin(theta),
                                  rims])
    points = np.vstack([points, rim_points]) + rng.normal(0.0, SIGMA, (13200, 3))
    sigma = np.full(len(points), SIGMA)
    with_sigma = surface_from_points(points, sigma=sigma)
    plain = surface_from_points(points)
    assert sum("rim line" in m for m in with_sigma.messages) == 2, with_sigma.messages
    z, z0 = with_sigma.vertices[:, 2], plain.vertices[:, 2]
    assert abs(z.min()) < SIGMA and abs(z.max() - 3.0) < SIGMA
    assert abs(z0.min()) + abs(z0.max() - 3.0) > 2 * (abs(z.min()) + abs(z.max() - 3.0))


@pytest.mark.parametrize("unseen", [45, 90])
def test_a_ring_with_a_side_unseen_is_bridged_and_closed(unseen):
    """The vase with a wedge of ``unseen`` degrees missing from every section (a ring of
    views that left one side unseen): the sections are open arcs over 13 % / 23 % of
    their length, under the refusal's 25 % (``reconstruct.MAX_BRIDGED_SHARE``); the
    surface closes, flat over the wedge (each ring's chord), and where the points are
    it is as close to the truth as the whole cloud's."""
    from surface.reconstruct import (
        bridged_share,
        organise_sections,
        slice_cloud,
        surface_from_points,
    )

    v, f = vase_truth()
    points = noisy_cloud(v, f, 8000, seed=3)
    angle = np.degrees(np.arctan2(points[:, 1], points[:, 0]))
    seen = points[~((angle > 0) & (angle < unseen))]
    _, loops, _ = organise_sections(slice_cloud(seen, axis="z").sections)
    assert 0.05 < bridged_share(loops) < 0.25
    result = surface_from_points(seen, axis="z")
    assert result.closed
    distance = np.abs(M.point_mesh_distance(result.vertices, v, f))
    at = np.degrees(np.arctan2(result.vertices[:, 1], result.vertices[:, 0]))
    over = (at > -5) & (at < unseen + 5)
    whole = surface_from_points(points, axis="z")
    rms = float(np.sqrt(np.mean(M.point_mesh_distance(whole.vertices, v, f) ** 2)))
    assert float(np.sqrt(np.mean(distance[~over] ** 2))) < 1.2 * rms  # measured 1.00x
    # over the wedge, no farther in than the chord's sagitta of the widest ring
    widest = float(np.hypot(v[:, 0], v[:, 1]).max())
    assert distance[over].max() < 1.1 * widest * (1 - np.cos(np.radians(unseen / 2))) + 0.01


def test_stitch_without_diagnostics_is_the_same_mesh():
    """The sizing's candidates skip the Delaunay measure: the same mesh, no fraction."""
    rings = vase_rings(15, 24, a=1.5, b=0.8, twist=0.15)
    full = stitch_rings(rings, Z_AXIS)
    bare = stitch_rings(rings, Z_AXIS, diagnostics=False)
    assert np.array_equal(full.vertices, bare.vertices)
    assert np.array_equal(full.triangles, bare.triangles)
    assert full.delaunay_fraction == 1.0 and np.isnan(bare.delaunay_fraction)
