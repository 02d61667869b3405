"""Input checks and tolerances for the surface package.

One shape-check helper and one tolerance object, so that no kernel carries a
magic epsilon of its own (the habit of trimesh's ``tol`` and kornia's
``KORNIA_CHECK_SHAPE``).  ``matching/validate.py`` holds the image-side twin; the
two packages never import each other, so each keeps its own small copy.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


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


def check_shape(array, spec: str, name: str, dtype=None) -> np.ndarray:
    """Check that ``array`` has the shape ``spec`` and return it as an ndarray.

    Parameters
    ----------
    array : array_like
    spec : str
        Shape pattern such as ``"(N, 3)"`` or ``"(3, 3)"``; letters match any
        length, integers must match exactly, ``*`` matches any leading dims.
    name : str
        The argument's name, used in the error message.
    dtype : numpy dtype, optional
        Convert to this dtype.

    Raises
    ------
    ValueError
        ``"points must have shape (N, 3), got (5, 2)"``.
    """
    arr = np.asarray(array, dtype=dtype)
    dims = [d.strip() for d in spec.strip("()").split(",") if d.strip()]
    leading = bool(dims) and dims[0] == "*"
    if leading:
        dims = dims[1:]
    ok = arr.ndim >= len(dims) if leading else arr.ndim == len(dims)
    if ok:
        tail = arr.shape[arr.ndim - len(dims):] if dims else ()
        for want, got in zip(dims, tail, strict=True):
            if want.isdigit() and int(want) != got:
                ok = False
                break
    if not ok:
        raise ValueError(f"{name} must have shape {spec}, got {tuple(arr.shape)}")
    return arr


def check_finite(array: np.ndarray, name: str) -> np.ndarray:
    """Raise ``ValueError`` if ``array`` holds NaN or inf."""
    if not np.all(np.isfinite(array)):
        bad = int(np.count_nonzero(~np.isfinite(array)))
        raise ValueError(f"{name} contains {bad} NaN/inf values")
    return array
