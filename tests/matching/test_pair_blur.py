"""The epipolar pass's blur balance: the sharper rectified image is found and smoothed by
the variance that equalises the two, where it differs (synthetic blocks, known blur)."""

from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from matching.lsm import prepare_image
from matching.pair_epipolar import _blur_balance, _smoothed

SHIFT = 6.0  # disparity, px


def _blocks(rng, shape, block=7):
    small = rng.uniform(0, 200, (shape[0] // block + 2, shape[1] // block + 2))
    big = cv2.resize(small, None, fx=block, fy=block, interpolation=cv2.INTER_NEAREST)
    return big[: shape[0], : shape[1]].astype(np.float64)


def _windows(left, right, spacing=9, side=15):
    ys, xs = np.mgrid[20:left.shape[0] - 20:spacing, 30:left.shape[1] - 20:spacing]
    centre = np.column_stack([xs.ravel(), ys.ravel()]).astype(np.float64)
    init = np.zeros((len(centre), 8))
    init[:, 0], init[:, 3] = centre[:, 0] - SHIFT, centre[:, 1]
    init[:, 1], init[:, 5], init[:, 7] = 1.0, 1.0, 1.0
    n = len(centre)
    return SimpleNamespace(ok=np.arange(n), from_2d=np.ones(n, bool), centre_r=centre,
                           init=init, fprep=prepare_image(left), gprep=prepare_image(right)), \
        np.full(n, side)


@pytest.mark.parametrize("extra", [0.3, 0.5])
def test_blur_balance_smooths_the_sharper_image_by_the_difference(extra):
    rng = np.random.default_rng(3)
    scene = _blocks(rng, (200, 320))
    left = cv2.GaussianBlur(scene, (0, 0), 1.0)
    # the right camera blurs more (variance 1 + extra); the right image is the scene
    # shifted SHIFT px left (x_right = x_left - SHIFT)
    right = cv2.GaussianBlur(scene, (0, 0), float(np.sqrt(1.0 + extra)))
    right = np.roll(right, -int(SHIFT), axis=1)
    right += rng.normal(0, 0.5, right.shape)
    left = left + rng.normal(0, 0.5, left.shape)
    w, sides = _windows(left, right)
    fields = _blur_balance(w, sides)
    assert fields is not None
    left_var, right_var = fields[2]
    # the template (left) is smoothed by the difference; the right image is not
    assert right_var == 0.0
    assert abs(left_var - extra) < 0.1 * extra + 0.03, left_var
    # and matched as equal: the smoothed left image's blur measured again is the right's
    w.fprep = _smoothed(w.fprep, fields[0], "spline")
    again = _blur_balance(w, sides)
    assert again is None or max(again[2]) < 0.25 * extra, again[2]


def test_blur_balance_follows_a_difference_that_varies_across_the_image():
    rng = np.random.default_rng(4)
    scene = _blocks(rng, (200, 400))
    left = cv2.GaussianBlur(scene, (0, 0), 1.0)
    sharp = cv2.GaussianBlur(scene, (0, 0), 1.0)
    blurry = cv2.GaussianBlur(scene, (0, 0), float(np.sqrt(1.4)))
    right = np.where(np.arange(400)[None, :] < 200, sharp, blurry)  # scene columns
    right = np.roll(right, -int(SHIFT), axis=1)
    w, sides = _windows(left, right)
    fields = _blur_balance(w, sides)
    left_field, right_field = fields[0], fields[1]
    assert np.median(left_field[:, 20:150]) < 0.05          # equal blur there
    assert abs(np.median(left_field[:, 260:380]) - 0.4) < 0.08  # right camera blurrier
    assert np.max(right_field) < 0.05
