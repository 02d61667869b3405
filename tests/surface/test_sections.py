"""Tests of surface.sections: slicing a cloud into planar sections, reading sectioned data.

Ground truth: the vase r(z) = 1 + 0.3 sin 2z, z ∈ [0, 3] (the issue's benchmark
surface), sampled area-uniformly with Gaussian noise σ.  A point at height
offset δ from its plane is projected along the axis, which moves its radius by
r'(z)·δ with |r'| ≤ 0.6, so the radius of a section point differs from
r(h_k) by at most ~5σ (largest of a few thousand Gaussian samples) plus
0.6·thickness plus second order (|r''| t²/2 ≤ 0.6 t²).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from surface.sections import (
    Section,
    common_frame,
    point_spacing,
    read_sectioned,
    slice_sections,
)


def vase(n: int, sigma: float = 0.002, seed: int = 0, radius_scale: float = 1.0) -> np.ndarray:
    """Area-uniform points on r(z) = s·(1 + 0.3 sin 2z), z ∈ [0, 3], plus N(0, σ²) noise."""
    rng = np.random.default_rng(seed)
    z = rng.uniform(0.0, 3.0, 6 * n)
    r = radius_scale * (1.0 + 0.3 * np.sin(2 * z))
    weight = r * np.sqrt(1.0 + (radius_scale * 0.6 * np.cos(2 * z)) ** 2)  # dA ∝ r·ds
    keep = rng.uniform(0.0, weight.max(), z.size) < weight
    z, r = z[keep][:n], r[keep][:n]
    assert z.size == n
    phi = rng.uniform(0.0, 2 * np.pi, n)
    pts = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)
    return pts + rng.normal(0.0, sigma, pts.shape)


def rotation(axis, angle: float) -> np.ndarray:
    """Rodrigues rotation matrix (3, 3)."""
    k = np.asarray(axis, float) / np.linalg.norm(axis)
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * kx + (1 - math.cos(angle)) * kx @ kx


def analytic_radius(h):
    return 1.0 + 0.3 * np.sin(2 * h)


# ----------------------------------------------------------------------------- geometry
def test_vase_sections_lie_at_the_analytic_radius():
    sigma, t = 0.002, 0.004
    pts = vase(20_000, sigma)
    sections = slice_sections(pts, "z", count=12, thickness=t)
    assert len(sections) == 12
    h_min, h_max = pts[:, 2].min(), pts[:, 2].max()
    delta = (h_max - h_min) / 12
    bound = 5.5 * sigma + 0.6 * t + 0.6 * t**2  # module docstring
    for k, s in enumerate(sections):
        assert s.section_id == k
        assert s.height == pytest.approx(h_min + (k + 0.5) * delta, abs=1e-12)
        assert len(s) > 20  # ρ·P·2t ≈ 950 · 2π·r · 0.008 ≥ 33
        np.testing.assert_allclose(s.points[:, 2], s.height, atol=1e-12)  # on the plane
        radius = np.hypot(s.points[:, 0], s.points[:, 1])
        err = radius - analytic_radius(s.height)
        assert np.max(np.abs(err)) < bound
        # zero-mean within the statistical error of the mean (σ_eff/√M, ×4)
        sigma_eff = math.hypot(sigma, 0.6 * t / math.sqrt(3))
        assert abs(err.mean()) < 4 * sigma_eff / math.sqrt(len(s)) + 0.6 * t**2
        # every point is within the thickness of its plane before projection
        assert np.all(np.abs(pts[s.source_index, 2] - s.height) <= t + 1e-12)
        np.testing.assert_allclose(s.points[:, :2], pts[s.source_index, :2])


def test_sections_partition_the_cloud_with_tiling_thickness():
    pts = vase(5_000)
    sections = slice_sections(pts, "z", count=10, thickness=(np.ptp(pts[:, 2]) / 10) / 2)
    used = np.concatenate([s.source_index for s in sections])
    assert np.array_equal(np.sort(used), np.arange(len(pts)))


def test_common_frame_is_right_handed_and_shared():
    pts = vase(3_000)
    sections = slice_sections(pts, (0.2, -0.3, 1.0), count=5)
    for s in sections:
        np.testing.assert_array_equal(s.frame, sections[0].frame)
        np.testing.assert_allclose(s.frame @ s.frame.T, np.eye(3), atol=1e-15)
        assert np.linalg.det(s.frame) == pytest.approx(1.0, abs=1e-14)
        np.testing.assert_allclose(np.cross(s.frame[0], s.frame[1]), s.frame[2], atol=1e-15)
    np.testing.assert_array_equal(common_frame(np.array([0.0, 0.0, 1.0])), np.eye(3))


def test_to_plane_and_back_round_trip():
    pts = vase(2_000)
    s = slice_sections(pts, (1.0, 2.0, 3.0), count=4)[2]
    uv = s.to_plane(s.points)
    assert uv.shape == (len(s), 2)
    np.testing.assert_allclose(s.to_world(uv), s.points, atol=1e-12)


def test_sections_invariant_under_rotation_about_the_axis():
    pts = vase(4_000)
    rot = rotation((0, 0, 1), 0.7)
    before = slice_sections(pts, "z", count=8)
    after = slice_sections(pts @ rot.T, "z", count=8)
    for a, b in zip(before, after, strict=True):
        assert a.height == pytest.approx(b.height, abs=1e-12)
        assert np.array_equal(a.source_index, b.source_index)
        np.testing.assert_allclose(a.points @ rot.T, b.points, atol=1e-12)


def test_tilted_axis_gives_the_same_sections():
    pts = vase(4_000)
    rot = rotation((1.0, 2.0, 0.5), 0.9)
    tilted_axis = rot @ np.array([0.0, 0.0, 1.0])
    straight = slice_sections(pts, "z", count=8)
    tilted = slice_sections(pts @ rot.T, tilted_axis, count=8)
    for a, b in zip(straight, tilted, strict=True):
        assert a.height == pytest.approx(b.height, abs=1e-12)
        assert np.array_equal(a.source_index, b.source_index)
        np.testing.assert_allclose(a.points @ rot.T, b.points, atol=1e-12)


def test_auto_axis_recovers_a_tilted_vase():
    # PCA's axis error has standard deviation ≈ sqrt(λ1 λ2 / N) / (λ1 − λ2) rad: for
    # this half-radius vase λ1 ≈ 0.75 (along z), λ2 ≈ 0.14, N = 20 000 → ≈ 0.004 rad
    # (0.2°); the bound 1° is five standard deviations.
    pts = vase(20_000, radius_scale=0.5)
    rot = rotation((1.0, -1.0, 0.3), 0.6)
    truth = rot @ np.array([0.0, 0.0, 1.0])
    sections = slice_sections(pts @ rot.T, "auto", count=6)
    axis = sections[0].frame[2]
    angle = math.degrees(math.acos(min(1.0, abs(float(axis @ truth)))))
    assert angle < 1.0
    assert axis[np.argmax(np.abs(axis))] > 0  # deterministic sign


def test_default_spacing_follows_the_point_density():
    # Poisson points on a unit square: spacing 1/sqrt(ρ) = 1/sqrt(N).  The median
    # of N nearest-neighbour distances has relative error ~1/sqrt(N) (≈1 %); the
    # border (where neighbours are missing on one side) adds ~2 %: 6 % bound.
    rng = np.random.default_rng(3)
    for n in (5_000, 80_000):  # the second uses the 20 000-point subsample
        square = np.c_[rng.uniform(size=(n, 2)), np.zeros(n)]
        assert point_spacing(square) == pytest.approx(1 / math.sqrt(n), rel=0.06)
    pts = vase(20_000)
    s = point_spacing(pts)
    sections = slice_sections(pts, "z")
    extent = np.ptp(pts[:, 2])
    assert len(sections) == round(extent / (2 * s))
    offsets = [np.abs(pts[sec.source_index, 2] - sec.height).max() for sec in sections if len(sec)]
    assert max(offsets) <= s / 2 + 1e-12


def test_spacing_argument_sets_the_count():
    pts = vase(3_000)
    sections = slice_sections(pts, "z", spacing=0.25)
    assert len(sections) == round(np.ptp(pts[:, 2]) / 0.25)
    assert np.diff([s.height for s in sections]) == pytest.approx(0.25)


# ----------------------------------------------------------------------------- bad input
@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"points": np.empty((0, 3))}, "points is empty"),
        ({"points": np.ones((5, 2))}, r"points must have shape \(N, 3\)"),
        ({"axis": (0.0, 0.0, 0.0)}, "axis must have non-zero length"),
        ({"axis": "w"}, "axis must be"),
        ({"axis": (1.0, np.nan, 0.0)}, "axis contains"),
        ({"count": 0}, "count must be a positive integer"),
        ({"count": 2.5}, "count must be a positive integer"),
        ({"count": 3, "spacing": 0.1}, "give count or spacing"),
        ({"spacing": -1.0}, "spacing must be"),
        ({"count": 3, "thickness": 5.0}, "thickness must be"),
    ],
)
def test_bad_arguments_raise_a_named_value_error(kwargs, match):
    args = {"points": vase(500), "axis": "z"} | kwargs
    with pytest.raises(ValueError, match=match):
        slice_sections(**args)


def test_nan_and_inf_coordinates_are_refused():
    pts = vase(500)
    pts[7, 1] = np.nan
    pts[9, 0] = np.inf
    with pytest.raises(ValueError, match="points contains 2 NaN/inf"):
        slice_sections(pts)


def test_points_on_one_plane_perpendicular_to_the_axis_are_refused():
    rng = np.random.default_rng(0)
    flat = np.c_[rng.uniform(size=(200, 2)), np.full(200, 0.5)]
    with pytest.raises(ValueError, match="lie on one plane"):
        slice_sections(flat, "z")
    assert len(slice_sections(flat, "x", count=3)) == 3  # another axis works


# ----------------------------------------------------------------------------- read_sectioned
def _rings(heights, m=40):
    phi = np.linspace(0, 2 * np.pi, m, endpoint=False)
    return [np.c_[np.cos(phi) * (1 + h), np.sin(phi) * (1 + h), np.full(m, h)] for h in heights]


def test_read_sectioned_with_id_column(tmp_path):
    rings = _rings([0.0, 0.5, 1.0])
    path = tmp_path / "survey.csv"
    rows = ["x,y,z,id", "# a contour survey"]
    for sid in (2, 0, 1):  # sections in any order in the file
        rows += [f"{x:.17g},{y:.17g},{z:.17g},{sid}" for x, y, z in rings[sid]]
    path.write_text("\n".join(rows) + "\n")
    sections = read_sectioned(path)
    assert [len(s) for s in sections] == [40, 40, 40]
    for sid, s in enumerate(sections):
        assert isinstance(s, Section)
        assert s.height == pytest.approx(0.5 * sid, abs=1e-15)
        np.testing.assert_allclose(s.points, rings[sid], atol=1e-15)


def test_read_sectioned_groups_equal_z(tmp_path):
    rings = _rings([0.25, -1.0])
    path = tmp_path / "survey.xyz"
    lines = [" ".join(f"{v:.17g}" for v in row) for ring in rings for row in ring]
    path.write_text("\n".join(lines))
    sections = read_sectioned(path)
    assert [s.height for s in sections] == pytest.approx([-1.0, 0.25])
    np.testing.assert_allclose(sections[0].points, rings[1])


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("0 0 0\n1 1 oops\n", r"bad\.xyz:2: not a row of numbers"),
        ("0 0 0\n1 1\n", r"bad\.xyz:2: expected 3 \(x y z\) or 4"),
        ("0 0 0 1\n1 1 1\n", r"bad\.xyz:2: 3 columns where earlier lines have 4"),
        ("0 0 0\n\n1 nan 2\n", r"bad\.xyz:3: NaN/inf"),
        ("0 0 0 1.5\n", r"bad\.xyz:1: section id must be an integer"),
        ("# only a comment\n", r"bad\.xyz: no points"),
    ],
)
def test_read_sectioned_names_file_and_line(tmp_path, text, match):
    path = tmp_path / "bad.xyz"
    path.write_text(text)
    with pytest.raises(ValueError, match=match):
        read_sectioned(path)


def test_fast_and_careful_readers_agree(tmp_path):
    # the numpy reader is the fast path; the line-by-line one only names bad lines
    from surface.sections import _parse_table, _parse_table_fast

    text = "x;y;z;id\n# survey\n1,2,3,0  # tail\n4;5;6;1\r\n\n7\t8\t9\t1\n"
    fast = _parse_table_fast(text)
    careful, lines = _parse_table(tmp_path / "t.csv", text)
    np.testing.assert_array_equal(fast, careful)
    assert lines.tolist() == [3, 4, 6]
    assert _parse_table_fast("0 0 0\n1 1\n") is None  # ragged: the careful reader decides


def test_read_sectioned_missing_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="missing.csv"):
        read_sectioned(tmp_path / "missing.csv")
