"""Precision control of matching.pair: adaptive patch size and the ``imprecise`` rejection.

A textured plane seen by the distorted convergent rig of ``test_pair`` (exact
correspondence), with the texture's contrast lowered on one half of the plane
(``y < 0``) in both views, 2 grey levels of noise and a gain/offset between views.
LSM's error there is noise-limited: σ ∝ σ_n / (contrast · sqrt(pixels)).
"""

from __future__ import annotations

import numpy as np
import pytest

from matching.lsm import Status
from matching.pair import IMPRECISE, adaptive_sides, default_max_patch, match_pair
from testkit.warps import sample, texture_coefficients
from tests.matching.test_pair import H, W, make_rig, plane_point, truth_right


def render(cam, coef, low_contrast, gain=1.0, offset=0.0, noise=2.0, seed=0):
    ys, xs = np.mgrid[0:H, 0:W].astype(np.float64)
    P = plane_point(cam, np.column_stack([xs.ravel(), ys.ravel()]))
    tex = sample(coef, 80 + 50 * P[:, 0], 80 + 50 * P[:, 1])
    contrast = np.where(P[:, 1] < 0.0, low_contrast, 1.0)
    img = (128.0 + contrast * (tex - 128.0)).reshape(H, W)
    return gain * img + offset + np.random.default_rng(seed).normal(0, noise, img.shape)


def pair_with_low_contrast(low_contrast):
    rig = make_rig()
    coef = texture_coefficients(160, blur=1.2, seed=9)
    left = render(rig.left, coef, low_contrast, seed=1)
    right = render(rig.right, coef, low_contrast, gain=1.1, offset=-8.0, seed=2)
    return rig, left, right


def low_half(rig, x_left):
    """Candidates whose 15x15 template lies wholly in the low-contrast half (y < 0)."""
    return plane_point(rig.left, x_left + [0.0, 8.0])[:, 1] < 0.0


def rms(values) -> float:
    return float(np.sqrt(np.mean(np.square(values))))


def test_default_max_patch_doubles_the_pixels_at_most():
    assert default_max_patch(15) == 21  # 441 <= 450 < 23² = 529
    assert default_max_patch(5) == 7
    for patch in (5, 7, 9, 11, 15, 21, 31):
        top = default_max_patch(patch)
        assert top % 2 == 1 and top**2 <= 2 * patch**2 < (top + 2) ** 2


@pytest.fixture(scope="module")
def moderate():
    """Contrast 0.3 on half the plane: textured, but σ ~ 3x the other half's."""
    rig, left, right = pair_with_low_contrast(0.3)
    # the adaptive patch alone: the uniqueness test (matching.uniqueness) rejects a
    # different ~10 % of each at this low SNR
    fixed = match_pair(left, right, rig, spacing=6, adaptive_patch=False, max_sigma_mad_k=None,
                       unique=False)
    adaptive = match_pair(left, right, rig, spacing=6, max_sigma_mad_k=None, unique=False)
    return rig, fixed, adaptive


def test_adaptive_patch_grows_where_the_precision_is_poor(moderate):
    rig, fixed, adaptive = moderate
    low = low_half(rig, adaptive.x_left)
    ok = adaptive.accepted
    assert (fixed.patch[fixed.accepted] == 15).all()
    # the low-contrast half gets the largest side (its σ at 15 is ~3x the median, a
    # 21 px patch only reaches ~15/21 of it); most of the textured half keeps 15
    assert np.median(adaptive.patch[ok & low]) == 21
    assert np.mean(adaptive.patch[ok & ~low] == 15) > 0.6
    # no coverage is lost to the growth (a grown window leaving the image falls back)
    assert ok.sum() >= 0.98 * fixed.accepted.sum()


def test_adaptive_patch_reduces_the_error_against_the_truth(moderate):
    rig, fixed, adaptive = moderate
    low_f = low_half(rig, fixed.x_left) & fixed.accepted
    low_a = low_half(rig, adaptive.x_left) & adaptive.accepted
    err_f = fixed.x_right[low_f] - truth_right(rig, fixed.x_left[low_f])
    err_a = adaptive.x_right[low_a] - truth_right(rig, adaptive.x_left[low_a])
    # noise-limited: σ ∝ 1/sqrt(pixels), so 2x the pixels gives 1/sqrt(2) = 0.71 of the
    # error; 0.85 leaves room for the RMS's own sampling error (~400 points: 4 %) and
    # for the model error a larger patch adds
    assert rms(err_a) < 0.85 * rms(err_f), (rms(err_a), rms(err_f))
    # the grown patches' σ is no less honest than the fixed patches' (at this low SNR
    # both under-report by ~1.3: the weak half's σ0 is near the noise floor)
    ratio = {}
    for name, m in (("fixed", fixed), ("adaptive", adaptive)):
        ok = m.accepted
        ratio[name] = rms(m.x_right[ok] - truth_right(rig, m.x_left[ok])) / rms(m.sigma[ok])
    assert ratio["adaptive"] < ratio["fixed"] + 0.05, ratio


def test_low_contrast_region_is_rejected_as_imprecise():
    """Contrast 0.15: most of that half is textureless; the rest matches with σ far above
    the population's and is rejected as ``imprecise``, so the accepted RMS against the
    truth stays at the textured half's noise-limited level."""
    rig, left, right = pair_with_low_contrast(0.15)
    m = match_pair(left, right, rig, spacing=6)
    low = low_half(rig, m.x_left)
    imprecise = m.status == IMPRECISE
    assert imprecise[low].sum() >= 20
    assert imprecise[~low].mean() < 0.05
    # every low-contrast candidate that got past the texture test is rejected
    seen = low & (m.status != Status.TEXTURELESS) & (m.status != 8)  # 8: no approximation
    assert not m.accepted[seen].any(), m.status_counts()
    assert m.status_counts()["imprecise"] == imprecise.sum()
    ok = m.accepted
    err = m.x_right[ok] - truth_right(rig, m.x_left[ok])
    # tolerance from the data's own noise: the reported σ (validated within ±25 %)
    assert rms(err) < 1.25 * rms(m.sigma[ok])
    unfiltered = match_pair(left, right, rig, spacing=6, max_sigma_mad_k=None)
    ok_u = unfiltered.accepted
    err_u = unfiltered.x_right[ok_u] - truth_right(rig, unfiltered.x_left[ok_u])
    assert rms(err) < 0.75 * rms(err_u), (rms(err), rms(err_u))


def test_adaptive_sides_rules():
    rig, left, _ = pair_with_low_contrast(0.3)
    pts = np.array([[60.0, 60.0], [160.0, 180.0], [3.0, 120.0], [160.0, 120.0],
                    [200.0, 60.0]])
    sigma = np.array([0.01, 0.05, 0.05, 0.02, 0.01])  # median of the accepted: 0.03
    accepted = np.array([True, True, True, False, True])
    sides = adaptive_sides(left, pts, sigma, accepted, 15)
    assert sides.dtype == np.int32 and sides.shape == (5,)
    assert sides[0] == 15  # better than the median: kept
    assert 15 < sides[1] <= 21  # worse: grown
    assert sides[2] == 15  # window leaves the image
    assert sides[3] == 15  # not accepted: kept
    with pytest.raises(ValueError, match="max_patch"):
        adaptive_sides(left, pts, sigma, accepted, 15, max_patch=16)
    with pytest.raises(ValueError, match="max_patch"):
        match_pair(left, left, rig, max_patch=13)
    with pytest.raises(ValueError, match="max_sigma_mad_k"):
        match_pair(left, left, rig, max_sigma_mad_k=-1.0)
