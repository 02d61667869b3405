"""Hostile and extreme input: no crash, no hang, no silent success, no lost data.

One section per kind of the issue; each case runs the real command (in-process,
stderr captured at file-descriptor level, or as a real process where the case
needs one: a file-size limit, a signal, a lock held by another process) and
asserts exit status 2 (128 + signal for a signal), exactly one line on stderr
naming the problem, and that nothing was written, deleted or left behind.

Kinds (the table under "Hostile and extreme input" in docs/cli.md counts them): limits,
numbers, files, writes, config, lock, one-line.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from pipeline import limits
from pipeline.errors import InputError
from pipeline.guards import check_coordinates, escape, image_format, image_header_size
from tests.pipeline.test_fuzz_inputs import (
    GOOD_RECIPE,
    call_main,
    cylinder_points,
    fails_cleanly,
    fuzz,
    make_rig,
    textured,
    write_png,
    write_rig_file,
)

ROOT = Path(__file__).resolve().parents[2]
W, H = 64, 48


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict:
    """A small cloud, a tetrahedron mesh, a textured pair and its rig."""
    from pipeline.cloud_io import write_cloud
    from pipeline.mesh_io import write_mesh
    from tests.pipeline.test_fuzz_inputs import tetra_mesh

    root = tmp_path_factory.mktemp("hostile")
    cloud = write_cloud(root / "cloud.xyz", cylinder_points(600))
    mesh = write_mesh(root / "tetra.ply", *tetra_mesh())
    left = write_png(root / "left.png", textured(W, H, 1))
    right = write_png(root / "right.png", np.roll(textured(W, H, 1), -3, axis=1))
    rig = write_rig_file(root / "rig.yml", W, H)
    return {"root": root, "cloud": cloud, "mesh": mesh, "left": left, "right": right,
            "rig": rig}


def _recipe(tmp: Path, extra: str = "", name: str = "scene.toml") -> Path:
    path = tmp / name
    path.write_text(GOOD_RECIPE + extra)
    return path


def _tree(folder: Path) -> dict[str, bytes]:
    return {p.relative_to(folder).as_posix(): p.read_bytes()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def _env(**extra) -> dict:
    env = dict(os.environ, PYTHONPATH=str(ROOT), **extra)
    env.pop(limits.ALLOW_ENV, None)
    return env


# =========================================================================== limits

def _sphere_mesh(path: Path, resolution: int) -> Path:
    import open3d as o3d

    from pipeline.mesh_io import write_mesh

    sphere = o3d.geometry.TriangleMesh.create_sphere(1.0, resolution)
    return write_mesh(path, np.asarray(sphere.vertices), np.asarray(sphere.triangles))


SYNTH_LIMITS = [
    ('[cameras]\nlayout = "ring"\nwidth = 48\nheight = 40\nn = 1000000000\n', "synth.views"),
    ('[cameras]\nlayout = "ring"\nwidth = 48\nheight = 40\nn = 8\n'
     '[cameras.second_ring]\nn = 100000000\nelevation_deg = 40.0\n', "synth.views"),
    ('[cameras]\nlayout = "stereo"\nwidth = 1000000\nheight = 1000000\n', "synth.pixels"),
    ('[shape]\nkind = "revolution"\nprofile = [[0.0, 1.0], [2.0, 0.9]]\n'
     'triangles = 1000000000000\n', "synth.triangles"),
    ("[render]\nsupersample = 1000000\n", "render.supersample"),
    ("[texture]\ncomponents = 1000000000\n", "texture.components"),
]


@pytest.mark.parametrize(("table", "key"), SYNTH_LIMITS, ids=[k for _, k in SYNTH_LIMITS])
def test_synth_oversized_recipe_refused_before_work(tmp_path, capfd, table, key):
    import tomllib

    import tomli_w

    raw = tomllib.loads(GOOD_RECIPE)
    for name, value in tomllib.loads(table).items():
        raw[name] = {**raw.get(name, {}), **value} if name != "cameras" else value
    recipe = tmp_path / "big.toml"
    recipe.write_text(tomli_w.dumps(raw))
    out = tmp_path / "out"
    line = fails_cleanly(capfd, ["synth", recipe, "--out", out], key, "estimated", out=out)
    assert "--allow-large" in line


def test_synth_nested_toml_refused(tmp_path, capfd):
    recipe = tmp_path / "deep.toml"
    recipe.write_text(GOOD_RECIPE + "x = " + "[" * 5000 + "]" * 5000 + "\n")
    fails_cleanly(capfd, ["synth", recipe, "--out", tmp_path / "out"], "nested too deeply")


@pytest.mark.parametrize(("options", "key"), [
    (["--sections", "1000000000"], "sections.count"),
    (["--n", "1000000000"], "ring.points"),
    (["--sections", "90000", "--n", "90000"], "mesh.triangles"),
])
def test_sections_oversized_refused(files, tmp_path, capfd, options, key):
    out = tmp_path / "m.ply"
    fails_cleanly(capfd, ["sections", files["cloud"], "--out", out, *options], key, out=out)


def test_smooth_level_past_the_triangle_limit(tmp_path, capfd):
    mesh = _sphere_mesh(tmp_path / "sphere.ply", 40)  # 6240 triangles: 4 x 6240 x 4^6 = 1e8
    out = tmp_path / "s.ply"
    line = fails_cleanly(capfd, ["smooth", mesh, "--out", out, "--level", "6"],
                         "smooth.triangles", "6240 control triangles", "102236160", out=out)
    assert "Bezier" not in line  # the request is refused, not the mesh


@pytest.mark.parametrize("claim", ["OFF\n1000000000 4 0\n0 0 0\n", "ply\nformat ascii 1.0\n"
                                   "element vertex 1000000000\nproperty float x\nproperty "
                                   "float y\nproperty float z\nend_header\n0 0 0\n"])
def test_header_counts_refused_before_reading(tmp_path, capfd, claim):
    mesh = tmp_path / ("m.off" if claim.startswith("OFF") else "m.ply")
    mesh.write_text(claim)
    fails_cleanly(capfd, ["smooth", mesh, "--out", tmp_path / "s.ply"], "file.elements",
                  "1000000000")


def test_png_header_size_refused_before_decoding(files, tmp_path, capfd):
    import struct
    import zlib

    big = tmp_path / "big.png"
    ihdr = struct.pack(">IIBBBBB", 100_000, 100_000, 8, 0, 0, 0, 0)
    chunk = struct.pack(">I", len(ihdr)) + b"IHDR" + ihdr + \
        struct.pack(">I", zlib.crc32(b"IHDR" + ihdr))
    big.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk + b"\x00" * 64)
    for command in ("match", "stereo"):
        out = tmp_path / ("m" if command == "match" else "c.ply")
        fails_cleanly(capfd, [command, big, files["right"], "--rig", files["rig"], "--out", out],
                      "image.pixels", "100000x100000", out=out)


@pytest.mark.parametrize(("argv", "needle"), [
    (["--pattern", "100000x100000", "--square", "0.02"], "calibrate.corners"),
    (["--pattern", "9x6", "--square", "1e308"], "--square"),
])
def test_calibrate_oversized(files, tmp_path, capfd, argv, needle):
    fails_cleanly(capfd, ["calibrate", str(files["left"]), str(files["right"]), *argv,
                          "--out", tmp_path / "rig.yml"], needle, out=tmp_path / "rig.yml")


@pytest.mark.parametrize(("argv", "needle"), [
    (["--scheduler", "local-cluster:0"], "at least 1"),
    (["--scheduler", "local-cluster:100000"], "workers"),
    (["--set", "sections.count=1000000000"], "sections.count"),
    (["--set", "acquire.max_iter=1000000000"], "iterations"),
    (["--set", "executor.workers=100000"], "workers"),
])
def test_run_oversized_settings(files, tmp_path, capfd, argv, needle):
    out = tmp_path / "w"
    fails_cleanly(capfd, ["run", files["cloud"], "--out", out, *argv], needle, out=out)


def test_match_max_iter(files, tmp_path, capfd):
    out = tmp_path / "m"
    fails_cleanly(capfd, ["match", files["left"], files["right"], "--rig", files["rig"], "--out",
                          out, "--max-iter", "1000000000"], "iterations", out=out)


def test_allow_large_lifts_a_limit(monkeypatch):
    with pytest.raises(limits.LimitError, match=r"sections\.count = 200000 .*estimated"):
        limits.check("sections.count", 200_000)
    monkeypatch.setenv(limits.ALLOW_ENV, "1")
    limits.check("sections.count", 200_000)  # lifted


def test_defaults_and_fixtures_are_within_the_limits():
    """The shipped recipes and every default pass: the limits refuse only the extreme."""
    from pipeline.config import resolve
    from pipeline.scenes import load_recipe

    resolve()
    for recipe in sorted((ROOT / "fixtures" / "scenes").glob("*.toml")):
        load_recipe(recipe)


# refusals cost the interpreter's start-up only (benchmarks/limits.py times them): the
# heavy libraries are not imported before the check that refuses
_HEAVY = ("open3d", "numba", "scipy", "surface.reconstruct", "surface.bezier", "matching.pair",
          "pipeline.scenes", "pipeline.render")


def _refusal_imports(argv: list, cwd: Path) -> tuple[int, list[str], str]:
    code = ("import sys\nimport pipeline.cli as cli\nrc = cli.main(sys.argv[1:])\n"
            f"heavy = {_HEAVY!r}\n"
            "print(' '.join(sorted(m for m in sys.modules if m in heavy)))\nsys.exit(rc)\n")
    proc = subprocess.run([sys.executable, "-c", code, *map(str, argv)], cwd=cwd, env=_env(),
                          capture_output=True, text=True, timeout=120)
    return proc.returncode, proc.stdout.split(), proc.stderr


def test_refusals_come_before_the_heavy_imports(files, tmp_path):
    import struct
    import zlib

    from pipeline.mesh_io import write_mesh
    from tests.pipeline.test_fuzz_inputs import tetra_mesh

    v, t = tetra_mesh()
    huge = write_mesh(tmp_path / "huge.ply", v * 1e200, t, compute_normals=False)
    off = tmp_path / "claims.off"
    off.write_text("OFF\n1000000000 1 0\n0 0 0\n")
    ihdr = struct.pack(">IIBBBBB", 100_000, 100_000, 8, 0, 0, 0, 0)
    png = tmp_path / "claims.png"
    png.write_bytes(b"\x89PNG\r\n\x1a\n" + struct.pack(">I", 13) + b"IHDR" + ihdr +
                    struct.pack(">I", zlib.crc32(b"IHDR" + ihdr)) + b"\x00" * 64)
    recipe = _recipe(tmp_path, "", "ok.toml")
    out = tmp_path / "out"
    cases = [
        (["sections", files["cloud"], "--out", out / "m.ply", "--sections", "1000000000"],
         "sections.count"),
        (["smooth", off, "--out", out / "s.ply"], "file.elements"),
        (["render", huge, "--out", out / "r.png"], "beyond"),
        (["synth", recipe, "--out", out / "s", "--set", "cameras.layout=ring", "--set",
          "cameras.n=1000000000"], "synth.views"),
        (["stereo", png, files["right"], "--rig", files["rig"], "--out", out / "c.ply"],
         "image.pixels"),
    ]
    for argv, needle in cases:
        status, heavy, err = _refusal_imports(argv, tmp_path)
        assert status == 2 and needle in err and len(err.strip().splitlines()) == 1, err
        assert heavy == [], f"{argv[0]} imported {heavy} before refusing: {err.strip()}"


def test_raw_recipe_costed_with_the_validated_defaults(tmp_path):
    """The synth pre-check costs a raw recipe with the defaults the validation fills."""
    import tomllib

    import tomli_w

    from pipeline.scenes import load_recipe

    raw = tomllib.loads(GOOD_RECIPE)
    raw.pop("render", None)
    raw["cameras"].pop("n", None)
    raw["cameras"]["layout"] = "ring"
    path = tmp_path / "plain.toml"
    path.write_text(tomli_w.dumps(raw))
    recipe = load_recipe(path)
    assert recipe["render"]["supersample"] == limits.RECIPE_DEFAULTS["render.supersample"]
    assert recipe["cameras"]["n"] == limits.RECIPE_DEFAULTS["cameras.n"]


def _lowered(monkeypatch, key: str, maximum: float) -> None:
    import dataclasses

    monkeypatch.setitem(limits.LIMITS, key, dataclasses.replace(limits.LIMITS[key],
                                                                maximum=maximum))


def _obj_text(v: np.ndarray, t: np.ndarray) -> str:
    return "".join(f"v {x!r} {y!r} {z!r}\n" for x, y, z in v.tolist()) + \
        "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in t.tolist())


def _ascii_stl(v: np.ndarray, t: np.ndarray) -> str:
    facets = "".join("facet normal 0 0 0\nouter loop\n" +
                     "".join(f"vertex {x!r} {y!r} {z!r}\n" for x, y, z in v[tri].tolist()) +
                     "endloop\nendfacet\n" for tri in t)
    return f"solid s\n{facets}endsolid s\n"


@pytest.mark.parametrize("kind", ["obj", "ascii-stl", "ply", "off", "glb"])
def test_every_mesh_format_counts_its_elements(tmp_path, capfd, monkeypatch, kind):
    """Each reader's file is costed before it is read: with the limit lowered below the
    sphere's element count, the refusal names the file, the key, the count and the cost
    (the same file is read when the limit allows it)."""
    import open3d as o3d

    from pipeline.export import write_glb
    from pipeline.mesh_io import check_header_counts, read_mesh, write_mesh

    sphere = o3d.geometry.TriangleMesh.create_sphere(1.0, 10)  # 182 vertices, 360 faces
    v, t = np.asarray(sphere.vertices), np.asarray(sphere.triangles)
    path = tmp_path / {"ascii-stl": "m.stl"}.get(kind, f"m.{kind}")
    if kind == "obj":
        path.write_text(_obj_text(v, t))
    elif kind == "ascii-stl":
        path.write_text(_ascii_stl(v, t))
    elif kind == "glb":
        write_glb(path, v, t)
    else:
        write_mesh(path, v, t)
    counts = check_header_counts(path)
    assert counts["faces"] == len(t)
    assert len(read_mesh(path)[1]) == len(t)  # read in full while the limit allows it
    if kind != "ascii-stl":
        assert counts["vertices"] == len(v)
    _lowered(monkeypatch, "file.elements", len(t) - 1)
    out = tmp_path / "r.png"
    line = fails_cleanly(capfd, ["render", path, "--out", out], path.name, "file.elements",
                         f"count {len(t)}", "estimated", out=out)
    assert "past the limit 359" in line


@pytest.mark.parametrize("claim", ["count", "bytes"])
def test_gltf_accessor_claims(tmp_path, capfd, claim):
    """A GLB whose accessor claims 10^12 positions (no buffer view: glTF's implicit zeros,
    nothing to compare with but the limit), or more than its buffer holds."""
    import json
    import struct

    count = 10 ** 12 if claim == "count" else 1000
    document = {"asset": {"version": "2.0"}, "buffers": [{"byteLength": 36}],
                "bufferViews": [{"buffer": 0, "byteLength": 36}],
                "accessors": [{"bufferView": 0, "componentType": 5126, "type": "VEC3",
                               "count": count}],
                "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}]}
    if claim == "count":
        del document["accessors"][0]["bufferView"]
    text = json.dumps(document).encode().ljust(4 * (len(json.dumps(document)) // 4 + 1))
    blob = np.zeros(9, "<f4").tobytes()
    path = tmp_path / "claims.glb"
    path.write_bytes(struct.pack("<III", 0x46546C67, 2, 28 + len(text) + len(blob)) +
                     struct.pack("<II", len(text), 0x4E4F534A) + text +
                     struct.pack("<II", len(blob), 0x004E4942) + blob)
    needles = ["file.elements", str(count)] if claim == "count" else ["1000 elements",
                                                                       "holds 36 bytes"]
    fails_cleanly(capfd, ["render", path, "--out", tmp_path / "r.png"], "claims.glb", *needles)



def test_binary_stl_whose_header_says_solid(tmp_path, capfd):
    """Some exporters start a binary STL's 80-byte header with "solid": without "facet"
    in its first lines it is costed as binary (here 10^9 facets claimed in 134 bytes)."""
    import struct

    path = tmp_path / "solid.stl"
    path.write_bytes(b"solid evil".ljust(80, b" ") + struct.pack("<I", 10 ** 9) + bytes(50))
    fails_cleanly(capfd, ["render", path, "--out", tmp_path / "r.png"], "solid.stl",
                  "facet count 1000000000", "file.elements")

def test_text_mesh_of_zeros_is_not_scanned_to_its_end(tmp_path, capfd):
    """A sparse 4 GB file named .obj (no lines at all) is refused after its first 64 MB."""
    path = tmp_path / "zeros.obj"
    with open(path, "wb") as fh:
        fh.truncate(4 << 30)
    fails_cleanly(capfd, ["smooth", path, "--out", tmp_path / "s.ply"], "zeros.obj",
                  "not a text .obj file")


def test_binary_ply_read_by_numpy_as_open3d_reads_it(tmp_path):
    """The numpy reader of binary triangle PLYs gives open3d's arrays bit for bit; a PLY of
    polygons falls back to open3d."""
    import open3d as o3d

    from pipeline.mesh_io import _read_binary_ply, read_mesh_with_normals, write_mesh

    sphere = o3d.geometry.TriangleMesh.create_sphere(1.0, 12)
    path = write_mesh(tmp_path / "s.ply", np.asarray(sphere.vertices) * 3.0 + 0.1,
                      np.asarray(sphere.triangles))
    assert _read_binary_ply(path) is not None
    v, t, n = read_mesh_with_normals(path)
    mesh = o3d.io.read_triangle_mesh(str(path))
    np.testing.assert_array_equal(v, np.asarray(mesh.vertices))
    np.testing.assert_array_equal(t, np.asarray(mesh.triangles))
    np.testing.assert_array_equal(n, np.asarray(mesh.vertex_normals))
    quad = tmp_path / "quad.ply"
    quad.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 4\nproperty double "
                     b"x\nproperty double y\nproperty double z\nelement face 1\nproperty list "
                     b"uchar int vertex_indices\nend_header\n" +
                     np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], "<f8").tobytes() +
                     b"\x04" + np.arange(4, dtype="<i4").tobytes())
    assert _read_binary_ply(quad) is None
    assert len(read_mesh_with_normals(quad)[1]) == 2  # open3d splits the quad


def test_cloud_text_and_npz_counts(tmp_path, capfd, monkeypatch):
    """An XYZ cloud's rows and an NPZ's ``points`` shape are costed before they are read."""
    points = cylinder_points(300)
    np.savetxt(tmp_path / "c.xyz", points)
    np.savez(tmp_path / "c.npz", points=points)
    _lowered(monkeypatch, "file.elements", 299)
    for name in ("c.xyz", "c.npz"):
        fails_cleanly(capfd, ["sections", tmp_path / name, "--out", tmp_path / "m.ply"], name,
                      "file.elements", "300", "estimated")


# =========================================================================== numbers

@pytest.mark.parametrize(("scale", "needle"), [(1e300, "beyond"), (1e60, "beyond")])
def test_sections_coordinates_past_float64_geometry(tmp_path, capfd, scale, needle):
    from pipeline.cloud_io import write_cloud

    cloud = write_cloud(tmp_path / "huge.ply", cylinder_points(300) * scale)
    out = tmp_path / "m.ply"
    fails_cleanly(capfd, ["sections", cloud, "--out", out], needle, "huge.ply", out=out)


def test_render_mesh_coordinates_past_float64_geometry(tmp_path, capfd):
    from pipeline.mesh_io import write_mesh
    from tests.pipeline.test_fuzz_inputs import tetra_mesh

    v, t = tetra_mesh()
    mesh = write_mesh(tmp_path / "huge.ply", v * 1e200, t, compute_normals=False)
    out = tmp_path / "r.png"
    fails_cleanly(capfd, ["render", mesh, "--out", out], "beyond", out=out)


def test_collinear_cloud_is_degenerate(tmp_path, capfd):
    line = np.linspace(0, 1, 1000)[:, None] * np.array([[0.3, 0.1, 1.0]])
    cloud = tmp_path / "line.xyz"
    np.savetxt(cloud, line)
    out = tmp_path / "m.ply"
    fails_cleanly(capfd, ["sections", cloud, "--out", out], "degenerate", "line", out=out)


def _flat_cloud(normal_tilt_rad: float, n: int = 600) -> np.ndarray:
    """Points in the plane y = 0 (which holds z), tilted about x by ``normal_tilt_rad``."""
    rng = np.random.default_rng(0)
    flat = np.column_stack([rng.uniform(-1, 1, n), np.zeros(n), rng.uniform(0, 2, n)])
    c, s = np.cos(normal_tilt_rad), np.sin(normal_tilt_rad)
    return flat @ np.array([[1, 0, 0], [0, c, -s], [0, s, c]]).T


@pytest.mark.parametrize(("tilt", "axis", "needles"), [
    (0.0, "z", ["holds the slicing axis [0.0, 0.0, 1.0]"]),
    (0.0, "auto", ["holds the principal (slicing) axis"]),
    (0.5, "z", ["at 28.6 deg to the slicing axis"]),  # arcsin(sin 0.5 rad) = 28.6 deg
])
def test_flat_cloud_across_the_slicing_axis(tmp_path, capfd, tilt, axis, needles):
    """A plane the slicing planes cross: every section a segment; refused, naming that."""
    cloud = tmp_path / "flat.xyz"
    np.savetxt(cloud, _flat_cloud(tilt))
    out = tmp_path / "m.ply"
    fails_cleanly(capfd, ["sections", cloud, "--out", out, "--axis", axis], "flat.xyz",
                  "one plane", "line segment", *needles, out=out)


def test_tiny_cloud_meshed_at_unit_size(tmp_path, capfd):
    """Scale-invariant maths: a cloud scaled by 2^-163 (1.7e-49; its 6th powers 1e-294
    are still normal float64) gives the unit cloud's mesh times 2^-163, bit for bit."""
    from pipeline.cloud_io import write_cloud
    from pipeline.mesh_io import read_mesh

    points = cylinder_points(600)
    scale = 2.0 ** -163
    meshes = []
    for name, factor in (("unit", 1.0), ("tiny", scale)):
        cloud = write_cloud(tmp_path / f"{name}.ply", points * factor)
        assert call_main(["sections", cloud, "--out", tmp_path / f"{name}_m.ply", "-q"]) == 0
        meshes.append(read_mesh(tmp_path / f"{name}_m.ply"))
    (v1, t1), (v2, t2) = meshes
    np.testing.assert_array_equal(t2, t1)
    np.testing.assert_array_equal(v2, v1 * scale)


def test_subnormal_cloud_refused(tmp_path, capfd):
    """Below float64's normal range the coordinates keep too few digits of the shape."""
    cloud = tmp_path / "sub.npz"
    np.savez(cloud, points=cylinder_points(300) * 1e-318)
    fails_cleanly(capfd, ["sections", cloud, "--out", tmp_path / "m.ply"], "sub.npz",
                  "subnormal")


def test_run_refuses_a_cloud_below_the_scale_invariant_range(tmp_path, capfd):
    """The pipeline's stages take lengths in scene units, so a 1e-6 cloud is refused with
    the reason (the command photosurf sections rescales it instead)."""
    cloud = tmp_path / "small.xyz"
    np.savetxt(cloud, cylinder_points(300) * 1e-6)
    out = tmp_path / "w"
    line = fails_cleanly(capfd, ["run", cloud, "--out", out], "below 0.0001",
                         "absolute tolerances")
    assert "spans 2e-06" in line


def test_complex_npz_cloud(tmp_path, capfd):
    cloud = tmp_path / "c.npz"
    np.savez(cloud, points=cylinder_points(300).astype(np.complex128) * (1 + 1j))
    fails_cleanly(capfd, ["sections", cloud, "--out", tmp_path / "m.ply"], "complex128")


@given(exponent=st.integers(51, 307), sign=st.sampled_from([1.0, -1.0]))
@fuzz(20)
def test_check_coordinates_refuses_past_the_limit(exponent, sign):
    points = cylinder_points(10)
    points[3, 1] = sign * 10.0 ** exponent
    with pytest.raises(InputError, match="beyond"):
        check_coordinates(points, "p")
    check_coordinates(points / 10.0 ** (exponent - 49), "p")  # within: accepted


def _rig_text(rig_path: Path, old: str, new: str, tmp: Path) -> Path:
    text = rig_path.read_text()
    assert old in text, old
    path = tmp / "edited.yml"
    path.write_text(text.replace(old, new, 1))
    return path


@pytest.mark.parametrize(("old", "new", "needle"), [
    ("version: 1", "version: 99", "version 99"),
    ("format: photosurf-cameras", "format: other-cameras", "other-cameras"),
    ("rig_R: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ ",
     "rig_R: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ .Nan, ", "rig_R"),
    ("rig_T: !!opencv-matrix\n   rows: 3\n   cols: 1\n   dt: d\n   data: [ ",
     "rig_T: !!opencv-matrix\n   rows: 3\n   cols: 1\n   dt: d\n   data: [ 5., ", "inconsistent"),
])
def test_rig_file_that_is_not_what_it_says(files, tmp_path, capfd, old, new, needle):
    rig = _rig_text(files["rig"], old, new, tmp_path)
    if needle == "rig_R":  # the NaN replaces the first value (a 3x3 keeps 9 numbers)
        text = rig.read_text()
        start = text.index(".Nan, ") + len(".Nan, ")
        comma = text.index(",", start)
        rig.write_text(text[:start] + text[comma + 1:].lstrip())
    if needle == "inconsistent":
        text = rig.read_text()
        start = text.index("5., ") + len("5., ")
        comma = text.index(",", start)
        rig.write_text(text[:start] + text[comma + 1:].lstrip())
    out = tmp_path / "m"
    fails_cleanly(capfd, ["match", files["left"], files["right"], "--rig", rig, "--out", out],
                  needle, out=out)


def test_rig_with_zero_baseline(tmp_path, capfd, files):
    from matching.cameras import Camera, StereoRig, write_rig

    left = make_rig(W, H).left
    twin = Camera(left.K, left.dist, left.R, left.t, W, H, "right")
    rig = tmp_path / "zero.yml"
    write_rig(rig, StereoRig(left, twin))
    fails_cleanly(capfd, ["match", files["left"], files["right"], "--rig", rig, "--out",
                          tmp_path / "m"], "baseline")


@pytest.mark.parametrize("how", ["same_path", "same_pixels"])
@pytest.mark.parametrize("command", ["match", "stereo"])
def test_stereo_pair_of_one_image(files, tmp_path, capfd, how, command):
    right = files["left"]
    if how == "same_pixels":
        right = tmp_path / "copy.png"
        right.write_bytes(files["left"].read_bytes())
    out = tmp_path / ("m" if command == "match" else "c.ply")
    fails_cleanly(capfd, [command, files["left"], right, "--rig", files["rig"], "--out", out],
                  "zero baseline", out=out)


def test_calibrate_same_glob_both_sides(files, tmp_path, capfd):
    out = tmp_path / "rig.yml"
    glob = str(files["root"] / "left.png")
    fails_cleanly(capfd, ["calibrate", glob, glob, "--square", "0.02", "--out", out],
                  "both a left and a right", out=out)


# =========================================================================== files

def _fifo(tmp_path: Path, name: str) -> Path:
    path = tmp_path / name
    os.mkfifo(path)
    return path


@pytest.mark.parametrize("special", ["fifo", "/dev/zero"])
@pytest.mark.parametrize("command", ["sections", "smooth", "match", "synth", "run-config"])
def test_fifo_or_device_input_refused_at_once(files, tmp_path, capfd, special, command):
    suffix = {"sections": ".xyz", "smooth": ".ply", "match": ".png", "synth": ".toml",
              "run-config": ".toml"}[command]
    src = _fifo(tmp_path, f"in{suffix}") if special == "fifo" else Path(special)
    out = tmp_path / "out"
    argv = {"sections": ["sections", src, "--out", tmp_path / "m.ply"],
            "smooth": ["smooth", src, "--out", tmp_path / "s.ply"],
            "match": ["match", src, files["right"], "--rig", files["rig"], "--out", out],
            "synth": ["synth", src, "--out", out],
            "run-config": ["run", files["cloud"], "--config", src, "--out", out]}[command]
    needle = "FIFO" if special == "fifo" else "character device"
    fails_cleanly(capfd, argv, needle)


def test_gif_named_png_refused(files, tmp_path, capfd):
    gif = tmp_path / "anim.png"
    gif.write_bytes(b"GIF89a" + bytes(range(64)) * 4)
    fails_cleanly(capfd, ["match", gif, files["right"], "--rig", files["rig"], "--out",
                          tmp_path / "m"], "GIF")


def test_image_header_size_by_format(tmp_path):
    import cv2

    image = textured(37, 23, 0)
    for suffix in (".png", ".jpg", ".tif", ".bmp", ".pgm", ".webp"):
        path = tmp_path / f"i{suffix}"
        assert cv2.imwrite(str(path), image)
        assert image_header_size(path)[1] == (37, 23), suffix
    (tmp_path / "j.png").write_bytes((tmp_path / "i.jpg").read_bytes())
    with pytest.raises(InputError, match="named .png but the content is a JPEG"):
        image_format(tmp_path / "j.png")


# =========================================================================== writes

def _limited(argv: list, fsize: int, cwd: Path) -> subprocess.CompletedProcess:
    """Run photosurf with a file-size limit (``ulimit -f``): writes past it fail with EFBIG."""
    import resource

    def limit():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # EFBIG instead of the signal
        resource.setrlimit(resource.RLIMIT_FSIZE, (fsize, fsize))

    return subprocess.run([sys.executable, "-m", "pipeline.cli", *map(str, argv)], cwd=cwd,
                          env=_env(), capture_output=True, text=True, preexec_fn=limit,
                          timeout=300)


@pytest.mark.parametrize("command", ["sections", "smooth", "render"])
def test_full_disk_fails_and_leaves_nothing(files, tmp_path, command):
    out = tmp_path / {"sections": "m.ply", "smooth": "s.ply", "render": "r.png"}[command]
    src = files["cloud"] if command == "sections" else files["mesh"]
    argv = [command, src, "--out", out] + (["--level", "2"] if command == "smooth" else [])
    result = _limited(argv, 2048, tmp_path)
    lines = [ln for ln in result.stderr.splitlines() if ln.strip()]
    assert result.returncode == 2, result.stderr
    assert len(lines) == 1, result.stderr
    assert "File too large" in lines[0], lines[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == [], "something was left behind"


def _limited_fails(argv: list, fsize: int, cwd: Path, names: str) -> None:
    """Under ``RLIMIT_FSIZE = fsize`` the command exits 2 with one line naming one of
    ``names`` and the failure (EFBIG, or numpy's short write, which has no errno), and
    ``cwd`` holds nothing afterwards."""
    result = _limited(argv, fsize, cwd)
    lines = [ln for ln in result.stderr.splitlines() if ln.strip()]
    assert result.returncode == 2, result.stderr
    assert len(lines) == 1, result.stderr
    assert "File too large" in lines[0] or "short write" in lines[0], lines[0]
    assert any(n in lines[0] for n in names.split()), lines[0]
    assert sorted(p.name for p in cwd.iterdir()) == [], "something was left behind"


@pytest.mark.parametrize("suffix", [".ply", ".stl", ".obj", ".glb"])
def test_full_disk_during_export(files, tmp_path, capfd, suffix):
    """``smooth`` exports the surface and its control net: written in full without a
    limit; with the limit at half the mesh's size the mesh write fails; for PLY, with the
    limit between the mesh's and the net's sizes, the net fails after the mesh temporary
    was complete -- and neither file appears."""
    done = tmp_path / "done"
    assert call_main(["smooth", files["mesh"], "--out", done / f"s{suffix}", "--level", "0",
                      "-q"]) == 0
    mesh_size = (done / f"s{suffix}").stat().st_size
    net_size = (done / "s.npz").stat().st_size
    cases = [(mesh_size // 2, f"s{suffix}")]
    if suffix == ".ply":
        assert mesh_size < net_size  # 16 patches: 16 flat triangles, 16 x 28 control points
        cases.append(((mesh_size + net_size) // 2, "s.npz"))
    for fsize, failing in cases:
        work = tmp_path / f"limit{fsize}"
        work.mkdir()
        _limited_fails(["smooth", files["mesh"], "--out", work / f"s{suffix}", "--level", "0"],
                       fsize, work, failing)


def test_full_disk_during_synth(tmp_path):
    """A rendered scene folder (many files, ``atomic_dir``) under a 4 kB file limit."""
    recipe_dir = tmp_path / "recipe"
    recipe_dir.mkdir()
    recipe = _recipe(recipe_dir)
    work = tmp_path / "work"
    work.mkdir()
    _limited_fails(["synth", recipe, "--out", work / "scene"], 4096, work, "scene")


def test_out_is_the_input(files, tmp_path, capfd):
    cloud = tmp_path / "c.ply"
    from pipeline.cloud_io import write_cloud

    write_cloud(cloud, cylinder_points(300))
    before = cloud.read_bytes()
    fails_cleanly(capfd, ["sections", cloud, "--out", cloud], "is the input")
    mesh = tmp_path / "t.ply"
    mesh.write_bytes(files["mesh"].read_bytes())
    fails_cleanly(capfd, ["smooth", mesh, "--out", mesh], "is the input")
    link = tmp_path / "link.ply"
    link.symlink_to(mesh)
    fails_cleanly(capfd, ["smooth", mesh, "--out", link], "is the input")
    assert cloud.read_bytes() == before and mesh.read_bytes() == files["mesh"].read_bytes()


def test_synth_out_holding_the_recipe(tmp_path, capfd):
    folder = tmp_path / "recipes"
    folder.mkdir()
    recipe = _recipe(folder)
    for out in (folder, tmp_path):  # the recipe's folder, and its parent
        fails_cleanly(capfd, ["synth", recipe, "--out", out], "holds the input")
    assert recipe.read_text() == GOOD_RECIPE


def test_match_out_holding_an_input(files, tmp_path, capfd):
    fails_cleanly(capfd, ["match", files["left"], files["right"], "--rig", files["rig"], "--out",
                          files["root"]], "holds the input")
    assert files["left"].is_file() and files["rig"].is_file()


@pytest.mark.parametrize("command", ["synth", "match"])
def test_existing_folder_with_unrelated_files_is_kept(files, tmp_path, capfd, command):
    out = tmp_path / "work"
    out.mkdir()
    (out / "thesis.tex").write_text("\\documentclass{article}\n")
    (out / "my_notes.txt").write_text("notes\n")
    before = _tree(out)
    argv = (["synth", _recipe(tmp_path), "--out", out] if command == "synth" else
            ["match", files["left"], files["right"], "--rig", files["rig"], "--out", out])
    fails_cleanly(capfd, argv, "photosurf did not write", "nothing was changed")
    assert _tree(out) == before


def test_synth_replaces_only_its_own_files(tmp_path, capfd):
    recipe = _recipe(tmp_path)
    out = tmp_path / "out"
    assert call_main(["synth", recipe, "--out", out, "-q"]) == 0
    first = _tree(out)
    (out / "notes.txt").write_text("mine\n")
    (out / "images" / "mine.txt").write_text("mine too\n")
    assert call_main(["synth", recipe, "--out", out, "-q", "--set", "seed=2"]) == 0
    second = _tree(out)
    assert second["notes.txt"] == b"mine\n" and second["images/mine.txt"] == b"mine too\n"
    assert set(second) == set(first) | {"notes.txt", "images/mine.txt"}
    assert second["images/view_00.png"] != first["images/view_00.png"]  # replaced (seed 2)
    assert not [p for p in out.iterdir() if p.name.startswith(".photosurf-tmp")]


@pytest.mark.parametrize("occupied", [False, True])
def test_synth_out_dot(tmp_path, capfd, monkeypatch, occupied):
    recipe = _recipe(tmp_path)
    here = tmp_path / "here"
    here.mkdir()
    if occupied:
        (here / "keep.txt").write_text("keep\n")
    monkeypatch.chdir(here)
    if occupied:
        fails_cleanly(capfd, ["synth", recipe, "--out", "."], "photosurf did not write")
        assert sorted(p.name for p in here.iterdir()) == ["keep.txt"]
    else:
        assert call_main(["synth", recipe, "--out", ".", "-q"]) == 0
        assert (here / "images" / "view_00.png").is_file()
        assert not [p for p in here.iterdir() if p.name.startswith(".photosurf-tmp")]


def test_batch_does_not_follow_a_link_in_outdir(files, tmp_path, capfd):
    outdir = tmp_path / "out"
    outdir.mkdir()
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (outdir / "a").symlink_to(elsewhere)
    manifest = tmp_path / "batch.toml"
    manifest.write_text(f'[[object]]\nname = "a"\ninput = "{files["cloud"]}"\n')
    line = fails_cleanly(capfd, ["batch", manifest, "--out", outdir, "--to", "sections"],
                         "1 of 1 objects failed", "symbolic link")
    assert str(outdir / "a") in line
    assert list(elsewhere.iterdir()) == []  # nothing written through the link


def _cloud_run(tmp_path: Path) -> tuple[Path, Path]:
    from pipeline.cloud_io import write_cloud

    theta = np.linspace(0, 2 * np.pi, 400, endpoint=False)
    z = np.linspace(0, 2, 120)
    tt, zz = np.meshgrid(theta, z)
    points = np.column_stack([np.cos(tt).ravel(), np.sin(tt).ravel(), zz.ravel()])
    return write_cloud(tmp_path / "cyl.npz", points), tmp_path / "w"


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP])
def test_signal_during_run_is_clean(tmp_path, sig):
    cloud, work = _cloud_run(tmp_path)
    proc = subprocess.Popen([sys.executable, "-m", "pipeline.cli", "run", str(cloud), "--out",
                             str(work), "-q"], env=_env(), stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        if work.is_dir() and any(p.name.startswith(".") and p.name != ".lock"
                                 for p in work.iterdir()):
            break  # a stage is writing its temporary
        time.sleep(0.02)
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=120)
    lines = [ln for ln in err.splitlines() if ln.strip()]
    if proc.returncode == 0:
        pytest.skip("the run finished before the signal arrived")
    assert proc.returncode == 128 + sig, err
    assert lines == [f"photosurf run: interrupted ({signal.Signals(sig).name})"], err
    left = [p.name for p in work.iterdir() if p.name.startswith(".") and p.name != ".lock"]
    assert left == [], f"temporaries left: {left}"


# =========================================================================== workspace

@pytest.mark.parametrize(("text", "needle"), [
    ("[" * 100_000 + "]" * 100_000, "nested too deeply"),
    ('{"manifest_version": 1, "stages": {"acquire": 5}}', "stage 'acquire' is a int"),
    ('{"manifest_version": 1, "stages": []}', "'stages' is a list"),
    ('{"manifest_version": 1, "stages": {"sections": {"outputs": {"/etc/passwd": "x"}}}}',
     "outside the workspace"),
    ("[1, 2]", "not an object"),
])
def test_damaged_manifest(files, tmp_path, capfd, text, needle):
    work = tmp_path / "w"
    work.mkdir()
    (work / "manifest.json").write_text(text)
    fails_cleanly(capfd, ["run", files["cloud"], "--out", work], "workspace is damaged", needle)


@pytest.mark.parametrize("call", ["lockf", "flock"])
def test_lock_held_by_another_process(files, tmp_path, capfd, call):
    work = tmp_path / "w"
    work.mkdir()
    holder = subprocess.Popen(
        [sys.executable, "-c",
         "import fcntl, sys, time\n"
         f"f = open({str(work / '.lock')!r}, 'a+')\n"
         f"fcntl.{call}(f, fcntl.LOCK_EX)\n"
         "print('locked', flush=True)\n"
         "time.sleep(60)\n"], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        fails_cleanly(capfd, ["run", files["cloud"], "--out", work], "another photosurf run")
        assert not (work / "manifest.json").exists()
    finally:
        holder.kill()
        holder.wait()


# =========================================================================== config

@given(value=st.sampled_from(["1\n[executor]\nworkers = 1000", "3\nfoo = 1", "4\r\n[x]",
                              "true\n", '"a"\n[report]\nwidth = 9'] +
                             [f"{n}\n[{t}]" for n in range(3) for t in ("a", "b.c")]))
@fuzz(12)
def test_set_value_is_one_toml_value(value):
    from pipeline.config import resolve

    with pytest.raises(InputError, match=r"--set sections\.count: the value must be one"):
        resolve(assignments=[f"sections.count={value}"])


def test_set_injection_through_the_cli(tmp_path, capfd):
    recipe = _recipe(tmp_path)
    fails_cleanly(capfd, ["synth", recipe, "--out", tmp_path / "o", "--set",
                          "seed=1\n[cameras]\nwidth = 9"], "--set seed", out=tmp_path / "o")
    fails_cleanly(capfd, ["run", recipe, "--out", tmp_path / "w", "--set",
                          "sections.count=3\n[executor]\nworkers=1000"], "--set sections.count")


# =========================================================================== one line

@given(name=st.text(st.sampled_from("ab\n\r\t\x1b[]2J\x07\x9b\u2028 "), min_size=1, max_size=12))
@fuzz(30)
def test_escape_leaves_no_control_character(name):
    shown = escape(name)
    assert shown.isprintable()
    assert "\n" not in shown and "\x1b" not in shown


def test_file_name_with_newline_and_escape_stays_one_line(tmp_path, capfd):
    name = tmp_path / "evil\n\x1b[2Jname.xyz"
    name.write_text("not numbers at all\nreally\nnot\n")
    line = fails_cleanly(capfd, ["sections", name, "--out", tmp_path / "m.ply"])
    assert "\\n" in line and "\\x1b" in line and "\x1b" not in line


def test_no_arguments_prints_one_line_on_stderr(capfd):
    from pipeline.cli import main

    capfd.readouterr()
    assert main([]) == 2
    captured = capfd.readouterr()
    assert captured.out == ""
    assert captured.err.startswith("photosurf: error: a command is required")
    assert len(captured.err.splitlines()) == 1


def test_batch_sums_failures_in_one_line(files, tmp_path, capfd):
    manifest = tmp_path / "batch.toml"
    manifest.write_text("[[object]]\nname = 'a'\ninput = 'missing1.ply'\n"
                        "[[object]]\nname = 'b'\ninput = 'missing2.ply'\n"
                        f"[[object]]\nname = 'c'\ninput = '{tmp_path}/bad\\nname.xyz'\n")
    line = fails_cleanly(capfd, ["batch", manifest, "--out", tmp_path / "o", "-q"],
                         "3 of 3 objects failed", "missing1.ply", "(and 2 more)")
    report = json.loads((tmp_path / "o" / "batch.json").read_text())
    assert [o["status"] for o in report["objects"]] == ["failed"] * 3
    assert "\n" not in line


def test_summary_lines_on_stdout_are_escaped(files, tmp_path, capfd):
    out = tmp_path / "evil\x1b[2J.ply"
    capfd.readouterr()
    assert call_main(["sections", files["cloud"], "--out", out]) == 0
    printed = capfd.readouterr().out
    assert "\x1b" not in printed and "evil\\x1b[2J.ply" in printed
    assert out.is_file()  # the file itself keeps its real name
