"""Dense, noisy clouds: the stitched surface's ends and walls against the truth.

Where the noise reaches the point spacing (a dense photogrammetric or scanner cloud:
10⁷ points of the σ = 0.002 vase have a spacing of 0.0016) the PCA normals of the
slicing decide whether cap points are told from wall points.  For each cloud the table
gives the stitched surface (``surface.reconstruct.surface_from_points``) with the
normals' neighbours chosen from the noise (``reconstruct.normal_neighbours``, the
default) and with a fixed 12 (the rule before 2026-12-03): Chamfer distance to the
truth, the mean distance over the ends (z < 0.1 or z > 2.9) and over the walls between,
Hausdorff distance, closedness.  One seed per cloud; the vase r(z) = 1 + 0.3 sin 2z.

Run: ``.venv/bin/python benchmarks/noisy_ends.py [--json PATH]``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.append(str(ROOT / "benchmarks"))

from _common import uptime, write_result  # noqa: E402

from surface import metrics, section_slicing  # noqa: E402
from surface import reconstruct as rc  # noqa: E402
from testkit.vase import noisy_cloud, vase_truth  # noqa: E402

CLOUDS = [(100_000, 0.002), (100_000, 0.02), (30_000, 0.035)]
SAMPLES = 200_000


def _parts(points: np.ndarray, distances: np.ndarray) -> tuple[float, float]:
    ends = (points[:, 2] < 0.1) | (points[:, 2] > 2.9)
    return float(distances[ends].mean()), float(distances[~ends].mean())


def measure(points: np.ndarray, truth, neighbours: str) -> dict:
    real = section_slicing.normal_neighbours
    if neighbours == "12":
        section_slicing.normal_neighbours = lambda cloud: 12
    try:
        k = section_slicing.normal_neighbours(points)
        start = time.perf_counter()
        mesh = rc.surface_from_points(points, axis="z")
        seconds = time.perf_counter() - start
    finally:
        section_slicing.normal_neighbours = real
    on_mesh = metrics.sample_mesh(mesh.vertices, mesh.triangles, SAMPLES, seed=1)
    on_truth = metrics.sample_mesh(*truth, SAMPLES, seed=2)
    to_truth = metrics.point_mesh_distance(on_mesh, *truth)
    to_mesh = metrics.point_mesh_distance(on_truth, mesh.vertices, mesh.triangles)
    ends_a, walls_a = _parts(on_mesh, to_truth)
    ends_b, walls_b = _parts(on_truth, to_mesh)
    return {"neighbours": neighbours, "k": int(k), "seconds": seconds,
            "chamfer": float((to_truth.mean() + to_mesh.mean()) / 2),
            "ends": (ends_a + ends_b) / 2, "walls": (walls_a + walls_b) / 2,
            "hausdorff": float(max(to_truth.max(), to_mesh.max())), "closed": bool(mesh.closed)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", default=str(ROOT / "benchmarks" / "results" / "noisy_ends.json"))
    parser.add_argument("--quick", action="store_true", help="the same run (it is short)")
    args = parser.parse_args(argv)
    truth = vase_truth(n_theta=512, n_z=384)
    rows = []
    print(f"{'points':>8} {'sigma':>6} {'normals':>8} {'k':>4} {'Chamfer':>9} {'ends':>9} "
          f"{'walls':>9} {'Hausdorff':>9} closed {'s':>6}")
    for n, sigma in CLOUDS:
        points = noisy_cloud(*truth, n, seed=0, sigma=sigma)
        for neighbours in ("auto", "12"):
            row = {"points": n, "sigma": sigma, **measure(points, truth, neighbours)}
            rows.append(row)
            print(f"{n:>8} {sigma:>6} {neighbours:>8} {row['k']:>4} {row['chamfer']:>9.6f} "
                  f"{row['ends']:>9.6f} {row['walls']:>9.6f} {row['hausdorff']:>9.4f} "
                  f"{'yes' if row['closed'] else 'no':>6} {row['seconds']:>6.1f}", flush=True)
    write_result(args.json, {"benchmark": "noisy-ends", "samples": SAMPLES, "rows": rows,
                             "load": uptime()})
    return 0


if __name__ == "__main__":
    sys.exit(main())
