"""Real photographs: the benchmarks of real data, one part per flag.

* (default)      the Middlebury temple ring (16 views, 640x480) with its exact cameras:
                 clouds beside SGBM's, pycolmap's SfM against the given cameras
                 (``benchmarks/real_temple.py``, whose head says every row and goal);
* ``--vase``     the default stereo recipe end to end against its truth
                 (``benchmarks/real_vase.py``);
* ``--pairs``    the chessboard rig's pairs to open surfaces (``benchmarks/real_pair.py``);
* ``--sceaux``   the Sceaux castle's photos through ``photosurf run``; ``--phone FOLDER``
                 a phone-sized folder to its cloud (``benchmarks/real_photos.py``);
* ``--phone-sfm FOLDER``  SfM alone at each SIFT size (``benchmarks/real_phone_sfm.py``);
* ``--turned``   the turned temple with its par file (``benchmarks/turned_ring.py``);
* ``--exif``     the rendered ring's EXIF-tagged JPEG copies (``benchmarks/exif_ring.py``).

    .venv/bin/python benchmarks/real.py [--quick] [--sfm-only | --no-sfm] [--json PATH]
                                        [--spacing N]

``--quick``: spacing 3 and no SfM-based cloud (the other rows as they are);
``--sfm-only``: the SfM rows only; ``--no-sfm``: the dense rows only.  Each part writes its
own JSON beside ``--json`` (``real.json`` for the temple, ``real_vase.json``,
``real_pairs.json``, ``real_photos.json``, ``real_phone_sfm.json``, ``real_turned.json``,
``real_exif.json``).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from _timed_run import run_in_process  # noqa: E402
from real_phone_sfm import phone_sfm_main  # noqa: E402
from real_photos import photos_main  # noqa: E402
from real_temple import (  # noqa: E402
    BOX,
    DATA,
    SILHOUETTE_GREY,
    pose_errors,
    print_table,
    run_photosurf,
    run_sgbm,
    shares,
    temple_main,
)
from real_vase import vase_main  # noqa: E402

#: What other benchmarks take from here: the temple data set, its shares, SGBM's row, the
#: timed in-process run.
__all__ = ["BOX", "DATA", "SILHOUETTE_GREY", "main", "pose_errors", "print_table",
           "run_in_process", "run_photosurf", "run_sgbm", "shares"]


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sceaux", action="store_true",
                        help="the Sceaux castle photos (SfM, cloud, memory) instead of the "
                             "temple rows")
    parser.add_argument("--phone", metavar="FOLDER",
                        help="a phone-sized photo folder (e.g. 30 views of 12 MP rendered by "
                             "photosurf synth) instead of the temple rows")
    parser.add_argument("--phone-sfm", metavar="FOLDER",
                        help="SfM alone on a photo folder at each --sift size (CPU-s, peak, "
                             "poses against --truth)")
    parser.add_argument("--truth", metavar="CAMERAS",
                        help="--phone-sfm / --phone: the folder's true cameras (a rendered "
                             "scene's cameras.yml, any image size; --phone: and the cloud "
                             "against the truth/mesh.ply beside it)")
    parser.add_argument("--sift", default="1600",
                        help="--phone-sfm: SIFT longer sides, comma-separated")
    parser.add_argument("--features", default="8192",
                        help="--phone-sfm: SIFT features an image at most, comma-separated")
    parser.add_argument("--matchers", default="exhaustive",
                        help="--phone-sfm: run_sfm matchers, comma-separated")
    parser.add_argument("--cameras", metavar="MODEL",
                        help="with --sceaux: the cameras (and sparse points) of an earlier "
                             "SfM run's COLMAP model instead of running SfM again")
    parser.add_argument("--vase", action="store_true",
                        help="photosurf run of the default stereo recipe against its truth "
                             "(benchmarks/open_surface.py's scores) instead of the temple rows")
    parser.add_argument("--turned", action="store_true",
                        help="the turned temple with its par file (benchmarks/turned_ring.py)")
    parser.add_argument("--pairs", metavar="NN,NN",
                        help="photosurf run of these chessboard rig pairs (e.g. 03,06,12) to "
                             "open surfaces, flatness beside Poisson (benchmarks/real_pair.py)")
    parser.add_argument("--exif", action="store_true",
                        help="the rendered ring's EXIF-tagged JPEG copies "
                             "(benchmarks/exif_ring.py)")
    parser.add_argument("--workspace", help="--vase/--sceaux/--phone: the run's workspace "
                                            "(default a new temporary folder)")
    parser.add_argument("--to", help="--sceaux/--phone: last stage (--phone: acquire)")
    parser.add_argument("--renders", default="/tmp",
                        help="--sceaux: folder of the surface-beside-photos PNG")
    parser.add_argument("--quick", action="store_true",
                        help="spacing 3, no photosurf cloud on SfM cameras")
    parser.add_argument("--sfm-only", action="store_true",
                        help="only the SfM rows (no dense clouds)")
    parser.add_argument("--no-sfm", action="store_true",
                        help="only the dense clouds on the given cameras (no SfM rows)")
    parser.add_argument("--json", default=str(ROOT / "benchmarks" / "results" / "real.json"))
    parser.add_argument("--spacing", type=int, default=None,
                        help="candidate spacing, px (default 2; --quick 3)")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    results = Path(args.json).parent
    if args.vase:
        return vase_main(args)
    if args.pairs:
        import real_pair

        return real_pair.main(["--pairs", args.pairs, "--renders", args.renders,
                               "--json", str(results / "real_pairs.json")]
                              + (["--workspace", args.workspace] if args.workspace else []))
    if args.turned:
        import turned_ring

        return turned_ring.main(["--spacing", str(args.spacing or 3),
                                 "--json", str(results / "real_turned.json")])
    if args.exif:
        import exif_ring

        return exif_ring.main(["--json", str(results / "real_exif.json")]
                              + (["--spacing", str(args.spacing)] if args.spacing else []))
    if args.phone_sfm:
        if args.json.endswith("real.json"):
            args.json = str(Path(args.json).with_name("real_phone_sfm.json"))
        return phone_sfm_main(args)
    if args.sceaux or args.phone:
        if args.json.endswith("real.json"):
            args.json = str(Path(args.json).with_name("real_photos.json"))
        return photos_main(args)
    return temple_main(args)


if __name__ == "__main__":
    sys.exit(main())
