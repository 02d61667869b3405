"""What photosurf reads from the user: input kinds, images, image folders, stereo rigs.

One set of rules for every command that reads images (``photosurf run``, ``match``,
``stereo``, ``acquire``):

* an image file is one of :data:`IMAGE_SUFFIXES`; hidden files (``.name``) are not images;
* :func:`read_image` reads it as the user sees it: the bytes read by Python and decoded
  by OpenCV (``IMREAD_UNCHANGED``: grey or BGR), its EXIF orientation applied
  (:mod:`matching.image_file`; cameras, masks, ``--roi`` and the report all refer to this
  upright image); it refuses a missing file, a folder, a FIFO or device, an undecodable
  file, one smaller than :data:`MIN_IMAGE_PX` on a side (a least-squares patch of 15 px
  with its search margin does not fit) and a float image with NaN/inf pixels, and maps
  other depths (16-bit, float) onto 0..255 ``uint8`` by their own range
  (:func:`matching.image_file.to_uint8`), since matching works on 8-bit grey levels;
* a folder's images are its image files, or those of ``FOLDER/images``, sorted by name
  (:func:`folder_images`);
* :func:`detect_kind` tells a scene recipe, a stereo pair, an image folder and a cloud
  apart (:data:`KINDS`).

:func:`load_folder` loads an image folder with its cameras (a camera file, the folder's
``cameras.yml`` / COLMAP ``sparse`` model, else pycolmap SfM) for
:mod:`pipeline.acquisition`.  Every refusal is an :class:`~pipeline.errors.InputError`
(or ``FileNotFoundError``) whose one line names the file.
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from pipeline.errors import InputError

log = logging.getLogger(__name__)

#: Input kinds ``photosurf run`` knows (``--kind`` takes these).
KINDS = ("scene", "stereo", "folder", "cloud")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".pgm", ".ppm", ".webp")
CLOUD_SUFFIXES = (".ply", ".xyz", ".csv", ".npz", ".txt", ".pts")
RIG_NAMES = ("rig.yml", "rig.yaml", "cameras.yml", "cameras.yaml", "extrinsics.yml")
#: Smallest image side read (pixels): a 15 px LSM patch and its search margin.
MIN_IMAGE_PX = 32


# --------------------------------------------------------------------------- images
def read_image(path: str | os.PathLike) -> np.ndarray:
    """One image file as ``(H, W)`` grey or ``(H, W, 3|4)`` BGR ``uint8`` (module rules).

    Raises
    ------
    FileNotFoundError
        No such file.
    InputError
        A FIFO or device, an undecodable file, an image smaller than
        :data:`MIN_IMAGE_PX`, or NaN/inf pixels.
    IsADirectoryError
        A folder.
    """
    from matching.image_file import to_uint8
    from pipeline import guards

    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: {guards.missing_reason(path)}")
    if path.is_dir():
        raise IsADirectoryError(f"{path}: is a folder, expected an image")
    # a regular file, its format by signature, its header size within the limits (before
    # decoding), libpng's own lines captured
    image = guards.read_image(path)
    if image is None or image.ndim not in (2, 3):
        raise InputError(f"{path}: not a readable image")
    if min(image.shape[:2]) < MIN_IMAGE_PX:
        raise InputError(f"{path}: image is too small to match: {image.shape[1]}x"
                         f"{image.shape[0]} px (at least {MIN_IMAGE_PX}x{MIN_IMAGE_PX})")
    try:
        return to_uint8(image, str(path))
    except ValueError as exc:
        raise InputError(str(exc)) from None


def read_pair(left: str | os.PathLike, right: str | os.PathLike,
              need_same_size: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Both images of a stereo pair (:func:`read_image`), optionally of one size.

    One image twice (the same file, or identical textured pixels) is refused: a pair
    of one view has a zero baseline.
    """
    from pipeline.guards import check_image_file

    if os.path.realpath(left) == os.path.realpath(right):
        raise InputError(f"{right}: is the left image {left} again; a stereo pair needs two "
                         "views (zero baseline)")
    for path in (left, right):  # both headers (size limit) before either image is decoded
        if Path(path).exists() and not Path(path).is_dir():
            check_image_file(path)
    images = read_image(left), read_image(right)
    if images[0].shape == images[1].shape and np.array_equal(images[0], images[1]) and \
            images[0].min() != images[0].max():  # (a blank pair: the matcher says why)
        raise InputError(f"{right}: is the same picture as {left} (identical pixels); a "
                         "stereo pair needs two views (zero baseline)")
    if need_same_size and images[0].shape[:2] != images[1].shape[:2]:
        (h1, w1), (h2, w2) = images[0].shape[:2], images[1].shape[:2]
        raise InputError(f"{right}: image is {w2}x{h2} px but {left} is {w1}x{h1} px; "
                         "the pair must have one size")
    return images


def read_rig_for(path: str | os.PathLike, left_image: str | os.PathLike | None = None):
    """:func:`matching.cameras.read_rig`, its errors as one line naming the file; then
    :func:`pipeline.guards.check_rig` (format, version, consistency, finite values, baseline)."""
    from matching.cameras import read_rig
    from pipeline.guards import check_rig, regular_file

    regular_file(path, "rig file")
    try:
        rig = read_rig(path, image=left_image)
    except (ValueError, OSError) as exc:
        message = str(exc)
        raise InputError(message if str(path) in message else f"{path}: {message}") from None
    check_rig(rig, path)
    return rig


def check_rig_size(rig, images, paths) -> None:
    """Each image must have its camera's size (the rig's calibration is per pixel)."""
    for label, image, cam, path in zip(("left", "right"), images, (rig.left, rig.right), paths,
                                       strict=True):
        if (image.shape[1], image.shape[0]) != cam.size:
            raise InputError(f"{path}: image is {image.shape[1]}x{image.shape[0]} px but the "
                             f"rig's {label} camera is {cam.size[0]}x{cam.size[1]} px")


# --------------------------------------------------------------------------- folders
def _image_files(where: Path) -> tuple[list[str], list[str]]:
    """Image names and other (visible) file names of one folder, sorted.

    Every entry but a folder counts, by its suffix: a FIFO, a device or a broken link
    named as an image is one (:func:`read_image` refuses it, so a folder's view is left
    out with its reason, not passed over without a word)."""
    files = sorted(p for p in where.iterdir() if not p.is_dir() and not p.name.startswith("."))
    images = [p.name for p in files if p.suffix.lower() in IMAGE_SUFFIXES]
    return images, [p.name for p in files if p.name not in images]


def folder_images(folder: str | os.PathLike) -> list[Path]:
    """Image files of ``folder`` (or of ``folder/images``), sorted by name; [] if none."""
    folder = Path(folder)
    for where in (folder, folder / "images"):
        if where.is_dir():
            images, _ = _image_files(where)
            if images:
                return [where / name for name in images]
    return []


def image_dir(folder: str | os.PathLike) -> tuple[Path, list[str], list[str]]:
    """The folder holding the images, the image names and the other file names.

    Raises ``FileNotFoundError`` / ``NotADirectoryError`` / ``InputError`` (empty
    folder, no image files) naming the folder.
    """
    folder = Path(folder)
    if not folder.exists():
        raise FileNotFoundError(f"{folder}: no such folder")
    if not folder.is_dir():
        raise NotADirectoryError(f"{folder}: not a folder")
    for where in (folder, folder / "images"):
        if where.is_dir():
            images, others = _image_files(where)
            if images:
                return where, images, others
    others = sorted(p.name for p in folder.iterdir() if not p.name.startswith("."))
    if not others:
        raise InputError(f"{folder}: empty folder (no images)")
    raise InputError(f"{folder}: no image files ({', '.join(IMAGE_SUFFIXES)}); found "
                     f"{', '.join(others[:5])}{' ...' if len(others) > 5 else ''}")


def read_images(where: Path, names: list[str]) -> list[np.ndarray]:
    """Every image (:func:`read_image`); the error names the first unreadable file."""
    return [read_image(Path(where) / name) for name in names]


class FolderImages(Sequence):
    """The images of a folder, read from disk on item access (bounded memory).

    Holds the paths and the shapes :func:`load_folder` recorded when it checked every
    file; ``images[v]`` reads the file again.  Pickles as its paths (a Dask task carries
    the file names, not the pixels).  :func:`matching.multiview.reconstruct_multiview`
    recognises it by ``lazy`` and ``shapes``.

    Parameters
    ----------
    where : Path
        The folder.
    names : list of str
        Image file names, in camera order.
    shapes : list of tuple
        Each image's array shape as read (at ``scale``), same order.
    scale : float
        Working scale (:mod:`matching.resolution`): each image is resized to the size
        in ``shapes`` (``cv2.INTER_AREA``) as it is read; 1.0: as stored.
    """

    lazy = True

    def __init__(self, where: Path, names: list[str], shapes: list[tuple],
                 scale: float = 1.0):
        self.paths = [Path(where) / name for name in names]
        self.shapes = list(shapes)  # read once by load_folder, which checks every file
        self.scale = float(scale)

    def __len__(self) -> int:
        return len(self.paths)

    def __getitem__(self, index):
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        image = read_image(self.paths[index])
        if self.scale != 1.0:
            import cv2

            height, width = self.shapes[index][:2]
            image = cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA)
        return image


def _camera_source(folder: Path, where: Path, cameras: str | None) -> Path | None:
    if cameras is not None:
        path = Path(cameras)
        if not path.exists():
            raise FileNotFoundError(f"{path}: no such camera file")
        return path
    for base in dict.fromkeys((folder, where)):
        for name in ("cameras.yml", "cameras.yaml", "sparse"):
            if (base / name).exists():
                return base / name
    return None


def _match_cameras(cams: list, names: list[str]) -> tuple[list, str]:
    """Each image's camera by file name (None where the file has none), and what the
    file holds, for the one-line reason of an image without one."""
    by_name = {Path(c.name).name: c for c in cams if c.name}
    holds = (f"({len(cams)} cameras: {', '.join(sorted(by_name)[:3])}"
             f"{' ...' if len(by_name) > 3 else ''})")
    return [by_name.get(n) for n in names], holds


def _readable_images(where: Path, names: list[str]) -> tuple[list[str], list, list[dict]]:
    """The images that can be read (names, shapes) and the views left out with the
    one-line reason of each (:func:`read_image`'s)."""
    kept, shapes, skipped = [], [], []
    for name in names:
        try:
            shapes.append(read_image(where / name).shape)
        except (InputError, FileNotFoundError) as exc:  # (a broken link: no such file)
            skipped.append({"view": name, "reason": str(exc)})
            continue
        kept.append(name)
    return kept, shapes, skipped


def _enough_views(names: list[str], skipped: list[dict], where: Path) -> None:
    """Two views at least: else the first left-out view's reason is the error, naming
    the other views left out."""
    if len(names) >= 2:
        return
    if skipped:
        others = [skip["view"] for skip in skipped[1:]]
        raise InputError(skipped[0]["reason"] + (f"; also left out: {', '.join(others[:5])}"
                                                 f"{' ...' if len(others) > 5 else ''}"
                                                 if others else ""))
    raise InputError(f"{where}: need at least 2 images, found {len(names)}")


def _cameras_from_file(source: Path, where: Path, names: list, shapes: list, sizes: set,
                       skipped: list) -> tuple[list, list, list]:
    """The folder's cameras read from ``source`` and matched to its images by name: a view
    without a camera or of another size is left out (``skipped`` gets its reason);
    ``(names, shapes, cameras)`` of the views kept (at least two)."""
    from matching.cameras import read_cameras

    try:
        # a file without sizes (Middlebury par): each camera takes its image's size,
        # so a portrait view with its K, R, t turned with it is used
        cams = read_cameras(source, *(next(iter(sizes)) if len(sizes) == 1 else (None, None)),
                            sizes={name: (shape[1], shape[0])
                                   for name, shape in zip(names, shapes, strict=True)})
    except ValueError as exc:  # the readers' messages name the file (or one inside)
        message = str(exc)
        raise InputError(message if str(source) in message else f"{source}: {message}"
                         ) from None
    cams, holds = _match_cameras(cams, names)
    keep = []
    for k, (name, shape, cam) in enumerate(zip(names, shapes, cams, strict=True)):
        if cam is None:
            skipped.append({"view": name,
                            "reason": f"{source}: no camera for image {name} {holds}"})
        elif (shape[1], shape[0]) != cam.size:
            skipped.append({"view": name, "reason": (
                f"{where / name}: image is {shape[1]}x{shape[0]} px but its camera in "
                f"{source} is {cam.size[0]}x{cam.size[1]} px")})
        else:
            keep.append(k)
    names, shapes, cams = ([seq[k] for k in keep] for seq in (names, shapes, cams))
    _enough_views(names, skipped, where)
    return names, shapes, cams


def load_folder(folder: str | Path, cameras: str | None = None,
                sfm_work_dir: str | Path | None = None,
                camera_model: str = "SIMPLE_RADIAL", spacing: float = 3.0,
                points_across: int = 0, precision: float = 0.0, section_count: int = 0,
                section_spacing: float = 0.0) -> dict:
    """Images and cameras of an image folder, checked.

    Cameras come from ``cameras`` (any format :func:`matching.cameras.read_cameras`
    reads), else ``FOLDER/cameras.yml`` or the COLMAP model ``FOLDER/sparse``, else
    pycolmap SfM (:func:`matching.sfm.run_sfm`, in its arbitrary similarity frame);
    they are matched to the images by file name.

    The views are read at a working scale (the object's extent in the images from
    SfM's sparse points, else its foreground, else the image size; ``spacing`` the LSM
    cell in pixels): ``points_across`` > 0 that many points across the object
    (:func:`matching.resolution.working_scale`); else the finest that ``precision``
    (a point's σ as a share of the object's extent), ``section_count`` and
    ``section_spacing`` (scene units) ask (:func:`matching.resolution.requested_scale`;
    none of them: full size).  The images are resized as they are read and the cameras
    scaled with them; the dict's ``working_scale``, ``working_scale_reason`` and
    ``full_sizes`` (each view's stored ``(W, H)``) say so.

    Returns
    -------
    dict
        ``images`` (:class:`FolderImages`, read on access), ``cameras`` (list of
        Camera, same order), ``names``,
        ``camera_source`` (path or ``"sfm"``), ``ignored`` (other files),
        ``unregistered`` (images SfM could not place, left out), ``sfm`` (its report),
        ``skipped_views`` (``[{"view": name, "reason": one line}]``: images left out
        because they cannot be read, have no camera in the camera file or not its size;
        each also a warning).

    Raises
    ------
    InputError
        Fewer than two usable views (the first left-out view's reason), a camera file
        that cannot be read, SfM registering fewer than two images.
    """
    folder = Path(folder)
    where, names, others = image_dir(folder)
    if len(names) < 2:
        raise InputError(f"{where}: need at least 2 images, found {len(names)} ({names[0]})")
    # one bad view is left out with its reason, not fatal (an unreadable or truncated
    # file, a camera of another size, no camera for it); fewer than two views left fail
    names, shapes, skipped = _readable_images(where, names)
    _enough_views(names, skipped, where)
    sizes = {(shape[1], shape[0]) for shape in shapes}
    source = _camera_source(folder, where, cameras)
    out = {"ignored": others, "unregistered": [], "sfm": None, "skipped_views": skipped}
    if source is not None:
        names, shapes, cams = _cameras_from_file(source, where, names, shapes, sizes, skipped)
        out["camera_source"] = str(source)
        out["sparse_points"] = _model_points(source)
    else:
        # images of several sizes: SfM turns one sensor's portrait shots upright to share
        # one camera with its landscape ones, else gives each image its own camera
        from matching.sfm import run_sfm

        result = run_sfm(where, work_dir=sfm_work_dir, image_names=names,
                         camera_model=camera_model)
        if len(result.registered) < 2:
            raise InputError(f"{where}: SfM registered {len(result.registered)} of "
                             f"{len(names)} images; need 2")
        keep = [n for n in names if n in set(result.registered)]
        by_name = {c.name: c for c in result.cameras}
        shapes = [shapes[names.index(n)] for n in keep]
        cams = [by_name[n] for n in keep]
        out.update(camera_source="sfm", unregistered=list(result.unregistered),
                   sfm=result.report())
        if result.unregistered:
            log.warning("SfM did not register %s; left out", ", ".join(result.unregistered))
        names = keep
        out["sparse_points"] = result.points
    for skip in skipped:
        log.warning("view %s left out: %s", skip["view"], skip["reason"])
    full_sizes = [(shape[1], shape[0]) for shape in shapes]
    asked = {"points_across": points_across, "precision": precision,
             "section_count": section_count, "section_spacing": section_spacing}
    scale, why, shapes, cams = _working_resolution(cams, shapes, out.get("sparse_points"),
                                                   spacing, asked,
                                                   FolderImages(where, names, shapes))
    out.update(images=FolderImages(where, names, shapes, scale), cameras=cams, names=names,
               working_scale=scale, working_scale_reason=why, full_sizes=full_sizes)
    return out


def _model_points(source: Path):
    """The sparse points of a COLMAP model folder (the object's extent in the images), or
    None for any other camera file."""
    if not (source.is_dir() and any((source / f"points3D.{ext}").is_file()
                                    for ext in ("bin", "txt"))):
        return None
    import pycolmap

    model = pycolmap.Reconstruction(str(source))
    return np.array([p.xyz for p in model.points3D.values()], dtype=np.float64).reshape(-1, 3)


def _working_resolution(cams: list, shapes: list, points, spacing: float, asked: dict,
                        images=None) -> tuple[float, str, list, list]:
    """The working scale (:mod:`matching.resolution`) and what set it, the shapes and
    cameras at it (the object's extent from ``points``, else from the foreground of
    ``images``); ``asked``: :func:`load_folder`'s ``points_across``, ``precision``,
    ``section_count``, ``section_spacing``."""
    from matching.resolution import (
        object_extent_px,
        requested_scale,
        scale_camera,
        scaled_size,
        working_scale,
    )

    full = [(shape[1], shape[0]) for shape in shapes]
    if not any(asked.values()):
        return 1.0, "full resolution", shapes, cams
    extent = object_extent_px(cams, points, images=images)
    if asked["points_across"]:
        scale = working_scale(extent, spacing, asked["points_across"])
        why = f"{asked['points_across']} points across"
    else:
        scale, why = requested_scale(cams, extent, spacing, asked["precision"],
                                     asked["section_count"], asked["section_spacing"], points)
    if scale >= 1.0:
        return 1.0, why, shapes, cams
    sizes = [scaled_size(size, scale) for size in full]
    shapes = [(h, w, *shape[2:]) for (w, h), shape in zip(sizes, shapes, strict=True)]
    log.info("acquire: views read at %.3g of their size (%dx%d -> %dx%d px): the object spans "
             "%.0f px; %s, at spacing %g px", scale, *full[0], *sizes[0], extent, why, spacing)
    return scale, why, shapes, [scale_camera(cam, scale) for cam in cams]


# --------------------------------------------------------------------------- kinds
def detect_kind(inputs: Sequence[str | os.PathLike], rig: str | os.PathLike | None = None,
                kind: str | None = None) -> str:
    """Tell what INPUT is: ``scene`` recipe, ``stereo`` pair, image ``folder`` or ``cloud``.

    Rules: two inputs are a stereo pair (LEFT RIGHT, with ``--rig``); a
    ``.toml`` file is a scene recipe; a point-cloud suffix (.ply .xyz .csv .npz
    .txt .pts) is a cloud; a folder with exactly two images and a rig/camera
    file (or ``--rig``) is a stereo pair, with more images an image folder.
    ``kind`` (``--kind``) overrides the detection but is still checked.
    """
    paths = [Path(p) for p in inputs]
    if not paths or len(paths) > 2:
        raise InputError(f"INPUT: expected one input or LEFT RIGHT, got {len(paths)} paths")
    for p in paths:
        if not p.exists():
            raise FileNotFoundError(f"{p}: no such file or folder")
    if kind is not None and kind not in KINDS:
        raise InputError(f"--kind {kind!r}: choose one of {', '.join(KINDS)}")
    if len(paths) == 2:
        if kind not in (None, "stereo"):
            raise InputError(f"--kind {kind}: two inputs (LEFT RIGHT) can only be a stereo pair")
        for p in paths:
            if not p.is_file() or p.suffix.lower() not in IMAGE_SUFFIXES:
                raise InputError(f"{p}: a stereo pair needs two image files "
                                 f"({', '.join(IMAGE_SUFFIXES)})")
        if rig is None:
            raise InputError(f"{paths[0]} {paths[1]}: a stereo pair needs --rig RIG.yml")
        return "stereo"
    path = paths[0]
    if kind is not None:
        detected = kind
    elif path.is_file() and path.suffix.lower() == ".toml":
        detected = "scene"
    elif path.is_file() and path.suffix.lower() in CLOUD_SUFFIXES:
        detected = "cloud"
    elif path.is_dir():
        images = folder_images(path)
        if len(images) == 2 and (rig is not None or folder_rig(path) is not None):
            detected = "stereo"
        elif len(images) >= 2:
            detected = "folder"
        else:
            raise InputError(f"{path}: folder holds {len(images)} images; need 2 (stereo, with a "
                             "rig file) or more (image folder)")
    else:
        raise InputError(f"{path}: cannot tell what this is (expected a scene recipe .toml, a "
                         f"point cloud {'/'.join(CLOUD_SUFFIXES)}, or a folder of images); "
                         "force it with --kind")
    if detected == "scene" and not path.is_file():
        raise InputError(f"{path}: --kind scene needs a recipe .toml file")
    if detected == "cloud" and not path.is_file():
        raise InputError(f"{path}: --kind cloud needs a point-cloud file")
    if detected in ("stereo", "folder") and not path.is_dir():
        raise InputError(f"{path}: --kind {detected} needs a folder of images (or LEFT RIGHT)")
    return detected


def scene_source(scene_dir: str | os.PathLike) -> str:
    """What a rendered scene folder is as an input: ``"stereo"`` (a pair) or ``"folder"``.

    The recipe's camera layout in ``scene.json`` decides; without one, two images are a
    stereo pair and more an image folder.
    """
    scene_dir = Path(scene_dir)
    meta = scene_dir / "scene.json"
    layout = None
    if meta.is_file():
        recipe = json.loads(meta.read_text(encoding="utf-8"))
        layout = recipe.get("cameras", {}).get("layout") or recipe.get("recipe", {}).get(
            "cameras", {}).get("layout")
    if not layout:
        layout = "stereo" if len(folder_images(scene_dir)) == 2 else "ring"
    return "stereo" if str(layout) == "stereo" else "folder"


def folder_rig(folder: Path) -> Path | None:
    """The rig/camera file of a stereo folder (:data:`RIG_NAMES`), or None."""
    for name in RIG_NAMES:
        if (Path(folder) / name).is_file():
            return Path(folder) / name
    return None


def stereo_inputs(inputs: Sequence[Path], rig: Path | None) -> tuple[Path, Path, Path]:
    """``(left, right, rig)`` for a stereo input given as LEFT RIGHT or as a folder."""
    if len(inputs) == 2:
        left, right = inputs
    else:
        left, right = folder_images(inputs[0])[:2]
        rig = rig or folder_rig(inputs[0])
    if rig is None:
        raise InputError(f"{inputs[0]}: no rig file (give --rig RIG.yml)")
    return Path(left), Path(right), Path(rig)
