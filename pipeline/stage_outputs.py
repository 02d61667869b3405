"""The export and report stages of ``photosurf run``: the surface in every
``export.formats`` with its control net (:mod:`pipeline.export`, :mod:`pipeline.cad_export`),
and ``OUTDIR/report.html`` (:func:`pipeline.report.build_report`).
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import TYPE_CHECKING

from pipeline import artifacts

if TYPE_CHECKING:
    from pipeline.engine import StageContext

log = logging.getLogger("photosurf")


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
        if fmt in ("step", "iges"):  # the exact surface as a CAD solid (pipeline.cad_export)
            if net is None or "domain_triangles" not in net:
                log.warning("export: no smooth surface, so no %s file (CAD needs the exact "
                            "patches)", fmt.upper())
                continue
            from pipeline.cad_export import write_cad

            # a face per control triangle where it stays within the smooth stage's chord
            # tolerance and G1 (pipeline.cad_export.write_cad), else a face per patch
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
    return normal_sigma(vertices, normals, cloud["points"], cloud["sigma"],
                        source=cloud.get("source")).sigma


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
