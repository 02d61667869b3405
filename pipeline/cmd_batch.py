"""``photosurf batch``: many inputs, one workspace each, the objects run as tasks.

A thin command over :mod:`pipeline.batch` (the manifest format, one object's run).  Each
object is one task on the executor (in-process by default, Dask with ``--scheduler``);
an object that fails is reported and the others go on.  ``OUTDIR/batch.json`` lists
every object's status and workspace.
"""

from __future__ import annotations

import argparse
import json
import sys

from pipeline import config as config_mod
from pipeline import progress
from pipeline.batch import read_manifest, run_object
from pipeline.errors import escape
from pipeline.executor import get_executor
from pipeline.options import add_config_arguments
from pipeline.plan import STAGE_ORDER
from pipeline.workspace import Workspace, write_text

HELP = "run the pipeline on many inputs listed in a TOML manifest (Dask with --scheduler)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.epilog = __doc__.split("\n", 2)[2]
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.add_argument("manifest", metavar="MANIFEST.toml", help="batch manifest")
    parser.add_argument("--out", required=True, metavar="OUTDIR",
                        help="folder of the workspaces (OUTDIR/<name>)")
    add_config_arguments(parser)
    parser.add_argument("--to", dest="stop", choices=STAGE_ORDER, metavar="STAGE",
                        help="last stage to run for every object")
    parser.add_argument("--json", action="store_true",
                        help="print a machine-readable summary (JSON) on stdout")


def run(args: argparse.Namespace) -> int:
    progress.set_quiet(args.quiet or args.json)
    tasks = read_manifest(args.manifest)
    base_config = config_mod.resolve(args.config, args.assignments)  # fail early, once
    ws = Workspace(args.out)
    for task in tasks:
        task["outdir"] = str(ws.root / task["name"])
        task["config_files"] = ([args.config] if args.config else []) + task["config_files"]
        task["assignments"] = list(args.assignments)
        task["stop"] = args.stop
        config_mod.resolve(task["config_files"], task["assignments"], task["overrides"],
                           task["overrides_origin"])
    scheduler = args.scheduler or base_config["executor"]["scheduler"]
    with get_executor(scheduler, base_config["executor"]["workers"]) as executor:
        results = executor.map(run_object, tasks)
    summary = {"manifest": str(args.manifest), "outdir": str(ws.root), "objects": results}
    write_text(ws.root / "batch.json", json.dumps(summary, indent=1) + "\n")
    failed = [r for r in results if r["status"] != "done"]
    if args.json:
        json.dump(summary, sys.stdout, indent=1)
        sys.stdout.write("\n")
    elif not args.quiet:
        for r in results:
            note = r.get("error", "") or r.get("report") or ""
            print(f"  {r['name']:<20} {r['status']:<8} {note}")
        print(f"photosurf batch: {len(results) - len(failed)} of {len(results)} objects done "
              f"-> {ws.root}")
    if failed:  # one line, whatever the number of failures; batch.json lists each
        first = failed[0]
        more = f" (and {len(failed) - 1} more)" if len(failed) > 1 else ""
        print(f"photosurf batch: error: {len(failed)} of {len(results)} objects failed "
              f"(see {ws.root / 'batch.json'}): {escape(first['name'])}: "
              f"{escape(first['error'])}{more}", file=sys.stderr)
    return 2 if failed else 0
