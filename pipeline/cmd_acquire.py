"""``photosurf acquire FOLDER --out CLOUD.ply``: an image folder all round an object -> one cloud.

A thin command over :func:`pipeline.acquisition.acquire_folder` (the same work as
``photosurf run``'s acquire stage; images and cameras loaded by
:func:`pipeline.inputs.load_folder`, which holds the rules below).

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
(V,), ``reason_names`` / ``reason_counts``); with SfM poses also ``CLOUD.cameras.yml``,
the cameras the cloud was matched with (its frame; give it to ``--cameras`` to reuse
them).  They appear together or not at all.  Images of several sizes without cameras
(portrait and landscape shots) are posed by SfM (:func:`matching.sfm.run_sfm`).

Bad input (one line, exit 2, nothing written): missing or empty folder, fewer than 2
usable images, SfM that registers fewer than 2.  One bad view (an unreadable or
truncated file, no camera for it in the cameras file, a size its camera does not
have) is left out with a warning naming the file and its problem.
"""

from __future__ import annotations

import argparse
import contextlib
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from pipeline.errors import InputError

HELP = "image folder all round an object -> merged multi-view point cloud (PLY + .npz)"


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
    parser.add_argument("--densify", action=argparse.BooleanOptionalAction, default="auto",
                        help="a second lattice, half a cell off, matched between accepted "
                             "matches: by default only as many candidates as the first "
                             "lattice left cells of the matched surface unaccepted (the "
                             "density SPACING asks for; nothing where it is complete); "
                             "--densify: wherever its neighbours were accepted; "
                             "--no-densify: the first lattice only")
    parser.add_argument("--masks", choices=("auto", "folder", "none"), default="folder",
                        help="object masks: FOLDER/masks/NAME.png (0 = ignore, COLMAP's "
                             "layout; folder, default); those, else the automatic foreground "
                             "of a uniform dark or light background (auto); none")
    parser.add_argument("--roi", metavar="X0,Y0,Z0,X1,Y1,Z1", default=None,
                        help="region of interest, a box in world units: points outside are "
                             "dropped")
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


def cameras_path(out: Path) -> Path:
    """Where ``photosurf acquire --out CLOUD.ply`` writes the SfM cameras it used."""
    return out.with_suffix(".cameras.yml")


def write_outputs(out: Path, cloud) -> None:
    """``out`` (.ply) and ``out.npz`` atomically, together; with SfM poses also the
    cameras they were matched with, ``out.cameras.yml`` (readable by ``--cameras``)."""
    from matching.cameras import write_cameras_yml
    from matching.multiview import REASON_NAMES
    from pipeline.atomic import atomic_file, naming
    from pipeline.cloud_io import write_ply
    from pipeline.workspace import write_npz_to

    names = sorted(REASON_NAMES)
    sfm = cloud.stats.get("camera_source") == "sfm" and cloud.stats.get("cameras")
    with contextlib.ExitStack() as stack:
        tmp_ply = stack.enter_context(atomic_file(out))
        tmp_npz = stack.enter_context(atomic_file(out.with_suffix(".npz")))
        if sfm:
            write_cameras_yml(stack.enter_context(atomic_file(cameras_path(out))),
                              cloud.stats["cameras"])
        with naming(out.with_suffix(".npz")):  # each failure names its own file
            # byte-reproducible (np.savez stamps the time into the zip)
            write_npz_to(tmp_npz, points=cloud.points, colours=cloud.colours, sigma=cloud.sigma,
                         views=cloud.views, pair=cloud.pair,
                         pairs=np.asarray(cloud.pairs, np.int64).reshape(-1, 2),
                         view_names=np.array(cloud.stats.get("view_names", []), dtype=str),
                         reason_names=np.array([REASON_NAMES[k] for k in names]),
                         reason_counts=np.array([cloud.reason_counts[REASON_NAMES[k]]
                                                 for k in names]))
        with naming(out):
            write_ply(tmp_ply, cloud.points, cloud.colours, cloud.sigma)


def run(args: argparse.Namespace) -> int:
    from pipeline.acquisition import acquire_folder
    from pipeline.executor import get_executor

    out = Path(args.out)
    if out.suffix.lower() != ".ply":
        raise InputError(f"{out}: --out must end in .ply")
    if args.spacing < 1 or args.patch < 5 or args.patch % 2 == 0:
        raise InputError(f"--spacing {args.spacing} / --patch {args.patch}: need spacing >= 1 "
                         "and an odd patch >= 5")
    if args.check_views < 1:
        raise InputError(f"--check-views {args.check_views}: must be >= 1")
    from pipeline.guards import check_output

    for target in (out, out.with_suffix(".npz")):
        check_output(target, [args.folder, args.cameras])
    roi = ()
    if args.roi is not None:
        try:
            roi = [float(v) for v in args.roi.split(",")]
        except ValueError:
            raise InputError(f"--roi {args.roi}: give six numbers X0,Y0,Z0,X1,Y1,Z1") from None
    with get_executor(args.scheduler) as executor:
        cloud = acquire_folder(args.folder, args.cameras, executor=executor,
                               check_views=args.check_views,
                               camera_model=args.sfm_camera_model, spacing=args.spacing,
                               patch=args.patch, eccentric=args.eccentric,
                               densify=args.densify,
                               masks=args.masks, roi=roi)
    write_outputs(out, cloud)
    if not getattr(args, "quiet", False):
        st = cloud.stats
        extra = (f"; SfM left out {', '.join(st['unregistered'])}" if st["unregistered"] else "")
        if st.get("skipped_views"):
            extra += f"; {len(st['skipped_views'])} view(s) left out"
        if st.get("pairs_skipped"):
            extra += f"; {st['pairs_skipped']} pair(s) skipped"
        print(f"{st['views']} views ({st['camera_source']}), {st['pairs']} pairs: "
              f"{len(cloud)} points (median sigma {float(np.median(cloud.sigma)):.3g}, "
              f"{st['fused']} fused, {cloud.reason_counts['outlier']} outliers removed; "
              f"{_rejected(cloud.reason_counts)}) in {st['seconds']:.1f} s{extra}; wrote {out}")
    return 0


def _rejected(counts: Mapping[str, int]) -> str:
    parts = [f"{n} {name}" for name, n in counts.items()
             if n and name not in ("multiview", "outlier")]
    return "rejected " + ", ".join(parts) if parts else "none rejected"
