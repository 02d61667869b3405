"""Input checks and tolerances for the surface package.

One shape-check helper and one tolerance object, so that no kernel carries a
magic epsilon of its own (the habit of trimesh's ``tol`` and kornia's
``KORNIA_CHECK_SHAPE``).  The shape and finiteness checks are
:mod:`checks.arrays`' (re-exported here), shared with the other package.
"""

from __future__ import annotations

from dataclasses import dataclass

from checks.arrays import check_finite, check_shape

__all__ = ["TOL", "Tolerance", "check_finite", "check_shape"]


@dataclass(frozen=True)
class Tolerance:
    """Every epsilon of the surface package, in the unit named."""

    #: Relative merge distance (x bounding-box diagonal) for duplicate points.
    merge_rel: float = 1e-9
    #: Relative tolerance for "these points are coplanar / collinear".
    planar_rel: float = 1e-9
    #: Numerical zero for areas, determinants and normalisation.
    zero: float = 1e-12
    #: Relative height tolerance (x bounding-box diagonal) grouping points of
    #: already-sectioned data into one section (sections.read_sectioned).
    section_group_rel: float = 1e-6
    #: Relative ridge added to the batched 3x3 normal equations of local
    #: quadratic fits (topology outlier rejection): regular when neighbours
    #: coincide, negligible elsewhere.
    ridge_rel: float = 1e-9
    #: Radians: an opposite-angle sum counts as Delaunay up to pi + angle
    #: (co-circular quads, e.g. N-to-N stitching of a cylinder, sum to pi exactly).
    angle: float = 1e-9


TOL = Tolerance()
