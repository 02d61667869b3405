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

    Raises
    ------
    FileNotFoundError, InputError
        Missing file, unknown format, or a file with no triangles.
    """
    import open3d as o3d

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such mesh file")
    if path.suffix.lower() not in MESH_SUFFIXES + (".glb",):
        raise InputError(f"{path}: unknown mesh format {path.suffix!r} "
                         f"(expected one of {', '.join(MESH_SUFFIXES)})")
    mesh = o3d.io.read_triangle_mesh(str(path))
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    triangles = np.asarray(mesh.triangles, dtype=np.int64)
    if len(triangles) == 0:
        raise InputError(f"{path}: no triangles could be read")
    if not np.all(np.isfinite(vertices)):
        raise InputError(f"{path}: vertices contain NaN/inf")
    return vertices, triangles


def write_mesh(path: str | os.PathLike, vertices: np.ndarray, triangles: np.ndarray,
               normals: np.ndarray | None = None, colors: np.ndarray | None = None,
               compute_normals: bool = True) -> Path:
    """Write a mesh atomically (temp file, then rename); format from the suffix."""
    import open3d as o3d

    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in MESH_SUFFIXES:
        raise InputError(f"{path}: cannot write mesh format {suffix!r} "
                         f"(choose one of {', '.join(MESH_SUFFIXES)})")
    mesh = to_open3d(vertices, triangles, normals, colors)
    if normals is None and compute_normals and suffix != ".stl":
        mesh.compute_vertex_normals()
    if suffix == ".stl":
        mesh.compute_triangle_normals()
    with atomic_file(path) as tmp:
        ok = o3d.io.write_triangle_mesh(str(tmp), mesh, write_ascii=False,
                                        write_vertex_normals=suffix != ".stl")
        if not ok:
            raise OSError(f"{path}: open3d could not write the mesh")
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

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such mesh file")
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
