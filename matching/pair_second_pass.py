"""A stereo pair's second LSM pass: grown windows and the precision test.

Gruen's **adaptive patch** (:func:`adaptive_sides`: a point whose first-pass σ is worse
than the median σ of the accepted matches is re-matched with the smallest odd side up to
``max_patch`` whose predicted σ reaches it), the ICI ladder and the population rule
(:mod:`matching.ici`), one batched LSM call per side (:func:`_rematch`), and the
**precision test** (:func:`_imprecise`: σ beyond the median by more than k robust
spreads).  Used by :func:`matching.pair.match_pair`.
"""

from __future__ import annotations

from dataclasses import fields, replace

import numpy as np

from matching.ici import (
    ici_choice,
    ici_ladder,
    interval_sigmas,
    population_choice,
    population_sides,
    select_results,
)
from matching.lsm import LSMResult, Status, lsm_match, robust_upper_limit
from matching.precision import class_variance_factors
from matching.seeds import shift_precision, window_offsets
from matching.validate import check_shape


def default_max_patch(patch: int) -> int:
    """Largest odd side with at most twice the pixels of ``patch`` (15 -> 21)."""
    side = int(np.floor(np.sqrt(2.0) * patch))
    side -= 1 - side % 2
    while side * side > 2 * patch * patch:
        side -= 2
    return max(side, int(patch))



def adaptive_sides(image, points, sigma, accepted, patch: int = 15,
                   max_patch: int | None = None, noise: float | None = None) -> np.ndarray:
    """Patch side per point that brings its predicted σ to the image's median (Gruen).

    Target: τ = the median σ of the accepted first-pass matches (``patch`` sides).  A
    point with σ > τ gets the smallest odd side s in ``patch + 2, ..., max_patch``
    with σ (p_s / p_patch) <= τ, p the structure-tensor prediction of
    :func:`matching.seeds.shift_precision` (the ratio carries the texture the larger
    window adds; σ carries the measured σ0 and the affine unknowns); ``max_patch``
    when none reaches τ.  Others, and points not accepted, keep ``patch``.

    Parameters
    ----------
    image : (H, W) array_like
        Template image, grey levels.
    points : (N, 2) array_like
        Integer template centres, px.
    sigma : (N,) array_like
        First-pass σ, px.
    accepted : (N,) bool
        First-pass acceptance.
    patch : int
        First-pass side, px.
    max_patch : int, optional
        Largest side (default :func:`default_max_patch`).
    noise : float, optional
        Template noise σ, grey levels (default: Immerkaer's estimate).

    Returns
    -------
    (N,) int32, px
    """
    points = check_shape(points, "(N, 2)", "points", dtype=np.float64)
    sigma = np.asarray(sigma, dtype=np.float64)
    accepted = np.asarray(accepted, dtype=bool)
    top = default_max_patch(patch) if max_patch is None else int(max_patch)
    if top < patch or top % 2 == 0:
        raise ValueError(f"max_patch must be an odd integer >= patch ({patch}), got {max_patch!r}")
    sides = np.full(len(points), patch, np.int32)
    ladder = list(range(patch, top + 1, 2))
    good = accepted & np.isfinite(sigma)
    if len(ladder) < 2 or not good.any():
        return sides
    tau = float(np.median(sigma[good]))
    worse = np.flatnonzero(good & (sigma > tau))
    pred = shift_precision(image, points[worse], ladder, noise=noise)  # (S, M)
    with np.errstate(invalid="ignore", divide="ignore"):
        est = sigma[worse] * pred / pred[0]
    reach = est <= tau  # NaN (window outside the image) and inf never reach
    first = np.where(reach.any(0), reach.argmax(0), len(ladder) - 1)
    # a side whose window leaves the image is not used: fall back to the largest inside
    inside = np.isfinite(pred)
    last_inside = np.where(inside.any(0), len(ladder) - 1 - np.argmax(inside[::-1], axis=0), 0)
    first = np.where(np.isfinite(pred[0]), np.minimum(first, last_inside), 0)
    sides[worse] = np.asarray(ladder, np.int32)[first]
    return sides



def _rematch_ici(fprep, gprep, points, start, first: LSMResult, quad, ladder, options,
                 shifted, edge) -> tuple[LSMResult, np.ndarray]:
    """The second pass at every side of ``ladder``, each point keeping the side ICI
    chooses (eccentric windows keep the smallest: a grown one would reach over the edge
    it was moved off).  The intervals' σ carry each side's variance factor per window
    class (``edge``: :func:`matching.precision.class_variance_factors`, as the pair's
    final σ do)."""

    n = len(points)
    classes = np.asarray(edge, dtype=np.int64)
    results, sigmas = [], []
    for side in ladder:
        result = _rematch(fprep, gprep, points, start, first, quad,
                          np.full(n, side, np.int32), options)
        results.append(result)
        per_window = class_variance_factors(points, result.affine, result.affine_cov,
                                            result.accepted, classes, patch=side)[0]
        sigmas.append(interval_sigmas(result, points, side, per_window)[0])
    accepted = np.stack([r.accepted for r in results])
    accepted[1:, np.asarray(shifted, bool)] = False
    choice = ici_choice(np.stack([r.position for r in results]), np.stack(sigmas), accepted)
    sides = np.asarray(ladder, np.int32)[np.maximum(choice, 0)]
    return select_results(results, choice), sides



def _clear_at_sides(cand, left, patch, spacing, mask, valid, idx, above):
    """{side: (len(idx),) bool} for the sides of ``ici_ladder(patch)`` above ``above``: the
    centred window of that side holds no pixel off the textured surface
    (:func:`matching.seeds.window_offsets`' test at that side)."""

    out = {}
    for side in ici_ladder(patch)[1:]:
        if side > above:
            out[side] = ~window_offsets(cand, left, side, spacing, mask, valid,
                                        move=False)[1][idx]
    return out



def _grow_population(fprep, gprep, points, start, first: LSMResult, quad,
                     second: LSMResult, sides, patch: int, options, shifted, edge,
                     clear_at: dict):
    """The sides of ``ici_ladder(patch)`` above Gruen's (``second``, ``sides``), each
    window class grown to the largest one the population rule allows
    (:func:`matching.ici.population_sides`), each point to the largest side up to its
    class's where it is accepted and its window clear of edges (``clear_at``; eccentric
    windows stay).  The nested statistics use the image's variance factor -- the
    windows clear of an edge, at Gruen's sides -- for every class: the edge windows' own
    factor holds their model error, which is what the rule must see.  Returns the
    result, the sides and whether any point grew."""

    up = [s for s in ici_ladder(patch)[1:] if s > int(sides.max())]
    ok = second.status == Status.OK
    classes = np.asarray(edge, dtype=np.int64)
    if not up or ok.sum() < 30:
        return second, sides, False
    factors = class_variance_factors(points, second.affine, second.affine_cov, ok,
                                     classes, patch=sides)[1]
    k2 = float(factors[0]) if len(factors) else 1.0
    n = len(points)
    results = [second] + [_rematch(fprep, gprep, points, start, first, quad,
                                   np.full(n, side, np.int32), options) for side in up]
    accepted = np.stack([ok] + [r.status == Status.OK for r in results[1:]])
    accepted[1:, np.asarray(shifted, bool)] = False
    for j, side in enumerate(up, start=1):
        accepted[j] &= clear_at[side]
    cap = population_sides(np.stack([r.position for r in results]),
                           np.stack([r.cov for r in results]), accepted, k2, classes,
                           np.stack([r.sigma0 for r in results]))
    choice = population_choice(accepted, cap[classes])
    if not (choice > 0).any():
        return second, sides, False
    chosen = select_results(results, choice)
    ladder = np.asarray([0] + up, np.int32)
    return chosen, np.where(choice > 0, ladder[choice], sides).astype(np.int32), True



def _rematch(fprep, gprep, points, start, first: LSMResult, quad, sides, options,
             only=None, into: LSMResult | None = None) -> LSMResult:
    """Second LSM pass from the first pass's solution, one call per patch side.

    ``only`` (N,) bool: re-match just these points, the others copied from ``into``.
    """
    n = len(points)
    init = np.column_stack([first.affine, first.radiometric])
    fresh = ~np.isfinite(init).all(1)
    init[fresh] = 0.0
    init[fresh, 0], init[fresh, 3] = start[fresh, 0], start[fresh, 1]
    init[fresh, 1] = init[fresh, 5] = init[fresh, 7] = 1.0
    quad = np.zeros((n, 6)) if quad is None else quad
    direction = options.get("direction")
    arrays = {"position": np.full((n, 2), np.nan), "affine": np.full((n, 6), np.nan),
              "radiometric": np.full((n, 2), np.nan), "converged": np.zeros(n, bool),
              "iterations": np.zeros(n, np.int32), "sigma0": np.full(n, np.nan),
              "cov": np.full((n, 2, 2), np.nan), "correlation": np.full(n, np.nan),
              "status": np.zeros(n, np.uint8), "window_cov": np.full((n, 2, 2), np.nan),
              "affine_cov": np.full((n, 6, 6), np.nan)}
    offset = options.get("offset")
    if offset is None:
        del arrays["window_cov"]
    if into is not None:
        arrays = {name: np.array(getattr(into, name)) for name in arrays}
    reference = first.noise_sigma0 if into is None else into.noise_sigma0
    todo = np.ones(n, bool) if only is None else np.asarray(only, bool)
    for side in np.unique(sides[todo]):  # a few sides: one batched call each
        sel = np.flatnonzero((sides == side) & todo)
        opts = {**options, "patch": int(side)}
        if direction is not None:
            opts["direction"] = np.broadcast_to(direction, (n, 2))[sel]
        if offset is not None:
            opts["offset"] = offset[sel]
        if "robust" in options:
            opts["robust"] = np.broadcast_to(options["robust"], (n,))[sel]
        res = lsm_match(fprep, gprep, points[sel], start[sel], initial=init[sel],
                        quadratic=quad[sel], **opts)
        for name in arrays:
            arrays[name][sel] = getattr(res, name)
        if side == options["patch"] and only is None:
            reference = res.noise_sigma0
    return LSMResult(noise_sigma0=reference, **arrays)



def _keep_first(second: LSMResult, first: LSMResult, lost: np.ndarray) -> LSMResult:
    """``second`` with the points ``lost`` (N,) bool taken from ``first`` (every array
    field both carry)."""
    arrays = {}
    for f in fields(second):
        mine, theirs = getattr(second, f.name), getattr(first, f.name)
        if f.name == "noise_sigma0" or mine is None or theirs is None:
            continue
        value = np.array(mine)
        value[lost] = theirs[lost]
        arrays[f.name] = value
    return replace(second, **arrays)



def _imprecise(res: LSMResult, k: float, patch: int, sides=None) -> np.ndarray:
    """(N,) bool: accepted with σ > median + k s over the accepted σ (>= 30 of them).

    s is the larger of 1.4826 MAD(σ) and the spread σ0's own estimation error gives σ,
    median / sqrt(2 (patch² - 8)) (as the σ0 test of :func:`matching.lsm.lsm_match`), so
    that a uniformly textured image, whose σ differ only by that, loses nothing.
    ``sides`` (N,): each side's windows against their own (ICI's sides differ 2x and their
    σ with them: a window kept small beside an edge is not imprecise for being small;
    a side with fewer than 30 accepted is not tested).
    """
    sigma = res.window_sigma  # the window's own precision (eccentric ones: before the
    ok = res.accepted & np.isfinite(sigma)  # transfer, whose growth is geometry, not texture)
    if sides is None:
        return _above_limit(sigma, ok, k, patch)
    out = np.zeros(len(ok), bool)
    for side in np.unique(sides[ok]):
        out |= _above_limit(sigma, ok & (sides == side), k, int(side))
    return out



def _above_limit(sigma: np.ndarray, ok: np.ndarray, k: float, patch: int) -> np.ndarray:
    if ok.sum() < 30:
        return np.zeros(len(ok), bool)
    return ok & (sigma > robust_upper_limit(sigma[ok], k, patch * patch - 8))

