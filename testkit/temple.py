"""The temple ring turned: every image by a seeded random quarter turn, its par file with it.

Shared by ``tests/pipeline/test_inputs_turned.py`` and ``benchmarks/turned_ring.py``; reads
the real data set ``temple_sparse_ring`` (images and ``templeSR_par.txt``, the Middlebury
projection-matrix format written by :func:`write_par`).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from matching.cameras import read_projection_txt, turn_camera
from matching.image_file import imread


def write_par(path: Path, cameras) -> None:
    """A Middlebury ``*_par.txt`` of ``cameras`` (every number as Python's repr: exact)."""
    lines = [str(len(cameras))]
    for cam in cameras:
        numbers = np.concatenate([cam.K.ravel(), cam.R.ravel(), cam.t.ravel()])
        lines.append(" ".join([cam.name, *(repr(float(v)) for v in numbers)]))
    path.write_text("\n".join(lines) + "\n")


def turned_temple(source: Path, folder: Path, seed: int = 0) -> dict[str, int]:
    """The temple ring with every image turned by a random quarter turn (np.rot90, seeded)
    and its par file turned with it (:func:`matching.cameras.turn_camera`), in ``folder``;
    returns each image's quarter turns."""
    upright = read_projection_txt(source / "templeSR_par.txt")
    turns = np.random.default_rng(seed).integers(0, 4, len(upright))
    folder.mkdir(parents=True, exist_ok=True)
    for cam, k in zip(upright, turns, strict=True):
        image = imread(source / cam.name)
        assert cv2.imwrite(str(folder / cam.name), np.ascontiguousarray(np.rot90(image, k)))
    write_par(folder / "templeSR_par.txt",
              [turn_camera(cam, int(k)) for cam, k in zip(upright, turns, strict=True)])
    return {cam.name: int(k) for cam, k in zip(upright, turns, strict=True)}
