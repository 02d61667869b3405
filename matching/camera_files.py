"""Camera files: photosurf's cameras.yml, OpenCV stereo calibration, COLMAP, projection matrices.

Readers and writers are symmetric and round-trip tested; every reader returns
:class:`matching.camera_model.Camera` objects (the model and its equations are there).

* **cameras.yml** (OpenCV FileStorage, YAML or XML by suffix), photosurf's own::

      format: "photosurf-cameras"   version: 1   n_views: N
      view_00: {name, width, height, K (3x3), dist (1xk), R (3x3), t (3x1)}
      ...
      rig_left: 0  rig_right: 1  rig_R (3x3)  rig_T (3x1)     # stereo pairs only
      rms_px, ...                                             # optional scalars

* **OpenCV stereo-calibration sample files**: ``intrinsics.yml`` (M1 D1 M2 D2)
  and ``extrinsics.yml`` (R T R1 R2 P1 P2 Q); the left camera is put at the
  world origin.  They carry no image size, so it is given or read from an image.
* **COLMAP text model** (``cameras.txt``, ``images.txt``, ``points3D.txt``)
  [1]_.  COLMAP puts the origin at the *corner* of the top-left pixel, OpenCV
  at its *centre*: the principal point is shifted by +0.5 px on writing and
  −0.5 px on reading, so that both programs project a point to the same pixel.
  Binary models are read through pycolmap.
* **Projection-matrix text files** (``name k11..k33 r11..r33 t1 t2 t3`` per
  line, optionally preceded by the number of lines, as the Middlebury
  multi-view sets [2]_ ship them): reader only.

:func:`read_cameras` reads any of them, by content.

References
----------
.. [1] J. L. Schönberger and J.-M. Frahm, "Structure-from-Motion Revisited",
   CVPR (2016); https://colmap.github.io/format.html
.. [2] S. M. Seitz, B. Curless, J. Diebel, D. Scharstein and R. Szeliski,
   "A Comparison and Evaluation of Multi-View Stereo Reconstruction
   Algorithms", CVPR (2006).
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path

import cv2
import numpy as np

from matching.camera_model import Camera, StereoRig, quaternion_to_rotation, rotation_to_quaternion
from matching.image_file import imread
from matching.validate import TOL, check_shape

__all__ = [
    "write_cameras_yml",
    "read_cameras_yml",
    "write_rig",
    "read_rig",
    "read_stereo_calibration",
    "write_colmap_text",
    "read_colmap_text",
    "read_colmap",
    "cameras_from_pycolmap",
    "read_projection_txt",
    "read_cameras",
]

_FORMAT_TAG = "photosurf-cameras"


# -------------------------------------------------------------- FileStorage helpers
def _check_exists(path: Path) -> Path:
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file")
    if path.is_dir():
        raise IsADirectoryError(f"{path}: is a folder, expected a file")
    return path


def _open_fs(path: Path) -> cv2.FileStorage:
    """The file parsed from memory: OpenCV's own file functions take the name as UTF-8 and
    crash the process on a name that is not."""
    _check_exists(path)
    try:
        text = path.read_bytes().decode("utf-8")
    except UnicodeDecodeError:
        raise ValueError(f"{path}: not a readable OpenCV FileStorage file (not UTF-8 text)"
                         ) from None
    if not text.strip() or "\x00" in text:
        raise ValueError(f"{path}: not a readable OpenCV FileStorage file (empty or binary)")
    try:
        fs = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
    except (cv2.error, SystemError) as exc:  # SystemError: cv2's parser on malformed text
        reason = " ".join(str(getattr(exc, "err", None) or exc.__cause__ or exc).split())
        raise ValueError(f"{path}: not a readable OpenCV FileStorage file ({reason})") from None
    if not fs.isOpened():
        raise ValueError(f"{path}: not a readable OpenCV FileStorage file")
    root = fs.root()
    if not (root.isMap() or root.empty() or root.isNone()):  # e.g. a truncated file: a string
        fs.release()
        raise ValueError(f"{path}: not a readable OpenCV FileStorage file (no top-level map)")
    return fs


def _read_mat(node, path: Path, label: str, shape: tuple[int, ...] | None = None,
              optional: bool = False) -> np.ndarray | None:
    if node.empty() or node.isNone():
        if optional:
            return None
        raise ValueError(f"{path}: missing field {label}")
    try:
        if node.isSeq():
            mat = np.array([node.at(i).real() for i in range(node.size())], dtype=np.float64)
        elif node.isReal() or node.isInt():
            mat = np.array([node.real()])
        else:
            mat = node.mat()
            if mat is None:  # an empty opencv-matrix (rows or cols 0)
                mat = np.zeros(0)
    except (cv2.error, SystemError):  # a malformed opencv-matrix (no dt, short data ...)
        raise ValueError(f"{path}: field {label} is not a readable matrix") from None
    mat = np.asarray(mat, dtype=np.float64)
    if shape is not None:
        if mat.size != int(np.prod(shape)):
            raise ValueError(f"{path}: field {label} must have shape {shape}, got {mat.shape}")
        mat = mat.reshape(shape)
    if not np.all(np.isfinite(mat)):
        raise ValueError(f"{path}: field {label} contains NaN/inf")
    return mat


def _read_scalar(node, path: Path, label: str, optional: bool = False):
    if node.empty() or node.isNone():
        if optional:
            return None
        raise ValueError(f"{path}: missing field {label}")
    if node.isString():
        return node.string()
    return node.real()


def _read_int(node, path: Path, label: str) -> int:
    """An integer field; ``ValueError`` naming the file and field for anything else."""
    value = _read_scalar(node, path, label)
    if isinstance(value, str) or not np.isfinite(value) or value != int(value):
        raise ValueError(f"{path}: field {label} must be an integer, got {value!r}")
    return int(value)


def _has(fs: cv2.FileStorage, key: str) -> bool:
    node = fs.getNode(key)
    return not (node.empty() or node.isNone())


def _camera_error(path: Path, label: str, exc: ValueError) -> ValueError:
    return ValueError(f"{path}: {label}: {exc}")


def _unique_names(cameras: list[Camera], entries: list[str], path: Path) -> list[Camera]:
    """``cameras`` with repeated entries of one image dropped; two entries of one image
    that differ (pose, intrinsics or size) are refused, naming the image and both
    entries (``entries[i]`` says where camera ``i`` is in ``path``)."""
    first: dict[str, int] = {}
    keep = []
    for i, cam in enumerate(cameras):
        j = first.setdefault(cam.name, i)
        if j == i or not cam.name:
            keep.append(cam)
        elif not (cam.size == cameras[j].size and cam.allclose(cameras[j])):
            raise ValueError(f"{path}: image {cam.name} has two different cameras: "
                             f"{entries[j]} and {entries[i]}")
    return keep


# ------------------------------------------------------------------- cameras.yml
def write_cameras_yml(path: str | os.PathLike, cameras: Sequence[Camera] | None,
                      rig: StereoRig | None = None, extra: dict | None = None) -> None:
    """Write cameras (and optionally a stereo rig) to an OpenCV FileStorage file.

    Parameters
    ----------
    path : path
        ``.yml`` / ``.yaml`` / ``.xml`` / ``.json``: OpenCV picks the format by suffix.
    cameras : sequence of Camera, or None
        The views.  With ``rig`` and no cameras, the rig's two cameras are written.
    rig : StereoRig, optional
        Recorded as ``rig_left``, ``rig_right`` (view indices, found among
        ``cameras`` by identity or equality), ``rig_R``, ``rig_T``.
    extra : dict of str -> float | int | str, optional
        Extra scalars (e.g. ``rms_px``) written at the top level.

    Notes
    -----
    The write is not atomic; wrap it in ``pipeline.atomic.atomic_file``.
    """
    path = Path(path)
    cameras = list(cameras) if cameras is not None else []
    if rig is not None and not cameras:
        cameras = [rig.left, rig.right]
    if not cameras:
        raise ValueError(f"{path}: no cameras to write")
    for i, cam in enumerate(cameras):
        if not isinstance(cam, Camera):
            raise ValueError(f"cameras[{i}] must be a Camera, got {type(cam).__name__}")
    rig_index = None
    if rig is not None:
        rig_index = (_find_camera(cameras, rig.left, "rig.left"),
                     _find_camera(cameras, rig.right, "rig.right"))
    # written in memory, then by Python (OpenCV's file functions crash on a name that is
    # not UTF-8); the format by suffix, as OpenCV picks it
    fmt = {".xml": cv2.FILE_STORAGE_FORMAT_XML, ".json": cv2.FILE_STORAGE_FORMAT_JSON}.get(
        path.suffix.lower(), cv2.FILE_STORAGE_FORMAT_YAML)
    fs = cv2.FileStorage("", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY | fmt)
    if not fs.isOpened():
        raise ValueError(f"{path}: cannot open for writing")
    try:
        fs.write("format", _FORMAT_TAG)
        fs.write("version", 1)
        fs.write("n_views", len(cameras))
        for i, cam in enumerate(cameras):
            fs.startWriteStruct(f"view_{i:02d}", cv2.FileNode_MAP)
            fs.write("name", cam.name)
            fs.write("width", cam.width)
            fs.write("height", cam.height)
            fs.write("K", cam.K)
            fs.write("dist", cam.dist.reshape(1, -1))
            fs.write("R", cam.R)
            fs.write("t", cam.t.reshape(3, 1))
            fs.endWriteStruct()
        if rig is not None:
            fs.write("rig_left", rig_index[0])
            fs.write("rig_right", rig_index[1])
            fs.write("rig_R", rig.R)
            fs.write("rig_T", rig.T.reshape(3, 1))
        for key, value in (extra or {}).items():
            fs.write(str(key), value if isinstance(value, str) else float(value))
        text = fs.releaseAndGetString()
    finally:
        fs.release()
    path.write_text(text, encoding="utf-8")


def _find_camera(cameras: list[Camera], cam: Camera, label: str) -> int:
    for i, other in enumerate(cameras):
        if other is cam:
            return i
    for i, other in enumerate(cameras):
        if other.allclose(cam):
            return i
    raise ValueError(f"{label} is not among the cameras written")


def _read_view(fs: cv2.FileStorage, path: Path, key: str) -> Camera:
    node = fs.getNode(key)
    if node.empty() or node.isNone():
        raise ValueError(f"{path}: missing field {key}")
    if not node.isMap():
        raise ValueError(f"{path}: field {key} must be a map (name, width, height, K, dist, R, t)")
    label = lambda f: f"{key}.{f}"
    K = _read_mat(node.getNode("K"), path, label("K"), (3, 3))
    dist = _read_mat(node.getNode("dist"), path, label("dist"), optional=True)
    R = _read_mat(node.getNode("R"), path, label("R"), (3, 3))
    t = _read_mat(node.getNode("t"), path, label("t"), (3,))
    width = _read_int(node.getNode("width"), path, label("width"))
    height = _read_int(node.getNode("height"), path, label("height"))
    name = _read_scalar(node.getNode("name"), path, label("name"), optional=True) or ""
    try:
        return Camera(K, np.zeros(0) if dist is None else dist.reshape(-1), R, t,
                      int(width), int(height), str(name))
    except ValueError as exc:
        raise _camera_error(path, key, exc) from None


def read_cameras_yml(path: str | os.PathLike) -> list[Camera]:
    """Read the cameras written by :func:`write_cameras_yml`.

    Parameters
    ----------
    path : path to a ``cameras.yml`` / ``.xml``

    Returns
    -------
    list of Camera, in view order.

    Raises
    ------
    FileNotFoundError
        The file does not exist.
    ValueError
        Unreadable file, missing ``n_views`` or a view field, invalid camera
        (the message names the file and the field).
    """
    path = Path(path)
    fs = _open_fs(path)
    try:
        n_views = _read_scalar(fs.getNode("n_views"), path, "n_views")
        if isinstance(n_views, str) or not np.isfinite(n_views) or n_views < 1 or \
                int(n_views) != n_views:
            raise ValueError(f"{path}: n_views must be a positive integer, got {n_views!r}")
        keys = [f"view_{i:02d}" for i in range(int(n_views))]
        return _unique_names([_read_view(fs, path, key) for key in keys], keys, path)
    finally:
        fs.release()


def write_rig(path: str | os.PathLike, rig: StereoRig, extra: dict | None = None) -> None:
    """Write a stereo rig as a two-view ``cameras.yml`` (see :func:`write_cameras_yml`)."""
    write_cameras_yml(path, [rig.left, rig.right], rig=rig, extra=extra)


def _read_rig_yml(path: Path) -> StereoRig:
    cameras = read_cameras_yml(path)
    fs = _open_fs(path)
    try:
        if _has(fs, "rig_left"):
            i = _read_int(fs.getNode("rig_left"), path, "rig_left")
            j = _read_int(fs.getNode("rig_right"), path, "rig_right")
        elif len(cameras) == 2:
            i, j = 0, 1
        else:
            raise ValueError(f"{path}: {len(cameras)} views and no rig_left/rig_right: "
                             "which two form the stereo pair?")
    finally:
        fs.release()
    for label, index in (("rig_left", i), ("rig_right", j)):
        if not 0 <= index < len(cameras):
            raise ValueError(f"{path}: {label} = {index} is not a view index (n_views = "
                             f"{len(cameras)})")
    return StereoRig(cameras[i], cameras[j])


# --------------------------------------------- OpenCV stereo calibration sample files
def _image_size(image: str | os.PathLike) -> tuple[int, int]:
    """(width, height) of an image file as the user sees it (its EXIF orientation applied)."""
    image = Path(image)
    _check_exists(image)
    array = imread(image)
    if array is None:
        raise ValueError(f"{image}: not a readable image")
    return int(array.shape[1]), int(array.shape[0])


def read_stereo_calibration(intrinsics: str | os.PathLike, extrinsics: str | os.PathLike,
                            width: int | None = None, height: int | None = None,
                            image: str | os.PathLike | None = None) -> StereoRig:
    """Read OpenCV's stereo-calibration sample output into a rig.

    Parameters
    ----------
    intrinsics : path
        ``intrinsics.yml`` with ``M1 D1 M2 D2`` (camera matrices, distortion).
    extrinsics : path
        ``extrinsics.yml`` with ``R T`` (``x_r = R x_l + T``); ``R1 R2 P1 P2 Q``
        (rectification) are ignored: they follow from the rest.  May be the
        same file as ``intrinsics``.
    width, height : int, optional
        Image size in pixels.  The files do not store it.
    image : path, optional
        An image of the pair, read for its size when width/height are not given.

    Returns
    -------
    StereoRig with the left camera at the world origin.
    """
    intrinsics, extrinsics = Path(intrinsics), Path(extrinsics)
    if width is None or height is None:
        if image is None:
            raise ValueError(f"{intrinsics}: OpenCV calibration files carry no image size; "
                             "give width and height (or an image of the pair)")
        width, height = _image_size(image)
    fs = _open_fs(intrinsics)
    try:
        K1 = _read_mat(fs.getNode("M1"), intrinsics, "M1", (3, 3))
        D1 = _read_mat(fs.getNode("D1"), intrinsics, "D1", optional=True)
        K2 = _read_mat(fs.getNode("M2"), intrinsics, "M2", (3, 3))
        D2 = _read_mat(fs.getNode("D2"), intrinsics, "D2", optional=True)
    finally:
        fs.release()
    fs = _open_fs(extrinsics)
    try:
        R = _read_mat(fs.getNode("R"), extrinsics, "R", (3, 3))
        T = _read_mat(fs.getNode("T"), extrinsics, "T", (3,))
    finally:
        fs.release()
    D1 = np.zeros(0) if D1 is None else D1.reshape(-1)
    D2 = np.zeros(0) if D2 is None else D2.reshape(-1)
    if _few_digits_rotation(R):
        R = _nearest_rotation(R)  # a hand-edited file may carry few digits
    try:
        left = Camera(K1, D1, np.eye(3), np.zeros(3), width, height, "left")
    except ValueError as exc:
        raise _camera_error(intrinsics, "M1/D1", exc) from None
    try:
        right = Camera(K2, D2, R, T, width, height, "right")
    except ValueError as exc:
        from_extrinsics = str(exc).startswith(("R ", "t "))
        raise _camera_error(extrinsics if from_extrinsics else intrinsics,
                            "R/T" if from_extrinsics else "M2/D2", exc) from None
    return StereoRig(left, right)


def read_rig(path: str | os.PathLike, extrinsics: str | os.PathLike | None = None,
             width: int | None = None, height: int | None = None,
             image: str | os.PathLike | None = None) -> StereoRig:
    """Read a stereo rig from any of the supported files, by content.

    Parameters
    ----------
    path : path
        One of: a ``cameras.yml`` with two views (synthetic scenes) or with
        ``rig_left``/``rig_right`` (more views); a rig file written by
        ``photosurf calibrate`` (the same format); OpenCV's ``intrinsics.yml``
        (its ``extrinsics.yml`` is taken from ``extrinsics`` or the same
        folder) or ``extrinsics.yml`` (its ``intrinsics.yml`` beside it), or
        one file holding ``M1 D1 M2 D2 R T``.
    extrinsics : path, optional
        The extrinsics file for an ``intrinsics.yml``.
    width, height, image :
        Image size for the OpenCV sample files (see :func:`read_stereo_calibration`).

    Returns
    -------
    StereoRig
    """
    path = Path(path)
    fs = _open_fs(path)
    try:
        kind = ("photosurf" if _has(fs, "n_views") else
                "intrinsics" if _has(fs, "M1") else
                "extrinsics" if _has(fs, "R") and _has(fs, "T") else None)
        combined = kind == "intrinsics" and _has(fs, "R") and _has(fs, "T")
    finally:
        fs.release()
    if kind == "photosurf":
        return _read_rig_yml(path)
    if kind is None:
        raise ValueError(f"{path}: not a rig file (no n_views, no M1/M2 intrinsics, "
                         "no R/T extrinsics)")
    if kind == "intrinsics":
        ext = path if combined else Path(extrinsics) if extrinsics is not None else \
            path.with_name(path.name.replace("intrinsics", "extrinsics"))
        if ext == path and not combined:
            raise ValueError(f"{path}: intrinsics only; give the extrinsics file (R, T)")
        return read_stereo_calibration(path, ext, width, height, image)
    intr = path.with_name(path.name.replace("extrinsics", "intrinsics"))
    if intr == path:
        raise ValueError(f"{path}: extrinsics only; give the intrinsics file (M1 D1 M2 D2)")
    return read_stereo_calibration(intr, path, width, height, image)


# ------------------------------------------------------------------- COLMAP text
#: COLMAP model -> (number of params, function params -> (fx, fy, cx, cy, dist))
_COLMAP_MODELS = {
    "SIMPLE_PINHOLE": (3, lambda p: (p[0], p[0], p[1], p[2], [])),
    "PINHOLE": (4, lambda p: (p[0], p[1], p[2], p[3], [])),
    "SIMPLE_RADIAL": (4, lambda p: (p[0], p[0], p[1], p[2], [p[3], 0, 0, 0])),
    "RADIAL": (5, lambda p: (p[0], p[0], p[1], p[2], [p[3], p[4], 0, 0])),
    "OPENCV": (8, lambda p: (p[0], p[1], p[2], p[3], list(p[4:8]))),
    "FULL_OPENCV": (12, lambda p: (p[0], p[1], p[2], p[3],
                                   list(p[4:9]) if not np.any(p[9:12]) else list(p[4:12]))),
}
#: COLMAP's pixel origin is the corner of the top-left pixel, OpenCV's its centre.
_COLMAP_PIXEL_SHIFT = 0.5


def _colmap_camera_line(camera_id: int, cam: Camera) -> str:
    fx, fy, cx, cy = cam.K[0, 0], cam.K[1, 1], cam.K[0, 2], cam.K[1, 2]
    if abs(cam.K[0, 1]) > TOL.zero:
        raise ValueError(
            f"camera {cam.name!r}: COLMAP models have no skew, K[0, 1] = {cam.K[0, 1]}")
    cx, cy = cx + _COLMAP_PIXEL_SHIFT, cy + _COLMAP_PIXEL_SHIFT
    dist = cam.dist
    if not cam.has_distortion:
        model, params = "PINHOLE", [fx, fy, cx, cy]
    elif dist.size == 4:
        model, params = "OPENCV", [fx, fy, cx, cy, *dist]
    elif dist.size in (5, 8):
        model, params = "FULL_OPENCV", [fx, fy, cx, cy, *np.pad(dist, (0, 8 - dist.size))]
    elif not np.any(dist[8:]):
        model, params = "FULL_OPENCV", [fx, fy, cx, cy, *dist[:8]]
    else:
        raise ValueError(f"camera {cam.name!r}: thin-prism/tilt distortion (dist[8:]) has no "
                         "COLMAP model")
    values = " ".join(repr(float(v)) for v in params)
    return f"{camera_id} {model} {cam.width} {cam.height} {values}"


def write_colmap_text(folder: str | os.PathLike, cameras: Sequence[Camera],
                      points: np.ndarray | None = None) -> None:
    """Write cameras as a COLMAP text model (``cameras.txt``, ``images.txt``, ``points3D.txt``).

    Parameters
    ----------
    folder : path
        Created if missing; the three files are overwritten.
    cameras : sequence of Camera
        One COLMAP camera and one image per entry (ids 1..N); names must be
        unique, non-empty and without whitespace.  PINHOLE model without
        distortion, OPENCV for 4 coefficients, FULL_OPENCV for 5 or 8.
    points : (M, 3) float64, optional
        Written to ``points3D.txt`` with colour 128 and no track (COLMAP's
        reader accepts empty tracks).  Default: an empty ``points3D.txt``.
    """
    folder = Path(folder)
    cameras = list(cameras)
    if not cameras:
        raise ValueError(f"{folder}: no cameras to write")
    names = [cam.name for cam in cameras]
    for i, name in enumerate(names):
        if not name or any(ch.isspace() for ch in name):
            raise ValueError(f"cameras[{i}].name must be non-empty without whitespace for COLMAP, "
                             f"got {name!r}")
    if len(set(names)) != len(names):
        raise ValueError("camera names must be unique for COLMAP")
    folder.mkdir(parents=True, exist_ok=True)
    cam_lines = [_colmap_camera_line(i + 1, cam) for i, cam in enumerate(cameras)]
    quats = rotation_to_quaternion(np.stack([cam.R for cam in cameras]))
    img_lines = []
    for i, (cam, q) in enumerate(zip(cameras, quats, strict=True)):
        values = " ".join(repr(float(v)) for v in (*q, *cam.t))
        img_lines += [f"{i + 1} {values} {i + 1} {cam.name}", ""]
    (folder / "cameras.txt").write_text(
        "# Camera list with one line of data per camera:\n"
        "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n"
        f"# Number of cameras: {len(cameras)}\n" + "\n".join(cam_lines) + "\n")
    (folder / "images.txt").write_text(
        "# Image list with two lines of data per image:\n"
        "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n"
        "#   POINTS2D[] as (X, Y, POINT3D_ID)\n"
        f"# Number of images: {len(cameras)}, mean observations per image: 0\n"
        + "\n".join(img_lines) + "\n")
    pts_lines = []
    if points is not None:
        points = check_shape(points, "(M, 3)", "points", dtype=np.float64)
        pts_lines = [f"{i + 1} {x!r} {y!r} {z!r} 128 128 128 0"
                     for i, (x, y, z) in enumerate(points.tolist())]
    (folder / "points3D.txt").write_text(
        "# 3D point list with one line of data per point:\n"
        "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n"
        f"# Number of points: {len(pts_lines)}, mean track length: 0\n"
        + "".join(line + "\n" for line in pts_lines))


def _data_lines(path: Path) -> list[tuple[int, str]]:
    lines = []
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        if line.strip() and not line.lstrip().startswith("#"):
            lines.append((number, line))
    return lines


def _parse_colmap_cameras(path: Path) -> dict[int, tuple]:
    intrinsics = {}
    for number, line in _data_lines(path):
        fields = line.split()
        where = f"{path}:{number}"
        if len(fields) < 4:
            raise ValueError(f"{where}: expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]")
        model = fields[1]
        if model not in _COLMAP_MODELS:
            raise ValueError(f"{where}: camera model {model} not supported (supported: "
                             f"{', '.join(_COLMAP_MODELS)})")
        n_params, convert = _COLMAP_MODELS[model]
        try:
            camera_id, width, height = int(fields[0]), int(fields[2]), int(fields[3])
            params = np.array([float(v) for v in fields[4:]])
        except ValueError:
            raise ValueError(f"{where}: malformed number in {line.strip()!r}") from None
        if params.size != n_params:
            raise ValueError(f"{where}: {model} needs {n_params} parameters, got {params.size}")
        if not np.all(np.isfinite(params)):
            raise ValueError(f"{where}: non-finite parameter in {line.strip()!r}")
        fx, fy, cx, cy, dist = convert(params)
        K = np.array([[fx, 0.0, cx - _COLMAP_PIXEL_SHIFT], [0.0, fy, cy - _COLMAP_PIXEL_SHIFT],
                      [0.0, 0.0, 1.0]])
        intrinsics[camera_id] = (K, np.array(dist, dtype=np.float64), width, height)
    return intrinsics


def read_colmap_text(folder: str | os.PathLike) -> list[Camera]:
    """Read the registered images of a COLMAP text model as cameras.

    Parameters
    ----------
    folder : path
        Holding ``cameras.txt`` and ``images.txt`` (``points3D.txt`` is not read).
        Supported models: SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL,
        OPENCV, FULL_OPENCV.

    Returns
    -------
    list of Camera, in ``images.txt`` order, named by the image names.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: no such folder")
    cam_path, img_path = folder / "cameras.txt", folder / "images.txt"
    _check_exists(cam_path)
    _check_exists(img_path)
    intrinsics = _parse_colmap_cameras(cam_path)
    cameras = []
    lines = _data_lines(img_path)
    # Every image has two lines, the second (POINTS2D) may be empty: parse the
    # raw lines, skipping comments, pairing each header with its next line.
    numbered = [(k, ln) for k, ln in enumerate(img_path.read_text().splitlines(), start=1)
                 if not ln.lstrip().startswith("#")]
    raw = [ln for _, ln in numbered]
    headers = raw[0::2]
    if not lines:
        raise ValueError(f"{img_path}: no images")
    for (number, points_line) in numbered[1::2]:
        if not _is_points_line(points_line):
            raise ValueError(
                f"{img_path}:{number}: malformed images.txt: expected the POINTS2D line "
                "(X Y POINT3D_ID triples, or empty) after each image line, got "
                f"{' '.join(points_line.split()[:4])[:60]!r}...")
    entries = []
    for index, line in enumerate(headers):
        if not line.strip():
            continue
        fields = line.split()
        where = f"{img_path}: image entry {index + 1}"
        if len(fields) < 10:
            raise ValueError(f"{where}: expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME")
        try:
            q = np.array([float(v) for v in fields[1:5]])
            t = np.array([float(v) for v in fields[5:8]])
            camera_id = int(fields[8])
        except ValueError:
            raise ValueError(f"{where}: malformed number in {line.strip()!r}") from None
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(t))):
            raise ValueError(f"{where}: non-finite pose in {line.strip()!r}")
        if np.linalg.norm(q) < TOL.zero:
            raise ValueError(f"{where}: quaternion QW QX QY QZ is zero")
        if camera_id not in intrinsics:
            raise ValueError(f"{where}: CAMERA_ID {camera_id} not in {cam_path}")
        K, dist, width, height = intrinsics[camera_id]
        name = " ".join(fields[9:])
        try:
            cameras.append(Camera(K, dist, quaternion_to_rotation(q), t, width, height, name))
        except ValueError as exc:
            raise ValueError(f"{where} ({name}): {exc}") from None
        entries.append(f"image entry {index + 1} (IMAGE_ID {fields[0]})")
    return _unique_names(cameras, entries, img_path)


def _is_points_line(line: str) -> bool:
    """An images.txt POINTS2D line: empty, or ``X Y POINT3D_ID`` triples (the first
    checked: an image line, 10 fields ending in a name, is not one)."""
    fields = line.split()
    if not fields:
        return True
    if len(fields) % 3:
        return False
    try:
        float(fields[0]), float(fields[1]), int(fields[2])
    except ValueError:
        return False
    return True


def cameras_from_pycolmap(reconstruction) -> list[Camera]:
    """Cameras of the registered images of a ``pycolmap.Reconstruction``, sorted by name.

    Supports the models of :func:`read_colmap_text`; the principal point is
    moved from COLMAP's pixel-corner origin to OpenCV's pixel-centre origin.
    """
    cameras = []
    for image in reconstruction.images.values():
        if not _is_registered(image):
            continue
        colmap_cam = reconstruction.cameras[image.camera_id]
        model = str(colmap_cam.model_name) if hasattr(colmap_cam, "model_name") else \
            colmap_cam.model.name
        if model not in _COLMAP_MODELS:
            raise ValueError(f"image {image.name}: camera model {model} not supported")
        fx, fy, cx, cy, dist = _COLMAP_MODELS[model][1](np.asarray(colmap_cam.params))
        K = np.array([[fx, 0.0, cx - _COLMAP_PIXEL_SHIFT], [0.0, fy, cy - _COLMAP_PIXEL_SHIFT],
                      [0.0, 0.0, 1.0]])
        pose = image.cam_from_world() if callable(image.cam_from_world) else image.cam_from_world
        R = np.asarray(pose.rotation.matrix())
        t = np.asarray(pose.translation)
        cameras.append(Camera(K, np.array(dist, dtype=np.float64), R, t, colmap_cam.width,
                              colmap_cam.height, image.name))
    return sorted(cameras, key=lambda c: c.name)


def _is_registered(image) -> bool:
    flag = getattr(image, "has_pose", None)
    if flag is None:
        flag = getattr(image, "registered", True)
    return bool(flag() if callable(flag) else flag)


def read_colmap(folder: str | os.PathLike) -> list[Camera]:
    """Read a COLMAP model folder, text (by photosurf's parser) or binary (through pycolmap)."""
    folder = Path(folder)
    if (folder / "cameras.txt").exists():
        return read_colmap_text(folder)
    if (folder / "cameras.bin").exists():
        import pycolmap

        try:
            reconstruction = pycolmap.Reconstruction(str(folder))
        except Exception as exc:  # pycolmap raises its own error types
            raise ValueError(f"{folder}: unreadable COLMAP binary model ({exc})") from None
        return cameras_from_pycolmap(reconstruction)
    raise FileNotFoundError(f"{folder}: no COLMAP model (cameras.txt or cameras.bin)")


# ------------------------------------------------------------ projection matrices
def _few_digits_rotation(R: np.ndarray) -> bool:
    """A rotation printed with few digits (orthonormal within the text precision, det > 0):
    snapping it is safe.  A reflection (det -1) is not a rotation; it is left to fail."""
    return bool(np.abs(R.T @ R - np.eye(3)).max() < TOL.rotation_text_digits
                and np.linalg.det(R) > 0)


def _nearest_rotation(R: np.ndarray) -> np.ndarray:
    U, _, Vt = np.linalg.svd(R)
    return U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt


def read_projection_txt(path: str | os.PathLike, width: int | None = None,
                        height: int | None = None,
                        image_dir: str | os.PathLike | None = None,
                        sizes: Mapping[str, tuple[int, int]] | None = None) -> list[Camera]:
    """Read per-image ``name k11..k33 r11..r33 t1 t2 t3`` lines (Middlebury ``*_par.txt``).

    The file holds no image size: each camera takes its own image's, so views of
    several sizes (a portrait view among landscape ones, with K, R, t turned with it)
    are read as they are.

    Parameters
    ----------
    path : path
        Text file; an optional first line holds the number of images.
    width, height : int, optional
        Image size of the views ``sizes`` does not hold.  If not given, the first
        image is looked up in ``image_dir`` (default: the file's folder) and its size used.
    image_dir : path, optional
    sizes : mapping of str to (int, int), optional
        ``(width, height)`` of each image by file name (the base name of the file's
        names), as the caller read them.

    Returns
    -------
    list of Camera, no distortion, in file order.  Rotations printed with few
    digits are projected onto the nearest rotation if they are within
    ``TOL.rotation_text_digits`` of one.
    """
    path = Path(path)
    _check_exists(path)
    rows = []
    for number, line in _data_lines(path):
        fields = line.split()
        if len(fields) == 1 and not rows:
            continue  # the image count
        if len(fields) != 22:
            raise ValueError(f"{path}:{number}: expected name and 21 numbers "
                             f"(k11..k33 r11..r33 t1 t2 t3), got {len(fields)} fields")
        try:
            values = np.array([float(v) for v in fields[1:]])
        except ValueError:
            raise ValueError(f"{path}:{number}: malformed number in {line.strip()!r}") from None
        if not np.all(np.isfinite(values)):
            raise ValueError(f"{path}:{number}: non-finite number in {line.strip()!r}")
        rows.append((number, fields[0], values))
    if not rows:
        raise ValueError(f"{path}: no camera lines")
    sizes = dict(sizes or {})
    if (width is None or height is None) and sizes:
        # the views without an image of their own (the caller has none to use them with)
        width, height = sizes.get(Path(rows[0][1]).name, next(iter(sizes.values())))
    if width is None or height is None:
        folder = Path(image_dir) if image_dir is not None else path.parent
        candidate = folder / rows[0][1]
        if not candidate.exists():
            raise ValueError(f"{path}: no image size given and {candidate} not found; give "
                             "width and height")
        width, height = _image_size(candidate)
    cameras = []
    entries = [f"line {number}" for number, _, _ in rows]
    for number, name, values in rows:
        K, R, t = values[:9].reshape(3, 3), values[9:18].reshape(3, 3), values[18:]
        if _few_digits_rotation(R):
            R = _nearest_rotation(R)
        try:
            cameras.append(Camera(K / K[2, 2] if K[2, 2] else K, np.zeros(0), R, t,
                                  *sizes.get(Path(name).name, (width, height)), name))
        except ValueError as exc:
            raise ValueError(f"{path}:{number} ({name}): {exc}") from None
    return _unique_names(cameras, entries, path)


# ------------------------------------------------------------------- dispatch
def read_cameras(path: str | os.PathLike, width: int | None = None,
                 height: int | None = None,
                 sizes: Mapping[str, tuple[int, int]] | None = None) -> list[Camera]:
    """Read cameras from any supported source, by content.

    Parameters
    ----------
    path : path
        ``cameras.yml`` / ``.xml`` (photosurf), a rig file, OpenCV
        ``intrinsics.yml`` / ``extrinsics.yml`` (returns [left, right]), a
        COLMAP model folder (text or binary) or its ``cameras.txt`` /
        ``images.txt``, or a projection-matrix ``.txt``.
    width, height : int, optional
        Image size for formats that do not store it.
    sizes : mapping of str to (int, int), optional
        Each image's ``(width, height)`` by file name, for formats that store no size
        (a projection-matrix ``.txt``): each camera takes its own image's.

    Returns
    -------
    list of Camera
    """
    path = Path(path)
    if path.is_dir():
        return read_colmap(path)
    _check_exists(path)
    if path.name in ("cameras.txt", "images.txt", "points3D.txt"):
        return read_colmap_text(path.parent)
    if path.suffix.lower() in (".yml", ".yaml", ".xml", ".json"):
        fs = _open_fs(path)
        try:
            photosurf = _has(fs, "n_views")
        finally:
            fs.release()
        if photosurf:
            return read_cameras_yml(path)
        rig = read_rig(path, width=width, height=height)
        return [rig.left, rig.right]
    if path.suffix.lower() == ".txt":
        return read_projection_txt(path, width, height, sizes=sizes)
    raise ValueError(f"{path}: unknown camera file type (expected .yml/.xml, a COLMAP folder "
                     "or cameras.txt, or a projection-matrix .txt)")
