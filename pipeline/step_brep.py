r"""The smooth surface as an OpenCascade B-rep: one face per patch, and reading CAD back.

Each sextic triangular patch of Loop's surface (``surface.bezier``) is one degree
(6, 6) tensor-product Bézier face, degenerate at the patch's corner 0: over the unit
square, the barycentric map (Duffy's)

    (r, s, t) = (1 - u, u (1 - v), u v)

turns the patch's Bernstein polynomial into one of degree 6 in u and in v
(r^i s^j t^k = (1-u)^i u^(j+k) (1-v)^j v^k, i + j + k = 6), so the face is
exact: its pole row ``u = m / 6`` is the row ``i = 6 - m`` of the triangular
net, a curve of degree m in v, degree-elevated to 6 (:func:`degenerate_nets`;
Farin, *Curves and Surfaces for CAGD*, 5th ed., §§17-18: the tensor-product
form of a triangular patch, and degree elevation).  The side ``u = 0`` collapses
to corner 0; the other three sides are the patch's edges, whose poles are the
triangular net's 7 edge control points, exactly, so neighbouring faces share
their edge curves bit for bit (one face a patch: a third of the faces of a centroid
split, ``surface.bezier.tensor_product_nets``).  :func:`shell_topology` names the
shared edges; :func:`solid_from_nets` assembles the ``TopoDS`` shell by topology, not
by sewing: every vertex and edge is made once and shared by the faces that meet there.

OpenCascade's own writers (the shape transfer to STEP for an open shell, IGES in BRep
mode) and readers (:func:`read_cad_solid`) are here too; the STEP text photosurf writes
itself is ``pipeline.step_text``'s, and ``pipeline.cad_export.write_cad`` chooses between them.

References: C. Loop, "Smooth spline surfaces over irregular meshes", SIGGRAPH 1994;
G. Farin, "Curves and Surfaces for CAGD", 5th ed. (2002); M. G. Duffy, SIAM J. Numer.
Anal. 19 (1982): the collapsed square.
"""

from __future__ import annotations

import gc
import os
from fractions import Fraction
from functools import cache
from math import comb
from pathlib import Path

import numpy as np

from pipeline.errors import InputError

__all__ = ["REL_TOLERANCE", "degenerate_nets", "read_cad_solid", "shell_topology",
           "solid_from_nets"]

#: Relative tolerance of vertices and edges (times the surface's size): far above the
#: rounding between a face's boundary row and its shared edge curve (~1e-16), far
#: below any modelling scale.
REL_TOLERANCE = 1e-9
_DEGREE = 6


@cache
def _degenerate_matrix() -> np.ndarray:
    """``(49, 28)`` map from a sextic triangular net to its degenerate (6, 6) net.

    Row ``7 m + l`` is the pole of u-index m and v-index l: the degree-m curve
    with poles ``b[6 - m, m - k, k]`` (k = 0..m) elevated to degree 6,
    ``P[m, l] = sum_k C(m, k) C(6 - m, l - k) / C(6, l) b[6 - m, m - k, k]``;
    the weights are rationals rounded once, so the boundary rows (m = 6, l = 0,
    l = 6), whose weights are 0 and 1, copy the edge control points exactly.
    """
    from surface.bezier import N_CONTROL, control_index

    n = _DEGREE
    out = np.zeros((n + 1, n + 1, N_CONTROL))
    for m in range(n + 1):
        for l in range(n + 1):
            for k in range(max(0, l - (n - m)), min(m, l) + 1):
                weight = Fraction(comb(m, k) * comb(n - m, l - k), comb(n, l))
                out[m, l, control_index(n - m, m - k, k)] = float(weight)
    out = out.reshape((n + 1) ** 2, N_CONTROL)
    out.flags.writeable = False
    return out


def degenerate_nets(control_points: np.ndarray) -> np.ndarray:
    """Each sextic triangular patch as one degree (6, 6) tensor-product Bézier net.

    Parameters
    ----------
    control_points : (P, 28, 3) float64
        ``surface.bezier`` index order.

    Returns
    -------
    (P, 7, 7, 3) float64
        ``out[p, m, l]`` is pole (m, l): the net evaluated at (u, v) is patch p
        at barycentric ``(1 - u, u (1 - v), u v)``.  Row m = 0 is corner 0 seven
        times; column l = 0 runs along edge 0 -> 1, row m = 6 along edge 1 -> 2,
        column l = 6 along edge 0 -> 2; ``dS/du x dS/dv`` points the way the
        triangle's normal does (u > 0).
    """
    cp = np.asarray(control_points, dtype=np.float64)
    return np.matmul(_degenerate_matrix(), cp).reshape(-1, 7, 7, 3)


def shell_topology(triangles: np.ndarray) -> dict:
    """Shared edges of the one-face-per-patch shell.

    Face p's sides, counter-clockwise in its ``(u, v)`` square: 0 ``v = 0``
    (corner 0 -> 1, u increasing), 1 ``u = 1`` (corner 1 -> 2, v increasing),
    2 ``v = 1`` (corner 0 -> 2, u increasing), 3 ``u = 0`` (degenerate, corner 0).
    An edge's curve runs from its lower to its higher vertex id.

    Parameters
    ----------
    triangles : (P, 3) int64
        Domain triangles of the patches (closed 2-manifold for a closed shell).

    Returns
    -------
    dict
        ``edge (P, 3) int64`` edge id of sides 0-2; ``same (P, 3) bool``: the side
        runs (in increasing u or v) the way its edge's curve does; ``start, end
        (E,)`` vertex ids of each edge's curve; ``owner (E, 2)``: the face and side
        whose boundary row defines the edge's curve; ``n_vertices``; ``closed``:
        every edge is shared by two patches.
    """
    from surface.bezier import _edge_ids

    tris = np.asarray(triangles, dtype=np.int64)
    half_edge, n_edges, forward = _edge_ids(tris)  # (P, 3): edge c -> c + 1, lower -> higher
    edge = half_edge  # sides 0, 1, 2 lie on half-edges 0, 1, 2
    # sides 0 and 1 run along their half-edge, side 2 (corner 0 -> 2) against half-edge 2
    same = np.stack([forward[:, 0], forward[:, 1], ~forward[:, 2]], axis=1)
    flat = edge.ravel()
    owner_slot = np.full(n_edges, -1, dtype=np.int64)
    owner_slot[flat[::-1]] = np.arange(len(flat))[::-1]  # first side naming each edge
    a = tris[:, [0, 1, 0]].ravel()[owner_slot]
    b = tris[:, [1, 2, 2]].ravel()[owner_slot]
    start, end = np.minimum(a, b), np.maximum(a, b)
    counts = np.bincount(flat, minlength=n_edges)
    if np.any(counts > 2):
        raise ValueError("triangles: an edge is shared by more than two patches")
    return {"edge": edge, "same": same, "start": start, "end": end,
            "owner": np.stack([owner_slot // 3, owner_slot % 3], axis=1),
            "n_vertices": int(tris.max()) + 1, "closed": bool(np.all(counts == 2))}


#: Pole rows of each side of a face, ``(4, 7)`` flat indices ``7 m + l`` in increasing u or v.
_SIDE_POLES = np.array([
    [7 * m for m in range(7)],  # v = 0 (l = 0), u increasing
    [42 + l for l in range(7)],  # u = 1 (m = 6), v increasing
    [7 * m + 6 for m in range(7)],  # v = 1 (l = 6), u increasing
    [l for l in range(7)],  # u = 0 (m = 0), v increasing: the apex
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
    TopoDS_Solid or TopoDS_Shell
        P faces (one degree (6, 6) Bézier surface each, degenerate at the
        triangle's corner 0), every edge shared by exactly two faces; a domain
        with a border gives the open shell of its faces instead (written as a
        surface model).

    Notes
    -----
    The OpenCascade objects are made one by one from Python (the kernel has
    no bulk constructor): about 0.2 ms of CPU per face, with the cyclic garbage
    collector paused (the wrappers hold no cycles; it scanned the ~10^5 of them
    again and again, +20 %).
    """
    from OCP.BRep import BRep_Builder
    from OCP.TopoDS import TopoDS_Shell, TopoDS_Solid

    poles = degenerate_nets(control_points).reshape(-1, 49, 3)  # (P, 49, 3)
    topo = shell_topology(triangles)
    size = float(np.ptp(poles.reshape(-1, 3), axis=0).max()) or 1.0
    tol = REL_TOLERANCE * size
    builder = BRep_Builder()
    tris = np.asarray(triangles, dtype=np.int64)
    corners = np.empty((topo["n_vertices"], 3))
    corners[tris.ravel()] = poles[:, [0, 42, 48]].reshape(-1, 3)  # corners 0, 1, 2
    owner = topo["owner"]
    edge_poles = poles[owner[:, 0][:, None], _SIDE_POLES[owner[:, 1]]]  # (E, 7, 3)
    owner_same = topo["same"][owner[:, 0], owner[:, 1]]
    edge_poles = np.where(owner_same[:, None, None], edge_poles, edge_poles[:, ::-1])
    shell = TopoDS_Shell()
    builder.MakeShell(shell)
    collecting = gc.isenabled()
    gc.disable()
    try:
        vertices = _make_vertices(builder, corners, tol)
        edges = _make_edges(builder, edge_poles, topo["start"], topo["end"], vertices, tol)
        _add_faces(builder, shell, poles, topo, tris[:, 0], vertices, edges, tol)
    finally:
        if collecting:
            gc.enable()
    if not topo["closed"]:
        return shell
    shell.Closed(True)
    if _signed_volume(control_points, triangles) < 0:  # domain triangles clockwise: turn over
        shell.Reverse()
    solid = TopoDS_Solid()
    builder.MakeSolid(solid)
    builder.Add(solid, shell)
    return solid


def _make_vertices(builder, points: np.ndarray, tol: float) -> list:
    from OCP.gp import gp_Pnt
    from OCP.TopoDS import TopoDS_Vertex

    vertices = []
    for x, y, z in points.tolist():
        vertex = TopoDS_Vertex()
        builder.MakeVertex(vertex, gp_Pnt(x, y, z), tol)
        vertices.append(vertex)
    return vertices


def _make_edges(builder, edge_poles: np.ndarray, start: np.ndarray, end: np.ndarray,
                vertices: list, tol: float) -> list:
    """One sextic Bézier edge per domain edge, ``edge_poles (E, 7, 3)`` from ``start``
    to ``end``, parameter range [0, 1]."""
    from OCP.collections import Array1_gp_Pnt
    from OCP.Geom import Geom_BezierCurve
    from OCP.gp import gp_Pnt
    from OCP.TopAbs import TopAbs_FORWARD, TopAbs_REVERSED
    from OCP.TopoDS import TopoDS_Edge

    edges = []
    for rows, a, b in zip(edge_poles.tolist(), start.tolist(), end.tolist(), strict=True):
        array = Array1_gp_Pnt(1, 7)
        for i, (x, y, z) in enumerate(rows, start=1):
            array.SetValue(i, gp_Pnt(x, y, z))
        edge = TopoDS_Edge()
        builder.MakeEdge(edge, Geom_BezierCurve(array), tol)
        builder.Add(edge, vertices[a].Oriented(TopAbs_FORWARD))
        builder.Add(edge, vertices[b].Oriented(TopAbs_REVERSED))
        builder.Range(edge, 0.0, 1.0)
        edges.append(edge)
    return edges


def _add_faces(builder, shell, poles: np.ndarray, topo: dict, apex: np.ndarray,
               vertices: list, edges: list, tol: float) -> None:
    """One face per patch: its Bézier surface, its three shared edges and its
    degenerated side, wired counter-clockwise in (u, v)."""
    from OCP.collections import Array2_gp_Pnt
    from OCP.Geom import Geom_BezierSurface
    from OCP.Geom2d import Geom2d_Line
    from OCP.gp import gp_Dir2d, gp_Pnt, gp_Pnt2d
    from OCP.TopAbs import TopAbs_FORWARD, TopAbs_REVERSED
    from OCP.TopoDS import TopoDS_Edge, TopoDS_Face, TopoDS_Wire

    lines = [[Geom2d_Line(gp_Pnt2d(*origin), gp_Dir2d(*direction)) for origin, direction in
              _SIDE_LINES],
             [Geom2d_Line(gp_Pnt2d(origin[0] + direction[0], origin[1] + direction[1]),
                          gp_Dir2d(-direction[0], -direction[1]))
              for origin, direction in _SIDE_LINES]]  # t -> side point at 1 - t
    forward, reversed_ = TopAbs_FORWARD, TopAbs_REVERSED
    grid_index = [(m // 7 + 1, m % 7 + 1) for m in range(49)]
    for face_poles, sides, same, corner in zip(poles.tolist(), topo["edge"].tolist(),
                                               topo["same"].tolist(), apex.tolist(),
                                               strict=True):
        grid = Array2_gp_Pnt(1, 7, 1, 7)
        for (row, col), (x, y, z) in zip(grid_index, face_poles, strict=True):
            grid.SetValue(row, col, gp_Pnt(x, y, z))
        face = TopoDS_Face()
        builder.MakeFace(face, Geom_BezierSurface(grid), tol)
        wire = TopoDS_Wire()
        builder.MakeWire(wire)
        for side, backwards in _WIRE[:3]:
            edge = edges[sides[side]]
            # the pcurve follows the edge's own parameter: along the side, or against it
            builder.UpdateEdge(edge, lines[0 if same[side] else 1][side], face, tol)
            builder.Add(wire, edge.Oriented(forward if same[side] != backwards else reversed_))
        collapsed = TopoDS_Edge()  # side u = 0: corner 0, walked from v = 1 to v = 0
        builder.MakeEdge(collapsed)
        builder.Degenerated(collapsed, True)
        builder.Add(collapsed, vertices[corner].Oriented(forward))
        builder.Add(collapsed, vertices[corner].Oriented(reversed_))
        builder.UpdateEdge(collapsed, lines[0][3], face, tol)
        builder.Range(collapsed, 0.0, 1.0)
        builder.Add(wire, collapsed.Oriented(reversed_))
        builder.Add(face, wire)
        builder.Add(shell, face)


def _signed_volume(control_points: np.ndarray, triangles: np.ndarray) -> float:
    """Volume enclosed by the patches' corner triangles (divergence theorem): the
    polyhedron inscribed in the surface at its patch corners, whose sign tells whether
    the faces point outward (ShapeFix_Solid finds the same at ~2 ms a face)."""
    from surface.bezier import control_index

    cp = np.asarray(control_points)
    a, b, c = (cp[:, control_index(*corner)] for corner in ((6, 0, 0), (0, 6, 0), (0, 0, 6)))
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)



def _quiet() -> None:
    """Silence OpenCascade's default messenger (the writers print transfer statistics to
    stdout, which is the CLI's)."""
    from OCP.Message import Message, Message_PrinterOStream

    Message.DefaultMessenger_s().RemovePrinters(Message_PrinterOStream.get_type_descriptor_s())


def _step_settings() -> None:
    from OCP.Interface import Interface_Static

    Interface_Static.SetCVal_s("write.step.schema", "AP214IS")
    Interface_Static.SetCVal_s("write.step.product.name", "photosurf surface")


def _write_step(solid, path: Path) -> bool:
    """``solid`` (or shell) through OpenCascade's shape transfer."""
    from OCP.IFSelect import IFSelect_RetDone
    from OCP.Interface import Interface_Static
    from OCP.STEPControl import STEPControl_AsIs, STEPControl_Writer

    writer = STEPControl_Writer()
    _step_settings()
    Interface_Static.SetIVal_s("write.precision.mode", 0)  # the shape's least tolerance
    # no pcurves: every face is a full Bezier patch whose sides are its iso-lines, which
    # readers rebuild exactly; a quarter fewer entities to write and read
    Interface_Static.SetIVal_s("write.surfacecurve.mode", 0)
    if writer.Transfer(solid, STEPControl_AsIs) != IFSelect_RetDone:
        return False
    # the transfer writes every pole of every surface and edge curve as its own point;
    # merged, a patch has 33 instead of 61: the demo's 34 208 patches 218 -> 138 MB for
    # 19.5 CPU-s of merging against 6.2 saved in writing (benchmarks/export.py), bought
    # for the size; OpenCascade >= 8.0 only
    clean = getattr(writer, "CleanDuplicateEntities", None)
    if clean is not None:
        clean()
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
