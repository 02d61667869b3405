"""A rectified stereo pair with exact disparity: periodic tiles, a fluted box, blank walls.

Two pinhole cameras with parallel axes (focal ``F`` px, baseline ``B`` along x: already
rectified, rows correspond) look at

* a **wall** slanted about the vertical axis, Z = ``WALL_Z`` + ``WALL_SLOPE`` X: on its left
  half glazed **tiles** (flat squares of one grey, a dark grout line between them, period
  ``TILE`` scene units: periodic and blank at once), on its right half a band-limited
  random **poster**, with a **blank** strip (one grey) between them;
* a **box** front face, the plane Z = ``BOX_Z`` (an occluding step in depth), carrying
  vertical **flutes** (a smooth sinusoid across x, constant along y: periodic along the
  rows, an aperture problem everywhere on it) on its left part and the poster on the rest.

Each pixel is the mean of ``supersample``² ray casts inside it (an area sensor), the right
image gets a gain, an offset and its own noise.  The truth is exact: the left pixel centre's
ray hits a surface at depth Z, its disparity is F B / Z (x_right = x_left - d), and it is
visible in the right view when the right camera's ray to that point does not cross the box
first and lands inside the image.  Images ``(H, W)`` float64 grey levels.

:func:`tiles_figures` measures ``match_pair(rectified=True)`` on it against SGBM
(``benchmarks/matching.py --part tiles``, ``tests/matching/test_pair_tiles.py``): LSM's
accepted share (of all candidates; of those with an answer to find: not ``textureless``,
not ``outside_image``), the share of points more than 1 px off (LSM: every accepted
point; SGBM, OpenCV 3-way with uniqueness ratio 10 and 15 over the scene's disparity
range: every pixel it keeps), the same on the candidates both keep, and per region.
"""

from __future__ import annotations

import time

import numpy as np

from matching.pair import PAIR_STATUS_NAMES, match_pair
from matching.seeds import sgbm_disparity
from testkit.warps import sample, texture_coefficients

W, H = 400, 300
F, B = 420.0, 0.3
CX, CY = (W - 1) / 2, (H - 1) / 2
WALL_Z, WALL_SLOPE = 4.0, 0.35
BOX_Z = 2.5
BOX = (-0.55, 0.25, -0.35, 0.3)  # x0, x1, y0, y1 of the box face, scene units
TILE, GROUT = 0.2, 0.025
FLUTE = 0.05  # flute period on the box, scene units (~8 px at BOX_Z)
BLANK = (-0.35, 0.0)  # the wall's blank strip, x range


def _hit(cx: float, x: np.ndarray, y: np.ndarray):
    """The surface each ray of a camera at (cx, 0, 0) through pixel (x, y) hits first:
    (X, Y, Z, on_box)."""
    dx, dy = (x - CX) / F, (y - CY) / F
    # the box face: Z = BOX_Z
    bx, by = cx + BOX_Z * dx, BOX_Z * dy
    on_box = (bx >= BOX[0]) & (bx <= BOX[1]) & (by >= BOX[2]) & (by <= BOX[3])
    # the wall: t = (WALL_Z + WALL_SLOPE cx) / (1 - WALL_SLOPE dx)
    t = (WALL_Z + WALL_SLOPE * cx) / (1.0 - WALL_SLOPE * dx)
    t = np.where(on_box, BOX_Z, t)
    return cx + t * dx, t * dy, t, on_box


def _texture(coef, X, Y, Z, on_box):
    """Grey level of the surface point (X, Y, Z)."""
    poster = sample(coef, 100.0 + 38.0 * X, 100.0 + 38.0 * Y)  # inside the tile, no mirror
    # wall: tiles left of the blank strip, the blank strip, the poster right of it
    u, v = np.mod(X, TILE), np.mod(Y, TILE)
    grout = (u < GROUT) | (v < GROUT)
    tiles = np.where(grout, 70.0, 185.0)
    wall = np.where(X < BLANK[0], tiles, np.where(X < BLANK[1], 150.0, poster))
    # box: flutes on its left part, the poster on the rest
    flutes = 128.0 + 45.0 * np.sin(2 * np.pi * X / FLUTE)
    box = np.where(X < -0.15, flutes, poster)
    return np.where(on_box, box, wall)


def render(cx: float, coef, supersample: int = 3) -> np.ndarray:
    """The view of the camera at (cx, 0, 0): each pixel the mean over a
    ``supersample`` x ``supersample`` grid inside it."""
    ys, xs = np.mgrid[0:H, 0:W].astype(np.float64)
    acc = np.zeros((H, W))
    offs = (np.arange(supersample) + 0.5) / supersample - 0.5
    for oy in offs:
        for ox in offs:
            X, Y, Z, on_box = _hit(cx, xs + ox, ys + oy)
            acc += _texture(coef, X, Y, Z, on_box)
    return acc / supersample**2


def truth_disparity() -> tuple[np.ndarray, np.ndarray]:
    """(H, W) disparity of every left pixel centre (x_right = x - d), and (H, W) bool:
    visible in the right view (not occluded by the box, inside the image)."""
    ys, xs = np.mgrid[0:H, 0:W].astype(np.float64)
    X, Y, Z, on_box = _hit(0.0, xs, ys)
    d = F * B / Z
    # the right camera's ray to (X, Y, Z) crosses the box plane at ...
    s = BOX_Z / Z
    bx, by = B + s * (X - B), s * Y
    hidden = ~on_box & (bx >= BOX[0]) & (bx <= BOX[1]) & (by >= BOX[2]) & (by <= BOX[3])
    xr = xs - d
    return d, ~hidden & (xr >= 0) & (xr <= W - 1)


def tiles_pair(noise: float = 2.0, gain: float = 1.08, offset: float = -6.0,
               seed: int = 0, supersample: int = 3):
    """(left, right, disparity, visible): the rendered rectified pair and its truth."""
    coef = texture_coefficients(200, blur=1.2, seed=seed + 5)
    rng = np.random.default_rng(seed)
    left = render(0.0, coef, supersample) + rng.normal(0.0, noise, (H, W))
    right = (gain * render(B, coef, supersample) + offset
             + rng.normal(0.0, noise, (H, W)))
    d, visible = truth_disparity()
    return left, right, d, visible


SGBM_RATIOS = (10, 15)
_CODE = {name: code for code, name in PAIR_STATUS_NAMES.items()}


def regions(x_left: np.ndarray) -> np.ndarray:
    """(N,) region name of each left pixel's surface point."""
    X, _, _, on_box = _hit(0.0, x_left[:, 0], x_left[:, 1])
    wall = np.where(X < BLANK[0], "tiles",
                    np.where(X < BLANK[1], "blank", "poster"))
    return np.where(on_box, np.where(X < -0.15, "flutes", "box poster"), wall)


def tiles_figures(seed: int = 0, **match_options) -> dict:
    """Every figure of the tiles pair (``match_options`` go to ``match_pair``)."""
    left, right, truth, visible = tiles_pair(seed=seed)
    # the scene's disparity range, 16-aligned for SGBM (the truth is 26.3-50.4 px)
    dmin = int(np.floor(truth[visible].min() / 16) * 16)
    count = int(np.ceil((truth[visible].max() - dmin + 1) / 16) * 16)
    t0 = time.process_time()
    m = match_pair(left, right, rectified=True, search_range=(dmin, count), **match_options)
    cpu = time.process_time() - t0
    xi = np.rint(m.x_left).astype(np.intp)
    d_true = truth[xi[:, 1], xi[:, 0]]
    vis = visible[xi[:, 1], xi[:, 0]]
    d_lsm = m.x_left[:, 0] - m.x_right[:, 0]
    off = np.abs(d_lsm - d_true) > 1.0
    acc = m.accepted
    answerable = ~np.isin(m.status, [_CODE["textureless"], _CODE["outside_image"]])
    out = {"image": [W, H], "candidates": int(len(acc)),
           "answerable": int(answerable.sum()), "cpu_seconds": cpu,
           "lsm": {"accepted": int(acc.sum()), "accepted_share": float(acc.mean()),
                   "accepted_share_of_answerable": float(acc[answerable].mean()),
                   "accepted_occluded": int((acc & ~vis).sum()),
                   "beyond_1px": float(np.mean(off[acc])) if acc.any() else float("nan"),
                   "status": m.status_counts()},
           "sgbm": {}}
    reg = regions(m.x_left)
    for ratio in SGBM_RATIOS:
        disp = sgbm_disparity(left, right, dmin, count, uniqueness=ratio).astype(np.float64)
        d_s = disp[xi[:, 1], xi[:, 0]]
        kept = np.isfinite(d_s)
        s_off = kept & (np.abs(d_s - d_true) > 1.0)
        both = kept & acc
        out["sgbm"][str(ratio)] = {
            "kept": int(kept.sum()), "kept_share": float(kept.mean()),
            "beyond_1px": float(np.mean(s_off[kept])),
            "both": int(both.sum()),
            "both_lsm_beyond_1px": float(np.mean(off[both])),
            "both_sgbm_beyond_1px": float(np.mean(s_off[both])),
            "regions": {r: {"kept_share": float(kept[reg == r].mean()),
                            "beyond_1px": float(np.mean(s_off[kept & (reg == r)]))
                            if (kept & (reg == r)).any() else float("nan")}
                        for r in np.unique(reg)}}
    out["lsm"]["regions"] = {
        r: {"candidates": int((reg == r).sum()), "accepted_share": float(acc[reg == r].mean()),
            "beyond_1px": float(np.mean(off[acc & (reg == r)]))
            if (acc & (reg == r)).any() else float("nan"),
            "median_abs_error_px": float(np.median(np.abs(d_lsm - d_true)[acc & (reg == r)]))
            if (acc & (reg == r)).any() else float("nan")}
        for r in np.unique(reg)}
    return out
