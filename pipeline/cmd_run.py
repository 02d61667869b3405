"""``photosurf run``: any supported input to a smooth surface and a report, resumably."""

from __future__ import annotations

import argparse
import json
import sys

from pipeline import config as config_mod
from pipeline import progress
from pipeline.errors import InputError
from pipeline.options import add_config_arguments
from pipeline.plan import KINDS, STAGE_ORDER

HELP = "run the whole pipeline (scene/stereo pair/image folder/point cloud -> surface + report)"

EPILOG = """\
INPUT kinds (detected, or forced with --kind):
  scene   a scene recipe .toml: rendered first into OUTDIR/scene, truth kept for the report
  stereo  LEFT RIGHT image files with --rig RIG.yml, or a folder with two images and a rig file
  folder  a folder of images all around the object (multi-view), cameras from
          --cameras FILE, FOLDER/cameras.yml or FOLDER/sparse, else pycolmap SfM
  cloud   a point cloud .ply .xyz .csv .npz

Stages: scene -> acquire -> sections -> curves -> stitch -> smooth -> export -> report.
A rerun skips stages whose inputs, parameters and outputs are unchanged; a killed
run resumes when the same command is run again.  Parameters: pipeline/defaults.toml,
--config FILE, --set section.key=value (resolved set in OUTDIR/config.toml).

examples:
  photosurf run fixtures/scenes/vase.toml --out out
  photosurf run left.png right.png --rig rig.yml --out out --set sections.count=40
  photosurf run cloud.ply --out out --from sections --to stitch
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.epilog = EPILOG
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.add_argument("inputs", nargs="+", metavar="INPUT",
                        help="scene recipe, point cloud, image folder, or LEFT RIGHT images")
    parser.add_argument("--out", required=True, metavar="OUTDIR", help="workspace folder")
    parser.add_argument("--kind", choices=KINDS, help="force the input kind")
    parser.add_argument("--rig", metavar="RIG.yml", help="stereo rig file (for LEFT RIGHT)")
    parser.add_argument("--cameras", metavar="FILE",
                        help="cameras of an image folder (as photosurf acquire --cameras: "
                             "cameras.yml, COLMAP model, projection-matrix .txt); default "
                             "FOLDER/cameras.yml or FOLDER/sparse, else pycolmap SfM")
    parser.add_argument("--scale", metavar="A_X,A_Y B_X,B_Y@IMAGE=DIST",
                        help="image folder: two pixels of IMAGE (as shown, full size) DIST "
                             "apart give the SfM frame real units (= --set acquire.scale=...)")
    parser.add_argument("--markers", type=float, metavar="SIDE",
                        help="image folder: ArUco markers of side SIDE in the images give "
                             "the SfM frame real units (= --set acquire.markers=SIDE)")
    parser.add_argument("--open", action="store_true",
                        help="leave holes in the data (an end the points do not cover) as "
                             "borders instead of filling them (= --set sections.open=true)")
    add_config_arguments(parser)
    parser.add_argument("--from", dest="start", choices=STAGE_ORDER, metavar="STAGE",
                        help=f"first stage to run ({', '.join(STAGE_ORDER)})")
    parser.add_argument("--to", dest="stop", choices=STAGE_ORDER, metavar="STAGE",
                        help="last stage to run")
    parser.add_argument("--force", action="store_true",
                        help="rerun the chosen stages even when up to date")
    parser.add_argument("--json", action="store_true",
                        help="print a machine-readable summary (JSON) on stdout")


def failure_summary(outdir: str, error: str) -> dict:
    """The ``--json`` summary of a run that stopped on a failed stage (from its manifest)."""
    from pathlib import Path

    manifest = Path(outdir) / "manifest.json"
    stages = json.loads(manifest.read_text())["stages"] if manifest.is_file() else {}
    report = Path(outdir) / "report.html"
    return {"outdir": str(outdir), "error": error, "manifest": str(manifest),
            "report": str(report) if report.is_file() else None,
            "stages": [{"name": name, "status": stages[name].get("status"),
                        **({"reason": stages[name]["reason"]} if "reason" in stages[name]
                           else {})}
                       for name in STAGE_ORDER if name in stages]}


def run(args: argparse.Namespace) -> int:
    from pipeline.engine import StageError, run_pipeline
    from pipeline.executor import get_executor

    progress.set_quiet(args.quiet or args.json)
    assignments = list(args.assignments or [])
    if args.scale is not None:
        from matching.scale import parse_scale

        try:
            parse_scale(args.scale)  # a bad form fails before any stage runs
        except ValueError as exc:
            raise InputError(f"--{exc}") from None
        assignments.append(f"acquire.scale={json.dumps(args.scale)}")
    if args.markers is not None:
        if not args.markers > 0:
            raise InputError(f"--markers {args.markers:g}: the marker side must be positive")
        assignments.append(f"acquire.markers={float(args.markers)!r}")
    if args.open:
        assignments.append("sections.open=true")
    config = config_mod.resolve(args.config, assignments)
    scheduler = args.scheduler or config["executor"]["scheduler"]
    with get_executor(scheduler, config["executor"]["workers"]) as executor:
        try:
            if args.rig and args.cameras:
                raise InputError("give --rig (stereo pair) or --cameras (image folder), "
                                 "not both")
            summary = run_pipeline(args.inputs, args.out, config, kind=args.kind,
                                   rig=args.rig or args.cameras,
                                   start=args.start, stop=args.stop, force=args.force,
                                   executor=executor)
        except StageError as exc:  # the CLI prints the one-line error; JSON readers get it too
            if args.json:
                json.dump(failure_summary(args.out, str(exc)), sys.stdout, indent=1)
                sys.stdout.write("\n")
            raise
    if args.json:
        json.dump(summary.to_dict(), sys.stdout, indent=1)
        sys.stdout.write("\n")
    elif not args.quiet:
        print(f"photosurf run: {summary.kind} input -> {summary.outdir}")
        print(summary.table())
        if summary.report is not None:
            print(f"report: {summary.report}")
    return 0
