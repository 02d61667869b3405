r"""STEP (and IGES) export of the exact smooth surface: :func:`write_cad`.

A closed surface's STEP text is written directly (``pipeline.step_text``): one exact
degree (6, 6) Bézier face per patch, degenerate at its corner 0 (``pipeline.step_brep``'s
collapsed square), or, given a chord tolerance and each patch's control triangle, one
face per control triangle (two-span 13 x 13 B-splines whose edges are the patch edges,
``surface.bezier_merge``) or per pair of control triangles (``quads``,
``surface.bezier_quad``) where every merged face lies within the tolerance of the
patches and turns within the angle tolerance along its sides; else the exact per-patch
file.  An open shell goes through OpenCascade's shape transfer
(``pipeline.step_brep.solid_from_nets``, ``STEPControl_Writer``); IGES: the ``TopoDS``
solid through ``IGESControl_Writer`` (5.3, BRep mode).  Every file is written
atomically.  Why each choice (sewing's time, what a reader spends its time on, which
faces FreeCAD opens fastest): ``docs/decisions/export.md``.

References: ISO 10303-21 (clear text encoding, STEP) and ISO 10303-214 (AP214).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import breadth_first_order, connected_components

from pipeline.atomic import atomic_file, raise_if_full
from pipeline.errors import InputError
from pipeline.step_brep import (  # noqa: F401  (the module's API and its tests')
    REL_TOLERANCE,
    _quiet,
    _signed_volume,
    _write_iges,
    _write_step,
    degenerate_nets,
    read_cad_solid,
    shell_topology,
    solid_from_nets,
)
from pipeline.step_text import (  # noqa: F401
    _reals,
    _reversed_nets,
    _write_merged_step_text,
    _write_step_text,
    step_uncertainty,
)
from surface.validate import check_finite, check_shape

#: Suffixes :func:`write_cad` writes.
CAD_SUFFIXES = (".step", ".stp", ".iges", ".igs")

__all__ = ["CAD_SUFFIXES", "degenerate_nets", "read_cad_solid", "shell_topology",
           "solid_from_nets", "step_uncertainty", "write_cad"]


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
        unpaired; faces written each after a neighbour (:func:`_connected_order`).
        FreeCAD opens the demo's in 12.9 and 15.3 CPU-s against the default file's 21.1
        (in pairing order: 20.7), but its kinks are larger (0.076 against 0.0005
        degrees, inside the angle gate) and it was not yet measured on every surface the
        default touches, so not the default (``docs/decisions/export.md``).
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


def _connected_order(corners: np.ndarray) -> np.ndarray:
    """The faces ``corners (F, 4)`` (corner 3 = corner 0: a collapsed side) in
    breadth-first order over their shared sides, each after a neighbour.  OpenCascade's
    shell orientation fix (``ShapeFix_Shell``, run by every STEP read) grows a shell
    face by face, rescanning the faces left from the first: in an order where each face
    touches one before it, it passes once (the quadrilateral file in pairing order spent
    28 % of FreeCAD's import there, the control triangles' 0.5 %)."""
    n = len(corners)
    a, b = corners[:, [0, 1, 3, 0]], corners[:, [1, 2, 2, 3]]
    valid = a != b
    lo, hi = np.minimum(a, b)[valid], np.maximum(a, b)[valid]
    face = np.broadcast_to(np.arange(n)[:, None], a.shape)[valid]
    key = lo * (int(corners.max()) + 1) + hi
    by = np.argsort(key, kind="stable")
    k, f = key[by], face[by]
    shared = k[1:] == k[:-1]
    graph = coo_matrix((np.ones(int(shared.sum())), (f[:-1][shared], f[1:][shared])),
                       shape=(n, n)).tocsr()
    count, label = connected_components(graph, directed=False)
    starts = np.unique(label, return_index=True)[1]
    return np.concatenate([breadth_first_order(graph, int(s), directed=False,
                                               return_predecessors=False) for s in starts])


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
    order = _connected_order(merged["corners"])
    merged = {k: v[order] for k, v in merged.items()}
    report.update(quads=int(keep.sum()), triangles=int(len(single)))
    return merged if _passes(merged, tolerance, angle_tolerance, report) else None
