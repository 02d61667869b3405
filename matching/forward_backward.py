r"""Forward-backward matching: the loop error of LSM, a lower bound on its error.

LSM reports :math:`\Sigma_f = \sigma_0^2 N^{-1}` per match, which holds for white noise
and a model that fits (Gruen 1985).  Real photographs add correlated noise
(demosaicing, compression), blur and shading differences between the views and the
affine model's own error; none of them is in :math:`\sigma_0^2 N^{-1}`.  Matching
back measures them: a forward match :math:`p \to x` (template image to search image,
affine :math:`A`) gives, at the integer search pixel :math:`q = \operatorname{round}(x)`,
the prediction :math:`\hat p = p + A^{-1}(q - x)` in the template image, and the
backward LSM (search image as template, started from :math:`\hat p` with shape
:math:`A^{-1}` and the inverted radiometry) finds :math:`p'`.  The loop error, in
search-image pixels,

.. math::

    e = A\,(p' - \hat p), \qquad E\,[e e^\mathsf{T}] = \Sigma_f + A \Sigma_b A^\mathsf{T}

when both reported covariances are right.  The *variance factor*

.. math::

    k^2 = \frac{\sum |e|^2}{\sum \operatorname{tr}(\Sigma_f + A\Sigma_b A^\mathsf{T})}

over the loops (blunders beyond the 99 % point of the χ² distribution, 9.21 k² times
their expectation, left out, iterated) would be the factor by which the reported
variances must grow to explain the loops if the two matches were independent.  They are
not: both use the same pixels, whose noise moves both matches alike and cancels in the
loop.  On synthetic warps with white noise (``tests/matching/test_forward_backward.py``)
k² = 0.045 where LSM's σ is right to 5 %.  The loop sees only what differs between the
two directions (resampling of one image or the other, a blur difference, the affine
model's asymmetry): a *lower bound* on the matching error, not an estimate of σ; a
forward-backward "consistency" figure (and SGBM's left-right check alike) understates it.

References
----------
.. [1] A. W. Gruen, "Adaptive least squares correlation: a powerful image matching
   technique", S. Afr. J. Photogramm. Remote Sens. Cartogr. 14(3), 175-187 (1985).
.. [2] W. Förstner, "Ein Verfahren zur Schätzung von Varianz- und Kovarianzkomponenten",
   Allgemeine Vermessungs-Nachrichten 86, 446-453 (1979).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from matching.lsm import LSMResult, lsm_match
from matching.validate import check_shape

#: χ²(2 dof) 99 % point: loops beyond 9.21 x their expected |e|² are blunders.
_CHI2_2_99 = 9.21


@dataclass(frozen=True)
class ForwardBackward:
    """Loop errors of forward-backward matching (arrays over the N forward points).

    Attributes
    ----------
    loop : (N, 2) float64
        ``e`` of the module docstring, search-image px (NaN: no backward match).
    expected : (N,) float64
        ``tr(Σ_f + A Σ_b Aᵀ)``, px² (the reported variance of ``|e|²``).
    used : (N,) bool
        Loops in the variance factor (both matches accepted, not a blunder).
    variance_factor : float
        ``k²`` of the loops against the reported variances (NaN: fewer than 10
        loops); far below 1 even when σ is right (module docstring).
    """

    loop: np.ndarray
    expected: np.ndarray
    used: np.ndarray
    variance_factor: float

    @property
    def loop_rms(self) -> float:
        """RMS of ``|e| / sqrt(2)`` over the used loops, px: one match's error (RMS
        of the two axes' combined), when both directions err alike."""
        e = self.loop[self.used]
        return float(np.sqrt(np.mean(np.sum(e**2, axis=1)) / 2.0)) if len(e) else np.nan


def forward_backward(template_image, search_image, points, forward: LSMResult, *,
                     patch: int = 15, **lsm_options) -> ForwardBackward:
    """Match every accepted forward match back and measure the loop (module docstring).

    Parameters
    ----------
    template_image, search_image : (H, W) array_like or matching.lsm.PreparedImage
        The forward pair (the backward match swaps them).
    points : (N, 2) array_like
        Forward template centres, px.
    forward : LSMResult
        The forward matches of ``points``.
    patch : int
        Patch side, px.
    **lsm_options
        Passed to the backward :func:`matching.lsm.lsm_match` (``interpolation``...);
        no epipolar constraint (the loop is measured in both axes).

    Returns
    -------
    ForwardBackward
    """
    points = check_shape(points, "(N, 2)", "points", dtype=np.float64)
    n = len(points)
    loop = np.full((n, 2), np.nan)
    expected = np.full(n, np.nan)
    used = np.zeros(n, bool)
    ok = np.flatnonzero(forward.accepted & np.isfinite(forward.position).all(1))
    if len(ok) == 0:
        return ForwardBackward(loop, expected, used, float("nan"))
    x = forward.position[ok]
    a = forward.affine[ok][:, [1, 2, 4, 5]].reshape(-1, 2, 2)
    det = np.linalg.det(a)
    sane = np.abs(det) > 1e-6
    ok, x, a = ok[sane], x[sane], a[sane]
    a_inv = np.linalg.inv(a)
    q = np.rint(x)
    pred = points[ok] + np.einsum("nij,nj->ni", a_inv, q - x)
    r0, r1 = forward.radiometric[ok, 0], forward.radiometric[ok, 1]
    init = np.column_stack([pred[:, 0], a_inv[:, 0, 0], a_inv[:, 0, 1], pred[:, 1],
                            a_inv[:, 1, 0], a_inv[:, 1, 1], -r0 / r1, 1.0 / r1])
    options = {k: v for k, v in lsm_options.items() if k not in ("direction", "offset")}
    back = lsm_match(search_image, template_image, q, pred, patch=patch, initial=init,
                     **options)
    good = back.accepted
    e = np.einsum("nij,nj->ni", a, back.position - pred)
    cov_b = np.einsum("nij,njk,nlk->nil", a, back.cov, a)
    exp = (np.trace(forward.cov[ok], axis1=1, axis2=2) + np.trace(cov_b, axis1=1, axis2=2))
    loop[ok[good]] = e[good]
    expected[ok[good]] = exp[good]
    r = np.sum(e**2, axis=1) / exp
    keep = good & np.isfinite(r)
    k2 = float("nan")
    for _ in range(10):  # trim blunders at the chi-square 99 % point, re-estimate
        if keep.sum() < 10:
            k2 = float("nan")
            break
        new = float(np.sum(np.sum(e[keep] ** 2, axis=1)) / np.sum(exp[keep]))
        keep_new = good & np.isfinite(r) & (r <= _CHI2_2_99 * new)
        if np.array_equal(keep_new, keep) and np.isfinite(k2):
            k2 = new
            break
        k2, keep = new, keep_new
    used[ok[keep]] = True
    return ForwardBackward(loop, expected, used, k2)
