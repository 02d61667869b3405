"""Two-view triangulation: accuracy of the 3D point and of its predicted σ, and throughput.

One stereo pair (640×480, f = 800 px, baseline 0.5 at depth ~5, Brown
distortion k1 = −0.1), N points, Gaussian image noise σ px on both images.
Rows, all in one process on the same observations:

* ``cv2.triangulatePoints`` on pixels undistorted by ``cv2.undistortPoints``
  (the usual OpenCV recipe; linear only);
* ``matching.triangulate.triangulate_pair(refine=False)``: the conditioned
  linear (DLT) solution;
* ``triangulate_pair(refine=True)``: DLT then batched Gauss-Newton on the
  reprojection error in the observed (distorted) image.

Columns: RMS 3D error (scene units), mean Mahalanobis error
e^T Σ^-1 e over the points (3.0 when the propagated covariance is right),
mean of (e·v₁)²/σ² along the worst direction (1.0 when σ is right), and
points per second.

Run: ``.venv/bin/python benchmarks/triangulate.py [--quick] [--json PATH]``
(default JSON: ``benchmarks/results/triangulate.json``).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from matching.cameras import Camera  # noqa: E402
from matching.triangulate import triangulate_pair  # noqa: E402


def make_pair():
    K = np.array([[800.0, 0.0, 319.5], [0.0, 800.0, 239.5], [0.0, 0.0, 1.0]])
    dist = np.array([-0.1, 0.02, 0.0, 0.0])
    left = Camera(K, dist, np.eye(3), np.zeros(3), 640, 480, "left")
    R = cv2.Rodrigues(np.array([0.0, -0.1, 0.0]))[0]  # converging by 0.1 rad
    centre = np.array([0.5, 0.0, 0.0])
    right = Camera(K, dist, R, -R @ centre, 640, 480, "right")
    return left, right


def scene(n, rng, left, right):
    pix = rng.uniform([20, 20], [620, 460], size=(n, 2))
    _, d = left.ray(pix)
    X = d * rng.uniform(4.0, 6.0, size=(n, 1))
    inside = np.all((right.project(X) > 0) & (right.project(X) < [640, 480]), axis=1)
    return X[inside]


def measure(name, fn, X, repeats):
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        points, cov = fn()
        best = min(best, time.perf_counter() - t0)
    e = points - X
    row = {"method": name, "points": int(len(X)),
           "rms_3d": float(np.sqrt(np.mean(np.sum(e**2, axis=1)))),
           "points_per_s": float(len(X) / best)}
    if cov is not None:
        row["mahalanobis_mean"] = float(np.mean(np.einsum("ni,nij,nj->n", e,
                                                          np.linalg.inv(cov), e)))
        val, vec = np.linalg.eigh(cov)
        row["worst_dir_ratio"] = float(np.mean(np.einsum("ni,ni->n", e, vec[:, :, -1]) ** 2
                                               / val[:, -1]))
    return row


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="20k points instead of 200k")
    parser.add_argument("--sigma", type=float, default=0.3, help="image noise, px")
    parser.add_argument("--json", default=str(Path(__file__).parent / "results" /
                                              "triangulate.json"))
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    left, right = make_pair()
    X = scene(20_000 if args.quick else 200_000, rng, left, right)
    xl = left.project(X) + rng.normal(scale=args.sigma, size=(len(X), 2))
    xr = right.project(X) + rng.normal(scale=args.sigma, size=(len(X), 2))
    cov2 = np.broadcast_to(np.eye(2) * args.sigma**2, (len(X), 2, 2))

    def opencv():
        ul, ur = left.undistort_points(xl), right.undistort_points(xr)
        Xh = cv2.triangulatePoints(left.P, right.P, ul.T, ur.T)
        return (Xh[:3] / Xh[3]).T, None

    def ours(refine):
        def run():
            t = triangulate_pair(left, right, xl, xr, cov2, cov2, refine=refine, reject_p=None)
            return t.points, t.cov
        return run

    repeats = 3 if args.quick else 2
    rows = [measure("cv2.triangulatePoints (undistorted, linear)", opencv, X, repeats),
            measure("triangulate_pair refine=False (DLT)", ours(False), X, repeats),
            measure("triangulate_pair refine=True (DLT + Gauss-Newton)", ours(True), X, repeats)]
    print(f"two-view triangulation, sigma = {args.sigma} px, {len(X)} points "
          "(Mahalanobis mean should be 3, worst-direction ratio 1)")
    print(f"{'method':52s} {'RMS 3D':>10s} {'Mahal.':>7s} {'worst':>6s} {'pts/s':>10s}")
    for r in rows:
        maha, worst = r.get("mahalanobis_mean", np.nan), r.get("worst_dir_ratio", np.nan)
        print(f"{r['method']:52s} {r['rms_3d']:10.5f} {maha:7.3f} {worst:6.3f} "
              f"{r['points_per_s']:10.0f}")
    out = Path(args.json)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"sigma_px": args.sigma, "rows": rows}, indent=2))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
