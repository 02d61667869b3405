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


def _resampled(path: np.ndarray, step: float) -> np.ndarray:
    closed = np.vstack([path, path[:1]])
    along = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(closed, axis=0), axis=1))])
    t = np.arange(0.0, along[-1], step)
    return np.column_stack([np.interp(t, along, closed[:, 0]), np.interp(t, along, closed[:, 1])])


def _arc(radius: float, start: float, stop: float, centre=(0.0, 0.0)) -> np.ndarray:
    a = np.linspace(start, stop, 400)
    return np.column_stack([centre[0] + radius * np.cos(a), centre[1] + radius * np.sin(a)])


def _keyhole(width: float = 0.07, step: float = 0.05) -> np.ndarray:
    """Round a unit circle, in through a channel ``width`` wide (1.4 point spacings), round
    a circle of radius 0.4 inside it and back out: a teapot's body and lid as one loop."""
    out, inn, top = np.arcsin(width / 2), np.arcsin(width / 0.8), np.pi / 2
    return _resampled(np.vstack([_arc(1.0, top + out, top - out + 2 * np.pi),
                                 _arc(0.4, top - inn, top + inn - 2 * np.pi)]), step)


def _lobes(step: float = 0.05) -> np.ndarray:
    """Two disks of radius 0.5 side by side, joined at a waist 0.07 wide."""
    return _resampled(np.vstack([_arc(0.5, np.pi + 0.07, 3 * np.pi - 0.07, (0.5, 0.0)),
                                 _arc(0.5, 0.07, 2 * np.pi - 0.07, (-0.5, 0.0))]), step)


def _finger(step: float = 0.05) -> np.ndarray:
    """A unit disk with a finger 0.07 wide and 0.8 long."""
    d = np.arcsin(0.035)
    return _resampled(np.vstack([_arc(1.0, d, 2 * np.pi - d), [[1.8, -0.035], [1.8, 0.035]]]),
                      step)


def _c_shape(step: float = 0.05) -> np.ndarray:
    """A thick C (radii 1 and 0.5) with a mouth 0.6 wide."""
    return _resampled(np.vstack([_arc(1.0, 0.6, 2 * np.pi - 0.6),
                                 _arc(0.5, 2 * np.pi - 1.2, 1.2)]), step)


def test_keyhole_is_two_nested_contours_through_a_neck():
    """Only the keyhole is nested at its neck; lobes at a waist and a thin finger have
    necks as narrow (1.4 spacings) but side by side, and a C's mouth is 12 spacings."""
    from surface.reconstruct import keyhole, self_intersects

    assert keyhole(_keyhole()) and not self_intersects(_keyhole())
    assert keyhole(_keyhole()[::-1]) and keyhole(np.roll(_keyhole(), 57, axis=0))
    for ring in (_lobes(), _finger(), _c_shape()):
        assert not keyhole(ring)
    assert not keyhole(_keyhole(width=0.15))   # a channel 3 spacings wide is resolved


def _sections(step: float = 0.05):
    body = [_circle(1.0, z, 126) for z in np.arange(0.0, 0.61, 0.1)]
    lid = [_circle(0.4, z, 50) for z in (0.8, 0.9, 1.0)]
    ring = _keyhole(step=step)
    return body, np.column_stack([ring, np.full(len(ring), 0.7)]), lid


def test_a_keyhole_section_is_skipped_and_the_stitch_is_valid():
    """A body (unit circles) under a lid (radius 0.4), the section between them a
    keyhole: stitched as it is, the strips on both sides of it fold out across the
    annulus between its contours and back (area 12.56 against 10.70 without the
    section; before the flips were kept off a section's chords the folds crossed, 35
    pairs); ``untangle`` skips it, with a note, and the body's top ring is stitched to
    the lid's: a valid solid, with and without the support rings."""
    from types import SimpleNamespace

    from surface.reconstruct import untangle
    from surface.stitch import axis_frame

    body, key, lid = _sections()
    rings = body + [key] + lid
    def area(result):
        v, t = result.vertices, result.triangles
        return 0.5 * np.linalg.norm(np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]]),
                                    axis=1).sum()
    folded = area(stitch_rings(rings, AXIS))
    kept = [SimpleNamespace(section_id=k, height=float(r[0, 2]), frame=axis_frame(AXIS))
            for k, r in enumerate(rings)]
    kept, loops, rings, notes = untangle(kept, [[None]] * len(rings), rings)
    assert [k.section_id for k in kept] == [0, 1, 2, 3, 4, 5, 6, 8, 9, 10]
    assert len(notes) == 1 and "section 7 " in notes[0] and "neck" in notes[0]
    for support in (None, 0.002):
        result = stitch_rings(rings, AXIS, support_sigma=support)
        report = check_solid(result.vertices, result.triangles)
        assert result.closed and report.valid and report.genus == 0, report.problems()
    assert folded > area(stitch_rings(rings, AXIS)) + 1.5


def test_a_thin_finger_between_two_strips_is_not_tiled_flat_twice():
    """Plain unit circles below and above a section with a finger 0.07 wide (1.4 ring
    spacings) and 0.8 long.  The Lawson flips on both strips used to take chords across
    the finger (faces with three corners in its section's plane), which overlap each
    other flat: 112 crossing pairs.  No flip in a strip now joins two points of one
    section: a valid solid, its flips still Delaunay where they may be (95 % of the
    flippable edges)."""
    d = np.arcsin(0.035)
    finger = _resampled(np.vstack([_arc(1.0, d, 2 * np.pi - d),
                                   [[1.8, -0.035], [1.8, 0.035]]]), 0.05)
    rings = ([_circle(1.0, z, 126) for z in (0.0, 0.1)]
             + [np.column_stack([finger, np.full(len(finger), 0.2)])]
             + [_circle(1.0, z, 126) for z in (0.3, 0.4)])
    for support in (None, 0.002):
        result = stitch_rings(rings, AXIS, support_sigma=support)
        report = check_solid(result.vertices, result.triangles)
        assert result.closed and report.valid, report.problems()
        strips = result.triangles[result.region >= 0]
        sections = result.section_of_vertex[strips]
        assert not np.any((sections[:, 0] == sections[:, 1]) & (sections[:, 1] == sections[:, 2]))
        assert result.flips > 0 and result.delaunay_fraction > 0.95


def _dumbbell(waist: float, big: float = 0.6, small: float = 0.3, step: float = 0.05):
    """Disks of radius ``big`` and ``small`` side by side, joined at a waist."""
    a, b = np.arcsin(waist / 2 / big), np.arcsin(waist / 2 / small)
    return _resampled(np.vstack([_arc(big, np.pi + a, 3 * np.pi - a, (big * np.cos(a), 0.0)),
                                 _arc(small, b, 2 * np.pi - b, (-small * np.cos(b), 0.0))]),
                      step)


def test_a_capped_end_of_a_dumbbell_contour_does_not_fold():
    """A prism over a dumbbell (disks of radius 0.6 and 0.3, waist 0.05 or 0.1), capped at
    both ends with support rings (σ̂ 0.002 and 0.01).  The support ring inside a cap is
    the rim moved towards the centroid, which lies in the big disk: the small disk's
    ring is pushed through the waist and the cap folded over (426-746 crossing pairs).
    An inset ring that would cross itself or the rim is not made (a note says so) and
    the cap is flat inside its rim: a valid solid."""
    for waist in (0.05, 0.1):
        contour = _dumbbell(waist)
        rings = [np.column_stack([contour, np.full(len(contour), z)])
                 for z in np.linspace(0.0, 1.0, 11)]
        for sigma in (0.002, 0.01):
            result = stitch_rings(rings, AXIS, support_sigma=sigma)
            report = check_solid(result.vertices, result.triangles)
            assert result.closed and report.valid, (waist, sigma, report.problems())
            assert any("inset contour would cross" in m for m in result.messages)
            ends = result.vertices[np.unique(result.triangles[result.region < 0])][:, 2]
            assert np.all((np.abs(ends) < 1e-12) | (np.abs(ends - 1.0) < 1e-12))


def _spur_ring(radius: float, z: float, width: float, tilt: float, base: float,
               length: float = 0.6, step: float = 0.05) -> np.ndarray:
    """A circle with a thin straight spur along +x (``width`` wide, its midline at
    ``base + tilt * (x - radius)``), counter-clockwise: out along the spur's lower side,
    back along its upper side, round the circle."""
    half = width / 2
    a0 = np.arcsin(half / radius)
    ang = np.linspace(a0, 2 * np.pi - a0, int(2 * np.pi * radius / step))
    xs = np.arange(radius, radius + length, step)
    mid = base + tilt * (xs - radius)
    ring = np.vstack([np.column_stack([xs, mid - half]),
                      [[radius + length, base + tilt * length]],
                      np.column_stack([xs[::-1], mid[::-1] + half]),
                      np.column_stack([radius * np.cos(ang), base + radius * np.sin(ang)])])
    return np.column_stack([ring, np.full(len(ring), z)])


def test_a_strip_is_not_tiled_through_a_pinch_at_a_spurs_root():
    """Two rings with a spur (a stick to a lobe, sub-spacing wide), the upper one's a
    spur's width to the side and turned by ``tilt``: the rings' closest pair of points is
    at the spur's root, where the lower ring leaves its spur as the upper one enters it.
    The shortest-span tiling started there fanned each ring's whole spur to one point of
    the other, and the fans crossed (22-24 pairs); started also a quarter, a half and
    three quarters round, the shortest tiling is a valid solid."""
    from scipy.spatial import cKDTree
    for width in (0.02, 0.04):
        for tilt, radius in ((0.1, 1.05), (0.3, 1.1)):
            lower = _spur_ring(1.0, 0.0, width, 0.0, 0.0)
            upper = _spur_ring(radius, 0.1, width, tilt, width)
            gap, nearest = cKDTree(upper).query(lower)
            root = lower[np.argmin(gap), :2]
            assert abs(root[0] - radius) < 1e-9 and abs(root[1] - width / 2) < 1e-9
            result = stitch_rings([lower, upper], AXIS)
            report = check_solid(result.vertices, result.triangles)
            assert result.closed and report.valid, (width, tilt, report.problems())


def test_two_domes_facing_across_one_slab_do_not_cross():
    """A tube ends under one section and another, beside it, starts over the next; their
    unit-circle contours overlap by a lens (3.7 % of a disc: too little to relate them).
    Both caps are domes fitted to the same points in the slab between the sections (a
    bump 0.1 high, σ 0.002), and where the contours overlap the rising dome and the
    falling one crossed (119-204 pairs); each is now held to its half of the slab, and
    the mesh is a valid solid."""
    gap = 1.8
    rings = [[_circle(1.0, z)] for z in np.arange(0.0, 0.55, 0.1)]
    rings += [[_circle(1.0, z, centre=(gap, 0.0))] for z in np.arange(0.6, 1.15, 0.1)]
    for seed in (0, 1):
        rng = np.random.default_rng(seed)
        x, y = rng.uniform(-1, gap + 1, 6000), rng.uniform(-1, 1, 6000)
        keep = (np.hypot(x, y) < 1) | (np.hypot(x - gap, y) < 1)
        x, y = x[keep], y[keep]
        h = 0.5 + 0.1 * np.exp(-((x - gap / 2) ** 2 + y ** 2) / 0.3) \
            + rng.normal(0, 0.002, len(x))
        result = stitch_rings(rings, AXIS, cap_points=np.column_stack([x, y, h]))
        assert sum("a dome" in note for note in result.notes) == 2
        report = check_solid(result.vertices, result.triangles)
        assert result.closed and report.valid, (seed, report.problems())
        inner = result.vertices[np.unique(result.triangles[result.region == -3])]
        assert inner[:, 2].min() >= 0.5 - 1e-12 and inner[:, 2].max() <= 0.6 + 1e-12


def test_no_flip_turns_a_cap_face_over_along_the_axis():
    """A pair of faces both facing up the axis whose quad is not convex seen along it:
    the flip is legal in 3-D (the opposite angles sum past π, the normals turn less than
    45°) and turns one new face over, so in a cap (a height field over the section plane:
    the noisy teapot's lid dome had 43 such faces crossing their neighbours) it is
    refused; in a strip (region >= 0) and without the axis it is made."""
    from surface.stitch import delaunay_flips
    v = np.array([[0.07, -0.52, -0.34], [-0.31, -0.06, 0.97], [-0.26, -0.46, -0.22],
                  [0.62, -0.85, 0.51]])
    faces = np.array([[0, 1, 2], [1, 0, 3]])

    def up(tri):   # twice the faces' areas seen along the axis
        e = v[tri][:, :, :2] - v[tri][:, :1, :2]
        return e[:, 1, 0] * e[:, 2, 1] - e[:, 2, 0] * e[:, 1, 1]
    assert (up(faces) > 0.1).all()
    flipped, flips, _ = delaunay_flips(v, faces, np.array([-1, -1]))
    assert flips == 1 and (up(flipped) < 0).any()
    kept, flips, _ = delaunay_flips(v, faces, np.array([-1, -1]), axis=AXIS)
    assert flips == 0 and np.array_equal(kept, faces)
    _, flips, _ = delaunay_flips(v, faces, np.array([0, 0]), axis=AXIS)
    assert flips == 1


def _head_outline(step: float = 0.07, cell: float = 0.01) -> np.ndarray:
    """A cow's section at its head, counter-clockwise: a body (an ellipse 2.4 by 1.5), a
    neck to the right and two ears on stalks (the boundary of their union on a raster
    of ``cell``, resampled at ``step``)."""
    import cv2
    img = np.zeros((int(3.4 / cell), int(8.0 / cell)), np.uint8)

    def px(x, y):
        return int((x + 3.6) / cell), int((y + 1.7) / cell)
    cv2.ellipse(img, px(-1.0, 0.0), (int(2.4 / cell), int(1.5 / cell)), 0, 0, 360, 255, -1)
    cv2.rectangle(img, px(1.0, -0.75), px(3.3, 0.75), 255, -1)
    for y in (-0.95, 0.95):
        cv2.circle(img, px(3.6, y), int(0.3 / cell), 255, -1)
        cv2.rectangle(img, px(3.0, min(y, 0.0)), px(3.5, max(y, 0.0)), 255, -1)
    contours, _ = cv2.findContours(img, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    c = max(contours, key=len)[:, 0, :].astype(np.float64) * cell - [3.6, 1.7]
    if np.sum(c[:, 0] * np.roll(c[:, 1], -1) - np.roll(c[:, 0], -1) * c[:, 1]) < 0:
        c = c[::-1]
    return _resampled(c, step)


def test_a_merge_of_five_loops_is_bridged_in_an_order_whose_pieces_are_simple():
    """Five loops (a body, two ears, two horns) merge into one (the head's outline). The
    children peeled in the default order (the one nearest to the fewest points first)
    give a bridge that crosses the loop and the merge was left open; another order
    gives simple sub-loops, and the mesh is a valid solid."""
    head = _head_outline()
    for horn_x, horn_y in ((2.3, 0.3), (2.5, 0.55)):
        loops = [_circle(1.4, 0.0, 200, (-1.0, 0.0)), _circle(0.18, 0.0, 40, (3.66, -0.93)),
                 _circle(0.18, 0.0, 40, (3.67, 0.98)), _circle(0.08, 0.0, 30, (horn_x, -horn_y)),
                 _circle(0.08, 0.0, 30, (horn_x, horn_y))]
        rings = [loops] + [[np.column_stack([head, np.full(len(head), z)])] for z in (0.1, 0.2)]
        result = stitch_rings(rings, AXIS)
        report = check_solid(result.vertices, result.triangles)
        assert result.closed and report.valid, (horn_x, horn_y, result.problems[:1])


def _rectangle(half_w: float, half_h: float, per_side: int, z: float) -> np.ndarray:
    xs = np.linspace(-half_w, half_w, per_side, endpoint=False)
    ys = np.linspace(-half_h, half_h, per_side, endpoint=False)
    ring = np.vstack([np.column_stack([xs, np.full(per_side, -half_h)]),
                      np.column_stack([np.full(per_side, half_w), ys]),
                      np.column_stack([-xs, np.full(per_side, half_h)]),
                      np.column_stack([np.full(per_side, -half_w), -ys])])
    return np.column_stack([ring, np.full(len(ring), z)])


def test_a_small_branch_inside_its_sub_loop_is_tiled_by_the_angle_about_it():
    """A sparse rectangle (24 points) splits into a wide loop and a small dense one (60
    points, radius 0.05-0.1) inside its bridged sub-loop.  By the shortest total span the
    small loop was fanned to one far point and the sub-loop to a few points behind it:
    the fans crossed (3-9 pairs) or the mesh came out open; by the angle about the small
    loop's centroid the mesh is a valid solid."""
    for (cx, cy), radius in (((1.2, 0.6), 0.05), ((1.0, 0.0), 0.1)):
        branches = [[_circle(0.8, z, 60, (-1.0, 0.0)), _circle(radius, z, 60, (cx, cy))]
                    for z in (0.1, 0.2)]
        result = stitch_rings([[_rectangle(2.0, 1.0, 6, 0.0)]] + branches, AXIS)
        report = check_solid(result.vertices, result.triangles)
        assert result.closed and report.valid, ((cx, cy), report.problems())


def test_a_section_whose_two_loops_cross_each_other_is_skipped():
    """Two legs (circles of radius 0.4 at x = ±0.5) over seven sections; in the middle one
    the legs' contours are drawn at x = ±0.3 and cross each other (two parts closer than
    the sections resolve, each taken into the other's contour).  Stitched as they are, the
    strips to that section cross; ``untangle`` skips it with a note naming the crossing
    loops, and the rest stitches to a valid solid of two components."""
    from types import SimpleNamespace

    from surface.reconstruct import untangle
    from surface.stitch import axis_frame, loops_cross

    t = np.linspace(0.0, 2.0 * np.pi, 48, endpoint=False)

    def leg(x, z):
        return np.column_stack([x + 0.4 * np.cos(t), 0.4 * np.sin(t), np.full(len(t), z)])

    rings = [[leg(-0.5, 0.1 * k), leg(0.5, 0.1 * k)] for k in range(7)]
    rings[3] = [leg(-0.3, 0.3), leg(0.3, 0.3)]
    assert loops_cross([r[:, :2] for r in rings[3]])
    assert not loops_cross([r[:, :2] for r in rings[2]])
    crossed = stitch_rings(rings, AXIS)
    assert not check_solid(crossed.vertices, crossed.triangles).valid
    kept = [SimpleNamespace(section_id=k, height=0.1 * k, frame=axis_frame(AXIS))
            for k in range(len(rings))]
    kept, loops, rings, notes = untangle(kept, [[None, None]] * len(rings), rings)
    assert [k.section_id for k in kept] == [0, 1, 2, 4, 5, 6]
    assert len(notes) == 1 and "section 3 " in notes[0] and "cross each other" in notes[0]
    result = stitch_rings(rings, AXIS)
    report = check_solid(result.vertices, result.triangles)
    assert result.closed and report.valid and report.components == 2, report.problems()


def test_a_strip_to_a_ring_with_a_narrow_spike_covers_the_plan_once():
    """Two rings of the temple ring's stitched top (209 and 418 points, the upper one
    with a narrow spike the lower lacks, the upper wholly inside the lower in the plan;
    centred, ``data/temple_spike_strip.npz``).  The shortest-span tiling fanned one
    lower point over both sides of the spike: 179 crossing pairs.  With the axis, a face
    whose third vertex lies on the wrong side of its ring edge costs more than any
    tiling without one: none."""
    from pathlib import Path

    from surface.stitch import tile_min_span
    from surface.validity import self_intersections

    data = np.load(Path(__file__).parent / "data" / "temple_spike_strip.npz")
    lower, upper, axis = data["lower"], data["upper"], data["axis"]
    v = np.vstack([lower, upper])
    assert len(self_intersections(v, tile_min_span(lower, upper))) > 100
    tri = tile_min_span(lower, upper, axis)
    assert len(tri) == len(v)
    edges = np.sort(np.vstack([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert counts.max() == 2 and np.sum(counts == 1) == len(v)   # a closed strip
    assert len(self_intersections(v, tri)) == 0


def test_a_hairpin_between_crossing_rings_takes_the_sided_tiling_where_it_crosses_less():
    """Sections 16 and 17 of the stitched fandisk (40 000 points, noise 0; centred,
    ``data/fandisk_hairpin_strip.npz``): section 17's ring runs out and back along nearly
    one line at the sharp edge, and the two rings cross in the plan, where the side rule
    is off.  The shortest-span tiling crossed itself at 5 pairs; the sided one does not,
    so it is taken."""
    from pathlib import Path

    from surface.stitch import tile_min_span
    from surface.validity import self_intersections

    data = np.load(Path(__file__).parent / "data" / "fandisk_hairpin_strip.npz")
    lower, upper, axis = data["lower"], data["upper"], data["axis"]
    v = np.vstack([lower, upper])
    assert len(self_intersections(v, tile_min_span(lower, upper))) > 0
    tri = tile_min_span(lower, upper, axis)
    edges = np.sort(np.vstack([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert counts.max() == 2 and np.sum(counts == 1) == len(v)   # a closed strip
    assert len(self_intersections(v, tri)) == 0


def test_a_strip_is_zipped_by_one_angle_about_one_centre():
    """The temple ring's first four rings (centred, ``data/temple_bottom_rings.npz``),
    stitched with support rings.  The two support rings between its bottom rings carry
    those rings' unlike samplings, their point means 0.009 apart in the plan (0.0006 in
    height): zipped by each ring's angle about its own mean, the strip sheared along the
    wall and crossed itself and the next strip (5 pairs).  About one centre: none."""
    from pathlib import Path

    data = np.load(Path(__file__).parent / "data" / "temple_bottom_rings.npz")
    rings = [data[f"ring{i}"] for i in range(4)]
    result = stitch_rings(rings, data["axis"], support_sigma=float(data["sigma"]))
    report = check_solid(result.vertices, result.triangles)
    assert result.closed and report.valid and report.genus == 0, report.problems()


def test_a_sided_strip_that_crosses_itself_gives_way_to_the_plain_one():
    """A column's sub-loop (59 points, after a split into four columns) and its column's
    loop (88 points) in the temple ring's thinned control mesh (centred,
    ``data/temple_column_strip.npz``); the rings do not cross in the plan.  The sided
    tiling judged a side by the other ring's nearest point, across a narrow gap, and
    crossed itself (7 pairs); the plain shortest-span tiling does not, so it is taken."""
    from pathlib import Path

    from surface.stitch import tile_min_span
    from surface.validity import self_intersections

    data = np.load(Path(__file__).parent / "data" / "temple_column_strip.npz")
    lower, upper, axis = data["lower"], data["upper"], data["axis"]
    v = np.vstack([lower, upper])
    tri = tile_min_span(lower, upper, axis)
    edges = np.sort(np.vstack([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert counts.max() == 2 and np.sum(counts == 1) == len(v)   # a closed strip
    assert len(self_intersections(v, tri)) == 0
