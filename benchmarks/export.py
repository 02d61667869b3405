"""Export and display of a tessellated surface: time, size and fidelity per format.

Rows, all in one process on the same mesh (a sphere of ``--triangles``
triangles, unit radius, exact radial normals):

* ``pipeline.export.export_mesh`` for .ply .obj .stl .gltf .glb: write time,
  file size, read-back time through open3d, largest corner-position and
  normal error after the round trip (triangle by triangle);
* the peers: open3d's own OBJ writer (six significant digits) and open3d's own
  GLB writer (which its reader rejects: 0 triangles read back);
* ``pipeline.render.render_mesh``: the default 3×2 contact sheet (1200×800,
  2× supersampling) and one 400×400 view, smooth shading; and the floor, the
  bare ``RaycastingScene.cast_rays`` for the same rays.

Run: ``.venv/bin/python benchmarks/export.py [--quick] [--json PATH]``
(default JSON: ``benchmarks/results/export.json``).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pipeline.export import EXPORT_SUFFIXES, export_mesh  # noqa: E402
from pipeline.render import camera_rays, look_at, render_mesh  # noqa: E402


def _sphere(triangles: int):
    import open3d as o3d

    resolution = max(4, int(round(np.sqrt(triangles / 4))))  # create_sphere: ≈ 4 r² triangles
    mesh = o3d.geometry.TriangleMesh.create_sphere(1.0, resolution)
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    return vertices, np.asarray(mesh.triangles, dtype=np.int64), vertices / np.linalg.norm(
        vertices, axis=1, keepdims=True)


def _read_back(path: Path, vertices, triangles, normals) -> dict:
    import open3d as o3d

    start = time.perf_counter()
    mesh = o3d.io.read_triangle_mesh(str(path))
    seconds = time.perf_counter() - start
    v, t = np.asarray(mesh.vertices), np.asarray(mesh.triangles)
    row = {"read_s": seconds, "triangles_read": len(t), "position_error": None,
           "normal_error": None}
    if len(t) == len(triangles):
        row["position_error"] = float(np.abs(v[t] - vertices[triangles]).max())
        if mesh.has_vertex_normals() and path.suffix != ".stl":
            n = np.asarray(mesh.vertex_normals)
            row["normal_error"] = float(np.abs(n[t] - normals[triangles]).max())
    return row


def bench_formats(vertices, triangles, normals, folder: Path) -> list[dict]:
    import open3d as o3d

    from pipeline.mesh_io import to_open3d

    rows = []
    for suffix in EXPORT_SUFFIXES:
        path = folder / f"ours{suffix}"
        start = time.perf_counter()
        export_mesh(path, vertices, triangles, normals)
        row = {"writer": f"photosurf {suffix}", "write_s": time.perf_counter() - start,
               "bytes": path.stat().st_size}
        rows.append({**row, **_read_back(path, vertices, triangles, normals)})
    mesh = to_open3d(vertices, triangles, normals)
    for suffix in (".obj", ".glb"):
        path = folder / f"open3d{suffix}"
        start = time.perf_counter()
        o3d.io.write_triangle_mesh(str(path), mesh, write_vertex_normals=True)
        row = {"writer": f"open3d {suffix}", "write_s": time.perf_counter() - start,
               "bytes": path.stat().st_size}
        rows.append({**row, **_read_back(path, vertices, triangles, normals)})
    return rows


def bench_render(vertices, triangles, normals, repeats: int) -> list[dict]:
    import open3d as o3d

    rows = []
    for label, kwargs in (("contact sheet 1200x800, 6 views, 2x SSAA",
                           {"views": 6, "size": (1200, 800)}),
                          ("one view 400x400, 2x SSAA", {"views": [(30.0, 20.0)],
                                                         "size": (400, 400)}),
                          ("one view 400x400, no SSAA", {"views": [(30.0, 20.0)],
                                                         "size": (400, 400),
                                                         "supersample": 1})):
        times = []
        for _ in range(repeats):
            start = time.perf_counter()
            render_mesh(vertices, triangles, normals=normals, **kwargs)
            times.append(time.perf_counter() - start)
        rows.append({"render": label, "seconds": float(np.median(times))})
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(vertices.astype(np.float32), triangles.astype(np.uint32))
    K, R, t = look_at(np.zeros(3), 1.0, 30.0, 20.0, 400, 400)
    rays = o3d.core.Tensor(camera_rays(K, R, t, 400, 400, 2).reshape(-1, 6))
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        scene.cast_rays(rays)
        times.append(time.perf_counter() - start)
    rows.append({"render": "floor: cast_rays only, 800x800 rays", "seconds":
                 float(np.median(times))})
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small mesh, one repeat")
    parser.add_argument("--triangles", type=int, default=None,
                        help="triangles of the test sphere (default 1e6, --quick 5e4)")
    parser.add_argument("--json", default=str(Path(__file__).parent / "results" / "export.json"))
    args = parser.parse_args(argv)
    import open3d as o3d

    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)  # open3d's GLB warning
    count = args.triangles or (50_000 if args.quick else 1_000_000)
    repeats = 1 if args.quick else 3
    vertices, triangles, normals = _sphere(count)
    with tempfile.TemporaryDirectory() as tmp:
        formats = bench_formats(vertices, triangles, normals, Path(tmp))
    renders = bench_render(vertices, triangles, normals, repeats)

    print(f"mesh: sphere, {len(vertices)} vertices, {len(triangles)} triangles")
    print(f"{'writer':<16}{'write s':>9}{'MB':>8}{'read s':>8}{'read tris':>11}"
          f"{'pos err':>10}{'normal err':>11}")
    for r in formats:
        pe = "-" if r["position_error"] is None else f"{r['position_error']:.1e}"
        ne = "-" if r["normal_error"] is None else f"{r['normal_error']:.1e}"
        print(f"{r['writer']:<16}{r['write_s']:>9.3f}{r['bytes'] / 1e6:>8.1f}{r['read_s']:>8.3f}"
              f"{r['triangles_read']:>11}{pe:>10}{ne:>11}")
    print()
    for r in renders:
        print(f"{r['render']:<45}{r['seconds']:>8.3f} s")
    out = Path(args.json)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"vertices": len(vertices), "triangles": len(triangles),
                               "formats": formats, "render": renders}, indent=1))
    print(f"\nwrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
