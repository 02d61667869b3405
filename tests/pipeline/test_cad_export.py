"""STEP / IGES export (pipeline/cad.py): read back with OpenCascade, compared with the
exact Bézier surface and its tessellation."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("OCP")

from pipeline import cad_export as cad  # noqa: E402
from surface import bezier  # noqa: E402
from surface.metrics import point_mesh_distance  # noqa: E402
from testkit.nets import ellipsoid_net  # noqa: E402


@pytest.fixture(scope="module")
def ellipsoid():
    """Loop's surface over a coarse ellipsoid (valence 4, 5, 6 vertices): 320 patches."""
    return ellipsoid_net()


def _props(shape):
    from OCP.BRepGProp import BRepGProp
    from OCP.GProp import GProp_GProps

    volume, area = GProp_GProps(), GProp_GProps()
    BRepGProp.VolumeProperties_s(shape, volume)
    BRepGProp.SurfaceProperties_s(shape, area)
    return volume.Mass(), area.Mass()


def _faces(shape):
    from OCP.TopAbs import TopAbs_FACE
    from OCP.TopExp import TopExp_Explorer
    from OCP.TopoDS import TopoDS

    explorer = TopExp_Explorer(shape, TopAbs_FACE)
    while explorer.More():
        yield TopoDS.Face(explorer.Current())
        explorer.Next()


def _same_closed_solid(path, cp, deviation: float):
    """The CAD file's shape and volume, checked: one valid solid whose shells are oriented
    (every edge in two faces, once) without free edges, its volume and area those of the
    patches ``cp`` within the faces' offset ``deviation`` times the area (OpenCascade's
    integration of a B-spline solid is itself approximate: ~1e-6 here)."""
    from OCP.BRepCheck import BRepCheck_Analyzer
    from OCP.ShapeAnalysis import ShapeAnalysis_Shell
    from OCP.TopAbs import TopAbs_SOLID

    from surface.measure import surface_integrals

    shape = cad.read_cad_solid(path)
    assert shape.ShapeType() == TopAbs_SOLID
    assert BRepCheck_Analyzer(shape).IsValid()
    shells = ShapeAnalysis_Shell()
    shells.LoadShells(shape)
    assert not shells.CheckOrientedShells(shape, True)
    assert not shells.HasFreeEdges()
    exact = surface_integrals(cp)
    volume, area = _props(shape)
    assert abs(volume - exact["volume"]) <= deviation * exact["area"] + 1e-5 * exact["area"]
    assert area == pytest.approx(exact["area"], rel=1e-4)
    return shape, volume


@pytest.mark.parametrize("suffix", [".step", ".iges"])
def test_cad_file_reads_back_as_the_closed_solid_of_the_surface(tmp_path, ellipsoid, suffix):
    from OCP.BRep import BRep_Tool
    from OCP.BRepCheck import BRepCheck_Analyzer
    from OCP.ShapeAnalysis import ShapeAnalysis_Shell
    from OCP.TopAbs import TopAbs_SOLID

    cp, tris = ellipsoid.control_points, ellipsoid.domain_mesh[1]
    path = cad.write_cad(tmp_path / f"surface{suffix}", cp, tris)
    shape = cad.read_cad_solid(path)
    faces = list(_faces(shape))
    assert len(faces) == len(cp)  # one degenerate (6, 6) face per patch
    if suffix == ".step":  # IGES keeps faces and shells but reads back as a compound
        assert shape.ShapeType() == TopAbs_SOLID
        assert BRepCheck_Analyzer(shape).IsValid()
        shells = ShapeAnalysis_Shell()
        shells.LoadShells(shape)
        assert not shells.CheckOrientedShells(shape, True)  # every edge in two faces, once
        assert not shells.HasFreeEdges()
    # area and volume against a fine tessellation of the same surface (exact to its chord
    # error: level 3 is within 1e-5 here), well inside the 0.5 %
    level = 3
    v, t, _ = bezier.tessellate(ellipsoid, level)
    a, b, c = (v[t[:, i]] for i in range(3))
    tess_volume = float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)
    tess_area = float(0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1).sum())
    volume, area = _props(shape)
    if suffix == ".step":
        assert volume == pytest.approx(tess_volume, rel=5e-3)
    assert area == pytest.approx(tess_area, rel=5e-3)
    # every face is exact: its points lie on the tessellation within its chord bound
    chord = float(bezier.chord_error_bound(bezier.subdivide(bezier.subdivide(
        bezier.subdivide(cp)))).max())
    grid = np.linspace(0.05, 0.95, 4)
    samples = []
    for face in faces:
        surface = BRep_Tool.Surface_s(face)
        u0, u1, v0, v1 = surface.Bounds()
        for u in grid:
            for w in grid:
                p = surface.Value(u0 + u * (u1 - u0), v0 + w * (v1 - v0))
                samples.append((p.X(), p.Y(), p.Z()))
    distance = point_mesh_distance(np.array(samples), v, t)
    assert distance.max() <= chord * 1.001 + 1e-12


def test_degenerate_nets_are_the_triangular_patches(ellipsoid):
    # each (6, 6) net, evaluated at (u, v), is the sextic at barycentric (1-u, u(1-v), uv)
    from math import comb

    cp = ellipsoid.control_points[:17]
    nets = cad.degenerate_nets(cp)
    rng = np.random.default_rng(5)
    for u, v in np.vstack([rng.random((6, 2)), [[0.0, 0.3], [1.0, 1.0], [0.5, 0.0]]]):
        bu = np.array([comb(6, k) * u ** k * (1 - u) ** (6 - k) for k in range(7)])
        bv = np.array([comb(6, k) * v ** k * (1 - v) ** (6 - k) for k in range(7)])
        expected = bezier.evaluate(cp, np.array([[1 - u, u * (1 - v), u * v]]))[:, 0]
        got = np.einsum("k,l,pkld->pd", bu, bv, nets)
        np.testing.assert_allclose(got, expected, atol=1e-14)
    # the three real sides are the net's edge control points bit for bit (what lets
    # neighbouring faces share one edge curve), the fourth is corner 0 seven times
    def row(i, j, k):
        return cp[:, bezier.control_index(i, j, k)]

    m = np.arange(7)
    assert np.array_equal(nets[:, :, 0], row(6 - m, m, 0 * m))
    assert np.array_equal(nets[:, 6, :], row(0 * m, 6 - m, m))
    assert np.array_equal(nets[:, :, 6], row(6 - m, 0 * m, m))
    assert np.array_equal(nets[:, 0, :], np.repeat(cp[:, :1], 7, axis=1))


def test_step_file_shares_the_poles_of_neighbouring_faces(tmp_path, ellipsoid):
    # one CARTESIAN_POINT per distinct pole: a corner per domain vertex, 5 per domain
    # edge, 25 inside each face (and the placement's origin); OpenCascade's shape
    # transfer would repeat every pole of every surface and edge curve (61 a patch)
    import re

    cp, tris = ellipsoid.control_points, ellipsoid.domain_mesh[1]
    path = cad.write_cad(tmp_path / "s.step", cp, tris)
    points = len(re.findall(r"CARTESIAN_POINT\('',\([^,)]*,[^,)]*,[^,)]*\)\)", path.read_text()))
    n_vertices, n_edges = int(tris.max()) + 1, len(tris) * 3 // 2
    distinct = n_vertices + 5 * n_edges + 25 * len(tris)
    assert distinct <= points <= distinct + 1


def test_clockwise_domain_gives_the_same_outward_solid(tmp_path, ellipsoid):
    # the same surface over the domain turned over (corners 1, 2 and net indices j, k
    # swapped): the solid is turned back, so its volume is the same and positive
    from OCP.BRepCheck import BRepCheck_Analyzer

    cp, tris = ellipsoid.control_points, ellipsoid.domain_mesh[1]
    volumes = []
    for name, (nets, domain) in {"ccw": (cp, tris),
                                 "cw": cad._reversed_nets(cp, tris)}.items():
        shape = cad.read_cad_solid(cad.write_cad(tmp_path / f"{name}.step", nets, domain))
        assert BRepCheck_Analyzer(shape).IsValid()
        volumes.append(_props(shape)[0])
    assert volumes[0] > 0
    assert volumes[1] == pytest.approx(volumes[0], rel=1e-12)


def _bernstein(t: np.ndarray) -> np.ndarray:
    from math import comb

    return np.array([comb(6, k) * t ** k * (1 - t) ** (6 - k) for k in range(7)])


def test_step_edges_carry_their_pcurves_on_both_faces(tmp_path, ellipsoid):
    # each edge's SURFACE_CURVE holds a PCURVE on each of its two faces (six shared 2D
    # lines); evaluated from the file's own entities, each face's surface at the
    # pcurve's point is the edge curve's point at the same parameter (a pcurve run the
    # wrong way, or on the wrong side, misses by up to the edge's length).  Checked in
    # the text: OpenCascade's reader repairs wrong pcurves silently.
    import re

    cp, tris = ellipsoid.control_points, ellipsoid.domain_mesh[1]
    path = cad.write_cad(tmp_path / "s.step", cp, tris)
    text = path.read_text()
    entity = dict(re.findall(r"^#(\d+)=([A-Z_]+\(.*\));$", text, re.MULTILINE))
    refs = lambda body: [int(i) for i in re.findall(r"#(\d+)", body)]  # noqa: E731
    numbers = lambda body: [float(x) for x in re.findall(r"\(([^()#']*)\)", body)[0].split(",")]  # noqa: E731,E501
    n_edges = len(tris) * 3 // 2
    surface_curves = [body for body in entity.values() if body.startswith("SURFACE_CURVE(")]
    assert len(surface_curves) == n_edges
    assert sum(body.startswith("PCURVE(") for body in entity.values()) == 2 * n_edges
    size = float(np.ptp(cp.reshape(-1, 3), axis=0).max())
    uncertainty = re.search(r"LENGTH_MEASURE\(([^)]*)\)", text).group(1)
    assert float(uncertainty) == pytest.approx(cad.step_uncertainty(size), rel=1e-5)
    t = np.linspace(0.0, 1.0, 5)
    worst = 0.0
    for body in surface_curves:
        curve, *pcurves = refs(body)
        poles = np.array([numbers(entity[str(i)]) for i in refs(entity[str(curve)])])
        on_curve = _bernstein(t).T @ poles  # (5, 3)
        assert len(pcurves) == 2
        for pcurve in pcurves:
            surface, representation = refs(entity[str(pcurve)])
            net = np.array([numbers(entity[str(i)]) for i in refs(entity[str(surface)])])
            line = refs(entity[str(representation)])[0]
            origin, vector = refs(entity[str(line)])
            direction = numbers(entity[str(refs(entity[str(vector)])[0])])
            u = numbers(entity[str(origin)])[0] + t * direction[0]
            v = numbers(entity[str(origin)])[1] + t * direction[1]
            on_surface = np.einsum("ki,li,kld->id", _bernstein(u), _bernstein(v),
                                   net.reshape(7, 7, 3))
            worst = max(worst, float(np.abs(on_surface - on_curve).max()))
    assert worst <= 1e-9 * size


def test_step_reals_have_their_decimal_point():
    # Part 21: a REAL is digits "." digits [E exponent]; %G drops the point
    assert cad._reals("(1E-05,0,-2,1.5E-05,0.25,-3E+16)") == "(1.E-05,0.,-2.,1.5E-05,0.25,-3.E+16)"


def test_open_surface_is_written_as_an_open_shell(tmp_path, ellipsoid):
    # the patches over part of the domain: a valid shell with a border, not a solid
    from OCP.BRepCheck import BRepCheck_Analyzer
    from OCP.ShapeAnalysis import ShapeAnalysis_Shell
    from OCP.TopAbs import TopAbs_SHELL

    cp, tris = ellipsoid.control_points, ellipsoid.domain_mesh[1]
    keep = ellipsoid.domain_mesh[0][tris].mean(axis=1)[:, 2] > 0  # the upper half
    used, local = np.unique(tris[keep], return_inverse=True)
    path = cad.write_cad(tmp_path / "half.step", cp[keep], local.reshape(-1, 3))
    shape = cad.read_cad_solid(path)
    assert shape.ShapeType() == TopAbs_SHELL
    assert sum(1 for _ in _faces(shape)) == int(keep.sum())
    assert BRepCheck_Analyzer(shape).IsValid()
    shells = ShapeAnalysis_Shell()
    shells.LoadShells(shape)
    shells.CheckOrientedShells(shape, True)
    assert shells.HasFreeEdges()  # the border


def test_write_cad_refuses_unknown_suffix_and_mismatched_arrays(tmp_path, ellipsoid):
    from pipeline.errors import InputError

    cp, tris = ellipsoid.control_points, ellipsoid.domain_mesh[1]
    with pytest.raises(InputError, match="cannot write CAD format '.dxf'"):
        cad.write_cad(tmp_path / "a.dxf", cp, tris)
    with pytest.raises(ValueError, match="one row per patch"):
        cad.write_cad(tmp_path / "a.step", cp, tris[:-1])
    assert list(tmp_path.iterdir()) == []


def test_write_cad_refuses_more_patches_than_the_limit(tmp_path, ellipsoid, monkeypatch):
    """``cad.patches``: refused in one line before OpenCascade builds anything, nothing
    written; --allow-large (its environment variable) lifts it."""
    import dataclasses

    from pipeline import limits

    cp, tris = ellipsoid.control_points, ellipsoid.domain_mesh[1]
    monkeypatch.setitem(limits.LIMITS, "cad.patches", dataclasses.replace(
        limits.LIMITS["cad.patches"], maximum=len(cp) - 1))
    monkeypatch.delenv(limits.ALLOW_ENV, raising=False)
    with pytest.raises(limits.LimitError, match=rf"a\.step: {len(cp)} patches: cad\.patches = "
                                                rf"{len(cp)} is past the limit {len(cp) - 1}"):
        cad.write_cad(tmp_path / "a.step", cp, tris)
    assert list(tmp_path.iterdir()) == []
    monkeypatch.setenv(limits.ALLOW_ENV, "1")
    assert cad.write_cad(tmp_path / "a.step", cp, tris).stat().st_size > 0


def test_run_exports_a_step_solid_of_the_sized_surface(tmp_path):
    """photosurf run on a small noisy vase cloud with export.formats = ["ply", "step"]."""
    import json

    from OCP.BRepCheck import BRepCheck_Analyzer

    from pipeline import cli

    rng = np.random.default_rng(0)
    n = 3000
    z = rng.uniform(0, 3, n)
    theta = rng.uniform(0, 2 * np.pi, n)
    r = 1 + 0.3 * np.sin(2 * z)
    cloud = tmp_path / "vase.xyz"
    np.savetxt(cloud, np.column_stack([r * np.cos(theta), r * np.sin(theta), z])
               + rng.normal(0, 0.002, (n, 3)))
    out = tmp_path / "run"
    code = cli.main(["run", str(cloud), "--out", str(out), "--to", "export", "-q",
                     "--set", 'export.formats=["ply", "step"]',
                     "--set", "smooth.size_tolerance=0.005"])  # coarse: a quick STEP
    assert code == 0
    manifest = json.loads((out / "manifest.json").read_text())
    smooth = manifest["stages"]["smooth"]["info"]
    assert smooth["size_step"] >= 1 and smooth["patches"] == 4 * smooth["control_triangles"]
    assert manifest["stages"]["export"]["info"]["files"] == ["surface.ply", "surface.step",
                                                             "surface.npz"]
    shape = cad.read_cad_solid(out / "export" / "surface.step")
    assert BRepCheck_Analyzer(shape).IsValid()
    # a face per control triangle (within the chord tolerance, G1) or else per patch
    faces = sum(1 for _ in _faces(shape))
    assert faces == manifest["stages"]["export"]["info"]["cad_faces"]
    assert faces in (smooth["patches"], smooth["control_triangles"])


def test_step_with_a_face_per_control_triangle_is_the_same_solid(tmp_path, ellipsoid):
    """Given a CAD tolerance, a fourth of the faces (surface.bezier_merge, two spans):
    a valid closed solid sharing every edge, its volume and area those of the patches to
    within the faces' measured offset times the area."""
    cp, tris, source = ellipsoid.control_points, ellipsoid.domain_mesh[1], ellipsoid.source_face
    report: dict = {}
    path = cad.write_cad(tmp_path / "merged.step", cp, tris, source_face=source,
                          tolerance=1e-3, report=report)
    assert report["merged"] and report["faces"] == len(cp) // 4
    assert report["deviation"] <= 1e-3
    shape, volume = _same_closed_solid(path, cp, report["deviation"])
    assert len(list(_faces(shape))) == len(cp) // 4
    # the turned-over domain gives the same outward solid
    flipped = cad.write_cad(tmp_path / "flipped.step", cp[:, _swap_jk()], tris[:, [0, 2, 1]],
                             source_face=source, tolerance=1e-3)
    assert _props(cad.read_cad_solid(flipped))[0] == pytest.approx(volume, rel=1e-9)


def _swap_jk() -> np.ndarray:
    table = bezier.index_table()
    return bezier.control_index(table[:, 0], table[:, 2], table[:, 1])


def test_step_keeps_the_patches_where_a_merged_face_misses_the_tolerance(tmp_path, ellipsoid):
    cp, tris, source = ellipsoid.control_points, ellipsoid.domain_mesh[1], ellipsoid.source_face
    report: dict = {}
    path = cad.write_cad(tmp_path / "exact.step", cp, tris, source_face=source,
                          tolerance=1e-12, report=report)
    assert not report["merged"] and report["deviation"] > 1e-12 and "reason" in report
    assert len(list(_faces(cad.read_cad_solid(path)))) == len(cp)
    with pytest.raises(ValueError, match="tolerance"):
        cad.write_cad(tmp_path / "bad.step", cp, tris, source_face=source, tolerance=0.0)
    # one-span faces lie within 1e-3 here but kink across their sides: not G1, refused,
    # unless kinks are accepted
    report = {}
    cad.write_cad(tmp_path / "one.step", cp, tris, source_face=source, tolerance=1e-3,
                   report=report, spans=1)
    assert not report["merged"] and "not G1" in report["reason"]
    assert report["deviation"] <= 1e-3 and report["angle_deg"] > report["angle_tolerance_deg"]
    report = {}
    path = cad.write_cad(tmp_path / "kinked.step", cp, tris, source_face=source,
                          tolerance=1e-3, report=report, spans=1, angle_tolerance=np.inf)
    assert report["merged"] and len(list(_faces(cad.read_cad_solid(path)))) == len(cp) // 4


def test_step_with_quadrilateral_faces_is_the_same_solid(tmp_path, ellipsoid):
    """quads=True: paired control triangles as one face each (surface.bezier_quad), the
    rest as control-triangle faces, each control edge one edge: a valid closed solid of
    fewer faces, the same volume and area as the control-triangle file, G1 kept within
    the gate."""
    cp, tris, source = ellipsoid.control_points, ellipsoid.domain_mesh[1], ellipsoid.source_face
    report: dict = {}
    path = cad.write_cad(tmp_path / "quads.step", cp, tris, source_face=source,
                          tolerance=1e-3, report=report, quads=True)
    assert report["merged"] and report["quads"] > 0
    assert report["faces"] == report["quads"] + report["triangles"] < len(cp) // 4
    assert 2 * report["quads"] + report["triangles"] == len(cp) // 4
    assert report["angle_deg"] <= report["angle_tolerance_deg"]
    shape, _ = _same_closed_solid(path, cp, report["deviation"])
    assert len(list(_faces(shape))) == report["faces"]


def test_step_points_are_rounded_far_below_the_file_s_uncertainty(tmp_path, ellipsoid):
    # fixed-point coordinates to _decimals places: each coordinate of every pole of every
    # face within a twentieth of the file's distance uncertainty (8 places at 1e-7)
    import re

    from scipy.spatial import cKDTree

    from pipeline import step_text

    assert step_text._decimals(1e-7) == 8 and step_text._decimals(1e-6) == 7
    cp, tris = ellipsoid.control_points, ellipsoid.domain_mesh[1]
    text = cad.write_cad(tmp_path / "s.step", cp, tris).read_text()
    points = np.array([[float(x) for x in body.split(",")] for body in re.findall(
        r"CARTESIAN_POINT\('',\(([^()]*)\)\)", text) if body.count(",") == 2])
    uncertainty = float(re.search(r"LENGTH_MEASURE\(([^)]*)\)", text).group(1))
    distance, _ = cKDTree(points).query(cad.degenerate_nets(cp).reshape(-1, 3), p=np.inf)
    assert distance.max() <= uncertainty / 20


def test_connected_order_puts_each_face_after_a_neighbour():
    """Merged faces are written in breadth-first order over shared sides (OpenCascade's
    shell orientation fix rescans from the first face otherwise): on a shuffled 12 x 12
    grid of quadrilaterals plus a collapsed (triangle) face, every face but the first
    shares a side with a face before it, and the order is a permutation."""
    from pipeline.cad_export import _connected_order

    n = 12
    ids = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    quads = np.stack([ids[:-1, :-1], ids[:-1, 1:], ids[1:, 1:], ids[1:, :-1]], axis=-1)
    corners = quads.reshape(-1, 4)
    tri = np.array([[ids[0, 0], ids[0, 1], ids[-1, -1], ids[0, 0]]])  # side 3 collapsed
    corners = np.concatenate([corners, tri])
    corners = corners[np.random.default_rng(3).permutation(len(corners))]
    order = _connected_order(corners)
    assert np.array_equal(np.sort(order), np.arange(len(corners)))

    def sides(c):
        pairs = [(c[0], c[1]), (c[1], c[2]), (c[3], c[2]), (c[0], c[3])]
        return {tuple(sorted(p)) for p in pairs if p[0] != p[1]}
    seen = sides(corners[order[0]])
    for f in order[1:]:
        assert sides(corners[f]) & seen
        seen |= sides(corners[f])
