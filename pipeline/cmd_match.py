"""``photosurf match``: dense least-squares matching of a stereo pair.

Writes ``OUT/matches.npz`` (every candidate: ``x_left``, ``x_right``, ``approx``,
``cov``, ``sigma``, ``sigma0``, ``correlation``, ``iterations``, ``affine``,
``radiometric``, ``texture``, ``status`` and the ``status_names`` table) and the maps of
:mod:`pipeline.match_maps`: ``OUT/disparity.npy`` (float32, left-image size,
``x_left - x_right``, NaN where not matched), ``OUT/sigma.npy`` (float32, the σ of each
disparity, px, NaN where not matched), ``OUT/status.npy`` (uint8 status code per
candidate pixel, 255 elsewhere), each also as a colour-mapped PNG with its legend
(``disparity.png``, ``sigma.png``, ``status.png``: where and why the matcher said no) and
``OUT/report.html`` showing them with every status's count and meaning.
With ``--dense`` (rectified only) every pixel is a candidate (spacing 1) and the speed
is printed.
The folder appears complete or not at all.  Images are read by
:func:`pipeline.inputs.read_image` (the rules of every command that reads images).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from pipeline.atomic import atomic_dir
from pipeline.errors import InputError
from pipeline.inputs import check_rig_size, read_pair, read_rig_for
from pipeline.match_maps import write_maps
from pipeline.options import add_match_options, check_some_matched, match_options, summary
from pipeline.workspace import write_npz_to

HELP = "least-squares matching of a stereo pair (calibrated or rectified) -> matches.npz"


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
    parser.add_argument("--dense", action="store_true",
                        help="rectified pair: match every pixel (spacing 1)")
    add_match_options(parser)


def run(args: argparse.Namespace) -> int:
    from pipeline.atomic import output_dir_state
    from pipeline.guards import check_output

    options = match_options(args)
    dense = getattr(args, "dense", False)
    if dense and not args.rectified:
        raise InputError("--dense needs --rectified (a disparity map is defined on rectified "
                         "images)")
    if dense:
        options["spacing"] = 1
    if Path(args.out).exists() and not Path(args.out).is_dir():
        raise InputError(f"{args.out}: is a file; --out must name a folder")
    check_output(args.out, [args.left, args.right, args.rig], folder=True)
    output_dir_state(args.out, "match")  # refused before matching, not after
    left, right = read_pair(args.left, args.right)
    rig = None if args.rectified else read_rig_for(args.rig, args.left)
    if rig is not None:
        check_rig_size(rig, (left, right), (args.left, args.right))
    # the matcher (numba, scipy: ~0.6 s of imports) only after every check of the inputs
    from matching.pair import match_pair
    from matching.scheduler import thread_map

    start = time.perf_counter()
    # a calibrated rig: LSM constrained to the epipolar line, windows ill-conditioned
    # along it rejected (match_pair's epipolar_pass; a rectified pair is already)
    # off the main thread, which waits where Ctrl-C reaches it (matching.scheduler)
    matches, = thread_map(1)(lambda _: match_pair(left, right, rig, rectified=args.rectified,
                                                  epipolar_pass=not args.rectified,
                                                  **options), [None])
    seconds = time.perf_counter() - start
    check_some_matched(matches, args.left)
    with atomic_dir(args.out, kind="match") as tmp:
        write_npz_to(tmp / "matches.npz", **matches.as_dict())  # byte-reproducible
        # where and why the matcher said no: disparity, σ and status maps (.npy + .png)
        write_maps(tmp, matches)
    if not getattr(args, "quiet", False):
        speed = (f"; dense: {len(matches) / seconds:.0f} px/s "
                 f"({int(matches.accepted.sum())} accepted in {seconds:.1f} s)" if dense else "")
        print(f"{summary(matches)}{speed}; wrote {args.out}")
    return 0
