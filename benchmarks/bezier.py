"""Benchmark of surface.bezier: construction, tessellation and G1 on a vase-like mesh.

Figures: patches per second for the construction (cold = first call, which
also solves the per-valence G1 systems once; warm = cached), tessellated
triangles per second (goal >= 1e6), and the largest gap / normal angle over
all interior patch edges.  Peers in the same process: open3d's
``subdivide_loop`` producing a comparable triangle count (the usual way to get
a smooth-looking mesh, with no surface behind it), and the ``bezier`` package
evaluating patches one at a time (if installed).

Usage::

    .venv/bin/python benchmarks/bezier.py [--quick] [--json PATH]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

# this file is called bezier.py: keep its folder off the path so that
# ``import bezier`` finds the PyPI package (the peer), not this script
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).parent.resolve()]

import numpy as np  # noqa: E402

from surface import bezier as bz  # noqa: E402


def band_mesh(n: int, sections: int, height: float = 2.0):
    """Vase-like closed mesh stitched N <-> 2N by angle (the direction criterion)."""
    z = np.linspace(0.0, height, sections)
    radius = 0.6 + 0.25 * np.sin(2.2 * z) + 0.1 * z
    counts = [n if k % 2 == 0 else 2 * n for k in range(sections)]
    points, start, tris = [], [], []
    for zk, rk, ck in zip(z, radius, counts, strict=True):
        theta = 2 * np.pi * np.arange(ck) / ck
        start.append(sum(len(p) for p in points))
        points.append(np.stack([rk * np.cos(theta), rk * np.sin(theta), np.full(ck, zk)], 1))
    for k in range(sections - 1):
        lo, up, nl, nu = start[k], start[k + 1], counts[k], counts[k + 1]
        i = j = 0
        while i < nl or j < nu:
            ahead = (i + 1) / nl - (j + 1) / nu
            if j >= nu or (i < nl and (ahead < -1e-12 or (abs(ahead) <= 1e-12 and nl < nu))):
                tris.append((lo + i % nl, lo + (i + 1) % nl, up + j % nu))
                i += 1
            else:
                tris.append((lo + i % nl, up + (j + 1) % nu, up + j % nu))
                j += 1
    vertices = np.concatenate(points + [[[0, 0, -0.4]], [[0, 0, height + 0.3]]])
    bottom, top = len(vertices) - 2, len(vertices) - 1
    tris += [(bottom, (i + 1) % counts[0], i) for i in range(counts[0])]
    tris += [(top, start[-1] + i, start[-1] + (i + 1) % counts[-1]) for i in range(counts[-1])]
    return vertices.astype(np.float64), np.array(tris, dtype=np.int64)


def _best(fn, repeat: int):
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return min(times), out


def run(quick: bool) -> dict:
    n, sections, level = (12, 12, 3) if quick else (32, 40, 3)
    vertices, tris = band_mesh(n, sections)
    repeat = 2 if quick else 3
    t0 = time.perf_counter()
    surface = bz.control_net(vertices, tris)
    cold = time.perf_counter() - t0
    warm, surface = _best(lambda: bz.control_net(vertices, tris), repeat)
    n_patches = len(surface.control_points)
    tess_time, (tv, tt, _) = _best(lambda: bz.tessellate(surface, level), repeat)
    g1_time, (gap, angle) = _best(
        lambda: bz.edge_continuity(surface.control_points, surface.domain_mesh[1], 9), 1)
    vertex_angle = _vertex_angle(surface)
    valence = np.bincount(tris.ravel())
    size = float(np.linalg.norm(vertices.max(0) - vertices.min(0)))
    result = {
        "mesh": {"vertices": len(vertices), "triangles": len(tris),
                 "valences": sorted(int(v) for v in set(valence)), "size": size},
        "construction": {"patches": n_patches, "cold_s": cold, "warm_s": warm,
                         "patches_per_s_cold": n_patches / cold,
                         "patches_per_s_warm": n_patches / warm},
        "tessellation": {"level": level, "triangles": len(tt), "vertices": len(tv),
                         "seconds": tess_time, "triangles_per_s": len(tt) / tess_time},
        "g1": {"samples_per_edge": 9, "max_gap": gap, "max_gap_rel": gap / size,
               "max_angle_rad": angle, "max_vertex_angle_rad": vertex_angle,
               "seconds": g1_time},
        "peers": {},
    }
    result["peers"]["open3d_subdivide_loop"] = _open3d_peer(vertices, tris, level + 1, repeat)
    result["peers"]["bezier_package"] = _bezier_peer(surface.control_points, level)
    return result


def _vertex_angle(surface) -> float:
    """Largest angle between the corner normals of the patches meeting at a vertex."""
    tris = surface.domain_mesh[1]
    corner = bz.corner_normals(surface.control_points).reshape(-1, 3)
    vertex = tris.ravel()
    first = np.zeros((int(tris.max()) + 1, 3))
    first[vertex[::-1]] = corner[::-1]
    ref = first[vertex]
    angle = np.arctan2(np.linalg.norm(np.cross(corner, ref), axis=1), np.sum(corner * ref, axis=1))
    return float(angle.max())


def _open3d_peer(vertices, tris, steps: int, repeat: int) -> dict:
    import open3d as o3d

    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(vertices),
                                     o3d.utility.Vector3iVector(tris))
    seconds, fine = _best(lambda: mesh.subdivide_loop(steps), repeat)
    n = len(fine.triangles)
    return {"steps": steps, "triangles": n, "seconds": seconds, "triangles_per_s": n / seconds}


def _bezier_peer(control_points: np.ndarray, level: int, n_patches: int = 50) -> dict:
    try:
        import bezier
    except ImportError:
        return {"available": False}
    bary, _, _ = bz._grid(2 ** level)
    table = bz.index_table()
    order = sorted(range(28), key=lambda p: (table[p][2], table[p][1]))
    params = np.asfortranarray(bary)
    t0 = time.perf_counter()
    for net in control_points[:n_patches]:
        bezier.Triangle(np.asfortranarray(net[order].T), degree=6).evaluate_barycentric_multi(
            params)
    seconds = time.perf_counter() - t0
    points = n_patches * len(bary)
    ours, _ = _best(lambda: bz.evaluate(control_points, bary), 3)
    return {"available": True, "patches": n_patches, "points_per_s": points / seconds,
            "ours_points_per_s": len(control_points) * len(bary) / ours}


def table(result: dict) -> str:
    c, t, g = result["construction"], result["tessellation"], result["g1"]
    o3, bp = result["peers"]["open3d_subdivide_loop"], result["peers"]["bezier_package"]
    rows = [
        ("mesh", f"{result['mesh']['triangles']} triangles, valences {result['mesh']['valences']}"),
        ("construction (cold)", f"{c['patches_per_s_cold']:,.0f} patches/s ({c['cold_s']:.3f} s)"),
        ("construction (warm)", f"{c['patches_per_s_warm']:,.0f} patches/s ({c['warm_s']:.3f} s)"),
        (f"tessellate level {t['level']}",
         f"{t['triangles_per_s']:,.0f} triangles/s ({t['triangles']:,} in {t['seconds']:.3f} s)"),
        ("G1 largest angle (edges)", f"{g['max_angle_rad']:.2e} rad"),
        ("G1 largest angle (vertices)", f"{g['max_vertex_angle_rad']:.2e} rad"),
        ("G1 largest gap", f"{g['max_gap']:.2e} ({g['max_gap_rel']:.1e} x size)"),
        (f"peer open3d subdivide_loop({o3['steps']})",
         f"{o3['triangles_per_s']:,.0f} triangles/s ({o3['triangles']:,})"),
    ]
    if bp.get("available"):
        rows.append(("peer bezier package (per patch)", f"{bp['points_per_s']:,.0f} points/s"))
        rows.append(("ours, all patches at once", f"{bp['ours_points_per_s']:,.0f} points/s"))
    width = max(len(r[0]) for r in rows)
    return "\n".join(f"{name:<{width}}  {value}" for name, value in rows)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small mesh, fewer repeats")
    parser.add_argument("--json", type=Path,
                        default=Path(__file__).parent / "results" / "bezier.json")
    args = parser.parse_args(argv)
    result = run(args.quick)
    print(table(result))
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(result, indent=2))
    print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
