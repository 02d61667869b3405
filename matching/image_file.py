"""Image files as the user sees them: bytes read by Python, decoded by OpenCV, upright.

One decoder for every image photosurf reads (views, masks, calibration shots, what SfM
refines on):

* the bytes are read by Python (``np.fromfile``) and decoded from memory
  (``cv2.imdecode``): OpenCV's own file functions take the name as UTF-8 and crash the
  process (segmentation fault) on a name that is not;
* the EXIF orientation tag (TIFF tag 274, in a JPEG's APP1 ``Exif`` segment, a PNG's
  ``eXIf`` chunk, a WebP's ``EXIF`` chunk or a TIFF's first IFD) is applied, so the
  array is the image as a viewer shows it (``docs/decisions/image-orientation.md``);
  values 2-8 map the stored array ``S`` to the displayed one ``D`` as

  ====  ==========================  ====  ==========================
  2     ``D = S[:, ::-1]``          6     ``D = rot90(S, -1)``
  3     ``D = rot90(S, 2)``         7     ``D = rot90(S.T, 2)``
  4     ``D = S[::-1]``             8     ``D = rot90(S, 1)``
  5     ``D = S.T``                 1     ``D = S``
  ====  ==========================  ====  ==========================

  (``S.T`` swaps the two pixel axes; colour channels stay last);
* :func:`to_uint8` is the one rule mapping other depths (16-bit, float) onto 0..255
  ``uint8`` by the image's own range (``cv2.NORM_MINMAX``): matching works on 8-bit
  grey levels.  An image with NaN pixels has no range and is refused.

References
----------
.. [1] JEITA CP-3451, "Exchangeable image file format for digital still cameras:
   Exif Version 2.3" (2010), tag 0x0112 Orientation.
"""

from __future__ import annotations

import os
import stat
import struct

import cv2
import numpy as np

__all__ = ["exif_orientation", "orient", "decode_image", "read_image_file", "imread", "to_uint8"]

#: TIFF tag number of the EXIF orientation.
_ORIENTATION_TAG = 0x0112


def _tiff_orientation(tiff: bytes) -> int:
    """The orientation tag of the first IFD of a TIFF structure (1 when absent or damaged)."""
    if len(tiff) < 8 or tiff[:2] not in (b"II", b"MM"):
        return 1
    order = "<" if tiff[:2] == b"II" else ">"
    if struct.unpack(order + "H", tiff[2:4])[0] != 42:
        return 1
    ifd = struct.unpack(order + "I", tiff[4:8])[0]
    if ifd + 2 > len(tiff):
        return 1
    count = struct.unpack(order + "H", tiff[ifd:ifd + 2])[0]
    for k in range(min(count, (len(tiff) - ifd - 2) // 12)):
        entry = tiff[ifd + 2 + 12 * k: ifd + 14 + 12 * k]
        tag, kind = struct.unpack(order + "HH", entry[:4])
        if tag == _ORIENTATION_TAG and kind == 3:  # SHORT, held in the value field
            value = struct.unpack(order + "H", entry[8:10])[0]
            return value if 1 <= value <= 8 else 1
    return 1


def _jpeg_exif(data: bytes) -> bytes:
    """The TIFF structure of a JPEG's APP1 ``Exif`` segment (b"" if none)."""
    pos = 2
    while pos + 4 <= len(data) and data[pos] == 0xFF:
        marker = data[pos + 1]
        if marker == 0xFF:  # fill byte
            pos += 1
            continue
        if marker in (0xD9, 0xDA):  # end of image, start of scan: no more headers
            break
        length = struct.unpack(">H", data[pos + 2:pos + 4])[0]
        if marker == 0xE1 and data[pos + 4:pos + 10] == b"Exif\x00\x00":
            return data[pos + 10:pos + 2 + length]
        pos += 2 + length
    return b""


def _png_exif(data: bytes) -> bytes:
    pos = 8
    while pos + 8 <= len(data):
        length, kind = struct.unpack(">I4s", data[pos:pos + 8])
        if kind == b"eXIf":
            return data[pos + 8:pos + 8 + length]
        if kind in (b"IDAT", b"IEND"):  # eXIf must come before the image data
            break
        pos += 12 + length
    return b""


def _webp_exif(data: bytes) -> bytes:
    pos = 12
    while pos + 8 <= len(data):
        kind, length = struct.unpack("<4sI", data[pos:pos + 8])
        if kind == b"EXIF":
            chunk = data[pos + 8:pos + 8 + length]
            return chunk[6:] if chunk.startswith(b"Exif\x00\x00") else chunk
        pos += 8 + length + (length & 1)
    return b""


def exif_orientation(data: bytes) -> int:
    """The EXIF orientation (1-8) of an encoded image; 1 when it carries none.

    Parameters
    ----------
    data : bytes
        The whole file (JPEG, PNG, WebP or TIFF; other formats carry no tag: 1).
    """
    if data[:2] == b"\xff\xd8":
        return _tiff_orientation(_jpeg_exif(data))
    if data[:8] == b"\x89PNG\r\n\x1a\n":
        return _tiff_orientation(_png_exif(data))
    if data[:4] == b"RIFF" and data[8:12] == b"WEBP":
        return _tiff_orientation(_webp_exif(data))
    if data[:4] in (b"II*\x00", b"MM\x00*"):
        return _tiff_orientation(data)
    return 1


def orient(image: np.ndarray, orientation: int) -> np.ndarray:
    """The displayed image of a stored ``(H, W[, C])`` array with EXIF ``orientation``
    (module table); a contiguous array."""
    swap = (1, 0) + tuple(range(2, image.ndim))
    shown = {1: image, 2: image[:, ::-1], 3: np.rot90(image, 2), 4: image[::-1],
             5: image.transpose(swap), 6: np.rot90(image, -1),
             7: np.rot90(image.transpose(swap), 2), 8: np.rot90(image, 1)}[int(orientation)]
    return np.ascontiguousarray(shown)


def decode_image(data: bytes, flags: int = cv2.IMREAD_UNCHANGED) -> np.ndarray | None:
    """Decode an encoded image from memory, upright (its EXIF orientation applied).

    Parameters
    ----------
    data : bytes
    flags : int
        ``cv2.IMREAD_*``; OpenCV's own orientation handling is turned off and the
        orientation applied here, for every flag alike.

    Returns
    -------
    ndarray or None
        ``(H, W)`` or ``(H, W, C)`` as OpenCV decodes it (BGR), None if it cannot.
    """
    if flags != cv2.IMREAD_UNCHANGED:
        flags |= cv2.IMREAD_IGNORE_ORIENTATION
    buffer = np.frombuffer(data, dtype=np.uint8)
    if buffer.size == 0:
        return None
    image = cv2.imdecode(buffer, flags)
    if image is None:
        return None
    return orient(image, exif_orientation(data))


def read_image_file(path: str | os.PathLike,
                    flags: int = cv2.IMREAD_UNCHANGED) -> tuple[np.ndarray | None, int]:
    """The upright image of a file and its EXIF orientation (:func:`decode_image`).

    The file is opened by Python, so any name the file system holds works (names that
    are not UTF-8 included).

    Raises
    ------
    OSError
        No such file, or not a regular file (a FIFO or a device would block or never
        end; ``pipeline.guards`` names the kind).
    """
    if not stat.S_ISREG(os.stat(path).st_mode):
        raise OSError(f"{os.fspath(path)}: not a regular file")
    data = np.fromfile(os.fspath(path), dtype=np.uint8).tobytes()
    return decode_image(data, flags), exif_orientation(data)


def imread(path: str | os.PathLike, flags: int = cv2.IMREAD_UNCHANGED) -> np.ndarray | None:
    """``cv2.imread``'s contract (None when unreadable), by :func:`read_image_file`: any
    file name, upright.  For callers that read files they wrote or that were checked."""
    try:
        return read_image_file(path, flags)[0]
    except OSError:
        return None


def to_uint8(image: np.ndarray, name: str = "image") -> np.ndarray:
    """``image`` as ``uint8``: other depths onto 0..255 by their own range (NORM_MINMAX).

    Raises
    ------
    ValueError
        Non-finite (NaN/inf) pixels, naming ``name``: they have no grey level.
    """
    if image.dtype == np.uint8:
        return image
    if image.dtype.kind == "f":
        bad = int(np.count_nonzero(~np.isfinite(image)))
        if bad:
            raise ValueError(f"{name}: {bad} of {image.size} pixel values are NaN/inf "
                             "(no grey level to match)")
    return cv2.normalize(image, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
