"""Tests of surface.catmull_rom: closed Catmull-Rom curves, smoothing, resampling.

Exact identities (interpolation, C1 at the knots, agreement with the matrix
form of eq. (3,5), locality of an update) hold to rounding: a few dozen
floating-point operations on coordinates of size ~1, so 1e-12.  Statistical
claims state their bound where they are made.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from surface.catmull_rom import (
    M_CR,
    ClosedCurve,
    RingFit,
    bridge_gaps,
    choose_smoothing,
    fit,
    fit_loop,
    precision_factor,
    predict_ring,
    predict_sections,
    ring_size,
)
from surface.sections import Section
from surface.topology import organise
from tests.surface.test_topology import c_shape

FRAME = np.eye(3)


def polygon(n: int, seed: int = 0, z: float = 0.0) -> np.ndarray:
    """A star-shaped random polygon (n, 3) around the origin, counter-clockwise."""
    rng = np.random.default_rng(seed)
    phi = np.sort(rng.uniform(0, 2 * np.pi, n))
    r = rng.uniform(0.7, 1.3, n)
    return np.c_[r * np.cos(phi), r * np.sin(phi), np.full(n, z)]


def paper_q(points: np.ndarray, i: int, t: float) -> np.ndarray:
    """Eq. (3,5) literally: ½·[t³ t² t 1]·M_CR·[P_{i−3} … P_i]ᵀ, indices cyclic."""
    n = len(points)
    block = points[[(i - 3) % n, (i - 2) % n, (i - 1) % n, i % n]]
    return 0.5 * np.array([t**3, t**2, t, 1.0]) @ M_CR @ block


# ----------------------------------------------------------------------------- exact form
def test_curve_interpolates_its_control_points():
    pts = polygon(11)
    curve = ClosedCurve.from_control_points(pts)
    np.testing.assert_allclose(curve.evaluate(np.arange(11)), pts, atol=1e-12)
    np.testing.assert_allclose(curve.evaluate(11.0), pts[0], atol=1e-12)  # closed


def test_curve_equals_the_matrix_form_of_eq_3_5():
    pts = polygon(9, seed=1) + [0.0, 0.0, 0.5]
    curve = ClosedCurve.from_control_points(pts)
    rng = np.random.default_rng(2)
    for _ in range(200):
        i = int(rng.integers(0, 9))  # paper's segment i runs from P_{i−2} to P_{i−1}
        t = float(rng.uniform(0, 1))
        global_t = (i - 2) % 9 + t
        np.testing.assert_allclose(curve.evaluate(global_t), paper_q(pts, i, t), atol=1e-12)


def test_uniform_tangents_are_central_differences():
    pts = polygon(7, seed=3)
    curve = ClosedCurve.from_control_points(pts)
    central = 0.5 * (np.roll(pts, -1, axis=0) - np.roll(pts, 1, axis=0))
    np.testing.assert_allclose(curve.derivative(np.arange(7)), central, atol=1e-12)


@pytest.mark.parametrize("parametrisation", ["uniform", "centripetal", "chordal"])
def test_curve_is_c1_at_the_knots(parametrisation):
    pts = polygon(10, seed=4)
    curve = ClosedCurve.from_control_points(pts, parametrisation)
    coeffs = curve.segment_coefficients()  # (4, n, 3), powers 3, 2, 1, 0 of (t − t_j)
    h = np.diff(curve.knots)
    # value and first derivative at the right end of segment j ...
    end_value = coeffs[0] * h[:, None] ** 3 + coeffs[1] * h[:, None] ** 2 + coeffs[2] * h[:, None]
    end_value += coeffs[3]
    end_slope = 3 * coeffs[0] * h[:, None] ** 2 + 2 * coeffs[1] * h[:, None] + coeffs[2]
    # ... equal those at the left end of segment j + 1 (cyclic)
    np.testing.assert_allclose(end_value, np.roll(coeffs[3], -1, axis=0), atol=1e-12)
    np.testing.assert_allclose(end_slope, np.roll(coeffs[2], -1, axis=0), atol=1e-12)


def test_centripetal_tangent_is_barry_goldman():
    pts = polygon(8, seed=5)
    curve = ClosedCurve.from_control_points(pts, "centripetal")
    d = np.linalg.norm(np.roll(pts, -1, axis=0) - pts, axis=1) ** 0.5
    np.testing.assert_allclose(np.diff(curve.knots), d, rtol=1e-14)
    j = 3
    p0, p1, p2 = pts[j - 1], pts[j], pts[j + 1]
    expect = (p1 - p0) / d[j - 1] - (p2 - p0) / (d[j - 1] + d[j]) + (p2 - p1) / d[j]
    np.testing.assert_allclose(curve.tangents[j], expect, atol=1e-12)


@pytest.mark.parametrize("parametrisation", ["uniform", "centripetal"])
def test_moving_one_point_changes_only_four_segments(parametrisation):
    n, j = 12, 0  # j = 0 checks the cyclic wrap
    curve = ClosedCurve.from_control_points(polygon(n, seed=6), parametrisation)
    moved = curve.update_point(j, curve.control_points[j] + [0.2, -0.1, 0.05])
    # uniform: bitwise; centripetal: the knots are a cumulative sum, so the other
    # segments' coefficients may differ by rounding of their breakpoints (1e-12)
    diff = np.abs(moved.segment_coefficients() - curve.segment_coefficients()).max(axis=(0, 2))
    changed = diff > (0.0 if parametrisation == "uniform" else 1e-12)
    expect = np.zeros(n, bool)
    expect[[(j - 2) % n, (j - 1) % n, j, (j + 1) % n]] = True  # segments P_{j−2} … P_{j+2}
    assert np.array_equal(changed, expect)
    if parametrisation == "uniform":  # same parameter for every other point: identical curve
        far = np.linspace(3.0, 9.0, 50)
        np.testing.assert_array_equal(moved.evaluate(far), curve.evaluate(far))


# ----------------------------------------------------------------------------- smoothing
def noisy_circle(m: int, sigma: float, seed: int = 0, radius: float = 1.0):
    rng = np.random.default_rng(seed)
    phi = np.sort(rng.uniform(0, 2 * np.pi, m))
    pts = np.c_[radius * np.cos(phi), radius * np.sin(phi), np.zeros(m)]
    pts[:, :2] += rng.normal(0, sigma, (m, 2))
    return pts


def radial_rms(curve: ClosedCurve, radius: float = 1.0) -> float:
    q = curve.evaluate(np.linspace(0, curve.period, 20_000, endpoint=False))
    return float(np.sqrt(np.mean((np.hypot(q[:, 0], q[:, 1]) - radius) ** 2)))


def test_smoothing_level_reduces_noise():
    # A least-squares curve with n control points through M points: the fitted
    # values' mean variance is σ²·n/M (trace of the hat matrix), so the normal
    # error is ≈ σ/√smoothing; bound 1.5× that, and "well below σ".
    sigma, m = 0.01, 2000
    pts = noisy_circle(m, sigma)
    for smoothing in (2, 4, 16, 32):
        curve = fit(pts, smoothing, frame=FRAME, centroid=np.zeros(3))
        assert curve.n == round(m / smoothing)
        assert radial_rms(curve) < 1.5 * sigma / math.sqrt(smoothing)
    assert radial_rms(fit(pts, 16, frame=FRAME, centroid=np.zeros(3))) < 0.4 * sigma


def test_noise_free_fit_is_close_to_exact():
    # uniform Catmull-Rom through n points of a unit circle errs by ≈ 0.023·(2π/n)⁴
    # (Taylor expansion of the midpoint formula (−P0 + 9P1 + 9P2 − P3)/16): 4e-6 at
    # n = 56 at the midpoints; least squares on random points stays within 2× that
    # (measured ~6e-8: the fit spreads the error, the interpolant concentrates it).
    pts = noisy_circle(450, 0.0, seed=1)
    curve = fit(pts, 8, frame=FRAME, centroid=np.zeros(3))
    assert curve.n == 56
    assert radial_rms(curve) < 2 * 0.0234 * (2 * math.pi / 56) ** 4


def test_auto_smoothing_picks_a_level_that_beats_the_noise():
    # GCV on a noisy circle: smooth enough to stay well below σ, the level recorded
    sigma = 0.01
    pts = noisy_circle(2000, sigma, seed=4)
    curve = fit(pts, "auto", frame=FRAME, centroid=np.zeros(3))
    assert curve.smoothing >= 8
    assert radial_rms(curve) < 1.5 * sigma / math.sqrt(curve.smoothing)
    assert radial_rms(curve) < 0.3 * sigma


def test_smoothing_at_most_one_interpolates_the_points():
    pts = polygon(20, seed=7)
    curve = fit(pts, 1, frame=FRAME)
    np.testing.assert_allclose(curve.control_points, pts)


def test_fit_orients_counter_clockwise():
    pts = polygon(30, seed=8)[::-1]  # clockwise input
    curve = fit(pts, 2, frame=FRAME)
    assert curve.signed_area() > 0


# ----------------------------------------------------------------------------- resampling
def ellipse_curve(n_ctrl: int = 200, a: float = 2.0, b: float = 1.0) -> ClosedCurve:
    phi = np.linspace(0, 2 * np.pi, n_ctrl, endpoint=False)
    pts = np.c_[a * np.cos(phi), b * np.sin(phi), np.zeros(n_ctrl)]
    return ClosedCurve.from_control_points(pts, frame=FRAME, centroid=np.zeros(3))


def test_resample_theta_hits_the_requested_angles_exactly():
    curve = ellipse_curve()
    for n, theta0 in ((16, 0.0), (33, 0.4)):
        ring = curve.resample_theta(n, theta0)
        want = theta0 + 2 * np.pi * np.arange(n) / n
        got = np.arctan2(ring[:, 1], ring[:, 0])
        err = np.mod(got - want + np.pi, 2 * np.pi) - np.pi
        assert np.max(np.abs(err)) < 1e-12
        # and the points are on the ellipse (200 control points: CR error ~1e-6)
        assert np.max(np.abs((ring[:, 0] / 2) ** 2 + ring[:, 1] ** 2 - 1)) < 1e-5


def test_resample_theta_refuses_a_non_star_shaped_curve():
    t = np.linspace(0, 2 * np.pi, 80, endpoint=False)
    # a closed curve winding twice about its centroid is not star-shaped
    pts = np.c_[np.cos(2 * t) * (1 + 0.3 * np.cos(t)), np.sin(2 * t) * (1 + 0.3 * np.cos(t)), 0 * t]
    curve = ClosedCurve.from_control_points(pts, frame=FRAME)
    assert not curve.is_star_shaped()
    with pytest.raises(ValueError, match="not star-shaped"):
        curve.resample_theta(10)


def test_resample_arclength_is_equally_spaced_from_theta0():
    curve = ellipse_curve()
    ring = curve.resample_arclength(64, theta0=0.0)
    step = np.linalg.norm(np.roll(ring, -1, axis=0) - ring, axis=1)
    # equal arc length s ⇒ chord s·(1 − (κ s)²/24): κ on this ellipse spans
    # [b/a², a/b²] = [0.25, 2], so the chords vary by < (2 s)²/24 relative
    s = step.mean()
    assert np.ptp(step) / s < (2 * s) ** 2 / 24
    np.testing.assert_allclose(ring[0], [2.0, 0.0, 0.0], atol=1e-9)  # starts on the θ0 ray
    x, y = ring[:, 0], ring[:, 1]
    assert np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y) > 0  # counter-clockwise


# ----------------------------------------------------------------------------- prediction
def circle_section(sid: int, m: int = 120, seed: int = 0) -> Section:
    rng = np.random.default_rng(seed + sid)
    phi = rng.uniform(0, 2 * np.pi, m)
    h = 0.1 * sid
    pts = np.c_[(1 + h) * np.cos(phi), (1 + h) * np.sin(phi), np.full(m, h)]
    return Section(h, pts, np.array([0.0, 0.0, h]), FRAME, sid, np.arange(m))


def test_predict_sections_gives_n_and_2n_points_at_equal_theta():
    loops = [organise(circle_section(k))[0] for k in range(4)]
    rings = predict_sections(loops, 10, smoothing=4)
    assert [len(r) for r in rings] == [10, 20, 10, 20]
    assert [ring_size(k, 10) for k in range(4)] == [10, 20, 10, 20]
    for k, (ring, loop) in enumerate(zip(rings, loops, strict=True)):
        rel = ring - loop.centroid
        got = np.mod(np.arctan2(rel[:, 1], rel[:, 0]), 2 * np.pi)
        want = 2 * np.pi * np.arange(len(ring)) / len(ring)
        assert np.max(np.abs(np.mod(got - want + np.pi, 2 * np.pi) - np.pi)) < 1e-12
        np.testing.assert_allclose(ring[:, 2], 0.1 * k, atol=1e-12)  # on the section plane


def test_predict_sections_mirrors_several_loops():
    loop = organise(circle_section(0))[0]
    rings = predict_sections([loop, [loop, loop]], 6, smoothing=4)
    assert rings[0].shape == (6, 3)
    assert isinstance(rings[1], list) and [r.shape for r in rings[1]] == [(12, 3), (12, 3)]


def test_a_branch_loop_gets_ring_points_by_the_root_of_its_perimeter():
    """A loop a quarter the size of the largest keeps its chord error (h^2 / 8r) with
    its points twice as far apart: half of N (and never fewer than 8)."""
    big = organise(circle_section(0, m=400))[0]
    small = replace(big, points=0.25 * big.points, centroid=0.25 * big.centroid)
    rings = predict_sections([[big, small], [big, small]], 64, smoothing=4)
    assert [len(r) for r in rings[0]] == [64, 32] and [len(r) for r in rings[1]] == [128, 64]
    tiny = replace(big, points=0.001 * big.points, centroid=0.001 * big.centroid)
    assert [len(r) for r in predict_sections([[big, tiny]], 64, smoothing=4)[0]] == [64, 8]
    from surface.catmull_rom import MIN_BRANCH_RING, branch_ring_size, perimeter

    length = perimeter(big.points)
    assert branch_ring_size(64, length, length) == 64
    assert branch_ring_size(64, 0.25 * length, length) == 32
    assert branch_ring_size(64, 1e-6 * length, length) == MIN_BRANCH_RING


def test_predict_ring_of_a_non_star_shaped_loop_uses_arc_length():
    uv, _ = c_shape(600, np.random.default_rng(9))
    pts = np.c_[uv, np.zeros(600)]
    loop = organise(Section(0.0, pts, np.zeros(3), FRAME, 0, np.arange(600)))[0]
    assert not loop.star_shaped
    curve = fit_loop(loop, 4)
    assert not curve.is_star_shaped()
    ring = predict_ring(loop, 40, smoothing=4)
    step = np.linalg.norm(np.roll(ring, -1, axis=0) - ring, axis=1)
    # equal arc steps s ≈ 0.31, curvature ≤ 1/0.35 (the C's round ends): chord
    # s·(1 − (κ s)²/24) ⇒ chords equal within (s/0.35)²/24 ≈ 3.2 %
    s = step.mean()
    assert np.ptp(step) / s < (s / 0.35) ** 2 / 24
    # the θ = π ray from the centroid crosses the inner and the outer arc: the ring
    # starts on the outermost crossing, the outer arc x = −1.35 (within CR error)
    start = curve.resample_arclength(40, theta0=np.pi)[0]
    assert abs(start[1] - loop.centroid[1]) < 1e-9 and start[0] < loop.centroid[0]
    assert start[0] == pytest.approx(-math.sqrt(1.35**2 - loop.centroid[1] ** 2), abs=1e-3)
    # the θ = 0 ray escapes through the C's opening: start at the θ closest to 0
    rel = ring[0] - loop.centroid
    dense = curve.evaluate(np.linspace(0, curve.period, 20_000)) - loop.centroid
    closest = np.abs(np.arctan2(dense[:, 1], dense[:, 0])).min()
    assert abs(math.atan2(rel[1], rel[0])) == pytest.approx(closest, abs=1e-3)


# ----------------------------------------------------------------------------- bad input
@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: ClosedCurve.from_control_points(np.zeros((3, 3))), "at least 4"),
        (lambda: ClosedCurve.from_control_points(polygon(5), "bezier"), "parametrisation"),
        (lambda: fit(np.full((10, 3), np.nan)), "NaN/inf"),
        (lambda: fit(polygon(3)), "at least 4"),
        (lambda: fit(polygon(10), -1.0), "smoothing"),
        (lambda: fit(polygon(10), "lots"), "smoothing"),
        (lambda: fit(polygon(10), parametrisation="bezier"), "centripetal"),
        (lambda: fit(np.zeros((10, 3)), 2.0, frame=FRAME), "coincide"),
        (lambda: ClosedCurve.from_control_points(polygon(5)).update_point(9, [0, 0, 0]), "index"),
        (lambda: ClosedCurve.from_control_points(polygon(5)).resample_theta(0), "n must"),
        (lambda: predict_sections([], 0), "n must"),
    ],
)
def test_bad_input_raises_a_named_value_error(call, match):
    with pytest.raises(ValueError, match=match):
        call()


@pytest.mark.parametrize("m", [4, 5, 6, 8, 9, 12, 16])
@pytest.mark.parametrize("parametrisation", ["uniform", "centripetal", "chordal"])
def test_fit_small_loop_with_large_smoothing(m, parametrisation):
    # A loop with no more points than the smoothing window (8) used to fail with
    # "points all coincide": the window averaged the whole loop to its centroid.
    theta = 2 * np.pi * np.arange(m) / m
    pts = np.stack([np.cos(theta), np.sin(theta), np.zeros(m)], axis=1)
    curve = fit(pts, 8.0, frame=FRAME, parametrisation=parametrisation)
    assert len(curve.control_points) >= 4  # the fewest a closed cubic needs
    dense = curve.evaluate(np.linspace(0.0, curve.period, 400, endpoint=False))
    # Four to six control points on a unit circle: the least-squares curve stays
    # within the chord sagitta of a square, 1 - cos(pi/4) = 0.29, of the circle.
    assert np.abs(np.linalg.norm(dense[:, :2], axis=1) - 1.0).max() < 0.3


# ----------------------------------------------------------------------------- properties
@settings(max_examples=30, deadline=None, derandomize=True)
@given(seed=st.integers(0, 2**16), n=st.integers(4, 40), t=st.floats(-50, 50))
def test_closure_the_curve_is_periodic(seed, n, t):
    curve = ClosedCurve.from_control_points(polygon(n, seed))
    np.testing.assert_allclose(curve.evaluate(t + curve.period), curve.evaluate(t), atol=1e-10)
    np.testing.assert_allclose(curve.derivative(t + curve.period), curve.derivative(t), atol=1e-9)


@settings(max_examples=20, deadline=None, derandomize=True)
@given(
    seed=st.integers(0, 2**16),
    shift=st.tuples(st.floats(-100, 100), st.floats(-100, 100), st.floats(-100, 100)),
    angle=st.floats(0, 2 * np.pi),
)
def test_fit_commutes_with_rigid_motions(seed, shift, angle):
    pts = noisy_circle(200, 0.01, seed=seed)
    c, s = math.cos(angle), math.sin(angle)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    base = fit(pts, 8, frame=FRAME, centroid=np.zeros(3))
    moved = fit(pts @ rot.T + shift, 8, frame=FRAME, centroid=np.asarray(shift))
    np.testing.assert_allclose(
        moved.control_points,
        base.control_points @ rot.T + shift,
        atol=1e-9 * (1 + np.abs(shift).max()),
    )


# ----------------------------------------------------------------------------- precision
def test_catmull_rom_gram_stencil_is_exact():
    from fractions import Fraction

    from surface.catmull_rom import _gram_stencil

    # integrals of products of cubics with rational coefficients: the module notes' values
    want = [Fraction(1, 560), Fraction(-1, 28), Fraction(71, 560), Fraction(57, 70)]
    got = _gram_stencil()
    np.testing.assert_allclose(got, [float(w) for w in want + want[-2::-1]], rtol=1e-13)
    assert abs(got.sum() - 1.0) < 1e-13  # the basis is a partition of unity: Σ g_k = 1


@pytest.mark.parametrize("points,smoothing", [(640, 32.0), (640, 8.0), (300, 4.0)])
def test_precision_factor_predicts_the_fitted_curves_noise(points, smoothing):
    # noisy circles (random θ, radial noise σ): the fitted curve's RMS radial error over
    # its parameter against σ · precision_factor.  40 draws of about M/s independent
    # control-point errors each: the RMS's sampling error is ~1/sqrt(2 · 40 · M/s),
    # 2-4 %; uneven random spacing raises the variance a few % (module notes: 1.02-1.08)
    rng = np.random.default_rng(5)
    sigma, errors = 0.002, []
    for _ in range(40):
        theta = np.sort(rng.uniform(0.0, 2.0 * np.pi, points))
        radius = 1.0 + rng.normal(0.0, sigma, points)
        curve = fit(np.c_[radius * np.cos(theta), radius * np.sin(theta), np.zeros(points)],
                    smoothing)
        q = curve.evaluate(np.linspace(0.0, curve.period, 2000, endpoint=False))
        errors.append(np.hypot(q[:, 0], q[:, 1]) - 1.0)
    ratio = np.sqrt(np.mean(np.square(errors))) / (
        sigma * precision_factor(max(4, round(points / smoothing)), points))
    assert 0.93 < ratio < 1.15
    # the naive σ/√s overstates it: the fairness term damps the highest modes (ρ ≈ 0.73)
    assert precision_factor(max(4, round(points / smoothing)), points) < 0.9 / np.sqrt(smoothing)


def test_precision_factor_of_an_interpolating_curve_is_one():
    assert precision_factor(50, 50) == 1.0 and precision_factor(60, 50) == 1.0
    with pytest.raises(ValueError, match="controls >= 1"):
        precision_factor(0, 10)


def test_predict_sections_returns_the_fits_mirroring_the_rings():
    rng = np.random.default_rng(2)
    loops = []
    for k in range(3):
        section = circle_section(k, m=400)
        noisy = section.points + np.c_[rng.normal(0, 0.002, (400, 2)), np.zeros(400)]
        loops.append(organise(Section(section.height, noisy, section.origin, FRAME, k,
                                      np.arange(400)))[0])
    rings, fits = predict_sections([loops[0], [loops[1], loops[2]]], 12, smoothing="auto",
                                   fits=True)
    assert isinstance(fits[0], RingFit) and isinstance(fits[1], list) and len(fits[1]) == 2
    plain = predict_sections([loops[0], [loops[1], loops[2]]], 12, smoothing="auto")
    np.testing.assert_array_equal(rings[0], plain[0])  # the same rings as without fits
    np.testing.assert_array_equal(rings[1][1], plain[1][1])
    for fit_record, loop in zip([fits[0], *fits[1]], loops, strict=True):
        assert fit_record.smoothing == choose_smoothing(loop.points, loop.frame)  # GCV's
        assert fit_record.points == 400
        assert fit_record.controls == round(400 / fit_record.smoothing)
        assert fit_record.noise == loop.noise
        assert fit_record.precision == pytest.approx(
            loop.noise * precision_factor(fit_record.controls, 400), rel=1e-12)


# ----------------------------------------------------------------------------- gaps
def test_bridge_gaps_puts_points_on_the_chord_of_each_wide_gap():
    phi = np.linspace(0.0, 1.5 * np.pi, 91)  # three quarters of a circle, step h = 0.0524
    arc = np.c_[np.cos(phi), np.sin(phi), np.zeros(91)]
    out = bridge_gaps(arc, 0.5)
    h = float(np.linalg.norm(arc[1] - arc[0]))
    chord = math.sqrt(2.0)  # from (0, -1) back to (1, 0)
    assert len(out) == 91 + math.ceil(chord / h) - 1
    assert np.array_equal(out[:91], arc)  # the data first, in order, untouched
    inserted = out[91:]
    assert np.abs(inserted[:, 0] - inserted[:, 1] - 1.0).max() < 1e-12  # on x - y = 1
    steps = np.linalg.norm(np.diff(np.r_[out, out[:1]], axis=0), axis=1)
    assert steps.max() <= h * (1 + 1e-9)
    assert np.array_equal(bridge_gaps(arc, 2.0), arc)  # no gap that wide: the points


def test_an_open_arc_is_bridged_by_its_chord_not_a_bulge():
    """A quarter of a noisy unit circle unseen: the fairness term alone continues the
    arcs' curvature across the gap, far out; the bridged fit follows the chord."""
    rng = np.random.default_rng(1)
    phi = rng.uniform(0, 1.5 * np.pi, 600)
    pts = np.c_[np.cos(phi) + rng.normal(0, 0.005, 600), np.sin(phi) + rng.normal(0, 0.005, 600),
                np.zeros(600)]
    loop = organise(Section(0.0, pts, np.zeros(3), FRAME, 0, np.arange(600)))[0]
    assert not loop.closed and loop.bridge < math.sqrt(2.0)

    def gap_departure(lp) -> float:  # farthest point of the curve over the gap from the chord
        curve = fit_loop(lp, 8)
        dense = curve.evaluate(np.linspace(0, curve.period, 20_000))
        theta = np.mod(np.arctan2(dense[:, 1], dense[:, 0]), 2 * np.pi)
        over = dense[theta > 1.5 * np.pi + 0.05]
        return float(np.abs(over[:, 0] - over[:, 1] - 1.0).max() / math.sqrt(2.0))

    assert gap_departure(loop) < 0.02  # σ = 0.005: within a few σ of the chord
    assert gap_departure(replace(loop, bridge=math.inf)) > 0.3  # measured 0.73


def test_a_lone_loop_in_a_list_keeps_n():
    """Only a section of several loops scales them; a list of one is the section's only
    loop (the workspace's curves are lists) and keeps N / 2N."""
    big = organise(circle_section(0, m=400))[0]
    small = replace(big, points=0.25 * big.points, centroid=0.25 * big.centroid)
    rings = predict_sections([[big], [small]], 64, smoothing=4)
    assert [len(r) for entry in rings for r in entry] == [64, 128]


def test_interleaved_order_turns_the_cyclic_band_into_a_band():
    """Unknowns cyclically at most 3 apart sit at most 6 apart in the interleaved order
    (so the banded Cholesky of the least-squares fit sees every non-zero)."""
    from surface.cyclic_band import interleaved

    for n in range(7, 80):
        order = interleaved(n)
        assert np.array_equal(np.sort(order), np.arange(n))
        where = np.argsort(order)                 # each unknown's place in the order
        i, j = np.meshgrid(np.arange(n), np.arange(n))
        near = np.minimum((i - j) % n, (j - i) % n) <= 3
        assert np.abs(where[i] - where[j])[near].max() <= 6


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_least_squares_band_cholesky_is_the_sparse_lu(monkeypatch, seed):
    """The fit's control points by the banded Cholesky kernel equal those of the sparse
    LU it replaced (kept as the fallback for a system not positive definite), to rounding:
    noisy loops of 40-600 points at every smoothing level, points bunched with gaps."""
    import surface.catmull_rom as cr

    rng = np.random.default_rng(seed)
    worst = 0.0
    for _ in range(40):
        m = int(rng.integers(40, 600))
        th = np.sort(rng.uniform(0, 2 * np.pi, m) ** (1 + seed % 2) / (2 * np.pi) ** (seed % 2))
        pts = np.column_stack([np.cos(th) * (1 + 0.2 * np.sin(3 * th)), np.sin(th),
                               0.01 * th]) + rng.normal(0, 0.01, (m, 3))
        s = float(rng.choice([4.0, 5.66, 8.0, 11.3, 16.0]))
        n = max(4, min(m, int(round(m / s))))
        got, t = cr._least_squares(pts, n, s)
        with monkeypatch.context() as patch:
            patch.setattr(cr, "cholesky_cyclic_band", lambda *args: False)
            want, t_lu = cr._least_squares(pts, n, s)
        assert np.array_equal(t, t_lu)
        worst = max(worst, float(np.abs(got - want).max()))
    assert worst < 1e-12
