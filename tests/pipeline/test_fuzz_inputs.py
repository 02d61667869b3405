"""Hardened inputs: malformed files fed to every public reader.

Each reader must either read the file (when a mutation happened to leave it
valid) or raise one of the errors the CLI turns into one line with exit
status 2 -- ``InputError`` / ``ValueError`` / ``FileNotFoundError`` /
``IsADirectoryError`` -- whose message names the file.  Never another
exception type (a traceback for the user).  The CLI-level cases, which also
check stderr and that nothing half-written is left, are in
``test_fuzz_cli.py``; the helpers shared by both live here.

Hypothesis runs derandomized (fixed examples, reproducible in CI) with small
inputs; example counts are sized so that the whole fuzz suite stays well
under three minutes on two cores.
"""

from __future__ import annotations

import math
import tempfile
import warnings
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pipeline.cli import USER_ERRORS, main
from pipeline.errors import InputError

#: What a reader may raise on bad input (the CLI prints these as one line, exit 2).
READER_ERRORS = (InputError, ValueError, FileNotFoundError, IsADirectoryError,
                 NotADirectoryError, PermissionError)

# --------------------------------------------------------------------------- shared helpers

#: Reproducible, fixture-friendly hypothesis settings; ``fuzz(n)`` sets the example count.
BASE = settings(deadline=None, derandomize=True, database=None, print_blob=False,
                suppress_health_check=list(HealthCheck))


def fuzz(n: int) -> settings:
    return settings(BASE, max_examples=n)


@contextmanager
def scratch():
    """A fresh folder per hypothesis example (``tmp_path`` is per test, not per example)."""
    with tempfile.TemporaryDirectory(prefix="fuzz-") as name:
        yield Path(name)


def leftovers(out: Path) -> list[str]:
    """Hidden temporaries of :mod:`pipeline.atomic` for ``out`` (and ``out.npz``) in its folder."""
    out = Path(out)
    if not out.parent.is_dir():
        return []
    stems = {out.stem, out.name}
    return sorted(p.name for p in out.parent.iterdir()
                  if p.name.startswith(".") and any(p.name.startswith(f".{s}.") for s in stems))


def assert_nothing_written(out: Path, *also: Path) -> None:
    out = Path(out)
    for path in (out, *also):
        assert not Path(path).exists(), f"{path} was written on a failed run"
    assert leftovers(out) == [], f"temporaries left beside {out}: {leftovers(out)}"


def call_main(argv) -> int:
    """``main(argv)``; Python warnings other than photosurf's own named ones fail the test.

    Under pytest a warning is recorded, not printed; the real program would print it on
    stderr (two more lines), so an anonymous ``RuntimeWarning`` (a division by zero on
    bad input) breaks the one-line rule.
    """
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        status = main([str(a) for a in argv])
    foreign = [f"{w.category.__name__}: {w.message} ({w.filename}:{w.lineno})" for w in caught
               if w.category.__module__.split(".")[0] not in ("surface", "matching", "pipeline")]
    assert not foreign, "warnings on stderr besides the error line:\n" + "\n".join(foreign)
    return status


def fails_cleanly(capfd, argv, *needles, out=None, also=()) -> str:
    """Run the CLI in-process; assert exit 2 and exactly one stderr line holding ``needles``.

    ``capfd`` captures file descriptor 2 too, so native libraries (OpenCV,
    open3d) printing their own diagnostics would fail the one-line rule.
    """
    capfd.readouterr()
    status = call_main(argv)
    err = capfd.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert "Traceback" not in err, err
    assert status == 2, f"exit status {status}, stderr:\n{err}"
    assert len(lines) == 1, f"expected one error line, got:\n{err}"
    assert lines[0].startswith(f"photosurf {argv[0]}: error: "), lines[0]
    for needle in needles:
        assert str(needle) in lines[0], f"{needle!r} not named in: {lines[0]}"
    if out is not None:
        assert_nothing_written(out, *also)
    return lines[0]


def raises_naming(func, path, *args, **kwargs):
    """Call a reader; it may succeed, else it must raise a user error naming ``path``."""
    try:
        return func(*args, **kwargs)
    except READER_ERRORS as exc:
        assert str(Path(path).name) in str(exc), f"{type(exc).__name__} does not name {path}: {exc}"
        return exc


def must_fail(func, path, *args, **kwargs) -> str:
    """The reader must raise a user error naming ``path``; return its message."""
    result = raises_naming(func, path, *args, **kwargs)
    assert isinstance(result, Exception), f"{path}: malformed input was accepted"
    return str(result)


# --------------------------------------------------------------------------- fixture makers


def make_rig(width: int = 64, height: int = 48):
    import cv2

    from matching.cameras import Camera, StereoRig

    K = np.array([[100.0, 0.0, (width - 1) / 2], [0.0, 100.0, (height - 1) / 2],
                  [0.0, 0.0, 1.0]])
    left = Camera(K, np.zeros(5), np.eye(3), np.zeros(3), width, height, "left")
    R, _ = cv2.Rodrigues(np.array([0.0, 0.1, 0.0]))
    right = Camera(K, np.zeros(5), R, np.array([-0.2, 0.0, 0.0]), width, height, "right")
    return StereoRig(left, right)


def write_rig_file(path: Path, width: int = 64, height: int = 48) -> Path:
    from matching.cameras import write_rig

    write_rig(path, make_rig(width, height))
    return path


def textured(width: int = 64, height: int = 48, seed: int = 0) -> np.ndarray:
    """A small uint8 image with texture at a few pixels' wavelength."""
    import cv2

    rng = np.random.default_rng(seed)
    noise = rng.uniform(0, 255, (height, width)).astype(np.float32)
    return np.clip(cv2.GaussianBlur(noise, (0, 0), 1.2) * 3 - 255, 0, 255).astype(np.uint8)


def write_png(path: Path, image: np.ndarray) -> Path:
    import cv2

    assert cv2.imwrite(str(path), image)
    return path


def cylinder_points(n: int = 600, seed: int = 0) -> np.ndarray:
    """``n`` points on the unit cylinder, z in [0, 2] (a star-shaped, closed-section object)."""
    rng = np.random.default_rng(seed)
    theta = rng.uniform(0, 2 * np.pi, n)
    z = rng.uniform(0.0, 2.0, n)
    return np.column_stack([np.cos(theta), np.sin(theta), z])


def tetra_mesh() -> tuple[np.ndarray, np.ndarray]:
    v = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], dtype=np.float64)
    t = np.array([[0, 1, 2], [0, 3, 1], [0, 2, 3], [1, 3, 2]], dtype=np.int64)
    return v, t


NONFINITE = st.sampled_from([math.nan, math.inf, -math.inf])


def mutate_number(text: str, index: int, value: str) -> str:
    """Replace the ``index``-th number of ``text`` (an opencv-matrix block) with ``value``."""
    import re

    tokens = list(re.finditer(r"(?<![\w.])-?\d+\.\d*(?:e-?\d+)?|(?<![\w.])-?\d+\.(?!\w)", text))
    token = tokens[index % len(tokens)]
    return text[: token.start()] + value + text[token.end():]


# =========================================================================== cameras


@fuzz(30)
@given(entry=st.integers(0, 8), view=st.sampled_from(["view_00", "view_01"]),
       value=NONFINITE, suffix=st.sampled_from([".yml", ".xml"]))
def test_rig_nonfinite_K_is_an_error_naming_the_field(entry, view, value, suffix):
    from matching.cameras import read_cameras, read_rig, write_rig

    with scratch() as tmp:
        path = tmp / f"rig{suffix}"
        rig = make_rig()
        write_rig(path, rig)
        text = path.read_text()
        # the K block of the chosen view: replace one of its nine numbers
        head, _, tail = text.partition(view)
        k_start = tail.index("K")
        k_end = tail.index("dist")
        block = mutate_number(tail[k_start:k_end], entry, {math.nan: ".nan", math.inf: ".inf",
                                                           -math.inf: "-.inf"}[value])
        path.write_text(head + view + tail[:k_start] + block + tail[k_end:])
        for reader in (read_rig, read_cameras):
            message = must_fail(reader, path, path)
            assert f"{view}.K" in message, message


@fuzz(25)
@given(kind=st.sampled_from(["zero_fx", "zero_fy", "zero_row", "all_zero", "bottom", "negative"]),
       view=st.sampled_from(["view_00", "view_01"]))
def test_rig_singular_or_invalid_K(kind, view):
    from matching.cameras import read_rig

    rig = make_rig()
    K = np.array(rig.left.K)
    if kind == "zero_fx":
        K[0, 0] = 0
    elif kind == "zero_fy":
        K[1, 1] = 0
    elif kind == "zero_row":
        K[1] = 0
    elif kind == "all_zero":
        K[:] = 0
    elif kind == "bottom":
        K[2] = [0.0, 0.0, 0.0]
    else:
        K[0, 0] = -K[0, 0]
    with scratch() as tmp:
        path = tmp / "rig.yml"
        write_rig_unchecked(path, rig, {view: {"K": K}})
        message = must_fail(read_rig, path, path)
        assert view in message and "K" in message


def write_rig_unchecked(path: Path, rig, replace: dict) -> None:
    """Write a two-view cameras.yml like ``write_rig`` but with arbitrary (invalid) matrices."""
    import cv2

    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("format", "photosurf-cameras")
    fs.write("version", 1)
    fs.write("n_views", 2)
    for i, cam in enumerate((rig.left, rig.right)):
        key = f"view_{i:02d}"
        fields = {"K": cam.K, "dist": cam.dist.reshape(1, -1), "R": cam.R,
                  "t": cam.t.reshape(3, 1), **replace.get(key, {})}
        fs.startWriteStruct(key, cv2.FileNode_MAP)
        fs.write("name", cam.name)
        fs.write("width", int(replace.get(key, {}).get("width", cam.width)))
        fs.write("height", int(replace.get(key, {}).get("height", cam.height)))
        for name in ("K", "dist", "R", "t"):
            if fields[name] is not None:
                fs.write(name, np.asarray(fields[name], dtype=np.float64))
        fs.endWriteStruct()
    fs.release()


@fuzz(30)
@given(matrix=st.lists(st.floats(-3, 3, allow_nan=False), min_size=9, max_size=9),
       view=st.sampled_from(["view_00", "view_01"]))
def test_rig_non_rotation_R(matrix, view):
    from matching.cameras import read_rig

    R = np.array(matrix).reshape(3, 3)
    orth = np.abs(R.T @ R - np.eye(3)).max()
    if orth < 1e-3 and abs(np.linalg.det(R) - 1) < 1e-3:  # hypothesis found a rotation
        return
    with scratch() as tmp:
        path = tmp / "rig.yml"
        write_rig_unchecked(path, make_rig(), {view: {"R": R}})
        message = must_fail(read_rig, path, path)
        assert view in message and "R" in message


@fuzz(24)
@given(field=st.sampled_from(["K", "R", "t", "width", "height"]),
       view=st.sampled_from(["view_00", "view_01"]), suffix=st.sampled_from([".yml", ".xml"]))
def test_rig_missing_matrix(field, view, suffix):
    import cv2

    from matching.cameras import read_cameras, read_rig

    rig = make_rig()
    with scratch() as tmp:
        path = tmp / f"rig{suffix}"
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
        fs.write("format", "photosurf-cameras")
        fs.write("n_views", 2)
        for i, cam in enumerate((rig.left, rig.right)):
            key = f"view_{i:02d}"
            fs.startWriteStruct(key, cv2.FileNode_MAP)
            values = {"width": cam.width, "height": cam.height, "K": cam.K, "R": cam.R,
                      "t": cam.t.reshape(3, 1)}
            for name, value in values.items():
                if not (key == view and name == field):
                    fs.write(name, value)
            fs.endWriteStruct()
        fs.release()
        for reader in (read_rig, read_cameras):
            message = must_fail(reader, path, path)
            assert f"{view}.{field}" in message


@fuzz(60)
@given(cut=st.floats(0.0, 0.97), suffix=st.sampled_from([".yml", ".xml"]))
def test_rig_truncated(cut, suffix):
    """A truncated rig file reads back identical (only whitespace lost) or is an error."""
    from matching.cameras import read_rig, write_rig

    rig = make_rig()
    with scratch() as tmp:
        path = tmp / f"rig{suffix}"
        write_rig(path, rig)
        data = path.read_bytes()
        path.write_bytes(data[: int(cut * len(data))])
        result = raises_naming(read_rig, path, path)
        if not isinstance(result, Exception):
            assert result.left.allclose(rig.left) and result.right.allclose(rig.right)


@fuzz(60)
@given(data=st.binary(max_size=200), suffix=st.sampled_from([".yml", ".xml", ".yaml", ".json"]),
       prefix=st.sampled_from([b"", b"%YAML 1.2\n---\n", b"<?xml version=\"1.0\"?>\n",
                               b"n_views: 2\nview_00:\n  K: [", b"{\"n_views\": "]))
def test_rig_garbage(data, suffix, prefix):
    from matching.cameras import read_cameras, read_rig

    with scratch() as tmp:
        path = tmp / f"rig{suffix}"
        path.write_bytes(prefix + data)
        for reader in (read_rig, read_cameras):
            result = raises_naming(reader, path, path)
            assert isinstance(result, Exception)


COLMAP_CAMERA = "1 PINHOLE 64 48 100.0 100.0 32.0 24.0"
COLMAP_IMAGE = "1 1.0 0.0 0.0 0.0 0.0 0.0 0.0 1 left"


@fuzz(40)
@given(which=st.sampled_from(["cameras.txt", "images.txt"]), field=st.integers(0, 11),
       value=st.sampled_from(["", "x", "nan", "inf", "-1", "0", "1e400", "PINHOLE", "3.5",
                              "SIMPLE_RADIAL_FISHEYE", "99"]))
def test_colmap_text_bad_lines(which, field, value):
    """One field of a COLMAP text model replaced: read, or an error naming the file."""
    from matching.cameras import read_cameras

    with scratch() as tmp:
        lines = {"cameras.txt": COLMAP_CAMERA, "images.txt": COLMAP_IMAGE}
        fields = lines[which].split()
        if field < len(fields):
            fields[field] = value
        else:
            fields.append(value)
        lines[which] = " ".join(f for f in fields if f)
        (tmp / "cameras.txt").write_text(f"# cameras\n{lines['cameras.txt']}\n")
        (tmp / "images.txt").write_text(f"# images\n{lines['images.txt']}\n\n")
        result = raises_naming(read_cameras, tmp, tmp)
        if not isinstance(result, Exception):
            assert all(np.all(np.isfinite(c.K)) for c in result)


@pytest.mark.parametrize("case", ["no_images_file", "empty_images", "empty_cameras", "folder_empty",
                                  "camera_id_unknown", "images_is_folder"])
def test_colmap_text_structure(tmp_path, case):
    from matching.cameras import read_cameras

    (tmp_path / "cameras.txt").write_text(COLMAP_CAMERA + "\n")
    (tmp_path / "images.txt").write_text(COLMAP_IMAGE + "\n\n")
    if case == "no_images_file":
        (tmp_path / "images.txt").unlink()
    elif case == "empty_images":
        (tmp_path / "images.txt").write_text("# nothing\n")
    elif case == "empty_cameras":
        (tmp_path / "cameras.txt").write_text("")
    elif case == "folder_empty":
        for p in tmp_path.iterdir():
            p.unlink()
    elif case == "camera_id_unknown":
        (tmp_path / "images.txt").write_text(COLMAP_IMAGE.replace(" 1 left", " 7 left") + "\n\n")
    else:
        (tmp_path / "images.txt").unlink()
        (tmp_path / "images.txt").mkdir()
    must_fail(read_cameras, tmp_path, tmp_path)


@fuzz(30)
@given(field=st.integers(0, 22), value=st.sampled_from(["x", "nan", "inf", "0", "", "1e999"]))
def test_projection_txt_bad_lines(field, value):
    from matching.cameras import read_projection_txt

    good = ["im0.png", "100", "0", "31.5", "0", "100", "23.5", "0", "0", "1",
            "1", "0", "0", "0", "1", "0", "0", "0", "1", "0", "0", "0"]
    fields = list(good)
    if field < len(fields):
        fields[field] = value
    else:
        fields.append(value)
    with scratch() as tmp:
        path = tmp / "par.txt"
        path.write_text("1\n" + " ".join(f for f in fields if f) + "\n")
        result = raises_naming(read_projection_txt, path, path, 64, 48)
        if not isinstance(result, Exception):
            assert np.all(np.isfinite(result[0].K)) and np.all(np.isfinite(result[0].R))


@pytest.mark.parametrize("case", ["missing", "folder", "unknown_suffix", "empty_yml"])
def test_cameras_missing_or_unknown(tmp_path, case):
    from matching.cameras import read_cameras, read_rig

    path = tmp_path / "cams.yml"
    if case == "folder":
        path.mkdir()
        must_fail(read_rig, path, path)
        return
    if case == "unknown_suffix":
        path = tmp_path / "cams.bin"
        path.write_bytes(b"\0\1")
    elif case == "empty_yml":
        path.write_text("")
    for reader in (read_rig, read_cameras):
        must_fail(reader, path, path)


# =========================================================================== point clouds


@fuzz(30)
@given(cut=st.integers(1, 400), colours=st.booleans(), sigma=st.booleans())
def test_cloud_truncated_ply(cut, colours, sigma):
    from pipeline.cloud_io import read_cloud, write_ply

    points = cylinder_points(20)
    with scratch() as tmp:
        path = tmp / "cloud.ply"
        write_ply(path, points, np.full((20, 3), 9) if colours else None,
                  np.ones(20) if sigma else None)
        data = path.read_bytes()
        path.write_bytes(data[: max(0, len(data) - cut)])
        must_fail(read_cloud, path, path)


@fuzz(30)
@given(data=st.binary(max_size=300), prefix=st.sampled_from(
    [b"", b"ply\n", b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n",
     b"ply\nformat binary_little_endian 1.0\nelement vertex 99999\nproperty double x\n"
     b"property double y\nproperty double z\nend_header\n",
     b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n"
     b"property float z\nend_header\n"]))
def test_cloud_garbage_ply(data, prefix):
    from pipeline.cloud_io import read_cloud

    with scratch() as tmp:
        path = tmp / "cloud.ply"
        path.write_bytes(prefix + data)
        result = raises_naming(read_cloud, path, path)
        if not isinstance(result, Exception):
            assert result.points.ndim == 2 and result.points.shape[1] == 3


@fuzz(40)
@given(rows=st.lists(st.lists(st.one_of(st.floats(allow_nan=True, allow_infinity=True),
                                        st.sampled_from(["x", "", "1,2", "#", "nan"])),
                              min_size=0, max_size=5), min_size=0, max_size=6),
       suffix=st.sampled_from([".xyz", ".csv", ".txt"]))
def test_cloud_text_wrong_columns(rows, suffix):
    """Text clouds with ragged rows, too few columns, words, NaN/inf: read, or an error."""
    from pipeline.cloud_io import read_cloud

    sep = "," if suffix == ".csv" else " "
    with scratch() as tmp:
        path = tmp / f"cloud{suffix}"
        path.write_text("\n".join(sep.join(str(v) for v in row) for row in rows) + "\n")
        result = raises_naming(read_cloud, path, path)
        if not isinstance(result, Exception):
            assert np.all(np.isfinite(result.points)) and result.points.shape[1] == 3
            assert len(result.points) > 0


def _cloud_cases():
    for case in ("empty_file", "no_points", "nan", "inf"):
        for suffix in (".ply", ".xyz", ".csv", ".npz"):
            yield pytest.param(case, suffix, id=f"{case}-{suffix}")


@pytest.mark.parametrize(("case", "suffix"), list(_cloud_cases()))
def test_cloud_empty_or_nonfinite(tmp_path, suffix, case):
    from pipeline.cloud_io import read_cloud, write_cloud

    path = tmp_path / f"cloud{suffix}"
    if case == "empty_file":
        path.write_bytes(b"")
    elif case == "no_points":
        write_cloud(path, np.zeros((0, 3))) if suffix != ".xyz" else path.write_text("# x y z\n")
    else:
        points = cylinder_points(10)
        points[3, 1] = math.nan if case == "nan" else -math.inf
        write_cloud(path, points)
    result = raises_naming(read_cloud, path, path)
    if case in ("nan", "inf") and not isinstance(result, Exception):
        pytest.fail(f"{path}: NaN/inf coordinates read without error")
    if case == "empty_file":
        assert isinstance(result, Exception)
    if case == "no_points" and not isinstance(result, Exception):
        assert len(result) == 0  # readable but empty: the consumers refuse it (test_fuzz_cli)


@pytest.mark.parametrize("case", [
    "no_points_key", "wrong_shape", "colour_shape", "sigma_shape", "object_array", "not_zip",
])
def test_cloud_bad_npz(tmp_path, case):
    from pipeline.cloud_io import read_cloud

    path = tmp_path / "cloud.npz"
    arrays = {"points": cylinder_points(5)}
    if case == "no_points_key":
        arrays = {"pts": arrays["points"]}
    elif case == "wrong_shape":
        arrays["points"] = np.zeros((5, 2))
    elif case == "colour_shape":
        arrays["colours"] = np.zeros((4, 3))
    elif case == "sigma_shape":
        arrays["sigma"] = np.zeros((5, 2))
    elif case == "object_array":
        arrays["points"] = np.array([{"a": 1}], dtype=object)
    if case == "not_zip":
        path.write_bytes(b"PK\3\4 not really a zip")
    else:
        np.savez(path, **arrays)
    must_fail(read_cloud, path, path)


# =========================================================================== meshes


@fuzz(30)
@given(cut=st.floats(0.05, 0.95), suffix=st.sampled_from([".ply", ".obj", ".stl", ".off"]))
def test_mesh_truncated(cut, suffix):
    from pipeline.mesh_io import read_mesh, read_mesh_with_normals, write_mesh

    v, t = tetra_mesh()
    with scratch() as tmp:
        path = tmp / f"mesh{suffix}"
        write_mesh(path, v, t)
        data = path.read_bytes()
        path.write_bytes(data[: int(cut * len(data))])
        for reader in (read_mesh, read_mesh_with_normals):
            result = raises_naming(reader, path, path)
            if not isinstance(result, Exception):
                vertices, triangles = result[0], result[1]
                assert np.all(np.isfinite(vertices))
                assert triangles.size and triangles.min() >= 0 and triangles.max() < len(vertices)


@fuzz(30)
@given(data=st.binary(max_size=200), suffix=st.sampled_from([".ply", ".obj", ".stl", ".off",
                                                             ".gltf", ".glb"]))
def test_mesh_garbage(data, suffix):
    from pipeline.mesh_io import read_mesh_with_normals

    with scratch() as tmp:
        path = tmp / f"mesh{suffix}"
        path.write_bytes(data)
        result = raises_naming(read_mesh_with_normals, path, path)
        if not isinstance(result, Exception):
            vertices, triangles, _ = result
            assert np.all(np.isfinite(vertices))
            assert triangles.min() >= 0 and triangles.max() < len(vertices)


@pytest.mark.parametrize("case", ["empty", "vertices_only", "nan_vertex", "bad_index", "missing",
                                  "folder", "unknown_suffix"])
def test_mesh_structure(tmp_path, case):
    from pipeline.mesh_io import read_mesh

    path = tmp_path / "mesh.obj"
    text = {"empty": "", "vertices_only": "v 0 0 0\nv 1 0 0\nv 0 1 0\n",
            "nan_vertex": "v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n",
            "bad_index": "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n"}
    if case in text:
        path.write_text(text[case])
    elif case == "folder":
        path.mkdir()
    elif case == "unknown_suffix":
        path = tmp_path / "mesh.3ds"
        path.write_text("x")
    result = raises_naming(read_mesh, path, path)
    if case != "bad_index":
        assert isinstance(result, Exception)
    elif not isinstance(result, Exception):  # open3d may drop the bad face: nothing out of range
        assert result[1].size == 0 or result[1].max() < len(result[0])


# =========================================================================== sectioned text


@fuzz(40)
@given(rows=st.lists(st.lists(st.one_of(st.floats(-5, 5), st.sampled_from(
    ["nan", "inf", "x", "1.5", "", ";", "#c"])), min_size=0, max_size=5), max_size=8))
def test_read_sectioned_garbage(rows):
    from surface.sections import read_sectioned

    with scratch() as tmp:
        path = tmp / "contours.csv"
        path.write_text("\n".join(",".join(str(v) for v in row) for row in rows) + "\n")
        result = raises_naming(read_sectioned, path, path)
        if not isinstance(result, Exception):
            for section in result:
                assert np.all(np.isfinite(section.points))


@pytest.mark.parametrize("case", ["missing", "folder", "empty", "non_integer_id", "nan", "mixed"])
def test_read_sectioned_structure(tmp_path, case):
    from surface.sections import read_sectioned

    path = tmp_path / "contours.xyz"
    body = {"empty": "# only a comment\n", "non_integer_id": "0 0 0 1\n1 0 0 1.5\n0 1 0 1\n",
            "nan": "0 0 0\n1 nan 0\n0 1 0\n", "mixed": "0 0 0\n1 0 0 4\n0 1 0\n"}
    if case in body:
        path.write_text(body[case])
    elif case == "folder":
        path.mkdir()
    must_fail(read_sectioned, path, path)


# =========================================================================== configuration


@fuzz(40)
@given(text=st.text(alphabet=st.sampled_from(list("[]=\"'{}.,#\n abc123_-")), max_size=60))
def test_config_broken_toml(text):
    from pipeline.config import resolve

    with scratch() as tmp:
        path = tmp / "params.toml"
        path.write_text(text)
        result = raises_naming(resolve, path, str(path))
        if not isinstance(result, Exception):
            assert "sections" in result  # an accepted file resolved to the full set


@fuzz(40)
@given(section=st.sampled_from(["sections", "curves", "smooth", "executor", "nosuch"]),
       key=st.sampled_from(["count", "axis", "level", "workers", "smoothing", "typo"]),
       value=st.one_of(st.text(max_size=4), st.booleans(), st.integers(-5, 5),
                       st.floats(allow_nan=True), st.lists(st.integers(), max_size=3)))
def test_config_unknown_keys_and_wrong_types(section, key, value):
    import tomli_w

    from pipeline.config import defaults, resolve

    with scratch() as tmp:
        path = tmp / "params.toml"
        path.write_text(tomli_w.dumps({section: {key: value}}))
        result = raises_naming(resolve, path, str(path))
        known = defaults()
        if not isinstance(result, Exception):
            # accepted only if the key exists and the value's type matches the default's
            assert section in known and key in known[section]
            default = known[section][key]
            if isinstance(default, bool):
                assert isinstance(value, bool)
            elif isinstance(default, int | float) and f"{section}.{key}" != "curves.smoothing":
                assert isinstance(value, int | float) and not isinstance(value, bool)
        else:
            assert key in str(result) or section in str(result) or "TOML" in str(result)


# =========================================================================== scene recipes

# the smallest valid recipe (benchmarks/limits.py reads the same file)
GOOD_RECIPE = (Path(__file__).resolve().parents[2] / "fixtures" / "scenes"
               / "tiny_stereo.toml").read_text()


@fuzz(40)
@given(edit=st.sampled_from([
    ("shape.kind", '"cone"'), ("shape.profile", "[[0.0, 1.0], [1.0, -0.5], [2.0, 0.9]]"),
    ("shape.profile", "[[0.0, 0.0], [1.0, 1.0]]"), ("shape.profile", "[[0.0, 1.0]]"),
    ("shape.profile", "[[1.0, 1.0], [0.0, 1.0]]"), ("shape.profile", '"round"'),
    ("shape.triangles", "3"), ("shape.scale_x", "0"), ("shape.scale_y", "-1.0"),
    ("shape.colour", '"red"'), ("cameras.width", "0"), ("cameras.height", "-3"),
    ("cameras.width", '"wide"'), ("cameras.layout", '"grid"'), ("cameras.focal_px", "0"),
    ("cameras.elevation_deg", "95"), ("cameras.distance", "0.01"), ("cameras.fill", "-1"),
    ("cameras.principal_point", "[1e6, 1e6]"), ("cameras.zoom", "2"),
    ("texture.wavelength_px", "[1.0, 2.0]"), ("texture.albedo", "[0.9, 0.1]"),
    ("noise.sigma", "-1"), ("render.supersample", "0"), ("lighting.direction", "[0, 0, 0]"),
    ("lighting.gain", "[1.0, 1.0, 1.0]"), ("seed", "-2"), ("seed", '"x"'), ("extra", "1"),
    ("shape.profile", "[[0.0, nan], [1.0, 1.0]]"), ("shape.profile", "[[0.0, inf], [1.0, 1.0]]"),
    ("cameras.distance", "nan"),
]))
def test_recipe_bad_fields(edit):
    """Each bad field: an error naming the recipe file and the field (or, for fields the
    recipe validator cannot judge alone, the scene builder)."""
    import tomllib

    import tomli_w

    from pipeline.scenes import build_scene, load_recipe

    dotted, value = edit
    table, _, key = dotted.rpartition(".")
    raw = tomllib.loads(GOOD_RECIPE)
    (raw.setdefault(table, {}) if table else raw)[key] = tomllib.loads(f"v = {value}")["v"]
    with scratch() as tmp:
        path = tmp / "scene.toml"
        path.write_text(tomli_w.dumps(raw))
        try:
            recipe = load_recipe(path)
            build_scene(recipe, source=str(path))
        except READER_ERRORS as exc:
            assert path.name in str(exc), exc
            assert key in str(exc) or (table and f"field {table}" in str(exc)), exc
        else:
            pytest.fail(f"recipe with {dotted} = {value} was accepted")


@pytest.mark.parametrize("case", ["missing_shape", "missing_cameras", "missing_kind",
                                  "missing_profile", "mesh_path_missing", "mesh_no_path",
                                  "binary", "missing_file", "folder"])
def test_recipe_missing_things(tmp_path, case):
    from pipeline.scenes import load_recipe

    path = tmp_path / "scene.toml"
    if case == "missing_shape":
        path.write_text(GOOD_RECIPE.split("[shape]")[0] + "[cameras]" +
                        GOOD_RECIPE.split("[cameras]")[1])
    elif case == "missing_cameras":
        path.write_text(GOOD_RECIPE.split("[cameras]")[0])
    elif case == "missing_kind":
        path.write_text(GOOD_RECIPE.replace('kind = "revolution"\n', ""))
    elif case == "missing_profile":
        path.write_text(GOOD_RECIPE.replace("profile = [[0.0, 1.0], [1.0, 1.2], [2.0, 0.9]]\n",
                                            ""))
    elif case in ("mesh_path_missing", "mesh_no_path"):
        shape = '[shape]\nkind = "mesh"\n' + ('path = "nowhere.ply"\n'
                                              if case == "mesh_path_missing" else "")
        old_shape = GOOD_RECIPE.split("[cameras]")[0].split("seed = 1\n")[1]
        path.write_text(GOOD_RECIPE.replace(old_shape, shape))
    elif case == "binary":
        path.write_bytes(b"\xff\xfe\x00 = 1\n")
    elif case == "folder":
        path.mkdir()
    message = must_fail(load_recipe, path, path)
    expected = {"missing_shape": "shape", "missing_cameras": "cameras", "missing_kind": "kind",
                "missing_profile": "profile", "mesh_path_missing": "path",
                "mesh_no_path": "path"}.get(case)
    if expected:
        assert expected in message


# =========================================================================== batch manifests


@fuzz(30)
@given(body=st.sampled_from([
    "", "[[object]]\n", "[[object]]\nname = \"a\"\n", "object = 3\n", "[object]\ninput = \"x\"\n",
    "[[object]]\ninput = \"a.toml\"\ninputs = [\"b.toml\"]\n", "[[object]]\ninputs = [1, 2]\n",
    "[[object]]\ninput = \"a.toml\"\nkind = \"video\"\n",
    "[[object]]\ninput = \"a.toml\"\ncolour = 1\n",
    "[[object]]\ninput = \"a.toml\"\nname = \"../x\"\n",
    "[[object]]\ninput = \"a.toml\"\nname = \".h\"\n",
    "[[object]]\ninput = \"a.toml\"\n[[object]]\ninput = \"a.toml\"\n",
    "set = 3\n[[object]]\ninput = \"a.toml\"\n", "typo = 1\n[[object]]\ninput = \"a.toml\"\n",
    "[[object]\ninput = \"a.toml\"\n", "[[object]]\ninput = a.toml\n", "\xff\xfe",
    "[[object]]\ninput = \"a.toml\"\nname = 7\n",
]), junk=st.text(alphabet="[]=\"# \n", max_size=3))
def test_batch_manifest_broken(body, junk):
    from pipeline.batch import read_manifest

    with scratch() as tmp:
        path = tmp / "batch.toml"
        path.write_text(body + junk, encoding="utf-8", errors="surrogateescape")
        result = raises_naming(read_manifest, path, path)
        if not isinstance(result, Exception):
            # a junk suffix of comments/whitespace can leave a valid manifest; it must then
            # produce well-formed tasks
            assert all(isinstance(t["inputs"], list) for t in result)


def test_cloud_ply_negative_vertex_count(tmp_path):
    from pipeline.cloud_io import read_cloud

    path = tmp_path / "cloud.ply"
    path.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex -4\n"
                     b"property double x\nproperty double y\nproperty double z\nend_header\n\0")
    must_fail(read_cloud, path, path)


@pytest.mark.parametrize("body", [
    pytest.param("[[object]]\ninput = \"a.toml\"\nset = 5\n", id="object-set-not-table"),
    pytest.param("[[object]]\ninput = \"a.toml\"\nrig = 5\n", id="object-rig-not-string"),
    pytest.param("config = 5\n[[object]]\ninput = \"a.toml\"\n", id="config-not-string"),
    pytest.param("[[object]]\ninput = \"a.toml\"\nset = { smooth = { level = 99 } }\n",
                 id="object-set-out-of-range"),
])
def test_batch_manifest_wrong_types(tmp_path, body):
    from pipeline.batch import read_manifest

    path = tmp_path / "batch.toml"
    path.write_text(body)
    must_fail(read_manifest, path, path)


def test_every_user_error_type_is_handled_by_the_cli():
    """The exception types these readers raise are exactly what the CLI turns into one line."""
    for exc in READER_ERRORS:
        assert issubclass(exc, USER_ERRORS)


@fuzz(20)
@given(small=st.integers(1, 3), which=st.integers(0, 3), seed=st.integers(0, 100))
def test_section_with_fewer_than_4_points_is_a_named_warning(small, which, seed):
    """A section with fewer than 4 points is skipped with a named warning
    (``SectionSkippedWarning`` naming the section), the others are kept."""
    from surface.sections import SectionSkippedWarning, read_sectioned
    from surface.topology import organise_all

    rng = np.random.default_rng(seed)
    rows = []
    for sid in range(4):
        n = small if sid == which else 40
        theta = rng.uniform(0, 2 * np.pi, n)
        rows += [f"{np.cos(a):.6f},{np.sin(a):.6f},{0.5 * sid},{sid}" for a in theta]
    with scratch() as tmp:
        path = tmp / "contours.csv"
        path.write_text("x,y,z,id\n" + "\n".join(rows) + "\n")
        sections = read_sectioned(path)
        with pytest.warns(SectionSkippedWarning) as caught:
            loops = organise_all(sections)
    skipped = [i for i, found in enumerate(loops) if not found]
    assert skipped == [which]
    assert any(f"section {sections[which].section_id}" in str(w.message) for w in caught)


# =========================================================================== image folders (SfM)


@pytest.mark.parametrize("case", ["missing", "a_file", "empty", "one_image", "only_text_files",
                                  "garbage_png", "textureless", "tiny_images", "names_missing"])
def test_sfm_bad_folders(tmp_path, case):
    """An empty folder, fewer than 2 images, non-image files, a folder where SfM
    registers nothing: a ValueError / FileNotFoundError naming the folder or file."""
    from matching.sfm import run_sfm

    folder = tmp_path / "images"
    kwargs = {}
    if case == "a_file":
        folder.write_text("x")
    elif case != "missing":
        folder.mkdir()
    if case == "one_image":
        write_png(folder / "a.png", textured(64, 48, 1))
        (folder / "notes.txt").write_text("x")
    elif case == "only_text_files":
        for name in ("a.txt", "b.csv", "c"):
            (folder / name).write_text("x")
    elif case == "garbage_png":
        write_png(folder / "a.png", textured(64, 48, 1))
        (folder / "b.png").write_text("not a png")
    elif case == "textureless":
        for i in range(3):
            write_png(folder / f"{i}.png", np.full((48, 64), 100, np.uint8))
    elif case == "tiny_images":
        for i in range(3):
            write_png(folder / f"{i}.png", textured(4, 4, i))
    elif case == "names_missing":
        for i in range(2):
            write_png(folder / f"{i}.png", textured(64, 48, i))
        kwargs["image_names"] = ["0.png", "zz.png"]
    message = must_fail(run_sfm, folder if case != "garbage_png" else folder / "b.png", folder,
                        num_threads=1, **kwargs)
    if case == "names_missing":
        assert "zz.png" in message


# =========================================================================== GLB and control nets

GLB_FIELDS = [("accessors", 0, "count"), ("accessors", 0, "componentType"),
              ("accessors", 0, "type"), ("accessors", 0, "bufferView"),
              ("accessors", 0, "byteOffset"), ("accessors", 1, "count"),
              ("bufferViews", 0, "byteLength"), ("bufferViews", 0, "byteOffset"),
              ("bufferViews", 0, "buffer"), ("meshes", 0, "primitives"), ("accessors",),
              ("bufferViews",), ("meshes",)]


def _glb_bytes(document: dict, blob: bytes) -> bytes:
    import json
    import struct

    text = json.dumps(document).encode()
    text += b" " * (-len(text) % 4)
    total = 12 + 8 + len(text) + 8 + len(blob)
    return (struct.pack("<III", 0x46546C67, 2, total) + struct.pack("<II", len(text), 0x4E4F534A)
            + text + struct.pack("<II", len(blob), 0x004E4942) + blob)


@fuzz(40)
@given(field=st.sampled_from(GLB_FIELDS),
       value=st.sampled_from([None, -1, 0, 7, 10**9, "x", "VEC2", [], {}, 1.5, True, 5126]),
       delete=st.booleans())
def test_glb_malformed_document(field, value, delete):
    """A GLB whose JSON lies (counts, offsets, types, missing tables): read, or an error
    naming the file -- never a KeyError/IndexError/TypeError traceback."""
    import json
    import struct

    from pipeline.export import read_glb, write_glb

    v, t = tetra_mesh()
    with scratch() as tmp:
        path = write_glb(tmp / "mesh.glb", v, t)
        data = path.read_bytes()
        json_len = struct.unpack_from("<I", data, 12)[0]
        document = json.loads(data[20:20 + json_len])
        blob = data[20 + json_len + 8:]
        node = document
        for key in field[:-1]:
            node = node[key]
        if delete and isinstance(node, dict):
            node.pop(field[-1], None)
        elif isinstance(node, dict):
            node[field[-1]] = value
        else:
            node[field[-1]] = value
        path.write_bytes(_glb_bytes(document, blob))
        result = raises_naming(read_glb, path, path)
        if not isinstance(result, Exception):
            vertices, triangles, _ = result
            assert triangles.size == 0 or triangles.max() < len(vertices)


@fuzz(40)
@given(cut=st.integers(0, 2000), flip=st.integers(0, 2000), byte=st.integers(0, 255))
def test_glb_truncated_or_flipped(cut, flip, byte):
    from pipeline.export import read_glb, write_glb

    v, t = tetra_mesh()
    with scratch() as tmp:
        path = write_glb(tmp / "mesh.glb", v, t)
        data = bytearray(path.read_bytes())
        data[flip % len(data)] = byte
        path.write_bytes(bytes(data[: len(data) - cut % len(data)]) if cut else bytes(data))
        result = raises_naming(read_glb, path, path)
        if not isinstance(result, Exception):
            vertices, triangles, _ = result
            assert triangles.size == 0 or triangles.max() < len(vertices)


@pytest.mark.parametrize("case", ["empty", "not_zip", "no_format", "wrong_version",
                                  "bad_control_points", "bad_index", "pickled", "truncated"])
def test_control_net_malformed(tmp_path, case):
    from pipeline.export import CONTROL_NET_FORMAT, CONTROL_NET_VERSION, read_control_net

    path = tmp_path / "net.npz"
    good = {"format": np.array(CONTROL_NET_FORMAT), "format_version": np.array(CONTROL_NET_VERSION),
            "control_points": np.zeros((2, 28, 3)), "source_face": np.zeros(2, np.int64)}
    from surface.bezier import index_table

    good["index"] = index_table()
    if case == "empty":
        path.write_bytes(b"")
    elif case == "not_zip":
        path.write_bytes(b"PK\x03\x04garbage" * 4)
    elif case == "truncated":
        np.savez(path, **good)
        path.write_bytes(path.read_bytes()[:200])
    else:
        arrays = dict(good)
        if case == "no_format":
            del arrays["format"]
        elif case == "wrong_version":
            arrays["format_version"] = np.array(99)
        elif case == "bad_control_points":
            arrays["control_points"] = np.zeros((2, 27, 3))
        elif case == "bad_index":
            arrays["index"] = np.zeros((28, 3), np.int64)
        elif case == "pickled":
            arrays["control_points"] = np.array([None, 1], dtype=object)
        np.savez(path, **arrays)
    must_fail(read_control_net, path, path)


# =========================================================================== OpenCV sample files


def _write_opencv_pair(folder: Path, breaks: dict, image_size=(64, 48)) -> Path:
    """OpenCV's stereo_calib sample output: intrinsics.yml (M1 D1 M2 D2), extrinsics.yml (R T)."""
    import cv2

    rig = make_rig(*image_size)
    fields = {"M1": rig.left.K, "D1": rig.left.dist.reshape(1, -1), "M2": rig.right.K,
              "D2": rig.right.dist.reshape(1, -1), "R": rig.R, "T": rig.T.reshape(3, 1)}
    fields.update(breaks)
    for name, keys in (("intrinsics.yml", ("M1", "D1", "M2", "D2")),
                       ("extrinsics.yml", ("R", "T"))):
        fs = cv2.FileStorage(str(folder / name), cv2.FILE_STORAGE_WRITE)
        for key in keys:
            if fields[key] is not None:
                fs.write(key, np.asarray(fields[key], dtype=np.float64))
        fs.release()
    return folder / "intrinsics.yml"


OPENCV_BREAKS = {
    "nan_M1": {"M1": np.full((3, 3), math.nan)}, "singular_M2": {"M2": np.zeros((3, 3))},
    "missing_M2": {"M2": None}, "missing_T": {"T": None}, "missing_R": {"R": None},
    "reflection_R": {"R": np.diag([1.0, 1.0, -1.0])}, "scaled_R": {"R": 3 * np.eye(3)},
    "inf_T": {"T": np.array([[math.inf], [0.0], [0.0]])},
    "short_D1": {"D1": np.zeros((1, 3))}, "M1_2x2": {"M1": np.eye(2)},
    "M1_negative_f": {"M1": np.diag([-100.0, 100.0, 1.0])},
}


@pytest.mark.parametrize("case", sorted(OPENCV_BREAKS))
@pytest.mark.parametrize("which", ["intrinsics", "extrinsics"])
def test_opencv_calibration_files_broken(tmp_path, case, which):
    from matching.cameras import read_rig

    intrinsics = _write_opencv_pair(tmp_path, OPENCV_BREAKS[case])
    path = intrinsics if which == "intrinsics" else tmp_path / "extrinsics.yml"
    message = str(raises_naming(read_rig, "trinsics.yml", path, width=64, height=48))
    assert "trinsics.yml" in message, message  # names one of the two files


@pytest.mark.parametrize("case", ["no_size", "image_missing", "image_garbage", "no_extrinsics"])
def test_opencv_calibration_files_without_size_or_partner(tmp_path, case):
    from matching.cameras import read_rig

    intrinsics = _write_opencv_pair(tmp_path, {})
    kwargs = {}
    if case == "image_missing":
        kwargs["image"] = tmp_path / "left.png"
    elif case == "image_garbage":
        (tmp_path / "left.png").write_text("no")
        kwargs["image"] = tmp_path / "left.png"
    elif case == "no_extrinsics":
        (tmp_path / "extrinsics.yml").unlink()
        kwargs = {"width": 64, "height": 48}
    result = raises_naming(read_rig, "png" if "image_" in case else "yml", intrinsics, **kwargs)
    assert isinstance(result, Exception)


@pytest.mark.parametrize("R", [[1, 0, 0, 0, 1, 0, 0, 0, -1], [0, 1, 0, 1, 0, 0, 0, 0, 1],
                               [1, 0, 0, 0, 1, 0, 0, 0, 1.5], [0] * 9])
def test_projection_txt_reflection_or_non_rotation(tmp_path, R):
    """A reflection printed in a projection file is not snapped to some rotation."""
    from matching.cameras import read_projection_txt

    path = tmp_path / "par.txt"
    values = [100, 0, 31.5, 0, 100, 23.5, 0, 0, 1, *R, 0, 0, 1]
    path.write_text("1\nim0.png " + " ".join(str(v) for v in values) + "\n")
    must_fail(read_projection_txt, path, path, 64, 48)
