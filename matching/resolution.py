r"""The working resolution of least-squares matching: from what is asked of the data.

LSM measures one point per ``spacing`` = :math:`k` px cell of the image it matches
(3 px, a fifth of its 15 px window), each to :math:`\sigma_\text{LSM}` ~0.1 px
(:data:`SIGMA_LSM_PX`).  With :math:`E` the object's extent in the images (the median
over the views of the box holding its central 90 %, :func:`object_extent_px`), a view
read at scale :math:`s` gives :math:`s E / k` points across the object, each with a
σ of :math:`\sigma_\text{LSM} / (s E)` of its extent.  So each request is a scale
(:func:`requested_scale`; the finest wins, never above full size, none: full size):

- a point's precision :math:`e` (share of the object's extent, ``acquire.precision``):
  :math:`s = \sigma_\text{LSM} / (e E)`;
- :math:`N` sections (``sections.count``): points half a section apart (the sections'
  own rule), :math:`2N` across: :math:`s = 2 N k / E`;
- a section spacing :math:`\Delta` (``sections.spacing``, scene units): :math:`\Delta/2`
  at the object's depth :math:`z` (:func:`object_depths`) is :math:`p = f \Delta / (2 z)`
  px at full size: :math:`s = k / p` (median over the views).

The sensor's pixel count does not enter: a 12 MP photo of an object 1 900 px across is
matched as one of 600 px.  The default precision 1.65e-4 is the demo ring's own (its
vase spans 513-563 px, under :math:`0.1 / 1.65\times10^{-4}` = 606 px: full size).
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

__all__ = ["object_extent_px", "foreground_extent_px", "working_scale", "requested_scale",
           "object_depths", "scale_camera", "scaled_size", "SIGMA_LSM_PX"]

#: LSM's standard deviation of a matched point's image position on textured images, px
#: (the temple's 0.10-0.37 px at 15 px windows, the rendered vase's 0.03-0.09 px:
#: docs/decisions/stereo-matching.md): what turns a precision asked into pixels.
SIGMA_LSM_PX = 0.1


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


def requested_scale(cameras: Sequence[Camera], extent_px: float, spacing: float,
                    precision: float = 0.0, section_count: int = 0,
                    section_spacing: float = 0.0, points=None) -> tuple[float, str]:
    """The working scale the request needs, and what set it.

    Each request asks a density; the finest one (the largest scale) wins, never above full
    size (1.0); none (every argument 0) is full size.

    - ``precision`` (a point's σ as a share of the object's extent ``extent_px``): LSM
      measures a point to :data:`SIGMA_LSM_PX` of the image it matches, so the object
      must span ``SIGMA_LSM_PX / precision`` px: ``s = SIGMA_LSM_PX / (precision E)``.
    - ``section_count`` ``N`` sections over the object: points half a section apart
      (the sections' own rule, spacing = 2 point spacings), ``2 N`` across it at one
      per ``spacing`` px cell: ``s = 2 N spacing / E``.
    - ``section_spacing`` ``Δ`` in scene units: ``Δ / 2`` projected into each view at
      the object's depth (:func:`object_depths`) is ``p = f Δ / (2 z)`` px at full
      size; ``s = spacing / p`` (the median over the views).
    """
    if spacing <= 0 or precision < 0 or section_count < 0 or section_spacing < 0:
        raise ValueError(f"spacing must be > 0 and precision, section count and spacing >= 0, "
                         f"got {spacing}, {precision}, {section_count}, {section_spacing}")
    needs = []
    if precision > 0 and extent_px > 0:
        needs.append((SIGMA_LSM_PX / (precision * extent_px), f"precision {precision:g}"))
    if section_count > 0 and extent_px > 0:
        needs.append((2.0 * section_count * spacing / extent_px,
                      f"{section_count} sections: {2 * section_count} points across"))
    if section_spacing > 0:
        depths = object_depths(cameras, points)
        if depths is not None:
            focal = np.array([0.5 * (c.K[0, 0] + c.K[1, 1]) for c in cameras])
            p = float(np.median(focal * 0.5 * section_spacing / depths))
            needs.append((spacing / p, f"section spacing {section_spacing:g}: "
                                       f"{p:.3g} px a point at full size"))
    if not needs:
        return 1.0, "full resolution (no precision or section spacing asked)"
    scale, why = max(needs)
    return float(min(1.0, scale)), why


def object_depths(cameras: Sequence[Camera], points=None) -> np.ndarray | None:
    """Each view's depth to the object: the median depth of the ``points`` in front of it
    (at least 20), else of the point nearest all the optical axes (least squares: where
    a ring or a path of views looks); None when the axes are parallel and no view sees
    enough points."""
    pts = None if points is None else check_shape(points, "(N, 3)", "points", dtype=np.float64)
    centres = np.array([c.center for c in cameras], dtype=np.float64)
    axes = np.array([c.R[2] for c in cameras], dtype=np.float64)
    # sum over views of (I - a a^T)(x - c) = 0
    proj = np.eye(3)[None] - axes[:, :, None] * axes[:, None, :]
    normal = proj.sum(axis=0)
    meet = None
    if np.linalg.cond(normal) < 1e8:
        meet = np.linalg.solve(normal, np.einsum("nij,nj->i", proj, centres))
    depths = []
    for cam in cameras:
        z = None if pts is None or not len(pts) else cam.depth(pts)
        if z is not None and (z > 0).sum() >= 20:
            depths.append(float(np.median(z[z > 0])))
        elif meet is not None and float(cam.depth(meet[None])[0]) > 0:
            depths.append(float(cam.depth(meet[None])[0]))
        else:
            return None
    return np.array(depths)


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
