"""One stereo pair to an open surface: the default stereo recipe end to end, against its truth.

``photosurf run fixtures/scenes/vase.toml`` (one calibrated pair of the vase r(z) = 1 +
0.3 sin 2z, 1024x768, 2 grey levels of noise, a gain/offset between the views) sees one
side of the object: the sections are open arcs and the run ends with an open surface
(``curves.open = "auto"``, :mod:`surface.open_surface`).  Rows, on the same cloud:

* ``photosurf-open``      the smooth surface (Loop's patches over the stitched arcs);
* ``photosurf-stitched``  its control mesh, the stitched open arcs (rings ending on the
  smooth border curves, ``surface.open_surface.smooth_border``);
* ``stitched-arc-ends``   the same sections stitched by the former rule (each ring ends
  where its arc's data end, strips stop at the shorter arc: a staircase border);
* ``poisson-trimmed``     open3d's screened Poisson reconstruction (depth 8) of the same
  cloud with normals oriented to the cameras, its vertices of the lowest 10 % density
  removed (the usual way to make an open surface of a one-sided scan).

Columns: the surface's distance to the truth mesh (mean, 90th percentile; the cloud's own
RMS distance beside it), the share of the part both views see that lies within τ of the
surface (``cover``: all of it; ``cover wall``: the wall, where the truth normal is more
than 30° from the axis, as the sections take it), the share of the surface's area whose
nearest truth point neither view pair sees (``beyond``), and where the border lies against
the border of the part both views see: for each point of the border (sampled every quarter
section spacing along its edges), the distance from its nearest truth point to the other
side of that border (positive: inside the seen part),
median and 90th percentile of its size, in section spacings; and, beside it, the
distance from each of those points to the nearest cloud point (``data``: the border lies
where the data end), in section spacings; the border's roughness (``excess``: its length
over its moving average's over two section spacings, minus 1; ``turn``: its turning angle
every half spacing, median and 90th percentile, :func:`border_roughness`).  The cloud's
own cover of the seen part (within two point spacings) is printed above the table: the
border cannot lie past the data.
"Seen by both" is exact: a truth point is seen by a camera when it projects into the
image and the ray from the camera centre meets the truth mesh first at it (open3d ray
casting).
τ = 0.002 × the truth's bounding-box diagonal (the report's ``tau_rel``).

    .venv/bin/python benchmarks/open_surface.py [--workspace DIR] [--json PATH]

``--workspace``: reuse (or keep) the run's workspace; default a temporary folder.

    .venv/bin/python benchmarks/open_surface.py --facade WORKSPACE [--photos DIR]
        [--renders DIR] [--json PATH]

``--facade``: a finished run of a one-sided folder without a truth (the Sceaux facade):
its stitched (and smooth, when there) open surface against its own cloud -- the cloud's
points' distance to the surface (median, 90th percentile; the share within 3 of their
own σ), components and border loops -- and, with ``--photos``, renders from three of its
cameras (first, middle, last) beside the photos (photo | surface, border red | blend).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
import tomllib
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from _common import print_goals, uptime, write_result  # noqa: E402

from checks.robust import mad_sigma  # noqa: E402

RECIPE = ROOT / "fixtures" / "scenes" / "vase.toml"
#: Truth samples for the visibility map and the coverage (area-weighted, seeded).
TRUTH_SAMPLES = 200_000
#: Samples on each reconstructed surface.
SURFACE_SAMPLES = 50_000
#: τ as a share of the truth's bounding-box diagonal (pipeline/defaults.toml report.tau_rel).
TAU_REL = 0.002
#: A wall point's truth normal is more than 30° from the axis (surface/reconstruct.py
#: MIN_WALL_SINE = 0.5: the sections take such points; flatter ones are cap points).
WALL_SINE = 0.5
#: RANSAC planes taken as the facade's walls (front, wings, a tower's faces) by
#: :func:`wall_flatness`.
WALL_PLANES = 4


def run(workspace: Path) -> dict:
    """``photosurf run`` of the recipe into ``workspace`` (resumed when up to date)."""
    from pipeline.config import resolve
    from pipeline.engine import run_pipeline

    t0 = time.perf_counter()
    summary = run_pipeline([str(RECIPE)], workspace, resolve())
    return {"seconds": time.perf_counter() - t0, "summary": summary}


def seen_by(cameras, truth, points: np.ndarray) -> np.ndarray:
    """``(N,) bool``: the point projects into every camera's image and no part of the truth
    lies between it and the camera (first hit within 1e-5 of the object's size)."""
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(truth[0].astype(np.float32)),
                        o3d.core.Tensor(truth[1].astype(np.uint32)))
    size = float(np.ptp(truth[0], axis=0).max())
    seen = np.ones(len(points), bool)
    for cam in cameras:
        centre = cam.center
        x_c = points @ cam.R.T + cam.t
        uv = x_c[:, :2] / x_c[:, 2:3] @ cam.K[:2, :2].T + cam.K[:2, 2]
        inside = (x_c[:, 2] > 0) & (uv[:, 0] > -0.5) & (uv[:, 0] < cam.width - 0.5) & \
            (uv[:, 1] > -0.5) & (uv[:, 1] < cam.height - 0.5)
        ray = points - centre
        dist = np.linalg.norm(ray, axis=1)
        rays = np.concatenate([np.broadcast_to(centre, ray.shape), ray / dist[:, None]], axis=1)
        hit = scene.cast_rays(o3d.core.Tensor(rays.astype(np.float32)))["t_hit"].numpy()
        seen &= inside & (hit >= dist - 1e-5 * size - 1e-4 * dist)
    return seen


def scores(vertices, triangles, truth, to_truth, visibility: dict, tau: float,
           spacing: float, cloud_tree) -> dict:
    """The table's columns for one mesh (module notes)."""
    from scipy.spatial import cKDTree

    from surface.metrics import edge_table, mesh_topology, sample_mesh

    samples = sample_mesh(vertices, triangles, count=SURFACE_SAMPLES, seed=0)
    d = to_truth(samples)
    tree = cKDTree(samples)
    gap, _ = tree.query(visibility["points"], distance_upper_bound=10 * tau)
    both, wall = visibility["both"], visibility["wall"]
    # nearest truth sample of each surface sample / border vertex: seen or not
    truth_tree = cKDTree(visibility["points"])
    _, near = truth_tree.query(samples)
    table = edge_table(triangles)
    edges = table.edges[table.counts == 1]
    border = np.unique(edges)
    inset = to_data = np.zeros(0)
    if len(border):
        # the border sampled every quarter spacing along its edges (per length, not per
        # vertex: a staircase's treads hold many vertices, a smooth border one a section)
        ends = vertices[edges]
        count = np.maximum(1, np.ceil(np.linalg.norm(ends[:, 1] - ends[:, 0], axis=1)
                                      / (spacing / 4)).astype(np.int64))
        edge = np.repeat(np.arange(len(edges)), count)
        frac = (np.arange(len(edge)) - np.repeat(np.cumsum(count) - count, count)) \
            / np.repeat(count, count)
        along = ends[edge, 0] + frac[:, None] * (ends[edge, 1] - ends[edge, 0])
        _, b_near = truth_tree.query(along)
        seen_tree = cKDTree(visibility["points"][both])
        unseen_tree = cKDTree(visibility["points"][~both])
        inside = both[b_near]
        q = visibility["points"][b_near]
        inset = np.where(inside, unseen_tree.query(q)[0], -seen_tree.query(q)[0])
        to_data = cloud_tree.query(along)[0]
    topo = mesh_topology(vertices, triangles)
    return {"mean": float(d.mean()), "p90": float(np.quantile(d, 0.9)),
            "cover": float(np.mean(gap[both] <= tau)),
            "cover_wall": float(np.mean(gap[both & wall] <= tau)),
            "beyond": float(np.mean(~both[near])),
            "border_inset_median": float(np.median(inset) / spacing) if len(inset) else None,
            "border_offset_p90": float(np.quantile(np.abs(inset), 0.9) / spacing)
            if len(inset) else None,
            "border_to_data_median": float(np.median(to_data) / spacing) if len(inset) else None,
            "border_to_data_p90": float(np.quantile(to_data, 0.9) / spacing)
            if len(inset) else None,
            **border_roughness(vertices, triangles, spacing),
            "border_vertices": int(len(border)), "components": topo["components"],
            "boundary_edges": topo["boundary_edges"], "faces": topo["faces"]}


def border_roughness(vertices: np.ndarray, triangles: np.ndarray, spacing: float) -> dict:
    """How jagged the longest border loop is, independent of its tessellation: the loop
    resampled every half section spacing by arc length; ``excess``: its length over the
    length of its moving average over two section spacings, minus 1 (a staircase of
    treads and risers one spacing high: ~0.3; a smooth curve: ~0); ``turn``: the
    resampled loop's turning angle at each point, degrees (median, 90th percentile)."""
    from surface.open_surface import boundary_loops

    loops = [lp for lp in boundary_loops(triangles) if len(lp) >= 8]
    if not loops:
        return {}
    pts = vertices[max(loops, key=len)]
    closed = np.vstack([pts, pts[:1]])
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(closed, axis=0), axis=1))])
    length = float(arc[-1])
    n = max(8, int(round(length / (spacing / 2))))
    at = np.linspace(0.0, length, n, endpoint=False)
    ring = np.stack([np.interp(at, arc, closed[:, i]) for i in range(3)], axis=1)
    window = 5  # samples every half spacing: ±1 spacing, a window of two spacings
    kernel = np.ones(window) / window
    wrapped = np.vstack([ring[-(window // 2):], ring, ring[:window // 2]])
    smooth = np.stack([np.convolve(wrapped[:, i], kernel, mode="valid") for i in range(3)],
                      axis=1)
    smooth_length = float(np.linalg.norm(np.roll(smooth, -1, axis=0) - smooth, axis=1).sum())
    seg = np.roll(ring, -1, axis=0) - ring
    seg /= np.maximum(np.linalg.norm(seg, axis=1), 1e-15)[:, None]
    turn = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", seg, np.roll(seg, 1, axis=0)),
                                        -1, 1)))
    return {"border_length": length, "border_excess": length / smooth_length - 1,
            "border_turn_median_deg": float(np.median(turn)),
            "border_turn_p90_deg": float(np.quantile(turn, 0.9)), "border_loops": len(loops)}


def former_rule(ws: Path, spacing: float, eyes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The stitched open mesh of the same sections by the former rule: each ring ends
    where its own arc's data end and strips stop where the shorter arc ends (the
    staircase border), for comparison in the same process."""
    from pipeline import artifacts
    from pipeline.config import resolve
    from surface import open_surface as osf
    from surface import reconstruct as rc

    p = resolve()["curves"]
    smoothing = p["smoothing"] or "auto"
    sliced = artifacts.read_sections(ws / "sections")[0]
    options = {"outlier_threshold": p["outlier_threshold"],
               "min_points": p["min_loop_points"] or rc.min_loop_points(smoothing)}
    loops = osf.organise_arcs(sliced, **options)[1]
    _, rings, params, step, _, _ = osf.open_arcs(loops, spacing, p["n"] or None,
                                                 smoothing=smoothing, border=False)
    result = osf.stitch_arcs(rings, params, step, viewpoint=eyes, reach=osf.QUARTER_STEP)
    return result.vertices, result.triangles


def poisson_trimmed(points: np.ndarray, eyes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """open3d's screened Poisson (depth 8) of the cloud, normals towards the cameras, its
    lowest-density tenth of the vertices removed."""
    import open3d as o3d

    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(12))
    normals = np.asarray(cloud.normals)
    towards = eyes.mean(axis=0) - points
    normals *= np.sign(np.einsum("ij,ij->i", normals, towards))[:, None]
    cloud.normals = o3d.utility.Vector3dVector(normals)
    mesh, density = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(cloud, depth=8)
    density = np.asarray(density)
    mesh.remove_vertices_by_mask(density < np.quantile(density, 0.1))
    mesh.remove_unreferenced_vertices()
    return np.asarray(mesh.vertices), np.asarray(mesh.triangles, dtype=np.int64)


def facade_figures(ws: Path, photos: Path | None = None, renders: Path | None = None
                   ) -> dict:
    """The ``--facade`` figures of a finished workspace (module notes)."""
    import open3d as o3d

    from matching.cameras import read_cameras_yml
    from pipeline import artifacts
    from pipeline.mesh_io import read_mesh
    from surface.metrics import mesh_topology
    from surface.open_surface import boundary_loops, window_footprint

    cloud = artifacts.read_cloud(ws / "acquire")
    points, sigma = cloud["points"], np.asarray(cloud["sigma"], np.float64)
    rows = {}
    for name, rel in (("stitched", "stitch/mesh.ply"), ("smooth", "smooth/surface.ply")):
        if not (ws / rel).is_file():
            continue
        v, t = read_mesh(ws / rel)
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(o3d.core.Tensor(v.astype(np.float32)),
                            o3d.core.Tensor(t.astype(np.uint32)))
        d = scene.compute_distance(o3d.core.Tensor(points.astype(np.float32))).numpy()
        topo = mesh_topology(v, t)
        rows[name] = {"vertices": len(v), "faces": len(t), "components": topo["components"],
                      "border_loops": len(boundary_loops(t)),
                      "distance_median": float(np.median(d)),
                      "distance_p90": float(np.percentile(d, 90)),
                      "within_3_sigma": float(np.mean(d <= 3 * sigma))}
        if name == "stitched" and photos is not None and renders is not None:
            _render_beside(v, t, read_cameras_yml(ws / "acquire" / "cameras.yml"), photos,
                           renders / f"{ws.name}_{name}_three_views.png")
    cameras = read_cameras_yml(ws / "acquire" / "cameras.yml")
    with open(ws / "config.toml", "rb") as fh:
        patch = float(tomllib.load(fh)["acquire"]["patch"])
    footprint = window_footprint(points, np.array([c.center for c in cameras]),
                                 np.array([c.K[0, 0] for c in cameras]), patch)
    return {"cloud_points": len(points), "sigma_median": float(np.median(sigma)),
            "rows": rows, "wall": wall_flatness(points, sigma, cloud.get("source"), footprint)}


def _robust_plane(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Signed distances ``(P,)`` of ``points`` to their least-squares plane, trimmed three
    times at 3 robust σ (1.4826 × MAD), and the points kept by the last trim."""
    keep = np.ones(len(points), bool)
    for _ in range(3):
        centre = points[keep].mean(axis=0)
        normal = np.linalg.svd(points[keep] - centre, full_matrices=False)[2][2]
        r = (points - centre) @ normal
        spread = mad_sigma(r[keep])
        keep = np.abs(r) <= 3 * max(spread, 1e-300)
    return r, keep


def _robust(x: np.ndarray) -> float:
    return float(mad_sigma(x)) if len(x) else float("nan")


def wall_flatness(points: np.ndarray, sigma: np.ndarray, source: np.ndarray | None,
                  footprint: float, seed: int = 0) -> dict:
    """Is the wall between the windows flat within the cloud's σ (module notes)?

    The walls: :data:`WALL_PLANES` RANSAC planes (open3d, inliers within 3 median σ, each
    holding ≥ 5 % of the cloud), each with the points within 2 window footprints of it
    (the recesses) not taken by an earlier plane; the wall cut into square cells of 2
    footprints in the plane (larger than the window), each cell with ≥ 30 points fitted
    by a trimmed plane (:func:`_robust_plane`: the windows' recesses and sills are the
    trimmed ones).  Per cell: the RMS of residual/σ over the kept points, their robust
    spread, the share within 3 σ; medians over the cells.  Whether σ is honest: points
    closer than a quarter footprint in the plane differ by their errors (the wall's relief
    the same for both): ``(r_i − r_j)/√(σ_i² + σ_j²)`` over pairs from two view pairs
    (``cross``, independent errors) and from one (``same``: the shared error cancels);
    1 if σ is the error.
    """
    import open3d as o3d
    from scipy.spatial import cKDTree

    o3d.utility.random.seed(seed)
    unit = float(np.median(sigma))
    rest, taken = np.arange(len(points)), np.zeros(len(points), bool)
    cells, diffs, planes = [], {"cross": [], "same": []}, []
    for _ in range(WALL_PLANES):
        pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points[rest]))
        model, inl = pcd.segment_plane(3 * unit, 3, 2000)
        inl = rest[np.asarray(inl, np.int64)]
        if len(inl) < 0.05 * len(points):
            break
        normal = np.asarray(model[:3]) / np.linalg.norm(model[:3])
        depth = points @ normal + model[3] / np.linalg.norm(model[:3])
        band = np.flatnonzero((np.abs(depth) <= 2 * footprint) & ~taken)
        taken[band] = True
        e1 = np.linalg.svd(points[inl] - points[inl].mean(axis=0), full_matrices=False)[2][0]
        plane_uv = points @ np.stack([e1, np.cross(normal, e1)], axis=1)
        cell = np.floor(plane_uv[band] / (2 * footprint)).astype(np.int64)
        _, label = np.unique(cell, axis=0, return_inverse=True)
        order = np.argsort(label.ravel(), kind="stable")
        groups = np.split(band[order], np.flatnonzero(np.diff(label.ravel()[order])) + 1)
        kept = [g for g in groups if len(g) >= 30]
        for idx in kept:
            r, keep = _robust_plane(points[idx])
            z = r / sigma[idx]
            cells.append((np.sqrt(np.mean(z[keep] ** 2)), _robust(z[keep]),
                          np.mean(np.abs(z) <= 3), keep.mean()))
            if source is None:
                continue
            near = cKDTree(plane_uv[idx]).query_pairs(footprint / 4, output_type="ndarray")
            a, b = idx[near[:, 0]], idx[near[:, 1]]
            ok = keep[near[:, 0]] & keep[near[:, 1]] & (source[a] >= 0) & (source[b] >= 0)
            zz = (r[near[:, 0]] - r[near[:, 1]]) / np.hypot(sigma[a], sigma[b])
            diffs["cross"].append(zz[ok & (source[a] != source[b])])
            diffs["same"].append(zz[ok & (source[a] == source[b])])
        planes.append({"inliers": int(len(inl)), "points": int(len(band)), "cells": len(kept)})
        rest = np.setdiff1d(rest, inl)
    c = np.array(cells).reshape(-1, 4)
    out = {"planes": planes, "cells": len(c), "cell_size": 2 * footprint,
           "footprint": footprint,
           "residual_over_sigma_rms": float(np.median(c[:, 0])) if len(c) else None,
           "residual_over_sigma_rms_quartiles": np.quantile(c[:, 0], [0.25, 0.75]).tolist()
           if len(c) else None,
           "residual_over_sigma_robust": float(np.median(c[:, 1])) if len(c) else None,
           "within_3_sigma": float(np.median(c[:, 2])) if len(c) else None,
           "kept_share": float(np.median(c[:, 3])) if len(c) else None}
    for kind, parts in diffs.items():
        z = np.concatenate(parts) if parts else np.zeros(0)
        out[f"{kind}_pair_difference_over_sigma"] = {
            "pairs": int(len(z)), "rms": float(np.sqrt(np.mean(z**2))) if len(z) else None,
            "robust": _robust(z)}
    return out


def _render_beside(v, t, cameras, photos: Path, out: Path) -> None:
    """Photo | surface (border red) | blend, from the first, middle and last camera."""
    import cv2

    from pipeline.mesh_io import vertex_normals
    from pipeline.raycast import RayCaster
    from pipeline.render import render_view, write_png
    from surface.open_surface import boundary_loops

    scene, normals, tiles = RayCaster(v, t), vertex_normals(v, t), []
    for cam in (cameras[0], cameras[len(cameras) // 2], cameras[-1]):
        width = 640
        s = width / cam.width
        K = cam.K.copy()
        K[:2] *= s
        K[:2, 2] += 0.5 * s - 0.5
        height = int(round(cam.height * s))
        img = np.ascontiguousarray(render_view(scene, v, t, normals, K, cam.R, cam.t,
                                               width, height))
        for loop in boundary_loops(t):
            p = v[loop] @ cam.R.T + cam.t
            uv = p[:, :2] / p[:, 2:] @ K[:2, :2].T + K[:2, 2]
            cv2.polylines(img, [np.round(uv * 4).astype(np.int32)], True, (255, 0, 0), 1,
                          cv2.LINE_AA, shift=2)
        photo = cv2.imread(str(photos / cam.name), cv2.IMREAD_COLOR)
        photo = cv2.cvtColor(cv2.resize(photo, (width, height), interpolation=cv2.INTER_AREA),
                             cv2.COLOR_BGR2RGB)
        tiles.append(np.hstack([photo, img, (0.5 * photo + 0.5 * img).astype(np.uint8)]))
    out.parent.mkdir(parents=True, exist_ok=True)
    write_png(out, np.vstack(tiles))


def truth_visibility(truth, cameras, axis: np.ndarray) -> dict:
    """The truth's visibility map: :data:`TRUTH_SAMPLES` seeded area-weighted samples
    (``points``), whether both views see each (``both``, :func:`seen_by`) and whether it
    is wall (``wall``: its face normal more than 30° from the sections' ``axis``)."""
    from surface.metrics import face_normals

    tv, tt = truth
    areas = np.linalg.norm(face_normals(tv, tt, unit=False), axis=1)
    rng = np.random.default_rng(0)
    face = rng.choice(len(tt), TRUTH_SAMPLES, p=areas / areas.sum())
    r1, r2 = rng.random(TRUTH_SAMPLES), rng.random(TRUTH_SAMPLES)
    flip = r1 + r2 > 1
    r1, r2 = np.where(flip, 1 - r1, r1), np.where(flip, 1 - r2, r2)
    a, b, c = tv[tt[face, 0]], tv[tt[face, 1]], tv[tt[face, 2]]
    pts = a + r1[:, None] * (b - a) + r2[:, None] * (c - a)
    normal = face_normals(tv, tt)[face]
    return {"points": pts, "both": seen_by(cameras, truth, pts),
            "wall": np.abs(normal @ axis) < np.sqrt(1 - WALL_SINE**2)}


def facade_main(args) -> int:
    """``--facade``: the figures of a finished one-sided folder's workspace, printed."""
    result = facade_figures(args.facade, args.photos, args.renders)
    print(f"{args.facade}: {result['cloud_points']} cloud points, their sigma median "
          f"{result['sigma_median']:.5f}")
    keys = ("vertices", "faces", "components", "border_loops", "distance_median",
            "distance_p90", "within_3_sigma")
    print(" | ".join(f"{k:>15}" for k in ("row",) + keys))
    for name, row in result["rows"].items():
        print(" | ".join([f"{name:>15}"] + [f"{row[k]:15.5g}" for k in keys]))
    wall = result["wall"]
    print(f"walls: {wall['cells']} cells of {wall['cell_size']:.4f} (2 window footprints) on "
          f"{len(wall['planes'])} planes; residual/sigma RMS {wall['residual_over_sigma_rms']:.2f}"
          f" (robust {wall['residual_over_sigma_robust']:.2f}), within 3 sigma "
          f"{wall['within_3_sigma']:.3f}; neighbours' difference/sigma (robust): two pairs "
          f"{wall['cross_pair_difference_over_sigma']['robust']:.2f}, one pair "
          f"{wall['same_pair_difference_over_sigma']['robust']:.2f}")
    if args.json:
        write_result(args.json, result)
    return 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workspace", type=Path, default=None)
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument("--facade", type=Path, default=None)
    parser.add_argument("--photos", type=Path, default=None)
    parser.add_argument("--renders", type=Path, default=None)
    args = parser.parse_args(argv)
    print(f"load {uptime()}")
    if args.facade is not None:
        return facade_main(args)
    from matching.cameras import read_cameras_yml
    from pipeline import artifacts
    from pipeline.mesh_io import read_mesh
    from surface.metrics import MeshDistance

    with tempfile.TemporaryDirectory() as tmp:
        ws = args.workspace or Path(tmp) / "vase"
        ran = run(ws)
        truth = read_mesh(ws / "scene" / "truth" / "mesh.ply")
        cameras = read_cameras_yml(ws / "scene" / "cameras.yml")
        stitched_notes = artifacts.read_stitched(ws / "stitch")[2]
        cloud = artifacts.read_cloud(ws / "acquire")["points"]
        _, _, spacing = artifacts.read_sections(ws / "sections")
        to_truth = MeshDistance(*truth)
        visibility = truth_visibility(truth, cameras,
                                      artifacts.read_curves(ws / "curves")[1][0].frame[2])
        tau = TAU_REL * float(np.linalg.norm(np.ptp(truth[0], axis=0)))
        cloud_d = to_truth(cloud)
        cloud_rms = float(np.sqrt(np.mean(cloud_d**2)))
        from scipy.spatial import cKDTree

        cloud_tree = cKDTree(cloud)
        # the cloud's own cover of the part both views see, within its point spacing
        cloud_step = float(np.median(cloud_tree.query(cloud, k=2)[0][:, 1]))
        reach = max(tau, 2 * cloud_step)
        near_cloud = cloud_tree.query(visibility["points"], distance_upper_bound=reach)[0] <= reach
        both = visibility["both"]
        cloud_row = {"cover": float(np.mean(near_cloud[both])),
                     "cover_wall": float(np.mean(near_cloud[both & visibility["wall"]])),
                     "reach": reach}
        rows = {}
        smooth = read_mesh(ws / "smooth" / artifacts.SURFACE)
        rows["photosurf-open"] = scores(*smooth, truth, to_truth, visibility, tau, spacing,
                                         cloud_tree)
        stitched = read_mesh(ws / "stitch" / artifacts.MESH)
        rows["photosurf-stitched"] = scores(*stitched, truth, to_truth, visibility, tau,
                                            spacing, cloud_tree)
        eyes = np.array([cam.center for cam in cameras])
        rows["stitched-arc-ends"] = scores(*former_rule(ws, spacing, eyes), truth, to_truth,
                                           visibility, tau, spacing, cloud_tree)
        t0 = time.perf_counter()
        rows["poisson-trimmed"] = scores(*poisson_trimmed(cloud, eyes), truth, to_truth,
                                         visibility, tau, spacing, cloud_tree)
        rows["poisson-trimmed"]["seconds"] = time.perf_counter() - t0
    print(f"\nstereo vase: {len(cloud)} points, cloud RMS to the truth {cloud_rms:.5f} "
          f"(mean {cloud_d.mean():.5f}, p90 {np.quantile(cloud_d, 0.9):.5f}); τ = {tau:.4f}; "
          f"section spacing {spacing:.4f}; seen by both views: "
          f"{visibility['both'].mean():.3f} of the truth's area; run {ran['seconds']:.1f} s")
    print(f"stitch record: open={stitched_notes.get('open')}, border loops "
          f"{stitched_notes.get('boundary_loops')}, border length "
          f"{stitched_notes.get('boundary_length', 0):.3f}")
    print(f"the cloud covers {cloud_row['cover']:.3f} of the part both views see "
          f"({cloud_row['cover_wall']:.3f} of its wall) within {reach:.4f} (2 point spacings)")
    header = ("row", "mean", "p90", "cover", "cover wall", "beyond", "inset med",
              "|off| p90", "data med", "data p90", "excess", "turn med", "turn p90",
              "comp", "faces")
    print(" | ".join(f"{h:>10}" for h in header))
    for name, r in rows.items():
        values = (r["mean"], r["p90"], r["cover"], r["cover_wall"], r["beyond"],
                  r["border_inset_median"], r["border_offset_p90"],
                  r["border_to_data_median"], r["border_to_data_p90"],
                  r.get("border_excess"), r.get("border_turn_median_deg"),
                  r.get("border_turn_p90_deg"))
        print(" | ".join([f"{name:>10}"] + [f"{v:10.5f}" if v is not None else f"{'-':>10}"
                                             for v in values]
                         + [f"{r['components']:10d}", f"{r['faces']:10d}"]))
    open_row = rows["photosurf-open"]
    goals = {"open surface (one border loop)": stitched_notes.get("open") is True
             and stitched_notes.get("boundary_loops") == 1,
             "mean distance to the truth <= the cloud's RMS": open_row["mean"] <= cloud_rms,
             "nothing beyond the seen part (beyond <= 1 %)": open_row["beyond"] <= 0.01}
    print_goals(goals)
    if args.json:
        write_result(args.json, {"cloud_points": len(cloud), "cloud_rms": cloud_rms,
                                 "tau": tau, "spacing": spacing,
                                 "seen_share": float(visibility["both"].mean()),
                                 "cloud_cover": cloud_row,
                                 "run_seconds": ran["seconds"], "stitch": stitched_notes,
                                 "rows": rows, "goals": goals})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
