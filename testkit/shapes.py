"""Procedural shapes with exact truth for the branching tests and benchmarks/branches.py.

Each shape is an implicit solid ``f(x) < 0`` built from signed distance functions
(Quilez's primitives: capped cylinders, tori; union = min, difference = max(a, -b),
smooth union = the polynomial smooth minimum of width ``k``) with a known genus:

========  ==========================================================  =====
torus     ring in the x-z plane, R = 1, r = 0.35: sections across z     1
          have two loops that merge at the ends
pants     a trunk splitting into two slanted legs (flat ends)            0
mug       wall (outer r 1, inner r 0.75, floor 0.25 thick, open top)     1
          with a handle (a half torus)
amphora   a body of revolution with two handles                          2
vase      a hollow body of revolution with an opening (a rim)            0
========  ==========================================================  =====

Points are sampled on ``f = 0`` by drawing uniform points in the band ``|f| < h``
and moving each to the surface by Newton steps ``x <- x - f ∇f / |∇f|²``
(central differences): the band's volume is its area times 2h, so the samples are
area-uniform up to O(κh).  The distance of a point to the truth is the length of
its own Newton path to ``f = 0`` (:func:`distance_to_truth`): exact where ``f`` is a
true distance (every shape away from its unions' blends, where it is within the
blend's O(k) of it).
"""

from __future__ import annotations

import numpy as np

SIGMA = 0.002        # isotropic Gaussian noise per coordinate (model units), as the vase's
TAU = 0.005          # F-score threshold (model units), as benchmarks/surface.py's
_BAND = 0.02         # sampling band half-width
_STEP = 1e-5         # central-difference step of the gradient


def _smin(a, b, k):
    """Polynomial smooth minimum of width ``k`` (= min outside the blend |a - b| < k)."""
    h = np.clip(0.5 + 0.5 * (b - a) / k, 0.0, 1.0)
    return b * (1 - h) + a * h - k * h * (1 - h)


def _cylinder_z(p, r, z0, z1, cx=0.0, cy=0.0):
    """Capped vertical cylinder, radius r, z in [z0, z1] (exact SDF)."""
    d_r = np.hypot(p[:, 0] - cx, p[:, 1] - cy) - r
    d_z = np.maximum(z0 - p[:, 2], p[:, 2] - z1)
    out = np.hypot(np.maximum(d_r, 0), np.maximum(d_z, 0))
    return out + np.minimum(np.maximum(d_r, d_z), 0.0)


def _torus_xz(p, centre, big, small):
    """Torus whose ring lies in the plane y = centre[1], parallel to x-z (exact SDF)."""
    q = p - np.asarray(centre)
    ring = np.hypot(q[:, 0], q[:, 2]) - big
    return np.hypot(ring, q[:, 1]) - small


def _slanted_leg(p, top, bottom, r, z_lo, z_hi):
    """Infinite cylinder through ``top``/``bottom`` cut by the planes z = z_lo, z_hi."""
    a, b = np.asarray(top, float), np.asarray(bottom, float)
    u = (b - a) / np.linalg.norm(b - a)
    q = p - a
    radial = np.linalg.norm(q - (q @ u)[:, None] * u, axis=1) - r
    return np.maximum(radial, np.maximum(z_lo - p[:, 2], p[:, 2] - z_hi))


def torus(p):
    return _torus_xz(p, (0.0, 0.0, 0.0), 1.0, 0.35)


def pants(p):
    trunk = _cylinder_z(p, 0.42, 0.35, 1.3)
    legs = np.minimum(_slanted_leg(p, (0.18, 0, 0.6), (0.6, 0, -0.6), 0.24, -0.55, 0.6),
                      _slanted_leg(p, (-0.18, 0, 0.6), (-0.6, 0, -0.6), 0.24, -0.55, 0.6))
    return _smin(trunk, legs, 0.12)


def mug(p):
    wall = np.maximum(_cylinder_z(p, 1.0, 0.0, 2.0), -_cylinder_z(p, 0.75, 0.25, 3.0))
    handle = np.maximum(_torus_xz(p, (1.1, 0.0, 1.0), 0.6, 0.13), 0.88 - p[:, 0])
    return np.minimum(wall, handle)


def _amphora_radius(z):
    return 0.5 + 0.2 * np.sin(np.pi * z / 2.0)


def amphora(p):
    radial = np.hypot(p[:, 0], p[:, 1]) - _amphora_radius(p[:, 2])
    body = np.maximum(radial * 0.95, np.maximum(-p[:, 2], p[:, 2] - 2.0))
    handles = np.minimum(_torus_xz(p, (0.72, 0.0, 1.15), 0.45, 0.1),
                         _torus_xz(p, (-0.72, 0.0, 1.15), 0.45, 0.1))
    handles = np.maximum(handles, 0.55 - np.abs(p[:, 0]))
    return np.minimum(body, handles)


def _vase_radius(z):
    return 0.7 + 0.2 * np.sin(1.6 * z + 0.4)


def vase(p):
    r = np.hypot(p[:, 0], p[:, 1])
    outer = np.maximum((r - _vase_radius(p[:, 2])) * 0.95, np.maximum(-p[:, 2], p[:, 2] - 2.0))
    inner = np.maximum((r - _vase_radius(p[:, 2]) + 0.2) * 0.95, 0.25 - p[:, 2])
    return np.maximum(outer, -inner)


#: name -> (implicit function, bounding box (2, 3), genus)
SHAPES = {
    "torus": (torus, np.array([[-1.4, -0.4, -1.4], [1.4, 0.4, 1.4]]), 1),
    "pants": (pants, np.array([[-0.9, -0.45, -0.6], [0.9, 0.45, 1.35]]), 0),
    "mug": (mug, np.array([[-1.05, -1.05, -0.05], [1.9, 1.05, 2.05]]), 1),
    "amphora": (amphora, np.array([[-1.3, -0.75, -0.05], [1.3, 0.75, 2.05]]), 2),
    "vase": (vase, np.array([[-0.95, -0.95, -0.05], [0.95, 0.95, 2.05]]), 0),
}


def _gradient(f, p):
    g = np.empty_like(p)
    for axis in range(3):
        e = np.zeros(3)
        e[axis] = _STEP
        g[:, axis] = (f(p + e) - f(p - e)) / (2 * _STEP)
    return g


def project(f, p, steps: int = 6) -> np.ndarray:
    """Points ``(P, 3)`` moved onto ``f = 0`` by Newton steps along the gradient."""
    x = np.array(p, dtype=np.float64, copy=True)
    for _ in range(steps):
        g = _gradient(f, x)
        x -= (f(x) / np.maximum(np.einsum("ij,ij->i", g, g), 1e-12))[:, None] * g
    return x


def sample(name: str, count: int, seed: int = 0, sigma: float = SIGMA) -> np.ndarray:
    """``count`` area-uniform points of shape ``name`` plus N(0, sigma²) noise: ``(count, 3)``."""
    f, box, _ = SHAPES[name]
    rng = np.random.default_rng(seed)
    kept, total = [], 0
    while total < count:
        cand = rng.uniform(box[0], box[1], (400_000, 3))
        cand = cand[np.abs(f(cand)) < _BAND]
        kept.append(cand)
        total += len(cand)
    pts = np.concatenate(kept)[:count]
    return project(f, pts) + rng.normal(0.0, sigma, (count, 3))


def distance_to_truth(name: str, points: np.ndarray) -> np.ndarray:
    """Distance ``(P,)`` of each point to the shape's surface (its Newton path, scene units)."""
    f = SHAPES[name][0]
    return np.linalg.norm(project(f, points) - points, axis=1)


def genus(name: str) -> int:
    return SHAPES[name][2]


def diagonal(name: str) -> float:
    box = SHAPES[name][1]
    return float(np.linalg.norm(box[1] - box[0]))


def score(name: str, vertices: np.ndarray, triangles: np.ndarray, count: int = 20_000,
          seed: int = 0, tau: float = TAU) -> dict:
    """Chamfer, F-score ... of a mesh against shape ``name`` (``metrics.distance_scores``).

    ``count`` area-uniform samples of the mesh are measured against the implicit
    surface (:func:`distance_to_truth`), and ``count`` noise-free samples of the
    shape against the mesh (``metrics.point_mesh_distance``).
    """
    from surface import metrics

    rec = metrics.sample_mesh(vertices, triangles, count=count, seed=seed)
    truth = sample(name, count, seed=seed + 1, sigma=0.0)
    return metrics.distance_scores(distance_to_truth(name, rec),
                                   metrics.point_mesh_distance(truth, vertices, triangles), tau)


def plane_section(points: np.ndarray):
    """``points`` (in the plane z = 0) as one :class:`surface.sections.Section` at height 0
    in the world frame."""
    from surface.sections import Section

    return Section(height=0.0, points=points, origin=np.zeros(3), frame=np.eye(3),
                   section_id=0)


def random_circle(radius: float, count: int, rng: np.random.Generator) -> np.ndarray:
    """``count`` points at uniformly random angles on a circle of ``radius`` in z = 0."""
    t = rng.uniform(0, 2 * np.pi, count)
    return np.column_stack([radius * np.cos(t), radius * np.sin(t), np.zeros(count)])
