"""Malformed inputs to ``photosurf run`` / ``batch``: a clear error or a named warning, never more.

Every example runs the real command in this process and checks the contract
of the hardened inputs:

* the exit status is 0 (the run went through, possibly with stages skipped
  with a named reason) or 2 (an error);
* an error is one line, ``photosurf CMD: error: ...``, and its message is a
  sentence, not a bare Python exception (``IndexError: ...``,
  ``TypeError: ...``): a wrapped unexpected exception is a bug of a stage;
* nothing is half-written: no temporary is left in OUTDIR, and every stage
  folder present is one the manifest records as done with these exact files.

Hypothesis draws the clouds (sizes 0..40, NaN/inf, duplicates, coplanar and
collinear sets, garbage bytes in every cloud format), images (truncated,
corrupt, wrong sizes), rig files (NaN, singular K, missing matrices) and TOML
(recipes, configs, batch manifests); with the fixed cases that is well over 300
malformed inputs.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pipeline import cli
from pipeline.workspace import sha256_file

ROOT = Path(__file__).resolve().parents[2]
FUZZ = settings(max_examples=60, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.function_scoped_fixture,
                                       HealthCheck.too_slow])
#: A wrapped exception of one of these types means a stage crashed instead of refusing.
_CRASH = re.compile(r"\b(IndexError|KeyError|TypeError|AttributeError|ZeroDivisionError|"
                    r"UnboundLocalError|NameError|AssertionError|RuntimeError|"
                    r"FloatingPointError|OverflowError|RecursionError|LinAlgError|"
                    r"QhullError)\b")
#: Small report and sections so that a run takes a fraction of a second.
FAST = ["--set", "report.samples=500", "--set", "report.width=48", "--set", "report.height=36"]


def run_cli(capfd, *args) -> tuple[int, str]:
    capfd.readouterr()
    code = cli.main([str(a) for a in args])
    return code, capfd.readouterr().err


def assert_clean(code: int, err: str, outdir: Path | None, command: str = "run") -> None:
    """The contract: exit 0 or a one-line error exit 2; no temporaries; no partial stage."""
    assert code in (0, 2), (code, err)
    if code == 2:
        lines = [line for line in err.splitlines() if line.strip()]
        errors = [line for line in lines if line.startswith(f"photosurf {command}: error: ")]
        assert len(errors) == 1, err
        assert not _CRASH.search(errors[0]), errors[0]
        assert "Traceback" not in err
    if outdir is None or not outdir.is_dir():
        return
    leftovers = [p.name for p in outdir.iterdir() if p.name.startswith(".") and p.name != ".lock"]
    assert leftovers == [], leftovers
    manifest_path = outdir / "manifest.json"
    stage_dirs = [p for p in outdir.iterdir() if p.is_dir() and not p.name.startswith(".")]
    if not manifest_path.is_file():
        assert stage_dirs == []
        return
    stages = json.loads(manifest_path.read_text())["stages"]
    for folder in stage_dirs:
        rec = stages.get(folder.name, {})
        if rec.get("status") != "done":  # an older complete output, not yet replaced
            continue
        for rel, digest in rec["outputs"].items():
            assert sha256_file(outdir / rel) == digest, rel


# ----------------------------------------------------------------------------- clouds
def _coordinates(draw, n: int) -> np.ndarray:
    special = draw(st.sampled_from(["plain", "nan", "inf", "duplicate", "coplanar",
                                    "collinear", "huge", "tiny"]))
    rng = np.random.default_rng(draw(st.integers(0, 2**16)))
    z = rng.uniform(0, 3, n)
    theta = rng.uniform(0, 2 * np.pi, n)
    points = np.column_stack([np.cos(theta), np.sin(theta), z])
    if n == 0:
        return points
    if special == "nan":
        points[rng.integers(0, n), rng.integers(0, 3)] = np.nan
    elif special == "inf":
        points[rng.integers(0, n), rng.integers(0, 3)] = -np.inf
    elif special == "duplicate":
        points[:] = points[0]
    elif special == "coplanar":
        points[:, 2] = 1.5
    elif special == "collinear":
        points[:, :2] = 0.0
    elif special == "huge":
        points *= 1e300
    elif special == "tiny":
        points *= 1e-300
    return points


@st.composite
def cloud_files(draw):
    n = draw(st.integers(0, 40))
    points = _coordinates(draw, n)
    fmt = draw(st.sampled_from(["xyz", "csv", "npz", "ply", "garbage", "truncated"]))
    return fmt, points, draw(st.binary(min_size=0, max_size=200))


def _write_cloud(path: Path, fmt: str, points: np.ndarray, garbage: bytes) -> Path:
    from pipeline.cloud_io import write_ply

    if fmt == "xyz":
        path = path.with_suffix(".xyz")
        np.savetxt(path, points)
    elif fmt == "csv":
        path = path.with_suffix(".csv")
        np.savetxt(path, points, delimiter=",", header="x,y,z", comments="")
    elif fmt == "npz":
        path = path.with_suffix(".npz")
        np.savez(path, points=points)
    elif fmt == "ply":
        path = write_ply(path.with_suffix(".ply"), points)
    elif fmt == "garbage":
        path = path.with_suffix(".ply" if garbage[:1] < b"\x80" else ".npz")
        path.write_bytes(garbage)
    else:  # a valid PLY cut short
        full = write_ply(path.with_suffix(".ply"), points if len(points) else np.zeros((3, 3)))
        data = full.read_bytes()
        full.write_bytes(data[: max(1, len(data) * 2 // 3)])
        path = full
    return path


@FUZZ
@given(case=cloud_files())
def test_malformed_clouds(tmp_path_factory, capfd, case):
    fmt, points, garbage = case
    work = tmp_path_factory.mktemp("cloud")
    path = _write_cloud(work / "cloud", fmt, points, garbage)
    out = work / "out"
    code, err = run_cli(capfd, "run", path, "--out", out, "--to", "stitch", *FAST)
    assert_clean(code, err, out)
    if code == 0:  # what went through is finite
        with np.load(out / "acquire" / "cloud.npz") as cloud:
            assert np.all(np.isfinite(cloud["points"]))


@st.composite
def section_clouds(draw):
    """Sectioned shapes that are hard for the topology: non-star, self-intersecting, split."""
    kind = draw(st.sampled_from(["star", "figure8", "two_loops", "spiral", "zigzag", "one_point"]))
    per = draw(st.integers(4, 60))
    levels = draw(st.integers(2, 6))
    t = np.linspace(0, 2 * np.pi, per, endpoint=False)
    rings = []
    for k in range(levels):
        if kind == "star":
            r = 1 + 0.6 * np.cos(7 * t)
            xy = np.column_stack([r * np.cos(t), r * np.sin(t)])
        elif kind == "figure8":
            xy = np.column_stack([np.sin(t), np.sin(t) * np.cos(t)])
        elif kind == "two_loops":
            xy = np.concatenate([np.column_stack([np.cos(t) - 3, np.sin(t)]),
                                 np.column_stack([np.cos(t) + 3, np.sin(t)])])
        elif kind == "spiral":
            xy = np.column_stack([t * np.cos(t), t * np.sin(t)])
        elif kind == "zigzag":
            xy = np.column_stack([t, (-1.0) ** np.arange(per)])
        else:
            xy = np.zeros((1, 2))
        rings.append(np.column_stack([xy, np.full(len(xy), 0.5 * k)]))
    return kind, np.concatenate(rings)


@FUZZ
@given(case=section_clouds())
def test_awkward_sections(tmp_path_factory, capfd, case):
    _, points = case
    work = tmp_path_factory.mktemp("sections")
    path = work / "cloud.xyz"
    np.savetxt(path, points)
    out = work / "out"
    code, err = run_cli(capfd, "run", path, "--out", out, "--to", "stitch", *FAST)
    assert_clean(code, err, out)


# ----------------------------------------------------------------------------- images and rigs
@pytest.fixture(scope="module")
def tiny_pair(tmp_path_factory) -> Path:
    """A rendered 64x48 stereo pair of the vase with its cameras.yml."""
    from pipeline.scenes import load_recipe, render_scene

    out = tmp_path_factory.mktemp("pair") / "scene"
    recipe = load_recipe(ROOT / "fixtures" / "scenes" / "vase.toml",
                         {"cameras": {"width": 64, "height": 48, "focal_px": 83.2},
                          "shape": {"triangles": 2000}, "render": {"supersample": 1}})
    render_scene(recipe, out, progress=False)
    return out


@st.composite
def broken_images(draw):
    how = draw(st.sampled_from(["truncate", "bytes", "empty", "resize", "text"]))
    cut = draw(st.floats(0.0, 0.95))
    size = (draw(st.integers(1, 80)), draw(st.integers(1, 60)))
    return how, cut, size, draw(st.binary(max_size=300))


@FUZZ
@given(case=broken_images(), which=st.sampled_from([0, 1]))
def test_broken_images(tmp_path_factory, capfd, tiny_pair, case, which):
    import cv2

    how, cut, size, garbage = case
    work = tmp_path_factory.mktemp("img")
    images = [tiny_pair / "images" / "view_00.png", tiny_pair / "images" / "view_01.png"]
    target = work / images[which].name
    data = images[which].read_bytes()
    if how == "truncate":
        target.write_bytes(data[: int(len(data) * cut)])
    elif how == "bytes":
        target.write_bytes(garbage)
    elif how == "empty":
        target.write_bytes(b"")
    elif how == "resize":
        cv2.imwrite(str(target), cv2.resize(cv2.imread(str(images[which])), size))
    else:
        target.write_text("not an image\n")
    pair = [target if k == which else images[k] for k in range(2)]
    out = work / "out"
    code, err = run_cli(capfd, "run", *pair, "--rig", tiny_pair / "cameras.yml", "--out", out,
                        "--to", "acquire", *FAST)
    assert_clean(code, err, out)
    if how != "resize" or size == (64, 48):
        return
    assert code == 2  # a wrong size is refused, never matched against the rig


@st.composite
def broken_rigs(draw):
    what = draw(st.sampled_from(["nan", "inf", "singular", "zero_focal", "drop", "garbage",
                                 "empty"]))
    return what, draw(st.integers(0, 1)), draw(st.binary(max_size=200))


@FUZZ
@given(case=broken_rigs())
def test_broken_rigs(tmp_path_factory, capfd, tiny_pair, case):
    what, view, garbage = case
    work = tmp_path_factory.mktemp("rig")
    text = (tiny_pair / "cameras.yml").read_text()
    rig = work / "rig.yml"
    if what == "garbage":
        rig.write_bytes(garbage)
    elif what == "empty":
        rig.write_text("")
    else:
        text = _edit_camera(text, view, what)
        rig.write_text(text)
    out = work / "out"
    images = [tiny_pair / "images" / f"view_0{k}.png" for k in range(2)]
    code, err = run_cli(capfd, "run", *images, "--rig", rig, "--out", out, "--to", "acquire",
                        *FAST)
    assert_clean(code, err, out)
    if what in ("nan", "inf", "singular", "zero_focal", "drop", "empty"):
        assert code == 2, err


def _edit_camera(text: str, view: int, what: str) -> str:
    """Break view ``view``'s K in an OpenCV FileStorage YAML (data: [fx, 0, cx, ...])."""
    blocks = re.split(r"(?m)^(?=view_\d\d:)", text)
    index = next(i for i, b in enumerate(blocks) if b.startswith(f"view_0{view}:"))
    block = blocks[index]
    if what == "drop":
        block = re.sub(r"(?ms)^   K: !!opencv-matrix.*?\]\n", "", block, count=1)
    else:
        match = re.search(r"(?ms)(   K: !!opencv-matrix.*?data: \[)(.*?)(\])", block)
        values = [v.strip() for v in match.group(2).split(",")]
        if what == "nan":
            values[0] = ".nan"
        elif what == "inf":
            values[4] = ".inf"
        elif what == "singular":
            values = ["0."] * 9
        else:
            values[0] = values[4] = "0."
        block = block[:match.start(2)] + ", ".join(values) + block[match.end(2):]
    blocks[index] = block
    return "".join(blocks)


# ----------------------------------------------------------------------------- TOML and paths
@FUZZ
@given(text=st.text(max_size=200), target=st.sampled_from(["recipe", "config", "batch"]))
def test_broken_toml(tmp_path_factory, capfd, text, target):
    work = tmp_path_factory.mktemp("toml")
    path = work / "file.toml"
    path.write_text(text, encoding="utf-8")
    out = work / "out"
    if target == "recipe":
        code, err = run_cli(capfd, "run", path, "--out", out, "--to", "scene", *FAST)
        assert code == 2  # no text of 200 characters is a complete valid recipe
    elif target == "config":
        code, err = run_cli(capfd, "run", path, "--out", out, "--config", path, "--to", "scene")
    else:
        code, err = run_cli(capfd, "batch", path, "--out", out)
    assert_clean(code, err, out, "batch" if target == "batch" else "run")


@pytest.mark.parametrize("args", [
    ["run", "{missing}.ply", "--out", "{out}"],
    ["run", "{missing}.toml", "--out", "{out}"],
    ["run", "{missing}", "--out", "{out}"],
    ["run", "{cloud}", "--out", "/proc/photosurf-out"],            # cannot be created
    ["run", "{cloud}", "--out", "{cloud}/sub"],                    # under a file
    ["run", "{cloud}", "--out", "{out}", "--kind", "scene"],
    ["run", "{cloud}", "--out", "{out}", "--kind", "folder"],
    ["run", "{work}", "--out", "{out}"],                           # a folder with no images
    ["run", "{cloud}", "--out", "{out}", "--rig", "{missing}.yml"],
    ["run", "{cloud}", "--out", "{out}", "--from", "report", "--to", "acquire"],
    ["run", "{cloud}", "--out", "{out}", "--scheduler", "nowhere"],
    ["run", "{cloud}", "--out", "{out}", "--set", "sections.axis=[0, 0, 0]"],
    ["run", "{cloud}", "--out", "{out}", "--set", "sections.axis=sideways"],
    ["run", "{cloud}", "--out", "{out}", "--set", "sections.count=-3"],
    ["run", "{cloud}", "--out", "{out}", "--set", "sections.spacing=-1.0"],
    ["run", "{cloud}", "--out", "{out}", "--set", "curves.n=2"],
    ["run", "{cloud}", "--out", "{out}", "--set", "curves.smoothing=-1"],
    ["run", "{cloud}", "--out", "{out}", "--set", "curves.parametrisation=wobbly"],
    ["run", "{cloud}", "--out", "{out}", "--set", "smooth.level=99"],
    ["run", "{cloud}", "--out", "{out}", "--set", "export.formats=[\"docx\"]"],
    ["run", "{cloud}", "--out", "{out}", "--set", "report.width=0"],
    ["batch", "{missing}.toml", "--out", "{out}"],
])
def test_bad_arguments_and_paths(tmp_path, capfd, args):
    rng = np.random.default_rng(1)
    z = rng.uniform(0, 3, 400)
    theta = rng.uniform(0, 2 * np.pi, 400)
    cloud = tmp_path / "cloud.xyz"
    np.savetxt(cloud, np.column_stack([np.cos(theta), np.sin(theta), z]))
    values = {"missing": tmp_path / "missing", "out": tmp_path / "out", "cloud": cloud,
              "work": tmp_path / "empty"}
    (tmp_path / "empty").mkdir()
    args = [a.format(**values) for a in args]
    code, err = run_cli(capfd, args[0], *FAST, *args[1:])  # the case's own --set wins
    assert code == 2, err
    assert_clean(code, err, tmp_path / "out", args[0])
