"""The stage functions of ``photosurf run``: small adapters between workspace files
and the public functions of ``matching``, ``surface`` and the pipeline's I/O modules.

    scene → acquire → sections → curves → stitch → smooth → export → report

Each function takes a :class:`pipeline.engine.StageContext`, reads its upstream
stages' files through :mod:`pipeline.artifacts` (where every workspace file's writer
and reader sit side by side), writes its own into ``ctx.out`` and returns a dict of
counts and metrics for the manifest.  No algorithm lives here.  Which stages run, in
which order, reading what, is :mod:`pipeline.plan`; running them is
:mod:`pipeline.engine`.  A stage that cannot apply to the data raises
:class:`pipeline.errors.StageSkipped` with the reason.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING

from pipeline import artifacts, progress
from pipeline.errors import InputError, StageSkipped
from pipeline.inputs import folder_images, scene_source, stereo_inputs
from pipeline.workspace import write_text

if TYPE_CHECKING:
    from pipeline.engine import StageContext

log = logging.getLogger("photosurf")
#: The acquire stage's record of the cameras' ring (for sections.axis = "data").
RING_FILE = "ring.json"


# --------------------------------------------------------------------------- scene
def scene(ctx: StageContext) -> dict:
    """``pipeline.scenes.render_scene``: the recipe's views, cameras and true mesh."""
    from pipeline import scenes

    overrides = ctx.params["scene"].get("overrides", {})
    recipe = scenes.load_recipe(ctx.inputs[0], overrides) if overrides else ctx.inputs[0]
    scenes.render_scene(recipe, ctx.out, progress=progress.enabled())
    return {"views": len(list((ctx.out / "images").glob("*.png")))}


# --------------------------------------------------------------------------- acquire
def acquire(ctx: StageContext) -> dict:
    """The input's point cloud: read (cloud), matched (stereo pair) or acquired from
    an image folder (:func:`pipeline.acquisition.acquire_folder`)."""
    kind = scene_source(ctx.stage_path("scene")) if ctx.kind == "scene" else ctx.kind
    if kind == "cloud":
        return _save_cloud(ctx, *_read_cloud(ctx.inputs[0]))
    if kind == "stereo":
        if ctx.kind == "scene":
            left, right = folder_images(ctx.stage_path("scene"))[:2]
            rig = ctx.stage_path("scene", "cameras.yml")
        else:
            left, right, rig = stereo_inputs(ctx.inputs, ctx.rig)
        return _save_cloud(ctx, *_stereo_cloud(left, right, rig, ctx.params["acquire"]))
    folder = ctx.stage_path("scene") if ctx.kind == "scene" else ctx.inputs[0]
    cloud, info = _multiview_cloud(folder, ctx)
    out = _save_cloud(ctx, *_cloud_arrays(cloud))
    # what the sections stage's axis "data" needs: the cameras' ring, and whether the
    # frame is the user's (given cameras) or an arbitrary SfM one
    ring = {**cloud.stats.get("ring", {}), "frame": "sfm" if info["cameras"] == "pycolmap SfM"
            else "given"}
    write_text(ctx.out / RING_FILE, json.dumps(ring, indent=1))
    if ring["frame"] == "sfm":  # the cloud's frame: reusable as --cameras
        artifacts.write_cameras(ctx.out, cloud.stats["cameras"])
    return {**out, **info}


def _save_cloud(ctx: StageContext, points, colors=None, sigma=None) -> dict:
    import numpy as np

    if len(np.asarray(points).reshape(-1, 3)) == 0:
        raise InputError(f"{ctx.inputs[0]}: acquisition produced no points")
    written = artifacts.write_cloud(ctx.out, points, colors, sigma)
    sigma = written["sigma"]
    finite = sigma[np.isfinite(sigma)]
    return {"points": len(written["points"]),
            **({"sigma_median": float(np.median(finite))} if finite.size else {})}


def _densify_info(densify: dict | None) -> dict:
    """The second lattice's share of the pairs and of the LSM candidates (manifest)."""
    if not densify:
        return {}
    return {"densified_pairs": int(densify["pairs"]),
            "densified_share": round(float(densify["share"]), 4)}


def _sfm_info(sfm: dict | None, views: int) -> dict:
    """SfM's registration figures for the manifest and the report (``SfmResult.report``):
    views registered of those it was given, sparse points, mean reprojection error (before
    and after the LSM re-measured tie points when refined), and the frame's scale."""
    if not sfm:
        return {}
    info = {"sfm_registered": f"{sfm['registered']} of {views}",
            "sfm_sparse_points": int(sfm["sparse_points"]),
            "sfm_reprojection_px": round(float(sfm["mean_reprojection_error_px"]), 3),
            "sfm_scale": "fixed" if sfm["scale"] == "fixed" else "arbitrary"}
    refinement = sfm.get("refinement") or {}
    if refinement.get("method") == "lsm":
        info["sfm_reprojection_before_lsm_px"] = round(
            float(refinement["reprojection_before_px"]), 3)
    return info


def _multiview_cloud(folder: Path, ctx: StageContext) -> tuple:
    """``pipeline.acquisition.acquire_folder`` (the same loading, checks and method as
    ``photosurf acquire``); view pairs on the executor."""
    from pipeline.acquisition import acquire_folder

    cameras = str(ctx.rig) if ctx.rig is not None and ctx.kind == "folder" else None
    # scratch files in the stage's temporary output: gone with it, also after a kill
    asked = ctx.params.get("sections", {})  # the sections asked: the working resolution
    cloud = acquire_folder(folder, cameras, executor=ctx.executor, work_dir=ctx.out,
                           section_count=int(asked.get("count") or 0),
                           section_spacing=float(asked.get("spacing") or 0.0),
                           **ctx.params["acquire"])
    stats = cloud.stats
    if stats.get("unregistered"):
        log.warning("acquire: %d image(s) not registered by SfM: %s",
                    len(stats["unregistered"]), ", ".join(stats["unregistered"]))
    source = stats.get("camera_source")
    skipped = stats.get("skipped", [])
    info = {"cameras": "pycolmap SfM" if source == "sfm" else Path(str(source)).name,
            "views": len(stats.get("view_names", [])), "pairs": len(cloud.pairs),
            "pairs_skipped": len(skipped),
            **({"views_skipped": "; ".join(s["reason"] for s in stats["skipped_views"])}
               if stats.get("skipped_views") else {}),
            **({"skipped": "; ".join(f"{' - '.join(s['views'])}: {s['reason']}"
                                     for s in skipped)} if skipped else {}),
            "masks": stats.get("masks", "none"), "search_range": stats.get("search", ""),
            "variance_factor": round(float(stats.get("variance_factor_median", 1.0)), 2),
            "ring": bool(stats.get("ring", {}).get("is_ring", False)),
            **_densify_info(stats.get("densify")),
            "working_scale": round(float(stats.get("working_scale", 1.0)), 4),
            **({"working_scale_from": stats["working_scale_reason"]}
               if stats.get("working_scale_reason") else {}),
            "peak_memory_gb": round(float(stats.get("peak_memory_gb", 0.0)), 2),
            **{k: (round(v, 6) if isinstance(v, float) else v)
               for k, v in stats.get("scale", {}).items()},
            **{k: v for k, v in stats.get("roi", {}).items() if k.startswith("roi")
               and not isinstance(v, list)},
            **_sfm_info(stats.get("sfm"), len(stats.get("view_names", []))
                        + len(stats.get("unregistered", []))),
            **{f"reason_{k}": v for k, v in cloud.reason_counts.items()}}
    return cloud, info


def _stereo_cloud(left: Path, right: Path, rig_path: Path, params: Mapping) -> tuple:
    """``matching.pair.reconstruct_pair`` on two image files and a rig file."""
    from matching.pair import reconstruct_pair
    from matching.scheduler import thread_map
    from pipeline.inputs import read_pair, read_rig_for

    rig = read_rig_for(rig_path)  # and pipeline.guards.check_rig: format, values, baseline
    options = dict(params)
    for key in ("eccentric", "densify", "masks", "roi", "points_across", "precision",
                "object_only", "scale", "markers"):  # image folders only (defaults.toml)
        options.pop(key, None)
    max_reproj = options.pop("max_reprojection_px") or None
    images = read_pair(left, right, need_same_size=False)
    # off the main thread, which waits where Ctrl-C reaches it (matching.scheduler)
    result, = thread_map(1)(lambda _: reconstruct_pair(
        *images, rig, max_reprojection_px=max_reproj, **options), [None])
    return result.points, result.colours, result.sigma


def _read_cloud(path: Path) -> tuple:
    """Points (and colours, sigma when the file has them) of a cloud file."""
    from pipeline import cloud_io

    return _cloud_arrays(cloud_io.read_cloud(path))


def _cloud_arrays(cloud) -> tuple:
    """``(points, colors, sigma)`` from whatever a reader returned (arrays, dict or object)."""
    if isinstance(cloud, tuple):
        return (tuple(cloud) + (None, None))[:3]
    get = cloud.get if isinstance(cloud, Mapping) else lambda k, d=None: getattr(cloud, k, d)
    colours = get("colours")
    return get("points"), get("colors") if colours is None else colours, get("sigma")


# --------------------------------------------------------------------------- surface
def sections(ctx: StageContext) -> dict:
    """``surface.reconstruct.slice_cloud``: slice and move the slab points to their planes."""
    import warnings

    import numpy as np

    from pipeline.guards import (
        MIN_EXTENT,
        check_cloud_shape,
        check_section_cost,
        drop_far_outliers,
    )
    from surface import reconstruct as rc
    from surface import sections as sections_mod

    p = ctx.params["sections"]
    cloud = artifacts.read_cloud(ctx.stage_path("acquire"))
    # far stray points would set the sections' extent: dropped, with a warning line
    points, cap_sigma, outliers = drop_far_outliers(cloud["points"], "sections",
                                                    cloud["sigma"])
    axis, axis_source = _section_axis(p["axis"], ctx.stage_path("acquire", RING_FILE))
    if isinstance(p["axis"], str) and p["axis"] == "data" and axis_source.startswith("z "):
        axis, axis_source = _across_the_view(points, _cameras(ctx), axis, axis_source)
    elif isinstance(p["axis"], str) and p["axis"] == "data" and axis == "auto":
        # SfM frame, no ring: cameras on one side (a facade) get sections along their view
        axis, axis_source = _across_the_view(points, _cameras(ctx), axis, axis_source,
                                             one_side=True)
    check_cloud_shape(points, "acquire: the cloud", axis=axis)  # a line or plane: no surface
    extent = float(np.ptp(points, axis=0).max()) if len(points) else 0.0
    if 0 < extent < MIN_EXTENT:  # the stages' lengths are in scene units: not rescaled here
        raise InputError(f"sections: the cloud spans {extent:.3g} scene units, below "
                         f"{MIN_EXTENT:g}, where the surface code's absolute tolerances change "
                         "the result; give the cloud in a smaller unit (or use photosurf "
                         "sections, which rescales it)")
    check_section_cost(points, axis, "sections", sections=p["count"] or None,
                       spacing=p["spacing"] or None)  # before anything is allocated
    if outliers:
        log.warning("%s", outliers)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", sections_mod.SectionSkippedWarning)
        sliced = rc.slice_cloud(
            points, axis=axis, sections=p["count"] or None, spacing=p["spacing"] or None,
            thickness=p["thickness"] or None, projection=p["projection"])
    kept = [s for s in sliced.sections if len(s) > 0]
    if len(kept) < 2:
        raise InputError(f"sections: only {len(kept)} non-empty sections; need at least 2 "
                         "(set sections.count or sections.spacing)")
    artifacts.write_sections(ctx.out, kept, sliced.cap_cloud, sliced.spacing,
                             cap_sigma[sliced.cap_index])
    warned = [str(w.message) for w in caught]
    for message in warned:
        log.warning("sections: %s", message)
    for message in sliced.notes:  # axis = "auto": the axis chosen and why
        log.info("sections: %s", message)
    used = kept[0].frame[2]
    return {"sections": len(kept), "empty": len(sliced.sections) - len(kept),
            "spacing": sliced.spacing, "cap_points": len(sliced.cap_cloud),
            "axis": [round(float(a), 6) for a in used], "axis_source": axis_source,
            "warnings": warned, "notes": list(sliced.notes),
            **({"outliers": outliers.split(": ", 1)[1]} if outliers else {})}


def _section_axis(axis, ring_file: Path):
    """The slicing axis and what it is: ``"data"`` is the cameras' ring normal when they
    form a ring (:func:`matching.ring.fit_ring`), else the cloud's principal axis in an
    SfM frame (whose z means nothing) and z in the user's own frame."""
    if not (isinstance(axis, str) and axis == "data"):
        return axis, "given" if not isinstance(axis, str) else f"sections.axis = {axis}"
    ring = json.loads(ring_file.read_text()) if ring_file.is_file() else {}
    if ring.get("is_ring"):
        return ring["axis"], "ring normal of the cameras"
    if ring.get("frame") == "sfm":
        return "auto", "principal axis (SfM frame; cameras not a ring)"
    return "z", "z (no camera ring)"


#: Largest angle (degrees) between the z axis and the cameras' mean viewing direction at
#: which ``sections.axis = "data"`` moves off z: closer than 45° the section planes face
#: the cameras more than they contain their rays, and a surface seen face-on is cut into
#: depth slabs (a real stereo pair's rig frame has z along the left optical axis: on the
#: chessboard pair 255 sections of blobs and a non-manifold stitched mesh).
AXIS_VIEW_DEGREES = 45.0


def _across_the_view(points, cameras, axis, source, one_side: bool = False):
    """The cloud's principal direction across the cameras' mean viewing direction ``d``
    (the largest eigenvector of ``(I - d dᵀ) Σ (I - d dᵀ)``), when z lies within
    :data:`AXIS_VIEW_DEGREES` of ``d``, or with ``one_side`` when every camera centre lies
    within 90° of their mean direction from the cloud's median (they see one side: each
    section then holds the view, a depth profile of what they see); else ``axis,
    source`` unchanged."""
    import numpy as np

    if not cameras:
        return axis, source
    view = np.mean([camera.R[2] for camera in cameras], axis=0)   # optical axes in world
    view /= np.linalg.norm(view)
    if one_side:
        sides = np.array([c.center for c in cameras]) - np.median(points, axis=0)
        sides /= np.linalg.norm(sides, axis=1)[:, None]
        mean = sides.sum(axis=0)
        if not (np.linalg.norm(mean) > 0 and np.min(sides @ mean) > 0):
            return axis, source
    elif abs(view[2]) < np.cos(np.radians(AXIS_VIEW_DEGREES)):
        return axis, source
    across = np.eye(3) - np.outer(view, view)
    centred = np.asarray(points, np.float64) - np.median(points, axis=0)
    scatter = across @ (centred.T @ centred) @ across
    principal = np.linalg.eigh(scatter)[1][:, -1]
    return ([round(float(a), 9) for a in principal],
            "principal axis across the cameras' view (" + (
                "they see the cloud from one side)" if one_side else
                f"z is within {AXIS_VIEW_DEGREES:g} degrees of their viewing direction)"))


def _cameras(ctx: StageContext) -> list:
    """The cameras the cloud was seen from (SfM's, the scene's or the rig's), or []."""
    from matching.cameras import read_cameras_yml, read_rig

    candidates = [ctx.stage_path("acquire", artifacts.CAMERAS)]
    if ctx.kind == "scene":
        candidates.append(ctx.stage_path("scene", "cameras.yml"))
    elif ctx.rig is not None:
        candidates.append(Path(ctx.rig))
    for path in candidates:
        if not path.is_file():
            continue
        for reader in (read_cameras_yml, lambda f: [read_rig(f).left, read_rig(f).right]):
            try:
                return list(reader(path))
            except Exception:  # noqa: BLE001 - another format, or no cameras: try the next
                continue
    return []


def curves(ctx: StageContext) -> dict:
    """``surface.reconstruct.organise_sections`` then ``section_rings`` (fit, predict) and
    ``untangle`` (sections whose rings knot the loop graph dropped); for one-sided data
    (``curves.open``), open arcs instead (:func:`_open_curves`)."""
    import numpy as np

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
    import numpy as np

    from surface import open_surface as osf
    from surface import reconstruct as rc

    p = ctx.params["curves"]
    _, _, spacing = artifacts.read_sections(ctx.stage_path("sections"))
    if not spacing > 0 and len(sliced) > 1:
        spacing = float(np.median(np.abs(np.diff([s.height for s in sliced]))))
    cameras = _cameras(ctx)
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
        cloud_sigma = artifacts.read_cloud(ctx.stage_path("acquire")).get("sigma")
        sigma = ((np.concatenate([s.points for s in sliced]),
                  np.asarray(cloud_sigma, np.float64)[
                      np.concatenate([s.source_index for s in sliced])])
                 if cameras and cloud_sigma is not None and sliced else None)
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


def _camera_centres(ctx: StageContext):
    """Centres ``(K, 3)`` of the cameras the cloud was seen from, or None (a cloud input,
    or cameras that cannot be read): the side the open surface faces."""
    import numpy as np

    cameras = _cameras(ctx)
    return np.array([camera.center for camera in cameras], np.float64) if cameras else None


def _stitch_open(ctx: StageContext, rings: list, params: list, step: float) -> dict:
    """``surface.open_surface.stitch_arcs`` of the curves stage's open arcs, facing the
    cameras when they are known."""
    from surface.metrics import mesh_topology
    from surface.open_surface import BORDER_REACH, stitch_arcs

    eyes = _camera_centres(ctx)
    try:  # the rings end on the smooth border curves: strips join their ends
        result = stitch_arcs([r[0] for r in rings], params, step, viewpoint=eyes,
                             reach=BORDER_REACH)
    except ValueError as exc:  # no two neighbouring arcs overlap
        raise InputError(f"stitch: {exc} (set sections.count or sections.spacing)") from exc
    topology = mesh_topology(result.vertices, result.triangles)
    notes = {**result.info(), "closed": False, "messages": list(result.notes),
             "faces_cameras": eyes is not None, "edge_manifold": topology["edge_manifold"],
             "oriented": topology["oriented"], "components": topology["components"]}
    artifacts.write_stitched(ctx.out, result.vertices, result.triangles, notes)
    for message in result.notes:
        log.warning("stitch: %s", message)
    from pipeline.smoothing import solid_report  # open by design: its border no defect

    notes["solid"] = solid_report("stitch", result.vertices, result.triangles,
                                  expect_closed=False)
    return {"vertices": len(result.vertices), "triangles": len(result.triangles), **notes}


def _stitcher(params: Mapping, planes: list, noise: float | None, cap_cloud, spacing: float,
              cap_sigma=None, leave_holes: bool = False, points=None):
    """``(rings, planes) -> (StitchResult, notes)`` with the stitch stage's rules: end rings
    moved to the cap points (``stitch.extend_ends``, weighted by their precision
    ``cap_sigma`` where known), caps, support rings at sharp rims (``stitch.support``),
    inner caps at their cap points' height; ``notes`` are the end extension's.  Each end
    is classified on the un-extended end loops (``surface.reconstruct.classify_ends``,
    the cloud ``points`` counting a mouth's sheets): a mouth on a wall too thin to part is
    left as a border, and with ``leave_holes`` (``sections.open``) a hole in the data;
    ``build.holes`` / ``build.mouths`` are then the last build's ``(bottom, top)`` ends
    left open.  ``build.ends``: the last build's end placements, their standard errors
    (``surface.reconstruct.extend_to_caps``) and kinds with the evidence."""
    import numpy as np

    from surface import reconstruct as rc
    from surface import stitch as st

    support = noise if params["support"] and noise is not None else None

    def build(rings, ring_planes, diagnostics=True):
        # a lone loop as itself, as surface.reconstruct.surface_from_points passes it
        rings = [item[0] if isinstance(item, list) and len(item) == 1 else item
                 for item in rings]
        notes_ends, close, kinds = [], params["caps"], None
        if params["caps"] and spacing > 0 and (leave_holes or points is not None):
            kinds = rc.classify_ends(rings, ring_planes[0].frame, cap_cloud, spacing, points,
                                     open_holes=leave_holes)
            notes_ends = [k.note for k in kinds if k.note]
            close = tuple(k.closed(leave_holes) for k in kinds)
            build.holes = tuple(k.kind == "hole" and leave_holes for k in kinds)
            build.mouths = tuple(k.kind == "mouth" and not k.closed() for k in kinds)
            if any(k.outer_only for k in kinds):   # a wall too thin to build both faces
                rings = rc.outer_loops(rings, ring_planes[0].frame)
        build.ends = {}
        if params["caps"] and params["extend_ends"] and spacing > 0:
            rings, notes_extend = rc.extend_to_caps(rings, ring_planes, cap_cloud,
                                                    np.arange(len(cap_cloud)), spacing,
                                                    sigma=cap_sigma, ends=build.ends)
            notes_ends += notes_extend
        for kind in kinds or ():
            build.ends.setdefault(kind.end, {}).update(kind.record())
        result = st.stitch_rings(rings, planes[0].frame[2], close_ends=close,
                                 support_sigma=support, cap_points=cap_cloud,
                                 diagnostics=diagnostics)
        return result, notes_ends

    build.holes, build.mouths, build.ends = (False, False), (False, False), {}
    return build


def stitch(ctx: StageContext) -> dict:
    """``surface.reconstruct.extend_to_caps`` (end rings to the cap points), then
    ``surface.stitch.stitch_rings`` (with support rings at sharp profile turns when
    ``stitch.support``; inner caps at their cap points' height); stitch.json holds the
    loop graph."""
    p = ctx.params["stitch"]
    rings, planes, noise = artifacts.read_curves(ctx.stage_path("curves"))
    arcs = artifacts.read_arc_parameters(ctx.stage_path("curves"))
    if arcs is not None:  # one-sided data: an open surface with a border
        return _stitch_open(ctx, rings, *arcs)
    _, cap_cloud, spacing = artifacts.read_sections(ctx.stage_path("sections"))
    cap_sigma = artifacts.read_cap_sigma(ctx.stage_path("sections"))
    points = (artifacts.read_cloud(ctx.stage_path("acquire"))["points"]
              if ctx.has_output("acquire") else None)   # a mouth's sheets are counted in it
    build = _stitcher(p, planes, noise, cap_cloud, spacing, cap_sigma,
                      leave_holes=bool(ctx.params["sections"]["open"]), points=points)
    result, notes_ends = build(rings, planes)
    messages = notes_ends + list(result.notes) + list(result.messages)
    notes = {"closed": bool(result.closed), "messages": messages,
             # sections.open: a hole in the data left as a border; a mouth on a wall too
             # thin to part left open (either: the smooth stage's open path)
             **({"open": True, "holes": [bool(h) for h in build.holes]}
                if any(build.holes) else {}),
             **({"open": True, "mouths": [bool(m) for m in build.mouths]}
                if any(build.mouths) else {}),
             # each end: where and how it was placed, the placement's own standard error,
             # its kind (none, hole, mouth) and the evidence
             "ends": build.ends,
             "open_interfaces": list(result.open_interfaces), "flips": int(result.flips),
             "delaunay_fraction": float(result.delaunay_fraction),
             "branch_events": result.graph.counts() if result.graph else {}}
    artifacts.write_stitched(ctx.out, result.vertices, result.triangles,
                             {**notes, "loop_graph": result.graph.to_json() if result.graph
                              else None})
    thin = [m for m in notes_ends if "too thin" in m]   # the one line a user must read
    for message in thin + list(result.messages):
        log.warning("stitch: %s", message)
    for message in [m for m in notes_ends if m not in thin] + list(result.notes):
        log.info("stitch: %s", message)
    from pipeline.smoothing import solid_report  # one warning line when not a valid solid

    notes["solid"] = solid_report("stitch", result.vertices, result.triangles,
                                  expect_closed=bool(result.closed))
    return {"vertices": len(result.vertices), "triangles": len(result.triangles), **notes}


def _sized_control_mesh(ctx: StageContext, vertices, triangles):
    """``surface.sizing.size_control_mesh`` of the curves' rings (``smooth.size``): the
    thinned stitched mesh (kept rings regressed across their neighbour sections) whose
    interpolating surface is estimated within ``smooth.size_tolerance`` of the truth (0:
    no farther than the dense stitched mesh, ``surface.sizing.stitched_error`` of the
    rings' variogram across sections, ``surface.sizing.section_variogram``; where it
    cannot be measured, their independent scatter ``surface.section_errors.ring_noise``, else
    their fits' precision stored by the curves stage, else the points' noise σ̂);
    ``None`` when not asked or not possible (no noise estimate, an open mesh), with the
    reason logged."""
    if not ctx.params["smooth"]["size"] or not ctx.has_output("curves") \
            or not ctx.has_output("sections"):
        return None
    rings, planes, noise = artifacts.read_curves(ctx.stage_path("curves"))
    fits = artifacts.read_curve_fits(ctx.stage_path("curves"))
    _, cap_cloud, spacing = artifacts.read_sections(ctx.stage_path("sections"))
    return sized_rings(ctx.params, rings, planes, noise,
                       fits["ring_precision"] if fits is not None else 0.0, cap_cloud, spacing,
                       artifacts.read_cap_sigma(ctx.stage_path("sections")),
                       (vertices, triangles))


def sized_rings(params: Mapping, rings: list, planes: list, noise: float | None,
                precision: float, cap_cloud, spacing: float, cap_sigma, dense: tuple):
    """The smooth stage's sizing of the curves' rings (``rings`` a list of loops per
    section, ``planes`` their sections, as ``pipeline.artifacts.read_curves`` gives them;
    ``precision`` the fits' ring precision; the sections' cap cloud, spacing and cap σ;
    ``dense`` the stitched ``(vertices, triangles)``) with the stitch stage's rules
    (``params``: the run's parameters): a ``surface.sizing.SizedMesh``, or ``None`` with
    the reason logged (:func:`_sized_control_mesh`)."""
    import numpy as np

    from surface import section_errors, sizing

    p = params["smooth"]
    variogram = sizing.section_variogram(rings, planes[0].frame[2])
    ring_sigma = section_errors.ring_noise(rings, planes[0].frame[2], precision, noise or 0.0) \
        if variogram is None else float(np.sqrt(variogram(1)))
    tolerance = float(p["size_tolerance"]) or None
    if (tolerance is None and variogram is None and ring_sigma <= 0) or spacing <= 0:
        log.info("smooth: no sizing (no noise estimate or section spacing); the stitched "
                 "mesh is the control mesh")
        return None
    build = _stitcher(params["stitch"], planes, noise, cap_cloud, spacing, cap_sigma)

    def mesh(thin_rings, thin_planes):
        result, _ = build(thin_rings, thin_planes, diagnostics=False)
        if not result.closed:
            raise ValueError("the thinned rings stitch to an open mesh")
        return result.vertices, result.triangles

    return sizing.size_control_mesh(rings, planes, spacing, mesh, dense,
                                    tolerance, noise=ring_sigma, variogram=variogram)


def smooth(ctx: StageContext) -> dict:
    """``pipeline.smoothing.smooth_mesh`` over the control mesh (the one smoothing path,
    with its G1 report: ``g1_angle`` radians, ``gap`` scene units).  The control mesh is
    the stitched mesh thinned by ``surface.sizing`` (``smooth.size``), its vertices
    interpolated except at sharp rims (``smooth.interpolate``:
    ``surface.sizing.interpolating_control``)."""
    from pipeline.mesh_io import read_mesh
    from pipeline.smoothing import smooth_mesh
    from surface.sizing import interpolating_control

    vertices, triangles = read_mesh(ctx.stage_path("stitch", artifacts.MESH))
    level = ctx.params["smooth"]["level"]
    info: dict = {}
    if _stitched_open(ctx):
        return _smooth_open(ctx, vertices, triangles, level)
    try:
        sized = _sized_control_mesh(ctx, vertices, triangles)
        if sized is not None:
            _log_sizing(sized, len(triangles))
            vertices, triangles = sized.vertices, sized.triangles
            info = {"size_step": sized.step, "size_n": sized.n,
                    "size_deviation": sized.deviation, "size_tolerance": sized.tolerance,
                    "size_error": sized.error, "size_noise": sized.noise,
                    "size_within_goal": bool(sized.error <= sized.tolerance),
                    "size_variogram": sized.variogram.to_json() if sized.variogram else None,
                    "size_tried": sized.tried,
                    "control_triangles": len(triangles)}
        control, built = vertices, None
        if ctx.params["smooth"]["interpolate"]:  # borders: the mesh's own vertices back
            if sized is not None and sized.surface is not None:
                built = sized.surface   # the sizing built it so, to judge it
            else:   # the object's ridges interpolated too (sizing.crease_vertices)
                creases = sized.creases if sized is not None else _mesh_creases(
                    ctx, vertices, triangles)
                control = interpolating_control(vertices, triangles, creases)
        tolerance = _smooth_tolerance(ctx, sized) if level in ("auto", "adaptive") else None
        if tolerance is not None:
            info["chord_tolerance"] = tolerance
        smoothed = smooth_mesh(control, triangles, level, tolerance, surface=built)
    except ValueError as exc:
        from surface.metrics import mesh_topology

        border = mesh_topology(vertices, triangles)["boundary_edges"]
        if border:  # an open stitched mesh (e.g. one stereo pair sees one side only)
            raise StageSkipped(f"the stitched mesh is open ({border} border edges) and the "
                               f"Bezier construction refused it: {exc}") from exc
        general = _general_surface(ctx, level, tolerance, None, reason=str(exc))
        if general is None:
            raise
        smoothed, chosen = general
        info.update(chosen)
    else:
        general = _general_surface(ctx, level, tolerance, smoothed)
        if general is not None:
            smoothed, chosen = general
            info.update(chosen)
    artifacts.write_smooth(ctx.out, smoothed.vertices, smoothed.triangles, smoothed.normals,
                           smoothed.surface)
    return {**smoothed.info(), **info}


def _general_surface(ctx: StageContext, level, tolerance, section, reason: str = "",
                     noise: float | None = None):
    """``smooth.general``: where one family of parallel sections cannot organise the
    points, the control mesh that knows no axis (``surface.general_mesh``).  ``"auto"``
    builds it beside the section surface and keeps the valid solid, then the one of the
    genus the data support, then the one nearer the cloud
    (``surface.general_mesh.prefer_general``, ``evidence_genus``, ``cloud_fidelity``);
    ``"always"`` takes it; ``"never"`` does not build it.  Returns ``(Smoothed, info)`` when
    the stage's surface changes or was measured, ``None`` when not asked or possible (no
    cloud, too few points).  With ``section`` None (the section surface was refused) the
    general surface stands in when asked.  ``"auto"`` builds it only where the section
    surface gives cause (``surface.general_mesh.needs_general``: not a valid solid, or its
    C beyond what the points' noise about their curves (the curves stage's estimate, else
    ``noise``) and the sizing's goal explain)."""
    import numpy as np

    from surface import general_mesh
    from surface.sections import point_spacing

    mode = ctx.params["smooth"]["general"]
    if mode not in ("auto", "always", "never"):
        raise InputError(f"smooth.general must be one of auto, always, never, got {mode!r}")
    if mode == "never" or not ctx.has_output("acquire") or not ctx.has_output("sections"):
        return None
    points = artifacts.read_cloud(ctx.stage_path("acquire"))["points"]
    heights = artifacts.section_heights(ctx.stage_path("sections"))
    if len(points) < 4 * general_mesh.NORMAL_NEIGHBOURS or len(heights) < 2:
        return None
    spacing = float(np.median(np.diff(np.sort(heights))))
    own = None
    if ctx.has_output("curves"):  # the points' noise about their sections' curves
        noise = artifacts.read_curves(ctx.stage_path("curves"))[2]
    if section is not None and mode == "auto":
        own = general_mesh.cloud_fidelity(section.vertices, section.triangles, points)
        valid = bool((section.solid or {}).get("valid", True))
        if not general_mesh.needs_general(own, valid, noise):
            return section, {"general_mode": mode, "sections_fidelity": own.to_json(),
                             "control": "sections"}
    try:  # triangles of the section spacing: as fine as the section mesh it stands in for
        vertices, triangles = general_mesh.poisson_control_mesh(points, spacing,
                                                                point_spacing(points))
        if tolerance is None and level in ("auto", "adaptive"):
            tolerance = _smooth_tolerance(ctx)
        general = _general_smooth(vertices, triangles, level, tolerance, points)
    except ValueError as exc:
        log.info("smooth: no general control mesh (%s): the section surface stays", exc)
        return None
    fidelity = general_mesh.cloud_fidelity(general.vertices, general.triangles, points)
    info = {"general_mode": mode, "general_fidelity": fidelity.to_json(),
            "general_control_triangles": len(triangles)}
    if section is None:
        log.warning("smooth: the section surface was refused (%s): the general control mesh "
                    "stands in", reason)
        return general, {**info, "control": "general", "control_triangles": len(triangles)}
    if own is None:
        own = general_mesh.cloud_fidelity(section.vertices, section.triangles, points)
    info["sections_fidelity"] = own.to_json()
    valid = [bool((smoothed.solid or {}).get("valid", True)) for smoothed in (section, general)]
    genera = [(smoothed.solid or {}).get("genus") for smoothed in (section, general)]
    evidence = None
    if mode == "auto" and None not in genera and genera[0] != genera[1]:
        evidence = general_mesh.evidence_genus(
            section.vertices, section.triangles, points,
            general_mesh.support_reach(point_spacing(points), noise))
        info["evidence_genus"] = evidence
    if mode == "always" or general_mesh.prefer_general(
            own, fidelity, section_valid=valid[0], general_valid=valid[1],
            section_genus=genera[0], general_genus=genera[1], evidence_genus=evidence):
        log.info("smooth: the general control mesh carries the surface (valid %s, genus %s, "
                 "A %.3g / C %.3g against the sections' %s, %s, %.3g / %.3g; the data's "
                 "genus %s)", valid[1], genera[1], fidelity.a90, fidelity.c50, valid[0],
                 genera[0], own.a90, own.c50, evidence)
        return general, {**info, "control": "general", "control_triangles": len(triangles)}
    return section, {**info, "control": "sections"}


def _general_smooth(vertices, triangles, level, tolerance, points=None):
    """Loop's patches over the general control mesh: ``pipeline.smoothing.smooth_general``
    (fitted to ``points`` where that is a valid solid, else through its vertices, else with
    the folds held back, else over the mesh itself)."""
    from pipeline.smoothing import smooth_general
    from surface.sections import point_spacing

    return smooth_general(vertices, triangles, level, tolerance, points=points,
                          spacing=None if points is None else point_spacing(points))


def _stitched_open(ctx: StageContext) -> bool:
    """Whether the stitch stage made an open surface from one-sided data."""
    notes_path = ctx.stage_path("stitch", artifacts.STITCH_NOTES)
    return notes_path.is_file() and bool(json.loads(notes_path.read_text()).get("open"))


def _smooth_open(ctx: StageContext, vertices, triangles, level) -> dict:
    """The smooth stage over an open stitched mesh: the stitched mesh is the control mesh
    (the sizing and the interpolating control points need a closed mesh), Loop's patches
    with the border rule of ``surface.bezier`` (ghost triangles past the border: the
    surface is G1 inside and ends at the border edges without interpolating them)."""
    import numpy as np

    from pipeline.smoothing import smooth_mesh
    from surface.open_surface import boundary_loops

    tolerance = _smooth_tolerance(ctx) if level in ("auto", "adaptive") else None
    try:
        smoothed = smooth_mesh(vertices, triangles, level, tolerance)
    except ValueError as exc:  # e.g. two strips meeting at one vertex only (a pinch)
        raise StageSkipped(f"the open stitched mesh was refused by the Bezier construction: "
                           f"{exc}") from exc
    artifacts.write_smooth(ctx.out, smoothed.vertices, smoothed.triangles, smoothed.normals,
                           smoothed.surface)
    border = boundary_loops(smoothed.triangles)
    length = sum(float(np.linalg.norm(smoothed.vertices[b] - smoothed.vertices[np.roll(b, -1)],
                                      axis=1).sum()) for b in border)
    return {**smoothed.info(), "open": True, "boundary_loops": len(border),
            "boundary_length": length, "control_triangles": len(triangles),
            **({"chord_tolerance": tolerance} if tolerance is not None else {}),
            "border_rule": "surface.bezier ghost layers (the border is approximated, "
                           "not interpolated)"}


def _mesh_creases(ctx: StageContext, vertices, triangles):
    """``surface.interpolation.mesh_creases`` of the stitched mesh, the sections' heights from the
    curves stage; None without curves (a mesh given as input)."""
    from surface import interpolation

    if not ctx.has_output("curves"):
        return None
    rings, planes, _ = artifacts.read_curves(ctx.stage_path("curves"))
    try:
        return interpolation.mesh_creases(vertices, triangles, rings, planes[0].frame[2])
    except ValueError:   # borders or a degenerate mesh: the sharp vertices kept as before
        return None


def _log_sizing(sized, dense_triangles: int) -> None:
    """One line on the sizing's choice; a warning when it kept the dense stitched mesh
    (no thinned candidate within its goal), with the closest candidate and the way to
    accept a coarser surface."""
    if sized.step > 1 or sized.n > 0:
        log.info("smooth: control mesh thinned to sections %d apart, %d ring points: %d of "
                 "%d triangles, estimated error %.3g against its goal %.3g", sized.step,
                 sized.n, len(sized.triangles), dense_triangles, sized.error, sized.tolerance)
        return
    judged = [c for c in sized.tried if isinstance(c.get("error"), float)]
    closest = min(judged, key=lambda c: c["error"] / c["tolerance"], default=None)
    told = "" if closest is None else (
        f"; the closest, sections {closest['step']} apart with {closest['n']} ring points, "
        f"was estimated {closest['error']:.3g} against {closest['tolerance']:.3g}")
    log.warning("smooth: no thinned control mesh was within its goal%s: the dense stitched "
                "mesh is the control mesh (%d triangles, 4 patches each); set "
                "smooth.size_tolerance to the error to accept for a coarser surface", told,
                dense_triangles)


def _smooth_tolerance(ctx: StageContext, sized=None) -> float:
    """Chord tolerance of ``smooth.level = "adaptive"`` / ``"auto"`` (scene units): given,
    else the sized surface's estimated error to the truth
    (``surface.sizing.SizedMesh.chord_tolerance``), else the cloud's median sigma, else
    5 % of the section spacing (the surface between two sections is only known to the
    scale of their spacing, finer facets would show no more)."""
    import numpy as np

    given = float(ctx.params["smooth"]["tolerance"])
    if given > 0:
        return given
    from_size = sized.chord_tolerance() if sized is not None else 0.0
    if from_size > 0:
        return from_size
    sigma = artifacts.read_cloud(ctx.stage_path("acquire"))["sigma"]
    sigma = sigma[np.isfinite(sigma) & (sigma > 0)]
    if sigma.size:
        return float(np.median(sigma))
    return 0.05 * float(np.median(np.diff(artifacts.section_heights(ctx.stage_path("sections")))))


# --------------------------------------------------------------------------- outputs
def export(ctx: StageContext) -> dict:
    """``pipeline.export``: the surface in every ``export.formats``, and its control net."""
    from pipeline import export as export_mod
    from pipeline.mesh_io import read_mesh, read_mesh_with_normals

    smoothed = ctx.has_output("smooth")
    source = ctx.stage_path("smooth", artifacts.SURFACE) if smoothed else \
        ctx.stage_path("stitch", artifacts.MESH)
    if not smoothed:
        log.warning("export: no smooth surface (%s); exporting the stitched mesh",
                    (ctx.workspace.record("smooth") or {}).get("reason", "smooth did not run"))
    # the smooth surface's exact normals come with it (one read of the file)
    vertices, triangles, normals = read_mesh_with_normals(source) if smoothed else \
        (*read_mesh(source), None)
    net = artifacts.read_control_net(ctx.stage_path("smooth")) if smoothed else None
    written, cad_faces = [], None
    for fmt in ctx.track(ctx.params["export"]["formats"], "formats"):
        fmt = str(fmt).lower().lstrip(".")
        path = ctx.out / f"surface.{fmt}"
        if fmt in ("step", "iges"):  # the exact surface as a CAD solid (pipeline.step)
            if net is None or "domain_triangles" not in net:
                log.warning("export: no smooth surface, so no %s file (CAD needs the exact "
                            "patches)", fmt.upper())
                continue
            from pipeline.step import write_cad

            # a face per control triangle where it stays within the smooth stage's chord
            # tolerance and G1 (pipeline.step.write_cad), else a face per patch
            tolerance = ((ctx.workspace.record("smooth") or {}).get("info") or {}).get(
                "chord_tolerance")
            cad = {}
            write_cad(path, net["control_points"], net["domain_triangles"],
                      source_face=net.get("source_face"), tolerance=tolerance, report=cad)
            cad_faces = cad["faces"]
        else:  # a PLY of the smooth surface carries each vertex's 1 sigma along its normal
            sigma = _surface_sigma(ctx, vertices, normals) if smoothed and fmt == "ply" \
                else None
            export_mod.export_mesh(path, vertices, triangles, normals=normals, sigma=sigma)
        written.append(path.name)
    if smoothed:
        domain = (net["domain_vertices"], net["domain_triangles"]) \
            if "domain_triangles" in net else None
        export_mod.write_control_net(ctx.out / "surface.npz", net["control_points"],
                                     net["index"], net["source_face"], domain_mesh=domain)
        written.append("surface.npz")
    info = {"files": written, "source": "smooth surface" if smoothed else "stitched mesh"}
    if cad_faces is not None:
        info["cad_faces"] = cad_faces
    return info


def _surface_sigma(ctx: StageContext, vertices, normals):
    """``surface.uncertainty.normal_sigma`` of the surface's vertices from the acquired
    points and their sigma (None without them)."""
    from surface.uncertainty import normal_sigma

    if not ctx.has_output("acquire"):
        return None
    cloud = artifacts.read_cloud(ctx.stage_path("acquire"))
    if "sigma" not in cloud or len(cloud["points"]) < 16:
        return None
    return normal_sigma(vertices, normals, cloud["points"], cloud["sigma"]).sigma


def report(ctx: StageContext) -> dict:
    """``pipeline.report.build_report``: ``OUTDIR/report.html``."""
    from pipeline.report import build_report

    views = _report_views(ctx)
    peer = None
    if views and ctx.params["report"]["poisson"] and ctx.has_output("acquire"):
        from surface.general_mesh import poisson_surface

        points = artifacts.read_cloud(ctx.stage_path("acquire"))["points"]
        peer = ("Poisson-8", *poisson_surface(points))
    return build_report(ctx.workspace.root, ctx.config, ctx.out,
                        track=lambda items, desc="": ctx.track(items, desc), order=ctx.plan,
                        views=views, peer=peer)


def _report_views(ctx: StageContext) -> list:
    """An image folder's views with known cameras (given, or SfM's ``acquire/cameras.yml``),
    each ``(RGB image, camera, silhouette or None)``: the silhouette from the view's mask
    file (``FOLDER/masks``), else its uniform background (``matching.masks``), else None."""
    import cv2

    from matching import masks
    from matching.cameras import read_cameras
    from matching.image_file import imread

    if ctx.kind != "folder" or not ctx.inputs:
        return []
    folder = Path(ctx.inputs[0])
    sources = [ctx.stage_path("acquire", artifacts.CAMERAS)]
    if ctx.rig is not None:
        sources.insert(0, Path(ctx.rig))
    cameras = []
    for source in sources:
        if source.exists():
            try:
                cameras = read_cameras(source)
                break
            except Exception:  # noqa: BLE001 - a file the acquisition read another way
                continue
    views = []
    for camera in cameras:
        path = folder / camera.name
        if not camera.name or not path.is_file():
            continue
        image = imread(str(path), cv2.IMREAD_COLOR)
        if image is None or image.shape[:2] != (camera.height, camera.width):
            continue
        mask_file = masks.mask_path(folder, camera.name)
        silhouette = (masks.read_mask(mask_file, (camera.width, camera.height))
                      if mask_file is not None else masks.foreground_mask(image))
        views.append((cv2.cvtColor(image, cv2.COLOR_BGR2RGB), camera, silhouette))
    return views
