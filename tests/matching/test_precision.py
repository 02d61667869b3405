"""Tests of matching.precision: the variance factor from independent neighbouring windows
(their affine warps' predictions of the midpoint between them) and the robust factor of
χ² distances."""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy import ndimage

from matching.cameras import read_rig
from matching.lsm import lsm_match
from matching.pair import match_pair
from matching.precision import midpoint_variance_factor, variance_factor
from testkit.warps import (
    grid_points,
    sample,
    start_near,
    texture_coefficients,
    truth_of,
    warped_pair,
)


def _factor(f, g, truth_fn=truth_of, patch=15, size=200):
    pts = grid_points(size, 3)
    res = lsm_match(f, g, pts, start_near(truth_fn(pts)), patch=patch)
    vf = midpoint_variance_factor(pts, res.affine, res.affine_cov, res.accepted, patch=patch)
    return vf, res, pts


def _scaled_over_actual(vf, res, truth):
    ok = res.accepted
    actual = np.sqrt(np.mean(np.sum((res.position[ok] - truth[ok]) ** 2, axis=1)))
    scaled = np.sqrt(vf.factor * np.mean(np.trace(res.cov[ok], axis1=1, axis2=2)))
    return scaled / actual


def test_white_noise_gives_a_factor_of_one():
    """White noise on an exact affine warp: LSM's σ is right (test_lsm: within 5 %), so
    k² = 1; ~2900 windows, ~10⁵ pairs (each window in ~70): measured 0.89 (the noise-
    corrected covariances are a little pessimistic; match_pair never applies a factor
    below 1)."""
    f, g = warped_pair(size=200, noise=2.0, seed=8)
    vf, res, _ = _factor(f, g)
    assert len(vf.d2) > 20 * res.accepted.sum()
    assert 0.7 < vf.factor < 1.25


def test_curved_mapping_is_not_an_error():
    """A strongly curved mapping (quadratic terms of 2e-3 /px: 1.6 px off the affine over
    a 2.5-patch radius) with white noise: two windows' warps agree at their midpoint for
    any quadratic mapping (the trapezoidal rule), so the factor stays near 1 (measured
    1.25: the affine fit's texture-dependent error over the curved map is real) and the
    scaled σ matches the windows' scatter about their common curvature bias."""
    coef = texture_coefficients(200, seed=4)
    q = np.array([2e-3, -1e-3, 1.5e-3])
    centre = 100.0

    def forward(p):
        d = p - centre
        quad = q[0] * d[:, 0] ** 2 + q[1] * d[:, 0] * d[:, 1] + q[2] * d[:, 1] ** 2
        return p @ np.array([[1.05, 0.1], [-0.05, 0.95]]).T + [3.3, -2.2] + np.column_stack(
            [quad, 0.5 * quad])

    ys, xs = np.mgrid[0:200, 0:200].astype(np.float64)
    grid = np.column_stack([xs.ravel(), ys.ravel()])
    src = grid.copy()
    for _ in range(30):  # fixed point: forward(src) = grid
        src += grid - forward(src)
    rng = np.random.default_rng(5)
    f = sample(coef, xs, ys) + rng.normal(0.0, 2.0, xs.shape)
    g = sample(coef, src[:, 0], src[:, 1]).reshape(200, 200) + rng.normal(0.0, 2.0, xs.shape)
    vf, res, pts = _factor(f, g, truth_fn=forward)
    ok = res.accepted
    assert ok.mean() > 0.8  # the rest leave the image
    assert 0.75 < vf.factor < 1.5
    # the windows' scatter about their common curvature bias (<x²>(q_xx + q_yy), the same
    # for every window) is what the scaled σ must match
    err = res.position[ok] - forward(pts[ok])
    scatter = np.sqrt(np.mean(np.sum((err - err.mean(0)) ** 2, axis=1)))
    scaled = np.sqrt(vf.factor * np.mean(np.trace(res.cov[ok], axis1=1, axis2=2)))
    assert scaled / scatter == pytest.approx(1.0, rel=0.25)


def test_correlated_noise_is_found():
    """Noise low-passed by a 1 px Gaussian (as demosaicing does): fewer independent
    observations than pixels, so σ0²N⁻¹ is too small; the factor finds it, and the
    scaled σ matches the actual error to 25 %."""
    f, g = warped_pair(size=200, noise=0.0, seed=8)
    rng = np.random.default_rng(9)
    for img in (f, g):
        noise = ndimage.gaussian_filter(rng.normal(0.0, 1.0, img.shape), 1.0)
        img += 2.0 * noise / noise.std()
    vf, res, pts = _factor(f, g)
    assert vf.factor > 2.0
    assert _scaled_over_actual(vf, res, truth_of(pts)) == pytest.approx(1.0, rel=0.25)


def test_epipolar_constraint_rank_one_covariances():
    """A shift constrained to the rows (rectified pair): the shift covariance is rank 1
    but the midpoint's is not (the affine unknowns move it), so the factor is defined
    and about 1 for white noise on a pure row shift (measured 0.83)."""
    a = np.array([[1.0, 0.0], [0.0, 1.0]])
    b = np.array([-4.3, 0.0])
    f, g = warped_pair(size=200, A=a, b=b, noise=2.0, seed=11)
    pts = grid_points(200, 3)
    truth = pts + b
    res = lsm_match(f, g, pts, truth + [0.7, 0.0], patch=15, direction=(1.0, 0.0))
    shift_det = np.linalg.det(res.cov[res.accepted])
    assert np.all(np.abs(shift_det) < 1e-12)
    vf = midpoint_variance_factor(pts, res.affine, res.affine_cov, res.accepted, patch=15)
    assert 0.65 < vf.factor < 1.3


def test_rows_held_by_the_geometry_give_a_one_dimensional_factor():
    """rigid_across (every window pixel on its row): the midpoint covariances are rank 1
    (nothing varies across the rows), the factor is taken along the rows with 1 degree of
    freedom -- about 1 for white noise (measured 0.83; the 2-D test gave NaN here), and
    it grows with a noise added to the matches' x (2 σ_x: measured 1.55, the midpoint's
    variance being mostly the shape's, a1 and a2 over half a window)."""
    a = np.array([[1.0, 0.0], [0.0, 1.0]])
    b = np.array([-4.3, 0.0])
    f, g = warped_pair(size=200, A=a, b=b, noise=2.0, seed=11)
    pts = grid_points(200, 3)
    truth = pts + b
    res = lsm_match(f, g, pts, truth + [0.7, 0.0], patch=15, direction=(1.0, 0.0),
                    rigid_across=True)
    ok = res.accepted
    assert ok.mean() > 0.95
    np.testing.assert_array_equal(res.affine_cov[ok][:, [3, 4, 5], :], 0.0)
    vf = midpoint_variance_factor(pts, res.affine, res.affine_cov, ok, patch=15)
    assert 0.65 < vf.factor < 1.35
    rng = np.random.default_rng(3)
    sigma_x = np.sqrt(res.affine_cov[:, 0, 0])
    moved = res.affine.copy()
    moved[:, 0] += 2.0 * sigma_x * rng.standard_normal(len(pts))
    vf2 = midpoint_variance_factor(pts, moved, res.affine_cov, ok, patch=15)
    assert vf2.factor > 1.5 * vf.factor


def test_thinning_keeps_the_estimate():
    """Above ``max_windows`` the windows are thinned on a grid: the factor stays within
    the median's own scatter."""
    f, g = warped_pair(size=200, noise=2.0, seed=8)
    vf, res, pts = _factor(f, g)
    thin = midpoint_variance_factor(pts, res.affine, res.affine_cov, res.accepted, patch=15,
                                    max_windows=600)
    assert len(np.unique(thin.pairs)) <= 600
    assert thin.factor == pytest.approx(vf.factor, rel=0.25)


@pytest.fixture(scope="module")
def correlated_vase(tmp_path_factory):
    """The default vase pair at 320x240 with its noise low-passed by a 1 px Gaussian."""
    from pipeline import scenes

    recipe = scenes.load_recipe(scenes.DEFAULT_RECIPE, overrides={
        "cameras.width": 320, "cameras.height": 240, "cameras.focal_px": 416.0,
        "noise.correlation_px": 1.0})
    out = tmp_path_factory.mktemp("correlated") / "scene"
    scenes.render_scene(recipe, out, progress=False)
    return out


def _pair_ratio(folder, **options):
    rig = read_rig(folder / "cameras.yml")
    left, right = (cv2.imread(str(folder / "images" / f"view_0{i}.png"), cv2.IMREAD_GRAYSCALE)
                   for i in (0, 1))
    corr = np.load(folder / "truth" / "correspondence.npy")
    m = match_pair(left, right, rig, spacing=4, **options)
    xi = m.x_left[m.accepted].astype(int)
    err = m.x_right[m.accepted] - corr[xi[:, 1], xi[:, 0]]
    good = np.isfinite(err).all(1) & (np.linalg.norm(err, axis=1) < 1.0)
    actual = np.sqrt(np.mean(err[good] ** 2))
    return actual / np.sqrt(np.mean(m.sigma[m.accepted][good] ** 2)), m


def test_rendered_pair_with_correlated_noise(correlated_vase):
    """Rendered vase with demosaicing-like correlated noise: σ0²N⁻¹ is 3x optimistic
    (measured 3.0); match_pair's default variance factor (~9) brings the actual / reported
    ratio to 1 within 25 % (measured 0.98 over ~1100 matches: the ratio's own scatter is
    a few %, the factor's median ~5 %)."""
    plain, _ = _pair_ratio(correlated_vase, sigma_factor=False)
    honest, m = _pair_ratio(correlated_vase)
    assert plain > 2.0
    assert m.sigma_factor > 4.0
    assert honest == pytest.approx(1.0, rel=0.25)


@pytest.fixture(scope="module")
def specular_vase(tmp_path_factory):
    """The default vase pair at 320x240 with a Blinn-Phong highlight (k_s 0.4, p 30)."""
    from pipeline import scenes

    recipe = scenes.load_recipe(scenes.DEFAULT_RECIPE, overrides={
        "cameras.width": 320, "cameras.height": 240, "cameras.focal_px": 416.0,
        "lighting.specular": 0.4, "lighting.shininess": 30.0})
    out = tmp_path_factory.mktemp("specular") / "scene"
    scenes.render_scene(recipe, out, progress=False)
    return out


def test_rendered_pair_with_a_specular_highlight(specular_vase):
    """A highlight that moves between the views is outside LSM's radiometric model
    (offset + gain per window): where it lies the matches err 0.17-0.27 px and 6-11 %
    of the axis errors exceed 3σ (against 0.7 % elsewhere).  match_pair's variance
    factor grows (k² ~7 against ~2 without the highlight) but is one for the image, so
    σ stays optimistic by 20-30 % overall (measured 1.23-1.30 over the matches within
    1 px, 2.9 % of the axis errors beyond 3σ; without the highlight 0.94 and 1.3 %).
    Asserted as a bound that must not get worse: actual / reported in [0.8, 1.45],
    under 4 % beyond 3σ, under 0.6 % of the accepted matches beyond 1 px (measured 3 of
    1113-1123 in two runs, the largest 1.45-1.7 px: blunders in the highlight)."""
    ratio, m = _pair_ratio(specular_vase)
    corr = np.load(specular_vase / "truth" / "correspondence.npy")
    xi = m.x_left[m.accepted].astype(int)
    err = m.x_right[m.accepted] - corr[xi[:, 1], xi[:, 0]]
    seen = np.isfinite(err).all(1)
    sig = np.sqrt(np.stack([m.cov[m.accepted, 0, 0], m.cov[m.accepted, 1, 1]], 1))[seen]
    beyond = np.mean(np.abs(err[seen]) > 3.0 * sig)
    assert 0.8 < ratio < 1.45
    assert beyond < 0.04
    assert np.mean(np.linalg.norm(err[seen], axis=1) > 1.0) < 0.006


def _graffiti(folder: Path):
    sys.path.append(str(Path(__file__).resolve().parents[2] / "benchmarks"))
    from _real_matching import _apply, _grey, _homography, _jacobian, smooth_mapping

    from matching.lsm import prepare_image
    from matching.seeds import select_points

    f, g = _grey(folder / "graf1.png"), _grey(folder / "graf3.png")
    hom = _homography(folder / "H1to3p.xml")
    patch = 21
    fp, gp = prepare_image(f), prepare_image(g)
    cand = select_points(f, spacing=12, patch=patch, noise=fp.noise)
    truth = _apply(hom, cand.points)
    h, w = g.shape
    sel = ((truth > patch) & (truth < [w - patch, h - patch])).all(1) & cand.textured
    pts, truth = cand.points[sel], truth[sel]
    jac = _jacobian(hom, pts)
    init = np.column_stack([truth[:, 0], jac[:, 0, 0], jac[:, 0, 1], truth[:, 1],
                            jac[:, 1, 0], jac[:, 1, 1], np.zeros(len(pts)), np.ones(len(pts))])
    res = lsm_match(fp, gp, pts, truth, patch=patch, initial=init)
    smooth = smooth_mapping(pts[res.accepted], res.position[res.accepted])
    return fp, gp, pts, res, smooth(pts)


def test_graffiti_factor(real_data_dir):
    """Real wall 40 degrees apart (21x21, ~2400 matches, ~10⁴ pairs): k² ~5.8, above the
    forward-backward loops' lower bound (~3.0: the loops share the pixels' noise).  The
    core of the residuals to the smooth mapping (median |e| against its Gaussian value)
    is then within 1.6x of σ (measured 1.45; 3.5 without the factor); their RMS 1.8x
    (4.4 without), the rest a component common to neighbouring windows (module
    docstring: relief or a shared bias, not separable with two images)."""
    from matching.forward_backward import forward_backward

    fp, gp, pts, res, smooth = _graffiti(real_data_dir / "graffiti")
    ok = res.accepted
    vf = midpoint_variance_factor(pts, res.affine, res.affine_cov, ok, patch=21)
    fb = forward_backward(fp, gp, pts, res, patch=21)
    assert fb.variance_factor < vf.factor < 12.0
    e = np.linalg.norm(res.position - smooth, axis=1)
    inl = ok & (e < 2.0)
    core = np.median(e[inl] / res.sigma[inl]) / np.sqrt(2 * np.log(2))
    rms = np.sqrt(np.mean((res.position - smooth)[inl] ** 2) / np.mean(res.sigma[inl] ** 2))
    assert core > 2.5 and rms > 3.5  # the reported σ alone: far too small
    assert 0.67 < core / np.sqrt(vf.factor) < 1.6
    assert rms / np.sqrt(vf.factor) < 2.1
    # the excess lies along the epipolar lines, correlated between independent windows
    # (plane + parallax: what a relief of the wall does); across them -- where no relief
    # acts -- the residual is within 1.5x of σk and uncorrelated (measured 1.30 / 0.03,
    # along 2.73 / 0.18)
    split = _parallax_split()(pts[inl], res.position[inl], (res.position - smooth)[inl],
                              res.cov[inl], vf.factor, 21)
    assert split["across_over_sigma_k"] < 1.5
    assert split["along_over_sigma_k"] > 2.0
    assert abs(split["across_neighbour_correlation"]) < 0.08
    assert split["along_neighbour_correlation"] > 0.1


def _parallax_split():
    sys.path.append(str(Path(__file__).resolve().parents[2] / "benchmarks"))
    from _real_matching import parallax_split

    return parallax_split


def test_parallax_split_recovers_relief_and_noise():
    """Plane + parallax with a known epipole: a relief smooth over ~15 px (0.15 px RMS)
    moves points along the epipolar lines, white noise (0.1 px per axis, reported
    exactly with k² = 4) both ways.  Across the lines only the noise is left: RMS 0.1,
    ratio to σk 1 (7 500 points: its scatter ~1 %; the fitted epipole leaks little of
    the relief across), uncorrelated between windows 21-31 px apart; along them the
    relief's correlation at that distance remains."""
    split = _parallax_split()
    rng = np.random.default_rng(5)
    ys, xs = np.mgrid[0:300:4, 0:400:4]
    pts = np.column_stack([xs.ravel(), ys.ravel()]).astype(np.float64)
    epipole = np.array([-3000.0, -1000.0])
    toward = epipole - pts
    toward /= np.linalg.norm(toward, axis=1)[:, None]
    relief = ndimage.gaussian_filter(rng.normal(size=(300, 400)), 15.0)[
        pts[:, 1].astype(int), pts[:, 0].astype(int)]
    relief *= 0.15 / np.sqrt(np.mean(relief**2))
    noise = rng.normal(0.0, 0.1, pts.shape)
    residual = relief[:, None] * toward + noise
    cov = np.broadcast_to(np.eye(2) * 0.01 / 4.0, (len(pts), 2, 2))
    out = split(pts, pts, residual, cov, 4.0, 21)
    assert abs(np.dot(out["epipole_direction_median"], np.median(toward, axis=0))) > 0.995
    assert out["across_rms_px"] == pytest.approx(0.1, rel=0.05)
    assert out["across_over_sigma_k"] == pytest.approx(1.0, rel=0.05)
    assert out["along_rms_px"] == pytest.approx(np.hypot(0.15, 0.1), rel=0.1)
    assert abs(out["across_neighbour_correlation"]) < 0.05
    assert out["along_neighbour_correlation"] > 0.15  # 0.26-0.43 over seeds 5-8


def test_robust_factor_of_chi2_distances():
    """median(d²) / median(χ²_dof), never below ``at_least``; too few values: ``at_least``."""
    rng = np.random.default_rng(3)
    d2 = 4.0 * np.sum(rng.normal(size=(20000, 2)) ** 2, axis=1)
    assert variance_factor(d2) == pytest.approx(4.0, rel=0.05)
    assert variance_factor(d2 / 16.0) == 1.0
    assert variance_factor(d2 / 16.0, at_least=0.0) == pytest.approx(0.25, rel=0.05)
    assert variance_factor(d2[:10]) == 1.0
    d1 = 2.0 * rng.normal(size=20000) ** 2
    assert variance_factor(d1, dof=1) == pytest.approx(2.0, rel=0.05)


def test_bad_arguments():
    pts = np.zeros((5, 2))
    with pytest.raises(ValueError, match="same length"):
        midpoint_variance_factor(pts, np.zeros((3, 6)), np.zeros((5, 6, 6)))
    with pytest.raises(ValueError, match="patch"):
        midpoint_variance_factor(pts, np.zeros((5, 6)), np.zeros((5, 6, 6)), patch=0)
    few = midpoint_variance_factor(pts, np.zeros((5, 6)), np.zeros((5, 6, 6)))
    assert np.isnan(few.factor)


def test_class_factors_keep_two_populations_apart():
    """White noise on the left half of the images, 1-px correlated noise on the right:
    one pooled factor is wrong for both halves, one per class is right for each (left
    k² about 1 -- never below 1 --, right > 2 with the scaled σ within 25 % of the
    actual error)."""
    from matching.precision import class_variance_factors

    f, g = warped_pair(size=200, noise=0.0, seed=8)
    rng = np.random.default_rng(9)
    for img in (f, g):
        white = rng.normal(0.0, 2.0, img.shape)
        corr = ndimage.gaussian_filter(rng.normal(0.0, 1.0, img.shape), 1.0)
        img += np.where(np.arange(img.shape[1])[None, :] < 100, white, 2.0 * corr / corr.std())
    pts = grid_points(200, 3)
    res = lsm_match(f, g, pts, start_near(truth_of(pts)), patch=15)
    # windows straddling the boundary (x within half a patch of 100) belong to neither
    left, right = pts[:, 0] < 100 - 8, pts[:, 0] > 100 + 8
    valid = res.accepted & (left | right)
    per_point, factors = class_variance_factors(pts, res.affine, res.affine_cov, valid,
                                                right.astype(np.int64), patch=15)
    pooled = midpoint_variance_factor(pts, res.affine, res.affine_cov, valid, patch=15).factor
    assert factors[0] == pytest.approx(1.0, abs=0.3)
    assert factors[1] > 2.0
    assert factors[0] < pooled < factors[1]
    np.testing.assert_array_equal(per_point, factors[right.astype(int)])
    sel = valid & right
    err = res.position[sel] - truth_of(pts[sel])
    actual = np.sqrt(np.mean(np.sum(err**2, axis=1)))
    scaled = np.sqrt(factors[1] * np.mean(np.trace(res.cov[sel], axis1=1, axis2=2)))
    assert scaled / actual == pytest.approx(1.0, rel=0.25)
