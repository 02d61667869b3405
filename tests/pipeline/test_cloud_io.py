"""Round trips and error cases of pipeline.cloud_io (PLY with sigma, text, NPZ)."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest

from pipeline.cloud_io import read_cloud, read_ply, write_cloud, write_ply
from pipeline.errors import InputError


@pytest.fixture
def cloud():
    rng = np.random.default_rng(0)
    points = rng.normal(size=(500, 3))
    colours = rng.integers(0, 256, (500, 3)).astype(np.uint8)
    sigma = rng.uniform(1e-4, 1e-2, 500)
    return points, colours, sigma


def test_ply_round_trip_exact(tmp_path, cloud):
    points, colours, sigma = cloud
    path = write_ply(tmp_path / "c.ply", points, colours, sigma)
    back = read_cloud(path)
    np.testing.assert_array_equal(back.points, points)  # float64 stored: bit-exact
    np.testing.assert_array_equal(back.colours, colours)
    np.testing.assert_array_equal(back.sigma, sigma.astype(np.float32))  # float32 property
    header = path.read_bytes()[:400].decode("ascii", "replace")
    assert "property float sigma" in header and "binary_little_endian" in header
    assert [p.name for p in tmp_path.iterdir()] == ["c.ply"]  # no temp file left


def test_ply_without_colours_or_sigma(tmp_path, cloud):
    points = cloud[0]
    back = read_cloud(write_ply(tmp_path / "p.ply", points))
    np.testing.assert_array_equal(back.points, points)
    assert back.colours is None and back.sigma is None


def test_open3d_reads_ours_and_we_read_open3ds(tmp_path, cloud):
    points, colours, sigma = cloud
    ours = write_ply(tmp_path / "ours.ply", points, colours, sigma)
    pcd = o3d.io.read_point_cloud(str(ours))
    np.testing.assert_allclose(np.asarray(pcd.points), points)
    np.testing.assert_allclose(np.asarray(pcd.colors), colours / 255.0)
    theirs = tmp_path / "theirs.ply"
    o3d.io.write_point_cloud(str(theirs), pcd)  # binary, double precision
    back = read_cloud(theirs)
    np.testing.assert_array_equal(back.points, points)
    np.testing.assert_array_equal(back.colours, colours)
    assert back.sigma is None
    assert back.colors is back.colours


@pytest.mark.parametrize("suffix", [".xyz", ".csv", ".txt"])
def test_text_round_trip(tmp_path, cloud, suffix):
    points, colours, sigma = cloud
    path = write_cloud(tmp_path / f"c{suffix}", points, colours, sigma)
    back = read_cloud(path)
    np.testing.assert_allclose(back.points, points, rtol=1e-9)
    # extra columns: red green blue sigma
    np.testing.assert_allclose(back.extra[:, :3], colours)
    np.testing.assert_allclose(back.extra[:, 3], sigma, rtol=1e-9)


def test_text_reader_header_comments_and_commas(tmp_path):
    path = tmp_path / "p.csv"
    path.write_text("x,y,z,intensity\n# a comment\n1,2,3,0.5\n4, 5, 6, 0.25  # end\n")
    back = read_cloud(path)
    np.testing.assert_array_equal(back.points, [[1, 2, 3], [4, 5, 6]])
    np.testing.assert_array_equal(back.extra, [[0.5], [0.25]])


def test_npz_round_trip(tmp_path, cloud):
    points, colours, sigma = cloud
    back = read_cloud(write_cloud(tmp_path / "c.npz", points, colours, sigma))
    np.testing.assert_array_equal(back.points, points)
    np.testing.assert_array_equal(back.colours, colours)
    np.testing.assert_array_equal(back.sigma, sigma)


def test_errors(tmp_path, cloud):
    with pytest.raises(FileNotFoundError, match="no such file"):
        read_cloud(tmp_path / "missing.ply")
    with pytest.raises(InputError, match="unknown point-cloud format"):
        read_cloud(_touch(tmp_path / "c.obj"))
    bad = tmp_path / "bad.xyz"
    bad.write_text("1 2 3\n4 5 six\n")
    with pytest.raises(InputError, match=r"bad.xyz:2: not numbers"):
        read_cloud(bad)
    short = tmp_path / "short.xyz"
    short.write_text("1 2\n3 4\n")
    with pytest.raises(InputError, match="x y z"):
        read_cloud(short)
    path = write_ply(tmp_path / "t.ply", *cloud)
    path.write_bytes(path.read_bytes()[:-100])
    with pytest.raises(InputError, match="truncated PLY"):
        read_ply(path)
    (tmp_path / "junk.ply").write_bytes(b"not a ply at all")
    with pytest.raises(InputError, match="not a PLY file"):
        read_cloud(tmp_path / "junk.ply")
    np.savez(tmp_path / "nopoints.npz", xyz=np.zeros((3, 3)))
    with pytest.raises(InputError, match="no 'points' array"):
        read_cloud(tmp_path / "nopoints.npz")


def test_failed_write_leaves_nothing(tmp_path, cloud):
    points, colours, _ = cloud
    with pytest.raises(ValueError, match=r"sigma must have shape \(500,\)"):
        write_ply(tmp_path / "x.ply", points, colours, np.ones(3))
    with pytest.raises(ValueError, match=r"points must have shape \(N, 3\)"):
        write_cloud(tmp_path / "x.npz", points[:, :2])
    assert list(tmp_path.iterdir()) == []


def _touch(path):
    path.write_text("")
    return path
