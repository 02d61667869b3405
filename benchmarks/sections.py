"""Benchmark of the section front end: slicing, topology and Catmull-Rom prediction.

Surface: the issue's vase r(z) = 1 + 0.3 sin 2z, z ∈ [0, 3] (no caps), points
area-uniform with Gaussian noise σ = 0.002.  Figures, one process:

* **scaling** (10⁴ … 10⁶ points, default section count and thickness from the
  point density): seconds for ``slice_sections``, ``organise`` (all sections)
  and ``predict_sections`` (N = 64, smoothing 8), points per section, and the
  RMS of the predicted ring points' radius against the analytic r(h);
* **curve fit** (50 000 points, the same sections): the ring RMS against the
  analytic radius and the seconds for Catmull-Rom least squares at several
  smoothing levels and ``smoothing="auto"`` (GCV), side by side with the
  peers: the paper's unsmoothed curve (Catmull-Rom through every point,
  ``smoothing=1``) and scipy's periodic smoothing spline
  ``splprep(per=1, s=M·σ̂²)`` with σ̂ the loop's robust noise.

Run: ``.venv/bin/python benchmarks/sections.py [--quick] [--json PATH]``
(default JSON ``benchmarks/results/sections.json``; ``--quick`` stops at 10⁵).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path

# benchmarks/surface.py would shadow the surface package: keep this folder off the path
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).parent.resolve()]

import numpy as np  # noqa: E402
from scipy.interpolate import splev, splprep  # noqa: E402

from surface.catmull_rom import fit_loop, predict_sections  # noqa: E402
from surface.sections import SectionSkippedWarning, slice_sections  # noqa: E402
from surface.topology import organise_all  # noqa: E402

SIGMA = 0.002
N_RING = 64


def vase(n: int, sigma: float = SIGMA, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    z = rng.uniform(0.0, 3.0, 6 * n)
    r = 1.0 + 0.3 * np.sin(2 * z)
    weight = r * np.sqrt(1.0 + (0.6 * np.cos(2 * z)) ** 2)
    keep = rng.uniform(0.0, weight.max(), z.size) < weight
    z, r = z[keep][:n], r[keep][:n]
    phi = rng.uniform(0.0, 2 * np.pi, n)
    pts = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)
    return pts + rng.normal(0.0, sigma, pts.shape)


def ring_error(rings) -> np.ndarray:
    pts = np.concatenate([r for r in rings])
    return np.hypot(pts[:, 0], pts[:, 1]) - (1.0 + 0.3 * np.sin(2 * pts[:, 2]))


def single_loops(loops_per_section):
    return [loops[0] for loops in loops_per_section if len(loops) == 1]


def scaling(sizes) -> list[dict]:
    rows = []
    for n in sizes:
        pts = vase(n)
        c0, t0 = time.process_time(), time.perf_counter()
        sections = slice_sections(pts, "z")
        c1, t1 = time.process_time(), time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", SectionSkippedWarning)
            loops = organise_all(sections)
        c2, t2 = time.process_time(), time.perf_counter()
        rings = predict_sections(single_loops(loops), N_RING, smoothing=8)
        c3, t3 = time.process_time(), time.perf_counter()
        err = ring_error(rings)
        rows.append(
            {
                "points": n,
                "sections": len(sections),
                "points_per_section": float(np.mean([len(s) for s in sections])),
                "slice_s": t1 - t0,
                "organise_s": t2 - t1,
                "predict_s": t3 - t2,
                "cpu_s": {"slice": c1 - c0, "organise": c2 - c1, "predict": c3 - c2},
                "ring_rms": float(np.sqrt(np.mean(err**2))),
            }
        )
    return rows


def _splprep_ring(loop, n: int) -> np.ndarray:
    """scipy periodic smoothing spline through the ordered loop, sampled at θ_j."""
    uv = (loop.points - loop.centroid) @ loop.frame[:2].T
    closed = np.vstack([uv, uv[:1]])
    tck, _ = splprep(closed.T, s=len(uv) * loop.noise**2, per=1, quiet=2)
    dense = np.stack(splev(np.linspace(0, 1, 20 * len(uv), endpoint=False), tck), axis=1)
    theta = np.mod(np.arctan2(dense[:, 1], dense[:, 0]), 2 * np.pi)
    order = np.argsort(theta)
    radius = np.hypot(dense[order, 0], dense[order, 1])
    want = 2 * np.pi * np.arange(n) / n
    r = np.interp(want, theta[order], radius[order], period=2 * np.pi)
    flat = np.stack([r * np.cos(want), r * np.sin(want)], axis=1)
    return loop.centroid + flat @ loop.frame[:2]


def curve_fit(n_points: int = 50_000) -> list[dict]:
    pts = vase(n_points)
    sections = slice_sections(pts, "z")
    loops = single_loops(organise_all(sections))
    rows = []
    methods = [(f"catmull-rom LS, smoothing {s}", s) for s in (4, 8, 16, 32, "auto")]
    methods.insert(0, ("catmull-rom through every point (paper, unsmoothed)", 1))
    for name, smoothing in methods:
        t0 = time.perf_counter()
        rings = [fit_loop(lp, smoothing).resample_theta(N_RING) for lp in loops]
        dt = time.perf_counter() - t0
        err = ring_error(rings)
        rows.append({"method": name, "seconds": dt, "ring_rms": float(np.sqrt(np.mean(err**2)))})
    t0 = time.perf_counter()
    rings = [_splprep_ring(lp, N_RING) for lp in loops]
    dt = time.perf_counter() - t0
    err = ring_error(rings)
    rows.append(
        {
            "method": "scipy splprep(per=1, s=M·σ̂²) [peer]",
            "seconds": dt,
            "ring_rms": float(np.sqrt(np.mean(err**2))),
        }
    )
    return rows, len(loops), float(np.mean([len(lp) for lp in loops]))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="stop the scaling at 1e5 points")
    parser.add_argument(
        "--json", type=Path, default=Path(__file__).parent / "results" / "sections.json"
    )
    args = parser.parse_args(argv)
    sizes = [10_000, 100_000] if args.quick else [10_000, 100_000, 1_000_000]
    scale_rows = scaling(sizes)
    print(f"vase r(z) = 1 + 0.3 sin 2z, sigma = {SIGMA}; default sections; N = {N_RING}")
    print("seconds: wall (CPU of this process; wall exceeds CPU when the machine is shared)")
    print(
        f"{'points':>9} {'sections':>8} {'pts/sec':>8} {'slice s':>15} {'organise s':>15} "
        f"{'predict s':>15} {'ring RMS':>9}"
    )
    for r in scale_rows:
        cpu = r["cpu_s"]
        print(
            f"{r['points']:>9} {r['sections']:>8} {r['points_per_section']:>8.0f} "
            f"{r['slice_s']:>6.2f} ({cpu['slice']:>6.2f}) "
            f"{r['organise_s']:>6.2f} ({cpu['organise']:>6.2f}) "
            f"{r['predict_s']:>6.2f} ({cpu['predict']:>6.2f}) {r['ring_rms']:>9.5f}"
        )
    fit_rows, n_loops, mean_pts = curve_fit()
    print(f"\ncurve fit on 50 000 points: {n_loops} loops of {mean_pts:.0f} points on average")
    print(f"{'method':<54} {'seconds':>8} {'ring RMS':>9}")
    for r in fit_rows:
        print(f"{r['method']:<54} {r['seconds']:>8.3f} {r['ring_rms']:>9.5f}")
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({"scaling": scale_rows, "curve_fit": fit_rows}, indent=2))
    print(f"\nwrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
