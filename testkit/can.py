"""Shared test support: a can with a raised rim round a recessed lid, and a bowl, built
analytically as surfaces of revolution.

The profile of revolution (r, z), from the axis round to the axis::

    (0, 0) -> (R, 0) -> (R, H) -> (R - w, H) -> (R - w, H - d) -> (0, H - d)

a flat base, the outer wall, the rim's top (an annulus ``w`` wide), the rim's inner
face down to the lid, and the lid ``d`` below the rim.  Default sizes are a drinks
can's (metres): R = 0.033, H = 0.1019, rim 0.003 wide and 0.004 deep.  The bowl
(:func:`bowl_truth`): outer radius ``0.5 + 0.5 sin(πz / 1.6)`` over z in [0, 0.8], an
inner face a given wall thickness inside it (measured across the axis) down to a floor
at z = 0.1, open mouth.  Used by ``tests/surface/test_ends.py``,
``tests/surface/test_mouths.py`` and ``benchmarks/ends.py``.
"""

import numpy as np

from surface import metrics as M

RADIUS, HEIGHT, RIM_WIDTH, RIM_DEPTH = 0.033, 0.1019, 0.003, 0.004


def revolve(profile, n_theta: int = 256, step: float = 0.001):
    """Closed, outward mesh ``(V, 3), (F, 3)`` of a profile ``(K, 2)`` of (r, z) pairs that
    starts and ends on the axis (r = 0); segments cut to at most ``step`` long."""
    prof = [tuple(profile[0])]
    for p, q in zip(profile[:-1], profile[1:], strict=True):
        pieces = max(1, int(np.ceil(np.hypot(q[0] - p[0], q[1] - p[1]) / step)))
        for t in np.linspace(0.0, 1.0, pieces + 1)[1:]:
            prof.append((p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1])))
    theta = 2 * np.pi * np.arange(n_theta) / n_theta
    j, jn = np.arange(n_theta), (np.arange(n_theta) + 1) % n_theta
    blocks, rows, start = [], [], 0
    for r, z in prof:
        if r == 0:
            blocks.append(np.array([[0.0, 0.0, z]]))
            rows.append(np.array([start]))
            start += 1
        else:
            blocks.append(np.column_stack([r * np.cos(theta), r * np.sin(theta),
                                           np.full(n_theta, z)]))
            rows.append(start + j)
            start += n_theta
    faces = []
    for a, b in zip(rows[:-1], rows[1:], strict=True):
        if len(a) == 1:
            faces.append(np.column_stack([np.full(n_theta, a[0]), b[jn], b[j]]))
        elif len(b) == 1:
            faces.append(np.column_stack([a[j], a[jn], np.full(n_theta, b[0])]))
        else:
            faces += [np.column_stack([a[j], a[jn], b[jn]]), np.column_stack([a[j], b[jn], b[j]])]
    vertices, triangles = np.vstack(blocks), np.vstack(faces).astype(np.int64)
    if M.signed_volume(vertices, triangles) < 0:
        triangles = triangles[:, ::-1]
    return vertices, triangles


def can_truth(radius: float = RADIUS, height: float = HEIGHT, rim_width: float = RIM_WIDTH,
              rim_depth: float = RIM_DEPTH):
    """The can's mesh ``(V, 3), (F, 3)`` (module docstring); ``rim_depth = 0``: a plain
    capped cylinder."""
    if rim_depth <= 0:
        profile = [(0.0, 0.0), (radius, 0.0), (radius, height), (0.0, height)]
    else:
        profile = [(0.0, 0.0), (radius, 0.0), (radius, height), (radius - rim_width, height),
                   (radius - rim_width, height - rim_depth), (0.0, height - rim_depth)]
    return revolve(profile)


BOWL_HEIGHT, BOWL_FLOOR = 0.8, 0.1


def bowl_outer_radius(z):
    """The bowl's outer radius at height ``z`` (array-like)."""
    return 0.5 + 0.5 * np.sin(np.pi * np.asarray(z) / (2 * BOWL_HEIGHT))


def bowl_truth(wall: float):
    """The bowl's mesh ``(V, 3), (F, 3)`` with its inner face ``wall`` inside the outer."""
    z = np.linspace(0, BOWL_HEIGHT, 41)
    zi = np.linspace(BOWL_FLOOR, BOWL_HEIGHT, 36)[::-1]
    profile = ([(0.0, 0.0)] + list(zip(bowl_outer_radius(z), z, strict=True))
               + list(zip(bowl_outer_radius(zi) - wall, zi, strict=True))
               + [(0.0, BOWL_FLOOR)])
    return revolve(profile, step=0.01)
