"""Each workspace file of ``pipeline.artifacts``: what its writer writes, its reader reads back.

Round trips with exact equality (the files store float64 as is), plus the byte
reproducibility the up-to-date rule relies on: the same arrays give the same bytes.
"""

from __future__ import annotations

import numpy as np
import pytest

from pipeline import artifacts
from pipeline.workspace import sha256_file


def _sections(rng, frame):
    from surface.sections import Section

    out = []
    start = 0
    for k, n in enumerate((5, 7, 4)):
        out.append(Section(height=0.5 * k, points=rng.normal(size=(n, 3)),
                           origin=rng.normal(size=3), frame=frame, section_id=k + 2,
                           source_index=np.arange(start, start + n, dtype=np.int64)))
        start += n
    return out


@pytest.fixture()
def rng():
    return np.random.default_rng(3)


@pytest.fixture()
def frame():
    q, _ = np.linalg.qr(np.random.default_rng(4).normal(size=(3, 3)))
    return q


def test_cloud_round_trip_and_defaults(tmp_path, rng):
    points = rng.normal(size=(50, 3))
    colors = rng.integers(0, 256, (50, 3))
    sigma = rng.uniform(0.001, 0.01, 50)
    artifacts.write_cloud(tmp_path, points, colors, sigma)
    back = artifacts.read_cloud(tmp_path)
    np.testing.assert_array_equal(back["points"], points)
    np.testing.assert_array_equal(back["colors"], colors.astype(np.uint8))
    np.testing.assert_array_equal(back["sigma"], sigma)
    from pipeline.cloud_io import read_cloud

    ply = read_cloud(tmp_path / artifacts.CLOUD_PLY)  # the viewers' copy says the same
    np.testing.assert_array_equal(ply.points, points)
    # without colours and sigma: black points of unknown sigma (NaN)
    (tmp_path / "bare").mkdir()
    artifacts.write_cloud(tmp_path / "bare", points)
    bare = artifacts.read_cloud(tmp_path / "bare")
    assert bare["colors"].dtype == np.uint8 and not bare["colors"].any()
    assert np.isnan(bare["sigma"]).all()


def test_cameras_round_trip(tmp_path, rng):
    # SfM's cameras of mixed sizes (a portrait view among landscape ones), with distortion
    import cv2

    from matching.cameras import Camera

    K = np.array([[1520.5, 0.0, 302.3], [0.0, 1520.5, 246.1], [0.0, 0.0, 1.0]])
    cams = [Camera(K, [-0.02, 0.01, 0.0, 0.0], cv2.Rodrigues(rng.normal(size=3))[0],
                   rng.normal(size=3), 640, 480, "a.png"),
            Camera(K[[1, 0, 2]][:, [1, 0, 2]], [], np.eye(3), rng.normal(size=3), 480, 640,
                   "b.jpg")]
    artifacts.write_cameras(tmp_path, cams)
    back = artifacts.read_cameras(tmp_path)
    assert [c.name for c in back] == ["a.png", "b.jpg"]
    assert all(b.allclose(c, rtol=0, atol=1e-12) for b, c in zip(back, cams, strict=True))


def test_sections_round_trip_is_byte_reproducible(tmp_path, rng, frame):
    sections = _sections(rng, frame)
    cap = rng.normal(size=(9, 3))
    artifacts.write_sections(tmp_path, sections, cap, 0.5)
    first = sha256_file(tmp_path / artifacts.SECTIONS)
    artifacts.write_sections(tmp_path, sections, cap, 0.5)
    assert sha256_file(tmp_path / artifacts.SECTIONS) == first
    back, cap_back, spacing = artifacts.read_sections(tmp_path)
    assert spacing == 0.5
    np.testing.assert_array_equal(cap_back, cap)
    assert len(back) == len(sections)
    for a, b in zip(back, sections, strict=True):
        assert (a.height, a.section_id) == (b.height, b.section_id)
        np.testing.assert_array_equal(a.points, b.points)
        np.testing.assert_array_equal(a.origin, b.origin)
        np.testing.assert_array_equal(a.frame, frame)
        np.testing.assert_array_equal(a.source_index, b.source_index)
    np.testing.assert_array_equal(artifacts.section_heights(tmp_path), [0.0, 0.5, 1.0])


def test_curves_round_trip_with_several_loops(tmp_path, rng, frame):
    sections = _sections(rng, frame)
    # section 1 holds two loops (a list), the others one ring each
    rings = [rng.normal(size=(6, 3)), [rng.normal(size=(12, 3)), rng.normal(size=(5, 3))],
             rng.normal(size=(6, 3))]
    assert artifacts.write_curves(tmp_path, rings, sections, 0.002) == (4, 29)
    back, planes, noise = artifacts.read_curves(tmp_path)
    assert noise == 0.002
    assert [len(item) for item in back] == [1, 2, 1]
    np.testing.assert_array_equal(back[0][0], rings[0])
    np.testing.assert_array_equal(back[1][1], rings[1][1])
    assert [p.height for p in planes] == [s.height for s in sections]
    np.testing.assert_array_equal(planes[0].frame, frame)


def test_curves_store_how_each_ring_was_fitted_and_old_files_still_read(tmp_path, rng,
                                                                       frame):
    from surface.catmull_rom import RingFit
    from surface.section_errors import ring_precision

    sections = _sections(rng, frame)
    rings = [rng.normal(size=(6, 3)), [rng.normal(size=(12, 3)), rng.normal(size=(5, 3))],
             rng.normal(size=(6, 3))]
    fits = [RingFit(8.0, 10, 80, 0.002, 0.0003),
            [RingFit(16.0, 12, 192, 0.003, 0.0004), RingFit(1.0, 5, 5, 0.001, 0.001)],
            RingFit(4.0, 20, 80, 0.002, 0.0006)]
    artifacts.write_curves(tmp_path, rings, sections, 0.002, fits)
    back = artifacts.read_curve_fits(tmp_path)
    np.testing.assert_array_equal(back["smoothing"], [8.0, 16.0, 1.0, 4.0])  # ring order
    np.testing.assert_array_equal(back["controls"], [10, 12, 5, 20])
    np.testing.assert_array_equal(back["data_points"], [80, 192, 5, 80])
    np.testing.assert_array_equal(back["loop_noise"], [0.002, 0.003, 0.001, 0.002])
    np.testing.assert_array_equal(back["precision"], [0.0003, 0.0004, 0.001, 0.0006])
    assert back["ring_precision"] == ring_precision(fits) == 0.0005  # median of four
    _, _, noise = artifacts.read_curves(tmp_path)
    assert noise == 0.002
    with pytest.raises(ValueError, match="3 records for 4 rings"):
        artifacts.write_curves(tmp_path / "x", rings, sections, 0.002, fits[:2])
    # a curves.npz of an older workspace (no fits) reads as before, with no fits
    (tmp_path / "old").mkdir()
    artifacts.write_curves(tmp_path / "old", rings, sections, 0.002)
    assert artifacts.read_curve_fits(tmp_path / "old") is None
    assert [len(item) for item in artifacts.read_curves(tmp_path / "old")[0]] == [1, 2, 1]


def test_stitched_and_smooth_round_trip(tmp_path):
    import open3d as o3d

    from pipeline.mesh_io import read_mesh
    from surface import bezier

    sphere = o3d.geometry.TriangleMesh.create_icosahedron()  # closed, outward, 20 faces
    vertices = np.asarray(sphere.vertices, np.float64)
    triangles = np.asarray(sphere.triangles, np.int64)
    notes = {"closed": True, "messages": ["a", "b"], "flips": 3}
    artifacts.write_stitched(tmp_path, vertices, triangles, notes)
    v, t, back = artifacts.read_stitched(tmp_path)
    np.testing.assert_array_equal(v, vertices)
    np.testing.assert_array_equal(t, triangles)
    assert back == notes
    surface = bezier.control_net(vertices, triangles)
    tv, tt, tn = bezier.tessellate(surface, level=1)
    artifacts.write_smooth(tmp_path, tv, tt, tn, surface)
    net = artifacts.read_control_net(tmp_path)
    np.testing.assert_array_equal(net["control_points"], surface.control_points)
    np.testing.assert_array_equal(net["domain_triangles"], surface.domain_mesh[1])
    np.testing.assert_array_equal(read_mesh(tmp_path / artifacts.SURFACE)[1], tt)
    # unit normals are stored as float32: within half an ulp of 1, 6e-8
    np.testing.assert_allclose(artifacts.read_ply_normals(tmp_path / artifacts.SURFACE), tn,
                               rtol=0, atol=1e-7)
