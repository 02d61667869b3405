"""Executors: the in-process default and Dask (LocalCluster of 2 worker processes) agree."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import numpy as np
import pytest

from pipeline import cli
from pipeline.batch import read_manifest
from pipeline.errors import InputError
from pipeline.executor import DaskExecutor, LocalExecutor, get_executor
from pipeline.workspace import sha256_file

ROOT = Path(__file__).resolve().parents[2]


def _square_sum(seed: int, scale: float = 1.0) -> tuple[int, float]:
    values = np.random.default_rng(seed).normal(size=1000) * scale
    return os.getpid(), float(np.sum(values ** 2))


def test_local_executor_keeps_order_and_kwargs():
    serial = LocalExecutor().map(_square_sum, range(6), scale=2.0)
    threaded = LocalExecutor(workers=2).map(_square_sum, range(6), scale=2.0)
    assert [v for _, v in serial] == [v for _, v in threaded]
    assert {pid for pid, _ in serial} == {os.getpid()}  # in this process
    # E[sum x^2] = 1000 * scale^2 = 4000; 6 sigma of a chi-square(1000) * 4 is ~1900
    assert all(abs(v - 4000) < 1900 for _, v in serial)


@pytest.mark.parametrize("scheduler", ["bogus", "tcp://", "local-cluster:x", "http://a:1"])
def test_bad_scheduler_is_one_line_error(scheduler):
    with pytest.raises(InputError, match="--scheduler"):
        get_executor(scheduler)


def test_unreachable_scheduler_is_one_line_error():
    with pytest.raises(InputError, match=r"--scheduler tcp://127.0.0.1:9: cannot connect"):
        DaskExecutor("tcp://127.0.0.1:9", timeout="1s")


def _outputs(workspace: Path) -> dict[str, str]:
    """Every stage's recorded output hashes (the report, stamped with the time, left out)."""
    manifest = json.loads((workspace / "manifest.json").read_text())
    found = {}
    for name, rec in manifest["stages"].items():
        if name != "report":
            found.update(rec.get("outputs", {}))
    return found


def test_dask_local_cluster_gives_identical_results(tmp_path, capfd):
    with get_executor("local-cluster:2") as ex:
        assert isinstance(ex, DaskExecutor)
        results = ex.map(_square_sum, range(6), scale=2.0)
    local = LocalExecutor().map(_square_sum, range(6), scale=2.0)
    assert [v for _, v in results] == [v for _, v in local]
    assert os.getpid() not in {pid for pid, _ in results}  # ran in worker processes
    # a batch of objects as tasks, cloud -> smooth surface: the same bytes as in-process
    # (BLAS threading kept as in this process; Dask's default pin changes the last bits)
    manifest = tmp_path / "batch.toml"
    lines = []
    for k in range(2):
        rng = np.random.default_rng(k)
        z, theta = rng.uniform(0, 3, 2000), rng.uniform(0, 2 * np.pi, 2000)
        r = 1 + 0.3 * np.sin(2 * z)
        np.savetxt(tmp_path / f"vase{k}.xyz", np.column_stack([r * np.cos(theta),
                                                               r * np.sin(theta), z]))
        lines.append(f'[[object]]\ninput = "vase{k}.xyz"\n')
    manifest.write_text("".join(lines))
    assert [t["name"] for t in read_manifest(manifest)] == ["vase0", "vase1"]
    capfd.readouterr()
    for out, extra in (("local", []), ("dask", ["--scheduler", "local-cluster:2"])):
        status = cli.main(["batch", str(manifest), "--out", str(tmp_path / out), "-q",
                           "--to", "smooth", *extra])
        assert status == 0
    err = capfd.readouterr().err
    # quiet: no dask warnings about ports, dashboards or the network (a stage's own
    # one-line warning, the same in both runs, may stand)
    lines = [line for line in err.splitlines() if line.strip()]
    assert all(line.startswith(("smooth: ", "photosurf: smooth: ")) for line in lines), err
    assert not any(w in err.lower() for w in ("distributed", "dashboard", "port ")), err
    for name in ("vase0", "vase1"):
        local_files = _outputs(tmp_path / "local" / name)
        assert "smooth/control_net.npz" in local_files
        assert _outputs(tmp_path / "dask" / name) == local_files
        for rel, digest in local_files.items():
            assert sha256_file(tmp_path / "dask" / name / rel) == digest


@pytest.mark.parametrize("text, message", [
    ("[[object]]\nname = 'a'\n", "give input"),
    ("[[object]]\ninput = 'x.toml'\ncolour = 1\n", "unknown key 'colour'"),
    ("[[object]]\ninput = 'a/x.toml'\n[[object]]\ninput = 'b/x.toml'\n", "duplicate name 'x'"),
    ("title = 'x'\n", "unknown key 'title'"),
    ("[[object]\n", "invalid TOML"),
    ("", r"no \[\[object\]\] entries"),
])
def test_batch_manifest_errors(tmp_path, text, message):
    path = tmp_path / "m.toml"
    path.write_text(text)
    with pytest.raises(InputError, match=message):
        read_manifest(path)


def test_batch_failed_object_does_not_stop_the_others(tmp_path, capfd):
    manifest = tmp_path / "batch.toml"
    manifest.write_text(
        "[[object]]\nname = 'missing'\ninput = 'nowhere.ply'\n"
        f'[[object]]\ninput = "{ROOT}/fixtures/scenes/vase.toml"\n'
        "set = { scene = { overrides = { cameras = { width = 64, height = 48, "
        "focal_px = 83.2 }, shape = { triangles = 2000 }, render = { supersample = 1 } } } }\n")
    status = cli.main(["batch", str(manifest), "--out", str(tmp_path / "out"), "--to", "scene",
                       "-q"])
    assert status == 2
    err = capfd.readouterr().err.strip().splitlines()
    assert err == [f"photosurf batch: error: 1 of 2 objects failed (see {tmp_path}/out/"
                   f"batch.json): missing: {tmp_path}/nowhere.ply: no such file or folder"]
    summary = json.loads((tmp_path / "out" / "batch.json").read_text())
    assert [o["status"] for o in summary["objects"]] == ["failed", "done"]


def test_dask_refuses_workers_that_run_other_code(tmp_path, monkeypatch):
    """A source file edited after this process imported it: the workers (which import it
    when they start) would run other code; the executor says so instead of returning
    other numbers (the 2026-11-22 cause of Dask != in-process on the 1024x768 ring)."""
    module = tmp_path / "photosurf_probe_mod.py"
    module.write_text("def value(x):\n    return x + 1\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(
        p for p in (str(tmp_path), os.environ.get("PYTHONPATH")) if p))
    import photosurf_probe_mod

    try:
        with DaskExecutor(None, n_workers=1) as ex:
            assert ex.map(photosurf_probe_mod.value, [1, 2]) == [2, 3]  # same code: runs
        # another length than the first text, so no stale bytecode cache can hide it
        module.write_text("def value(x):\n    return x + 1000\n")
        with DaskExecutor(None, n_workers=1) as ex:
            with pytest.raises(InputError, match=r"other code .*photosurf_probe_mod"):
                ex.map(photosurf_probe_mod.value, [1, 2])
    finally:
        sys.modules.pop("photosurf_probe_mod", None)


def test_code_fingerprint_is_the_same_in_a_fresh_process():
    """The fingerprint hashes code, not process state (set constants follow the per-process
    string hash seed; marshal's bytes would differ)."""
    import subprocess

    import matching.multiview  # noqa: F401 - loaded here and in the child alike
    from pipeline.executor import code_fingerprint, project_modules

    names = [n for n in project_modules() if n.startswith(("matching", "pipeline.executor"))]
    here = code_fingerprint(names)
    script = ("import json, sys; from pipeline.executor import code_fingerprint; "
              f"print(json.dumps(code_fingerprint({names!r})))")
    env = {**os.environ, "PYTHONHASHSEED": "12345"}
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                         check=True, cwd=ROOT, env=env).stdout
    assert json.loads(out) == here


@pytest.mark.slow
def test_dask_view_pairs_identical_to_in_process_at_1024x768():
    """View pairs + consistency checks of the 1024x768 vase ring through LocalCluster(2)
    give the in-process (threaded) cloud bit for bit.  Full size matters: above 640 px
    the SIFT disparity range is found at half resolution, and OpenCV/numba split their
    work by image size and thread count (the 2026-11-22 runs saw a difference only at 1024x768)."""
    from matching.multiview import reconstruct_multiview, select_pairs
    from pipeline.scenes import build_scene, load_recipe, render_view

    scene = build_scene(load_recipe(ROOT / "fixtures" / "scenes" / "vase_ring.toml"))
    views = range(5)  # an arc of the 24-view ring: 2 pairs, each with further views
    images = [render_view(scene, k)[0] for k in views]
    cameras = [scene.cameras[k] for k in views]
    pairs = select_pairs(cameras)[1:3]
    local = reconstruct_multiview(images, cameras, pairs=pairs)
    with DaskExecutor(None, n_workers=2) as ex:
        remote = reconstruct_multiview(images, cameras, pairs=pairs, map_func=ex.map)
    assert len(local) > 5000
    for name in ("points", "sigma", "views", "pair", "colours"):
        assert np.array_equal(getattr(local, name), getattr(remote, name)), name
    assert local.reason_counts == remote.reason_counts
