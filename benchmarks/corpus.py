"""The corpus: every real scan, the synthetic branching shapes and the temple, beside Poisson.

Cases (``CASES``):

* the real scans of ``../shared/data/real/scans`` (SOURCE.md there): ``SIZE`` points sampled
  uniformly by area on each mesh (exact duplicate vertices welded: OBJ readers split them at
  texture seams); Igea has points only: its own points, subsampled, and its full point set
  stands in for the truth (Chamfer from point distances);
* the synthetic shapes of ``testkit/shapes.py`` (vase with an opening, mug, amphora, torus,
  pants: implicit solids with an exact distance and genus);
* the temple ring's cloud (``photosurf run`` of ``temple_sparse_ring`` with its given
  cameras, acquired once into ``--temple-workspace``), subsampled; no surface truth.

Each at ``--sizes`` points (default 10^4 and 6·10^4) and noise ``--noises`` × the cloud's
diagonal (default 0 and 0.0005), axis ``auto``, one row each, run in its own process with a
time bound (``--timeout``; a row past it is printed as such).  Methods, in the row's process:

* ``sections``: what ``photosurf sections --smooth --axis auto`` does
  (``pipeline.section_surface.sized_mesh``, ``interpolating_control``, Loop's patches tessellated
  within the sizing's chord tolerance); a refusal is printed with its reason;
* ``general``: ``surface.general_mesh.poisson_control_mesh`` (triangles of the sections'
  control edge, or 1.5 point spacings without one), Loop's patches over it fitted to the
  cloud as the smooth stage builds them (``pipeline.bezier_surface.smooth_general``);
* ``auto``: the smooth stage's choice between the two (``surface.general_mesh.prefer_general``
  on validity, then the genus the data support, then A and Cp; without the stage's gate
  ``needs_general``, whose noise estimate is the curves stage's: here both surfaces are
  always built and compared);
* ``poisson-8``: open3d's screened Poisson, depth 8, PCA normals of 30 neighbours oriented by
  the tangent-plane graph, closed (no density trimming).

Per method: valid solid (``surface.validity.check_solid``: closed, manifold, oriented, no
self-intersection), components, genus (the truth's beside it), Chamfer and F-score at
``tau = 0.002 × diagonal`` against the truth (20 000 samples a side), A (90th percentile of
surface samples -> nearest cloud point) and C (median cloud point -> surface) against the
row's cloud, Cp (the mean distance from the cloud projected onto its neighbour planes,
``surface.general_mesh.plane_reference``; ``plane_k`` its neighbours, 1 for the cloud
itself), Bézier patches, CPU seconds (ours: sections -> smooth, libraries imported before;
Poisson: its normals and solve).

    .venv/bin/python benchmarks/corpus.py [--quick] [--cases NAME ...] [--sizes N ...]
        [--noises R ...] [--timeout S] [--json PATH]

``--quick``: 10^4 points, noise 0.0005, the complex scans, mug, pants and the temple.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
HERE = Path(__file__).resolve().parent

SCANS = ROOT.parent / "shared" / "data" / "real" / "scans"
TEMPLE = ROOT.parent / "shared" / "data" / "real" / "temple_sparse_ring"
SCAN_NAMES = ["cow", "fandisk", "igea", "nefertiti", "teapot", "ycb_banana",
              "ycb_mustard_bottle", "ycb_power_drill"]
SHAPE_NAMES = ["vase", "mug", "amphora", "torus", "pants"]
CASES = SCAN_NAMES + SHAPE_NAMES + ["temple"]
QUICK_CASES = ["cow", "nefertiti", "teapot", "ycb_banana", "ycb_power_drill", "mug", "pants",
               "temple"]
SIZES = [10_000, 60_000]
NOISES = [0.0, 0.0005]
#: F-score threshold as a share of the diagonal: 4 sigma of the noisier rows.
TAU_SHARE = 0.002
#: Samples a side of the Chamfer and F-score.
SCORE_SAMPLES = 20_000
METHODS = ("sections", "general", "auto", "poisson-8")
#: The truth's genus where its mesh does not say it (``check_solid`` gives ``None``): the
#: cow is a genus-0 mesh with one pinched vertex (V - E + F = 1 with that vertex shared);
#: the teapot's four open pieces (body, lid, handle, spout) make a solid of genus 1 (the
#: handle) once joined.
TRUTH_GENUS = {"cow": 0, "teapot": 1}


# ----------------------------------------------------------------------------- data
def _shapes_module():
    """The procedural shapes with exact truth (``testkit.shapes``)."""
    from testkit import shapes

    return shapes


def _weld(v: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    unique, inverse = np.unique(v, axis=0, return_inverse=True)
    return unique, inverse.reshape(-1)[t]


def temple_cloud(workspace: Path) -> np.ndarray:
    """The temple ring's cloud (acquired into ``workspace`` when absent)."""
    sys.path.insert(0, str(ROOT))
    from pipeline import artifacts, cli

    if not (workspace / "acquire" / "cloud.npz").is_file():
        args = ["run", str(TEMPLE), "--cameras", str(TEMPLE / "templeSR_par.txt"), "--out",
                str(workspace), "-q", "--to", "acquire"]
        if cli.main(args) != 0:
            raise SystemExit("photosurf run of the temple failed")
    return artifacts.read_cloud(workspace / "acquire")["points"]


def load_case(case: str, size: int, noise: float, workspace: Path) -> tuple[np.ndarray, dict]:
    """The row's cloud ``(size, 3)`` and its truth: ``{"kind", "genus", ...}``."""
    from surface.metrics import sample_mesh

    rng = np.random.default_rng(0)
    if case in SHAPE_NAMES:
        _shapes = _shapes_module()
        sigma = noise * _shapes.diagonal(case)
        return (_shapes.sample(case, size, seed=0, sigma=sigma),
                {"kind": "implicit", "genus": _shapes.genus(case),
                 "diagonal": _shapes.diagonal(case)})
    if case == "temple":
        full = temple_cloud(workspace)
        truth = {"kind": "none", "genus": None}
    elif case == "igea":
        from pipeline.cloud_io import read_cloud

        full = read_cloud(SCANS / "igea" / "mesh.ply").points
        truth = {"kind": "points", "genus": 0, "points": full}
    else:
        from pipeline.mesh_io import read_mesh
        from surface.validity import check_solid

        v, t = _weld(*read_mesh(next(iter(sorted((SCANS / case).glob("mesh.*"))))))
        report = check_solid(v, t, intersections=False)
        truth = {"kind": "mesh", "genus": TRUTH_GENUS.get(case, report.genus),
                 "vertices": v, "triangles": t, "components": report.components}
        full = None
    if full is not None:
        cloud = full[rng.choice(len(full), min(size, len(full)), replace=False)]
    else:
        cloud = sample_mesh(truth["vertices"], truth["triangles"], size, seed=0)
    diagonal = float(np.linalg.norm(np.ptp(cloud, axis=0)))
    truth["diagonal"] = diagonal
    return cloud + rng.normal(0.0, noise * diagonal, cloud.shape), truth


# ----------------------------------------------------------------------------- methods
def _clock():
    return time.perf_counter(), time.process_time()


def _since(start) -> tuple[float, float]:
    return time.perf_counter() - start[0], time.process_time() - start[1]


def run_sections(points: np.ndarray) -> dict:
    from pipeline.bezier_surface import smooth_mesh
    from pipeline.guards import unit_scale
    from pipeline.section_surface import sized_mesh
    from surface.sizing import interpolating_control

    unit = unit_scale(points)
    start = _clock()
    sized, _ = sized_mesh(points / unit, axis="auto")
    control = interpolating_control(sized.vertices, sized.triangles, sized.creases) * unit
    # checked and, where it crosses itself, repaired (pipeline.bezier_surface.smooth_mesh), as
    # photosurf sections --smooth writes it
    smooth = smooth_mesh(control, sized.triangles, "adaptive", sized.chord_tolerance() * unit,
                         spacing=sized.spacing * unit)
    smooth.g1_angle   # noqa: B018  (the G1 figures the command reports: computed when asked)
    seconds, cpu = _since(start)
    edges = control[sized.triangles] - control[np.roll(sized.triangles, 1, axis=1)]
    return {"vertices": smooth.vertices, "triangles": smooth.triangles,
            "patches": len(smooth.surface.control_points), "seconds": seconds, "cpu": cpu,
            "tolerance": sized.chord_tolerance() * unit, "repair": _repair(smooth),
            "control_edge": float(np.median(np.linalg.norm(edges, axis=2)))}


def run_general(points: np.ndarray, edge: float | None, tolerance: float | None) -> dict:
    from pipeline.bezier_surface import smooth_general
    from surface.general_mesh import poisson_control_mesh
    from surface.sections import point_spacing

    start = _clock()
    spacing = point_spacing(points)
    edge = edge or 1.5 * spacing
    vertices, triangles = poisson_control_mesh(points, edge, spacing)
    tolerance = tolerance or 0.1 * spacing
    # as the smooth stage (pipeline.stages._general_smooth)
    smooth = smooth_general(vertices, triangles, "adaptive", tolerance, points=points,
                            spacing=spacing)
    smooth.g1_angle   # noqa: B018  (the G1 figures the stage reports: computed when asked)
    seconds, cpu = _since(start)
    control = (smooth.solid or {}).get("general_control")
    return {"vertices": smooth.vertices, "triangles": smooth.triangles,
            "patches": len(smooth.surface.control_points), "seconds": seconds, "cpu": cpu,
            "approximating": control == "approximating", "general_control": control,
            "fit": {k: (smooth.solid or {}).get(k) for k in ("fit_weight", "fit_bend")},
            "repair": _repair(smooth)}


def _repair(smooth) -> dict | None:
    """The smooth surface's repair figures (``pipeline.bezier_surface.smooth_mesh``), if any."""
    return (smooth.solid or {}).get("repair")


def run_poisson(points: np.ndarray, depth: int = 8) -> dict:
    import open3d as o3d

    start = _clock()
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(knn=30))
    cloud.orient_normals_consistent_tangent_plane(30)
    mesh, _ = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(cloud, depth=depth)
    seconds, cpu = _since(start)
    return {"vertices": np.asarray(mesh.vertices, np.float64),
            "triangles": np.asarray(mesh.triangles, np.int64), "seconds": seconds, "cpu": cpu}


# ----------------------------------------------------------------------------- scores
def _scores(result: dict, points: np.ndarray, truth: dict, case: str,
            reference: np.ndarray | None = None) -> dict:
    from surface import metrics
    from surface.general_mesh import cloud_fidelity
    from surface.validity import check_solid

    v, t = result["vertices"], result["triangles"]
    report = check_solid(v, t)
    out = {"valid": bool(report.valid), "components": int(report.components),
           "genus": report.genus, "pairs": int(len(report.intersecting_pairs)),
           "border_edges": int(report.boundary_edges), "triangles": int(len(t))}
    fidelity = cloud_fidelity(v, t, points, reference=reference)
    out.update(A=fidelity.a90, C=fidelity.c50, Cp=fidelity.cp)
    tau = TAU_SHARE * truth["diagonal"]
    if truth["kind"] == "implicit":
        s = _shapes_module().score(case, v, t, count=SCORE_SAMPLES, tau=tau)
    elif truth["kind"] == "mesh":
        s = metrics.compare_meshes(v, t, truth["vertices"], truth["triangles"], tau,
                                   count=SCORE_SAMPLES)
    elif truth["kind"] == "points":
        rng = np.random.default_rng(1)
        full = truth["points"]
        ref = full[rng.choice(len(full), min(SCORE_SAMPLES, len(full)), replace=False)]
        on = metrics.sample_mesh(v, t, SCORE_SAMPLES, seed=0)
        s = metrics.distance_scores(metrics.point_cloud_distance(on, full),
                                    metrics.point_mesh_distance(ref, v, t), tau)
    else:
        s = None
    if s is not None:
        out.update(chamfer=s["chamfer"], fscore=s["fscore"])
    return out


def one_row(case: str, size: int, noise: float, workspace: Path) -> dict:
    """Every method on one cloud, in this process."""
    import open3d  # noqa: F401  (libraries imported before any clock)

    import surface.general_mesh  # noqa: F401
    import surface.reconstruct  # noqa: F401
    import surface.sizing  # noqa: F401

    points, truth = load_case(case, size, noise, workspace)
    methods, results = {}, {}
    try:
        results["sections"] = run_sections(points)
    except ValueError as exc:
        methods["sections"] = {"refused": str(exc).splitlines()[0][:200]}
    sec = results.get("sections", {})
    try:
        results["general"] = run_general(points, sec.get("control_edge"), sec.get("tolerance"))
    except ValueError as exc:
        methods["general"] = {"refused": str(exc).splitlines()[0][:200]}
    results["poisson-8"] = run_poisson(points)
    return scored_row(case, noise, points, truth, results, methods)


def scored_row(case: str, noise: float, points: np.ndarray, truth: dict, results: dict,
               refused: dict) -> dict:
    """The row of ``results`` (method -> ``run_*``'s dict, surfaces included) and
    ``refused`` (method -> ``{"refused": reason}``): scores, and auto's choice."""
    from surface.general_mesh import (
        cloud_fidelity,
        evidence_genus,
        plane_reference,
        prefer_general,
        support_reach,
    )
    from surface.sections import point_spacing

    row = {"case": case, "points": int(len(points)), "noise": noise,
           "truth_genus": truth["genus"], "methods": dict(refused)}
    start = _clock()
    reference, row["plane_k"] = plane_reference(points)
    reference_s = _since(start)
    for name, result in results.items():
        row["methods"][name] = {**_scores(result, points, truth, case, reference),
                                **{k: v for k, v in result.items()
                                   if k not in ("vertices", "triangles")}}
    # the smooth stage's choice: its clock holds both surfaces, the projected cloud and
    # their fidelity to it
    if "sections" in results and "general" in results:
        start = _clock()
        fs, fg = (cloud_fidelity(results[m]["vertices"], results[m]["triangles"], points,
                                 reference=reference) for m in ("sections", "general"))
        valid = [row["methods"][m]["valid"] for m in ("sections", "general")]
        genera = [row["methods"][m]["genus"] for m in ("sections", "general")]
        evidence = None
        if None not in genera and genera[0] != genera[1]:
            # the points' noise is not known to a user here: the reach from the spacing
            # alone (3 sigma is < 3 % of it on every row of the corpus)
            evidence = evidence_genus(results["sections"]["vertices"],
                                      results["sections"]["triangles"], points,
                                      support_reach(point_spacing(points)))
        choose_s = tuple(x + y for x, y in zip(_since(start), reference_s, strict=True))
        row["evidence_genus"] = evidence
        chosen = "general" if prefer_general(fs, fg, section_valid=valid[0],
                                             general_valid=valid[1], section_genus=genera[0],
                                             general_genus=genera[1],
                                             evidence_genus=evidence) else "sections"
    else:
        choose_s = (0.0, 0.0)
        chosen = "sections" if "sections" in results else "general"
    if chosen in results:
        auto = dict(row["methods"][chosen])
        auto["chosen"] = chosen
        auto["seconds"] = choose_s[0] + sum(row["methods"][m].get("seconds", 0.0)
                                            for m in ("sections", "general"))
        auto["cpu"] = choose_s[1] + sum(row["methods"][m].get("cpu", 0.0)
                                        for m in ("sections", "general"))
        row["methods"]["auto"] = auto
    return row


# ----------------------------------------------------------------------------- table
def _cell(m: dict | None) -> str:
    if m is None:
        return f"{'(none)':>64s}"
    if "refused" in m:
        return f"  refused: {m['refused'][:54]}"
    chamfer = f"{m['chamfer']:.2e}" if "chamfer" in m else "-"
    fscore = f"{m['fscore']:.3f}" if "fscore" in m else "-"
    return (f"{'V' if m['valid'] else 'x'} c{m['components']:<2d} g{m['genus']!s:<4s} "
            f"{chamfer:>9s} {fscore:>6s} {m['A']:9.2e} {m['C']:9.2e} "
            f"{m.get('Cp', float('nan')):9.2e} "
            f"{m.get('patches', '-')!s:>7s} {m['cpu']:7.1f}")


HEADER = (f"{'case':<19s}{'points':>7s} {'noise':>7s} {'gT':>3s} {'method':<10s} "
          f"{'valid/comp/genus':<15s}{'Chamfer':>9s} {'F':>6s} {'A':>9s} {'C':>9s} {'Cp':>9s} "
          f"{'patches':>7s} {'CPU s':>7s}")


def print_row(row: dict) -> None:
    if "error" in row:
        print(f"{row['case']:<19s}{row['points']:>7d} {row['noise']:7.4f}     "
              f"{row['error']}", flush=True)
        return
    for name in METHODS:
        m = row["methods"].get(name)
        extra = (f"  <- {m['chosen']} (planes of {row.get('plane_k')})"
                 if m and "chosen" in m else "")
        if extra and row.get("evidence_genus") is not None:
            extra += f" (the data's genus {row['evidence_genus']})"
        print(f"{row['case']:<19s}{row['points']:>7d} {row['noise']:7.4f} "
              f"{row['truth_genus']!s:>3s} {name:<10s}{_cell(m)}{extra}", flush=True)


def goals(rows: list[dict]) -> dict:
    """Per row: the chosen surface a valid solid of the truth's genus; Chamfer <= Poisson-8's
    (on rows with a truth); A <= Poisson-8's and C <= 1.5x (every row)."""
    out = {}
    for row in rows:
        key = f"{row['case']}_{row['points']}_{row['noise']}"
        auto, p8 = row.get("methods", {}).get("auto"), row.get("methods", {}).get("poisson-8")
        if not auto or not p8 or "refused" in auto:
            out[f"{key}_built"] = False
            continue
        if row["truth_genus"] is not None:
            out[f"{key}_valid_genus"] = bool(auto["valid"] and auto["genus"]
                                             == row["truth_genus"])
        if "chamfer" in auto and "chamfer" in p8:
            out[f"{key}_chamfer_le_p8"] = bool(auto["chamfer"] <= p8["chamfer"])
        out[f"{key}_A_le_p8"] = bool(auto["A"] <= p8["A"])
        out[f"{key}_C_le_1.5p8"] = bool(auto["C"] <= 1.5 * p8["C"])
    return out


def _row_in_child(case, size, noise, workspace: Path, timeout: float) -> dict:
    with tempfile.TemporaryDirectory(prefix="corpus-") as tmp:
        out = Path(tmp) / "row.json"
        command = [sys.executable, str(Path(__file__).resolve()), "--row", case, str(size),
                   str(noise), str(out), "--temple-workspace", str(workspace)]
        try:
            done = subprocess.run(command, capture_output=True, text=True, timeout=timeout)
        except subprocess.TimeoutExpired:
            return {"case": case, "points": size, "noise": noise,
                    "error": f"past the row's time bound of {timeout:.0f} s"}
        if done.returncode != 0 or not out.is_file():
            lines = (done.stderr or done.stdout).strip().splitlines()
            return {"case": case, "points": size, "noise": noise,
                    "error": f"failed: {lines[-1] if lines else done.returncode}"}
        return json.loads(out.read_text())


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="the small subset (module doc)")
    parser.add_argument("--cases", nargs="+", choices=CASES)
    parser.add_argument("--sizes", nargs="+", type=int)
    parser.add_argument("--noises", nargs="+", type=float)
    parser.add_argument("--timeout", type=float, default=900.0, help="seconds a row")
    parser.add_argument("--temple-workspace",
                        default=str(Path(tempfile.gettempdir()) / "photosurf-corpus-temple"))
    parser.add_argument("--json", default=str(HERE / "results" / "corpus.json"))
    parser.add_argument("--row", nargs=4, metavar=("CASE", "SIZE", "NOISE", "OUT"),
                        help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    sys.path.insert(0, str(ROOT))
    workspace = Path(args.temple_workspace)
    if args.row:
        case, size, noise, out = args.row
        row = one_row(case, int(size), float(noise), workspace)
        Path(out).write_text(json.dumps(row, default=float))
        return 0
    sys.path.append(str(HERE))   # after ROOT: benchmarks/pipeline.py is no package
    from _common import print_goals, uptime, write_result

    cases = args.cases or (QUICK_CASES if args.quick else CASES)
    sizes = args.sizes or ([10_000] if args.quick else SIZES)
    noises = args.noises if args.noises is not None else ([0.0005] if args.quick else NOISES)
    if not SCANS.is_dir():
        cases = [c for c in cases if c in SHAPE_NAMES]
        print(f"no scans at {SCANS}: the synthetic shapes only")
    if "temple" in cases:
        if (TEMPLE / "templeSR_par.txt").is_file():
            temple_cloud(workspace)        # acquired once, before the rows' clocks
        else:
            cases = [c for c in cases if c != "temple"]
    print(f"load (1, 5, 15 min): {uptime()}\n(V valid solid / x not; c components, g genus; "
          f"gT the truth's genus; tau = {TAU_SHARE} x diagonal; A, C against the row's cloud)")
    print(HEADER)
    rows = []
    for case in cases:
        for size in sizes:
            for noise in noises:
                row = _row_in_child(case, size, noise, workspace, args.timeout)
                rows.append(row)
                print_row(row)
                # the rows so far, so that a run stopped part way keeps them
                Path(args.json).parent.mkdir(parents=True, exist_ok=True)
                Path(args.json).write_text(json.dumps({"rows": rows, "partial": True},
                                                      default=float))
    met = goals(rows)
    print_goals(met)
    print(f"load (1, 5, 15 min): {uptime()}")
    write_result(args.json, {"rows": rows, "goals": met, "tau_share": TAU_SHARE,
                             "load": uptime()})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
