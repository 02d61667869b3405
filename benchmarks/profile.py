"""Benchmark of the profile measures, volume and capacity against exact and real truth.

Synthetic vessels of revolution with analytic profiles (exact truth): the tapered cup of
``testkit/cup.py`` (flat base, straight walls 5 mm apart, round lip) and a hemispherical
bowl (spherical shell, outer radius 60, inner 55, cut flat at 45 mm).  Each is measured
two ways: (1) ``mesh``: the revolved polygon mesh (128 azimuths) itself; (2) ``smooth``:
Loop's sextic surface through a coarser revolved mesh (96 and 48 azimuths; the pipeline's
interpolating control mesh, sharp edges kept: ``surface.sizing.interpolating_control``),
volume and area exact over its patches, profile and capacity on its tessellation; and,
as the cause of the earlier 48-azimuth shortfall, Loop's approximating surface over the
mesh's vertices themselves, which lies inside their polygon.  Truth: height, rim, base and
maximum diameters, wall thickness (normal to the wall) at mid height, the solid's volume
``pi int (r_out^2 - r_in^2) dz`` and the capacity ``pi int r_in^2 dz`` up to 2/3 of the
height.  Beside the exact patch integral, the volume of the smooth surface's tessellation
(signed tetrahedra of its flat triangles): the chord error the exact integral avoids.
open3d's ``TriangleMesh.get_volume`` is no peer here: it first checks watertightness with its
all-pairs self-intersection test, which had not finished after 3.5 CPU-minutes on the
45 824-triangle cup mesh (killed).

The real scan: the YCB mustard bottle (``../shared/data/real/scans``, metres, closed):
its mesh's profile (height and the major/minor profiles' maximum diameters against the
mesh's extent), and -- without ``--quick`` -- ``--points`` points sampled on it by area
(seeded), reconstructed by ``photosurf sections --smooth --axis z``: the smooth
surface's exact volume and its profile against the truth mesh's.

Run: ``.venv/bin/python benchmarks/profile.py [--quick] [--json PATH]``
(default JSON ``benchmarks/results/profile.json``).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))     # before this folder: benchmarks/surface.py is no package

import numpy as np  # noqa: E402
from _common import print_goals, uptime, write_result  # noqa: E402

from pipeline import cmd_profile  # noqa: E402
from surface import bezier  # noqa: E402
from surface.profile import revolve  # noqa: E402
from surface.sizing import interpolating_control  # noqa: E402
from testkit import cup as _cup  # noqa: E402

SCANS = ROOT.parent / "shared" / "data" / "real" / "scans"
Z = np.array([0.0, 0.0, 1.0])


# ----------------------------------------------------------------------------- vessels
def _cup_truth() -> dict:
    zt = _cup.H - _cup.W / 2
    # outer solid: frustum to zt and the lip's half disc swept round its centre radius
    # (Pappus: the half disc is symmetric about r_c = RT - W/2); minus the cavity to zt
    frustum = np.pi * zt / 3 * (_cup.RB ** 2 + _cup.RB * _cup.RT + _cup.RT ** 2)
    lip = np.pi * (_cup.W / 2) ** 2 / 2 * 2 * np.pi * (_cup.RT - _cup.W / 2)
    cavity_top = _cup.analytic_capacity(zt)
    return {"profile": _cup.cup_profile(wall=60, base=20, lip=25),
            "coarse": _cup.cup_profile(wall=24, base=10, lip=7),
            "height": _cup.H, "rim_diameter": 2 * _cup.RT, "base_diameter": 2 * _cup.RB,
            "max_diameter": 2 * _cup.RT, "max_diameter_height": zt,
            "thickness_at": 45.0, "thickness": _cup.W / np.hypot(1.0, _cup.K),
            "volume": frustum + lip - cavity_top,
            "fill": 60.0, "capacity": _cup.analytic_capacity(60.0)}


RO, RI, CUT = 60.0, 55.0, 45.0  # the bowl: spherical shell about (0, 0, RO), cut at CUT


def _bowl_profile(n: int) -> np.ndarray:
    """Half-section: outer arc from the bottom pole to the cut, inner arc back down."""
    zc = RO
    a_o = np.linspace(0.0, np.arccos((zc - CUT) / RO), n)
    outer = np.column_stack([RO * np.sin(a_o), zc - RO * np.cos(a_o)])
    a_i = np.linspace(np.arccos((zc - CUT) / RI), 0.0, n)
    inner = np.column_stack([RI * np.sin(a_i), zc - RI * np.cos(a_i)])
    return np.vstack([outer, inner])


def _bowl_truth() -> dict:
    def cap(h, r):  # volume of a spherical cap of height h of a sphere of radius r
        return np.pi * h ** 2 * (3 * r - h) / 3
    inner_bottom = RO - RI
    fill = 30.0
    r_rim = np.sqrt(RO ** 2 - (RO - CUT) ** 2)
    return {"profile": _bowl_profile(120), "coarse": _bowl_profile(28),
            "height": CUT, "rim_diameter": 2 * r_rim, "base_diameter": 0.0,
            "max_diameter": 2 * r_rim, "max_diameter_height": CUT,
            "thickness_at": 20.0, "thickness": RO - RI,
            "volume": cap(CUT, RO) - cap(CUT - inner_bottom, RI),
            "fill": fill, "capacity": cap(fill - inner_bottom, RI)}


VESSELS = {"cup": _cup_truth, "bowl": _bowl_truth}


def _measures(surface: dict, truth: dict) -> dict:
    t0 = time.perf_counter()
    fig = cmd_profile.profile_figures(surface, Z, heights=[truth["thickness_at"]],
                                      fill=truth["fill"])
    seconds = time.perf_counter() - t0
    p = fig["profiles"][0]
    return {"seconds": seconds, "uncertainty": fig["uncertainty"],
            "height": fig["height"], "rim_diameter": p["rim_diameter"],
            "base_diameter": p["base_diameter"], "max_diameter": p["max_diameter"],
            "thickness": p["thickness"].get(truth["thickness_at"]),
            "volume": fig["volume"], "area": fig["area"], "integrals": fig["integrals"],
            "capacity": None if fig["capacity"] is None else fig["capacity"]["volume"],
            "capacity_sigma": None if fig["capacity"] is None else fig["capacity"]["sigma"]}


def _tessellation_volume(surface: dict) -> float:
    from surface.measure import mesh_volume

    return mesh_volume(surface["vertices"], surface["triangles"])


def vessel_rows(name: str) -> list[dict]:
    truth = VESSELS[name]()
    rows = []
    vertices, triangles = revolve(truth["profile"], 128)
    mesh = cmd_profile.mesh_surface(vertices, triangles)
    rows.append({"vessel": name, "route": "mesh 128", **_measures(mesh, truth),
                 "tessellation_volume": None})
    for azimuths, construction in ((96, "interpolating"), (48, "interpolating"),
                                   (48, "approximating")):
        coarse_v, coarse_t = revolve(truth["coarse"], azimuths)
        # the pipeline's surface passes through the mesh's vertices (sharp edges kept);
        # Loop's surface over the vertices themselves lies inside their polygon
        control = (interpolating_control(coarse_v, coarse_t)
                   if construction == "interpolating" else coarse_v)
        net = bezier.control_net(control, coarse_t)
        smooth = cmd_profile._net_surface(net.control_points, net.domain_mesh[1], name)
        rows.append({"vessel": name, "route": f"{construction[:6]}. {azimuths} az",
                     "azimuths": azimuths, "construction": construction,
                     "patches": len(net.control_points),
                     **_measures(smooth, truth), "level": smooth["level"],
                     "tessellation_volume": _tessellation_volume(smooth)})
    for r in rows:
        r["truth"] = {k: v for k, v in truth.items() if not isinstance(v, np.ndarray)}
    return rows


# ----------------------------------------------------------------------------- the scan
def _sample(vertices, triangles, count: int, seed: int = 7) -> np.ndarray:
    """Area-weighted points on a mesh (seeded: open3d's sampler takes no seed)."""
    rng = np.random.default_rng(seed)
    tri = vertices[triangles]
    area = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    pick = rng.choice(len(tri), count, p=area / area.sum())
    u, v = rng.random(count), rng.random(count)
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    t = tri[pick]
    return t[:, 0] + u[:, None] * (t[:, 1] - t[:, 0]) + v[:, None] * (t[:, 2] - t[:, 0])


def scan_rows(points: int, quick: bool) -> list[dict]:
    path = SCANS / "ycb_mustard_bottle" / "mesh.obj"
    if not path.is_file():
        print(f"no scan at {path}")
        return []
    truth_surface = cmd_profile.read_surface(path)
    v, f = truth_surface["vertices"], truth_surface["triangles"]
    fig = cmd_profile.profile_figures(truth_surface, Z)
    from surface.measure import mesh_volume
    from surface.profile import frame

    e1, e2, _ = frame(Z)
    truth_volume = mesh_volume(v, f)
    rows = []
    for p in fig["profiles"]:
        phi = np.radians(p["azimuth_deg"])
        extent = float(np.ptp(v @ (np.cos(phi) * e1 + np.sin(phi) * e2)))
        rows.append({"vessel": "mustard", "route": f"truth mesh, {p['azimuth_deg']:.0f} deg",
                     "height": fig["height"], "truth_height": float(np.ptp(v[:, 2])),
                     "max_diameter": p["max_diameter"], "truth_extent": extent,
                     "volume": fig["volume"], "truth_volume": truth_volume})
    if quick:
        return rows
    with tempfile.TemporaryDirectory() as tmp:
        cloud = Path(tmp) / "cloud.npz"
        np.savez(cloud, points=_sample(v, f, points))
        out = Path(tmp) / "smooth.ply"
        t0 = time.perf_counter()
        run = subprocess.run([sys.executable, "-m", "pipeline.cli", "sections", str(cloud),
                              "--out", str(out), "--smooth", "--axis", "z", "-q"],
                             cwd=ROOT, capture_output=True, text=True, timeout=900)
        seconds = time.perf_counter() - t0
        if run.returncode != 0:
            print(f"photosurf sections failed: {run.stderr.strip()}")
            return rows
        smooth = cmd_profile.read_surface(out.with_suffix(".npz"))
        sfig = cmd_profile.profile_figures(smooth, Z)
    for p, tp in zip(sfig["profiles"], fig["profiles"], strict=False):
        rows.append({"vessel": "mustard", "route": f"smooth from {points} points, "
                     f"{p['azimuth_deg']:.0f} deg",
                     "height": sfig["height"], "truth_height": fig["height"],
                     "max_diameter": p["max_diameter"], "truth_extent": tp["max_diameter"],
                     "volume": sfig["volume"], "truth_volume": truth_volume,
                     "reconstruct_seconds": seconds, "patches": len(smooth["control_points"])})
    return rows


#: The real scans (``SCANS``): mesh file and the axis they are sectioned and measured along
#: (the up axis ``SOURCE.md`` states, else None: the truth mesh's principal axis).
SCAN_AXES = {"ycb_mustard_bottle": "z", "ycb_power_drill": None, "ycb_banana": None,
             "nefertiti": "z", "igea": None, "cow": "y", "fandisk": None, "teapot": "y"}


def _scan_axis(name: str, vertices: np.ndarray) -> np.ndarray:
    given = SCAN_AXES[name]
    if given is not None:
        return np.eye(3)["xyz".index(given)]
    centred = vertices - vertices.mean(axis=0)
    axis = np.linalg.eigh(centred.T @ centred)[1][:, -1]  # largest spread
    return axis * np.sign(axis[np.argmax(np.abs(axis))])


def _figures_or_error(surface: dict, axis: np.ndarray) -> dict:
    """The profile's height and maximum diameters, volume and area, or the error."""
    try:
        fig = cmd_profile.profile_figures(surface, axis)
    except Exception as exc:  # noqa: BLE001  (a non-vessel may have no profile: say so)
        return {"error": f"{type(exc).__name__}: {exc}"[:200]}
    return {"height": fig["height"], "volume": fig["volume"], "area": fig["area"],
            "max_diameters": [p["max_diameter"] for p in fig["profiles"]],
            "azimuths_deg": [p["azimuth_deg"] for p in fig["profiles"]]}


def _reconstruct(points: np.ndarray, axis: np.ndarray, folder: Path) -> tuple[dict, dict]:
    """``photosurf sections --smooth`` over ``points`` along ``axis``: the surface as
    ``cmd_profile.read_surface`` reads it (None on failure) and the run's facts."""
    cloud = folder / "cloud.npz"
    np.savez(cloud, points=points)
    out = folder / "smooth.ply"
    t0, cpu0 = time.perf_counter(), os.times()
    try:
        run = subprocess.run([sys.executable, "-m", "pipeline.cli", "sections", str(cloud),
                              "--out", str(out), "--smooth",
                              "--axis=" + ",".join(f"{c:.9f}" for c in axis), "-q"],
                             cwd=ROOT, capture_output=True, text=True, timeout=1200)
    except subprocess.TimeoutExpired:
        return None, {"error": "photosurf sections: over 1200 s"}
    cpu1 = os.times()
    facts = {"reconstruct_s": time.perf_counter() - t0,
             "reconstruct_cpu_s": (cpu1.children_user - cpu0.children_user
                                   + cpu1.children_system - cpu0.children_system)}
    if run.returncode != 0:
        return None, {**facts, "error": (run.stderr.strip().splitlines() or ["?"])[-1][:200]}
    surface = cmd_profile.read_surface(out.with_suffix(".npz"))
    return surface, {**facts, "patches": len(surface["control_points"])}


def all_scan_rows(points: int, names: list[str], json_path: str | None = None) -> list[dict]:
    """Each real scan: the truth mesh's profile height, maximum diameters, volume and area
    along its axis, and the same of the smooth surface ``photosurf sections --smooth``
    makes from ``points`` points sampled on it by area (seeded); igea has points only
    (a subsample of them is the cloud, no truth figures); a mesh that is not closed (the
    cow, the teapot's four pieces) has no truth volume.  ``json_path``: the rows so far,
    written after each scan."""
    from pipeline.errors import InputError
    from pipeline.mesh_io import read_mesh
    from surface.metrics import mesh_topology

    rows = []
    for name in names:
        path = next(iter(sorted((SCANS / name).glob("mesh.*"))), None)
        if path is None:
            continue
        print(f"scan {name} ...", flush=True)
        try:
            vertices, triangles = read_mesh(path)
        except InputError:  # points only (igea)
            import open3d as o3d

            vertices = np.asarray(o3d.io.read_point_cloud(str(path)).points, dtype=np.float64)
            triangles = np.empty((0, 3), dtype=np.int64)
        row: dict = {"scan": name, "points": points}
        if len(triangles) == 0:  # points only
            cloud = vertices[np.random.default_rng(7).choice(len(vertices), points,
                                                             replace=False)]
            axis = _scan_axis(name, vertices)
            row["truth"] = None
        else:
            cloud = _sample(vertices, triangles, points)
            axis = _scan_axis(name, vertices)
            # an OBJ repeats a vertex along texture seams: closed is judged on positions
            _, weld = np.unique(vertices, axis=0, return_inverse=True)
            closed = bool(mesh_topology(vertices, weld.reshape(-1)[triangles])["closed"])
            truth = _figures_or_error(cmd_profile.mesh_surface(vertices, triangles), axis)
            if not closed:
                truth.pop("volume", None)
            row["truth"] = {"closed": closed, **truth}
        row["axis"] = axis.tolist()
        with tempfile.TemporaryDirectory() as tmp:
            surface, facts = _reconstruct(cloud, axis, Path(tmp))
        row.update(facts)
        if surface is not None:
            row["smooth"] = _figures_or_error(surface, axis)
        rows.append(row)
        print_all_scans([row])
        if json_path:  # each scan's row as soon as it is measured
            write_result(json_path, {"scans": rows, "points": points})
    return rows


# ----------------------------------------------------------------------------- report
def _rel(a, b):
    return None if a is None or b is None or b == 0 else a / b - 1


def print_vessels(rows: list[dict]) -> None:
    print(f"\n{'vessel':<6} {'route':<22} {'u':>7} {'dH':>8} {'dRim':>8} {'dBase':>8} "
          f"{'dMax':>8} {'dWall':>8} {'vol rel':>9} {'tess rel':>9} {'cap rel':>9} "
          f"{'cap/u.A':>7} {'s':>5}")
    for r in rows:
        t = r["truth"]

        def d(key, r=r, t=t):
            return f"{r[key] - t[key]:>8.3f}" if r[key] is not None else f"{'-':>8}"
        tess_rel = _rel(r["tessellation_volume"], t["volume"])
        cap_rel = _rel(r["capacity"], t["capacity"])
        within = (abs(r["capacity"] - t["capacity"]) / r["capacity_sigma"]
                  if r["capacity_sigma"] else float("nan"))
        print(f"{r['vessel']:<6} {r['route']:<22} {r['uncertainty']:>7.3f} {d('height')} "
              f"{d('rim_diameter')} {d('base_diameter')} {d('max_diameter')} "
              f"{r['thickness'] - t['thickness']:>8.3f} "
              f"{_rel(r['volume'], t['volume']):>9.2e} "
              f"{'-' if tess_rel is None else f'{tess_rel:.2e}':>9} {cap_rel:>9.2e} "
              f"{within:>7.2f} {r['seconds']:>5.1f}")


def print_scan(rows: list[dict]) -> None:
    print(f"\n{'route':<36} {'height':>8} {'truth':>8} {'maxD':>8} {'extent':>8} "
          f"{'volume':>10} {'truth':>10} {'rel':>9}")
    for r in rows:
        print(f"{r['route']:<36} {r['height']:>8.4f} {r['truth_height']:>8.4f} "
              f"{r['max_diameter']:>8.4f} {r['truth_extent']:>8.4f} {r['volume']:>10.4e} "
              f"{r['truth_volume']:>10.4e} {_rel(r['volume'], r['truth_volume']):>9.2e}")


def print_all_scans(rows: list[dict]) -> None:
    for r in rows:
        t, s = r.get("truth") or {}, r.get("smooth") or {}
        def cell(d, k, fmt):
            v = d.get(k)
            return format(v, fmt) if isinstance(v, float) else "-"
        print(f"{r['scan']:<20} height {cell(s, 'height', '.4g')} / {cell(t, 'height', '.4g')}"
              f"  max diameter {s.get('max_diameters', '-')} / {t.get('max_diameters', '-')}"
              f"  volume {cell(s, 'volume', '.5g')} / {cell(t, 'volume', '.5g')} "
              f"({_rel(s.get('volume'), t.get('volume')) or float('nan'):+.2e})"
              f"  area {cell(s, 'area', '.5g')} / {cell(t, 'area', '.5g')} "
              f"({_rel(s.get('area'), t.get('area')) or float('nan'):+.2e})"
              f"  {r.get('reconstruct_cpu_s', float('nan')):.0f} CPU-s"
              f"  {r.get('error', '') or s.get('error', '') or t.get('error', '')}", flush=True)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true",
                        help="no reconstruction of the scan from sampled points")
    parser.add_argument("--points", type=int, default=40_000)
    parser.add_argument("--scans", nargs="*", default=None, metavar="NAME",
                        help="only the real scans (all eight when no NAME): truth mesh "
                             "against the smooth surface from --points points")
    parser.add_argument("--json", default="benchmarks/results/profile.json")
    args = parser.parse_args(argv)
    if args.scans is not None:
        names = args.scans or list(SCAN_AXES)
        print(f"load (1, 5, 15 min): {uptime()}")
        all_scan_rows(args.points, names, args.json)
        print(f"load (1, 5, 15 min): {uptime()}")
        return 0
    print(f"load (1, 5, 15 min): {uptime()}")
    vessels = [row for name in VESSELS for row in vessel_rows(name)]
    print("(d*: measure - truth, scene units; u: the measures' uncertainty; rel: relative "
          "error; cap/u.A: capacity error over its sigma u x wet area)")
    print_vessels(vessels)
    scan = scan_rows(args.points, args.quick)
    if scan:
        print_scan(scan)
    goals = {"capacity within 0.5 % on the synthetic vessels (mesh and interpolating routes)":
             all(abs(_rel(r["capacity"], r["truth"]["capacity"])) <= 0.005 for r in vessels
                 if r.get("construction") != "approximating"),
             "capacity within 0.5 % at 48 azimuths":
             all(abs(_rel(r["capacity"], r["truth"]["capacity"])) <= 0.005 for r in vessels
                 if r.get("azimuths") == 48 and r["construction"] == "interpolating")}
    print()
    print_goals(goals)
    print(f"load (1, 5, 15 min): {uptime()}")
    write_result(args.json, {"vessels": vessels, "scan": scan, "goals": goals,
                             "points": args.points, "quick": args.quick})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
