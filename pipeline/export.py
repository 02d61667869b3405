"""Export of the tessellated surface and of its exact Bézier control net.

A tessellated mesh ``vertices (V, 3) float64``, ``triangles (F, 3) int64``,
``normals (V, 3)`` is written by file suffix:

========  =========================================  ==========================
suffix    writer                                     keeps
========  =========================================  ==========================
``.ply``  open3d, binary little-endian               float64 xyz, normals, rgb
``.obj``  here (``v``/``vn``/``f a//a``, shortest    xyz and normals, exact
          round-trip decimal of each float64)        float64 text
``.stl``  open3d, binary                             float32 xyz, face normals
``.gltf`` open3d (buffer embedded as a data URI)     float32 xyz, normals
``.glb``  here: the glTF 2.0 binary container        float32 xyz, normals, rgb
          [1]_ (12-byte header, JSON chunk, BIN
          chunk), uint32 indices
========  =========================================  ==========================

GLB and OBJ are written here: open3d 0.20's ``.glb`` fails its own reader (no BIN
chunk) and its OBJ keeps six significant digits (``docs/decisions/export.md``).

The control net of the sextic triangular Bézier surface (Loop [2]_) is written beside
the mesh as a ``.npz`` (:func:`write_control_net`): version 2 stores each distinct control
point once (``points (Q, 3)``, ~18 a patch) and the patches as rows of 28 indices
(``patches (P, 28)``), read back bit for bit; version 1 (``(P, 28, 3)``) is still read.
Patch ``p`` is
:math:`S_p(r, s, t) = \\sum_{i+j+k=6} \\frac{6!}{i!\\,j!\\,k!} r^i s^j t^k P_{p,ijk}`,
``r + s + t = 1``, row ``m`` of ``control_points[p]`` being :math:`P_{p,ijk}` with
``(i, j, k) = index[m]`` (corner ``(6, 0, 0)`` the patch's first);
:meth:`ControlNet.evaluate` evaluates it without ``surface.bezier``, which is how the
tests prove the file is sufficient.

Every write is atomic (:func:`pipeline.atomic.atomic_file`); :func:`export_surface`
publishes the mesh and its control net together or not at all.

References
----------
.. [1] Khronos Group, "glTF 2.0 Specification", section 4.4 "GLB File Format" (2021).
.. [2] C. Loop, "Smooth spline surfaces over irregular meshes", SIGGRAPH '94, 303-310.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import struct
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipeline.atomic import atomic_file, naming
from pipeline.errors import InputError
from pipeline.mesh_io import vertex_normals, write_mesh_to
from pipeline.workspace import write_npz_to
from surface.validate import TOL, check_finite, check_shape

#: Suffixes :func:`export_mesh` writes.
EXPORT_SUFFIXES = (".ply", ".obj", ".stl", ".gltf", ".glb")

#: ``format`` field of the control-net ``.npz`` and its version.
CONTROL_NET_FORMAT = "photosurf.bezier_control_net"
CONTROL_NET_VERSION = 2
#: Versions :func:`read_control_net` reads (1: one ``(P, 28, 3)`` array; 2: shared points).
_CONTROL_NET_VERSIONS = (2, 1)
#: Degree of Loop's patches and their number of control points, (d+1)(d+2)/2.
DEGREE = 6
N_CONTROL = (DEGREE + 1) * (DEGREE + 2) // 2

# glTF 2.0 constants (specification section 3.6 / 5.24).
_GLB_MAGIC = 0x46546C67  # b"glTF"
_CHUNK_JSON = 0x4E4F534A  # b"JSON"
_CHUNK_BIN = 0x004E4942  # b"BIN\0"
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963
_FLOAT, _UNSIGNED_INT = 5126, 5125
_INDEX_TYPES = {5121: "<u1", 5123: "<u2", 5125: "<u4"}
_TRIANGLES = 4


# --------------------------------------------------------------------------- meshes


def _check_mesh(vertices, triangles, normals=None, colors=None):
    """Validate mesh arrays at the entrance; return them as contiguous arrays."""
    vertices = check_shape(vertices, "(V, 3)", "vertices", dtype=np.float64)
    check_finite(vertices, "vertices")
    triangles = check_shape(triangles, "(F, 3)", "triangles")
    if triangles.size and not np.issubdtype(triangles.dtype, np.integer):
        raise ValueError(f"triangles must be integer indices, got dtype {triangles.dtype}")
    triangles = triangles.astype(np.int64)
    if len(triangles) == 0:
        raise ValueError("triangles is empty: nothing to export")
    if triangles.min() < 0 or triangles.max() >= len(vertices):
        raise ValueError(f"triangles index vertices outside [0, {len(vertices)}): "
                         f"min {triangles.min()}, max {triangles.max()}")
    if normals is not None:
        normals = check_shape(normals, "(V, 3)", "normals", dtype=np.float64)
        if len(normals) != len(vertices):
            raise ValueError(f"normals must have one row per vertex ({len(vertices)}), "
                             f"got {len(normals)}")
        check_finite(normals, "normals")
    if colors is not None:
        colors = check_shape(colors, "(V, 3)", "colors")
        if len(colors) != len(vertices):
            raise ValueError(f"colors must have one row per vertex ({len(vertices)}), "
                             f"got {len(colors)}")
    return vertices, triangles, normals, colors


def export_mesh(path: str | os.PathLike, vertices: np.ndarray, triangles: np.ndarray,
                normals: np.ndarray | None = None, colors: np.ndarray | None = None,
                sigma: np.ndarray | None = None) -> Path:
    """Write a triangle mesh atomically, the format chosen by the suffix.

    Parameters
    ----------
    path : path-like
        Output file; suffix one of :data:`EXPORT_SUFFIXES`.
    vertices : (V, 3) float64, scene units
    triangles : (F, 3) int64, counter-clockwise seen from outside
    normals : (V, 3) float64, optional
        Unit vertex normals (e.g. the exact Bézier normals); area-weighted
        normals are computed when omitted.  STL keeps only face normals.
    colors : (V, 3) uint8 or float in [0, 1], optional
        Vertex colours (PLY, glTF, GLB).
    sigma : (V,) float, optional
        Each vertex's 1σ along its normal (``surface.uncertainty``), scene units: the
        PLY's ``float sigma`` vertex property (other formats have no place for it).

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    ValueError
        Unknown suffix or malformed arrays (the message names which).
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in EXPORT_SUFFIXES:
        raise InputError(f"{path}: cannot export mesh format {suffix!r} "
                         f"(choose one of {', '.join(EXPORT_SUFFIXES)})")
    vertices, triangles, normals, colors = _check_mesh(vertices, triangles, normals, colors)
    if normals is None:
        normals = vertex_normals(vertices, triangles)
    if sigma is not None:
        sigma = check_finite(np.asarray(sigma, dtype=np.float64).reshape(-1), "sigma")
        if len(sigma) != len(vertices):
            raise ValueError(f"sigma must have one value per vertex ({len(vertices)}), "
                             f"got {len(sigma)}")
    with atomic_file(path) as tmp:
        _write_mesh_to(tmp, suffix, vertices, triangles, normals, colors, sigma)
    return path


def _write_mesh_to(tmp: Path, suffix: str, vertices, triangles, normals, colors,
                   sigma=None) -> None:
    """Write the (validated) mesh to ``tmp`` in the format of ``suffix``."""
    if suffix == ".glb":
        _write_glb_to(tmp, vertices, triangles, normals, colors)
    elif suffix == ".obj":
        _write_obj_to(tmp, vertices, triangles, normals)
    else:
        _write_open3d_to(tmp, suffix, vertices, triangles, normals, colors, sigma)


def _write_open3d_to(tmp: Path, suffix: str, vertices, triangles, normals, colors,
                     sigma=None) -> None:
    # PLY/STL by photosurf's own checked writers, glTF by open3d with its result and
    # fd-2 lines checked (pipeline.mesh_io.write_mesh_to): a full disk is an error
    write_mesh_to(tmp, suffix, vertices, triangles, None if suffix == ".stl" else normals,
                  colors, sigma)


def _write_obj_to(tmp: Path, vertices, triangles, normals) -> None:
    """Wavefront OBJ with ``v``, ``vn`` and ``f a//a b//b c//c`` (1-based) lines.

    ``%r`` prints the shortest decimal that reads back to the same float64, so
    the text is exact; the whole block is formatted by one C-level ``%``.
    """
    n_v, n_f = len(vertices), len(triangles)
    with open(tmp, "w", encoding="ascii", newline="\n") as out:
        out.write(f"# photosurf OBJ: {n_v} vertices, {n_f} triangles, vertex normals\n")
        out.write(("v %r %r %r\n" * n_v) % tuple(vertices.ravel().tolist()))
        out.write(("vn %r %r %r\n" * n_v) % tuple(normals.ravel().tolist()))
        faces = np.repeat(triangles + 1, 2, axis=1)  # (F, 6): a a b b c c
        out.write(("f %d//%d %d//%d %d//%d\n" * n_f) % tuple(faces.ravel().tolist()))


# --------------------------------------------------------------------------- GLB


def _pad4(data: bytes, fill: bytes) -> bytes:
    return data + fill * (-len(data) % 4)


def write_glb(path: str | os.PathLike, vertices: np.ndarray, triangles: np.ndarray,
              normals: np.ndarray | None = None, colors: np.ndarray | None = None) -> Path:
    """Write a binary glTF 2.0 (``.glb``) file atomically.

    One mesh, one primitive (mode TRIANGLES) with ``POSITION`` and ``NORMAL``
    (float32 VEC3, and ``COLOR_0`` when colours are given), uint32 indices,
    in the scene's units and axes (glTF calls +Y up; no transform is added,
    the same choice as open3d's ``.gltf`` writer).

    Parameters
    ----------
    path : path-like
    vertices : (V, 3) float64
    triangles : (F, 3) int64
    normals : (V, 3) float64, optional (area-weighted when omitted)
    colors : (V, 3) uint8 or float in [0, 1], optional

    Returns
    -------
    Path
    """
    path = Path(path)
    vertices, triangles, normals, colors = _check_mesh(vertices, triangles, normals, colors)
    if normals is None:
        normals = vertex_normals(vertices, triangles)
    with atomic_file(path) as tmp:
        _write_glb_to(tmp, vertices, triangles, normals, colors)
    return path


def _glb_document(vertices, triangles, normals, colors) -> tuple[dict, bytes]:
    """The glTF JSON document and the BIN chunk's payload for one primitive."""
    positions = np.ascontiguousarray(vertices, dtype="<f4")
    unit = normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), TOL.zero)
    arrays = [np.ascontiguousarray(triangles, dtype="<u4"), positions,
              np.ascontiguousarray(unit, dtype="<f4")]
    if colors is not None:
        rgb = np.asarray(colors)
        rgb = rgb / 255.0 if rgb.dtype == np.uint8 else rgb
        arrays.append(np.ascontiguousarray(np.clip(rgb, 0.0, 1.0), dtype="<f4"))
    blob, views = b"", []
    for i, array in enumerate(arrays):
        data = array.tobytes()
        views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(data),
                      "target": _ELEMENT_ARRAY_BUFFER if i == 0 else _ARRAY_BUFFER})
        blob += _pad4(data, b"\0")  # every view starts 4-byte aligned (spec 3.6.2.4)
    accessors = [{"bufferView": 0, "componentType": _UNSIGNED_INT, "count": int(triangles.size),
                  "type": "SCALAR", "min": [int(triangles.min())],
                  "max": [int(triangles.max())]},
                 {"bufferView": 1, "componentType": _FLOAT, "count": len(positions),
                  "type": "VEC3", "min": positions.min(axis=0).tolist(),
                  "max": positions.max(axis=0).tolist()},
                 {"bufferView": 2, "componentType": _FLOAT, "count": len(positions),
                  "type": "VEC3"}]
    attributes = {"POSITION": 1, "NORMAL": 2}
    if colors is not None:
        accessors.append({"bufferView": 3, "componentType": _FLOAT, "count": len(positions),
                          "type": "VEC3"})
        attributes["COLOR_0"] = 3
    document = {
        "asset": {"version": "2.0", "generator": "photosurf pipeline.export"},
        "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": attributes, "indices": 0,
                                    "mode": _TRIANGLES}]}],
        "buffers": [{"byteLength": len(blob)}],
        "bufferViews": views, "accessors": accessors,
    }
    return document, blob


def _write_glb_to(tmp: Path, vertices, triangles, normals, colors) -> None:
    document, blob = _glb_document(vertices, triangles, normals, colors)
    text = _pad4(json.dumps(document, separators=(",", ":")).encode("utf-8"), b" ")
    total = 12 + 8 + len(text) + 8 + len(blob)
    with open(tmp, "wb") as out:
        out.write(struct.pack("<III", _GLB_MAGIC, 2, total))
        out.write(struct.pack("<II", len(text), _CHUNK_JSON) + text)
        out.write(struct.pack("<II", len(blob), _CHUNK_BIN) + blob)


def read_glb(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Read the triangle primitives of a binary glTF 2.0 file.

    A small, strict reader (header, chunk types and lengths, accessor bounds
    are checked) used to verify :func:`write_glb` independently of open3d.
    Node transforms are ignored; all TRIANGLES primitives are concatenated.

    Returns
    -------
    vertices : (V, 3) float64
    triangles : (F, 3) int64
    normals : (V, 3) float64 or None
        ``None`` when any primitive lacks ``NORMAL``.

    Raises
    ------
    FileNotFoundError, InputError
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such GLB file")
    data = path.read_bytes()
    try:
        return _read_glb_document(path, *_glb_chunks(path, data))
    except InputError:
        raise
    except (KeyError, IndexError, TypeError, AttributeError, ValueError, struct.error) as exc:
        # a document that lies (missing tables, wrong types, offsets past the data)
        raise InputError(f"{path}: malformed glTF document ({type(exc).__name__}: "
                         f"{exc})") from None


def _read_glb_document(path: Path, document, blob: bytes):
    if not isinstance(document, dict):
        raise InputError(f"{path}: the glTF JSON chunk is not an object")
    vertices, triangles, normals = [], [], []
    for mesh in document.get("meshes", []):
        for prim in mesh.get("primitives", []):
            if prim.get("mode", _TRIANGLES) != _TRIANGLES:
                continue
            attrs = prim.get("attributes", {})
            if "POSITION" not in attrs or "indices" not in prim:
                raise InputError(f"{path}: primitive without POSITION or indices")
            positions = _accessor(path, document, blob, attrs["POSITION"])
            index = _accessor(path, document, blob, prim["indices"])
            if index.size % 3 or (index.size and index.max() >= len(positions)):
                raise InputError(f"{path}: indices do not form triangles over "
                                 f"{len(positions)} vertices")
            triangles.append(index.reshape(-1, 3).astype(np.int64) + sum(map(len, vertices)))
            vertices.append(positions.astype(np.float64))
            normals.append(_accessor(path, document, blob, attrs["NORMAL"])
                           if "NORMAL" in attrs else None)
    if not triangles:
        raise InputError(f"{path}: no triangle primitives")
    has_normals = all(n is not None for n in normals)
    return (np.concatenate(vertices), np.concatenate(triangles),
            np.concatenate(normals).astype(np.float64) if has_normals else None)


def _glb_chunks(path: Path, data: bytes) -> tuple[dict, bytes]:
    if len(data) < 20:
        raise InputError(f"{path}: too short for a GLB file ({len(data)} bytes)")
    magic, version, length = struct.unpack_from("<III", data, 0)
    if magic != _GLB_MAGIC or version != 2 or length != len(data):
        raise InputError(f"{path}: not a glTF 2.0 binary (magic {magic:#x}, version "
                         f"{version}, length {length} vs {len(data)} bytes)")
    json_len, json_type = struct.unpack_from("<II", data, 12)
    if json_type != _CHUNK_JSON or 20 + json_len > len(data):
        raise InputError(f"{path}: first chunk is not a JSON chunk")
    document = json.loads(data[20:20 + json_len].decode("utf-8"))
    blob = b""
    offset = 20 + json_len
    if offset + 8 <= len(data):
        bin_len, bin_type = struct.unpack_from("<II", data, offset)
        if bin_type != _CHUNK_BIN or offset + 8 + bin_len > len(data):
            raise InputError(f"{path}: second chunk is not a BIN chunk")
        blob = data[offset + 8:offset + 8 + bin_len]
    return document, blob


def _accessor(path: Path, document: dict, blob: bytes, index: int) -> np.ndarray:
    accessor = document["accessors"][index]
    view = document["bufferViews"][accessor["bufferView"]]
    if view.get("buffer", 0) != 0 or "byteStride" in view:
        raise InputError(f"{path}: accessor {index}: only tightly packed data in the BIN chunk "
                         "is supported")
    width = {"SCALAR": 1, "VEC3": 3}.get(accessor["type"])
    dtype = {_FLOAT: "<f4", **_INDEX_TYPES}.get(accessor["componentType"])
    if width is None or dtype is None:
        raise InputError(f"{path}: accessor {index}: unsupported type {accessor['type']} / "
                         f"{accessor['componentType']}")
    start = view.get("byteOffset", 0) + accessor.get("byteOffset", 0)
    count = accessor["count"] * width
    if not all(isinstance(n, int) and n >= 0 for n in (start, count)):
        raise InputError(f"{path}: accessor {index}: offsets and count must be integers >= 0")
    end = start + count * np.dtype(dtype).itemsize
    if end > view.get("byteOffset", 0) + view["byteLength"] or end > len(blob):
        raise InputError(f"{path}: accessor {index} runs past its buffer view")
    values = np.frombuffer(blob, dtype=dtype, count=count, offset=start)
    return values.reshape(-1, 3) if width == 3 else values


# --------------------------------------------------------------------------- control net


@dataclass(frozen=True)
class ControlNet:
    """The exact Bézier surface as stored in the control-net ``.npz``.

    Attributes
    ----------
    control_points : (P, 28, 3) float64
        Control point ``m`` of patch ``p`` is :math:`P_{p,ijk}`, ``(i,j,k) = index[m]``
        (version 2: ``points[patches]``, rebuilt by the reader).
    index : (28, 3) int64
        The (i, j, k) exponents, each row summing to 6.
    source_face : (P,) int64
        The triangle of the input control mesh each patch lies over (``-1``
        when unknown).
    format_version : int
    domain_vertices : (D, 3) float64 or None
    domain_triangles : (P, 3) int64 or None
        The triangle mesh the patches are built over (patch ``p``'s corners
        ``b_600, b_060, b_006`` lie over ``domain_triangles[p]``): which
        patches share an edge, for re-tessellating without cracks.
    points : (Q, 3) float64 or None
        Version 2: the distinct control points.
    patches : (P, 28) int64 or None
        Version 2: row ``p`` holds the rows of ``points`` that form patch ``p``.
    """

    control_points: np.ndarray
    index: np.ndarray
    source_face: np.ndarray
    format_version: int = CONTROL_NET_VERSION
    domain_vertices: np.ndarray | None = None
    domain_triangles: np.ndarray | None = None
    points: np.ndarray | None = None
    patches: np.ndarray | None = None

    def evaluate(self, barycentric: np.ndarray) -> np.ndarray:
        """Points of every patch at the barycentric coordinates ``(r, s, t)``.

        Parameters
        ----------
        barycentric : (M, 3) float64
            Rows ``(r, s, t)`` with ``r + s + t = 1``.

        Returns
        -------
        points : (P, M, 3) float64
        """
        uvw = check_shape(barycentric, "(M, 3)", "barycentric", dtype=np.float64)
        fact = np.array([math.factorial(n) for n in range(DEGREE + 1)], dtype=np.float64)
        coeff = math.factorial(DEGREE) / fact[self.index].prod(axis=1)  # (28,)
        basis = coeff * np.prod(uvw[:, None, :] ** self.index[None], axis=2)  # (M, 28)
        return np.einsum("mc,pcx->pmx", basis, self.control_points)


def _check_index(index) -> np.ndarray:
    index = check_shape(index, f"({N_CONTROL}, 3)", "index")
    if not np.issubdtype(index.dtype, np.integer):
        raise ValueError(f"index must hold integers, got dtype {index.dtype}")
    if index.min() < 0 or np.any(index.sum(axis=1) != DEGREE):
        raise ValueError(f"index rows must be (i, j, k) >= 0 with i + j + k = {DEGREE}")
    if len({tuple(row) for row in index.tolist()}) != N_CONTROL:
        raise ValueError(f"index must list each of the {N_CONTROL} (i, j, k) exactly once")
    return index.astype(np.int64)


def shared_points(control_points: np.ndarray, index: np.ndarray,
                  domain_triangles: np.ndarray | None = None
                  ) -> tuple[np.ndarray, np.ndarray]:
    """The distinct control points and each patch's rows in them (format version 2).

    With the domain triangles, the points are numbered by topology
    (``surface.bezier.control_point_ids``: a corner by its domain vertex, an
    edge point by its undirected domain edge and position): neighbouring
    patches share their boundary points whenever their copies are
    bit-identical, which ``surface.bezier.control_net`` makes them
    (``share_boundaries``).  Without them, or where copies differ, points are
    shared by exact equality of their three float64 coordinates.  Either way
    ``points[patches]`` is ``control_points`` bit for bit.

    Parameters
    ----------
    control_points : (P, 28, 3) float64
    index : (28, 3) int64
    domain_triangles : (P, 3) int64, optional

    Returns
    -------
    points : (Q, 3) float64
    patches : (P, 28) int64
    """
    flat = control_points.reshape(-1, 3)
    if domain_triangles is not None and len(domain_triangles):
        from surface.bezier import control_index, control_point_ids, gather_shared

        # the topological ids are in surface.bezier's storage order; map to this net's rows
        order = control_index(index[:, 0], index[:, 1], index[:, 2])
        ids, count = control_point_ids(domain_triangles)
        if not np.array_equal(order, np.arange(N_CONTROL)):
            ids = ids[:, order]
        shared = gather_shared(control_points, ids, count)  # None: copies differ
        if shared is not None:
            points, used = shared
            if used.all():
                return points, ids
            remap = np.cumsum(used) - 1  # ids of a mesh with unused vertices leave gaps
            return points[used], remap[ids]
    rows = np.ascontiguousarray(flat).view(np.dtype((np.void, 24))).ravel()
    _, first, inverse = np.unique(rows, return_index=True, return_inverse=True)
    order = np.argsort(first, kind="stable")  # number points by first use
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    return flat[first[order]], rank[inverse.ravel()].reshape(len(control_points), N_CONTROL)


def _net_arrays(control_points, index, source_face, domain_mesh=None,
                version: int = CONTROL_NET_VERSION) -> dict:
    control_points = check_shape(control_points, f"(P, {N_CONTROL}, 3)", "control_points",
                                 dtype=np.float64)
    check_finite(control_points, "control_points")
    index = _check_index(index)
    if source_face is None:
        source_face = np.full(len(control_points), -1, dtype=np.int64)
    source_face = check_shape(source_face, "(P,)", "source_face").astype(np.int64)
    if len(source_face) != len(control_points):
        raise ValueError(f"source_face must have one entry per patch ({len(control_points)}), "
                         f"got {len(source_face)}")
    arrays = {"format": np.array(CONTROL_NET_FORMAT),
              "format_version": np.int64(version), "degree": np.int64(DEGREE),
              "index": index, "source_face": source_face}
    domain_triangles = None
    if domain_mesh is not None:
        domain_vertices = check_shape(domain_mesh[0], "(D, 3)", "domain_vertices",
                                      dtype=np.float64)
        domain_triangles = check_shape(domain_mesh[1], "(P, 3)", "domain_triangles")
        if len(domain_triangles) != len(control_points) or (
                domain_triangles.size and (domain_triangles.min() < 0
                                           or domain_triangles.max() >= len(domain_vertices))):
            raise ValueError(f"domain_triangles must be ({len(control_points)}, 3) indices "
                             f"into {len(domain_vertices)} domain vertices")
        domain_triangles = domain_triangles.astype(np.int64)
        arrays["domain_vertices"] = domain_vertices
        arrays["domain_triangles"] = domain_triangles
    if version == 1:
        arrays["control_points"] = control_points
    else:
        points, patches = shared_points(control_points, index, domain_triangles)
        arrays["points"] = points
        # int32 where it can hold every row number: 112 instead of 224 bytes per patch
        arrays["patches"] = patches.astype(np.int32 if len(points) < 2 ** 31 else np.int64)
    return arrays


def _arrays_to_net(arrays: dict, version: int) -> tuple[dict, ControlNet]:
    """Check a file's arrays and rebuild its :class:`ControlNet` (both versions)."""
    domain = ((arrays["domain_vertices"], arrays["domain_triangles"])
              if "domain_vertices" in arrays and "domain_triangles" in arrays else None)
    points = patches = None
    if version == 1:
        control_points = arrays["control_points"]
    else:
        points = check_shape(arrays["points"], "(Q, 3)", "points", dtype=np.float64)
        check_finite(points, "points")
        patches = check_shape(arrays["patches"], f"(P, {N_CONTROL})", "patches")
        if not np.issubdtype(patches.dtype, np.integer):
            raise ValueError(f"patches must hold integer rows, got dtype {patches.dtype}")
        if patches.size and (patches.min() < 0 or patches.max() >= len(points)):
            raise ValueError(f"patches must index rows 0..{len(points) - 1} of points, found "
                             f"{patches.min()}..{patches.max()}")
        patches = patches.astype(np.int64)
        control_points = points[patches]
    checked = _net_arrays(control_points, arrays["index"], arrays["source_face"], domain,
                          version=1)
    return checked, ControlNet(checked["control_points"], checked["index"],
                               checked["source_face"], version,
                               checked.get("domain_vertices"), checked.get("domain_triangles"),
                               points, patches)


#: Control-net members written deflated: the integer tables, which shrink to 5-45 % at
#: ~50 MB/s (the demo's 65 312 patches: 37.3 -> 32.6 MB in 0.18 s; deflating the float64
#: points as well would save 4.9 MB more for 0.95 s of the back end's 15 s).
NET_DEFLATED = ("index", "source_face", "domain_triangles", "patches")


def write_control_net(path: str | os.PathLike, control_points: np.ndarray, index: np.ndarray,
                      source_face: np.ndarray | None = None,
                      domain_mesh: tuple[np.ndarray, np.ndarray] | None = None,
                      version: int = CONTROL_NET_VERSION) -> Path:
    """Write the Bézier control net as an ``.npz``, atomically: float64 members stored,
    the integer tables deflated (:data:`NET_DEFLATED`; ``numpy.load`` reads both).

    Arrays in the file (read them with ``numpy.load(path)``; no pickles):

    ====================  ===============  ==========================================
    ``format``            str              ``"photosurf.bezier_control_net"``
    ``format_version``    int64            2 (1: the old layout, still read)
    ``degree``            int64            6
    ``points``            (Q, 3) f8        v2: the distinct control points
    ``patches``           (P, 28) int32    v2: patch p's control point m is
                                           ``points[patches[p, m]]`` ↔ ``index[m]``
    ``control_points``    (P, 28, 3) f8    v1 only: :math:`P_{p,ijk}`, row ``m`` ↔ ``index[m]``
    ``index``             (28, 3) int64    the (i, j, k), ``i + j + k = 6``
    ``source_face``       (P,) int64       input-mesh triangle under each patch, or -1
    ``domain_vertices``   (D, 3) f8        optional: the mesh the patches lie over,
    ``domain_triangles``  (P, 3) int64     patch p's corners over row p (shared edges)
    ====================  ===============  ==========================================

    Patch ``p`` is
:math:`S_p(r,s,t)=\\sum 6!/(i!j!k!)\\,r^i s^j t^k P_{p,ijk}`
    (module docstring).  Version 2 stores each control point that neighbouring
    patches share (their common boundary rows, bit-identical) once
    (:func:`shared_points`): ``points[patches]`` is the surface bit for bit, in
    about 18 points per patch instead of 28 on a closed mesh.

    Parameters
    ----------
    path : path-like, suffix ``.npz``
    control_points : (P, 28, 3) float64
    index : (28, 3) int
    source_face : (P,) int, optional
    domain_mesh : ((D, 3) float64, (P, 3) int), optional
        The triangle mesh the patches lie over (``BezierSurface.domain_mesh``);
        it also lets version 2 number the shared points by topology (fast).
    version : {2, 1}
        1 writes the old layout (one net per patch).

    Returns
    -------
    Path
    """
    path = Path(path)
    if path.suffix.lower() != ".npz":
        raise InputError(f"{path}: the control net is written as .npz")
    if version not in _CONTROL_NET_VERSIONS:
        raise ValueError(f"version must be one of {_CONTROL_NET_VERSIONS}, got {version!r}")
    arrays = _net_arrays(control_points, index, source_face, domain_mesh, version)
    with atomic_file(path) as tmp:
        # byte-reproducible (np.savez stamps the time); the integer tables deflated
        write_npz_to(tmp, deflate=NET_DEFLATED, **arrays)
    return path


def read_control_net(path: str | os.PathLike) -> ControlNet:
    """Read a control net written by :func:`write_control_net` (format version 1 or 2).

    Raises
    ------
    FileNotFoundError, InputError
        Missing file, not a control net, a newer format version, or
        malformed arrays.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such control-net file")
    try:
        # our own handle: closed even when numpy fails half-way (else the raised
        # error's traceback keeps numpy's open file alive: a ResourceWarning later)
        with open(path, "rb") as fh, np.load(fh, allow_pickle=False) as npz:
            arrays = {name: npz[name] for name in npz.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        raise InputError(f"{path}: not a readable .npz ({exc or type(exc).__name__})") from exc
    if str(arrays.get("format", "")) != CONTROL_NET_FORMAT:
        raise InputError(f"{path}: not a photosurf control net (format "
                         f"{str(arrays.get('format', 'missing'))!r})")
    try:
        version = int(arrays.get("format_version", -1))
    except (TypeError, ValueError) as exc:
        raise InputError(f"{path}: format_version is not an integer") from exc
    if version not in _CONTROL_NET_VERSIONS:
        raise InputError(f"{path}: control-net format version {version} is not supported "
                         f"(this reader knows {', '.join(map(str, _CONTROL_NET_VERSIONS))})")
    try:
        return _arrays_to_net(arrays, version)[1]
    except (KeyError, ValueError) as exc:
        raise InputError(f"{path}: {exc}") from exc


def export_surface(path: str | os.PathLike, vertices: np.ndarray, triangles: np.ndarray,
                   normals: np.ndarray | None, control_points: np.ndarray, index: np.ndarray,
                   source_face: np.ndarray | None = None,
                   domain_mesh: tuple[np.ndarray, np.ndarray] | None = None
                   ) -> tuple[Path, Path]:
    """Write the tessellated mesh to ``path`` and its control net to ``path.npz``.

    Both files are written to temporaries first and renamed only when both
    are complete, so either both appear or neither does.

    Parameters
    ----------
    path : path-like
        Mesh file, suffix one of :data:`EXPORT_SUFFIXES`; the net goes to
        ``path.with_suffix(".npz")``.
    vertices, triangles, normals
        As :func:`export_mesh`.
    control_points, index, source_face, domain_mesh
        As :func:`write_control_net`.

    Returns
    -------
    (mesh_path, net_path) : tuple of Path
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in EXPORT_SUFFIXES:
        raise InputError(f"{path}: cannot export mesh format {suffix!r} "
                         f"(choose one of {', '.join(EXPORT_SUFFIXES)})")
    net_path = path.with_suffix(".npz")
    for target in (path, net_path):  # a rename over a folder fails after the other landed
        if target.is_dir():
            raise InputError(f"{target}: is a folder; the surface and its control net are "
                             "files")
    vertices, triangles, normals, _ = _check_mesh(vertices, triangles, normals)
    if normals is None:
        normals = vertex_normals(vertices, triangles)
    arrays = _net_arrays(control_points, index, source_face, domain_mesh)
    with contextlib.ExitStack() as stack:
        tmp_mesh = stack.enter_context(atomic_file(path))
        tmp_net = stack.enter_context(atomic_file(net_path))
        with naming(path):  # a failure names the file that failed, not the inner block's
            _write_mesh_to(tmp_mesh, suffix, vertices, triangles, normals, None)
        with naming(net_path):
            write_npz_to(tmp_net, **arrays)  # byte-reproducible (np.savez stamps the time)
    return path, net_path
