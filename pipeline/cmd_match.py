"""``photosurf match``: dense least-squares matching of a stereo pair.

Writes ``OUT/matches.npz`` (every candidate: ``x_left``, ``x_right``, ``approx``,
``cov``, ``sigma``, ``sigma0``, ``correlation``, ``iterations``, ``affine``,
``radiometric``, ``texture``, ``status`` and the ``status_names`` table) and, for a
rectified pair, ``OUT/disparity.npy`` (float32, left-image size,
``x_left - x_right``, NaN where not matched).  The folder appears complete or not
at all.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from pipeline.atomic import atomic_dir
from pipeline.errors import InputError
from pipeline.workspace import write_npz_to

HELP = "least-squares matching of a stereo pair (calibrated or rectified) -> matches.npz"


def add_match_options(parser: argparse.ArgumentParser) -> None:
    """Matching options shared by ``photosurf match`` and ``photosurf stereo``."""
    parser.add_argument("--spacing", type=int, default=3,
                        help="one candidate per SPACING x SPACING pixels (default 3)")
    parser.add_argument("--patch", type=int, default=15,
                        help="LSM patch side in pixels, odd (default 15)")
    parser.add_argument("--interpolation", choices=("bilinear", "bicubic", "spline"),
                        default="spline", help="search-image resampler (default spline)")
    parser.add_argument("--epipolar", action=argparse.BooleanOptionalAction, default=None,
                        help="constrain the shift to the epipolar line (default: only for "
                             "--rectified)")
    parser.add_argument("--max-iter", type=int, default=20, help="Gauss-Newton iterations")
    parser.add_argument("--min-correlation", type=float, default=0.7,
                        help="reject matches below this correlation (default 0.7)")


def match_options(args: argparse.Namespace) -> dict:
    """The matching keyword arguments, checked (``InputError`` naming the option)."""
    import math

    if args.patch < 5 or args.patch % 2 == 0:
        raise InputError(f"--patch must be an odd integer >= 5, got {args.patch}")
    if args.spacing < 1:
        raise InputError(f"--spacing must be a positive integer, got {args.spacing}")
    if args.max_iter < 1:
        raise InputError(f"--max-iter must be a positive integer, got {args.max_iter}")
    if not (math.isfinite(args.min_correlation) and -1.0 <= args.min_correlation <= 1.0):
        raise InputError(f"--min-correlation must be in [-1, 1], got {args.min_correlation}")
    return {"spacing": args.spacing, "patch": args.patch, "interpolation": args.interpolation,
            "epipolar": args.epipolar, "max_iter": args.max_iter,
            "min_correlation": args.min_correlation}


def read_image(path: str | Path) -> np.ndarray:
    """An image file as an array (grey or BGR); ``InputError`` if missing or unreadable."""
    import cv2

    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file")
    if path.is_dir():
        raise IsADirectoryError(f"{path}: is a folder, expected an image")
    from pipeline.mesh_io import quiet_native_stderr

    with quiet_native_stderr():  # libpng prints its own diagnostics on fd 2
        image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise InputError(f"{path}: not a readable image")
    if min(image.shape[:2]) < 32:
        raise InputError(f"{path}: image is too small to match: {image.shape[1]}x"
                         f"{image.shape[0]} px (at least 32x32)")
    return image


def read_pair(left: str, right: str, need_same_size: bool = True):
    images = read_image(left), read_image(right)
    if need_same_size and images[0].shape[:2] != images[1].shape[:2]:
        (h1, w1), (h2, w2) = images[0].shape[:2], images[1].shape[:2]
        raise InputError(f"{right}: image is {w2}x{h2} px but {left} is {w1}x{h1} px; "
                         "the pair must have one size")
    return images


def read_rig_for(path: str, left_image: str):
    from matching.cameras import read_rig

    try:
        return read_rig(path, image=left_image)
    except (ValueError, OSError) as exc:
        message = str(exc)
        raise InputError(message if str(path) in message else f"{path}: {message}") from None


def check_rig_size(rig, images, paths) -> None:
    """Each image must have its camera's size (the rig's calibration is per pixel)."""
    for label, image, cam, path in zip(("left", "right"), images, (rig.left, rig.right), paths,
                                       strict=True):
        if (image.shape[1], image.shape[0]) != cam.size:
            raise InputError(f"{path}: image is {image.shape[1]}x{image.shape[0]} px but the "
                             f"rig's {label} camera is {cam.size[0]}x{cam.size[1]} px")


def summary(matches) -> str:
    counts = matches.status_counts()
    rejected = ", ".join(f"{k} {v}" for k, v in counts.items() if k != "ok")
    return (f"{counts.get('ok', 0)} of {len(matches)} candidates matched "
            f"({rejected or 'none rejected'})")


def check_some_matched(matches, left: str) -> None:
    if not matches.accepted.any():
        raise InputError(f"{left}: no point could be matched: {summary(matches)}")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("left", metavar="LEFT", help="left image")
    parser.add_argument("right", metavar="RIGHT", help="right image")
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--rig", metavar="RIG.yml",
                        help="stereo rig (cameras.yml, photosurf calibrate output, OpenCV "
                             "intrinsics.yml/extrinsics.yml)")
    source.add_argument("--rectified", action="store_true",
                        help="the images are rectified: corresponding points share a row")
    parser.add_argument("--out", required=True, metavar="DIR", help="output folder")
    add_match_options(parser)


def run(args: argparse.Namespace) -> int:
    from matching.pair import match_pair

    options = match_options(args)
    if Path(args.out).exists() and not Path(args.out).is_dir():
        raise InputError(f"{args.out}: is a file; --out must name a folder")
    left, right = read_pair(args.left, args.right)
    rig = None if args.rectified else read_rig_for(args.rig, args.left)
    if rig is not None:
        check_rig_size(rig, (left, right), (args.left, args.right))
    matches = match_pair(left, right, rig, rectified=args.rectified, **options)
    check_some_matched(matches, args.left)
    with atomic_dir(args.out) as tmp:
        write_npz_to(tmp / "matches.npz", **matches.as_dict())  # byte-reproducible
        if args.rectified:
            np.save(tmp / "disparity.npy", matches.disparity_map())
    if not getattr(args, "quiet", False):
        print(f"{summary(matches)}; wrote {args.out}")
    return 0
