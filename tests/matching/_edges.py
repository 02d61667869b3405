"""Rendered rectified pairs with edges and exact truth.

Two fronto-parallel layers seen by a rectified pair: a *front* plane at disparity
``d_front`` covering the half-plane left of a straight line, in front of a *back* plane
at disparity ``d_back``.  A right-image pixel ``(x, y)`` sees the front at left
coordinates ``(x + d_front, y)`` when that point lies in the front's half-plane, else the
back at ``(x + d_back, y)`` (ray casting of two planes: the front wins).  The left image
is the same with zero disparity.  Each layer carries its own band-limited texture
(Gaussian-filtered noise, B-spline-interpolated, as in ``test_lsm.py``) or a uniform
grey level; pixels are box averages of ``supersample``² samples, each of which weighs
the two layers by the share of its cell the front covers (a sharp depth edge is
anti-aliased as a camera does, and its position is not quantised to the sample grid:
with hard samples a 0.1 px move of an edge between the views would not show at all),
then Gaussian noise is added.

Truth of a left pixel: the disparity of the layer its centre sees; a back pixel the
front hides in the right view (occluded) has none (NaN).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

_OVERSAMPLE = 4


def _texture(size: tuple[int, int], seed: int, blur: float = 1.5, contrast: float = 40.0):
    """B-spline coefficients of a band-limited texture 4x denser than the pixels."""
    rng = np.random.default_rng(seed)
    shape = (size[0] * _OVERSAMPLE, size[1] * _OVERSAMPLE)
    big = ndimage.gaussian_filter(rng.standard_normal(shape), blur * _OVERSAMPLE, mode="wrap")
    big = 128.0 + contrast * big / big.std()
    return ndimage.spline_filter(big, 3, mode="mirror")


def _sample(coef, x, y):
    return ndimage.map_coordinates(coef, [(y + 8.0) * _OVERSAMPLE, (x + 8.0) * _OVERSAMPLE],
                                   order=3, prefilter=False, mode="mirror")


@dataclass(frozen=True)
class LayeredPair:
    """A rendered pair and its truth.

    Attributes
    ----------
    left, right : (H, W) float64, grey levels.
    disparity : (H, W) float64, x_left - x_right of each left pixel centre, px (NaN where
        occluded in the right view).
    front : (H, W) bool, the left pixel centre sees the front layer.
    normal : (2,) float64, unit normal of the edge line (pointing into the back layer).
    offset : float, the line is ``normal @ (x, y) = offset``.
    """

    left: np.ndarray
    right: np.ndarray
    disparity: np.ndarray
    front: np.ndarray
    normal: np.ndarray
    offset: float

    def edge_distance(self, points: np.ndarray) -> np.ndarray:
        """(N,) signed distance of left points from the edge line, px (< 0: front side)."""
        return points @ self.normal - self.offset

    def truth(self, points: np.ndarray) -> np.ndarray:
        """(N, 2) right-image position of integer left ``points`` (NaN: occluded)."""
        xi = points.astype(int)
        d = self.disparity[xi[:, 1], xi[:, 0]]
        return np.column_stack([points[:, 0] - d, points[:, 1] + 0.0 * d])


def layered_pair(size=(120, 160), *, angle_deg: float = 0.0, edge_x: float = 80.3,
                 d_front: float = 6.4, d_back: float = 2.7, front: str = "texture",
                 front_level: float = 128.0, back: str = "texture",
                 noise: float = 2.0, supersample: int = 4, seed: int = 0) -> LayeredPair:
    """Render a rectified pair of a front plane before a back plane (module docstring).

    Parameters
    ----------
    size : (H, W)
        Image size, px.
    angle_deg : float
        Edge line's angle from the image's y axis (0: a vertical edge, across the
        epipolar lines), degrees; it passes through ``(edge_x, H/2)``.
    edge_x : float
        x of the edge at mid-height, px.
    d_front, d_back : float
        Disparities of the two layers, px (front > back: the front is nearer).
    front, back : {"texture", "uniform"}
        Each layer's albedo: its own band-limited texture or the grey ``front_level``
        (uniform back: 128).
    noise : float
        Gaussian noise σ, grey levels (independent in the two images).
    supersample : int
        Samples per pixel and axis of the box average.
    seed : int
    """
    h, w = size
    a = np.radians(angle_deg)
    normal = np.array([np.cos(a), -np.sin(a)])
    offset = float(normal @ [edge_x, h / 2.0])
    coef = {"front": _texture((h + 16, w + 16), seed + 1),
            "back": _texture((h + 16, w + 16), seed + 2)}
    kinds = {"front": front, "back": back}
    levels = {"front": front_level, "back": 128.0}

    def albedo(layer, x, y):
        if kinds[layer] == "uniform":
            return np.full(x.shape, levels[layer])
        return _sample(coef[layer], x, y)

    s = supersample
    sub = (np.arange(s) + 0.5) / s - 0.5
    ys, xs = np.mgrid[0:h * s, 0:w * s].astype(np.float64)
    xs = xs // s + sub[(np.arange(w * s) % s)][None, :]
    ys = ys // s + sub[(np.arange(h * s) % s)][:, None]

    def view(disparity_front, disparity_back):
        xf, xb = xs + disparity_front, xs + disparity_back
        # the share of each sample's 1/s x 1/s cell the front covers: the box integral of
        # the half-plane (exact for an axis-parallel edge, a linear ramp across the cell
        # otherwise), so that the edge is not quantised to the 1/s grid
        reach = 0.5 * np.abs(normal).sum() / s
        cover = np.clip(0.5 - (xf * normal[0] + ys * normal[1] - offset) / (2 * reach), 0, 1)
        img = cover * albedo("front", xf, ys) + (1 - cover) * albedo("back", xb, ys)
        return img.reshape(h, s, w, s).mean(axis=(1, 3))

    rng = np.random.default_rng(seed + 100)
    left = view(0.0, 0.0) + rng.normal(0.0, noise, (h, w))
    right = view(d_front, d_back) + rng.normal(0.0, noise, (h, w))
    py, px = np.mgrid[0:h, 0:w].astype(np.float64)
    is_front = px * normal[0] + py * normal[1] < offset
    # a back point is hidden in the right view when the front covers its right pixel
    hidden = ~is_front & ((px - d_back + d_front) * normal[0] + py * normal[1] < offset)
    disparity = np.where(is_front, d_front, np.where(hidden, np.nan, d_back))
    return LayeredPair(left, right, disparity, is_front, normal, offset)


def chessboard_pair(size: int = 160, square: int = 40, shift=(0.3, 0.0),
                    noise: float = 2.0, texture: float = 0.0, psf_px: float = 0.0,
                    seed: int = 12, supersample: int = 4):
    """A chessboard (60 / 180 grey levels) moved by ``shift`` (x, y) px between the views.

    Squares' edges are box-averaged like a camera's pixels, after a Gaussian optical
    blur of σ ``psf_px`` px (0: none, a step sharper than any lens gives);
    ``texture`` > 0 adds a band-limited texture of that standard deviation (grey
    levels) painted on the board.  Returns ``(left, right)``.
    """
    s = supersample
    sub = (np.arange(size * s) + 0.5) / s - 0.5
    xs, ys = np.meshgrid(sub, sub)
    coef = _texture((size + 16, size + 16), seed + 1, contrast=texture)

    def odd_share(t):
        """Share of each sample's cell [t - 1/2s, t + 1/2s] lying in odd squares (exact
        box integral: the edges are not quantised to the 1/s grid)."""
        def integral(u):  # ∫_0^u [floor(v / square) odd] dv
            period = 2.0 * square
            return (np.floor(u / period) * square
                    + np.clip(np.mod(u, period) - square, 0.0, square))
        return (integral(t + 0.5 / s) - integral(t - 0.5 / s)) * s

    def board(dx, dy):
        ox, oy = odd_share(xs - dx), odd_share(ys - dy)
        cell = ox * (1 - oy) + (1 - ox) * oy  # the cell's mean of the squares' parity
        paint = 60.0 + 120.0 * cell
        if texture > 0:
            paint = paint + _sample(coef, xs - dx, ys - dy) - 128.0
        if psf_px > 0:
            paint = ndimage.gaussian_filter(paint, psf_px * s, mode="nearest")
        return paint.reshape(size, s, size, s).mean(axis=(1, 3))

    rng = np.random.default_rng(seed)
    return (board(0.0, 0.0) + rng.normal(0.0, noise, (size, size)),
            board(*shift) + rng.normal(0.0, noise, (size, size)))
