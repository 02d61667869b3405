"""The epipolar pass of a calibrated pair: LSM constrained to the rectified rows.

Every window LSM tried is matched again in the rectified images with the y-shift fixed
by the rig (Gruen & Baltsavias 1988): only the shift and the shape along the row are
solved, then once more with fixed second-order terms along the row from the neighbours.
A window ill-conditioned along the line is tried at larger sides, then rejected
(``aperture``: the shape takes the shift's information at the window's least-variance
point, :func:`_least_variance_point`, or the rig's row error through the edge slope
exceeds the match's σ).  Where the two cameras blur differently, the sharper rectified
image is first smoothed to the other's blur, measured from the matched windows' edge
profiles (:func:`_blur_balance`).  :func:`_epipolar_refine` returns the matches in the original
images and the rectified frame's (a dict) for the uniqueness test, the backward loop and
the report (:mod:`matching.pair_verify`, :mod:`matching.pair_centres`).
Measured: ``docs/decisions/stereo-epipolar.md``.
"""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import cv2
import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from checks.robust import MAD_TO_SIGMA, mad_sigma
from matching.lsm import LSMResult, PreparedImage, Status, lsm_match, prepare_image
from matching.pair_status import MAX_INFLATION
from matching.precision import class_variance_factors
from matching.rectify import (
    left_to_rectified,
    rectified_to_original,
    rectify_images,
    right_to_rectified,
)
from matching.second_order import second_order_terms
from matching.seeds import DEFAULT_SPACING


def _structure_tensors(image: np.ndarray, points: np.ndarray, sides: np.ndarray) -> np.ndarray:
    """(N, 2, 2) mean structure tensor (central differences) of each ``sides`` x ``sides``
    window of ``image`` centred on the integer ``points``."""

    img = np.asarray(image, dtype=np.float64)
    gx = np.zeros_like(img)
    gy = np.zeros_like(img)
    gx[:, 1:-1] = 0.5 * (img[:, 2:] - img[:, :-2])
    gy[1:-1, :] = 0.5 * (img[2:, :] - img[:-2, :])
    xi = np.rint(points).astype(np.intp)
    xi[:, 0] = np.clip(xi[:, 0], 0, img.shape[1] - 1)
    xi[:, 1] = np.clip(xi[:, 1], 0, img.shape[0] - 1)
    out = np.zeros((len(points), 2, 2))
    for side in np.unique(sides):
        sel = np.flatnonzero(sides == side)
        box = [cv2.boxFilter(p, -1, (int(side), int(side)), borderType=cv2.BORDER_REFLECT)
               for p in (gx * gx, gx * gy, gy * gy)]
        vals = [b[xi[sel, 1], xi[sel, 0]] for b in box]
        out[sel] = np.stack([np.stack([vals[0], vals[1]], -1),
                             np.stack([vals[1], vals[2]], -1)], -2)
    return out



def _jacobians(fn, points: np.ndarray, step: float = 0.5) -> np.ndarray:
    """(N, 2, 2) central-difference Jacobians of the point map ``fn`` at ``points``."""
    cols = [(fn(points + e) - fn(points - e)) / (2.0 * step)
            for e in (np.array([step, 0.0]), np.array([0.0, step]))]
    return np.stack(cols, axis=2)



def _odd_at_least(value) -> np.ndarray:
    """Smallest odd integers >= ``value`` (array_like)."""
    side = np.ceil(np.asarray(value, dtype=np.float64) - 1e-9).astype(np.int32)
    return side + 1 - side % 2



def _least_variance_point(affine_cov: np.ndarray, half) -> tuple[np.ndarray, np.ndarray]:
    """The least-variance point of constrained warps along the row and its variance.

    The warp x' = a0 + a1 x + a2 y gives the match of every template pixel (x, y) (from the
    window's centre) with variance gᵀ C g, g = (1, x, y), C the covariance of a0 a1 a2
    (the first three of ``affine_cov`` (N, >= 3, >= 3)); it is least at
    p* = -C₁₁⁻¹ c₁₀ (Förstner's optimal point of a window).  Returns p* (N, 2) and its
    variance (N,), NaN where p* is undefined or outside the window (|p*| > ``half``).
    """
    c3 = np.asarray(affine_cov)[:, :3, :3]
    with np.errstate(divide="ignore", invalid="ignore"):
        det = c3[:, 1, 1] * c3[:, 2, 2] - c3[:, 1, 2] ** 2
        px = -(c3[:, 2, 2] * c3[:, 1, 0] - c3[:, 1, 2] * c3[:, 2, 0]) / det
        py = -(c3[:, 1, 1] * c3[:, 2, 0] - c3[:, 1, 2] * c3[:, 1, 0]) / det
    pstar = np.column_stack([px, py])
    inside = (np.isfinite(pstar).all(axis=1)
              & (np.abs(pstar) <= np.asarray(half, np.float64).reshape(-1, 1)).all(axis=1))
    g = np.column_stack([np.ones(len(c3)), pstar])
    var = np.where(inside, np.einsum("ni,nij,nj->n", np.nan_to_num(g), c3, np.nan_to_num(g)),
                   np.nan)
    pstar[~inside] = np.nan
    return pstar, var



def _epipolar_refine(left, right, rig, rect, points, start, res: LSMResult, sides,
                     options: dict,
                     aperture_k: float | None, interpolation: str,
                     max_inflation: float | None = MAX_INFLATION, grow_sides=(1.5, 2.0),
                     second_order: bool = True, spacing: int = DEFAULT_SPACING,
                     classes=None, scale_cov: bool = True, fixed: dict | None = None,
                     at_best_point: bool = True, equalise_blur: bool = False):
    """LSM constrained to the epipolar line of a calibrated pair (Gruen & Baltsavias 1988).

    Every window LSM tried (the 2-D solution where it was accepted, else the approximation
    ``start``) is matched again in the rectified images (cubic B-spline resampling at the
    maps' exact coordinates), where the y-shift is the rig's: the template on the rectified
    pixel grid with the left point reported through the warp (``offset``), the search
    window started on the left point's row, the 2-D warp taken into the rectified frame
    through the rectifications' Jacobians (Jr A Jl⁻¹), and only the shift and the shape
    along the row solved with the radiometry (``lsm_match``'s ``direction`` (1, 0) +
    ``rigid_across``: rows map to rows, exact), then once more with fixed second-order
    terms along the row from the neighbours (``second_order``).

    Ill-conditioned along the line (``aperture``), tried again at ``grow_sides`` x the
    side (a window reaching the texture's next corner is conditioned), rejected if still:

    * the shape unknowns take the shift's information: its variance exceeds
      ``max_inflation`` x σ0² / Σ f_x², what the template's x-gradients alone give (a
      single edge off the window's centre trades the shift for the scale along the row),
      at the window's least-variance point where that is inside it and ``at_best_point``
      (the match is reported there, :func:`matching.pair_centres._information_centres`;
      a window reported elsewhere is tested again where it is,
      :func:`matching.pair_centres._shape_dominated`), else at its centre;
    * the rig's own row error δy, moved by the edge slope ``|N_xy / N_xx|`` of the window's
      structure tensor into the column, exceeds ``aperture_k`` x the match's σ along the
      line (δy's spread σ_g: 1.4826 MAD of the accepted 2-D matches' rectified row
      differences over windows textured in both directions, λmin/λmax >= 1/4).

    Returns the result in the original images (rank-1 covariance along the line, with the
    constrained matches' own variance factor per window class ``classes``, unless
    ``scale_cov`` is off; a window the pass loses keeps its rejection), the variance
    ``(slope σ_g)²`` along the line (px²; NaN: ``aperture``), the (N, 2) line directions
    in the right image, the sides used, the variance factors (clear windows, edge
    windows) and the rectified frame's matches (a dict of (N, ...) arrays, NaN where the
    pass did not run, with the prepared rectified images; ``fixed``: σ_g and the
    variance factors taken from an earlier call's frame instead of estimated).

    ``equalise_blur``: the rectified images' blur along the rows made equal where it
    differs (:func:`_blur_balance`, :func:`_smoothed`) and the footprint smoothing off;
    the frame's ``blur`` holds the median variance each image was smoothed by (None:
    not measured, the footprint rule kept).
    """

    n = len(points)
    w = _rectified_windows(left, right, rig, rect, points, start, res, fixed, interpolation)
    opts = {k: v for k, v in options.items()
            if k not in ("offset", "robust", "quadratic", "direction", "rigid_across")}
    blur = None
    if equalise_blur:
        # the rectified images' blur along the rows made equal where it differs, measured
        # from the matched windows, in place of the footprint rule's geometric guess; a
        # later call (``fixed``) matches in the images the first call made
        if fixed is None:
            fields = _blur_balance(w, sides)
            if fields is not None:
                w.fprep = _smoothed(w.fprep, fields[0], interpolation)
                w.gprep = _smoothed(w.gprep, fields[1], interpolation)
                w.left_r = w.fprep.raw
                blur = fields[2]
        else:
            blur = fixed.get("blur")
        if blur is not None:
            opts["footprint_var"] = None
    found, side_of, todo, sigma_g, k2_each, k2_classes = _constrained_matches(
        w, n, res, sides, opts, aperture_k, max_inflation, grow_sides, classes, fixed,
        at_best_point)
    good = found["status"] == Status.OK
    # the final warp and its covariance (the second-order pass's where it ran) and the
    # fixed second-order terms: where the window's shift is best determined
    # (_information_centres)
    found["affine_fin"] = found["affine"].copy()
    found["affine_cov_fin"] = found["affine_cov"].copy()
    found["quad"] = np.zeros((len(w.ok), 6))
    if second_order and good.sum() >= 8:
        _second_order_along_row(w, found, good, side_of, opts, spacing)
    out, geo, dirs, new_sides, stretch_ok = _in_original_images(
        w, rig, rect, res, found, side_of, todo, sides, sigma_g, k2_each, scale_cov)
    k2 = float(k2_classes[0]) if len(k2_classes) else 1.0
    factors = (k2, float(k2_classes[1]) if len(k2_classes) > 1 else k2)
    # the rectified frame's matches, for the uniqueness test and the backward loop there
    frame = {"fprep": w.fprep, "gprep": w.gprep, "opts": opts, "sigma_g": sigma_g,
             "factors": factors, "index": np.arange(n), "blur": blur}
    for key, value in (("centre", w.centre_r), ("frac", w.frac), ("xl", w.xl_r),
                       ("position", found["position"]), ("affine", found["affine"]),
                       ("radiometric", found["radiometric"]), ("cov", found["cov"]),
                       ("sides", side_of), ("k2", k2_each), ("sigma0", found["sigma0"]),
                       ("correlation", found["correlation"]), ("stretch", stretch_ok),
                       ("affine_fin", found["affine_fin"]),
                       ("affine_cov_fin", found["affine_cov_fin"]), ("quad", found["quad"]),
                       ("unit", found["unit"])):
        value = np.asarray(value)
        full = (np.full(n, -1, np.int32) if key == "sides"
                else np.full((n,) + value.shape[1:], np.nan))
        full[w.ok] = value
        frame[key] = full
    return out, geo, dirs, new_sides, factors, frame


def _rectified_windows(left, right, rig, rect, points, start, res: LSMResult, fixed,
                       interpolation: str) -> SimpleNamespace:
    """The windows of :func:`_epipolar_refine` in the rectified frame: which (``ok``: every
    window LSM tried), their template centres on the rectified pixel grid and the left
    points' fractions of a pixel from them, the 2-D warps taken into the frame (the
    initial parameters), the rig's row differences of the accepted 2-D matches, and the
    prepared rectified images (an earlier call's with ``fixed``)."""
    accepted = res.accepted
    # every window LSM tried from an approximation: the 2-D solution where it was
    # accepted, else the approximation (a 2-D window sliding along an edge fails the
    # pull-in test that the constrained one passes)
    tried = accepted | (np.isfinite(start).all(1) & ~np.isin(
        res.status, (Status.TEXTURELESS, Status.OUTSIDE_IMAGE)))
    ok = np.flatnonzero(tried)
    from_2d = accepted[ok]
    x_start = np.where(from_2d[:, None], res.position[ok], start[ok])
    xl_r = left_to_rectified(rect, rig.left, points[ok])
    xr_r = right_to_rectified(rect, rig.right, x_start)
    dy = (xr_r[:, 1] - xl_r[:, 1])[from_2d]
    if fixed is not None and "fprep" in fixed:  # the earlier call's rectified pair
        left_r, right_r = fixed["fprep"].raw, fixed["gprep"].raw
    else:
        left_r, right_r = rectify_images(rect, left, right, interpolation="spline")
    jl = _jacobians(lambda p: left_to_rectified(rect, rig.left, p), points[ok])
    jr = _jacobians(lambda p: right_to_rectified(rect, rig.right, p), x_start)
    # the 2-D warp (template -> search) in the rectified frame: Jr A Jl⁻¹ (A = I
    # from an approximation)
    amat = np.tile(np.eye(2), (len(ok), 1, 1))
    amat[from_2d] = res.affine[ok[from_2d]][:, [1, 2, 4, 5]].reshape(-1, 2, 2)
    a_rect = jr @ amat @ np.linalg.inv(jl)
    init = np.zeros((len(ok), 8))
    # the template window on the rectified image's pixel grid (a template resampled at a
    # fraction of a pixel smooths its noise: σ0²N⁻¹ would under-report), the left point
    # reported through the warp as an eccentric pixel (lsm_match's ``offset``)
    centre_r = np.rint(xl_r)
    frac = xl_r - centre_r
    init[:, [1, 2, 4, 5]] = a_rect.reshape(-1, 4)
    init[:, 0] = xr_r[:, 0] - a_rect[:, 0, 0] * frac[:, 0] - a_rect[:, 0, 1] * frac[:, 1]
    init[:, 3] = centre_r[:, 1]
    init[:, 6], init[:, 7] = 0.0, 1.0
    init[from_2d, 6:] = res.radiometric[ok[from_2d]]
    if fixed is not None and "fprep" in fixed:
        fprep, gprep = fixed["fprep"], fixed["gprep"]
    else:
        fprep = prepare_image(left_r, interpolation)
        gprep = prepare_image(right_r, interpolation)
    return SimpleNamespace(ok=ok, from_2d=from_2d, xl_r=xl_r, dy=dy, left_r=left_r, jl=jl,
                           init=init, centre_r=centre_r, frac=frac, fprep=fprep, gprep=gprep)


def _constrained_matches(w: SimpleNamespace, n: int, res: LSMResult, sides, opts: dict,
                         aperture_k, max_inflation, grow_sides, classes, fixed,
                         at_best_point: bool):
    """The constrained LSM of :func:`_epipolar_refine`'s windows ``w`` at the base side,
    then at ``grow_sides`` x it where ill-conditioned along the line; the rig's row error
    σ_g and the variance factors (from ``fixed`` or estimated).  Returns the matches
    (a dict of arrays over ``w.ok``), their sides, the windows still ill-conditioned, σ_g,
    each window's variance factor and the classes'."""
    m = len(w.ok)
    side_of = np.asarray(sides, np.int32)[w.ok].copy()
    base = side_of.copy()
    sigma_g = 0.0
    found = {"status": np.array(res.status[w.ok]), "position": np.full((m, 2), np.nan),
             "cov": np.full((m, 2, 2), np.nan), "sigma0": np.full(m, np.nan),
             "correlation": np.full(m, np.nan), "inflation": np.full(m, np.nan),
             "unit": np.full(m, np.nan),
             "slope": np.full(m, np.nan), "affine": np.full((m, 6), np.nan),
             "radiometric": np.full((m, 2), np.nan),
             "affine_cov": np.full((m, 6, 6), np.nan)}
    todo = np.ones(m, bool)
    for step, factor in enumerate((1.0,) + tuple(grow_sides)):
        # the base side, then (where the window is ill-conditioned along the line) the
        # larger ones: a window that reaches the next corner of the texture is
        side_of[todo] = _odd_at_least(factor * base[todo])
        for side in np.unique(side_of[todo]):
            _match_side(w, found, np.flatnonzero(todo & (side_of == side)), int(side), opts,
                        at_best_point)
        if step == 0 and fixed is not None:
            sigma_g = fixed["sigma_g"]
        elif step == 0:
            # the rig's row error, from the windows textured in both directions
            eig = np.linalg.eigvalsh(_structure_tensors(w.left_r, w.centre_r[w.from_2d],
                                                        base[w.from_2d]))
            round_ = eig[:, 0] >= 0.25 * eig[:, 1]
            ref = w.dy[round_] if round_.sum() >= 30 else w.dy
            sigma_g = (float(mad_sigma(ref))
                       if len(ref) else 0.0)
        good = found["status"] == Status.OK
        if step == 0 and fixed is not None:
            cls = (np.zeros(n, np.int64) if classes is None
                   else np.asarray(classes, np.int64))[w.ok]
            k2_classes = np.asarray(fixed["factors"], np.float64)
            k2_each = np.maximum(k2_classes[np.minimum(cls, len(k2_classes) - 1)], 1.0)
        elif step == 0:
            # the variance factor of the constrained matches (independent neighbouring
            # windows predicting their midpoint, along the row: 1 degree of freedom);
            # the rectified images' resampling correlates their noise
            # per window class (``edge`` windows reach over an untextured region: a
            # second population, class_variance_factors)
            k2_each, k2_classes = class_variance_factors(
                w.centre_r, found["affine"], found["affine_cov"], good,
                (np.zeros(n, np.int64) if classes is None
                 else np.asarray(classes, np.int64))[w.ok], patch=side_of)
            k2_each = np.maximum(k2_each, 1.0)
        cond = good.copy()
        geo_r = (found["slope"] * sigma_g) ** 2  # rectified px²
        if aperture_k is not None:
            cond &= geo_r <= aperture_k**2 * k2_each * found["cov"][:, 0, 0]
        if max_inflation is not None:
            cond &= found["inflation"] <= max_inflation
        todo = todo & good & ~cond
        if not todo.any():
            break
    return found, side_of, todo, sigma_g, k2_each, k2_classes


def _match_side(w: SimpleNamespace, found: dict, sel: np.ndarray, side: int, opts: dict,
                at_best_point: bool) -> None:
    """One side's constrained LSM of the windows ``sel`` into ``found``, with each window's
    edge slope and its variance inflation along the row."""
    tensor = _structure_tensors(w.left_r, w.centre_r[sel], np.full(len(sel), side))
    with np.errstate(divide="ignore", invalid="ignore"):
        found["slope"][sel] = np.abs(tensor[:, 0, 1] / tensor[:, 0, 0])
    opts["patch"] = int(side)
    r = lsm_match(w.fprep, w.gprep, w.centre_r[sel], w.init[sel][:, [0, 3]],
                  initial=w.init[sel], direction=(1.0, 0.0), rigid_across=True,
                  offset=w.frac[sel], **opts)
    found["status"][sel] = r.status
    found["position"][sel] = r.position
    found["cov"][sel] = r.cov
    found["sigma0"][sel], found["correlation"][sel] = r.sigma0, r.correlation
    found["affine"][sel], found["affine_cov"][sel] = r.affine, r.affine_cov
    found["radiometric"][sel] = r.radiometric
    with np.errstate(divide="ignore", invalid="ignore"):
        # what the shape unknowns take from the shift: its variance over the one
        # the texture's gradients along the line alone give, σ0² / Σ f_x², at
        # the window's centre and at its least-variance point (where the match
        # is reported when that is inside the window: _information_centres)
        unit = tensor[:, 0, 0] * side**2 / r.sigma0**2
        found["unit"][sel] = unit
        var_best = (_least_variance_point(r.affine_cov, side // 2)[1]
                    if at_best_point else np.full(len(sel), np.nan))
        found["inflation"][sel] = np.where(np.isfinite(var_best), var_best,
                                           r.cov[:, 0, 0]) * unit


def _second_order_along_row(w: SimpleNamespace, found: dict, good: np.ndarray, side_of,
                            opts: dict, spacing) -> None:
    """The fixed second-order terms along the row from the neighbours' shapes (the
    curvature bias of an affine window, :mod:`matching.second_order`), one more pass;
    its accepted results replace the final warp, covariance and position in ``found``."""
    quad = second_order_terms(w.centre_r, found["affine"], good,
                              radius_px=max(20.0, 5.0 * float(spacing)))
    quad[:, 3:] = 0.0
    again = np.concatenate([found["affine"], w.init[:, 6:]], axis=1)
    for side in np.unique(side_of[good]):
        sel = np.flatnonzero(good & (side_of == side))
        opts["patch"] = int(side)
        r = lsm_match(w.fprep, w.gprep, w.centre_r[sel], w.init[sel][:, [0, 3]],
                      initial=again[sel], direction=(1.0, 0.0), rigid_across=True,
                      offset=w.frac[sel], quadratic=np.nan_to_num(quad[sel]), **opts)
        keep = r.accepted
        sub = sel[keep]
        found["position"][sub], found["cov"][sub] = r.position[keep], r.cov[keep]
        found["affine_fin"][sub] = r.affine[keep]
        found["affine_cov_fin"][sub] = r.affine_cov[keep]
        found["quad"][sub] = np.nan_to_num(quad[sub])
        found["sigma0"][sub] = r.sigma0[keep]
        found["correlation"][sub] = r.correlation[keep]


def _in_original_images(w: SimpleNamespace, rig, rect, res: LSMResult, found: dict, side_of,
                        todo, sides, sigma_g: float, k2_each, scale_cov: bool):
    """The constrained matches back in the original images: positions, covariances (rank 1
    along the line, times each window's variance factor unless ``scale_cov`` is off), the
    warps (Jr⁻¹ A Jl), line directions, the rig's row error along the line (NaN:
    ``aperture``), the sides, and each window's right-image stretch per rectified column."""
    n, ok = len(res.status), w.ok
    position, cov = np.array(res.position), np.array(res.cov)
    status = np.array(res.status)
    status[ok] = found["status"]
    sigma0, corr = np.array(res.sigma0), np.array(res.correlation)
    dirs = np.tile([1.0, 0.0], (n, 1))
    geo = np.full(n, np.nan)
    good = np.flatnonzero(found["status"] == Status.OK)
    g = ok[good]
    position[g] = rectified_to_original(rect, rig.right, found["position"][good])
    jinv = np.linalg.inv(_jacobians(lambda p: right_to_rectified(rect, rig.right, p),
                                    position[g]))
    scale = k2_each[good, None, None] if scale_cov else 1.0  # (sigma_factor off: σ0²N⁻¹)
    cov[g] = scale * jinv @ found["cov"][good] @ jinv.transpose(0, 2, 1)
    d = jinv[:, :, 0]  # right-image step of one rectified column
    stretch = np.einsum("ni,ni->n", d, d)
    dirs[g] = d / np.sqrt(stretch)[:, None]
    geo[g] = (found["slope"][good] * sigma_g) ** 2 * stretch
    stretch_ok = np.full(len(ok), np.nan)
    stretch_ok[good] = stretch
    geo[g[todo[good]]] = np.nan  # ill-conditioned at every side: aperture
    sigma0[g], corr[g] = found["sigma0"][good], found["correlation"][good]
    new_sides = np.asarray(sides, np.int32).copy()
    new_sides[ok] = side_of
    # the warp back in the original images (Jr⁻¹ A Jl), for the backward loop and the maps
    affine, radiometric = np.array(res.affine), np.array(res.radiometric)
    a_rect = found["affine"][good][:, [1, 2, 4, 5]].reshape(-1, 2, 2)
    affine[np.ix_(g, [1, 2, 4, 5])] = (jinv @ a_rect @ w.jl[good]).reshape(-1, 4)
    affine[:, 0], affine[:, 3] = position[:, 0], position[:, 1]
    radiometric[g] = found["radiometric"][good]
    out = replace(res, radiometric=radiometric, position=position, cov=cov,
                  status=status.astype(res.status.dtype), sigma0=sigma0, correlation=corr,
                  affine=affine, window_cov=None)
    return out, geo, dirs, new_sides, stretch_ok





#: Gaussian variances (rectified px²) :func:`_blur_balance` tries on either image; the
#: variance it finds is interpolated between them (beyond the last: the last)
BLUR_STEPS = (0.0, 0.05, 0.1, 0.15, 0.2, 0.3, 0.4, 0.5, 0.65, 0.8)


def _ladder(raw: np.ndarray) -> list[np.ndarray]:
    """``raw`` smoothed by a Gaussian of each variance of :data:`BLUR_STEPS`."""
    return [raw if var == 0 else cv2.GaussianBlur(raw, (0, 0), float(np.sqrt(var)),
                                                  borderType=cv2.BORDER_REFLECT)
            for var in BLUR_STEPS]


def _smoothed(prep: PreparedImage, field: np.ndarray, interpolation: str) -> PreparedImage:
    """``prep``'s image smoothed at each pixel by a Gaussian of the variance ``field``
    (H, W) px² (linear between the images of :data:`BLUR_STEPS`); its noise the
    original's times the root sum of squared weights of the median variance's kernel
    (white noise: the separable k⊗k gives √Σ(k_i k_j)² = Σ k_i²)."""
    if not np.any(field > 0):
        return prep
    steps = np.asarray(BLUR_STEPS)
    v = np.clip(field, 0.0, steps[-1])
    out = np.zeros_like(prep.raw)
    for k, img in enumerate(_ladder(prep.raw)):
        lo = steps[k - 1] if k else steps[0] - 1.0
        hi = steps[k + 1] if k + 1 < len(steps) else steps[-1] + 1.0
        weight = np.where(v <= steps[k], (v - lo) / (steps[k] - lo), (hi - v) / (hi - steps[k]))
        weight = np.clip(weight, 0.0, 1.0)
        if weight.any():
            out += weight * img
    var = float(np.median(v[v > 0]))
    sigma = float(np.sqrt(var))
    kern = cv2.getGaussianKernel(2 * int(np.ceil(4 * sigma)) + 1, sigma)[:, 0]
    return replace(prepare_image(out, interpolation), noise=prep.noise * float(np.sum(kern**2)))


def _robust_planes(design: np.ndarray, values: np.ndarray, rounds: int = 3) -> np.ndarray:
    """(N, 3) least-squares planes of ``values`` (N, K) over ``design`` (N, K, 3), each
    refitted ``rounds`` times without the values beyond 3 x 1.4826 MAD of its residuals
    (a 2-D pass's slips); NaN where singular."""
    weight = np.ones(values.shape)
    plane = np.full((len(values), 3), np.nan)
    for _ in range(rounds):
        normal = np.einsum("nk,nki,nkj->nij", weight, design, design)
        rhs = np.einsum("nk,nki,nk->ni", weight, design, values)
        ok = np.abs(np.linalg.det(normal)) > 1e-9
        plane[:] = np.nan
        plane[ok] = np.linalg.solve(normal[ok], rhs[ok][..., None])[..., 0]
        resid = np.abs(values - np.einsum("nki,ni->nk", design, np.nan_to_num(plane)))
        mad = np.median(resid, axis=1, keepdims=True)
        weight = (resid <= 3.0 * MAD_TO_SIGMA * np.maximum(mad, 1e-3)).astype(np.float64)
    return plane


def _sharpness(windows: np.ndarray) -> np.ndarray:
    """Each (N, s+2, s+2) window's x-gradient energy over its grey-level variance (inner
    s x s pixels, central differences).  For the same structure at the same contrast it
    is inversely proportional to the blur of its edges along the row: a Gaussian edge of
    contrast C and σ b has ∫ g_x² = C² / (2 √π b) per unit length, whatever the gain."""
    gx = 0.5 * (windows[:, 1:-1, 2:] - windows[:, 1:-1, :-2])
    with np.errstate(divide="ignore", invalid="ignore"):
        return (gx**2).sum(axis=(1, 2)) / windows[:, 1:-1, 1:-1].var(axis=(1, 2))


def _blur_balance(w: SimpleNamespace, sides, max_windows: int = 3000, neighbours: int = 200,
                  region: int = 100):
    """Per-pixel Gaussian variances (rectified px²) for the left and the right rectified
    images that give them the same blur along the rows, measured from the matched
    windows; None where too few windows tell.

    The accepted 2-D matches (at most ``max_windows``, evenly spread) are read in both
    images: the template on its pixels, the search window resampled (cubic B-spline) at
    the template's scale -- its scale and shear along the row from a robust plane
    through the ``neighbours`` nearest matches' disparities, not from the window's own
    LSM shape, which absorbs part of a blur difference (a stretched window looks
    blurrier).  The ratio of the two windows' :func:`_sharpness` is the ratio of the
    images' edge blur there (gain and contrast cancel).  Over the windows with the
    stronger half of the gradient energy, its median over the ``region`` nearest windows
    is taken with either image smoothed by each variance of :data:`BLUR_STEPS`, and the
    variance (interpolated) that brings it to 1 is that window's: defocus differs with
    depth, so the blur difference varies across the image.  The windows' variances are
    spread over each image (nearest window, smoothed over 2 x 16 px cells).  Two cameras
    that blur an edge differently leave a residual the linear radiometry of LSM cannot
    absorb, with a shift that follows the edge's sign (docs/decisions/stereo-blur.md).
    Returns (left field, right field, median variance of each image over the windows).
    """
    sel = np.flatnonzero(w.from_2d)
    if len(sel) > max_windows:
        sel = sel[np.linspace(0, len(sel) - 1, max_windows).astype(np.intp)]
    if len(sel) < 30:
        return None
    side = int(np.median(np.asarray(sides)[w.ok][sel]))
    half = side // 2 + 1
    oy, ox = np.mgrid[-half:half + 1, -half:half + 1].astype(np.float64)
    acc = np.flatnonzero(w.from_2d)
    disp = w.centre_r[acc, 0] - w.init[acc, 0]
    k = min(neighbours, len(acc))
    _, nb = cKDTree(w.centre_r[acc]).query(w.centre_r[sel], k=k)
    design = np.concatenate([np.ones((len(sel), k, 1)), w.centre_r[acc][nb]
                             - w.centre_r[sel][:, None, :]], axis=2)
    plane = _robust_planes(design, disp[nb])
    a1, a2 = 1.0 - plane[:, 1], -plane[:, 2]
    xf = (w.centre_r[sel, 0, None, None] + ox).astype(np.intp)
    yf = (w.centre_r[sel, 1, None, None] + oy).astype(np.intp)
    xg = w.init[sel, 0, None, None] + a1[:, None, None] * ox + a2[:, None, None] * oy
    yg = w.init[sel, 3, None, None] + oy
    hf, wf = w.fprep.raw.shape
    hg, wg = w.gprep.raw.shape
    inside = (np.isfinite(a1) & (a1 > 0.5) & (a1 < 2.0) & (xf.min((1, 2)) >= 0)
              & (yf.min((1, 2)) >= 0) & (xf.max((1, 2)) < wf) & (yf.max((1, 2)) < hf)
              & (xg.min((1, 2)) >= 1) & (yg.min((1, 2)) >= 0) & (xg.max((1, 2)) < wg - 2)
              & (yg.max((1, 2)) < hg - 1))
    xf, yf, xg, yg = xf[inside], yf[inside], xg[inside], yg[inside]
    if len(xf) < 30:
        return None

    def sampled(img, which):
        if which == "f":
            return _sharpness(img[yf, xf])
        coef = ndimage.spline_filter(img, order=3, mode="mirror", output=np.float64)
        return _sharpness(ndimage.map_coordinates(coef, [yg, xg], order=3, prefilter=False,
                                                  mode="mirror"))

    sf = np.array([sampled(img, "f") for img in _ladder(w.fprep.raw)])  # (steps, N)
    sg = np.array([sampled(img, "g") for img in _ladder(w.gprep.raw)])
    f0 = w.fprep.raw[yf, xf][:, 1:-1, 1:-1]
    energy = sf[0] * f0.var(axis=(1, 2))
    strong = (np.isfinite(sf).all(0) & np.isfinite(sg).all(0) & (sf > 0).all(0)
              & (sg > 0).all(0) & (energy >= np.nanmedian(energy)))
    if strong.sum() < 30:
        return None
    steps = np.asarray(BLUR_STEPS)
    # the candidates in the order of the blur ratio (search / template) they give: the
    # template smoothed most ... neither ... the search smoothed most; signed variance
    # (negative: the template smoothed)
    log_ratio = np.concatenate([np.log(sf[:0:-1] / sg[0]), np.log(sf[:1] / sg[:1]),
                                np.log(sf[0] / sg[1:])])[:, strong]
    signed = np.concatenate([-steps[:0:-1], [0.0], steps[1:]])
    centres = w.centre_r[sel][inside][strong]
    right = np.column_stack([xg[strong, half, half], yg[strong, half, half]])
    kk = min(region, len(centres))
    _, nb = cKDTree(centres).query(centres, k=kk)
    local = np.median(log_ratio[:, nb], axis=2)  # (candidates, windows)
    # the first candidate at which the local median ratio reaches 1, interpolated
    above = local >= 0
    first = np.where(above.any(0), above.argmax(0), len(signed) - 1)
    prev = np.maximum(first - 1, 0)
    cols = np.arange(local.shape[1])
    lo, hi = local[prev, cols], local[first, cols]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where((first > 0) & (hi > lo), -lo / (hi - lo), 0.0)
    need = signed[prev] + t * (signed[first] - signed[prev])
    need = np.where(above.all(0), signed[0], need)
    fields = []
    for pos, amount, shape in ((centres, np.maximum(-need, 0.0), (hf, wf)),
                               (right, np.maximum(need, 0.0), (hg, wg))):
        cell = 16
        gy, gx = np.mgrid[0:shape[0]:cell, 0:shape[1]:cell]
        _, near = cKDTree(pos).query(np.column_stack([gx.ravel(), gy.ravel()]), k=1)
        coarse = cv2.GaussianBlur(amount[near].reshape(gx.shape), (0, 0), 2.0)
        fields.append(cv2.resize(coarse, (shape[1], shape[0]), interpolation=cv2.INTER_LINEAR))
    return fields[0], fields[1], (float(np.median(np.maximum(-need, 0))),
                                  float(np.median(np.maximum(need, 0))))
