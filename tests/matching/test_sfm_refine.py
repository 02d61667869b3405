"""LSM re-measured SfM tie points (matching.sfm_refine) on ray-cast rings, true cameras."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from matching.sfm import align_to_reference, run_sfm
from testkit.images import exif_jpeg
from tests.matching.test_sfm import make_scene, render, ring_cameras


def _pose_errors(result, truth):
    aligned, rms = align_to_reference(result, truth)
    by_name = {cam.name: cam for cam in truth}
    angles = [np.rad2deg(np.linalg.norm(cv2.Rodrigues(cam.R @ by_name[cam.name].R.T)[0]))
              for cam in aligned.cameras]
    return float(np.median(angles)), float(np.max(angles)), rms


@pytest.fixture(scope="module")
def rolled_ring(tmp_path_factory):
    """The 8-view ring of test_sfm, every other camera turned 180 degrees about its axis."""
    folder = tmp_path_factory.mktemp("sfm_refine_images")
    scene, cams = make_scene(), ring_cameras()
    flip = np.diag([-1.0, -1.0, 1.0])
    cams = [cam if i % 2 == 0 else type(cam)(cam.K, [], flip @ cam.R, flip @ cam.t, cam.width,
                                             cam.height, cam.name)
            for i, cam in enumerate(cams)]
    for cam in cams:
        cv2.imwrite(str(folder / cam.name), render(scene, cam))
    return folder, cams


def test_lsm_tie_points_sharpen_poses_on_a_rolled_ring(rolled_ring, tmp_path, capfd):
    """With the true K held, LSM tie points cut the rotation and centre errors by >= 3x.

    SIFT locates keypoints to ~0.2 px on these aliased renders; LSM on the same
    texture to a few hundredths, so the bundle adjustment's pose errors, which
    scale with the tie points' σ, shrink with them.  Views turned 180 degrees
    against their neighbours need the affine start from the geometry (an identity
    start would not converge).  Measured: rotations 0.115 / 0.219 degrees (median /
    max) -> 0.018 / 0.034, centre RMS 0.0051 -> 0.00051 (radius 4.5), mean
    reprojection error 0.18 -> 0.007 px: 6-10x, so the bound leaves >= 2x.
    """
    folder, truth = rolled_ring
    K = truth[0].K
    plain = run_sfm(folder, work_dir=tmp_path / "plain", num_threads=2, intrinsics=K,
                    refine="none")
    refined = run_sfm(folder, work_dir=tmp_path / "lsm", num_threads=2, intrinsics=K)
    assert len(plain.registered) == len(refined.registered) == len(truth)
    rep = refined.refinement
    med0, max0, rms0 = _pose_errors(plain, truth)
    med1, max1, rms1 = _pose_errors(refined, truth)
    assert rep["method"] == "lsm" and rep["share_accepted"] > 0.5
    assert refined.mean_reprojection_error_px < 0.5 * plain.mean_reprojection_error_px
    assert med1 < med0 / 3 and max1 < max0 / 3, (med0, max0, med1, max1)
    assert rms1 < rms0 / 3, (rms0, rms1)
    assert refined.report()["refinement"]["method"] == "lsm"
    assert plain.refinement == {}
    # bundle_adjust called on its own (as benchmarks/real.py does) says nothing on stderr
    import pycolmap

    from matching.sfm_refine import bundle_adjust

    capfd.readouterr()
    bundle_adjust(pycolmap.Reconstruction(str(tmp_path / "lsm" / "sparse_refined")),
                  refine_intrinsics=False)
    assert capfd.readouterr().err == ""


def test_refine_option_checked(rolled_ring):
    with pytest.raises(ValueError, match="refine must be one of"):
        run_sfm(rolled_ring[0], refine="gauss")


def test_quiet_colmap_drops_glog_lines_keeps_the_rest(capfd):
    """COLMAP/Ceres lines written to fd 2 inside the block are dropped (with a coloured
    line's reset code); anything else written there comes back after it."""
    import os

    from matching.sfm import _quiet_colmap

    with _quiet_colmap():
        os.write(2, b"I20261201 23:39:42.616234 1 bundle_adjustment.cc:46] === Global ===\n")
        os.write(2, b"\x1b[0;33mW20261201 23:37:03.558940 1 lm.cc:123] Linear solver failure.\n")
        os.write(2, b"\x1b[mplain line\n")
    assert capfd.readouterr().err == "plain line\n"


def test_tie_point_images_are_in_colmaps_pixel_frame(tmp_path):
    """An EXIF-oriented JPEG: COLMAP reads the pixels as stored (64x48), so SfM is given
    an upright copy (48 wide, 64 high), and the LSM re-measurement reads that copy in
    the frame of COLMAP's keypoints: the image as the user sees it."""
    import pycolmap

    from matching.sfm import _image_sizes, _stage_upright
    from matching.sfm_refine import _prepare

    image = np.zeros((48, 64, 3), np.uint8)
    image[:10, :20] = 200
    (tmp_path / "portrait.jpg").write_bytes(exif_jpeg(image, 6))
    bitmap = pycolmap.Bitmap.read(str(tmp_path / "portrait.jpg"), False)
    assert (bitmap.width, bitmap.height) == (64, 48)
    sizes, restage = _image_sizes(tmp_path, ["portrait.jpg"])
    assert sizes == {"portrait.jpg": (48, 64)} and restage == {"portrait.jpg"}
    work = tmp_path / "work"
    work.mkdir()
    staged, original = _stage_upright(tmp_path, ["portrait.jpg"], {}, work, restage)
    assert original == {"portrait.jpg.png": "portrait.jpg"}
    bitmap = pycolmap.Bitmap.read(str(staged / "portrait.jpg.png"), False)
    assert (bitmap.width, bitmap.height) == (48, 64)
    prepared = _prepare(staged, {0: "portrait.jpg.png"})[0]
    assert prepared.raw.shape == (64, 48)
    assert float(prepared.raw[:20, 38:].mean()) > 150   # shown top right, as a viewer does
