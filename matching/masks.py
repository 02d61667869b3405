r"""Object masks: COLMAP-style mask files, an automatic foreground, the visual hull.

**Mask files.**  As COLMAP takes them: ``masks/NAME.png`` beside the images (``NAME``
the image's file name, e.g. ``masks/img01.jpg.png``; ``masks/img01.png`` is accepted
too), one grey or colour image of the image's size, **0 = ignore** (background),
anything else = object.

**Automatic foreground** for a uniform background, dark or light
(:func:`foreground_mask`): the background's grey levels from the image border (a frame
3 % of the shorter side, blurred by σ = 1.5 px), its median :math:`m` and :math:`t`, the
median over the four sides of the 99.9th percentile of :math:`|g - m|`; a pixel is
object where :math:`|g - m| > t`.  No mask (``None``) unless the background is uniform
(three sides' medians within :math:`t` of :math:`m`, :math:`t` below half the image's
grey range).  Small components dropped, holes kept, dilated by ``margin_px``.

**Visual hull** (Laurentini 1994 [1]_): a point is kept when, in every view where it
projects inside the image, it falls on the view's object mask (:func:`inside_masks`).

**Silhouette consistency** (:func:`near_foreground`): a point is rejected when its
signed distance from a view's undilated foreground exceeds :math:`\sqrt2/2 + q\,\sigma_k`
px (the raster's bound plus :math:`q` times its own σ in the view, :math:`\sigma_k =
\sigma f_k / z_k`; :math:`q` = 3.29 at 0.999).

Why each rule is as it is (the thresholds' derivations, the temple ring's figures):
``docs/method/acquire.md``, *Object masks*.

References
----------
.. [1] A. Laurentini, "The visual hull concept for silhouette-based image understanding",
   IEEE TPAMI 16(2), 150-162 (1994).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np
from scipy import ndimage

from matching.validate import check_shape

__all__ = ["mask_path", "read_mask", "foreground_mask", "inside_masks", "signed_distance",
           "near_foreground"]

#: Border frame used for the background statistics, share of the shorter image side.
_BORDER_SHARE = 0.03
#: Quantile of the border's deviations that bounds the background.
_BACKGROUND_QUANTILE = 0.999
#: Gaussian blur before thresholding, px.
_BLUR_SIGMA = 1.5
#: How far a binary mask's boundary can lie from the edge it samples, px: a pixel is
#: object when its centre is, so the edge may pass anywhere up to half a pixel's
#: diagonal from the boundary :func:`signed_distance` puts halfway between centres.
_RASTER_PX = 0.5 * np.sqrt(2.0)


def mask_path(folder: str | os.PathLike, image_name: str) -> Path | None:
    """The mask file of ``image_name`` in ``folder/masks`` (COLMAP's naming first), or None."""
    masks = Path(folder) / "masks"
    for candidate in (masks / f"{image_name}.png", masks / f"{Path(image_name).stem}.png"):
        if candidate.is_file():
            return candidate
    return None


def read_mask(path: str | os.PathLike, size: tuple[int, int],
              full_size: tuple[int, int] | None = None) -> np.ndarray:
    """(H, W) bool object mask (file pixel != 0) of an image of ``size = (width, height)``.

    ``full_size``: the image's stored size when it is read at a working scale
    (:mod:`matching.resolution`); a mask of that size is resized to ``size`` (area
    average, kept where at least half of a pixel is on the mask).

    Raises
    ------
    ValueError
        Unreadable file, or not the image's size (one line naming the file).
    """
    from matching.image_file import imread

    img = imread(path)  # upright, as its image is read
    if img is None:
        raise ValueError(f"{path}: not a readable mask image")
    if img.ndim == 3:
        img = img.max(axis=2)
    if full_size is not None and tuple(full_size) != tuple(size) and \
            (img.shape[1], img.shape[0]) == tuple(full_size):
        import cv2

        on = (img != 0).astype(np.float32)
        return cv2.resize(on, tuple(size), interpolation=cv2.INTER_AREA) >= 0.5
    if (img.shape[1], img.shape[0]) != tuple(size):
        raise ValueError(f"{path}: mask is {img.shape[1]}x{img.shape[0]} px but its image is "
                         f"{size[0]}x{size[1]} px")
    return img != 0


def grey(image, dtype=np.float64) -> np.ndarray:
    """(H, W) grey image of a grey or BGR(A) one (OpenCV's BT.601 weights), as ``dtype``."""
    img = np.asarray(image)
    if img.ndim == 3:
        img = img[..., :3].astype(np.float64) @ np.array([0.114, 0.587, 0.299])  # BGR
    return np.asarray(img, dtype=dtype)


def foreground_mask(image, margin_px: int = 3) -> np.ndarray | None:
    """(H, W) bool object mask of an image on a uniform background, or None (module docstring).

    Parameters
    ----------
    image : (H, W) or (H, W, 3) array_like
        Grey or BGR image, any range (8 or 16 bit, float).
    margin_px : int
        Dilation of the mask, px.

    Returns
    -------
    (H, W) bool or None
        None when the border is not a uniform background.
    """
    blurred = cv2.GaussianBlur(grey(image, np.float32), (0, 0), _BLUR_SIGMA)
    h, w = blurred.shape
    b = max(4, int(round(_BORDER_SHARE * min(h, w))))
    if 4 * b >= min(h, w):
        return None
    sides = [blurred[:b].ravel(), blurred[-b:].ravel(), blurred[:, :b].ravel(),
             blurred[:, -b:].ravel()]
    border = np.concatenate(sides)
    median = float(np.median(border))
    # per side, and the median of the four: a side the object touches does not count
    t = float(np.median([np.quantile(np.abs(s - median), _BACKGROUND_QUANTILE)
                         for s in sides]))
    lo, hi = np.percentile(blurred, [1, 99])
    agree = sum(abs(float(np.median(s)) - median) <= t for s in sides)
    if agree < 3 or not (t < 0.5 * (hi - lo)):
        return None
    fg = (np.abs(blurred - median) > t).astype(np.uint8)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(fg, connectivity=8)
    if count < 2:
        return None
    areas = stats[1:, cv2.CC_STAT_AREA]
    keep = np.zeros(count, bool)
    keep[1:] = areas >= 0.01 * areas.max()
    # holes are kept: a gap between columns is background the visual hull needs
    fg = keep[labels].astype(np.uint8)
    if margin_px > 0:
        side = 2 * int(margin_px) + 1
        fg = cv2.dilate(fg, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (side, side)))
    share = fg.mean()
    if not 0.001 < share < 0.98:
        return None
    return fg > 0


def inside_masks(points, cameras: Sequence, masks: Sequence) -> np.ndarray:
    """(N,) bool: inside every given view's mask where the point projects into the image.

    Parameters
    ----------
    points : (N, 3) float64, scene units
    cameras : sequence of V matching.cameras.Camera
    masks : sequence of V (H, W) bool or None
        None: the view does not constrain.
    """
    points = check_shape(points, "(N, 3)", "points", dtype=np.float64)
    keep = np.ones(len(points), bool)
    for cam, mask in zip(cameras, masks, strict=True):
        if mask is None or not len(points):
            continue
        front = cam.depth(points) > 0
        x = np.rint(cam.project(points)).astype(np.int64)
        w, h = cam.size
        inside = front & (x[:, 0] >= 0) & (x[:, 0] < w) & (x[:, 1] >= 0) & (x[:, 1] < h)
        on = np.zeros(len(points), bool)
        on[inside] = mask[x[inside, 1], x[inside, 0]]
        keep &= on | ~inside
    return keep


def signed_distance(mask) -> np.ndarray:
    """(H, W) float32 signed distance of every pixel centre from a mask's boundary, px.

    Positive outside the mask, negative inside; the boundary runs halfway between an
    object and a background pixel centre (so a background pixel next to the object is
    at +0.5, an object pixel next to the background at -0.5).  Exact Euclidean
    distances (scipy's, float64, the same bits on every run: OpenCV's precise transform
    is float32 and not bitwise reproducible from run to run).
    """
    m = np.asarray(mask, bool)
    if not m.any() or m.all():  # no boundary: farther than any distance in the image
        return np.full(m.shape, (-1.0 if m.all() else 1.0) * sum(m.shape), np.float32)
    outside = ndimage.distance_transform_edt(~m)
    inside = ndimage.distance_transform_edt(m)
    return np.where(m, 0.5 - inside, outside - 0.5).astype(np.float32)


def near_foreground(points, sigma, cameras: Sequence, distances: Sequence,
                    quantile: float) -> np.ndarray:
    """(N,) bool: within ``quantile`` σ of every given view's foreground (module docstring).

    Parameters
    ----------
    points : (N, 3) float64, scene units
    sigma : (N,) float64, scene units
        Each point's standard deviation (worst direction).
    cameras : sequence of V matching.cameras.Camera
    distances : sequence of V (H, W) float32 or None
        :func:`signed_distance` of each view's foreground; None: the view does not
        constrain (no automatic foreground: a textured background).
    quantile : float
        Tolerance in units of the point's σ projected into the view (σ f / depth), added
        to the mask's own raster bound (half a pixel's diagonal).

    Returns
    -------
    (N,) bool
        False where, in a view that constrains and into whose image the point projects
        (in front of the camera), the point lies farther outside the foreground than its
        tolerance.
    """
    points = check_shape(points, "(N, 3)", "points", dtype=np.float64)
    sigma = check_shape(sigma, "(N,)", "sigma", dtype=np.float64)
    if len(sigma) != len(points):
        raise ValueError(f"sigma: got {len(sigma)} values for {len(points)} points")
    keep = np.ones(len(points), bool)
    for cam, dist in zip(cameras, distances, strict=True):
        if dist is None or not len(points):
            continue
        depth = cam.depth(points)
        x = cam.project(points)
        w, h = cam.size
        inside = (depth > 0) & (x[:, 0] >= 0) & (x[:, 0] <= w - 1) & (x[:, 1] >= 0) \
            & (x[:, 1] <= h - 1)
        idx = np.flatnonzero(inside)
        d = bilinear(dist, x[idx])
        focal = 0.5 * (cam.K[0, 0] + cam.K[1, 1])
        tol = _RASTER_PX + quantile * sigma[idx] * focal / depth[idx]
        keep[idx[~(d <= tol)]] = False
    return keep


#: Rows of one ``cv2.remap`` call: its map is an image, fewer than 2^15 rows and columns.
REMAP_MAX_ROWS = 32_000
#: Positions per row of :func:`bilinear`'s maps.
REMAP_ROW = 1024


def bilinear(image: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Bilinear samples of ``image`` (H, W) at positions ``x`` (..., 2) px (x, y), any count.

    ``cv2.remap`` (linear, replicated border, float32 positions: within 1e-5 of the exact
    bilinear value on unit-variance pixels); its map is an image of fewer than 2^15 rows,
    so the positions go as rows of :data:`REMAP_ROW`, at most :data:`REMAP_MAX_ROWS`
    rows a call (an object outline of a 5-megapixel view holds more than 2^15 edge
    pixels: one map of a row per edge pixel failed there).

    Returns
    -------
    (...) float64
        ``x``'s shape less its last axis.
    """
    x = np.asarray(x, dtype=np.float32)
    shape = x.shape[:-1]
    flat = x.reshape(-1, 2)
    count = len(flat)
    if not count:
        return np.zeros(shape)
    img = np.ascontiguousarray(image, dtype=np.float32)
    rows = -(-count // REMAP_ROW)
    coords = np.zeros((rows * REMAP_ROW, 2), np.float32)
    coords[:count] = flat
    coords = coords.reshape(rows, REMAP_ROW, 2)
    out = np.concatenate([
        cv2.remap(img, coords[r:r + REMAP_MAX_ROWS], None, cv2.INTER_LINEAR,
                  borderMode=cv2.BORDER_REPLICATE).reshape(-1)
        for r in range(0, rows, REMAP_MAX_ROWS)])
    return out[:count].astype(np.float64).reshape(shape)
