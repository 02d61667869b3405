"""Input checks and tolerances for the matching package.

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
    """Every epsilon of the matching package, in the unit named."""

    #: LSM stops when the shift update is below this (px).
    lsm_shift_stop_px: float = 0.01
    #: Determinant of the affine part below this counts as degenerate.
    affine_det_min: float = 0.1
    #: Numerical zero for pivots / determinants of small matrices.
    zero: float = 1e-12
    #: Largest |R^T R - I| (and |det R - 1|) accepted for a camera rotation.
    rotation_orthonormal: float = 1e-6
    #: Rotations read from text with few digits are re-orthonormalised when
    #: |R^T R - I| is below this (beyond it the file is wrong, not rounded).
    rotation_text_digits: float = 1e-3
    #: Triangulation: a point whose normal matrix J^T W J has a larger condition
    #: number is ill-conditioned (~1/angle² between rays: 1e10 <-> 1e-5 rad).
    triangulation_cond_max: float = 1e10
    #: Gauss-Newton triangulation stops when every step is below this times the
    #: mean camera distance from the camera centroid.
    triangulation_step_rel: float = 1e-10
    #: Isotropic σ floor (px) added to each LSM match covariance before triangulation,
    #: so that an epipolar-constrained (rank-1) covariance stays positive definite.
    match_cov_floor_px: float = 1e-3
    #: Smallest eigenvalue, per camera, of sum(I - a a^T) over the optical axes a for
    #: their least-squares intersection to count as defined (~1e-3 rad spread).
    axes_min_eig: float = 1e-6


TOL = Tolerance()
