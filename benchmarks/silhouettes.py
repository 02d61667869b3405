"""Silhouette consistency on and off, side by side in one process.

:func:`matching.multiview.reconstruct_multiview` with ``silhouettes=True`` (the default:
every point within :math:`\\sqrt2/2 + q\\,\\sigma f/z` px of each view's automatic
foreground, :func:`matching.masks.near_foreground`) against ``silhouettes=False`` on

* the rendered 320x240 vase ring (``fixtures/scenes/vase_ring_small.toml``, known
  cameras, no masks: what ``benchmarks/multiview.py --quick`` runs): points, RMS and
  median distance to the truth mesh, the 99th percentile and the largest distance;
* the real temple ring (``../shared/data/real/temple_sparse_ring``, given cameras,
  automatic masks, spacing 3: what ``benchmarks/real.py --quick --no-sfm`` runs):
  points, the shares of :func:`real.shares`, and the breakdown of the points outside a
  3 px silhouette (:func:`real.outside_breakdown`).

    .venv/bin/python benchmarks/silhouettes.py [--json PATH] [--scene DIR] [--no-temple]

Figures: benchmarks/README.md, *Real temple ring: what the points outside a 3 px
silhouette are*.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from _common import uptime, write_result  # noqa: E402


def _run(name: str, images, cameras, silhouettes: bool, **options) -> tuple[dict, object]:
    from matching.multiview import reconstruct_multiview

    load = uptime()
    start, cpu = time.perf_counter(), time.process_time()
    cloud = reconstruct_multiview(images, cameras, silhouettes=silhouettes, **options)
    return {"method": name, "points": len(cloud), "seconds": time.perf_counter() - start,
            "cpu_seconds": time.process_time() - cpu,
            "silhouette_rejected": cloud.stats["silhouette_rejected"],
            "silhouette_views": cloud.stats["silhouette_views"],
            "load_before": load, "load_after": uptime()}, cloud


def rendered_rows(scene: str | None) -> list[dict]:
    from multiview import _images

    from matching.cameras import read_cameras
    from pipeline.mesh_io import read_mesh
    from pipeline.scenes import render_scene
    from surface import metrics

    rows = []
    with tempfile.TemporaryDirectory(prefix="photosurf-sil-") as tmp:
        folder = Path(scene) if scene else Path(tmp) / "scene"
        if not scene:
            render_scene(ROOT / "fixtures" / "scenes" / "vase_ring_small.toml", folder,
                         progress=False)
        cameras = read_cameras(folder / "cameras.yml")
        images = _images(folder, cameras)
        truth = read_mesh(folder / "truth" / "mesh.ply")[:2]
        for on in (True, False):
            row, cloud = _run(f"vase-320 silhouettes={on}", images, cameras, on)
            d = metrics.point_mesh_distance(cloud.points, *truth)
            row.update(rms=float(np.sqrt(np.mean(d**2))), median=float(np.median(d)),
                       p99=float(np.quantile(d, 0.99)), max=float(d.max()))
            print(f"  {row['method']}: {row['points']} points, RMS {row['rms']:.6f}", flush=True)
            rows.append(row)
    return rows


def temple_rows() -> list[dict]:
    import real

    from matching.cameras import read_cameras
    from matching.masks import foreground_mask

    if not (real.DATA / "templeSR_par.txt").is_file():
        print(f"real data not found at {real.DATA}; temple rows skipped")
        return []
    cameras = read_cameras(real.DATA / "templeSR_par.txt")
    images = real._images(cameras)
    masks = [foreground_mask(img) for img in images]
    rows = []
    for on in (True, False):
        row, cloud = _run(f"temple silhouettes={on}", images, cameras, on, masks=masks,
                          spacing=3)
        row.update(real.shares(cloud.points, cameras, images))
        row["outside_3px"] = real.outside_breakdown(cloud.points, cloud.views, cameras, images)
        print(f"  {row['method']}: {row['points']} points, "
              f"silhouettes 3 px {row['in_silhouettes_3px']:.4f}", flush=True)
        rows.append(row)
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", default=str(ROOT / "benchmarks" / "results" /
                                              "silhouettes.json"))
    parser.add_argument("--scene", default=None, help="an already rendered vase_ring_small")
    parser.add_argument("--no-temple", action="store_true", help="the rendered ring only")
    parser.add_argument("--quick", action="store_true",
                        help="accepted (make bench): both runs are the quick variants already")
    args = parser.parse_args(argv)
    import open3d as o3d

    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    rows = rendered_rows(args.scene) + ([] if args.no_temple else temple_rows())
    print()
    cols = [("points", 8, "d"), ("silhouette_rejected", 8, "d"), ("rms", 10, ".6f"),
            ("median", 10, ".6f"), ("p99", 10, ".6f"), ("max", 10, ".6f"),
            ("in_silhouettes_3px", 8, ".4f"), ("in_silhouettes_5px", 8, ".4f"),
            ("in_outlines_3px", 8, ".4f"), ("seconds", 8, ".1f"), ("cpu_seconds", 8, ".1f")]
    heads = ["points", "sil rej", "RMS", "median", "p99", "max", "sil3", "sil5", "out3",
             "seconds", "CPU s"]
    print(f"{'method':26s}" + "".join(f"{h:>{w}s}" for h, (_, w, _) in zip(heads, cols,
                                                                            strict=True)))
    for r in rows:
        print(f"{r['method']:26s}" + "".join(
            f"{r[k]:>{w}{f}}" if isinstance(r.get(k), int | float) else " " * w
            for k, w, f in cols) + f"   load {r['load_before']} -> {r['load_after']}")
    write_result(args.json, {"benchmark": "silhouettes", "rows": rows})
    return 0


if __name__ == "__main__":
    sys.exit(main())
