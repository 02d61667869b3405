"""Refusal time and peak memory of the oversized and hostile requests.

Each row runs the real program, ``python -m pipeline.cli ...``, as a child
process and reads its wall time and peak resident memory (``os.wait4``: the
child's own ``ru_maxrss``, i.e. RUSAGE_CHILDREN of that one child).  Every
request must be refused (exit status 2, one line on stderr, no file written or left
behind: the inputs' folder is listed before and after each row) in under 2 s and
500 MB; before they were checked these requests crashed (``sections`` on a 1e300 cloud:
exit -11), printed tracebacks, or ran until killed by time or memory.  Rows marked
*handled* are odd but usable input (a cylinder with 5 points 10^6 away, a stdout that
is closed or full): exit 0 with at most one warning line and no temporary left, the far
points dropped (before: 12 GiB and killed).

The peer row is ``photosurf --help`` in the same way: the interpreter and the
imports every command pays before it can refuse anything.

Run: ``.venv/bin/python benchmarks/limits.py [--quick] [--json PATH]``
(default JSON: ``benchmarks/results/limits.json``; ``--quick`` runs a third of
the rows).  The machine's load average is printed and stored with the figures:
wall time on a shared machine is CPU time stretched by the load.
"""

from __future__ import annotations

import argparse
import json
import os
import struct
import subprocess
import sys
import tempfile
import time
import zlib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
# numpy and photosurf are imported by the --make-inputs child only (see _make_inputs)

# the smallest valid scene recipe, shared with tests/pipeline/test_fuzz_inputs.py
RECIPE = (ROOT / "fixtures" / "scenes" / "tiny_stereo.toml").read_text()


def _inputs(tmp: Path) -> dict:
    """Small valid inputs plus the hostile files the requests name."""
    import cv2
    import numpy as np
    import open3d as o3d

    from matching.cameras import Camera, StereoRig, write_rig
    from pipeline.cloud_io import write_cloud
    from pipeline.mesh_io import write_mesh

    rng = np.random.default_rng(0)
    theta, z = rng.uniform(0, 2 * np.pi, 600), rng.uniform(0, 2, 600)
    cylinder = np.column_stack([np.cos(theta), np.sin(theta), z])
    files = {"cloud": write_cloud(tmp / "cloud.xyz", cylinder),
             "huge_cloud": write_cloud(tmp / "huge.ply", cylinder * 1e300)}
    sphere = o3d.geometry.TriangleMesh.create_sphere(1.0, 81)  # 25 920 triangles
    files["mesh"] = write_mesh(tmp / "sphere26k.ply", np.asarray(sphere.vertices),
                               np.asarray(sphere.triangles))
    with np.errstate(all="ignore"):  # its normals overflow: the point of the file
        files["huge_mesh"] = write_mesh(tmp / "huge_mesh.ply",
                                        np.asarray(sphere.vertices) * 1e200,
                                        np.asarray(sphere.triangles), compute_normals=False)
    (tmp / "claims.off").write_text("OFF\n1000000000 1 0\n0 0 0\n")
    files["off"] = tmp / "claims.off"
    image = np.clip(rng.normal(128, 40, (48, 64)), 0, 255).astype(np.uint8)
    cv2.imwrite(str(tmp / "left.png"), image)
    cv2.imwrite(str(tmp / "right.png"), np.roll(image, -3, axis=1))
    files["left"], files["right"] = tmp / "left.png", tmp / "right.png"
    K = np.array([[100.0, 0, 31.5], [0, 100.0, 23.5], [0, 0, 1]])
    R, _ = cv2.Rodrigues(np.array([0.0, 0.1, 0.0]))
    rig = StereoRig(Camera(K, np.zeros(5), np.eye(3), np.zeros(3), 64, 48, "left"),
                    Camera(K, np.zeros(5), R, np.array([-0.2, 0, 0]), 64, 48, "right"))
    write_rig(tmp / "rig.yml", rig)
    files["rig"] = tmp / "rig.yml"
    ihdr = struct.pack(">IIBBBBB", 100_000, 100_000, 8, 0, 0, 0, 0)
    (tmp / "claims.png").write_bytes(b"\x89PNG\r\n\x1a\n" + struct.pack(">I", 13) + b"IHDR" +
                                     ihdr + struct.pack(">I", zlib.crc32(b"IHDR" + ihdr)) +
                                     b"\x00" * 64)
    files["big_png"] = tmp / "claims.png"
    import io
    import json as json_mod
    import zipfile

    header = io.BytesIO()  # an .npy header claiming 10^12 points, and no data
    np.lib.format.write_array_header_1_0(header, {"descr": "<f8", "fortran_order": False,
                                                  "shape": (10 ** 12, 3)})
    with zipfile.ZipFile(tmp / "claims.npz", "w") as archive:
        archive.writestr("points.npy", b"\x93NUMPY\x01\x00" + header.getvalue()[8:])
    files["npz"] = tmp / "claims.npz"
    document = json_mod.dumps({  # a GLB whose POSITION accessor claims 10^12 vertices
        "asset": {"version": "2.0"}, "accessors": [{"componentType": 5126, "type": "VEC3",
                                                    "count": 10 ** 12}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}]}).encode()
    document += b" " * (-len(document) % 4)
    (tmp / "claims.glb").write_bytes(struct.pack("<III", 0x46546C67, 2, 20 + len(document)) +
                                     struct.pack("<II", len(document), 0x4E4F534A) + document)
    files["glb"] = tmp / "claims.glb"
    flat = np.column_stack([rng.uniform(-1, 1, 600), np.zeros(600), rng.uniform(0, 2, 600)])
    files["flat"] = write_cloud(tmp / "flat.ply", flat)
    os.mkfifo(tmp / "pipe.xyz")
    files["fifo"] = tmp / "pipe.xyz"
    _hostile_two(tmp, files, rng)
    _hostile_views(tmp, files, image, rng)
    for name, extra in (("views", '[cameras]\nlayout = "ring"\nwidth = 48\nheight = 40\n'
                                  "n = 1000000000\n"),
                        ("ring2", '[cameras]\nlayout = "ring"\nwidth = 48\nheight = 40\nn = 8\n'
                                  "[cameras.second_ring]\nn = 100000000\nelevation_deg = 40.0\n"),
                        ("pixels", '[cameras]\nlayout = "stereo"\nwidth = 1000000\n'
                                   "height = 1000000\n"),
                        ("supersample", ""), ("components", ""), ("triangles", ""),
                        ("nested", "")):
        text = RECIPE
        if extra:
            text = text.split("[cameras]")[0] + extra + "[render]\nsupersample = 1\n"
        if name == "supersample":
            text = text.replace("supersample = 1", "supersample = 1000000")
        if name == "components":
            text += "[texture]\ncomponents = 1000000000\n"
        if name == "triangles":
            text = text.replace("triangles = 2000", "triangles = 1000000000000")
        if name == "nested":
            text += "x = " + "[" * 5000 + "]" * 5000 + "\n"
        (tmp / f"{name}.toml").write_text(text)
        files[f"recipe_{name}"] = tmp / f"{name}.toml"
    (tmp / "ok.toml").write_text(RECIPE)
    files["recipe"] = tmp / "ok.toml"
    return files


def _hostile_two(tmp: Path, files: dict, rng) -> None:
    """The second round's files: links in a loop, far outliers, a vertex of valence 2000,
    a PLY claiming 50 faces it lacks, sigma all zero, decimal commas, a noisy line, two
    planes across the axis."""
    import numpy as np

    from pipeline.cloud_io import write_cloud
    from pipeline.mesh_io import write_mesh

    (tmp / "a.xyz").symlink_to(tmp / "b.xyz")
    (tmp / "b.xyz").symlink_to(tmp / "a.xyz")
    (tmp / "loop_a").symlink_to(tmp / "loop_b")
    (tmp / "loop_b").symlink_to(tmp / "loop_a")
    files["link_loop"], files["out_loop"] = tmp / "a.xyz", tmp / "loop_a"
    theta, z = rng.uniform(0, 2 * np.pi, 7200), rng.uniform(0, 2, 7200)
    cylinder = np.column_stack([np.cos(theta), np.sin(theta), z])
    files["far"] = write_cloud(tmp / "far.xyz", np.vstack([cylinder,
                                                           rng.normal(size=(5, 3)) * 1e6]))
    files["far_axis"] = write_cloud(tmp / "far_axis.npz", np.vstack([cylinder, np.column_stack(
        [np.zeros(5), np.zeros(5), 1e6 * np.arange(1, 6)])]))
    files["far_group"] = write_cloud(tmp / "far_group.xyz", np.vstack(
        [cylinder, 1e6 + rng.normal(size=(20, 3))]))
    n = 2000  # a bipyramid: two apexes of valence 2000
    ring = np.column_stack([np.cos(np.arange(n) * 2 * np.pi / n),
                            np.sin(np.arange(n) * 2 * np.pi / n), np.zeros(n)])
    i, j = np.arange(n), (np.arange(n) + 1) % n
    files["valence"] = write_mesh(tmp / "valence2000.ply", np.vstack([ring, [[0, 0, 1],
                                                                             [0, 0, -1]]]),
                                  np.vstack([np.column_stack([i, j, np.full(n, n)]),
                                             np.column_stack([j, i, np.full(n, n + 1)])]))
    data = files["mesh"].read_bytes()
    files["faces_claim"] = tmp / "faces_claim.ply"
    files["faces_claim"].write_bytes(data.replace(b"element face 25920",
                                                  b"element face 25970"))
    files["sigma_zero"] = write_cloud(tmp / "sigma0.npz", cylinder[:600], sigma=np.zeros(600))
    files["sigma_negative"] = write_cloud(tmp / "sigma_negative.npz", cylinder[:600],
                                          sigma=-np.ones(600))
    (tmp / "commas.xyz").write_text("".join(f"{x:.6f} {y:.6f} {z:.6f}\n".replace(".", ",")
                                            for x, y, z in cylinder[:600]))
    files["commas"] = tmp / "commas.xyz"
    t = rng.uniform(0, 2, 2000)
    files["line"] = write_cloud(tmp / "line.xyz", np.column_stack([t, 2 * t, 3 * t])
                                + rng.normal(0, 1e-3, (2000, 3)))
    disc = rng.uniform(-1, 1, (1000, 2))
    files["planes"] = write_cloud(tmp / "planes.xyz", np.vstack(
        [np.column_stack([disc, np.zeros(1000)]), np.column_stack([disc, np.full(1000, 0.5)])]))


def _hostile_views(tmp: Path, files: dict, image, rng) -> None:
    """Image and camera files of the second round: a view named in bytes that are not
    UTF-8, a float TIFF with NaN pixels, camera files naming an image twice (cameras.yml,
    a Middlebury par file, a COLMAP images.txt), an images.txt without its points lines,
    a cameras.yml that is no camera file."""
    import shutil

    import cv2
    import numpy as np

    from matching.cameras import Camera, write_cameras_yml, write_colmap_text

    files["left_nonutf8"] = os.fsencode(tmp) + b"/l_caf\xe9.png"
    shutil.copy(tmp / "left.png", files["left_nonutf8"])
    floats = image.astype(np.float32)
    floats[10:12, 20:30] = np.nan
    cv2.imwrite(str(tmp / "nan.tif"), floats)
    files["nan_tiff"] = tmp / "nan.tif"
    K = np.array([[100.0, 0, 31.5], [0, 100.0, 23.5], [0, 0, 1]])
    names = [f"v{k}.png" for k in range(6)]
    cameras = [Camera(K, np.zeros(5), np.eye(3), np.array([0.1 * k, 0, 2]), 64, 48, name)
               for k, name in enumerate(names)]
    for label in ("yml_twice", "par_twice", "colmap_twice", "colmap_no_points", "yml_bad"):
        folder = tmp / label
        folder.mkdir()
        for name in names:
            cv2.imwrite(str(folder / name), np.roll(image, 2 * int(name[1]), axis=1))
        files[label] = folder
    twice = [*cameras[:5], Camera(K, np.zeros(5), np.eye(3), np.array([0.7, 0, 2]), 64, 48,
                                  "v2.png")]
    write_cameras_yml(tmp / "yml_twice" / "cameras.yml", twice)
    (tmp / "par_twice" / "views_par.txt").write_text(f"{len(twice)}\n" + "".join(
        f"{c.name} " + " ".join(f"{v:.17g}" for v in (*c.K.ravel(), *c.R.ravel(), *c.t))
        + "\n" for c in twice))
    files["par_file"] = tmp / "par_twice" / "views_par.txt"
    write_colmap_text(tmp / "colmap_twice" / "sparse", [  # v2.png's second pose, renamed
        *cameras[:5], Camera(K, np.zeros(5), np.eye(3), np.array([0.7, 0, 2]), 64, 48,
                             "v5.png")])
    images_txt = tmp / "colmap_twice" / "sparse" / "images.txt"
    images_txt.write_text(images_txt.read_text().replace(" v5.png", " v2.png"))
    write_colmap_text(tmp / "colmap_no_points" / "sparse", cameras)
    text = (tmp / "colmap_no_points" / "sparse" / "images.txt").read_text()
    (tmp / "colmap_no_points" / "sparse" / "images.txt").write_text(
        "\n".join(ln for ln in text.splitlines() if ln.strip()) + "\n")
    (tmp / "yml_bad" / "cameras.yml").write_text("%YAML:1.0\n---\nn_views: 2\nview_00: 3\n")


#: Requests that are odd but usable: exit 0 expected (see the module notes).
HANDLED = ("sections cylinder + 5 points 1e6 away", "sections cylinder + 5 points 1e6 along z",
           "run cylinder + 5 points 1e6 away", "sections --axis 1e308,1e308,0",
           "sections, stdout closed (>&-)", "sections, stdout /dev/full")
#: Environment of a row besides the defaults.
ROW_ENV = {"PHOTOSURF_ALLOW_LARGE=banana": {"PHOTOSURF_ALLOW_LARGE": "banana"},
           "PHOTOSURF_ALLOW_LARGE=off, --sections 1e9": {"PHOTOSURF_ALLOW_LARGE": "off"}}
#: Where a row's stdout goes besides /dev/null: closed, or a device that is always full.
ROW_STDOUT = {"sections, stdout closed (>&-)": "closed",
              "sections, stdout /dev/full": "/dev/full"}


def _cases(f: dict, out: Path) -> list[tuple[str, list]]:
    pair = [f["left"], f["right"], "--rig", f["rig"]]
    return [
        ("sections --sections 1e9", ["sections", f["cloud"], "--out", out / "m.ply",
                                     "--sections", "1000000000"]),
        ("sections --n 1e9", ["sections", f["cloud"], "--out", out / "m.ply", "--n",
                              "1000000000"]),
        ("sections cloud |x| ~ 1e300", ["sections", f["huge_cloud"], "--out", out / "m.ply"]),
        ("sections FIFO input", ["sections", f["fifo"], "--out", out / "m.ply"]),
        ("sections NPZ header 1e12 points", ["sections", f["npz"], "--out", out / "m.ply"]),
        ("sections cloud in a plane holding z", ["sections", f["flat"], "--out", out / "m.ply"]),
        ("synth cameras.n = 1e9", ["synth", f["recipe_views"], "--out", out / "s"]),
        ("synth second_ring.n = 1e8", ["synth", f["recipe_ring2"], "--out", out / "s"]),
        ("synth width = height = 1e6", ["synth", f["recipe_pixels"], "--out", out / "s"]),
        ("synth shape.triangles = 1e12", ["synth", f["recipe_triangles"], "--out", out / "s"]),
        ("synth render.supersample = 1e6", ["synth", f["recipe_supersample"], "--out",
                                            out / "s"]),
        ("synth texture.components = 1e9", ["synth", f["recipe_components"], "--out",
                                            out / "s"]),
        ("synth TOML nested 5000 deep", ["synth", f["recipe_nested"], "--out", out / "s"]),
        ("synth --set cameras.n=1e9", ["synth", f["recipe"], "--out", out / "s", "--set",
                                       "cameras.layout=ring", "--set", "cameras.n=1000000000"]),
        ("run --set sections.count=1e9", ["run", f["cloud"], "--out", out / "w", "--set",
                                          "sections.count=1000000000"]),
        ("run --scheduler local-cluster:100000", ["run", f["cloud"], "--out", out / "w",
                                                  "--scheduler", "local-cluster:100000"]),
        ("run --scheduler local-cluster:0", ["run", f["cloud"], "--out", out / "w",
                                             "--scheduler", "local-cluster:0"]),
        ("match --max-iter 1e9", ["match", *pair, "--out", out / "m", "--max-iter",
                                  "1000000000"]),
        ("match PNG header 100000x100000", ["match", f["big_png"], f["right"], "--rig", f["rig"],
                                            "--out", out / "m"]),
        ("stereo PNG header 100000x100000", ["stereo", f["big_png"], f["right"], "--rig",
                                             f["rig"], "--out", out / "c.ply"]),
        ("match /dev/zero as a view", ["match", "/dev/zero", f["right"], "--rig", f["rig"],
                                       "--out", out / "m"]),
        ("smooth --level 6, 26k triangles", ["smooth", f["mesh"], "--out", out / "s.ply",
                                             "--level", "6"]),
        ("smooth OFF header 1e9 vertices", ["smooth", f["off"], "--out", out / "s.ply"]),
        ("render mesh |x| ~ 1e200", ["render", f["huge_mesh"], "--out", out / "r.png"]),
        ("render GLB accessor count 1e12", ["render", f["glb"], "--out", out / "r.png"]),
        ("calibrate --pattern 100000x100000", ["calibrate", str(f["left"]), str(f["right"]),
                                               "--pattern", "100000x100000", "--square", "0.02",
                                               "--out", out / "rig.yml"]),
        ("calibrate --square 1e308", ["calibrate", str(f["left"]), str(f["right"]), "--square",
                                      "1e308", "--out", out / "rig.yml"]),
        ("photosurf (no command)", []),
        ("sections input a symlink loop", ["sections", f["link_loop"], "--out", out / "m.ply"]),
        ("run --out a symlink loop", ["run", f["cloud"], "--out", f["out_loop"]]),
        ("sections --out ''", ["sections", f["cloud"], "--out", ""]),
        ("PHOTOSURF_ALLOW_LARGE=banana", ["sections", f["cloud"], "--out", out / "m.ply",
                                          "--sections", "1000000000"]),
        ("sections --axis 1e308,1e308,0", ["sections", f["cloud"], "--out", out / "m.ply",
                                           "--axis=1e308,1e308,0"]),
        ("sections cylinder + 5 points 1e6 away", ["sections", f["far"], "--out",
                                                   out / "far.ply"]),
        ("sections cylinder + 5 points 1e6 along z", ["sections", f["far_axis"], "--out",
                                                      out / "far_axis.ply"]),
        ("run cylinder + 5 points 1e6 away", ["run", f["far"], "--out", out / "far_run",
                                              "--to", "sections"]),
        ("sections cylinder + 20 points 1e6 away", ["sections", f["far_group"], "--out",
                                                    out / "m.ply"]),
        ("sections noisy line", ["sections", f["line"], "--out", out / "m.ply"]),
        ("sections two planes across z", ["sections", f["planes"], "--out", out / "m.ply"]),
        ("sections npz sigma all zero", ["sections", f["sigma_zero"], "--out", out / "m.ply"]),
        ("sections decimal commas", ["sections", f["commas"], "--out", out / "m.ply"]),
        ("smooth vertex of valence 2000", ["smooth", f["valence"], "--out", out / "s.ply"]),
        ("smooth PLY header +50 faces", ["smooth", f["faces_claim"], "--out", out / "s.ply"]),
        ("synth cameras.fill = 100", ["synth", f["recipe"], "--out", out / "s", "--set",
                                      "cameras.fill=100"]),
        ("synth distortion k1 = 1e6", ["synth", f["recipe"], "--out", out / "s", "--set",
                                       "cameras.distortion=[1000000.0, 0.0, 0.0, 0.0, 0.0]"]),
        ("PHOTOSURF_ALLOW_LARGE=off, --sections 1e9", ["sections", f["cloud"], "--out",
                                                       out / "m.ply", "--sections",
                                                       "1000000000"]),
        ("run --out ''", ["run", f["cloud"], "--out", ""]),
        ("sections npz sigma negative", ["sections", f["sigma_negative"], "--out",
                                         out / "m.ply"]),
        ("stereo left named l_caf\\xe9.png (no overlap)", ["stereo", f["left_nonutf8"],
                                                            f["right"], "--rig", f["rig"],
                                                            "--out", out / "c.ply"]),
        ("stereo float TIFF with NaN pixels", ["stereo", f["nan_tiff"], f["right"], "--rig",
                                               f["rig"], "--out", out / "c.ply"]),
        ("acquire cameras.yml naming an image twice", ["acquire", f["yml_twice"], "--out",
                                                       out / "c.ply"]),
        ("acquire par file naming an image twice", ["acquire", f["par_twice"], "--cameras",
                                                    f["par_file"], "--out", out / "c.ply"]),
        ("acquire images.txt naming an image twice", ["acquire", f["colmap_twice"], "--out",
                                                      out / "c.ply"]),
        ("acquire images.txt without points lines", ["acquire", f["colmap_no_points"],
                                                     "--out", out / "c.ply"]),
        ("acquire cameras.yml that is no camera file", ["acquire", f["yml_bad"], "--out",
                                                        out / "c.ply"]),
        ("sections, stdout closed (>&-)", ["sections", f["cloud"], "--out", out / "m.ply"]),
        ("sections, stdout /dev/full", ["sections", f["cloud"], "--out", out / "m.ply"]),
    ]


def _make_inputs(tmp: Path) -> dict:
    """The inputs, written by a child process: a child's ``ru_maxrss`` counts the pages it
    shares with its parent at fork time, so the measuring process must not hold open3d and
    OpenCV (277 MB) itself."""
    subprocess.run([sys.executable, __file__, "--make-inputs", str(tmp)], check=True,
                   env=dict(os.environ, PYTHONPATH=str(ROOT)))
    return json.loads((tmp / "files.json").read_text())


def _measure(argv: list, timeout: float = 60.0, extra_env: dict | None = None,
             stdout: str | None = None) -> dict:
    """Run ``photosurf ARGV`` as a child; its wall time, peak RSS, status and stderr.
    ``stdout``: "closed" (the shell's ``>&-``) or a file to write it to (``/dev/full``)."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    env.pop("PHOTOSURF_ALLOW_LARGE", None)
    env.update(extra_env or {})
    out = open(stdout, "wb") if stdout and stdout != "closed" else subprocess.DEVNULL  # noqa: SIM115
    with tempfile.TemporaryFile() as err:
        start = time.perf_counter()
        proc = subprocess.Popen([sys.executable, "-m", "pipeline.cli", *map(os.fsencode, argv)],
                                stdout=out, stderr=err, env=env,
                                preexec_fn=(lambda: os.close(1)) if stdout == "closed" else None)
        if out is not subprocess.DEVNULL:
            out.close()
        deadline = start + timeout
        while True:
            pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
            if pid:
                break
            if time.perf_counter() > deadline:
                proc.kill()
                pid, status, usage = os.wait4(proc.pid, 0)
                break
            time.sleep(0.005)
        seconds = time.perf_counter() - start
        proc.returncode = os.waitstatus_to_exitcode(status)
        err.seek(0)
        lines = [ln for ln in err.read().decode("utf-8", "replace").splitlines() if ln.strip()]
    return {"status": proc.returncode, "seconds": round(seconds, 3),
            "cpu_s": round(usage.ru_utime + usage.ru_stime, 3),
            "peak_mb": round(usage.ru_maxrss / 1024, 1), "lines": len(lines),
            "message": lines[0] if lines else ""}


#: The hidden files an output may hold: a workspace's lock, an output folder's marker.
MARKER = ".photosurf-output.json"


def _tree(root: Path) -> set[str]:
    """Every path under ``root`` (links not followed), relative."""
    found = set()
    for folder, dirs, names in os.walk(root):
        found.update(os.path.relpath(os.path.join(folder, n), root) for n in dirs + names)
    return found


def _remove(root: Path, paths: list[str]) -> None:
    import shutil

    for rel in sorted(paths, key=len):
        path = root / rel
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path, ignore_errors=True)
        elif os.path.lexists(path):
            path.unlink()


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="a third of the rows")
    parser.add_argument("--json", default=str(Path(__file__).parent / "results" / "limits.json"))
    parser.add_argument("--make-inputs", metavar="DIR", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.make_inputs:  # in a child: this process stays small (see _make_inputs)
        files = _inputs(Path(args.make_inputs))
        (Path(args.make_inputs) / "files.json").write_text(
            json.dumps({k: os.fsdecode(v) if isinstance(v, bytes) else str(v)
                        for k, v in files.items()}))
        return 0
    rows = []
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory(prefix="limits-") as name:
        tmp = Path(name)
        files = _make_inputs(tmp)
        (tmp / "out").mkdir()
        cases = _cases(files, tmp / "out")
        if args.quick:
            cases = cases[::3]
        peer = _measure(["--help"])
        rows.append({"request": "peer: photosurf --help (start-up)", **peer})
        for label, command in cases:
            before = _tree(tmp)
            expect = "handled" if label in HANDLED else "refused"
            row = {"request": label, "expect": expect,  # handled rows do the work: 5 min
                   **_measure(command, timeout=300.0 if expect == "handled" else 60.0,
                              extra_env=ROW_ENV.get(label), stdout=ROW_STDOUT.get(label))}
            new = sorted(_tree(tmp) - before)
            # a refusal leaves nothing; a handled request its outputs, but no temporary
            row["left"] = [p for p in new if row["expect"] == "refused" or Path(p).name
                           .startswith(".") and Path(p).name not in (".lock", MARKER)]
            rows.append(row)
            _remove(tmp, new)  # the next row starts from the same files
    load = [round(max(a, b), 2) for a, b in zip(load_before, os.getloadavg(), strict=True)]
    width = max(len(r["request"]) for r in rows)
    print(f"{'request':<{width}}  status  wall s  CPU s  peak MB  lines  left  message")
    for r in rows:
        message = r["message"].split(": error: ", 1)[-1][:60]
        print(f"{r['request']:<{width}}  {r['status']:>6}  {r['seconds']:>6.2f}  "
              f"{r['cpu_s']:>5.2f}  {r['peak_mb']:>7.0f}  {r['lines']:>5}  "
              f"{len(r.get('left', [])):>4}  {message}")
    refused = [r for r in rows[1:] if r["expect"] == "refused" and r["status"] == 2
               and r["lines"] == 1 and not r["left"]]
    handled = [r for r in rows[1:] if r["expect"] == "handled" and r["status"] == 0
               and r["lines"] <= 1 and not r["left"]]
    expected_refusals = sum(r["expect"] == "refused" for r in rows[1:])
    worst_s = max(r["seconds"] for r in rows[1:])
    worst_cpu = max(r["cpu_s"] for r in rows[1:])
    worst_mb = max(r["peak_mb"] for r in rows[1:])
    print(f"{len(refused)} of {expected_refusals} refused in one line, {len(handled)} of "
          f"{len(rows) - 1 - expected_refusals} odd inputs handled; slowest {worst_s:.2f} s wall "
          f"({worst_cpu:.2f} s CPU), largest {worst_mb:.0f} MB (start-up alone "
          f"{peer['seconds']:.2f} s wall, {peer['cpu_s']:.2f} s CPU, {peer['peak_mb']:.0f} MB); "
          f"load average {load[0]:.2f} / {load[1]:.2f} / {load[2]:.2f} (1 / 5 / 15 min, the "
          "larger of before and after)")
    path = Path(args.json)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"rows": rows, "refused": len(refused), "handled": len(handled),
                                "cases": len(rows) - 1,
                                "slowest_s": worst_s, "slowest_cpu_s": worst_cpu,
                                "largest_mb": worst_mb, "load_average": load,
                                "cpus": os.cpu_count()}, indent=1) + "\n")
    return 0 if len(refused) + len(handled) == len(rows) - 1 else 1


if __name__ == "__main__":
    sys.exit(main())
