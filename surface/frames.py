r"""The orthonormal frame of an axis: one rule for every module that cuts or unrolls about one.

``axis_frame(a)`` returns the rows ``(e1, e2, â)``, :math:`\hat a = a / |a|`, a right-handed
orthonormal frame (:math:`e_1 \times e_2 = \hat a`):

.. math::

    e_1 = \frac{r - (r \cdot \hat a)\,\hat a}{|r - (r \cdot \hat a)\,\hat a|}, \qquad
    e_2 = \hat a \times e_1,

with ``r`` the world axis least aligned with ``a`` (the first of x, y, z on ties), so the
frame of ``z`` is the identity and a polar angle about ``z`` is the usual one.
``quarter_turns = k`` turns ``(e1, e2)`` about the axis by ``k`` × 90° (exact: only signs
and the order of the rows change), for a caller whose angles start elsewhere:
``k = 1`` gives ``(e2, -e1)``, ``k = -1`` gives ``(-e2, e1)``.

``axis`` : (3,) array_like, finite, non-zero; returns (3, 3) float64.
"""

from __future__ import annotations

import numpy as np

from surface.validate import TOL, check_finite, check_shape

__all__ = ["axis_frame"]


def axis_frame(axis, quarter_turns: int = 0) -> np.ndarray:
    """Right-handed orthonormal frame ``(3, 3)`` with rows ``e1, e2, axis / |axis|``.

    Parameters
    ----------
    axis : (3,) array_like
        Finite, non-zero; any length.
    quarter_turns : int
        ``(e1, e2)`` turned about the axis by this many quarter turns (counter-clockwise
        seen from the tip of the axis).

    Returns
    -------
    (3, 3) float64

    Raises
    ------
    ValueError
        A non-finite or zero-length axis.
    """
    a = check_shape(axis, "(3,)", "axis", dtype=np.float64)
    check_finite(a, "axis")
    norm = float(np.linalg.norm(a))
    if norm <= TOL.zero:
        raise ValueError(f"axis must have non-zero length, got {a.tolist()}")
    a = a / norm
    ref = np.zeros(3)
    ref[int(np.argmin(np.abs(a)))] = 1.0
    e1 = ref - (ref @ a) * a
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(a, e1)
    for _ in range(int(quarter_turns) % 4):
        e1, e2 = e2, -e1
    return np.stack([e1, e2, a])
