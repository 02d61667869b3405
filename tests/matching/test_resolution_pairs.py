"""Views read reduced: the pairs only cover the views (matching.view_pairs.covering_pairs)."""

from __future__ import annotations

import numpy as np
import pytest

from matching.cameras import Camera
from matching.view_pairs import select_pairs
from testkit.rings import ring_cameras


def _ring(n: int, jitter: float = 0.0, seed: int = 0) -> list[Camera]:
    """``n`` views on a ring round the origin's vertical axis, looking at (0, 0, 1.5);
    ``jitter``: each centre moved by up to that share of the ring's radius."""
    return ring_cameras(n, jitter=jitter, seed=seed)


class _Views(list):
    def __init__(self, images, scratch):
        super().__init__(images)

    def close(self):
        pass


@pytest.mark.parametrize("n, jitter", [(30, 0.0), (30, 0.01), (24, 0.005), (31, 0.0)])
def test_a_cover_keeps_every_view_and_a_pair_in_any_three_neighbours(n, jitter):
    cams = _ring(n, jitter, seed=n)
    full = select_pairs(cams)
    kept = select_pairs(cams, cover=True)
    assert len(full) == n                       # both ring neighbours of every view
    assert set(kept) <= set(full)
    assert {v for p in kept for v in p} == set(range(n))
    assert len(kept) <= n // 2 + 1              # about half: every other neighbour pair
    unordered = {frozenset(p) for p in kept}
    for k in range(n):                          # three neighbouring views hold a kept pair
        run = [k, (k + 1) % n, (k + 2) % n]
        assert frozenset(run[:2]) in unordered or frozenset(run[1:]) in unordered


def _path(n: int) -> list[Camera]:
    """``n`` views walked past a wall (parallel axes, not a ring)."""
    K = np.array([[400.0, 0, 159.5], [0, 400.0, 119.5], [0, 0, 1]])
    return [Camera(K, [], np.eye(3), -np.array([0.5 * k, 0.0, -6.0]), 320, 240, f"p{k}.png")
            for k in range(n)]


def test_acquire_covers_only_a_ring_read_reduced(monkeypatch, tmp_path):
    """``_matched`` asks for a cover exactly when the views form a ring and the working
    scale is below 1 (one pair's σ meets the request there), and records it."""
    import matching.multiview as multiview
    import pipeline.acquisition as acquisition

    seen = []

    class _Cloud:
        def __init__(self):
            self.stats = {}

    def fake(images, cameras, **kwargs):
        seen.append(kwargs["pair_options"])
        return _Cloud()

    monkeypatch.setattr(multiview, "reconstruct_multiview", fake)
    monkeypatch.setattr(acquisition, "_warn_identical_views", lambda *args: None)
    for cams, scale, cover in ((_ring(6), 1.0, False), (_ring(6), 0.4, True),
                               (_path(6), 0.4, False)):
        loaded = {"images": [np.zeros((240, 320), np.uint8)] * 6, "cameras": cams,
                  "names": [c.name for c in cams], "working_scale": scale,
                  "camera_source": "x", "unregistered": [], "ignored": [], "sfm": None}
        if scale < 1.0:  # WorkingViews wraps a lazily reading folder
            monkeypatch.setattr(acquisition, "WorkingViews", _Views)
        scratch = tmp_path / f"{scale}{cams[0].name}"
        scratch.mkdir()
        cloud = acquisition._matched("f", loaded, None, 2, "none", None, {}, str(scratch))
        assert seen[-1] == {"cover": cover} and cloud.stats["pairs_cover"] is cover
