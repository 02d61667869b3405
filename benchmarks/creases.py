"""Creases interpolated or kept (``surface.interpolation.INTERPOLATE_CREASES``), side by side.

The smooth surface passes through the vertices of the object's ridges inside its end
sections (``surface.sizing.crease_vertices``, 2026-12-06); before, every vertex on an edge
sharper than 30° was kept as it is, and Loop's limit rounded the edge inwards.  Both rules
in one process on the same data:

* the procedural shapes of ``testkit/shapes.py`` (30 000 points, σ = ``_shapes.SIGMA``,
  seeds 0 and 1): ``pipeline.section_surface.sized_mesh``, Loop's surface through the sized
  mesh, adaptive tessellation; patches, crease vertices, Chamfer to the implicit truth;
* with ``--workspace W`` (a ``photosurf run`` of ``../shared/data/real/temple_sparse_ring``
  with its cameras): the smooth stage rerun on a copy of W under each rule, sized and with
  ``smooth.size=false``; patches and the silhouettes' IoU per view (grey above 0.19 x 255)
  against the stitched mesh's.

    .venv/bin/python benchmarks/creases.py [--workspace W] [--shapes NAME ...] [--quick]
                                           [--json PATH]
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from _common import uptime, write_result  # noqa: E402

from matching.image_file import imread  # noqa: E402
from pipeline.section_surface import sized_mesh  # noqa: E402
from surface import bezier, interpolation, sizing  # noqa: E402
from testkit import shapes as _shapes  # noqa: E402

SEEDS = (0, 1)
POINTS = 30_000


def shape_row(shape: str, seed: int) -> dict:
    """One cloud under both rules."""
    points = _shapes.sample(shape, POINTS, seed=seed)
    row = {"shape": shape, "seed": seed}
    for label, on in (("kept", False), ("interpolated", True)):
        interpolation.INTERPOLATE_CREASES = on
        try:
            sized, _ = sized_mesh(points, axis="z")
        except ValueError as exc:   # a refusal is a result too
            row[label] = {"error": str(exc)}
            continue
        control = sizing.interpolating_control(sized.vertices, sized.triangles, sized.creases)
        surface = bezier.control_net(control, sized.triangles)
        vertices, triangles, _ = bezier.tessellate_adaptive(surface, sized.chord_tolerance())
        score = _shapes.score(shape, vertices, triangles, count=20_000, seed=14)
        row[label] = {"patches": len(surface.control_points),
                      "creases": 0 if sized.creases is None else int(sized.creases.sum()),
                      "chamfer": score["chamfer"]}
    interpolation.INTERPOLATE_CREASES = True
    if "chamfer" in row["kept"] and "chamfer" in row["interpolated"]:
        row["chamfer_ratio"] = row["interpolated"]["chamfer"] / row["kept"]["chamfer"]
    return row


def temple_rows(workspace: Path) -> dict:
    """The smooth stage of ``workspace`` under both rules, against the silhouettes."""
    import cv2
    from real import DATA, SILHOUETTE_GREY

    from matching.cameras import read_cameras
    from pipeline import cli
    from pipeline.mesh_io import read_mesh
    from surface.metrics import silhouette_scores

    cameras = read_cameras(DATA / "templeSR_par.txt")
    silhouettes = [imread(str(DATA / cam.name), cv2.IMREAD_GRAYSCALE) > SILHOUETTE_GREY
                   for cam in cameras]

    def iou(path: Path) -> np.ndarray:
        return np.asarray(silhouette_scores(*read_mesh(path), cameras, silhouettes)["iou"])

    stitched = iou(workspace / "stitch" / "mesh.ply")
    out = {"stitched_iou": stitched.tolist()}
    runs = [(f"{label}{suffix}", on, extra) for suffix, extra in (("", []), (
        " unsized", ["--set", "smooth.size=false"])) for label, on in (("kept", False),
                                                                         ("interpolated", True))]
    for label, on, extra in runs:
        interpolation.INTERPOLATE_CREASES = on
        with tempfile.TemporaryDirectory() as scratch:
            copy = Path(scratch) / "w"
            shutil.copytree(workspace, copy)
            if cli.main(["run", str(DATA), "--cameras", str(DATA / "templeSR_par.txt"),
                         "--out", str(copy), "--from", "smooth", "--to", "smooth", "--force",
                         "-q", *extra]) != 0:
                raise SystemExit("the smooth stage failed")
            info = json.loads((copy / "manifest.json").read_text())["stages"]["smooth"]["info"]
            values = iou(copy / "smooth" / "surface.ply")
        out[label] = {"patches": info["patches"], "iou": values.tolist(),
                      "iou_min": float(values.min()), "iou_median": float(np.median(values)),
                      "mean_over_stitched": float(np.mean(values - stitched))}
    interpolation.INTERPOLATE_CREASES = True
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workspace", help="a photosurf run of the temple with its cameras")
    parser.add_argument("--shapes", nargs="*", choices=list(_shapes.SHAPES),
                        default=list(_shapes.SHAPES))
    parser.add_argument("--quick", action="store_true", help="seed 0 only")
    parser.add_argument("--json", default=str(ROOT / "benchmarks" / "results" / "creases.json"))
    args = parser.parse_args(argv)
    print(f"creases kept / interpolated; load {uptime()}")
    print(f"{'shape':<9s}{'seed':>5s}{'patches':>16s}{'creases':>9s}{'Chamfer kept':>14s}"
          f"{'interp.':>10s}{'ratio':>7s}")
    rows = []
    for shape in args.shapes:
        for seed in SEEDS[:1] if args.quick else SEEDS:
            row = shape_row(shape, seed)
            rows.append(row)
            a, b = row["kept"], row["interpolated"]
            if "chamfer_ratio" not in row:
                print(f"{shape:<9s}{seed:5d}  refused: {a.get('error') or b.get('error')}")
                continue
            print(f"{shape:<9s}{seed:5d}{a['patches']:8d}{b['patches']:8d}{b['creases']:9d}"
                  f"{a['chamfer']:14.6f}{b['chamfer']:10.6f}{row['chamfer_ratio']:7.3f}",
                  flush=True)
    result = {"benchmark": "creases", "points": POINTS, "rows": rows, "load": uptime()}
    if args.workspace:
        temple = temple_rows(Path(args.workspace))
        result["temple"] = temple
        for label in ("kept", "interpolated", "kept unsized", "interpolated unsized"):
            t = temple[label]
            print(f"temple {label:<21s}{t['patches']:8d} patches, IoU min / median "
                  f"{t['iou_min']:.4f} / {t['iou_median']:.4f}, mean over the stitched mesh "
                  f"{t['mean_over_stitched']:+.4f}")
    write_result(args.json, result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
