r"""Images for least-squares matching: the noise estimate and the resampler's prefilter.

:func:`estimate_noise` is Immerkaer's Laplacian-difference estimator [1]_ taken over the
flattest blocks of the image (texture would count as noise over the whole image);
:func:`prepare_image` computes it once per image together with the cubic B-spline
coefficients :func:`matching.lsm.lsm_match` resamples, so that several calls on the same
image share them (:class:`PreparedImage`).

References
----------
.. [1] J. Immerkaer, "Fast noise variance estimation", Computer Vision and
   Image Understanding 64(2), 300-302 (1996).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

INTERPOLATIONS = ("bilinear", "bicubic", "spline")
_KIND = {"bilinear": 0, "bicubic": 1, "spline": 2}
#: Default resampling: the cubic B-spline (see ``benchmarks/matching.py``: its
#: zero-noise bias is ~4x below bilinear's for ~1.3x the time).
DEFAULT_INTERPOLATION = "spline"


#: Block side of :func:`estimate_noise`'s flat-block estimate, px.
NOISE_BLOCK_PX = 16
#: Quantile of the block estimates taken as the noise (the flattest tenth).
NOISE_BLOCK_QUANTILE = 0.10
#: Relative spread of one block's Immerkaer estimate on white noise, times the block
#: side (Monte Carlo, 5 draws of 800x640 Gaussian noise: 1.37 at 16, 24 and 32 px);
#: the quantile of the block estimates is divided by 1 - z_q * this / side
#: (z_0.1 = 1.2816: 0.890 at 16 px, measured 0.890).
_NOISE_BLOCK_SPREAD = 1.37
#: Fewer unsaturated blocks than this: the global estimate alone.
_NOISE_MIN_BLOCKS = 20


def _immerkaer_abs(img: np.ndarray) -> np.ndarray:
    """|I * N| over the interior, N = [[1,-2,1],[-2,4,-2],[1,-2,1]], (H-2, W-2)."""
    return np.abs(img[:-2, :-2] - 2 * img[:-2, 1:-1] + img[:-2, 2:]
                  - 2 * img[1:-1, :-2] + 4 * img[1:-1, 1:-1] - 2 * img[1:-1, 2:]
                  + img[2:, :-2] - 2 * img[2:, 1:-1] + img[2:, 2:])


def estimate_noise(image: np.ndarray, flat_blocks: bool = True) -> float:
    """Image noise σ (grey levels) by Immerkaer's Laplacian-difference estimator [1]_.

    Immerkaer's σ = sqrt(π/2) / (6 (W-2)(H-2)) Σ |I * N| counts texture as noise: on
    a textured photograph it is an upper bound far above the noise (graffiti
    ``graf1.png``: 2.61 grey levels over the whole image, against 1.2-1.4 in its
    flattest tenth of 21x21 windows), and every threshold derived from it (the texture
    test, the noise correction of the covariance) then rejects real texture.  With
    ``flat_blocks`` (default) the estimate is taken where the texture adds least: the
    same estimator over ``NOISE_BLOCK_PX`` blocks, the 10th percentile of the blocks
    (corrected for the spread of a block estimate on pure noise, so that a noise image
    gives σ; where only a share s of the blocks is flat it is the (0.1/s)-th quantile of
    the flat ones, up to 1.11σ at s = 0.1), never above the global value.  Blocks
    holding a saturated pixel (the image's minimum or maximum value) are left out:
    clipping removes noise.

    Parameters
    ----------
    image : (H, W) array_like
        Grey image.
    flat_blocks : bool
        Use the flattest blocks (default); False: the global estimate.

    Returns
    -------
    float
        σ, grey levels.
    """
    img = np.asarray(image, dtype=np.float64)
    if img.ndim != 2 or min(img.shape) < 3:
        raise ValueError(f"image must be a 2-D array of at least 3x3, got shape {img.shape}")
    lap = _immerkaer_abs(img)
    scale = np.sqrt(np.pi / 2.0) / 6.0
    overall = float(scale * lap.mean())
    b = NOISE_BLOCK_PX
    ny, nx = lap.shape[0] // b, lap.shape[1] // b
    if not flat_blocks or ny * nx < _NOISE_MIN_BLOCKS:
        return overall
    blocks = lap[:ny * b, :nx * b].reshape(ny, b, nx, b).mean(axis=(1, 3))
    inner = img[1:1 + ny * b, 1:1 + nx * b]
    lo, hi = img.min(), img.max()
    clipped = ((inner <= lo) | (inner >= hi)).reshape(ny, b, nx, b).any(axis=(1, 3))
    usable = blocks[~clipped]
    if len(usable) < _NOISE_MIN_BLOCKS:
        return overall
    z = 1.2815515655446004  # standard normal 90 % quantile
    flat = scale * float(np.quantile(usable, NOISE_BLOCK_QUANTILE))
    flat /= 1.0 - z * _NOISE_BLOCK_SPREAD / b
    return min(overall, flat)


@dataclass(frozen=True)
class PreparedImage:
    """An image ready for :func:`matching.lsm.lsm_match`'s resampler.

    Attributes
    ----------
    values : (H, W) float64
        Pixel values, or cubic B-spline coefficients for ``interpolation == "spline"``.
    raw : (H, W) float64
        The pixel values themselves (templates at integer centres read them directly).
    noise : float
        Immerkaer noise estimate of the original image, grey levels.
    interpolation : str
        The resampler ``values`` is meant for.
    """

    values: np.ndarray
    raw: np.ndarray
    noise: float
    interpolation: str


def prepare_image(image, interpolation: str = DEFAULT_INTERPOLATION) -> PreparedImage:
    """Prepare an image once for several :func:`matching.lsm.lsm_match` calls (prefilter + noise).

    Parameters
    ----------
    image : (H, W) array_like
        Grey image, grey levels.
    interpolation : {"bilinear", "bicubic", "spline"}
    """
    if interpolation not in _KIND:
        raise ValueError(f"interpolation must be one of {INTERPOLATIONS}, got {interpolation!r}")
    img = np.ascontiguousarray(image, dtype=np.float64)
    if img.ndim != 2:
        raise ValueError(f"image must be a 2-D grey image, got shape {img.shape}")
    noise = estimate_noise(img)
    values = img
    if interpolation == "spline":
        values = ndimage.spline_filter(img, order=3, mode="mirror", output=np.float64)
    return PreparedImage(values=values, raw=img, noise=noise, interpolation=interpolation)
