r"""The working resolution of least-squares matching: from the object's size in the images.

LSM measures one point per ``spacing x spacing`` cell of a view.  A view in which the
object spans :math:`E` pixels (its extent, the longer side of the box its points fill)
gives about :math:`E / \text{spacing}` points across it; the surface stages need a few
hundred (sections, rings), not the thousand-odd a 12 MP phone photo gives at full size,
whose cost (patches, memory) grows with the square.  The working scale is

.. math::  s = \min\Big(1, \frac{\text{spacing}\cdot n_\text{across}}{E}\Big),

with :math:`n_\text{across}` the points wanted across the object (``points_across``).
Precision is not the limit at that scale: LSM's σ is ~0.03-0.2 px, a relative
precision of :math:`\sigma/E \approx 10^{-4}` of the object's size at
:math:`E \approx 1\,500` px, far below the distance between neighbouring points
(:math:`1/n_\text{across}`).  Views are then read downsampled (``cv2.INTER_AREA``) to
:math:`W' = \operatorname{round}(s W)`, :math:`H' = \operatorname{round}(s H)`, and
their cameras scaled with them (pixel centres at integer coordinates):

.. math::  x' = s_x (x + \tfrac12) - \tfrac12,\quad
           f_x' = s_x f_x,\quad c_x' = s_x (c_x + \tfrac12) - \tfrac12,

:math:`s_x = W'/W` (the same in y); lens distortion acts on normalised coordinates and is
unchanged.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from matching.cameras import Camera
from matching.validate import check_shape

__all__ = ["object_extent_px", "working_scale", "scale_camera", "scaled_size"]


def object_extent_px(cameras: Sequence[Camera], points=None, share: float = 0.9) -> float:
    """Median over the views of the object's extent in pixels.

    Parameters
    ----------
    cameras : sequence of Camera
    points : (N, 3) float64, optional
        Points on the object (e.g. SfM's sparse points).  None or fewer than 20 in a
        view: that view's extent is its image's longer side (the object fills it).
    share : float
        Each view's box holds this central share of the points it sees (the
        ``(1 - share) / 2`` quantiles on each side cut stray points).

    Returns
    -------
    float
        The median of the views' extents: the longer side of each box, pixels.
    """
    extents = []
    pts = None if points is None else check_shape(points, "(N, 3)", "points", dtype=np.float64)
    low, high = 50.0 * (1.0 - share), 50.0 * (1.0 + share)
    for cam in cameras:
        extent = float(max(cam.size))
        if pts is not None and len(pts):
            depth = cam.depth(pts)
            uv = cam.project(pts[depth > 0])
            inside = ((uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0)
                      & (uv[:, 1] < cam.height))
            if inside.sum() >= 20:
                lo, hi = np.percentile(uv[inside], [low, high], axis=0)
                extent = float(np.max(hi - lo))
        extents.append(extent)
    return float(np.median(extents)) if extents else 0.0


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
