r"""STEP (and IGES) export of the exact smooth surface, through OpenCascade.

Each sextic triangular patch of Loop's surface (``surface.bezier``) is split
at its centroid and edge midpoints into three quadrilaterals, each exactly a
non-degenerate degree (6, 6) tensor-product Bézier patch
(``surface.bezier.tensor_product_nets``; Farin, *Curves and Surfaces for CAGD*,
5th ed., §17: a triangular patch reparametrised over a bilinear image of the
square is a tensor-product patch of degree (n, n)).  The faces are assembled
into one closed shell directly, by topology, not by sewing: every vertex
(domain vertex, edge midpoint, patch centroid) and every edge (each half of a
domain edge, each spoke from an edge midpoint to a centroid) is made once and
shared by the faces that meet there, each face carrying a straight pcurve
along its side of the parameter square.  ``BRepBuilderAPI_Sewing`` would find
the same neighbours geometrically, at a cost that grows faster than the face
count (measured: 18 240 faces in 91 s); the shared topology is exact and
linear.  The shell becomes a solid (turned over if the tessellation's signed
volume is negative) written by ``STEPControl_Writer`` (AP214, entities
``B_SPLINE_SURFACE_WITH_KNOTS`` of degree 6 x 6 with Bézier knots,
``ADVANCED_FACE``, ``CLOSED_SHELL``, ``MANIFOLD_SOLID_BREP``) or
``IGESControl_Writer`` (5.3, BRep mode).

Geometry is exact up to float64 rounding: a face's boundary row and the edge
curve it shares with its neighbour differ by rounding only (~1e-16 of the
size), far inside the edges' tolerance.

References
----------
.. [1] ISO 10303-21, "Clear text encoding of the exchange structure" (STEP),
   and ISO 10303-214 (automotive design, AP214).
.. [2] C. Loop, "Smooth spline surfaces over irregular meshes", SIGGRAPH 1994.
.. [3] G. Farin, "Curves and Surfaces for CAGD", 5th ed., Morgan Kaufmann (2002).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from pipeline.atomic import atomic_file
from pipeline.errors import InputError
from surface.validate import check_finite, check_shape

#: Suffixes :func:`write_cad` writes.
CAD_SUFFIXES = (".step", ".stp", ".iges", ".igs")
#: Relative tolerance of vertices and edges (times the surface's size): far above the
#: rounding between a face's boundary row and its shared edge curve (~1e-16), far
#: below any modelling scale.
REL_TOLERANCE = 1e-9

__all__ = ["CAD_SUFFIXES", "read_cad_solid", "shell_topology", "solid_from_nets", "write_cad"]


def shell_topology(triangles: np.ndarray) -> dict:
    """Shared vertices and edges of the three-quadrilateral split of every patch.

    Face ``3 p + c`` is the quadrilateral at corner ``c`` of patch ``p``, with
    sides, counter-clockwise in its ``(u, v)`` square: ``v = 0`` (corner ->
    midpoint of domain edge ``c``, i.e. corner c -> c + 1), ``u = 1`` (that midpoint
    -> centroid), ``v = 1`` (midpoint of edge ``c + 2`` -> centroid), ``u = 0``
    (corner -> midpoint of edge ``c + 2``).

    Parameters
    ----------
    triangles : (P, 3) int64
        Domain triangles of the patches (closed 2-manifold for a closed shell).

    Returns
    -------
    dict
        ``edge (3P, 4) int64`` edge id of each side; ``start (n_edges,)``,
        ``end (n_edges,)`` vertex ids of each edge in the direction of its curve;
        ``same (3P, 4) bool``: the side runs (in increasing u or v) the way its
        edge's curve does; ``owner (n_edges, 2)``: the face and side whose
        boundary row defines the edge's curve; ``n_vertices``; ``vertex_owner
        (n_vertices, 2)``: a face and its pole (k, l) index giving each vertex.
    """
    from surface.bezier import _edge_ids

    tris = np.asarray(triangles, dtype=np.int64)
    n_patches = len(tris)
    n_domain = int(tris.max()) + 1
    edge_id, n_domain_edges, forward = _edge_ids(tris)  # (P, 3): domain edge c -> c + 1
    corner = np.arange(3)
    prev = (corner + 2) % 3
    # vertex ids: domain vertices, then edge midpoints, then centroids
    mid = n_domain + edge_id  # (P, 3)
    centre = n_domain + n_domain_edges + np.arange(n_patches)
    # edge ids: the two halves of each domain edge (half 0 touches its lower vertex), spokes
    low_half = 2 * edge_id + np.where(forward, 0, 1)  # half at corner c of edge c -> c + 1
    high_half = 2 * edge_id + np.where(forward, 1, 0)  # half at corner c + 1
    spoke = 2 * n_domain_edges + 3 * np.arange(n_patches)[:, None] + corner[None, :]
    # sides of face (p, c), each as (edge, start vertex, end vertex) in increasing u or v
    v_corner = tris  # (P, 3)
    sides = [
        (low_half, v_corner, mid),  # v = 0: corner -> mid of edge c
        (spoke, mid, np.repeat(centre[:, None], 3, axis=1)),  # u = 1: mid c -> centre
        (spoke[:, prev], mid[:, prev], np.repeat(centre[:, None], 3, axis=1)),  # v = 1
        (high_half[:, prev], v_corner, mid[:, prev]),  # u = 0: corner -> mid of edge c + 2
    ]
    edge = np.stack([s[0] for s in sides], axis=2).reshape(-1, 4)  # (3P, 4)
    a = np.stack([s[1] for s in sides], axis=2).reshape(-1, 4)
    b = np.stack([s[2] for s in sides], axis=2).reshape(-1, 4)
    n_edges = 2 * n_domain_edges + 3 * n_patches
    flat = edge.ravel()
    owner_slot = np.full(n_edges, -1, dtype=np.int64)
    owner_slot[flat[::-1]] = np.arange(len(flat))[::-1]  # first side naming each edge
    start, end = a.ravel()[owner_slot], b.ravel()[owner_slot]
    same = (a == start[edge]) & (b == end[edge])
    if not np.all(same | ((a == end[edge]) & (b == start[edge]))):
        raise ValueError("triangles: a shared edge joins different vertices on its two sides")
    n_vertices = n_domain + n_domain_edges + n_patches
    # a face and pole giving each vertex: corner (0, 0) of (p, c); mid (6, 0); centre (6, 6)
    vertex_owner = np.empty((n_vertices, 2), dtype=np.int64)
    faces = 3 * np.arange(n_patches)[:, None] + corner[None, :]
    vertex_owner[v_corner.ravel()] = np.stack([faces.ravel(), np.zeros(3 * n_patches, int)], 1)
    vertex_owner[mid.ravel()] = np.stack([faces.ravel(), np.full(3 * n_patches, 6 * 7)], 1)
    vertex_owner[centre] = np.stack([3 * np.arange(n_patches), np.full(n_patches, 48)], 1)
    return {"edge": edge, "start": start, "end": end, "same": same,
            "owner": np.stack([owner_slot // 4, owner_slot % 4], axis=1),
            "n_vertices": n_vertices, "vertex_owner": vertex_owner}


#: Pole rows of each side of a face, ``(4, 7)`` flat indices ``7 k + l`` in increasing u or v.
_SIDE_POLES = np.array([
    [7 * k for k in range(7)],  # v = 0 (l = 0), u increasing
    [42 + l for l in range(7)],  # u = 1 (k = 6), v increasing
    [7 * k + 6 for k in range(7)],  # v = 1 (l = 6), u increasing
    [l for l in range(7)],  # u = 0 (k = 0), v increasing
])
#: Each side's pcurve in the face's (u, v) square: origin and direction of t in [0, 1].
_SIDE_LINES = (((0.0, 0.0), (1.0, 0.0)), ((1.0, 0.0), (0.0, 1.0)),
               ((0.0, 1.0), (1.0, 0.0)), ((0.0, 0.0), (0.0, 1.0)))
#: Sides in the counter-clockwise order of the outer wire, and whether the wire walks
#: each side against increasing u or v.
_WIRE = ((0, False), (1, False), (2, True), (3, True))


def solid_from_nets(control_points: np.ndarray, triangles: np.ndarray):
    """The closed solid bounded by Loop's surface, as an OpenCascade ``TopoDS_Solid``.

    Parameters
    ----------
    control_points : (P, 28, 3) float64
        Sextic triangular nets (``surface.bezier`` index order).
    triangles : (P, 3) int64
        Their domain triangles, a closed, oriented 2-manifold
        (``BezierSurface.domain_mesh[1]``).

    Returns
    -------
    TopoDS_Solid
        3P faces (one degree (6, 6) Bézier surface each), every edge shared by
        exactly two faces.

    Notes
    -----
    The OpenCascade objects are made one by one from Python (the kernel has
    no bulk constructor): about 0.5 ms per face.
    """
    from OCP.BRep import BRep_Builder
    from OCP.collections import Array1_gp_Pnt, Array2_gp_Pnt
    from OCP.Geom import Geom_BezierCurve, Geom_BezierSurface
    from OCP.Geom2d import Geom2d_Line
    from OCP.gp import gp_Dir2d, gp_Pnt, gp_Pnt2d
    from OCP.TopAbs import TopAbs_FORWARD, TopAbs_REVERSED
    from OCP.TopoDS import (
        TopoDS_Edge,
        TopoDS_Face,
        TopoDS_Shell,
        TopoDS_Solid,
        TopoDS_Vertex,
        TopoDS_Wire,
    )

    from surface.bezier import tensor_product_nets

    poles = tensor_product_nets(control_points).reshape(-1, 49, 3)  # (3P, 49, 3)
    topo = shell_topology(triangles)
    size = float(np.ptp(poles.reshape(-1, 3), axis=0).max()) or 1.0
    tol = REL_TOLERANCE * size
    builder = BRep_Builder()
    vertex_xyz = poles[topo["vertex_owner"][:, 0], topo["vertex_owner"][:, 1]].tolist()
    vertices = []
    for x, y, z in vertex_xyz:
        vertex = TopoDS_Vertex()
        builder.MakeVertex(vertex, gp_Pnt(x, y, z), tol)
        vertices.append(vertex)
    owner = topo["owner"]
    edge_poles = poles[owner[:, 0][:, None], _SIDE_POLES[owner[:, 1]]].tolist()  # (E, 7, 3)
    edges = []
    for rows, a, b in zip(edge_poles, topo["start"].tolist(), topo["end"].tolist(), strict=True):
        array = Array1_gp_Pnt(1, 7)
        for i, (x, y, z) in enumerate(rows, start=1):
            array.SetValue(i, gp_Pnt(x, y, z))
        edge = TopoDS_Edge()
        builder.MakeEdge(edge, Geom_BezierCurve(array), tol)
        builder.Add(edge, vertices[a].Oriented(TopAbs_FORWARD))
        builder.Add(edge, vertices[b].Oriented(TopAbs_REVERSED))
        builder.Range(edge, 0.0, 1.0)
        edges.append(edge)
    lines = [[Geom2d_Line(gp_Pnt2d(*origin), gp_Dir2d(*direction)) for origin, direction in
              _SIDE_LINES],
             [Geom2d_Line(gp_Pnt2d(origin[0] + direction[0], origin[1] + direction[1]),
                          gp_Dir2d(-direction[0], -direction[1]))
              for origin, direction in _SIDE_LINES]]  # t -> side point at 1 - t
    shell = TopoDS_Shell()
    builder.MakeShell(shell)
    face_edges, face_same = topo["edge"].tolist(), topo["same"].tolist()
    for face_poles, sides, same in zip(poles.tolist(), face_edges, face_same, strict=True):
        grid = Array2_gp_Pnt(1, 7, 1, 7)
        for m, (x, y, z) in enumerate(face_poles):
            grid.SetValue(m // 7 + 1, m % 7 + 1, gp_Pnt(x, y, z))
        face = TopoDS_Face()
        builder.MakeFace(face, Geom_BezierSurface(grid), tol)
        wire = TopoDS_Wire()
        builder.MakeWire(wire)
        for side, backwards in _WIRE:
            edge = edges[sides[side]]
            # the pcurve follows the edge's own parameter: along the side, or against it
            builder.UpdateEdge(edge, lines[0 if same[side] else 1][side], face, tol)
            along_wire = same[side] != backwards
            builder.Add(wire, edge.Oriented(TopAbs_FORWARD if along_wire else TopAbs_REVERSED))
        builder.Add(face, wire)
        builder.Add(shell, face)
    shell.Closed(True)
    if _signed_volume(control_points, triangles) < 0:  # domain triangles clockwise: turn over
        shell.Reverse()
    solid = TopoDS_Solid()
    builder.MakeSolid(solid)
    builder.Add(solid, shell)
    return solid


def _signed_volume(control_points: np.ndarray, triangles: np.ndarray) -> float:
    """Volume of the surface's level-2 tessellation (divergence theorem): its sign tells
    whether the faces point outward (ShapeFix_Solid finds the same at ~2 ms a face)."""
    from surface.bezier import tessellate

    vertices, tris, _ = tessellate(control_points, 2, triangles)
    a, b, c = (vertices[tris[:, i]] for i in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def write_cad(path: str | os.PathLike, control_points: np.ndarray,
              triangles: np.ndarray) -> Path:
    """Write the exact surface as a closed solid to STEP (``.step``/``.stp``) or IGES.

    Parameters
    ----------
    path : path-like
        Suffix one of :data:`CAD_SUFFIXES`; written atomically.
    control_points : (P, 28, 3) float64
    triangles : (P, 3) int64
        Closed, oriented domain mesh of the patches.

    Returns
    -------
    Path

    Raises
    ------
    InputError
        Unknown suffix, or OpenCascade refused to write.
    ValueError
        Malformed arrays.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in CAD_SUFFIXES:
        raise InputError(f"{path}: cannot write CAD format {suffix!r} "
                         f"(choose one of {', '.join(CAD_SUFFIXES)})")
    cp = check_shape(control_points, "(P, 28, 3)", "control_points", dtype=np.float64)
    check_finite(cp, "control_points")
    tris = check_shape(triangles, "(P, 3)", "triangles", dtype=np.int64)
    if len(tris) != len(cp) or len(tris) == 0:
        raise ValueError(f"triangles must have one row per patch ({len(cp)}), got {len(tris)}")
    _quiet()
    solid = solid_from_nets(cp, tris)
    with atomic_file(path) as tmp:
        ok = _write_step(solid, tmp) if suffix in (".step", ".stp") else _write_iges(solid, tmp)
        if not ok:
            raise InputError(f"{path}: OpenCascade could not write the {suffix[1:].upper()} file")
    return path


def _quiet() -> None:
    """Silence OpenCascade's default messenger (the writers print transfer statistics to
    stdout, which is the CLI's)."""
    from OCP.Message import Message, Message_PrinterOStream

    Message.DefaultMessenger_s().RemovePrinters(Message_PrinterOStream.get_type_descriptor_s())


def _write_step(solid, path: Path) -> bool:
    from OCP.IFSelect import IFSelect_RetDone
    from OCP.Interface import Interface_Static
    from OCP.STEPControl import STEPControl_AsIs, STEPControl_Writer

    writer = STEPControl_Writer()
    Interface_Static.SetCVal_s("write.step.schema", "AP214IS")
    Interface_Static.SetCVal_s("write.step.product.name", "photosurf surface")
    # no pcurves: every face is a full Bezier patch whose sides are its iso-lines, which
    # readers rebuild exactly; a quarter fewer entities to write and read
    Interface_Static.SetIVal_s("write.surfacecurve.mode", 0)
    if writer.Transfer(solid, STEPControl_AsIs) != IFSelect_RetDone:
        return False
    return writer.Write(str(path)) == IFSelect_RetDone


def _write_iges(solid, path: Path) -> bool:
    from OCP.IGESControl import IGESControl_Writer

    writer = IGESControl_Writer("MM", 1)  # 1: BRep mode (faces, shells, solids)
    return bool(writer.AddShape(solid)) and bool(writer.Write(str(path)))


def read_cad_solid(path: str | os.PathLike):
    """Read a STEP or IGES file back into one OpenCascade shape (tests, checks).

    Raises
    ------
    FileNotFoundError, InputError
    """
    from OCP.IFSelect import IFSelect_RetDone

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such CAD file")
    _quiet()
    if path.suffix.lower() in (".step", ".stp"):
        from OCP.STEPControl import STEPControl_Reader

        reader = STEPControl_Reader()
    else:
        from OCP.IGESControl import IGESControl_Reader

        reader = IGESControl_Reader()
    if reader.ReadFile(str(path)) != IFSelect_RetDone or reader.TransferRoots() == 0:
        raise InputError(f"{path}: OpenCascade could not read it")
    return reader.OneShape()
