"""Checks at the door: files that are what they say, outputs that cannot destroy inputs.

Every reader of user files calls these before it opens anything, wherever the
reader lives (``pipeline.cloud_io``, ``pipeline.mesh_io``, the image readers,
the TOML readers), so that

* only regular files are read (:func:`regular_file`): a FIFO, ``/dev/zero`` or
  another device would block or read forever;
* an image is checked by content, not by name (:func:`image_format`): the
  signature must be one of the formats photosurf reads and agree with the
  suffix, and its width and height are read from the header
  (:func:`image_header_size`) and checked against :mod:`pipeline.limits`
  *before* the decoder allocates them;
* TOML is read with its nesting bounded (:func:`load_toml`: ``tomllib`` recurses
  once per level, so a file nested thousands deep is a ``RecursionError``);
* coordinates are finite and small enough for float64 geometry
  (:func:`check_coordinates`, :data:`MAX_COORDINATE`);
* an output never is, holds or lies inside an input of the same command
  (:func:`check_output`);
* third-party libraries writing to file descriptor 2 are captured
  (:func:`native_stderr`), so the CLI's error stays one line;
* names printed in messages are escaped (:func:`escape`): a newline, a control
  character or a terminal escape sequence in a file name is shown as ``\\n``,
  ``\\x1b``, never sent raw to the terminal.
"""

from __future__ import annotations

import contextlib
import errno
import os
import stat
import struct
import tomllib
from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np

from matching.fd_capture import Captured, captured_fd2
from pipeline import limits
from pipeline.errors import InputError, escape  # noqa: F401  (escape: re-exported)

#: Largest |coordinate| accepted, in scene units.  Geometry forms products of up
#: to six coordinates (the squared norm of a cross product is a 4th power, a squared
#: volume or a 3x3 determinant of such products a 6th); with |x| <= 1e50 the 6th
#: power is 1e300, below float64's largest 1.8e308, so none of them overflows.
#: Measured on a 600-point cylinder: scaled by 1e49 ``photosurf sections`` gives the
#: very mesh of scale 1 (776 triangles); by 1e99 ``numpy.linalg.norm`` overflows
#: and the mesh changes (732); by 1e300 Shewchuk's Triangle (called by
#: ``surface.section_trees._triangle_edges`` for each section's MST graph) crashed the
#: process with a segmentation fault (exit -11, nothing on stderr).
MAX_COORDINATE = 1e50

#: Smallest extent accepted relative to the largest |coordinate|: below this the
#: coordinates carry fewer than ~6 significant digits of shape (float64 has 15.9).
MIN_RELATIVE_EXTENT = 1e-10

#: Smallest extent the surface code is scale-invariant at (scene units): a 600-point
#: cylinder scaled by 2^-17 (7.6e-6) gives the very mesh of scale 1, by 2^-20 (9.5e-7) a
#: different one (absolute tolerances such as ``TOL.zero = 1e-12`` on areas take over).
#: ``photosurf sections`` rescales a smaller cloud by an exact power of two
#: (:func:`unit_scale`); the pipeline's sections stage refuses it, naming this.
MIN_EXTENT = 1e-4

#: Smallest extent float64 resolves to ~10 digits: below the normal range (2.2e-308)
#: numbers are subnormal, spaced 4.9e-324 apart (4.9e-324 / 1e-10 = 4.9e-314).
MIN_NORMAL_EXTENT = float(np.finfo(np.float64).smallest_subnormal) / MIN_RELATIVE_EXTENT


# --------------------------------------------------------------------------- files

_KIND_NAMES = ((stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISCHR, "a character device"),
               (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))


def regular_file(path: str | os.PathLike, what: str = "file") -> Path:
    """``path`` as a ``Path`` if it is a regular file (symlinks followed), else an error.

    Raises
    ------
    FileNotFoundError
        Nothing at ``path``.
    IsADirectoryError
        A folder.
    InputError
        A FIFO, a device or a socket: reading it could block or never end.
    """
    path = Path(path)
    try:
        info = os.stat(path)
    except FileNotFoundError:
        raise FileNotFoundError(f"{path}: no such {what if what.endswith('file') else 'file'}"
                                ) from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read this {what} ({exc.strerror or exc})") from None
    if stat.S_ISDIR(info.st_mode):
        raise IsADirectoryError(f"{path}: is a folder, expected a {what}")
    if not stat.S_ISREG(info.st_mode):
        kind = next((name for test, name in _KIND_NAMES if test(info.st_mode)), "not a file")
        raise InputError(f"{path}: is {kind}, not a regular {what}; photosurf reads only "
                         "regular files")
    return path


def read_bytes(path: str | os.PathLike, what: str = "file", limit: int | None = None) -> bytes:
    """The bytes of a regular file, refusing one larger than ``limit`` bytes."""
    path = regular_file(path, what)
    if limit is not None:
        size = path.stat().st_size
        if size > limit:
            raise InputError(f"{path}: {size} bytes is too large for a {what} "
                             f"(at most {limit} bytes)")
    return path.read_bytes()


#: A text file of elements (mesh or cloud lines) has one at least every this many bytes
#: (a long comment aside); past its first 64 MB a file with fewer is not what it says.
SCAN_SPARSE_BYTES = 4096


def count_occurrences(path: str | os.PathLike, patterns: dict[str, tuple[bytes, ...]],
                      limit: float, start: bytes = b"\n") -> dict[str, int]:
    """How often each element's ``patterns`` occur in a file, read in 16 MB chunks.

    Memory stays bounded whatever the file; the scan stops once a count passes ``limit``
    (a hostile file is not read to its end), and a file with fewer than one element per
    :data:`SCAN_SPARSE_BYTES` past its first 64 MB is refused (zeros, another format: it
    would be scanned, then parsed, for nothing).

    Parameters
    ----------
    patterns : dict
        Element name -> byte strings counted for it (``b"\\nv "`` counts OBJ vertex lines).
    start : bytes
        Virtual text before the file (a newline: a line at the very start counts too).
    """
    counts = dict.fromkeys(patterns, 0)
    overlap = max(len(p) for ps in patterns.values() for p in ps) - 1
    tail, scanned = start, 0
    with open(regular_file(path), "rb") as fh:
        while chunk := fh.read(16 << 20):
            data = tail + chunk
            scanned += len(chunk)
            for name, ps in patterns.items():
                counts[name] += sum(data.count(p) for p in ps)
            if max(counts.values()) > limit:
                break
            if scanned >= 64 << 20 and sum(counts.values()) * SCAN_SPARSE_BYTES < scanned:
                raise InputError(f"{path}: {sum(counts.values())} element lines in its first "
                                 f"{scanned >> 20} MB: not a text {path.suffix or 'data'} file "
                                 "of points or faces")
            tail = data[len(data) - overlap:] if overlap else b""
    return counts


#: A TOML file (config, recipe, batch manifest) larger than this is refused unread.
MAX_TOML_BYTES = 16 << 20


def load_toml(path: str | os.PathLike, what: str = "TOML file") -> dict:
    """Parse a TOML file; every failure is an ``InputError`` naming the file.

    Covers a file that is not text, invalid TOML, and nesting deep enough to
    exhaust ``tomllib``'s recursion (``RecursionError``).
    """
    path = Path(path)
    data = read_bytes(path, what, MAX_TOML_BYTES)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InputError(f"{path}: not a text TOML file ({exc.reason})") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{path}: invalid TOML: {exc}") from None
    except RecursionError:
        raise InputError(f"{path}: invalid TOML: nested too deeply") from None


# --------------------------------------------------------------------------- images

#: Image formats photosurf reads (OpenCV decodes them): name -> (signatures, suffixes).
IMAGE_FORMATS = {
    "PNG": ((b"\x89PNG\r\n\x1a\n",), (".png",)),
    "JPEG": ((b"\xff\xd8\xff",), (".jpg", ".jpeg", ".jpe")),
    "TIFF": ((b"II*\x00", b"MM\x00*"), (".tif", ".tiff")),
    "BMP": ((b"BM",), (".bmp", ".dib")),
    "PNM": ((b"P1", b"P2", b"P3", b"P4", b"P5", b"P6"), (".pbm", ".pgm", ".ppm", ".pnm")),
    "WebP": ((b"RIFF",), (".webp",)),
}
#: Formats recognised only to name them in the refusal.
_OTHER_FORMATS = ((b"GIF87a", "GIF"), (b"GIF89a", "GIF"), (b"%PDF", "PDF"), (b"PK\x03\x04", "ZIP"),
                  (b"\x1f\x8b", "gzip"), (b"ply", "PLY"), (b"<?xml", "XML"))


def image_format(path: str | os.PathLike, head: bytes | None = None) -> str:
    """The format of an image file by its signature; ``InputError`` when photosurf cannot
    read it or when its suffix names another image format (a GIF named ``.png``)."""
    path = Path(path)
    if head is None:
        with open(regular_file(path, "image"), "rb") as fh:
            head = fh.read(32)
    found = next((name for name, (magics, _) in IMAGE_FORMATS.items()
                  if any(head.startswith(m) for m in magics)), None)
    if found == "WebP" and head[8:12] != b"WEBP":
        found = None
    if found is None:
        other = next((name for magic, name in _OTHER_FORMATS if head.startswith(magic)), None)
        kind = f"a {other} file" if other else "no known image signature"
        raise InputError(f"{path}: not a readable image ({kind}; photosurf reads "
                         f"{', '.join(IMAGE_FORMATS)})")
    suffix = path.suffix.lower()
    claimed = next((name for name, (_, suffixes) in IMAGE_FORMATS.items()
                    if suffix in suffixes), None)
    if claimed is not None and claimed != found:
        raise InputError(f"{path}: named {suffix} but the content is a {found} image")
    return found


def _jpeg_size(fh) -> tuple[int, int] | None:
    """(width, height) from the first SOF marker of a JPEG stream (ITU T.81 B.2.2)."""
    fh.seek(2)
    for _ in range(10000):  # markers before the frame header; bounded
        byte = fh.read(1)
        while byte == b"\xff":
            byte = fh.read(1)
        if not byte:
            return None
        marker = byte[0]
        if marker in (0xD8, 0x01) or 0xD0 <= marker <= 0xD7:
            continue
        length_bytes = fh.read(2)
        if len(length_bytes) < 2:
            return None
        length = struct.unpack(">H", length_bytes)[0]
        if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):
            frame = fh.read(5)
            if len(frame) < 5:
                return None
            height, width = struct.unpack(">HH", frame[1:5])
            return width, height
        fh.seek(length - 2, os.SEEK_CUR)
    return None


def _tiff_size(fh, head: bytes) -> tuple[int, int] | None:
    """(width, height) from the first IFD of a TIFF (tags 256, 257)."""
    order = "<" if head.startswith(b"II") else ">"
    fh.seek(4)
    offset = struct.unpack(order + "I", fh.read(4))[0]
    fh.seek(offset)
    count_bytes = fh.read(2)
    if len(count_bytes) < 2:
        return None
    size = {}
    for _ in range(min(struct.unpack(order + "H", count_bytes)[0], 4096)):
        entry = fh.read(12)
        if len(entry) < 12:
            break
        tag, kind = struct.unpack(order + "HH", entry[:4])
        if tag in (256, 257):
            value = struct.unpack(order + ("H" if kind == 3 else "I"),
                                  entry[8:10] if kind == 3 else entry[8:12])[0]
            size[tag] = value
    return (size[256], size[257]) if len(size) == 2 else None


def image_header_size(path: str | os.PathLike) -> tuple[str, tuple[int, int] | None]:
    """``(format, (width, height))`` read from the file header, without decoding.

    ``(width, height)`` is ``None`` where the header does not say (a truncated
    file; the decoder will then refuse it).  Formats: PNG (IHDR), JPEG (SOF),
    TIFF (first IFD), BMP (BITMAPINFOHEADER), PNM (the text header), WebP (VP8/VP8L/VP8X).
    """
    path = regular_file(path, "image")
    with open(path, "rb") as fh:
        head = fh.read(64)
        fmt = image_format(path, head)
        size = None
        if fmt == "PNG" and head[12:16] == b"IHDR":
            size = struct.unpack(">II", head[16:24])
        elif fmt == "JPEG":
            size = _jpeg_size(fh)
        elif fmt == "TIFF":
            size = _tiff_size(fh, head)
        elif fmt == "BMP" and len(head) >= 26:
            width, height = struct.unpack("<ii", head[18:26])
            size = (abs(width), abs(height))
        elif fmt == "PNM":
            words = head[2:].split()
            numbers = [w for w in words if w.isdigit()][:2]
            size = tuple(int(n) for n in numbers) if len(numbers) == 2 else None
        elif fmt == "WebP":
            chunk = head[12:16]
            if chunk == b"VP8X" and len(head) >= 30:
                size = (1 + int.from_bytes(head[24:27], "little"),
                        1 + int.from_bytes(head[27:30], "little"))
            elif chunk == b"VP8 " and len(head) >= 30:
                w, h = struct.unpack("<HH", head[26:30])
                size = (w & 0x3FFF, h & 0x3FFF)
            elif chunk == b"VP8L" and len(head) >= 25:
                bits = int.from_bytes(head[21:25], "little")
                size = (1 + (bits & 0x3FFF), 1 + ((bits >> 14) & 0x3FFF))
    return fmt, (tuple(int(v) for v in size) if size else None)


def check_image_file(path: str | os.PathLike) -> tuple[int, int] | None:
    """Regular file, a readable format, and its header size within ``image.pixels``.

    Returns the header's ``(width, height)`` (``None`` if the header does not say).
    """
    _, size = image_header_size(path)
    if size is not None:
        width, height = size
        if width <= 0 or height <= 0:
            raise InputError(f"{path}: the header says {width}x{height} px")
        limits.check("image.pixels", width * height, where=f"{path}: {width}x{height} px")
    return size


def read_image(path: str | os.PathLike, flags: int | None = None) -> np.ndarray:
    """Decode an image after :func:`check_image_file` (:func:`matching.image_file.
    read_image_file`: the bytes read by Python, upright by its EXIF orientation); libpng's
    and libjpeg's own lines are captured.  ``InputError`` when it cannot be decoded."""
    import cv2

    from matching.image_file import read_image_file

    check_image_file(path)
    with native_stderr():
        image, _ = read_image_file(path, cv2.IMREAD_UNCHANGED if flags is None else flags)
    if image is None:
        raise InputError(f"{path}: not a readable image")
    return image


# --------------------------------------------------------------------------- numbers


def check_coordinates(points: np.ndarray, name: str, what: str = "coordinates") -> np.ndarray:
    """Refuse non-finite values or ``|x| > MAX_COORDINATE``; return ``points`` unchanged.

    Parameters
    ----------
    points : (N, 3) float64 (any shape works)
    name : str
        The file or field named in the message.
    """
    points = np.asarray(points)
    if np.iscomplexobj(points):
        raise InputError(f"{name}: {what} are complex numbers ({points.dtype})")
    if points.size == 0:
        return points
    finite = np.isfinite(points)
    if not finite.all():
        rows = int(np.count_nonzero(~finite.reshape(len(points), -1).all(axis=1))) \
            if points.ndim > 1 else int(np.count_nonzero(~finite))
        raise InputError(f"{name}: {rows} {'points have' if points.ndim > 1 else 'values are'} "
                         f"NaN/inf {what}")
    largest = float(np.abs(points).max())
    if largest > MAX_COORDINATE:
        raise InputError(f"{name}: {what} up to {largest:.3g}: beyond {MAX_COORDINATE:.0e}, "
                         "where products of coordinates overflow float64")
    return points


def check_cloud_shape(points: np.ndarray, name: str, axis=None) -> None:
    """Refuse a cloud that spans no volume: all points equal, on a line, in one plane,
    too small against its distance from the origin for float64 to resolve its shape, or
    so small that float64 holds it only as subnormal numbers.

    The test is on the singular values s1 >= s2 >= s3 of the centred points scaled by
    their extent (so it is the same at every scale): a line has s2 ~ 0, so every section
    of it is a point (1000 collinear points used to give a "closed" 2164-triangle mesh);
    a plane has s3 ~ 0, and every plane across it meets it in a line segment, not a
    closed loop -- the slicing planes cut such a cloud in segments whenever the slicing
    axis lies in its plane or crosses it (a plane perpendicular to the axis is one
    section: ``surface.sections`` says so).

    Parameters
    ----------
    points : (N, 3) float64
    name : str
        The file or stage named in the message.
    axis : "x", "y", "z", (3,) array, or None
        The slicing axis, named in the message ("auto"/None: the principal axis).
    """
    points = np.asarray(points, dtype=np.float64)
    if len(points) < 4:
        return
    centre = points.mean(axis=0)
    extent = float(np.ptp(points, axis=0).max())
    scale = max(float(np.abs(centre).max()), extent)
    if extent == 0 or extent < MIN_RELATIVE_EXTENT * scale:
        raise InputError(f"{name}: degenerate cloud: every point at the same place "
                         f"(extent {extent:.3g} at distance {scale:.3g})")
    if extent < MIN_NORMAL_EXTENT:
        raise InputError(f"{name}: coordinates spanning {extent:.3g}: float64 holds numbers "
                         f"below {np.finfo(np.float64).tiny:.3g} only as subnormals, which "
                         f"resolve fewer than 10 digits of a shape this small")
    sample = points[:: max(1, len(points) // 200_000)] - centre
    _, singular, directions = np.linalg.svd(sample / extent, full_matrices=False)
    if singular[1] <= 1e-9 * singular[0]:
        raise InputError(f"{name}: degenerate cloud: all {len(points)} points lie on one line "
                         "(no surface passes through them)")
    if singular[2] <= 1e-9 * singular[0]:
        normal = directions[2]
        named = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}
        if axis is None or (isinstance(axis, str) and axis.strip().lower() not in named):
            vector, label = directions[0], "the principal (slicing) axis"
        else:
            vector = np.asarray(named.get(axis.strip().lower()) if isinstance(axis, str)
                                else axis, dtype=np.float64)
            label = f"the slicing axis {np.round(vector / np.linalg.norm(vector), 6).tolist()}"
        cosine = abs(float(normal @ vector)) / float(np.linalg.norm(vector))
        if cosine >= 1 - 1e-9:
            return  # one plane across the axis: one section, surface.sections refuses it
        angle = np.degrees(np.arcsin(min(1.0, cosine)))
        where = ("which holds " + label if angle < 1e-6 else
                 f"at {angle:.3g} deg to {label}")
        raise InputError(f"{name}: degenerate cloud: all {len(points)} points lie in one plane "
                         f"(normal {np.round(normal, 6).tolist()}) {where}: every section would "
                         "be a line segment, not a closed loop (no closed surface)")
    _check_spread(points, centre, directions, name, axis)


#: Sections are ``Δ = 2 s`` apart and a ring's points as far apart as the sections
#: (:func:`surface.reconstruct.ring_count`); a closed cubic needs more than 3 of them
#: (:func:`surface.reconstruct.min_loop_points`: 4), so a loop at least ``3 Δ`` long.  A
#: convex loop of width ``W`` is at most ``π W`` long: a cloud narrower than
#: ``3 Δ / π = 6 s / π`` across its line holds no loop.
LINE_WIDTH_SPACINGS = 6.0 / np.pi


def _check_spread(points: np.ndarray, centre: np.ndarray, directions: np.ndarray, name: str,
                  axis) -> None:
    """Refuse a cloud on a line within its noise, or in planes across the slicing axis with
    no wall between them -- both judged against the point spacing ``s``
    (:func:`surface.sections.point_spacing`), so a noisy line is a line.

    * width across the principal direction below ``LINE_WIDTH_SPACINGS · s``;
    * heights along the slicing axis in two or more levels, each thinner than the
      section spacing ``Δ = 2 s`` and more than ``Δ`` apart: no point between two levels,
      so no wall joins them, and every section is a level's filled area or empty.
    """
    from surface.sections import point_spacing, resolve_axis

    s = point_spacing(points)
    if not s > 0:
        return
    width = float(np.ptp((points - centre) @ directions[1]))
    if width < LINE_WIDTH_SPACINGS * s:
        raise InputError(f"{name}: degenerate cloud: all {len(points)} points lie on one line "
                         f"within {width:.3g} ({width / s:.2g} point spacings; a closed loop "
                         f"needs {LINE_WIDTH_SPACINGS:.2g}): no surface passes round them")
    try:
        direction = resolve_axis("z" if axis is None else axis, points)
    except ValueError:
        return
    heights = np.sort(points @ direction)
    cuts = np.flatnonzero(np.diff(heights) > 2 * s) + 1
    if cuts.size == 0:
        return
    edges = np.concatenate([[0], cuts, [len(heights)]])
    thickness = heights[edges[1:] - 1] - heights[edges[:-1]]
    if np.all(thickness < 2 * s):
        levels = ", ".join(f"{h:.3g}" for h in heights[edges[:-1]][:5])
        raise InputError(f"{name}: degenerate cloud: all {len(points)} points lie in "
                         f"{len(thickness)} planes across the slicing axis (heights {levels}"
                         f"{' ...' if len(thickness) > 5 else ''}), none thicker than a section "
                         "spacing, with nothing between them: no wall joins them (no closed "
                         "surface)")


def drop_far_outliers(points: np.ndarray, name: str, *per_point) -> tuple:
    """The cloud without its far outliers (:func:`surface.outliers.far_outliers`), and each
    of ``per_point`` (``(N, ...)`` arrays or ``None``: sigma, colours) likewise.

    Returns ``(points, *per_point, report)``; ``report`` is one line naming ``name`` or
    ``None`` when no point was dropped (the caller logs it once the cloud is accepted: a
    refusal that follows stays the one line).
    """
    from surface.outliers import far_outliers

    found = far_outliers(points)
    if not found.count:
        return (points, *per_point, None)
    keep = ~found.mask
    report = f"{name}: {found.report(len(points))}"
    return (points[keep], *(None if a is None else np.asarray(a)[keep] for a in per_point),
            report)


def check_section_cost(points: np.ndarray, axis, where: str, sections: int | None = None,
                       spacing: float | None = None, n: int | None = None) -> None:
    """Refuse, before anything is sliced, a cloud whose sections or rings would pass
    :mod:`pipeline.limits`, costed from what the data are: the extent along the slicing
    axis in point spacings, not the count of points or the bounding box alone.

    With the default spacing the sections are ``Δ = 2 s`` apart (``s`` the point spacing,
    :func:`surface.sections.point_spacing`), so a cloud spanning ``L`` along the axis has
    ``L / Δ`` sections; a ring's default point count is its loop's perimeter over ``Δ``,
    at most about ``π W / Δ`` for a cloud ``W`` wide across the axis.

    Parameters
    ----------
    points : (N, 3) float64
    axis : "x", "y", "z", "auto" or (3,) array
    where : str
        The file or stage named in the message.
    sections, spacing, n : as the section stage's options (given: costed as given).
    """
    from surface.sections import point_spacing, resolve_axis

    points = np.asarray(points, dtype=np.float64)
    if len(points) < 2:
        return
    direction = resolve_axis(axis, points)
    heights = points @ direction
    extent = float(np.ptp(heights))
    if extent <= 0:
        return
    if sections is None:
        s = point_spacing(points) if not spacing else 0.0
        delta = float(spacing) if spacing else 2.0 * s
        if delta <= 0:
            return
        limits.check("sections.count", extent / delta,
                     where=f"{where}: {extent:.3g} along the slicing axis at sections "
                           f"{delta:.3g} apart ({'given' if spacing else 'two point spacings'})")
    else:
        delta = extent / sections
    if n is None:
        across = points - np.outer(heights, direction)
        width = float(np.linalg.norm(np.ptp(across, axis=0)))
        limits.check("ring.points", np.pi * width / delta,
                     where=f"{where}: loops up to pi x {width:.3g} around at ring points "
                           f"{delta:.3g} apart")


def unit_scale(points: np.ndarray) -> float:
    """An exact power of two ``u`` such that ``points / u`` spans [1, 2), when the cloud is
    smaller than :data:`MIN_EXTENT`; else 1.

    Dividing by a power of two is exact in binary floating point (no digit changes, only
    the exponent), and the surface code is scale-invariant from ~2e-5 up (a 600-point
    cylinder scaled by 2^-17 gives the very mesh of scale 1, by 2^-20 another one: its
    absolute tolerances, ``TOL.zero = 1e-12`` on areas, take over).  So ``photosurf
    sections`` meshes ``points / u`` and multiplies the vertices by ``u``: a cloud
    scaled by 1e-49 gives the mesh of its unit-size copy.
    """
    extent = float(np.ptp(np.asarray(points, dtype=np.float64), axis=0).max())
    if not 0 < extent < MIN_EXTENT:
        return 1.0
    return float(np.ldexp(1.0, int(np.floor(np.log2(extent)))))


# --------------------------------------------------------------------------- outputs


def _resolved(path: str | os.PathLike) -> Path:
    """The absolute path with every link followed; a link loop is an ``InputError``
    (Python 3.11's ``Path.resolve`` raises ``RuntimeError("Symlink loop ...")``)."""
    try:
        return Path(os.path.abspath(path)).resolve()
    except (RuntimeError, OSError) as exc:
        raise InputError(f"{path}: {symlink_loop_reason(exc)}") from None


def symlink_loop_reason(exc: BaseException) -> str:
    """The reason a path could not be followed: ``"symbolic link loop"`` for pathlib's
    ``RuntimeError`` and for ``ELOOP``, else the system's own words."""
    if isinstance(exc, RuntimeError) or getattr(exc, "errno", None) == errno.ELOOP:
        return "a symbolic link loop (the link leads back to itself)"
    return getattr(exc, "strerror", None) or str(exc)


def missing_reason(path: str | os.PathLike) -> str:
    """Why ``path``, whose ``exists()`` is false, cannot be read: a link in a loop, a link
    to nothing, or no such file."""
    try:
        os.stat(path)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            return symlink_loop_reason(exc)
    if os.path.islink(path):
        return f"a link to {os.readlink(path)}, which does not exist"
    return "no such file"


def _inside(child: Path, parent: Path) -> bool:
    return child == parent or parent in child.parents


def check_output(out: str | os.PathLike, inputs: Iterable[str | os.PathLike | None],
                 folder: bool = False, option: str = "--out") -> None:
    """Refuse an output that is, holds or lies inside one of ``inputs``.

    Parameters
    ----------
    out : path
        The output file, or folder when ``folder``.
    inputs : paths
        The command's input files and folders (``None`` entries skipped).
    folder : bool
        ``out`` is a folder: an input anywhere inside it is refused as well.
    """
    target = _resolved(out)
    for item in inputs:
        if item is None:
            continue
        source = _resolved(item)
        same = target == source
        if not same and os.path.exists(out) and os.path.exists(item):
            with contextlib.suppress(OSError):
                same = os.path.samefile(out, item)
        if same:
            raise InputError(f"{option} {out}: is the input {item}; choose another output")
        if folder and _inside(source, target):
            raise InputError(f"{option} {out}: holds the input {item}; choose another folder")
        if _inside(target, source):
            raise InputError(f"{option} {out}: lies inside the input {item}; choose another "
                             "output")


# --------------------------------------------------------------------------- native stderr


@contextlib.contextmanager
def native_stderr() -> Iterator[Captured]:
    """Capture C-level writes to file descriptor 2 (open3d's RPly, libpng, tinyobj).

    ``VerbosityLevel`` and ``cv2.setLogLevel`` do not reach every native line;
    this redirects the descriptor itself to a temporary file for the block
    (:func:`matching.fd_capture.captured_fd2`: one redirection shared by every
    thread, so concurrent readers -- the view-pair threads reading images --
    cannot leave fd 2 pointing at a closed file).  The captured text is on the
    yielded object's ``text`` after the block (writers check it for failure
    lines); it is printed again only with ``PHOTOSURF_NATIVE_STDERR=1``.
    """
    with captured_fd2() as captured:
        yield captured
    if captured.text and os.environ.get("PHOTOSURF_NATIVE_STDERR"):
        os.write(2, captured.text.encode())


# --------------------------------------------------------------------------- writes


def write_image(path: str | os.PathLike, image: np.ndarray) -> Path:
    """Encode ``image`` in memory by ``path``'s suffix (OpenCV) and write the bytes ourselves.

    ``cv2.imwrite`` hands the file to libpng, whose write errors (a full disk)
    are printed on fd 2 and may still return ``True``; here a failed write is
    the ``OSError`` of Python's own ``write``.  Not atomic: for a temporary
    the caller renames (:func:`pipeline.atomic.atomic_file`, ``atomic_dir``).
    """
    import cv2

    path = Path(path)
    with native_stderr():
        ok, buffer = cv2.imencode(path.suffix or ".png", image)
    if not ok:
        raise OSError(f"{path}: could not encode the image as {path.suffix or '.png'}")
    with open(path, "wb") as fh:
        fh.write(buffer.tobytes())
    return path


# --------------------------------------------------------------------------- rigs

#: Versions of the photosurf ``cameras.yml`` format this code reads.
RIG_VERSIONS = (1,)


def _fs_node(fs, key: str):
    node = fs.getNode(key)
    return None if node.empty() or node.isNone() else node


def check_rig(rig, path: str | os.PathLike) -> None:
    """Refuse a stereo rig photosurf cannot triangulate with, or whose file contradicts itself.

    * a photosurf ``cameras.yml`` must say ``format: photosurf-cameras`` and a
      known ``version`` (:data:`RIG_VERSIONS`); its redundant ``rig_R``/``rig_T``
      must be finite and agree with the two views' poses (``R_r R_l^T``,
      ``t_r - R t_l``) to 1e-6 of their size -- a file edited in one place only
      is inconsistent;
    * every camera value within :data:`MAX_COORDINATE`;
    * a baseline that is not (near) zero: at most 1e-9 of the centres' distance
      from the origin (float64 keeps ~16 digits, so such a baseline is the
      rounding of equal centres) is refused, as is an exact zero.
    """
    import cv2

    path = Path(path)
    for label, cam in (("left", rig.left), ("right", rig.right)):
        for name in ("K", "dist", "R", "t"):
            check_coordinates(getattr(cam, name), f"{path}: {label} camera", f"{name} values")
    fs = None
    with native_stderr():
        try:  # parsed from memory: OpenCV crashes on a file name that is not UTF-8
            fs = cv2.FileStorage(path.read_bytes().decode("utf-8", "replace"),
                                 cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
        except (cv2.error, SystemError, OSError):
            fs = None
    if fs is not None and fs.isOpened():
        try:
            _check_rig_fields(fs, rig, path)
        finally:
            fs.release()
    scale = max(float(np.linalg.norm(rig.left.center)), float(np.linalg.norm(rig.right.center)))
    if rig.baseline == 0 or rig.baseline <= 1e-9 * scale:
        raise InputError(f"{path}: the two cameras are at the same place (baseline "
                         f"{rig.baseline:.3g}); a stereo rig needs a baseline")


def _check_rig_fields(fs, rig, path: Path) -> None:
    import cv2

    if _fs_node(fs, "n_views") is None:
        return  # OpenCV's intrinsics/extrinsics files: no format tag of ours
    fmt = _fs_node(fs, "format")
    if fmt is not None and (not fmt.isString() or fmt.string() != "photosurf-cameras"):
        shown = fmt.string() if fmt.isString() else fmt.real()
        raise InputError(f"{path}: format {shown!r} is not photosurf-cameras")
    version = _fs_node(fs, "version")
    if version is not None:
        value = version.string() if version.isString() else version.real()
        if value not in RIG_VERSIONS:
            raise InputError(f"{path}: version {value!r} of the cameras format is not one this "
                             f"photosurf reads ({', '.join(map(str, RIG_VERSIONS))})")
    for key, expected in (("rig_R", rig.R), ("rig_T", rig.T)):
        node = _fs_node(fs, key)
        if node is None:
            continue
        try:
            value = np.asarray(node.mat(), dtype=np.float64)
        except (cv2.error, SystemError, TypeError):
            raise InputError(f"{path}: field {key} is not a readable matrix") from None
        if value.size != expected.size or not np.all(np.isfinite(value)):
            raise InputError(f"{path}: field {key} must be {expected.size} finite numbers, got "
                             f"{value.ravel().tolist()}")
        size = max(1.0, float(np.abs(expected).max()))
        if np.abs(value.reshape(expected.shape) - expected).max() > 1e-6 * size:
            raise InputError(f"{path}: inconsistent rig: {key} does not match the two views' "
                             "poses")
