"""The folder's views at the working scale are decoded once and read back unchanged."""

from __future__ import annotations

import pickle

import cv2
import numpy as np

from pipeline.acquisition import WorkingViews
from pipeline.inputs import FolderImages


class _Counting(FolderImages):
    reads = 0

    def __getitem__(self, index):
        type(self).reads += 1
        return super().__getitem__(index)


def test_views_decoded_once_the_same_pixels_and_removed(tmp_path):
    rng = np.random.default_rng(5)
    names = []
    for k in range(3):
        names.append(f"v{k}.png")
        cv2.imwrite(str(tmp_path / names[-1]), rng.integers(0, 255, (120, 160, 3), np.uint8))
    shapes = [(60, 80, 3)] * 3
    folder = _Counting(tmp_path, names, shapes, 0.5)
    views = WorkingViews(folder)
    first = [views[k] for k in range(3)] + [views[1], views[1]]
    assert _Counting.reads == 3                       # each file decoded once
    for k in range(3):
        np.testing.assert_array_equal(first[k], FolderImages(tmp_path, names, shapes, 0.5)[k])
    np.testing.assert_array_equal(first[3], first[1])
    assert views.shapes == shapes and len(views) == 3 and views.lazy
    assert isinstance(pickle.loads(pickle.dumps(views)), FolderImages)  # tasks elsewhere
    where = views._dir
    assert len(list(where.glob("*.npy"))) == 3
    views.close()
    assert not where.exists()
