r"""Do the cameras form a ring about the object, and what is its axis?

The camera centres :math:`C_v` are fitted with a plane (the smallest right singular
vector :math:`n` of the centred centres, total least squares) and, in that plane, a
circle (Kåsa's algebraic fit: :math:`|p|^2 = 2 c\cdot p + (r^2 - |c|^2)`, linear in
:math:`c` and :math:`r^2 - |c|^2`).  The views form a **ring** when

* there are at least 4 of them,
* they lie near the plane: the RMS distance from it is at most 10 % of the radius,
* near the circle: the RMS radial residual is at most 10 % of the radius, and
* all round: the largest gap between neighbouring azimuths about the circle's
  centre is below 180° (an arc covering less than half a turn is not a ring).

The ring's normal is then the direction the object stands in (a turntable's axis, a
gantry's ring): the natural axis to cut sections across.  Its sign is not fixed by the
centres; it is taken so that the cameras' image "up" (:math:`-R^\mathsf{T} e_y`) agree
with it on average when they do (|mean| > 0.1), else pointing from the scene centre
(the optical axes' intersection) towards the ring plane (cameras usually look down at
an object), else as the fit gives it.

References
----------
.. [1] I. Kåsa, "A circle fitting procedure and its error analysis", IEEE Transactions
   on Instrumentation and Measurement 25(1), 8-14 (1976).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from matching.view_pairs import scene_centre

__all__ = ["RingFit", "fit_ring"]

#: Largest off-plane and radial RMS residual, as a share of the radius.
_MAX_RESIDUAL = 0.1
#: Largest azimuth gap of a ring, degrees.
_MAX_GAP_DEG = 180.0


@dataclass(frozen=True)
class RingFit:
    """Plane and circle through the camera centres.

    Attributes
    ----------
    is_ring : bool
        The views form a ring (module docstring).
    axis : (3,) float64
        Unit normal of the fitted plane.
    centre : (3,) float64
        The circle's centre, scene units.
    radius : float
        Scene units.
    plane_rms, circle_rms : float
        RMS distance of the centres from the plane and from the circle (in the plane).
    max_gap_deg : float
        Largest azimuth gap between neighbouring views.
    reason : str
        Why it is not a ring ("" when it is).
    """

    is_ring: bool
    axis: np.ndarray
    centre: np.ndarray
    radius: float
    plane_rms: float
    circle_rms: float
    max_gap_deg: float
    reason: str = ""

    def as_dict(self) -> dict:
        """JSON-ready summary."""
        return {"is_ring": bool(self.is_ring), "axis": [float(a) for a in self.axis],
                "centre": [float(c) for c in self.centre], "radius": float(self.radius),
                "plane_rms": float(self.plane_rms), "circle_rms": float(self.circle_rms),
                "max_gap_deg": float(self.max_gap_deg), "reason": self.reason}


def fit_ring(cameras: Sequence) -> RingFit:
    """Fit a plane and a circle to the camera centres and say whether they form a ring.

    Parameters
    ----------
    cameras : sequence of V matching.cameras.Camera

    Returns
    -------
    RingFit
    """
    cams = list(cameras)
    centres = np.stack([c.center for c in cams]) if cams else np.zeros((0, 3))
    nan3 = np.full(3, np.nan)
    if len(cams) < 3:
        return RingFit(False, nan3, nan3, float("nan"), float("nan"), float("nan"),
                       float("nan"), f"{len(cams)} views: a ring needs at least 4")
    mean = centres.mean(axis=0)
    _, _, vt = np.linalg.svd(centres - mean)
    e1, e2, normal = vt
    rel = centres - mean
    off = rel @ normal
    xy = np.column_stack([rel @ e1, rel @ e2])
    A = np.column_stack([2.0 * xy, np.ones(len(xy))])
    sol = np.linalg.lstsq(A, (xy**2).sum(axis=1), rcond=None)[0]
    c2 = sol[:2]
    radius = float(np.sqrt(max(sol[2] + c2 @ c2, 0.0)))
    centre = mean + c2[0] * e1 + c2[1] * e2
    radial = np.linalg.norm(xy - c2, axis=1) - radius
    az = np.sort(np.degrees(np.arctan2(xy[:, 1] - c2[1], xy[:, 0] - c2[0])))
    gaps = np.diff(np.concatenate([az, az[:1] + 360.0]))
    plane_rms, circle_rms = float(np.sqrt(np.mean(off**2))), float(np.sqrt(np.mean(radial**2)))
    max_gap = float(gaps.max())
    normal = _orient(normal, cams, centre)
    reason = ""
    if len(cams) < 4:
        reason = f"{len(cams)} views: a ring needs at least 4"
    elif not radius > 0:
        reason = "the centres do not lie on a circle"
    elif plane_rms > _MAX_RESIDUAL * radius:
        reason = f"the centres are {plane_rms / radius:.0%} of the radius off their plane"
    elif circle_rms > _MAX_RESIDUAL * radius:
        reason = f"the centres are {circle_rms / radius:.0%} of the radius off a circle"
    elif max_gap >= _MAX_GAP_DEG:
        reason = f"the views leave a {max_gap:.0f} degree gap (not all round)"
    return RingFit(not reason, normal, centre, radius, plane_rms, circle_rms, max_gap, reason)


def _orient(normal: np.ndarray, cams: list, centre: np.ndarray) -> np.ndarray:
    up = np.mean([-c.R[1] for c in cams], axis=0)
    if abs(float(up @ normal)) > 0.1:
        return normal if up @ normal > 0 else -normal
    try:
        towards = centre - scene_centre(cams)
    except ValueError:
        return normal
    if abs(float(towards @ normal)) > 1e-9 * max(float(np.linalg.norm(towards)), 1e-300):
        return normal if towards @ normal > 0 else -normal
    return normal
