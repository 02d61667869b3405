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
their edge curves bit for bit (one face a patch: a third of the faces of a centroid
split, ``surface.bezier.tensor_product_nets``).  The shell is assembled by topology, not
by sewing: every vertex and edge is made once and shared by the faces that meet there.

STEP (AP214): the file's text is written directly (:func:`_write_step_text`): one
``CARTESIAN_POINT`` per distinct pole, ``B_SPLINE_SURFACE_WITH_KNOTS`` of degree 6 x 6 and
``B_SPLINE_CURVE_WITH_KNOTS`` of degree 6 with Bézier knots, each edge's ``SURFACE_CURVE``
with its ``PCURVE`` on both faces, ``EDGE_CURVE``, ``ADVANCED_FACE`` bounded by its three
real edges (the collapsed side has none, as in OpenCascade's own output),
``CLOSED_SHELL``, ``MANIFOLD_SOLID_BREP``, at the distance uncertainty
:func:`step_uncertainty`; given a tolerance, one face per pair of control triangles
(a quadrilateral) or per control triangle where the patches merge, each control edge one
edge (:func:`_write_merged_step_text`).  An open shell goes through the shape
transfer (:func:`solid_from_nets`, ``STEPControl_Writer``).  IGES: the ``TopoDS`` solid
through ``IGESControl_Writer`` (5.3, BRep mode).  Why each choice (sewing's time, what a
reader spends its time on): ``docs/decisions/export.md``.

Geometry is exact up to float64 rounding of the degree elevation (~1e-16 of the
size) and the writer's 12-13 significant digits.

References: ISO 10303-21 (clear text encoding, STEP) and ISO 10303-214 (AP214); C. Loop,
"Smooth spline surfaces over irregular meshes", SIGGRAPH 1994; G. Farin, "Curves and
Surfaces for CAGD", 5th ed. (2002); M. G. Duffy, SIAM J. Numer. Anal. 19 (1982): the
collapsed square.
"""

from __future__ import annotations

import gc
import os
import re
import time
from fractions import Fraction
from functools import cache
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
           "solid_from_nets", "step_uncertainty", "write_cad"]


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
              triangles: np.ndarray, source_face: np.ndarray | None = None,
              tolerance: float | None = None, report: dict | None = None,
              spans: int = 2, angle_tolerance: float | None = None,
              quads: bool = False) -> Path:
    """Write the surface as a closed solid to STEP (``.step``/``.stp``) or IGES.

    By default every patch is one face, exact.  Given ``source_face`` and a
    ``tolerance`` (scene units), a closed surface's STEP has one face per control
    triangle instead, a fourth of the faces (``surface.bezier_merge``): the same edges
    and vertices, faces within ``tolerance`` of the patches along the normal and
    tangent-plane continuous across their sides; where any face is farther than
    ``tolerance`` or turns more than ``angle_tolerance`` (or the patches are not four per
    control triangle) the exact per-patch file is written.

    Parameters
    ----------
    path : path-like
        Suffix one of :data:`CAD_SUFFIXES`; written atomically.
    control_points : (P, 28, 3) float64
    triangles : (P, 3) int64
        Oriented domain mesh of the patches: closed, the file holds a closed solid;
        with a border, the open shell of the faces.

    source_face : (P,) int64, optional
        Each patch's control triangle (``BezierSurface.source_face``).
    tolerance : float, optional
        Largest distance a merged face may lie from the patches.
    spans : {2, 1}
        Merged faces' form (``surface.bezier_merge``): 2, 13 x 13 B-spline faces whose
        edges are the patch edges, exact; 1, 7 x 7 Bézier faces with fitted edges (a
        third of OpenCascade's reading time, but kinks and folded parametrisations on
        thin control triangles: measured in ``benchmarks/export.py``, not the default).
    angle_tolerance : float, optional
        Largest angle (radians) a merged face's normal may make with the patches' along
        its sides (the kink between two faces is at most twice it); default the slope
        ``tolerance`` allows over a control edge, ``tolerance / median control edge``
        (the demo: 0.064 degrees); ``numpy.inf`` to accept kinks.
    quads : bool
        With two spans, pair neighbouring control triangles into quadrilateral faces
        (``surface.bezier_quad``: half the Bézier spans a face pair), keeping
        control-triangle faces where a quadrilateral misses the tolerances or is left
        unpaired: OpenCascade transfers the demo's in 5.6 CPU-s against 8.1, but
        FreeCAD opens it no faster (22.7 against 20.6 CPU-s; 22.0 against 23.9 in
        another run) and its kinks are larger (0.076 against 0.0005 degrees), so not
        the default (``docs/decisions/export.md``).
    report : dict, optional
        Filled with ``faces``, ``merged`` (bool), with ``quads`` the ``quads`` and
        ``triangles`` written, and for a merge attempt
        ``deviation`` (largest distance along the normal), ``slide`` (largest
        parameter-induced offset along the surface) and ``angle_deg`` (largest angle
        between a merged face's normal and the patches' along its sides).

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
    if tolerance is not None and not tolerance > 0:
        raise ValueError(f"tolerance must be positive, got {tolerance}")
    report = report if report is not None else {}
    report.update(faces=len(cp), merged=False)
    merged = None
    if suffix in (".step", ".stp") and source_face is not None and tolerance is not None:
        merged = _merged(cp, tris, source_face, tolerance, report, spans, angle_tolerance,
                         quads)
    _quiet()
    with atomic_file(path) as tmp:
        if not _write_cad_file(tmp, suffix, cp, tris, merged, report):
            raise_if_full(tmp, path)  # a full disk says so (OpenCascade gives no errno)
            raise InputError(f"{path}: OpenCascade could not write the {suffix[1:].upper()} file")
    return path


def _write_cad_file(tmp: Path, suffix: str, cp: np.ndarray, tris: np.ndarray,
                    merged: dict | None, report: dict) -> bool:
    """:func:`write_cad`'s file at ``tmp``: STEP text directly (the merged faces when
    given), an open shell through the shape transfer; IGES through OpenCascade."""
    if suffix not in (".step", ".stp"):
        return _write_iges(solid_from_nets(cp, tris), tmp)
    ok = merged is not None and (
        _write_merged_step_text(merged, tmp) if merged["poles"].shape[1] == 13
        else _write_step_text(None, merged["corners"], tmp, nets=merged["poles"]))
    if ok:
        report.update(faces=len(merged["poles"]), merged=True)
    return ok or _write_step_text(cp, tris, tmp) or _write_step(solid_from_nets(cp, tris), tmp)


def _merged(cp: np.ndarray, tris: np.ndarray, source_face, tolerance: float,
            report: dict, spans: int = 1, angle_tolerance: float | None = None,
            quads: bool = False) -> dict | None:
    """The merged faces when all lie within ``tolerance`` of the patches and their
    normals along the sides within ``angle_tolerance`` (radians) of the patches'.
    Two spans: ``corners (F, 4)``, ``mids (F, 4)``, ``poles (F, 13, 13, 3)`` for
    :func:`_write_merged_step_text`, quadrilaterals (``quads``) where they pass the
    gate, control triangles elsewhere; one span: ``bezier_merge.merged_faces``' dict."""
    from surface.bezier_merge import merged_faces

    source = np.asarray(source_face, dtype=np.int64)
    if source.shape != (len(tris),):
        raise ValueError(f"source_face must have one entry per patch ({len(tris)}), "
                         f"got shape {source.shape}")
    if _signed_volume(cp, tris) < 0:  # faces must point outward
        cp, tris = _reversed_nets(cp, tris)
    if quads and spans == 2:
        return _merged_quads(cp, tris, source, tolerance, report, angle_tolerance)
    merged = merged_faces(cp, tris, source, spans=spans)
    if merged is None:
        report["reason"] = "the patches are not four per control triangle"
        return None
    if angle_tolerance is None:
        angle_tolerance = _slope_tolerance(cp, merged["patches"], tolerance)
    if not _passes(merged, tolerance, angle_tolerance, report):
        return None
    return merged if spans == 1 else _four_cornered(merged)


def _slope_tolerance(cp: np.ndarray, patches: np.ndarray, tolerance: float) -> float:
    """The slope the distance tolerance allows over a control edge (radians):
    ``tolerance / median control edge``."""
    # corner 0 of the corner patches at A and B: A and m_AB, half the control edge
    first = cp[patches[:, :2], 0]
    edge = 2.0 * float(np.median(np.linalg.norm(first[:, 1] - first[:, 0], axis=1)))
    return tolerance / max(edge, 1e-300)


def _passes(faces: dict, tolerance: float, angle_tolerance: float, report: dict) -> bool:
    """Whether every face of ``faces`` (``deviation``, ``slide``, ``angle``) is within
    the tolerances; the figures (and why not) into ``report``."""
    deviation, angle = float(faces["deviation"].max()), float(faces["angle"].max())
    report.update(deviation=deviation, slide=float(faces["slide"].max()),
                  angle_deg=float(np.degrees(angle)), tolerance=tolerance,
                  angle_tolerance_deg=float(np.degrees(angle_tolerance)),
                  folded=int(np.count_nonzero(faces["angle"] > np.pi / 2)))
    if deviation > tolerance:
        report["reason"] = f"a merged face lies {deviation:.3g} from the patches"
        return False
    if angle > angle_tolerance:
        report["reason"] = (f"a merged face's normal turns {np.degrees(angle):.3g} degrees "
                            "from the patches' along its sides (not G1)")
        return False
    return True


def _four_cornered(merged: dict) -> dict:
    """Two-span control-triangle faces in :func:`_write_merged_step_text`'s layout."""
    corners, mids = merged["corners"], merged["mids"]
    return {**merged, "corners": np.column_stack([corners, corners[:, 0]]),
            "mids": np.column_stack([mids, np.full(len(mids), -1)])}


def _merged_quads(cp: np.ndarray, tris: np.ndarray, source: np.ndarray, tolerance: float,
                  report: dict, angle_tolerance: float | None) -> dict | None:
    """Quadrilateral faces (``surface.bezier_quad``) where within the tolerances and not
    folded, two-span control-triangle faces for the control triangles left."""
    from surface.bezier_merge import merged_faces
    from surface.bezier_quad import quad_faces

    quad = quad_faces(cp, tris, source)
    if quad is None:
        report["reason"] = "the patches are not four per control triangle"
        return None
    patches = quad["triangles"]["patches"]
    if angle_tolerance is None:
        angle_tolerance = _slope_tolerance(cp, patches, tolerance)
    keep = (quad["deviation"] <= tolerance) & (quad["angle"] <= angle_tolerance) \
        & (quad["inner_angle"] < np.pi / 2)
    single = np.sort(np.concatenate([quad["single"], quad["pairs"][~keep].ravel()]))
    parts = [{k: quad[k][keep] for k in ("corners", "mids", "poles", "deviation", "slide",
                                         "angle")}]
    if len(single):
        chosen = patches[single].ravel()
        dense = np.unique(source[chosen], return_inverse=True)[1]  # ids 0..S-1
        tri = merged_faces(cp[chosen], tris[chosen], dense, spans=2)
        parts.append(_four_cornered(tri))
    merged = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    report.update(quads=int(keep.sum()), triangles=int(len(single)))
    return merged if _passes(merged, tolerance, angle_tolerance, report) else None


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


def _write_step_text(control_points: np.ndarray | None, triangles: np.ndarray, path: Path,
                     pcurves: bool = True, uncertainty: float | None = None,
                     nets: np.ndarray | None = None) -> bool:
    """The closed solid written as ISO 10303-21 text by numpy and Python's string
    formatting, every distinct pole one ``CARTESIAN_POINT``; False (nothing written)
    for an open shell, which the shape transfer writes.

    Entities, in blocks of consecutive ids: the product structure and units of
    OpenCascade's AP214 output for one solid, the points (12 significant digits, as
    OpenCascade writes them), one ``VERTEX_POINT`` per domain vertex, one sextic
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
    _write_points_and_curves(write, xyz, first_point, n_vertices, first_curve, np.column_stack(
        [start, n_vertices + 5 * np.arange(n_edges)[:, None] + np.arange(5), end]))
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
                          first_surface, first_tail, uncertainty if uncertainty is not None
                          else step_uncertainty(size))
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


def _write_points_and_curves(write, xyz: np.ndarray, first_point: int, n_vertices: int,
                             first_curve: int, curve_points: np.ndarray) -> None:
    """The ``CARTESIAN_POINT`` entities from ``first_point`` (12 significant digits; a REAL
    needs its decimal point, "1.E-05", "0."), a ``VERTEX_POINT`` on each of the first
    ``n_vertices`` (right after the points), and one sextic Bézier
    ``B_SPLINE_CURVE_WITH_KNOTS`` per row of ``curve_points`` (7 point indices)."""
    first_vertex = first_point + len(xyz)
    text = "\n".join(f"#{i}=CARTESIAN_POINT('',(%.12G,%.12G,%.12G));" % tuple(p) for i, p in
                     zip(range(first_point, first_vertex), xyz.tolist(), strict=True))
    write(_reals(text))
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
    _write_points_and_curves(write, xyz, first_point, n_vertices, first_curve,
                             np.empty((0, 7), dtype=np.int64))
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
                          first_surface, first_tail, uncertainty if uncertainty is not None
                          else step_uncertainty(size))
    return True
