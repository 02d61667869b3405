"""``photosurf synth RECIPE --out OUTDIR``: render a synthetic scene with its ground truth.

The recipe (TOML) is validated before anything is written; the output folder
appears complete or not at all (see :func:`pipeline.scenes.render_scene` for
its contents and :mod:`pipeline.scenes` for the image-formation model).
"""

from __future__ import annotations

import argparse
import logging

HELP = "render a synthetic scene (TOML recipe) with exact ground truth into a folder"

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    # the default is resolved in run(): importing pipeline.scenes (numba, OpenCV) here would
    # cost every photosurf command ~0.5 s before it can even refuse bad input
    parser.add_argument("recipe", nargs="?", default=None, metavar="RECIPE",
                        help="scene recipe (TOML); default: the vase, fixtures/scenes/vase.toml")
    parser.add_argument("--out", required=True, metavar="OUTDIR",
                        help="output folder: new, empty, or an earlier synth output (only "
                             "the files photosurf wrote there are replaced)")
    parser.add_argument("--set", action="append", default=[], metavar="TABLE.KEY=VALUE",
                        dest="overrides",
                        help="override a recipe field, value in TOML syntax "
                             "(e.g. --set cameras.width=320 --set seed=7); repeatable")


def parse_override(text: str) -> tuple[str, object]:
    """``"cameras.width=320"`` -> ``("cameras.width", 320)``; a bare word stays a string."""
    from pipeline.config import parse_assignment

    path, value = parse_assignment(text, "TABLE.KEY=VALUE", min_parts=1)
    return ".".join(path), value


def _precheck(path: str, overrides: dict) -> None:
    """The recipe's sizes (:func:`pipeline.limits.check_recipe`) from its raw TOML plus the
    ``--set`` values, before the scene code (numba, scipy, open3d: ~0.7 s of imports) is
    loaded: an oversized request is refused at the cost of the interpreter's start-up."""
    from pipeline import limits
    from pipeline.config import deep_update
    from pipeline.guards import load_toml

    raw = load_toml(path, "recipe file")  # regular file, bounded size and nesting
    deep_update(raw, overrides, dotted=True)  # as load_recipe will
    limits.check_recipe(raw, path)


def run(args: argparse.Namespace) -> int:
    from pipeline import progress
    from pipeline.atomic import output_dir_state
    from pipeline.guards import check_output, regular_file

    progress.set_quiet(args.quiet)
    overrides = dict(parse_override(text) for text in args.overrides)
    if args.recipe is not None:
        regular_file(args.recipe, "recipe file")
        _precheck(args.recipe, overrides)
    from pipeline.scenes import DEFAULT_RECIPE, load_recipe, render_scene

    if args.recipe is None:
        args.recipe = str(DEFAULT_RECIPE)
    recipe = load_recipe(args.recipe, overrides=overrides)
    mesh = recipe["shape"].get("path")
    check_output(args.out, [args.recipe, mesh], folder=True)
    output_dir_state(args.out, "synth")  # refused before rendering, not after
    outdir = render_scene(recipe, args.out, progress=not args.quiet, source=args.recipe)
    log.info("wrote %s", outdir)
    return 0
