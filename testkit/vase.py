"""Shared test support: the analytic vase r(z) = 1 + 0.3 sin 2z, z in [0, 3], and its noisy cloud.

Used by the stitch, sections-command and run-stage tests (one generator, so they test
the same surface) and by ``benchmarks/surface.py`` (at 1024 x 768; it puts the
repository root on ``sys.path``).
"""

import numpy as np

from surface import metrics as M

SIGMA = 0.002  # isotropic Gaussian noise per coordinate of the test clouds (model units)


def radius(z):
    """Vase radius r(z) = 1 + 0.3 sin 2z; ``z`` array-like, same shape out."""
    return 1.0 + 0.3 * np.sin(2.0 * z)


def vase_truth(n_theta=256, n_z=192):
    """Closed vase mesh, flat caps (fans to the centres), outward.

    Returns vertices ``(n_z * n_theta + 2, 3)`` and triangles
    ``(2 (n_z - 1) n_theta + 2 n_theta, 3)``;
    the two cap fans (``n_theta`` faces each) are the last ``2 n_theta`` rows.
    """
    z = np.linspace(0.0, 3.0, n_z)
    theta = 2 * np.pi * np.arange(n_theta) / n_theta
    r = radius(z)
    v = np.stack([np.outer(r, np.cos(theta)), np.outer(r, np.sin(theta)),
                  np.repeat(z[:, None], n_theta, 1)], axis=-1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(n_z - 1), np.arange(n_theta), indexing="ij")
    a = (i * n_theta + j).ravel()
    b = (i * n_theta + (j + 1) % n_theta).ravel()
    faces = [np.stack([a, b, b + n_theta], 1), np.stack([a, b + n_theta, a + n_theta], 1)]
    bottom, top = len(v), len(v) + 1
    v = np.vstack([v, [[0, 0, 0], [0, 0, 3.0]]])
    ring = np.arange(n_theta)
    nxt = (ring + 1) % n_theta
    last = (n_z - 1) * n_theta
    faces += [np.stack([np.full(n_theta, bottom), nxt, ring], 1),
              np.stack([np.full(n_theta, top), last + ring, last + nxt], 1)]
    return v, np.vstack(faces).astype(np.int64)


def noisy_cloud(v, f, count, seed, sigma=SIGMA):
    """``count`` area-uniform samples of mesh ``(v, f)`` plus N(0, sigma^2) noise: ``(count, 3)``.

    The noise generator is seeded with ``seed`` too (as the tests always did).
    """
    rng = np.random.default_rng(seed)
    return M.sample_mesh(v, f, count=count, seed=seed) + rng.normal(0.0, sigma, (count, 3))
