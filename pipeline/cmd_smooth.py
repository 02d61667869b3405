"""``photosurf smooth``: a triangle mesh -> Loop's G1 sextic Bézier surface.

The mesh is the control mesh of ``surface.bezier.control_net`` (refined once,
so ``P = 4 F`` patches), tessellated at ``--level L`` (each patch edge cut into
``2**L`` segments: ``4**L`` triangles per patch), written with its exact
normals to ``OUT`` (.ply .obj .stl .gltf .glb) and the control net beside it as
``OUT`` with suffix ``.npz`` (``pipeline.export`` documents that format).

Default level: the pipeline's ``smooth.level`` (``pipeline/defaults.toml``),
one setting for ``photosurf run`` and ``photosurf smooth``.  It is chosen a
priori: the refinement halves the control mesh's edge h₀ and level L cuts a
patch edge into 2^L, so the flat triangles have edges h = h₀/2^(L+1) and
deviate from the exact surface by about the sagitta κh²/8 — 4× less per
level; the ``.npz`` keeps the exact surface whatever the level.  An STL input
(three vertices per facet) is welded first (bit-identical positions only).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from pipeline.errors import InputError

HELP = "smooth a triangle mesh into Loop's G1 sextic Bezier surface (mesh + control net)"

#: G1 is checked at this many points per interior patch edge (ends included).
EDGE_SAMPLES = 9


def _default_level() -> int:
    from pipeline.config import defaults

    return int(defaults()["smooth"]["level"])


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from pipeline.export import EXPORT_SUFFIXES

    parser.add_argument("mesh", metavar="MESH", help="oriented 2-manifold triangle mesh, "
                        "closed for a watertight result (.ply .obj .stl .off .gltf .glb): "
                        "the control mesh")
    parser.add_argument("--out", required=True, metavar="OUT",
                        help=f"tessellated surface ({' '.join(EXPORT_SUFFIXES)}); the control "
                             "net is written beside it as OUT.npz")
    parser.add_argument("--level", type=int, default=None, metavar="L",
                        help="tessellation level: 4^L triangles per patch, 4 patches per input "
                             f"triangle (default {_default_level()}, the pipeline's smooth.level)")


def smooth_to_files(vertices, triangles, out, level: int | None = None,
                    source: str = "control mesh") -> dict:
    """Build the Bézier surface over a control mesh; write ``out`` and ``out.npz``.

    The reusable core of this command (``photosurf sections --smooth`` can
    call it on the stitched mesh).

    Parameters
    ----------
    vertices : (V, 3) float64
    triangles : (F, 3) int64
        Oriented 2-manifold control mesh (closed gives a watertight surface;
        borders as far as ``surface.bezier.control_net`` accepts them).
    out : path-like
        Mesh file (suffix one of ``pipeline.export.EXPORT_SUFFIXES``); the
        control net goes to ``out`` with suffix ``.npz``.  Both appear
        together or not at all.
    level : int, optional
        Tessellation level (default: the pipeline's ``smooth.level``).
    source : str
        Name of the input used in error messages (e.g. its path).

    Returns
    -------
    dict
        ``patches``, ``vertices``, ``triangles``, ``level``, ``g1_angle``
        (radians), ``gap`` (scene units), ``mesh`` and ``control_net`` paths.

    Raises
    ------
    InputError
        Bad output name or level, or a control mesh the construction rejects
        (non-manifold, unoriented, bordered, degenerate).
    """
    from pipeline.export import EXPORT_SUFFIXES, export_surface
    from surface import bezier

    out = Path(out)
    level = _default_level() if level is None else int(level)
    if out.suffix.lower() not in EXPORT_SUFFIXES:
        raise InputError(f"{out}: cannot write mesh format {out.suffix!r} "
                         f"(choose one of {', '.join(EXPORT_SUFFIXES)})")
    if not 0 <= level <= 8:
        raise InputError(f"--level must be in 0..8, got {level}")
    try:
        surface = bezier.control_net(vertices, triangles)
    except ValueError as exc:
        raise InputError(f"{source}: cannot build the Bezier surface: {exc}") from exc
    tess_vertices, tess_triangles, tess_normals = bezier.tessellate(surface, level)
    gap, angle = bezier.edge_continuity(surface.control_points, surface.domain_mesh[1],
                                        samples=EDGE_SAMPLES)
    mesh_out, net_out = export_surface(out, tess_vertices, tess_triangles, tess_normals,
                                       surface.control_points, bezier.index_table(),
                                       surface.source_face, surface.domain_mesh)
    return {"patches": len(surface.control_points), "vertices": len(tess_vertices),
            "triangles": len(tess_triangles), "level": level, "g1_angle": angle, "gap": gap,
            "mesh": mesh_out, "control_net": net_out}


def run(args: argparse.Namespace) -> int:
    from pipeline.mesh_io import read_mesh_with_normals, weld_vertices

    mesh_path = Path(args.mesh)
    if Path(args.out).suffix.lower() == ".npz":
        raise InputError(f"{args.out}: the control net takes the .npz name; choose a mesh format")
    vertices, triangles, _ = read_mesh_with_normals(mesh_path)
    if mesh_path.suffix.lower() == ".stl":
        vertices, triangles = weld_vertices(vertices, triangles)
    info = smooth_to_files(vertices, triangles, args.out, args.level, source=str(mesh_path))
    if not args.quiet:
        print(f"photosurf smooth: {len(triangles)} control triangles -> "
              f"{info['patches']} sextic patches")
        print(f"  tessellation level {info['level']}: {info['vertices']} vertices, "
              f"{info['triangles']} triangles -> {info['mesh']}")
        print(f"  G1: largest normal angle across patch edges {info['g1_angle']:.3g} rad, "
              f"largest gap {info['gap']:.3g} ({EDGE_SAMPLES} points per edge)")
        print(f"  control net -> {info['control_net']}")
    return 0
