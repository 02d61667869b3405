"""``photosurf stereo``: a calibrated stereo pair to a point cloud with per-point σ.

Writes ``OUT.ply`` (binary: x y z, red green blue, ``sigma`` as a float vertex
property, scene units) and ``OUT.npz`` beside it with every per-point quantity
(``points``, ``colours``, ``sigma``, ``cov``, ``x_left``, ``x_right``, ``cov_2d``,
``sigma_px``, ``sigma0``, ``correlation``, ``iterations``, ``reprojection_error``,
``index``) plus the candidates' ``status`` and ``status_names``, and beside them the
maps of :mod:`pipeline.match_maps` -- ``OUT.disparity.npy``/``.png``,
``OUT.sigma.npy``/``.png``, ``OUT.status.npy``/``.png`` (where and why the matcher said
no) and ``OUT.report.html`` showing them.  The files appear together or not at all.
"""

from __future__ import annotations

import argparse
from contextlib import ExitStack
from pathlib import Path

import numpy as np

from pipeline.atomic import atomic_file, naming
from pipeline.cloud_io import write_ply
from pipeline.errors import InputError
from pipeline.inputs import check_rig_size, read_pair, read_rig_for
from pipeline.match_maps import map_paths, write_maps
from pipeline.options import add_match_options, check_some_matched, match_options, summary
from pipeline.workspace import write_npz_to

HELP = "calibrated stereo pair -> point cloud (PLY with per-point sigma, plus .npz)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("left", metavar="LEFT", help="left image")
    parser.add_argument("right", metavar="RIGHT", help="right image")
    parser.add_argument("--rig", required=True, metavar="RIG.yml", help="stereo rig file")
    parser.add_argument("--out", required=True, metavar="OUT.ply", help="point cloud to write")
    parser.add_argument("--max-reprojection", type=float, default=None, metavar="PX",
                        help="also reject points with a larger RMS reprojection error")
    add_match_options(parser)


def run(args: argparse.Namespace) -> int:
    out = Path(args.out)
    if out.suffix.lower() != ".ply":
        raise InputError(f"{out}: --out must end in .ply")
    from pipeline.guards import check_output

    for target in (out, out.with_suffix(".npz"), *map_paths(out.parent, f"{out.stem}.")):
        if target.is_dir():
            raise InputError(f"{target}: is a folder; --out must name a file")
        check_output(target, [args.left, args.right, args.rig])
    options = match_options(args)
    left, right = read_pair(args.left, args.right, need_same_size=False)
    rig = read_rig_for(args.rig, args.left)
    check_rig_size(rig, (left, right), (args.left, args.right))
    options.pop("epipolar")
    # the matcher (numba, scipy: ~0.6 s of imports) only after every check of the inputs
    from matching.pair import PAIR_STATUS_NAMES, reconstruct_pair
    from matching.scheduler import thread_map

    # a calibrated rig: LSM constrained to the epipolar line, windows ill-conditioned
    # along it rejected (match_pair's epipolar_pass)
    # off the main thread, which waits where Ctrl-C reaches it (matching.scheduler)
    rec, = thread_map(1)(lambda _: reconstruct_pair(
        left, right, rig, epipolar=args.epipolar, max_reprojection_px=args.max_reprojection,
        epipolar_pass=True, **options), [None])
    check_some_matched(rec.matches, args.left)
    per_point = rec.per_point()
    per_point["status"] = rec.matches.status
    per_point["status_names"] = np.array([PAIR_STATUS_NAMES[k] for k in sorted(PAIR_STATUS_NAMES)])
    # the .ply (inner) is renamed first: if that fails the .npz and the maps are never
    # renamed
    with ExitStack() as maps, atomic_file(out.with_suffix(".npz")) as tmp_npz, \
            atomic_file(out) as tmp_ply:
        with naming(out.with_suffix(".npz")):  # each failure names its own file
            write_npz_to(tmp_npz, **per_point)  # byte-reproducible (np.savez stamps the time)
        with naming(out):
            write_ply(tmp_ply, rec.points, rec.colours, rec.sigma)
        # where and why the matcher said no, beside the cloud (OUT.disparity.png, ...)
        write_maps(out.parent, rec.matches, prefix=f"{out.stem}.", stack=maps)
    if not getattr(args, "quiet", False):
        print(f"{summary(rec.matches)}; {len(rec)} points triangulated (median sigma "
              f"{float(np.median(rec.sigma)):.3g}); wrote {out}")
    return 0
