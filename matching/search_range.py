r"""Disparity search ranges from the camera geometry, not from feature matches.

With known cameras the object lies where the views look: in the **common volume of the
viewing frusta** (a point every view sees inside its image, in front of it), and, with
object masks, inside the **visual hull** (inside every view's mask where it projects
into the image; Laurentini 1994).  :func:`scene_volume` samples that region on a grid:
a cube about the scene centre (the optical axes' least-squares intersection) reaching
the farthest camera, cut to the cells kept, then sampled again at the same number of
cells over the bounding box of those (so the cells shrink with the volume).  Sparse
points (an SfM model's) may be given instead or as well.

A pair's SGBM range (:func:`pair_disparity_range`) is then the span of the disparities
:math:`d = x_1 - x_2 = f b / Z + (c_{x,1} - c_{x,2})` of the volume's samples that fall
inside both rectified images, widened by the disparity a cell's half diagonal can add
and 2 px, rounded out to SGBM's multiple of 16.  A weakly textured object thus gets its
approximations (SGBM needs no features to know where to search); SIFT matches stay an
aid for pairs whose cameras bound nothing (:func:`matching.seeds.disparity_range`).

References
----------
.. [1] A. Laurentini, "The visual hull concept for silhouette-based image understanding",
   IEEE TPAMI 16(2), 150-162 (1994).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from matching.validate import check_shape
from matching.view_pairs import scene_centre

__all__ = ["SceneVolume", "scene_volume", "pair_disparity_range"]

#: Grid cells per axis of each sampling pass.
_CELLS = 48
#: Extra disparity on either side of the sampled span, px (SGBM's sub-pixel and the
#: rectification's rounding).
_PAD_PX = 2.0


@dataclass(frozen=True, eq=False)
class SceneVolume:
    """Samples of the region the object can occupy.

    Attributes
    ----------
    points : (M, 3) float64, scene units
        Cell centres inside the region (and any sparse points given).
    cell : float
        Cell side, scene units (0 for sparse points only).
    source : str
        ``"frusta"``, ``"visual hull"`` or ``"sparse points"``.
    """

    points: np.ndarray
    cell: float
    source: str

    @property
    def bounds(self) -> np.ndarray:
        """(2, 3) lower and upper corner of the samples' box (cell half-widths added)."""
        half = 0.5 * self.cell
        return np.stack([self.points.min(0) - half, self.points.max(0) + half])


def _inside_views(points: np.ndarray, cameras: Sequence, masks: Sequence | None,
                  min_views: int) -> np.ndarray:
    """(N,) bool: seen (in front, inside the image, on the mask) by >= min_views views,
    and never projected onto a mask's background."""
    alive = np.arange(len(points))  # points that can still qualify
    seen = np.zeros(len(points), np.int32)
    for v, cam in enumerate(cameras):
        if not len(alive):
            break
        X = points[alive]
        front = X @ cam.R[2] + cam.t[2] > 0
        x = np.full((len(X), 2), -1.0)
        if front.any():
            x[front] = cam.project(X[front])
        w, h = cam.size
        inside = front & (x[:, 0] >= -0.5) & (x[:, 0] < w - 0.5) & (x[:, 1] >= -0.5) & (
            x[:, 1] < h - 0.5)
        mask = None if masks is None else masks[v]
        drop = np.zeros(len(X), bool)
        if mask is not None:
            xi = np.rint(x[inside]).astype(np.int64)
            xi[:, 0] = np.clip(xi[:, 0], 0, w - 1)
            xi[:, 1] = np.clip(xi[:, 1], 0, h - 1)
            drop[np.flatnonzero(inside)[~mask[xi[:, 1], xi[:, 0]]]] = True
        seen[alive] += inside
        # off a mask, or too many views left out to reach min_views
        drop |= seen[alive] + (len(cameras) - 1 - v) < min_views
        alive = alive[~drop]
    keep = np.zeros(len(points), bool)
    keep[alive] = seen[alive] >= min_views
    return keep


def _grid(lo: np.ndarray, hi: np.ndarray, cells: int) -> tuple[np.ndarray, float]:
    side = float(np.max(hi - lo)) / cells
    axes = [lo[a] + side * (np.arange(max(1, int(np.ceil((hi[a] - lo[a]) / side)))) + 0.5)
            for a in range(3)]
    g = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    return g, side


def scene_volume(cameras: Sequence, masks: Sequence | None = None,
                 sparse_points=None, min_views: int | None = None,
                 cells: int = _CELLS) -> SceneVolume:
    """Sample the common volume of the views' frusta, or their visual hull (module docstring).

    Parameters
    ----------
    cameras : sequence of V matching.cameras.Camera
    masks : sequence of V (H, W) bool or None, optional
        Object masks (None entries: that view does not constrain).
    sparse_points : (P, 3) array_like, optional
        Points known to lie on the object (an SfM model's); added to the samples, and
        alone they are the volume when the frusta bound nothing.
    min_views : int, optional
        Views a sample must be seen by (default: all, at least 2).
    cells : int
        Cells per axis of each grid pass.

    Returns
    -------
    SceneVolume

    Raises
    ------
    ValueError
        No sample is seen by ``min_views`` views (and no sparse points).
    """
    cameras = list(cameras)
    if masks is not None and len(masks) != len(cameras):
        raise ValueError(f"masks: got {len(masks)} for {len(cameras)} cameras")
    need = len(cameras) if min_views is None else int(min_views)
    need = max(min(need, len(cameras)), 1)
    sparse = (np.zeros((0, 3)) if sparse_points is None
              else check_shape(sparse_points, "(N, 3)", "sparse_points", dtype=np.float64))
    centres = np.stack([c.center for c in cameras])
    try:
        centre = scene_centre(cameras)
    except ValueError:
        centre = sparse.mean(0) if len(sparse) else centres.mean(0)
    reach = float(np.max(np.linalg.norm(centres - centre, axis=1)))
    lo, hi = centre - reach, centre + reach
    kept, side = np.zeros((0, 3)), 0.0
    for n_cells in (max(8, cells // 2), cells):  # coarse, then over the box of what was kept
        grid, side = _grid(lo, hi, n_cells)
        keep = _inside_views(grid, cameras, masks, need)
        if not keep.any():
            break
        kept = grid[keep]
        lo, hi = kept.min(0) - side, kept.max(0) + side
    source = "visual hull" if masks is not None and any(m is not None for m in masks) \
        else "frusta"
    if len(kept) == 0:
        if len(sparse) == 0:
            raise ValueError(f"no point is seen by {need} of the {len(cameras)} views: the "
                             "cameras share no viewing volume")
        return SceneVolume(points=sparse, cell=0.0, source="sparse points")
    return SceneVolume(points=np.concatenate([kept, sparse]), cell=side, source=source)


def pair_disparity_range(volume: SceneVolume, left_rect, right_rect,
                         max_count: int | None = None) -> tuple[int, int] | None:
    """SGBM's (min_disparity, num_disparities) of a rectified pair from a volume.

    Parameters
    ----------
    volume : SceneVolume
    left_rect, right_rect : matching.cameras.Camera
        The rectified pinhole cameras (:func:`matching.multiview.rectify_pair`).
    max_count : int, optional
        Largest ``num_disparities`` (default: the rectified width rounded down to 16).

    Returns
    -------
    (int, int) or None
        None when no sample falls inside both rectified images.
    """
    X = volume.points
    w, h = left_rect.size
    zl, zr = left_rect.depth(X), right_rect.depth(X)
    xl, xr = left_rect.project(X), right_rect.project(X)
    inside = (zl > 0) & (zr > 0)
    for x in (xl, xr):
        inside &= (x[:, 0] >= 0) & (x[:, 0] <= w - 1) & (x[:, 1] >= 0) & (x[:, 1] <= h - 1)
    if not inside.any():
        return None
    d = xl[inside, 0] - xr[inside, 0]
    # a cell's half diagonal changes the depth by up to that much: d' = f b / Z^2 dZ
    f = left_rect.K[0, 0]
    base = float(np.linalg.norm(left_rect.center - right_rect.center))
    z = zl[inside]
    spread = f * base * (0.5 * np.sqrt(3.0) * volume.cell) / np.maximum(z, 1e-12) ** 2
    lo = float(np.min(d - spread)) - _PAD_PX
    hi = float(np.max(d + spread)) + _PAD_PX
    top = max(16, (w - 16) // 16 * 16) if max_count is None else int(max_count)
    dmin = int(max(np.floor(lo), -(w - 32)))
    count = int(np.ceil((min(hi, w - 32) - dmin) / 16.0)) * 16
    return dmin, int(np.clip(count, 16, top))
