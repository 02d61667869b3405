"""Photo folders through ``photosurf run`` in this process: the Sceaux castle's photos and
a phone-sized folder (SfM, the cloud, memory and CPU seconds of each phase), the wall's
flatness against the points' σ, the surface rendered beside the photos, and for a rendered
folder its cameras and cloud against the truth."""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from _common import print_goals, uptime, write_result  # noqa: E402
from _poses import pose_errors  # noqa: E402
from _timed_run import phase_figures, run_in_process  # noqa: E402
from real_temple import DATA  # noqa: E402

from matching.cameras import read_cameras  # noqa: E402
from matching.image_file import imread  # noqa: E402


def wall_flatness(points: np.ndarray, sigma: np.ndarray, cameras) -> dict:
    """The largest plane of the cloud (a facade's wall, :func:`matching.roi.support_plane`'s
    RANSAC, band ``max(3 σ̃, 2 spacing)``): its share of the points and its inliers' RMS
    distance against their median σ (a flat wall measured with σ: about 1)."""
    from matching.roi import support_plane

    sigma = np.where(np.isfinite(sigma), sigma, np.nanmedian(sigma))
    _, plane = support_plane(points, sigma, cameras)
    if "plane" not in plane:
        return {}
    from scipy.spatial import cKDTree

    n, d = np.array(plane["plane"][:3]), plane["plane"][3]
    dist = np.abs(points @ n + d)
    inliers = dist <= plane["band"]
    # locally, between the windows: the RMS distance of each wall point's 32 nearest
    # points to their own least-squares plane over their median sigma (a wall flat within
    # the points' sigma: a little under 1, as the fit takes up some noise -- 0.92 and 0.83
    # on a synthetic 10 x 6 wall with recessed windows, 60 000 points, sigma 0.01 and 0.03;
    # 12 000 seeded wall points)
    wall = np.flatnonzero(inliers)
    wall = np.random.default_rng(0).choice(wall, min(len(wall), 12_000), replace=False)
    _, near = cKDTree(points).query(points[wall], k=32)
    nb = points[near] - points[near].mean(axis=1, keepdims=True)
    smallest = np.linalg.eigvalsh(np.einsum("nki,nkj->nij", nb, nb) / 32)[:, 0]
    local = np.sqrt(np.maximum(smallest, 0)) / np.median(sigma[near], axis=1)
    return {"plane_local_rms_over_sigma_median": float(np.median(local)),
            "plane_local_rms_over_sigma_p25_p75": [float(q) for q in
                                                   np.quantile(local, [0.25, 0.75])],
            "plane_share": float(inliers.mean()), "plane_band": float(plane["band"]),
            "plane_rms": float(np.sqrt(np.mean(dist[inliers] ** 2))),
            "plane_median_sigma": float(np.median(sigma[inliers])),
            "plane_rms_over_sigma": float(np.sqrt(np.mean(dist[inliers] ** 2))
                                          / np.median(sigma[inliers]))}


def render_beside(ws: Path, folder: Path, out: Path, views: int = 3, width: int = 640) -> dict:
    """The run's surface (the smooth one, else the stitched mesh; with neither, the cloud's
    points where they project, grey by depth) rendered from ``views`` of its cameras
    (first, middle, last), each row: the photo, the render, the two blended half and half
    (registration shows as edges that line up); one PNG."""
    import cv2

    from pipeline import artifacts
    from pipeline.mesh_io import read_mesh, vertex_normals
    from pipeline.raycast import RayCaster
    from pipeline.render import render_view, write_png

    for path in (ws / "smooth" / artifacts.SURFACE, ws / "stitch" / artifacts.MESH):
        if path.is_file():
            vertices, triangles = read_mesh(path)
            normals = vertex_normals(vertices, triangles)
            caster = RayCaster(vertices, triangles)
            break
    else:  # no surface: the cloud's points drawn where they project, grey by depth
        path = ws / "acquire" / "cloud.npz"
        if not path.is_file():
            return {"rendered": None}
        cloud = artifacts.read_cloud(ws / "acquire")["points"]
    given = ws / "acquire" / artifacts.CAMERAS  # SfM's cameras; a scene's are its own
    cameras = artifacts.read_cameras(given.parent if given.is_file() else ws / "scene")
    picks = sorted({0, len(cameras) // 2, len(cameras) - 1})[:views]
    rows, covered = [], []
    for v in picks:
        cam = cameras[v]
        s = width / cam.width
        K = cam.K.copy()
        K[:2] *= s
        K[:2, 2] += 0.5 * s - 0.5  # pixel-centre mapping of cv2.resize
        h = int(round(cam.height * s))
        if path.suffix == ".npz":
            x_c = cloud @ cam.R.T + cam.t
            front = x_c[:, 2] > 0
            uv = np.rint(x_c[front, :2] / x_c[front, 2:] @ K[:2, :2].T + K[:2, 2]).astype(int)
            depth = x_c[front, 2]
            grey = 40 + 180 * (depth - depth.min()) / max(np.ptp(depth), 1e-12)
            ok = (uv[:, 0] >= 0) & (uv[:, 0] < width) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
            order = np.argsort(-depth[ok])  # far first: the nearest point is drawn last
            shaded = np.full((h, width, 3), 255, np.uint8)
            shaded[uv[ok][order, 1], uv[ok][order, 0]] = grey[ok][order, None].astype(np.uint8)
        else:
            shaded = render_view(caster, vertices, triangles, normals, K, cam.R, cam.t,
                                 width, h)
        photo = cv2.cvtColor(imread(str(folder / cam.name)), cv2.COLOR_BGR2RGB)
        photo = cv2.resize(photo, (width, h), interpolation=cv2.INTER_AREA)
        hit = np.any(shaded != 255, axis=2)
        covered.append(float(hit.mean()))
        blend = photo.copy()
        blend[hit] = (0.5 * photo[hit] + 0.5 * shaded[hit]).astype(np.uint8)
        rows.append(np.hstack([photo, shaded, blend]))
    write_png(out, np.vstack(rows))
    print(f"rendered {path.relative_to(ws)} from views "
          f"{', '.join(cameras[v].name for v in picks)} -> {out}")
    return {"rendered": str(path.relative_to(ws)), "render_png": str(out),
            "render_views": [cameras[v].name for v in picks], "render_cover": covered}


def folder_run_main(args, name: str, folder: Path) -> dict:
    """``photosurf run FOLDER`` end to end (SfM, cloud, object selection, sections ... the
    report) in this process: registered views, reprojection, seconds / CPU seconds / peak
    memory of SfM, the cloud and the whole run, the stages that ran, the wall's flatness,
    and the surface rendered from three of its cameras beside the photos."""
    import json

    from pipeline import artifacts

    ws = Path(args.workspace or tempfile.mkdtemp(prefix=f"real-{name}-"))
    argv = [str(folder), "--out", str(ws)] + (["--to", args.to] if args.to else []) \
        + (["--cameras", args.cameras] if args.cameras else [])
    status, phases, stats = run_in_process(argv)
    sfm = stats.get("sfm") or {}
    row = {"method": name, "exit": status, "workspace": str(ws), "load": uptime(),
           "views": len(stats.get("view_names", ())) + len(stats.get("unregistered", ())),
           "registered": sfm.get("registered", len(stats.get("view_names", ()))),
           "reprojection_px": sfm.get("mean_reprojection_error_px"),
           "working_scale": stats.get("working_scale", 1.0), "roi": stats.get("roi_kept"),
           **phase_figures(phases)}
    manifest = ws / "manifest.json"
    if manifest.is_file():
        row["stages_done"] = sorted(json.loads(manifest.read_text()).get("stages", {}))
    if (ws / "acquire" / "cloud.npz").is_file():
        cloud = artifacts.read_cloud(ws / "acquire")
        row["points"] = int(len(cloud["points"]))
        row["median_sigma"] = float(np.nanmedian(cloud["sigma"]))
        row.update(wall_flatness(cloud["points"], cloud["sigma"],
                                 artifacts.read_cameras(ws / "acquire")))
        if getattr(args, "truth", None):
            row.update(truth_scores(cloud["points"], artifacts.read_cameras(ws / "acquire"),
                                    Path(args.truth)))
        row.update(render_beside(ws, folder, Path(args.renders) / f"{name}_beside.png"))
    return row


def truth_scores(points: np.ndarray, cameras, truth: Path) -> dict:
    """A rendered folder's cloud against its truth: the run's (SfM) cameras against the
    true ones (``truth``, a cameras.yml of any image size) after the similarity of their
    centres, the cloud taken by it into the true frame, and its distances to the true
    surface (``truth``'s folder's ``truth/mesh.ply``), as a share of the object's size
    (the mesh's bounding-box diagonal)."""
    from dataclasses import replace

    from pipeline.mesh_io import read_mesh
    from surface.metrics import point_mesh_distance

    stem = [replace(c, name=Path(c.name).stem) for c in read_cameras(truth)]
    mine = [replace(c, name=Path(c.name).stem) for c in cameras]
    errors, (s, R, t) = pose_errors(mine, stem)
    out = {f"truth_{k}": v for k, v in errors.items()}
    mesh = truth.parent / "truth" / "mesh.ply"
    if mesh.is_file():
        vertices, triangles = read_mesh(mesh)
        size = float(np.linalg.norm(np.ptp(vertices, axis=0)))
        moved = s * points @ R.T + t
        d = point_mesh_distance(moved, vertices, triangles)
        out.update(truth_size=size, truth_median=float(np.median(d)),
                   truth_p90=float(np.quantile(d, 0.9)), truth_rms=float(np.sqrt(np.mean(d**2))),
                   truth_median_rel=float(np.median(d)) / size,
                   truth_p90_rel=float(np.quantile(d, 0.9)) / size)
        # the cloud's own shape, whatever SfM's frame and self-calibration: a similarity
        # fitted to the surface (6 ICP rounds against 400 000 samples of it)
        from scipy.spatial import cKDTree

        from matching.sfm import umeyama
        from surface.metrics import sample_mesh

        samples = sample_mesh(vertices, triangles, 400_000)
        samples = samples[0] if isinstance(samples, tuple) else samples
        tree = cKDTree(samples)
        for _ in range(6):
            s2, R2, t2 = umeyama(moved, samples[tree.query(moved)[1]])
            moved = s2 * moved @ R2.T + t2
        d = point_mesh_distance(moved, vertices, triangles)
        out.update(truth_icp_median=float(np.median(d)), truth_icp_p90=float(np.quantile(d, 0.9)))
    print("  against the truth: " + " ".join(f"{k}={v:.4g}" for k, v in out.items()), flush=True)
    return out


def photos_main(args) -> int:
    """``--sceaux`` / ``--phone FOLDER``: ``photosurf run`` of a photo folder (the phone
    folder to the cloud, ``--to acquire`` unless ``--to`` says otherwise)."""
    import logging

    # the run's progress lines (SfM steps, each view pair) on stderr, as photosurf run -v
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    rows = []
    sceaux = DATA.parent / "sceaux_castle"
    if args.sceaux and sceaux.is_dir():
        rows.append(folder_run_main(args, "sceaux", sceaux))
    if args.phone:
        args.to = args.to or "acquire"
        rows.append(folder_run_main(args, "phone-" + Path(args.phone).name, Path(args.phone)))
    keys = ("views", "registered", "reprojection_px", "sfm_cpu_seconds", "sfm_peak_gb",
            "working_scale", "points", "cloud_cpu_seconds", "acquire_seconds",
            "acquire_peak_gb", "total_cpu_seconds", "total_peak_gb", "plane_rms_over_sigma",
            "plane_local_rms_over_sigma_median")
    print(f"{'folder':16s}" + "".join(f"{k[:11]:>12s}" for k in keys))
    for r in rows:
        print(f"{r['method'][:16]:16s}" + "".join(
            f"{r[k]:>12.4g}" if isinstance(r.get(k), int | float) else " " * 12 for k in keys))
        print(f"  {r['method']}: exit {r['exit']}, stages done {r.get('stages_done')}, "
              f"object selection kept {r['roi']}; load {r['load']}")
    goals = {}
    for r in rows:
        # an interrupted run (exit 143) has no acquire record: no goal is met by it
        goals[f"{r['method']}_all_views_registered"] = \
            r["exit"] == 0 and r["views"] > 0 and r["registered"] == r["views"]
        goals[f"{r['method']}_peak_le_6GB"] = r["exit"] == 0 and r["total_peak_gb"] <= 6.0
        if r["method"].startswith("phone"):
            goals[f"{r['method']}_le_3min_to_cloud"] = r.get("acquire_seconds", 1e9) <= 180.0
            goals[f"{r['method']}_le_3_cpu_min_to_cloud"] = \
                r.get("acquire_cpu_seconds", 1e9) <= 180.0
        else:
            goals[f"{r['method']}_surface"] = r.get("rendered") is not None
    print_goals(goals)
    write_result(args.json, {"benchmark": "real-photos", "rows": rows, "goals": goals})
    return 0
