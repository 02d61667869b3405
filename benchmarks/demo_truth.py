"""A rendered demo workspace against its truth: where the distance is, and the rings' errors.

For a workspace made by ``photosurf run fixtures/scenes/vase_ring.toml --out W`` (any
rendered scene whose truth is a surface of revolution about z standing on z = 0), two
tables:

* **Distance by region** -- the smooth surface (``smooth/surface.ply``, the exported
  tessellation) and the stitched mesh (``stitch/mesh.ply``) against the truth
  (``scene/truth/mesh.ply``), 200 000 area samples each way: the mean distance over the
  walls, the two rims (within 0.02 of the ends) and the two caps (within 0.002 of the
  end planes, inside the rims), and each region's share of the Chamfer distance.
* **The rings' variogram** -- ``surface.sizing.section_variogram`` of the curves stage's
  rings, the sizing's measure of the rings' errors across sections, beside the same
  variogram from the rings' signed distances to the truth (the end five sections left
  out): γ(k) at lags 1, 2, 4, 8, 12 and the sill, as RMS (√γ).
* **The ends** -- the stitched mesh's lowest and highest point along z against the truth's
  (``surface.reconstruct.extend_to_caps``: where an open end's rings were moved, the rim
  line or the quantile rule; positive = past the truth's end).

Run: ``.venv/bin/python benchmarks/demo_truth.py [W] [--json PATH]`` (W: default ``out``, the
``make demo`` workspace; ``make bench`` runs it so, and says so when there is none).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.append(str(ROOT / "benchmarks"))

from _common import uptime, write_result  # noqa: E402

from pipeline import artifacts  # noqa: E402
from pipeline.mesh_io import read_mesh  # noqa: E402
from surface import metrics, ring_resample, section_chains, sizing  # noqa: E402

SAMPLES = 200_000
LAGS = (1, 2, 4, 8, 12)
REGIONS = ("wall", "bottom-rim", "top-rim", "bottom-cap", "top-cap")


def regions(points: np.ndarray, z0: float, z1: float, cap_radius: tuple) -> np.ndarray:
    z, r = points[:, 2], np.hypot(points[:, 0], points[:, 1])
    label = np.full(len(points), "wall", dtype=object)
    label[z < z0 + 0.02] = "bottom-rim"
    label[z > z1 - 0.02] = "top-rim"
    label[(z < z0 + 0.002) & (r < cap_radius[0])] = "bottom-cap"
    label[(z > z1 - 0.002) & (r < cap_radius[1])] = "top-cap"
    return label


def by_region(vertices, triangles, truth) -> dict:
    tv, tt = truth
    z0, z1 = float(tv[:, 2].min()), float(tv[:, 2].max())
    r = np.hypot(tv[:, 0], tv[:, 1])
    # the caps inside their rims: 95 % of the rim radius at each end plane
    cap_radius = tuple(0.95 * float(r[np.abs(tv[:, 2] - z) < 1e-6].max()) for z in (z0, z1))
    truth_samples = metrics.sample_mesh(tv, tt, count=SAMPLES, seed=1)
    samples = metrics.sample_mesh(vertices, triangles, count=SAMPLES, seed=2)
    completeness = metrics.point_mesh_distance(truth_samples, vertices, triangles)
    accuracy = metrics.point_mesh_distance(samples, tv, tt)
    out = {"chamfer": 0.5 * float(completeness.mean() + accuracy.mean())}
    lab_t = regions(truth_samples, z0, z1, cap_radius)
    lab_s = regions(samples, z0, z1, cap_radius)
    for name in REGIONS:
        t, s = lab_t == name, lab_s == name
        out[name] = {
            "mean": 0.5 * float(completeness[t].mean() + accuracy[s].mean()),
            "share_of_chamfer": 0.5 * float(completeness[t].sum() / len(completeness)
                                            + accuracy[s].sum() / len(accuracy)),
            "area_share": float(t.mean())}
    return out


def variograms(workspace: Path, truth) -> dict:
    rings, planes, _ = artifacts.read_curves(workspace / "curves")
    axis = np.asarray(planes[0].frame[2], dtype=np.float64)
    measured = sizing.section_variogram(rings, axis)
    frame = section_chains.plane_frame(axis)
    distance = metrics.MeshDistance(*truth)
    loops = [section_chains.single_loop(e) for e in rings]
    count = min(len(loop) for loop in loops if loop is not None)
    errors = np.full((len(rings), count), np.nan)
    for k, loop in enumerate(loops):
        if loop is None:
            continue
        centre = section_chains.area_centroid(loop, frame)
        aligned = ring_resample.resample_at_angles(loop, count, centre, frame)
        if aligned is not None:
            errors[k] = distance(aligned, signed=True)
    errors = errors[5:-5]
    true = {lag: float(np.sqrt(0.5 * np.nanmean((errors[lag:] - errors[:-lag]) ** 2)))
            for lag in LAGS}
    return {"measured": {lag: float(np.sqrt(measured(lag))) for lag in LAGS}
            if measured else None,
            "measured_sill": float(np.sqrt(measured.sill)) if measured else None,
            "truth": true, "truth_rms": float(np.sqrt(np.nanmean(errors ** 2)))}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("workspace", type=Path, nargs="?", default=ROOT / "out",
                        help="a rendered scene's workspace (default: make demo's out/)")
    parser.add_argument("--quick", action="store_true",
                        help="accepted for make bench's BENCH_ARGS; the workspace is measured "
                             "as it is")
    parser.add_argument("--json", type=Path,
                        default=ROOT / "benchmarks" / "results" / "demo_truth.json")
    args = parser.parse_args()
    w = args.workspace
    if not (w / "scene" / "truth" / "mesh.ply").is_file():
        print(f"{w}: no rendered scene's workspace here (run make demo first); nothing to "
              "measure")
        return 0
    truth = read_mesh(w / "scene" / "truth" / "mesh.ply")
    rows = {"smooth surface": by_region(*read_mesh(w / "smooth" / "surface.ply"), truth),
            "stitched mesh": by_region(*read_mesh(w / "stitch" / "mesh.ply"), truth)}
    print(f"{w}: mean distance to the truth by region (share of the Chamfer distance)")
    print(f"{'surface':16s} {'Chamfer':>9s} " + " ".join(f"{n:>20s}" for n in REGIONS))
    for name, row in rows.items():
        cells = " ".join(f"{row[n]['mean']:10.6f} ({row[n]['share_of_chamfer']:.6f})"
                         for n in REGIONS)
        print(f"{name:16s} {row['chamfer']:9.6f} {cells}")
    z = read_mesh(w / "stitch" / "mesh.ply")[0][:, 2]
    ends = {"bottom": float(truth[0][:, 2].min() - z.min()),
            "top": float(z.max() - truth[0][:, 2].max())}
    print(f"ends of the stitched mesh past the truth's: bottom {ends['bottom']:+.5f}, "
          f"top {ends['top']:+.5f}")
    vg = variograms(w, truth)
    print("rings' variogram across sections, sqrt(gamma(k)) (sizing's measure / truth):")
    for lag in LAGS:
        m = vg["measured"][lag] if vg["measured"] else float("nan")
        print(f"  k = {lag:2d}: {m:.3e} / {vg['truth'][lag]:.3e}")
    print(f"  sill {vg['measured_sill'] or float('nan'):.3e} / rings' RMS error "
          f"{vg['truth_rms']:.3e}")
    write_result(args.json, {"benchmark": "demo_truth", "workspace": str(w), "load": uptime(),
                             "regions": rows, "ends": ends, "variogram": vg})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
