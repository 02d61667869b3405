"""The ``photosurf`` command.

Each subcommand lives in its own module ``pipeline/cmd_<name>.py`` exposing

* ``HELP``: one line for ``photosurf --help``;
* ``add_arguments(parser)``: its argparse options (inputs positional, outputs
  named by ``--out``);
* ``run(args) -> int``: the work; returns the exit status.

Errors a user can fix (bad input, missing file, invalid recipe) are raised as
``ValueError`` / ``FileNotFoundError`` / :class:`pipeline.errors.InputError`
and printed here as one line, ``photosurf CMD: error: ...``, with exit
status 2.  ``-v`` also prints the traceback.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
import traceback

from pipeline import __version__
from pipeline.errors import InputError

#: Subcommands in the order ``--help`` lists them.
COMMANDS = [
    "run",
    "synth",
    "calibrate",
    "match",
    "stereo",
    "acquire",
    "sections",
    "smooth",
    "render",
    "batch",
]

#: Errors printed as one line with exit status 2.  ``OSError`` covers what the
#: system refuses (a missing file, --out under a regular file, a full disk ...).
USER_ERRORS = (InputError, ValueError, OSError)


def _load(name: str):
    try:
        return importlib.import_module(f"pipeline.cmd_{name}")
    except ModuleNotFoundError as exc:
        if exc.name == f"pipeline.cmd_{name}":
            return None  # not built yet
        raise


class _Parser(argparse.ArgumentParser):
    """argparse with one-line usage errors, like every other photosurf error."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="photosurf",
        description="Photographs to a smooth, watertight surface: least-squares matching, "
        "planar sections, Catmull-Rom curves, Delaunay stitching, Loop's sextic Bezier patches.",
    )
    parser.add_argument("--version", action="version", version=f"photosurf {__version__}")
    common = _Parser(add_help=False)
    common.add_argument("-v", "--verbose", action="count", default=0,
                        help="more output (-vv for debug); tracebacks on error")
    common.add_argument("-q", "--quiet", action="store_true", help="only errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        module = _load(name)
        if module is None:
            continue
        p = sub.add_parser(name, help=module.HELP, description=module.HELP, parents=[common])
        module.add_arguments(p)
        p.set_defaults(_module=module)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 2
    level = logging.ERROR if args.quiet else (logging.DEBUG if args.verbose > 1 else
                                              logging.INFO if args.verbose else logging.WARNING)
    logging.basicConfig(level=level, format="photosurf: %(message)s")
    _quiet_opencv(args.verbose)
    try:
        status = args._module.run(args)
    except USER_ERRORS as exc:
        if args.verbose:
            traceback.print_exc()
        message = str(exc) or type(exc).__name__
        if isinstance(exc, OSError) and exc.filename and exc.strerror:
            # not "[Errno 21] ...: 'tmp' -> 'out'": a rename names the user's path (filename2)
            message = f"{exc.filename2 or exc.filename}: {exc.strerror}"
            if isinstance(exc, FileExistsError):  # mkdir of an output folder over a file
                message += " (a file is where a folder is needed)"
        print(f"photosurf {args.command}: error: {message}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"photosurf {args.command}: interrupted", file=sys.stderr)
        return 130
    return int(status or 0)


def _quiet_opencv(verbose: int) -> None:
    """OpenCV's decoders log to stderr themselves ("[ WARN:0] grfmt_png ..."); the error
    line is ours, so keep them quiet unless -v."""
    try:
        import cv2
    except ImportError:  # pragma: no cover - OpenCV is a dependency
        return
    logging_api = cv2.utils.logging
    logging_api.setLogLevel(logging_api.LOG_LEVEL_INFO if verbose
                            else logging_api.LOG_LEVEL_SILENT)


if __name__ == "__main__":
    sys.exit(main())
