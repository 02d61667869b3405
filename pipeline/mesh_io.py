"""Triangle-mesh reading and writing through open3d, atomically.

Meshes cross every boundary as ``vertices (V, 3) float64`` and
``triangles (F, 3) int64`` (counter-clockwise seen from outside).  Formats by
extension: ``.ply`` (binary, with vertex normals), ``.obj``, ``.stl``,
``.gltf``; ``.glb`` written by open3d 0.20 cannot be read back by open3d
itself, so ``.glb`` is not offered here (see
``pipeline/export.py`` for the verified GLB path when it exists).
"""

from __future__ import annotations

import contextlib
import os
import struct
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from pipeline.atomic import atomic_file
from pipeline.errors import InputError

MESH_SUFFIXES = (".ply", ".obj", ".stl", ".gltf", ".off")


def to_open3d(vertices: np.ndarray, triangles: np.ndarray, normals: np.ndarray | None = None,
              colors: np.ndarray | None = None):
    """Build an ``open3d.geometry.TriangleMesh`` from plain arrays."""
    import open3d as o3d

    mesh = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(np.ascontiguousarray(vertices, dtype=np.float64)),
        o3d.utility.Vector3iVector(np.ascontiguousarray(triangles, dtype=np.int32)),
    )
    if normals is not None:
        mesh.vertex_normals = o3d.utility.Vector3dVector(np.asarray(normals, dtype=np.float64))
    if colors is not None:
        c = np.asarray(colors)
        c = c / 255.0 if c.dtype == np.uint8 else c
        mesh.vertex_colors = o3d.utility.Vector3dVector(c.astype(np.float64))
    return mesh


def read_mesh(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Read a triangle mesh; return ``(vertices (V,3) float64, triangles (F,3) int64)``.

    Before open3d reads anything the file must be a regular file
    (:func:`pipeline.guards.regular_file`), and a PLY, OFF or binary STL header's
    element counts must fit the file's size and :mod:`pipeline.limits`
    (``file.elements``): a header claiming 10^9 vertices is refused at once.
    open3d's own lines on fd 2 (RPly, tinyobj) are captured.

    Raises
    ------
    FileNotFoundError, InputError
        Missing file, unknown format, or a file with no triangles.
    """
    import open3d as o3d

    from pipeline.guards import check_coordinates, native_stderr, regular_file

    path = regular_file(path, "mesh file")
    if path.suffix.lower() not in MESH_SUFFIXES + (".glb",):
        raise InputError(f"{path}: unknown mesh format {path.suffix!r} "
                         f"(expected one of {', '.join(MESH_SUFFIXES)})")
    check_header_counts(path)
    with native_stderr():
        mesh = o3d.io.read_triangle_mesh(str(path))
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    triangles = np.asarray(mesh.triangles, dtype=np.int64)
    if len(triangles) == 0:
        raise InputError(f"{path}: no triangles could be read")
    if not np.all(np.isfinite(vertices)):
        raise InputError(f"{path}: vertices contain NaN/inf")
    check_coordinates(vertices, str(path), "vertex coordinates")
    return vertices, triangles


#: Bytes of one value of each PLY scalar type.
_PLY_SIZES = {"char": 1, "int8": 1, "uchar": 1, "uint8": 1, "short": 2, "int16": 2,
              "ushort": 2, "uint16": 2, "int": 4, "int32": 4, "uint": 4, "uint32": 4,
              "float": 4, "float32": 4, "double": 8, "float64": 8}


def _ply_counts(path: Path, head: bytes) -> tuple[str, list[tuple[str, int, int]], int]:
    """``(format, [(element, count, least bytes per element)], header bytes)`` of a PLY."""
    end = head.find(b"end_header")
    if end < 0:
        return "", [], len(head)  # no header to check: the reader refuses the file
    stop = head.find(b"\n", end)
    stop = len(head) if stop < 0 else stop + 1
    fmt, elements = "ascii", []
    for line in head[:stop].decode("ascii", "replace").splitlines():
        words = line.split()
        if len(words) >= 2 and words[0] == "format":
            fmt = words[1]
        elif words and words[0] == "element":
            try:
                count = int(words[2])
            except (IndexError, ValueError):
                raise InputError(f"{path}: bad PLY line {line!r}") from None
            if count < 0:
                raise InputError(f"{path}: negative {words[1]} count {count}")
            elements.append([words[1], count, 0])
        elif words and words[0] == "property" and elements:
            if fmt == "ascii":
                elements[-1][2] += 2  # a digit and a separator at least
            elif len(words) >= 3 and words[1] == "list":
                elements[-1][2] += _PLY_SIZES.get(words[2], 1)  # the list's length, at least
            else:
                elements[-1][2] += _PLY_SIZES.get(words[1] if len(words) > 1 else "", 1)
    return fmt, [tuple(e) for e in elements], stop


def check_header_counts(path: str | os.PathLike) -> None:
    """Refuse a PLY/OFF/STL header whose element counts the file cannot hold, or past
    the ``file.elements`` limit -- before any reader allocates them.

    Each element needs at least a fixed number of bytes (binary: the sizes of its
    properties; text: a digit and a separator per value), so
    ``count x least bytes <= file size`` must hold.
    """
    from pipeline import limits

    path = Path(path)
    suffix = path.suffix.lower()
    size = path.stat().st_size
    with open(path, "rb") as fh:
        head = fh.read(65536)
    counts: list[tuple[str, int, int]] = []
    body = size
    if suffix == ".ply":
        if not head.startswith(b"ply"):
            return  # not a PLY header: the reader refuses the file
        _, counts, stop = _ply_counts(path, head)
        body = size - stop
    elif suffix == ".off":
        lines = [ln.split(b"#", 1)[0].strip() for ln in head.split(b"\n")[:1000]]
        words = b" ".join(ln for ln in lines if ln).split()
        if not words or not words[0].endswith(b"OFF"):
            raise InputError(f"{path}: not an OFF file (no 'OFF' keyword)")
        try:
            n_vertices, n_faces = int(words[1]), int(words[2])
        except (IndexError, ValueError):
            raise InputError(f"{path}: bad OFF header (expected 'OFF' then the vertex, face "
                             "and edge counts)") from None
        if n_vertices < 0 or n_faces < 0:
            raise InputError(f"{path}: negative OFF counts {n_vertices} {n_faces}")
        counts = [("vertex", n_vertices, 6), ("face", n_faces, 8)]  # "x y z", "3 a b c"
    elif suffix == ".stl" and size >= 84 and not head[:80].lstrip().startswith(b"solid"):
        n_facets = struct.unpack("<I", head[80:84])[0]
        counts = [("facet", n_facets, 50)]
        body = size - 84
    for element, count, _ in counts:
        limits.check("file.elements", count, where=f"{path}: {element} count {count}")
    needed = sum(count * least for _, count, least in counts)
    if needed > body:
        shown = ", ".join(f"{count} {element}s" for element, count, _ in counts)
        raise InputError(f"{path}: the header claims {shown}, which need at least {needed} "
                         f"bytes, but the file holds {body}: truncated or not what it says")


def _area_normals(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals ((0, 0, 1) where none is defined)."""
    corners = vertices[triangles]
    face = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    normals = np.zeros_like(vertices)
    for c in range(3):
        np.add.at(normals, triangles[:, c], face)
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    good = length[:, 0] > 0
    normals[good] /= length[good]
    normals[~good] = (0.0, 0.0, 1.0)
    return normals


def _write_ply_to(tmp: Path, vertices, triangles, normals, colors) -> None:
    """Binary little-endian PLY: double x y z [nx ny nz] [uchar rgb], int vertex_indices."""
    fields = [("x", "<f8"), ("y", "<f8"), ("z", "<f8")]
    header = ["ply", "format binary_little_endian 1.0", "comment photosurf mesh",
              f"element vertex {len(vertices)}", "property double x", "property double y",
              "property double z"]
    if normals is not None:
        fields += [("nx", "<f8"), ("ny", "<f8"), ("nz", "<f8")]
        header += ["property double nx", "property double ny", "property double nz"]
    if colors is not None:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
        header += ["property uchar red", "property uchar green", "property uchar blue"]
    header += [f"element face {len(triangles)}", "property list uchar int vertex_indices",
               "end_header"]
    data = np.empty(len(vertices), dtype=np.dtype(fields))
    data["x"], data["y"], data["z"] = np.asarray(vertices, dtype=np.float64).T
    if normals is not None:
        data["nx"], data["ny"], data["nz"] = np.asarray(normals, dtype=np.float64).T
    if colors is not None:
        c = np.asarray(colors)
        c = c if c.dtype == np.uint8 else np.clip(np.rint(c * 255), 0, 255).astype(np.uint8)
        data["red"], data["green"], data["blue"] = c.T
    faces = np.empty(len(triangles), dtype=np.dtype([("n", "u1"), ("v", "<i4", (3,))]))
    faces["n"] = 3
    faces["v"] = triangles
    with open(tmp, "wb") as fh:  # Python's write: a full disk is an OSError here
        fh.write(("\n".join(header) + "\n").encode("ascii"))
        fh.write(memoryview(data).cast("B"))
        fh.write(memoryview(faces).cast("B"))


def _write_stl_to(tmp: Path, vertices, triangles) -> None:
    """Binary STL: 80-byte header, facet count, (normal, 3 corners, 0) per facet as float32."""
    corners = np.asarray(vertices, dtype=np.float64)[triangles]
    face = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    length = np.linalg.norm(face, axis=1, keepdims=True)
    face = np.divide(face, length, out=np.zeros_like(face), where=length > 0)
    facets = np.zeros(len(triangles), dtype=np.dtype([("n", "<f4", (3,)), ("v", "<f4", (3, 3)),
                                                      ("a", "<u2")]))
    facets["n"], facets["v"] = face, corners
    with open(tmp, "wb") as fh:
        fh.write(b"photosurf STL".ljust(80, b" "))
        fh.write(struct.pack("<I", len(triangles)))
        fh.write(memoryview(facets).cast("B"))


def _write_text_to(tmp: Path, suffix: str, vertices, triangles, normals) -> None:
    """OFF or OBJ text; ``%r`` is the shortest decimal that reads back to the same float64."""
    n_v, n_f = len(vertices), len(triangles)
    coords = tuple(np.asarray(vertices, dtype=np.float64).ravel().tolist())
    with open(tmp, "w", encoding="ascii", newline="\n") as out:
        if suffix == ".off":
            out.write(f"OFF\n{n_v} {n_f} 0\n")
            out.write(("%r %r %r\n" * n_v) % coords)
            out.write(("3 %d %d %d\n" * n_f) % tuple(np.asarray(triangles).ravel().tolist()))
            return
        out.write(f"# photosurf OBJ: {n_v} vertices, {n_f} triangles\n")
        out.write(("v %r %r %r\n" * n_v) % coords)
        if normals is not None:
            out.write(("vn %r %r %r\n" * n_v) % tuple(np.asarray(normals).ravel().tolist()))
            faces = np.repeat(np.asarray(triangles) + 1, 2, axis=1)
            out.write(("f %d//%d %d//%d %d//%d\n" * n_f) % tuple(faces.ravel().tolist()))
        else:
            out.write(("f %d %d %d\n" * n_f) % tuple((np.asarray(triangles) + 1).ravel().tolist()))


def write_mesh_to(tmp: str | os.PathLike, suffix: str, vertices, triangles, normals=None,
                  colors=None) -> None:
    """Write a mesh to ``tmp`` (not atomic: for a temporary the caller renames).

    PLY, STL, OFF and OBJ are written here with Python's own ``write``, so a
    full disk or an I/O error is an ``OSError``; glTF goes through open3d,
    whose return value and fd-2 lines are checked (a line holding "fail" or
    "error" is a failed write).
    """
    tmp = Path(tmp)
    if suffix == ".ply":
        _write_ply_to(tmp, vertices, triangles, normals, colors)
    elif suffix == ".stl":
        _write_stl_to(tmp, vertices, triangles)
    elif suffix in (".off", ".obj"):
        _write_text_to(tmp, suffix, vertices, triangles, normals)
    else:
        import open3d as o3d

        from pipeline.guards import native_stderr

        mesh = to_open3d(vertices, triangles, normals, colors)
        with native_stderr() as said:
            ok = o3d.io.write_triangle_mesh(str(tmp), mesh, write_ascii=False,
                                            write_vertex_normals=normals is not None,
                                            write_vertex_colors=colors is not None)
        failed = [ln for ln in said.text.splitlines() if "fail" in ln.lower()
                  or "error" in ln.lower()]
        if not ok or failed:
            detail = f": {failed[0].strip()[:120]}" if failed else ""
            raise OSError(f"{tmp}: open3d could not write the {suffix} mesh{detail}")


def write_mesh(path: str | os.PathLike, vertices: np.ndarray, triangles: np.ndarray,
               normals: np.ndarray | None = None, colors: np.ndarray | None = None,
               compute_normals: bool = True) -> Path:
    """Write a mesh atomically (temp file, then rename); format from the suffix.

    Every write is checked (:func:`write_mesh_to`): a full disk fails the
    command and leaves nothing at ``path``.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in MESH_SUFFIXES:
        raise InputError(f"{path}: cannot write mesh format {suffix!r} "
                         f"(choose one of {', '.join(MESH_SUFFIXES)})")
    vertices = np.asarray(vertices, dtype=np.float64)
    triangles = np.asarray(triangles, dtype=np.int64)
    if len(triangles) == 0:  # an empty mesh is no output (open3d's writer refused it too)
        raise InputError(f"{path}: no triangles to write")
    if normals is None and compute_normals and suffix not in (".stl", ".off"):
        normals = _area_normals(vertices, triangles)
    with atomic_file(path) as tmp:
        write_mesh_to(tmp, suffix, vertices, triangles,
                      None if suffix in (".stl", ".off") else normals, colors)
    return path


# --------------------------------------------------------------------------- additions for
# the smooth/render commands (pipeline/cmd_smooth.py, pipeline/cmd_render.py)


@contextlib.contextmanager
def quiet_native_stderr() -> Iterator[None]:
    """Silence C-level writes to file descriptor 2 (open3d's RPly, tinyobj) for a moment.

    The CLI promises one error line on bad input; open3d's file parsers print
    their own diagnostics straight to fd 2, which ``VerbosityLevel`` does not
    reach.  Python-level ``sys.stderr`` is untouched.
    """
    try:
        saved = os.dup(2)
    except OSError:  # no fd 2 (embedded interpreter): nothing to silence
        yield
        return
    try:
        with open(os.devnull, "wb") as sink:
            os.dup2(sink.fileno(), 2)
            try:
                yield
            finally:
                os.dup2(saved, 2)
    finally:
        os.close(saved)


def read_mesh_with_normals(path: str | os.PathLike, quiet: bool = True
                           ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """:func:`read_mesh` plus the file's vertex normals, if it stores any.

    Returns
    -------
    vertices : (V, 3) float64
    triangles : (F, 3) int64
    normals : (V, 3) float64 or None
        Unit vertex normals as stored (PLY, OBJ, glTF, GLB), ``None`` when the
        file has none (STL stores facet normals only, so ``None``).
    """
    import open3d as o3d

    from pipeline.guards import regular_file

    path = regular_file(path, "mesh file")  # no FIFO or device
    with contextlib.ExitStack() as stack:
        if quiet:
            stack.enter_context(quiet_native_stderr())
            stack.enter_context(o3d.utility.VerbosityContextManager(
                o3d.utility.VerbosityLevel.Error))
        vertices, triangles = read_mesh(path)
        normals = None
        if path.suffix.lower() != ".stl":
            mesh = o3d.io.read_triangle_mesh(str(path))
            if mesh.has_vertex_normals() and len(mesh.vertex_normals) == len(vertices):
                normals = np.asarray(mesh.vertex_normals, dtype=np.float64)
                if not np.all(np.isfinite(normals)):
                    normals = None
    return vertices, triangles, normals


def weld_vertices(vertices: np.ndarray, triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Merge vertices with bit-identical positions (STL stores three per facet).

    Exact equality only, no distance tolerance: two distinct vertices of a
    real mesh never coincide exactly unless the file split them.

    Returns
    -------
    vertices : (U, 3) float64, U <= V
    triangles : (F, 3) int64, re-indexed
    """
    unique, inverse = np.unique(vertices, axis=0, return_inverse=True)
    return unique, inverse.reshape(-1)[triangles]
