"""Images as cameras store them: EXIF-oriented JPEG bytes, and the stored array of an upright view.

Shared by the image-reader and SfM tests and ``benchmarks/exif_ring.py``.  Images are
``(H, W)`` or ``(H, W, 3)`` uint8 arrays; orientations are EXIF's 1..8.
"""

from __future__ import annotations

import struct

import cv2
import numpy as np

from matching.image_file import orient


def exif_jpeg(image: np.ndarray, orientation: int) -> bytes:
    """JPEG bytes of ``image`` with an EXIF APP1 segment holding only Orientation
    (tag 0x0112; 6 = "turn 90° clockwise to view", as a phone writes for a portrait shot)."""
    ok, buffer = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 95])
    assert ok
    tiff = (b"II*\x00" + struct.pack("<I", 8) + struct.pack("<H", 1)
            + struct.pack("<HHIHH", 0x0112, 3, 1, orientation, 0) + struct.pack("<I", 0))
    payload = b"Exif\x00\x00" + tiff
    data = buffer.tobytes()
    return data[:2] + b"\xff\xe1" + struct.pack(">H", len(payload) + 2) + payload + data[2:]


def stored_for(upright: np.ndarray, orientation: int) -> np.ndarray:
    """The array a camera stores so that a viewer applying ``orientation`` shows ``upright``."""
    for candidate in range(4):  # the inverse of each of the 8 maps is one of them composed
        for flip in (False, True):
            stored = np.rot90(upright, candidate)
            stored = np.ascontiguousarray(stored[:, ::-1] if flip else stored)
            shown = orient(stored, orientation)
            if shown.shape == upright.shape and np.array_equal(shown, upright):
                return stored
    raise AssertionError(f"no inverse for orientation {orientation}")
