"""pipeline.guards' native-stderr capture under the acquisition's threads."""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

import cv2
import numpy as np

from pipeline.guards import read_image
from tests.matching.test_fd_capture import _fd2_to_file, _read_back, _same_file


def test_images_read_on_many_threads_leave_stderr_working(tmp_path):
    """The acquisition's pattern: views decoded on a thread pool, each read inside a capture."""
    rng = np.random.default_rng(0)
    paths = []
    for k in range(8):
        path = tmp_path / f"view{k}.png"
        cv2.imwrite(str(path), rng.integers(0, 255, (64, 64), dtype=np.uint8))
        paths.append(path)
    with _fd2_to_file() as target:
        with ThreadPoolExecutor(4) as pool:
            shapes = list(pool.map(lambda p: read_image(p).shape, paths * 25))
        assert _same_file(2, target)
        os.write(2, b"after\n")
        assert _read_back(target) == b"after\n"
    assert shapes == [(64, 64)] * 200
