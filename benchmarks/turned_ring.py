"""The temple ring with every image turned by a random quarter turn, its par file with it.

One run, side by side, on ``../shared/data/real/temple_sparse_ring`` (16 views, 640x480,
the data set's exact cameras in ``templeSR_par.txt``, which holds no image size):

* ``upright``  ``photosurf acquire`` of the ring as it is, ``--cameras templeSR_par.txt``;
* ``turned``   the same of a copy whose every image is turned by a seeded random quarter
  turn (``np.rot90``) and whose par file is turned with it
  (:func:`matching.cameras.turn_camera`): portrait views (480x640) among landscape ones.

Columns: views used, points, seconds; for ``turned`` the share of the upright ring's
points (goal >= 95 %) and the distance from each turned point to the upright cloud and
back (median and 90th percentile, mm) beside the upright cloud's own nearest-neighbour
spacing (the same surface within the matching noise: the distances are of the order of
the spacing, not of a wrong geometry's centimetres); both clouds' share inside every
view's silhouette (grey above 0.19 x 255, dilated by 3 px; SOURCE.md).

    .venv/bin/python benchmarks/turned_ring.py [--spacing N] [--seed S] [--json PATH]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from _common import print_goals, uptime, write_result  # noqa: E402

from matching.image_file import imread  # noqa: E402
from testkit.temple import turned_temple  # noqa: E402

DATA = ROOT.parent / "shared" / "data" / "real" / "temple_sparse_ring"
SILHOUETTE_GREY = 0.19 * 255


def acquire(folder: Path, out: Path, spacing: int) -> dict:
    """``photosurf acquire FOLDER --cameras FOLDER/templeSR_par.txt`` in this process."""
    from pipeline.cli import main
    from pipeline.cloud_io import read_ply

    start = time.perf_counter()
    said = io.StringIO()
    with contextlib.redirect_stdout(said):
        status = main(["acquire", str(folder), "--cameras", str(folder / "templeSR_par.txt"),
                       "--out", str(out), "--spacing", str(spacing), "-q"])
    if status != 0:
        raise SystemExit(f"acquire {folder}: exit {status}")
    with np.load(out.with_suffix(".npz")) as data:
        views = list(data["view_names"]) if "view_names" in data else []
    return {"points": read_ply(out).points, "views": len(views),
            "seconds": time.perf_counter() - start}


def in_silhouettes(points: np.ndarray, folder: Path) -> float:
    """Share of the points inside every view's silhouette (the par file's cameras)."""
    import cv2

    from matching.cameras import read_cameras
    from matching.masks import inside_masks

    images = {p.name: p for p in folder.glob("*.png")}
    cameras = read_cameras(folder / "templeSR_par.txt",
                           sizes={n: imread(p).shape[1::-1] for n, p in images.items()})
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (7, 7))
    masks = []
    for cam in cameras:
        grey = imread(images[cam.name], cv2.IMREAD_GRAYSCALE)
        masks.append(cv2.dilate((grey > SILHOUETTE_GREY).astype(np.uint8), kernel) > 0)
    return float(inside_masks(points, cameras, masks).mean())


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spacing", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", default=str(ROOT / "benchmarks" / "results" /
                                              "turned_ring.json"))
    args = parser.parse_args(argv)
    if not (DATA / "templeSR_par.txt").is_file():
        print(f"no data at {DATA}")
        return 2
    from scipy.spatial import cKDTree

    print(f"load before: {uptime()}")
    with tempfile.TemporaryDirectory(prefix="turned-ring-") as tmp:
        tmp = Path(tmp)
        turns = turned_temple(DATA, tmp / "turned", seed=args.seed)
        upright_dir = tmp / "upright"
        upright_dir.mkdir()
        for p in DATA.iterdir():
            if p.suffix in (".png", ".txt"):
                (upright_dir / p.name).symlink_to(p)
        upright = acquire(upright_dir, tmp / "upright.ply", args.spacing)
        turned = acquire(tmp / "turned", tmp / "turned.ply", args.spacing)
        a, b = upright["points"], turned["points"]
        spacing_mm = 1e3 * float(np.median(cKDTree(a).query(a, k=2)[0][:, 1]))
        to_upright = 1e3 * cKDTree(a).query(b)[0]
        to_turned = 1e3 * cKDTree(b).query(a)[0]
        rows = [
            {"method": "upright", "views": upright["views"], "points": len(a),
             "seconds": upright["seconds"], "in_silhouettes_3px": in_silhouettes(a, upright_dir),
             "nn_spacing_mm": spacing_mm},
            {"method": "turned", "views": turned["views"], "points": len(b),
             "seconds": turned["seconds"],
             "in_silhouettes_3px": in_silhouettes(b, tmp / "turned"),
             "share_of_upright": len(b) / max(len(a), 1),
             "to_upright_mm_median": float(np.median(to_upright)),
             "to_upright_mm_p90": float(np.percentile(to_upright, 90)),
             "from_upright_mm_median": float(np.median(to_turned)),
             "from_upright_mm_p90": float(np.percentile(to_turned, 90))},
        ]
    print(f"quarter turns (seed {args.seed}): {turns}")
    print(f"{'method':8} {'views':>5} {'points':>7} {'share':>6} {'in sil3':>7} "
          f"{'to up med/p90 mm':>17} {'from up med/p90':>16} {'s':>6}")
    for row in rows:
        share = f"{row.get('share_of_upright', 1.0):6.3f}"
        to = (f"{row['to_upright_mm_median']:.3f}/{row['to_upright_mm_p90']:.3f}"
              if "to_upright_mm_median" in row else f"(nn {row['nn_spacing_mm']:.3f})")
        back = (f"{row['from_upright_mm_median']:.3f}/{row['from_upright_mm_p90']:.3f}"
                if "from_upright_mm_median" in row else "")
        print(f"{row['method']:8} {row['views']:>5} {row['points']:>7} {share} "
              f"{row['in_silhouettes_3px']:7.4f} {to:>17} {back:>16} {row['seconds']:6.1f}")
    print(f"load after: {uptime()}")
    goals = {"turned: every view used": rows[1]["views"] == 16,
             "turned: >= 95 % of the upright ring's points": rows[1]["share_of_upright"] >= 0.95}
    print_goals(goals)
    write_result(args.json, {"spacing": args.spacing, "seed": args.seed, "turns": turns,
                             "rows": rows, "goals": goals})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
