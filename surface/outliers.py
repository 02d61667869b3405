"""Far outliers: small groups of points cut off from the rest of the cloud by empty slabs.

The section stage's costs grow with the cloud's extent in point spacings (the
sections are ``Δ = 2 s`` apart, :func:`surface.sections.slice_sections`), so five
stray points 10⁶ away from a unit object ask for 10⁷ sections.  A point is a
*far outlier* when, along one of the coordinate axes, it lies in a group of
fewer than :data:`MIN_GROUP` points that an empty slab wider than
``GAP_SPACINGS · s`` separates from every other point.

Why these figures (``docs/decisions/hostile-input.md``):

* ``GAP_SPACINGS = 16``: a surface sampled at spacing ``s`` (density
  ``ρ = 1/s²``) that crosses a slab of width ``g`` leaves in it, on a strip as
  narrow as one spacing, ``ρ · s · g = g/s`` points on average, so for Poisson
  sampling the slab is empty with probability ``exp(-g/s)``: at ``g = 16 s``,
  1.1e-7.  An empty slab that wide says the surface does not cross it.
* ``MIN_GROUP = 8``: the fewest points a piece of surface needs to give two
  adjacent sections one closed loop each (4 points a closed cubic needs,
  :func:`surface.reconstruct.min_loop_points`), the least anything is stitched from.

A point far from the cloud (distance ``D`` much larger than the cloud) is at
least ``D/√3`` beyond it along one coordinate axis, so the three projections
find it; a point inside the cloud's box is no cost and is kept.  A larger far
group is kept too: the cost check that follows
(:func:`pipeline.guards.check_section_cost`) then refuses it by its extent in
spacings.  Cost: three sorts and one spacing estimate, ``O(N log N)`` time and
``O(N)`` memory, whatever the coordinates.

Shapes: points ``(N, 3) float64`` in scene units; the mask ``(N,) bool``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Empty-slab width, in point spacings, that separates a group from the rest (module notes).
GAP_SPACINGS = 16.0

#: Groups of fewer points than this beyond such a slab are far outliers (module notes).
MIN_GROUP = 8


@dataclass(frozen=True)
class FarOutliers:
    """The far outliers of a cloud.

    Attributes
    ----------
    mask : (N,) bool
        True for a far outlier.
    spacing : float
        The cloud's point spacing ``s`` (scene units), 0 when it has none.
    gap : float
        The empty-slab width ``GAP_SPACINGS · s`` used (scene units).
    distance : float
        The largest distance of an outlier from the kept points' bounding box (scene
        units; 0 without outliers).
    """

    mask: np.ndarray
    spacing: float
    gap: float
    distance: float

    @property
    def count(self) -> int:
        return int(np.count_nonzero(self.mask))

    def report(self, total: int) -> str:
        """One line: how many points were dropped, how far, and by which rule."""
        return (f"{self.count} far outlier point(s) of {total} dropped: up to {self.distance:.3g} "
                f"beyond the rest, in groups of fewer than {MIN_GROUP} points past an empty "
                f"slab wider than {GAP_SPACINGS:g} point spacings ({self.gap:.3g})")


def far_outliers(points: np.ndarray, spacing: float | None = None) -> FarOutliers:
    """Find the far outliers of a cloud (module notes).

    Parameters
    ----------
    points : (N, 3) float64
        Finite coordinates, scene units.
    spacing : float, optional
        The point spacing ``s``; default :func:`surface.sections.point_spacing`.

    Returns
    -------
    FarOutliers
    """
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points must have shape (N, 3), got {points.shape}")
    n = len(points)
    mask = np.zeros(n, bool)
    if n <= MIN_GROUP:
        return FarOutliers(mask, 0.0, 0.0, 0.0)
    if spacing is None:
        from surface.sections import point_spacing

        spacing = point_spacing(points)
    if not (np.isfinite(spacing) and spacing > 0):
        return FarOutliers(mask, 0.0, 0.0, 0.0)
    gap = GAP_SPACINGS * float(spacing)
    for column in range(3):
        mask |= _small_groups(points[:, column], gap)
    if mask.all():  # no group holds MIN_GROUP points: nothing to tell the rest by
        mask[:] = False
    distance = 0.0
    if mask.any():
        kept = points[~mask]
        below = np.maximum(kept.min(axis=0) - points[mask], 0.0)
        above = np.maximum(points[mask] - kept.max(axis=0), 0.0)
        distance = float(np.sqrt(((below + above) ** 2).sum(axis=1)).max())
    return FarOutliers(mask, float(spacing), gap, distance)


def _small_groups(values: np.ndarray, gap: float) -> np.ndarray:
    """``(N,) bool``: the values in runs of fewer than :data:`MIN_GROUP` once sorted and cut
    wherever two neighbours are more than ``gap`` apart."""
    order = np.argsort(values, kind="stable")
    cuts = np.flatnonzero(np.diff(values[order]) > gap) + 1  # first index of each later run
    if cuts.size == 0:
        return np.zeros(len(values), bool)
    edges = np.concatenate([[0], cuts, [len(values)]])
    small_run = np.diff(edges) < MIN_GROUP  # (runs,)
    run_of_sorted = np.zeros(len(values), np.int64)
    run_of_sorted[cuts] = 1
    run_of_sorted = np.cumsum(run_of_sorted)
    mask = np.zeros(len(values), bool)
    mask[order] = small_run[run_of_sorted]
    return mask
