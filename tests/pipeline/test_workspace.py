"""The workspace engine: manifest, up-to-date rule, --from/--to, blocked stages, config."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from pipeline import config as config_mod
from pipeline.engine import StageError, run_pipeline
from pipeline.errors import InputError
from pipeline.inputs import detect_kind
from pipeline.plan import Stage
from pipeline.workspace import Workspace, save_npz, sha256_file

CALLS: list[str] = []


def _first(ctx):
    CALLS.append("first")
    values = np.loadtxt(ctx.inputs[0]) * ctx.params["toy"]["scale"]
    save_npz(ctx.out / "values.npz", values=values)
    return {"count": len(values)}


def _second(ctx):
    CALLS.append("second")
    values = np.load(ctx.stage_path("first", "values.npz"))["values"]
    save_npz(ctx.out / "sum.npz", total=values.sum() + ctx.params["toy2"]["offset"])


def _third(ctx):
    CALLS.append("third")
    total = np.load(ctx.stage_path("second", "sum.npz"))["total"]
    ctx.out.write_text(f"{float(total)!r}\n")


def _broken(ctx):
    raise np.linalg.LinAlgError("singular matrix")


TOY = [
    Stage("first", _first, params=("toy",), external=True),
    Stage("second", _second, params=("toy2",), needs=("first",)),
    Stage("third", _third, needs=("second",), target="third.txt"),
]
TOY_CONFIG = {"toy": {"scale": 2.0}, "toy2": {"offset": 1.0}}


@pytest.fixture()
def toy_input(tmp_path):
    path = tmp_path / "in.txt"
    np.savetxt(path, np.arange(5.0))
    return path


def _run(toy_input, out, config=None, **kw):
    CALLS.clear()
    return run_pipeline([toy_input], out, config or json.loads(json.dumps(TOY_CONFIG)),
                        stages=kw.pop("stages", TOY), **kw)


def test_run_writes_manifest_and_skips_up_to_date(toy_input, tmp_path):
    out = tmp_path / "ws"
    summary = _run(toy_input, out)
    assert [s.status for s in summary.stages] == ["done"] * 3
    assert CALLS == ["first", "second", "third"]
    # 2 * (0+1+2+3+4) + 1 = 21
    assert float((out / "third.txt").read_text()) == 21.0
    manifest = json.loads((out / "manifest.json").read_text())
    rec = manifest["stages"]["first"]
    assert rec["outputs"] == {"first/values.npz": sha256_file(out / "first/values.npz")}
    assert rec["params"] == {"toy": {"scale": 2.0}}
    assert rec["info"] == {"count": 5}
    assert "numpy" in manifest["versions"]
    assert manifest["inputs"][0]["sha256"] == sha256_file(toy_input)
    assert (out / "config.toml").is_file()
    summary = _run(toy_input, out)
    assert CALLS == []
    assert [s.status for s in summary.stages] == ["up to date"] * 3


def test_parameter_change_reruns_that_stage_and_downstream(toy_input, tmp_path):
    out = tmp_path / "ws"
    _run(toy_input, out)
    config = json.loads(json.dumps(TOY_CONFIG))
    config["toy2"]["offset"] = 5.0
    _run(toy_input, out, config)
    assert CALLS == ["second", "third"]
    assert float((out / "third.txt").read_text()) == 25.0


def test_changed_input_or_tampered_output_reruns(toy_input, tmp_path):
    out = tmp_path / "ws"
    _run(toy_input, out)
    (out / "second" / "sum.npz").write_bytes(b"garbage")
    _run(toy_input, out)
    assert CALLS == ["second"]  # same bytes again: third's input hash is unchanged
    np.savetxt(toy_input, np.arange(6.0))
    _run(toy_input, out)
    assert CALLS == ["first", "second", "third"]
    assert float((out / "third.txt").read_text()) == 31.0


def test_deterministic_npz(tmp_path):
    a = save_npz(tmp_path / "a.npz", x=np.arange(3), y=np.eye(2))
    b = save_npz(tmp_path / "b.npz", x=np.arange(3), y=np.eye(2))
    assert sha256_file(a) == sha256_file(b)
    assert np.array_equal(np.load(a)["y"], np.eye(2))


def test_from_to_and_force(toy_input, tmp_path):
    out = tmp_path / "ws"
    with pytest.raises(InputError, match="stage first has no outputs"):
        _run(toy_input, out, start="second")
    summary = _run(toy_input, out, stop="second")
    assert CALLS == ["first", "second"]
    assert summary.stages[2].status == "outside range"
    assert not (out / "third.txt").exists()
    _run(toy_input, out, start="second", force=True)
    assert CALLS == ["second", "third"]
    with pytest.raises(InputError, match="--from 'nope'"):
        _run(toy_input, out, start="nope")


def test_failed_stage_is_one_line_error_and_recorded(toy_input, tmp_path):
    out = tmp_path / "ws"
    stages = [TOY[0], Stage("second", _broken, needs=("first",)), TOY[2]]
    with pytest.raises(StageError, match=r"^stage second failed: LinAlgError: singular matrix$"):
        _run(toy_input, out, stages=stages)
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["stages"]["second"]["status"] == "failed"
    assert not (out / "second").exists()  # nothing half-written
    assert not [p for p in out.iterdir() if p.name.startswith(".second")]


def test_workspace_rejects_file_and_lock(tmp_path):
    (tmp_path / "f").write_text("x")
    with pytest.raises(InputError, match="must be a folder"):
        Workspace(tmp_path / "f")
    ws = Workspace(tmp_path / "ws")
    with ws.lock(), pytest.raises(InputError, match="another photosurf run"), \
            Workspace(tmp_path / "ws").lock():
        pass


def test_detect_kind(tmp_path):
    recipe = tmp_path / "r.toml"
    recipe.write_text("")
    cloud = tmp_path / "c.xyz"
    cloud.write_text("0 0 0\n")
    folder = tmp_path / "imgs"
    folder.mkdir()
    for i in range(3):
        (folder / f"{i}.png").write_bytes(b"")
    pair = tmp_path / "pair"
    pair.mkdir()
    (pair / "left.png").write_bytes(b"")
    (pair / "right.png").write_bytes(b"")
    (pair / "rig.yml").write_text("")
    assert detect_kind([recipe]) == "scene"
    assert detect_kind([cloud]) == "cloud"
    assert detect_kind([folder]) == "folder"
    assert detect_kind([pair]) == "stereo"
    assert detect_kind([pair / "left.png", pair / "right.png"], pair / "rig.yml") == "stereo"
    assert detect_kind([cloud], kind="cloud") == "cloud"
    with pytest.raises(InputError, match="needs --rig"):
        detect_kind([pair / "left.png", pair / "right.png"])
    with pytest.raises(InputError, match="cannot tell"):
        detect_kind([Path(sys.executable)])  # a file of no known kind
    with pytest.raises(FileNotFoundError, match="no such file"):
        detect_kind([tmp_path / "missing.ply"])
    with pytest.raises(InputError, match="--kind scene needs a recipe"):
        detect_kind([folder], kind="scene")


def test_config_resolution(tmp_path):
    cfg = tmp_path / "c.toml"
    cfg.write_text("[sections]\ncount = 12\n[smooth]\nlevel = 2\n")
    resolved = config_mod.resolve(cfg, ["smooth.level=4", "sections.axis=auto",
                                        "report.tau_rel=1", "scene.overrides.noise.sigma=0",
                                        "scene.overrides.cameras.width=64",
                                        "scene.overrides.cameras.height=48"])
    assert resolved["sections"]["count"] == 12
    assert resolved["smooth"]["level"] == 4
    assert resolved["sections"]["axis"] == "auto"
    assert resolved["report"]["tau_rel"] == 1.0
    assert resolved["scene"]["overrides"] == {"noise": {"sigma": 0},
                                              "cameras": {"width": 64, "height": 48}}
    assert config_mod.resolve(None, ["sections.axis=[0, 1, 0]"])["sections"]["axis"] == [0, 1, 0]
    # the written file reads back to the same set
    import tomllib

    assert tomllib.loads(config_mod.dumps(resolved)) == resolved


@pytest.mark.parametrize("assignment, message", [
    ("sections.cuont=3",
     r"unknown parameter 'sections.cuont' "
     r"\(known: axis, count, open, projection, spacing, thickness\)"),
    ("nosuch.key=3", r"unknown section 'nosuch'"),
    ("smooth.level=high",
     r"smooth.level must be int \(like 1\) or 'auto' or 'adaptive', got 'high'"),
    ("smooth.level=2.5", r"smooth.level must be int"),
    ("sections.axis=sideways", r"sections.axis must be \[x, y, z\] or 'x' or 'y' or 'z'"),
    ("sections.axis=[1, 2]", r"sections.axis must be"),
    ("stitch.caps=1", r"stitch.caps must be bool"),
    ("smoothlevel", r"expected section.key=value"),
    ("curves.parametrisation=wobbly", r"'wobbly': choose from uniform, centripetal, chordal"),
    ('export.formats=["ply", "docx"]', r"'docx': choose from ply, obj, stl, gltf, glb"),
])
def test_config_errors_name_the_key(assignment, message):
    with pytest.raises(InputError, match=message):
        config_mod.resolve(None, [assignment])


def test_config_file_errors(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[sections\ncount = 3\n")
    with pytest.raises(InputError, match=r"bad.toml: invalid TOML"):
        config_mod.resolve(bad)
    with pytest.raises(FileNotFoundError, match="no such config file"):
        config_mod.resolve(tmp_path / "none.toml")


def test_stages_of_another_input_kind_are_forgotten(toy_input, tmp_path):
    out = tmp_path / "ws"
    _run(toy_input, out)
    _run(toy_input, out, stages=TOY[:2])  # e.g. a cloud after a scene: no "scene" stage
    manifest = json.loads((out / "manifest.json").read_text())
    assert set(manifest["stages"]) == {"first", "second"}


def test_code_closure_follows_own_imports_only():
    from pipeline.workspace import code_files

    names = {p.relative_to(p.parents[1]).as_posix() for p in code_files(["surface.bezier"])}
    assert {"surface/bezier.py", "surface/_loop_patches.py", "surface/__init__.py"} <= names
    assert not any(n.startswith(("matching/", "pipeline/")) for n in names)
    names = {p.relative_to(p.parents[1]).as_posix() for p in code_files(["matching.pair"])}
    assert {"matching/lsm.py", "matching/seeds.py", "matching/triangulate.py"} <= names
    assert not any(n.startswith("surface/") for n in names)


def test_code_closure_imports_nothing():
    """The code hash reads the sources; it does not execute them (2026-12-06: finding each
    module with importlib's find_spec imported the closure, scipy.stats and all, ~2 s
    before a run's first stage)."""
    import subprocess

    probe = ("import sys; from pipeline.workspace import code_files; "
             "files = code_files(['pipeline.stages', 'surface.sizing', 'matching.multiview']); "
             "print(len(files), sorted(m for m in ('scipy.stats', 'matching.further_views', "
             "'surface.sizing', 'open3d') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                         check=True, cwd=Path(__file__).resolve().parents[2])
    count, imported = out.stdout.split(" ", 1)
    assert int(count) > 30 and imported.strip() == "[]"


def test_code_closure_kept_imports_give_the_same_files(tmp_path):
    """The names each source imports are kept by its content hash: a fresh process reads
    them back instead of parsing (0.5 s of every ``photosurf run``) and finds the same
    files; an edited source (another hash) or a damaged cache file is parsed anew."""
    import subprocess

    cache = tmp_path / "imports.json"
    probe = ("import ast, sys, pathlib; from pipeline import workspace as w; "
             f"w.IMPORTS_CACHE = pathlib.Path({str(cache)!r}); "
             "parse = ast.parse; calls = []; "
             "ast.parse = lambda *a, **k: (calls.append(1), parse(*a, **k))[1]; "
             "files = w.code_files(['pipeline.stages', 'surface.sizing', 'matching.multiview']); "
             "print(len(calls), '|'.join(map(str, files)))")

    def run():
        out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                             check=True, cwd=Path(__file__).resolve().parents[2])
        parsed, files = out.stdout.strip().split(" ", 1)
        return int(parsed), files

    first = run()
    assert first[0] > 30 and cache.is_file()
    again = run()
    assert again == (0, first[1])                  # read back: nothing parsed, same files
    kept = json.loads(cache.read_text())
    victim = next(iter(kept))
    kept[victim] = "not a list"                    # a damaged entry is parsed anew
    cache.write_text(json.dumps(kept))
    assert run() == (1, first[1])
    cache.write_text("{not json")                  # a damaged file: everything parsed anew
    assert run() == first


def test_code_change_reruns_the_stage_that_uses_it(toy_input, tmp_path, monkeypatch):
    """An upgraded photosurf: the source of a module a stage calls changes."""
    from pipeline import workspace

    source = tmp_path / "toy_code.py"
    source.write_text("SCALE = 1\n")
    real = workspace._module_file
    monkeypatch.setattr(workspace, "_module_file",
                        lambda name: source if name == "pipeline._toy_code" else real(name))
    stages = [TOY[0],
              Stage("second", _second, params=("toy2",), needs=("first",),
                    modules=("pipeline._toy_code",)),
              TOY[2]]
    out = tmp_path / "ws"
    _run(toy_input, out, stages=stages)
    assert CALLS == ["first", "second", "third"]
    _run(toy_input, out, stages=stages)
    assert CALLS == []
    source.write_text("SCALE = 2\n")
    _run(toy_input, out, stages=stages)
    assert CALLS == ["second"]  # same output bytes: third stays up to date
