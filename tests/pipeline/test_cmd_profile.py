"""``photosurf profile``: SVG and DXF drawings, JSON figures, control nets, bad input."""

import json
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from pipeline.cli import main
from pipeline.mesh_io import write_mesh
from surface.profile import revolve
from testkit import cup as _cup

SVG = "{http://www.w3.org/2000/svg}"


@pytest.fixture(scope="module")
def cup_mesh(tmp_path_factory):
    folder = tmp_path_factory.mktemp("cup")
    path = folder / "cup.ply"
    write_mesh(path, *revolve(_cup.cup_profile(), 64))
    return path


def test_svg_drawing_and_figures(tmp_path, cup_mesh, capsys):
    out = tmp_path / "cup.svg"
    assert main(["profile", str(cup_mesh), "--out", str(out), "--units", "mm",
                 "--scale", "1:2", "--thickness-at", "20,50"]) == 0
    text = capsys.readouterr().out
    assert "capacity" in text and " l" in text and "drawing ->" in text
    root = ET.parse(out).getroot()
    assert root.tag == SVG + "svg"
    assert root.get("width").endswith("mm")
    section = root.find(f"{SVG}g[@id='section']")
    polygon = section.find(f"{SVG}polygon")
    points = np.array([[float(c) for c in p.split(",")] for p in polygon.get("points").split()])
    axis = root.find(f"{SVG}line[@id='axis']")
    assert axis.get("stroke-dasharray")  # dash-dot
    x_axis = float(axis.get("x1"))
    # the cut on the left of the axis, filled; at 1:2 in mm the cup's 90 mm are 45 mm
    assert section.get("fill") == "black"
    assert points[:, 0].max() <= x_axis + 1e-6
    assert np.ptp(points[:, 1]) == pytest.approx(_cup.H / 2, rel=1e-6)
    silhouette = root.find(f"{SVG}polyline[@id='silhouette']")
    outline = np.array([[float(c) for c in p.split(",")]
                        for p in silhouette.get("points").split()])
    assert outline[:, 0].min() >= x_axis - 1e-6  # the outside seen, on the right
    # RT on the paper at 1:2, less the 64-gon's sagitta at most
    assert outline[:, 0].max() - x_axis == pytest.approx(_cup.RT / 2, rel=1.5e-3)
    assert root.find(f"{SVG}g[@id='scalebar']") is not None
    lines = [t.text for t in root.iter(SVG + "text")]
    assert any("scale 1:2" in t for t in lines) and any("capacity" in t for t in lines)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cup.svg"]


def test_json_capacity_in_litres(cup_mesh, capsys):
    assert main(["profile", str(cup_mesh), "--json", "--units", "cm", "--fill", "60"]) == 0
    figures = json.loads(capsys.readouterr().out)
    n = 64
    share = n * np.sin(2 * np.pi / n) / (2 * np.pi)  # the 64-gon's part of the circle
    cap = figures["capacity"]
    assert cap["fill_height"] == pytest.approx(60.0, abs=1e-9)
    assert cap["volume"] == pytest.approx(share * _cup.analytic_capacity(60.0), rel=1e-9)
    assert cap["litres"] == pytest.approx(cap["volume"] / 1000.0, rel=1e-12)  # cm^3 -> l
    assert figures["height"] == pytest.approx(_cup.H, abs=1e-9)
    assert figures["circular"] is True
    assert figures["integrals"] == "mesh"
    assert figures["volume"] > 0 and figures["area"] > 0


def test_dxf_reads_back_with_its_entities(tmp_path, cup_mesh, capsys):
    ezdxf = pytest.importorskip("ezdxf")
    out = tmp_path / "cup.dxf"
    assert main(["profile", str(cup_mesh), "--out", str(out), "--units", "mm", "-q"]) == 0
    assert capsys.readouterr().out == ""
    doc = ezdxf.readfile(out)
    assert doc.header["$INSUNITS"] == 4
    msp = doc.modelspace()
    section = msp.query('LWPOLYLINE[layer=="SECTION"]')
    assert len(section) >= 1 and section[0].closed
    xy = np.array([p[:2] for p in section[0].get_points()])
    assert xy[:, 0].max() <= 1e-9  # drawn at -r
    assert np.ptp(xy[:, 1]) == pytest.approx(_cup.H, abs=1e-9)  # 1:1 in the model unit
    assert len(msp.query('HATCH[layer=="SECTION"]')) >= 1
    axis = msp.query('LINE[layer=="AXIS"]')
    assert len(axis) == 1 and axis[0].dxf.linetype == "DASHDOT"
    assert len(msp.query('LWPOLYLINE[layer=="SILHOUETTE"]')) == 1
    texts = [t.dxf.text for t in msp.query("TEXT")]
    assert any("capacity" in t for t in texts) and any("scale 1:" in t for t in texts)


def test_control_net_input_uses_the_exact_integrals(tmp_path, capsys):
    from pipeline.export import write_control_net
    from surface import bezier

    vertices, triangles = revolve(_cup.cup_profile(wall=12, base=6, lip=5), 24)
    net = bezier.control_net(vertices, triangles)
    path = tmp_path / "cup.npz"
    write_control_net(path, net.control_points, bezier.index_table(), net.source_face,
                      net.domain_mesh)
    assert main(["profile", str(path), "--json"]) == 0
    figures = json.loads(capsys.readouterr().out)
    from surface.measure import surface_volume

    assert figures["integrals"] == "exact patches"
    assert figures["volume"] == pytest.approx(surface_volume(net.control_points), rel=1e-12)
    assert figures["capacity"] is not None and figures["capacity"]["volume"] > 0
    assert figures["chord_bound"] > 0 and figures["uncertainty"] >= figures["chord_bound"]


@pytest.mark.parametrize("extra, message", [
    (["--out", "x.png"], "cannot write a drawing"),
    (["--scale", "2:3"], "--scale must be 1:N"),
    (["--thickness-at", "a,b"], "--thickness-at"),
    (["--sigma", "-1"], "--sigma must be"),
    (["--fill", "0"], "--fill must be"),
])
def test_bad_options_are_one_line_errors(tmp_path, cup_mesh, capsys, extra, message):
    args = ["profile", str(cup_mesh)] + [str(tmp_path / a) if a.endswith(".png") else a
                                          for a in extra]
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and message in err
    assert list(tmp_path.iterdir()) == []


def test_missing_and_foreign_inputs(tmp_path, capsys):
    assert main(["profile", str(tmp_path / "none.ply")]) == 2
    assert "none.ply" in capsys.readouterr().err
    junk = tmp_path / "junk.npz"
    np.savez(junk, something=np.zeros(3))
    assert main(["profile", str(junk)]) == 2
    err = capsys.readouterr().err
    assert "junk.npz" in err and "control_points" in err
    assert main(["profile", str(tmp_path)]) == 2  # a folder that is no workspace
    assert "not a photosurf workspace" in capsys.readouterr().err


def test_workspace_brings_its_axis_and_sigma(tmp_path, capsys):
    from pipeline import artifacts
    from surface import bezier

    vertices, triangles = revolve(_cup.cup_profile(wall=12, base=6, lip=5), 24)
    # the cup lying along x (a rotation about y: (x, y, z) -> (z, y, -x)), mouth to +x:
    # the workspace's sections axis says so
    vertices = vertices[:, [2, 1, 0]] * [1.0, 1.0, -1.0]
    net = bezier.control_net(vertices, triangles)
    tv, tt, tn = bezier.tessellate(net, 1)
    (tmp_path / "smooth").mkdir()
    artifacts.write_smooth(tmp_path / "smooth", tv, tt, tn, net)
    (tmp_path / "curves").mkdir()
    np.savez(tmp_path / "curves" / "curves.npz", axis=np.array([1.0, 0.0, 0.0]))
    (tmp_path / "acquire").mkdir()
    sigma = np.full(10, 0.5)
    sigma[0] = np.nan  # unknown: left out of the median
    np.savez(tmp_path / "acquire" / "cloud.npz", points=np.zeros((10, 3)), sigma=sigma)
    assert main(["profile", str(tmp_path), "--json"]) == 0
    figures = json.loads(capsys.readouterr().out)
    assert figures["axis"] == pytest.approx([1.0, 0.0, 0.0])
    assert figures["sigma"] == 0.5 and figures["uncertainty"] >= 0.5
    assert figures["height"] == pytest.approx(_cup.H, abs=2 * figures["uncertainty"])
    assert figures["capacity"] is not None
    assert figures["volume_sigma"] == pytest.approx(figures["uncertainty"] * figures["area"])
