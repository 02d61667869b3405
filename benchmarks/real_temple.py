"""Real photographs all round an object: the Middlebury temple ring (16 views, 640x480).

One run, side by side, on ``../shared/data/real/temple_sparse_ring`` (the data set's
exact cameras in ``templeSR_par.txt``, a black cloth behind the object):

* ``photosurf``          :func:`matching.multiview.reconstruct_multiview` with the given
  cameras and the automatic foreground masks (:mod:`matching.masks`): points, share
  inside the data set's bounding box + 5 mm, share inside every view's silhouette (grey
  above 0.19 x 255, dilated by 3 px and by 5 px) and inside every view's outline (the
  silhouette with its enclosed holes filled, dilated by 3 px: see :func:`_silhouettes`)
  and inside every view's silhouette with its shadowed holes counted as object (``in shd3``:
  the enclosed holes brighter than the black cloth), and what the points outside a 3 px
  silhouette are (:func:`outside_breakdown`, printed under the table),
  pairs used / skipped (with reasons), the a-posteriori variance factor of the matches, seconds;
  the default second lattice (``densify="auto"``; ``densify`` in the JSON row: pairs and
  candidates it matched);
* ``photosurf-densify``  the same with the second lattice forced (``densify=True``);
* ``sgbm``               OpenCV's SGBM on the *same* rectified pairs with the same search
  ranges, every valid disparity triangulated in the rectified cameras and fused the
  same way (:func:`matching.multiview.merge_clouds`, visual hull of the same masks);
* ``pycolmap-sfm``       pycolmap's SfM of the folder without cameras (what
  ``photosurf run FOLDER`` does): registered views and the poses' errors against the
  given cameras after a similarity alignment (rotation median / max, centre RMS and as
  a share of the ring radius); its sparse points, aligned, as a peer cloud;
* ``pycolmap-sfm-K``     the same with the given intrinsics held fixed
  (:func:`matching.sfm.run_sfm` ``intrinsics``);
* ``...-lsm``            the same two runs with the tie points re-measured by LSM and
  bundle-adjusted again (``run_sfm(refine="lsm")``, :mod:`matching.sfm_refine`; the
  rows without it use ``refine="none"``);
* ``given-cams-BA``      the given cameras put into the ``-K-lsm`` tie points (after the
  similarity) and bundle-adjusted with K held: their errors are how far the tie points'
  reprojection minimum lies from the given cameras (the floor of the rows above);
* ``given-cams-held``    the given cameras held fixed on those tie points, only the points
  adjusted: the reprojection error the given cameras leave (beside the SfM's own), and
  the worst view's RMS and mean shift (is the reference exact at the tie points' σ?);
* ``sfm-K-lsm-noise``    the pose errors that the tie points' own noise explains: the
  ``-K-lsm`` model's observations replaced by their reprojections plus white noise of
  its adjustment's σ, re-adjusted, compared after a similarity (mean of 12 trials);
* ``photosurf-sfm``      photosurf's cloud with the ``pycolmap-sfm-K-lsm`` cameras, aligned.

Goals: >= 40 000 points with the given cameras, >= 99 % inside the box + 5 mm
and >= 99 % inside every silhouette; SfM: all 16 views, rotations within 0.1 degrees
and centres within 0.1 % of the ring radius.

    .venv/bin/python benchmarks/real.py [--quick] [--sfm-only | --no-sfm] [--json PATH]
                                        [--spacing N]

``--quick``: spacing 3 and no SfM-based cloud (the other rows as they are);
``--sfm-only``: the SfM rows only; ``--no-sfm``: the dense rows only.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from _common import print_goals, uptime, write_result  # noqa: E402
from _poses import pose_errors  # noqa: E402

from matching.cameras import read_cameras  # noqa: E402
from matching.image_file import imread  # noqa: E402

DATA = ROOT.parent / "shared" / "data" / "real" / "temple_sparse_ring"
BOX = np.array([[-0.073568, 0.021728, -0.012445], [0.028855, 0.181892, 0.062736]])
SILHOUETTE_GREY = 0.19 * 255


def _images(cameras) -> list:
    import cv2

    return [imread(str(DATA / c.name), cv2.IMREAD_UNCHANGED) for c in cameras]


def _silhouettes(images, dilate_px: int, outline: bool = False,
                 shadows: bool = False) -> list:
    """Grey above 0.19 x 255 (SOURCE.md's silhouette), dilated by ``dilate_px``.

    ``outline``: with every background region the silhouette encloses filled (only the
    background connected to the image border stays), i.e. the object's outline.  The
    threshold silhouette has holes wherever the plaster is in shadow (recesses, the
    cella behind the columns) as well as where the cloth shows between the columns; a
    correct point on a shadowed part projects into such a hole.  The two figures bound
    the truth: the plain silhouette counts the shadowed holes as background, the
    outline counts the see-through gaps as object.

    ``shadows``: the enclosed holes' pixels that are brighter than the black cloth --
    on the view's automatic foreground (:func:`matching.masks.foreground_mask` without
    dilation: above the background's own level, taken from the image border) -- count
    as object: plaster in shadow (grey 20-45, textured, against the cloth's 0-3) is
    object, a see-through gap to the black cloth stays background.
    """
    import cv2

    from matching.masks import foreground_mask

    side = 2 * dilate_px + 1
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (side, side))
    out = []
    for img in images:
        sil = (cv2.cvtColor(img, cv2.COLOR_BGR2GRAY) > SILHOUETTE_GREY).astype(np.uint8)
        if outline or shadows:
            outer = _outer_background(sil)
            if outline:
                sil = (~outer).astype(np.uint8)
            else:
                fg = foreground_mask(img, margin_px=0)
                if fg is not None:
                    sil = ((sil > 0) | (~outer & fg)).astype(np.uint8)
        out.append(cv2.dilate(sil, kernel) > 0)
    return out


def _outer_background(sil: np.ndarray) -> np.ndarray:
    """(H, W) bool: the background of a silhouette connected to the image border."""
    import cv2

    _, labels = cv2.connectedComponents((1 - sil).astype(np.uint8), connectivity=4)
    border = np.unique(np.r_[labels[0], labels[-1], labels[:, 0], labels[:, -1]])
    return np.isin(labels, border) & (sil == 0)


def _latitudes(cameras) -> np.ndarray | None:
    """(V,) gantry latitude of each view (``templeSR_ang.txt``), degrees, or None."""
    path = DATA / "templeSR_ang.txt"
    if not path.is_file():
        return None
    lat = {line.split()[2]: float(line.split()[0])
           for line in path.read_text().splitlines() if len(line.split()) == 3}
    return np.array([lat.get(c.name, np.nan) for c in cameras])


def outside_breakdown(points: np.ndarray, views: np.ndarray | None, cameras,
                      images) -> dict:
    """What the points outside a 3 px silhouette are: where, how far, in which views.

    For every (point, view) where the point projects outside that view's silhouette
    dilated by 3 px (``incidences``): in an enclosed hole of the silhouette whose pixel
    is on the automatic foreground (``hole_shadow``: plaster in shadow) or not
    (``hole_gap``: the black cloth between columns), outside the outline on the
    automatic foreground (``outer_dim``: a shadowed side, lit cloth beside the object)
    or not (``outer_black``); ``black_cloth``: incidences whose 3 x 3 px neighbourhood
    is darker than 6 grey levels (the clipped cloth; a bright edge's blur halo is 3-5
    grey levels at 3-4 px); ``distance_px``: the distance from the undilated silhouette
    (median, 90 %); ``other_latitude``: incidences in a view of a gantry latitude none
    of the point's matching views has, against ``other_latitude_base``, the share of
    all (point, view) projections that are such (the two latitudes' cameras sit
    ~1.25 px apart).  ``points_shadow_only``: points outside only in shadowed holes.
    """
    import cv2

    from matching.masks import foreground_mask, grey

    n, nv = len(points), len(cameras)
    fail = np.zeros((n, nv), bool)
    kinds = {k: np.zeros((n, nv), bool) for k in ("hole", "fg", "black")}
    dist = np.full((n, nv), np.nan)
    seen_in = np.zeros((n, nv), bool)
    for v, (cam, img) in enumerate(zip(cameras, images, strict=True)):
        g = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
        sil = (g > SILHOUETTE_GREY).astype(np.uint8)
        sil3 = cv2.dilate(sil, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (7, 7))) > 0
        outer = _outer_background(sil)
        fg = foreground_mask(img, margin_px=0)
        fg = np.zeros(g.shape, bool) if fg is None else fg
        black = cv2.dilate(grey(img, np.float32), np.ones((3, 3), np.uint8)) < 6
        d = cv2.distanceTransform(1 - sil, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
        x = np.rint(cam.project(points)).astype(np.int64)
        w, h = cam.size
        inside = (cam.depth(points) > 0) & (x[:, 0] >= 0) & (x[:, 0] < w) & (x[:, 1] >= 0) \
            & (x[:, 1] < h)
        i = np.flatnonzero(inside)
        xi, yi = x[i, 0], x[i, 1]
        seen_in[i, v] = True
        fail[i, v] = ~sil3[yi, xi]
        kinds["hole"][i, v] = ~outer[yi, xi]
        kinds["fg"][i, v] = fg[yi, xi]
        kinds["black"][i, v] = black[yi, xi]
        dist[i, v] = d[yi, xi]
    hole, fg = kinds["hole"], kinds["fg"]
    out = {"points_outside": int(fail.any(axis=1).sum()), "incidences": int(fail.sum()),
           "hole_shadow": int((fail & hole & fg).sum()),
           "hole_gap": int((fail & hole & ~fg).sum()),
           "outer_dim": int((fail & ~hole & fg).sum()),
           "outer_black": int((fail & ~hole & ~fg).sum()),
           "black_cloth": int((fail & kinds["black"]).sum()),
           "points_on_black_cloth": int((fail & kinds["black"]).any(axis=1).sum()),
           "points_shadow_only": int((fail.any(axis=1)
                                      & ~(fail & ~(hole & fg)).any(axis=1)).sum()),
           "distance_px": [float(q) for q in np.nanpercentile(dist[fail], [50, 90])]
           if fail.any() else [], "views": [int(c) for c in fail.sum(axis=0)]}
    lat = _latitudes(cameras)
    if views is not None and lat is not None and np.isfinite(lat).all():
        levels = np.unique(lat)
        has = np.stack([views[:, lat == lv].any(axis=1) for lv in levels], 1)  # (N, L)
        other = ~has[:, np.searchsorted(levels, lat)]  # (N, V): view's latitude unseen
        out["other_latitude"] = float((fail & other).sum() / max(fail.sum(), 1))
        out["other_latitude_base"] = float((seen_in & other).sum() / max(seen_in.sum(), 1))
    return out


def shares(points: np.ndarray, cameras, images) -> dict:
    """Share of the points inside the box + 5 mm, inside every silhouette and outline."""
    from matching.masks import inside_masks

    if len(points) == 0:
        return {"in_box": float("nan"), "in_silhouettes_3px": float("nan"),
                "in_silhouettes_5px": float("nan"), "in_outlines_3px": float("nan"),
                "in_silhouettes_3px_shadows": float("nan")}
    box = np.all((points >= BOX[0] - 0.005) & (points <= BOX[1] + 0.005), axis=1)
    out = {"in_box": float(box.mean())}
    for px in (3, 5):
        out[f"in_silhouettes_{px}px"] = float(
            inside_masks(points, cameras, _silhouettes(images, px)).mean())
    out["in_outlines_3px"] = float(
        inside_masks(points, cameras, _silhouettes(images, 3, outline=True)).mean())
    out["in_silhouettes_3px_shadows"] = float(
        inside_masks(points, cameras, _silhouettes(images, 3, shadows=True)).mean())
    return out


def run_photosurf(name: str, images, cameras, masks, spacing: int, reference=None,
                  similarity=None, **options) -> tuple[dict, object]:
    from matching.multiview import reconstruct_multiview

    start, cpu = time.perf_counter(), time.process_time()
    load = uptime()
    cloud = reconstruct_multiview(images, cameras, masks=masks, spacing=spacing, **options)
    seconds = time.perf_counter() - start
    points = cloud.points
    if similarity is not None:
        s, R, t = similarity
        points = s * points @ R.T + t
    st = cloud.stats
    row = {"method": name, "points": len(cloud), "seconds": seconds,
           "cpu_seconds": time.process_time() - cpu, "pairs": st["pairs"],
           "pairs_skipped": st["pairs_skipped"],
           "skipped": [f"{'-'.join(s['views'])}: {s['reason']}" for s in st["skipped"]],
           "search": st["search"], "variance_factor": st["variance_factor_median"],
           "further_view_offsets": st["further_view_offsets"],
           "densify": st.get("densify"), "reasons": cloud.reason_counts,
           "silhouette_rejected": st.get("silhouette_rejected"),
           "load_before": load, "load_after": uptime(),
           **shares(points, reference or cameras, images),
           "outside_3px": outside_breakdown(points, cloud.views, reference or cameras,
                                            images)}
    return row, cloud


def run_sgbm(images, cameras, masks, spacing: int) -> dict:
    """SGBM on photosurf's rectified pairs and ranges, triangulated and fused alike.

    Sampled on photosurf's candidate grid (one pixel per ``spacing`` x ``spacing`` cell
    of the rectified left image), so that the counts compare like with like.
    """
    import cv2

    from matching.masks import grey, inside_masks
    from matching.multiview import (
        _search_range,
        _search_volume,
        merge_clouds,
        rectify_pair,
        select_pairs,
    )
    from matching.rectify import rectify_images
    from matching.seeds import sgbm_disparity
    from matching.triangulate import triangulate_pair

    start = time.perf_counter()
    volume = _search_volume(cameras, masks, None)
    pairs = select_pairs(cameras)
    pts, src, views = [], [], []
    for p, (a, b) in enumerate(pairs):
        rect, cam_l, cam_r = rectify_pair(cameras[a], cameras[b])
        gl, gr = rectify_images(rect, grey(images[a]), grey(images[b]))
        dmin, count = _search_range(volume, cam_l, cam_r, gl, gr)
        disp = sgbm_disparity(gl, gr, dmin, count, block=5)
        m = masks[a] if masks[a] is not None else np.ones(cameras[a].size[::-1], bool)
        valid = cv2.remap(m.astype(np.float32), *rect.maps_left, cv2.INTER_NEAREST) > 0
        grid = np.zeros_like(valid)
        grid[::spacing, ::spacing] = True
        ys, xs = np.nonzero(np.isfinite(disp) & valid & grid)
        xl = np.column_stack([xs, ys]).astype(np.float64)
        xr = xl - np.column_stack([disp[ys, xs], np.zeros(len(xs))])
        tri = triangulate_pair(cam_l, cam_r, xl, xr, refine=False, reject_p=None)
        good = tri.valid
        pts.append(tri.points[good])
        src.append(np.full(int(good.sum()), p, np.int64))
        v = np.zeros((int(good.sum()), len(cameras)), bool)
        v[:, [a, b]] = True
        views.append(v)
    points = np.concatenate(pts)
    keep = inside_masks(points, cameras, masks)
    points, source, views = points[keep], np.concatenate(src)[keep], np.concatenate(views)[keep]
    merged = merge_clouds(points, np.ones(len(points)), views, source,
                          np.zeros((len(points), 3), np.uint8))
    return {"method": "sgbm", "points": len(merged["points"]),
            "seconds": time.perf_counter() - start, "pairs": len(pairs),
            **shares(merged["points"], cameras, images)}


def _given_poses(model_dir, reference):
    """The model's reconstruction moved onto the given cameras' frame (similarity by the
    centres) with every pose replaced by the given camera's."""
    import pycolmap

    from matching.cameras import cameras_from_pycolmap

    rec = pycolmap.Reconstruction(str(model_dir))
    _, (s, R, t) = pose_errors(cameras_from_pycolmap(rec), reference)
    rec.transform(pycolmap.Sim3d(s, pycolmap.Rotation3d(R), t))
    ref = {c.name: c for c in reference}
    for image in rec.images.values():
        c = ref[image.name]
        image.frame.rig_from_world = pycolmap.Rigid3d(pycolmap.Rotation3d(c.R), c.t)
    return rec


def _ba_options(poses: bool):
    import pycolmap

    options = pycolmap.BundleAdjustmentOptions()
    options.refine_focal_length = options.refine_extra_params = False
    options.refine_principal_point = False
    options.refine_rig_from_world = poses
    options.print_summary = False
    return options


def given_ba_row(model_dir, reference) -> dict:
    """The given cameras put into the refined tie points and bundle-adjusted (K held).

    How far the tie points move the given cameras is what the SfM's own pose errors
    against them can be expected to reach at best: a minimum of the reprojection
    error sits there, not at the given cameras.
    """
    from matching.cameras import cameras_from_pycolmap
    from matching.sfm_refine import bundle_adjust

    start = time.perf_counter()
    rec = _given_poses(model_dir, reference)
    bundle_adjust(rec, refine_intrinsics=False)
    cams = cameras_from_pycolmap(rec)
    errors, _ = pose_errors(cams, reference)
    return {"method": "given-cams-BA", "registered": len(cams), "views": len(reference),
            "reprojection_px": float(rec.compute_mean_reprojection_error()),
            "points": rec.num_points3D(), "seconds": time.perf_counter() - start, **errors}


def given_held_row(model_dir, reference) -> dict:
    """The tie points' reprojection error with the *given* cameras held fixed.

    Only the 3D points are adjusted, so what is left is how far the given cameras are
    from what the images measure: next to the SfM's own reprojection error it tells
    whether the reference itself is exact at the tie points' precision.  Per view: the
    RMS residual and the length of its mean (a systematic shift of the whole view).
    """
    import pycolmap

    from matching.sfm import _quiet_colmap

    rec = _given_poses(model_dir, reference)
    with _quiet_colmap():
        pycolmap.bundle_adjustment(rec, _ba_options(poses=False))
    rms, shift = [], []
    for image in rec.images.values():
        res = np.array([np.asarray(image.project_point(rec.points3D[p.point3D_id].xyz))
                        - np.asarray(p.xy) for p in image.points2D if p.has_point3D()])
        if len(res):
            rms.append(float(np.sqrt((res ** 2).sum(axis=1).mean())))
            shift.append(float(np.linalg.norm(res.mean(axis=0))))
    return {"method": "given-cams-held", "registered": rec.num_reg_images(),
            "views": len(reference), "points": rec.num_points3D(),
            "reprojection_px": float(rec.compute_mean_reprojection_error()),
            "view_rms_max_px": max(rms, default=float("nan")),
            "view_shift_max_px": max(shift, default=float("nan"))}


def precision_row(model_dir, sigma_px: float, trials: int = 12, seed: int = 0) -> dict:
    """Pose precision the tie points support, by simulation (Monte Carlo).

    Every observation of the adjusted model is replaced by its own reprojection plus
    white noise of the adjustment's σ (``sigma_px``), the poses and points adjusted
    again (K held) and compared with the noise-free poses after a similarity, as the
    SfM rows are compared with the given cameras: the spread of the rows' errors that
    noise alone explains.
    """
    import pycolmap

    from matching.cameras import cameras_from_pycolmap
    from matching.sfm import _quiet_colmap

    clean = pycolmap.Reconstruction(str(model_dir))
    reference = cameras_from_pycolmap(clean)
    rng = np.random.default_rng(seed)
    rows = []
    for _ in range(trials):
        rec = pycolmap.Reconstruction(clean)
        for point in rec.points3D.values():
            for element in point.track.elements:
                image = rec.images[element.image_id]
                image.points2D[element.point2D_idx].xy = (
                    np.asarray(image.project_point(point.xyz)) + rng.normal(0.0, sigma_px, 2))
        with _quiet_colmap():
            pycolmap.bundle_adjustment(rec, _ba_options(poses=True))
        rows.append(pose_errors(cameras_from_pycolmap(rec), reference)[0])
    # (centre_rms_mm is in the model's own scale here: only the share of the radius is kept)
    mean = {key: float(np.mean([r[key] for r in rows])) for key in rows[0]
            if key != "centre_rms_mm"}
    return {"method": "sfm-K-lsm-noise", "registered": clean.num_reg_images(),
            "views": clean.num_reg_images(), "reprojection_px": sigma_px,
            "trials": trials, **mean,
            "rot_max_deg_worst": float(max(r["rot_max_deg"] for r in rows))}


def run_sfm_row(name: str, reference, images, intrinsics=None,
                refine: str = "none", given_ba: bool = False) -> tuple[dict, object, tuple]:
    from matching.sfm import run_sfm

    start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="photosurf-real-sfm-") as tmp:
        result = run_sfm(DATA, work_dir=tmp, image_names=[c.name for c in reference],
                         intrinsics=intrinsics, refine=refine)
        seconds = time.perf_counter() - start
        extra = None
        if given_ba and refine == "lsm":
            model = Path(tmp) / "sparse_refined"
            extra = [given_ba_row(model, reference), given_held_row(model, reference),
                     precision_row(model, float(result.refinement.get("ba_sigma_px", 0.05)))]
    ref = {c.name: c for c in reference}
    cams = [c for c in result.cameras if c.name in ref]
    row = {"method": name, "registered": len(cams), "views": len(reference),
           "seconds": seconds, "reprojection_px": result.mean_reprojection_error_px,
           "refinement": result.refinement}
    if extra is not None:
        row["given_ba"] = extra
    if len(cams) < 3:
        return row, result, None
    errors, (s, R, t) = pose_errors(cams, reference)
    sparse = s * result.points @ R.T + t
    row.update(**errors, points=len(sparse), **shares(sparse, reference, images))
    return row, result, (s, R, t)


COLUMNS = [("points", 8, "d"), ("in_box", 8, ".4f"), ("in_silhouettes_3px", 9, ".4f"),
           ("in_silhouettes_5px", 9, ".4f"), ("in_outlines_3px", 9, ".4f"),
           ("in_silhouettes_3px_shadows", 9, ".4f"),
           ("pairs", 6, "d"), ("pairs_skipped", 5, "d"),
           ("registered", 5, "d"), ("rot_median_deg", 8, ".3f"), ("rot_max_deg", 8, ".3f"),
           ("centre_rms_mm", 8, ".2f"), ("centre_rms_pct_radius", 8, ".3f"),
           ("reprojection_px", 8, ".3f"), ("view_rms_max_px", 8, ".3f"), ("seconds", 8, ".1f")]


def print_table(rows: list[dict]) -> None:
    heads = ["points", "in box", "in sil3", "in sil5", "in out3", "in shd3", "pairs", "skip",
             "reg", "rot med",
             "rot max", "C mm", "C %r", "rep px", "view px", "seconds"]
    print(f"{'method':19s}" + "".join(f"{h:>{w}s}" for h, (_, w, _) in zip(heads, COLUMNS,
                                                                           strict=True)))
    for r in rows:
        cells = []
        for key, width, fmt in COLUMNS:
            v = r.get(key)
            cells.append(f"{v:>{width}{fmt}}" if isinstance(v, int | float) else " " * width)
        print(f"{r['method']:19s}" + "".join(cells))
    for r in rows:
        for line in r.get("skipped", []):
            print(f"  {r['method']}: skipped {line}")
    for r in rows:
        b = r.get("outside_3px")
        if b:
            print(f"  {r['method']}: outside a 3 px silhouette {b['points_outside']} points "
                  f"({b['points_shadow_only']} only in shadowed holes, "
                  f"{b['points_on_black_cloth']} somewhere on the black cloth); "
                  f"{b['incidences']} (point, view): hole shadow {b['hole_shadow']}, hole gap "
                  f"{b['hole_gap']}, outer dim {b['outer_dim']}, outer black "
                  f"{b['outer_black']}; distance median / 90 % "
                  + (" / ".join(f"{q:.1f}" for q in b['distance_px']) or "-") + " px"
                  + (f"; other latitude {100 * b['other_latitude']:.0f} % "
                     f"(base {100 * b['other_latitude_base']:.0f} %)"
                     if "other_latitude" in b else ""))


def temple_main(args) -> int:
    """The temple rows (the default of ``benchmarks/real.py``): the clouds on the given
    cameras beside SGBM's, the SfM rows, the goals; the JSON at ``args.json``."""
    if not (DATA / "templeSR_par.txt").is_file():
        print(f"real data not found at {DATA}; nothing to measure")
        return 0
    from matching.masks import foreground_mask

    spacing = args.spacing or (3 if args.quick else 2)
    cameras = read_cameras(DATA / "templeSR_par.txt")
    images = _images(cameras)
    masks = [foreground_mask(img) for img in images]
    print(f"{len(cameras)} views {cameras[0].size[0]}x{cameras[0].size[1]}; automatic masks "
          f"for {sum(m is not None for m in masks)}; spacing {spacing}", flush=True)
    rows = []
    if not args.sfm_only:
        known, cloud = run_photosurf("photosurf", images, cameras, masks, spacing)
        print(f"  photosurf: {known['points']} points in {known['seconds']:.1f} s", flush=True)
        # the default is densify="auto" (the second lattice where the first falls short);
        # True: the second lattice wherever its four neighbours were accepted
        dense, _ = run_photosurf("photosurf-densify", images, cameras, masks, spacing,
                                 densify=True)
        print(f"  photosurf-densify: {dense['points']} points in {dense['seconds']:.1f} s",
              flush=True)
        sgbm = run_sgbm(images, cameras, masks, spacing)
        print(f"  sgbm: {sgbm['points']} points in {sgbm['seconds']:.1f} s", flush=True)
        rows += [known, dense, sgbm]
    sfm_rows, sim_k = [], None
    sfm_runs = () if args.no_sfm else (
        ("pycolmap-sfm", None, "none"), ("pycolmap-sfm-lsm", None, "lsm"),
        ("pycolmap-sfm-K", cameras[0].K, "none"), ("pycolmap-sfm-K-lsm", cameras[0].K, "lsm"))
    for name, K, refine in sfm_runs:
        row, result, sim = run_sfm_row(name, cameras, images, intrinsics=K, refine=refine,
                                       given_ba=K is not None)
        print(f"  {name}: {row['registered']} views in {row['seconds']:.1f} s", flush=True)
        sfm_rows.append(row)
        if "given_ba" in row:
            sfm_rows.extend(row.pop("given_ba"))
        if name == "pycolmap-sfm-K-lsm":
            result_k, sim_k = result, sim
    rows += sfm_rows
    if not args.quick and not args.sfm_only and sim_k is not None:
        by_name = {c.name: c for c in result_k.cameras}
        idx = [v for v, c in enumerate(cameras) if c.name in by_name]
        with_sfm, _ = run_photosurf("photosurf-sfm", [images[v] for v in idx],
                                    [by_name[cameras[v].name] for v in idx],
                                    [masks[v] for v in idx], spacing, similarity=sim_k,
                                    reference=[cameras[v] for v in idx])
        rows.append(with_sfm)
    print()
    print_table(rows)
    goals = {}
    if not args.sfm_only:
        for row, suffix in ((known, ""), (dense, "_densify")):
            goals.update({
                f"points_ge_40000{suffix}": row["points"] >= 40_000,
                f"in_box_ge_99pct{suffix}": row["in_box"] >= 0.99,
                f"in_silhouettes_3px_ge_99pct{suffix}": row["in_silhouettes_3px"] >= 0.99,
                f"in_silhouettes_5px_ge_99pct{suffix}": row["in_silhouettes_5px"] >= 0.99,
                f"in_outlines_3px_ge_99pct{suffix}": row["in_outlines_3px"] >= 0.99,
                f"in_silhouettes_3px_shadows_ge_99pct{suffix}":
                    row["in_silhouettes_3px_shadows"] >= 0.99,
            })
    sfm_rows = [r for r in sfm_rows if r["method"] in
                ("pycolmap-sfm", "pycolmap-sfm-lsm", "pycolmap-sfm-K", "pycolmap-sfm-K-lsm")]
    goals.update({} if args.no_sfm else {
        "sfm_all_views": max(r["registered"] for r in sfm_rows) == len(cameras),
        "sfm_rotations_le_0.1deg": min(r.get("rot_max_deg", np.inf) for r in sfm_rows) <= 0.1,
        "sfm_centres_le_0.1pct_radius": min(r.get("centre_rms_pct_radius", np.inf)
                                            for r in sfm_rows) <= 0.1,
    })
    print()
    print_goals(goals)
    write_result(args.json, {"benchmark": "real", "data": "temple_sparse_ring",
                             "views": len(cameras), "spacing": spacing,
                             "quick": bool(args.quick), "rows": rows, "goals": goals})
    return 0
