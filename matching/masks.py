r"""Object masks: COLMAP-style mask files, an automatic foreground, the visual hull.

**Mask files.**  As COLMAP takes them: ``masks/NAME.png`` beside the images (``NAME``
the image's file name, e.g. ``masks/img01.jpg.png``; ``masks/img01.png`` is accepted
too), one grey or colour image of the image's size, **0 = ignore** (background),
anything else = object.

**Automatic foreground** for a uniform background, dark or light
(:func:`foreground_mask`).  The background's grey-level distribution is taken from the
image border (a frame 3 % of the shorter side wide, after a Gaussian blur of σ = 1.5 px
that averages the sensor noise and the cloth's or wall's fine texture): its median
:math:`m` and :math:`t`, the median over the four sides of the 99.9th percentile of
:math:`|g - m|` along the side (an object touching one side does not raise it).  A
pixel is object where :math:`|g - m| > t`: at most ~0.1 % of the background passes
(fewer once the small components are removed).  The background must be uniform: at
least three of the four sides have their median within :math:`t` of :math:`m`, and
:math:`t` is below half the image's own grey range (1st-99th percentile);
otherwise there is no automatic mask (``None``: a textured background, or an object
filling the frame).  Components smaller than 1 % of the largest are dropped, holes are
kept (a gap between columns is background), and the mask is dilated by ``margin_px``
(silhouette blur, the blur above).  The threshold follows the data; where the
background is lit unevenly (the temple ring's cloth has lit folds) the mask also takes
the lit parts: it errs on the object's side, which is what a visual hull needs (a
superset of each silhouette); on the temple ring it holds >= 99.8 % of the pixels
above the data set's suggested 0.19 x 255 in every view and exceeds them (dilated by
3 px) by 1-14 % of the image.

**Visual hull** (Laurentini 1994 [1]_): a point is kept when, in every view where it
projects inside the image, it falls on the view's object mask
(:func:`inside_masks`).

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

from matching.validate import check_shape

__all__ = ["mask_path", "read_mask", "foreground_mask", "inside_masks"]

#: Border frame used for the background statistics, share of the shorter image side.
_BORDER_SHARE = 0.03
#: Quantile of the border's deviations that bounds the background.
_BACKGROUND_QUANTILE = 0.999
#: Gaussian blur before thresholding, px.
_BLUR_SIGMA = 1.5


def mask_path(folder: str | os.PathLike, image_name: str) -> Path | None:
    """The mask file of ``image_name`` in ``folder/masks`` (COLMAP's naming first), or None."""
    masks = Path(folder) / "masks"
    for candidate in (masks / f"{image_name}.png", masks / f"{Path(image_name).stem}.png"):
        if candidate.is_file():
            return candidate
    return None


def read_mask(path: str | os.PathLike, size: tuple[int, int]) -> np.ndarray:
    """(H, W) bool object mask (file pixel != 0) of an image of ``size = (width, height)``.

    Raises
    ------
    ValueError
        Unreadable file, or not the image's size (one line naming the file).
    """
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ValueError(f"{path}: not a readable mask image")
    if img.ndim == 3:
        img = img.max(axis=2)
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
