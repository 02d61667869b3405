"""Is a stereo pair's match the only answer?  Uniqueness, backward loops, verified growth.

:func:`_verify_unique` (2-D matches) and :func:`_verify_unique_rectified` (the epipolar
pass's, strict) test every accepted match for a rival along the epipolar search range
(:mod:`matching.uniqueness`); :func:`_loop_closes` and :func:`_loop_closes_rectified`
require the backward (right-to-left) LSM from each survivor to return to its template
within the loop's 99.9 % bound; :func:`_grow_verified` grows the rejected windows again
from verified neighbours only, so that growth cannot carry a one-period slip across a
repeated pattern; :func:`_grow_from_volume` starts the windows still unmatched where their
verified neighbours' disparity plane (or the scene range) leaves one unique peak, where SGBM
was blind or a period off.  Measured: ``docs/decisions/stereo-uniqueness.md``,
``stereo-ambiguity.md``, ``stereo-far-growth.md``.
"""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
from scipy.spatial import cKDTree

from checks.robust import MAD_TO_SIGMA
from matching import uniqueness
from matching.lsm import LSMResult, Status, lsm_match
from matching.pair_status import AMBIGUOUS, NO_APPROXIMATION, OUTLIER_Z
from matching.rectify import (
    left_to_rectified,
    rectified_to_original,
    rectify_images,
    right_to_rectified,
)
from matching.validate import TOL


def _verify_unique(left, right, rig, rect, rectified, fprep, gprep, points, res: LSMResult,
                   search_range, patch: int, options: dict) -> np.ndarray:
    """(N,) uint8 :mod:`matching.uniqueness` verdict per match after the ambiguous ones
    were given their chance to be resolved by unique neighbours (:func:`uniqueness.anchored`).

    The profiles run in the rectified frame (the given images for a rectified pair);
    the rivals are re-matched by the first pass's matcher (base ``patch``, no
    second-order terms) in the original images.
    """

    ok = res.accepted
    xr_rect = np.full((len(points), 2), np.nan)
    if rectified:
        left_rect, right_rect, xl_rect = left, right, points
        xr_rect[ok] = res.position[ok]

        def to_right(p):
            return p
    else:
        left_rect, right_rect = rectify_images(rect, left, right)
        xl_rect = left_to_rectified(rect, rig.left, points)
        xr_rect[ok] = right_to_rectified(rect, rig.right, res.position[ok])

        def to_right(p):
            return rectified_to_original(rect, rig.right, p)

    def match(index, start, init, population, direction):
        opts = {k: v for k, v in options.items() if v is not None and k != "quadratic"}
        opts["direction"] = direction
        opts["max_shift_px"] = float(patch)
        for key in ("offset", "robust"):  # per-window options
            if key in opts and np.ndim(opts[key]) >= 1 and len(opts[key]) == len(points):
                opts[key] = np.asarray(opts[key])[index]
        return lsm_match(fprep, gprep, points[index], start, initial=init,
                         sigma0_population=population, **opts)

    ver = uniqueness.verify_matches(match, points, res, left_rect, right_rect, xl_rect,
                                    xr_rect, to_right, search_range, fprep.noise, patch,
                                    float(options.get("min_correlation", 0.7)))
    verdict = ver.verdict.copy()
    solution = xl_rect[:, 0] - xr_rect[:, 0]
    ambiguous = verdict == uniqueness.AMBIGUOUS
    if ambiguous.any():
        # anchors: unique with no rival peak in the profile at all (a unique verdict
        # whose rival re-match failed may still be the slip: pair 02, 30 of 284 slips)
        anchors = ok & (verdict == uniqueness.UNIQUE) & (ver.peaks_tried == 0)
        resolved = uniqueness.anchored(points, res.position, res.sigma, res.affine,
                                       anchors, ambiguous & ok, radius=float(patch),
                                       max_offset=np.minimum(solution - ver.lobe[:, 0],
                                                             ver.lobe[:, 1] - solution))
        verdict[resolved] = uniqueness.UNIQUE
    return verdict



def _verify_unique_rectified(frame: dict, points, res: LSMResult, search_range,
                             patch: int, interval=None) -> tuple[np.ndarray, np.ndarray]:
    """Uniqueness of the epipolar pass's matches, judged in the rectified frame by the
    matcher that made them (:mod:`matching.uniqueness` ``strict``).

    Every separated peak of the plain ZNCC profile along the row that is as good as the
    solution's within the noise margin (or better) makes the match ambiguous unless the
    constrained matcher, started there with the solution's shape and radiometry, refutes
    it.  Ambiguous matches are not resolved by their neighbours here (measured on the
    chessboard rig, pair 06: the 228 that :func:`matching.uniqueness.anchored` would pin
    put 13.6 % of themselves beyond the blunder band against 4.3 % of the rest): the
    region growing from verified matches (:func:`_grow_verified`) is where geometry
    pins a window.  ``interval``: (N, 2) the disparities geometry admits per match
    (``verify_matches``).  Returns the (N,) verdicts and (N,) variance the rivals leave
    along the row (rectified px², ``Verification.rival_var``).
    """

    n = len(points)
    ok = frame["index"]
    status = np.where(res.status[ok] == Status.OK, 0, 1)
    sub = SimpleNamespace(status=status, sigma0=frame["sigma0"],
                          correlation=frame["correlation"])
    shape = np.concatenate([frame["affine"], frame["radiometric"]], axis=1)
    fprep, gprep, frac = frame["fprep"], frame["gprep"], frame["frac"]
    sides = frame["sides"]

    def match(index, start, init, population, direction):
        # the rival's window centre on the template's pixel grid (the point is eccentric
        # by ``frac``), the search centre moved by the shape
        a0 = start[:, 0] - init[:, 1] * frac[index, 0] - init[:, 2] * frac[index, 1]
        init = init.copy()
        init[:, 0], init[:, 3] = a0, frame["centre"][index, 1]
        init[:, 4], init[:, 5] = 0.0, 1.0
        approx = init[:, [0, 3]]
        status_r = np.full(len(index), Status.PULL_IN, np.uint8)
        position = np.full((len(index), 2), np.nan)
        corr = np.full(len(index), np.nan)
        opts = dict(frame["opts"])
        opts["max_shift_px"] = float(patch) / 4.0
        for side in np.unique(sides[index]):
            sel = np.flatnonzero(sides[index] == side)
            opts["patch"] = int(side)
            r = lsm_match(fprep, gprep, frame["centre"][index[sel]], approx[sel],
                          initial=init[sel], direction=(1.0, 0.0), rigid_across=True,
                          offset=frac[index[sel]], sigma0_population=population, **opts)
            status_r[sel], position[sel], corr[sel] = r.status, r.position, r.correlation
        return SimpleNamespace(status=status_r, position=position, correlation=corr)

    ver = uniqueness.verify_matches(match, frame["xl"], sub, fprep.raw, gprep.raw,
                                    frame["xl"], frame["position"], lambda q: q,
                                    search_range, fprep.noise, patch,
                                    float(frame["opts"].get("min_correlation", 0.7)),
                                    shape=shape, strict=True,
                                    interval=None if interval is None else interval[ok])
    verdict = np.full(n, uniqueness.OUTSIDE, np.uint8)
    verdict[ok] = ver.verdict
    rival_var = np.zeros(n)
    rival_var[ok] = ver.rival_var
    return verdict, rival_var



def _loop_closes(fprep, gprep, points, res: LSMResult, which, patch: int,
                 options: dict) -> np.ndarray:
    """(N,) bool: the backward (right-to-left) LSM from each solution in ``which`` returns
    to its template centre within the loop's 99.9 % bound (σ_fwd² + σ_bwd², the
    white-noise σ of both solutions, times the loops' own variance factor); True where
    not checked or where the backward match itself failed.

    Started at the solution with the inverse warp and radiometry (f = r0 + r1 g, so
    g = -r0/r1 + f/r1); a solution LSM reached in a biased minimum -- a window sliding
    along a straight edge, a warp bent to fit a repeat -- is not the minimum of the
    window centred at its answer, and the loop opens.
    """
    out = np.ones(len(points), bool)
    sel = np.flatnonzero(which)
    if not len(sel):
        return out
    aff = res.affine[sel]
    jac = np.stack([aff[:, 1:3], aff[:, 4:6]], axis=1)  # (M, 2, 2)
    det = np.linalg.det(jac)
    good = np.abs(det) > TOL.zero
    sel, jac = sel[good], jac[good]
    out[np.flatnonzero(which)[~good]] = False
    inv = np.linalg.inv(jac)
    r0, r1 = res.radiometric[sel, 0], res.radiometric[sel, 1]
    init = np.column_stack([points[sel, 0], inv[:, 0, 0], inv[:, 0, 1], points[sel, 1],
                            inv[:, 1, 0], inv[:, 1, 1], -r0 / r1, 1.0 / r1])
    opts = {k: v for k, v in options.items()
            if k in ("interpolation", "min_texture_snr", "min_correlation", "max_iter")}
    back = lsm_match(gprep, fprep, res.position[sel], points[sel], initial=init,
                     patch=patch, **opts)
    loop = np.linalg.norm(back.position - points[sel], axis=1)
    ratio = loop / np.hypot(res.sigma[sel], back.sigma)
    converged = back.status == Status.OK
    # σ0²N⁻¹ is optimistic on real images by a variance factor k (matching.precision);
    # the loops give their own: a 2-D loop of per-axis σ k has its median at
    # sqrt(2 ln 2) σ k (Rayleigh), and 99.9 % of loops within sqrt(2 ln 1000) σ k
    k = 1.0
    if converged.sum() >= 30:
        k = max(1.0, float(np.median(ratio[converged])) / np.sqrt(2.0 * np.log(2.0)))
    # a backward match that fails its own tests (pull-in, σ0, convergence: 30 % of a
    # temple pair's, whose forward matches are sound) gives no verdict
    out[sel] = ~converged | (ratio <= np.sqrt(2.0 * np.log(1000.0)) * k)
    return out



def _loop_closes_rectified(frame: dict, which) -> np.ndarray:
    """(N,) bool: the backward (right-to-left) constrained LSM from each epipolar-pass
    solution in ``which`` returns to its left point within the loop's 99.9 % bound along
    the row; True where not checked or where the backward match itself failed.

    The template is the right rectified image on its pixel grid at the solution (the
    solution eccentric by its fraction of a pixel), started in the left image at the
    inverse of the solution's warp along the row (x_l = (x_r - a0 - a2 dy) / a1) and
    radiometry; the loop's bound is the forward and backward σ along the row combined,
    times the loops' own variance factor (their median |loop| / 0.6745 σ, at least 1).
    """
    n = len(which)
    out = np.ones(n, bool)
    ok = frame["index"]
    local = np.flatnonzero(np.asarray(which, bool)[ok]
                           & np.isfinite(frame["position"]).all(1))
    if not len(local):
        return out
    aff = frame["affine"][local]
    rad = frame["radiometric"][local]
    a1 = aff[:, 1]
    usable = (np.abs(a1) > TOL.zero) & (np.abs(rad[:, 1]) > TOL.zero)
    out[ok[local[~usable]]] = False
    local, aff, rad, a1 = local[usable], aff[usable], rad[usable], a1[usable]
    pos = frame["position"][local]
    centre = np.rint(pos)
    frac = pos - centre
    # the left point of the template centre: x_l = c_l + (x_r - a0 - a2 dy) / a1, dy the
    # row offset (0 here: rows map to rows)
    xl_c = frame["centre"][local]
    init = np.zeros((len(local), 8))
    init[:, 0] = xl_c[:, 0] + (centre[:, 0] - aff[:, 0]) / a1
    init[:, 1], init[:, 2] = 1.0 / a1, -aff[:, 2] / a1
    init[:, 3], init[:, 5] = centre[:, 1], 1.0
    init[:, 6], init[:, 7] = -rad[:, 0] / rad[:, 1], 1.0 / rad[:, 1]
    opts = dict(frame["opts"])
    back_x = np.full(len(local), np.nan)
    back_var = np.full(len(local), np.nan)
    converged = np.zeros(len(local), bool)
    sides = frame["sides"][local]
    for side in np.unique(sides):
        sel = np.flatnonzero(sides == side)
        opts["patch"] = int(side)
        r = lsm_match(frame["gprep"], frame["fprep"], centre[sel], init[sel][:, [0, 3]],
                      initial=init[sel], direction=(1.0, 0.0), rigid_across=True,
                      offset=frac[sel], **opts)
        back_x[sel], back_var[sel] = r.position[:, 0], r.cov[:, 0, 0]
        converged[sel] = r.status == Status.OK
    loop = back_x - frame["xl"][local, 0]
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.abs(loop) / np.sqrt(frame["cov"][local, 0, 0] + back_var)
    k = float(frame.get("loop_k", 1.0))  # an earlier, larger population's
    if converged.sum() >= 30:
        k = max(1.0, float(np.median(ratio[converged])) / 0.6745)
        frame["loop_k"] = k
    # 99.9 % of a normal loop of standard deviation σ k within 3.29 σ k
    out[ok[local]] = ~converged | (ratio <= 3.29 * k)
    return out



#: LSM failures a better approximation may turn into a match (grown again from verified
#: neighbours); the others are properties of the window (texture, conditioning) or of
#: what it holds: a window that converged to a residual above the image noise
#: (``SIGMA0_TOO_LARGE``) or a low correlation holds what one affine plane does not fit
#: (an occluding rim, background), and a new start only finds a biased fit of it
#: (docs/decisions/stereo-ambiguity.md)
_REGROW = (Status.NO_CONVERGENCE, Status.PULL_IN, Status.DEGENERATE_AFFINE,
           NO_APPROXIMATION)



def _grow_verified(status, points, res: LSMResult, frame: dict, geo, dirs, sides,
                   refine, patch: int, max_rounds: int = 60, reach: float | None = None,
                   ambiguous: bool = False):
    """Region growing in the rectified frame from the matches already shown unique.

    A candidate whose window failed from its approximation (``_REGROW``; with
    ``ambiguous`` also the ambiguous ones) is started at the median prediction of its
    verified accepted neighbours within ``reach`` px (default half the patch)
    (their warps, at least two within 1 px of each other; shape and radiometry of the
    nearest), matched by the epipolar pass (``refine``:
    :func:`matching.pair_epipolar._epipolar_refine` with the first call's σ_g and
    variance factors), and kept only where every verified neighbour in reach agrees with
    it within 3σ (:func:`matching.uniqueness.anchored`,
    at least two: a one-period slip is a period off every prediction) and its backward
    loop closes (:func:`_loop_closes_rectified`).  Rounds until the front stops: only
    verified matches seed, so growth cannot carry a slip across a repeated pattern.
    Updates ``status``, ``geo``, ``dirs``, ``sides`` and ``frame`` in place; returns the
    updated result and the (N,) mask of the matches grown.
    """

    n = len(points)
    reach = float(patch) / 2.0 if reach is None else float(reach)
    tried = np.zeros(n, bool)
    grown = np.zeros(n, bool)
    arrays = _copies(res)
    position, affine, cov = arrays["position"], arrays["affine"], arrays["cov"]
    for _ in range(max_rounds):
        verified = np.flatnonzero(status == Status.OK)
        regrow = _REGROW + ((AMBIGUOUS,) if ambiguous else ())
        cand = np.flatnonzero(np.isin(status, regrow) & ~tried)
        if len(verified) < 2 or not len(cand):
            break
        tree = cKDTree(points[verified])
        k = min(4, len(verified))
        dist, nb = tree.query(points[cand], k=k, distance_upper_bound=reach)
        dist, nb = dist.reshape(len(cand), k), nb.reshape(len(cand), k)
        found = np.isfinite(dist)
        j = verified[np.where(found, nb, 0)]
        d = points[cand][:, None, :] - points[j]
        aff = affine[j]
        pu = aff[..., 0] + aff[..., 1] * d[..., 0] + aff[..., 2] * d[..., 1]
        pv = aff[..., 3] + aff[..., 4] * d[..., 0] + aff[..., 5] * d[..., 1]
        pu, pv = np.where(found, pu, np.nan), np.where(found, pv, np.nan)
        two = found.sum(axis=1) >= 2
        # the median of the predictions (nearest first; NaN where not found)
        mu = np.full(len(cand), np.nan)
        mv = np.full(len(cand), np.nan)
        if two.any():
            mu[two] = np.nanmedian(pu[two], axis=1)
            mv[two] = np.nanmedian(pv[two], axis=1)
        off = np.hypot(pu - mu[:, None], pv - mv[:, None])
        spread = np.max(np.where(found, off, 0.0), axis=1)
        usable = two & (spread <= 1.0)
        if not usable.any():
            break
        tried[cand[usable]] = True
        sel, nearest = cand[usable], j[usable, 0]
        start_aff = affine[nearest].copy()
        start_aff[:, 0], start_aff[:, 3] = mu[usable], mv[usable]
        sub_pos, sub = _started(res, sel, start_aff, arrays["radiometric"][nearest])
        out, geo_s, dirs_s, sides_s, _, frame_s = refine(sub_pos, sub, sides)
        ok_s = sel[(out.status[sel] == Status.OK) & np.isfinite(geo_s[sel])]
        if not len(ok_s):
            continue
        new = np.zeros(n, bool)
        new[ok_s] = True
        sigma_now = np.sqrt(np.maximum(np.trace(cov, axis1=1, axis2=2), 0.0) / 2.0)
        pinned = uniqueness.anchored(points, np.where(new[:, None], out.position, position),
                                     np.where(new, out.sigma, sigma_now),
                                     np.where(new[:, None], out.affine, affine),
                                     status == Status.OK, new, radius=float(patch),
                                     max_rounds=1)
        keep = ok_s[pinned[ok_s]]
        if len(keep):
            mask = np.zeros(n, bool)
            mask[keep] = True
            frame_s["loop_k"] = frame.get("loop_k", 1.0)
            closes = _loop_closes_rectified(frame_s, mask)
            keep = keep[closes[keep]]
        if not len(keep):
            continue
        _adopt(keep, out, geo_s, dirs_s, sides_s, frame_s, arrays, frame, geo, dirs, sides,
               status)
        grown[keep] = True
    res = replace(res, **arrays,
                  status=np.where(status == Status.OK, Status.OK, res.status).astype(
                      res.status.dtype))
    return res, grown



def _copies(res: LSMResult) -> dict:
    """Copies of the result's arrays a regrowth round updates (:func:`_adopt`)."""
    return {key: np.array(getattr(res, key)) for key in
            ("position", "cov", "affine", "radiometric", "sigma0", "correlation")}


def _adopt(keep, out, geo_s, dirs_s, sides_s, frame_s, arrays: dict, frame: dict, geo,
           dirs, sides, status) -> None:
    """The matches ``keep`` of a regrowth round (``refine``'s output) taken into the running
    arrays, the pass's ``geo``, ``dirs``, ``sides``, ``frame`` and ``status``, in place."""
    for key, value in arrays.items():
        value[keep] = getattr(out, key)[keep]
    geo[keep], dirs[keep], sides[keep] = geo_s[keep], dirs_s[keep], sides_s[keep]
    n = len(status)
    for key, value in frame.items():
        if isinstance(value, np.ndarray) and value.shape[:1] == (n,) and key != "index":
            value[keep] = frame_s[key][keep]
    status[keep] = Status.OK


def _neighbour_planes(xl, disparity, sigma, verified, cand, k: int):
    """The disparity each candidate's ``k`` nearest verified matches predict at it and
    that prediction's σ, px: a plane d = c0 + c1 dx + c2 dy through their rectified
    disparities (three rounds, trimmed at 3 x 1.4826 MAD, the spread s at least their
    median σ), σ = s √(1 + (XᵀX)⁻¹₀₀) with the plane's own uncertainty.  NaN where they
    do not fix one plane: a quarter of them trimmed, or their MAD spread above twice
    their median σ."""
    m = len(cand)
    k = min(k, len(verified))
    tree = cKDTree(xl[verified])
    _, nb = tree.query(xl[cand], k=k)
    nb = verified[nb.reshape(m, k)]
    dx = (xl[nb] - xl[cand][:, None, :]) / 100.0  # scaled for conditioning
    design = np.concatenate([np.ones((m, k, 1)), dx], axis=2)  # (M, K, 3)
    d = disparity[nb]
    floor = np.median(sigma[nb], axis=1)
    w = np.ones((m, k))
    pred = np.full(m, np.nan)
    for _ in range(3):
        xtx = np.einsum("mki,mk,mkj->mij", design, w, design)
        good = (np.linalg.cond(xtx) < 1e8) & (w.sum(1) >= 6)
        if not good.any():
            return pred, pred.copy()
        inv = np.full_like(xtx, np.nan)
        inv[good] = np.linalg.inv(xtx[good])
        coef = np.einsum("mij,mkj,mk,mk->mi", inv, design, w, d)
        resid = d - np.einsum("mki,mi->mk", design, coef)
        absr = np.where(w > 0, np.abs(resid), np.nan)
        absr[~np.isfinite(absr).any(axis=1)] = np.inf  # no plane: no spread
        med = np.nanmedian(absr, axis=1)
        spread = np.maximum(MAD_TO_SIGMA * med, floor)
        w = (np.abs(resid) <= 3.0 * spread[:, None]).astype(np.float64)
    # one surface: a plane that leaves a quarter of the neighbours out spans a depth
    # edge, and one they depart from by more than twice their σ (the honest-σ bound of
    # residual / σ) is not their surface -- the scene range decides there
    good &= (w.sum(1) >= 0.75 * k) & (MAD_TO_SIGMA * med <= 2.0 * floor)
    pred = np.where(good, coef[:, 0], np.nan)
    sigma_pred = np.where(good, spread * np.sqrt(1.0 + inv[:, 0, 0]), np.nan)
    return pred, sigma_pred


def _started(res: LSMResult, sel, start_aff, radiometric):
    """The start positions (N, 2) and the result ``refine`` re-matches: the windows
    ``sel`` accepted at ``start_aff``'s shift and shape with ``radiometric``, none else."""
    n = len(res.status)
    sub_status = np.full(n, Status.TEXTURELESS, np.uint8)
    sub_status[sel] = Status.OK
    sub_pos = np.full((n, 2), np.nan)
    sub_pos[sel] = start_aff[:, [0, 3]]
    sub_aff = np.full((n, 6), np.nan)
    sub_aff[sel] = start_aff
    sub_rad = np.full((n, 2), np.nan)
    sub_rad[sel] = radiometric
    return sub_pos, replace(res, status=sub_status, position=sub_pos, affine=sub_aff,
                            radiometric=sub_rad)


def _profile_starts(frame: dict, xl, lo, hi, patch: int, search_range):
    """Which windows (rectified left points ``xl``) have one near-best run of their ZNCC
    profile within the noise margin over the admitted disparities ``lo`` ... ``hi``,
    inside them, no wider than half a patch, above the matcher's correlation floor and
    with signal (:mod:`matching.uniqueness`); and the disparity of its best sample."""
    fprep, gprep = frame["fprep"], frame["gprep"]
    prof = uniqueness.zncc_profiles(fprep.raw, gprep.raw, xl, search_range, patch,
                                    fprep.noise)
    dd = prof.disparities[None, :]
    inside = (dd >= lo[:, None]) & (dd <= hi[:, None])
    cost = np.where(inside, prof.cost, np.nan)
    runs, best, run_lo, run_hi = uniqueness.near_best_runs(cost, prof.margin)
    first = np.argmax(inside, axis=1)
    last = inside.shape[1] - 1 - np.argmax(inside[:, ::-1], axis=1)
    top = cost[np.arange(len(xl)), np.minimum(best, cost.shape[1] - 1)]
    min_corr = float(frame["opts"].get("min_correlation", 0.7))
    usable = ((runs == 1) & (run_lo > first) & (run_hi < last)
              & (run_hi - run_lo + 1 <= patch // 2) & (np.nan_to_num(top) >= min_corr)
              & (prof.template_std > uniqueness.MIN_SNR * fprep.noise))
    return usable, prof.disparities[best[usable]].astype(np.float64)


def _grow_from_volume(status, points, res: LSMResult, frame: dict, geo, dirs, sides, refine,
                      patch: int, search_range, to_rectified, to_right, tried,
                      neighbours: int = 12):
    """Approximations that do not come from SGBM, for the windows still without a match
    from their approximation (``_REGROW``): SGBM is blind in a strip as wide as its
    disparity range and can be a period off on a repeated pattern.

    Each such window's admissible disparities are those its ``neighbours`` nearest verified
    matches predict within what they leave (:func:`_neighbour_planes`; the whole scene
    range ``search_range`` where they fix no plane).  The window's ZNCC profile over them
    must have one near-best run within the noise margin, inside them, above the matcher's
    correlation floor (:mod:`matching.uniqueness`): the epipolar pass (``refine``) starts
    there with the nearest verified match's shape and radiometry, and keeps the match
    when the strict uniqueness test over the same disparities finds it unique, it lies
    within them and its backward loop closes.  ``to_rectified``/``to_right``: left points
    -> rectified frame, rectified right points -> right image.  Updates ``status``,
    ``geo``, ``dirs``, ``sides`` and ``frame`` in place; returns the updated result, the
    (N,) mask of the matches grown and their rivals' variance (rectified px²).
    """
    n = len(points)
    grown = np.zeros(n, bool)
    rival = np.zeros(n)
    verified = np.flatnonzero(status == Status.OK)
    cand = np.flatnonzero(np.isin(status, _REGROW) & ~tried)
    if len(verified) < neighbours or not len(cand):
        return res, grown, rival
    xl = to_rectified(points)
    disparity = frame["xl"][:, 0] - frame["position"][:, 0]
    sigma = np.sqrt(np.nan_to_num(frame["cov"][:, 0, 0] * frame["k2"], nan=np.inf))
    verified = verified[np.isfinite(disparity[verified])]
    if len(verified) < neighbours:
        return res, grown, rival
    pred, sigma_pred = _neighbour_planes(xl, np.nan_to_num(disparity), sigma, verified,
                                         cand, neighbours)
    half = OUTLIER_Z * sigma_pred + 1.0
    dmin, count = int(search_range[0]), int(search_range[1])
    lo = np.where(np.isfinite(pred), np.maximum(pred - half, dmin), dmin)
    hi = np.where(np.isfinite(pred), np.minimum(pred + half, dmin + count - 1),
                  dmin + count - 1)
    usable, d_start = _profile_starts(frame, xl[cand], lo, hi, patch, (dmin, count))
    if not usable.any():
        return res, grown, rival
    sel = cand[usable]
    tried[sel] = True
    start = to_right(np.column_stack([xl[sel, 0] - d_start, xl[sel, 1]]))
    nearest = verified[cKDTree(xl[verified]).query(xl[sel])[1]]
    start_aff = np.array(res.affine)[nearest].copy()
    start_aff[:, 0], start_aff[:, 3] = start[:, 0], start[:, 1]
    sub_pos, sub = _started(res, sel, start_aff, np.array(res.radiometric)[nearest])
    out, geo_s, dirs_s, sides_s, _, frame_s = refine(sub_pos, sub, sides)
    new = np.zeros(n, bool)
    new[sel] = (out.status[sel] == Status.OK) & np.isfinite(geo_s[sel])
    bounds = np.full((n, 2), np.nan)
    bounds[cand] = np.column_stack([lo, hi])
    d_new = frame_s["xl"][:, 0] - frame_s["position"][:, 0]
    # within the neighbours' prediction by the 99.9 % bound of both σ (the match's along
    # the row with its variance factor), where they predict; else in the scene range
    pred_all = np.full(n, np.nan)
    pred_all[cand] = pred
    sig_all = np.full(n, np.inf)
    sig_all[cand] = sigma_pred
    sig_new = np.sqrt(frame_s["cov"][:, 0, 0] * frame_s["k2"] + sig_all ** 2)
    with np.errstate(invalid="ignore"):
        new &= (d_new >= bounds[:, 0]) & (d_new <= bounds[:, 1])
        new &= ~np.isfinite(pred_all) | (np.abs(d_new - pred_all) <= OUTLIER_Z * sig_new)
    if not new.any():
        return res, grown, rival
    verdict, rival_var = _verify_unique_rectified(
        frame_s, points, replace(out, status=np.where(new, Status.OK, Status.PULL_IN)
                                 .astype(out.status.dtype)),
        search_range, patch, interval=bounds)
    new &= verdict == uniqueness.UNIQUE
    frame_s["loop_k"] = frame.get("loop_k", 1.0)
    new &= _loop_closes_rectified(frame_s, new)
    keep = np.flatnonzero(new)
    if not len(keep):
        return res, grown, rival
    arrays = _copies(res)
    _adopt(keep, out, geo_s, dirs_s, sides_s, frame_s, arrays, frame, geo, dirs, sides,
           status)
    grown[keep] = True
    rival[keep] = rival_var[keep]
    res = replace(res, **arrays,
                  status=np.where(status == Status.OK, Status.OK, res.status).astype(
                      res.status.dtype))
    return res, grown, rival
