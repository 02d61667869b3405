"""The folder's views at the working scale are decoded once and read back unchanged."""

from __future__ import annotations

import pickle
from pathlib import Path

import cv2
import numpy as np
import pytest

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


def test_scratch_lives_in_the_work_folder_and_goes_with_it(tmp_path, monkeypatch):
    """acquire_folder's scratch (SfM's work folder, the reduced views, the pairs' stored
    clouds) is one folder inside ``work_dir`` (photosurf run: the stage's temporary
    output, removed with it after a kill), gone when the call ends, even by an error."""
    import pipeline.acquisition as acquisition
    import pipeline.inputs as inputs

    seen = {}

    def fake_load(folder, cameras, sfm_work_dir=None, **kwargs):
        seen["sfm"] = Path(sfm_work_dir)
        return {"images": None}

    def fake_matched(folder, loaded, executor, check_views, masks, box, options, scratch):
        seen["scratch"] = Path(scratch)
        (Path(scratch) / "pairs").mkdir()
        (Path(scratch) / "pairs" / "pair_0_1.npz").write_bytes(b"x")
        raise KeyboardInterrupt  # a signal's exception mid-run

    monkeypatch.setattr(inputs, "load_folder", fake_load)
    monkeypatch.setattr(acquisition, "_matched", fake_matched)
    work = tmp_path / ".acquire.1234"
    with pytest.raises(KeyboardInterrupt):
        acquisition.acquire_folder(tmp_path, work_dir=work)
    assert seen["scratch"].parent == work and seen["sfm"].parent == seen["scratch"]
    assert work.is_dir() and not any(work.iterdir())
