"""Argument checks shared by every package: an array's shape and its finiteness.

The one neutral module below ``matching`` and ``surface`` (which never import each
other): each package's ``validate`` module re-exports these beside its own tolerances.
Errors are ``ValueError`` with the argument's name and what was wrong, for the caller to
turn into its one-line message.
"""

from __future__ import annotations

import numpy as np

__all__ = ["check_finite", "check_shape"]


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
