"""Real stereo pairs to a surface: ``photosurf run LEFT RIGHT --rig RIG`` on the chessboard rig.

``../shared/data/real/chessboard_stereo``: the rig from ``photosurf calibrate`` of its 12
pairs (``--pattern 9x6 --square 1``: units are squares), then ``photosurf run`` of each
chosen pair in this process (``benchmarks/real.py``'s :func:`run_in_process`).  Each run
ends with an open surface or a one-line refusal (the manifest's reason is recorded).

A flat board must come out flat.  Inside the board's inner-corner outline in the left
view (``benchmarks/_chessboard.py``):

* ``corners``   the board's own corners triangulated with the rig: their RMS distance to
  their plane, what the rig and the print allow.  That plane is the board's truth;
* ``cloud``     the run's points inside the outline: their RMS distance to the corners'
  plane (those within one square of it: a match one period off lies tens of squares
  away, counted apart as ``slips``) and their robust σ (1.4826 × MAD);
* ``surface``   the run's smooth surface (else its stitched mesh), 50 000 area samples,
  those seen inside the outline: RMS and 90th percentile of their distance to the
  corners' plane, their RMS to their own least-squares plane (flatness), and the share
  of the outline's pixels the surface covers when rendered from the left camera;
* ``poisson``   open3d's screened Poisson (depth 8, normals towards the cameras, lowest
  10 % density cut: ``benchmarks/open_surface.py``) of the same cloud, the same measures.

Each pair's PNG: the left photo, the surface rendered from the left camera, the two
blended, and Poisson rendered the same way.  The graffiti pair (Oxford, two photos of a
flat wall) has a homography but no calibration: ``photosurf run`` needs ``--rig`` for a
pair and SfM registers neither image of the folder (both refusals are recorded).

    .venv/bin/python benchmarks/real.py --pairs 03,06,12 [--workspace W] [--renders DIR]
"""

from __future__ import annotations

import contextlib
import io
import json
import sys
from pathlib import Path

import numpy as np

from checks.robust import mad_sigma

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

REAL = ROOT.parent / "shared" / "data" / "real"
BOARD = REAL / "chessboard_stereo"
GRAFFITI = REAL / "graffiti"
#: Area samples on each surface.
SURFACE_SAMPLES = 50_000


def _refusal(ws: Path, text: str) -> str:
    """The failed stage's one-line reason from the manifest, else the CLI's last line."""
    manifest = ws / "manifest.json"
    if manifest.is_file():
        stages = json.loads(manifest.read_text()).get("stages", {})
        for name, info in stages.items():
            if isinstance(info, dict) and info.get("status") == "failed":
                return f"stage {name} failed: {info.get('reason')}"
    lines = [ln for ln in text.splitlines() if ln.strip()]
    return lines[-1] if lines else ""


def _quiet_run(argv: list[str]):
    from real import run_in_process

    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        status, phases, _ = run_in_process(argv)
    return status, phases, err.getvalue()


def surface_mesh(ws: Path):
    """The run's smooth surface, else its stitched mesh: (vertices, triangles, name); only
    a stage the manifest records as done by the last run (a refusal upstream leaves an
    earlier run's files behind, its stages recorded blocked)."""
    from pipeline import artifacts
    from pipeline.mesh_io import read_mesh

    try:
        records = json.loads((ws / "manifest.json").read_text())["stages"]
    except (OSError, ValueError, KeyError):
        return None
    for path, stage, name in ((ws / "smooth" / artifacts.SURFACE, "smooth", "smooth"),
                              (ws / "stitch" / artifacts.MESH, "stitch", "stitched")):
        if records.get(stage, {}).get("status") == "done" and path.is_file():
            return (*read_mesh(path), name)
    return None


def _render(cam, vertices, triangles, width: int, height: int) -> np.ndarray:
    from pipeline.mesh_io import vertex_normals
    from pipeline.raycast import RayCaster
    from pipeline.render import render_view

    return render_view(RayCaster(vertices, triangles), vertices, triangles,
                       vertex_normals(vertices, triangles), cam.K, cam.R, cam.t, width,
                       height)


def _undistorted(cam, pixels: np.ndarray) -> np.ndarray:
    """Pixels of the (distorted) image where the pinhole render shows them."""
    import cv2

    if not cam.has_distortion:
        return pixels
    return cv2.undistortPoints(pixels.reshape(-1, 1, 2).astype(np.float64), cam.K,
                               cam.dist, P=cam.K).reshape(-1, 2)


def mesh_flatness(vertices, triangles, cam, outline, plane, image_size) -> dict:
    """The surface measures inside the board's outline (module notes)."""
    import cv2
    from _chessboard import fit_plane, inside_outline

    from surface.metrics import sample_mesh

    samples = sample_mesh(vertices, triangles, count=SURFACE_SAMPLES, seed=0)
    front = cam.depth(samples) > 0
    uv = np.full((len(samples), 2), -1e9)
    uv[front] = cam.project(samples[front])
    on = inside_outline(outline, uv)
    row = {"samples_on_board": int(on.sum())}
    if on.sum() >= 10:
        centroid, normal = plane
        d = np.abs((samples[on] - centroid) @ normal)
        own_c, own_n = fit_plane(samples[on])
        row.update(rms_to_board=float(np.sqrt(np.mean(d ** 2))),
                   p90_to_board=float(np.quantile(d, 0.9)),
                   own_plane_rms=float(np.sqrt(np.mean(((samples[on] - own_c) @ own_n) ** 2))),
                   normal_angle_deg=float(np.degrees(np.arccos(min(1.0, abs(own_n @ normal))))))
    # the outline's pixels the surface covers, seen from the left camera (a pinhole
    # render: the outline's corners undistorted)
    w, h = image_size
    shaded = _render(cam, vertices, triangles, w, h)
    hit = np.any(shaded != 255, axis=2)
    mask = np.zeros((h, w), np.uint8)
    hull = cv2.convexHull(_undistorted(cam, outline).astype(np.float32))
    cv2.fillConvexPoly(mask, np.rint(hull).astype(np.int32), 1)
    row["board_cover"] = float(hit[mask > 0].mean())
    return row, shaded


def pair_row(name: str, ws: Path, rig_path: Path, renders: Path) -> dict:
    """``photosurf run`` of one chessboard pair and its measures (module notes)."""
    import cv2
    from _chessboard import board_corners, fit_plane
    from open_surface import poisson_trimmed

    from matching.camera_files import read_rig
    from matching.image_file import imread
    from matching.triangulate import triangulate_pair
    from pipeline import artifacts
    from pipeline.render import write_png

    left, right = BOARD / f"left{name}.jpg", BOARD / f"right{name}.jpg"
    status, phases, err = _quiet_run([str(left), str(right), "--rig", str(rig_path),
                                      "--out", str(ws), "-q"])
    total = phases["total"]
    row = {"pair": name, "status": int(status), "seconds": total.seconds,
           "cpu_seconds": total.cpu_seconds, "peak_gb": total.peak}
    if status != 0:
        row["refusal"] = _refusal(ws, err)
    stitch_notes = ws / "stitch" / artifacts.STITCH_NOTES
    if stitch_notes.is_file():
        notes = json.loads(stitch_notes.read_text())
        row.update({k: notes.get(k) for k in ("open", "boundary_loops", "components",
                                              "edge_manifold")})
    rig = read_rig(rig_path)
    cam = rig.left
    grey_l = imread(str(left), cv2.IMREAD_GRAYSCALE).astype(np.float64)
    grey_r = imread(str(right), cv2.IMREAD_GRAYSCALE).astype(np.float64)
    cl, cr = board_corners(grey_l), board_corners(grey_r)
    if cl is None or cr is None:
        row["board"] = "not found"
        return row
    corners = triangulate_pair(rig.left, rig.right, cl, cr, refine=True, reject_p=None).points
    c0, n0 = fit_plane(corners)
    row["corners_rms"] = float(np.sqrt(np.mean(((corners - c0) @ n0) ** 2)))
    cloud = artifacts.read_cloud(ws / "acquire")["points"] if \
        (ws / "acquire" / "cloud.npz").is_file() else np.zeros((0, 3))
    from _chessboard import inside_outline

    front = cam.depth(cloud) > 0
    uv = np.full((len(cloud), 2), -1e9)
    uv[front] = cam.project(cloud[front])
    on = inside_outline(cl, uv) if len(cloud) else np.zeros(0, bool)
    row["cloud_points"] = int(len(cloud))
    plane = (c0, n0)
    d = (cloud[on] - c0) @ n0
    near = np.abs(d) <= 1.0
    row["cloud"] = {"points": int(on.sum()), "slips": int((~near).sum()),
                    "rms_to_board": float(np.sqrt(np.mean(d[near] ** 2))) if near.any()
                    else None,
                    "robust_sigma": float(mad_sigma(d))
                    if len(d) else None}
    if on.sum() < 10:
        return row
    w, h = cam.width, cam.height
    photo = cv2.cvtColor(imread(str(left)), cv2.COLOR_BGR2RGB)
    if cam.has_distortion:   # as the pinhole renders see it
        photo = cv2.undistort(photo, cam.K, cam.dist)
    tiles = [photo]
    mesh = surface_mesh(ws)
    if mesh is not None:
        row["surface_kind"] = mesh[2]
        row["surface"], shaded = mesh_flatness(mesh[0], mesh[1], cam, cl, plane, (w, h))
        hit = np.any(shaded != 255, axis=2)
        blend = photo.copy()
        blend[hit] = (0.5 * photo[hit] + 0.5 * shaded[hit]).astype(np.uint8)
        tiles += [shaded, blend]
    eyes = np.array([rig.left.center, rig.right.center])
    pv, pt = poisson_trimmed(cloud, eyes)
    row["poisson"], shaded_p = mesh_flatness(pv, pt, cam, cl, plane, (w, h))
    tiles.append(shaded_p)
    out = renders / f"pair{name}_surface_poisson.png"
    write_png(out, np.hstack(tiles))
    row["render_png"] = str(out)
    return row


def graffiti_rows(ws: Path) -> list[dict]:
    """The graffiti pair as a user would try it: as a pair (no rig) and as a folder."""
    rows = []
    if not (GRAFFITI / "graf1.png").is_file():
        return rows
    rigs = sorted(GRAFFITI.glob("*.yml")) + sorted(GRAFFITI.glob("*.yaml"))
    for label, argv in (("graffiti pair", [str(GRAFFITI / "graf1.png"),
                                           str(GRAFFITI / "graf3.png")]),
                        ("graffiti folder", [str(GRAFFITI)])):
        out = ws / label.replace(" ", "_")
        status, _, err = _quiet_run([*argv, "--out", str(out), "-q"])
        rows.append({"pair": label, "status": int(status), "calibration": [p.name for p in rigs],
                     "refusal": _refusal(out, err) if status else None})
    return rows


def main(argv: list[str] | None = None) -> int:
    import argparse
    import tempfile

    from _common import print_goals, uptime, write_result

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", default="03,06,12")
    parser.add_argument("--workspace", type=Path, default=None)
    parser.add_argument("--renders", type=Path, default=Path("/tmp"))
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)
    if not BOARD.is_dir():
        print(f"real data not found at {BOARD}; nothing to measure")
        return 0
    ws = args.workspace or Path(tempfile.mkdtemp(prefix="real-pairs-"))
    ws.mkdir(parents=True, exist_ok=True)
    args.renders.mkdir(parents=True, exist_ok=True)
    print(f"load {uptime()}")
    rig_path = ws / "rig.yml"
    if not rig_path.is_file():
        from pipeline.cli import main as cli_main

        with contextlib.redirect_stdout(io.StringIO()):
            cli_main(["calibrate", str(BOARD / "left*.jpg"), str(BOARD / "right*.jpg"),
                      "--pattern", "9x6", "--square", "1", "--out", str(rig_path), "-q"])
    rows = [pair_row(name, ws / f"pair{name}", rig_path, args.renders)
            for name in args.pairs.split(",")]
    rows += graffiti_rows(ws)
    print(f"\nchessboard rig ({rig_path}), units: squares; load {uptime()}")
    head = ("pair", "exit", "CPU-s", "cloud", "on board", "slips", "corners", "cloud rms",
            "cloud rσ", "surf rms", "surf p90", "surf flat", "cover", "poi rms", "poi flat",
            "poi cover")
    print(" | ".join(f"{h:>9}" for h in head))
    for r in rows:
        if "cloud" not in r:
            print(f"{r['pair']:>9} | {r['status']:>9} | {r.get('refusal') or r.get('board')}")
            continue
        s, p, c = r.get("surface", {}), r.get("poisson", {}), r["cloud"]
        vals = (r.get("cpu_seconds"), r["cloud_points"], c["points"], c["slips"],
                r["corners_rms"], c.get("rms_to_board"), c.get("robust_sigma"),
                s.get("rms_to_board"), s.get("p90_to_board"), s.get("own_plane_rms"),
                s.get("board_cover"), p.get("rms_to_board"), p.get("own_plane_rms"),
                p.get("board_cover"))
        print(" | ".join([f"{r['pair']:>9}", f"{r['status']:>9}"]
                         + [f"{v:9.4f}" if isinstance(v, float) else f"{v!s:>9}"
                            for v in vals]))
        if r.get("refusal"):
            print(f"          refusal: {r['refusal']}")
    board = [r for r in rows if "cloud" in r]
    goals = {
        "every chessboard pair ends with a surface or a one-line refusal":
            all(r["status"] == 0 or "\n" not in (r.get("refusal") or "\n") for r in board),
        "the board's surface as close to the board as its cloud (RMS to the corners' plane)":
            all(r.get("surface", {}).get("rms_to_board", np.inf)
                <= (r["cloud"].get("rms_to_board") or 0) for r in board if r["status"] == 0),
    }
    print_goals(goals)
    if args.json:
        write_result(args.json, {"benchmark": "real-pairs", "load": uptime(), "rows": rows,
                                 "goals": goals})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
