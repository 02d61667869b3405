"""Real-image figures of ``benchmarks/matching.py``: graffiti (a flat wall 40 deg apart)
and neighbouring temple pairs (16 real views with exact cameras), peers side by side.

Graffiti (``graf1.png`` -> ``graf3.png``, homography ``H13``): the candidates of
``matching.seeds.select_points`` (21x21 unless ``--graffiti-patch``, the spacing given)
whose homography image lies inside graf3 and whose window lies on the wall plane
(``graffiti_wall``: the strip below the step at the bottom and the car stand off the
plane); every method starts from the homography's position plus 1 px of Gaussian noise and
(LSM, ECC) its local affine map.
Judged by the share beyond 2 px of the homography and by the residual to a smooth
mapping -- a homography plus a degree-7 polynomial fitted robustly to LSM's accepted
matches (the data set's homography has no lens-distortion term) -- per axis over the
residuals below 2 px; LSM's ratio of that residual to its reported σ, without and with
the variance factor of independent neighbouring windows
(``matching.precision.midpoint_variance_factor``, what ``match_pair`` applies; RMS over
RMS, and the median |e|/σ over its Gaussian value), and beside it the forward-backward
loops' factor (``matching.forward_backward``, a lower bound); and the residuals split along /
across the epipolar lines (``parallax_split``: plane + parallax, where a relief of the wall
can only act along them). Peers: ``cv2.findTransformECC``
(MOTION_AFFINE, gaussFiltSize 1) per patch, ``cv2.calcOpticalFlowPyrLK`` (the same window).
LSM runs with ``match_pair``'s footprint smoothing
(``matching.lsm.DEFAULT_FOOTPRINT_VAR``), and once without it beside. The same
candidates on a synthetic graf3 (``graffiti_synthetic``: graf1 through the homography,
pixel-area integration, graf3's noise) are judged against the exact homography: LSM's
own error on this geometry and texture.

Temple: neighbouring ring views (``matching.view_pairs.select_pairs``, the ring
pipeline's pairs; the first with ``--quick``, four spread over the list without)
rectified by ``matching.multiview.rectify_pair`` (baseline = rectified x; mirrored where
the disparity would be negative); ``matching.pair.match_pair`` on the rectified pair
(SGBM seeds, region growing); object = grey > 0.19 x 255, dilated 5 px. LSM's
forward-backward loop along the rows / sqrt(2) against its reported σ, and SGBM's
left-right loop (disparity of the left, then of the right image at the matched position)
/ sqrt(2) on the same pixels. LSM's σ includes ``match_pair``'s variance factor
(``sigma_factor``, reported as k²). The accepted share is split into interior windows
(no background pixel in the 15x15 window) and those on the outline, and given again with
eccentric windows (``match_pair(eccentric=True)``, as the ring pipeline matches).

Temple cross-pair check (``cross_pair_comparisons``; ``matching.precision``'s cross-pair
section): every ring pair is matched (LSM and SGBM); each accepted LSM match of a pair P
is triangulated with the given cameras and carried into every pair Q that shares no view
with it, where Q's nearest accepted match (within ``CROSS_RADIUS_PX``) predicts the right
column through its warp; the discrepancy δ = ε_Q + c ε_P holds the two pairs' errors and
no shared image noise.  The same is done with SGBM's disparities on the same P pixels and
SGBM's map in Q (bilinear).  Kept: points whose rays from P's and Q's left views meet at
<= ``CROSS_MAX_ANGLE_DEG`` and |δ| < ``CROSS_BOUND_PX`` for both methods; per comparison
the cameras' own inconsistency is removed (``geometric_trend``, reported as its RMS) and
δ's spread is the Gaussian core of a core + uniform-outlier mixture (``core_spread``,
its outlier share beside).  ``lsm_over_reported``: the core spread of δ over
sqrt(σ_Q² + c² σ_P²), both σ as ``match_pair`` reports them (with its variance factor);
per pair, the network of comparisons (``matching.precision.network_variances``) gives
its own error where a cycle of three pairs determines it.  On a rendered ring with exact
truth (``tests/matching/test_cross_pair.py``) δ equals the two true errors' combination
to 0.01 px for 95 % of the points, and δ/σ agrees with the truth's within 10 %.
"""

from __future__ import annotations

import time
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial import cKDTree

from checks.robust import MAD_TO_SIGMA
from matching.forward_backward import forward_backward
from matching.grow import grow_matches
from matching.ici import (
    ici_choice,
    ici_ladder,
    interval_sigmas,
    population_choice,
    population_sides,
    select_results,
)
from matching.image_file import imread
from matching.lsm import DEFAULT_FOOTPRINT_VAR, LSMResult, lsm_match, prepare_image
from matching.precision import midpoint_variance_factor
from matching.seeds import disparity_range, select_points, sgbm_disparity

GRAFFITI_PATCH = 21


def _grey(path: Path) -> np.ndarray:
    img = imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise FileNotFoundError(f"cannot read {path}")
    return img.astype(np.float64) @ np.array([0.114, 0.587, 0.299])


def _homography(path: Path) -> np.ndarray:
    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    hom = storage.getNode("H13").mat()
    storage.release()
    return hom


def _apply(hom, p):
    q = np.column_stack([p, np.ones(len(p))]) @ hom.T
    return q[:, :2] / q[:, 2:]


def _jacobian(hom, p):
    q = np.column_stack([p, np.ones(len(p))]) @ hom.T
    w = q[:, 2]
    uv = q[:, :2] / w[:, None]
    jac = np.empty((len(p), 2, 2))
    for r in range(2):
        for c in range(2):
            jac[:, r, c] = (hom[r, c] - uv[:, r] * hom[2, c]) / w
    return jac


def _poly(p, deg, centre, scale):
    x, y = ((p - centre) / scale).T
    return np.column_stack([x**i * y**j for i in range(deg + 1) for j in range(deg + 1 - i)])


def smooth_mapping(src, dst, deg: int = 7, iterations: int = 6):
    """Homography + degree-``deg`` polynomial, robust (4 x 1.4826 MAD), fitted to src->dst."""
    centre, scale = src.mean(0), np.ptp(src, axis=0) / 2
    keep = np.ones(len(src), bool)
    for _ in range(iterations):
        hom, _ = cv2.findHomography(src[keep], dst[keep], 0)
        design = _poly(src, deg, centre, scale)
        coef = np.linalg.lstsq(design[keep], (dst - _apply(hom, src))[keep], rcond=None)[0]
        res = dst - _apply(hom, src) - design @ coef
        e = np.linalg.norm(res, axis=1)
        keep = e < max(4 * MAD_TO_SIGMA * np.median(e[keep]), 0.05)
    return lambda p: _apply(hom, p) + _poly(p, deg, centre, scale) @ coef


def _ecc(f, g, points, approx, jac, patch):
    half, pad = patch // 2, patch
    out = np.full_like(approx, np.nan)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-4)
    h, w = g.shape
    f32, g32 = f.astype(np.float32), g.astype(np.float32)
    for i, ((x, y), (ax, ay)) in enumerate(zip(points.astype(int), approx, strict=True)):
        x0, y0 = int(round(ax)) - pad, int(round(ay)) - pad
        if x0 < 0 or y0 < 0 or x0 + 2 * pad + 1 > w or y0 + 2 * pad + 1 > h:
            continue
        a = jac[i]
        # warp maps template pixel (u, v) (0..patch-1) into the search crop
        t = np.array([ax - x0, ay - y0]) - a @ [half, half]
        warp = np.array([[a[0, 0], a[0, 1], t[0]], [a[1, 0], a[1, 1], t[1]]], np.float32)
        try:
            _, warp = cv2.findTransformECC(f32[y - half:y + half + 1, x - half:x + half + 1],
                                           g32[y0:y0 + 2 * pad + 1, x0:x0 + 2 * pad + 1],
                                           warp, cv2.MOTION_AFFINE, crit, None, 1)
        except cv2.error:
            continue
        out[i] = warp[:, :2] @ [half, half] + warp[:, 2] + [x0, y0]
    return out


def _lk(f, g, points, approx, patch):
    p0 = points.astype(np.float32).reshape(-1, 1, 2)
    p1 = approx.astype(np.float32).reshape(-1, 1, 2)
    res, status, _ = cv2.calcOpticalFlowPyrLK(
        np.clip(f, 0, 255).astype(np.uint8), np.clip(g, 0, 255).astype(np.uint8), p0, p1,
        winSize=(patch, patch), maxLevel=2,
        criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 0.001),
        flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
    out = np.full_like(approx, np.nan)
    good = status.ravel() == 1
    out[good] = res.reshape(-1, 2)[good]
    return out


def _judge(name, pos, truth, smooth, points, seconds, candidates, sigma=None, extra=None):
    found = np.isfinite(pos).all(1)
    off_h = np.linalg.norm(pos - truth, axis=1)
    res = pos - smooth(points)
    e = np.linalg.norm(res, axis=1)
    inl = found & (e < 2.0)
    row = {"method": name, "accepted": float(found.sum() / candidates),
           "beyond_2px_of_homography": float(np.mean(off_h[found] > 2.0)),
           "beyond_2px_of_smooth": float(np.mean(e[found] > 2.0)),
           "residual_rms_px": float(np.sqrt(np.mean(res[inl] ** 2))),
           "points": int(found.sum()), "points_per_s": float(len(points) / seconds)}
    if sigma is not None:
        row["reported_sigma_rms_px"] = float(np.sqrt(np.mean(sigma[inl] ** 2)))
        row["residual_over_sigma"] = row["residual_rms_px"] / row["reported_sigma_rms_px"]
    row.update(extra or {})
    return row


#: graf1's part of the wall plane, where the homography holds: above the horizontal step
#: from (0, 528) to (800, 496) px (the strip below it stands off the plane: LSM's matches
#: there lie 2-4 px from the homography, consistently over the whole strip) and off the
#: car in the lower right (x > 600, y > 470).
def graffiti_wall(points: np.ndarray, half: int) -> np.ndarray:
    """(N,) bool: the window of half side ``half`` around ``points`` (graf1 px) lies on the
    wall plane (``graffiti_wall``'s comment)."""
    x, y = np.asarray(points, dtype=np.float64).T
    return (y + half < 528.0 - 0.04 * x) & ~((x + half > 600.0) & (y + half > 470.0))


def render_homography(image: np.ndarray, hom: np.ndarray, shape, supersample: int = 4):
    """``image`` seen through ``hom`` (image px -> output px) by a camera whose pixels
    integrate their area: the warp (bicubic) onto a ``supersample``-times finer grid,
    averaged over ``supersample``² sub-pixels (pixel centres at integers)."""
    s = int(supersample)
    fine = np.array([[s, 0, s / 2 - 0.5], [0, s, s / 2 - 0.5], [0, 0, 1.0]]) @ hom
    big = cv2.warpPerspective(image.astype(np.float32), fine, (shape[1] * s, shape[0] * s),
                              flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
    return big.reshape(shape[0], s, shape[1], s).mean(axis=(1, 3)).astype(np.float64)


def _lsm_grown(fp, gp, pts, approx, init, patch, footprint_var=DEFAULT_FOOTPRINT_VAR,
               **options):
    """LSM one pass from ``init`` and region growing: (first, growth, seconds, seconds)
    (``options``: more of ``lsm_match``'s)."""
    opts = {"patch": patch, "footprint_var": footprint_var, **options}
    lsm_match(fp, gp, pts[:20], approx[:20], initial=init[:20], **opts)  # kernels
    t0 = time.perf_counter()
    first = lsm_match(fp, gp, pts, approx, initial=init, **opts)
    t1 = time.perf_counter()
    growth = grow_matches(fp, gp, pts, first, approx, **opts)
    return first, growth, t1 - t0, time.perf_counter() - t0


#: Gaussian scale (px) of the residual field's correlated part in :func:`parallax_split`:
#: half a 21-px window, below the ~40 px over which graffiti's residuals stay correlated.
PARALLAX_SMOOTHING_PX = 10.0


def _smoothed_field(points, values, scale):
    """(N, 2) Gaussian-weighted mean of ``values`` over the points within 3 ``scale``."""
    pairs = cKDTree(points).query_pairs(3.0 * scale, output_type="ndarray")
    i = np.concatenate([pairs[:, 0], pairs[:, 1], np.arange(len(points))])
    j = np.concatenate([pairs[:, 1], pairs[:, 0], np.arange(len(points))])
    w = np.exp(-0.5 * np.sum((points[i] - points[j]) ** 2, axis=1) / scale**2)
    total = np.bincount(i, w, len(points))
    return np.column_stack([np.bincount(i, w * values[j, k], len(points)) / total
                            for k in range(2)])


def _epipolar_directions(theta, x2):
    """Unit directions of the epipolar lines through ``x2`` (image 2 px) for the epipole
    ``(cos a cos b, sin a cos b, sin b)`` (homogeneous, px / 1000)."""
    a, b = theta
    epi = np.array([np.cos(a) * np.cos(b), np.sin(a) * np.cos(b), np.sin(b)])
    d = epi[:2][None] - epi[2] * x2 / 1000.0
    return d / np.linalg.norm(d, axis=1)[:, None]


def parallax_split(points, x2, residual, cov, k2, patch):
    """Residuals to the wall's smooth mapping split along / across the epipolar lines.

    Two views of a rigid scene differ from a plane's homography only by parallax along
    the epipolar lines (plane + parallax, Irani & Anandan 1996): a relief of the wall
    -- paint layers, a bulge -- moves points along them, never across.  The epipole is
    fitted (2 unknowns, multi-start least squares) to the correlated part of the
    residual field (``_smoothed_field``, Gaussian ``PARALLAX_SMOOTHING_PX``): the
    direction that field takes.  Returned: per component the residual RMS, the reported
    σ k RMS projected on it (``cov`` with the variance factor ``k2``), their ratio, and
    the correlation of the component between windows 1-1.5 patch sides apart (the
    pairs the variance factor compares: what they cannot see).

    points, x2, residual : (N, 2) float64 -- template px, matches in image 2, residuals
    cov : (N, 2, 2) float64 -- reported covariances, px²
    """
    from scipy.optimize import least_squares

    field = _smoothed_field(points, residual, PARALLAX_SMOOTHING_PX)

    def across(theta):
        d = _epipolar_directions(theta, x2)
        return field[:, 0] * d[:, 1] - field[:, 1] * d[:, 0]

    starts = [(a, b) for a in np.linspace(0.0, np.pi, 7) for b in np.linspace(-1.4, 1.4, 7)]
    best = min((least_squares(across, s) for s in starts), key=lambda r: r.cost)
    along_dir = _epipolar_directions(best.x, x2)
    across_dir = np.column_stack([along_dir[:, 1], -along_dir[:, 0]])
    pairs = cKDTree(points).query_pairs(1.5 * patch, output_type="ndarray")
    dist = np.linalg.norm(points[pairs[:, 0]] - points[pairs[:, 1]], axis=1)
    pairs = pairs[dist >= patch]
    out = {"epipole_direction_median": np.median(along_dir, axis=0).tolist()}
    for name, u in (("along", along_dir), ("across", across_dir)):
        comp = np.sum(residual * u, axis=1)
        var = np.einsum("ni,nij,nj->n", u, cov, u) * max(k2, 1.0)
        c = comp - comp.mean()
        out[f"{name}_rms_px"] = float(np.sqrt(np.mean(comp**2)))
        out[f"{name}_sigma_k_rms_px"] = float(np.sqrt(np.mean(var)))
        out[f"{name}_over_sigma_k"] = out[f"{name}_rms_px"] / out[f"{name}_sigma_k_rms_px"]
        out[f"{name}_neighbour_correlation"] = float(
            np.mean(c[pairs[:, 0]] * c[pairs[:, 1]]) / np.mean(c**2))
    return out


def _factor_figures(row, pts, res, mapping, patch):
    """Variance factor of independent neighbouring windows and residual / (σ k) into ``row``
    (``patch``: the side, or the sides per point)."""
    t0 = time.perf_counter()
    vf = midpoint_variance_factor(pts, res.affine, res.affine_cov, res.accepted, patch=patch)
    row["variance_factor"] = vf.factor
    row["variance_factor_seconds"] = time.perf_counter() - t0
    k2 = max(1.0, vf.factor)
    row["residual_over_sigma_with_factor"] = float(row["residual_over_sigma"] / np.sqrt(k2))
    # the core of the distribution against its tails: median |e| / σ over its Gaussian
    # value sqrt(2 ln 2) (|e| of a 2-D error with σ per axis)
    e = np.linalg.norm(res.position - mapping(pts), axis=1)
    inl = res.accepted & (e < 2.0)
    row["median_residual_over_sigma_with_factor"] = float(
        np.median(e[inl] / res.sigma[inl]) / np.sqrt(2 * np.log(2) * k2))
    row["parallax_split"] = parallax_split(pts[inl], res.position[inl],
                                           (res.position - mapping(pts))[inl], res.cov[inl],
                                           k2, int(np.median(np.broadcast_to(patch,
                                                                             inl.shape)[inl])))


def _window_rules(rows: list, fp, gp, pts, approx, init, patch: int, res, truth, smooth,
                  n_cand: int, t_grown: float) -> None:
    """The graffiti rows of LSM's window chosen per point (:func:`graffiti`): by ICI and by
    the population rule over the same ladder of sides (appended to ``rows``)."""
    # LSM's window per point by ICI (matching.ici) over a ladder from the benchmark's side
    # to twice it: each side matched and grown as above, then each point keeps the
    # largest side that agrees with every smaller one within ±Γ σk
    ladder = ici_ladder(patch)
    t0 = time.perf_counter()
    grown = [res] + [_lsm_grown(fp, gp, pts, approx, init, side)[1].result
                     for side in ladder[1:]]
    t_ladder = time.perf_counter() - t0  # the larger sides' passes, shared by both rules
    sig = [interval_sigmas(r, pts, side, None)[0] for r, side in zip(grown, ladder, strict=True)]
    choice = ici_choice(np.stack([r.position for r in grown]), np.stack(sig),
                        np.stack([r.accepted for r in grown]))
    ici = select_results(grown, choice)
    sides = np.asarray(ladder)[np.maximum(choice, 0)]
    rows.append(_judge(f"LSM + growing, window by ICI ({'/'.join(map(str, ladder))})",
                       np.where(ici.accepted[:, None], ici.position, np.nan), truth, smooth,
                       pts, time.perf_counter() - t0 + t_grown, n_cand, ici.sigma,
                       extra={"sides": {int(s): int(np.sum((choice >= 0) & (sides == s)))
                                        for s in ladder}}))
    _factor_figures(rows[-1], pts, ici, smooth, sides)
    # the same sides by the population rule (matching.ici.population_sides, what
    # match_pair(adaptive_patch="population") adds above Gruen's sides): the wall is one
    # class, the image's variance factor is the 21 px side's
    t0 = time.perf_counter()
    k2 = interval_sigmas(res, pts, patch, None)[1]
    accepted = np.stack([r.accepted for r in grown])
    cap = population_sides(np.stack([r.position for r in grown]),
                           np.stack([r.cov for r in grown]), accepted, k2,
                           np.zeros(len(pts), np.int64), np.stack([r.sigma0 for r in grown]))
    pop_choice = population_choice(accepted, np.full(len(pts), cap[0]))
    population = select_results(grown, pop_choice)
    pop_sides = np.asarray(ladder)[pop_choice]
    rows.append(_judge(f"LSM + growing, population rule "
                       f"({'/'.join(map(str, ladder))})",
                       np.where(population.accepted[:, None], population.position, np.nan),
                       truth, smooth, pts, time.perf_counter() - t0 + t_ladder + t_grown,
                       n_cand, population.sigma,
                       extra={"sides": {int(s): int(np.sum(population.accepted
                                                           & (pop_sides == s)))
                                        for s in ladder}}))
    _factor_figures(rows[-1], pts, population, smooth, pop_sides)


def graffiti(folder: Path, quick: bool, patch: int = GRAFFITI_PATCH) -> dict:
    """Graffiti figures (module docstring); ``patch``: the window side of LSM and its peers
    (odd, px)."""
    f, g = _grey(folder / "graf1.png"), _grey(folder / "graf3.png")
    hom = _homography(folder / "H1to3p.xml")
    if patch < 5 or patch % 2 == 0:
        raise ValueError(f"graffiti patch must be an odd side >= 5 px, got {patch}")
    spacing = 8 if quick else 4
    fp, gp = prepare_image(f), prepare_image(g)
    cand = select_points(f, spacing=spacing, patch=patch, noise=fp.noise)
    truth_all = _apply(hom, cand.points)
    h, w = g.shape
    inside = ((truth_all > patch) & (truth_all < [w - patch, h - patch])).all(1)
    wall = graffiti_wall(cand.points, patch // 2)
    n_cand = int((inside & wall).sum())
    sel = inside & wall & cand.textured
    pts, truth = cand.points[sel], truth_all[sel]
    approx = truth + np.random.default_rng(0).normal(0.0, 1.0, truth.shape)
    jac = _jacobian(hom, pts)
    init = np.column_stack([approx[:, 0], jac[:, 0, 0], jac[:, 0, 1], approx[:, 1],
                            jac[:, 1, 0], jac[:, 1, 1], np.zeros(len(pts)), np.ones(len(pts))])
    first, growth, t_first, t_grown = _lsm_grown(fp, gp, pts, approx, init, patch)
    res = growth.result
    plain = _lsm_grown(fp, gp, pts, approx, init, patch, footprint_var=None)[1].result
    t2 = time.perf_counter()
    fb = forward_backward(fp, gp, pts, res, patch=patch)
    t3 = time.perf_counter()
    ok = res.accepted
    near = ok & (np.linalg.norm(res.position - truth, axis=1) < 20.0)
    smooth = smooth_mapping(pts[near], res.position[near])
    k = float(np.sqrt(fb.variance_factor))
    rows = []
    one_pass = f"LSM one pass ({patch}x{patch}, H + 1 px start)"
    for name, result, seconds in ((one_pass, first, t_first),
                                  ("LSM + region growing (retries from neighbours)", res,
                                   t_grown)):
        pos = np.where(result.accepted[:, None], result.position, np.nan)
        rows.append(_judge(name, pos, truth, smooth, pts, seconds, n_cand, result.sigma))
    lsm_row = rows[-1]
    rows.append(_judge("LSM + growing, no footprint smoothing", np.where(
        plain.accepted[:, None], plain.position, np.nan), truth, smooth, pts, np.nan, n_cand,
        plain.sigma))
    # peer: robust LSM in every window (``lsm_match(robust=True)``, first pass and growth)
    robust = _lsm_grown(fp, gp, pts, approx, init, patch, robust=True)[1].result
    rows.append(_judge("LSM + growing, robust LSM (robust=True)", np.where(
        robust.accepted[:, None], robust.position, np.nan), truth, smooth, pts, np.nan, n_cand,
        robust.sigma))
    _factor_figures(rows[-1], pts, robust, smooth, patch)
    lsm_row["fb_variance_factor"] = fb.variance_factor
    lsm_row["fb_loop_rms_px"] = fb.loop_rms
    lsm_row["residual_over_sigma_with_fb_factor"] = lsm_row["residual_over_sigma"] / k
    lsm_row["fb_seconds"] = t3 - t2
    _factor_figures(lsm_row, pts, res, smooth, patch)
    _window_rules(rows, fp, gp, pts, approx, init, patch, res, truth, smooth, n_cand, t_grown)
    m = min(len(pts), 600 if quick else 3000)
    pick = np.random.default_rng(1).choice(len(pts), m, replace=False)
    t0 = time.perf_counter()
    ecc_pos = _ecc(f, g, pts[pick], approx[pick], jac[pick], patch)
    ecc_s = time.perf_counter() - t0
    rows.append(_judge("cv2.findTransformECC gauss=1 (per patch, subset)", ecc_pos,
                       truth[pick], smooth, pts[pick], ecc_s, m,
                       extra={"note": f"{m} random candidates"}))
    lsm_sub = np.where(res.accepted[pick, None], res.position[pick], np.nan)
    rows.append(_judge("LSM + growing on the ECC subset", lsm_sub, truth[pick], smooth,
                       pts[pick], np.nan, m, res.sigma[pick]))
    t0 = time.perf_counter()
    lk_pos = _lk(f, g, pts, approx, patch)
    rows.append(_judge(f"cv2.calcOpticalFlowPyrLK ({patch}x{patch})", lk_pos, truth, smooth, pts,
                       time.perf_counter() - t0, n_cand))
    status = {str(k_): int(v) for k_, v in zip(*np.unique(res.status, return_counts=True),
                                              strict=True)}
    return {"rows": rows, "candidates": n_cand, "textured": int(sel.sum()),
            "candidates_off_wall": int((inside & ~wall).sum()),
            "spacing": spacing, "patch": patch, "rounds": growth.rounds,
            "grown": int(growth.grown.sum()), "status_codes": status,
            "noise_flat_blocks": fp.noise,
            "synthetic": graffiti_synthetic(f, g, hom, pts, approx, init, patch)}


def graffiti_synthetic(f, g, hom, pts, approx, init, patch) -> dict:
    """The same candidates on graf1 warped by the homography (exact truth, no relief).

    graf3 re-rendered from graf1 (``render_homography``: the foreshortening and the
    pixel-area integration of the real view) plus white noise of graf3's flat-block σ;
    LSM and region growing as on the real pair, judged against the homography itself.
    What LSM errs here is its own error on this geometry and texture; the difference to
    the real pair is what the real images add.
    """
    from matching.lsm import estimate_noise

    rng = np.random.default_rng(2)
    noise = estimate_noise(g)
    synth = render_homography(f, hom, g.shape) + rng.normal(0.0, noise, g.shape)
    fp, gp = prepare_image(f), prepare_image(synth)
    first, growth, t_first, t_grown = _lsm_grown(fp, gp, pts, approx, init, patch)
    res = growth.result
    plain = _lsm_grown(fp, gp, pts, approx, init, patch, footprint_var=None)[1].result
    truth = _apply(hom, pts)
    exact = lambda p: _apply(hom, p)  # noqa: E731
    rows = []
    for name, result, seconds in (("LSM one pass, synthetic graf3", first, t_first),
                                  ("LSM + region growing, synthetic graf3", res, t_grown)):
        pos = np.where(result.accepted[:, None], result.position, np.nan)
        rows.append(_judge(name, pos, truth, exact, pts, seconds, len(pts), result.sigma))
    _factor_figures(rows[-1], pts, res, exact, patch)
    rows.append(_judge("LSM + growing, synthetic, no footprint smoothing", np.where(
        plain.accepted[:, None], plain.position, np.nan), truth, exact, pts, np.nan, len(pts),
        plain.sigma))
    return {"rows": rows, "noise_added": float(noise)}


# ------------------------------------------------------------------------------ temple
def _rectified_pair(cams, images, i, j):
    """The pair as the multi-view pipeline matches it (rectify_pair + rectify_images): the
    rectified grey images (the baseline along +x, matching.rectify) and the left's valid area."""
    from matching.masks import grey
    from matching.multiview import rectify_pair
    from matching.rectify import rectify_images

    rect, _, _ = rectify_pair(cams[i], cams[j])
    left, right = rectify_images(rect, grey(images[i]), grey(images[j]))
    valid = cv2.remap(np.ones(images[i].shape[:2], np.float32), *rect.maps_left,
                      cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=0) > 0
    return left, right, valid


def _sgbm_loop(left, right, points):
    """SGBM left-right loop along the rows at ``points`` (NaN where either is missing).

    The right image's disparity comes from SGBM on the mirrored pair (right mirrored as
    the left image): a right pixel x_r matches x_l = x_r + d_r, the same range.
    """
    lo, count = disparity_range(left, right)
    d_left = sgbm_disparity(left, right, lo, count)
    d_right = sgbm_disparity(right[:, ::-1], left[:, ::-1], lo, count)[:, ::-1]
    w = left.shape[1]
    xi, yi = points[:, 0].astype(int), points[:, 1].astype(int)
    xr = points[:, 0] - d_left[yi, xi]
    ok = np.isfinite(xr) & (xr >= 0) & (xr < w - 1)
    x0 = np.where(ok, np.floor(np.nan_to_num(xr)), 0).astype(int)
    t = xr - x0
    rows = d_right[yi]
    idx = np.arange(len(points))
    back = (1 - t) * rows[idx, x0] + t * rows[idx, np.minimum(x0 + 1, w - 1)]
    back[~ok] = np.nan
    return (xr + back) - points[:, 0], d_left


def _temple_row(d: dict, robust: dict, reference: np.ndarray) -> dict:
    """One temple pair's figures (:func:`temple`): acceptance on the object, its interior
    and outline, forward-backward loops against LSM's σ and SGBM's, eccentric windows and
    robust LSM on the edge windows (``robust``: the same pair's data with robust="edge")."""
    from _visibility import seen_in_both

    from matching.pair import PAIR_STATUS_NAMES, match_pair

    i, j = d["pair"]
    left, right, valid = d["left"], d["right"], d["valid"]
    fg = (left > 0.19 * 255).astype(np.float32)
    obj = cv2.dilate(fg.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    # interior: no background pixel in the 15x15 window (match_pair's base patch);
    # the rest of the object's candidates straddle its outline (a depth edge)
    background = 1.0 - cv2.boxFilter(fg, -1, (15, 15), normalize=True,
                                      borderType=cv2.BORDER_CONSTANT)
    m, seconds = d["matches"], d["seconds"]
    xi = m.x_left.astype(int)
    on_obj = obj[xi[:, 1], xi[:, 0]]
    interior = on_obj & (background[xi[:, 1], xi[:, 0]] < 1e-6)
    ecc = match_pair(left, right, rectified=True, mask=valid, spacing=4, eccentric=True)
    forward = LSMResult(position=m.x_right, affine=m.affine, radiometric=m.radiometric,
                        converged=m.accepted, iterations=m.iterations, sigma0=m.sigma0,
                        cov=m.cov, correlation=m.correlation, status=m.status,
                        noise_sigma0=float("nan"))
    fb = forward_backward(prepare_image(left), prepare_image(right), m.x_left, forward)
    use = fb.used & on_obj
    loop_x = fb.loop[:, 0]
    lsm_fb = float(np.sqrt(np.mean(loop_x[use] ** 2) / 2))
    sig_x = float(np.sqrt(np.mean(m.cov[use, 0, 0])))
    try:
        sgbm_loop, _ = _sgbm_loop(left, right, m.x_left)
    except ValueError as exc:  # SIFT finds no row-consistent match on this pair
        sgbm_loop = np.full(len(m.x_left), np.nan)
        print(f"temple pair {(i, j)}: SGBM left-right loop skipped ({exc})")
    same = use & np.isfinite(sgbm_loop) & (np.abs(sgbm_loop) < 3)
    mp = robust["matches"]
    surface, seen = seen_in_both(reference, d["cams"][0], d["cams"][1], m.x_left)
    both = on_obj & seen
    row = {
        "reference_surface_share_of_object": float(surface[on_obj].mean()),
        "seen_in_both_share_of_object": float(both.sum() / on_obj.sum()),
        "accepted_share_seen_in_both": float(m.accepted[both].mean()),
        "status_seen_in_both": {PAIR_STATUS_NAMES[int(k)]: int(v) for k, v in zip(
            *np.unique(m.status[both], return_counts=True), strict=True)},
        "pair": [i, j], "candidates_on_object": int(on_obj.sum()),
        "accepted_share_on_object": float(m.accepted[on_obj].mean()),
        "accepted_share_on_object_robust_edge": float(mp.accepted[on_obj].mean()),
        "edge_share_of_accepted": float(m.edge[m.accepted].mean()),
        "edge_share_of_accepted_robust_edge": float(mp.edge[mp.accepted].mean()),
        "interior_share_of_object": float(interior.sum() / on_obj.sum()),
        "accepted_share_interior": float(m.accepted[interior].mean()),
        "accepted_share_outline": float(m.accepted[on_obj & ~interior].mean()),
        "accepted_share_on_object_eccentric": float(ecc.accepted[on_obj].mean()),
        "accepted_share_interior_eccentric": float(ecc.accepted[interior].mean()),
        "status_on_object": {PAIR_STATUS_NAMES[int(k)]: int(v) for k, v in zip(
            *np.unique(m.status[on_obj], return_counts=True), strict=True)},
        "lsm_fb_loop_rms_px": lsm_fb, "lsm_reported_sigma_x_rms_px": sig_x,
        "lsm_fb_over_sigma": lsm_fb / sig_x, "fb_variance_factor": fb.variance_factor,
        "variance_factor": m.sigma_factor, "variance_factor_edge": m.sigma_factor_edge,
        "lsm_sigma_x_without_factor_rms_px": float(np.sqrt(np.mean(
            m.cov[use, 0, 0] / np.where(m.edge[use], m.sigma_factor_edge,
                                        m.sigma_factor)))),
        "same_pixels": int(same.sum()),
        "lsm_fb_loop_rms_same_px": float(np.sqrt(np.mean(loop_x[same] ** 2) / 2)),
        "sgbm_lr_loop_rms_same_px": float(np.sqrt(np.mean(sgbm_loop[same] ** 2) / 2)),
        "seconds": seconds}
    row["sgbm_over_lsm"] = row["sgbm_lr_loop_rms_same_px"] / row["lsm_fb_loop_rms_same_px"]
    return row


def temple(folder: Path, quick: bool) -> dict:
    """Temple neighbouring-pair figures (module docstring)."""
    from matching.cameras import read_projection_txt
    from matching.pair import match_pair

    cams = read_projection_txt(folder / "templeSR_par.txt", image_dir=folder)
    images = [imread(str(folder / c.name), cv2.IMREAD_COLOR) for c in cams]
    # the ring pipeline's own pairs (baseline/depth and viewing angle): the views are not
    # numbered in ring order (4-5 or 12-13 are no neighbours: no common rectification)
    from matching.view_pairs import select_pairs

    chosen = select_pairs(cams)
    pairs = [chosen[0]] if quick else [chosen[k * len(chosen) // 4] for k in range(4)]
    # every ring pair once (LSM and SGBM): the cross-pair check needs the whole network
    data = [_pair_data(cams, images, i, j) for i, j in chosen]
    # which object pixels the right view sees at all: the 16-view cloud as a reference
    # (benchmarks/_visibility.py; with the given cameras, the ring pipeline's defaults)
    from matching.multiview import reconstruct_multiview

    reference = reconstruct_multiview(images, cams).points
    # the peer: the same pairs with robust LSM on the edge windows (robust="edge")
    robust = [_pair_data(cams, images, i, j, robust="edge") for i, j in chosen]
    robust_by_pair = {d["pair"]: d for d in robust}
    by_pair = {d["pair"]: d for d in data}
    rows = [_temple_row(by_pair[(i, j)], robust_by_pair[(i, j)], reference) for i, j in pairs]
    # dense mode: every pixel of the first rectified pair (640x480 transposed)
    left, right, valid = _rectified_pair(cams, images, *pairs[0])
    t0 = time.perf_counter()
    dense = match_pair(left, right, rectified=True, mask=valid, spacing=1)
    seconds = time.perf_counter() - t0
    comps = cross_pair_comparisons(data)
    network = cross_pair_network(data, comps)
    by_class = {name: cross_pair_summary(cross_pair_comparisons(_window_class(data, keep)))
                for name, keep in (("clear", False), ("edge", True))}
    comps_robust = cross_pair_comparisons(robust)
    network_robust = cross_pair_network(robust, comps_robust)
    by_class_robust = {
        name: cross_pair_summary(cross_pair_comparisons(_window_class(robust, keep)))
        for name, keep in (("clear", False), ("edge", True))}
    for r in rows:
        mine = next(p for p in network["pairs"] if p["pair"] == r["pair"])
        r["cross_pair"] = mine
        r["cross_pair_robust_edge"] = next(p for p in network_robust["pairs"]
                                            if p["pair"] == r["pair"])
    out = {"rows": rows, "cross_pair": {
        "comparisons": [{k: v for k, v in c.items() if k != "p_points"} for c in comps],
        "network": network, "summary": cross_pair_summary(comps),
        "summary_by_window_class": by_class,
        "robust_edge": {"summary": cross_pair_summary(comps_robust),
                         "summary_by_window_class": by_class_robust,
                         "network": network_robust},
        "max_angle_deg": CROSS_MAX_ANGLE_DEG, "bound_px": CROSS_BOUND_PX,
        "radius_px": CROSS_RADIUS_PX,
        "pairs": [list(d["pair"]) for d in data]}, "dense": {
        "pair": list(pairs[0]), "image": [int(left.shape[1]), int(left.shape[0])],
        "candidates": len(dense), "accepted": int(dense.accepted.sum()),
        "seconds": seconds, "px_per_s": left.size / seconds,
        "accepted_per_s": float(dense.accepted.sum() / seconds)}}
    return out


# ------------------------------------------------------------------ temple cross-pair check
#: Largest angle (deg) at the point between the rays of P's and Q's left views: beyond
#: it the two pairs see a relief through windows too different (and the surface too often
#: hidden) for one to check the other.  The ring's neighbouring disjoint pairs lie 23-60
#: deg apart; the table is split at 35 deg.
CROSS_MAX_ANGLE_DEG = 50.0
#: Discrepancies beyond this (px) are no matching error (occlusion, another surface).
CROSS_BOUND_PX = 3.0
#: Q's match must lie within this of the transferred point (px): its warp carries it there.
CROSS_RADIUS_PX = 2.0


def _pair_data(cams, images, i, j, spacing=4, **options):
    """LSM (``match_pair``, ``options``) and SGBM of one rectified ring pair, with its
    rectified cameras."""
    from matching.multiview import rectify_pair
    from matching.pair import match_pair

    left, right, valid = _rectified_pair(cams, images, i, j)
    _, cam_l, cam_r = rectify_pair(cams[i], cams[j])
    t0 = time.perf_counter()
    m = match_pair(left, right, rectified=True, mask=valid, spacing=spacing, **options)
    seconds = time.perf_counter() - t0
    try:
        lo, count = disparity_range(left, right)
        sgbm = sgbm_disparity(left, right, lo, count)
    except ValueError:
        sgbm = np.full(left.shape, np.nan, np.float32)
    return {"pair": (i, j), "matches": m, "cams": (cam_l, cam_r), "sgbm": sgbm,
            "left": left, "right": right, "valid": valid, "seconds": seconds}


def cross_pair_comparisons(data: list[dict], max_angle: float = CROSS_MAX_ANGLE_DEG,
                           bound: float = CROSS_BOUND_PX, radius: float = CROSS_RADIUS_PX,
                           min_points: int = 100) -> list[dict]:
    """Every ordered comparison of two pairs without a common view (module section).

    On the same P pixels (LSM accepted, SGBM valid there and at Q) and the same Q
    neighbourhoods: LSM's discrepancy (P's match transferred, Q's nearest match's
    warp at the transferred point) and SGBM's (P's SGBM disparity transferred, Q's
    SGBM map bilinearly there), each with the cameras' trend removed
    (``matching.precision.geometric_trend``), its Gaussian core's spread and outlier
    share (``core_spread``), and LSM's discrepancy over the σ both pairs report.
    """
    from matching.precision import (
        core_spread,
        discrepancy,
        geometric_trend,
        lsm_column_at,
        map_column_at,
        ray_angle,
        transfer_matches,
    )

    out = []
    for p, dp in enumerate(data):
        mp = dp["matches"]
        ok = np.flatnonzero(mp.accepted)
        xl, xr = mp.x_left[ok], mp.x_right[ok]
        xi = xl.astype(int)
        d_sgbm = dp["sgbm"][xi[:, 1], xi[:, 0]].astype(np.float64)
        for q, dq in enumerate(data):
            if set(dp["pair"]) & set(dq["pair"]):
                continue
            mq = dq["matches"]
            angle = ray_angle(dp["cams"][0], dq["cams"][0], xl, xr[:, 0], dp["cams"])
            near = angle <= max_angle
            if near.sum() < min_points:
                continue
            tr = transfer_matches(dp["cams"], xl, xr, dq["cams"])
            col, qi, slope = lsm_column_at(tr.u, mq.x_left, mq.x_right, mq.affine,
                                           mq.accepted, radius)
            delta, c = discrepancy(tr, col, slope)
            trs = transfer_matches(dp["cams"], xl, xl[:, 0] - d_sgbm, dq["cams"])
            col_s, slope_s = map_column_at(trs.u, dq["sgbm"].astype(np.float64))
            delta_s, c_s = discrepancy(trs, col_s, slope_s)
            use = (near & np.isfinite(delta) & np.isfinite(delta_s)
                   & (np.abs(delta) < bound) & (np.abs(delta_s) < bound))
            if use.sum() < min_points:
                continue
            disp_q = tr.u[use, 0] - tr.v_x[use]
            res_l, trend = geometric_trend(tr.u[use], disp_q, delta[use], bound)
            res_s, _ = geometric_trend(trs.u[use], disp_q, delta_s[use], bound)
            var_q = mq.cov[qi[use], 0, 0]
            var_p = c[use] ** 2 * mp.cov[ok[use], 0, 0]
            total = var_q + var_p
            lsm_sigma, _, lsm_out = core_spread(res_l, bound)
            sgbm_sigma, _, sgbm_out = core_spread(res_s, bound)
            z = core_spread(res_l / np.sqrt(total), 5 * bound)[0]
            out.append({
                "p": p, "q": q, "P": list(dp["pair"]), "Q": list(dq["pair"]),
                "points": int(use.sum()), "angle_median_deg": float(np.median(angle[use])),
                "c2_lsm": float(np.mean(c[use] ** 2)), "c2_sgbm": float(np.mean(c_s[use] ** 2)),
                "lsm_px": lsm_sigma, "sgbm_px": sgbm_sigma,
                "lsm_outliers": lsm_out, "sgbm_outliers": sgbm_out,
                "sgbm_over_lsm": sgbm_sigma / lsm_sigma,
                "trend_rms_px": float(np.sqrt(np.mean(trend**2))),
                "lsm_over_reported": z,
                "share_q": float(np.mean(var_q / total)), "share_p": float(np.mean(var_p / total)),
                "p_points": ok[use]})
    return out


def _window_class(data: list[dict], edge: bool) -> list[dict]:
    """``data`` with only the accepted windows clear of an edge (``edge`` False) or
    reaching over one (True) left accepted, in P and in Q."""
    from dataclasses import replace

    out = []
    for d in data:
        m = d["matches"]
        status = m.status.copy()
        status[m.edge != edge] = 255  # no status: not accepted
        out.append(dict(d, matches=replace(m, status=status)))
    return out


def cross_pair_network(data: list[dict], comps: list[dict]) -> dict:
    """Per pair: its own LSM and SGBM error (px) and LSM's actual / reported σ, from the
    network of comparisons (``matching.precision.network_variances``)."""
    from matching.precision import network_variances

    g = lambda key: np.array([c[key] for c in comps], np.float64)  # noqa: E731
    p, q, n = g("p").astype(int), g("q").astype(int), g("points")
    lsm = network_variances(len(data), p, q, g("lsm_px") ** 2, g("c2_lsm"), np.ones(len(p)), n)
    sgbm = network_variances(len(data), p, q, g("sgbm_px") ** 2, g("c2_sgbm"), np.ones(len(p)),
                             n)
    scale = network_variances(len(data), p, q, g("lsm_over_reported") ** 2, g("share_p"),
                              g("share_q"), n)
    rows = []
    for k, d in enumerate(data):
        m = d["matches"]
        used = np.zeros(len(m), bool)
        for c in comps:
            if c["p"] == k:
                used[c["p_points"]] = True
        mine = (p == k) | (q == k)
        rows.append({
            "pair": list(d["pair"]), "comparisons": int(mine.sum()),
            "points_as_p": int(used.sum()),
            "lsm_px": float(np.sqrt(lsm.variance[k])), "sgbm_px": float(np.sqrt(sgbm.variance[k])),
            "sgbm_over_lsm": float(np.sqrt(sgbm.variance[k] / lsm.variance[k]))
            if lsm.variance[k] > 0 else float("nan"),
            "lsm_over_reported": float(np.sqrt(scale.variance[k])),
            "reported_sigma_rms_px": float(np.sqrt(np.mean(m.cov[used, 0, 0])))
            if used.any() else float("nan"),
            "variance_factor": float(m.sigma_factor),
            "variance_factor_edge": float(m.sigma_factor_edge),
            "median_sgbm_over_lsm": float(np.median(g("sgbm_over_lsm")[mine]))
            if mine.any() else float("nan"),
            "median_lsm_over_reported": float(np.median(g("lsm_over_reported")[mine]))
            if mine.any() else float("nan")})
    fit = {name: float(np.sqrt(np.nanmean(v.residual ** 2)))
           for name, v in (("lsm", lsm), ("sgbm", sgbm), ("scale", scale))}
    return {"pairs": rows, "fit_relative_rms": fit}


def cross_pair_summary(comps: list[dict]) -> dict:
    """Medians over the comparisons, by angle class (below / above 35 deg)."""
    out = {}
    for name, lo, hi in (("all", 0.0, 180.0), ("below_35deg", 0.0, 35.0),
                         ("35deg_and_above", 35.0, 180.0)):
        sel = [c for c in comps if lo <= c["angle_median_deg"] < hi]
        if not sel:
            continue
        def g(key, sel=sel):
            return np.array([c[key] for c in sel], np.float64)

        out[name] = {"comparisons": len(sel), "points": int(g("points").sum()),
                     "lsm_px": float(np.median(g("lsm_px"))),
                     "sgbm_px": float(np.median(g("sgbm_px"))),
                     "sgbm_over_lsm": float(np.median(g("sgbm_over_lsm"))),
                     "lsm_over_reported": float(np.median(g("lsm_over_reported"))),
                     "lsm_outliers": float(np.median(g("lsm_outliers"))),
                     "sgbm_outliers": float(np.median(g("sgbm_outliers"))),
                     "trend_rms_px": float(np.median(g("trend_rms_px")))}
    return out
