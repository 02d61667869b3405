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


# ------------------------------------------------------------------ thin-walled vessels
#: The thin-walled vessel (:func:`vessel`): a mug-like pot of outer radius 1, height 2,
#: a floor 0.25 thick, an open mouth, optionally a handle (a half torus in the x-z plane).
VESSEL_RADIUS, VESSEL_HEIGHT, VESSEL_FLOOR = 1.0, 2.0, 0.25
VESSEL_BOX = np.array([[-1.05, -1.05, -0.05], [1.9, 1.05, 2.05]])


def vessel(wall: float, handle: bool):
    """Implicit solid ``f(p) < 0`` ``(P, 3) -> (P,)`` of a pot with a wall ``wall`` thick
    (exact signed distance away from the handle's joints): outer cylinder r = 1,
    z in [0, 2], the inside r < 1 - wall above the floor, and with ``handle`` a half
    torus (ring radius 0.6, tube 0.13) joined to the wall at z = 0.4 and 1.6, cut
    in the middle of the wall."""
    from testkit.shapes import _cylinder_z, _torus_xz

    def f(p):
        body = np.maximum(_cylinder_z(p, VESSEL_RADIUS, 0.0, VESSEL_HEIGHT),
                          -_cylinder_z(p, VESSEL_RADIUS - wall, VESSEL_FLOOR, 3.0))
        if not handle:
            return body
        # cut inside the wall, so that the handle does not reach into the cavity
        cut = VESSEL_RADIUS - wall / 2
        ring = np.maximum(_torus_xz(p, (1.1, 0.0, 1.0), 0.6, 0.13), cut - p[:, 0])
        return np.minimum(body, ring)
    return f


def vessel_area(f, seed: int = 0, band: float = 0.01, draws: int = 4_000_000) -> float:
    """Surface area of ``f = 0`` in :data:`VESSEL_BOX` by Monte Carlo: the band
    ``|f| < band`` has volume ≈ area · 2 band (relative error ~1e-2 at the defaults)."""
    rng = np.random.default_rng(seed)
    box = VESSEL_BOX
    volume = float(np.prod(box[1] - box[0]))
    inside = 0
    for _ in range(draws // 1_000_000):
        cand = rng.uniform(box[0], box[1], (1_000_000, 3))
        inside += int((np.abs(f(cand)) < band).sum())
    return volume * inside / draws / (2 * band)


def vessel_sample(f, count: int, seed: int = 0, sigma: float = 0.0) -> np.ndarray:
    """``count`` area-uniform points ``(count, 3)`` on ``f = 0`` (band draws moved on by
    Newton steps, as ``testkit.shapes.sample``) plus N(0, sigma²) noise."""
    from testkit.shapes import project

    rng = np.random.default_rng(seed)
    kept, total = [], 0
    while total < count:
        cand = rng.uniform(VESSEL_BOX[0], VESSEL_BOX[1], (400_000, 3))
        cand = cand[np.abs(f(cand)) < 0.02]
        kept.append(cand)
        total += len(cand)
    pts = np.concatenate(kept)[:count]
    return project(f, pts) + rng.normal(0.0, sigma, (count, 3))
