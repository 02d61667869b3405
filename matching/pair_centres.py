"""Where and how the epipolar pass's accepted matches are reported.

Each at the left pixel nearest its window's information centre (Förstner's optimal point
p* = -C₁₁⁻¹c₁₀ of the constrained warp, :func:`_information_centres`); one that the shape
dominates where it is reported is ``aperture`` (:func:`_shape_dominated`); the pair's
edge-polarity bias (the two cameras render a rising and a falling edge δ apart) is
estimated from the matches alone and removed, one-signed windows get their own variance
factor, and a match off its neighbours' plane is ``off_surface``
(:func:`_polarity_bias`, :func:`_correct_polarity`).  :func:`_report_epipolar` runs them
in order.  Measured: ``docs/decisions/stereo-information-centre.md``, ``stereo-edges.md``.
"""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
from scipy.spatial import cKDTree

from checks.robust import MAD_TO_SIGMA, mad_sigma
from matching.lsm import LSMResult, Status
from matching.pair_epipolar import _jacobians, _least_variance_point
from matching.pair_status import APERTURE, CHI2_1_MEDIAN, MAX_INFLATION, OFF_SURFACE, OUTLIER_Z
from matching.rectify import left_to_rectified, rectified_to_original, right_to_rectified


def _report_epipolar(frame: dict, rect, rig, res: LSMResult, epi_dirs, status, cand_points,
                     idx, points, offset, x_left_out, width: int, centre_points: bool,
                     scale_cov: bool):
    """Where and how the epipolar pass's accepted matches are reported.

    Each at the left pixel nearest its window's information centre (``centre_points``:
    :func:`_information_centres`; its shape's extrapolation elsewhere carries the cameras'
    blur differences); one whose variance where it is reported the shape dominates is
    ``aperture`` (:func:`_shape_dominated`); the pair's edge-polarity bias removed, the
    one-signed windows' variance factor applied, and a match off its neighbours' plane
    rejected (:func:`_correct_polarity`).  ``status`` (over ``idx``) is updated in place.
    Returns the result, line directions, offsets, reported left points (None: the
    candidates) and the variance the polarity estimate leaves along the line (px²).
    """
    if centre_points:
        keys = (np.rint(cand_points[:, 1]) * width
                + np.rint(cand_points[:, 0])).astype(np.int64)
        plain = ~np.any(offset[idx] != 0.0, axis=1)  # eccentric windows stay
        mv, q, right_q, cov_q, dir_q = _information_centres(
            frame, rect, rig, (status == Status.OK) & plain, points, keys, width,
            scale_cov=scale_cov)
        if len(mv):
            position, cov_r = np.array(res.position), np.array(res.cov)
            position[mv], cov_r[mv] = right_q, cov_q
            res = replace(res, position=position, cov=cov_r)
            epi_dirs = np.array(epi_dirs)
            epi_dirs[mv] = dir_q
            x_left_out = np.array(cand_points) if x_left_out is None else x_left_out
            offset = offset.copy()
            offset[idx[mv]] = points[mv] - q  # the window centre from the point
            x_left_out[idx[mv]] = q
    # a window passed at its least-variance point but reported elsewhere
    reported = cand_points if x_left_out is None else x_left_out
    status[_shape_dominated(frame, rect, rig, status == Status.OK, reported[idx])] = APERTURE
    # the cameras' edge rendering: a rising and a falling edge matched δ apart
    polarity_var, edge_factor, off = _correct_polarity(frame, status == Status.OK)
    status[off] = OFF_SURFACE
    res = replace(res, position=res.position + frame["polarity_shift"][:, None] * epi_dirs,
                  cov=res.cov * edge_factor[:, None, None])
    return res, epi_dirs, offset, x_left_out, polarity_var



def _edge_polarity(image: np.ndarray, points: np.ndarray, sides: np.ndarray) -> np.ndarray:
    """(N,) the information-weighted polarity of each ``sides`` x ``sides`` window of
    ``image`` centred on the integer ``points``: Σ sign(f_x) f_x² / Σ f_x² (1: every
    gradient along the row rises, -1: every one falls, 0: balanced, e.g. a corner of a
    chessboard).  The shift along the row is Σ f_x e / Σ f_x², so a shift ±δ of the edges
    of each sign moves it by δ times this."""

    img = np.asarray(image, dtype=np.float64)
    gx = np.zeros_like(img)
    gx[:, 1:-1] = 0.5 * (img[:, 2:] - img[:, :-2])
    xi = np.rint(points).astype(np.intp)
    xi[:, 0] = np.clip(xi[:, 0], 0, img.shape[1] - 1)
    xi[:, 1] = np.clip(xi[:, 1], 0, img.shape[0] - 1)
    out = np.zeros(len(points))
    for side in np.unique(sides):
        sel = np.flatnonzero(sides == side)
        num, den = (cv2.boxFilter(p, -1, (int(side), int(side)), borderType=cv2.BORDER_REFLECT)
                    for p in (gx * np.abs(gx), gx * gx))
        with np.errstate(divide="ignore", invalid="ignore"):
            out[sel] = num[xi[sel, 1], xi[sel, 0]] / den[xi[sel, 1], xi[sel, 0]]
    return np.nan_to_num(out)



def _polarity_bias(frame: dict, accepted: np.ndarray, neighbours: int = 40,
                   rounds: int = 5) -> tuple[float, float, np.ndarray, np.ndarray,
                                            np.ndarray]:
    """The pair's edge-polarity bias along the row, δ (rectified px), its variance, and
    each window's polarity (:func:`_edge_polarity`; 0 where not accepted).

    The two cameras render an edge differently (blur, tone curve): LSM's linear
    radiometry then places a rising edge δ one way and a falling one δ the other, the
    same for the whole pair.  Estimated from the accepted matches at their
    least-variance points: each one's disparity against the least-squares plane of its
    ``neighbours`` nearest accepted windows that share none of its pixels (a surface is
    locally planar over a few windows; rectified disparity is exactly affine in the
    image over a plane), regressed on the polarity: d_i - plane_i = δ (s_i - plane of
    the s_j) (the neighbours carry the bias too), MAD-trimmed at 3.29 robust spreads.
    """

    n = len(accepted)
    s = np.zeros(n)
    k = np.flatnonzero(accepted & np.isfinite(frame["affine_cov_fin"][:, 0, 0])
                       & (frame["sides"] > 0))
    ratio = np.full(n, np.nan)
    near = np.full((n, neighbours), -1, np.intp)
    if len(k) < neighbours + 1:
        return 0.0, 0.0, s, ratio, near
    half = frame["sides"][k] // 2
    pstar, var = _least_variance_point(frame["affine_cov_fin"][k], half)
    inside = np.isfinite(var)
    pstar[~inside] = frame["frac"][k][~inside]
    a, fo = frame["affine_fin"][k], frame["frac"][k]
    xr = frame["position"][k, 0] + a[:, 1] * (pstar[:, 0] - fo[:, 0]) + a[:, 2] * (
        pstar[:, 1] - fo[:, 1])
    xl = frame["centre"][k] + pstar
    disp = xl[:, 0] - xr
    s_k = _edge_polarity(frame["fprep"].raw, frame["centre"][k], frame["sides"][k])
    s[k] = s_k
    tree = cKDTree(xl)
    m = min(len(k), 4 * neighbours)
    dist, nb = tree.query(xl, k=m)
    far = dist >= frame["sides"][k][:, None].astype(np.float64)  # shares no pixel
    order = np.argsort(~far, axis=1, kind="stable")[:, :neighbours]
    nb = np.take_along_axis(nb, order, axis=1)
    usable = np.take_along_axis(far, order, axis=1).all(axis=1)
    design = np.concatenate([np.ones((len(k), neighbours, 1)), xl[nb] - xl[:, None, :]],
                            axis=2)  # plane about the window's own point
    pinv = np.linalg.pinv(design)  # (K, 3, neighbours)
    own_d = np.einsum("kj,kj->k", pinv[:, 0, :], disp[nb])
    own_s = np.einsum("kj,kj->k", pinv[:, 0, :], s_k[nb])
    e, t = disp - own_d, s_k - own_s
    keep = usable & np.isfinite(e) & np.isfinite(t)
    delta, var_delta = 0.0, 0.0
    for _ in range(rounds):
        if keep.sum() < neighbours or np.sum(t[keep] ** 2) <= 0:
            return 0.0, 0.0, s, ratio, near
        delta = float(np.sum(e[keep] * t[keep]) / np.sum(t[keep] ** 2))
        r = e - delta * t
        spread = float(mad_sigma(r[keep]))
        keep_new = usable & (np.abs(r) <= 3.29 * spread)
        var_delta = spread**2 / float(np.sum(t[keep_new] ** 2))
        if np.array_equal(keep_new, keep):
            break
        keep = keep_new
    # each window's departure from its neighbours' plane over its own σ along the row
    var_own = np.where(inside, var, frame["affine_cov_fin"][k][:, 0, 0]) * frame["k2"][k]
    ratio[k] = np.where(usable, (e - delta * t) / np.sqrt(var_own), np.nan)
    near = np.full((n, neighbours), -1, np.intp)
    near[k] = k[nb]
    return delta, var_delta, s, ratio, near



def _correct_polarity(frame: dict, accepted: np.ndarray) -> tuple[np.ndarray, np.ndarray,
                                                                  np.ndarray]:
    """The pair's edge-polarity bias (:func:`_polarity_bias`) removed from the matches
    ``accepted``, and what one-signed edges leave.

    Sets ``frame["polarity_shift"]`` (N,), the shift of each right position along the line
    in the original right image (px).  Returns the variance the bias estimate leaves along
    the line there (px²), each match's variance factor for its edges' own errors, and the
    matches off the surface.  A window whose gradients along the row mostly share one sign
    holds one edge, whose rendering error it does not average with other edges': per
    quartile of |polarity| over the matches, the departures from the neighbours' plane
    over σ, against those of the most balanced quartile (all see the same surface), give
    the factor (never below 1).  Off the surface: a departure, in its class's units,
    beyond 3.29 robust spreads (1.4826 MAD) of its neighbours'.
    """
    delta, var_delta, pol, ratio, near = _polarity_bias(frame, accepted)
    step = np.sqrt(np.nan_to_num(frame["stretch"], nan=1.0))  # right px per rectified px
    frame["polarity_shift"] = np.where(accepted, delta * pol * step, 0.0)
    factor = np.ones(len(accepted))
    known = np.isfinite(ratio)
    outlier = np.zeros(len(accepted), bool)
    if known.sum() >= 4 * 30:
        # classes: the quartiles of |polarity| over the matches (the first, the most
        # balanced windows, the reference)
        edges = np.quantile(np.abs(pol[known]), [0.25, 0.5, 0.75])
        cls = np.searchsorted(edges, np.abs(pol), side="right")
        spread2 = np.array([np.median(ratio[known & (cls == c)] ** 2) for c in range(4)])
        spread2 = spread2 / CHI2_1_MEDIAN
        factor = np.where(accepted, np.maximum(1.0, spread2[cls] / spread2[0]), 1.0)
        # beyond the 99.9 % bound of the departures of its neighbours (in units of their
        # classes' spreads; a rougher surface, a wider bound): off the surface
        z = np.nan_to_num(ratio / np.sqrt(spread2[cls]), nan=np.inf)
        zn = np.where(near >= 0, np.abs(z[np.maximum(near, 0)]), np.inf)
        local = MAD_TO_SIGMA * np.median(zn, axis=1)
        outlier = accepted & known & (np.abs(z) > OUTLIER_Z * local)
    return np.where(accepted, var_delta * pol**2 * step**2, 0.0), factor, outlier



def _shape_dominated(frame: dict, rect, rig, which: np.ndarray, x_left: np.ndarray,
                     max_inflation: float = MAX_INFLATION) -> np.ndarray:
    """(N,) bool: the epipolar-pass matches ``which`` whose variance along the row at their
    reported left point ``x_left`` exceeds ``max_inflation`` x σ0² / Σ f_x² (the shape
    unknowns take the shift's information there: a one-edge window reported off its edge
    is extrapolated through its scale; the ``aperture`` test of
    :func:`matching.pair_epipolar._epipolar_refine`, made at the point reported instead
    of at the window's least-variance point)."""

    k = np.flatnonzero(which & np.isfinite(frame["unit"]))
    out = np.zeros(len(which), bool)
    if len(k) == 0:
        return out
    fn = left_to_rectified(rect, rig.left, x_left[k]) - frame["centre"][k]
    g = np.column_stack([np.ones(len(k)), fn])
    var = np.einsum("ni,nij,nj->n", g, frame["affine_cov_fin"][k][:, :3, :3], g)
    out[k] = ~(var * frame["unit"][k] <= max_inflation)
    return out



def _information_centres(frame: dict, rect, rig, accepted: np.ndarray, x_left: np.ndarray,
                         taken: np.ndarray, width: int, scale_cov: bool = True):
    """Report each accepted epipolar-pass match at its window's best-determined pixel.

    The constrained warp along the row, x' = a0 + a1 x + a2 y (+ the fixed second-order
    terms), gives the match of every template pixel; its variance gᵀ C g (g = (1, x, y),
    C the covariance of a0 a1 a2) is smallest at p* = -C₁₁⁻¹ c₁₀, the window's
    information centre (Förstner's optimal point of a window): where its gradients are.
    Anywhere else the match is extrapolated from there through the shape a1, a2, and
    the shape carries what the window model does not (the two cameras' different blur
    and resampling at an edge or a corner), multiplied by the lever arm |p - p*|
    (measured on the chessboard rig: docs/decisions/stereo-information-centre.md).

    Each accepted window (``accepted``, over the frame's candidates) is moved to the
    left image's pixel nearest its p* (of the 3 x 3 around the nearest pixel) that is no
    other candidate's (``taken``: (M,) int64 keys y * ``width`` + x of every candidate's
    pixel) when that pixel lies inside the window; two windows aiming at one pixel: the
    first moves.  Its right position and its variance along the row are those of the warp
    there.
    Returns (moved indices into the frame's candidates, their new left pixels (K, 2),
    right positions (K, 2), covariances (K, 2, 2) in the original right image, unit
    line directions (K, 2)).
    """

    empty = (np.zeros(0, np.intp), np.zeros((0, 2)), np.zeros((0, 2)), np.zeros((0, 2, 2)),
             np.zeros((0, 2)))
    cov_all = frame["affine_cov_fin"]
    k = np.flatnonzero(accepted & np.isfinite(cov_all[:, 0, 0]) & (frame["sides"] > 0))
    if len(k) == 0:
        return empty
    centre = frame["centre"][k]
    half = (frame["sides"][k] // 2).astype(np.float64)
    pstar, _ = _least_variance_point(cov_all[k], half)
    fine = np.isfinite(pstar).all(axis=1)
    k, pstar, centre, half = k[fine], pstar[fine], centre[fine], half[fine]
    if len(k) == 0:
        return empty
    target = rectified_to_original(rect, rig.left, centre + pstar, which="left")
    own = (np.rint(x_left[k, 1]) * width + np.rint(x_left[k, 0])).astype(np.int64)
    # the pixel nearest p* that is no other candidate's (of the 3 x 3 around the nearest)
    steps = np.array([(i, j) for j in (-1, 0, 1) for i in (-1, 0, 1)], np.float64)
    near = np.rint(target)[:, None, :] + steps[None]  # (K, 9, 2)
    dist = np.linalg.norm(near - target[:, None, :], axis=2)
    keys9 = (near[..., 1] * width + near[..., 0]).astype(np.int64)
    free = ~np.isin(keys9, taken) | (keys9 == own[:, None])
    pick = np.argmin(np.where(free, dist, np.inf), axis=1)
    rows = np.arange(len(k))
    q = near[rows, pick]
    key = keys9[rows, pick]
    frac_new = left_to_rectified(rect, rig.left, q) - centre
    move = (free[rows, pick] & (key != own)
            & (np.abs(frac_new) <= half[:, None]).all(axis=1))
    # two windows to one pixel: the first keeps it, the other stays where it was
    first = np.zeros(len(k), bool)
    _, at = np.unique(np.where(move, key, -1 - np.arange(len(k))), return_index=True)
    first[at] = True
    move &= first
    k, q, frac_new = k[move], q[move], frac_new[move]
    if len(k) == 0:
        return empty
    a, quad, fo = frame["affine_fin"][k], frame["quad"][k], frame["frac"][k]
    fn = frac_new
    dx, dy = fn[:, 0] - fo[:, 0], fn[:, 1] - fo[:, 1]
    xr = (frame["position"][k, 0] + a[:, 1] * dx + a[:, 2] * dy
          + quad[:, 0] * (fn[:, 0] ** 2 - fo[:, 0] ** 2)
          + quad[:, 1] * (fn[:, 0] * fn[:, 1] - fo[:, 0] * fo[:, 1])
          + quad[:, 2] * (fn[:, 1] ** 2 - fo[:, 1] ** 2))
    yr = frame["position"][k, 1] + a[:, 4] * dx + a[:, 5] * dy
    g = np.column_stack([np.ones(len(k)), fn])
    var = np.einsum("ni,nij,nj->n", g, frame["affine_cov_fin"][k][:, :3, :3], g)
    if scale_cov:
        var = var * frame["k2"][k]
    right = rectified_to_original(rect, rig.right, np.column_stack([xr, yr]))
    jinv = np.linalg.inv(_jacobians(lambda p: right_to_rectified(rect, rig.right, p), right))
    d = jinv[:, :, 0]  # right-image step of one rectified column
    cov = var[:, None, None] * d[:, :, None] * d[:, None, :]
    dirs = d / np.linalg.norm(d, axis=1)[:, None]
    return k, q, right, cov, dirs

