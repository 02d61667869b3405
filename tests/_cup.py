"""A tapered cup of revolution with exact measures: flat base, straight walls, a round lip.

Half-section ``(r, z)`` counter-clockwise: base from the axis out to ``RB``, the outer wall
up to ``(RT, H - W/2)``, a semicircular lip of diameter ``W`` (horizontal), the inner wall
down to the inner bottom at ``ZB``, back to the axis.  The walls are ``W`` apart
horizontally, ``W / sqrt(1 + K^2)`` along their normal.
"""

import numpy as np

RB, RT, H, W, ZB = 30.0, 45.0, 90.0, 5.0, 8.0
K = (RT - RB) / (H - W / 2)  # dr/dz of both walls


def inner_radius(z):
    """The inner wall's radius at height ``z`` (ZB <= z <= H - W/2)."""
    return RB - W + K * np.asarray(z, dtype=np.float64)


def analytic_capacity(h: float) -> float:
    """pi * int_ZB^h r_in(z)^2 dz, for ZB <= h <= H - W/2."""
    a = inner_radius(ZB)
    b = inner_radius(h)
    return float(np.pi * (b ** 3 - a ** 3) / (3 * K))


def cup_profile(wall: int = 40, base: int = 16, lip: int = 9) -> np.ndarray:
    """``(M, 2)`` half-section, from the axis at the base to the axis at the inner bottom."""
    zt = H - W / 2
    outer = np.column_stack([np.linspace(RB, RT, wall), np.linspace(0.0, zt, wall)])
    theta = np.linspace(0.0, np.pi, lip)[1:-1]
    rim = np.column_stack([RT - W / 2 + W / 2 * np.cos(theta), zt + W / 2 * np.sin(theta)])
    z_in = np.linspace(zt, ZB, wall)
    inner = np.column_stack([inner_radius(z_in), z_in])
    floor = np.column_stack([np.linspace(0.0, RB, base), np.zeros(base)])
    bottom = np.column_stack([np.linspace(inner_radius(ZB), 0.0, base), np.full(base, ZB)])
    return np.vstack([floor[:-1], outer, rim, inner, bottom[1:]])
