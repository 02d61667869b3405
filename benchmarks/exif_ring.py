"""A rendered ring whose JPEG copies are stored sideways with EXIF orientation tags.

One run, side by side, on ``fixtures/scenes/vase_ring_small.toml`` (24 views, 320x240,
its exact cameras in ``cameras.yml``, its truth mesh):

* ``png``          ``photosurf acquire`` of the rendered upright PNGs;
* ``jpeg``         the same of upright JPEG copies (quality 95, no tag): what JPEG loss
  alone does;
* ``jpeg-exif``    JPEG copies (quality 95) stored sideways, view ``v`` under EXIF
  orientation ``1 + (3 v + 5) mod 8`` (every value), the pixels turned so that a viewer
  shows the upright view; the same ``cameras.yml`` (the upright images' cameras);
* ``png-sfm``, ``jpeg-sfm``, ``jpeg-exif-sfm``  the same three folders without cameras:
  pycolmap SfM (:func:`matching.sfm.run_sfm`; the tagged images given to it as upright
  copies), the cloud aligned to the truth frame by the similarity of its cameras'
  centres to the true ones.  SfM's self-calibration on this ring is poor whatever the
  orientation (one run: 6-24 views registered, the clouds 0.12-0.15 from the truth for
  all three; pycolmap's focal length 419-539 px where the truth is 416): these rows show
  the tagged folder goes through SfM, not that orientation is neutral there -- the
  given-camera rows and ``tests/matching/test_image_file.py`` do that.

Columns: views used, points, distance of the points to the truth mesh (median, 90th
percentile, scene units: the vase's radius is 0.7-1.3), and for each JPEG
row the median distance to the ``png`` cloud's nearest point.  Goal: ``jpeg-exif``
within the ``jpeg`` row's noise (the same cloud up to JPEG loss).

    .venv/bin/python benchmarks/exif_ring.py [--spacing N] [--json PATH]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from _common import print_goals, uptime, write_result  # noqa: E402

from matching.image_file import imread  # noqa: E402
from testkit.images import exif_jpeg  # noqa: E402
from testkit.images import stored_for as _stored_for  # noqa: E402

SCENE = ROOT / "fixtures" / "scenes" / "vase_ring_small.toml"


def acquire(folder: Path, out: Path, spacing: int) -> tuple[np.ndarray, int, float, object]:
    """``photosurf acquire FOLDER`` in this process: points, views used, seconds, and
    the cameras it wrote beside the cloud (SfM's; None when a camera file gave them)."""
    from matching.cameras import read_cameras
    from pipeline.cli import main
    from pipeline.cloud_io import read_ply

    start = time.perf_counter()
    with contextlib.redirect_stdout(io.StringIO()):
        status = main(["acquire", str(folder), "--out", str(out), "--spacing", str(spacing),
                       "-q"])
    if status != 0:
        raise SystemExit(f"acquire {folder}: exit {status}")
    seconds = time.perf_counter() - start
    with np.load(out.with_suffix(".npz")) as data:
        views = len(data["view_names"])
    written = out.with_suffix(".cameras.yml")  # the cameras SfM found (none when given)
    cameras = read_cameras(written) if written.is_file() else None
    return read_ply(out).points, views, seconds, cameras


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spacing", type=int, default=4)
    parser.add_argument("--json", default=str(ROOT / "benchmarks" / "results" /
                                              "exif_ring.json"))
    args = parser.parse_args(argv)
    import cv2

    from matching.cameras import read_cameras, write_cameras_yml
    from matching.sfm import umeyama
    from pipeline.mesh_io import read_mesh
    from pipeline.scenes import render_scene
    from surface.metrics import point_cloud_distance, point_mesh_distance

    print(f"load before: {uptime()}")
    rows = []
    with tempfile.TemporaryDirectory(prefix="exif-ring-") as tmp:
        tmp = Path(tmp)
        render_scene(SCENE, tmp / "scene", progress=False)
        truth = read_mesh(tmp / "scene" / "truth" / "mesh.ply")
        cameras = read_cameras(tmp / "scene" / "cameras.yml")
        folders = {name: tmp / name for name in ("png", "jpeg", "jpeg-exif", "png-sfm",
                                                   "jpeg-sfm", "jpeg-exif-sfm")}
        for folder in folders.values():
            folder.mkdir()
        renamed = []
        for v, cam in enumerate(cameras):
            image = imread(tmp / "scene" / "images" / cam.name)
            shutil.copy(tmp / "scene" / "images" / cam.name, folders["png"] / cam.name)
            shutil.copy(tmp / "scene" / "images" / cam.name, folders["png-sfm"] / cam.name)
            stem = Path(cam.name).stem
            ok, plain = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 95])
            (folders["jpeg"] / f"{stem}.jpg").write_bytes(plain.tobytes())
            (folders["jpeg-sfm"] / f"{stem}.jpg").write_bytes(plain.tobytes())
            orientation = 1 + (3 * v + 5) % 8
            tagged = exif_jpeg(_stored_for(image, orientation), orientation)
            (folders["jpeg-exif"] / f"{stem}.jpg").write_bytes(tagged)
            (folders["jpeg-exif-sfm"] / f"{stem}.jpg").write_bytes(tagged)
            renamed.append(cam.__class__(cam.K, cam.dist, cam.R, cam.t, cam.width, cam.height,
                                         f"{stem}.jpg"))
        write_cameras_yml(folders["png"] / "cameras.yml", cameras)
        write_cameras_yml(folders["jpeg"] / "cameras.yml", renamed)
        write_cameras_yml(folders["jpeg-exif"] / "cameras.yml", renamed)
        reference = None
        truth_centres = {Path(c.name).stem: c.center for c in cameras}
        for name, folder in folders.items():
            points, views, seconds, used = acquire(folder, tmp / f"{name}.ply", args.spacing)
            if name.endswith("-sfm"):  # SfM's frame -> the truth's, by the camera centres
                src = np.array([c.center for c in used])
                dst = np.array([truth_centres[Path(c.name).stem] for c in used])
                s, R, t = umeyama(src, dst, True)
                points = s * points @ R.T + t
            to_truth = point_mesh_distance(points, *truth)
            row = {"method": name, "views": views, "points": len(points), "seconds": seconds,
                   "truth_median": float(np.median(to_truth)),
                   "truth_p90": float(np.percentile(to_truth, 90))}
            if reference is None:
                reference = points
            else:
                row["to_png_median"] = float(np.median(point_cloud_distance(points, reference)))
            rows.append(row)
    print(f"{'method':14} {'views':>5} {'points':>7} {'truth med':>10} {'truth p90':>10} "
          f"{'to png med':>10} {'s':>6}")
    for row in rows:
        print(f"{row['method']:14} {row['views']:>5} {row['points']:>7} "
              f"{row['truth_median']:10.5f} {row['truth_p90']:10.5f} "
              f"{row.get('to_png_median', float('nan')):10.5f} {row['seconds']:6.1f}")
    print(f"load after: {uptime()}")
    by = {row["method"]: row for row in rows}
    goals = {
        "jpeg-exif: every view used": by["jpeg-exif"]["views"] == len(cameras),
        "jpeg-exif: points within 5 % of the untagged jpeg's":
            abs(by["jpeg-exif"]["points"] / by["jpeg"]["points"] - 1) <= 0.05,
        "jpeg-exif: truth p90 within 10 % of the untagged jpeg's":
            by["jpeg-exif"]["truth_p90"] <= 1.1 * by["jpeg"]["truth_p90"],
    }
    print_goals(goals)
    write_result(args.json, {"spacing": args.spacing, "rows": rows, "goals": goals})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
