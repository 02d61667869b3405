"""``axis="auto"``: the axis trial's sections and loops are the slicing's own, organised once."""

from __future__ import annotations

import functools

import numpy as np

from surface import section_loops
from surface.reconstruct import organise_sections, slice_cloud, surface_from_points
from testkit import shapes


def test_the_axis_trials_loops_are_reused_and_equal_to_organising_afresh(monkeypatch):
    """The chosen axis's sections come back organised (``SlicedCloud.organised``):
    ``organise_sections(organised=)`` with the trial's options calls no
    ``topology.organise`` and gives the loops and messages organising afresh gives;
    other options organise again; ``surface_from_points`` organises no section beyond
    the axis trial's."""
    cloud = shapes.sample("torus", 4000, seed=0, sigma=0.002)
    sliced = slice_cloud(cloud, axis="auto")
    sections = [s for s in sliced.sections if len(s)]
    assert sliced.organised and {id(s) for s in sections} <= set(sliced.organised)

    calls = [0]
    real = section_loops.organise

    @functools.wraps(real)
    def counted(*args, **kwargs):
        calls[0] += 1
        return real(*args, **kwargs)

    monkeypatch.setattr(section_loops, "organise", counted)
    kept, loops, messages = organise_sections(sections, organised=sliced.organised,
                                              min_points=4, outlier_threshold=4.0)
    assert calls[0] == 0
    fresh_kept, fresh_loops, fresh_messages = organise_sections(sections, min_points=4)
    assert calls[0] == len(sections)
    assert [id(s) for s in kept] == [id(s) for s in fresh_kept]
    assert messages == fresh_messages
    for found, again in zip(loops, fresh_loops, strict=True):
        assert len(found) == len(again)
        for a, b in zip(found, again, strict=True):
            np.testing.assert_array_equal(a.points, b.points)
    organise_sections(sections, organised=sliced.organised, min_points=6)
    assert calls[0] == 2 * len(sections)
    calls[0] = 0
    slice_cloud(cloud, axis="auto")
    trial = calls[0]
    calls[0] = 0
    surface_from_points(cloud, axis="auto")
    assert trial > 0 and calls[0] == trial
