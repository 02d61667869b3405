"""SfM alone on a photo folder (:func:`matching.sfm.run_sfm`) at each SIFT size and
matcher: views registered, reprojection, CPU seconds, peak memory, and the poses against
the true cameras of a rendered folder."""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from _common import print_goals, uptime, write_result  # noqa: E402
from _poses import pose_errors  # noqa: E402

from matching.cameras import read_cameras  # noqa: E402


def phone_sfm_main(args) -> int:
    """``--phone-sfm FOLDER``: :func:`matching.sfm.run_sfm` alone on a photo folder at each
    SIFT size of ``--sift`` (and each matcher of ``--matchers``): views registered,
    reprojection, CPU seconds of every thread (and per step, from SfM's progress lines),
    peak RSS, and with ``--truth CAMERAS`` (the true cameras of a rendered folder, matched
    by file stem, intrinsics scaled to the folder's size) the poses' errors after a
    similarity."""
    import logging
    import resource
    from dataclasses import replace

    from matching import sfm

    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    folder, rows = Path(args.phone_sfm), []
    truth = None
    if args.truth:
        truth = [replace(c, name=Path(c.name).stem) for c in read_cameras(args.truth)]
    for size, features in ((int(v), int(f)) for v in args.sift.split(",")
                           for f in args.features.split(",")):
        for matcher in args.matchers.split(","):
            sfm.SIFT_MAX_IMAGE_SIZE, sfm.SIFT_MAX_FEATURES = size, features
            cpu0, wall0 = time.process_time(), time.perf_counter()
            with tempfile.TemporaryDirectory(prefix="phone-sfm-") as work:
                res = sfm.run_sfm(folder, work_dir=work, matcher=matcher)
            row = {"method": f"sift{size}-{features}-{matcher}", "sift_px": size,
                   "sift_features": features, "matcher": matcher,
                   "views": len(res.registered) + len(res.unregistered),
                   "registered": len(res.registered),
                   "reprojection_px": res.mean_reprojection_error_px,
                   "sparse_points": len(res.points),
                   "cpu_seconds": time.process_time() - cpu0,
                   "seconds": time.perf_counter() - wall0,
                   "peak_gb_so_far": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6,
                   "focal_median_px": float(np.median([c.K[0, 0] for c in res.cameras]))}
            if truth:
                cams = [replace(c, name=Path(c.name).stem) for c in res.cameras]
                row.update(pose_errors(cams, truth)[0])
                width = max(c.width for c in res.cameras)
                row["focal_truth_px"] = float(truth[0].K[0, 0] * width / truth[0].width)
            print("  " + " ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}"
                                  for k, v in row.items()), flush=True)
            rows.append(row)
    goals = {"phone_sfm_all_registered": all(r["registered"] == r["views"] for r in rows)}
    print_goals(goals)
    write_result(args.json, {"benchmark": "real-phone-sfm", "folder": str(folder),
                             "load": uptime(), "rows": rows, "goals": goals})
    return 0
