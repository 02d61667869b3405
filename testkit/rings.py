"""Camera rings round a vertical axis, for the tests of view pairs and scene centres.

Pinhole views of 320 × 240 px (f = 400 px) on a circle about the z axis, each looking at
``(0, 0, height)`` from ``height + 1`` above the origin's plane; world units, no distortion.
"""

from __future__ import annotations

import numpy as np

from matching.cameras import Camera


def ring_cameras(n: int, radius: float = 7.0, height: float = 1.5, jitter: float = 0.0,
                 seed: int = 0) -> list[Camera]:
    """``n`` views at equal angles on a ring of ``radius``, named ``v00.png``...;
    ``jitter``: each centre moved by up to that share of the radius along each axis
    (uniform, from ``seed``)."""
    rng = np.random.default_rng(seed)
    K = np.array([[400.0, 0, 159.5], [0, 400.0, 119.5], [0, 0, 1]])
    cams = []
    for k in range(n):
        a = 2 * np.pi * k / n
        c = (np.array([radius * np.cos(a), radius * np.sin(a), height + 1.0])
             + rng.uniform(-1, 1, 3) * radius * jitter)
        f = np.array([0.0, 0.0, height]) - c
        f /= np.linalg.norm(f)
        r = np.cross(f, [0, 0, 1.0])
        r /= np.linalg.norm(r)
        R = np.stack([r, np.cross(f, r), f])
        cams.append(Camera(K, [], R, -R @ c, 320, 240, f"v{k:02d}.png"))
    return cams
