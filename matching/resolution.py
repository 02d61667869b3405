r"""The working resolution of least-squares matching: from the object's size in the images.

The sections need points a spacing :math:`d` apart on the object (about
:math:`n_\text{across}` across it, ``points_across``: sections ~2 d apart, rings as
fine); LSM measures one point per ``spacing`` = :math:`k` px cell of the image it
matches (3 px, a fifth of its 15 px window).  The spacing :math:`d` projected into a
view at the object's depth is :math:`p = f d / z` px at full size, so the view is
matched at the scale where :math:`p` becomes :math:`k` px.  With :math:`E` the object's
extent in the images (the median over the views of the box holding its central 90 %,
:func:`object_extent_px`; :math:`E = n_\text{across}\, p`):

.. math::  s = \min\Big(1, \frac{k}{p}\Big) = \min\Big(1, \frac{k\, n_\text{across}}{E}\Big).

The sensor's pixel count does not enter: a 12 MP photo of an object 1 900 px across is
matched as one of 600 px.  Precision at that scale: LSM's σ of ~0.1 px is
:math:`\sigma / (k\, n_\text{across})` of the object's size per point, the demo ring's
own (its vase spans 513-563 px, 171-188 points across, and its surface meets 1e-4).
Views are then read downsampled (``cv2.INTER_AREA``) to
:math:`W' = \operatorname{round}(s W)`, :math:`H' = \operatorname{round}(s H)`, and
their cameras scaled with them (pixel centres at integer coordinates):

.. math::  x' = s_x (x + \tfrac12) - \tfrac12,\quad
           f_x' = s_x f_x,\quad c_x' = s_x (c_x + \tfrac12) - \tfrac12,

:math:`s_x = W'/W` (the same in y); lens distortion acts on normalised coordinates and is
unchanged.  Figures: ``docs/decisions/photo-folders.md``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import cv2
import numpy as np

from matching.cameras import Camera
from matching.masks import foreground_mask
from matching.validate import check_shape

__all__ = ["object_extent_px", "foreground_extent_px", "working_scale", "scale_camera",
           "scaled_size"]


def object_extent_px(cameras: Sequence[Camera], points=None, share: float = 0.9,
                     images=None, probe_views: int = 8) -> float:
    """Median over the views of the object's extent in pixels.

    Parameters
    ----------
    cameras : sequence of Camera
    points : (N, 3) float64, optional
        Points on the object (e.g. SfM's sparse points).
    share : float
        Each view's box holds this central share of the points it sees, or of its
        foreground's pixels (the ``(1 - share) / 2`` quantiles on each side cut strays).
    images : sequence of images, optional
        The views' images, for the views where fewer than 20 points fall: their
        automatic foreground on a uniform background (:func:`foreground_extent_px`, at
        most ``probe_views`` of them evenly spread, read once each), else (no points, no
        uniform background) the image's longer side (the object fills it).

    Returns
    -------
    float
        The median of the views' extents: the longer side of each box, pixels.
    """
    extents: list[float | None] = []
    pts = None if points is None else check_shape(points, "(N, 3)", "points", dtype=np.float64)
    low, high = 50.0 * (1.0 - share), 50.0 * (1.0 + share)
    for cam in cameras:
        extent = None
        if pts is not None and len(pts):
            depth = cam.depth(pts)
            uv = cam.project(pts[depth > 0])
            inside = ((uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0)
                      & (uv[:, 1] < cam.height))
            if inside.sum() >= 20:
                lo, hi = np.percentile(uv[inside], [low, high], axis=0)
                extent = float(np.max(hi - lo))
        extents.append(extent)
    missing = [v for v, e in enumerate(extents) if e is None]
    if missing and images is not None:
        probe = [missing[int(i)] for i in np.unique(np.linspace(
            0, len(missing) - 1, min(probe_views, len(missing))).round())]
        found = [e for e in (foreground_extent_px(images[v], share) for v in probe)
                 if e is not None]
        if found:
            fill = float(np.median(found))
            extents = [fill if e is None else e for e in extents]
    extents = [float(max(cam.size)) if e is None else e
               for e, cam in zip(extents, cameras, strict=True)]
    return float(np.median(extents)) if extents else 0.0


def foreground_extent_px(image, share: float = 0.9, probe_px: int = 1000) -> float | None:
    """The longer side (px, at the image's size) of the box holding the central ``share``
    of the image's automatic foreground (:func:`matching.masks.foreground_mask`, no
    dilation), found on a copy at most ``probe_px`` long; None: no uniform background."""
    image = np.asarray(image)
    h, w = image.shape[:2]
    ratio = min(1.0, probe_px / max(h, w))
    small = image if ratio == 1.0 else cv2.resize(
        image, (max(1, round(w * ratio)), max(1, round(h * ratio))),
        interpolation=cv2.INTER_AREA)
    mask = foreground_mask(small, margin_px=0)
    if mask is None or mask.sum() < 20:
        return None
    ys, xs = np.nonzero(mask)
    low, high = 50.0 * (1.0 - share), 50.0 * (1.0 + share)
    lo, hi = np.percentile(np.c_[xs, ys], [low, high], axis=0)
    return float(np.max(hi - lo)) / ratio


def working_scale(extent_px: float, spacing: float, points_across: int) -> float:
    """The scale ``s`` in (0, 1] at which a view is matched (module docstring).

    ``points_across`` 0 means full resolution (1.0).
    """
    if points_across < 0 or spacing <= 0:
        raise ValueError(f"points_across must be >= 0 and spacing > 0, got {points_across} "
                         f"and {spacing}")
    if points_across == 0 or extent_px <= 0:
        return 1.0
    return float(min(1.0, spacing * points_across / extent_px))


def scaled_size(size: tuple[int, int], scale: float) -> tuple[int, int]:
    """``(W', H')`` of an image of ``size = (W, H)`` read at ``scale`` (at least 1 px)."""
    return max(1, int(round(size[0] * scale))), max(1, int(round(size[1] * scale)))


def scale_camera(camera: Camera, scale: float) -> Camera:
    """The camera of its image resized to :func:`scaled_size` (module docstring)."""
    if scale == 1.0:
        return camera
    width, height = scaled_size(camera.size, scale)
    sx, sy = width / camera.width, height / camera.height
    K = np.array(camera.K, dtype=np.float64)
    K[0, :] *= sx
    K[1, :] *= sy
    K[0, 2] = sx * (camera.K[0, 2] + 0.5) - 0.5
    K[1, 2] = sy * (camera.K[1, 2] + 0.5) - 0.5
    return replace(camera, K=K, width=width, height=height)
