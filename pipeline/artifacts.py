"""The workspace's intermediate files: each one's writer and reader side by side.

``photosurf run`` keeps what lies between its stages in ``OUTDIR/<stage>/`` (COLMAP keeps
its model files the same way: one module, a writer and a reader per file).  Every
``.npz`` is written byte-reproducibly (:func:`pipeline.workspace.save_npz`: fixed zip
dates), so the same arrays give the same file and the same hash.

==========================  =============================================================
file                        arrays (shapes; lengths in scene units)
==========================  =============================================================
``acquire/cloud.npz``       ``points`` (N,3) float64, ``colors`` (N,3) uint8, ``sigma`` (N,)
                            float64 (NaN when unknown); ``acquire/cloud.ply`` the same
                            for viewers (:func:`pipeline.cloud_io.write_ply`)
``sections/sections.npz``   ``points`` (P,3) on their planes, ``offsets`` (K+1,) int64,
                            ``heights`` (K,), ``section_id`` (K,) int64, ``origin`` (K,3),
                            ``frame`` (3,3), ``source_index`` (P,) int64, ``cap_cloud`` (C,3)
                            the points an end cap may move to, ``cap_sigma`` (C,) their
                            precision (NaN unknown; absent in older workspaces),
                            ``spacing`` ()
``curves/curves.npz``       ``points`` (Q,3) of the resampled closed rings, ``offsets``
                            (R+1,), ``section`` (R,), ``loop`` (R,), ``heights`` (R,),
                            ``axis`` (3,), ``frame`` (3,3), ``noise`` () the section
                            points' sigma (:func:`surface.reconstruct.section_noise`); R rings,
                            a section may hold several loops.  How each ring was fitted
                            (``surface.catmull_rom.RingFit``): ``smoothing`` (R,) points
                            per control point, ``controls`` (R,) int64, ``data_points``
                            (R,) int64, ``loop_noise`` (R,) the loop's sigma-hat,
                            ``precision`` (R,) the ring's own sigma, ``ring_precision`` ()
                            their median (:func:`surface.section_errors.ring_precision`); absent in
                            files written before 2026-12-01 (:func:`read_curve_fits`: None)
``stitch/mesh.ply``         the stitched mesh (:func:`pipeline.mesh_io.write_mesh`);
``stitch/stitch.json``      its notes (closed, messages, open interfaces, flips ...)
``smooth/surface.ply``      the tessellated Bézier surface with its exact normals
``smooth/control_net.npz``  ``control_points`` (P,28,3), ``index`` (28,3), ``source_face``
                            (P,), ``domain_vertices``, ``domain_triangles`` (the refined
                            control mesh)
``export/surface.*``        the surface in every export format; ``export/surface.npz``
                            the control net in :mod:`pipeline.export`'s format
==========================  =============================================================
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from pipeline.cloud_io import write_ply
from pipeline.mesh_io import read_mesh, write_mesh
from pipeline.workspace import save_npz, write_text

CLOUD = "cloud.npz"
CLOUD_PLY = "cloud.ply"
SECTIONS = "sections.npz"
CURVES = "curves.npz"
MESH = "mesh.ply"
STITCH_NOTES = "stitch.json"
SURFACE = "surface.ply"
CONTROL_NET = "control_net.npz"
CAMERAS = "cameras.yml"
#: The acquire stage's record of the cameras' ring (for sections.axis = "data").
RING_FILE = "ring.json"


def _members(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Every array of an ``.npz``, each read once (``NpzFile[key]`` decodes on every access)."""
    with np.load(path) as npz:
        return {key: npz[key] for key in npz.files}


# --------------------------------------------------------------------------- cloud
def write_cloud(folder: str | os.PathLike, points, colours=None,
                sigma=None, source=None) -> dict[str, np.ndarray]:
    """``folder/cloud.npz`` and ``folder/cloud.ply`` (for viewers: MeshLab, CloudCompare).

    Parameters
    ----------
    points : (N, 3) array_like
    colours : (N, 3) array_like, optional
        0..255 (cast to uint8); zeros when absent.  Stored as the file's ``colors``
        array (the on-disk name, kept: workspaces written before read the same).
    sigma : (N,) array_like, optional
        Per-point standard deviation, scene units; NaN when absent.
    source : (N,) array_like, optional
        The view pair each point came from (an image folder's; negative: from no one pair,
        fused from several or a view's outline point), stored as ``source`` when given.

    Returns
    -------
    dict
        The arrays as written (``points``, ``colors``, ``sigma``).
    """
    folder = Path(folder)
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    colours = (np.zeros((len(points), 3), np.uint8) if colours is None
               else np.asarray(colours).astype(np.uint8).reshape(-1, 3))
    sigma = np.full(len(points), np.nan) if sigma is None else np.asarray(sigma, np.float64)
    extra = {} if source is None else {"source": np.asarray(source, np.int64).reshape(-1)}
    save_npz(folder / CLOUD, points=points, colors=colours, sigma=sigma, **extra)
    write_ply(folder / CLOUD_PLY, points, colours, sigma)
    return {"points": points, "colors": colours, "sigma": sigma}


def read_cloud(folder: str | os.PathLike) -> dict[str, np.ndarray]:
    """The arrays of ``folder/cloud.npz`` (``points``, ``colors``, ``sigma``)."""
    return _members(Path(folder) / CLOUD)


def write_cameras(folder: str | os.PathLike, cameras: Sequence) -> None:
    """``folder/cameras.yml``: the cameras an image folder was matched with when SfM
    posed it (the cloud's frame; OpenCV FileStorage, as ``--cameras`` reads it)."""
    from matching.cameras import write_cameras_yml

    write_cameras_yml(Path(folder) / CAMERAS, cameras)


def read_cameras(folder: str | os.PathLike) -> list:
    """The cameras of ``folder/cameras.yml`` (:func:`write_cameras`)."""
    from matching.cameras import read_cameras_yml

    return read_cameras_yml(Path(folder) / CAMERAS)


# --------------------------------------------------------------------------- sections
def write_sections(folder: str | os.PathLike, sections: Sequence, cap_cloud: np.ndarray,
                   spacing: float, cap_sigma: np.ndarray | None = None) -> Path:
    """``folder/sections.npz`` from non-empty :class:`surface.sections.Section` objects.

    Parameters
    ----------
    sections : sequence of Section
        Each with ``points`` (n_k, 3), ``height``, ``section_id``, ``origin`` (3,),
        ``frame`` (3, 3) (one frame for all: the first one is stored),
        ``source_index`` (n_k,).
    cap_cloud : (C, 3) float64
    spacing : float
        Distance between adjacent section planes, scene units.
    cap_sigma : (C,) float64, optional
        Precision of the cap points (NaN unknown; default all unknown).
    """
    if cap_sigma is None:
        cap_sigma = np.full(len(cap_cloud), np.nan)
    offsets = np.concatenate([[0], np.cumsum([len(s) for s in sections])]).astype(np.int64)
    return save_npz(Path(folder) / SECTIONS,
                    points=np.concatenate([s.points for s in sections]), offsets=offsets,
                    heights=np.array([s.height for s in sections]),
                    section_id=np.array([s.section_id for s in sections], np.int64),
                    origin=np.array([s.origin for s in sections]), frame=sections[0].frame,
                    source_index=np.concatenate([s.source_index for s in sections]
                                                ).astype(np.int64),
                    cap_cloud=cap_cloud,
                    cap_sigma=np.asarray(cap_sigma, dtype=np.float64).reshape(len(cap_cloud)),
                    spacing=np.float64(spacing))


def read_sections(folder: str | os.PathLike) -> tuple[list, np.ndarray, float]:
    """The sections of ``folder/sections.npz``, its cap cloud ``(C, 3)`` and the spacing."""
    from surface.sections import Section

    d = _members(Path(folder) / SECTIONS)
    off = d["offsets"]
    sections = [Section(height=float(d["heights"][k]), points=d["points"][off[k]:off[k + 1]],
                        origin=d["origin"][k], frame=d["frame"].copy(),
                        section_id=int(d["section_id"][k]),
                        source_index=d["source_index"][off[k]:off[k + 1]])
                for k in range(len(off) - 1)]
    return sections, d["cap_cloud"], float(d["spacing"])


def read_cap_sigma(folder: str | os.PathLike) -> np.ndarray | None:
    """The cap points' precision ``(C,)`` of ``folder/sections.npz``; ``None`` when the
    workspace predates it or no σ is known."""
    with np.load(Path(folder) / SECTIONS) as npz:
        if "cap_sigma" not in npz.files:
            return None
        sigma = npz["cap_sigma"]
    return sigma if np.isfinite(sigma).any() else None


def section_heights(folder: str | os.PathLike) -> np.ndarray:
    """The section planes' heights ``(K,)`` of ``folder/sections.npz`` (no points read)."""
    with np.load(Path(folder) / SECTIONS) as d:
        return d["heights"]


# --------------------------------------------------------------------------- curves
def write_curves(folder: str | os.PathLike, rings: Sequence, sections: Sequence,
                 noise: float, fits: Sequence | None = None, params: Sequence | None = None,
                 step: float | None = None) -> tuple[int, int]:
    """``folder/curves.npz``: the rings of each section, flattened.

    Parameters
    ----------
    rings : sequence
        Per section, one ``(n, 3)`` ring or a list of rings (several loops).
    sections : sequence of Section
        The sections the rings belong to (same order): their heights and frame.
    noise : float
        The section points' sigma, scene units.
    params, step : optional
        Open arcs (``surface.open_surface.open_arcs``): each ring's common parameter
        ``u`` ``(n_k,)`` and the odd arcs' grid step; stored as ``u`` and ``u_step``
        (:func:`read_arc_parameters`), which mark the curves as open.
    fits : sequence, optional
        Mirroring ``rings``: each ring's ``surface.catmull_rom.RingFit`` (or a list of
        them); stored per ring with their median precision.

    Returns
    -------
    (int, int)
        Number of rings and of ring points written.
    """
    flat, sec, loop_ids = [], [], []
    for s_index, item in enumerate(rings):
        for lp, ring in enumerate([item] if getattr(item, "ndim", 0) == 2 else list(item)):
            flat.append(np.asarray(ring, np.float64))
            sec.append(s_index)
            loop_ids.append(lp)
    offsets = np.concatenate([[0], np.cumsum([len(r) for r in flat])]).astype(np.int64)
    frame = sections[0].frame
    extra = {}
    if fits is not None:
        from surface.section_errors import ring_precision

        records = [f for item in fits for f in ([item] if hasattr(item, "precision")
                                                 else list(item))]
        if len(records) != len(flat):
            raise ValueError(f"fits: {len(records)} records for {len(flat)} rings")
        extra = {"smoothing": np.array([f.smoothing for f in records], np.float64),
                 "controls": np.array([f.controls for f in records], np.int64),
                 "data_points": np.array([f.points for f in records], np.int64),
                 "loop_noise": np.array([f.noise for f in records], np.float64),
                 "precision": np.array([f.precision for f in records], np.float64),
                 "ring_precision": np.float64(ring_precision(records))}
    if params is not None:
        extra["u"] = np.concatenate([np.asarray(u, np.float64) for u in params])
        extra["u_step"] = np.float64(step)
        if len(extra["u"]) != int(offsets[-1]):
            raise ValueError(f"params: {len(extra['u'])} values for {offsets[-1]} ring points")
    save_npz(Path(folder) / CURVES, points=np.concatenate(flat), offsets=offsets,
             section=np.array(sec, np.int64), loop=np.array(loop_ids, np.int64),
             heights=np.array([sections[k].height for k in sec]), axis=frame[2], frame=frame,
             noise=np.float64(noise), **extra)
    return len(flat), int(offsets[-1])


def read_curves(folder: str | os.PathLike) -> tuple[list, list, float | None]:
    """Rings of ``folder/curves.npz`` per section (a list of loops each), the sections'
    planes as ``Section`` objects without points (height and frame), and the section
    points' noise sigma (None in a curves.npz written before it was stored)."""
    from surface.sections import Section

    d = _members(Path(folder) / CURVES)
    off, sec, frame = d["offsets"], d["section"], d["frame"]
    rings: list[list] = []
    planes = []
    for k in range(len(off) - 1):
        if k == 0 or sec[k] != sec[k - 1]:
            rings.append([])
            planes.append(Section(height=float(d["heights"][k]), points=np.zeros((0, 3)),
                                  origin=np.zeros(3), frame=frame, section_id=len(planes)))
        rings[-1].append(d["points"][off[k]:off[k + 1]])
    return rings, planes, (float(d["noise"]) if "noise" in d else None)


def read_arc_parameters(folder: str | os.PathLike) -> tuple[list, float] | None:
    """Open arcs' common parameter per ring (one ring per section) and the grid step
    (:func:`write_curves` with ``params``); None for closed rings."""
    d = _members(Path(folder) / CURVES)
    if "u" not in d:
        return None
    off = d["offsets"]
    return [d["u"][off[k]:off[k + 1]] for k in range(len(off) - 1)], float(d["u_step"])


#: The per-ring fit arrays of ``curves.npz`` (:func:`write_curves` with ``fits``).
CURVE_FITS = ("smoothing", "controls", "data_points", "loop_noise", "precision")


def read_curve_fits(folder: str | os.PathLike) -> dict | None:
    """How the rings of ``folder/curves.npz`` were fitted: the per-ring arrays
    ``smoothing``, ``controls``, ``data_points``, ``loop_noise``, ``precision`` (R,) and
    the median ``ring_precision`` (float); None for a file written before they were
    stored."""
    with np.load(Path(folder) / CURVES) as d:
        if "ring_precision" not in d.files:
            return None
        out = {key: d[key] for key in CURVE_FITS}
        out["ring_precision"] = float(d["ring_precision"])
    return out


# --------------------------------------------------------------------------- stitch
def write_stitched(folder: str | os.PathLike, vertices: np.ndarray, triangles: np.ndarray,
                   notes: Mapping) -> None:
    """``folder/mesh.ply`` and its notes ``folder/stitch.json`` (sorted keys, one space)."""
    write_mesh(Path(folder) / MESH, vertices, triangles)
    write_text(Path(folder) / STITCH_NOTES, json.dumps(notes, indent=1, sort_keys=True) + "\n")


def read_stitched(folder: str | os.PathLike) -> tuple[np.ndarray, np.ndarray, dict]:
    """``(vertices, triangles, notes)`` of ``folder/mesh.ply`` and ``stitch.json``."""
    vertices, triangles = read_mesh(Path(folder) / MESH)
    notes_path = Path(folder) / STITCH_NOTES
    notes = json.loads(notes_path.read_text(encoding="utf-8")) if notes_path.is_file() else {}
    return vertices, triangles, notes


# --------------------------------------------------------------------------- smooth
def write_smooth(folder: str | os.PathLike, vertices: np.ndarray, triangles: np.ndarray,
                 normals: np.ndarray, surface) -> None:
    """``folder/surface.ply`` (with its exact normals) and ``folder/control_net.npz``.

    ``surface`` is a :class:`surface.bezier.BezierSurface` (``control_points``,
    ``source_face``, ``domain_mesh``).
    """
    from surface import bezier

    folder = Path(folder)
    write_mesh(folder / SURFACE, vertices, triangles, normals=normals)
    domain_vertices, domain_triangles = surface.domain_mesh
    save_npz(folder / CONTROL_NET, control_points=surface.control_points,
             index=bezier.index_table(), source_face=surface.source_face,
             domain_vertices=domain_vertices, domain_triangles=domain_triangles)


def read_control_net(folder: str | os.PathLike) -> dict[str, np.ndarray]:
    """The arrays of ``folder/control_net.npz``."""
    return _members(Path(folder) / CONTROL_NET)


def read_ply_normals(path: str | os.PathLike) -> np.ndarray | None:
    """The vertex normals ``(V, 3)`` stored in a PLY mesh (None if it has none)."""
    import open3d as o3d

    mesh = o3d.io.read_triangle_mesh(str(path))
    return np.asarray(mesh.vertex_normals, np.float64) if mesh.has_vertex_normals() else None
