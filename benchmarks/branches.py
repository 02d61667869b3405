"""Shapes that are not one tube: photosurf beside screened Poisson, same clouds.

Each procedural shape of ``testkit/shapes.py`` (torus, pants, mug, amphora, vase with an
opening; exact implicit truth, known genus) is sampled with isotropic Gaussian noise
(σ = ``testkit.shapes.SIGMA``) and reconstructed, in the same run, by

* ``stitched``        ``surface.reconstruct.surface_from_points`` (axis z, defaults);
* ``stitched+bezier`` the same mesh smoothed by Loop's G1 sextic Bézier patches
  (``surface.bezier.control_net`` + ``tessellate`` at the pipeline's level);
* ``poisson-8``       open3d's screened Poisson, depth 8, normals by PCA (30
  neighbours) oriented by ``orient_normals_consistent_tangent_plane``.

Scores: Chamfer (mean of the two mean distances: mesh samples to the implicit
surface by Newton projection, truth samples to the mesh), F-score at τ, closed /
components / genus (from the Euler characteristic of a closed oriented mesh).

Goals: every photosurf surface closed, one component, genus exact;
Chamfer ≤ Poisson-8's in no more time.

Usage::

    python benchmarks/branches.py [--quick] [--points 60000] [--json PATH]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from _common import print_goals, uptime, write_result  # noqa: E402

import surface.topology  # noqa: E402, F401  (imported before timing, as open3d is)
from pipeline.bezier_surface import default_level  # noqa: E402
from surface import bezier, metrics  # noqa: E402
from surface.reconstruct import surface_from_points  # noqa: E402
from testkit import shapes as _shapes  # noqa: E402

SEED = 14


def run_stitched(points):
    result = surface_from_points(points, axis="z")
    return {"vertices": result.vertices, "triangles": result.triangles,
            "branch_events": result.graph.branch_events() if result.graph else None,
            "messages": list(result.messages)}


def run_bezier(points):
    level = default_level()
    result = surface_from_points(points, axis="z")
    smooth = bezier.control_net(result.vertices, result.triangles)
    vertices, triangles, _ = bezier.tessellate(smooth, level=level)
    start = time.perf_counter()
    _, angle = bezier.edge_continuity(smooth.control_points, smooth.domain_mesh[1])
    return {"vertices": vertices, "triangles": triangles, "g1_angle": float(angle),
            "excluded_seconds": time.perf_counter() - start}


def run_poisson(points, depth=8):
    import open3d as o3d

    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(knn=30))
    cloud.orient_normals_consistent_tangent_plane(30)
    mesh, _ = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(cloud, depth=depth)
    return {"vertices": np.asarray(mesh.vertices, np.float64),
            "triangles": np.asarray(mesh.triangles, np.int64)}


METHODS = [("stitched", run_stitched), ("stitched+bezier", run_bezier),
           ("poisson-8", run_poisson)]


def evaluate(shape: str, name: str, method, points: np.ndarray, samples: int) -> dict:
    start = time.perf_counter()
    try:
        out = method(points)
    except ValueError as exc:  # a refusal is a result too
        return {"shape": shape, "method": name, "seconds": time.perf_counter() - start,
                "error": str(exc), "closed": False, "components": 0}
    seconds = time.perf_counter() - start - out.pop("excluded_seconds", 0.0)
    vertices, triangles = out.pop("vertices"), out.pop("triangles")
    topo = metrics.mesh_topology(vertices, triangles)
    genus = (1 - topo["euler"] // 2) if topo["closed"] and topo["components"] == 1 else None
    scores = _shapes.score(shape, vertices, triangles, count=samples, seed=SEED)
    return {"shape": shape, "method": name, "seconds": seconds, "triangles": len(triangles),
            "closed": bool(topo["closed"]), "oriented": bool(topo["oriented"]),
            "components": int(topo["components"]), "euler": int(topo["euler"]),
            "genus": genus, "genus_truth": _shapes.genus(shape),
            "chamfer": scores["chamfer"], "fscore": scores["fscore"],
            "hausdorff": scores["hausdorff"], **out}


def goals(rows: list[dict]) -> dict[str, bool]:
    out = {}
    by = {(r["shape"], r["method"]): r for r in rows}
    for shape in dict.fromkeys(r["shape"] for r in rows):
        p = by.get((shape, "poisson-8"))
        for name in ("stitched", "stitched+bezier"):
            r = by.get((shape, name))
            if r is None:
                continue
            out[f"{shape}_{name}_closed_one_component_genus"] = bool(
                r["closed"] and r["components"] == 1 and r.get("genus") == r.get("genus_truth"))
            if p is not None and "chamfer" in r:
                out[f"{shape}_{name}_chamfer_le_poisson8"] = bool(r["chamfer"] <= p["chamfer"])
                out[f"{shape}_{name}_time_le_poisson8"] = bool(r["seconds"] <= p["seconds"])
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="30 000 points, 3 shapes")
    parser.add_argument("--points", type=int, default=60_000)
    parser.add_argument("--json", default=str(ROOT / "benchmarks" / "results" / "branches.json"))
    parser.add_argument("--shapes", nargs="+", choices=list(_shapes.SHAPES))
    args = parser.parse_args(argv)
    points_count = 30_000 if args.quick else args.points
    shapes = args.shapes or (["torus", "mug", "amphora"] if args.quick else list(_shapes.SHAPES))
    samples = 20_000 if args.quick else 50_000
    print(f"branches: {points_count} points per shape, sigma = {_shapes.SIGMA}, "
          f"tau = {_shapes.TAU}, load {uptime()}")
    print(f"{'shape':8s} {'method':16s} {'seconds':>8s} {'Chamfer':>9s} {'F':>6s} "
          f"{'closed':>6s} {'comps':>5s} {'genus':>5s} {'truth':>5s}")
    rows = []
    for shape in shapes:
        cloud = _shapes.sample(shape, points_count, seed=SEED)
        for name, method in METHODS:
            row = evaluate(shape, name, method, cloud, samples)
            rows.append(row)
            if "error" in row:
                print(f"{shape:8s} {name:16s} {row['seconds']:8.2f}  refused: {row['error']}")
                continue
            print(f"{shape:8s} {name:16s} {row['seconds']:8.2f} {row['chamfer']:9.5f} "
                  f"{row['fscore']:6.3f} {'yes' if row['closed'] else 'no':>6s} "
                  f"{row['components']:5d} {str(row['genus']):>5s} {row['genus_truth']:5d}")
    verdict = goals(rows)
    print()
    print_goals(verdict)
    write_result(args.json, {"benchmark": "branches", "points": points_count,
                             "sigma": _shapes.SIGMA, "tau": _shapes.TAU, "rows": rows,
                             "goals": verdict})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
