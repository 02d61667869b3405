"""Triangle-mesh reading and writing through open3d, atomically.

Meshes cross every boundary as ``vertices (V, 3) float64`` and
``triangles (F, 3) int64`` (counter-clockwise seen from outside).  Formats by
extension: ``.ply`` (binary, with vertex normals), ``.obj``, ``.stl``,
``.gltf``; ``.glb`` written by open3d 0.20 cannot be read back by open3d
itself, so ``.glb`` is not offered here (see
``pipeline/export.py`` for the verified GLB path when it exists).
"""

from __future__ import annotations

import os
import struct
from pathlib import Path

import numpy as np

from pipeline.atomic import atomic_file
from pipeline.errors import InputError
from surface.validate import TOL

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

    Before anything is allocated the file must be a regular file
    (:func:`pipeline.guards.regular_file`) whose element counts
    (:func:`check_header_counts`: the PLY/OFF/STL header, the glTF accessors, the
    lines of an OBJ or ASCII STL) fit the file's size and :mod:`pipeline.limits`
    (``file.elements``): a header claiming 10^9 vertices is refused at once.  A
    binary PLY of triangles is read here with numpy (:func:`_read_binary_ply`: no
    open3d import, so its coordinates are checked within the interpreter's
    start-up); other files through open3d, whose own lines on fd 2 (RPly,
    tinyobj) are captured.

    Raises
    ------
    FileNotFoundError, InputError
        Missing file, unknown format, a file with no triangles, indices past the
        vertices, non-finite or too large coordinates.
    """
    vertices, triangles, _ = _read_checked(path, want_normals=False)
    return vertices, triangles


def _read_checked(path: str | os.PathLike, want_normals: bool
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    from pipeline.guards import check_coordinates, native_stderr, regular_file

    path = regular_file(path, "mesh file")
    suffix = path.suffix.lower()
    if suffix not in MESH_SUFFIXES + (".glb",):
        raise InputError(f"{path}: unknown mesh format {path.suffix!r} "
                         f"(expected one of {', '.join(MESH_SUFFIXES)})")
    claimed = check_header_counts(path)
    read = _read_binary_ply(path) if suffix == ".ply" else None
    if read is None:
        import open3d as o3d

        with native_stderr(), o3d.utility.VerbosityContextManager(
                o3d.utility.VerbosityLevel.Error):
            mesh = o3d.io.read_triangle_mesh(str(path))
        vertices = np.asarray(mesh.vertices, dtype=np.float64)
        normals = (np.asarray(mesh.vertex_normals, dtype=np.float64)
                   if want_normals and suffix != ".stl" and mesh.has_vertex_normals()
                   and len(mesh.vertex_normals) == len(vertices) else None)
        read = vertices, np.asarray(mesh.triangles, dtype=np.int64), normals
    vertices, triangles, normals = read
    if len(triangles) == 0:
        raise InputError(f"{path}: no triangles could be read")
    if suffix in (".ply", ".off"):  # each face is one triangle at least (polygons: more)
        for name, held in (("vertices", len(vertices)), ("faces", len(triangles))):
            if held < claimed.get(name, 0):
                raise InputError(f"{path}: the header claims {claimed[name]} {name} but the "
                                 f"file holds {held}: truncated or not what it says")
    if not np.all(np.isfinite(vertices)):
        raise InputError(f"{path}: vertices contain NaN/inf")
    check_coordinates(vertices, str(path), "vertex coordinates")
    if triangles.min() < 0 or triangles.max() >= len(vertices):
        raise InputError(f"{path}: face indices run past the {len(vertices)} vertices "
                         f"({int(triangles.min())}..{int(triangles.max())})")
    if normals is not None and not np.all(np.isfinite(normals)):
        normals = None
    return vertices, triangles, normals


#: Bytes of one value of each PLY scalar type.
_PLY_SIZES = {"char": 1, "int8": 1, "uchar": 1, "uint8": 1, "short": 2, "int16": 2,
              "ushort": 2, "uint16": 2, "int": 4, "int32": 4, "uint": 4, "uint32": 4,
              "float": 4, "float32": 4, "double": 8, "float64": 8}
#: numpy kinds of the PLY scalar types (the byte order is the file's).
PLY_KINDS = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2",
              "int16": "i2", "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4",
              "uint": "u4", "uint32": "u4", "float": "f4", "float32": "f4", "double": "f8",
              "float64": "f8"}


def ply_header(head: bytes) -> tuple[str, list[list], int] | None:
    """``(format, [[element, count, [property words ...]], ...], header bytes)`` or ``None``
    when ``head`` holds no complete header."""
    end = head.find(b"end_header")
    if not head.startswith(b"ply") or end < 0:
        return None
    stop = head.find(b"\n", end)
    stop = len(head) if stop < 0 else stop + 1
    fmt, elements = "ascii", []
    for line in head[:stop].decode("ascii", "replace").splitlines():
        words = line.split()
        if len(words) >= 2 and words[0] == "format":
            fmt = words[1]
        elif words and words[0] == "element":
            elements.append([words[1] if len(words) > 1 else "", words[2:3], []])
        elif words and words[0] == "property" and elements:
            elements[-1][2].append(words[1:])
    return fmt, elements, stop


def ply_count(path, name: str, count_words: list) -> int:
    """The element count of a header line ``element NAME COUNT`` (one-line errors)."""
    try:
        count = int(count_words[0])
    except (IndexError, ValueError):
        raise InputError(f"{path}: bad PLY line 'element {name} "
                         f"{' '.join(count_words)}'") from None
    if count < 0:
        raise InputError(f"{path}: negative {name} count {count}")
    return count


def _ply_counts(path: Path, head: bytes) -> tuple[str, list[tuple[str, int, int]], int]:
    """``(format, [(element, count, least bytes per element)], header bytes)`` of a PLY."""
    parsed = ply_header(head)
    if parsed is None:
        return "", [], len(head)  # no header to check: the reader refuses the file
    fmt, elements, stop = parsed
    counts = []
    for name, count_words, properties in elements:
        count = ply_count(path, name, count_words)
        least = 0
        for words in properties:
            if fmt == "ascii":
                least += 2  # a digit and a separator at least
            elif len(words) >= 2 and words[0] == "list":
                least += _PLY_SIZES.get(words[1], 1)  # the list's length, at least
            else:
                least += _PLY_SIZES.get(words[0] if words else "", 1)
        counts.append((name, count, least))
    return fmt, counts, stop


def _read_binary_ply(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray | None] | None:
    """A binary PLY of ``vertex`` (scalar properties with x, y, z) then ``face`` (one
    list of 3 indices each) read with numpy structured arrays; ``None`` for any other
    layout (ASCII, polygons, other elements first: open3d reads those).

    Returns
    -------
    vertices : (V, 3) float64
    triangles : (F, 3) int64
    normals : (V, 3) float64 or None
        ``nx ny nz`` when the file has them.
    """
    with open(path, "rb") as fh:
        head = fh.read(65536)
    parsed = ply_header(head)
    if parsed is None:
        return None
    fmt, elements, stop = parsed
    order = {"binary_little_endian": "<", "binary_big_endian": ">"}.get(fmt)
    if order is None or [e[0] for e in elements[:2]] != ["vertex", "face"]:
        return None
    (_, (n_vertices,), vertex_props), (_, (n_faces,), face_props) = elements[:2]
    if any(len(w) != 2 or w[0] not in PLY_KINDS for w in vertex_props) or \
            len(face_props) != 1 or len(face_props[0]) != 4 or face_props[0][0] != "list" or \
            face_props[0][1] not in PLY_KINDS or face_props[0][2] not in PLY_KINDS:
        return None
    vertex_type = np.dtype([(w[1], order + PLY_KINDS[w[0]]) for w in vertex_props])
    names = set(vertex_type.names)
    if not {"x", "y", "z"} <= names or len(names) != len(vertex_props):
        return None
    face_type = np.dtype([("n", order + PLY_KINDS[face_props[0][1]]),
                          ("v", order + PLY_KINDS[face_props[0][2]], (3,))])
    n_vertices, n_faces = int(n_vertices), int(n_faces)  # checked by check_header_counts
    with open(path, "rb") as fh:
        fh.seek(stop)
        vertex_data = np.fromfile(fh, dtype=vertex_type, count=n_vertices)
        if len(vertex_data) < n_vertices:
            raise InputError(f"{path}: truncated PLY: {len(vertex_data)} of {n_vertices} "
                             "vertices")
        # a polygon (count != 3) would misalign every later face: read the counts first
        face_data = np.fromfile(fh, dtype=face_type, count=n_faces)
    if len(face_data) < n_faces and np.all(face_data["n"] == 3):
        raise InputError(f"{path}: the header claims {n_faces} faces but the file holds "
                         f"{len(face_data)}: truncated or not what it says")
    if np.any(face_data["n"] != 3):
        return None  # polygons: open3d's reader decides
    vertices = np.column_stack([vertex_data[c] for c in "xyz"]).astype(np.float64)
    normals = (np.column_stack([vertex_data[c] for c in ("nx", "ny", "nz")])
               .astype(np.float64) if {"nx", "ny", "nz"} <= names else None)
    return vertices, face_data["v"].astype(np.int64), normals


#: Least bytes of one element of the text formats: an OBJ line "v 0 0 0\n" or "f 1 2 3\n"
#: (8), an ASCII STL facet "facet normal 0 0 0 outer loop vertex 0 0 0 (x3) endloop
#: endfacet" with single separators (80).
_OBJ_LEAST, _ASCII_STL_LEAST = 8, 80
#: A glTF JSON document (a .gltf file, the JSON chunk of a .glb) larger than this is refused.
MAX_GLTF_JSON_BYTES = 64 << 20


def _gltf_document(path: Path, head: bytes, size: int) -> tuple[dict, int]:
    """The JSON document of a .gltf/.glb and the bytes its binary buffer 0 really holds
    (GLB: the BIN chunk; .gltf: its first buffer's file or data URI)."""
    import json

    blob = 0
    if path.suffix.lower() == ".glb":
        if len(head) < 20 or head[:4] != b"glTF":
            raise InputError(f"{path}: not a binary glTF (no 'glTF' magic)")
        json_len = struct.unpack_from("<I", head, 12)[0]
        if 20 + json_len > size or json_len > MAX_GLTF_JSON_BYTES:
            raise InputError(f"{path}: the GLB JSON chunk claims {json_len} bytes, the file "
                             f"holds {size}")
        with open(path, "rb") as fh:
            fh.seek(20)
            text = fh.read(json_len)
            bin_head = fh.read(8)
        if len(bin_head) == 8:
            blob = min(struct.unpack("<I", bin_head[:4])[0], size - 28 - json_len)
    else:
        if size > MAX_GLTF_JSON_BYTES:
            raise InputError(f"{path}: {size} bytes is too large for a glTF JSON file "
                             f"(at most {MAX_GLTF_JSON_BYTES})")
        text = path.read_bytes()
    try:
        document = json.loads(text)
    except (ValueError, RecursionError) as exc:
        raise InputError(f"{path}: the glTF JSON does not parse "
                         f"({type(exc).__name__})") from None
    if not isinstance(document, dict):
        raise InputError(f"{path}: the glTF JSON is not an object")
    buffers = document.get("buffers")
    if isinstance(buffers, list) and buffers and isinstance(buffers[0], dict) and \
            "uri" in buffers[0]:  # an external or data-URI buffer (a GLB's may be one too)
        blob = 0
        uri = buffers[0].get("uri", "")
        if isinstance(uri, str) and uri.startswith("data:"):
            blob = (len(uri) - uri.find(",") - 1) * 3 // 4  # base64: 3 bytes per 4 chars
        elif isinstance(uri, str) and (path.parent / uri).is_file():
            blob = (path.parent / uri).stat().st_size
    return document, blob


#: Bytes of one component of each glTF componentType, and components per accessor type.
_GLTF_COMPONENT = {5120: 1, 5121: 1, 5122: 2, 5123: 2, 5125: 4, 5126: 4}
_GLTF_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}


def _gltf_counts(path: Path, head: bytes, size: int) -> list[tuple[str, int, int]]:
    """Vertices and triangles the mesh primitives' accessors claim (glTF 2.0 section 3.6),
    each accessor's bytes checked against what the buffer really holds."""
    document, blob = _gltf_document(path, head, size)
    accessors, views = document.get("accessors", []), document.get("bufferViews", [])
    if not isinstance(accessors, list) or not isinstance(views, list):
        raise InputError(f"{path}: glTF accessors / bufferViews are not lists")

    def claimed(index) -> int:
        if not isinstance(index, int) or not 0 <= index < len(accessors) or \
                not isinstance(accessors[index], dict):
            raise InputError(f"{path}: glTF accessor {index!r} does not exist")
        accessor = accessors[index]
        count = accessor.get("count")
        if not isinstance(count, int) or count < 0:
            raise InputError(f"{path}: glTF accessor {index}: count {count!r} is not a "
                             "whole number >= 0")
        view = accessor.get("bufferView")
        if isinstance(view, int) and 0 <= view < len(views) and isinstance(views[view], dict):
            need = count * _GLTF_COMPONENT.get(accessor.get("componentType"), 1) * \
                _GLTF_WIDTH.get(accessor.get("type"), 1)
            length = views[view].get("byteLength", 0)
            hold = min(length if isinstance(length, int) else 0, blob) \
                if views[view].get("buffer", 0) == 0 else length
            if isinstance(hold, int) and need > hold:
                raise InputError(f"{path}: glTF accessor {index} claims {count} elements "
                                 f"({need} bytes) but its buffer holds {hold} bytes: "
                                 "truncated or not what it says")
        return count

    vertices = triangles = 0
    meshes = document.get("meshes", [])
    for mesh in meshes if isinstance(meshes, list) else []:
        primitives = mesh.get("primitives", []) if isinstance(mesh, dict) else []
        for prim in primitives if isinstance(primitives, list) else []:
            attributes = prim.get("attributes", {}) if isinstance(prim, dict) else {}
            if not isinstance(attributes, dict) or "POSITION" not in attributes:
                continue
            n = claimed(attributes["POSITION"])
            vertices += n
            triangles += claimed(prim["indices"]) // 3 if "indices" in prim else n // 3
    return [("vertex", vertices, 0), ("triangle", triangles, 0)]


def check_header_counts(path: str | os.PathLike) -> dict[str, int]:
    """Refuse a mesh or cloud file whose element counts the file cannot hold, or past the
    ``file.elements`` limit -- before any reader allocates them.

    The counts are what the file says or implies: the PLY, OFF and binary STL headers;
    the glTF/GLB accessors of the mesh primitives (each accessor's bytes must fit its
    buffer); the ``v``/``f`` lines of an OBJ and the facets of an ASCII STL, counted in
    a bounded-memory pass that stops once the limit is passed.  In a header, each
    element needs at least a fixed number of bytes (binary: the sizes of its properties;
    text: a digit and a separator per value), so ``count x least bytes <= file size``
    must hold.

    Returns
    -------
    dict
        ``{"vertices": V, "faces": F}`` as far as the file says (faces of a PLY/OFF/OBJ
        may be polygons: each is at least one triangle).
    """
    from pipeline import limits
    from pipeline.guards import count_occurrences

    path = Path(path)
    suffix = path.suffix.lower()
    size = path.stat().st_size
    with open(path, "rb") as fh:
        head = fh.read(65536)
    counts: list[tuple[str, int, int]] = []
    body = size
    if suffix == ".ply":
        if not head.startswith(b"ply"):
            return {}  # not a PLY header: the reader refuses the file
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
    elif suffix == ".stl" and size >= 84 and (not head[:80].lstrip().startswith(b"solid")
                                              or b"facet" not in head[:4096]):
        # binary (some exporters start the 80-byte header with "solid" too: an ASCII STL
        # says "facet" within its first lines)
        n_facets = struct.unpack("<I", head[80:84])[0]
        counts = [("facet", n_facets, 50)]
        body = size - 84
    elif suffix == ".stl":  # ASCII: "solid ... facet ... endfacet ... endsolid"
        found = count_occurrences(path, {"facet": (b"endfacet",)},
                                  limits.LIMITS["file.elements"].maximum)
        counts = [("facet", found["facet"], _ASCII_STL_LEAST)]
    elif suffix == ".obj":
        found = count_occurrences(path, {"vertex": (b"\nv ", b"\nv\t"),
                                         "face": (b"\nf ", b"\nf\t")},
                                  limits.LIMITS["file.elements"].maximum)
        counts = [("vertex", found["vertex"], _OBJ_LEAST), ("face", found["face"], _OBJ_LEAST)]
    elif suffix in (".gltf", ".glb"):
        counts = _gltf_counts(path, head, size)
    for element, count, _ in counts:
        limits.check("file.elements", count, where=f"{path}: {element} count {count}")
    needed = sum(count * least for _, count, least in counts)
    if needed > body:
        shown = ", ".join(f"{count} {element}s" for element, count, _ in counts)
        raise InputError(f"{path}: the header claims {shown}, which need at least {needed} "
                         f"bytes, but the file holds {body}: truncated or not what it says")
    canonical = {"vertex": "vertices", "face": "faces", "facet": "faces", "triangle": "faces"}
    return {canonical[e]: c for e, c, _ in counts if e in canonical}


def _write_ply_to(tmp: Path, vertices, triangles, normals, colors, sigma=None) -> None:
    """Binary little-endian PLY: double x y z [float nx ny nz] [uchar rgb] [float sigma],
    int vertex_indices.

    Positions stay float64 (georeferenced coordinates need every bit); unit normals are
    float32: 6e-8 rad, and 12 of the 48 bytes a vertex took."""
    fields = [("x", "<f8"), ("y", "<f8"), ("z", "<f8")]
    header = ["ply", "format binary_little_endian 1.0", "comment photosurf mesh",
              f"element vertex {len(vertices)}", "property double x", "property double y",
              "property double z"]
    if normals is not None:
        fields += [("nx", "<f4"), ("ny", "<f4"), ("nz", "<f4")]
        header += ["property float nx", "property float ny", "property float nz"]
    if colors is not None:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
        header += ["property uchar red", "property uchar green", "property uchar blue"]
    if sigma is not None:  # 1 sigma along the normal, scene units
        fields += [("sigma", "<f4")]
        header += ["property float sigma"]
    header += [f"element face {len(triangles)}", "property list uchar int vertex_indices",
               "end_header"]
    data = np.empty(len(vertices), dtype=np.dtype(fields))
    data["x"], data["y"], data["z"] = np.asarray(vertices, dtype=np.float64).T
    if normals is not None:
        data["nx"], data["ny"], data["nz"] = np.asarray(normals, dtype=np.float32).T
    if colors is not None:
        c = np.asarray(colors)
        c = c if c.dtype == np.uint8 else np.clip(np.rint(c * 255), 0, 255).astype(np.uint8)
        data["red"], data["green"], data["blue"] = c.T
    if sigma is not None:
        data["sigma"] = np.asarray(sigma, dtype=np.float32).reshape(-1)
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


def vertex_normals(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals.

    Parameters
    ----------
    vertices : (V, 3) float64
    triangles : (F, 3) int64, counter-clockwise seen from outside

    Returns
    -------
    normals : (V, 3) float64
        Unit normals; a vertex used by no triangle (or only by degenerate
        ones) gets ``(0, 0, 1)`` so that no writer ever sees a NaN.
    """
    corners = vertices[triangles]  # (F, 3, 3)
    face = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])  # 2·area·n
    normals = np.zeros_like(vertices)
    for c in range(3):
        np.add.at(normals, triangles[:, c], face)
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    scale = float(np.abs(vertices).max()) if len(vertices) else 1.0
    empty = length[:, 0] <= TOL.zero * max(scale, 1.0) ** 2  # |Σ 2·area·n| ~ size²
    normals[~empty] /= length[~empty]
    normals[empty] = (0.0, 0.0, 1.0)
    return normals


def write_mesh_to(tmp: str | os.PathLike, suffix: str, vertices, triangles, normals=None,
                  colors=None, sigma=None) -> None:
    """Write a mesh to ``tmp`` (not atomic: for a temporary the caller renames).

    ``sigma`` (V,), optional: each vertex's 1σ along its normal, a ``float sigma``
    vertex property of a PLY (other formats have no place for it).

    PLY, STL, OFF and OBJ are written here with Python's own ``write``, so a
    full disk or an I/O error is an ``OSError``; glTF goes through open3d,
    whose return value and fd-2 lines are checked (a line holding "fail" or
    "error" is a failed write).
    """
    tmp = Path(tmp)
    if suffix == ".ply":
        _write_ply_to(tmp, vertices, triangles, normals, colors, sigma)
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
        normals = vertex_normals(vertices, triangles)
    with atomic_file(path) as tmp:
        write_mesh_to(tmp, suffix, vertices, triangles,
                      None if suffix in (".stl", ".off") else normals, colors)
    return path


def read_mesh_with_normals(path: str | os.PathLike
                           ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """:func:`read_mesh` plus the file's vertex normals, if it stores any.

    Returns
    -------
    vertices : (V, 3) float64
    triangles : (F, 3) int64
    normals : (V, 3) float64 or None
        Vertex normals as stored (PLY, OBJ, glTF, GLB), ``None`` when the file has
        none or any is not finite (STL stores facet normals only, so ``None``).
    """
    return _read_checked(path, want_normals=True)


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
