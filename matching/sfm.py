r"""Cameras and poses of an image folder by structure from motion (pycolmap, CPU).

Incremental SfM [1]_ minimises the reprojection error over all intrinsics,
poses and sparse points,

.. math::  \min_{K, R_i, t_i, X_j} \sum_{(i,j)}
           \rho\big(\lVert x_{ij} - \pi(K, R_i, t_i; X_j)\rVert^2\big),

starting from SIFT features [2]_ matched exhaustively (small sets) or
sequentially (large, ordered sets) and verified by two-view geometry.  The
solution is defined up to a similarity :math:`X \mapsto s R X + t`
(7 degrees of freedom): the scale is arbitrary unless a known distance fixes
it, and comparing with another frame takes a similarity alignment, estimated
here in closed form by Umeyama's method [3]_:

.. math::  \Sigma = \tfrac1n \sum (y_i - \mu_y)(x_i - \mu_x)^T = U D V^T,\quad
           R = U S V^T,\quad s = \operatorname{tr}(D S) / \sigma_x^2,\quad
           t = \mu_y - s R \mu_x,

with :math:`S = \mathrm{diag}(1, 1, \operatorname{sign}\det U \det V)`.

COLMAP's pixel origin is the corner of the top-left pixel; cameras are
returned in OpenCV's convention (see :mod:`matching.cameras`).

References
----------
.. [1] J. L. Schönberger and J.-M. Frahm, "Structure-from-Motion Revisited",
   CVPR (2016).
.. [2] D. G. Lowe, "Distinctive Image Features from Scale-Invariant
   Keypoints", IJCV 60(2) (2004).
.. [3] S. Umeyama, "Least-Squares Estimation of Transformation Parameters
   Between Two Point Patterns", IEEE TPAMI 13(4), 376-380 (1991).
"""

from __future__ import annotations

import contextlib
import logging
import os
import sqlite3
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np

from matching.cameras import Camera, cameras_from_pycolmap, turn_camera
from matching.colmap_log import quiet_colmap as _quiet_colmap
from matching.image_file import read_image_file
from matching.validate import TOL, check_shape

__all__ = [
    "SfmResult",
    "run_sfm",
    "list_images",
    "umeyama",
    "transform_cameras",
    "fix_scale",
    "align_to_reference",
]

log = logging.getLogger(__name__)

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".ppm", ".pgm", ".webp")
MATCHERS = ("auto", "exhaustive", "selected", "sequential", "ordered")
REFINEMENTS = ("auto", "lsm", "none")
#: "auto" matches exhaustively up to this many images: n(n-1)/2 pairs, ~1200
#: pairs at 50 images, a few minutes of SIFT matching on 2 cores.
EXHAUSTIVE_MAX_IMAGES = 50
#: "selected" pairs: a coarse pass (SIFT on each image at this longer side, at most
#: ``COARSE_FEATURES`` features, every pair matched and verified) finds which pairs
#: overlap; only those are matched at full size (:func:`_overlapping_pairs`).  Not the
#: default: on the rendered phone ring it cost more than matching every pair
#: (docs/decisions/photo-folders.md).
COARSE_SIDE = 800
COARSE_FEATURES = 1024
#: A pair the coarse pass verified with at least this many inlier matches is matched at
#: full size: COLMAP's mapper uses no pair with fewer (``min_num_matches``, 15).
COARSE_MIN_INLIERS = 15
#: ... and each image's best pairs by coarse inliers, whatever their count (so that no
#: image is left without a pair to be registered by).
COARSE_BEST_PER_IMAGE = 3
#: SIFT runs on each image reduced to this longer side (``FeatureExtractionOptions.
#: max_image_size``; COLMAP's default is 3 200).  About the size least-squares matching
#: reads the views at (the object ~1 500 px across, :mod:`matching.resolution`).  A
#: rendered phone ring (30 views of 4 000 x 3 000 with true cameras): 3 200 px took 291
#: CPU-s (extraction ~100); 1 600 px 120 CPU-s (extraction 31, exhaustive matching of
#: 435 pairs 42, mapping 46), peak 0.48 GB, 30/30 registered, reprojection 0.665 px,
#: rotations 0.014 deg median / 0.032 max from the truth, centres 0.017 % of the ring's
#: radius, focal length -0.55 %.  Sceaux (11 views of 2 832 px): 11/11 either way,
#: reprojection 0.635 -> 0.729 px, 7 785 -> 4 271 sparse points, 42 -> 19.5 CPU-s.
SIFT_MAX_IMAGE_SIZE = 1600
#: Images at least this long (longer side, px, as SIFT sees them) skip SIFT's 2x
#: upsampled first octave (COLMAP's ``first_octave`` -1 -> 0): they have features enough
#: at full scale, and the upsampled scale space is what filled memory.  Sceaux (11 views,
#: 2 832 px): peak 3.69 -> 1.12 GB, 11/11 registered both ways, reprojection 0.61 ->
#: 0.63 px, 7 881 -> 7 785 sparse points, focal 2 973 -> 2 971 px.  Smaller images keep
#: COLMAP's default (-1).
SIFT_FULL_SCALE_PX = 1600
#: At most this many SIFT features an image (COLMAP's ``max_num_features``, 8 192).  At
#: 4 096 the rendered phone ring's exhaustive matching took the same 42 CPU-s: its
#: images at 1 600 px hold fewer features than either bound.
SIFT_MAX_FEATURES = 8192
#: "ordered" pairs: an image is matched with the next ones in name order (cyclically:
#: the last with the first, a ring's closure) until this many in a row verify with
#: fewer than ``COARSE_MIN_INLIERS`` inliers (:func:`_ordered_pairs`).  Not the default:
#: on the 30-view rendered ring of 1 000 x 750 every pair up to 10 steps (120 deg) apart
#: verified, so it matched 360 of 435 pairs, in 11 rounds that cost 97.9 CPU-s against
#: 60.9 for all 435 in one call (30/30 registered either way).
ORDERED_MISSES = 2


@dataclass(frozen=True, eq=False)
class SfmResult:
    """Cameras, sparse points and a report of an SfM run.

    Attributes
    ----------
    cameras : list of Camera
        Registered images, sorted by name, OpenCV convention.
    points : (N, 3) float64
        Sparse points, in the same (arbitrary unless fixed) frame and scale.
    track_length : (N,) int64
        Number of images observing each point.
    colors : (N, 3) uint8
        RGB colour of each point: zeros (the mapper does not read every image at full
        size again for them; nothing here uses them).
    registered : list of str
        Names of the registered images.
    unregistered : list of str
        Images given but not registered (never silently dropped).
    ignored : list of str
        Files in the folder that are not images by suffix.
    mean_reprojection_error_px : float
    scale : float
        Factor applied to COLMAP's frame (1.0: the scale is arbitrary).
    scale_fixed : bool
        True once a known distance or a reference frame fixed the scale.
    matcher : str
        "exhaustive" or "sequential".
    """

    cameras: list[Camera]
    points: np.ndarray
    track_length: np.ndarray
    colors: np.ndarray
    registered: list[str]
    unregistered: list[str]
    ignored: list[str] = field(default_factory=list)
    mean_reprojection_error_px: float = float("nan")
    scale: float = 1.0
    scale_fixed: bool = False
    matcher: str = "exhaustive"
    refinement: dict = field(default_factory=dict)

    def report(self) -> dict:
        """Plain-type summary for logs and JSON."""
        return {
            "registered": len(self.registered),
            "unregistered": list(self.unregistered),
            "ignored": list(self.ignored),
            "sparse_points": int(len(self.points)),
            "mean_track_length": float(np.mean(self.track_length)) if len(self.points) else 0.0,
            "mean_reprojection_error_px": float(self.mean_reprojection_error_px),
            "scale_factor": float(self.scale),
            "scale": "fixed" if self.scale_fixed else "arbitrary (similarity gauge of SfM)",
            "matcher": self.matcher,
            "refinement": dict(self.refinement),
        }


# --------------------------------------------------------------- similarity
def umeyama(src, dst, with_scale: bool = True) -> tuple[float, np.ndarray, np.ndarray]:
    """Least-squares similarity ``dst ≈ s R src + t`` (Umeyama 1991).

    Parameters
    ----------
    src, dst : (N, 3) float64
        Corresponding points, N >= 3, not all on one line.
    with_scale : bool
        Estimate s; otherwise s = 1 (rigid motion).

    Returns
    -------
    s : float
    R : (3, 3) float64, det +1
    t : (3,) float64
    """
    src = check_shape(src, "(N, 3)", "src", dtype=np.float64)
    dst = check_shape(dst, "(N, 3)", "dst", dtype=np.float64)
    if len(src) != len(dst):
        raise ValueError(f"src and dst must have the same length, got {len(src)} and {len(dst)}")
    if len(src) < 3:
        raise ValueError(f"umeyama needs at least 3 point pairs, got {len(src)}")
    mu_s, mu_d = src.mean(axis=0), dst.mean(axis=0)
    a, b = src - mu_s, dst - mu_d
    var_s = np.mean(np.sum(a * a, axis=1))
    sigma = b.T @ a / len(src)  # (3, 3) cross-covariance
    U, D, Vt = np.linalg.svd(sigma)
    if var_s <= TOL.zero or D[1] <= TOL.zero * max(D[0], TOL.zero):
        raise ValueError("umeyama: the points are (nearly) collinear or coincident; the "
                         "rotation is not determined")
    S = np.diag([1.0, 1.0, np.sign(np.linalg.det(U) * np.linalg.det(Vt)) or 1.0])
    R = U @ S @ Vt
    s = float(np.trace(np.diag(D) @ S) / var_s) if with_scale else 1.0
    return s, R, mu_d - s * R @ mu_s


def transform_cameras(cameras: Sequence[Camera], s: float, R, t) -> list[Camera]:
    """Cameras after the world moved by ``X' = s R X + t`` (they see the same pixels).

    With :math:`X = R^T (X' - t) / s`, the camera frame scaled by s gives
    :math:`R_c' = R_c R^T` and :math:`t_c' = s\\,t_c - R_c' t`.
    """
    R = check_shape(R, "(3, 3)", "R", dtype=np.float64)
    t = check_shape(t, "(3,)", "t", dtype=np.float64)
    if not s > 0:
        raise ValueError(f"scale s must be positive, got {s}")
    out = []
    for cam in cameras:
        R_new = cam.R @ R.T
        out.append(replace(cam, R=R_new, t=s * cam.t - R_new @ t))
    return out


def _transform_result(result: SfmResult, s: float, R, t, scale_fixed: bool) -> SfmResult:
    points = s * result.points @ np.asarray(R).T + t if len(result.points) else result.points
    return replace(result, cameras=transform_cameras(result.cameras, s, R, t), points=points,
                   scale=result.scale * s, scale_fixed=scale_fixed)


def fix_scale(result: SfmResult, name_a: str, name_b: str, distance: float) -> SfmResult:
    """Scale the reconstruction so that the centres of two images are ``distance`` apart."""
    if not distance > 0:
        raise ValueError(f"known distance must be positive, got {distance}")
    by_name = {cam.name: cam for cam in result.cameras}
    for name in (name_a, name_b):
        if name not in by_name:
            raise ValueError(f"known distance: image {name!r} is not registered "
                             f"(registered: {', '.join(result.registered)})")
    d = np.linalg.norm(by_name[name_a].center - by_name[name_b].center)
    if d <= TOL.zero:
        raise ValueError(f"known distance: {name_a} and {name_b} have the same centre")
    return _transform_result(result, distance / d, np.eye(3), np.zeros(3), True)


def align_to_reference(result: SfmResult, reference: Sequence[Camera],
                       with_scale: bool = True) -> tuple[SfmResult, float]:
    """Align an SfM result to reference cameras by their centres (matched by name).

    Returns
    -------
    aligned : SfmResult
    rms : float
        RMS distance between aligned and reference centres, reference units.
    """
    ref = {cam.name: cam for cam in reference}
    pairs = [(cam.center, ref[cam.name].center) for cam in result.cameras if cam.name in ref]
    if len(pairs) < 3:
        raise ValueError(f"need at least 3 registered images with a reference camera, got "
                         f"{len(pairs)}")
    src, dst = (np.array(v) for v in zip(*pairs, strict=True))
    s, R, t = umeyama(src, dst, with_scale)
    rms = float(np.sqrt(np.mean(np.sum((s * src @ R.T + t - dst) ** 2, axis=1))))
    return _transform_result(result, s, R, t, True), rms


# --------------------------------------------------------------- SfM run
def list_images(folder: str | os.PathLike) -> tuple[list[str], list[str]]:
    """Image names (by suffix, sorted) and the other file names of a folder."""
    folder = Path(folder)
    if not folder.exists():
        raise FileNotFoundError(f"{folder}: no such folder")
    if not folder.is_dir():
        raise NotADirectoryError(f"{folder}: not a folder")
    files = sorted(p for p in folder.iterdir() if p.is_file() and not p.name.startswith("."))
    images = [p.name for p in files if p.suffix.lower() in IMAGE_SUFFIXES]
    others = [p.name for p in files if p.suffix.lower() not in IMAGE_SUFFIXES]
    return images, others


def exif_focal_px(path: str | os.PathLike) -> float | None:
    """The focal length in pixels of the stored image that its EXIF gives (focal length in
    mm and the sensor width of COLMAP's camera database, or the 35 mm equivalent), as
    COLMAP reads it; None when the file has none."""
    import pycolmap

    bitmap = pycolmap.Bitmap.read(str(path), False)
    focal = bitmap.exif_focal_length() if bitmap is not None else None
    return float(focal) if focal is not None and np.isfinite(focal) and focal > 0 else None


def _image_sizes(folder: Path, names: list[str]) -> tuple[dict[str, tuple[int, int]], set[str]]:
    """Each image's (width, height) as the user sees it (its EXIF orientation applied),
    and the images COLMAP cannot be given as they are: an EXIF orientation other than 1
    (COLMAP would see the stored pixels) or a name that is not UTF-8 (COLMAP's names are
    UTF-8 strings)."""
    sizes, restage = {}, set()
    for name in names:
        image, orientation = read_image_file(folder / name)
        if image is None:
            raise ValueError(f"{folder / name}: not a readable image")
        sizes[name] = (image.shape[1], image.shape[0])
        if orientation != 1 or _staged_name(name) != name:
            restage.add(name)
    return sizes, restage


def _staged_name(name: str) -> str:
    """A UTF-8 name for ``name`` (a name that is not UTF-8 has its bytes spelt ``\\xNN``)."""
    return name.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")


def _turned_views(sizes: dict[str, tuple[int, int]]) -> dict[str, int]:
    """Images of one camera held both ways (portrait and landscape): the quarter turns
    (np.rot90) that bring each image of the less common orientation to the other's.

    Empty unless every image has one of two sizes that are each other's transpose (one
    sensor, turned): then one shared camera fits them all once they are turned upright,
    where COLMAP's per-image cameras would each need their own focal length.
    """
    counts: dict[tuple[int, int], int] = {}
    for size in sizes.values():
        counts[size] = counts.get(size, 0) + 1
    if len(counts) != 2:
        return {}
    (a, _), (b, _) = sorted(counts.items(), key=lambda kv: (-kv[1], kv[0][1] > kv[0][0]))
    if a != (b[1], b[0]):
        return {}
    return {name: 1 for name, size in sizes.items() if size == b}


def _stage_upright(image_dir: Path, names: list[str], turned: dict[str, int],
                   work: Path, restage: set[str] = frozenset()) -> tuple[Path, dict[str, str]]:
    """A folder COLMAP reads as the user sees it: the images ``turned`` by quarter turns
    to one orientation and those in ``restage`` (an EXIF orientation, a name that is not
    UTF-8) written upright as lossless PNG (``NAME.png``, the name spelt in UTF-8), the
    others linked (or copied).  Returns the folder and each staged name's original name."""
    staged = work / "upright"
    staged.mkdir(exist_ok=True)
    original = {}
    for name in names:
        written = name in turned or name in restage
        target = staged / (f"{_staged_name(name)}.png" if written else name)
        target.unlink(missing_ok=True)
        if written:
            image, _ = read_image_file(image_dir / name)
            if not cv2.imwrite(str(target), np.ascontiguousarray(
                    np.rot90(image, turned.get(name, 0)))):
                raise ValueError(f"{target}: could not write an upright copy of {name}")
        else:
            try:
                target.symlink_to((image_dir / name).resolve())
            except OSError:
                target.write_bytes((image_dir / name).read_bytes())
        original[target.name] = name
    return staged, original


def _turn_back(result: SfmResult, original: dict[str, str],
               turned: dict[str, int]) -> SfmResult:
    """The SfM result of a staged folder in the original images' names and upright frames."""
    cameras = []
    for cam in result.cameras:
        name = original[cam.name]
        back = turn_camera(cam, -turned[name]) if name in turned else cam
        cameras.append(replace(back, name=name))
    return replace(result, cameras=cameras,
                   registered=[original[n] for n in result.registered],
                   unregistered=[original[n] for n in result.unregistered])


def run_sfm(image_dir: str | os.PathLike, work_dir: str | os.PathLike | None = None,
            image_names: Sequence[str] | None = None, matcher: str = "auto",
            single_camera: bool | None = None, camera_model: str = "SIMPLE_RADIAL",
            known_distance: tuple[str, str, float] | None = None,
            num_threads: int | None = None, seed: int = 0,
            intrinsics=None, refine: str = "auto") -> SfmResult:
    """Recover intrinsics and poses of the images in a folder with pycolmap on the CPU.

    Parameters
    ----------
    image_dir : path
        Folder of images (by suffix: png, jpg, tif, bmp, ppm, pgm, webp).
    work_dir : path, optional
        Where the feature database and the sparse model (``sparse/``, COLMAP
        binary) are kept, and the refined model (``sparse_refined/``, see
        ``refine``); default a temporary folder, removed afterwards.
    image_names : sequence of str, optional
        Use only these images of the folder.
    matcher : {"auto", "exhaustive", "selected", "sequential"}
        "auto": exhaustive up to ``EXHAUSTIVE_MAX_IMAGES`` images, else
        sequential (images ordered by name, as a walk-around sequence).  "selected":
        only the pairs a coarse matching pass finds overlapping
        (:func:`_overlapping_pairs`).  "ordered": each image with the next ones in
        name order while they overlap (:func:`_ordered_pairs`).
    single_camera : bool, optional
        One shared camera for all images (one physical camera, fixed zoom).
        Default: True when all images have the same size, and when they are one
        sensor's portrait and landscape shots (two sizes, each the other's transpose;
        not with ``intrinsics`` or the OPENCV model): those of the less common
        orientation are matched turned upright (lossless copies in the work folder)
        and their cameras turned back (:func:`matching.cameras.turn_camera`).  Other
        mixed sizes: a camera per image.
    camera_model : str
        COLMAP model: SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV.
    known_distance : (name_a, name_b, distance), optional
        Fix the scale: the centres of these two images are ``distance`` apart.
    num_threads : int, optional
        Default: all cores.
    seed : int
        Random seed of the mapper (RANSAC), for repeatable runs.
    intrinsics : (3, 3) array_like, optional
        The images' known camera matrix K (OpenCV convention, one camera for all;
        e.g. from a cameras file without poses): a PINHOLE camera with these values
        (COLMAP's principal point is OpenCV's + 0.5), held fixed in every bundle
        adjustment (unknown intrinsics trade against the poses on a narrow field of
        view).
    refine : {"auto", "lsm", "none"}
        "lsm": re-measure every track by least-squares matching against one
        reference observation and bundle-adjust again, with outlier rounds
        (:func:`matching.sfm_refine.refine_tracks_lsm`, :func:`~matching.sfm_refine.
        bundle_adjust`; intrinsics held if given).  "auto" (default): "lsm" when
        ``intrinsics`` are given, else "none" (the figures that decided both:
        ``docs/decisions/photo-folders.md``, *SfM: turned views, known K, LSM refinement*).

    Notes
    -----
    Cameras refer to the images as the user sees them (:mod:`matching.image_file`): an
    image with an EXIF orientation other than 1, or whose name is not UTF-8, is given to
    COLMAP as an upright lossless copy in the work folder (COLMAP would read the stored
    pixels, or fail on the name).  When the mapper leaves images out, it is run once more
    with the registration thresholds halved (:func:`_mapped`).

    Returns
    -------
    SfmResult
        The largest reconstruction; images outside it are listed as unregistered.

    Raises
    ------
    FileNotFoundError, NotADirectoryError
        No such folder.
    ValueError
        Fewer than 2 images, unreadable image, unknown matcher/model, mixed
        sizes with ``single_camera=True``, or no image registered.
    """
    image_dir = Path(image_dir)
    names, others, matcher = _checked_request(image_dir, image_names, matcher, refine,
                                              camera_model)
    by_name, restage = _image_sizes(image_dir, names)
    turned, sizes, single_camera = _camera_sharing(image_dir, names, by_name, single_camera,
                                                   intrinsics, camera_model)
    threads = int(num_threads) if num_threads else (os.cpu_count() or 1)

    reconstructions, names, original, read_dir, step = _sparse_models(
        image_dir, names, work_dir, turned, restage, sizes, by_name,
        dict(single_camera=single_camera, intrinsics=intrinsics, camera_model=camera_model,
             threads=threads, matcher=matcher, seed=seed))
    if not reconstructions:
        raise ValueError(f"{image_dir}: SfM registered no image ({len(names)} images; too "
                         "little texture or overlap for SIFT matches?)")
    best = max(reconstructions.values(), key=lambda r: r.num_reg_images())
    if refine == "auto":
        refine = "lsm" if intrinsics is not None else "none"
    refinement = (_refined(best, read_dir, intrinsics is None, work_dir, step)
                  if refine == "lsm" else {})
    result = replace(_result_from(best, names, others, matcher), refinement=refinement)
    if turned or restage:
        result = _turn_back(result, original, turned)
    _log_outcome(result, len(reconstructions), len(names), step)
    return fix_scale(result, *known_distance) if known_distance is not None else result


def _sparse_models(image_dir: Path, names: list, work_dir, turned: dict, restage: set,
                   sizes: set, by_name: dict, how: dict) -> tuple:
    """In the work folder (a temporary one unless ``work_dir``): the images staged upright
    where needed (:func:`_stage_upright`), their features extracted and matched, and
    mapped (:func:`_mapped`); ``how``: ``single_camera``, ``intrinsics``, ``camera_model``,
    ``threads``, ``matcher``, ``seed``.  Returns ``(reconstructions, names, original,
    read_dir, step)``: the names COLMAP saw, each one's original and the folder read."""
    import pycolmap

    single_camera, intrinsics, threads = how["single_camera"], how["intrinsics"], how["threads"]
    with contextlib.ExitStack() as stack:
        if work_dir is None:
            work = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="photosurf-sfm-")))
        else:
            work = Path(work_dir)
            work.mkdir(parents=True, exist_ok=True)
        original, read_dir = {name: name for name in names}, image_dir
        if turned or restage:
            read_dir, original = _stage_upright(image_dir, names, turned, work, restage)
            names = sorted(original)
            log.info("SfM: %d of %d images turned upright to share one camera, %d by their "
                     "EXIF orientation or name", len(turned), len(names), len(restage))
        database = work / "database.db"
        database.unlink(missing_ok=True)
        reader, single_camera = _reader_options(
            image_dir, original, turned, restage, single_camera, intrinsics, how["camera_model"],
            sizes)
        mode = pycolmap.CameraMode.SINGLE if single_camera else pycolmap.CameraMode.PER_IMAGE
        step = _Steps()
        _extract_and_match(database, read_dir, names, reader, mode, threads, how["matcher"], work,
                           min(min(max(size), SIFT_MAX_IMAGE_SIZE) for size in by_name.values()),
                           step)
        reconstructions = _mapped(database, read_dir, work, len(names), threads, how["seed"],
                                  intrinsics is not None, step)
    return reconstructions, names, original, read_dir, step


def _camera_sharing(image_dir: Path, names: list, by_name: dict, single_camera, intrinsics,
                    camera_model: str) -> tuple[dict, set, bool]:
    """Which images share one camera: ``(turned, sizes, single_camera)`` -- portrait and
    landscape shots of one camera (:func:`_turned_views`; not with ``intrinsics`` or the
    OPENCV model, nor a given ``single_camera``) turned upright, the image sizes SfM
    sees, and one camera by default when they are all of one size."""
    sizes = set(by_name.values())
    turned = (_turned_views(by_name) if single_camera is None and intrinsics is None
              and camera_model != "OPENCV" else {})
    if turned:  # the images SfM sees: all of one size
        sizes = {by_name[name] for name in names if name not in turned}
    if single_camera is None:
        single_camera = len(sizes) == 1
    elif single_camera and len(sizes) > 1:
        raise ValueError(f"{image_dir}: single_camera but the images have {len(sizes)} sizes: "
                         f"{sorted(sizes)}")
    return turned, sizes, single_camera


def _log_outcome(result: SfmResult, models: int, count: int, step: _Steps) -> None:
    """The warnings on a split model or unregistered images, and the last step line."""
    if models > 1:
        log.warning("SfM split the images into %d models; kept the largest (%d images)",
                    models, len(result.registered))
    if result.unregistered:
        log.warning("SfM did not register %d image(s): %s", len(result.unregistered),
                    ", ".join(result.unregistered))
    step("done: %d of %d images registered, reprojection %.3f px", len(result.registered),
         count, result.mean_reprojection_error_px)


def _checked_request(image_dir: Path, image_names, matcher: str, refine: str,
                     camera_model: str) -> tuple[list, list, str]:
    """:func:`run_sfm`'s options checked, the images it uses and the matcher:
    ``(names, others, matcher)`` (``others``: the folder's files that are not images;
    "auto" resolved)."""
    names, others = list_images(image_dir)
    if image_names is not None:
        missing = sorted(set(image_names) - set(names))
        if missing:
            raise ValueError(f"{image_dir}: no image(s) {', '.join(missing)}")
        names = [n for n in names if n in set(image_names)]
    if len(names) < 2:
        raise ValueError(f"{image_dir}: SfM needs at least 2 images, found {len(names)}"
                         + (f" (other files: {', '.join(others[:5])})" if others else ""))
    if refine not in REFINEMENTS:
        raise ValueError(f"refine must be one of {', '.join(REFINEMENTS)}, got {refine!r}")
    if matcher not in MATCHERS:
        raise ValueError(f"matcher must be one of {', '.join(MATCHERS)}, got {matcher!r}")
    models = ("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV")
    if camera_model not in models:
        raise ValueError(f"camera_model must be one of {', '.join(models)}, got {camera_model!r}")
    if matcher == "auto":
        matcher = "exhaustive" if len(names) <= EXHAUSTIVE_MAX_IMAGES else "sequential"
    if matcher in ("selected", "ordered") and any(any(c.isspace() for c in n) for n in names):
        matcher = "exhaustive"  # COLMAP's pair list separates the names by a space
    return names, others, matcher


def _reader_options(image_dir: Path, original: dict, turned: dict, restage: set,
                    single_camera: bool, intrinsics, camera_model: str, sizes: set):
    """COLMAP's image reader options: the camera model and its starting parameters (the
    originals' EXIF focal length for staged copies, or the given ``intrinsics``, held as a
    PINHOLE camera); ``(reader, single_camera)``."""
    import pycolmap

    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = camera_model
    focal = _staged_focal(image_dir, original, turned, restage, single_camera, intrinsics)
    if focal is not None:  # the staged PNGs carry no EXIF: its focal length given here
        width, height = next(iter(sizes))
        extra = {"SIMPLE_PINHOLE": "", "PINHOLE": None, "SIMPLE_RADIAL": ",0",
                 "RADIAL": ",0,0"}.get(camera_model)
        if camera_model == "PINHOLE":
            reader.camera_params = f"{focal},{focal},{width / 2},{height / 2}"
        elif extra is not None:
            reader.camera_params = f"{focal},{width / 2},{height / 2}{extra}"
        log.info("SfM: starting focal length %.1f px from the EXIF of the originals", focal)
    if intrinsics is not None:
        K = check_shape(intrinsics, "(3, 3)", "intrinsics", dtype=np.float64)
        if not (K[0, 0] > 0 and K[1, 1] > 0 and np.all(np.isfinite(K))):
            raise ValueError(f"intrinsics must have positive focal lengths, got {K.tolist()}")
        reader.camera_model = "PINHOLE"
        reader.camera_params = (f"{float(K[0, 0])},{float(K[1, 1])},{float(K[0, 2]) + 0.5},"
                                f"{float(K[1, 2]) + 0.5}")
        single_camera = True
        if len(sizes) > 1:
            raise ValueError(f"{image_dir}: one intrinsics matrix but the images have "
                             f"{len(sizes)} sizes: {sorted(sizes)}")
    return reader, single_camera


def _extract_and_match(database: Path, read_dir: Path, names: list, reader, mode,
                       threads: int, matcher: str, work: Path, sift_side: int,
                       step: _Steps) -> None:
    """SIFT features of the images into ``database`` (full scale from the first octave when
    the smallest image's side used is at least ``SIFT_FULL_SCALE_PX``), then matched by
    ``matcher`` ("selected": the pairs :func:`_overlapping_pairs` finds, listed in
    ``work/pairs.txt``)."""
    import pycolmap

    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = threads
    extraction.max_image_size = SIFT_MAX_IMAGE_SIZE
    extraction.sift.max_num_features = SIFT_MAX_FEATURES
    if sift_side >= SIFT_FULL_SCALE_PX:
        extraction.sift.first_octave = 0
    step("extracting SIFT features of %d images (longer side <= %d px)", len(names),
         SIFT_MAX_IMAGE_SIZE)
    with _quiet_colmap():  # per call: the step lines between calls reach stderr
        pycolmap.extract_features(database, read_dir, image_names=names, camera_mode=mode,
                                  reader_options=reader, extraction_options=extraction,
                                  device=pycolmap.Device.cpu)
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = threads
    step("matching features (%s%s)", matcher, f", {len(names) * (len(names) - 1) // 2} "
         "pairs" if matcher == "exhaustive" else "")
    with _quiet_colmap():
        if matcher == "exhaustive":
            pycolmap.match_exhaustive(database, matching_options=matching,
                                      device=pycolmap.Device.cpu)
        elif matcher == "selected":
            pairs = _overlapping_pairs(read_dir, names, reader, mode, threads, work)
            listed = work / "pairs.txt"
            listed.write_text("".join(f"{a} {b}\n" for a, b in pairs))
            step("matching %d of %d pairs at full size (those a coarse pass found "
                 "overlapping)", len(pairs), len(names) * (len(names) - 1) // 2)
            pycolmap.match_image_pairs(
                database, matching_options=matching,
                pairing_options=pycolmap.ImportedPairingOptions(match_list_path=str(listed)),
                device=pycolmap.Device.cpu)
        elif matcher == "ordered":
            pairs = _ordered_pairs(database, names, matching, work)
            step("matched %d of %d pairs (each image with the next in name order while "
                 "they overlap)", pairs, len(names) * (len(names) - 1) // 2)
        else:
            pycolmap.match_sequential(database, matching_options=matching,
                                      device=pycolmap.Device.cpu)


def _mapped(database: Path, read_dir: Path, work: Path, count: int, threads: int, seed: int,
            fixed_intrinsics: bool, step: _Steps) -> dict:
    """COLMAP's incremental mapping of the matched images (``work/sparse``); when it leaves
    images out, once more with the registration thresholds halved (at least 15 inlier
    correspondences for a new image instead of 30, 50 for the initial pair instead of
    100; ``work/sparse_relaxed``), kept if it registers more: a small object against a
    plain background gives neighbouring views few common features, and a ring whose views
    are all registered closes its loop.  Returns the reconstructions by index."""
    import pycolmap

    step("incremental mapping")
    sparse = work / "sparse"
    sparse.mkdir(exist_ok=True)
    options = pycolmap.IncrementalPipelineOptions()
    options.num_threads = threads
    options.random_seed = seed
    # no colours for the sparse points (COLMAP decodes every image at full size once
    # more for them: 30 12 MP JPEGs, single-threaded at the end of the mapping), and the
    # bundle adjustments on every thread from 1 000 residuals (COLMAP: 50 000, so the
    # local ones ran on one core); the same poses (rendered 12 MP ring: 30/30, every
    # rotation and centre as before)
    options.extract_colors = False
    options.ba_min_num_residuals_for_cpu_multi_threading = 1000
    if fixed_intrinsics:
        options.ba_refine_focal_length = False
        options.ba_refine_principal_point = False
        options.ba_refine_extra_params = False
    with _quiet_colmap():
        reconstructions = pycolmap.incremental_mapping(database, read_dir, sparse,
                                                       options=options)
    if reconstructions and max(r.num_reg_images() for r in reconstructions.values()) < count:
        options.mapper.abs_pose_min_num_inliers = 15
        options.mapper.init_min_num_inliers = 50
        options.min_num_matches = 10
        step("mapping again with halved registration thresholds (%d of %d registered)",
             max(r.num_reg_images() for r in reconstructions.values()), count)
        retry = work / "sparse_relaxed"
        retry.mkdir(exist_ok=True)
        with _quiet_colmap():
            again = pycolmap.incremental_mapping(database, read_dir, retry, options=options)
        if again and (max(r.num_reg_images() for r in again.values())
                      > max(r.num_reg_images() for r in reconstructions.values())):
            reconstructions = again
    return reconstructions


def _refined(best, read_dir: Path, refine_intrinsics: bool, work_dir, step: _Steps) -> dict:
    """``refine="lsm"``: every track re-measured by LSM and the model bundle-adjusted again
    (:mod:`matching.sfm_refine`; written to ``work_dir/sparse_refined`` when kept); the
    refinement's record."""
    from matching.sfm_refine import bundle_adjust, refine_tracks_lsm

    step("re-measuring the tie points by LSM and adjusting")
    with _quiet_colmap():
        before = float(best.compute_mean_reprojection_error())
        refinement = refine_tracks_lsm(best, read_dir)
        adjustment = bundle_adjust(best, refine_intrinsics=refine_intrinsics)
        if work_dir is not None:
            refined = Path(work_dir) / "sparse_refined"
            refined.mkdir(exist_ok=True)
            best.write(refined)
    return {"method": "lsm", "reprojection_before_px": before, **refinement,
            "ba_rejected": adjustment["rejected"], "ba_sigma_px": adjustment["sigma_px"],
            "ba_converged": adjustment["converged"]}


class _Steps:
    """One progress line per step of SfM (logger ``photosurf.progress``, shown at the
    command line's default verbosity: :mod:`pipeline.logs`), with the seconds the previous
    step took (wall and the process's CPU seconds, every thread)."""

    def __init__(self):
        self._clock, self._cpu = time.monotonic, time.process_time
        self._last, self._last_cpu = self._clock(), self._cpu()

    def __call__(self, message: str, *args) -> None:
        now, cpu = self._clock(), self._cpu()
        logging.getLogger("photosurf.progress").info(
            "SfM: " + message + " (previous step %.1f s, %.1f CPU-s)", *args, now - self._last,
            cpu - self._last_cpu)
        self._last, self._last_cpu = now, cpu


def _staged_focal(image_dir: Path, original: dict, turned: dict, restage: set,
                  single_camera: bool, intrinsics) -> float | None:
    """The EXIF focal length (px) to start from when COLMAP sees staged PNG copies (which
    carry no EXIF): one camera, no intrinsics given, and the originals' EXIF agree (their
    median; a quarter turn leaves the focal length as it is)."""
    if intrinsics is not None or not single_camera or not (turned or restage):
        return None
    focals = [exif_focal_px(image_dir / name) for name in original.values()]
    focals = [f for f in focals if f is not None]
    return float(np.median(focals)) if focals else None


def _overlapping_pairs(read_dir: Path, names: list[str], reader, mode,
                       threads: int, work: Path) -> list[tuple[str, str]]:
    """The image pairs worth matching at full size, from a coarse SfM matching pass.

    Every pair is matched on small images (``COARSE_SIDE`` px, ``COARSE_FEATURES``
    features: (1024 / ~6 000)^2, about 1/35 of a full pair's descriptor comparisons) and
    verified by COLMAP's two-view geometry; kept are the pairs with at least
    ``COARSE_MIN_INLIERS`` inliers and each image's ``COARSE_BEST_PER_IMAGE`` best pairs.
    Views that share nothing (the far side of a ring, the two ends of a walk) are not
    matched at full size.
    """
    import pycolmap

    coarse = work / "coarse.db"
    coarse.unlink(missing_ok=True)
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = threads
    extraction.max_image_size = COARSE_SIDE
    extraction.sift.max_num_features = COARSE_FEATURES
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = threads
    with _quiet_colmap():
        pycolmap.extract_features(coarse, read_dir, image_names=names, camera_mode=mode,
                                  reader_options=reader, extraction_options=extraction,
                                  device=pycolmap.Device.cpu)
        pycolmap.match_exhaustive(coarse, matching_options=matching,
                                  device=pycolmap.Device.cpu)
    with contextlib.closing(sqlite3.connect(coarse)) as db:
        ids = dict(db.execute("SELECT image_id, name FROM images"))
        rows = db.execute("SELECT pair_id, rows FROM two_view_geometries WHERE rows > 0")
        inliers = {tuple(sorted(ids[i] for i in pycolmap.pair_id_to_image_pair(pair_id))): int(n)
                   for pair_id, n in rows}
    coarse.unlink(missing_ok=True)
    keep = {pair for pair, n in inliers.items() if n >= COARSE_MIN_INLIERS}
    for name in names:
        mine = sorted((n, pair) for pair, n in inliers.items() if name in pair)
        keep.update(pair for _, pair in mine[-COARSE_BEST_PER_IMAGE:])
    return sorted(keep)


def _ordered_pairs(database: Path, names: list[str], matching, work: Path) -> int:
    """Match each image with the next ones in name order (a phone's or camera's file
    names follow the capture: the walk round or past the object), cyclically (the last
    image with the first: a ring's closure; on a walk those pairs fail to verify), until
    ``ORDERED_MISSES`` in a row verify with fewer than ``COARSE_MIN_INLIERS`` inliers
    (COLMAP's mapper uses no pair with fewer) or half the images are passed.  Rounds
    of one step each (all open images' pairs at that distance in one
    ``match_image_pairs`` call); returns the number of pairs matched."""
    import pycolmap

    n = len(names)
    misses = dict.fromkeys(range(n), 0)
    listed, matched = work / "pairs.txt", set()
    for step in range(1, n // 2 + 1):
        todo = sorted({tuple(sorted((i, (i + step) % n))) for i, m in misses.items()
                       if m < ORDERED_MISSES} - matched)
        if not todo:
            break
        listed.write_text("".join(f"{names[a]} {names[b]}\n" for a, b in todo))
        pycolmap.match_image_pairs(
            database, matching_options=matching,
            pairing_options=pycolmap.ImportedPairingOptions(match_list_path=str(listed)),
            device=pycolmap.Device.cpu)
        matched.update(todo)
        with contextlib.closing(sqlite3.connect(database)) as db:
            ids = {i: names.index(name) for i, name in db.execute(
                "SELECT image_id, name FROM images") if name in names}
            verified = {tuple(sorted(ids[i] for i in pycolmap.pair_id_to_image_pair(pid)))
                        for pid, rows in db.execute(
                            "SELECT pair_id, rows FROM two_view_geometries")
                        if rows >= COARSE_MIN_INLIERS}
        for i in list(misses):
            if misses[i] < ORDERED_MISSES:
                ok = tuple(sorted((i, (i + step) % n))) in verified
                misses[i] = 0 if ok else misses[i] + 1
    return len(matched)


def _result_from(reconstruction, names: list[str], others: list[str], matcher: str) -> SfmResult:
    cameras = cameras_from_pycolmap(reconstruction)
    registered = [cam.name for cam in cameras]
    points3d = list(reconstruction.points3D.values())
    points = np.array([p.xyz for p in points3d], dtype=np.float64).reshape(-1, 3)
    track = np.array([p.track.length() for p in points3d], dtype=np.int64)
    colors = np.array([p.color for p in points3d], dtype=np.uint8).reshape(-1, 3)
    return SfmResult(cameras=cameras, points=points, track_length=track, colors=colors,
                     registered=registered,
                     unregistered=[n for n in names if n not in set(registered)],
                     ignored=list(others),
                     mean_reprojection_error_px=float(
                         reconstruction.compute_mean_reprojection_error()),
                     matcher=matcher)
