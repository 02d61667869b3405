"""Cameras against reference cameras: rotation and centre errors after a similarity."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def pose_errors(cams, reference) -> tuple[dict, tuple]:
    """Rotation / centre errors of cameras against the reference after a similarity (by name)."""
    from matching.sfm import umeyama

    ref = {c.name: c for c in reference}
    cams = [c for c in cams if c.name in ref]
    src = np.stack([c.center for c in cams])
    dst = np.stack([ref[c.name].center for c in cams])
    s, R, t = umeyama(src, dst)
    centre_err = np.linalg.norm(s * src @ R.T + t - dst, axis=1)
    rot = []
    for c in cams:
        d = c.R @ R.T @ ref[c.name].R.T
        rot.append(np.degrees(np.arccos(np.clip((np.trace(d) - 1) / 2, -1, 1))))
    centres = np.stack([c.center for c in reference])
    radius = float(np.mean(np.linalg.norm(centres - centres.mean(0), axis=1)))
    return {"rot_median_deg": float(np.median(rot)), "rot_max_deg": float(np.max(rot)),
            "centre_rms_mm": 1000 * float(np.sqrt(np.mean(centre_err**2))),
            "centre_rms_pct_radius": 100 * float(np.sqrt(np.mean(centre_err**2))) / radius,
            }, (s, R, t)
