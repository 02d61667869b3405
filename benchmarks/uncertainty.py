"""Coverage of the surface's 1σ along the normal (``surface.uncertainty``) on rendered scenes.

For each workspace of a rendered scene (``photosurf run RECIPE --out W``): the smooth
surface (``W/smooth``'s control net, tessellated at level 1 with exact normals; the
stitched mesh ``W/stitch/mesh.ply`` when there is no smooth surface yet), the
points, their σ and view pairs when recorded (``W/acquire/cloud.npz``), and the scene's truth mesh
(``W/scene/truth/mesh.ply``).  The true deviation of each surface point is its distance
to the truth mesh (open3d ray casting); the figures are the shares of points whose
deviation is within 1σ and 2σ (a Gaussian error: 68.3 % and 95.4 %), over all points,
over those the data cover and over those in a bridged gap or cap; and the σ's median
and 95th percentile beside the deviations'.  The row ``input_points`` is the input's own: each
point's distance to the truth mesh against its σ from the matcher.

Run: ``.venv/bin/python benchmarks/uncertainty.py W1 [W2 ...] [--json PATH]``
(default JSON ``benchmarks/results/uncertainty.json``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pipeline.artifacts import read_control_net  # noqa: E402
from pipeline.mesh_io import read_mesh, vertex_normals  # noqa: E402
from surface import bezier  # noqa: E402
from surface.uncertainty import normal_sigma  # noqa: E402


def _truth_distance(vertices: np.ndarray, truth: Path) -> np.ndarray:
    import open3d as o3d

    mesh = o3d.io.read_triangle_mesh(str(truth))
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    query = o3d.core.Tensor(vertices.astype(np.float32))
    return scene.compute_distance(query).numpy().astype(np.float64)


def _shares(deviation: np.ndarray, sigma: np.ndarray) -> dict:
    if len(deviation) == 0:
        return {"n": 0}
    return {"n": int(len(deviation)),
            "within_1sigma": float(np.mean(deviation <= sigma)),
            "within_2sigma": float(np.mean(deviation <= 2 * sigma)),
            "deviation_median": float(np.median(deviation)),
            "deviation_p95": float(np.percentile(deviation, 95)),
            "sigma_median": float(np.median(sigma)),
            "sigma_p95": float(np.percentile(sigma, 95))}


def workspace_row(workspace: Path, level: int = 1) -> dict:
    if (workspace / "smooth" / "control_net.npz").is_file():
        net = read_control_net(workspace / "smooth")
        vertices, triangles, normals = bezier.tessellate(net["control_points"], level,
                                                         net["domain_triangles"])
        surface = f"smooth, level {level}"
    else:  # --surface stitch, or a run stopped before smooth: the stitched mesh
        vertices, triangles = read_mesh(workspace / "stitch" / "mesh.ply")
        normals, surface = vertex_normals(vertices, triangles), "stitched mesh"
    with np.load(workspace / "acquire" / "cloud.npz") as cloud:
        points, sigma = cloud["points"], cloud["sigma"]
        source = cloud["source"] if "source" in cloud.files else None
    result = normal_sigma(vertices, normals, points, sigma, source=source)
    truth = workspace / "scene" / "truth" / "mesh.ply"
    deviation = _truth_distance(vertices, truth)
    point_error = _truth_distance(points, truth)
    covered = result.gap == 0
    return {"workspace": str(workspace), "surface": surface, "vertices": int(len(vertices)),
            "points": int(len(points)), "curvature": result.curvature,
            "view_pairs": source is not None,
            "all": _shares(deviation, result.sigma),
            "covered": _shares(deviation[covered], result.sigma[covered]),
            "bridged": _shares(deviation[~covered], result.sigma[~covered]),
            "propagated_only": _shares(deviation, result.propagated),
            "input_points": _shares(point_error, sigma)}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("workspaces", nargs="+")
    parser.add_argument("--json", default=str(Path(__file__).parent / "results"
                                              / "uncertainty.json"))
    args = parser.parse_args(argv)
    rows = [workspace_row(Path(w)) for w in args.workspaces]
    print(f"{'workspace':<24}{'part':<17}{'n':>8}{'<=1s':>7}{'<=2s':>7}{'dev med':>10}"
          f"{'dev p95':>10}{'sig med':>10}{'sig p95':>10}")
    for r in rows:
        print(f"{r['workspace']}: {r['surface']}, {r['vertices']} vertices, {r['points']} "
              f"points, curvature {r['curvature']:.3g}")
        for part in ("all", "covered", "bridged", "propagated_only", "input_points"):
            s = r[part]
            if not s["n"]:
                print(f"{Path(r['workspace']).name:<24}{part:<17}{0:>8}")
                continue
            print(f"{Path(r['workspace']).name:<24}{part:<17}{s['n']:>8}"
                  f"{100 * s['within_1sigma']:>6.1f}%{100 * s['within_2sigma']:>6.1f}%"
                  f"{s['deviation_median']:>10.2e}{s['deviation_p95']:>10.2e}"
                  f"{s['sigma_median']:>10.2e}{s['sigma_p95']:>10.2e}")
    out = Path(args.json)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(rows, indent=1))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
