r"""Loop's subdivision weights, for every module that needs them.

A vertex ``v`` of valence ``n`` with neighbours ``w_i`` moves, in one Loop subdivision
step [1]_, to :math:`(1 - n\beta)\,v + \beta \sum_i w_i` and, in the limit, to
:math:`(1 - n\chi)\,v + \chi \sum_i w_i` with

.. math::

    \beta(n) = \frac{1}{n}\Bigl(\frac58 - \bigl(\frac38 + \frac14\cos\frac{2\pi}{n}\bigr)^2\Bigr),
    \qquad \chi(n) = \frac{1}{n + 3 / (8 \beta(n))}.

``n`` : (V,) array_like of valences (> 0); returns (V,) float64.

References
----------
.. [1] C. Loop, "Smooth subdivision surfaces based on triangles", MSc thesis,
   University of Utah (1987).
"""

from __future__ import annotations

import numpy as np

__all__ = ["limit_weight", "loop_beta"]


def loop_beta(n) -> np.ndarray:
    """Loop's (1987) vertex weight ``beta(n) = (5/8 - (3/8 + cos(2 pi/n)/4)^2) / n``."""
    n = np.asarray(n, dtype=np.float64)
    return (5.0 / 8.0 - (3.0 / 8.0 + 0.25 * np.cos(2.0 * np.pi / n)) ** 2) / n


def limit_weight(n) -> np.ndarray:
    """The weight ``chi(n) = 1 / (3 / (8 beta(n)) + n)`` of each neighbour in the limit position."""
    n = np.asarray(n, dtype=np.float64)
    return 1.0 / (3.0 / (8.0 * loop_beta(n)) + n)
