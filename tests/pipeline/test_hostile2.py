"""Hostile and odd input, round two: what a fresh probe still found.

Each case runs the real command (in-process with stderr captured at descriptor
level, or as a real process where the case needs one: a closed or full stdout)
and asserts exit status 2, exactly one line on stderr naming the problem, and
that nothing was written or left behind -- or, where the input is legitimate
but odd, that the command succeeds and says what it did.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pipeline import cli, cmd_sections, limits
from tests.pipeline.test_fuzz_inputs import (
    assert_nothing_written,
    call_main,
    cylinder_points,
    fails_cleanly,
)

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def cloud(tmp_path_factory) -> Path:
    from pipeline.cloud_io import write_cloud

    return write_cloud(tmp_path_factory.mktemp("hostile2") / "cyl.xyz", cylinder_points(600))


def _env(**extra) -> dict:
    env = dict(os.environ, PYTHONPATH=str(ROOT), **extra)
    env.pop(limits.ALLOW_ENV, None)
    return env


def _photosurf(argv: list, cwd: Path, shell_redirect: str = "",
               **env) -> subprocess.CompletedProcess:
    """The real program; ``shell_redirect`` (``>&-``, ``> /dev/full``) applied by a shell."""
    command = " ".join([f"'{sys.executable}'", "-m", "pipeline.cli",
                        *(f"'{a}'" for a in argv), shell_redirect])
    return subprocess.run(["/bin/sh", "-c", command], cwd=cwd, env=_env(**env),
                          stderr=subprocess.PIPE, text=True, timeout=120)


# =========================================================================== one line

def test_no_arguments_is_one_line(capfd):
    capfd.readouterr()
    assert call_main([]) == 2
    captured = capfd.readouterr()
    lines = captured.err.splitlines()
    assert captured.out == ""
    assert len(lines) == 1, captured.err
    assert lines[0].startswith("photosurf: error: a command is required")
    assert "sections" in lines[0] and "--help" in lines[0]


@pytest.mark.parametrize("axis", ["1e308,1e308,0", "-1e308,0,1e308", "1e-320,0,0"])
def test_extreme_axis_is_a_direction(cloud, tmp_path, capfd, axis):
    """A vector axis is a direction: its scale (overflowing or underflowing squares) must
    neither warn nor turn it into [0, 0, 0]."""
    from pipeline.cmd_sections import parse_axis

    direction = parse_axis(axis)
    expected = np.array([float(v) for v in axis.split(",")])
    expected = np.sign(expected) * (np.abs(expected) == np.abs(expected).max())
    np.testing.assert_allclose(direction, expected / np.linalg.norm(expected), atol=1e-15)
    capfd.readouterr()
    status = call_main(["sections", cloud, f"--axis={axis}", "--out", tmp_path / "m.ply"])
    err = capfd.readouterr().err
    assert "[0.0, 0.0, 0.0]" not in err and "Warning" not in err, err
    assert len([ln for ln in err.splitlines() if ln.strip()]) <= 1, err
    assert status in (0, 2)


def test_empty_out_refused(cloud, tmp_path, capfd, monkeypatch):
    monkeypatch.chdir(tmp_path)
    for argv in (["sections", cloud, "--out", ""], ["run", cloud, "--out", ""]):
        fails_cleanly(capfd, argv, "--out is empty")
    assert list(tmp_path.iterdir()) == []


# =========================================================================== limits switch

@pytest.mark.parametrize("value", ["banana", "2", "yes please"])
def test_allow_large_unknown_value_is_an_error(cloud, tmp_path, capfd, monkeypatch, value):
    import dataclasses

    # the limit lowered to 10 sections: were the value taken as a yes, 20 sections cost
    # nothing (10^9 would fill the machine)
    monkeypatch.setitem(limits.LIMITS, "sections.count",
                        dataclasses.replace(limits.LIMITS["sections.count"], maximum=10))
    monkeypatch.setenv(limits.ALLOW_ENV, value)
    out = tmp_path / "m.ply"
    line = fails_cleanly(capfd, ["sections", cloud, "--sections", "20", "--out", out],
                         limits.ALLOW_ENV, out=out)
    assert "neither yes" in line


@pytest.mark.parametrize(("value", "lifted"), [("1", True), ("YES", True), ("true", True),
                                                ("off", False), ("0", False), ("", False)])
def test_allow_large_yes_and_no(monkeypatch, value, lifted):
    monkeypatch.setenv(limits.ALLOW_ENV, value)
    if lifted:
        limits.check("sections.count", 1e9)
    else:
        with pytest.raises(limits.LimitError):
            limits.check("sections.count", 1e9)


# =========================================================================== links

def test_symlink_loop_as_input(cloud, tmp_path, capfd):
    (tmp_path / "a.xyz").symlink_to(tmp_path / "b.xyz")
    (tmp_path / "b.xyz").symlink_to(tmp_path / "a.xyz")
    out = tmp_path / "m.ply"
    fails_cleanly(capfd, ["sections", tmp_path / "a.xyz", "--out", out], "a.xyz",
                  "symbolic link loop", out=out)


@pytest.mark.parametrize("command", ["sections", "run"])
def test_symlink_loop_as_out(cloud, tmp_path, capfd, command):
    suffix = ".ply" if command == "sections" else ""
    a, b = tmp_path / f"a{suffix}", tmp_path / f"b{suffix}"
    a.symlink_to(b)
    b.symlink_to(a)
    fails_cleanly(capfd, [command, cloud, "--out", a], "symbolic link loop")
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([a.name, b.name])


# =========================================================================== stdout

def test_stdout_closed(cloud, tmp_path):
    """``>&-``: Python starts with ``sys.stdout = None``; the summary is dropped, the mesh
    written, exit 0 -- and no file the command opens takes descriptor 1."""
    proc = _photosurf(["sections", cloud, "--out", "o.ply"], tmp_path, ">&-")
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr and proc.stderr.strip() == "", proc.stderr
    from pipeline.mesh_io import read_mesh

    vertices, triangles = read_mesh(tmp_path / "o.ply")[:2]
    assert len(triangles) > 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o.ply"]


def test_stdout_full(cloud, tmp_path):
    """``> /dev/full``: the mesh is the product, stdout only reports: exit 0 with the mesh,
    one warning line saying the summary was lost (never exit 2 with the mesh written)."""
    if not Path("/dev/full").exists():
        pytest.skip("no /dev/full")
    proc = _photosurf(["sections", cloud, "--out", "o.ply"], tmp_path, "> /dev/full")
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert proc.returncode == 0, proc.stderr
    assert len(lines) == 1 and "No space left on device" in lines[0], proc.stderr
    assert "warning" in lines[0] and "Exception ignored" not in proc.stderr
    assert (tmp_path / "o.ply").is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o.ply"]


def test_stdout_full_on_a_failure_writes_nothing(tmp_path):
    if not Path("/dev/full").exists():
        pytest.skip("no /dev/full")
    proc = _photosurf(["sections", "nope.xyz", "--out", "o.ply"], tmp_path, "> /dev/full")
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert proc.returncode == 2 and len(lines) == 1 and "nope.xyz" in lines[0], proc.stderr
    assert_nothing_written(tmp_path / "o.ply")


# =========================================================================== far outliers

def _with_far_points(n: int, along_axis: bool, seed: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """A ``n``-point unit cylinder and the same plus 5 points ~10^6 away (scattered, or
    strung along its axis)."""
    clean = cylinder_points(n, seed=seed)
    if along_axis:
        far = np.column_stack([np.zeros(5), np.zeros(5), 1e6 * np.arange(1, 6)])
    else:
        far = np.random.default_rng(seed).normal(size=(5, 3)) * 1e6
    return clean, np.vstack([clean, far])


def _limited(argv: list, cwd: Path) -> subprocess.CompletedProcess:
    """The real program with its address space capped at 6 GB: a cost that is not bounded
    fails at once instead of filling the machine (numba and open3d reserve ~2.5 GB)."""
    import resource

    def cap():
        resource.setrlimit(resource.RLIMIT_AS, (6 << 30, 6 << 30))

    return subprocess.run([sys.executable, "-m", "pipeline.cli", *map(str, argv)], cwd=cwd,
                          env=_env(), capture_output=True,
                          text=True, timeout=300, preexec_fn=cap)


@pytest.mark.parametrize("along_axis", [False, True], ids=["scattered", "along-axis"])
def test_far_outliers_dropped_by_sections(tmp_path, along_axis):
    """The 5 far points are dropped with one warning line and the mesh is the clean
    cloud's, bit for bit (the same points reach the surface code)."""
    from pipeline.cloud_io import write_cloud
    from pipeline.mesh_io import read_mesh

    clean, dirty = _with_far_points(2000, along_axis)
    write_cloud(tmp_path / "clean.xyz", clean)
    write_cloud(tmp_path / "dirty.xyz", dirty)
    proc = _limited(["sections", "dirty.xyz", "--out", "dirty.ply"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stderr.splitlines()
    assert len(lines) == 1 and "5 far outlier point(s) of 2005 dropped" in lines[0], proc.stderr
    assert "2000 points" in proc.stdout
    assert call_main(["sections", tmp_path / "clean.xyz", "--out", tmp_path / "clean.ply",
                      "-q"]) == 0
    v_dirty, t_dirty = read_mesh(tmp_path / "dirty.ply")[:2]
    v_clean, t_clean = read_mesh(tmp_path / "clean.ply")[:2]
    np.testing.assert_array_equal(t_dirty, t_clean)
    np.testing.assert_array_equal(v_dirty, v_clean)


def test_far_outliers_dropped_by_run(tmp_path):
    """Through ``photosurf run``: the sections stage drops them, says so, and no stage
    temporary is left."""
    import json

    from pipeline.cloud_io import write_cloud

    _, dirty = _with_far_points(1500, along_axis=False)
    write_cloud(tmp_path / "dirty.npz", dirty)
    proc = _limited(["run", "dirty.npz", "--out", "w", "--to", "sections"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "5 far outlier point(s) of 1505 dropped" in proc.stderr
    left = [p.name for p in (tmp_path / "w").iterdir() if p.name.startswith(".")
            and p.name != ".lock"]
    assert left == [], left
    manifest = json.loads((tmp_path / "w" / "manifest.json").read_text())
    assert "5 far outlier" in json.dumps(manifest["stages"]["sections"])


def test_a_far_group_too_large_to_drop_is_costed_before_slicing(tmp_path, capfd):
    """20 points together 10^6 away are more than a stray (they could be a small piece):
    kept, and the cloud is refused by its extent in point spacings before any slicing."""
    from pipeline.cloud_io import write_cloud

    rng = np.random.default_rng(3)
    cloud = np.vstack([cylinder_points(2000), 1e6 + rng.normal(size=(20, 3))])
    path = write_cloud(tmp_path / "group.xyz", cloud)
    out = tmp_path / "m.ply"
    fails_cleanly(capfd, ["sections", path, "--out", out], "sections.count",
                  "along the slicing axis", "two point spacings", out=out)


def test_far_outliers_rule():
    from surface.outliers import GAP_SPACINGS, MIN_GROUP, far_outliers

    clean = cylinder_points(3000)
    assert far_outliers(clean).count == 0
    # two objects far apart are two objects, not outliers
    two = np.vstack([clean, clean + [1e4, 0.0, 0.0]])
    assert far_outliers(two).count == 0
    # a group of MIN_GROUP - 1 beyond the gap is dropped, one of MIN_GROUP kept
    found = far_outliers(clean)
    beyond = clean[:, 2].max() + 1.5 * GAP_SPACINGS * found.spacing
    for size, dropped in ((MIN_GROUP - 1, MIN_GROUP - 1), (MIN_GROUP, 0)):
        group = np.column_stack([np.zeros(size), np.zeros(size),
                                 beyond + 0.1 * found.spacing * np.arange(size)])
        assert far_outliers(np.vstack([clean, group])).count == dropped
    # a stray just inside the gap is kept: the rule is the gap, not a distance
    near = np.array([[0.0, 0.0, clean[:, 2].max() + 0.5 * GAP_SPACINGS * found.spacing]])
    assert far_outliers(np.vstack([clean, near])).count == 0


# =========================================================================== file contents

@pytest.mark.parametrize(("text", "line", "needles"), [
    ("-0,651928 -0,758701 1,299520\n-0,1 0,2 0,3\n", 1, ["decimal comma", "-0,651928"]),
    ("1 2 3\n4 5 6\n7 8\n", 3, ["2 numbers", "'7 8'"]),
    ("1 2 3 4\n5 6 7 8\n", 1, ["4 numbers", "3 or 6"]),
    ("1 2 3\n4 5 6 7 8 9\n", 2, ["6 numbers, the lines before hold 3"]),
    ("1,2,3\n4,,6\n", 2, ["not numbers"]),
])
def test_text_cloud_line_that_is_not_3_or_6_numbers(tmp_path, capfd, text, line, needles):
    path = tmp_path / "c.xyz"
    path.write_text(text)
    out = tmp_path / "m.ply"
    fails_cleanly(capfd, ["sections", path, "--out", out], f"c.xyz:{line}:", *needles, out=out)


def test_text_cloud_header_names_its_columns(tmp_path):
    from pipeline.cloud_io import read_cloud

    path = tmp_path / "c.xyz"
    path.write_text("# x y z sigma\n1 2 3 0.5\n4 5 6 0.25\n")
    back = read_cloud(path)
    np.testing.assert_array_equal(back.points, [[1, 2, 3], [4, 5, 6]])
    np.testing.assert_array_equal(back.extra, [[0.5], [0.25]])


@pytest.mark.parametrize(("sigma", "needle"), [(0.0, "none of its"), (-0.01, "never negative"),
                                                (np.nan, "none of its")])
def test_npz_sigma_that_is_not_a_precision(tmp_path, capfd, sigma, needle):
    from pipeline.cloud_io import write_cloud

    points = cylinder_points(600)
    path = write_cloud(tmp_path / "c.npz", points, sigma=np.full(len(points), sigma))
    out = tmp_path / "m.ply"
    fails_cleanly(capfd, ["sections", path, "--out", out], "c.npz", "'sigma'", needle, out=out)


@pytest.mark.parametrize("ascii_ply", [False, True], ids=["binary", "ascii"])
def test_ply_header_claiming_more_faces_than_present(tmp_path, capfd, ascii_ply):
    import open3d as o3d

    sphere = o3d.geometry.TriangleMesh.create_sphere(1.0, 8)
    good = tmp_path / "good.ply"
    o3d.io.write_triangle_mesh(str(good), sphere, write_ascii=ascii_ply)
    faces = len(sphere.triangles)
    data = good.read_bytes()
    claim = f"element face {faces}\n".encode()
    assert claim in data
    bad = tmp_path / "bad.ply"
    bad.write_bytes(data.replace(claim, f"element face {faces + 50}\n".encode()))
    out = tmp_path / "s.ply"
    fails_cleanly(capfd, ["smooth", bad, "--out", out], "bad.ply", f"claims {faces + 50} faces",
                  f"holds {faces}", out=out, also=[out.with_suffix(".npz")])


# =========================================================================== smooth

def _bipyramid(n: int) -> tuple[np.ndarray, np.ndarray]:
    """A closed mesh whose two apexes have valence ``n``."""
    theta = np.linspace(0, 2 * np.pi, n, endpoint=False)
    ring = np.column_stack([np.cos(theta), np.sin(theta), np.zeros(n)])
    vertices = np.vstack([ring, [[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]]])
    i = np.arange(n)
    j = (i + 1) % n
    triangles = np.vstack([np.column_stack([i, j, np.full(n, n)]),
                           np.column_stack([j, i, np.full(n, n + 1)])])
    return vertices, triangles


def test_smooth_vertex_of_valence_2000_refused_before_building(tmp_path, capfd):
    """A vertex of valence n costs ~19 kB x n^2 (its ring operator): 2000 would need
    ~77 GB; refused by the limit, before the control net is built."""
    from pipeline.mesh_io import write_mesh

    mesh = write_mesh(tmp_path / "fan.ply", *_bipyramid(2000))
    out = tmp_path / "s.ply"
    line = fails_cleanly(capfd, ["smooth", mesh, "--out", out], "smooth.valence = 2000",
                         "estimated 76.8 GB", out=out, also=[out.with_suffix(".npz")])
    assert "--allow-large" in line


def test_valence_limit_costs_the_square():
    assert limits.estimate("smooth.valence", 1000).startswith("19.2 GB")
    assert limits.estimate("smooth.valence", 2000).startswith("76.8 GB")


# =========================================================================== degenerate clouds

def test_noisy_line_is_a_line(tmp_path, capfd):
    """Collinear to 1e-3 over a length of 7.5: the exact-collinearity test (s2 <= 1e-9 s1)
    lets it through, but it is narrower than a loop at its own point spacing."""
    from pipeline.cloud_io import write_cloud

    rng = np.random.default_rng(0)
    t = rng.uniform(0, 2, 2000)
    cloud = np.column_stack([t, 2 * t, 3 * t]) + rng.normal(0, 1e-3, (2000, 3))
    path = write_cloud(tmp_path / "line.xyz", cloud)
    out = tmp_path / "m.ply"
    fails_cleanly(capfd, ["sections", path, "--out", out], "one line", "point spacings",
                  out=out)


def test_thin_tube_is_not_a_line():
    """A tube ~8 points round (width ~2.5 spacings) is kept: the line rule is a loop's need."""
    from pipeline.guards import check_cloud_shape
    from surface.sections import point_spacing

    rng = np.random.default_rng(2)
    theta, z = rng.uniform(0, 2 * np.pi, 4000), rng.uniform(0, 40, 4000)
    tube = np.column_stack([0.3 * np.cos(theta), 0.3 * np.sin(theta), z])
    assert 0.6 / point_spacing(tube) > 2.0
    check_cloud_shape(tube, "tube", axis="z")


def test_planes_across_the_axis_with_nothing_between(tmp_path, capfd):
    from pipeline.cloud_io import write_cloud

    rng = np.random.default_rng(0)
    disc = rng.uniform(-1, 1, (1000, 2))
    cloud = np.vstack([np.column_stack([disc, np.zeros(1000)]),
                       np.column_stack([disc, np.full(1000, 0.5)])])
    path = write_cloud(tmp_path / "planes.xyz", cloud)
    out = tmp_path / "m.ply"
    fails_cleanly(capfd, ["sections", path, "--out", out], "2 planes across the slicing axis",
                  out=out)


# =========================================================================== synth

@pytest.mark.parametrize(("setting", "needle"), [
    ("cameras.fill=100", "cameras.fill: 100"),
    ("cameras.distortion=[1000000.0, 0.0, 0.0, 0.0, 0.0]", "cameras.distortion"),
])
def test_synth_camera_that_is_no_camera(tmp_path, capfd, setting, needle):
    from tests.pipeline.test_fuzz_inputs import GOOD_RECIPE

    recipe = tmp_path / "scene.toml"
    recipe.write_text(GOOD_RECIPE)
    out = tmp_path / "out"
    fails_cleanly(capfd, ["synth", recipe, "--out", out, "--set", setting], needle, out=out)


# =========================================================================== full disk

_STEP_UNDER_LIMIT = """
import resource, signal, sys
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # EFBIG instead of the signal
from surface import bezier
from tests.pipeline.test_fuzz_inputs import tetra_mesh
from pipeline.cad_export import write_cad
net = bezier.control_net(*tetra_mesh())
limit = int(sys.argv[1])
if limit:
    resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
try:
    if len(sys.argv) > 2:  # inside a stage folder being written, as photosurf run's export
        from pipeline.atomic import atomic_dir
        with atomic_dir(sys.argv[2]) as stage:
            write_cad(stage / "s.step", net.control_points, net.domain_mesh[1])
    else:
        write_cad("s.step", net.control_points, net.domain_mesh[1])
except Exception as exc:
    print(type(exc).__name__, exc)
"""


def test_step_export_on_a_full_disk_says_so(tmp_path):
    """OpenCascade's writer returns a status without the errno; the export finds the cause
    (a file-size limit here, ENOSPC alike) instead of "OpenCascade could not write"."""
    def write(limit: int) -> str:
        return subprocess.run([sys.executable, "-c", _STEP_UNDER_LIMIT, str(limit)],
                              cwd=tmp_path, env=_env(), capture_output=True, text=True,
                              timeout=300).stdout.strip()

    # 8 kB: past the header, short of the tetrahedron's 60 kB of entities
    message = write(8192)
    assert message.startswith("OSError") and "File too large" in message, message
    assert "s.step" in message and "OpenCascade" not in message
    assert list(tmp_path.iterdir()) == []


def test_step_export_inside_a_stage_on_a_full_disk_names_the_final_path(tmp_path):
    """The STEP text is written by Python, whose failed write names no file: inside a
    stage folder being filled (``photosurf run``'s export) the error names the file where
    the user will find it, not the stage's temporary folder."""
    proc = subprocess.run([sys.executable, "-c", _STEP_UNDER_LIMIT, "8192", "w/export"],
                          cwd=tmp_path, env=_env(), capture_output=True, text=True, timeout=300)
    message = proc.stdout.strip()
    assert message.startswith("OSError") and "File too large" in message, message
    assert "'w/export/s.step'" in message and "/.export." not in message, message
    assert [p for p in tmp_path.rglob("*") if not p.is_dir()] == []


# =========================================================================== signals

TEMPLE = ROOT.parent / "shared" / "data" / "real" / "temple_sparse_ring"


def test_sigterm_during_structure_from_motion_is_one_line(tmp_path):
    """pycolmap installs glog's failure handler for SIGTERM when imported (a native stack
    trace, death by the signal); the CLI puts its own handler back after the import."""
    import signal
    import time

    images = sorted(TEMPLE.glob("*.png")) if TEMPLE.is_dir() else []
    if len(images) < 8:
        pytest.skip("real data ../shared/data/real/temple_sparse_ring absent")
    folder = tmp_path / "views"  # the images alone (links): cameras from SfM
    folder.mkdir()
    for image in images:
        (folder / image.name).symlink_to(image)
    proc = subprocess.Popen([sys.executable, "-m", "pipeline.cli", "acquire", str(folder),
                             "--out", str(tmp_path / "c.ply")], env=_env(),
                            stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        if "pycolmap" in Path(f"/proc/{proc.pid}/maps").read_text():
            break
        time.sleep(0.05)
    time.sleep(1.0)  # into pycolmap's work
    proc.send_signal(signal.SIGTERM)
    sent = time.monotonic()
    _, err = proc.communicate(timeout=120)
    if proc.returncode == 0:
        pytest.skip("acquire finished before the signal")
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert proc.returncode == 128 + signal.SIGTERM, err
    assert lines == ["photosurf acquire: interrupted (SIGTERM)"], err
    assert time.monotonic() - sent < 30
    assert not (tmp_path / "c.ply").exists()


_SLOW_COMMAND = """
import sys, threading, time, types
from pipeline import cli
from matching.scheduler import thread_map


def pair(item):  # a view pair: 60 s of work in its thread
    print("started", flush=True)
    time.sleep(60)


def run(args):  # two view pairs at once
    thread_map(2)(pair, range(6))


cli._load = lambda name: types.SimpleNamespace(HELP="slow", add_arguments=lambda p: None,
                                               run=run) if name == "run" else None
sys.argv = ["photosurf", "run"]
sys.exit(cli.main())
"""


@pytest.mark.parametrize("sig", ["SIGINT", "SIGTERM"])
def test_interrupt_does_not_wait_for_running_pairs(tmp_path, sig):
    """Ctrl-C while pairs run on threads: the queued pairs are cancelled and the running
    ones not waited for (before: the pool's exit, then the interpreter's, joined them)."""
    import signal
    import time

    signum = getattr(signal, sig)
    proc = subprocess.Popen([sys.executable, "-c", _SLOW_COMMAND], cwd=tmp_path, env=_env(),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert "started" in proc.stdout.readline()  # the pairs' threads are running
    time.sleep(0.5)
    proc.send_signal(signum)
    sent = time.monotonic()
    _, err = proc.communicate(timeout=120)
    assert time.monotonic() - sent < 10, "the interruption waited for the running tasks"
    assert proc.returncode == 128 + signum, err
    assert [ln for ln in err.splitlines() if ln.strip()] == [
        f"photosurf run: interrupted ({sig})"], err


def test_local_executor_cancels_queued_tasks():
    """A task's error ends the map at once: the queued tasks never start, the running one
    is not waited for (it would take 5 s)."""
    import threading
    import time

    from pipeline.executor import LocalExecutor

    started = []
    lock = threading.Lock()
    release = threading.Event()

    def task(item):
        with lock:
            started.append(item)
        if item == 0:
            time.sleep(0.2)  # the other worker is inside its task by then
            raise ValueError("bad item")
        release.wait(5.0)
        return item

    begin = time.monotonic()
    with pytest.raises(ValueError, match="bad item"):
        LocalExecutor(workers=2).map(task, range(40))
    elapsed = time.monotonic() - begin
    release.set()
    assert elapsed < 2.5, f"waited {elapsed:.1f} s for the running task"
    assert len(started) < 10, started


# =========================================================================== identical views

def test_identical_images_under_different_cameras_warn(tmp_path, caplog):
    """24 copies of one image under 24 cameras of a ring: one warning line naming them."""
    import logging
    from types import SimpleNamespace

    from pipeline.acquisition import _warn_identical_views, identical_views
    from tests.pipeline.test_fuzz_inputs import textured, write_png

    names = [f"v{k:02d}.png" for k in range(24)]
    for name in names:
        write_png(tmp_path / name, textured(64, 48, 1))
    write_png(tmp_path / "other.png", textured(64, 48, 2))
    assert identical_views(tmp_path, names + ["other.png"]) == [names]
    angles = np.linspace(0, 2 * np.pi, 24, endpoint=False)
    cameras = [SimpleNamespace(center=np.array([np.cos(a), np.sin(a), 0.0])) for a in angles]
    with caplog.at_level(logging.WARNING, logger="photosurf"):
        _warn_identical_views(tmp_path, names, cameras)
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 1 and "24 views are one and the same image" in lines[0], lines
    assert "cameras at different places" in lines[0]
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="photosurf"):
        _warn_identical_views(tmp_path, names[:1] + ["other.png"], cameras[:2])
    assert caplog.records == []


def test_disk_full_names_the_final_path_not_the_stage_temporary(tmp_path):
    """Inside a folder being written (a stage of photosurf run), the probe's error names
    the place the file will have, not the temporary folder."""
    from pipeline.atomic import atomic_dir, raise_if_full, user_path

    final = tmp_path / "w" / "export"
    with atomic_dir(final) as tmp:
        inside = tmp / "surface.step"
        assert user_path(inside) == final / "surface.step"
        inside.write_bytes(b"x")
        raise_if_full(inside, inside)  # room on this disk: no error, file as it was
        assert inside.read_bytes() == b"x"
    assert user_path(tmp / "surface.step") == tmp / "surface.step"


@pytest.mark.parametrize(("value", "expected"), [("[1e308, 1e308, 0]", [1.0, 1.0, 0.0]),
                                                 ("[0, 0, 2]", [0.0, 0.0, 1.0])])
def test_run_axis_vector_is_a_direction(value, expected):
    from pipeline.config import resolve

    config = resolve(None, [f"sections.axis={value}"])
    assert config["sections"]["axis"] == expected


@pytest.mark.parametrize("value", ["[0, 0, 0]", "[inf, 0, 0]", "[nan, 1, 0]"])
def test_run_axis_vector_that_is_no_direction(value):
    from pipeline.config import resolve
    from pipeline.errors import InputError

    with pytest.raises(InputError, match="sections.axis must be a finite, non-zero"):
        resolve(None, [f"sections.axis={value}"])


def test_view_that_is_a_link_loop_or_a_dangling_link_says_so(tmp_path):
    """An image that is a link in a loop, or a link to nothing, was left out as "no such
    file": the reason names the link."""
    from pipeline.inputs import read_image

    (tmp_path / "a.png").symlink_to("b.png")
    (tmp_path / "b.png").symlink_to("a.png")
    (tmp_path / "c.png").symlink_to("gone.png")
    with pytest.raises(FileNotFoundError, match=r"a\.png: a symbolic link loop"):
        read_image(tmp_path / "a.png")
    with pytest.raises(FileNotFoundError, match=r"c\.png: a link to gone\.png, which does not "
                                                r"exist"):
        read_image(tmp_path / "c.png")
    with pytest.raises(FileNotFoundError, match=r"d\.png: no such file$"):
        read_image(tmp_path / "d.png")


_SINGLE_PAIR = """
import hashlib, sys
import matching.pair as pair
from pipeline import cli


def busy(*args, **kwargs):  # one C call of ~14 CPU-s (> 10 s wall), no signal interrupts
    print("started", flush=True)
    hashlib.pbkdf2_hmac("sha256", b"x", b"y", 6 * 10 ** 7)


pair.reconstruct_pair = pair.match_pair = busy
sys.argv = ["photosurf", *sys.argv[1:]]
sys.exit(cli.main())
"""


@pytest.mark.parametrize("command", ["stereo", "match"])
def test_interrupt_does_not_wait_for_a_single_pair(tmp_path, command):
    """Ctrl-C into ``stereo`` or ``match``: the pair ran in the main thread, where a signal
    waits until the running C call returns (OpenCV's SGBM, an LSM kernel: 20-45 s each
    on a 12-megapixel pair at load 20); it now runs off it and the stop acts at once."""
    import signal
    import time

    from tests.pipeline.test_fuzz_inputs import textured, write_png, write_rig_file

    left = write_png(tmp_path / "l.png", textured(64, 48, 1))
    right = write_png(tmp_path / "r.png", textured(64, 48, 2))
    rig = write_rig_file(tmp_path / "rig.yml")
    out = tmp_path / ("c.ply" if command == "stereo" else "m")
    proc = subprocess.Popen([sys.executable, "-c", _SINGLE_PAIR, command, str(left), str(right),
                             "--rig", str(rig), "--out", str(out)], cwd=tmp_path, env=_env(),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert "started" in proc.stdout.readline(), proc.stderr.read()
    time.sleep(0.5)
    proc.send_signal(signal.SIGINT)
    sent = time.monotonic()
    _, err = proc.communicate(timeout=300)
    assert time.monotonic() - sent < 10, "the interruption waited for the pair's C call"
    assert proc.returncode == 128 + signal.SIGINT, err
    assert [ln for ln in err.splitlines() if ln.strip()] == [
        f"photosurf {command}: interrupted (SIGINT)"], err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["l.png", "r.png", "rig.yml"]


def test_a_signal_inside_a_compiled_kernel_is_one_line(tmp_path, capfd, monkeypatch):
    """SIGTERM handled while a numba kernel runs reaches the command wrapped in a
    SystemError ("... returned a result with an exception set", the signal's exception its
    cause): still one line naming the signal and the exit status 128 + 15, no traceback;
    a SystemError of another cause is not taken for an interruption."""
    def wrapped(args):
        try:
            raise cli.Terminated(signal.SIGTERM)
        except KeyboardInterrupt as exc:
            raise SystemError("CPUDispatcher(kernel) returned a result with an exception "
                              "set") from exc

    monkeypatch.setattr(cmd_sections, "run", wrapped)
    status = cli.main(["sections", str(tmp_path / "c.ply"), "--out", str(tmp_path / "o.ply")])
    err = capfd.readouterr().err
    assert status == 128 + signal.SIGTERM
    assert err.strip().splitlines() == ["photosurf sections: interrupted (SIGTERM)"], err

    def other(args):
        raise SystemError("a real bug")

    monkeypatch.setattr(cmd_sections, "run", other)
    with pytest.raises(SystemError, match="a real bug"):
        cli.main(["sections", str(tmp_path / "c.ply"), "--out", str(tmp_path / "o.ply")])
