"""matching.contours: sub-pixel object edges and outline points, against exact geometry."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from matching.contours import edge_points, outline_points


def _disk(radius=50.3, centre=(100.2, 99.7), size=200, ss=8, noise=1.5, seed=0,
          background=20.0):
    """A textured disk on a uniform background, area-sampled (``ss``² rays a pixel).

    ``centre`` in continuous image coordinates (pixel ``i`` covers ``[i, i + 1)``); in
    OpenCV's pixel coordinates (centres on the integers) it is ``centre - 0.5``.
    """
    n = size * ss
    y, x = (np.mgrid[0:n, 0:n] + 0.5) / ss
    inside = np.hypot(x - centre[0], y - centre[1]) < radius
    texture = 130.0 + 50.0 * np.sin(x / 3.1) * np.cos(y / 4.3)
    fine = np.where(inside, texture, background).astype(np.float32)
    img = cv2.resize(fine, (size, size), interpolation=cv2.INTER_AREA)
    rng = np.random.default_rng(seed)
    return img + rng.normal(0, noise, img.shape).astype(np.float32)


@pytest.mark.parametrize("margin", [0, 3])
def test_edge_points_lie_on_the_true_circle(margin):
    """The half-level crossing of an area-sampled step is the edge: mean radius within
    0.05 px, RMS within 0.15 px (noise 1.5 grey levels, contrast >= 50), whether the
    mask is tight or dilated by 3 px."""
    img = _disk()
    mask = img > 60
    if margin:
        mask = cv2.dilate(mask.astype(np.uint8), np.ones((2 * margin + 1,) * 2, np.uint8)) > 0
    edge, sigma_px = edge_points(img, mask)
    r = np.hypot(edge[:, 0] - 99.7, edge[:, 1] - 99.2)
    assert len(edge) > 250  # the perimeter is 316 px
    assert abs(np.mean(r) - 50.3) < 0.05
    assert np.sqrt(np.mean((r - 50.3) ** 2)) < 0.15
    assert np.median(sigma_px) < 0.15


def test_edge_points_refuse_a_textured_background():
    """No uniform background beyond the mask, no edge: a textured image gives nothing."""
    rng = np.random.default_rng(1)
    img = cv2.GaussianBlur(rng.uniform(0, 255, (200, 200)).astype(np.float32), (0, 0), 2.0)
    mask = np.zeros((200, 200), bool)
    mask[50:150, 50:150] = True
    edge, _ = edge_points(img, mask)
    assert len(edge) < 0.05 * 400


def test_outline_points_are_empty_without_masks_or_points():
    img = _disk()
    out = outline_points([img], [None], [None], np.zeros((0, 3)), np.zeros(0))
    assert len(out) == 0


def test_edge_points_of_an_outline_longer_than_remaps_map():
    """More than 2^15 edge pixels (a 5-megapixel view's outline): the profiles are sampled
    in pieces (``cv2.remap``'s map is an image of fewer than 2^15 rows; one row per edge
    pixel failed there) and the edges still lie on the disks' circles."""
    size, step, radius = 1600, 50, 20.3
    y, x = np.mgrid[0:size, 0:size].astype(np.float64)
    cx, cy = (np.round((x - 24.6) / step) * step + 24.6, np.round((y - 25.2) / step) * step + 25.2)
    r = np.hypot(x - cx, y - cy)
    inside = 1.0 / (1.0 + np.exp((r - radius) / 0.45))          # a blurred step at `radius`
    texture = 130.0 + 50.0 * np.sin(x / 3.1) * np.cos(y / 4.3)
    img = (20.0 + (texture - 20.0) * inside).astype(np.float32)
    img += np.random.default_rng(0).normal(0, 1.0, img.shape).astype(np.float32)
    mask = img > 60
    edge, _ = edge_points(img, mask)
    assert len(edge) > 2 ** 15
    cxe = np.round((edge[:, 0] - 24.6) / step) * step + 24.6
    cye = np.round((edge[:, 1] - 25.2) / step) * step + 25.2
    re = np.hypot(edge[:, 0] - cxe, edge[:, 1] - cye)
    assert abs(np.median(re) - radius) < 0.1
