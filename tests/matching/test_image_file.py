"""The one image decoder: any file name, EXIF orientation applied, one depth rule."""

from __future__ import annotations

import os
import struct
import subprocess
import sys
import textwrap
from pathlib import Path

import cv2
import numpy as np
import pytest

from matching.image_file import decode_image, exif_orientation, imread, to_uint8
from testkit.images import exif_jpeg
from testkit.images import stored_for as _stored_for

ROOT = Path(__file__).resolve().parents[2]
SCENE = ROOT / "fixtures" / "scenes" / "vase_ring_small.toml"


def _textured(shape=(40, 56, 3), seed=0) -> np.ndarray:
    return (np.random.default_rng(seed).random(shape) * 255).astype(np.uint8)


@pytest.mark.parametrize("orientation", range(1, 9))
def test_orientation_is_opencvs_own(orientation):
    """Each of the 8 EXIF orientations turns the image exactly as OpenCV's own EXIF
    handling does (``IMREAD_COLOR`` applies it; ``IMREAD_UNCHANGED``, which photosurf
    reads with to keep 16-bit and alpha, does not)."""
    data = exif_jpeg(_textured(), orientation)
    assert exif_orientation(data) == orientation
    ours = decode_image(data, cv2.IMREAD_COLOR)
    opencv = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    assert ours.shape == opencv.shape and np.array_equal(ours, opencv)
    unchanged = decode_image(data)  # the default flag: turned all the same
    assert np.array_equal(unchanged, ours)


def test_png_exif_chunk_and_no_tag():
    """A PNG's eXIf chunk (orientation 8: shown a quarter turn counter-clockwise) is
    applied; a file without EXIF, or with a damaged one, is used as stored."""
    image = _textured((36, 50))
    ok, png = cv2.imencode(".png", image)
    png = png.tobytes()
    tiff = (b"MM\x00*" + struct.pack(">I", 8) + struct.pack(">H", 1)
            + struct.pack(">HHIHH", 0x0112, 3, 1, 8, 0) + struct.pack(">I", 0))
    chunk = struct.pack(">I", len(tiff)) + b"eXIf" + tiff + b"\x00\x00\x00\x00"  # CRC unchecked
    tagged = png[:33] + chunk + png[33:]   # after the 8-byte signature and the IHDR chunk
    assert exif_orientation(tagged) == 8
    assert np.array_equal(decode_image(tagged), np.rot90(image, 1))
    assert exif_orientation(png) == 1 and np.array_equal(decode_image(png), image)
    assert exif_orientation(b"\xff\xd8\xff\xe1\x00\x10Exif\x00\x00II*\x00\xff\xff") == 1
    assert decode_image(b"") is None and decode_image(b"not an image") is None


@pytest.fixture(scope="module")
def tagged_ring(tmp_path_factory):
    """Eight consecutive views (15 degrees apart) of the small rendered ring as upright
    PNGs, and JPEG copies stored sideways: each under another EXIF orientation (every
    value 1..8), the pixels turned so that a viewer shows the upright image; both
    folders with the upright cameras in ``cameras.yml``."""
    from matching.cameras import write_cameras_yml
    from pipeline.scenes import build_scene, load_recipe, render_view

    if not SCENE.is_file():
        pytest.skip(f"{SCENE} absent")
    scene = build_scene(load_recipe(SCENE))
    root = tmp_path_factory.mktemp("tagged_ring")
    upright_dir, tagged_dir = root / "upright", root / "tagged"
    upright_dir.mkdir()
    tagged_dir.mkdir()
    upright_cams, tagged_cams = [], []
    for v in range(8):
        image = render_view(scene, v)[0]
        cv2.imwrite(str(upright_dir / f"view_{v:02d}.png"), image)
        orientation = 1 + (3 * v + 5) % 8
        (tagged_dir / f"view_{v:02d}.jpg").write_bytes(
            exif_jpeg(_stored_for(image, orientation), orientation))
        cam = scene.cameras[v]
        upright_cams.append(cam.__class__(cam.K, cam.dist, cam.R, cam.t, cam.width,
                                          cam.height, f"view_{v:02d}.png"))
        tagged_cams.append(cam.__class__(cam.K, cam.dist, cam.R, cam.t, cam.width,
                                         cam.height, f"view_{v:02d}.jpg"))
    write_cameras_yml(upright_dir / "cameras.yml", upright_cams)
    write_cameras_yml(tagged_dir / "cameras.yml", tagged_cams)
    return upright_dir, tagged_dir


def test_exif_tagged_copies_read_as_the_upright_images(tagged_ring):
    """The one reader returns each sideways-stored JPEG as the upright view: equal to the
    upright pixels up to JPEG loss; the folder loads with the upright sizes, so the
    upright cameras fit every view and none is left out."""
    from pipeline.inputs import load_folder, read_image

    upright_dir, tagged_dir = tagged_ring
    for v in range(8):
        upright = read_image(upright_dir / f"view_{v:02d}.png")
        shown = read_image(tagged_dir / f"view_{v:02d}.jpg")
        assert shown.shape == upright.shape
        # the loss of JPEG quality 95 on the upright pixels themselves bounds it (the
        # 8x8 blocks fall elsewhere on a turned image: twice that, plus rounding)
        ok, plain = cv2.imencode(".jpg", upright, [cv2.IMWRITE_JPEG_QUALITY, 95])
        loss = np.abs(cv2.imdecode(plain, cv2.IMREAD_UNCHANGED).astype(float) - upright).mean()
        assert np.abs(shown.astype(float) - upright).mean() <= 2 * loss + 0.5
    loaded = load_folder(tagged_dir)
    assert loaded["skipped_views"] == [] and len(loaded["names"]) == 8
    for cam, shape in zip(loaded["cameras"], loaded["images"].shapes, strict=True):
        assert cam.size == (shape[1], shape[0])


def test_sfm_on_exif_tagged_copies_gives_the_upright_cameras(tagged_ring):
    """SfM on the sideways-stored JPEGs finds the cameras of the upright images: the
    views registered in the upright frame (sizes), their rotations and centres after a
    similarity alignment as close to the true upright cameras as SfM on the upright PNGs
    gets.  Measured on this ring: upright PNGs 0.42-0.83 degrees, centres <= 0.6 % of the
    ring's radius; the tagged JPEGs 0.28-0.56 degrees (seed 0), 1.3-1.8 degrees with 6 of
    8 registered (seed 1); a camera left in the stored frame would be 90 degrees off and
    of the transposed size."""
    from matching.cameras import read_cameras
    from matching.sfm import align_to_reference, run_sfm

    _, tagged_dir = tagged_ring
    truth = read_cameras(tagged_dir / "cameras.yml")
    result = run_sfm(tagged_dir, num_threads=1, seed=0)  # (cameras.yml: not an image)
    assert len(result.registered) >= 6
    by_name = {c.name: c for c in truth}
    for cam in result.cameras:
        assert cam.size == by_name[cam.name].size
    aligned, _ = align_to_reference(result, truth)
    centres = np.array([c.center for c in truth])
    radius = float(np.linalg.norm(centres - centres.mean(axis=0), axis=1).mean())
    for cam in aligned.cameras:
        true = by_name[cam.name]
        angle = np.degrees(np.arccos(np.clip((np.trace(true.R.T @ cam.R) - 1) / 2, -1, 1)))
        assert angle < 2.0
        assert np.linalg.norm(cam.center - true.center) < 0.01 * radius


def test_depth_rule_and_nan_pixels():
    """16-bit and float images go onto 0..255 by their own range; NaN pixels are refused
    by name, without numpy's RuntimeWarning."""
    import warnings

    wide = np.array([[1000, 2000], [3000, 5000]], np.uint16)
    assert to_uint8(wide).tolist() == [[0, 64], [128, 255]]
    floats = np.array([[0.0, np.nan], [1.0, 2.0]], np.float32)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ValueError, match=r"view\.tif: 1 of 4 pixel values are NaN"):
            to_uint8(floats, "view.tif")


_ANY_NAME_SCRIPT = textwrap.dedent("""
    import os, sys, tempfile
    import numpy as np, cv2
    from hypothesis import given, settings, strategies as st, HealthCheck
    from pipeline.errors import InputError
    from pipeline.inputs import read_image
    from matching.cameras import read_cameras, write_cameras_yml, write_rig, Camera, StereoRig
    from matching.image_file import imread
    from pipeline.inputs import read_rig_for

    ok, png = cv2.imencode(".png", np.random.default_rng(0).integers(0, 255, (40, 40), np.uint8))
    folder = tempfile.mkdtemp()
    cam = Camera(np.array([[50.0, 0, 20], [0, 50, 20], [0, 0, 1]]), np.zeros(0), np.eye(3),
                 np.array([0.0, 0, 1]), 40, 40, "a.png")
    right = Camera(cam.K, cam.dist, cam.R, np.array([-0.1, 0, 1]), 40, 40, "b.png")
    names = st.binary(min_size=1, max_size=120).filter(
        lambda b: b"/" not in b and b"\\0" not in b and b not in (b".", b".."))

    @settings(max_examples=40, deadline=None, derandomize=True,
              suppress_health_check=list(HealthCheck))
    @given(names)
    def check(raw):
        path = os.path.join(folder, os.fsdecode(raw + b".png"))
        with open(path, "wb") as fh:
            fh.write(png.tobytes())
        image = read_image(path)
        assert image.shape == (40, 40), image.shape
        assert imread(path).shape == (40, 40)
        os.remove(path)
        missing = os.path.join(folder, os.fsdecode(raw + b"_missing.png"))
        try:
            read_image(missing)
        except FileNotFoundError:
            pass
        yml = os.path.join(folder, os.fsdecode(raw + b".yml"))
        write_cameras_yml(yml, [cam])
        assert read_cameras(yml)[0].allclose(cam)
        os.remove(yml)
        write_rig(yml, StereoRig(cam, right))
        assert read_rig_for(yml).baseline > 0
        os.remove(yml)

    check()
    print("ok")
""")


def test_any_file_name_never_crashes_the_reader(tmp_path):
    """File names of arbitrary bytes (not UTF-8 included: OpenCV's ``imread`` and
    ``FileStorage`` crashed the process on them): the one image reader, the camera file
    reader and writer and the rig check work, in a child process so a crash is a
    failure here."""
    pytest.importorskip("hypothesis")
    env = dict(os.environ, PYTHONPATH=str(ROOT), PYTHONWARNINGS="error::RuntimeWarning")
    run = subprocess.run([sys.executable, "-c", _ANY_NAME_SCRIPT], cwd=tmp_path, env=env,
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0 and run.stdout.strip().endswith("ok"), (
        f"exit {run.returncode}: {run.stderr[-2000:]}")


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs here")
def test_special_files_are_not_read(tmp_path):
    """A FIFO or a device is never opened for reading (it would block or never end):
    ``imread`` says it cannot read it, as for a missing file or a folder."""
    os.mkfifo(tmp_path / "pipe.png")
    for path in (tmp_path / "pipe.png", Path("/dev/zero"), tmp_path / "none.png", tmp_path):
        assert imread(path) is None
