"""The scene and acquire stages of ``photosurf run``: a recipe's rendered views, and the
input's point cloud (read from a file, matched from a stereo pair, or acquired from an
image folder by :func:`pipeline.acquisition.acquire_folder`), written to the workspace
(:func:`pipeline.artifacts.write_cloud`) with the counts the manifest records.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from pipeline import artifacts, progress
from pipeline.errors import InputError
from pipeline.inputs import folder_images, scene_source, stereo_inputs
from pipeline.workspace import write_text

if TYPE_CHECKING:
    from pipeline.engine import StageContext

log = logging.getLogger("photosurf")


def scene(ctx: StageContext) -> dict:
    """``pipeline.scenes.render_scene``: the recipe's views, cameras and true mesh."""
    from pipeline import scenes

    overrides = ctx.params["scene"].get("overrides", {})
    recipe = scenes.load_recipe(ctx.inputs[0], overrides) if overrides else ctx.inputs[0]
    scenes.render_scene(recipe, ctx.out, progress=progress.enabled())
    return {"views": len(list((ctx.out / "images").glob("*.png")))}


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
    out = _save_cloud(ctx, *_cloud_arrays(cloud), source=getattr(cloud, "pair", None))
    # what the sections stage's axis "data" needs: the cameras' ring, and whether the
    # frame is the user's (given cameras) or an arbitrary SfM one
    ring = {**cloud.stats.get("ring", {}), "frame": "sfm" if info["cameras"] == "pycolmap SfM"
            else "given"}
    write_text(ctx.out / artifacts.RING_FILE, json.dumps(ring, indent=1))
    if ring["frame"] == "sfm":  # the cloud's frame: reusable as --cameras
        artifacts.write_cameras(ctx.out, cloud.stats["cameras"])
    return {**out, **info}


def _save_cloud(ctx: StageContext, points, colors=None, sigma=None, source=None) -> dict:
    if len(np.asarray(points).reshape(-1, 3)) == 0:
        raise InputError(f"{ctx.inputs[0]}: acquisition produced no points")
    written = artifacts.write_cloud(ctx.out, points, colors, sigma, source)
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
            "pairs_cover": bool(stats.get("pairs_cover", False)),
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
