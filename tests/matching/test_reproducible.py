"""The distance transforms the acquisition ranks candidates and thresholds points by are
exact, so the same photographs give the same cloud on every run.

OpenCV's precise distance transform (float32) returned last-bit differences on the same
input from one call to the next at a few cells; ``pair_densify._fill_deficit`` ranks candidates by
those distances, so ties swapped and the multi-view cloud differed between runs (one pair
of the small ring: 136 of 2 401 points, up to 0.73 scene units).  Both users now take
scipy's exact float64 transform.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from matching.masks import signed_distance
from matching.pair_densify import _fill_deficit


def _exact(mask: np.ndarray) -> np.ndarray:
    """Brute force: per pixel, the distance to the nearest False pixel (integer squares)."""
    ys, xs = np.nonzero(~mask)
    yy, xx = np.mgrid[:mask.shape[0], :mask.shape[1]]
    d2 = ((yy[..., None] - ys) ** 2 + (xx[..., None] - xs) ** 2).min(axis=-1)
    return np.sqrt(d2.astype(np.float64))


def test_signed_distance_is_the_exact_euclidean_distance():
    rng = np.random.default_rng(3)
    mask = ndimage.binary_opening(rng.random((40, 50)) > 0.35, iterations=2)
    got = signed_distance(mask)
    want = np.where(mask, 0.5 - _exact(mask), _exact(~mask) - 0.5).astype(np.float32)
    assert np.array_equal(got, want)


def test_fill_deficit_gives_the_same_choice_on_every_call():
    deficit = np.zeros((9, 9), bool)
    deficit[4, 4] = True
    labels = np.ones((9, 9), np.int32)
    # four candidates whose corner cells lie at the same exact distances from the hole
    # (mean 1.66257 cells each): the tie is broken by texture, then by order
    base = np.array([[2, 3], [5, 3], [3, 2], [3, 5]])
    corners = np.stack([base + d for d in ([0, 0], [1, 0], [0, 1], [1, 1])], 1)
    texture = np.array([1.0, 3.0, 2.0, 3.0])
    first = _fill_deficit(corners, texture, deficit, labels)
    assert np.flatnonzero(first).tolist() == [1]
    assert all(np.array_equal(first, _fill_deficit(corners, texture, deficit, labels))
               for _ in range(20))
