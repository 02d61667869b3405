"""What every benchmark does the same way: the machine's load, goal lines, the JSON file."""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path


def uptime() -> str:
    """Load averages (1, 5, 15 min) of the shared machine, as ``uptime`` prints them."""
    return " ".join(Path("/proc/loadavg").read_text().split()[:3])


def print_goals(goals: Mapping[str, bool]) -> None:
    """One ``goal NAME: met`` / ``NOT met`` line per goal."""
    for key, ok in goals.items():
        print(f"goal {key}: {'met' if ok else 'NOT met'}")


def write_result(path: str | Path, result: Mapping) -> Path:
    """Write the benchmark's figures as indented JSON (numpy scalars as floats)."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1, default=float) + "\n")
    print(f"\nwrote {out}")
    return out
