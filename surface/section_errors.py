r"""The dense rings' errors across sections, and a thinned candidate's estimated error to the truth.

*The rings' errors* (:func:`section_variogram`): ``γ(k) = ½ E|ε_{i+k} − ε_i|²`` across sections,
from 6th differences at lags 1..12, fitted by a nugget + exponential model (:class:`Variogram`);
:func:`section_scatter` gives their σ from 4th differences where no variogram can be fitted.

*A candidate's error* (:func:`risk_estimate`): with ``S`` its smoothing across sections
(``surface.section_regression.smoothing_matrix``),
``E|Sx − truth|² = E|Sx − x|² − 2 Σ_j S_ij γ(|i − j|) + sill`` (Stein's unbiased risk estimate [1]
for correlated errors), ``|Sx − x|`` the distances from a fixed sample of dense vertices to the
candidate's surface.

*The goal* (:func:`stitched_surface_error`): the stitched mesh's own error over its faces,
``sill + E d_q² − E d_v²`` (points on the dense faces against the dense vertices).  Distances in
scene units, variances in scene units².

References
----------
.. [1] C. M. Stein, Annals of Statistics 9 (1981) 1135-1151; C. L. Mallows, "Some comments
   on Cp", Technometrics 15 (1973) 661-675.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from checks.robust import MAD_TO_SIGMA
from surface.ring_resample import resample_at_angles
from surface.section_chains import (
    aligned_rings,
    area_centroid,
    loop_chains,
    plane_frame,
    section_heights,
    single_loop,
)

__all__ = ["Variogram", "error_estimate", "ring_noise", "ring_precision", "risk_estimate",
           "section_scatter", "section_variogram", "stitched_error", "stitched_surface_error",
           "unshared_noise"]


def ring_precision(fits: Sequence) -> float:
    """The dense rings' precision σ_ring: the median of the rings' own σ (module notes).

    Parameters
    ----------
    fits : sequence
        ``surface.catmull_rom.RingFit`` records, or lists of them (one per section, as
        ``predict_sections(..., fits=True)`` returns them).

    Returns
    -------
    float
        Scene units; 0 when no ring has a noise estimate (noise-free points give 0 too).
    """
    values = [float(f.precision) for item in fits
              for f in ([item] if hasattr(item, "precision") else list(item))]
    values = [v for v in values if np.isfinite(v)]
    return float(np.median(values)) if values else 0.0


def ring_noise(rings: Sequence, axis, precision: float = 0.0, points_noise: float = 0.0
               ) -> float:
    """σ of the dense rings' errors: their scatter between sections (:func:`section_scatter`),
    else the fits' own precision σ_ring (:func:`ring_precision`), else the points' σ̂;
    scene units (0 if none is known)."""
    for value in (section_scatter(rings, axis), precision, points_noise):
        if value is not None and np.isfinite(value) and value > 0:
            return float(value)
    return 0.0


#: Consecutive sections of one 4th difference, and its noise gain Σ c² = 1+16+36+16+1.
_D4 = np.array([1.0, -4.0, 6.0, -4.0, 1.0])


def section_scatter(rings: Sequence, axis=(0.0, 0.0, 1.0)) -> float:
    """The dense rings' error measured from their scatter between neighbouring sections.

    The rings are resampled to one count at the same polar angles about the window's
    mean centroid (:func:`resample_at_angles`: the rings' own first points are not
    aligned from section to section), and at each point of five consecutive sections,
    equally spaced, of one loop followed from section to section (:func:`loop_chains`:
    a stack of single loops, or a branch's loops related one to one), the 4th
    difference across the sections ``x_{k-2} - 4x_{k-1} + 6x_k - 4x_{k+1} + x_{k+2}``
    is taken along the middle ring's in-plane radial direction: the profile's shape up
    to a cubic cancels and the rings' independent errors add up to 70 σ², so
    ``σ = 1.4826 · median|d4| / √70`` (robust to the rims and to branch events).
    Each ring is fitted to its own section's points, so their errors are independent
    from section to section, whatever their correlation along the ring.

    Only single-loop sections were read before: on the real temple ring (plinth, four
    columns, entablature) that left one window of five sections, whose L-shaped loops
    were 45 % bridged gaps, and the estimate moved 4x with how the gaps were filled; its
    columns' chains give ~200 windows.

    Parameters
    ----------
    rings : sequence
        One entry per section, ``(M, 3)`` or a list of loops.
    axis : (3,) float64
        The sections' common normal.

    Returns
    -------
    float
        Scene units; ``nan`` when no loop runs through five consecutive sections.
    """
    frame = plane_frame(axis)
    axis = frame[2]
    heights = section_heights(rings, frame[2])
    values = []
    for sections, chain in loop_chains(rings, frame):
        if len(chain) < 5:
            continue
        count = min(len(loop) for loop in chain)
        for k in range(2, len(chain) - 2):
            gaps = np.diff(heights[sections[k - 2:k + 3]])
            if np.ptp(gaps) > 0.25 * abs(float(np.median(gaps))):
                continue
            window = aligned_rings(chain, np.arange(k - 2, k + 3), count, frame)
            if window is None:
                continue
            d4 = np.tensordot(_D4, window, axes=1)                      # (count, 3)
            radial = window[2] - window[2].mean(axis=0)
            radial -= np.outer(radial @ axis, axis)
            radial /= np.maximum(np.linalg.norm(radial, axis=1), 1e-300)[:, None]
            values.append(np.einsum("ij,ij->i", d4, radial))
    if not values:
        return float("nan")
    return float(MAD_TO_SIGMA * np.median(np.abs(np.concatenate(values))) / np.sqrt(_D4 @ _D4))


#: 6th difference across seven sections (cancels the profile up to a quintic) and its
#: noise gain Σ c².
_D6 = np.array([1.0, -6.0, 15.0, -20.0, 15.0, -6.0, 1.0])


#: Largest lag (in sections) of the measured variogram.
MAX_LAG = 12


#: Fewest windows (of seven sections) a lag of the variogram is measured on.
MIN_WINDOWS = 5


#: The 6th differences' mean squares of the :class:`Variogram` model are concave in the
#: lag L (``504 p L/r − 56 p (L/r)³ + …`` from the nugget's level, then saturating at
#: ``924 sill``), so they grow no faster than L; a profile that the 6th differences do not
#: cancel grows as L¹² (a rounded end's last sections, where the profile's 6th derivative
#: is large).  :func:`section_variogram` stops at the first lag whose mean square exceeds
#: the previous one's times ``L / L_prev`` by more than this share (a margin for the
#: medians' sampling scatter, ~5 %).  The profile of a shape of revolution is taken out
#: before (the spread about each window's mean over the ring: on a 10⁵-point capsule,
#: σ 0.002, the mean squares had run 3.8e-4 flat to lag 5 and 5.5e-4 .. 1.0e-3 beyond, a
#: fitted sill of 1.9e-3); this stop guards against a profile that varies with the angle.
PROFILE_MARGIN = 0.25


@dataclass
class Variogram:
    """The dense rings' errors across sections: ``γ(k) = ½ E|ε_{i+k} − ε_i|²``.

    Modelled as a nugget (errors independent between sections) plus an exponential
    part (errors shared by neighbouring sections, e.g. one camera pair's bias seen in
    several sections): ``γ(k) = nugget + partial (1 − exp(−k / range))`` for ``k >= 1``,
    ``γ(0) = 0``; variances in scene units².  Only differences of the rings' errors are
    measurable, so an error common to all sections (a scale or offset of the whole
    cloud) is not in it -- and needs not be: it moves every candidate and the dense mesh
    alike.  ``lags`` / ``measured``: the measurements it was fitted to.
    """

    nugget: float
    partial: float = 0.0
    range: float = 1.0
    lags: tuple = ()
    measured: tuple = ()

    @classmethod
    def white(cls, sigma: float) -> Variogram:
        """Independent errors of σ (``γ(k) = σ²`` for ``k >= 1``)."""
        return cls(float(sigma) ** 2)

    @property
    def sill(self) -> float:
        """``γ(∞)``: the variance of one ring's error about the sections' common error."""
        return self.nugget + self.partial

    def __call__(self, k) -> np.ndarray:
        k = np.abs(np.asarray(k, dtype=np.float64))
        value = self.nugget + self.partial * (1.0 - np.exp(-k / max(self.range, 1e-12)))
        return np.where(k == 0, 0.0, value)

    def to_json(self) -> dict:
        return {"nugget": self.nugget, "partial": self.partial, "range": self.range,
                "lags": list(self.lags), "measured": list(self.measured)}


def _radial_profiles(rings: Sequence, axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each single-loop ring's distance from its own centroid at the common polar angles
    ``2πj/M`` (M the smallest ring), ``(K, M)`` with NaN rows for sections with several
    loops or not star-shaped; and the sections' heights.

    A ring's own area centroid as its centre (:func:`area_centroid`): the centroids'
    drift along the axis is a smooth function of the height, which the 6th differences
    cancel like the profile itself.
    """
    frame = plane_frame(axis)
    single = [single_loop(entry) for entry in rings]
    count = min(len(loop) for loop in single if loop is not None)
    out = np.full((len(rings), count), np.nan)
    for k, loop in enumerate(single):
        if loop is None:
            continue
        centre = area_centroid(loop, frame)
        aligned = resample_at_angles(loop, count, centre, frame)
        if aligned is not None:
            flat = (aligned - centre) @ frame[:2].T
            out[k] = np.hypot(flat[:, 0], flat[:, 1])
    return out, section_heights(rings, frame[2])


def section_variogram(rings: Sequence, axis=(0.0, 0.0, 1.0), max_lag: int = MAX_LAG
                      ) -> Variogram | None:
    """The dense rings' variogram across sections, measured from the data.

    At each lag ``L`` the 6th difference over every ``L``-th section,
    ``Σ c_m r_{i+mL}(θ)`` with ``c = (1, −6, 15, −20, 15, −6, 1)``, of the rings' radii at
    common polar angles (:func:`_radial_profiles`) cancels the profile up to a quintic;
    its mean square is ``−Σ_{m≠m'} c_m c_m' γ(|m − m'| L)`` (``924 γ`` for independent
    errors).  Per lag, the median over the windows (seven equally spaced single-loop
    sections, spanning at most half the sections) of each window's mean square over
    the ring: a mean square within the window, because the errors are heavier-tailed
    than a Gaussian and the sizing compares mean squares (on the demo's rings a median
    of the single values under-stated γ by 15 % against the truth); a median across
    windows, because one odd ring spoils every window that holds it (the densified
    demo's cloud: one ring made 3 % of the lag-1 windows 12× the rest, and a mean
    square with the largest 1 % clipped gave 2.6× the truth's sill).  The lags
    ``1 .. max_lag`` are fitted by the model of :class:`Variogram` (log least squares);
    checked against the truth by ``benchmarks/demo_truth.py`` (``docs/decisions/sizing.md``,
    *The variogram against the truth*).

    Returns
    -------
    Variogram or None
        None when fewer than seven consecutive single-loop sections exist.
    """
    axis = np.asarray(axis, dtype=np.float64)
    if len(rings) < len(_D6) or sum(single_loop(e) is not None for e in rings) < len(_D6):
        return None
    radii, heights = _radial_profiles(rings, axis)
    pairs = [np.sum(_D6[:-d] * _D6[d:]) for d in range(1, len(_D6))]
    lags, measured = [], []
    for lag in range(1, max(1, int(max_lag)) + 1):
        span = (len(_D6) - 1) * lag
        if span >= len(rings) or (lag > 1 and span > len(rings) // 2):
            break
        starts = np.arange(len(rings) - span)
        index = starts[:, None] + lag * np.arange(len(_D6))[None, :]       # (W, 7)
        gaps = np.diff(heights[index], axis=1)
        median_gap = np.median(gaps, axis=1)
        even = np.ptp(gaps, axis=1) <= 0.25 * np.abs(median_gap)
        values = np.tensordot(radii[index[even]], _D6, axes=([1], [0]))     # (W', M)
        values = values[np.isfinite(values).all(axis=1)]
        if len(values) < MIN_WINDOWS:
            break
        # About the window's mean over the ring: a shape of revolution's profile term is
        # the same at every angle, so what the 6th differences leave of it near a rounded
        # end goes; the rings' errors lose their mean over the ring (mode 0), put back
        # below from lag 1, where the profile term is smallest.
        spread = float(np.median(np.var(values, axis=1)))
        if not lags:
            mode0 = float(np.median(np.mean(values ** 2, axis=1))) / max(spread, 1e-300)
        mean_square = spread * mode0
        if lags and mean_square > (1.0 + PROFILE_MARGIN) * measured[-1] * lag / lags[-1]:
            break   # growing faster than any variogram of the model can: the profile
        lags.append(lag)
        measured.append(mean_square)
    if not lags:
        return None
    lags_a, measured_a = np.array(lags, dtype=np.float64), np.array(measured)

    def model(params):
        g = Variogram(*np.exp(params))
        return np.array([-2.0 * sum(pairs[d - 1] * g(d * lag) for d in range(1, len(_D6)))
                         for lag in lags_a])

    white = float(measured_a[0] / (_D6 @ _D6))
    if len(lags) < 3:
        return Variogram(white, 0.0, 1.0, tuple(lags), tuple(measured))
    start = np.log([white, white, 2.0])
    fit = least_squares(lambda p: np.log(model(p) / measured_a), start,
                        bounds=(np.log([white * 1e-4, white * 1e-6, 0.1]),
                                np.log([white * 10, white * 1e3, 4.0 * lags_a[-1]])))
    nugget, partial, rng = (float(x) for x in np.exp(fit.x))
    return Variogram(nugget, partial, rng, tuple(lags), tuple(measured))


def unshared_noise(matrix: np.ndarray, variogram: Variogram) -> np.ndarray:
    """Per dense section ``i``, ``Σ_j S_ij γ(|i − j|)``: how much of the dense rings' error
    the thinned surface does *not* share with the ring at ``i`` (``E⟨(I − S)ε, ε⟩_i``
    for rows of ``S`` summing to 1), the correlated-noise form of ``σ² (1 − S_ii)``."""
    lag = np.abs(np.arange(len(matrix))[:, None] - np.arange(len(matrix))[None, :])
    return np.einsum("ij,ij->i", matrix, variogram(lag))


def risk_estimate(distances: np.ndarray, variogram: Variogram, unshared: float) -> float:
    """RMS error to the truth of a thinned surface, from its distances to the dense
    vertices, for errors correlated across sections.

    With ``x = truth + ε`` the dense vertices and ``S x`` the thinned surface at them,
    ``E|Sx − truth|² = E|Sx − x|² − 2 E⟨(I − S)ε, ε⟩ + E|ε|²``; with rows of ``S``
    summing to 1, ``E⟨(I − S)ε, ε⟩ = Σ_j S_ij γ(|i − j|)`` (``unshared``, the mean of
    :func:`unshared_noise` over the reference vertices' sections) and ``E|ε|²`` is the
    variogram's sill (an error common to all sections is left out: it is in every
    surface alike).  For independent errors (``γ = σ²``) it is Stein's estimate,
    :func:`error_estimate`.

    Returns
    -------
    float
        Scene units (0 if the estimate is negative).
    """
    mean_square = float(np.mean(np.square(distances)))
    return float(np.sqrt(max(mean_square - 2.0 * unshared + variogram.sill, 0.0)))


def stitched_error(variogram: Variogram) -> float:
    """RMS error to the truth of the dense stitched mesh over its surface (not at its
    vertices): a point of a triangle with barycentrics ``b`` errs by ``Σ b_i ε_i``, whose
    mean square over the triangle is ``sill − Σ_{i<j} E[b_i b_j] 2γ_ij = sill −
    (γ_a + 2 γ(1)) / 6`` (``E[b_i b_j] = 1/12``; two vertices on one ring, ``γ_a`` their
    variogram along the ring, one on the next section); ``γ_a`` is taken as ``γ(1)``,
    which under-states the stitched mesh's error (the demo's rings: ``γ_a`` = 3.5e-5² by
    the truth) and so makes the sizing stricter.  This, not the error at the vertices,
    is what a mean distance to the truth (Chamfer) sees: for independent errors
    ``σ/√2``, the 0.56 σ mean distance of a polyhedron through noisy vertices against a
    smooth surface's √(2/π) of its RMS error.
    """
    return float(np.sqrt(max(variogram.sill - 0.5 * float(variogram(1)), 0.0)))


def stitched_surface_error(distances: np.ndarray, face_distances: np.ndarray | None,
                           variogram: Variogram) -> float:
    """RMS error to the truth of the dense stitched mesh over its surface, measured against
    a candidate's smooth surface.

    Points ``q`` spread over the dense mesh's faces err by their vertices' errors
    interpolated (``Σ b_i ε_i``, smaller than at the vertices: :func:`stitched_error`)
    plus the flat triangles' chord error (``κ h² / 8`` at an edge's middle: on a coarse
    dense mesh -- few points a section -- as large as the noise).  Both show in their
    distances to any fixed smooth surface as against the vertices' distances:
    ``E d_q² − E d_v² ≈ R_q − R_v`` for a surface whose own error is not correlated with
    the chords, so ``R_q = sill + E d_q² − E d_v²`` (``sill`` = ``R_v``, the vertices'
    error, :class:`Variogram`), and at least :func:`stitched_error` (the interpolated
    noise without chords: a coarse candidate, whose own error follows the chords,
    measures less).  Measured to the exact surface: its tessellation lies
    inside it by its own chords, which cancel part of the dense faces' (by
    ``2 c_dense c_tess``): on the 10⁵-point vase the tessellation's goal was 7 % low and
    took a candidate 1.6× finer.  Without face points (a mesh all rims), the model value
    :func:`stitched_error`.

    Parameters
    ----------
    distances : (N,) float64
        From the reference vertices to the candidate's surface.
    face_distances : (N',) float64 or None
        From points on the dense faces (``_points_on_faces``) to it, measured the same
        way (the far candidates' first check uses the tessellation for both).
    variogram : Variogram

    Returns
    -------
    float
        Scene units.
    """
    if face_distances is None:
        return stitched_error(variogram)
    shift = float(np.mean(np.square(face_distances)) - np.mean(np.square(distances)))
    # never below the interpolated noise alone (chords only add to it): a candidate far
    # from the data, whose own error follows the chords, would measure less
    return max(float(np.sqrt(max(variogram.sill + shift, 0.0))), stitched_error(variogram))


def error_estimate(distances: np.ndarray, noise: float, influence_mean: float) -> float:
    """RMS error to the truth of a surface fitted to noisy points, from its distances to them.

    Stein's unbiased risk estimate (Mallows' Cp): for points ``x = truth + ε``,
    ``ε ~ N(0, σ²)`` independent, and a fit ``S x`` linear in them, the mean squared
    error to the truth is ``E|Sx - x|² - σ² + 2σ²·tr(S)/N``; ``tr(S)/N`` is the mean
    influence of a point on the fit at itself (the diagonal of
    ``surface.section_regression.smoothing_matrix``).  A fit that copies the
    points (influence 1) gets σ, one that ignores them (0) ``sqrt(mean d² - σ²)``.

    Parameters
    ----------
    distances : (N,) float64
        From the dense vertices to the thinned surface, scene units.
    noise : float
        σ of the dense vertices (:func:`section_scatter`).
    influence_mean : float
        Mean influence over the same vertices.

    Returns
    -------
    float
        Scene units (0 if the estimate is negative).
    """
    mean_square = float(np.mean(np.square(distances)))
    return float(np.sqrt(max(mean_square - noise ** 2 * (1.0 - 2.0 * influence_mean), 0.0)))
