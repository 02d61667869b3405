r"""STEP (and IGES) export of the exact smooth surface, through OpenCascade.

Each sextic triangular patch of Loop's surface (``surface.bezier``) is written
as one degree (6, 6) tensor-product Bézier face, degenerate at the patch's
corner 0: over the unit square, the barycentric map (Duffy's)

    (r, s, t) = (1 - u, u (1 - v), u v)

turns the patch's Bernstein polynomial into one of degree 6 in u and in v
(r^i s^j t^k = (1-u)^i u^(j+k) (1-v)^j v^k, i + j + k = 6), so the face is
exact: its pole row ``u = m / 6`` is the row ``i = 6 - m`` of the triangular
net, a curve of degree m in v, degree-elevated to 6 (:func:`degenerate_nets`;
Farin, *Curves and Surfaces for CAGD*, 5th ed., §§17-18: the tensor-product
form of a triangular patch, and degree elevation).  The side ``u = 0`` collapses
to corner 0; the other three sides are the patch's edges, whose poles are the
triangular net's 7 edge control points, exactly, so neighbouring faces share
their edge curves bit for bit.  One face per patch instead of the three
non-degenerate quadrilaterals of a centroid split (``surface.bezier.
tensor_product_nets``): a third of the faces, no spokes, 49 surface poles a
patch instead of 147 (33 distinct ones once shared with the neighbours).

The faces are assembled into one closed shell by topology, not by sewing:
every vertex (a domain vertex) and every edge (a domain edge) is made once and
shared by the two faces that meet there.  ``BRepBuilderAPI_Sewing`` would find
the same neighbours geometrically, at a cost that grows faster than the face
count (measured: 18 240 faces in 91 s).

STEP (AP214): the entities are made directly with OpenCascade's STEP data
classes (``StepGeom``, ``StepShape``) and written by ``STEPControl_Writer``:
one ``CARTESIAN_POINT`` per distinct pole (a corner per domain vertex, 5 per
domain edge, 25 per face), ``B_SPLINE_SURFACE_WITH_KNOTS`` of degree 6 x 6 and
``B_SPLINE_CURVE_WITH_KNOTS`` of degree 6 with Bézier knots, ``EDGE_CURVE``,
``ADVANCED_FACE`` bounded by its three real edges (the collapsed side has none,
as in OpenCascade's own output; readers restore a degenerated edge),
``CLOSED_SHELL``, ``MANIFOLD_SOLID_BREP``, in the product structure the writer
makes for a template solid.  The shape transfer of the same solid
(``TopoDS`` built by :func:`solid_from_nets`, ``STEPControl_Writer.Transfer``)
writes each pole of each surface and edge curve as its own point (61 a patch)
and needs ``CleanDuplicateEntities`` to share them: twice the time for the
same file (``benchmarks/export.py``); it remains the path of an open shell.
IGES: the ``TopoDS`` solid (faces with straight pcurves, degenerated edges
along ``u = 0``) through ``IGESControl_Writer`` (5.3, BRep mode).

Geometry is exact up to float64 rounding of the degree elevation (~1e-16 of the
size) and the writer's 12-13 significant digits.

References
----------
.. [1] ISO 10303-21, "Clear text encoding of the exchange structure" (STEP),
   and ISO 10303-214 (automotive design, AP214).
.. [2] C. Loop, "Smooth spline surfaces over irregular meshes", SIGGRAPH 1994.
.. [3] G. Farin, "Curves and Surfaces for CAGD", 5th ed., Morgan Kaufmann (2002).
.. [4] M. G. Duffy, "Quadrature over a pyramid or cube of integrands with a
   singularity at a vertex", SIAM J. Numer. Anal. 19 (1982): the collapsed square.
"""

from __future__ import annotations

import gc
import os
from collections import deque
from fractions import Fraction
from functools import cache
from itertools import repeat
from math import comb
from pathlib import Path

import numpy as np

from pipeline.atomic import atomic_file, raise_if_full
from pipeline.errors import InputError
from surface.validate import check_finite, check_shape

#: Suffixes :func:`write_cad` writes.
CAD_SUFFIXES = (".step", ".stp", ".iges", ".igs")
#: Relative tolerance of vertices and edges (times the surface's size): far above the
#: rounding between a face's boundary row and its shared edge curve (~1e-16), far
#: below any modelling scale.
REL_TOLERANCE = 1e-9
_DEGREE = 6

__all__ = ["CAD_SUFFIXES", "degenerate_nets", "read_cad_solid", "shell_topology",
           "solid_from_nets", "write_cad"]


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


def write_cad(path: str | os.PathLike, control_points: np.ndarray,
              triangles: np.ndarray) -> Path:
    """Write the exact surface as a closed solid to STEP (``.step``/``.stp``) or IGES.

    Parameters
    ----------
    path : path-like
        Suffix one of :data:`CAD_SUFFIXES`; written atomically.
    control_points : (P, 28, 3) float64
    triangles : (P, 3) int64
        Oriented domain mesh of the patches: closed, the file holds a closed solid;
        with a border, the open shell of the faces.

    Returns
    -------
    Path

    Raises
    ------
    InputError
        Unknown suffix, or OpenCascade refused to write.
    pipeline.limits.LimitError
        More patches than ``cad.patches`` allows (OpenCascade's model holds ~24 KB a
        patch), unless the limits are lifted.
    ValueError
        Malformed arrays.
    """
    from pipeline import limits

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
    limits.check("cad.patches", len(cp), where=f"{path}: {len(cp)} patches")
    _quiet()
    with atomic_file(path) as tmp:
        if suffix in (".step", ".stp"):
            # the entities directly; an open shell, or a template this OpenCascade
            # structures otherwise (_STEP_ROOTS), through the shape transfer
            ok = _write_step_entities(cp, tris, tmp)
            ok = ok or _write_step(solid_from_nets(cp, tris), tmp)
        else:
            ok = _write_iges(solid_from_nets(cp, tris), tmp)
        if not ok:
            raise_if_full(tmp, path)  # a full disk says so (OpenCascade gives no errno)
            raise InputError(f"{path}: OpenCascade could not write the {suffix[1:].upper()} file")
    return path


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


# --------------------------------------------------------------- STEP entities, directly
def _reversed_nets(control_points: np.ndarray, triangles: np.ndarray):
    """The same surface over the domain turned over: corners 1 and 2 swapped, and with
    them the net's indices j and k."""
    from surface.bezier import control_index, index_table

    table = index_table()
    return (control_points[:, control_index(table[:, 0], table[:, 2], table[:, 1])],
            triangles[:, [0, 2, 1]])


def _pole_ids(triangles: np.ndarray, topo: dict) -> tuple[np.ndarray, int]:
    """``(P, 49)`` id of each pole of each degenerate net among the ``Q`` distinct ones:
    a domain vertex's corner point (ids ``0..V-1``), the 5 inner points of each edge
    curve in its own direction (``V + 5 e + 0..4``), the 25 inner poles of each face."""
    n_patches, n_vertices, n_edges = len(triangles), topo["n_vertices"], len(topo["start"])
    ids = np.empty((n_patches, 7, 7), dtype=np.int64)
    inner = np.arange(1, 6)
    edge, same = topo["edge"], topo["same"]

    def along(side: int) -> np.ndarray:  # (P, 5): the side's inner points, increasing u or v
        position = np.where(same[:, side][:, None], inner[None, :], 6 - inner[None, :])
        return n_vertices + 5 * edge[:, side][:, None] + position - 1

    ids[:, 0, :] = triangles[:, 0][:, None]  # the collapsed side
    ids[:, 6, 0], ids[:, 6, 6] = triangles[:, 1], triangles[:, 2]
    ids[:, 1:6, 0], ids[:, 6, 1:6], ids[:, 1:6, 6] = along(0), along(1), along(2)
    first = n_vertices + 5 * n_edges
    ids[:, 1:6, 1:6] = (first + 25 * np.arange(n_patches))[:, None, None] \
        + np.arange(25).reshape(5, 5)
    return ids.reshape(n_patches, 49), first + 25 * n_patches


def _write_step_entities(control_points: np.ndarray, triangles: np.ndarray,
                         path: Path) -> bool:
    """The closed solid written as STEP entities made directly (``StepGeom``,
    ``StepShape``), every distinct pole one ``CARTESIAN_POINT``, into the product
    structure OpenCascade's writer makes for a template solid; False (nothing written)
    for an open shell or a template structured otherwise, which the shape transfer writes.

    The shape transfer (``STEPControl_Writer.Transfer`` of :func:`solid_from_nets`)
    writes each pole of each surface and edge curve as its own point and needs
    ``CleanDuplicateEntities`` to share them: on the demo's 34 208 patches 38.2
    CPU-s against 21.0 here in the same run, for the same 138 MB (benchmarks/export.py;
    34 216 patches, one run at load ≈ 2.4: 24.5 against 11.1).

    Where the CPU goes on the demo's 34 216 patches (1.49 M entities, ~8 CPU-s in
    all): the entities made from Python ~3.2 s (:func:`_step_shell`), the model
    filled from its roots ~0.45 s (``AddWithRefs``, its index map sized first), the
    writer ~3.2 s (``StepData_StepWriter``: the text of the entities ~3.0 s, printed
    ~0.7 s; the same through ``WriteStream`` or the ``StepWriter`` used directly, and
    no ``Interface_Static`` setting reaches it), and freeing the model when the
    writer goes ~0.5 s.
    """
    from OCP.BRepPrimAPI import BRepPrimAPI_MakeBox
    from OCP.IFSelect import IFSelect_RetDone
    from OCP.Interface import Interface_Static
    from OCP.STEPControl import STEPControl_AsIs, STEPControl_Writer
    from OCP.StepShape import StepShape_ManifoldSolidBrep

    if _signed_volume(control_points, triangles) < 0:  # faces must point outward
        control_points, triangles = _reversed_nets(control_points, triangles)
    topo = shell_topology(triangles)
    if not topo["closed"]:
        return False
    poles = degenerate_nets(control_points).reshape(-1, 49, 3)
    ids, n_points = _pole_ids(triangles, topo)
    xyz = np.empty((n_points, 3))
    xyz[ids.ravel()] = poles.reshape(-1, 3)  # shared poles are equal bit for bit
    size = float(np.ptp(xyz, axis=0).max()) or 1.0
    collecting = gc.isenabled()
    gc.disable()
    try:
        shell = _step_shell(xyz, ids, topo)
    finally:
        if collecting:
            gc.enable()
    # the product, context, units and uncertainty of a template solid, its brep's shell
    # replaced by ours, and the model rebuilt from its roots (the template's faces dropped)
    writer = STEPControl_Writer()
    _step_settings()
    Interface_Static.SetIVal_s("write.precision.mode", 2)  # the uncertainty given here
    Interface_Static.SetRVal_s("write.precision.val", REL_TOLERANCE * size)
    if writer.Transfer(BRepPrimAPI_MakeBox(1.0, 1.0, 1.0).Shape(),
                       STEPControl_AsIs) != IFSelect_RetDone:
        return False
    model = writer.Model()
    entities = [model.Value(i) for i in range(1, model.NbEntities() + 1)]
    breps = [e for e in entities if isinstance(e, StepShape_ManifoldSolidBrep)]
    roots = [e for e in entities if e.DynamicType().Name() in _STEP_ROOTS]
    if len(breps) != 1 or len(roots) != len(_STEP_ROOTS):
        return False
    breps[0].SetOuter(shell)
    model.ClearEntities()
    # room for every entity at once (the template's, the points, vertices, curves and
    # edges, 7 a face): the model's index map is not rehashed as it grows to ~1.5 M
    n_faces, n_edges = len(ids), len(topo["start"])
    model.Reservate(len(entities) + n_points + topo["n_vertices"] + 2 * n_edges + 7 * n_faces + 1)
    for root in roots:
        model.AddWithRefs(root)
    return writer.Write(str(path)) == IFSelect_RetDone


#: The entities no other refers to in OpenCascade's AP214 output for one solid.
_STEP_ROOTS = ("StepBasic_ApplicationProtocolDefinition",
               "StepShape_ShapeDefinitionRepresentation",
               "StepBasic_ProductRelatedProductCategory")


def _step_shell(xyz: np.ndarray, ids: np.ndarray, topo: dict):
    """``CLOSED_SHELL`` of one ``ADVANCED_FACE`` per patch (degree 6 x 6
    ``B_SPLINE_SURFACE_WITH_KNOTS``, Bézier knots) bounded by the shared
    ``EDGE_CURVE`` s (sextic ``B_SPLINE_CURVE_WITH_KNOTS``); the collapsed side has no
    edge (OpenCascade's writer omits degenerated edges too; readers restore them).

    ~1.1 M points, 0.1 M curves and 34 k faces on the demo, each entity one
    constructor and one ``Init`` call from Python, each slot of a pole array one
    ``SetValue`` (OpenCascade's arrays of handles have no bulk setter the binding can
    feed): the loops over points and over array slots are ``map`` s of the bound
    methods, consumed by :func:`_consume` (no interpreter loop, no tuple unpacking
    per call).  What remains is the binding's own cost, ~0.7 µs a new wrapper and
    ~0.4-0.6 µs a call: on the demo ~1.2 CPU-s for the points, ~1.0 s for the faces'
    1.7 M pole slots, ~3.2 s in all (3.7 s with loops of calls).
    """
    import OCP.StepGeom as geom
    import OCP.StepShape as shape
    from OCP.collections import HArray1_double, HArray1_int, HArray1_StepGeom_CartesianPoint
    from OCP.StepData import StepData_Logical
    from OCP.TCollection import TCollection_HAsciiString

    name = TCollection_HAsciiString("")
    point_type, vertex_type = geom.StepGeom_CartesianPoint, shape.StepShape_VertexPoint
    points = [point_type() for _ in range(len(xyz))]
    _consume(map(point_type.Init3D, points, repeat(name), *xyz.T.tolist()))
    vertices = [vertex_type() for _ in range(topo["n_vertices"])]
    _consume(map(vertex_type.Init, vertices, repeat(name), points))  # the first V: corners
    multiplicities = HArray1_int(1, 2)
    knots = HArray1_double(1, 2)
    for i, (count, knot) in enumerate(((7, 0.0), (7, 1.0)), start=1):
        multiplicities.SetValue(i, count)
        knots.SetValue(i, knot)
    common = {"name": name, "multiplicities": multiplicities, "knots": knots,
              "false": StepData_Logical.StepData_LFalse,
              "bezier": geom.StepGeom_KnotType.StepGeom_ktPiecewiseBezierKnots}
    start, end = topo["start"], topo["end"]
    curve_ids = np.column_stack([start, topo["n_vertices"] + 5 * np.arange(len(start))[:, None]
                                 + np.arange(5), end])  # (E, 7)
    form = geom.StepGeom_BSplineCurveForm.StepGeom_bscfUnspecified
    curve_type, edge_type = geom.StepGeom_BSplineCurveWithKnots, shape.StepShape_EdgeCurve
    init_curve, init_edge = curve_type.Init, edge_type.Init
    false, bezier = common["false"], common["bezier"]
    slots, pole = range(1, 8), points.__getitem__
    curves = [curve_type() for _ in range(len(start))]
    for curve, row in zip(curves, curve_ids.tolist(), strict=True):
        array = HArray1_StepGeom_CartesianPoint(1, 7)
        _consume(map(array.SetValue, slots, map(pole, row)))
        init_curve(curve, name, 6, array, form, false, false, multiplicities, knots, bezier)
    edges = [edge_type() for _ in range(len(start))]
    _consume(map(init_edge, edges, repeat(name), map(vertices.__getitem__, start.tolist()),
                 map(vertices.__getitem__, end.tolist()), curves, repeat(True)))
    return _step_faces(points, edges, ids, topo, common)


def _step_faces(points: list, edges: list, ids: np.ndarray, topo: dict, common: dict):
    import OCP.StepGeom as geom
    import OCP.StepShape as shape
    from OCP.collections import (
        HArray1_StepShape_Face,
        HArray1_StepShape_FaceBound,
        HArray1_StepShape_OrientedEdge,
        HArray2_StepGeom_CartesianPoint,
    )

    name, false = common["name"], common["false"]
    multiplicities, knots, bezier = common["multiplicities"], common["knots"], common["bezier"]
    form = geom.StepGeom_BSplineSurfaceForm.StepGeom_bssfUnspecified
    rows, cols = [m // 7 + 1 for m in range(7, 49)], [m % 7 + 1 for m in range(7, 49)]
    pole = points.__getitem__
    faces = HArray1_StepShape_Face(1, len(ids))
    surface_type = geom.StepGeom_BSplineSurfaceWithKnots
    oriented_type = shape.StepShape_OrientedEdge
    init_surface, init_oriented = surface_type.Init, oriented_type.Init
    # the three real sides' oriented edges, in the wire's order
    sides = topo["edge"][:, [side for side, _ in _WIRE[:3]]]
    senses = topo["same"][:, [side for side, _ in _WIRE[:3]]] \
        != np.array([backwards for _, backwards in _WIRE[:3]])
    for f, (row, loop_sides, loop_senses) in enumerate(zip(ids.tolist(), sides.tolist(),
                                                           senses.tolist(), strict=True), start=1):
        # row u = 0 is the apex seven times: the array made full of it, the rest set
        grid = HArray2_StepGeom_CartesianPoint(1, 7, 1, 7, points[row[0]])
        _consume(map(grid.SetValue, rows, cols, map(pole, row[7:])))
        surface = surface_type()
        init_surface(surface, name, 6, 6, grid, form, false, false, false, multiplicities,
                     multiplicities, knots, knots, bezier)
        loop_edges = HArray1_StepShape_OrientedEdge(1, 3)
        for i, side, sense in zip((1, 2, 3), loop_sides, loop_senses, strict=True):
            oriented = oriented_type()
            init_oriented(oriented, name, edges[side], sense)
            loop_edges.SetValue(i, oriented)
        loop = shape.StepShape_EdgeLoop()
        loop.Init(name, loop_edges)
        bound = shape.StepShape_FaceBound()
        bound.Init(name, loop, True)
        face = shape.StepShape_AdvancedFace()
        face.Init(name, HArray1_StepShape_FaceBound(1, 1, bound), surface, True)
        faces.SetValue(f, face)
    shell = shape.StepShape_ClosedShell()
    shell.Init(name, faces)
    return shell


def _consume(calls) -> None:
    """Run an iterator of calls (a ``map``) to its end, keeping none of the results."""
    deque(calls, maxlen=0)


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
