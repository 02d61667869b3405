"""The surface stages of ``photosurf run`` (sections → curves → stitch) against
``surface.reconstruct.surface_from_points``: the same steps, so the same mesh.

The cloud is the stitch tests' noisy vase r(z) = 1 + 0.3 sin 2z (σ = 0.002),
given as an ``.npz`` point cloud.
"""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.mesh_io import read_mesh
from surface import metrics as M
from testkit.vase import SIGMA, noisy_cloud, vase_truth


@pytest.fixture(scope="module")
def vase(tmp_path_factory):
    v, f = vase_truth()
    points = noisy_cloud(v, f, 6000, seed=11)
    path = tmp_path_factory.mktemp("cloud") / "vase.npz"
    np.savez(path, points=points)
    return v, f, points, path


def _run(path, out, *sets):
    from pipeline import cli

    args = ["run", str(path), "--out", str(out), "--to", "stitch"]
    for s in sets:
        args += ["--set", s]
    assert cli.main(args) == 0


@pytest.mark.parametrize(("sets", "kwargs"), [
    ((), {}),
    (("sections.count=24", "curves.smoothing=4.0"), {"sections": 24, "smoothing": 4.0}),
    # 2026-11-22's mesh: fixed smoothing, no support rings (the defaults: 0 = "auto", support)
    (("curves.smoothing=8.0", "stitch.support=false"), {"smoothing": 8.0, "support": False}),
    (("curves.smoothing=auto",), {}),
])
def test_stages_give_the_mesh_of_surface_from_points(vase, tmp_path, sets, kwargs):
    from surface.reconstruct import surface_from_points

    v, f, points, path = vase
    _run(path, tmp_path / "out", *sets)
    vertices, triangles = read_mesh(tmp_path / "out" / "stitch" / "mesh.ply")
    expected = surface_from_points(points, **kwargs)
    # One implementation: the stages store what lies between the steps, nothing else.
    assert vertices.shape == expected.vertices.shape
    np.testing.assert_allclose(vertices, expected.vertices, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(triangles, expected.triangles)
    scores = M.compare_meshes(vertices, triangles, v, f, tau=0.005, count=20000)
    # As in tests/surface/test_stitch.py: the raw points lie sqrt(2/pi) σ = 0.8 σ
    # from the truth on average; the surface averages many points, so it is closer.
    assert scores["chamfer"] < 0.8 * SIGMA


def test_axis_projection_without_extension_is_worse(vase, tmp_path):
    v, f, points, path = vase
    _run(path, tmp_path / "out", "sections.projection=axis", "stitch.extend_ends=false")
    vertices, triangles = read_mesh(tmp_path / "out" / "stitch" / "mesh.ply")
    from surface.reconstruct import surface_from_points

    expected = surface_from_points(points, projection="axis", extend_ends=False)
    np.testing.assert_allclose(vertices, expected.vertices, rtol=0, atol=1e-12)
    worse = M.compare_meshes(vertices, triangles, v, f, tau=0.005, count=20000)
    # the caps sit half a section spacing inside the truth: above the raw points' 0.8 σ
    assert worse["chamfer"] > 0.8 * SIGMA


def test_a_failed_stage_stops_the_run_without_more_messages(vase, tmp_path, capfd,
                                                            monkeypatch):
    """After a failure only the report runs: export must not log "no smooth surface"
    before the one error line (the CLI promises one line)."""
    from pipeline import cli
    from surface import bezier

    def broken(*args, **kwargs):
        raise ValueError("broken on purpose")

    monkeypatch.setattr(bezier, "control_net", broken)
    out = tmp_path / "out"
    code = cli.main(["run", str(vase[3]), "--out", str(out), "--to", "export"])
    lines = [line for line in capfd.readouterr().err.splitlines() if line.strip()]
    assert code == 2
    assert len(lines) == 1 and "smooth failed" in lines[0] and "broken on purpose" in lines[0]
    import json

    stages = json.loads((out / "manifest.json").read_text())["stages"]
    assert stages["export"]["status"] == "blocked"
    assert stages["export"]["reason"] == "smooth failed"


@pytest.mark.parametrize(("setting", "needle"), [
    ("smooth.level=99", "smooth.level must be 0..6"),
    ("sections.count=1", "sections.count must be >= 2"),
    ("sections.spacing=-0.1", "sections.spacing must be > 0"),
    ("curves.smoothing=nan", "curves.smoothing must be >= 0"),
    ("acquire.patch=4", "acquire.patch must be an odd integer"),
])
def test_out_of_range_parameters_fail_before_the_workspace(vase, tmp_path, capfd, setting,
                                                          needle):
    from pipeline import cli

    out = tmp_path / "out"
    code = cli.main(["run", str(vase[3]), "--out", str(out), "--set", setting])
    err = capfd.readouterr().err
    assert code == 2 and needle in err and f"--set {setting}" in err, err
    assert not out.exists()


def test_curves_store_the_noise_and_stitch_adds_support_rings_at_the_rims(vase, tmp_path):
    """curves.npz carries the section points' sigma (surface.reconstruct.section_noise: the
    robust spread across the curve, ~ the cloud's sigma = 0.002 per coordinate, between
    0.8 and 1.5 of it with the local-quadratic misfit of 6000 points); the stitch stage
    adds support rings at the two 90° rims and nowhere else, and not with support off."""
    import json

    v, f, points, path = vase
    _run(path, tmp_path / "out")
    with np.load(tmp_path / "out" / "curves" / "curves.npz") as curves:
        assert 0.8 * SIGMA <= float(curves["noise"]) <= 1.5 * SIGMA
    notes = json.loads((tmp_path / "out" / "stitch" / "stitch.json").read_text())
    assert sum("support rings" in m for m in notes["messages"]) == 2
    _run(path, tmp_path / "off", "stitch.support=false")
    notes = json.loads((tmp_path / "off" / "stitch" / "stitch.json").read_text())
    assert not any("support rings" in m for m in notes["messages"])


def test_sfm_registration_reaches_the_manifest():
    # an SfM-posed folder's acquire stage carries SfM's own figures:
    # views registered of those given, sparse points, reprojection before / after the
    # LSM tie points, the frame's scale; a folder with its cameras carries none
    from matching.sfm import SfmResult
    from pipeline.stages import _sfm_info

    result = SfmResult(cameras=[], points=np.zeros((4211, 3)),
                       track_length=np.full(4211, 3), colors=np.zeros((4211, 3), np.uint8),
                       registered=[f"v{k}.png" for k in range(13)],
                       unregistered=["v13.png", "v14.png", "v15.png"],
                       mean_reprojection_error_px=0.0412,
                       refinement={"method": "lsm", "reprojection_before_px": 0.2137})
    info = _sfm_info(result.report(), 13 + 3)
    assert info == {"sfm_registered": "13 of 16", "sfm_sparse_points": 4211,
                    "sfm_reprojection_px": 0.041, "sfm_reprojection_before_lsm_px": 0.214,
                    "sfm_scale": "arbitrary"}
    assert _sfm_info(None, 16) == {}


def test_the_smooth_stage_says_when_the_sizing_keeps_the_dense_mesh(caplog):
    """A sizing with no candidate within its goal (the real temple posed by SfM) is told as
    a warning naming the closest candidate and the setting that accepts a coarser one."""
    from types import SimpleNamespace

    from pipeline.stages import _log_sizing

    tried = [{"step": 20, "n": 12, "error": "the thinned rings stitch to an open mesh"},
             {"step": 4, "n": 34, "error": 3.0e-3, "tolerance": 1.0e-3},
             {"step": 2, "n": 68, "error": 1.4e-3, "tolerance": 1.0e-3}]
    dense = SimpleNamespace(step=1, n=0, tried=tried, triangles=np.zeros((100, 3)),
                            error=0.0, tolerance=1.0e-3)
    with caplog.at_level("INFO", logger="photosurf"):
        _log_sizing(dense, 100)
    (record,) = caplog.records
    assert record.levelname == "WARNING"
    assert "sections 2 apart with 68 ring points" in record.message
    assert "0.0014 against 0.001" in record.message and "smooth.size_tolerance" in record.message
    caplog.clear()
    thinned = SimpleNamespace(step=2, n=68, tried=tried, triangles=np.zeros((40, 3)),
                              error=9e-4, tolerance=1.0e-3)
    with caplog.at_level("INFO", logger="photosurf"):
        _log_sizing(thinned, 100)
    (record,) = caplog.records
    assert record.levelname == "INFO" and "40 of 100 triangles" in record.message
