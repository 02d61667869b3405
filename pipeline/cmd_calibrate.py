"""``photosurf calibrate``: chessboard image pairs -> stereo rig file."""

from __future__ import annotations

import argparse
import glob
import logging
import math
from pathlib import Path

from pipeline.errors import InputError

HELP = "calibrate a stereo rig from chessboard image pairs (writes a rig file for --rig)"

EPILOG = """\
The two globs are sorted by name and paired in order (left_01 with right_01, ...).
--pattern counts the INNER corners (a board of 10x7 squares is 9x6); --square is the
side of one square in the unit the rig should have (e.g. 0.025 for metres).
Pairs where either image misses the board are skipped and named.

example:
  photosurf calibrate 'calib/left_*.png' 'calib/right_*.png' --pattern 9x6 --square 0.025 \\
      --out rig.yml
"""

log = logging.getLogger(__name__)

#: The board's extent (square x largest corner count) must survive float32 squaring:
#: OpenCV stores the object points as float32 (range 1.2e-38 .. 3.4e38).
BOARD_EXTENT = (1e-18, 1e18)
#: A calibrated baseline below this many squares is a zero baseline: the board's own
#: corners are located to ~0.1 px, a far larger share of a square than this.
MIN_BASELINE_SQUARES = 1e-3


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.epilog = EPILOG
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.add_argument("left", metavar="LEFT_GLOB", help="left images (quote the glob)")
    parser.add_argument("right", metavar="RIGHT_GLOB", help="right images (quote the glob)")
    parser.add_argument("--pattern", default="9x6", metavar="COLSxROWS",
                        help="inner corners per row x per column (default 9x6)")
    parser.add_argument("--square", type=float, required=True, metavar="SIZE",
                        help="side of one square, in the rig's unit")
    parser.add_argument("--fit-k3", action="store_true",
                        help="also estimate k3 (wide-angle lenses); default k3 = 0")
    parser.add_argument("--out", required=True, metavar="RIG.yml", help="rig file to write")


def _expand(pattern: str, side: str) -> list[Path]:
    paths = sorted(Path(p) for p in glob.glob(pattern) if Path(p).is_file())
    if not paths and Path(pattern).is_dir():
        raise InputError(f"{pattern}: is a folder; give a glob such as '{pattern}/*.png'")
    if not paths:
        raise InputError(f"{side} glob {pattern!r} matches no file")
    return paths


def _read_gray(path: Path):
    import cv2

    from pipeline.guards import read_image

    # regular file, format, size limit; upright (EXIF orientation applied), as every other
    # reader takes them (a rig calibrated in another frame would not fit the views)
    return read_image(path, cv2.IMREAD_GRAYSCALE)


def run(args: argparse.Namespace) -> int:
    # OpenCV and the calibration code are imported after the checks: a refusal costs
    # the interpreter's start-up only (benchmarks/limits.py)
    from matching.calibrate import parse_pattern
    from pipeline import limits
    from pipeline.guards import check_image_file, check_output

    if not (math.isfinite(args.square) and args.square > 0):
        raise InputError(f"--square must be positive, got {args.square}")
    pattern = parse_pattern(args.pattern)
    limits.check("calibrate.corners", pattern[0] * pattern[1], where=f"--pattern {args.pattern}")
    extent = args.square * max(pattern)
    if not BOARD_EXTENT[0] <= extent <= BOARD_EXTENT[1]:
        raise InputError(f"--square {args.square:g}: the board spans {extent:.3g}; OpenCV "
                         "takes it as float32 and squares it, so it must lie in "
                         f"[{BOARD_EXTENT[0]:g}, {BOARD_EXTENT[1]:g}]")
    lefts, rights = _expand(args.left, "left"), _expand(args.right, "right")
    if len(lefts) != len(rights):
        raise InputError(f"{len(lefts)} left images ({args.left}) but {len(rights)} right "
                         f"images ({args.right}); they must pair up")
    same = [a for a, b in zip(lefts, rights, strict=True) if a.resolve() == b.resolve()]
    if same:
        raise InputError(f"{same[0]}: is both a left and a right image (the globs name the "
                         "same files); each pair needs two cameras")
    out = Path(args.out)
    if out.suffix.lower() not in (".yml", ".yaml", ".xml", ".json"):
        raise InputError(f"--out {out}: must end in .yml, .yaml, .xml or .json")
    check_output(out, [*lefts, *rights])
    for path in (*lefts, *rights):  # every header before any image is decoded
        check_image_file(path)
    left_images = [_read_gray(p) for p in lefts]
    right_images = [_read_gray(p) for p in rights]
    names = [f"{a.name}/{b.name}" for a, b in zip(lefts, rights, strict=True)]
    sizes = {img.shape for img in (*left_images, *right_images)}
    if len(sizes) != 1:
        raise InputError(f"calibration images have different sizes: "
                         f"{sorted((w, h) for h, w in sizes)}")
    from matching.calibrate import stereo_calibrate
    from matching.cameras import read_rig, write_rig
    from pipeline.atomic import atomic_file

    try:
        result = stereo_calibrate(left_images, right_images, pattern, args.square,
                                  fix_k3=not args.fit_k3, names=names)
    except ValueError as exc:
        raise InputError(f"{args.left} / {args.right}: {exc}") from None
    for message in result.skipped.values():
        log.warning("skipped %s", message)
    if not result.rig.baseline > MIN_BASELINE_SQUARES * args.square:
        raise InputError(f"{args.left} / {args.right}: the calibrated cameras are "
                         f"{result.rig.baseline:.3g} apart, under {MIN_BASELINE_SQUARES:g} of "
                         "a square: the left and right images were taken from one place "
                         "(zero baseline), no rig is written")
    extra = {"rms_px": result.rms_px, "rms_left_px": result.rms_left_px,
             "rms_right_px": result.rms_right_px, "n_pairs": len(result.used),
             "pattern": f"{pattern[0]}x{pattern[1]}", "square": float(args.square)}
    with atomic_file(out) as tmp:
        write_rig(tmp, result.rig, extra=extra)
        read_rig(tmp)  # what --rig will read must read back
    if not getattr(args, "quiet", False):
        print(f"pairs used: {len(result.used)} of {len(lefts)}")
        print(f"RMS reprojection error: {result.rms_px:.3f} px "
              f"(left {result.rms_left_px:.3f}, right {result.rms_right_px:.3f})")
        print(f"baseline: {result.rig.baseline:.6g} (unit of --square)")
        print(f"focal lengths: left {result.rig.left.K[0, 0]:.2f} px, "
              f"right {result.rig.right.K[0, 0]:.2f} px")
        print(f"wrote {out}")
    return 0
