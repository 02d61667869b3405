"""Export round-trips: every format read back by open3d (and GLB by a second reader).

Tolerances: positions and normals of the unit sphere are below 1 in magnitude,
so a float32 copy is within half an ulp, 2**-24 ≈ 6e-8, of the float64 value;
``F32`` = 1e-7 bounds that.  PLY stores float64 positions and must keep them exactly
(its unit normals are float32).
"""

import json
import struct
import zipfile

import numpy as np
import open3d as o3d
import pytest

from pipeline import export as export_module
from pipeline.errors import InputError
from pipeline.export import (
    CONTROL_NET_FORMAT,
    EXPORT_SUFFIXES,
    ControlNet,
    export_mesh,
    export_surface,
    read_control_net,
    read_glb,
    vertex_normals,
    write_control_net,
    write_glb,
)

F32 = 1e-7


@pytest.fixture(scope="module")
def sphere():
    mesh = o3d.geometry.TriangleMesh.create_sphere(1.0, 20)
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    triangles = np.asarray(mesh.triangles, dtype=np.int64)
    normals = vertices / np.linalg.norm(vertices, axis=1, keepdims=True)  # exact sphere normals
    return vertices, triangles, normals


def _read(path):
    mesh = o3d.io.read_triangle_mesh(str(path))
    return (np.asarray(mesh.vertices), np.asarray(mesh.triangles),
            np.asarray(mesh.vertex_normals) if mesh.has_vertex_normals() else None,
            np.asarray(mesh.vertex_colors) if mesh.has_vertex_colors() else None)


def _index_table():
    return np.array([(i, j, 6 - i - j) for i in range(6, -1, -1) for j in range(6 - i, -1, -1)])


# --------------------------------------------------------------------------- meshes


@pytest.mark.parametrize("suffix", EXPORT_SUFFIXES)
def test_round_trip_through_open3d(tmp_path, sphere, suffix):
    vertices, triangles, normals = sphere
    path = export_mesh(tmp_path / f"s{suffix}", vertices, triangles, normals)
    v2, t2, n2, _ = _read(path)
    assert len(t2) == len(triangles)
    # Readers may renumber vertices (OBJ, glTF) or split them (STL), but keep
    # the triangle order: compare the corners triangle by triangle.
    tol = 0.0 if suffix == ".ply" else F32
    np.testing.assert_allclose(v2[t2], vertices[triangles], rtol=0, atol=tol)
    if suffix == ".stl":  # one normal per facet, vertices split per facet
        assert len(np.unique(v2.round(6), axis=0)) == len(vertices)
    else:
        assert len(v2) == len(vertices)
        np.testing.assert_allclose(n2[t2], normals[triangles], rtol=0, atol=F32)
    assert list(tmp_path.iterdir()) == [path]  # no temporary left behind


def test_stl_keeps_face_normals(tmp_path, sphere):
    vertices, triangles, normals = sphere
    path = export_mesh(tmp_path / "s.stl", vertices, triangles, normals)
    # Binary STL: 80-byte header, uint32 count, 50-byte records (normal, 3 corners, attribute).
    record = np.dtype([("normal", "<f4", 3), ("corners", "<f4", (3, 3)), ("attr", "<u2")])
    data = path.read_bytes()
    count = int(np.frombuffer(data, "<u4", 1, 80)[0])
    facets = np.frombuffer(data, record, count, 84)
    assert count == len(triangles) and len(data) == 84 + 50 * count
    np.testing.assert_allclose(facets["corners"], vertices[triangles], atol=F32)
    c = vertices[triangles]
    expected = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])
    expected /= np.linalg.norm(expected, axis=1, keepdims=True)
    # unit normals from float64 corners, stored as float32
    np.testing.assert_allclose(facets["normal"], expected, atol=F32)


def test_obj_text_is_exact_float64(tmp_path, sphere):
    vertices, triangles, normals = sphere
    rng = np.random.default_rng(1)
    noisy = vertices + 1e-9 * rng.standard_normal(vertices.shape)  # digits float32 would lose
    path = export_mesh(tmp_path / "s.obj", noisy, triangles, normals)
    lines = path.read_text().splitlines()
    v = np.array([[float(x) for x in ln.split()[1:]] for ln in lines if ln.startswith("v ")])
    vn = np.array([[float(x) for x in ln.split()[1:]] for ln in lines if ln.startswith("vn ")])
    f = np.array([[int(x.split("//")[0]) for x in ln.split()[1:]] for ln in lines
                  if ln.startswith("f ")])
    np.testing.assert_array_equal(v, noisy)
    np.testing.assert_array_equal(vn, normals)
    np.testing.assert_array_equal(f - 1, triangles)


def test_glb_container_is_valid_and_reads_back_exactly(tmp_path, sphere):
    vertices, triangles, normals = sphere
    path = write_glb(tmp_path / "s.glb", vertices, triangles, normals)
    data = path.read_bytes()
    magic, version, length = struct.unpack_from("<III", data)
    assert (magic, version, length) == (0x46546C67, 2, len(data))
    json_len, json_type = struct.unpack_from("<II", data, 12)
    assert json_type == 0x4E4F534A and json_len % 4 == 0
    document = json.loads(data[20:20 + json_len])
    assert document["asset"]["version"] == "2.0"
    bin_len, bin_type = struct.unpack_from("<II", data, 20 + json_len)
    assert bin_type == 0x004E4942 and bin_len % 4 == 0
    assert bin_len == document["buffers"][0]["byteLength"]
    # POSITION min/max are required by the specification (3.7.2.1)
    position = document["accessors"][document["meshes"][0]["primitives"][0]["attributes"]
                                     ["POSITION"]]
    np.testing.assert_array_equal(position["min"], vertices.astype(np.float32).min(axis=0))
    v2, t2, n2 = read_glb(path)
    np.testing.assert_array_equal(v2, vertices.astype(np.float32))
    np.testing.assert_array_equal(t2, triangles)
    np.testing.assert_allclose(n2, normals, atol=F32)


def test_glb_large_mesh_and_colours(tmp_path):
    # > 65 535 vertices: indices must be uint32 for the file to read back at all.
    mesh = o3d.geometry.TriangleMesh.create_sphere(1.0, 200)
    vertices, triangles = np.asarray(mesh.vertices), np.asarray(mesh.triangles)
    assert len(vertices) > 65535
    colors = np.zeros((len(vertices), 3), dtype=np.uint8)
    colors[:, 0] = 255
    colors[::2, 2] = 128
    path = export_mesh(tmp_path / "big.glb", vertices, triangles, colors=colors)
    v2, t2, n2, c2 = _read(path)
    assert len(v2) == len(vertices) and len(t2) == len(triangles)
    np.testing.assert_allclose(v2[t2], vertices[triangles], atol=F32)
    np.testing.assert_allclose(n2[t2], vertex_normals(vertices, triangles)[triangles], atol=F32)
    # colours travel as float32 c/255
    np.testing.assert_allclose(c2[t2], colors[triangles] / 255.0, atol=F32)


def test_vertex_normals_of_sphere_point_outwards(sphere):
    vertices, triangles, exact = sphere
    normals = vertex_normals(vertices, triangles)
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-12)
    # area-weighted normals deviate from the radial direction by O(h) where the
    # 1-ring is not symmetric (the rings next to the poles), h = pi/20 here:
    # under h/4 = 0.04 rad, cos > 0.999.
    assert np.einsum("ij,ij->i", normals, exact).min() > 0.999
    # the same definition as open3d's (sum of unnormalised face normals)
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(vertices),
                                     o3d.utility.Vector3iVector(triangles.astype(np.int32)))
    mesh.compute_vertex_normals()
    np.testing.assert_allclose(normals, np.asarray(mesh.vertex_normals), atol=1e-12)


def test_isolated_vertex_gets_a_finite_normal():
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [5, 5, 5]], dtype=np.float64)
    normals = vertex_normals(vertices, np.array([[0, 1, 2]]))
    np.testing.assert_array_equal(normals, [[0, 0, 1]] * 4)


def test_bad_mesh_input(tmp_path, sphere):
    vertices, triangles, normals = sphere
    with pytest.raises(InputError, match=r"s\.xyz.*'\.xyz'"):
        export_mesh(tmp_path / "s.xyz", vertices, triangles)
    with pytest.raises(ValueError, match="triangles index vertices outside"):
        export_mesh(tmp_path / "s.ply", vertices, triangles + 1000)
    with pytest.raises(ValueError, match="normals must have one row per vertex"):
        export_mesh(tmp_path / "s.ply", vertices, triangles, normals[:5])
    with pytest.raises(ValueError, match="vertices contains 1 NaN"):
        bad = vertices.copy()
        bad[3, 1] = np.nan
        export_mesh(tmp_path / "s.ply", bad, triangles)
    assert list(tmp_path.iterdir()) == []


def test_read_glb_rejects_other_files(tmp_path):
    path = tmp_path / "x.glb"
    path.write_bytes(b"not a glb file at all, really")
    with pytest.raises(InputError, match="not a glTF 2.0 binary"):
        read_glb(path)
    with pytest.raises(FileNotFoundError, match="missing.glb"):
        read_glb(tmp_path / "missing.glb")


# --------------------------------------------------------------------------- control net


def _linear_net(corners):
    """Degree elevation of the flat triangle ``corners`` (P, 3, 3): P_ijk = (i a + j b + k c)/6."""
    index = _index_table()
    return np.einsum("mc,pcx->pmx", index / 6.0, corners), index


def test_control_net_round_trip_and_linear_precision(tmp_path):
    rng = np.random.default_rng(7)
    corners = rng.standard_normal((5, 3, 3))
    control_points, index = _linear_net(corners)
    path = write_control_net(tmp_path / "net.npz", control_points, index, np.arange(5) * 2)
    net = read_control_net(path)
    np.testing.assert_array_equal(net.control_points, control_points)
    np.testing.assert_array_equal(net.index, index)
    np.testing.assert_array_equal(net.source_face, np.arange(5) * 2)
    assert net.format_version == 2
    with np.load(path, allow_pickle=False) as raw:  # plain numpy can read every field
        assert str(raw["format"]) == CONTROL_NET_FORMAT and int(raw["degree"]) == 6
    # Bernstein polynomials reproduce linear functions: S(r,s,t) = r a + s b + t c.
    bary = rng.dirichlet(np.ones(3), size=11)
    expected = np.einsum("mc,pcx->pmx", bary, corners)
    np.testing.assert_allclose(net.evaluate(bary), expected, atol=1e-14)
    # corner (6,0,0) interpolates the first control point
    np.testing.assert_allclose(net.evaluate(np.eye(3))[:, 0], corners[:, 0], atol=1e-15)


def _bezier_sphere():
    """Loop's surface over a UV sphere: shared boundary rows, irregular poles."""
    import open3d as o3d

    from surface import bezier

    mesh = o3d.geometry.TriangleMesh.create_sphere(1.0, 8)
    return bezier.control_net(np.asarray(mesh.vertices), np.asarray(mesh.triangles))


def test_control_net_v2_shares_boundary_points_and_rebuilds_bit_for_bit(tmp_path):
    from surface.bezier import index_table

    surface = _bezier_sphere()
    cp, (dv, dt) = surface.control_points, surface.domain_mesh
    n_edges = len(dt) * 3 // 2  # closed mesh: each edge in two patches
    expected = len(dv) + 5 * n_edges + 10 * len(dt)  # corners, edge rows, interiors
    for domain in ((dv, dt), None):  # by topology, and by exact equality
        path = write_control_net(tmp_path / "v2.npz", cp, index_table(), surface.source_face,
                                 domain_mesh=domain)
        net = read_control_net(path)
        assert net.format_version == 2 and len(net.points) == expected
        assert net.control_points.tobytes() == cp.tobytes()  # bit for bit
        # the integer tables deflated, the coordinates stored: numpy.load reads both
        with zipfile.ZipFile(path) as zf:
            kinds = {i.filename[:-4]: i.compress_type for i in zf.infolist()}
        assert kinds["patches"] == kinds.get("domain_triangles", zipfile.ZIP_DEFLATED) \
            == zipfile.ZIP_DEFLATED
        assert kinds["points"] == zipfile.ZIP_STORED
        with np.load(path) as plain:
            assert plain["points"][plain["patches"]].tobytes() == cp.tobytes()
    # the same surface in version 1 is read as well, and is larger
    v1 = write_control_net(tmp_path / "v1.npz", cp, index_table(), surface.source_face,
                           domain_mesh=(dv, dt), version=1)
    old = read_control_net(v1)
    assert old.format_version == 1 and old.points is None
    assert old.control_points.tobytes() == cp.tobytes()
    # compare the arrays held (both files are deflated, which also finds v1's repeats)
    def held(p):
        with zipfile.ZipFile(p) as zf:
            return sum(i.file_size for i in zf.infolist())
    assert held(path) < 0.85 * held(v1)
    assert path.stat().st_size < v1.stat().st_size


def test_control_net_v2_keeps_points_that_differ_in_the_last_bit(tmp_path):
    from surface.bezier import index_table

    surface = _bezier_sphere()
    cp = surface.control_points.copy()
    cp[0, 1, 0] = np.nextafter(cp[0, 1, 0], np.inf)  # an edge point, now one ulp off its twin
    path = write_control_net(tmp_path / "v2.npz", cp, index_table(), surface.source_face,
                             domain_mesh=surface.domain_mesh)
    assert read_control_net(path).control_points.tobytes() == cp.tobytes()


def test_control_net_v2_numbers_points_of_a_domain_with_unused_vertices(tmp_path):
    from surface.bezier import index_table

    surface = _bezier_sphere()
    cp, (dv, dt) = surface.control_points, surface.domain_mesh
    # vertex 0 of the domain used by no patch: its id is a gap the numbering closes
    domain = (np.vstack([np.zeros((1, 3)), dv]), dt + 1)
    path = write_control_net(tmp_path / "gap.npz", cp, index_table(), surface.source_face,
                             domain_mesh=domain)
    net = read_control_net(path)
    assert len(net.points) == len(dv) + 5 * (len(dt) * 3 // 2) + 10 * len(dt)
    assert net.control_points.tobytes() == cp.tobytes()


def test_control_net_v2_rejects_bad_patch_indices(tmp_path):
    from surface.bezier import index_table

    surface = _bezier_sphere()
    path = write_control_net(tmp_path / "v2.npz", surface.control_points, index_table())
    with np.load(path) as raw:
        fields = dict(raw)
    fields["patches"] = fields["patches"].copy()
    fields["patches"][3, 4] = len(fields["points"])
    np.savez(tmp_path / "bad.npz", **fields)
    with pytest.raises(InputError, match="bad.npz: patches must index rows"):
        read_control_net(tmp_path / "bad.npz")


def test_control_net_evaluate_matches_direct_bernstein_sum():
    rng = np.random.default_rng(3)
    index = _index_table()[rng.permutation(28)]  # any documented order works
    net = ControlNet(rng.standard_normal((2, 28, 3)), index, np.array([0, 1]))
    r, s, t = 0.2, 0.5, 0.3
    from math import factorial

    direct = sum(factorial(6) / (factorial(i) * factorial(j) * factorial(k))
                 * r**i * s**j * t**k * net.control_points[:, m]
                 for m, (i, j, k) in enumerate(index))
    np.testing.assert_allclose(net.evaluate(np.array([[r, s, t]]))[:, 0], direct, atol=1e-14)


def test_control_net_rejects_bad_files(tmp_path):
    control_points, index = _linear_net(np.zeros((1, 3, 3)))
    with pytest.raises(ValueError, match="index rows must be"):
        write_control_net(tmp_path / "a.npz", control_points, index + 1)
    with pytest.raises(ValueError, match="each of the 28"):
        write_control_net(tmp_path / "a.npz", control_points, np.repeat(index[:1], 28, axis=0))
    with pytest.raises(ValueError, match=r"control_points must have shape \(P, 28, 3\)"):
        write_control_net(tmp_path / "a.npz", control_points[:, :10], index)
    np.savez(tmp_path / "other.npz", control_points=control_points)
    with pytest.raises(InputError, match="not a photosurf control net"):
        read_control_net(tmp_path / "other.npz")
    path = write_control_net(tmp_path / "net.npz", control_points, index)
    with np.load(path) as raw:
        fields = dict(raw)
    fields["format_version"] = np.int64(99)
    np.savez(tmp_path / "future.npz", **fields)
    with pytest.raises(InputError, match="version 99 is not supported"):
        read_control_net(tmp_path / "future.npz")


def test_export_surface_is_all_or_nothing(tmp_path, sphere, monkeypatch):
    vertices, triangles, normals = sphere
    control_points, index = _linear_net(vertices[triangles])
    mesh_path, net_path = export_surface(tmp_path / "out.glb", vertices, triangles, normals,
                                         control_points, index, np.arange(len(triangles)))
    assert net_path == tmp_path / "out.npz"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.glb", "out.npz"]
    np.testing.assert_array_equal(read_control_net(net_path).control_points, control_points)

    # A failure while writing the second file leaves neither behind.
    target = tmp_path / "fail"
    target.mkdir()

    def broken_savez(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(export_module, "write_npz_to", broken_savez)
    with pytest.raises(OSError, match="disk full"):
        export_surface(target / "out.ply", vertices, triangles, normals, control_points, index)
    assert list(target.iterdir()) == []


def test_export_is_byte_reproducible(tmp_path, sphere):
    # np.savez stamps the time into the zip; the same surface must give the same bytes
    # (workspace hashes, rerun checks), so two exports a few seconds apart are identical.
    import time

    vertices, triangles, normals = sphere
    control_points, index = _linear_net(vertices[triangles])
    files = []
    for run in range(2):
        if run:
            time.sleep(2.1)  # zip times have a 2 s resolution
        folder = tmp_path / str(run)
        folder.mkdir()
        written = [write_control_net(folder / "net.npz", control_points, index)]
        for suffix in EXPORT_SUFFIXES:
            written += export_surface(folder / f"s{suffix}", vertices, triangles, normals,
                                      control_points, index, np.arange(len(triangles)))
        files.append({p.name: p.read_bytes() for p in written})
    assert files[0] == files[1]


def test_ply_carries_each_vertex_sigma(tmp_path, sphere):
    # the surface's 1 sigma along the normal as a float vertex property, after the normals
    vertices, triangles, normals = sphere
    sigma = np.linspace(1e-4, 2e-3, len(vertices))
    path = export_mesh(tmp_path / "s.ply", vertices, triangles, normals, sigma=sigma)
    raw = path.read_bytes()
    head, body = raw.split(b"end_header\n", 1)
    assert b"property float sigma" in head
    record = np.dtype([("p", "<f8", 3), ("n", "<f4", 3), ("sigma", "<f4")])
    data = np.frombuffer(body[:record.itemsize * len(vertices)], dtype=record)
    np.testing.assert_array_equal(data["p"], vertices)
    np.testing.assert_allclose(data["sigma"], sigma, rtol=1e-7)
    with pytest.raises(ValueError):
        export_mesh(tmp_path / "bad.ply", vertices, triangles, normals, sigma=sigma[:-1])
