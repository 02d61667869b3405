"""Synthetic affine-warped image pairs with exact truth, for the LSM tests and benchmarks.

The texture is band-limited Gaussian noise generated at 4x the pixel density and
resampled with a cubic B-spline for both images, so the right image is the left one
seen through a known affine map with no interpolation error above ~1e-4 px
(``cv2.warpAffine`` quantises sub-pixel positions to 1/32 px, which would be a truth
error of ~0.01 px).  Images are ``(size, size)`` float64 grey levels; points ``(N, 2)``
pixel coordinates ``(x, y)``.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

OVERSAMPLE = 4
A_TRUE = np.array([[1.03, 0.04], [-0.02, 0.97]])
B_TRUE = np.array([4.3, -2.6])
GAIN, OFFSET = 1.15, -9.0  # f = OFFSET + GAIN * g


def texture_coefficients(size: int, blur: float = 1.5, contrast: float = 40.0, seed: int = 0):
    """B-spline coefficients of a band-limited texture sampled 4x denser than the pixels."""
    rng = np.random.default_rng(seed)
    big = ndimage.gaussian_filter(rng.standard_normal((size * OVERSAMPLE,) * 2),
                                  blur * OVERSAMPLE, mode="wrap")
    big = 128.0 + contrast * big / big.std()
    return ndimage.spline_filter(big, 3, mode="mirror")


def sample(coef, x, y):
    return ndimage.map_coordinates(coef, [y * OVERSAMPLE, x * OVERSAMPLE], order=3,
                                   prefilter=False, mode="mirror")


def warped_pair(size=160, A=A_TRUE, b=B_TRUE, gain=GAIN, offset=OFFSET, noise=0.0, seed=0):
    """Left f and right g with f(x) = offset + gain * g(A x + b), plus Gaussian noise."""
    coef = texture_coefficients(size, seed=seed)
    ys, xs = np.mgrid[0:size, 0:size].astype(np.float64)
    f = sample(coef, xs, ys)
    src = np.linalg.solve(A, np.stack([xs.ravel() - b[0], ys.ravel() - b[1]]))
    g = (sample(coef, src[0], src[1]).reshape(size, size) - offset) / gain
    rng = np.random.default_rng(seed + 100)
    return f + noise * rng.standard_normal(f.shape), g + noise * rng.standard_normal(g.shape)


def grid_points(size, step, margin=20):
    ys, xs = np.mgrid[margin:size - margin:step, margin:size - margin:step]
    return np.column_stack([xs.ravel(), ys.ravel()]).astype(np.float64)


def truth_of(points, A=A_TRUE, b=B_TRUE):
    return points @ A.T + b


def start_near(truth, spread=1.0, seed=1):
    return truth + np.random.default_rng(seed).uniform(-spread, spread, truth.shape)
