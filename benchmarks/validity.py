"""Benchmark of the solid check: ``surface.validity.check_solid`` beside open3d's.

Meshes: two interpenetrating UV spheres (radius 1, centres 1.1 apart: their surfaces
cross along a circle), 10³ … 5·10⁵ triangles in all.  Figures, one process: seconds
of our whole check (manifold, orientation, genus, self-intersections) and of its
topology part alone; seconds of open3d's ``is_edge_manifold`` + ``is_vertex_manifold``
and of its ``get_self_intersecting_triangles`` (an all-pairs loop with a box test:
quadratic), the latter only while its time predicted from the previous size
(× (F/F_prev)²) stays under ``--o3d-limit`` seconds; the intersecting pairs each finds
(open3d skips pairs that share a vertex: compared on the others, which is all of
them on these meshes).

With ``--scans``: the real scans of ``../shared/data/real/scans`` (SOURCE.md there) as a
user meets them: ``--points`` points sampled on each mesh by area (Igea: its own points,
subsampled), noise ``--noise`` × the diagonal, through ``photosurf sections CLOUD
--axis auto`` (the stitched mesh) and ``... --smooth`` (the smooth surface's
tessellation), each output checked; the truth mesh too (exact duplicate vertices
welded: OBJ readers split them at texture seams).

With ``--against TREE`` (a source tree, e.g. ``git archive COMMIT | tar -x -C TREE``): that
tree's ``surface/validity.py`` (loaded from its own path, its numba cache kept there) is
run beside this one's on the same meshes in the same process: its CPU seconds and whether
it finds the same pairs.

Run: ``.venv/bin/python benchmarks/validity.py [--quick] [--scans] [--against TREE] [--json
PATH]`` (default JSON ``benchmarks/results/validity.json``; ``--quick`` stops at 10⁵).
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))     # before this folder: benchmarks/surface.py is no package

import numpy as np  # noqa: E402
import open3d as o3d  # noqa: E402
from _common import uptime, write_result  # noqa: E402

from surface.validity import check_solid, self_intersections  # noqa: E402

SIZES = [1_000, 10_000, 30_000, 100_000, 500_000]


def two_spheres(faces: int):
    """Two crossing UV spheres with about ``faces`` triangles together."""
    resolution = max(4, int(round(np.sqrt(faces / 8.0))))   # create_sphere: ~4 r² faces
    parts, offset = [], 0
    for centre in ((0.0, 0.0, 0.0), (1.1, 0.2, 0.1)):
        mesh = o3d.geometry.TriangleMesh.create_sphere(1.0, resolution)
        v = np.asarray(mesh.vertices) + centre
        parts.append((v, np.asarray(mesh.triangles, np.int64) + offset))
        offset += len(v)
    return np.vstack([p[0] for p in parts]), np.vstack([p[1] for p in parts])


def _timed(fn):
    start = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - start


def _cpu(fn):
    start = time.process_time()
    fn()
    return time.process_time() - start


def _other(tree: str | None):
    """The ``surface/validity.py`` module of another source tree, or None."""
    if tree is None:
        return None
    import importlib.util

    spec = importlib.util.spec_from_file_location("validity_against",
                                                  Path(tree) / "surface" / "validity.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module          # its dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def _beside(other, v, t, pairs) -> dict:
    """The other tree's self-intersection test on the same mesh: CPU-s, same pairs."""
    if other is None:
        return {}
    skip = np.asarray(check_solid(v, t, intersections=False).degenerate_faces)
    cpu = time.process_time()
    found = other.self_intersections(v, t, skip=skip)
    return {"against_pairs_cpu_s": time.process_time() - cpu,
            "against_same_pairs": bool(np.array_equal(found, pairs))}


def row(faces: int, o3d_predicted: float | None, o3d_limit: float, other=None) -> dict:
    v, t = two_spheres(faces)
    report, ours = _timed(lambda: check_solid(v, t))
    _, topo = _timed(lambda: check_solid(v, t, intersections=False))
    ours_cpu = _cpu(lambda: check_solid(v, t))      # the machine is shared: CPU seconds too
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v),
                                     o3d.utility.Vector3iVector(t.astype(np.int32)))
    (edge_ok, vertex_ok), o3d_manifold = _timed(
        lambda: (mesh.is_edge_manifold(), mesh.is_vertex_manifold()))
    out = {"faces": int(len(t)), "ours_s": ours, "ours_cpu_s": ours_cpu,
           "ours_topology_s": topo,
           "ours_pairs": int(len(report.intersecting_pairs)), "ours_valid": report.valid,
           "ours_genus": report.genus, "o3d_manifold_s": o3d_manifold,
           "manifold_agree": bool(edge_ok == report.edge_manifold
                                  and vertex_ok == report.vertex_manifold),
           "o3d_pairs_s": None, "o3d_pairs": None, "pairs_agree": None,
           "ours_pairs_cpu_s": _cpu(lambda: self_intersections(v, t)),
           **_beside(other, v, t, report.intersecting_pairs)}
    if o3d_predicted is None or o3d_predicted < o3d_limit:
        pairs, seconds = _timed(lambda: np.asarray(mesh.get_self_intersecting_triangles()))
        pairs = np.sort(pairs.reshape(-1, 2).astype(np.int64), axis=1)
        pairs = pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]
        out.update(o3d_pairs_s=seconds, o3d_pairs=int(len(pairs)),
                   pairs_agree=bool(np.array_equal(pairs, report.intersecting_pairs)))
    return out


SCANS = ROOT.parent / "shared" / "data" / "real" / "scans"


def _weld(v, t):
    """Merge vertices with identical coordinates."""
    unique, inverse = np.unique(v, axis=0, return_inverse=True)
    return unique, inverse.reshape(-1)[t]


def _solid_figures(v, t, other=None) -> dict:
    cpu = time.process_time()
    report, seconds = _timed(lambda: check_solid(v, t))
    cpu = time.process_time() - cpu
    return {**_beside(other, v, t, report.intersecting_pairs),
            "pairs_cpu_s": _cpu(lambda: self_intersections(v, t, report.degenerate_faces)),
            "valid": report.valid, "faces": report.faces, "components": report.components,
            "genus": report.genus, "pairs": int(len(report.intersecting_pairs)),
            "nonmanifold_edges": int(len(report.nonmanifold_edges)),
            "nonmanifold_vertices": int(len(report.nonmanifold_vertices)),
            "flipped": int(len(report.flipped_faces)), "border_loops": report.boundary_loops,
            "degenerate": int(len(report.degenerate_faces)), "check_s": seconds,
            "check_cpu_s": cpu,   # this process's peak so far (the check's, mostly)
            "check_peak_gb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20,
            "problems": report.problems()}


def _run_sections(cloud: Path, out: Path, smooth: bool, other=None) -> dict:
    from pipeline.mesh_io import read_mesh

    command = [str(Path(sys.executable).parent / "photosurf"), "sections", str(cloud),
               "--out", str(out), "--axis", "auto"] + (["--smooth"] if smooth else [])
    start = time.perf_counter()
    with tempfile.TemporaryFile("w+") as log:
        child = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT)
        try:     # its own CPU seconds and peak memory (the machine is shared)
            _, status, usage = os.wait4(child.pid, 0)
        except BaseException:
            child.kill()
            raise
        child.returncode = os.waitstatus_to_exitcode(status)
        log.seek(0)
        lines = log.read().strip().splitlines()
    row = {"exit": child.returncode, "seconds": time.perf_counter() - start,
           "cpu_s": usage.ru_utime + usage.ru_stime, "peak_gb": usage.ru_maxrss / 2**20,
           "said": lines[-1] if lines else ""}
    if child.returncode == 0 and out.exists():
        row.update(_solid_figures(*read_mesh(out), other))
    return row


def scans(points: int, noise: float, only: list[str] | None = None, other=None) -> list[dict]:
    from pipeline.cloud_io import read_cloud, write_cloud
    from pipeline.mesh_io import read_mesh
    from surface.metrics import sample_mesh

    rows = []
    rng = np.random.default_rng(0)
    folders = sorted(p for p in SCANS.iterdir() if p.is_dir())
    if only:   # in the order given
        folders = [SCANS / name for name in only if (SCANS / name).is_dir()]
    for folder in folders:
        mesh_file = next(iter(sorted(folder.glob("mesh.*"))))
        row = {"scan": folder.name}
        try:
            v, t = read_mesh(mesh_file)
        except Exception:                 # Igea: points only
            v, t = np.zeros((0, 3)), np.zeros((0, 3), np.int64)
        if len(t):
            v, t = _weld(v, t)
            row["truth"] = _solid_figures(v, t, other)
            cloud = sample_mesh(v, t, points, seed=0)
        else:
            cloud = read_cloud(mesh_file).points
            cloud = cloud[rng.choice(len(cloud), min(points, len(cloud)), replace=False)]
        diagonal = float(np.linalg.norm(np.ptp(cloud, axis=0)))
        cloud = cloud + rng.normal(0.0, noise * diagonal, cloud.shape)
        with tempfile.TemporaryDirectory() as tmp:
            path = write_cloud(Path(tmp) / "cloud.ply", cloud)
            row["stitched"] = _run_sections(path, Path(tmp) / "stitched.ply", False, other)
            row["smooth"] = _run_sections(path, Path(tmp) / "smooth.ply", True, other)
        rows.append(row)
        _print_scan(row)
    return rows


def _cell(figures: dict | None) -> str:
    if not figures:
        return "-"
    if "valid" not in figures:
        return f"refused (exit {figures.get('exit')})"
    genus = "-" if figures["genus"] is None else figures["genus"]
    return (f"{'VALID' if figures['valid'] else 'not valid'} c{figures['components']} "
            f"g{genus} x{figures['pairs']} nme{figures['nonmanifold_edges']} "
            f"nmv{figures['nonmanifold_vertices']} b{figures['border_loops']}")


def _print_scan(row: dict) -> None:
    print(f"{row['scan']:<20} truth: {_cell(row.get('truth'))}")
    for key in ("stitched", "smooth"):
        figures = row[key]
        print(f"{'':<20} {key}: {_cell(figures)}  ({figures['seconds']:.0f} s, "
              f"{figures['cpu_s']:.0f} CPU-s, {figures['peak_gb']:.2f} GB; check "
              f"{figures.get('check_cpu_s', 0):.1f} CPU-s, pairs "
              f"{figures.get('pairs_cpu_s', 0):.1f}"
              + (f", against {figures['against_pairs_cpu_s']:.1f} same "
                 f"{figures['against_same_pairs']}" if "against_pairs_cpu_s" in figures else "")
              + ") "
              f"{'; '.join(figures.get('problems', [])) or figures['said']}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="stop at 10^5 triangles")
    parser.add_argument("--json", default="benchmarks/results/validity.json")
    parser.add_argument("--o3d-limit", type=float, default=60.0,
                        help="skip open3d's pair test where predicted slower (s)")
    parser.add_argument("--scans", action="store_true",
                        help="the real scans through photosurf sections, outputs checked")
    parser.add_argument("--points", type=int, default=40_000)
    parser.add_argument("--noise", type=float, default=0.0, help="σ / diagonal")
    parser.add_argument("--only", nargs="+", metavar="SCAN",
                        help="with --scans: these scans only, in this order")
    parser.add_argument("--against", metavar="TREE",
                        help="time TREE's surface/validity.py beside this one's")
    args = parser.parse_args(argv)
    other = _other(args.against)
    if args.scans:
        if not SCANS.is_dir():
            print(f"no scans at {SCANS}")
            return 0
        print(f"load (1, 5, 15 min): {uptime()}\n(c components, g genus, x intersecting "
              "pairs, nme/nmv non-manifold edges/vertices, b border loops)")
        rows = scans(args.points, args.noise, args.only, other)
        write_result(args.json, {"scans": rows, "points": args.points, "noise": args.noise,
                                 "load": uptime(), "against": args.against})
        return 0
    sizes = [s for s in SIZES if not args.quick or s <= 100_000]
    print(f"load (1, 5, 15 min): {uptime()}")
    rows, predicted = [], None
    for i, faces in enumerate(sizes):
        r = row(faces, predicted, args.o3d_limit, other)
        rows.append(r)
        following = sizes[i + 1] if i + 1 < len(sizes) else faces
        # open3d's pair loop is quadratic in the faces: its next time from this one
        predicted = (float("inf") if r["o3d_pairs_s"] is None
                     else r["o3d_pairs_s"] * (following / r["faces"]) ** 2)
    print(f"\n{'faces':>8} {'ours s':>8} {'cpu s':>6} {'topo s':>7} {'pairs':>6} "
          f"{'pairs cpu':>9} {'against cpu':>11} {'same':>5} {'o3d manif s':>11} "
          f"{'agree':>5} {'o3d pairs s':>11} {'o3d pairs':>9} {'same':>5}")
    for r in rows:
        o3d_s = "-" if r["o3d_pairs_s"] is None else f"{r['o3d_pairs_s']:.2f}"
        o3d_p = "-" if r["o3d_pairs"] is None else str(r["o3d_pairs"])
        same = "-" if r["pairs_agree"] is None else str(r["pairs_agree"])
        against = r.get("against_pairs_cpu_s")
        against = "-" if against is None else f"{against:.2f}"
        print(f"{r['faces']:>8} {r['ours_s']:>8.2f} {r['ours_cpu_s']:>6.2f} "
              f"{r['ours_topology_s']:>7.2f} "
              f"{r['ours_pairs']:>6} {r['ours_pairs_cpu_s']:>9.2f} {against:>11} "
              f"{str(r.get('against_same_pairs', '-')):>5} {r['o3d_manifold_s']:>11.2f} "
              f"{str(r['manifold_agree']):>5} {o3d_s:>11} {o3d_p:>9} {same:>5}")
    print(f"load (1, 5, 15 min): {uptime()}")
    write_result(args.json, {"rows": rows, "load": uptime(), "o3d_limit_s": args.o3d_limit,
                             "against": args.against})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
