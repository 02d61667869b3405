"""Views of an image folder that cannot be used are left out with one line each."""

from __future__ import annotations

import logging
import os

import cv2
import numpy as np
import pytest

from matching.cameras import Camera, write_cameras_yml
from pipeline.errors import InputError
from pipeline.inputs import load_folder, read_image, read_pair

K = np.array([[80.0, 0, 31.5], [0, 80, 31.5], [0, 0, 1]])


def _folder(tmp_path, names):
    """Textured 64x64 views with their cameras in ``cameras.yml``."""
    folder = tmp_path / "views"
    folder.mkdir()
    rng = np.random.default_rng(0)
    for name in names:
        cv2.imwrite(str(folder / name), rng.integers(0, 255, (64, 64), np.uint8))
    cams = [Camera(K, np.zeros(0), np.eye(3), np.array([0.1 * k, 0, 2]), 64, 64, name)
            for k, name in enumerate(names)]
    return folder, cams


def _nan_tiff(path):
    image = np.random.default_rng(1).random((64, 64)).astype(np.float32)
    image[10:12, 20:30] = np.nan
    assert cv2.imwrite(str(path), image)


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs here")
def test_fifo_device_and_nan_views_are_left_out_with_a_line(tmp_path, caplog):
    """A FIFO and a link to /dev/zero named as images were passed over without a word,
    and a float TIFF with NaN pixels was used (numpy's RuntimeWarning on stderr): each
    is now left out with its one-line reason, like an unreadable view."""
    folder, cams = _folder(tmp_path, ["a.png", "b.png", "c.png"])
    os.mkfifo(folder / "d.png")
    os.symlink("/dev/zero", folder / "e.png")
    _nan_tiff(folder / "f.tif")
    cams += [Camera(K, np.zeros(0), np.eye(3), np.array([0.5, 0, 2]), 64, 64, n)
             for n in ("d.png", "e.png", "f.tif")]
    write_cameras_yml(folder / "cameras.yml", cams)
    import warnings

    with caplog.at_level(logging.WARNING), warnings.catch_warnings():
        warnings.simplefilter("error")
        loaded = load_folder(folder)
    assert loaded["names"] == ["a.png", "b.png", "c.png"]
    reasons = {skip["view"]: skip["reason"] for skip in loaded["skipped_views"]}
    assert set(reasons) == {"d.png", "e.png", "f.tif"}
    assert "FIFO" in reasons["d.png"] or "fifo" in reasons["d.png"].lower()
    assert "regular" in reasons["e.png"]
    assert "NaN" in reasons["f.tif"] and str(folder / "f.tif") in reasons["f.tif"]
    said = [r.getMessage() for r in caplog.records if "left out" in r.getMessage()]
    assert len(said) == 3 and all("\n" not in s for s in said)


def test_nan_tiff_is_refused_by_the_reader_and_the_pair(tmp_path):
    _nan_tiff(tmp_path / "l.tif")
    cv2.imwrite(str(tmp_path / "r.png"), np.random.default_rng(2).integers(0, 255, (64, 64),
                                                                         np.uint8))
    with pytest.raises(InputError, match=r"l\.tif: 20 of 4096 pixel values are NaN/inf"):
        read_image(tmp_path / "l.tif")
    with pytest.raises(InputError, match="NaN"):
        read_pair(tmp_path / "l.tif", tmp_path / "r.png")


def test_camera_file_error_names_the_file_once(tmp_path):
    """A bad cameras.yml: its path once in the one-line error (it was printed twice)."""
    folder, cams = _folder(tmp_path, ["a.png", "b.png"])
    (folder / "cameras.yml").write_text("%YAML:1.0\n---\nn_views: 2\nview_00: 3\n")
    with pytest.raises(InputError) as info:
        load_folder(folder)
    message = str(info.value)
    assert message.count(str(folder / "cameras.yml")) == 1 and "\n" not in message
