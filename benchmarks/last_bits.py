"""Does the surface depend on the last bits of the cloud?  Perturbation checks.

Results that differ in the last bits between machines (another BLAS, another CPU's
vector paths, a solver changed elsewhere) must not change a decision: a section kept or
dropped, a cap's triangulation, the sizing's level.  Each cloud is moved by relative
perturbations ``x (1 + eps N(0, 1))`` (eps 0, then 1e-13 and 1e-12) and taken to its
sized surface again; the table shows, per cloud, the dense stitched triangles and the
sized step / ring points / triangles of every run and whether they all agree.

* the shapes of ``testkit/shapes.py`` (torus, amphora, pants, mug, vase; ``--points``,
  default 10⁴, seed 1), through ``pipeline.section_surface.sized_mesh``;
* with ``--workspace W`` (a workspace of the real temple ring with its cameras, e.g.
  ``benchmarks/real_surface.py --workspace W``'s), the pipeline from the sections to the
  smooth surface on a copy of W per run (``photosurf run --from sections``): rings,
  stitched triangles, patches.

    .venv/bin/python benchmarks/last_bits.py [--points N] [--shape S ...] [--runs K]
                                             [--workspace W] [--json PATH]

A cloud whose dense stitch is open under every perturbation (the 10⁴-point mug: its
handle merges with the wall at that density) is reported as such: consistent, not closed.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from _common import uptime, write_result  # noqa: E402

SHAPES = ("torus", "amphora", "pants", "mug", "vase")


def _epsilons(runs: int) -> list[tuple[int, float]]:
    """(seed, eps) of each run: the cloud as it is, then 1e-13 (and 1e-12 for the last)."""
    out = [(0, 0.0)] + [(seed, 1e-13) for seed in range(1, runs - 1)]
    return out + [(runs - 1, 1e-12)] if runs > 1 else out


def _moved(points: np.ndarray, seed: int, eps: float) -> np.ndarray:
    if eps == 0:
        return points
    return points * (1 + eps * np.random.default_rng(seed).standard_normal(points.shape))


def shape_runs(shape: str, points: int, runs: int) -> dict:
    from pipeline.section_surface import sized_mesh
    from testkit import shapes as _shapes

    cloud = _shapes.sample(shape, points, seed=1)
    outcomes = []
    for seed, eps in _epsilons(runs):
        try:
            sized, dense = sized_mesh(_moved(cloud, seed, eps), axis="z")
            outcomes.append([len(dense.triangles), sized.step, sized.n, len(sized.triangles)])
        except ValueError as exc:   # e.g. an open dense stitch
            outcomes.append(f"refused: {str(exc)[:60]}")
    return {"cloud": f"{shape} {points}", "runs": outcomes,
            "same": all(o == outcomes[0] for o in outcomes)}


def temple_runs(workspace: Path, runs: int) -> dict:
    from real import DATA  # noqa: E402  (benchmarks/real.py: the data set)

    from pipeline import artifacts, cli

    original = artifacts.read_cloud
    outcomes = []
    with tempfile.TemporaryDirectory() as scratch:
        for seed, eps in _epsilons(runs):
            copy = Path(scratch) / f"run{seed}"
            shutil.copytree(workspace, copy)

            def moved(folder, seed=seed, eps=eps):
                out = dict(original(folder))
                out["points"] = _moved(out["points"], seed, eps)
                return out

            artifacts.read_cloud = moved
            try:
                if cli.main(["run", str(DATA), "--cameras", str(DATA / "templeSR_par.txt"),
                             "--out", str(copy), "-q", "--from", "sections", "--to", "smooth",
                             "--force"]) != 0:
                    raise SystemExit(f"photosurf run on {copy} failed")
            finally:
                artifacts.read_cloud = original
            stages = json.loads((copy / "manifest.json").read_text())["stages"]
            outcomes.append([stages["curves"]["info"]["rings"],
                             stages["stitch"]["info"]["triangles"],
                             stages["smooth"]["info"]["patches"]])
            shutil.rmtree(copy)
    return {"cloud": f"temple ({workspace})", "runs": outcomes,
            "same": all(o == outcomes[0] for o in outcomes)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=10_000)
    parser.add_argument("--shape", nargs="+", choices=SHAPES, default=list(SHAPES))
    parser.add_argument("--runs", type=int, default=4, help="runs per cloud (>= 2)")
    parser.add_argument("--workspace", help="a workspace of the real temple ring with cameras")
    parser.add_argument("--json", default=str(ROOT / "benchmarks" / "results" / "last_bits.json"))
    args = parser.parse_args(argv)
    if args.runs < 2:
        parser.error("--runs must be at least 2")
    started = time.perf_counter()
    rows = [shape_runs(shape, args.points, args.runs) for shape in args.shape]
    if args.workspace:
        rows.append(temple_runs(Path(args.workspace), args.runs))
    print(f"last bits, eps {[eps for _, eps in _epsilons(args.runs)]}; load {uptime()}")
    for row in rows:
        print(f"{row['cloud']:<28} {'same' if row['same'] else 'DIFFERENT':<9} {row['runs']}")
    write_result(args.json, {"benchmark": "last_bits", "load": uptime(),
                             "seconds": time.perf_counter() - started, "rows": rows})
    return 0 if all(row["same"] for row in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
