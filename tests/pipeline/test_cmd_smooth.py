"""``photosurf smooth``: icosphere -> closed smooth surface near the sphere; bad input."""

import re

import numpy as np
import open3d as o3d
import pytest
from scipy.spatial import cKDTree

from pipeline.cli import main
from pipeline.export import read_control_net
from pipeline.mesh_io import read_mesh_with_normals, write_mesh
from surface import bezier
from surface.metrics import is_watertight


def _icosphere(subdivisions=2):
    mesh = o3d.geometry.TriangleMesh.create_icosahedron(1.0).subdivide_midpoint(subdivisions)
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    vertices /= np.linalg.norm(vertices, axis=1, keepdims=True)  # on the unit sphere
    return vertices, np.asarray(mesh.triangles, dtype=np.int64)


@pytest.fixture(scope="module")
def icosphere_file(tmp_path_factory):
    vertices, triangles = _icosphere()
    path = tmp_path_factory.mktemp("in") / "ico.ply"
    write_mesh(path, vertices, triangles)
    return path, vertices, triangles


def test_icosphere_gives_closed_surface_near_the_sphere(tmp_path, icosphere_file, capsys):
    path, vertices, triangles = icosphere_file
    out = tmp_path / "smooth.ply"
    assert main(["smooth", str(path), "--out", str(out), "--level", "2"]) == 0
    text = capsys.readouterr().out
    # 320 triangles, refined once -> 1280 patches, 4**2 triangles each
    assert "1280 sextic patches" in text and "20480 triangles" in text
    angle = float(re.search(r"largest normal angle across patch edges (\S+) rad", text)[1])
    assert angle <= 1e-9  # G1 to rounding (<= 1e-9 rad)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["smooth.npz", "smooth.ply"]

    v, t, n = read_mesh_with_normals(out)
    assert len(t) == 20480 and is_watertight(t)
    assert len(v) - 3 * len(t) // 2 + len(t) == 2  # Euler characteristic of a sphere
    # Loop's limit surface shrinks a sphere-inscribed mesh: at a regular vertex
    # v∞ = v + ½·mean(w_i - v), whose radial part is -h²/4 for edges of length
    # h on the unit sphere; so 1 - |x| = O(h²) with coefficient ≈ 1/4 (0.14-0.25
    # measured over three refinements), never outside the sphere.
    edges = np.linalg.norm(vertices[triangles] - vertices[np.roll(triangles, 1, axis=1)], axis=2)
    h = edges.max()
    shrink = 1.0 - np.linalg.norm(v, axis=1)
    assert shrink.min() > 0.1 * h**2
    assert shrink.max() < 0.3 * h**2
    # the exported normals are the surface's: close to radial (O(h²) again)
    radial = v / np.linalg.norm(v, axis=1, keepdims=True)
    assert np.einsum("ij,ij->i", n, radial).min() > np.cos(h**2)


def test_control_net_file_rebuilds_the_surface(tmp_path, icosphere_file, capsys):
    path, _, _ = icosphere_file
    out = tmp_path / "s.glb"
    assert main(["smooth", str(path), "--out", str(out), "--level", "1"]) == 0
    net = read_control_net(tmp_path / "s.npz")
    assert net.control_points.shape == (1280, 28, 3)
    np.testing.assert_array_equal(net.index, bezier.index_table())
    assert set(np.unique(net.source_face)) == set(range(320))
    # Evaluated from the file alone (ControlNet.evaluate, not surface.bezier),
    # the patches at the level-1 sample grid are the tessellated vertices.
    grid = bezier.index_table(2) / 2.0
    points = net.evaluate(grid).reshape(-1, 3)
    v, t, n = read_mesh_with_normals(out)
    gap = cKDTree(points).query(v)[0]
    assert gap.max() < 1e-6  # GLB stores float32 positions: ≤ 6e-8 per unit coordinate
    assert len(np.unique(points.round(9), axis=0)) == len(v)
    # and the stored domain mesh re-tessellates it watertight, triangle for
    # triangle (open3d's glTF reader renumbers vertices, so compare corners)
    v2, t2, _ = bezier.tessellate(net.control_points, 1, net.domain_triangles)
    assert len(v2) == len(v) and is_watertight(t2)
    np.testing.assert_allclose(v2[t2], v[t], atol=1e-6)


def test_stl_input_is_welded(tmp_path, icosphere_file, capsys):
    from pipeline.export import export_mesh

    _, vertices, triangles = icosphere_file
    stl = export_mesh(tmp_path / "ico.stl", vertices, triangles)
    assert main(["smooth", str(stl), "--out", str(tmp_path / "s.obj"), "--level", "0"]) == 0
    assert "1280 sextic patches" in capsys.readouterr().out


def _closed_tetra_pair():
    """Two tetrahedra sharing edge 0-1 (an edge of four triangles: non-manifold)."""
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [0, -1, 0], [0, 0, -1.0]])
    triangles = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3],
                          [0, 1, 4], [0, 5, 1], [1, 5, 4], [0, 4, 5]])
    return vertices, triangles


def _flipped_icosahedron():
    """A closed icosahedron with one triangle turned inside out (unoriented)."""
    vertices, triangles = _icosphere(0)
    triangles = triangles.copy()
    triangles[0] = triangles[0, ::-1]
    return vertices, triangles


@pytest.mark.parametrize("case, message", [
    ("missing", r"missing\.ply: no such mesh file"),
    ("garbage", r"garbage\.ply: no triangles could be read"),
    ("nonmanifold", r"nonmanifold\.ply: cannot build the Bezier surface: .*non-manifold"),
    ("unoriented", r"unoriented\.ply: cannot build the Bezier surface: .*oriented"),
    ("suffix", r"out\.xyz: cannot write mesh format '\.xyz'"),
    ("level", r"--level must be in 0\.\.8, got 12"),
])
def test_bad_input_one_line_exit_2_nothing_written(tmp_path, capfd, case, message):
    inputs = tmp_path / "in"
    inputs.mkdir()
    src = inputs / f"{case}.ply"
    if case == "garbage":
        src.write_text("ply\nthis is not a mesh\n")
    elif case == "nonmanifold":
        write_mesh(src, *_closed_tetra_pair())
    elif case == "unoriented":
        write_mesh(src, *_flipped_icosahedron())
    elif case in ("suffix", "level"):
        write_mesh(src, *_icosphere(0))
    capfd.readouterr()
    outdir = tmp_path / "out"
    out = outdir / ("out.xyz" if case == "suffix" else "out.ply")
    argv = ["smooth", str(src), "--out", str(out)] + (["--level", "12"] if case == "level"
                                                        else [])
    assert main(argv) == 2
    err = capfd.readouterr().err  # file-descriptor level: open3d's C parsers included
    assert len(err.strip().splitlines()) == 1, err
    assert re.search(message, err), err
    assert err.startswith("photosurf smooth: error: ")
    assert not outdir.exists() or list(outdir.iterdir()) == []
