"""Status codes of a stereo pair's candidates, and the bounds the pair's tests share.

LSM's own codes (:data:`matching.lsm.STATUS_NAMES`, 0-7 and 11) and the pair's: 8-10 and
12-16 (their meanings: ``docs/method/acquire.md``).
"""

from __future__ import annotations

from matching.lsm import STATUS_NAMES

NO_APPROXIMATION = 8
TRIANGULATION = 9
IMPRECISE = 10
AMBIGUOUS = 12
BLANK = 13
BACKWARD = 14
APERTURE = 15
#: ``aperture``: the shift's variance along the row may be at most this many times what
#: the template's gradients along the row alone give (σ0² / Σ f_x²)
MAX_INFLATION = 2.0
OFF_SURFACE = 16
#: median of χ² with one degree of freedom
CHI2_1_MEDIAN = 0.45494
#: two-sided 99.9 % bound of a normal variable
OUTLIER_Z = 3.29
#: Every pair status code -> name (LSM's codes 0-7 and 11, then 8-10 and 12-14).
PAIR_STATUS_NAMES = {**STATUS_NAMES, NO_APPROXIMATION: "no_approximation",
                     TRIANGULATION: "triangulation", IMPRECISE: "imprecise",
                     AMBIGUOUS: "ambiguous", BLANK: "blank", BACKWARD: "backward",
                     APERTURE: "aperture", OFF_SURFACE: "off_surface"}

