"""Hostile and odd input, round two: what a fresh probe still found.

Each case runs the real command (in-process with stderr captured at descriptor
level, or as a real process where the case needs one: a closed or full stdout)
and asserts exit status 2, exactly one line on stderr naming the problem, and
that nothing was written or left behind -- or, where the input is legitimate
but odd, that the command succeeds and says what it did.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pipeline import limits
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
    monkeypatch.setenv(limits.ALLOW_ENV, value)
    out = tmp_path / "m.ply"
    line = fails_cleanly(capfd, ["sections", cloud, "--sections", "1000000000", "--out", out],
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
