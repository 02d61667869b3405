"""Ends within the noise: where the stitched surface puts an object's ends, over samplings.

For each object, ``--samplings`` noise-free clouds of ``--points`` points drawn by area
on its truth mesh (``surface.metrics.sample_mesh``, seeds 0, 1, ...) go through
``surface.reconstruct.surface_from_points`` (axis z); the stitched mesh's lowest and
highest point along the axis are its ends; the Chamfer distance to the truth (mean of
both directions, 50 000 points each) says whether what lies between is right.  Against
the truth's ends: bias (mean offset) and spread (max - min over the samplings; the
standard deviation beside it), in point spacings ``s = sqrt(area / N)``.  Goals:
spread <= 0.5 s, |bias| <= 0.25 s per end.

Objects: a can with a raised rim round a recessed lid (``testkit/can.py``: its top is
the rim's, the lid 0.004 below it) and the YCB mustard bottle of
``../shared/data/real/scans`` (metres, +z; skipped when absent).

Walls and mouths: the bowl of ``testkit/can.py`` (60 000 points, σ = 0.002, one
sampling) with walls 2, 3, 4 and 8 point spacings and 30σ thick: closed or not, the share
of the mesh over the mouth (more than 5σ inside the inner face, above the floor), the
mean distance of the truth's outer and inner wall (0.15 < z < 0.75) to the mesh, and the
Chamfer distance.  Goal: nothing over the mouth, each wall within σ/2.

The smooth surface of each sampling (as ``photosurf sections --smooth`` makes it: sized,
interpolated, adaptive; ``--no-smooth`` skips it) is measured the same way; its seconds
are CPU seconds.  The stitched rows also give the ends' stated standard error
(``extend_to_caps(ends=)``, as the stitch stage records it), mean over the samplings, in s.

Run: ``.venv/bin/python benchmarks/ends.py [--samplings 10] [--points 40000] [--json PATH]``
(``--quick``: 3 samplings; ``--no-bowls``: the ends only; ``--bowls-only``: the bowls only).
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

from _common import print_goals, write_result  # noqa: E402

from surface import metrics  # noqa: E402
from surface import reconstruct as rc  # noqa: E402
from testkit.can import BOWL_FLOOR, bowl_outer_radius, bowl_truth, can_truth  # noqa: E402

#: Points sampled on each surface for the Chamfer distance (mean of both directions).
CHAMFER_SAMPLES = 50_000
MUSTARD = ROOT.parent / "shared" / "data" / "real" / "scans" / "ycb_mustard_bottle" / "mesh.obj"


def read_obj(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices ``(V, 3)`` and triangles ``(F, 3)`` of an OBJ file (polygons as fans)."""
    vertices, faces = [], []
    for line in path.read_text().splitlines():
        if line.startswith("v "):
            vertices.append([float(x) for x in line.split()[1:4]])
        elif line.startswith("f "):
            idx = [int(tok.split("/")[0]) - 1 for tok in line.split()[1:]]
            faces += [[idx[0], idx[k], idx[k + 1]] for k in range(1, len(idx) - 1)]
    return np.asarray(vertices, np.float64), np.asarray(faces, np.int64)


def _chamfer(vertices, triangles, mesh_vertices, mesh_triangles) -> float:
    on_mesh = metrics.sample_mesh(mesh_vertices, mesh_triangles, CHAMFER_SAMPLES, seed=1)
    on_truth = metrics.sample_mesh(vertices, triangles, CHAMFER_SAMPLES, seed=2)
    return 0.5 * float(metrics.point_mesh_distance(on_mesh, vertices, triangles).mean()
                       + metrics.point_mesh_distance(on_truth, mesh_vertices,
                                                     mesh_triangles).mean())


def smooth_surface(cloud: np.ndarray):
    """The smooth surface as ``photosurf sections CLOUD --smooth`` builds it: the sized
    control mesh (``pipeline.section_surface.sized_mesh``), its vertices interpolated
    (``interpolating_control``), Loop's patches tessellated adaptively within the sizing's
    chord tolerance, no finer than the point spacing, checked (and repaired) as a solid."""
    from pipeline.bezier_surface import smooth_mesh
    from pipeline.section_surface import sized_mesh
    from surface.sizing import interpolating_control

    sized, _ = sized_mesh(cloud, axis="z")
    control = interpolating_control(sized.vertices, sized.triangles, sized.creases)
    return smooth_mesh(control, sized.triangles, "adaptive",
                       tolerance=sized.chord_tolerance(), spacing=sized.spacing)


def _end_rows(bottoms, tops, spacing: float, samplings: int) -> dict:
    row = {}
    for end, offsets in (("bottom", np.array(bottoms)), ("top", np.array(tops))):
        row[end] = {"offsets": (offsets / spacing).tolist(),
                    "bias": float(offsets.mean() / spacing),
                    "spread": float(np.ptp(offsets) / spacing),
                    "std": float(offsets.std(ddof=1) / spacing) if samplings > 1 else 0.0}
    return row


def measure(name: str, truth: tuple, points: int, samplings: int, smooth: bool = True) -> dict:
    """The stitched mesh's ends (and the smooth surface's with ``smooth``) over
    ``samplings`` noise-free samplings, with the ends' stated standard errors."""
    vertices, triangles = truth
    spacing = float(np.sqrt(metrics.triangle_areas(vertices, triangles).sum() / points))
    lo, hi = float(vertices[:, 2].min()), float(vertices[:, 2].max())
    bottoms, tops, seconds, notes, chamfer = [], [], [], [], []
    s_bottoms, s_tops, s_cpu, s_chamfer, placed = [], [], [], [], []
    for seed in range(samplings):
        cloud = metrics.sample_mesh(vertices, triangles, points, seed=seed)
        start = time.perf_counter()
        ends: dict = {}
        mesh = rc.surface_from_points(cloud, axis="z", ends=ends)
        seconds.append(time.perf_counter() - start)
        placed.append(ends)
        chamfer.append(_chamfer(vertices, triangles, mesh.vertices, mesh.triangles))
        bottoms.append(float(mesh.vertices[:, 2].min()) - lo)
        tops.append(float(mesh.vertices[:, 2].max()) - hi)
        notes.append([m for m in mesh.messages if "bottom" in m or "top" in m])
        if smooth:
            cpu = time.process_time()
            surface = smooth_surface(cloud)
            s_cpu.append(time.process_time() - cpu)
            s_chamfer.append(_chamfer(vertices, triangles, surface.vertices, surface.triangles))
            s_bottoms.append(float(surface.vertices[:, 2].min()) - lo)
            s_tops.append(float(surface.vertices[:, 2].max()) - hi)
    row = {"object": name, "points": points, "spacing": spacing, "samplings": samplings,
           "seconds": float(np.mean(seconds)), "notes_seed0": notes[0],
           "chamfer_median": float(np.median(chamfer)), "chamfer_max": float(np.max(chamfer)),
           "chamfer": chamfer, "ends_placed": placed}
    row.update(_end_rows(bottoms, tops, spacing, samplings))
    for end in ("bottom", "top"):
        stated = [p.get(end, {}).get("standard_error") for p in placed]
        row[end]["stated_error"] = (float(np.mean([u for u in stated if u is not None])
                                          / spacing) if any(u is not None for u in stated)
                                    else None)
    if smooth:
        row["smooth"] = {"cpu_seconds": float(np.mean(s_cpu)),
                         "chamfer_median": float(np.median(s_chamfer)),
                         "chamfer_max": float(np.max(s_chamfer)), "chamfer": s_chamfer,
                         **_end_rows(s_bottoms, s_tops, spacing, samplings)}
    return row


BOWL_POINTS, BOWL_SIGMA = 60_000, 0.002


def measure_bowl(walls_in_spacings: float | None) -> dict:
    """One bowl row; ``None``: the wall 30σ thick."""
    vertices, triangles = bowl_truth(0.06)
    spacing = float(np.sqrt(metrics.triangle_areas(vertices, triangles).sum() / BOWL_POINTS))
    wall = 30 * BOWL_SIGMA if walls_in_spacings is None else walls_in_spacings * spacing
    vertices, triangles = bowl_truth(wall)
    cloud = metrics.sample_mesh(vertices, triangles, BOWL_POINTS, seed=0)
    cloud += np.random.default_rng(50).normal(0.0, BOWL_SIGMA, cloud.shape)
    start = time.perf_counter()
    mesh = rc.surface_from_points(cloud, axis="z")
    seconds = time.perf_counter() - start
    on_mesh = metrics.sample_mesh(mesh.vertices, mesh.triangles, CHAMFER_SAMPLES, seed=1)
    on_truth = metrics.sample_mesh(vertices, triangles, CHAMFER_SAMPLES, seed=2)
    to_truth = metrics.point_mesh_distance(on_mesh, vertices, triangles)
    to_mesh = metrics.point_mesh_distance(on_truth, mesh.vertices, mesh.triangles)
    r = np.hypot(on_mesh[:, 0], on_mesh[:, 1])
    cavity = (on_mesh[:, 2] > BOWL_FLOOR + 5 * BOWL_SIGMA) & (
        r < bowl_outer_radius(on_mesh[:, 2]) - wall - 5 * BOWL_SIGMA)
    r = np.hypot(on_truth[:, 0], on_truth[:, 1])
    band = (on_truth[:, 2] > 0.15) & (on_truth[:, 2] < 0.75)
    outer = band & (r > bowl_outer_radius(on_truth[:, 2]) - wall / 2)
    inner = band & ~outer
    return {"wall": wall, "wall_spacings": wall / spacing, "spacing": spacing,
            "closed": bool(mesh.closed), "over_mouth": float(cavity.mean()),
            "outer_wall": float(to_mesh[outer].mean()), "inner_wall": float(to_mesh[inner].mean()),
            "chamfer": 0.5 * float(to_truth.mean() + to_mesh.mean()), "seconds": seconds}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samplings", type=int, default=10)
    parser.add_argument("--points", type=int, default=40_000)
    parser.add_argument("--quick", action="store_true", help="3 samplings")
    parser.add_argument("--no-smooth", action="store_true",
                        help="the stitched mesh's ends only (not the smooth surface's)")
    parser.add_argument("--no-bowls", action="store_true", help="skip the bowl rows")
    parser.add_argument("--bowls-only", action="store_true", help="the bowl rows alone")
    parser.add_argument("--json", default=str(ROOT / "benchmarks" / "results" / "ends.json"))
    args = parser.parse_args(argv)
    samplings = 3 if args.quick else args.samplings
    objects = [] if args.bowls_only else [("can, raised rim", can_truth())]
    if args.bowls_only:
        pass
    elif MUSTARD.exists():
        objects.append(("mustard bottle", read_obj(MUSTARD)))
    else:
        print(f"skipped the mustard bottle: {MUSTARD} not found")
    rows, goals = [], {}
    print(f"{'object':<16} {'surface':>8} {'spacing':>9} {'end':>6} {'bias/s':>7} "
          f"{'spread/s':>8} {'std/s':>6} {'stated/s':>8} {'Chamfer/s med, max':>19} "
          f"{'s/run':>6}")
    for name, truth in objects:
        row = measure(name, truth, args.points, samplings, smooth=not args.no_smooth)
        rows.append(row)
        kinds = [("stitched", row, row["seconds"])] + (
            [("smooth", row["smooth"], row["smooth"]["cpu_seconds"])] if "smooth" in row
            else [])
        for kind, figures, sec in kinds:
            for end in ("bottom", "top"):
                e = figures[end]
                stated = row[end]["stated_error"]
                stated = "-" if stated is None or kind != "stitched" else f"{stated:.3f}"
                print(f"{name:<16} {kind:>8} {row['spacing']:>9.6f} {end:>6} {e['bias']:>+7.2f} "
                      f"{e['spread']:>8.2f} {e['std']:>6.2f} {stated:>8} "
                      f"{figures['chamfer_median'] / row['spacing']:>9.3f} "
                      f"{figures['chamfer_max'] / row['spacing']:>9.3f} {sec:>6.1f}",
                      flush=True)
                goals[f"{name} {kind} {end} spread <= 0.5 s"] = e["spread"] <= 0.5
                goals[f"{name} {kind} {end} |bias| <= 0.25 s"] = abs(e["bias"]) <= 0.25
    if args.no_bowls:
        print()
        print_goals(goals)
        write_result(args.json, {"benchmark": "ends", "rows": rows, "goals": goals})
        return 0
    print(f"\n{'bowl wall':>12} {'closed':>6} {'over mouth':>10} {'outer wall':>10} "
          f"{'inner wall':>10} {'Chamfer':>9} {'s':>5}")
    bowls = []
    for walls in (2.0, 3.0, 4.0, None, 8.0):
        row = measure_bowl(walls)
        bowls.append(row)
        label = f"{row['wall_spacings']:.1f} s" + (" (30σ)" if walls is None else "")
        print(f"{label:>12} {'yes' if row['closed'] else 'no':>6} {row['over_mouth']:>10.3f} "
              f"{row['outer_wall']:>10.5f} {row['inner_wall']:>10.5f} {row['chamfer']:>9.5f} "
              f"{row['seconds']:>5.1f}", flush=True)
        goals[f"bowl wall {label}: open mouth, walls within σ/2"] = (
            row["over_mouth"] == 0 and max(row["outer_wall"], row["inner_wall"]) < BOWL_SIGMA / 2)
    print()
    print_goals(goals)
    write_result(args.json, {"benchmark": "ends", "rows": rows, "bowls": bowls, "goals": goals})
    return 0


if __name__ == "__main__":
    sys.exit(main())
