"""Point-cloud files: binary PLY with a per-point ``sigma``, XYZ/CSV text, NPZ.

PLY (written here with numpy structured arrays, because open3d cannot write custom
vertex properties)::

    ply
    format binary_little_endian 1.0
    comment photosurf point cloud
    element vertex N
    property double x / y / z          scene units
    property uchar red / green / blue  (when colours are given)
    property float sigma               scene units (when sigma is given)
    end_header

Readers: our PLY and any other binary/ASCII vertex-only or mesh PLY (through
open3d, which drops unknown properties), text ``.xyz`` / ``.txt`` / ``.csv`` with
columns ``x y z [extra ...]`` (whitespace or comma separated, ``#`` comments, an
optional header line), and ``.npz`` with ``points`` (and optionally ``colours``,
``sigma``).  Writes are atomic (:func:`pipeline.atomic.atomic_file`).
"""

from __future__ import annotations

import os
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipeline import limits
from pipeline.atomic import atomic_file
from pipeline.errors import InputError, escape
from pipeline.guards import check_coordinates, count_occurrences, native_stderr, regular_file
from pipeline.mesh_io import PLY_KINDS, check_header_counts, ply_count, ply_header
from pipeline.workspace import write_npz_to

SUFFIXES = (".ply", ".xyz", ".txt", ".csv", ".npz")


@dataclass(frozen=True)
class Cloud:
    """A point cloud read from a file.

    Attributes
    ----------
    points : (N, 3) float64, scene units
    colours : (N, 3) uint8 or None
    sigma : (N,) float64 or None, scene units
    extra : (N, K) float64 or None
        Further columns of a text file.
    """

    points: np.ndarray
    colours: np.ndarray | None = None
    sigma: np.ndarray | None = None
    extra: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.points)

    @property
    def colors(self) -> np.ndarray | None:
        """Alias of ``colours`` (open3d's spelling)."""
        return self.colours


def _check(points, colours, sigma):
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points must have shape (N, 3), got {points.shape}")
    n = len(points)
    if colours is not None:
        colours = np.asarray(colours)
        if colours.shape != (n, 3):
            raise ValueError(f"colours must have shape ({n}, 3), got {colours.shape}")
        colours = np.clip(colours, 0, 255).astype(np.uint8)
    if sigma is not None:
        sigma = np.asarray(sigma, dtype=np.float64)
        if sigma.shape != (n,):
            raise ValueError(f"sigma must have shape ({n},), got {sigma.shape}")
    return points, colours, sigma


def write_ply(path: str | os.PathLike, points, colours=None, sigma=None) -> Path:
    """Write a binary little-endian PLY with x y z, optionally red green blue and sigma.

    Parameters
    ----------
    path : path-like
    points : (N, 3) float64, scene units
    colours : (N, 3) uint8, optional
    sigma : (N,) float, optional, scene units (stored as float32)
    """
    points, colours, sigma = _check(points, colours, sigma)
    fields = [("x", "<f8"), ("y", "<f8"), ("z", "<f8")]
    header = ["ply", "format binary_little_endian 1.0", "comment photosurf point cloud",
              f"element vertex {len(points)}", "property double x", "property double y",
              "property double z"]
    if colours is not None:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
        header += ["property uchar red", "property uchar green", "property uchar blue"]
    if sigma is not None:
        fields += [("sigma", "<f4")]
        header += ["property float sigma"]
    header += ["end_header"]
    data = np.empty(len(points), dtype=np.dtype(fields))
    data["x"], data["y"], data["z"] = points.T
    if colours is not None:
        data["red"], data["green"], data["blue"] = colours.T
    if sigma is not None:
        data["sigma"] = sigma
    path = Path(path)
    with atomic_file(path) as tmp, open(tmp, "wb") as fh:
        fh.write(("\n".join(header) + "\n").encode("ascii"))
        fh.write(data.tobytes())
    return path


def _parse_header(path: Path):
    """(format, vertex count, [(name, dtype)], header bytes, only-vertex flag) or None.

    The header is read by :func:`pipeline.mesh_io.ply_header` (one PLY header parser for
    meshes and clouds); None: vertex properties this fast path does not read (lists,
    unknown types), open3d reads the file instead.
    """
    with open(path, "rb") as fh:
        head = fh.read(65536)
    parsed = ply_header(head)
    if parsed is None:
        raise InputError(f"{path}: not a PLY file (no 'ply' magic / end_header)")
    fmt, elements, stop = parsed
    count, props = 0, []
    for name, count_words, properties in elements:
        if name != "vertex":
            continue
        count = ply_count(path, name, count_words)
        limits.check("file.elements", count, where=f"{path}: vertex count {count}")
        for words in properties:
            if len(words) < 2 or words[0] not in PLY_KINDS:
                return None  # a list property, or a type this path does not read
            props.append((words[-1], "<" + PLY_KINDS[words[0]]))
        break
    return fmt, count, props, stop, [e[0] for e in elements] == ["vertex"]


def read_ply(path: str | os.PathLike) -> Cloud:
    """Read a PLY point cloud (ours with ``sigma``, or any other through open3d)."""
    path = Path(path)
    parsed = _parse_header(path)
    if parsed is not None:
        fmt, count, props, offset, vertex_only = parsed
        names = [p[0] for p in props]
        if fmt == "binary_little_endian" and vertex_only and {"x", "y", "z"} <= set(names):
            dtype = np.dtype(props)
            raw = path.read_bytes()[offset:]
            if len(raw) < dtype.itemsize * count:
                raise InputError(f"{path}: truncated PLY ({len(raw)} bytes of vertex data, "
                                 f"expected {dtype.itemsize * count})")
            data = np.frombuffer(raw, dtype=dtype, count=count)
            points = np.column_stack([data["x"], data["y"], data["z"]]).astype(np.float64)
            colours = (np.column_stack([data["red"], data["green"], data["blue"]])
                       .astype(np.uint8) if {"red", "green", "blue"} <= set(names) else None)
            sigma = data["sigma"].astype(np.float64) if "sigma" in names else None
            return Cloud(_finite(points, path), colours, _precision(sigma, path))
    import open3d as o3d

    check_header_counts(path)  # a header claiming 10^9 points is refused before reading
    with native_stderr():  # RPly's own lines
        pcd = o3d.io.read_point_cloud(str(path))
    points = np.asarray(pcd.points, dtype=np.float64)
    if len(points) == 0:
        raise InputError(f"{path}: no points in this PLY file")
    colours = (np.clip(np.rint(np.asarray(pcd.colors) * 255), 0, 255).astype(np.uint8)
               if pcd.has_colors() else None)
    return Cloud(_finite(points, path), colours)


def _precision(sigma: np.ndarray | None, path: Path) -> np.ndarray | None:
    """``sigma`` (the points' standard deviation, scene units) if it can be one: no value
    below zero, and at least one finite and above zero (all zero would be infinite
    weights, :func:`surface.reconstruct._precision_weights`); else ``InputError``."""
    if sigma is None or len(sigma) == 0:
        return sigma
    negative = int(np.count_nonzero(sigma < 0))
    if negative:
        raise InputError(f"{path}: 'sigma' is the points' standard deviation, never negative; "
                         f"{negative} of {len(sigma)} values are (smallest {np.nanmin(sigma):.3g})")
    if not np.any(np.isfinite(sigma) & (sigma > 0)):
        raise InputError(f"{path}: 'sigma' is the points' standard deviation; none of its "
                         f"{len(sigma)} values is finite and above zero")
    return sigma


def _finite(points: np.ndarray, path: Path) -> np.ndarray:
    if not np.isfinite(points).all():
        bad = int(np.count_nonzero(~np.isfinite(points).all(axis=1)))
        raise InputError(f"{path}: {bad} points with non-finite coordinates")
    return check_coordinates(points, str(path))


#: Numbers a text line may hold without a header naming its columns: x y z, or x y z
#: and three more (colours or a normal).  A header (``x,y,z,intensity``, or the comment
#: ``# x y z sigma`` :func:`write_cloud` writes) allows the count of its names.
TEXT_WIDTHS = (3, 6)


def _header_names(text: str) -> list[str] | None:
    """Column names of a header line (``x y z ...`` / ``x,y,z,...``), else ``None``."""
    names = [w for w in text.replace(",", " ").split() if w]
    return names if len(names) >= 3 and [n.lower() for n in names[:3]] == ["x", "y", "z"] \
        else None


def _text_values(text: str) -> list[str]:
    """The fields of a data line: comma-separated (spaces around them allowed) or
    whitespace-separated; a line mixing both inside a field is ``[]`` (a decimal comma:
    ``-0,651928 -0,758701`` is not four numbers)."""
    if "," not in text:
        return text.split()
    fields = [f.strip() for f in text.split(",")]
    if any(not f or len(f.split()) != 1 for f in fields):
        return []
    return fields


def read_text(path: str | os.PathLike) -> Cloud:
    """Read ``x y z [extra ...]`` rows (whitespace or commas; ``#`` comments; header ok).

    Every data line holds the same count of numbers: 3 or 6 (:data:`TEXT_WIDTHS`), or
    as many as a header line names; any other line is refused, naming it (a decimal
    comma, a missing or extra value).
    """
    path = Path(path)
    # its lines bound its rows: costed before a row is parsed (bounded memory, early stop)
    lines = count_occurrences(path, {"line": (b"\n",)}, limits.LIMITS["file.elements"].maximum,
                              start=b"")["line"]
    limits.check("file.elements", lines, where=f"{path}: line count {lines}")
    rows: list[list[float]] = []
    widths = set(TEXT_WIDTHS)
    with open(path, encoding="utf-8", errors="replace") as fh:
        for number, line in enumerate(fh, 1):
            body, _, comment = line.partition("#")
            text = body.strip()
            if not text:
                names = _header_names(comment) if not rows else None
                widths |= {len(names)} if names else set()
                continue
            fields = _text_values(text)
            try:
                values = [float(v) for v in fields] if fields else None
            except ValueError:
                values = None
            if values is None and not rows and number <= 2 and fields:  # a header line
                names = _header_names(text)
                widths |= {len(names)} if names else set()
                continue
            width = len(rows[0]) if rows else None
            if values is None or len(values) not in widths or (width and len(values) != width):
                shown = escape(line.strip()[:60])
                what = ("not numbers" if values is None else
                        f"{len(values)} numbers, the lines before hold {width}" if width else
                        f"{len(values)} numbers")
                expected = " or ".join(str(w) for w in sorted(widths))
                hint = " (a decimal comma?)" if "," in text and " " in text.strip() else ""
                raise InputError(f"{path}:{number}: {what}{hint}: {shown!r}; each line holds "
                                 f"x y z as {expected} numbers, separated by spaces or commas")
            rows.append(values)
    if not rows:
        raise InputError(f"{path}: no points")
    data = np.array(rows, dtype=np.float64)
    width = data.shape[1]
    if not np.isfinite(data[:, :3]).all():
        raise InputError(f"{path}: non-finite coordinates")
    return Cloud(_finite(data[:, :3], path), extra=data[:, 3:] if width > 3 else None)


def _check_npz_shapes(path: Path) -> None:
    """The shapes in the ``.npy`` headers of ``points`` (and ``colours``, ``sigma``) before
    any array is read: an archive of a few kB can claim 10^12 rows (zeros compress well)."""
    try:
        with open(path, "rb") as fh, zipfile.ZipFile(fh) as archive:
            shapes = {}
            for name in ("points", "colours", "sigma"):
                if f"{name}.npy" not in archive.namelist():
                    continue
                with archive.open(f"{name}.npy") as member:
                    version = np.lib.format.read_magic(member)
                    read_header = (np.lib.format.read_array_header_1_0 if version == (1, 0)
                                   else np.lib.format.read_array_header_2_0)
                    shapes[name] = read_header(member)[0]
    except (zipfile.BadZipFile, EOFError, ValueError, OSError, TypeError):
        return  # np.load says what is wrong with the file
    points = shapes.get("points")
    if points is None:
        return
    rows = points[0] if points else 1
    limits.check("file.elements", rows, where=f"{path}: points row count {rows}")
    for name, shape in shapes.items():
        if int(np.prod(shape, dtype=np.float64)) > 3 * max(rows, 1):
            raise InputError(f"{path}: '{name}' has shape {shape}, expected ({rows}, 3) or "
                             f"({rows},) like the points")


def read_npz(path: str | os.PathLike) -> Cloud:
    """Read ``points`` (and ``colours``, ``sigma`` if present) from an ``.npz``."""
    path = Path(path)
    _check_npz_shapes(path)
    try:
        with open(path, "rb") as fh, np.load(fh, allow_pickle=False) as data:
            if "points" not in data:
                raise InputError(f"{path}: no 'points' array (has {sorted(data.files)})")
            arrays = {k: data[k] for k in ("points", "colours", "sigma") if k in data}
        for name, array in arrays.items():  # a cast would drop parts silently
            if array.dtype.kind not in "biuf":
                raise InputError(f"{path}: '{name}' holds {array.dtype} values, expected "
                                 "real numbers")
        points = np.asarray(arrays["points"], dtype=np.float64)
        colours, sigma = arrays.get("colours"), arrays.get("sigma")
    except InputError:
        raise
    except (zipfile.BadZipFile, EOFError, ValueError, OSError, TypeError) as exc:
        raise InputError(f"{path}: not a readable .npz point cloud ({exc})") from None
    try:
        points, colours, sigma = _check(points, colours, sigma)
    except ValueError as exc:
        raise InputError(f"{path}: {exc}") from None
    return Cloud(_finite(points, path), colours, _precision(sigma, path))


def read_cloud(path: str | os.PathLike) -> Cloud:
    """Read a point cloud by suffix: .ply, .xyz/.txt/.csv, .npz."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file")
    if path.is_dir():
        raise IsADirectoryError(f"{path}: is a folder, expected a point-cloud file")
    regular_file(path, "point-cloud file")  # no FIFO, device or socket
    suffix = path.suffix.lower()
    if suffix == ".ply":
        return read_ply(path)
    if suffix in (".xyz", ".txt", ".csv"):
        return read_text(path)
    if suffix == ".npz":
        return read_npz(path)
    raise InputError(f"{path}: unknown point-cloud format {suffix!r} (expected one of "
                     f"{', '.join(SUFFIXES)})")


def write_cloud(path: str | os.PathLike, points, colours=None, sigma=None) -> Path:
    """Write a point cloud by suffix: .ply (binary), .xyz/.csv/.txt (text), .npz."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".ply":
        return write_ply(path, points, colours, sigma)
    points, colours, sigma = _check(points, colours, sigma)
    if suffix == ".npz":
        arrays = {"points": points}
        if colours is not None:
            arrays["colours"] = colours
        if sigma is not None:
            arrays["sigma"] = sigma
        with atomic_file(path) as tmp:
            write_npz_to(tmp, **arrays)  # byte-reproducible (np.savez stamps the time)
        return path
    if suffix in (".xyz", ".txt", ".csv"):
        cols = [points] + ([colours.astype(np.float64)] if colours is not None else []) + \
            ([sigma[:, None]] if sigma is not None else [])
        names = "x y z" + (" red green blue" if colours is not None else "") + \
            (" sigma" if sigma is not None else "")
        sep = "," if suffix == ".csv" else " "
        with atomic_file(path) as tmp:
            np.savetxt(tmp, np.hstack(cols), fmt="%.10g", delimiter=sep,
                       header=names.replace(" ", sep))
        return path
    raise InputError(f"{path}: unknown point-cloud format {suffix!r} (expected one of "
                     f"{', '.join(SUFFIXES)})")
