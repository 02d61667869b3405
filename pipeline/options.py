"""Command-line options shared by several commands (commands never import each other:
they import this): the stereo-pair matching options and summaries of ``photosurf match``
and ``photosurf stereo``, the configuration options of ``photosurf run`` and ``batch``."""

from __future__ import annotations

import argparse
import math

from pipeline import limits
from pipeline.errors import InputError

#: ``--window`` -> ``match_pair(adaptive_patch=...)``.
WINDOW_MODES = {"adaptive": True, "ici": "ici", "population": "population", "fixed": False}


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
    parser.add_argument("--window", choices=tuple(WINDOW_MODES), default="adaptive",
                        help="LSM window per point: 'adaptive' (default: grown where the first "
                             "pass is less precise than the image's median), 'ici' (the side "
                             "of PATCH, ~1.5x, ~2x that agrees with every smaller one; ~3x "
                             "the second pass), 'population' (adaptive, then each window "
                             "class grown to the largest of ~1.5x, ~2x PATCH its nested "
                             "differences allow, windows clear of edges only: the one for "
                             "planar or gently curved, richly textured scenes; ~3x the "
                             "second pass), 'fixed'")


def match_options(args: argparse.Namespace) -> dict:
    """The matching keyword arguments, checked (``InputError`` naming the option)."""
    if args.patch < 5 or args.patch % 2 == 0:
        raise InputError(f"--patch must be an odd integer >= 5, got {args.patch}")
    if args.spacing < 1:
        raise InputError(f"--spacing must be a positive integer, got {args.spacing}")
    if args.max_iter < 1:
        raise InputError(f"--max-iter must be a positive integer, got {args.max_iter}")

    limits.check("iterations", args.max_iter, where="--max-iter")
    if not (math.isfinite(args.min_correlation) and -1.0 <= args.min_correlation <= 1.0):
        raise InputError(f"--min-correlation must be in [-1, 1], got {args.min_correlation}")
    return {"spacing": args.spacing, "patch": args.patch, "interpolation": args.interpolation,
            "epipolar": args.epipolar, "max_iter": args.max_iter,
            "min_correlation": args.min_correlation,
            "adaptive_patch": WINDOW_MODES[getattr(args, "window", "adaptive")]}


def summary(matches) -> str:
    counts = matches.status_counts()
    rejected = ", ".join(f"{k} {v}" for k, v in counts.items() if k != "ok")
    return (f"{counts.get('ok', 0)} of {len(matches)} candidates matched "
            f"({rejected or 'none rejected'})")


def check_some_matched(matches, left: str) -> None:
    if not matches.accepted.any():
        raise InputError(f"{left}: no point could be matched: {summary(matches)}")


def add_config_arguments(parser: argparse.ArgumentParser) -> None:
    """``--config``, ``--set`` and ``--scheduler`` (shared with ``photosurf batch``)."""
    parser.add_argument("--config", metavar="FILE", help="TOML file of parameters")
    parser.add_argument("--set", dest="assignments", action="append", default=[],
                        metavar="SECTION.KEY=VALUE",
                        help="set one parameter (repeatable), e.g. --set sections.count=40")
    parser.add_argument("--scheduler", metavar="ADDRESS",
                        help="Dask scheduler tcp://HOST:PORT, local-cluster[:N], or local "
                             "(default: executor.scheduler of the config)")
