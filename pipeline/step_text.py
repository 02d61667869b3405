r"""STEP (ISO 10303-21, AP214) text of the closed smooth surface, written directly.

numpy and Python's string formatting write every entity, in blocks of consecutive ids
(:func:`_entity_blocks`): one ``CARTESIAN_POINT`` per distinct pole (shared poles equal
bit for bit), ``B_SPLINE_SURFACE_WITH_KNOTS`` faces, ``B_SPLINE_CURVE_WITH_KNOTS``
edges, each edge's ``SURFACE_CURVE`` with its ``PCURVE`` on both faces, ``EDGE_CURVE``,
``ADVANCED_FACE`` bounded by its real edges (a collapsed side has none, as in
OpenCascade's own output), ``CLOSED_SHELL``, ``MANIFOLD_SOLID_BREP``, at the distance
uncertainty :func:`step_uncertainty`.  Two layouts:

- :func:`_write_step_text`: one degree (6, 6) Bézier face per patch (the degenerate nets
  of ``pipeline.step_brep``), or per control triangle for one-span merged faces; one
  sextic Bézier edge per domain edge.
- :func:`_write_merged_step_text`: one 13 x 13 two-span B-spline face per control
  triangle or quadrilateral (``surface.bezier_merge``, ``surface.bezier_quad``), each
  control edge one two-span edge whose poles the two faces share.

Both return False, writing nothing, for an open shell (``pipeline.cad_export`` then goes
through OpenCascade's shape transfer).  Why each choice (what a reader spends its time
on, the uncertainty, the pcurves): ``docs/decisions/export.md``.

Geometry is exact up to float64 rounding of the degree elevation (~1e-16 of the size)
and the points' rounding to a twentieth of the file's distance uncertainty.
"""

from __future__ import annotations

import re
import time
from pathlib import Path

import numpy as np

from pipeline.step_brep import (
    _SIDE_LINES,
    _WIRE,
    REL_TOLERANCE,
    _signed_volume,
    degenerate_nets,
    shell_topology,
)

__all__ = ["step_uncertainty"]


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


def _write_step_text(control_points: np.ndarray | None, triangles: np.ndarray, path: Path,
                     pcurves: bool = True, uncertainty: float | None = None,
                     nets: np.ndarray | None = None) -> bool:
    """The closed solid written as ISO 10303-21 text by numpy and Python's string
    formatting, every distinct pole one ``CARTESIAN_POINT``; False (nothing written)
    for an open shell, which the shape transfer writes.

    Entities, in blocks of consecutive ids: the product structure and units of
    OpenCascade's AP214 output for one solid, the points (fixed point,
    :func:`_decimals`), one ``VERTEX_POINT`` per domain vertex, one sextic
    ``B_SPLINE_CURVE_WITH_KNOTS`` per domain edge, one degree (6, 6)
    ``B_SPLINE_SURFACE_WITH_KNOTS`` per patch (Bézier knots), with ``pcurves`` each
    edge's ``SURFACE_CURVE`` (its 3D curve and a ``PCURVE`` on each of its two faces:
    the straight side of the face's (u, v) square, one of six shared
    ``DEFINITIONAL_REPRESENTATION`` s), ``EDGE_CURVE``, and per face three
    ``ORIENTED_EDGE`` s, ``EDGE_LOOP``, ``FACE_BOUND``, ``ADVANCED_FACE``; the collapsed
    side has no edge (as in OpenCascade's own output; readers restore a degenerated
    edge).  Without pcurves a reader projects every edge onto both its faces
    (``Extrema_GenExtPS``, then ShapeFix), most of its reading time; the pcurves are
    what OpenCascade's writer gives with ``write.surfacecurve.mode`` 1, which the
    binding could not make directly at speed (a ``PcurveOrSurface`` select costs
    ~9 ms a call through OCP).  The file's distance uncertainty is
    :func:`step_uncertainty`.  ``nets`` ``(F, 7, 7, 3)``: degenerate nets over
    ``triangles`` given directly (outward, in :func:`degenerate_nets`' layout; the
    control-triangle faces of ``surface.bezier_merge``), ``control_points`` unused.
    """
    if nets is None and _signed_volume(control_points, triangles) < 0:  # point outward
        control_points, triangles = _reversed_nets(control_points, triangles)
    topo = shell_topology(triangles)
    if not topo["closed"]:
        return False
    poles = (degenerate_nets(control_points) if nets is None else nets).reshape(-1, 49, 3)
    ids, n_points = _pole_ids(triangles, topo)
    xyz = np.empty((n_points, 3))
    xyz[ids.ravel()] = poles.reshape(-1, 3)  # shared poles are equal bit for bit
    size = float(np.ptp(xyz, axis=0).max()) or 1.0
    n_faces, n_vertices, n_edges = len(ids), topo["n_vertices"], len(topo["start"])
    (first_point, first_vertex, first_curve, first_surface, first_2d, first_pcurve,
     first_surface_curve, first_edge, first_oriented, first_loop, first_face,
     first_tail) = _entity_blocks(n_points, n_vertices, n_edges, n_faces,
                                  6 if pcurves else None, 3 * n_faces)
    out: list[str] = []
    write = out.append
    _write_step_head(write, first_tail, first_face, n_faces)
    start, end = topo["start"], topo["end"]
    uncertainty = uncertainty if uncertainty is not None else step_uncertainty(size)
    _write_points_and_curves(write, xyz, first_point, n_vertices, first_curve, np.column_stack(
        [start, n_vertices + 5 * np.arange(n_edges)[:, None] + np.arange(5), end]), uncertainty)
    grid = (first_point + ids).reshape(-1, 7, 7).tolist()
    write("\n".join(f"#{first_surface + f}=B_SPLINE_SURFACE_WITH_KNOTS('',6,6,("
                    + ",".join("(" + ",".join(f"#{q}" for q in r) + ")" for r in rows)
                    + "),.UNSPECIFIED.,.F.,.F.,.F.,(7,7),(7,7),(0.,1.),(0.,1.),"
                    ".PIECEWISE_BEZIER_KNOTS.);" for f, rows in enumerate(grid)))
    write("\n")
    geometry = np.arange(first_curve, first_curve + n_edges)
    if pcurves:
        lines = []
        for side, along in ((s, a) for s in range(3) for a in (False, True)):
            (x, y), (dx, dy) = _SIDE_LINES[side]
            if not along:  # from the side's far end back
                x, y, dx, dy = x + dx, y + dy, -dx, -dy
            lines.append(((x, y), (dx, dy)))
        _write_lines_2d(write, first_2d, lines)
        # each edge's two face sides, the owner's first
        flat = topo["edge"].ravel()
        order = np.argsort(flat, kind="stable").reshape(n_edges, 2)
        owner_slot = topo["owner"][:, 0] * 3 + topo["owner"][:, 1]
        order = np.where((order[:, :1] == owner_slot[:, None]), order, order[:, ::-1])
        same = topo["same"].ravel()[order].astype(np.int64)
        representation = first_2d + 1 + 5 * (2 * (order % 3) + same)
        surface = first_surface + order // 3
        write("\n".join(f"#{first_pcurve + j}=PCURVE('',#{s},#{r});" for j, (s, r) in
                        enumerate(zip(surface.ravel().tolist(),
                                      representation.ravel().tolist(), strict=True))))
        write("\n")
        write("\n".join(f"#{first_surface_curve + e}=SURFACE_CURVE('',#{first_curve + e},"
                        f"(#{first_pcurve + 2 * e},#{first_pcurve + 2 * e + 1}),.PCURVE_S1.);"
                        for e in range(n_edges)))
        write("\n")
        geometry = np.arange(first_surface_curve, first_surface_curve + n_edges)
    write("\n".join(f"#{first_edge + e}=EDGE_CURVE('',#{first_vertex + a},#{first_vertex + b},"
                    f"#{g},.T.);" for e, (a, b, g) in
                    enumerate(zip(start.tolist(), end.tolist(), geometry.tolist(), strict=True))))
    write("\n")
    sides = topo["edge"][:, [side for side, _ in _WIRE[:3]]]
    senses = topo["same"][:, [side for side, _ in _WIRE[:3]]] \
        != np.array([backwards for _, backwards in _WIRE[:3]])
    _write_faces_and_tail(out, path, first_edge, sides, senses, first_oriented, first_loop,
                          first_surface, first_tail, uncertainty)
    return True


def _entity_blocks(n_points: int, n_vertices: int, n_edges: int, n_faces: int,
                   n_lines: int | None, n_oriented: int) -> tuple[int, ...]:
    """The first entity id of each block of a STEP text file: ``#1``-``#16`` the product
    structure, brep and shell, then points, vertices, edge curves, face surfaces, the
    2-D context with ``n_lines`` pcurve representations (five entities each; ``None``:
    no pcurves), two pcurves and one surface curve per edge, edges, ``n_oriented``
    oriented edges, loops, bounds, faces, the tail.  Returns the firsts of points,
    vertices, curves, surfaces, 2-D context, pcurves, surface curves, edges, oriented
    edges, loops, faces and the tail (bounds follow the loops)."""
    first_point = 17
    first_vertex = first_point + n_points
    first_curve = first_vertex + n_vertices
    first_surface = first_curve + n_edges
    first_2d = first_surface + n_faces
    first_pcurve = first_2d + (0 if n_lines is None else 1 + 5 * n_lines)
    first_surface_curve = first_pcurve + (0 if n_lines is None else 2 * n_edges)
    first_edge = first_surface_curve + (0 if n_lines is None else n_edges)
    first_oriented = first_edge + n_edges
    first_loop = first_oriented + n_oriented
    first_face = first_loop + 2 * n_faces
    return (first_point, first_vertex, first_curve, first_surface, first_2d, first_pcurve,
            first_surface_curve, first_edge, first_oriented, first_loop, first_face,
            first_face + n_faces)


def _decimals(uncertainty: float) -> int:
    """Decimal places of the points' coordinates: rounded by at most a twentieth of the
    file's distance ``uncertainty`` (8 at OpenCascade's 1e-7)."""
    return max(1, int(np.ceil(-np.log10(uncertainty / 10.0) - 1e-9)))


def _write_points_and_curves(write, xyz: np.ndarray, first_point: int, n_vertices: int,
                             first_curve: int, curve_points: np.ndarray,
                             uncertainty: float) -> None:
    """The ``CARTESIAN_POINT`` entities from ``first_point`` (fixed point, to
    :func:`_decimals` places: far below the ``uncertainty`` a reader merges points
    within, and shared poles are shared by id; fixed point is shorter than 12
    significant digits and always has its decimal point), a ``VERTEX_POINT`` on each of
    the first ``n_vertices`` (right after the points), and one sextic Bézier
    ``B_SPLINE_CURVE_WITH_KNOTS`` per row of ``curve_points`` (7 point indices)."""
    first_vertex = first_point + len(xyz)
    number = f"%.{_decimals(uncertainty)}f"
    line = f"CARTESIAN_POINT('',({number},{number},{number}));"
    write("\n".join(f"#{i}=" + line % tuple(p) for i, p in
                     zip(range(first_point, first_vertex), xyz.tolist(), strict=True)))
    write("\n")
    write("\n".join(f"#{first_vertex + v}=VERTEX_POINT('',#{first_point + v});"
                    for v in range(n_vertices)))
    write("\n")
    write("\n".join(f"#{first_curve + e}=B_SPLINE_CURVE_WITH_KNOTS('',6,(#%d,#%d,#%d,#%d,#%d,"
                    "#%d,#%d),.UNSPECIFIED.,.F.,.F.,(7,7),(0.,1.),.PIECEWISE_BEZIER_KNOTS.);"
                    % tuple(row) for e, row in enumerate((first_point + curve_points).tolist())))
    write("\n")


def _write_lines_2d(write, first_2d: int, lines) -> None:
    """The 2-D parameter context at ``first_2d``, then per ``((x, y), (dx, dy))`` of
    ``lines`` its pcurve representation (representation, line, point, vector, direction:
    five entities)."""
    write(f"#{first_2d}=(GEOMETRIC_REPRESENTATION_CONTEXT(2)"
          "PARAMETRIC_REPRESENTATION_CONTEXT()REPRESENTATION_CONTEXT('2D SPACE',''));\n")
    for k, ((x, y), (dx, dy)) in enumerate(lines):
        i = first_2d + 1 + 5 * k
        write(f"#{i}=DEFINITIONAL_REPRESENTATION('',(#{i + 1}),#{first_2d});\n"
              f"#{i + 1}=LINE('',#{i + 2},#{i + 3});\n"
              f"#{i + 2}=CARTESIAN_POINT('',({x:.1f},{y:.1f}));\n"
              f"#{i + 3}=VECTOR('',#{i + 4},1.);\n"
              f"#{i + 4}=DIRECTION('',({dx:.1f},{dy:.1f}));\n")


def _write_faces_and_tail(out: list, path: Path, first_edge: int, edges: np.ndarray,
                          senses: np.ndarray, first_oriented: int, first_loop: int,
                          first_surface: int, first_tail: int, uncertainty: float) -> None:
    """Per face (a row of ``edges``, edge indices in wire order, -1 for none, and
    ``senses``, whether each runs the wire's way) its ``ORIENTED_EDGE`` entities from
    ``first_oriented``, its ``EDGE_LOOP``, bound and ``ADVANCED_FACE`` (loops, bounds and
    faces in three blocks from ``first_loop``), then the tail; ``out`` written to
    ``path``."""
    write = out.append
    n_faces = len(edges)
    valid = edges >= 0
    count = valid.sum(axis=1)
    begin = (np.cumsum(count) - count).tolist()
    write("\n".join(f"#{first_oriented + j}=ORIENTED_EDGE('',*,*,#{first_edge + e},"
                    f"{'.T.' if a else '.F.'});" for j, (e, a) in
                    enumerate(zip(edges[valid].tolist(), senses[valid].tolist(), strict=True))))
    write("\n")
    first_bound, first_face = first_loop + n_faces, first_loop + 2 * n_faces
    write("\n".join(f"#{first_loop + f}=EDGE_LOOP('',("
                    + ",".join(f"#{first_oriented + b + k}" for k in range(c))
                    + "));\n"
                    f"#{first_bound + f}=FACE_BOUND('',#{first_loop + f},.T.);\n"
                    f"#{first_face + f}=ADVANCED_FACE('',(#{first_bound + f}),"
                    f"#{first_surface + f},.T.);"
                    for f, (b, c) in enumerate(zip(begin, count.tolist(), strict=True))))
    write("\n")
    _write_step_tail(write, first_tail, uncertainty)
    with open(path, "w", encoding="ascii") as handle:
        handle.writelines(out)


def _write_step_head(write, first_tail: int, first_face: int, n_faces: int) -> None:
    """Header, product structure, brep and the closed shell of faces ``first_face ...``
    (``#1``-``#16``); the representation context is entity ``first_tail``."""
    stamp = time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime())
    write("ISO-10303-21;\nHEADER;\nFILE_DESCRIPTION(('photosurf surface'),'2;1');\n"
          f"FILE_NAME('photosurf surface','{stamp}',(''),(''),'photosurf','photosurf','');\n"
          "FILE_SCHEMA(('AUTOMOTIVE_DESIGN { 1 0 10303 214 1 1 1 1 }'));\nENDSEC;\nDATA;\n")
    context = first_tail
    write("#1=APPLICATION_PROTOCOL_DEFINITION('international standard','automotive_design',"
          "2000,#2);\n#2=APPLICATION_CONTEXT('core data for automotive mechanical design "
          "processes');\n#3=SHAPE_DEFINITION_REPRESENTATION(#4,#10);\n"
          "#4=PRODUCT_DEFINITION_SHAPE('','',#5);\n#5=PRODUCT_DEFINITION('design','',#6,#9);\n"
          "#6=PRODUCT_DEFINITION_FORMATION('','',#7);\n"
          "#7=PRODUCT('photosurf surface','photosurf surface','',(#8));\n"
          "#8=PRODUCT_CONTEXT('',#2,'mechanical');\n"
          "#9=PRODUCT_DEFINITION_CONTEXT('part definition',#2,'design');\n"
          f"#10=ADVANCED_BREP_SHAPE_REPRESENTATION('',(#11,#15),#{context});\n"
          "#11=AXIS2_PLACEMENT_3D('',#12,#13,#14);\n#12=CARTESIAN_POINT('',(0.,0.,0.));\n"
          "#13=DIRECTION('',(0.,0.,1.));\n#14=DIRECTION('',(1.,0.,0.));\n"
          "#15=MANIFOLD_SOLID_BREP('',#16);\n#16=CLOSED_SHELL('',(")
    write(",".join(f"#{i}" for i in range(first_face, first_face + n_faces)))
    write("));\n")


def _write_step_tail(write, context: int, uncertainty: float) -> None:
    """The representation context (``#context``), its units and distance uncertainty."""
    length = context + 1
    uncertainty = _reals(f"({uncertainty:.6G})")[1:-1]
    write(f"#{context}=(GEOMETRIC_REPRESENTATION_CONTEXT(3)"
          f"GLOBAL_UNCERTAINTY_ASSIGNED_CONTEXT((#{context + 4}))"
          f"GLOBAL_UNIT_ASSIGNED_CONTEXT((#{length},#{context + 2},#{context + 3}))"
          "REPRESENTATION_CONTEXT('Context #1','3D Context with UNIT and UNCERTAINTY'));\n"
          f"#{length}=(LENGTH_UNIT()NAMED_UNIT(*)SI_UNIT(.MILLI.,.METRE.));\n"
          f"#{context + 2}=(NAMED_UNIT(*)PLANE_ANGLE_UNIT()SI_UNIT($,.RADIAN.));\n"
          f"#{context + 3}=(NAMED_UNIT(*)SI_UNIT($,.STERADIAN.)SOLID_ANGLE_UNIT());\n"
          f"#{context + 4}=UNCERTAINTY_MEASURE_WITH_UNIT(LENGTH_MEASURE({uncertainty}),"
          f"#{length},'distance_accuracy_value','confusion accuracy');\n"
          f"#{context + 5}=PRODUCT_RELATED_PRODUCT_CATEGORY('part',$,(#7));\n"
          "ENDSEC;\nEND-ISO-10303-21;\n")


def step_uncertainty(size: float) -> float:
    """Distance uncertainty written in the STEP file for a surface of extent ``size``.

    ``REL_TOLERANCE * size``, but never below OpenCascade's confusion distance
    ``Precision::Confusion()`` (1e-7 model units), its smallest meaningful distance:
    read at an uncertainty below it, OpenCascade's reader checks and refits the edges'
    pcurves (measured: the transfer of a 1 760-face ellipsoid 6x slower at 1.9e-9 than
    at 1e-7, ``benchmarks/export.py``).
    """
    return max(REL_TOLERANCE * size, 1e-7)


def _reals(text: str) -> str:
    """Numbers printed by ``%G`` made STEP REALs: a mantissa without a decimal point
    gets one (``1E-05`` -> ``1.E-05``, ``0`` -> ``0.``); exponents are left alone."""
    return _INTEGER_MANTISSA.sub(r"\1.", text)


_INTEGER_MANTISSA = re.compile(r"(?<![\d.E+\-])(-?\d+)(?=[E,)])")



# ----------------------------------------- STEP text: merged faces, 13 x 13 B-splines
#: A merged face's sides over its ``[0, 2]^2`` (``corners (F, 4)`` at ``(u, v)`` = (0, 0),
#: (2, 0), (2, 2), (0, 2)): side 0 ``v = 0`` runs corner 0 -> 1, 1 ``u = 2`` 1 -> 2,
#: 2 ``v = 2`` 3 -> 2, 3 ``u = 0`` 0 -> 3 (collapsed where corner 3 is corner 0: a
#: control-triangle face); the wire walks sides 2 and 3 backwards.
_FACE_SIDES = ((0, 1), (1, 2), (3, 2), (0, 3))


def _merged_topology(corners: np.ndarray, mids: np.ndarray) -> dict | None:
    """The control edges of merged faces: per (face, side) ``edge`` (-1 collapsed),
    ``valid`` and ``same`` (the side's parameter runs from the edge's lower vertex id to
    its higher); per edge ``low``, ``high`` and its midpoint vertex ``mid``.  None unless
    every edge bounds two faces, walked once each way by their wires (a closed oriented
    shell)."""
    start = corners[:, [a for a, _ in _FACE_SIDES]]
    end = corners[:, [b for _, b in _FACE_SIDES]]
    valid = start != end
    n = int(corners.max()) + 1
    key = np.minimum(start, end) * n + np.maximum(start, end)
    unique, inverse, counts = np.unique(key[valid], return_inverse=True, return_counts=True)
    if len(unique) == 0 or (counts != 2).any():
        return None
    edge = np.full(start.shape, -1, dtype=np.int64)
    edge[valid] = inverse
    same = start < end
    upward = (same != np.array([False, False, True, True]))[valid]  # the wire: low -> high
    if not np.array_equal(np.bincount(inverse, weights=upward, minlength=len(unique)),
                          np.ones(len(unique))):
        return None
    mid = np.empty(len(unique), dtype=np.int64)
    mid[inverse] = mids[valid]
    return {"edge": edge, "same": same, "valid": valid, "low": unique // n,
            "high": unique % n, "mid": mid}


def _side_line(side: int, same: bool) -> tuple[tuple, tuple]:
    """A whole side's pcurve: origin and unit direction of the edge's parameter
    ``0 -> 2``, with (``same``) or against the side's increasing parameter."""
    lines = (((0.0, 0.0), (1.0, 0.0)), ((2.0, 0.0), (0.0, 1.0)),
             ((0.0, 2.0), (1.0, 0.0)), ((0.0, 0.0), (0.0, 1.0)))
    (x, y), (dx, dy) = lines[side]
    if same:
        return (x, y), (dx, dy)
    return (x + 2.0 * dx, y + 2.0 * dy), (-dx, -dy)


def _write_merged_step_text(merged: dict, path: Path, uncertainty: float | None = None
                            ) -> bool:
    """The closed solid of merged faces (``surface.bezier_quad``'s quadrilaterals and
    ``surface.bezier_merge``'s control triangles) as ISO 10303-21 text; False (nothing
    written) for an open shell.

    ``merged``: ``corners (F, 4)`` (a triangle's corner 3 is its corner 0), ``mids (F,
    4)`` each side's midpoint vertex, ``poles (F, 13, 13, 3)``.  Every face is a degree
    (6, 6) ``B_SPLINE_SURFACE_WITH_KNOTS`` of 13 x 13 poles (knots 0, 1, 2 with
    multiplicities 7, 6, 7) bounded by its control edges, each one edge: a two-span
    sextic B-spline over ``[0, 2]`` (the side's own parameter) whose 13 poles are the
    face's boundary poles, shared by id with the neighbour (watertight exactly; the
    midpoint is a pole, not a vertex: half the edges and vertices of two half edges, and
    half OpenCascade's transfer time, ``docs/decisions/export.md``).  Each edge carries
    its pcurve on both faces: a side of the face's ``[0, 2]^2`` (eight shared
    ``DEFINITIONAL_REPRESENTATION`` s)."""
    corners, poles = merged["corners"], merged["poles"]
    topo = _merged_topology(corners, merged["mids"])
    if topo is None:
        return False
    vertex, compact = np.unique(corners, return_inverse=True)
    compact = compact.reshape(corners.shape)
    n_faces, n_edges, n_vertices = len(corners), len(topo["low"]), len(vertex)
    low, high = (np.searchsorted(vertex, topo[k]) for k in ("low", "high"))
    edge, same, valid = topo["edge"], topo["same"], topo["valid"]
    ids = np.empty((n_faces, 13, 13), dtype=np.int64)
    step11 = np.arange(11)

    def along(side: int) -> np.ndarray:
        e, s = np.maximum(edge[:, side], 0)[:, None], same[:, side][:, None]
        return n_vertices + 11 * e + np.where(s, step11[None, :], 10 - step11[None, :])

    ids[:, 0, 0], ids[:, 12, 0], ids[:, 12, 12], ids[:, 0, 12] = compact.T
    ids[:, 1:12, 0], ids[:, 12, 1:12], ids[:, 1:12, 12] = along(0), along(1), along(2)
    ids[:, 0, 1:12] = np.where(valid[:, 3:], along(3), compact[:, :1])
    ids[:, 1:12, 1:12] = (n_vertices + 11 * n_edges + 121 * np.arange(n_faces))[:, None, None] \
        + np.arange(121).reshape(11, 11)
    xyz = np.empty((n_vertices + 11 * n_edges + 121 * n_faces, 3))
    xyz[ids.ravel()] = poles.reshape(-1, 3)
    size = float(np.ptp(xyz, axis=0).max()) or 1.0
    wire_edge = np.where(valid, edge, -1)
    senses = same != np.array([False, False, True, True])
    (first_point, first_vertex, first_curve, first_surface, first_2d, first_pcurve,
     first_surface_curve, first_edge, first_oriented, first_loop, first_face,
     first_tail) = _entity_blocks(len(xyz), n_vertices, n_edges, n_faces, 8, int(valid.sum()))
    out: list[str] = []
    write = out.append
    _write_step_head(write, first_tail, first_face, n_faces)
    uncertainty = uncertainty if uncertainty is not None else step_uncertainty(size)
    _write_points_and_curves(write, xyz, first_point, n_vertices, first_curve,
                             np.empty((0, 7), dtype=np.int64), uncertainty)
    rows = first_point + np.column_stack([low, n_vertices + 11 * np.arange(n_edges)[:, None]
                                          + step11, high])
    write("\n".join(f"#{first_curve + e}=B_SPLINE_CURVE_WITH_KNOTS('',6,("
                    + ",".join(f"#{q}" for q in row) + "),.UNSPECIFIED.,.F.,.F.,(7,6,7),"
                    "(0.,1.,2.),.UNSPECIFIED.);" for e, row in enumerate(rows.tolist())))
    write("\n")
    write("\n".join(f"#{first_surface + f}=B_SPLINE_SURFACE_WITH_KNOTS('',6,6,("
                    + ",".join("(" + ",".join(f"#{q}" for q in r) + ")" for r in grid)
                    + "),.UNSPECIFIED.,.F.,.F.,.F.,(7,6,7),(7,6,7),(0.,1.,2.),(0.,1.,2.),"
                    ".UNSPECIFIED.);" for f, grid in enumerate((first_point + ids).tolist())))
    write("\n")
    _write_lines_2d(write, first_2d, [_side_line(k // 2, bool(k % 2)) for k in range(8)])
    face, side = (a.ravel() for a in np.meshgrid(np.arange(n_faces), np.arange(4),
                                                  indexing="ij"))
    keep = valid[face, side]
    face, side = face[keep], side[keep]
    order = np.argsort(edge[face, side], kind="stable")
    representation = first_2d + 1 + 5 * (2 * side + same[face, side].astype(np.int64))
    write("\n".join(f"#{first_pcurve + j}=PCURVE('',#{first_surface + f},#{r});" for j, (f, r) in
                    enumerate(zip(face[order].tolist(), representation[order].tolist(),
                                  strict=True))))
    write("\n")
    write("\n".join(f"#{first_surface_curve + e}=SURFACE_CURVE('',#{first_curve + e},"
                    f"(#{first_pcurve + 2 * e},#{first_pcurve + 2 * e + 1}),.PCURVE_S1.);"
                    for e in range(n_edges)))
    write("\n")
    write("\n".join(f"#{first_edge + e}=EDGE_CURVE('',#{first_vertex + a},#{first_vertex + b},"
                    f"#{first_surface_curve + e},.T.);" for e, (a, b) in
                    enumerate(zip(low.tolist(), high.tolist(), strict=True))))
    write("\n")
    _write_faces_and_tail(out, path, first_edge, wire_edge, senses, first_oriented, first_loop,
                          first_surface, first_tail, uncertainty)
    return True
