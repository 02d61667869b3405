"""surface.topology: points on one straight line are no closed curve.

A flat cloud cut along an axis lying in its plane gives sections whose
points are collinear; ``organise`` skips them with a
``SectionSkippedWarning`` instead of building a zero-area loop.  The rule is
relative (width ≤ ``TOL.planar_rel``·diameter), so a genuinely thin but
two-dimensional loop is kept.
"""

from __future__ import annotations

import numpy as np
import pytest

from surface.sections import SectionSkippedWarning, slice_sections
from surface.topology import organise
from tests.surface.test_topology import ellipse, make_section


@pytest.mark.parametrize("angle", [0.0, 0.7, np.pi / 2])
@pytest.mark.parametrize("offset", [0.0, 1e6])
def test_collinear_section_is_skipped(angle, offset):
    # 60 points on a segment of length 2 in any direction, anywhere: rounding in
    # to_plane leaves them within ~1e-16 relative of the line, far below 1e-9
    t = np.random.default_rng(1).uniform(-1, 1, 60)
    uv = np.c_[t * np.cos(angle), t * np.sin(angle)] + offset
    with pytest.warns(SectionSkippedWarning, match="one line"):
        assert organise(make_section(uv, sid=3)) == []


def test_thin_ellipse_is_still_a_loop():
    # axes 2 and 1e-4: width/diameter = 5e-5, five decades above TOL.planar_rel
    uv = ellipse(200, np.random.default_rng(2), axes=(2.0, 1e-4))
    loops = organise(make_section(uv))
    assert len(loops) == 1 and len(loops[0]) == 200


@pytest.mark.parametrize("axis", ["x", "auto", (1.0, 1.0, 0.0)])
def test_flat_cloud_cut_across_its_plane_has_no_loop(axis):
    # a disc of 400 points in the plane z = 0.3 cut along axes in that plane: the
    # projection onto a section plane moves points along the axis, so they stay on
    # the section's line z = 0.3 -- never a closed curve
    phi = np.random.default_rng(3).uniform(0, 2 * np.pi, 400)
    r = np.sqrt(np.random.default_rng(4).uniform(0, 1, 400))
    flat = np.c_[r * np.cos(phi), r * np.sin(phi), np.full(400, 0.3)]
    with pytest.warns(SectionSkippedWarning):
        loops = [organise(s) for s in slice_sections(flat, axis, count=8) if len(s)]
    assert all(found == [] for found in loops)
