"""matching.ring: a plane and circle through the camera centres; ring or not."""

from __future__ import annotations

import numpy as np

from matching.cameras import Camera, read_cameras
from matching.ring import fit_ring


def _cams(azimuths_deg, radius=5.0, height=1.0, tilt=None, noise=0.0, seed=0):
    rng = np.random.default_rng(seed)
    axis = np.array([0.0, 0.0, 1.0]) if tilt is None else np.asarray(tilt, float)
    axis /= np.linalg.norm(axis)
    e1 = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    K = np.array([[400.0, 0, 159.5], [0, 400.0, 119.5], [0, 0, 1]])
    cams = []
    for a in np.radians(azimuths_deg):
        c = radius * (np.cos(a) * e1 + np.sin(a) * e2) + height * axis
        c = c + rng.normal(0, noise, 3)
        f = -c / np.linalg.norm(c)
        r = np.cross(f, axis)
        r /= np.linalg.norm(r)
        R = np.stack([r, np.cross(f, r), f])  # image y points along -axis: "up" = axis
        cams.append(Camera(K, [], R, -R @ c, 320, 240))
    return cams


def test_a_tilted_noisy_ring_gives_its_normal_pointing_up():
    tilt = [0.3, -0.2, 1.0]
    fit = fit_ring(_cams(np.arange(0, 360, 30), tilt=tilt, noise=0.05))
    assert fit.is_ring and fit.reason == ""
    expected = np.asarray(tilt) / np.linalg.norm(tilt)
    # 12 centres with 0.05 noise on a radius-5 ring: the normal to ~0.05/5/sqrt(12) rad
    assert np.degrees(np.arccos(fit.axis @ expected)) < 1.0
    assert abs(fit.radius - 5.0) < 0.1
    assert fit.max_gap_deg < 40


def test_an_arc_or_a_line_is_not_a_ring():
    arc = fit_ring(_cams(np.arange(0, 120, 15)))
    assert not arc.is_ring and "gap" in arc.reason
    assert not fit_ring(_cams([0, 30])).is_ring
    line = [Camera(c.K, [], c.R, c.t + [0.0, 0.0, 3.0 * k], 320, 240)
            for k, c in enumerate(_cams([0, 0, 0, 0, 0]))]
    assert not fit_ring(line).is_ring


def test_the_temple_ring_stands_along_its_height(real_data_dir):
    cams = read_cameras(real_data_dir / "temple_sparse_ring" / "templeSR_par.txt")
    fit = fit_ring(cams)
    assert fit.is_ring
    # the bounding box of the data set is 102 x 160 x 75 mm: the temple's height is y
    assert abs(fit.axis[1]) > np.cos(np.radians(5.0))
    # measured: centres 0.1 mm off their plane, 0.56 m radius, largest gap 42 degrees
    assert fit.plane_rms < 0.01 * fit.radius
    assert fit.max_gap_deg < 60
