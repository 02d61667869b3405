"""The robust scale of every outlier test: σ from the median absolute deviation.

For Gaussian values the median absolute deviation from the median is
:math:`\\Phi^{-1}(3/4)\\,\\sigma \\approx 0.6745\\,\\sigma`, so
:math:`\\hat\\sigma = 1.4826\\,\\mathrm{MAD}` estimates σ and is not moved by up to half the values
being outliers (Rousseeuw & Croux, "Alternatives to the median absolute deviation", JASA 1993).
"""

from __future__ import annotations

import numpy as np

#: :math:`1/\Phi^{-1}(3/4)`: the MAD of Gaussian values times this is their σ.
MAD_TO_SIGMA = 1.4826


def mad_sigma(values, axis: int | None = None):
    """1.4826 × the median absolute deviation from the median of ``values`` (along ``axis``).

    Parameters
    ----------
    values : array_like
        The values; NaN propagates as in :func:`numpy.median`.
    axis : int, optional
        The axis to reduce; ``None`` (default) reduces all values to one number.

    Returns
    -------
    numpy.float64 or numpy.ndarray
        σ estimated robustly: a scalar for ``axis=None``, else the array reduced along ``axis``.
    """
    values = np.asarray(values)
    centre = np.median(values, axis=axis, keepdims=axis is not None)
    return MAD_TO_SIGMA * np.median(np.abs(values - centre), axis=axis)
