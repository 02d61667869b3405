"""``photosurf acquire FOLDER --out CLOUD.ply``: an image folder all round an object -> one cloud.

Images are the image files of ``FOLDER`` (or of ``FOLDER/images``).  Cameras come from
``--cameras FILE`` (any format :func:`matching.cameras.read_cameras` reads: photosurf
``cameras.yml``, a COLMAP model folder or its ``cameras.txt``, a projection-matrix
``.txt``), else from ``FOLDER/cameras.yml`` or the COLMAP model ``FOLDER/sparse``, else
from pycolmap SfM on the CPU (:func:`matching.sfm.run_sfm`; the cloud is then in SfM's
arbitrary similarity frame).  Cameras are matched to images by file name.  The work is
:func:`matching.multiview.reconstruct_multiview`, its view pairs and consistency
checks mapped over :mod:`pipeline.executor` (``--scheduler`` for Dask).

Writes ``CLOUD.ply`` (binary: x y z, red green blue, ``sigma`` float, scene units) and
``CLOUD.npz`` beside it (``points``, ``colours``, ``sigma``, ``views`` (N, V) bool,
``pair`` (N,) int64 (-1: fused from several pairs), ``pairs`` (P, 2), ``view_names``
(V,), ``reason_names`` / ``reason_counts``); both appear together or not at all.

Bad input (one line, exit 2, nothing written): missing or empty folder, fewer than 2
images, an unreadable image file, images of different sizes without cameras that say
so, cameras that do not cover the images, SfM that registers nothing.
"""

from __future__ import annotations

import argparse
import json
import logging
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from pipeline.errors import InputError

HELP = "image folder all round an object -> merged multi-view point cloud (PLY + .npz)"

log = logging.getLogger(__name__)

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".pgm", ".ppm", ".webp")
#: Options of ``[acquire]`` (pipeline/defaults.toml) that matching.multiview takes.
_MATCH_KEYS = ("spacing", "patch", "interpolation", "min_texture_snr", "max_iter",
               "shift_stop_px", "sigma0_factor", "min_correlation", "eccentric")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("folder", metavar="FOLDER", help="folder of images (or FOLDER/images)")
    parser.add_argument("--out", required=True, metavar="CLOUD.ply", help="point cloud to write")
    parser.add_argument("--cameras", metavar="FILE", default=None,
                        help="cameras (cameras.yml, COLMAP model, projection-matrix .txt); "
                             "default FOLDER/cameras.yml or FOLDER/sparse, else pycolmap SfM")
    parser.add_argument("--spacing", type=int, default=3,
                        help="one candidate per SPACING x SPACING pixels (default 3)")
    parser.add_argument("--patch", type=int, default=15, help="LSM patch side, odd (default 15)")
    parser.add_argument("--no-eccentric", dest="eccentric", action="store_false",
                        help="keep LSM windows centred near untextured regions (background "
                             "past a rim): those points are then dropped instead of "
                             "matched with the window moved onto the surface")
    parser.add_argument("--check-views", type=int, default=2,
                        help="further views each point is LSM-checked in (default 2)")
    parser.add_argument("--sfm-camera-model", default="SIMPLE_RADIAL",
                        choices=("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV"),
                        help="COLMAP camera model when poses come from SfM (default "
                             "SIMPLE_RADIAL; SIMPLE_PINHOLE for distortion-free images: on a "
                             "narrow field k1 trades against the focal length)")
    parser.add_argument("--scheduler", default=None,
                        help="Dask scheduler (tcp://HOST:PORT or local-cluster[:N]); "
                             "default in-process")


# --------------------------------------------------------------------------- inputs
def _image_dir(folder: Path) -> tuple[Path, list[str], list[str]]:
    """The folder holding the images, the image names and the other file names."""
    if not folder.exists():
        raise FileNotFoundError(f"{folder}: no such folder")
    if not folder.is_dir():
        raise NotADirectoryError(f"{folder}: not a folder")
    for where in (folder, folder / "images"):
        if not where.is_dir():
            continue
        files = sorted(p for p in where.iterdir() if p.is_file() and not p.name.startswith("."))
        images = [p.name for p in files if p.suffix.lower() in IMAGE_SUFFIXES]
        if images:
            return where, images, [p.name for p in files if p.name not in images]
    others = sorted(p.name for p in folder.iterdir() if not p.name.startswith("."))
    if not others:
        raise InputError(f"{folder}: empty folder (no images)")
    raise InputError(f"{folder}: no image files ({', '.join(IMAGE_SUFFIXES)}); found "
                     f"{', '.join(others[:5])}{' ...' if len(others) > 5 else ''}")


def read_image(path: Path) -> np.ndarray:
    """One image (grey or BGR, uint8); ``InputError`` naming an unreadable file."""
    import cv2

    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None or image.ndim not in (2, 3) or min(image.shape[:2]) < 32:
        raise InputError(f"{path}: not a readable image (or smaller than 32x32 px)")
    if image.dtype != np.uint8:
        image = cv2.normalize(image, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    return image


def read_images(where: Path, names: list[str]) -> list[np.ndarray]:
    """Every image (grey or BGR); ``InputError`` naming the first unreadable file."""
    return [read_image(where / name) for name in names]


class FolderImages(Sequence):
    """The images of a folder, read from disk on item access (bounded memory).

    Every file is read once on construction to check it and record its shape, then
    dropped; ``images[v]`` reads it again.  Pickles as its paths (a Dask task carries
    the file names, not the pixels).  :func:`matching.multiview.reconstruct_multiview`
    recognises it by ``lazy`` and ``shapes``.

    Parameters
    ----------
    where : Path
        The folder.
    names : list of str
        Image file names, in camera order.
    """

    lazy = True

    def __init__(self, where: Path, names: list[str]):
        self.paths = [Path(where) / name for name in names]
        self.shapes = [read_image(path).shape for path in self.paths]

    def __len__(self) -> int:
        return len(self.paths)

    def __getitem__(self, index):
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        return read_image(self.paths[index])

    def subset(self, indices: list[int]) -> FolderImages:
        """The images at ``indices`` (no file is read again)."""
        out = object.__new__(FolderImages)
        out.paths = [self.paths[i] for i in indices]
        out.shapes = [self.shapes[i] for i in indices]
        return out


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


def _match_cameras(cams: list, names: list[str], source: Path) -> list:
    by_name = {Path(c.name).name: c for c in cams if c.name}
    if all(n in by_name for n in names):
        return [by_name[n] for n in names]
    missing = [n for n in names if n not in by_name]
    raise InputError(f"{source}: no camera for image(s) {', '.join(missing[:5])}"
                     f"{' ...' if len(missing) > 5 else ''} ({len(cams)} cameras: "
                     f"{', '.join(sorted(by_name)[:3])}{' ...' if len(by_name) > 3 else ''})")


def load_folder(folder: str | Path, cameras: str | None = None,
                sfm_work_dir: str | Path | None = None,
                camera_model: str = "SIMPLE_RADIAL") -> dict:
    """Images and cameras of a folder (module docstring), checked.

    Returns
    -------
    dict
        ``images`` (:class:`FolderImages`, read on access), ``cameras`` (list of
        Camera, same order), ``names``,
        ``camera_source`` (path or ``"sfm"``), ``ignored`` (other files),
        ``unregistered`` (images SfM could not place, left out), ``sfm`` (its report).
    """
    from matching.cameras import read_cameras

    folder = Path(folder)
    where, names, others = _image_dir(folder)
    if len(names) < 2:
        raise InputError(f"{where}: need at least 2 images, found {len(names)} ({names[0]})")
    images = FolderImages(where, names)
    sizes = {(shape[1], shape[0]) for shape in images.shapes}
    source = _camera_source(folder, where, cameras)
    out = {"ignored": others, "unregistered": [], "sfm": None}
    if source is not None:
        try:
            cams = read_cameras(source, *(next(iter(sizes)) if len(sizes) == 1 else (None, None)))
        except ValueError as exc:
            raise InputError(f"{source}: {exc}") from None
        cams = _match_cameras(cams, names, source)
        for name, shape, cam in zip(names, images.shapes, cams, strict=True):
            if (shape[1], shape[0]) != cam.size:
                raise InputError(f"{where / name}: image is {shape[1]}x{shape[0]} px but "
                                 f"its camera in {source} is {cam.size[0]}x{cam.size[1]} px")
        out["camera_source"] = str(source)
    else:
        if len(sizes) > 1:
            raise InputError(f"{where}: images of different sizes {sorted(sizes)} and no "
                             "cameras to say so (give --cameras)")
        from matching.sfm import run_sfm

        result = run_sfm(where, work_dir=sfm_work_dir, image_names=names,
                         camera_model=camera_model)
        if len(result.registered) < 2:
            raise InputError(f"{where}: SfM registered {len(result.registered)} of "
                             f"{len(names)} images; need 2")
        keep = [n for n in names if n in set(result.registered)]
        by_name = {c.name: c for c in result.cameras}
        images = images.subset([names.index(n) for n in keep])
        cams = [by_name[n] for n in keep]
        out.update(camera_source="sfm", unregistered=list(result.unregistered),
                   sfm=result.report())
        if result.unregistered:
            log.warning("SfM did not register %s; left out", ", ".join(result.unregistered))
        names = keep
    out.update(images=images, cameras=cams, names=names)
    return out


# --------------------------------------------------------------------------- work
def acquire_folder(folder: str | Path, cameras: str | None = None, executor=None,
                   check_views: int = 2, camera_model: str = "SIMPLE_RADIAL", **options):
    """Image folder -> :class:`matching.multiview.MultiViewCloud` (plus what was loaded).

    Parameters
    ----------
    folder : path
    cameras : path, optional
        Camera file (default: found in the folder, else SfM).
    executor : pipeline.executor executor, optional
        A Dask executor's ``map`` runs the view pairs and consistency checks as tasks;
        in process (default, or a ``LocalExecutor``) they run on one thread per usable
        core (:func:`matching.multiview.reconstruct_multiview`'s ``workers``).
    check_views : int
    camera_model : str
        COLMAP camera model for SfM (only used without cameras).
    **options
        ``[acquire]`` options of pipeline/defaults.toml; the matching ones are passed
        on (``max_reprojection_px`` has no multi-view meaning and is ignored).

    Returns
    -------
    matching.multiview.MultiViewCloud
        With ``points``, ``colors``-compatible ``colours`` and ``sigma``; its ``stats``
        gain ``camera_source``, ``unregistered``, ``ignored``, ``sfm``, ``view_names``.
    """
    from matching.multiview import reconstruct_multiview

    loaded = load_folder(folder, cameras, camera_model=camera_model)
    match = {k: v for k, v in options.items() if k in _MATCH_KEYS}
    from pipeline.executor import LocalExecutor

    map_func = None if executor is None or isinstance(executor, LocalExecutor) else executor.map
    try:
        cloud = reconstruct_multiview(loaded["images"], loaded["cameras"], map_func=map_func,
                                      check_views=check_views, **match)
    except ValueError as exc:
        raise InputError(f"{folder}: {exc}") from None
    cloud.stats.update(camera_source=loaded["camera_source"],
                       unregistered=loaded["unregistered"], ignored=loaded["ignored"],
                       sfm=loaded["sfm"], view_names=loaded["names"])
    if len(cloud) == 0:
        raise InputError(f"{folder}: no point survived matching and the consistency checks "
                         f"({json.dumps(cloud.reason_counts)})")
    return cloud


def write_outputs(out: Path, cloud) -> None:
    """``out`` (.ply) and ``out.npz`` atomically, together."""
    from matching.multiview import REASON_NAMES
    from pipeline.atomic import atomic_file
    from pipeline.cloud_io import write_ply
    from pipeline.workspace import write_npz_to

    names = sorted(REASON_NAMES)
    with atomic_file(out) as tmp_ply, atomic_file(out.with_suffix(".npz")) as tmp_npz:
        # byte-reproducible (np.savez stamps the time into the zip)
        write_npz_to(tmp_npz, points=cloud.points, colours=cloud.colours, sigma=cloud.sigma,
                     views=cloud.views, pair=cloud.pair,
                     pairs=np.asarray(cloud.pairs, np.int64).reshape(-1, 2),
                     view_names=np.array(cloud.stats.get("view_names", []), dtype=str),
                     reason_names=np.array([REASON_NAMES[k] for k in names]),
                     reason_counts=np.array([cloud.reason_counts[REASON_NAMES[k]]
                                             for k in names]))
        write_ply(tmp_ply, cloud.points, cloud.colours, cloud.sigma)


def run(args: argparse.Namespace) -> int:
    from pipeline.executor import get_executor

    out = Path(args.out)
    if out.suffix.lower() != ".ply":
        raise InputError(f"{out}: --out must end in .ply")
    if args.spacing < 1 or args.patch < 5 or args.patch % 2 == 0:
        raise InputError(f"--spacing {args.spacing} / --patch {args.patch}: need spacing >= 1 "
                         "and an odd patch >= 5")
    if args.check_views < 1:
        raise InputError(f"--check-views {args.check_views}: must be >= 1")
    with get_executor(args.scheduler) as executor:
        cloud = acquire_folder(args.folder, args.cameras, executor=executor,
                               check_views=args.check_views,
                               camera_model=args.sfm_camera_model, spacing=args.spacing,
                               patch=args.patch, eccentric=args.eccentric)
    write_outputs(out, cloud)
    if not getattr(args, "quiet", False):
        st = cloud.stats
        extra = (f"; SfM left out {', '.join(st['unregistered'])}" if st["unregistered"] else "")
        print(f"{st['views']} views ({st['camera_source']}), {st['pairs']} pairs: "
              f"{len(cloud)} points (median sigma {float(np.median(cloud.sigma)):.3g}, "
              f"{st['fused']} fused, {cloud.reason_counts['outlier']} outliers removed; "
              f"{_rejected(cloud.reason_counts)}) in {st['seconds']:.1f} s{extra}; wrote {out}")
    return 0


def _rejected(counts: Mapping[str, int]) -> str:
    parts = [f"{n} {name}" for name, n in counts.items()
             if n and name not in ("multiview", "outlier")]
    return "rejected " + ", ".join(parts) if parts else "none rejected"
