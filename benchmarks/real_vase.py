"""The default stereo recipe end to end: ``photosurf run fixtures/scenes/vase.toml`` in
this process (timed), then ``benchmarks/open_surface.py``'s scores of its workspace (the
open surface against the truth on the part both views see)."""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from _common import uptime, write_result  # noqa: E402
from _timed_run import phase_figures, run_in_process  # noqa: E402


def vase_main(args) -> int:
    """``--vase``: ``photosurf run fixtures/scenes/vase.toml`` (the default stereo recipe)
    end to end, then ``benchmarks/open_surface.py``'s scores of its workspace (the open
    surface against the truth on the part both views see, its border against that part's)."""
    import json

    import open_surface

    ws = Path(args.workspace or tempfile.mkdtemp(prefix="real-vase-"))
    status, phases, _ = run_in_process([str(open_surface.RECIPE), "--out", str(ws), "-q"])
    if status != 0:
        print(f"photosurf run {open_surface.RECIPE.name}: exit {status}")
        return status
    ran = {"seconds": phases["total"].seconds}
    # score the workspace photosurf run wrote (open_surface's own run() is not repeated)
    open_surface.run = lambda workspace: {**ran, "summary": None}
    if args.json.endswith("real.json"):
        args.json = str(Path(args.json).with_name("real_vase.json"))
    open_surface.main(["--workspace", str(ws), "--json", args.json])
    result = json.loads(Path(args.json).read_text())
    result.pop("_meta", None)
    result.update(benchmark="real-vase", command="photosurf run fixtures/scenes/vase.toml",
                  run=phase_figures(phases), load=uptime())
    print(f"photosurf run: {phases['total'].seconds:.1f} s, {phases['total'].cpu_seconds:.1f} "
          f"CPU-s, peak {phases['total'].peak:.2f} GB (load {uptime()})")
    write_result(args.json, result)
    return 0
