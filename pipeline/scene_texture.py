r"""The synthetic scenes' solid texture and shading (numba kernels): a point's albedo and radiance.

Texture.  A solid (3D) band-limited texture, the same function of the surface point from every view:

.. math::  T(X) = \sum_{k=1}^{K} \sin 2\pi(\mathbf f_k \cdot X + \varphi_k),
           \qquad a(X) = \bar a + \Delta a \tanh\!\big(T(X) / 2\sigma_T\big),

with :math:`|\mathbf f_k|` log-uniform between 1/λ_max and 1/λ_min, directions uniform on the
sphere, :math:`\sigma_T = \sqrt{K/2}` and the albedo
:math:`a \in [\bar a - \Delta a, \bar a + \Delta a]`.

Shading (Lambert with ambient light, no cast shadows):

.. math::  L = a(X)\,\big(k_a + k_d \max(0, \mathbf n \cdot \mathbf l)\big)
           + k_s \max(0, \mathbf n \cdot \mathbf h)^{p},

**n** the barycentric interpolation of the corner normals.  The specular term (Blinn-Phong [1]_,
``lighting.specular`` :math:`k_s` and ``lighting.shininess`` :math:`p`, off unless given) uses the
half vector :math:`\mathbf h` of the light and the direction back to the camera, and only where
:math:`\mathbf n \cdot \mathbf l > 0`: a highlight that moves with the viewpoint, not the texture.
Points ``(N, 3) float64`` in scene units; radiance ``float32`` (1 is white).

References
----------
.. [1] J. F. Blinn, "Models of light reflection for computer synthesized pictures",
   Computer Graphics (SIGGRAPH '77) 11(2), 192–198 (1977).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numba
import numpy as np

__all__ = ["SinusoidTexture", "quiet_numba", "shade"]


#: The texture kernels' floating-point flags: only "no signed zeros".  Reassociation
#: (fastmath's "reassoc") lets LLVM vectorise the 48-term float32 sum with the host's
#: vector width (8 lanes with AVX2, 16 with AVX-512), and contraction ("contract") fuses
#: multiply-adds where the host has FMA: the rendered grey levels then differ in the
#: last float32 bits between CPUs, a few pixels round to another 8-bit level, and every
#: test on a rendered scene sees other data on another machine (the
#: 24-view ring's lowest point moved 1.6 px on an AMD EPYC).  Without them the
#: arithmetic is IEEE's on any x86-64 (texture evaluation ~1.8x slower: ~+1 s of the
#: 24-view 320x240 ring's render).
_EXACT = {"nsz"}


@numba.njit(inline="always", fastmath=_EXACT, cache=True)
def _sin_turns(u):  # pragma: no cover - compiled
    # sin 2πu: reduce to [-1/4, 1/4] turn, degree-9 Taylor polynomial (error < 4e-6, far
    # below a grey level); ~7x faster than libm's sin, which numba cannot vectorise here
    # (no SVML).
    u = u - np.floor(u + np.float32(0.5))
    a = abs(u)
    if a > np.float32(0.25):
        a = np.float32(0.5) - a
    w = a * np.float32(2.0 * np.pi)
    w2 = w * w
    sine = w * (np.float32(1.0) + w2 * (np.float32(-1.0 / 6.0) + w2 * (
        np.float32(1.0 / 120.0) + w2 * (np.float32(-1.0 / 5040.0)
                                       + w2 * np.float32(1.0 / 362880.0)))))
    return sine if u >= 0 else -sine


@numba.njit(inline="always", fastmath=_EXACT, cache=True)
def _texture_sum(x, y, z, freq, phase):  # pragma: no cover - compiled
    total = np.float32(0.0)
    for k in range(freq.shape[0]):
        total += _sin_turns(freq[k, 0] * x + freq[k, 1] * y + freq[k, 2] * z + phase[k])
    return total


@numba.njit(parallel=True, fastmath=_EXACT, cache=True)
def _sinusoid_sum(points, freq, phase, out):  # pragma: no cover - compiled
    for i in numba.prange(points.shape[0]):
        out[i] = _texture_sum(points[i, 0], points[i, 1], points[i, 2], freq, phase)


@numba.njit(parallel=True, fastmath=_EXACT, cache=True)
def shade(origin, directions, t, ids, uv, corner, light, params, freq, phase,
           out):  # pragma: no cover - compiled
    """Radiance per ray; params = ambient, diffuse, background, albedo mid, half-range,
    1/(2 σ_T), specular, shininess.  Corner normals interpolated barycentrically,
    texture at the hit point; the Blinn-Phong term only where specular > 0."""
    for i in numba.prange(t.shape[0]):
        tri = ids[i]
        if tri < 0:
            out[i] = params[2]
            continue
        u, v = uv[i, 0], uv[i, 1]
        w = np.float32(1.0) - u - v
        nx = w * corner[tri, 0, 0] + u * corner[tri, 1, 0] + v * corner[tri, 2, 0]
        ny = w * corner[tri, 0, 1] + u * corner[tri, 1, 1] + v * corner[tri, 2, 1]
        nz = w * corner[tri, 0, 2] + u * corner[tri, 1, 2] + v * corner[tri, 2, 2]
        dx, dy, dz = directions[i, 0], directions[i, 1], directions[i, 2]
        if nx * dx + ny * dy + nz * dz > 0:  # seen from behind: shade the side seen
            nx, ny, nz = -nx, -ny, -nz
        norm = np.sqrt(nx * nx + ny * ny + nz * nz)
        lambert = max((nx * light[0] + ny * light[1] + nz * light[2]) / norm, np.float32(0.0))
        x = origin[0] + t[i] * dx
        y = origin[1] + t[i] * dy
        z = origin[2] + t[i] * dz
        albedo = params[3] + params[4] * np.tanh(_texture_sum(x, y, z, freq, phase) * params[5])
        out[i] = albedo * (params[0] + params[1] * lambert)
        if params[6] > 0 and lambert > 0:
            # half vector of the light and the direction back to the camera (-d)
            dn = np.sqrt(dx * dx + dy * dy + dz * dz)
            hx = light[0] - dx / dn
            hy = light[1] - dy / dn
            hz = light[2] - dz / dn
            hn = np.sqrt(hx * hx + hy * hy + hz * hz)
            cos_h = (nx * hx + ny * hy + nz * hz) / (norm * hn)
            if cos_h > 0:
                out[i] += params[6] * cos_h ** params[7]


def quiet_numba(function, *args):
    """Call a parallel kernel with numba's one-time TBB-version warning silenced."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", numba.NumbaWarning)
        return function(*args)


@dataclass(frozen=True)
class SinusoidTexture:
    """Solid band-limited texture: albedo of a 3D point (see the module equations).

    Attributes
    ----------
    frequencies : (K, 3) float64, cycles per scene unit.
    phases : (K,) float64, turns.
    albedo : (2,) albedo range [min, max].
    """

    frequencies: np.ndarray
    phases: np.ndarray
    albedo: tuple[float, float]

    @classmethod
    def random(cls, components: int, wavelength: tuple[float, float], albedo, rng):
        """Draw K components: |f| log-uniform in [1/λmax, 1/λmin], isotropic directions."""
        direction = rng.standard_normal((components, 3))
        direction /= np.linalg.norm(direction, axis=1, keepdims=True)
        lo, hi = np.log(1.0 / wavelength[1]), np.log(1.0 / wavelength[0])
        magnitude = np.exp(rng.uniform(lo, hi, components))
        return cls(direction * magnitude[:, None], rng.uniform(0.0, 1.0, components),
                   (float(albedo[0]), float(albedo[1])))

    def raw(self, points: np.ndarray) -> np.ndarray:
        """The sum T(X) of the K sinusoids at ``points (N, 3)``; returns ``(N,) float32``."""
        points = np.ascontiguousarray(points, dtype=np.float32)
        out = np.empty(len(points), dtype=np.float32)
        if len(points):
            quiet_numba(_sinusoid_sum, points, self.frequencies.astype(np.float32),
                         self.phases.astype(np.float32), out)
        return out

    @property
    def sigma(self) -> float:
        """Standard deviation of T over space, sqrt(K / 2)."""
        return math.sqrt(len(self.phases) / 2.0)

    def __call__(self, points: np.ndarray) -> np.ndarray:
        """Albedo at ``points (N, 3)`` scene units; returns ``(N,) float32`` in the albedo range."""
        mid = 0.5 * (self.albedo[0] + self.albedo[1])
        half = 0.5 * (self.albedo[1] - self.albedo[0])
        return (mid + half * np.tanh(self.raw(points) / np.float32(2.0 * self.sigma))).astype(
            np.float32)
