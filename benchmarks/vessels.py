"""Thin-walled vessels, handles and holes in the data: what the section method makes of them.

Vessels: the pot of ``testkit/cup.py`` (outer r 1, height 2, floor 0.25 thick, open
mouth; optionally a handle, a half torus joined at z = 0.4 and 1.6, genus 1) with walls
0.5, 1, 2, 3, 4 and 8 point spacings thick (``--walls``), ``--points`` area-uniform
points (spacing s = sqrt(area/N) of the 0.1-wall pot) with noise 0.1 s, through
``surface.reconstruct.surface_from_points`` (axis z). Per row: closed, components, genus
(from the Euler characteristic) against the truth's, the share of the mesh over the
mouth (inside the cavity more than 5σ from the inner face, above the floor), the mean
distance of the truth's outer and inner wall (0.5 < z < 1.8, away from the handle) to
the mesh, Chamfer (mean of both directions; mesh samples to the implicit surface by
Newton projection), seconds. A wall the sections cannot part
(``reconstruct.classify_ends``: a thin mouth, one line "too thin") is judged as what the data allow:
one piece, one border at the mouth, nothing over it, the outer surface within half the
wall and σ of the truth's outer wall.

Holes: real scans of ``../shared/data/real/scans`` sampled with ``--points`` points,
those within ``--cut`` of the extent above the lowest point along the axis removed (a
base the scanner never saw), default and ``open_holes``: closed, border loops, the
largest and 99th-percentile distance of the surface to the cloud (a dome over the hole
would be far from every point), seconds.

Corpus rows (``--corpus CASE:SIZE:NOISE ...``): ``benchmarks/corpus.py``'s clouds and scores
of the section surface (``photosurf sections --smooth --axis auto``) beside Poisson-8, without
the general surface: Chamfer and F-score against the truth, valid solid, genus, CPU-s.

Run: ``.venv/bin/python benchmarks/vessels.py [--points 60000] [--json PATH] [--quick]``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.append(str(ROOT / "benchmarks"))

import corpus  # noqa: E402
from _common import print_goals, write_result  # noqa: E402

from surface import metrics  # noqa: E402
from surface import reconstruct as rc  # noqa: E402
from surface.open_surface import boundary_loops  # noqa: E402
from testkit import cup as _cup  # noqa: E402

SCANS = ROOT.parent / "shared" / "data" / "real" / "scans"
SAMPLES = 30_000


def _genus(topo: dict) -> float | None:
    if not topo["closed"]:
        return None
    return topo["components"] - topo["euler"] / 2


def vessel_row(walls: float, handle: bool, points: int) -> dict:
    from testkit.shapes import project

    spacing = float(np.sqrt(_cup.vessel_area(_cup.vessel(0.1, False)) / points))
    wall, sigma = walls * spacing, 0.1 * spacing
    f = _cup.vessel(wall, handle)
    cloud = _cup.vessel_sample(f, points, seed=0, sigma=sigma)
    start = time.perf_counter()
    mesh = rc.surface_from_points(cloud, axis="z")
    seconds = time.perf_counter() - start
    topo = metrics.mesh_topology(mesh.vertices, mesh.triangles)
    on_mesh = metrics.sample_mesh(mesh.vertices, mesh.triangles, SAMPLES, seed=1)
    r = np.hypot(on_mesh[:, 0], on_mesh[:, 1])
    cavity = (on_mesh[:, 2] > _cup.VESSEL_FLOOR + 5 * sigma) & (
        r < _cup.VESSEL_RADIUS - wall - 5 * sigma)
    truth = _cup.vessel_sample(f, SAMPLES, seed=2)
    to_mesh = metrics.point_mesh_distance(truth, mesh.vertices, mesh.triangles)
    to_truth = np.linalg.norm(project(f, on_mesh) - on_mesh, axis=1)
    rt = np.hypot(truth[:, 0], truth[:, 1])
    band = (truth[:, 2] > 0.5) & (truth[:, 2] < 1.8) & (rt < _cup.VESSEL_RADIUS + 0.01) & ~(
        (truth[:, 0] > 0.8) & (np.abs(truth[:, 1]) < 0.3))
    outer = band & (rt > _cup.VESSEL_RADIUS - wall / 2)
    inner = band & ~outer
    return {"wall_spacings": walls, "handle": handle, "points": points, "spacing": spacing,
            "closed": bool(topo["closed"]), "components": int(topo["components"]),
            "genus": _genus(topo), "truth_genus": 1 if handle else 0,
            "over_mouth": float(cavity.mean()),
            "outer_wall": float(to_mesh[outer].mean()), "inner_wall": float(to_mesh[inner].mean()),
            "chamfer": 0.5 * float(to_truth.mean() + to_mesh.mean()), "seconds": seconds,
            "too_thin": [m for m in mesh.messages if "too thin" in m],
            "borders": len(boundary_loops(mesh.triangles)) if not topo["closed"] else 0,
            "messages": [m for m in mesh.messages if "dropped" not in m][:12]}


def _scan(name: str):
    import open3d as o3d
    from ends import read_obj

    path = next((SCANS / name).glob("mesh.*"))
    if path.suffix == ".obj":
        return read_obj(path)
    mesh = o3d.io.read_triangle_mesh(str(path))
    return np.asarray(mesh.vertices), np.asarray(mesh.triangles)


def hole_row(name: str, axis: str, cut: float, points: int, open_holes: bool) -> dict:
    vertices, triangles = _scan(name)
    cloud = metrics.sample_mesh(vertices, triangles, points, seed=0)
    k = "xyz".index(axis)
    cloud = cloud[cloud[:, k] > cloud[:, k].min() + cut * np.ptp(cloud[:, k])]
    start = time.perf_counter()
    try:
        mesh = rc.surface_from_points(cloud, axis=axis, open_holes=open_holes)
    except ValueError as exc:
        return {"scan": name, "open": open_holes, "refused": str(exc)}
    seconds = time.perf_counter() - start
    topo = metrics.mesh_topology(mesh.vertices, mesh.triangles)
    on_mesh = metrics.sample_mesh(mesh.vertices, mesh.triangles, SAMPLES, seed=1)
    far = cKDTree(cloud).query(on_mesh)[0]
    diagonal = float(np.linalg.norm(np.ptp(cloud, axis=0)))
    return {"scan": name, "axis": axis, "cut": cut, "points": len(cloud), "open": open_holes,
            "closed": bool(topo["closed"]), "components": int(topo["components"]),
            "edge_manifold": bool(topo["edge_manifold"]),
            "borders": len(boundary_loops(mesh.triangles)) if not topo["closed"] else 0,
            "to_cloud_max_diag": float(far.max()) / diagonal,
            "to_cloud_p99_diag": float(np.quantile(far, 0.99)) / diagonal,
            "seconds": seconds,
            "notes": [m for m in mesh.messages if "hole" in m or "dome" in m]}


def corpus_rows(specs: list[str], json_path: str) -> int:
    """``--corpus CASE:SIZE:NOISE ...``: the corpus rows (``benchmarks/corpus.py``'s clouds
    and scores) of the section surface beside Poisson-8 alone, one process, no general
    surface: Chamfer, F-score, valid solid, genus, CPU-s of each."""
    rows = []
    print(f"{'case':>20} {'points':>6} {'noise':>6} {'ours C':>9} {'P8 C':>9} {'ratio':>5} "
          f"{'valid':>5} {'genus':>5} {'truth':>5} {'ours s':>6} {'P8 s':>6}")
    for spec in specs:
        case, size, noise = spec.split(":")
        points, truth = corpus.load_case(case, int(size), float(noise), ROOT)
        results, refused = {}, {}
        try:
            results["sections"] = corpus.run_sections(points)
        except ValueError as exc:
            refused["sections"] = {"refused": str(exc).splitlines()[0][:200]}
        results["poisson-8"] = corpus.run_poisson(points)
        row = corpus.scored_row(case, float(noise), points, truth, results,
                                {**refused, "general": {"refused": "not run"}})
        for name in ("general", "auto"):   # the smooth stage's choice needs the general one
            row["methods"].pop(name, None)
        rows.append(row)
        ours, p8 = row["methods"].get("sections", {}), row["methods"]["poisson-8"]
        if "refused" in ours:
            print(f"{case:>20} {size:>6} {noise:>6} refused: {ours['refused']}", flush=True)
            continue
        print(f"{case:>20} {size:>6} {noise:>6} {ours['chamfer']:>9.3e} {p8['chamfer']:>9.3e} "
              f"{ours['chamfer'] / p8['chamfer']:>5.2f} {str(ours['valid']):>5} "
              f"{ours['genus']!s:>5} {row['truth_genus']!s:>5} {ours['cpu']:>6.1f} "
              f"{p8['cpu']:>6.1f}", flush=True)
        write_result(json_path, {"benchmark": "vessels --corpus", "rows": rows})  # each row
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--corpus", nargs="+", metavar="CASE:SIZE:NOISE",
                        help="corpus rows: the section surface beside Poisson-8 (corpus_rows)")
    parser.add_argument("--points", type=int, default=60_000)
    parser.add_argument("--cut", type=float, default=0.002)
    parser.add_argument("--quick", action="store_true", help="walls 2 and 4 only, no scans")
    parser.add_argument("--walls", type=float, nargs="+",
                        help="wall thicknesses in spacings (default 2 3 4 8; --quick: 2 4)")
    parser.add_argument("--no-scans", action="store_true", help="the vessels only")
    parser.add_argument("--json", default=str(ROOT / "benchmarks" / "results" / "vessels.json"))
    args = parser.parse_args(argv)
    if args.corpus:
        return corpus_rows(args.corpus, args.json)
    rows = []
    print(f"{'wall/s':>6} {'handle':>6} {'closed':>6} {'comp':>4} {'genus':>5} {'truth':>5} "
          f"{'mouth':>6} {'outer/s':>8} {'inner/s':>8} {'chamfer/s':>9} {'s':>6}")
    for walls in args.walls or ((2.0, 4.0) if args.quick else (0.5, 1.0, 2.0, 3.0, 4.0, 8.0)):
        for handle in (False, True):
            row = vessel_row(walls, handle, args.points)
            rows.append(row)
            s = row["spacing"]
            print(f"{walls:>6.1f} {str(handle):>6} {str(row['closed']):>6} "
                  f"{row['components']:>4} {row['genus']!s:>5} {row['truth_genus']:>5} "
                  f"{row['over_mouth']:>6.3f} {row['outer_wall'] / s:>8.3f} "
                  f"{row['inner_wall'] / s:>8.3f} {row['chamfer'] / s:>9.3f} "
                  f"{row['seconds']:>6.1f}" + ("  (too thin, open)" if row["too_thin"] else ""),
                  flush=True)
    holes = []
    if not (args.quick or args.no_scans):
        print(f"\n{'scan':>20} {'axis':>4} {'open':>5} {'closed':>6} {'comp':>4} "
              f"{'borders':>7} {'max/diag':>8} {'p99/diag':>8} {'s':>6}")
        for name, axis in (("nefertiti", "z"), ("cow", "y"), ("ycb_mustard_bottle", "z")):
            if not (SCANS / name).is_dir():
                continue
            for open_holes in (False, True):
                row = hole_row(name, axis, args.cut, args.points, open_holes)
                holes.append(row)
                if "refused" in row:
                    print(f"{name:>20} {axis:>4} {str(open_holes):>5} refused: {row['refused']}")
                    continue
                print(f"{name:>20} {axis:>4} {str(open_holes):>5} {str(row['closed']):>6} "
                      f"{row['components']:>4} {row['borders']:>7} "
                      f"{row['to_cloud_max_diag']:>8.4f} {row['to_cloud_p99_diag']:>8.4f} "
                      f"{row['seconds']:>6.1f}", flush=True)
    goals = {}
    for row in rows:
        label = f"wall {row['wall_spacings']:g} s{' + handle' if row['handle'] else ''}"
        if row["too_thin"]:   # the faces not resolved: one line, the outer surface, open
            goals[f"{label}: too thin in one line, one piece, the mouth open"] = (
                len(row["too_thin"]) == 1 and row["components"] == 1 and row["borders"] == 1
                and row["over_mouth"] == 0.0)
            goals[f"{label}: the outer surface within half the wall and σ of the outer wall"] = (
                row["outer_wall"] <= 0.5 * row["wall_spacings"] * row["spacing"]
                + 0.1 * row["spacing"])
            continue
        goals[f"{label}: one closed piece of the truth's genus"] = (
            row["closed"] and row["components"] == 1 and row["genus"] == row["truth_genus"])
        goals[f"{label}: nothing over the mouth, walls within σ"] = (
            row["over_mouth"] == 0.0 and max(row["outer_wall"], row["inner_wall"])
            <= 0.1 * row["spacing"])
    for row in holes:
        if "refused" in row:
            goals[f"{row['scan']} open={row['open']}: not refused"] = False
            continue
        goals[f"{row['scan']} open={row['open']}: "
              + ("closed" if not row["open"] else "open only where the data end")] = (
            row["closed"] if not row["open"] else row["edge_manifold"])
    print_goals(goals)
    write_result(args.json, {"benchmark": "vessels", "rows": rows, "holes": holes,
                             "goals": goals})
    return 0


if __name__ == "__main__":
    sys.exit(main())
