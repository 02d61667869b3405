"""What every benchmark does the same way: the machine's load, goal lines, the JSON file."""

from __future__ import annotations

import datetime
import json
import subprocess
import sys
from collections.abc import Mapping
from pathlib import Path


def uptime() -> str:
    """Load averages (1, 5, 15 min) of the shared machine, as ``uptime`` prints them."""
    return " ".join(Path("/proc/loadavg").read_text().split()[:3])


def print_goals(goals: Mapping[str, bool]) -> None:
    """One ``goal NAME: met`` / ``NOT met`` line per goal."""
    for key, ok in goals.items():
        print(f"goal {key}: {'met' if ok else 'NOT met'}")


def run_meta() -> dict:
    """The command, commit and UTC time of this run (``docs/gen_figures.py`` shows them)."""
    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True,
                                text=True, cwd=Path(__file__).parent, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        commit = ""
    argv = [Path(sys.argv[0]).as_posix()] + sys.argv[1:] if sys.argv else []
    return {"command": "python " + " ".join(argv), "commit": commit or None,
            "utc": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M"),
            "load": uptime()}


def write_result(path: str | Path, result: Mapping) -> Path:
    """Write the benchmark's figures as indented JSON (numpy scalars as floats).

    A ``_meta`` entry records how the figures were made (:func:`run_meta`).
    """
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    result = {**result, "_meta": run_meta()}
    out.write_text(json.dumps(result, indent=1, default=float) + "\n")
    print(f"\nwrote {out}")
    return out
