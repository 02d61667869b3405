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
  bare ``RaycastingScene.cast_rays`` for the same rays;
* ``pipeline.cad_export``: the exact Bézier surface as a closed CAD solid (Loop's
  surface over an ellipsoid of ``--patches`` patches, or the control net of a
  workspace with ``--net W/smooth``): ``write_cad``'s CPU seconds and bytes,
  and the file read back by OpenCascade (valid closed solid, faces, volume and
  area against a fine tessellation, largest distance of face samples from it
  against the chord bound); the peers: the same solid through OpenCascade's
  shape transfer phase by phase (building the solid, transfer, merging
  duplicate entities, writing), merged and unmerged; IGES; the PLY of the
  tessellation for scale.

The STEP read-back rows (``bench_step_read``): the text writer's variants, with and
without pcurves, at the old and the current distance uncertainty, read by
OpenCascade (parse, transfer, BRepCheck) and opened by FreeCAD when ``freecadcmd``
is installed (``--step-only`` runs only these).

``--light [quads] [uncertainty]``: only the STEP file the export stage writes (and the named
variants beside it), read once by OpenCascade and opened ``--repeats`` times by FreeCAD, the
files in turn: minutes on the demo's net instead of the full run's half hour.

Run: ``.venv/bin/python benchmarks/export.py [--quick] [--step-only] [--net W/smooth]
[--light [VARIANT ...]] [--json PATH]``
(default JSON: ``benchmarks/results/export.json``).
"""

from __future__ import annotations

import argparse
import functools
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _common import write_result  # noqa: E402

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


def _recorded_tolerance(net: str | None) -> float | None:
    """The chord tolerance the smooth stage recorded in the workspace of ``net``."""
    if not net:
        return None
    manifest = Path(net).parent / "manifest.json"
    try:
        info = json.loads(manifest.read_text())["stages"]["smooth"]["info"]
        return float(info["chord_tolerance"])
    except (OSError, KeyError, TypeError, ValueError):
        return None


def _ellipsoid_net(patches: int, with_source: bool = False):
    """Loop's surface over an ellipsoid (axes 1, 0.7, 0.5) with about ``patches`` patches."""
    import open3d as o3d

    from surface import bezier

    resolution = max(2, int(round(np.sqrt(patches / 16))))  # 4 r^2 triangles, 4 patches each
    mesh = o3d.geometry.TriangleMesh.create_sphere(1.0, resolution)
    surface = bezier.control_net(np.asarray(mesh.vertices) * [1.0, 0.7, 0.5],
                                 np.asarray(mesh.triangles))
    if with_source:
        return surface.control_points, surface.domain_mesh[1], surface.source_face
    return surface.control_points, surface.domain_mesh[1]


def _clocked(timings: dict, name: str, call):
    start, cpu = time.perf_counter(), time.process_time()
    out = call()
    timings[f"{name}_s"] = time.perf_counter() - start
    timings[f"{name}_cpu_s"] = time.process_time() - cpu
    return out


def _step_read_back(path: Path, control_points, triangles) -> dict:
    """The file read back: validity, faces, volume and area against the level-3
    tessellation, face samples' distance to it against its chord bound."""
    from OCP.BRep import BRep_Tool
    from OCP.BRepCheck import BRepCheck_Analyzer
    from OCP.BRepGProp import BRepGProp
    from OCP.GProp import GProp_GProps
    from OCP.TopAbs import TopAbs_FACE, TopAbs_SOLID
    from OCP.TopExp import TopExp_Explorer
    from OCP.TopoDS import TopoDS

    from pipeline.cad_export import read_cad_solid
    from surface import bezier
    from surface.metrics import point_mesh_distance

    row: dict = {}
    shape = _clocked(row, "read", lambda: read_cad_solid(path))
    row["solid"] = shape.ShapeType() == TopAbs_SOLID
    row["valid"] = bool(_clocked(row, "check", lambda: BRepCheck_Analyzer(shape).IsValid()))
    volume, area = GProp_GProps(), GProp_GProps()
    BRepGProp.VolumeProperties_s(shape, volume)
    BRepGProp.SurfaceProperties_s(shape, area)
    level = 3
    v, t, _ = bezier.tessellate(control_points, level, triangles)
    a, b, c = (v[t[:, i]] for i in range(3))
    tess_volume = float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)
    tess_area = float(0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1).sum())
    row["volume_rel_error"] = abs(volume.Mass() - tess_volume) / abs(tess_volume)
    row["area_rel_error"] = abs(area.Mass() - tess_area) / tess_area
    cp = control_points
    for _ in range(level):
        cp = bezier.subdivide(cp)
    row["chord_bound"] = float(bezier.chord_error_bound(cp).max())
    samples, faces = [], 0
    explorer = TopExp_Explorer(shape, TopAbs_FACE)
    grid = (0.1, 0.5, 0.9)
    while explorer.More():
        surface = BRep_Tool.Surface_s(TopoDS.Face(explorer.Current()))
        if faces % 10 == 0:  # every tenth face, 9 samples each
            u0, u1, v0, v1 = surface.Bounds()
            for u in grid:
                for w in grid:
                    p = surface.Value(u0 + u * (u1 - u0), v0 + w * (v1 - v0))
                    samples.append((p.X(), p.Y(), p.Z()))
        faces += 1
        explorer.Next()
    row["faces"] = faces
    row["sample_distance_max"] = float(point_mesh_distance(np.array(samples), v, t).max())
    return row


def _step_phases(control_points, triangles, path: Path, merge: bool) -> dict:
    """The STEP path through OpenCascade's shape transfer (``pipeline.cad_export.solid_from_nets``,
    ``STEPControl_Writer``; ``write_cad``'s path for open shells) phase by phase, the merge
    of duplicate entities optional."""
    from OCP.IFSelect import IFSelect_RetDone
    from OCP.Interface import Interface_Static
    from OCP.STEPControl import STEPControl_AsIs, STEPControl_Writer

    from pipeline import cad_export

    row: dict = {}
    solid = _clocked(row, "build", lambda: cad_export.solid_from_nets(control_points, triangles))
    writer = STEPControl_Writer()
    Interface_Static.SetCVal_s("write.step.schema", "AP214IS")
    Interface_Static.SetIVal_s("write.surfacecurve.mode", 0)
    ok = _clocked(row, "transfer", lambda: writer.Transfer(solid, STEPControl_AsIs))
    if merge:
        _clocked(row, "merge", writer.CleanDuplicateEntities)
    ok = ok == IFSelect_RetDone and _clocked(
        row, "write", lambda: writer.Write(str(path))) == IFSelect_RetDone
    row["ok"] = bool(ok)
    row["bytes"] = path.stat().st_size
    return row


def bench_step(control_points, triangles, folder: Path, read_back: bool = True) -> list[dict]:
    """``pipeline.cad_export.write_cad`` to STEP (its entities made directly, poles shared) with
    the file read back; the peers: the shape transfer, merged and unmerged, phase by phase
    (CPU and wall seconds), IGES, and the level-2 tessellation's PLY for scale."""
    from pipeline import cad_export
    from surface import bezier

    cad_export._quiet()
    cad_export.write_cad(folder / "warm.step", *_ellipsoid_net(64))  # imports, caches
    rows = []
    row = {"writer": "STEP (write_cad)", "patches": len(control_points)}
    path = _clocked(row, "total", lambda: cad_export.write_cad(folder / "s.step", control_points,
                                                         triangles))
    row["bytes"] = path.stat().st_size
    if read_back:
        row.update(_step_read_back(path, control_points, triangles))
    rows.append(row)
    for label, merge in (("STEP transfer + merge", True), ("STEP transfer, unmerged", False)):
        path = folder / f"{'merged' if merge else 'unmerged'}.step"
        rows.append({"writer": label, "patches": len(control_points),
                     **_step_phases(control_points, triangles, path, merge)})
    row = {"writer": "IGES (write_cad)", "patches": len(control_points)}
    path = _clocked(row, "total", lambda: cad_export.write_cad(folder / "s.iges", control_points,
                                                         triangles))
    row["bytes"] = path.stat().st_size
    rows.append(row)
    v, t, n = bezier.tessellate(control_points, 2, triangles)
    row = {"writer": "PLY, level-2 tessellation", "patches": len(control_points)}
    path = _clocked(row, "total", lambda: export_mesh(folder / "s.ply", v, t, n))
    row["bytes"] = path.stat().st_size
    rows.append(row)
    for row in rows:
        row["total_cpu_s"] = row.get("total_cpu_s", sum(
            row.get(f"{k}_cpu_s", 0.0) for k in ("build", "transfer", "merge", "write")))
        row["total_s"] = row.get("total_s", sum(
            row.get(f"{k}_s", 0.0) for k in ("build", "transfer", "merge", "write")))
    return rows


_FREECAD_SCRIPT = """
import os, resource, sys, time
import FreeCAD, Import
path = sys.argv[-1]
start, cpu = time.perf_counter(), time.process_time()
doc = FreeCAD.newDocument("d")
Import.insert(path, "d")
wall, cpu = time.perf_counter() - start, time.process_time() - cpu
shape = doc.Objects[0].Shape
check = os.environ.get("PHOTOSURF_FC_CHECK", "1") == "1"
print("FCRESULT %.3f %.3f %d %d %d %d %.0f" % (wall, cpu, len(shape.Faces), len(shape.Solids),
      shape.isValid() if check else -1, shape.isClosed() if check else -1,
      resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024), flush=True)
os._exit(0)  # freecadcmd would open the file argument again after the script
"""


def _freecad_open(path: Path, folder: Path, check: bool = True) -> dict:
    """FreeCAD opening ``path`` (``freecadcmd``, its STEP importer into a document), when
    installed: wall and CPU seconds of the import, faces, solids, validity and closure
    (``check``: FreeCAD's own, after the timed import), peak RSS."""
    import os
    import shutil
    import subprocess

    if shutil.which("freecadcmd") is None:
        return {}
    script = folder / "freecad_open.py"
    script.write_text(_FREECAD_SCRIPT)
    done = subprocess.run(["freecadcmd", str(script), str(path)], capture_output=True,
                          text=True, timeout=3600,
                          env={**os.environ, "PHOTOSURF_FC_CHECK": "1" if check else "0"})
    for line in (done.stdout + done.stderr).splitlines():
        if "FCRESULT" in line:
            cells = line.split("FCRESULT", 1)[1].split()
            row = {"freecad_open_s": float(cells[0]), "freecad_open_cpu_s": float(cells[1]),
                   "freecad_faces": int(cells[2]), "freecad_solids": int(cells[3]),
                   "freecad_rss_mb": float(cells[6])}
            if check:
                row.update(freecad_valid=bool(int(cells[4])), freecad_closed=bool(int(cells[5])))
            return row
    return {"freecad_error": (done.stderr or done.stdout)[-300:]}


#: OpenCascade's peak memory reading a STEP file, per byte of the file (2026-12-07): 13 for
#: the demo's 116 MB two-span file (1.49 GB); over 35 for the temple's 201 MB one-span file
#: (7 GB and rising when stopped).
READ_BYTES_PER_BYTE = 35


def _mesh_measures(control_points, triangles):
    """The level-3 tessellation's volume and area, computed once when first asked."""
    from surface import bezier

    @functools.cache
    def measures() -> tuple[float, float]:
        v, t, _ = bezier.tessellate(control_points, 3, triangles)
        a, b, c = (v[t[:, i]] for i in range(3))
        return (abs(float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)),
                float(0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1).sum()))
    return measures


def _occ_read(path: Path, mesh_measures) -> dict:
    """``path`` read by OpenCascade (``ReadFile``, ``TransferRoots``,
    ``BRepCheck_Analyzer``; CPU seconds), its faces, volume and area against the
    level-3 tessellation (``mesh_measures()``)."""
    from OCP.BRepCheck import BRepCheck_Analyzer
    from OCP.BRepGProp import BRepGProp
    from OCP.GProp import GProp_GProps
    from OCP.STEPControl import STEPControl_Reader
    from OCP.TopAbs import TopAbs_FACE, TopAbs_SOLID
    from OCP.TopExp import TopExp_Explorer

    row: dict = {}
    reader = STEPControl_Reader()
    _clocked(row, "occ_parse", lambda: reader.ReadFile(str(path)))
    _clocked(row, "occ_transfer", reader.TransferRoots)
    shape = reader.OneShape()
    row["occ_solid"] = shape.ShapeType() == TopAbs_SOLID
    row["occ_valid"] = bool(_clocked(row, "occ_check",
                                     lambda: BRepCheck_Analyzer(shape).IsValid()))
    row["occ_read_cpu_s"] = row["occ_parse_cpu_s"] + row["occ_transfer_cpu_s"]
    faces, explorer = 0, TopExp_Explorer(shape, TopAbs_FACE)
    while explorer.More():
        faces += 1
        explorer.Next()
    row["faces"] = faces
    volume, area = GProp_GProps(), GProp_GProps()
    BRepGProp.VolumeProperties_s(shape, volume)
    BRepGProp.SurfaceProperties_s(shape, area)
    mesh_volume, mesh_area = mesh_measures()
    row["volume_rel_error"] = abs(volume.Mass() - mesh_volume) / mesh_volume
    row["area_rel_error"] = abs(area.Mass() - mesh_area) / mesh_area
    return row


#: ``--light`` variants: the file the export stage writes (control-triangle faces, two
#: spans), the quadrilateral faces, and the default faces at a distance uncertainty of a
#: tenth of the merge tolerance (6 decimals on the demo instead of 8).
LIGHT_VARIANTS = ("default", "quads", "uncertainty")


def _light_file(name: str, path: Path, control_points, triangles, source_face,
                tolerance: float, report: dict) -> None:
    from pipeline import cad_export

    if name == "uncertainty":
        merged = cad_export._merged(control_points, triangles, source_face, tolerance, report, 2)
        if merged is not None:
            cad_export._write_merged_step_text(merged, path, tolerance / 10)
            report.update(faces=len(merged["poles"]), merged=True)
        else:  # as write_cad: the exact per-patch file
            cad_export._write_step_text(control_points, triangles, path, True, tolerance / 10)
            report.update(faces=len(control_points), merged=False)
        return
    cad_export.write_cad(path, control_points, triangles, source_face=source_face,
                   tolerance=tolerance, report=report, quads=name == "quads")


def bench_step_light(control_points, triangles, folder: Path, source_face, tolerance: float,
                     variants=("default",), repeats: int = 2, freecad: bool = True
                     ) -> list[dict]:
    """The STEP file as the export stage writes it and the given ``variants`` (of
    :data:`LIGHT_VARIANTS`): write CPU seconds, bytes, OpenCascade's read (once), and
    FreeCAD's import ``repeats`` times, the files taken in turn each round (so that the
    machine's load falls on all alike); the first import of each also checks validity."""
    from pipeline import cad_export

    cad_export._quiet()
    mesh_measures = _mesh_measures(control_points, triangles)
    rows, paths = [], []
    for name in variants:
        row: dict = {"variant": name, "patches": len(control_points)}
        path, report = folder / f"light_{name}.step", {}
        _clocked(row, "write", lambda n=name, p=path, r=report: _light_file(
            n, p, control_points, triangles, source_face, tolerance, r))
        row.update({"bytes": path.stat().st_size, "read": True,
                    **{f"merge_{k}": v for k, v in report.items()}})
        row.update(_occ_read(path, mesh_measures))
        rows.append(row)
        paths.append(path)
    for repeat in range(repeats if freecad else 0):
        for row, path in zip(rows, paths, strict=True):
            opened = _freecad_open(path, folder, check=repeat == 0)
            row.setdefault("freecad_runs", []).append(opened)
            if repeat == 0:
                row.update(opened)
    for row in rows:
        cpu = [r["freecad_open_cpu_s"] for r in row.get("freecad_runs", [])
               if "freecad_open_cpu_s" in r]
        if cpu:
            row["freecad_open_cpu_s"] = float(np.median(cpu))
            row["freecad_open_cpu_s_runs"] = cpu
    return rows


def bench_step_read(control_points, triangles, folder: Path, freecad: bool = True,
                    source_face=None, tolerance: float | None = None,
                    variants: str = "all", read_limit_mb: float | None = None) -> list[dict]:
    """What a CAD program does with the STEP file: the variants of ``write_cad``'s text
    (pcurves or not; distance uncertainty ``1e-9 size`` as before, or
    ``step_uncertainty``; given ``source_face`` and ``tolerance``, also one face per
    control triangle, ``spans`` 2 and 1, and quadrilaterals), each written, read by OpenCascade
    (``ReadFile``, ``TransferRoots``, ``BRepCheck_Analyzer``; CPU seconds), volume and
    area against the level-3 tessellation, and opened by FreeCAD when ``freecadcmd`` is
    installed.  ``variants`` ``"faces"``: only the per-patch file as written now and
    the merged ones.  A file larger than ``read_limit_mb`` is written and measured but
    not read (``read: False``): reading holds up to :data:`READ_BYTES_PER_BYTE` times its size."""
    from pipeline import cad_export

    cad_export._quiet()
    mesh_measures = _mesh_measures(control_points, triangles)

    size = float(np.ptp(control_points.reshape(-1, 3), axis=0).max())
    rows = []
    plans = [(pcurves, floor, None) for pcurves, floor in
             ((False, False), (False, True), (True, False), (True, True))]
    if variants == "faces":
        plans = [(True, True, None)]
    if source_face is not None and tolerance is not None:
        plans += [(True, True, "quad"), (True, True, 2), (True, True, 1)]
    for pcurves, floor, spans in plans:
        row = {"variant": f"{'pcurves' if pcurves else 'no pcurves'}, uncertainty "
                          f"{'max(1e-9 size, 1e-7)' if floor else '1e-9 size'}",
               "pcurves": pcurves, "uncertainty": cad_export.step_uncertainty(size) if floor
               else cad_export.REL_TOLERANCE * size, "patches": len(control_points)}
        path = folder / f"read_{int(pcurves)}{int(floor)}{spans or 0}.step"
        if spans is None:
            _clocked(row, "write", lambda p=path, c=pcurves, r=row: cad_export._write_step_text(
                control_points, triangles, p, c, r["uncertainty"]))
        else:
            row["variant"] = ("quadrilaterals (two control triangles), two spans"
                              if spans == "quad" else
                              f"a face per control triangle, {spans} span(s)")
            report: dict = {}
            _clocked(row, "write", lambda p=path, r=report, n=spans: cad_export.write_cad(
                p, control_points, triangles, source_face=source_face,
                tolerance=tolerance, report=r, spans=1 if n == 1 else 2, quads=n == "quad",
                angle_tolerance=None if n != 1 else np.inf))  # one span: kinks measured
            row.update({f"merge_{k}": v for k, v in report.items()})
        row["bytes"] = path.stat().st_size
        row["read"] = read_limit_mb is None or row["bytes"] <= read_limit_mb * 1e6
        if not row["read"]:
            rows.append(row)
            path.unlink()
            continue
        row.update(_occ_read(path, mesh_measures))
        if freecad:
            row.update(_freecad_open(path, folder))
        rows.append(row)
        path.unlink()
    return rows


def _print_step_read(rows: list[dict]) -> None:
    print(f"\nSTEP read back: {rows[0]['patches']} patches (OpenCascade CPU seconds; FreeCAD "
          "wall/CPU seconds of its import, when installed)")
    print(f"{'variant':<44}{'MB':>7}{'write':>7}{'parse':>7}{'transfer':>9}{'check':>7}"
          f"{'valid':>6}{'faces':>7}{'dV':>9}{'dA':>9}{'FC wall':>8}{'FC cpu':>8}{'FC MB':>7}")
    for r in rows:
        if not r["read"]:
            print(f"{r['variant'][:43]:<44}{r['bytes'] / 1e6:>7.1f}{r['write_cpu_s']:>7.1f}"
                  f"  not read (over --read-limit-mb)")
            continue
        fc = "".join(f"{r[k]:>{w}.{d}f}" if k in r else f"{'-':>{w}}" for k, w, d in
                     (("freecad_open_s", 8, 1), ("freecad_open_cpu_s", 8, 1),
                      ("freecad_rss_mb", 7, 0)))
        print(f"{r['variant'][:43]:<44}{r['bytes'] / 1e6:>7.1f}{r['write_cpu_s']:>7.1f}"
              f"{r['occ_parse_cpu_s']:>7.1f}{r['occ_transfer_cpu_s']:>9.1f}"
              f"{r['occ_check_cpu_s']:>7.1f}{str(r['occ_valid'] and r['occ_solid']):>6}"
              f"{r['faces']:>7}{r['volume_rel_error']:>9.1e}{r['area_rel_error']:>9.1e}{fc}")
    for r in rows:
        if "merge_deviation" in r:
            print(f"  {r['variant']}: merged {r.get('merge_merged')}, normal offset "
                  f"{r['merge_deviation']:.2e} (tolerance {r['merge_tolerance']:.2e}), slide "
                  f"{r['merge_slide']:.2e}, largest angle to the patches' normal along the "
                  f"sides {r['merge_angle_deg']:.3g} deg")


def _print_step(rows: list[dict], source: str) -> None:
    print(f"\nCAD export of {source}: {rows[0]['patches']} patches "
          f"(CPU seconds; wall in the JSON)")
    print(f"{'writer':<27}{'build':>7}{'transfer':>9}{'merge':>7}{'write':>7}{'total':>7}"
          f"{'ms/patch':>9}{'MB':>8}{'KB/patch':>9}")
    for r in rows:
        cells = "".join(f"{r[f'{k}_cpu_s']:>{w}.1f}" if f"{k}_cpu_s" in r else f"{'-':>{w}}"
                        for k, w in (("build", 7), ("transfer", 9), ("merge", 7), ("write", 7)))
        print(f"{r['writer']:<27}{cells}{r['total_cpu_s']:>7.1f}"
              f"{r['total_cpu_s'] / r['patches'] * 1e3:>9.2f}{r['bytes'] / 1e6:>8.1f}"
              f"{r['bytes'] / r['patches'] / 1e3:>9.2f}")
    r = rows[0]
    if "valid" in r:
        print(f"read back: {r['read_s']:.1f} s, {r['faces']} faces, solid {r['solid']}, valid "
              f"{r['valid']} (BRepCheck {r['check_s']:.1f} s); volume {r['volume_rel_error']:.1e}, "
              f"area {r['area_rel_error']:.1e} from the level-3 tessellation; face samples "
              f"within {r['sample_distance_max']:.1e} of it (chord bound {r['chord_bound']:.1e})")


def _run_light(args, control_points, domain, source_face, tolerance: float,
               cad_source: str) -> None:
    """``--light``: :func:`bench_step_light`, its table and JSON."""
    variants = ["default"] + [v for v in args.light if v != "default"]
    with tempfile.TemporaryDirectory() as tmp:
        rows = bench_step_light(control_points, domain, Path(tmp), source_face, tolerance,
                                variants, args.repeats, freecad=not args.no_freecad)
    print(f"\nCAD: {cad_source}")
    _print_step_read(rows)
    for r in rows:
        if "freecad_open_cpu_s_runs" in r:
            print(f"  {r['variant']}: FreeCAD CPU-s "
                  + ", ".join(f"{c:.2f}" for c in r["freecad_open_cpu_s_runs"]))
    write_result(args.json, {"cad_light": {"source": cad_source, "rows": rows,
                                           "repeats": args.repeats}})


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small mesh, one repeat")
    parser.add_argument("--triangles", type=int, default=None,
                        help="triangles of the test sphere (default 1e6, --quick 5e4)")
    parser.add_argument("--patches", type=int, default=None,
                        help="patches of the ellipsoid written to STEP (default 4000, --quick 500)")
    parser.add_argument("--net", default=None,
                        help="a workspace's smooth/ folder: write its control net instead")
    parser.add_argument("--no-read-back", action="store_true",
                        help="skip reading the STEP file back (large nets)")
    parser.add_argument("--step-only", action="store_true",
                        help="only the STEP rows (no mesh formats, no renders)")
    parser.add_argument("--no-freecad", action="store_true",
                        help="skip opening the STEP variants in FreeCAD (freecadcmd)")
    parser.add_argument("--cad-tolerance", type=float, default=None,
                        help="largest distance of a merged face from the patches (default: "
                             "the smooth stage's chord tolerance of --net, else 1e-5 size)")
    parser.add_argument("--faces-only", action="store_true",
                        help="STEP read rows: only the per-patch file and the merged ones")
    parser.add_argument("--read-limit-mb", type=float, default=150.0,
                        help="write but do not read back STEP files larger than this "
                             f"(reading holds up to {READ_BYTES_PER_BYTE}x the file; default 150: "
                             "the demo's files are read, the temple's not)")
    parser.add_argument("--light", nargs="*", default=None, metavar="VARIANT",
                        choices=LIGHT_VARIANTS,
                        help="only the STEP file the export stage writes and the named "
                             f"variants ({', '.join(LIGHT_VARIANTS[1:])}) beside it, each "
                             "read once by OpenCascade and opened --repeats times by FreeCAD "
                             "in turn: minutes instead of the full run's half hour")
    parser.add_argument("--repeats", type=int, default=2,
                        help="--light: FreeCAD imports of each file (default 2)")
    parser.add_argument("--json", default=str(Path(__file__).parent / "results" / "export.json"))
    args = parser.parse_args(argv)
    import open3d as o3d

    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)  # open3d's GLB warning
    if args.net:
        from pipeline.artifacts import read_control_net

        net = read_control_net(args.net)
        cad_source = f"the control net in {args.net}"
        control_points, domain = net["control_points"], net["domain_triangles"]
        source_face = net.get("source_face")
    else:
        control_points, domain, source_face = _ellipsoid_net(
            args.patches or (500 if args.quick else 4000), with_source=True)
        cad_source = "Loop's surface over an ellipsoid"
    # the merged faces' tolerance: given, else the chord tolerance the smooth stage
    # recorded for the net, else 1e-5 of the size
    tolerance = args.cad_tolerance or _recorded_tolerance(args.net) or \
        1e-5 * float(np.ptp(control_points.reshape(-1, 3), axis=0).max())
    cad_source += f"; merged faces within {tolerance:.3g}"
    if args.light is not None:
        _run_light(args, control_points, domain, source_face, tolerance, cad_source)
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        cad_read = bench_step_read(control_points, domain, Path(tmp),
                                   freecad=not args.no_freecad, source_face=source_face,
                                   tolerance=tolerance,
                                   variants="faces" if args.faces_only else "all",
                                   read_limit_mb=args.read_limit_mb)
    result = {"cad_read": {"source": cad_source, "rows": cad_read}}
    if not args.step_only:
        count = args.triangles or (50_000 if args.quick else 1_000_000)
        repeats = 1 if args.quick else 3
        vertices, triangles, normals = _sphere(count)
        with tempfile.TemporaryDirectory() as tmp:
            formats = bench_formats(vertices, triangles, normals, Path(tmp))
        renders = bench_render(vertices, triangles, normals, repeats)
        with tempfile.TemporaryDirectory() as tmp:
            cad = bench_step(control_points, domain, Path(tmp), read_back=not args.no_read_back)
        print(f"mesh: sphere, {len(vertices)} vertices, {len(triangles)} triangles")
        print(f"{'writer':<16}{'write s':>9}{'MB':>8}{'read s':>8}{'read tris':>11}"
              f"{'pos err':>10}{'normal err':>11}")
        for r in formats:
            pe = "-" if r["position_error"] is None else f"{r['position_error']:.1e}"
            ne = "-" if r["normal_error"] is None else f"{r['normal_error']:.1e}"
            print(f"{r['writer']:<16}{r['write_s']:>9.3f}{r['bytes'] / 1e6:>8.1f}"
                  f"{r['read_s']:>8.3f}{r['triangles_read']:>11}{pe:>10}{ne:>11}")
        print()
        for r in renders:
            print(f"{r['render']:<45}{r['seconds']:>8.3f} s")
        _print_step(cad, cad_source)
        result.update({"vertices": len(vertices), "triangles": len(triangles),
                       "formats": formats, "render": renders,
                       "cad": {"source": cad_source, "rows": cad}})
    print(f"\nCAD: {cad_source}")
    _print_step_read(cad_read)
    out = Path(args.json)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1))
    print(f"\nwrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
