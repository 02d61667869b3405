"""``photosurf calibrate`` end to end on rendered chessboard pairs."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from matching.cameras import read_rig
from pipeline.cli import main
from tests.matching.test_calibrate import PATTERN, SQUARE, make_rig, render_pairs


@pytest.fixture(scope="module")
def board_folder(tmp_path_factory):
    folder = tmp_path_factory.mktemp("calib")
    rig = make_rig()
    for i, (left, right) in enumerate(render_pairs(rig, n=5, seed=3)):
        cv2.imwrite(str(folder / f"left_{i:02d}.png"), left)
        cv2.imwrite(str(folder / f"right_{i:02d}.png"), right)
    return folder, rig


def test_calibrate_writes_rig(board_folder, tmp_path, capsys):
    folder, rig = board_folder
    out = tmp_path / "rig.yml"
    status = main(["calibrate", str(folder / "left_*.png"), str(folder / "right_*.png"),
                   "--pattern", f"{PATTERN[0]}x{PATTERN[1]}", "--square", str(SQUARE),
                   "--out", str(out)])
    assert status == 0
    printed = capsys.readouterr().out
    assert "RMS reprojection error" in printed and "baseline" in printed
    got = read_rig(out)
    assert got.baseline == pytest.approx(rig.baseline, rel=0.005)
    np.testing.assert_allclose(got.left.K[0, 0], rig.left.K[0, 0], rtol=0.005)
    assert "rms_px" in out.read_text()


def test_calibrate_bad_input(board_folder, tmp_path, capsys):
    folder, _ = board_folder
    out = tmp_path / "rig.yml"
    # counts differ
    status = main(["calibrate", str(folder / "left_*.png"), str(folder / "right_0[0-2].png"),
                   "--square", str(SQUARE), "--out", str(out)])
    assert status == 2 and "must pair up" in capsys.readouterr().err
    # wrong pattern: no board anywhere
    status = main(["calibrate", str(folder / "left_0[0-2].png"), str(folder / "right_0[0-2].png"),
                   "--pattern", "7x7", "--square", str(SQUARE), "--out", str(out)])
    assert status == 2 and "no 7x7 chessboard found" in capsys.readouterr().err
    # no match for the glob
    status = main(["calibrate", str(tmp_path / "nothing_*.png"), str(folder / "right_*.png"),
                   "--square", str(SQUARE), "--out", str(out)])
    assert status == 2 and "matches no file" in capsys.readouterr().err
    assert not out.exists() and not list(tmp_path.glob(".rig*"))


def test_every_image_reader_reads_the_upright_image(tmp_path):
    """A phone's portrait JPEG (EXIF Orientation 6, "turn 90 degrees clockwise to view"):
    calibration reads it as the matching commands do, as the user sees it (a rig
    calibrated in another frame would not fit the views it is used on)."""
    import numpy as np

    from pipeline.cmd_calibrate import _read_gray
    from pipeline.inputs import read_image
    from tests.matching.test_sfm_refine import exif_jpeg

    image = np.zeros((48, 64, 3), np.uint8)
    image[:10, :20] = 200
    path = tmp_path / "portrait.jpg"
    path.write_bytes(exif_jpeg(image, 6))
    assert _read_gray(path).shape == (64, 48)
    assert read_image(path).shape == (64, 48, 3)
    # the stored top-left corner is shown top right after the clockwise quarter turn
    assert float(_read_gray(path)[:20, 38:].mean()) > 150
    assert float(read_image(path)[:20, 38:].mean()) > 150
