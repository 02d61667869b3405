"""The curves stage of ``photosurf run``: each section's loops organised and fitted with
closed Catmull-Rom rings (:func:`surface.reconstruct.section_rings`, then ``untangle``),
or, for one-sided data, open arcs (:mod:`surface.open_surface`).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import TYPE_CHECKING

import numpy as np

from pipeline import artifacts
from pipeline.errors import InputError
from pipeline.stage_cameras import view_cameras

if TYPE_CHECKING:
    from pipeline.engine import StageContext

log = logging.getLogger("photosurf")


def curves(ctx: StageContext) -> dict:
    """``surface.reconstruct.organise_sections`` then ``section_rings`` (fit, predict) and
    ``untangle`` (sections whose rings knot the loop graph dropped); for one-sided data
    (``curves.open``), open arcs instead (:func:`_open_curves`)."""
    from surface import open_surface as osf
    from surface import reconstruct as rc
    from surface.section_errors import ring_precision

    p = ctx.params["curves"]
    smoothing = p["smoothing"] or "auto"  # 0: from the data (as the other "0:" keys)
    sliced, _, _ = artifacts.read_sections(ctx.stage_path("sections"))
    options = loop_options(p, smoothing)
    mode = _open_mode(p["open"])
    try:
        if mode is True:
            raise ValueError("curves.open = true")
        kept, loops, messages = rc.organise_sections(
            ctx.track(sliced, "loops", total=len(sliced), unit="section"), **options)
        if mode == "auto" and osf.one_sided(loops):
            # loops that look closed but are lines traced there and back (a board, a
            # wall): open by the same rule (docs/decisions/open-surfaces.md)
            raise rc.OneSidedError("the sections' loops are open or lines")
    except ValueError as exc:
        # one-sided data (open arcs over most of the object): an open surface, not an error
        # the closed rule found open arcs (OneSidedError): the open path does not judge
        # again on its own chained arcs, whose bridged share is lower once chained
        arcs = None if mode is False else _open_curves(
            ctx, sliced, options, smoothing,
            forced=mode is True or isinstance(exc, rc.OneSidedError))
        if arcs is None:
            raise InputError(f"curves: {exc} (set sections.count"
                             + (")" if mode is False else
                                ", or curves.open = true for an open surface)")) from exc
        return arcs
    kept, loops, rings, fits, untangled = fitted_rings(kept, loops, p, smoothing)
    messages += untangled
    for message in messages:
        log.warning("curves: %s", message)
    n_rings, n_points = artifacts.write_curves(ctx.out, rings, kept, rc.section_noise(loops),
                                               fits)
    n = p["n"] or rc.ring_count(kept, loops)
    records = [f for item in fits for f in ([item] if hasattr(item, "smoothing") else item)]
    return {"rings": n_rings, "n": int(n), "points": n_points,
            "sections_without_loop": len(sliced) - len(kept), "warnings": messages,
            "ring_precision": ring_precision(records),
            "smoothing_median": float(np.median([f.smoothing for f in records]))}


def loop_options(params: Mapping, smoothing) -> dict:
    """``surface.reconstruct.organise_sections``' options from the ``curves`` parameters."""
    from surface import reconstruct as rc

    return {"outlier_threshold": params["outlier_threshold"],
            "min_points": params["min_loop_points"] or rc.min_loop_points(smoothing)}


def fitted_rings(kept: list, loops: list, params: Mapping, smoothing) -> tuple:
    """The curves stage's closed rings from organised sections: ``section_rings`` (fit,
    predict) then ``untangle``; ``(kept, loops, rings, fits, messages)``, ``fits`` one entry
    per kept section."""
    from surface import reconstruct as rc

    rings, fits = rc.section_rings(kept, loops, params["n"] or None, smoothing=smoothing,
                                   parametrisation=params["parametrisation"], fits=True)
    fit_of = {id(section): fit for section, fit in zip(kept, fits, strict=True)}
    kept, loops, rings, untangled = rc.untangle(kept, loops, rings)
    return kept, loops, rings, [fit_of[id(section)] for section in kept], untangled


def _open_mode(value) -> bool | str:
    """``curves.open``: "auto" (open when the arcs rule says so), true or false."""
    if isinstance(value, bool) or value == "auto":
        return value
    raise InputError(f"curves.open must be \"auto\", true or false, got {value!r}")


def _open_curves(ctx: StageContext, sliced: list, options: dict, smoothing,
                 forced: bool = False) -> dict | None:
    """The curves stage for one-sided data (``surface.open_surface``): every section's
    loops as one open arc (the pieces that continue one another), its open Catmull-Rom
    curve, resampled on the arcs' common parameter, over the run of arcs that overlap;
    None when the loops go round the object (``one_sided`` false) and the open surface
    was not asked for."""
    from surface import open_surface as osf
    from surface import reconstruct as rc

    p = ctx.params["curves"]
    _, _, spacing = artifacts.read_sections(ctx.stage_path("sections"))
    if not spacing > 0 and len(sliced) > 1:
        spacing = float(np.median(np.abs(np.diff([s.height for s in sliced]))))
    cameras = view_cameras(ctx)
    view = np.mean([camera.R[2] for camera in cameras], axis=0) if cameras else None
    # one sheet: the largest piece when it holds most of the points (a pair's object in
    # its scene); else, seen from cameras, every piece (a facade's stone between windows
    # has no points: on Sceaux the largest piece held a third)
    main, piece = osf.main_piece(sliced, spacing) if spacing > 0 else (sliced, None)
    if view is None or sum(map(len, main)) >= 0.5 * sum(map(len, sliced)):
        sliced = main
    else:
        piece = None
    kept, loops, messages = osf.organise_arcs(sliced, drop_splits=view is None, **options)
    messages += [piece] if piece else []
    share = rc.bridged_share(loops)
    if len(kept) < 2 or not (forced or osf.one_sided(loops)):
        return None
    try:
        # the matcher's window on the surface: points closer than it share their errors
        window = ((np.array([c.center for c in cameras]), np.array([c.K[0, 0] for c in cameras]),
                   float(ctx.config["acquire"]["patch"])) if cameras else None)
        # the sections' points and their cloud points' sigma (the fits' bound)
        cloud = artifacts.read_cloud(ctx.stage_path("acquire"))
        cloud_sigma = cloud.get("sigma")
        sigma = ((np.concatenate([s.points for s in sliced]),
                  np.asarray(cloud_sigma, np.float64)[
                      np.concatenate([s.source_index for s in sliced])])
                 if cameras and cloud_sigma is not None and sliced else None)
        if sigma is not None and "source" in cloud:  # view pairs: errors shared within one
            sigma += (cloud["source"][np.concatenate([s.source_index for s in sliced])],)
        curves, rings, params, step, notes, run = osf.open_arcs(
            loops, spacing, p["n"] or None, smoothing=smoothing, view=view, window=window,
            sigma=sigma)
    except ValueError as exc:
        raise InputError(f"curves: one-sided data, but no open surface: {exc}") from exc
    if len(run) < 2:
        raise InputError("curves: one-sided data, but no two neighbouring sections' arcs "
                         "overlap: no open surface (set sections.count or sections.spacing)")
    kept, loops = [kept[k] for k in run], [loops[k] for k in run]
    messages += notes
    for message in messages:
        log.warning("curves: %s", message)
    log.info("curves: %.0f %% of the sections' loop length lies across gaps: one-sided data, "
             "%d open arcs (curves.open = %s)", 100 * share, len(rings), p["open"])
    n_rings, n_points = artifacts.write_curves(ctx.out, rings, kept, rc.section_noise(loops),
                                               params=params, step=step)
    return {"open": True, "rings": n_rings, "points": n_points, "bridged_share": share,
            "sections_without_loop": len(sliced) - len(kept), "warnings": messages,
            "smoothing_median": float(np.median([c.smoothing for c in curves]))}
